/* Marching squares (contour.h). */
#include "contour.h"

/* The point on the edge from corner p (value fp) to corner q (value fq) where f = level. */
static void cut(const double p[2], const double q[2], double fp, double fq, double level,
                double out[2])
{
    double t = (level - fp) / (fq - fp);
    out[0] = p[0] + t * (q[0] - p[0]);
    out[1] = p[1] + t * (q[1] - p[1]);
}

int ns_contour(const double *f, int nu, int nv, double level,
               int (*emit)(void *ctx, const double a[2], const double b[2]), void *ctx)
{
    for (int j = 0; j + 1 < nv; j++)
        for (int i = 0; i + 1 < nu; i++) {
            /* corners counter-clockwise: (i,j) (i+1,j) (i+1,j+1) (i,j+1) */
            const double c[4][2] = {{i, j}, {i + 1, j}, {i + 1, j + 1}, {i, j + 1}};
            const double v[4] = {f[j * nu + i], f[j * nu + i + 1], f[(j + 1) * nu + i + 1],
                                 f[(j + 1) * nu + i]};
            int mask = 0;
            for (int k = 0; k < 4; k++)
                mask |= (v[k] >= level) << k;
            if (mask == 0 || mask == 15)
                continue;
            /* the crossing on each edge k (corner k to k+1) that changes side */
            double x[4][2];
            int has[4];
            for (int k = 0; k < 4; k++) {
                int a = k, b = (k + 1) % 4;
                has[k] = (v[a] >= level) != (v[b] >= level);
                if (has[k])
                    cut(c[a], c[b], v[a], v[b], level, x[k]);
            }
            int rc = 0;
            if (mask == 5 || mask == 10) { /* a saddle: the centre decides which corners join */
                double mid = 0.25 * (v[0] + v[1] + v[2] + v[3]);
                int centre_above = mid >= level, corner0_above = (mask & 1) != 0;
                if (centre_above == corner0_above) { /* corners 0 and 2 joined through the centre */
                    rc = emit(ctx, x[0], x[1]);
                    rc = rc ? rc : emit(ctx, x[2], x[3]);
                } else {
                    rc = emit(ctx, x[3], x[0]);
                    rc = rc ? rc : emit(ctx, x[1], x[2]);
                }
            } else {
                int e[2], n = 0;
                for (int k = 0; k < 4 && n < 2; k++)
                    if (has[k])
                        e[n++] = k;
                rc = emit(ctx, x[e[0]], x[e[1]]);
            }
            if (rc)
                return rc;
        }
    return 0;
}
