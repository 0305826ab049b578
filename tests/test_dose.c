/* sim/dose.c: the TG-43 interpolation rules, the geometry function, and the dose grid (a voxel
 * is the point formula; two seeds superpose; the dose is symmetric about a seed's axis; thread
 * counts give the same bits; bad input is refused). A small made-up source, not the 6711 data
 * (engine/validate_dose.c checks that). */
#include <math.h>
#include <stdlib.h>

#include "dose.h"
#include "dvh.h"
#include "ns_test.h"

#define DEG (M_PI / 180.0)

static NsTg43Source source(void)
{
    NsTg43Source s;
    memset(&s, 0, sizeof s);
    s.lambda = 1e4; /* 1 cGy h^-1 U^-1 */
    s.length = 0.003;
    s.half_life = 59.4 * 86400.0;
    static const double gr[] = {0.001, 0.01, 0.02, 0.05}, g[] = {1.2, 1.0, 0.8, 0.4};
    s.n_g = 4;
    for (int i = 0; i < 4; i++) {
        s.g_r[i] = gr[i];
        s.g[i] = g[i];
    }
    s.n_fr = 2;
    s.f_r[0] = 0.01;
    s.f_r[1] = 0.03;
    static const double th[] = {0, 30, 90}, f[] = {0.4, 0.6, 0.8, 0.9, 1.0, 1.0};
    s.n_ft = 3;
    for (int t = 0; t < 3; t++)
        s.f_theta[t] = t == 2 ? M_PI / 2 : th[t] * DEG;
    for (int k = 0; k < 6; k++)
        s.f[k] = f[k];
    return s;
}

static int test_radial_interpolation(void)
{
    NsTg43Source s = source();
    ENSURE(ns_tg43_check(&s, NULL, 0) == 0);
    ENSURE_SMALL(ns_tg43_radial(&s, 0.01) - 1.0, 1e-15);
    /* log-linear: halfway in r is the geometric mean */
    ENSURE_SMALL(ns_tg43_radial(&s, 0.015) - sqrt(1.0 * 0.8), 1e-14);
    ENSURE_SMALL(ns_tg43_radial(&s, 0.0005) - 1.2, 0.0); /* below the table: the first value */
    /* beyond: the last two points' log-linear line, 0.8 * (0.4/0.8)^((0.08-0.02)/0.03) */
    ENSURE_SMALL(ns_tg43_radial(&s, 0.08) - 0.2, 1e-14);
    return 0;
}

static int test_anisotropy_interpolation(void)
{
    NsTg43Source s = source();
    ENSURE_SMALL(ns_tg43_anisotropy(&s, 0.01, 15 * DEG) - 0.6, 1e-14);    /* linear in theta */
    ENSURE_SMALL(ns_tg43_anisotropy(&s, 0.02, 0.0) - 0.5, 1e-14);         /* linear in r */
    ENSURE_SMALL(ns_tg43_anisotropy(&s, 0.02, 15 * DEG) - 0.675, 1e-14);  /* both */
    ENSURE_SMALL(ns_tg43_anisotropy(&s, 0.02, 165 * DEG) - 0.675, 1e-14); /* mirrored */
    ENSURE_SMALL(ns_tg43_anisotropy(&s, 0.002, 0.0) - 0.4, 1e-15);        /* nearest radius */
    ENSURE_SMALL(ns_tg43_anisotropy(&s, 0.09, 30 * DEG) - 0.9, 1e-15);
    ENSURE_SMALL(ns_tg43_anisotropy(&s, 0.02, 90 * DEG) - 1.0, 1e-15);
    return 0;
}

static int test_geometry(void)
{
    double L = 0.003;
    /* transverse axis: beta = 2 atan(L / 2r) */
    ENSURE_SMALL(ns_tg43_geometry(L, 0.01, M_PI / 2) / (2 * atan(L / 0.02) / (L * 0.01)) - 1,
                 1e-14);
    ENSURE_SMALL(ns_tg43_geometry(L, 0.01, 0.0) * (1e-4 - L * L / 4) - 1, 1e-14);
    ENSURE(isinf(ns_tg43_geometry(L, 0.001, 0.0))); /* on the active length */
    ENSURE_SMALL(ns_tg43_geometry(0.0, 0.02, 0.3) * 4e-4 - 1, 1e-15);
    /* continuous onto the axis */
    ENSURE_SMALL(ns_tg43_geometry(L, 0.01, 1e-7) / ns_tg43_geometry(L, 0.01, 0.0) - 1, 1e-9);
    return 0;
}

static const double LO[3] = {-0.01, -0.01, -0.01}, HI[3] = {0.01, 0.01, 0.01};

static int test_voxel_is_point_formula(void)
{
    NsTg43Source s = source();
    NsDoseSeed seed = {{0.0003, -0.0002, 0.0001}, {0, 0, 2}, NS_TG43_UNIT_U};
    NsDoseGrid g;
    char err[256];
    ENSURE(ns_dose_grid(&s, &seed, 1, LO, HI, 1e-3, 1, &g, err, sizeof err) == 0);
    ENSURE(g.n[0] == 20 && g.n[1] == 20 && g.n[2] == 20);
    double tau = ns_tg43_mean_life(&s), worst = 0.0;
    for (int k = 0; k < 20; k++)
        for (int j = 0; j < 20; j++)
            for (int i = 0; i < 20; i++) {
                double p[3] = {LO[0] + (i + 0.5) * 1e-3, LO[1] + (j + 0.5) * 1e-3,
                               LO[2] + (k + 0.5) * 1e-3};
                double v = g.dose[(k * 20 + j) * 20 + i];
                ENSURE(v == ns_dose_at(&s, &seed, 1, p)); /* the same code, the same bits */
                double d[3] = {p[0] - seed.pos[0], p[1] - seed.pos[1], p[2] - seed.pos[2]};
                double r = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
                double rho = sqrt(d[0] * d[0] + d[1] * d[1]);
                if (rho < NS_TG43_RHO_MIN && fabs(d[2]) < NS_TG43_Z_CAP)
                    continue; /* inside the capsule: clamped */
                double want = ns_tg43_dose_rate(&s, seed.sk, r, acos(d[2] / r)) * tau;
                worst = fmax(worst, fabs(v / want - 1));
            }
    ENSURE_SMALL(worst, 1e-12); /* the grid's own arctangent and interval search vs libm's */
    ns_dose_grid_free(&g);
    return 0;
}

static int test_superposition_and_threads(void)
{
    NsTg43Source s = source();
    NsDoseSeed seeds[2] = {{{0.002, 0.001, -0.003}, {0, 0, 1}, NS_TG43_UNIT_U},
                           {{-0.004, 0.0005, 0.002}, {1, 1, 0}, 0.7 * NS_TG43_UNIT_U}};
    NsDoseGrid both, a, b, two;
    ENSURE(ns_dose_grid(&s, seeds, 2, LO, HI, 1e-3, 1, &both, NULL, 0) == 0);
    ENSURE(ns_dose_grid(&s, seeds, 1, LO, HI, 1e-3, 1, &a, NULL, 0) == 0);
    ENSURE(ns_dose_grid(&s, seeds + 1, 1, LO, HI, 1e-3, 1, &b, NULL, 0) == 0);
    ENSURE(ns_dose_grid(&s, seeds, 2, LO, HI, 1e-3, 2, &two, NULL, 0) == 0);
    for (int v = 0; v < 8000; v++)
        ENSURE(both.dose[v] == a.dose[v] + b.dose[v]);
    ENSURE(ns_same_bits(both.dose, two.dose, 8000));
    ns_dose_grid_free(&both);
    ns_dose_grid_free(&a);
    ns_dose_grid_free(&b);
    ns_dose_grid_free(&two);
    return 0;
}

static int test_symmetric_about_axis(void)
{
    NsTg43Source s = source();
    /* a seed at the box's centre along z: x <-> y, x -> -x and z -> -z leave the dose alone */
    NsDoseSeed seed = {{0, 0, 0}, {0, 0, 1}, NS_TG43_UNIT_U};
    NsDoseGrid g;
    ENSURE(ns_dose_grid(&s, &seed, 1, LO, HI, 1e-3, 1, &g, NULL, 0) == 0);
    double worst = 0.0;
#define AT(i, j, k) g.dose[((k)*20 + (j)) * 20 + (i)]
    for (int k = 0; k < 20; k++)
        for (int j = 0; j < 20; j++)
            for (int i = 0; i < 20; i++) {
                double v = AT(i, j, k);
                worst = fmax(worst, fabs(AT(j, i, k) / v - 1));
                worst = fmax(worst, fabs(AT(19 - i, j, k) / v - 1));
                worst = fmax(worst, fabs(AT(i, j, 19 - k) / v - 1));
            }
#undef AT
    ENSURE_SMALL(worst, 1e-13);
    ns_dose_grid_free(&g);
    /* a tilted seed along (1,1,1): turning a point a third of a turn about the axis (x->y->z) */
    NsDoseSeed tilt = {{0.001, 0.001, 0.001}, {1, 1, 1}, NS_TG43_UNIT_U};
    for (int n = 0; n < 50; n++) {
        double p[3] = {0.001 + 0.004 * sin(n), 0.001 + 0.006 * cos(3 * n),
                       0.001 - 0.003 * sin(7 * n)};
        double q[3] = {p[2], p[0], p[1]};
        double dp = ns_dose_at(&s, &tilt, 1, p), dq = ns_dose_at(&s, &tilt, 1, q);
        ENSURE_SMALL(dq / dp - 1, 1e-12);
    }
    return 0;
}

static int test_bad_input(void)
{
    NsTg43Source s = source();
    NsDoseGrid g;
    char err[256];
    NsDoseSeed seed = {{0, 0, 0}, {0, 0, 0}, NS_TG43_UNIT_U};
    ENSURE(ns_dose_grid(&s, &seed, 1, LO, HI, 1e-3, 1, &g, err, sizeof err) == -1);
    ENSURE(strstr(err, "seed 1") != NULL && g.dose == NULL);
    seed.axis[2] = 1.0;
    seed.sk = -1.0;
    ENSURE(ns_dose_grid(&s, &seed, 1, LO, HI, 1e-3, 1, &g, err, sizeof err) == -1);
    seed.sk = NS_TG43_UNIT_U;
    seed.pos[0] = NAN;
    ENSURE(ns_dose_grid(&s, &seed, 1, LO, HI, 1e-3, 1, &g, err, sizeof err) == -1);
    seed.pos[0] = 0.0;
    ENSURE(ns_dose_grid(&s, &seed, 1, HI, LO, 1e-3, 1, &g, err, sizeof err) == -1); /* empty box */
    ENSURE(ns_dose_grid(&s, &seed, 1, LO, HI, 0.0, 1, &g, err, sizeof err) == -1);
    ENSURE(ns_dose_grid(&s, &seed, 1, LO, HI, 1e-5, 1, &g, err, sizeof err) == -1); /* 8e9 voxels */
    ENSURE(strstr(err, "voxels") != NULL);
    NsTg43Source bad = s;
    bad.g_r[2] = bad.g_r[1];
    ENSURE(ns_tg43_check(&bad, err, sizeof err) == -1);
    bad = s;
    bad.f_theta[2] = 80 * DEG; /* F must reach 90 deg */
    ENSURE(ns_tg43_check(&bad, err, sizeof err) == -1);
    bad = s;
    bad.lambda = 0.0;
    ENSURE(ns_dose_grid(&bad, &seed, 1, LO, HI, 1e-3, 1, &g, err, sizeof err) == -1);
    ENSURE(ns_dose_grid(&s, &seed, 1, LO, HI, 1e-3, 1, &g, err, sizeof err) == 0);
    ns_dose_grid_free(&g);
    return 0;
}

/* ns_dose_points at the grid's voxel centres is the grid, bit for bit, with 1 or 2 threads. */
static int test_points_are_grid(void)
{
    NsTg43Source s = source();
    NsDoseSeed seeds[2] = {{{0.002, 0.001, -0.003}, {0, 0, 1}, NS_TG43_UNIT_U},
                           {{-0.004, 0.0005, 0.002}, {1, 1, 0}, 0.7 * NS_TG43_UNIT_U}};
    NsDoseGrid g;
    ENSURE(ns_dose_grid(&s, seeds, 2, LO, HI, 1e-3, 1, &g, NULL, 0) == 0);
    static double pts[8000 * 3], one[8000], two[8000];
    for (int k = 0; k < 20; k++)
        for (int j = 0; j < 20; j++)
            for (int i = 0; i < 20; i++) {
                double *p = pts + 3 * ((k * 20 + j) * 20 + i);
                p[0] = LO[0] + (i + 0.5) * 1e-3;
                p[1] = LO[1] + (j + 0.5) * 1e-3;
                p[2] = LO[2] + (k + 0.5) * 1e-3;
            }
    ENSURE(ns_dose_points(&s, seeds, 2, pts, 8000, 1, one, NULL, 0) == 0);
    ENSURE(ns_dose_points(&s, seeds, 2, pts, 8000, 2, two, NULL, 0) == 0);
    ENSURE(ns_same_bits(one, g.dose, 8000));
    ENSURE(ns_same_bits(one, two, 8000));
    char err[256];
    ENSURE(ns_dose_points(&s, seeds, 2, pts, -1, 1, one, err, sizeof err) == -1);
    seeds[1].sk = 0.0;
    ENSURE(ns_dose_points(&s, seeds, 2, pts, 8000, 1, one, err, sizeof err) == -1);
    ENSURE(strstr(err, "seed 2") != NULL);
    ns_dose_grid_free(&g);
    return 0;
}

/* The dose-volume readings on a region whose answers are counted by hand: ten voxels of 2 cc
 * (2e-6 m^3) with doses 1..10 Gy in scrambled order. */
static int test_dvh_readings(void)
{
    const double dose[10] = {7, 2, 9, 4, 10, 1, 5, 3, 8, 6};
    NsDvh d;
    char err[256];
    ENSURE(ns_dvh_make(&d, dose, 10, 2e-6, err, sizeof err) == 0);
    ENSURE(d.dose[0] == 10 && d.dose[9] == 1);
    ENSURE(ns_dvh_d_pct(&d, 90) == 2);  /* the 9 hottest voxels get >= 2 Gy */
    ENSURE(ns_dvh_d_pct(&d, 10) == 10); /* the hottest one */
    ENSURE(ns_dvh_d_pct(&d, 30) == 8);
    ENSURE(ns_dvh_d_pct(&d, 100) == 1);
    ENSURE(ns_dvh_d_pct(&d, 25) == 8);    /* 2.5 voxels: the third hottest */
    ENSURE(ns_dvh_d_vol(&d, 2e-6) == 10); /* D2cc: one voxel */
    ENSURE(ns_dvh_d_vol(&d, 5e-6) == 8);  /* 2.5 voxels */
    ENSURE(ns_dvh_d_vol(&d, 1.0) == 1);   /* more than the region: all of it */
    ENSURE(ns_dvh_v_pct(&d, 5) == 60);    /* 5..10 */
    ENSURE(ns_dvh_v_pct(&d, 5.5) == 50);  /* 6..10 */
    ENSURE(ns_dvh_v_pct(&d, 11) == 0);
    ENSURE(ns_dvh_v_pct(&d, 0) == 100);
    ENSURE_SMALL(ns_dvh_v_vol(&d, 9) - 4e-6, 1e-18);
    ns_dvh_free(&d);
    const double bad[2] = {1, NAN};
    ENSURE(ns_dvh_make(&d, bad, 2, 1e-9, err, sizeof err) == -1 && d.dose == NULL);
    ENSURE(ns_dvh_make(&d, dose, 0, 1e-9, err, sizeof err) == -1);
    ENSURE(ns_dvh_make(&d, dose, 3, 0.0, err, sizeof err) == -1);
    const double neg[1] = {-1};
    ENSURE(ns_dvh_make(&d, neg, 1, 1e-9, err, sizeof err) == -1);
    return 0;
}

/* The DVH of a sphere around an isotropic point source (L = 0, g = F = 1): the dose falls as
 * K / r^2, so the hottest fraction f of the sphere's volume is the ball of radius R f^(1/3):
 * D90 = K / (R 0.9^(1/3))^2, and the volume receiving K / (R/2)^2 is the ball of radius R/2,
 * 12.5 %. Voxel centres inside the sphere, 0.5 mm apart, sample it. */
static int test_dvh_sphere_analytic(void)
{
    NsTg43Source s;
    memset(&s, 0, sizeof s);
    s.lambda = 1e4;
    s.length = 0.0;
    s.half_life = 59.4 * 86400.0;
    s.n_g = 2;
    s.g_r[0] = 0.001;
    s.g_r[1] = 0.1;
    s.g[0] = s.g[1] = 1.0;
    s.n_fr = 1;
    s.f_r[0] = 0.01;
    s.n_ft = 2;
    s.f_theta[1] = M_PI / 2;
    s.f[0] = s.f[1] = 1.0;
    NsDoseSeed seed = {{0, 0, 0}, {0, 0, 1}, NS_TG43_UNIT_U};
    const double R = 0.015, h = 0.5e-3;
    const int m = (int)(R / h);
    long n = 0;
    double *pts = malloc((size_t)8 * m * m * m * 3 * sizeof *pts);
    ENSURE(pts != NULL);
    for (int k = -m; k < m; k++)
        for (int j = -m; j < m; j++)
            for (int i = -m; i < m; i++) {
                double p[3] = {(i + 0.5) * h, (j + 0.5) * h, (k + 0.5) * h};
                if (p[0] * p[0] + p[1] * p[1] + p[2] * p[2] <= R * R) {
                    memcpy(pts + 3 * n, p, sizeof p);
                    n++;
                }
            }
    double *dose = malloc((size_t)n * sizeof *dose);
    ENSURE(dose != NULL);
    ENSURE(ns_dose_points(&s, &seed, 1, pts, n, 1, dose, NULL, 0) == 0);
    NsDvh d;
    ENSURE(ns_dvh_make(&d, dose, n, h * h * h, NULL, 0) == 0);
    double K = NS_TG43_UNIT_U * s.lambda * ns_tg43_mean_life(&s) * NS_TG43_R0 * NS_TG43_R0;
    double r90 = R * cbrt(0.9);
    ENSURE_SMALL(ns_dvh_d_pct(&d, 90) / (K / (r90 * r90)) - 1.0, 0.01);
    ENSURE_SMALL(ns_dvh_v_pct(&d, K / (0.25 * R * R)) / 12.5 - 1.0, 0.02); /* a 15-voxel ball */
    ENSURE_SMALL(ns_dvh_v_vol(&d, 0.0) / (4.0 / 3.0 * M_PI * R * R * R) - 1.0, 0.01);
    ns_dvh_free(&d);
    free(dose);
    free(pts);
    return 0;
}

int main(int argc, char **argv)
{
    static const NsTestCase cases[] = {
        {"radial_interpolation", test_radial_interpolation},
        {"anisotropy_interpolation", test_anisotropy_interpolation},
        {"geometry", test_geometry},
        {"voxel_is_point_formula", test_voxel_is_point_formula},
        {"superposition_and_threads", test_superposition_and_threads},
        {"symmetric_about_axis", test_symmetric_about_axis},
        {"bad_input", test_bad_input},
        {"points_are_grid", test_points_are_grid},
        {"dvh_readings", test_dvh_readings},
        {"dvh_sphere_analytic", test_dvh_sphere_analytic},
    };
    return ns_test_main(argc, argv, cases, (int)(sizeof cases / sizeof cases[0]));
}
