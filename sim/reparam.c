/* Needle reparameterization (paper §3.4.2): carrying the rod's quantities onto a new set of
 * nodes, and the split / merge of edges that grew too long or too short.
 *
 * Every node is labelled by its distance from the base along the rod before the change (the sum
 * of the edge lengths before it). Quantities that the rod's forces are built from are carried
 * across with Akima's interpolation (sim/akima.h): the rest lengths through their running sum
 * (so that the new rest lengths add up to the old ones exactly), the twist as the angle of the
 * material frame from the rod's Bishop frame, and the rest curvature per unit length. Velocity and
 * acceleration are carried linearly, as the paper does, because Akima's curve is not monotone
 * and could inject energy. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "akima.h"
#include "rod.h"
#include "ns_limits.h"
#include "rod_internal.h"

/* Linear interpolation of the n points (xs, ys) (stride ys_stride) at xq, clamped at the ends. */
static double lerp_at(const double *xs, const double *ys, int stride, int n, double xq)
{
    if (xq <= xs[0])
        return ys[0];
    if (xq >= xs[n - 1])
        return ys[(size_t)stride * (size_t)(n - 1)];
    int lo = 0, hi = n - 1;
    while (hi - lo > 1) {
        int mid = (lo + hi) / 2;
        if (xs[mid] <= xq)
            lo = mid;
        else
            hi = mid;
    }
    double f = (xq - xs[lo]) / (xs[hi] - xs[lo]);
    return (1.0 - f) * ys[(size_t)stride * (size_t)lo] + f * ys[(size_t)stride * (size_t)hi];
}

/* Running sum of the current edge lengths: d[i] is node i's distance from the base. */
static void arc_parameters(const NsRod *r, double *d)
{
    d[0] = 0.0;
    for (int j = 0; j + 1 < r->nodes; j++) {
        double s = 0.0;
        for (int k = 0; k < 3; k++) {
            double e = r->x[3 * (j + 1) + k] - r->x[3 * j + k];
            s += e * e;
        }
        d[j + 1] = d[j] + sqrt(s);
    }
}

/* The body of ns_rod_resample; linear_rest carries the rest lengths' running sum linearly
 * instead of by Akima (the split and merge below: each piece of a split edge then gets its share
 * of the old rest length in proportion, and a merged edge the exact sum). */
static int resample(NsRod *r, const double *xn, const double *s, int m, int linear_rest)
{
    int n = r->nodes, ne = n - 1, me = m - 1;
    if (m < 3)
        return -1;
    for (int j = 0; j < m; j++) {
        if (!isfinite(s[j]) || (j > 0 && !(s[j] > s[j - 1])))
            return -1;
        for (int k = 0; k < 3; k++)
            if (!isfinite(xn[3 * j + k]))
                return -1;
        if (j > 0) {
            double l = 0.0;
            for (int k = 0; k < 3; k++) {
                double e = xn[3 * j + k] - xn[3 * (j - 1) + k];
                l += e * e;
            }
            if (!(l > 0.0))
                return -1;
        }
    }
    int big = n > m ? n : m;
    /* Old data: parameters d, running rest length L, edge midpoints sm with Bishop angles phi,
     * rest curvature (2 per node), v and a. New: the same at s. */
    size_t per = 17;
    double *buf =
        malloc((size_t)big * per * sizeof(double) + (2 * (size_t)big + 3) * sizeof(double));
    uint8_t *pin = malloc((size_t)m);
    if (!buf || !pin) {
        free(buf);
        free(pin);
        return -1;
    }
    double *d = buf, *L = d + big, *sm = L + big, *phi = sm + big, *kc = phi + big;
    double *kq = kc + big, *Ln = kq + big, *smn = Ln + big, *phin = smn + big;
    double *k1n = phin + big, *k2n = k1n + big, *vn = k2n + big, *an = vn + 3 * (size_t)big;
    double *work = buf + (size_t)big * per;
    arc_parameters(r, d);
    L[0] = 0.0;
    for (int j = 0; j < ne; j++)
        L[j + 1] = L[j] + r->rest_len[j];
    double psi = 0.0;
    for (int j = 0; j < ne; j++) {
        if (j > 0)
            psi += r->ref_twist[j];
        sm[j] = 0.5 * (d[j] + d[j + 1]);
        phi[j] = r->theta[j] + psi;
    }
    int rc = ns_akima(d, L, n, s, Ln, m, work);
    for (int j = 0; j < me; j++)
        smn[j] = 0.5 * (s[j] + s[j + 1]);
    rc |= ns_akima(sm, phi, ne, smn, phin, me, work);
    /* Rest curvature: interior nodes 1 .. n-2 of the old rod, at the interior new nodes. */
    if (n >= 3) {
        for (int c = 0; c < 2; c++) {
            for (int i = 1; i < ne; i++)
                kc[i - 1] = r->rest_curv[2 * i + c];
            for (int j = 1; j < me; j++)
                kq[j - 1] = s[j];
            rc |= ns_akima(d + 1, kc, ne - 1, kq, c == 0 ? k1n + 1 : k2n + 1, me - 1, work);
        }
    }
    if (rc != 0) {
        free(buf);
        free(pin);
        return -1;
    }
    for (int j = 0; j < m; j++)
        for (int k = 0; k < 3; k++) {
            vn[3 * j + k] = lerp_at(d, r->v + k, 3, n, s[j]);
            an[3 * j + k] = lerp_at(d, r->a + k, 3, n, s[j]);
        }
    /* A new node is pinned if it sits exactly where a pinned old node was. */
    for (int j = 0, i = 0; j < m; j++) {
        while (i < n && d[i] < s[j])
            i++;
        pin[j] = i < n && d[i] == s[j] ? r->pinned[i] : 0;
    }
    /* New rest lengths from the interpolated running sum; Akima can in principle make a piece
     * non-positive on wildly uneven data, then that piece falls back to the linear value. */
    double *newlen = kc; /* reuse */
    for (int j = 0; j < me; j++) {
        double l = Ln[j + 1] - Ln[j];
        if (linear_rest || !(l > 0.0))
            l = lerp_at(d, L, 1, n, s[j + 1]) - lerp_at(d, L, 1, n, s[j]);
        if (!(l > 0.0)) {
            free(buf);
            free(pin);
            return -1;
        }
        newlen[j] = l;
    }
    double t0_old[3], d10_old[3];
    memcpy(t0_old, r->ref_t, sizeof t0_old);
    memcpy(d10_old, r->ref_d1, sizeof d10_old);
    if (rod_reserve(r, m) != 0) {
        free(buf);
        free(pin);
        return -1;
    }
    r->nodes = m;
    memcpy(r->x, xn, 3 * (size_t)m * sizeof(double));
    memcpy(r->v, vn, 3 * (size_t)m * sizeof(double));
    memcpy(r->a, an, 3 * (size_t)m * sizeof(double));
    memcpy(r->pinned, pin, (size_t)m);
    for (int j = 0; j < me; j++) {
        r->rest_len[j] = newlen[j];
        double e[3], l = 0.0;
        for (int k = 0; k < 3; k++) {
            e[k] = xn[3 * (j + 1) + k] - xn[3 * j + k];
            l += e[k] * e[k];
        }
        l = sqrt(l);
        for (int k = 0; k < 3; k++)
            r->ref_t[3 * j + k] = e[k] / l;
    }
    rod_transport(t0_old, r->ref_t, d10_old, r->ref_d1);
    rod_bishop_frames(r);
    psi = 0.0;
    for (int j = 0; j < me; j++) {
        if (j > 0)
            psi += r->ref_twist[j];
        r->theta[j] = phin[j] - psi;
        r->twist_anchor[j] = r->theta[j]; /* the edges are new: the next step sets both */
        r->twist_fric[j] = 0.0;
    }
    for (int j = 0; j < m; j++) {
        r->rest_curv[2 * j] = j > 0 && j < me ? k1n[j] : 0.0;
        r->rest_curv[2 * j + 1] = j > 0 && j < me ? k2n[j] : 0.0;
    }
    rod_masses(r);
    free(buf);
    free(pin);
    return 0;
}

int ns_rod_resample(NsRod *r, const double *xn, const double *s, int m)
{
    return resample(r, xn, s, m, 0);
}

/* The rod's unit tangent at node i for the split cubic. */
static void node_tangent(const NsRod *r, int i, double *T)
{
    int ne = r->nodes - 1;
    double a[3] = {0, 0, 0}, b[3] = {0, 0, 0};
    if (i > 0)
        for (int k = 0; k < 3; k++)
            a[k] = r->x[3 * i + k] - r->x[3 * (i - 1) + k];
    if (i < ne)
        for (int k = 0; k < 3; k++)
            b[k] = r->x[3 * (i + 1) + k] - r->x[3 * i + k];
    double la = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
    double lb = sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2]);
    int sleeve_exit = r->held == 2 && i == 1;
    for (int k = 0; k < 3; k++) {
        double u = la > 0.0 ? a[k] / la : 0.0, w = lb > 0.0 ? b[k] / lb : 0.0;
        T[k] = i == 0 ? w : i == ne || sleeve_exit ? u : u + w;
    }
    double l = sqrt(T[0] * T[0] + T[1] * T[1] + T[2] * T[2]);
    for (int k = 0; k < 3; k++)
        T[k] = l > 0.0 ? T[k] / l : 0.0;
}

int ns_rod_reparameterize(NsRod *r, NsRodStats *stats)
{
    int n = r->nodes, ne = n - 1;
    double split = r->params.split_factor * r->max_rest_edge;
    double merge = r->params.merge_factor * r->min_rest_edge;
    /* First pass: decide. keep[i] = 0 drops node i; pieces[j] = number of pieces of edge j. */
    int first = r->held > 0 ? 1 : 0; /* edge 0 lies inside the sleeve */
    uint8_t *keep = malloc((size_t)n);
    int *pieces = malloc((size_t)n * sizeof *pieces);
    if (!keep || !pieces) {
        free(keep);
        free(pieces);
        return -1;
    }
    memset(keep, 1, (size_t)n);
    int splits = 0, merges = 0, m = n;
    for (int j = 0; j < ne; j++) {
        pieces[j] = 1;
        /* An edge between two pinned nodes (inside the tissue: it lies along a tissue edge) is
         * never split. */
        if (j < first || !(r->rest_len[j] > split) || (r->pinned[j] && r->pinned[j + 1]))
            continue;
        while (r->rest_len[j] / pieces[j] > split && pieces[j] < NS_LIMIT_ROD_NODES)
            pieces[j] *= 2; /* runs at least once: at least 2 pieces */
        splits += pieces[j] - 1;
        m += pieces[j] - 1;
        if (m > NS_LIMIT_ROD_NODES) { /* bounded by construction, whatever the speed asked */
            free(keep);
            free(pieces);
            return -1;
        }
    }
    for (int j = first; j < ne && m > 3; j++) {
        if (!(r->rest_len[j] < merge) || pieces[j] > 1 || !keep[j] || !keep[j + 1])
            continue;
        /* Drop the far node if it is free, else the near one; never a held or pinned node, the
         * base or the tip. */
        int cand[2] = {j + 1, j};
        for (int c = 0; c < 2; c++) {
            int i = cand[c];
            if (i < r->held || i == 0 || i == n - 1 || r->pinned[i])
                continue;
            if (pieces[i - 1] > 1 || pieces[i] > 1)
                continue;
            keep[i] = 0;
            merges++;
            m--;
            break;
        }
    }
    if (splits == 0 && merges == 0) {
        free(keep);
        free(pieces);
        return 0;
    }
    double *d = malloc((size_t)n * sizeof *d), *xn = malloc(3 * (size_t)m * sizeof *xn);
    double *s = malloc((size_t)m * sizeof *s);
    int rc = -1;
    if (!d || !xn || !s)
        goto done;
    arc_parameters(r, d);
    /* New node list: kept old nodes at their old parameters, and split points at equal
     * parameter fractions of their edge. */
    int q = 0;
    for (int i = 0; i < n; i++) {
        if (keep[i]) {
            s[q] = d[i];
            memcpy(xn + 3 * q, r->x + 3 * i, 3 * sizeof(double));
            q++;
        }
        if (i < ne && pieces[i] > 1)
            for (int p = 1; p < pieces[i]; p++) {
                s[q] = d[i] + (d[i + 1] - d[i]) * (double)p / (double)pieces[i];
                q++;
            }
    }
    /* Split points lie on the interpolating cubic of their edge: the Hermite cubic through its two
     * nodes with the rod's tangents there (the unit mean of the two edge tangents at an interior
     * node, the sleeve axis at the sleeve's exit, the edge's own at the tip), which reproduces a
     * circular arc to third order. A single split takes the cubic's midpoint, as the paper. */
    for (int i = 0, q2 = 0; i < n; i++) {
        q2 += keep[i];
        if (i >= ne || pieces[i] < 2)
            continue;
        double T0[3], T1[3], l = d[i + 1] - d[i];
        node_tangent(r, i, T0);
        node_tangent(r, i + 1, T1);
        for (int p = 1; p < pieces[i]; p++, q2++) {
            double f = (double)p / (double)pieces[i], f2 = f * f, f3 = f2 * f;
            double h00 = 2 * f3 - 3 * f2 + 1, h10 = f3 - 2 * f2 + f, h01 = -2 * f3 + 3 * f2;
            double h11 = f3 - f2;
            for (int k = 0; k < 3; k++)
                xn[3 * q2 + k] = h00 * r->x[3 * i + k] + h10 * l * T0[k] +
                                 h01 * r->x[3 * (i + 1) + k] + h11 * l * T1[k];
        }
    }
    rc = resample(r, xn, s, m, 1);
    if (rc == 0 && stats) {
        stats->splits += splits;
        stats->merges += merges;
    }
done:
    free(keep);
    free(pieces);
    free(d);
    free(xn);
    free(s);
    return rc;
}
