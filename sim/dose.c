/* The TG-43U1 dose model and the dose grid (dose.h; docs/brachytherapy.md). */
#include "dose.h"

#include <math.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>

#include "err.h"
#include "ns_config.h"

#define PI_2 1.57079632679489661923

/* i in [0, n-2] with x[i] <= v <= x[i+1] when v lies in the table, else the end interval
 * (n >= 2, x increasing). */
static int bracket(const double *x, int n, double v)
{
    int lo = 0, hi = n - 1;
    while (hi - lo > 1) {
        int mid = (lo + hi) / 2;
        if (v < x[mid])
            hi = mid;
        else
            lo = mid;
    }
    return lo;
}

static bool increasing(const double *x, int n)
{
    for (int i = 0; i < n; i++)
        if (!isfinite(x[i]) || (i > 0 && !(x[i] > x[i - 1])))
            return false;
    return true;
}

int ns_tg43_check(const NsTg43Source *s, char *err, int err_sz)
{
    if (!(isfinite(s->lambda) && s->lambda > 0.0)) {
        ns_set_err(err, err_sz, "dose-rate constant %g m^-2: must be > 0", s->lambda);
        return -1;
    }
    if (!(isfinite(s->length) && s->length >= 0.0 && s->length < 2.0 * NS_TG43_Z_CAP)) {
        ns_set_err(err, err_sz, "active length %g m: must be in [0, %g) m", s->length,
                   2.0 * NS_TG43_Z_CAP);
        return -1;
    }
    if (!(isfinite(s->half_life) && s->half_life > 0.0)) {
        ns_set_err(err, err_sz, "half-life %g s: must be > 0", s->half_life);
        return -1;
    }
    if (s->n_g < 2 || s->n_g > NS_TG43_MAX_G || !increasing(s->g_r, s->n_g) || !(s->g_r[0] > 0.0)) {
        ns_set_err(err, err_sz, "radial dose function: %d radii, need 2..%d positive increasing",
                   s->n_g, NS_TG43_MAX_G);
        return -1;
    }
    for (int i = 0; i < s->n_g; i++)
        if (!(isfinite(s->g[i]) && s->g[i] > 0.0)) {
            ns_set_err(err, err_sz, "radial dose function at r = %g m: g_L = %g, must be > 0",
                       s->g_r[i], s->g[i]);
            return -1;
        }
    if (s->n_fr < 1 || s->n_fr > NS_TG43_MAX_FR || !increasing(s->f_r, s->n_fr) ||
        !(s->f_r[0] > 0.0)) {
        ns_set_err(err, err_sz, "anisotropy function: %d radii, need 1..%d positive increasing",
                   s->n_fr, NS_TG43_MAX_FR);
        return -1;
    }
    if (s->n_ft < 2 || s->n_ft > NS_TG43_MAX_FT || !increasing(s->f_theta, s->n_ft) ||
        s->f_theta[0] != 0.0 || fabs(s->f_theta[s->n_ft - 1] - PI_2) > 1e-12) {
        ns_set_err(err, err_sz,
                   "anisotropy function: %d angles, need 2..%d increasing from 0 to 90 deg",
                   s->n_ft, NS_TG43_MAX_FT);
        return -1;
    }
    for (int k = 0; k < s->n_ft * s->n_fr; k++)
        if (!(isfinite(s->f[k]) && s->f[k] > 0.0 && s->f[k] < 2.0)) {
            ns_set_err(err, err_sz,
                       "anisotropy function: F = %g at angle row %d, radius column "
                       "%d: must be in (0, 2)",
                       s->f[k], k / s->n_fr, k % s->n_fr);
            return -1;
        }
    if (s->n_phi < 0 || s->n_phi > NS_TG43_MAX_FR) {
        ns_set_err(err, err_sz, "1D anisotropy function: %d points, at most %d", s->n_phi,
                   NS_TG43_MAX_FR);
        return -1;
    }
    return 0;
}

double ns_tg43_geometry(double L, double r, double theta)
{
    double rho = r * sin(theta), z = r * cos(theta);
    double r2 = r * r;
    if (L <= 0.0)
        return 1.0 / r2;
    double d = rho * rho + z * z - 0.25 * L * L;
    if (fabs(rho) <= 1e-12 * r) /* on the axis: TG-43U1's 1 / (r^2 - L^2/4) */
        return d > 0.0 ? 1.0 / d : INFINITY;
    /* beta, the angle between the rays to the two ends (z -+ L/2): its sine and cosine are the
     * cross and dot products of (z - L/2, rho) and (z + L/2, rho), rho L and r^2 - L^2/4. */
    double beta = atan2(fabs(rho) * L, d);
    return beta / (L * fabs(rho));
}

/* Log-linear g_L: linear in r, in log g. lng[i] = log(g[i]). */
static double radial_ln(const NsTg43Source *s, const double *lng, double r)
{
    int n = s->n_g;
    if (r <= s->g_r[0])
        return s->g[0];
    int i = bracket(s->g_r, n, r);
    double t = (r - s->g_r[i]) / (s->g_r[i + 1] - s->g_r[i]); /* > 1 beyond the last radius */
    return exp(lng[i] + t * (lng[i + 1] - lng[i]));
}

double ns_tg43_radial(const NsTg43Source *s, double r)
{
    double lng[NS_TG43_MAX_G];
    for (int i = 0; i < s->n_g; i++)
        lng[i] = log(s->g[i]);
    return radial_ln(s, lng, r);
}

double ns_tg43_anisotropy(const NsTg43Source *s, double r, double theta)
{
    if (theta > PI_2)
        theta = M_PI - theta;
    if (theta < 0.0)
        theta = 0.0;
    int nr = s->n_fr;
    int t = bracket(s->f_theta, s->n_ft, theta);
    double u = (theta - s->f_theta[t]) / (s->f_theta[t + 1] - s->f_theta[t]);
    const double *row0 = s->f + t * nr, *row1 = row0 + nr;
    if (nr == 1 || r <= s->f_r[0])
        return row0[0] + u * (row1[0] - row0[0]);
    if (r >= s->f_r[nr - 1])
        return row0[nr - 1] + u * (row1[nr - 1] - row0[nr - 1]);
    int i = bracket(s->f_r, nr, r);
    double v = (r - s->f_r[i]) / (s->f_r[i + 1] - s->f_r[i]);
    double a = row0[i] + u * (row1[i] - row0[i]);
    double b = row0[i + 1] + u * (row1[i + 1] - row0[i + 1]);
    return a + v * (b - a);
}

double ns_tg43_dose_rate(const NsTg43Source *s, double sk, double r, double theta)
{
    double g0 = ns_tg43_geometry(s->length, NS_TG43_R0, PI_2);
    return sk * s->lambda * ns_tg43_geometry(s->length, r, theta) / g0 * ns_tg43_radial(s, r) *
           ns_tg43_anisotropy(s, r, theta);
}

double ns_tg43_mean_life(const NsTg43Source *s)
{
    return s->half_life / log(2.0);
}

/* The grid's arithmetic. Two thirds of a plain evaluation went to libm's atan2 and to the table
 * searches (perf, 80 seeds x 64,000 voxels): the grid uses its own arctangent (a reduction to
 * |x| <= 1/128 by a table of atan(k/64), then the Taylor series; plain arithmetic, so
 * the same bits for every thread count) and finds table intervals from a bin index
 * made once per source. ns_dose_at uses the same code, so a voxel is exactly the point value. */
#define R_BIN  2.5e-4         /* radial bin of the interval index [m] */
#define R_BINS 512            /* radii beyond R_BINS * R_BIN start from the last bin */
#define T_BIN  (M_PI / 180.0) /* angular bin [rad] */
#define T_BINS 91

/* atan(x), 0 <= x <= 1: atan x = atan c + atan((x - c) / (1 + x c)) with c the nearest k/64
 * (atan_c[k] = atan(k/64)), |reduced| <= 1/128, then the odd Taylor series to y^9 (the next
 * term is below 1e-21 of the sum). */
static double atan_unit(const double *atan_c, double x)
{
    int k = (int)(x * 64.0 + 0.5);
    double ck = k * (1.0 / 64);
    double y = (x - ck) / (1.0 + x * ck), y2 = y * y;
    /* y (1 - y^2/3 + y^4/5 - y^6/7 + y^8/9), Horner in y^2 */
    double p = 1.0 / 7 - y2 * (1.0 / 9);
    p = 1.0 / 5 - y2 * p;
    p = 1.0 / 3 - y2 * p;
    p = 1.0 - y2 * p;
    return atan_c[k] + y * p;
}

/* atan2(y, x) for y >= 0, x >= 0 (0 at the origin): the smaller over the larger, so that which
 * of the two is larger is a select, not a branch (it changes from voxel to voxel). */
static double atan2_pos(const double *atan_c, double y, double x)
{
    double lo = y < x ? y : x, hi = y < x ? x : y;
    double a = hi > 0.0 ? atan_unit(atan_c, lo / hi) : 0.0;
    return y <= x ? a : PI_2 - a;
}

/* What the grid needs per source and per seed, computed once. */
typedef struct Prep {
    const NsTg43Source *s;
    double lng[NS_TG43_MAX_G];
    double tau_over_g0;             /* mean life / G_L(r0, theta0) [s m^2] */
    unsigned char g_at[R_BINS];     /* the g_L interval a radius in bin b starts its search at */
    unsigned char f_at[R_BINS];     /* the same for F's radii */
    unsigned char t_at[T_BINS + 1]; /* and for F's angles */
    double atan_c[65];              /* atan(k/64), k = 0..64 */
    double g_inv[NS_TG43_MAX_G];    /* 1 / (g_r[i+1] - g_r[i]) */
    double fr_inv[NS_TG43_MAX_FR];  /* 1 / (f_r[i+1] - f_r[i]) */
    double ft_inv[NS_TG43_MAX_FT];  /* 1 / (f_theta[i+1] - f_theta[i]) */
} Prep;

typedef struct SeedPrep {
    double pos[3], axis[3]; /* axis of unit length */
    double scale;           /* S_K Lambda tau / G_L(r0, theta0) [Gy m^2] */
} SeedPrep;

static void prep_source(const NsTg43Source *s, Prep *P)
{
    P->s = s;
    for (int i = 0; i < s->n_g; i++)
        P->lng[i] = log(s->g[i]);
    P->tau_over_g0 = ns_tg43_mean_life(s) / ns_tg43_geometry(s->length, NS_TG43_R0, PI_2);
    for (int b = 0; b < R_BINS; b++) {
        P->g_at[b] = (unsigned char)bracket(s->g_r, s->n_g, b * R_BIN);
        P->f_at[b] = (unsigned char)(s->n_fr > 1 ? bracket(s->f_r, s->n_fr, b * R_BIN) : 0);
    }
    for (int b = 0; b <= T_BINS; b++)
        P->t_at[b] = (unsigned char)bracket(s->f_theta, s->n_ft, b * T_BIN);
    for (int k = 0; k <= 64; k++)
        P->atan_c[k] = atan(k / 64.0);
    for (int i = 0; i + 1 < s->n_g; i++)
        P->g_inv[i] = 1.0 / (s->g_r[i + 1] - s->g_r[i]);
    for (int i = 0; i + 1 < s->n_fr; i++)
        P->fr_inv[i] = 1.0 / (s->f_r[i + 1] - s->f_r[i]);
    for (int i = 0; i + 1 < s->n_ft; i++)
        P->ft_inv[i] = 1.0 / (s->f_theta[i + 1] - s->f_theta[i]);
}

/* bracket(x, n, v) from a start at or below the answer. */
static int advance(const double *x, int n, int i, double v)
{
    while (i < n - 2 && v >= x[i + 1])
        i++;
    return i;
}

static int r_bin(double r)
{
    double b = r / R_BIN;
    return b < (double)(R_BINS - 1) ? (int)b : R_BINS - 1;
}

/* g_L(r) F(r, theta), theta in [0, pi/2]: radial_ln and ns_tg43_anisotropy's arithmetic. */
static double radial_aniso(const Prep *P, double r, double theta)
{
    const NsTg43Source *s = P->s;
    int rb = r_bin(r);
    double g;
    if (r <= s->g_r[0]) {
        g = s->g[0];
    } else {
        int i = advance(s->g_r, s->n_g, P->g_at[rb], r);
        double t = (r - s->g_r[i]) * P->g_inv[i];
        g = exp(P->lng[i] + t * (P->lng[i + 1] - P->lng[i]));
    }
    int nr = s->n_fr, tb = (int)(theta / T_BIN);
    int t = advance(s->f_theta, s->n_ft, P->t_at[tb > T_BINS ? T_BINS : tb], theta);
    double u = (theta - s->f_theta[t]) * P->ft_inv[t];
    const double *row0 = s->f + t * nr, *row1 = row0 + nr;
    double f;
    if (nr == 1 || r <= s->f_r[0]) {
        f = row0[0] + u * (row1[0] - row0[0]);
    } else if (r >= s->f_r[nr - 1]) {
        f = row0[nr - 1] + u * (row1[nr - 1] - row0[nr - 1]);
    } else {
        int i = advance(s->f_r, nr, P->f_at[rb], r);
        double v = (r - s->f_r[i]) * P->fr_inv[i];
        double a = row0[i] + u * (row1[i] - row0[i]);
        double b = row0[i + 1] + u * (row1[i + 1] - row0[i + 1]);
        f = a + v * (b - a);
    }
    return g * f;
}

static void prep_seed(const Prep *P, const NsDoseSeed *d, SeedPrep *q)
{
    double len = sqrt(d->axis[0] * d->axis[0] + d->axis[1] * d->axis[1] + d->axis[2] * d->axis[2]);
    for (int c = 0; c < 3; c++) {
        q->pos[c] = d->pos[c];
        q->axis[c] = d->axis[c] / len;
    }
    q->scale = d->sk * P->s->lambda * P->tau_over_g0;
}

/* One seed's total dose to full decay [Gy] at p: the formalism in the seed's cylindrical
 * coordinates (rho off the axis, z along it), the capsule clamp (dose.h), and the geometry
 * function of ns_tg43_geometry written in rho and z. */
static double seed_dose(const Prep *P, const SeedPrep *q, const double p[3])
{
    double d0 = p[0] - q->pos[0], d1 = p[1] - q->pos[1], d2 = p[2] - q->pos[2];
    double z = d0 * q->axis[0] + d1 * q->axis[1] + d2 * q->axis[2];
    double rho2 = d0 * d0 + d1 * d1 + d2 * d2 - z * z;
    double rho = rho2 > 0.0 ? sqrt(rho2) : 0.0;
    double az = fabs(z);
    if (rho < NS_TG43_RHO_MIN && az < NS_TG43_Z_CAP)
        rho = NS_TG43_RHO_MIN;
    double r2 = rho * rho + z * z, r = sqrt(r2);
    double L = P->s->length, G;
    if (L <= 0.0) {
        G = 1.0 / r2;
    } else {
        double d = r2 - 0.25 * L * L;
        if (rho <= 1e-12 * r) /* on the axis beyond the capsule: r > L/2 */
            G = 1.0 / d;
        else /* beta = atan2(rho L, d), d of either sign */
            G = (d >= 0.0 ? atan2_pos(P->atan_c, rho * L, d)
                          : M_PI - atan2_pos(P->atan_c, rho * L, -d)) /
                (L * rho);
    }
    double theta =
        atan2_pos(P->atan_c, rho, az); /* folded into [0, pi/2]: F is symmetric about 90 deg */
    return q->scale * G * radial_aniso(P, r, theta);
}

int ns_dose_check_seeds(const NsDoseSeed *seeds, int n_seeds, char *err, int err_sz)
{
    if (n_seeds < 0 || n_seeds > NS_DOSE_MAX_SEEDS || (n_seeds > 0 && !seeds)) {
        ns_set_err(err, err_sz, "%d seeds: must be 0..%d", n_seeds, NS_DOSE_MAX_SEEDS);
        return -1;
    }
    for (int k = 0; k < n_seeds; k++) {
        const NsDoseSeed *d = &seeds[k];
        double a2 = 0.0;
        bool finite = isfinite(d->sk);
        for (int c = 0; c < 3; c++) {
            finite = finite && isfinite(d->pos[c]) && isfinite(d->axis[c]);
            a2 += d->axis[c] * d->axis[c];
        }
        if (!finite || !(a2 > 1e-24) || !isfinite(a2) || !(d->sk > 0.0)) {
            ns_set_err(err, err_sz,
                       "seed %d: position, axis and strength must be finite, the axis non-zero "
                       "and the strength > 0 (S_K %g Gy m^2/s)",
                       k + 1, d->sk);
            return -1;
        }
    }
    return 0;
}

double ns_dose_at(const NsTg43Source *s, const NsDoseSeed *seeds, int n_seeds, const double p[3])
{
    Prep P;
    prep_source(s, &P);
    double sum = 0.0;
    for (int k = 0; k < n_seeds; k++) {
        SeedPrep q;
        prep_seed(&P, &seeds[k], &q);
        sum += seed_dose(&P, &q, p);
    }
    return sum;
}

static int grid_shape(const double lo[3], const double hi[3], double h, int n[3], char *err,
                      int err_sz)
{
    if (!(isfinite(h) && h >= NS_DOSE_MIN_SPACING)) {
        ns_set_err(err, err_sz, "dose grid spacing %g m: must be at least %g m", h,
                   NS_DOSE_MIN_SPACING);
        return -1;
    }
    double count = 1.0;
    for (int c = 0; c < 3; c++) {
        double size = hi[c] - lo[c];
        if (!(isfinite(lo[c]) && isfinite(hi[c]) && size > 0.0)) {
            ns_set_err(err, err_sz,
                       "dose grid box: axis %d from %g to %g m is empty or not "
                       "finite",
                       c, lo[c], hi[c]);
            return -1;
        }
        double cells = ceil(size / h - 1e-9);
        count *= cells;
        if (count > (double)NS_DOSE_MAX_VOXELS) {
            ns_set_err(err, err_sz, "dose grid: more than %ld voxels (box / spacing %g m)",
                       NS_DOSE_MAX_VOXELS, h);
            return -1;
        }
        n[c] = cells < 1.0 ? 1 : (int)cells;
    }
    return 0;
}

/* Slice k of the grid: every voxel, the seeds summed in order from 0. */
static void grid_slice(const Prep *P, const SeedPrep *q, int n_seeds, NsDoseGrid *g, int k)
{
    int nx = g->n[0], ny = g->n[1];
    double *out = g->dose + (size_t)k * nx * ny;
    double h = g->spacing, p[3];
    p[2] = g->lo[2] + (k + 0.5) * h;
    for (int j = 0; j < ny; j++) {
        p[1] = g->lo[1] + (j + 0.5) * h;
        for (int i = 0; i < nx; i++) {
            p[0] = g->lo[0] + (i + 0.5) * h;
            double sum = 0.0;
            for (int m = 0; m < n_seeds; m++)
                sum += seed_dose(P, &q[m], p);
            out[j * nx + i] = sum;
        }
    }
}

int ns_dose_grid(const NsTg43Source *s, const NsDoseSeed *seeds, int n_seeds, const double lo[3],
                 const double hi[3], double spacing, int threads, NsDoseGrid *g, char *err,
                 int err_sz)
{
    memset(g, 0, sizeof *g);
    if (ns_tg43_check(s, err, err_sz) || ns_dose_check_seeds(seeds, n_seeds, err, err_sz))
        return -1;
    int n[3];
    if (grid_shape(lo, hi, spacing, n, err, err_sz))
        return -1;
    size_t count = (size_t)n[0] * n[1] * n[2];
    double *dose = malloc(count * sizeof *dose);
    SeedPrep *q = malloc((size_t)(n_seeds > 0 ? n_seeds : 1) * sizeof *q);
    if (!dose || !q) {
        free(dose);
        free(q);
        ns_set_err(err, err_sz, "dose grid: out of memory (%zu voxels)", count);
        return -1;
    }
    Prep P;
    prep_source(s, &P);
    for (int m = 0; m < n_seeds; m++)
        prep_seed(&P, &seeds[m], &q[m]);
    for (int c = 0; c < 3; c++) {
        g->lo[c] = lo[c];
        g->n[c] = n[c];
    }
    g->spacing = spacing;
    g->dose = dose;
    int nz = n[2], chunks = 1;
#if NS_HAVE_OPENMP
    chunks = threads > 1 ? (threads < nz ? threads : nz) : 1;
#pragma omp parallel for num_threads(chunks) schedule(static) if (chunks > 1)
#else
    (void)threads;
#endif
    for (int k = 0; k < nz; k++)
        grid_slice(&P, q, n_seeds, g, k);
    (void)chunks;
    free(q);
    return 0;
}

void ns_dose_grid_free(NsDoseGrid *g)
{
    free(g->dose);
    g->dose = NULL;
}

int ns_dose_points(const NsTg43Source *s, const NsDoseSeed *seeds, int n_seeds, const double *pts,
                   long n, int threads, double *out, char *err, int err_sz)
{
    if (ns_tg43_check(s, err, err_sz) || ns_dose_check_seeds(seeds, n_seeds, err, err_sz))
        return -1;
    if (n < 0 || n > NS_DOSE_MAX_VOXELS || (n > 0 && (!pts || !out))) {
        ns_set_err(err, err_sz, "%ld dose points: must be 0..%ld", n, NS_DOSE_MAX_VOXELS);
        return -1;
    }
    SeedPrep *q = malloc((size_t)(n_seeds > 0 ? n_seeds : 1) * sizeof *q);
    if (!q) {
        ns_set_err(err, err_sz, "dose points: out of memory (%d seeds)", n_seeds);
        return -1;
    }
    Prep P;
    prep_source(s, &P);
    for (int m = 0; m < n_seeds; m++)
        prep_seed(&P, &seeds[m], &q[m]);
#if NS_HAVE_OPENMP
    int chunks = threads > 1 ? threads : 1;
#pragma omp parallel for num_threads(chunks) schedule(static) if (chunks > 1 && n > 1024)
#else
    (void)threads;
#endif
    for (long i = 0; i < n; i++) {
        double sum = 0.0;
        for (int m = 0; m < n_seeds; m++)
            sum += seed_dose(&P, &q[m], pts + 3 * i);
        out[i] = sum;
    }
    free(q);
    return 0;
}
