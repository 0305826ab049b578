/* Tests for sim/fem.c: forces are the negative energy gradient, the Jacobians (frame held fixed,
 * §3.2) match finite differences to 1e-5, rigid motions are force-free, inverted elements give
 * finite restoring forces, and the projected neo-Hookean stiffness is definite. */
#include "fem.h"
#include "ns_test.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

static double rnd(uint64_t *st)
{
    *st = *st * 6364136223846793005ull + 1442695040888963407ull;
    return (double)(*st >> 11) / 9007199254740992.0 * 2.0 - 1.0;
}

/* A random well-shaped rest tet near the unit corner tet (1 cm scale) and a deformed copy. */
static void make_tet(uint64_t *st, double u[12], double x[12], double strain)
{
    double base[12] = {0, 0, 0, 0.01, 0, 0, 0, 0.01, 0, 0, 0, 0.01};
    for (int i = 0; i < 12; i++)
        u[i] = base[i] + 0.002 * rnd(st);
    double A[9];
    for (int i = 0; i < 9; i++)
        A[i] = (i % 4 == 0 ? 1.0 : 0.0) + strain * rnd(st);
    double th = 3.0 * rnd(st), c = cos(th), s = sin(th);
    double R[9] = {c, -s, 0, s, c, 0, 0, 0, 1};
    for (int a = 0; a < 4; a++)
        for (int i = 0; i < 3; i++) {
            double y = 0.0;
            for (int k = 0; k < 3; k++) {
                double ak = 0.0;
                for (int j = 0; j < 3; j++)
                    ak += A[3 * k + j] * u[3 * a + j];
                y += R[3 * i + k] * ak;
            }
            x[3 * a + i] = y + 0.001 * rnd(st) * strain;
        }
}

static void ptrs(double *x, const double *p[4])
{
    for (int a = 0; a < 4; a++)
        p[a] = x + 3 * a;
}

static const double zero_v[12] = {0};

static int forces_are_energy_gradient(void)
{
    uint64_t st = 1;
    for (int model = 0; model < 2; model++)
        for (int n = 0; n < 50; n++) {
            NsFemMaterial m = ns_fem_material(model, 60e3, 0.45, 0, 0);
            double u[12], x[12], f[12];
            make_tet(&st, u, x, 0.15);
            NsTetRest r;
            const double *pu[4], *px[4], *pv[4];
            ptrs(u, pu);
            ptrs(x, px);
            ptrs((double *)zero_v, pv);
            ENSURE(ns_fem_rest(pu[0], pu[1], pu[2], pu[3], &r) == 0);
            NsTetFrame fr;
            ns_fem_tet_forces(&r, &m, px, pv, f, &fr);
            ENSURE(fr.s[2] > NS_FEM_NEOHOOKEAN_S_MIN);
            double fmax = 0.0;
            for (int i = 0; i < 12; i++)
                fmax = fmax > fabs(f[i]) ? fmax : fabs(f[i]);
            for (int i = 0; i < 12; i++) {
                double h = 1e-7, save = x[i];
                x[i] = save + h;
                double ep = ns_fem_tet_energy(&r, &m, px);
                x[i] = save - h;
                double em = ns_fem_tet_energy(&r, &m, px);
                x[i] = save;
                double fd = -(ep - em) / (2 * h);
                ENSURE_SMALL((fd - f[i]) / fmax, 1e-6);
            }
        }
    return 0;
}

/* Relative error of an analytic 12x12 Jacobian against central differences of the fixed-frame
 * forces in x (wrt = 0) or v (wrt = 1). */
static double jacobian_error(const NsTetRest *r, const NsFemMaterial *m, const NsTetFrame *fr,
                             double *x, double *v, const double *J, int wrt)
{
    const double *px[4], *pv[4];
    ptrs(x, px);
    ptrs(v, pv);
    double *y = wrt ? v : x;
    double scale = wrt ? 1e-3 : 1e-8, num = 0.0, den = 0.0;
    for (int c = 0; c < 12; c++) {
        double fp[12], fm[12], save = y[c];
        y[c] = save + scale;
        ns_fem_tet_forces_fixed_frame(r, m, fr, px, pv, fp);
        y[c] = save - scale;
        ns_fem_tet_forces_fixed_frame(r, m, fr, px, pv, fm);
        y[c] = save;
        for (int i = 0; i < 12; i++) {
            double fd = (fp[i] - fm[i]) / (2 * scale);
            num += (fd - J[12 * i + c]) * (fd - J[12 * i + c]);
            den += J[12 * i + c] * J[12 * i + c];
        }
    }
    return sqrt(num / den);
}

static int jacobians_match_finite_differences(void)
{
    uint64_t st = 2;
    double worst = 0.0;
    for (int model = 0; model < 2; model++)
        for (int n = 0; n < 50; n++) {
            NsFemMaterial m = ns_fem_material(model, 60e3, 0.45, 3.0, 10.0);
            double u[12], x[12], v[12], f[12], K[144], D[144];
            make_tet(&st, u, x, 0.15);
            for (int i = 0; i < 12; i++)
                v[i] = 0.01 * rnd(&st);
            NsTetRest r;
            const double *pu[4], *px[4], *pv[4];
            ptrs(u, pu);
            ptrs(x, px);
            ptrs(v, pv);
            ns_fem_rest(pu[0], pu[1], pu[2], pu[3], &r);
            NsTetFrame fr;
            ns_fem_tet_forces(&r, &m, px, pv, f, &fr);
            /* The fixed-frame forces agree with the real ones at the frame's own state. */
            double f2[12];
            ns_fem_tet_forces_fixed_frame(&r, &m, &fr, px, pv, f2);
            for (int i = 0; i < 12; i++)
                ENSURE_SMALL(f2[i] - f[i], 1e-9 * (1 + fabs(f[i])));
            ns_fem_tet_jacobians(&r, &m, &fr, 0, K, D);
            double ek = jacobian_error(&r, &m, &fr, x, v, K, 0);
            double ed = jacobian_error(&r, &m, &fr, x, v, D, 1);
            ENSURE(ek < 1e-5);
            ENSURE(ed < 1e-5);
            worst = worst > ek ? worst : ek;
            /* K is symmetric. */
            for (int i = 0; i < 12; i++)
                for (int j = 0; j < 12; j++)
                    ENSURE_SMALL(K[12 * i + j] - K[12 * j + i], 1e-9 * fabs(K[12 * i + i]));
        }
    printf("  worst relative Jacobian error %.2e\n", worst);
    return 0;
}

static int rigid_motion_is_force_free(void)
{
    uint64_t st = 3;
    for (int model = 0; model < 2; model++) {
        NsFemMaterial m = ns_fem_material(model, 60e3, 0.45, 0, 0);
        double u[12], x[12], f[12];
        make_tet(&st, u, x, 0.0); /* strain 0: a pure rotation of the rest tet */
        NsTetRest r;
        const double *pu[4], *px[4], *pv[4];
        ptrs(u, pu);
        ptrs(x, px);
        ptrs((double *)zero_v, pv);
        ns_fem_rest(pu[0], pu[1], pu[2], pu[3], &r);
        NsTetFrame fr;
        ns_fem_tet_forces(&r, &m, px, pv, f, &fr);
        for (int i = 0; i < 12; i++)
            ENSURE_SMALL(f[i], 1e-9);
    }
    return 0;
}

static int forces_balance(void)
{
    /* Internal forces have zero resultant and zero torque. */
    uint64_t st = 4;
    NsFemMaterial m = ns_fem_material(NS_MODEL_NEOHOOKEAN, 60e3, 0.4, 2, 2);
    double u[12], x[12], v[12], f[12];
    make_tet(&st, u, x, 0.2);
    for (int i = 0; i < 12; i++)
        v[i] = 0.05 * rnd(&st);
    NsTetRest r;
    const double *pu[4], *px[4], *pv[4];
    ptrs(u, pu);
    ptrs(x, px);
    ptrs(v, pv);
    ns_fem_rest(pu[0], pu[1], pu[2], pu[3], &r);
    NsTetFrame fr;
    ns_fem_tet_forces(&r, &m, px, pv, f, &fr);
    double sum[3] = {0}, tq[3] = {0}, mag = 0;
    for (int a = 0; a < 4; a++) {
        const double *p = x + 3 * a, *q = f + 3 * a;
        for (int i = 0; i < 3; i++) {
            sum[i] += q[i];
            mag += fabs(q[i]);
        }
        tq[0] += p[1] * q[2] - p[2] * q[1];
        tq[1] += p[2] * q[0] - p[0] * q[2];
        tq[2] += p[0] * q[1] - p[1] * q[0];
    }
    for (int i = 0; i < 3; i++) {
        ENSURE_SMALL(sum[i] / mag, 1e-12);
    }
    /* Elastic forces are torque-free; damping ones are only for rigid velocities, so check
     * the torque without damping. */
    m.damp_mu = m.damp_lambda = 0;
    ns_fem_tet_forces(&r, &m, px, pv, f, &fr);
    memset(tq, 0, sizeof tq);
    mag = 0;
    for (int a = 0; a < 4; a++) {
        const double *p = x + 3 * a, *q = f + 3 * a;
        tq[0] += p[1] * q[2] - p[2] * q[1];
        tq[1] += p[2] * q[0] - p[0] * q[2];
        tq[2] += p[0] * q[1] - p[1] * q[0];
        mag += fabs(q[0]) + fabs(q[1]) + fabs(q[2]);
    }
    for (int i = 0; i < 3; i++)
        ENSURE_SMALL(tq[i] / (mag * 0.01), 1e-10);
    return 0;
}

static int inverted_element_restores(void)
{
    /* Push the apex of the corner tet through its base: det F < 0. Both models must give a
     * finite force pushing the apex back up (+z). */
    for (int model = 0; model < 2; model++) {
        NsFemMaterial m = ns_fem_material(model, 60e3, 0.45, 0, 0);
        double u[12] = {0, 0, 0, 0.01, 0, 0, 0, 0.01, 0, 0, 0, 0.01};
        double x[12];
        memcpy(x, u, sizeof x);
        x[11] = -0.005;
        NsTetRest r;
        const double *pu[4], *px[4], *pv[4];
        ptrs(u, pu);
        ptrs(x, px);
        ptrs((double *)zero_v, pv);
        ns_fem_rest(pu[0], pu[1], pu[2], pu[3], &r);
        double f[12], K[144];
        NsTetFrame fr;
        ns_fem_tet_forces(&r, &m, px, pv, f, &fr);
        ENSURE(fr.s[2] < 0);
        for (int i = 0; i < 12; i++)
            ENSURE(isfinite(f[i]));
        ENSURE(f[11] > 0);
        ns_fem_tet_jacobians(&r, &m, &fr, 1, K, NULL);
        for (int i = 0; i < 144; i++)
            ENSURE(isfinite(K[i]));
    }
    return 0;
}

static int projected_stiffness_is_definite(void)
{
    uint64_t st = 5;
    for (int n = 0; n < 200; n++) {
        NsFemMaterial m = ns_fem_material(NS_MODEL_NEOHOOKEAN, 60e3, 0.45, 0, 0);
        double u[12], x[12], f[12], K[144];
        make_tet(&st, u, x, 0.5); /* large strains, some compressed or inverted */
        NsTetRest r;
        const double *pu[4], *px[4], *pv[4];
        ptrs(u, pu);
        ptrs(x, px);
        ptrs((double *)zero_v, pv);
        ns_fem_rest(pu[0], pu[1], pu[2], pu[3], &r);
        NsTetFrame fr;
        ns_fem_tet_forces(&r, &m, px, pv, f, &fr);
        ns_fem_tet_jacobians(&r, &m, &fr, 1, K, NULL);
        double kmax = 0;
        for (int i = 0; i < 144; i++)
            kmax = kmax > fabs(K[i]) ? kmax : fabs(K[i]);
        for (int trial = 0; trial < 20; trial++) {
            double y[12], q = 0.0, yy = 0.0;
            for (int i = 0; i < 12; i++)
                y[i] = rnd(&st);
            for (int i = 0; i < 12; i++) {
                yy += y[i] * y[i];
                for (int j = 0; j < 12; j++)
                    q += y[i] * K[12 * i + j] * y[j];
            }
            ENSURE(q <= 1e-10 * kmax * yy); /* -K is positive semi-definite */
        }
    }
    return 0;
}

/* ns_fem_tet_forces_svd_n gives ns_fem_tet_forces_svd's bits for every tet of a batch, whatever
 * its lane: both models, with and without damping side by side, stretched, inverted and
 * non-finite tets, in batches of 1 to 9. */
static int batch_forces_match_single(void)
{
    enum { COUNT = 600 };
    static NsTetRest rest[COUNT];
    static NsTetFrame frame[COUNT];
    static double xs[COUNT][12], vs[COUNT][12], f[COUNT][12];
    NsFemMaterial mats[4] = {ns_fem_material(NS_MODEL_COROTATIONAL, 30e3, 0.45, 1.0, 2.0),
                             ns_fem_material(NS_MODEL_NEOHOOKEAN, 30e3, 0.45, 1.0, 2.0),
                             ns_fem_material(NS_MODEL_COROTATIONAL, 60e3, 0.3, 0.0, 0.0),
                             ns_fem_material(NS_MODEL_NEOHOOKEAN, 60e3, 0.3, 0.0, 0.0)};
    const NsFemMaterial *mat[COUNT];
    uint64_t st = 77;
    for (int n = 0; n < COUNT; n++) {
        double u[12];
        make_tet(&st, u, xs[n], n % 5 == 0 ? 0.8 : 0.1);
        if (n % 7 == 3) /* inverted: one node through the opposite face */
            for (int i = 0; i < 3; i++)
                xs[n][i] = 2.0 * xs[n][3 + i] - xs[n][i];
        for (int i = 0; i < 12; i++)
            vs[n][i] = 0.05 * rnd(&st);
        if (n % 11 == 4)
            vs[n][5] = NAN;
        ENSURE(ns_fem_rest(u, u + 3, u + 6, u + 9, &rest[n]) == 0);
        mat[n] = &mats[(n * 7 + n / 9) % 4];
        const double *xp[4], *vp[4];
        ptrs(xs[n], xp);
        ptrs(vs[n], vp);
        ns_fem_tet_forces(&rest[n], mat[n], xp, vp, f[n], &frame[n]); /* the frame */
    }
    int done = 0;
    for (int batch = 1; done < COUNT; batch = batch % 9 + 1) {
        int m = COUNT - done < batch ? COUNT - done : batch;
        const NsTetRest *rp[9];
        const NsFemMaterial *mp[9];
        const double *vn[9][4];
        const double *const *vp[9];
        double *fp[9];
        const NsTetFrame *frp[9];
        for (int k = 0; k < m; k++) {
            rp[k] = &rest[done + k];
            mp[k] = mat[done + k];
            ptrs(vs[done + k], vn[k]);
            vp[k] = vn[k];
            fp[k] = f[done + k];
            frp[k] = &frame[done + k];
        }
        ns_fem_tet_forces_svd_n(m, rp, mp, vp, fp, frp);
        done += m;
    }
    for (int n = 0; n < COUNT; n++) {
        const double *vp[4];
        ptrs(vs[n], vp);
        double f1[12];
        ns_fem_tet_forces_svd(&rest[n], mat[n], vp, f1, &frame[n]);
        if (!ns_same_bits(f1, f[n], 12)) {
            fprintf(stderr, "tet %d: the batch's forces differ from one at a time\n", n);
            return 1;
        }
    }
    return 0;
}

/* The rest data of tet u and the frame of its state x (at rest velocity). */
static int frame_at(const double u[12], const double x[12], const NsFemMaterial *m, NsTetRest *r,
                    NsTetFrame *fr)
{
    const double *pu[4], *px[4], *pv[4];
    for (int a = 0; a < 4; a++) {
        pu[a] = u + 3 * a;
        px[a] = x + 3 * a;
        pv[a] = zero_v + 3 * a;
    }
    double f[12];
    if (ns_fem_rest(pu[0], pu[1], pu[2], pu[3], r))
        return -1;
    ns_fem_tet_forces(r, m, px, pv, f, fr);
    return 0;
}

/* The corotational closed form (ns_fem_corot_row) gives ns_fem_tet_jacobians' blocks, and
 * with an old rotation their change, on stretched, sheared and inverted tets. */
static int corotational_rows_match(void)
{
    uint64_t st = 11;
    double worst = 0.0;
    int inverted = 0;
    for (int n = 0; n < 60; n++) {
        NsFemMaterial m = ns_fem_material(NS_MODEL_COROTATIONAL, 60e3, 0.45, 3.0, 10.0);
        /* A rest tet, a state (the strong ones invert some tets) and an earlier state. */
        double u[12], x[12], u2[12], x2[12];
        make_tet(&st, u, x, n < 40 ? 0.15 : 1.2);
        make_tet(&st, u2, x2, 0.15);
        NsTetRest r;
        NsTetFrame fr, fo;
        ENSURE(frame_at(u, x, &m, &r, &fr) == 0 && frame_at(u, x2, &m, &r, &fo) == 0);
        inverted += fr.s[2] < 0.0;
        double K[144], D[144], Ko[144], Do[144], R[9], Ro[9];
        ns_fem_tet_jacobians(&r, &m, &fr, 0, K, D);
        ns_fem_tet_jacobians(&r, &m, &fo, 0, Ko, Do);
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) {
                R[3 * i + j] = Ro[3 * i + j] = 0.0;
                for (int k = 0; k < 3; k++) {
                    R[3 * i + j] += fr.U[3 * i + k] * fr.V[3 * j + k];
                    Ro[3 * i + j] += fo.U[3 * i + k] * fo.V[3 * j + k];
                }
            }
        double scale = 0.0, dscale = 0.0;
        for (int k = 0; k < 144; k++) {
            scale = fmax(scale, fabs(K[k]));
            dscale = fmax(dscale, fabs(D[k]));
        }
        for (int a = 0; a < 4; a++) {
            double kb[4][9] = {{0}}, db[4][9] = {{0}}, kc[4][9] = {{0}}, dc[4][9] = {{0}};
            double *kp[4] = {kb[0], kb[1], kb[2], kb[3]}, *dp[4] = {db[0], db[1], db[2], db[3]};
            double *kq[4] = {kc[0], kc[1], kc[2], kc[3]}, *dq[4] = {dc[0], dc[1], dc[2], dc[3]};
            ns_fem_corot_row(&r, &m, R, NULL, a, kp, dp);
            ns_fem_corot_row(&r, &m, R, Ro, a, kq, dq);
            for (int b = 0; b < 4; b++)
                for (int i = 0; i < 3; i++)
                    for (int j = 0; j < 3; j++) {
                        int e = 12 * (3 * a + i) + 3 * b + j;
                        double ek = fabs(kb[b][3 * i + j] - K[e]) / scale;
                        double ed = fabs(db[b][3 * i + j] - D[e]) / dscale;
                        double ck = fabs(kc[b][3 * i + j] - (K[e] - Ko[e])) / scale;
                        double cd = fabs(dc[b][3 * i + j] - (D[e] - Do[e])) / dscale;
                        worst = fmax(worst, fmax(fmax(ek, ed), fmax(ck, cd)));
                    }
        }
    }
    printf("  worst difference %.2e of the largest entry, %d inverted tets\n", worst, inverted);
    ENSURE(worst < 1e-12 && inverted > 0);
    return 0;
}

NS_TEST_MAIN({"forces_are_energy_gradient", forces_are_energy_gradient},
             {"jacobians_match_finite_differences", jacobians_match_finite_differences},
             {"rigid_motion_is_force_free", rigid_motion_is_force_free},
             {"forces_balance", forces_balance},
             {"inverted_element_restores", inverted_element_restores},
             {"projected_stiffness_is_definite", projected_stiffness_is_definite},
             {"batch_forces_match_single", batch_forces_match_single},
             {"corotational_rows_match", corotational_rows_match})
