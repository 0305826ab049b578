/* Akima interpolation (Akima 1970), for the needle's reparameterization (§3.4.2). */
#include "akima.h"

#include <math.h>

int ns_akima(const double *xs, const double *ys, int n, const double *xq, double *yq, int m,
             double *work)
{
    if (n < 1)
        return -1;
    for (int i = 0; i < n; i++)
        if (!isfinite(xs[i]) || (i > 0 && !(xs[i] > xs[i - 1])))
            return -1;
    if (n == 1) {
        for (int k = 0; k < m; k++)
            yq[k] = ys[0];
        return 0;
    }
    /* Chord slopes d[i + 2] = m_i for i = 0..n-2, extended by two on each side so that every
     * point has the four neighbouring chords Akima's weights need (his end rule: the extra
     * points continue the quadratic through the last three, i.e. the slopes change linearly). */
    double *d = work, *t = work + n + 3;
    for (int i = 0; i + 1 < n; i++)
        d[i + 2] = (ys[i + 1] - ys[i]) / (xs[i + 1] - xs[i]);
    if (n == 2) {
        d[0] = d[1] = d[4] = d[5] = d[2];
    } else {
        d[1] = 2.0 * d[2] - d[3];
        d[0] = 2.0 * d[1] - d[2];
        d[n + 1] = 2.0 * d[n] - d[n - 1];
        d[n + 2] = 2.0 * d[n + 1] - d[n];
    }
    /* Slope at point i: chords m_{i-2}, m_{i-1} on its left, m_i, m_{i+1} on its right, i.e.
     * d[i], d[i+1], d[i+2], d[i+3]; each side weighted by how much the other side bends. */
    for (int i = 0; i < n; i++) {
        double wl = fabs(d[i + 3] - d[i + 2]), wr = fabs(d[i + 1] - d[i]);
        t[i] = wl + wr > 0.0 ? (wl * d[i + 1] + wr * d[i + 2]) / (wl + wr)
                             : 0.5 * (d[i + 1] + d[i + 2]);
    }
    int seg = 0;
    for (int k = 0; k < m; k++) {
        double x = xq[k];
        if (x <= xs[0]) {
            yq[k] = ys[0] + t[0] * (x - xs[0]);
            continue;
        }
        if (x >= xs[n - 1]) {
            yq[k] = ys[n - 1] + t[n - 1] * (x - xs[n - 1]);
            continue;
        }
        /* Queries usually come in order: walk from the last interval, else bisect. */
        if (!(xs[seg] <= x && x < xs[seg + 1])) {
            int lo = 0, hi = n - 1;
            while (hi - lo > 1) {
                int mid = (lo + hi) / 2;
                if (xs[mid] <= x)
                    lo = mid;
                else
                    hi = mid;
            }
            seg = lo;
        }
        /* Cubic Hermite on [xs[seg], xs[seg+1]] with end slopes t. */
        double h = xs[seg + 1] - xs[seg], s = (x - xs[seg]) / h;
        double c = d[seg + 2];
        double p2 = (3.0 * c - 2.0 * t[seg] - t[seg + 1]) / h;
        double p3 = (t[seg] + t[seg + 1] - 2.0 * c) / (h * h);
        double u = s * h;
        yq[k] = ys[seg] + u * (t[seg] + u * (p2 + u * p3));
    }
    return 0;
}
