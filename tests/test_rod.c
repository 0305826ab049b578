/* Tests for sim/rod.c and sim/reparam.c: the forces are the negative gradient of the energies
 * (central differences, relative error < 1e-5) for bending, twisting and stretching; the
 * quasi-static twist is stationary; the Jacobian matches differences where it is exact and is
 * definite where it is not; a rod created in a shape rests in it; stepping is deterministic;
 * resampling and split / merge keep what they must; the twist's friction step meets the stick/slip
 * conditions, the active set's M-matrix case and the coordinate descent's general one alike. */
#include "ns_test.h"
#include "rod.h"
#include "twist_friction.h"

#include <stdint.h>
#include <stdlib.h>

static double rnd(uint64_t *st)
{
    *st = *st * 6364136223846793005ull + 1442695040888963407ull;
    return (double)(*st >> 11) / 9007199254740992.0 * 2.0 - 1.0;
}

/* A rod of n nodes along +z with spacing h, bent into a gentle helix-like curve. */
static void curved_nodes(double *x, int n, double h, double amp)
{
    for (int i = 0; i < n; i++) {
        double s = h * i;
        x[3 * i] = amp * sin(3.0 * s / (h * n));
        x[3 * i + 1] = amp * (1.0 - cos(2.0 * s / (h * n)));
        x[3 * i + 2] = s;
    }
}

/* Largest |F + dE/dx| over the free nodes, relative to the largest |F|, by central differences
 * of the total energy. */
static double fd_force_error(NsRod *r, double *fmax_out)
{
    int n = r->nodes;
    ns_rod_forces(r, NULL);
    double *F = malloc(3 * (size_t)n * sizeof *F), *x = malloc(3 * (size_t)n * sizeof *x);
    memcpy(F, r->force, 3 * (size_t)n * sizeof *F);
    memcpy(x, r->x, 3 * (size_t)n * sizeof *x);
    double fmax = 0.0, emax = 0.0;
    for (int i = 0; i < 3 * n; i++)
        fmax = fabs(F[i]) > fmax ? fabs(F[i]) : fmax;
    double h = 1e-7 * r->min_rest_edge;
    for (int i = 0; i < 3 * n; i++) {
        double x0 = x[i];
        x[i] = x0 + h;
        double ep = ns_rod_energy(r, x, NULL, NULL, NULL);
        x[i] = x0 - h;
        double em = ns_rod_energy(r, x, NULL, NULL, NULL);
        x[i] = x0;
        double fd = -(ep - em) / (2.0 * h);
        double e = fabs(fd - F[i]);
        emax = e > emax ? e : emax;
    }
    free(F);
    free(x);
    if (fmax_out)
        *fmax_out = fmax;
    return emax / fmax;
}

/* A perturbed, twisted rod with rest curvature and uneven edges: every energy term is active. */
static int make_test_rod(NsRod *r, double stretch_scale, double twist)
{
    int n = 14;
    double x[3 * 14];
    curved_nodes(x, n, 0.01, 0.01);
    uint64_t st = 7;
    NsRodParams p = ns_default_rod_params();
    p.stretch_scale = stretch_scale;
    p.auto_reparam = 0;
    char err[256];
    if (ns_rod_init(r, x, n, NULL, 2, &p, err, sizeof err) != 0) {
        fprintf(stderr, "%s\n", err);
        return -1;
    }
    for (int i = 1; i < n - 1; i++)
        ns_rod_set_rest_curvature(r, i, 3.0 * rnd(&st), 3.0 * rnd(&st));
    for (int i = 2; i < n; i++)
        for (int k = 0; k < 3; k++)
            r->x[3 * i + k] += 1e-3 * rnd(&st);
    r->theta[0] = twist;
    ns_rod_update_frames(r, NULL);
    return 0;
}

/* Twist angles away from the quasi-static ones, so that the twisting energy is large (the forces
 * are the position gradient at any fixed twist). */
static void scramble_twist(NsRod *r, double amp)
{
    uint64_t st = 11;
    for (int j = 1; j < r->nodes - 1; j++)
        r->theta[j] += amp * rnd(&st);
}

static int forces_match_energy_bending_twisting(void)
{
    NsRod r;
    ENSURE(make_test_rod(&r, 1e-6, 1.3) == 0); /* stretching made weak: bending and twist lead */
    scramble_twist(&r, 0.5);
    double eb, et, es;
    ns_rod_energy(&r, NULL, &eb, &et, &es);
    printf("  energies: bending %.3g, twisting %.3g, stretching %.3g J\n", eb, et, es);
    ENSURE(eb > es && et > 0.01 * eb);
    double fmax, e = fd_force_error(&r, &fmax);
    printf("  bending+twisting: max |F| %.3g N, rel err %.2e\n", fmax, e);
    ns_rod_free(&r);
    ENSURE(e < 1e-5);
    return 0;
}

static int forces_match_energy_all(void)
{
    NsRod r;
    ENSURE(make_test_rod(&r, 1.0, 0.4) == 0);
    scramble_twist(&r, 0.5);
    double fmax, e = fd_force_error(&r, &fmax);
    printf("  all terms: max |F| %.3g N, rel err %.2e\n", fmax, e);
    ns_rod_free(&r);
    ENSURE(e < 1e-5);
    return 0;
}

/* After the quasi-static solve the energy is stationary in every free twist angle. */
static int twist_is_quasi_static(void)
{
    NsRod r;
    ENSURE(make_test_rod(&r, 1e-6, 2.0) == 0);
    int ne = r.nodes - 1;
    double h = 1e-6, gmax = 0.0, scale = r.twist_stiff / r.max_rest_edge;
    for (int j = 1; j < ne; j++) {
        double t0 = r.theta[j];
        r.theta[j] = t0 + h;
        double ep = ns_rod_energy(&r, NULL, NULL, NULL, NULL);
        r.theta[j] = t0 - h;
        double em = ns_rod_energy(&r, NULL, NULL, NULL, NULL);
        r.theta[j] = t0;
        double g = fabs(ep - em) / (2.0 * h);
        gmax = g > gmax ? g : gmax;
    }
    printf("  max |dE/dtheta| %.2e N m (scale G J / l = %.2e)\n", gmax, scale);
    ns_rod_free(&r);
    ENSURE(gmax < 1e-8 * scale);
    return 0;
}

/* On a straight rod in tension the Jacobian is exact: K matches differences of the forces. */
static int jacobian_exact_when_straight(void)
{
    int n = 8;
    double x[3 * 8];
    for (int i = 0; i < n; i++)
        x[3 * i] = x[3 * i + 1] = 0.0, x[3 * i + 2] = 0.01 * i;
    NsRodParams p = ns_default_rod_params();
    p.damping_mass = 0.0;
    NsRod r;
    ENSURE(ns_rod_init(&r, x, n, NULL, 2, &p, NULL, 0) == 0);
    for (int i = 0; i < n; i++)
        r.x[3 * i + 2] *= 1.001; /* 0.1 % stretch */
    ns_rod_update_frames(&r, NULL);
    ns_rod_forces(&r, NULL);
    double *F0 = malloc(3 * (size_t)n * sizeof *F0);
    double worst = 0.0, kmax = 0.0;
    for (int i = 0; i < 3 * n; i++) {
        double *blk;
        for (int j = 0; j < 3 * n; j++)
            if ((blk = ns_banded_block(&r.K, i / 3, j / 3)))
                kmax = fmax(kmax, fabs(blk[3 * (i % 3) + j % 3]));
    }
    for (int j = 0; j < 3 * n; j++) {
        double h = 1e-9, x0 = r.x[j];
        r.x[j] = x0 + h;
        ns_rod_forces(&r, NULL);
        memcpy(F0, r.force, 3 * (size_t)n * sizeof *F0);
        r.x[j] = x0 - h;
        ns_rod_forces(&r, NULL);
        for (int i = 0; i < 3 * n; i++) {
            double fd = (F0[i] - r.force[i]) / (2.0 * h);
            double *blk = ns_banded_block(&r.K, i / 3, j / 3);
            double k = blk ? blk[3 * (i % 3) + j % 3] : 0.0;
            worst = fmax(worst, fabs(fd - k));
        }
        r.x[j] = x0;
    }
    ns_rod_forces(&r, NULL);
    printf("  straight rod: max |K - dF/dx| / max |K| = %.2e\n", worst / kmax);
    free(F0);
    ns_rod_free(&r);
    ENSURE(worst < 1e-5 * kmax);
    return 0;
}

/* A rod created in a curved shape is at rest in it: no force, no motion after steps. */
static int created_shape_is_rest(void)
{
    int n = 20;
    double x[3 * 20];
    curved_nodes(x, n, 0.005, 0.02);
    NsRod r;
    ENSURE(ns_rod_init(&r, x, n, NULL, 2, NULL, NULL, 0) == 0);
    ns_rod_forces(&r, NULL);
    double fbig = 0.0;
    for (int i = 0; i < 3 * n; i++)
        fbig = fmax(fbig, fabs(r.force[i]));
    for (int s = 0; s < 50; s++)
        ENSURE(ns_rod_step(&r, 1e-3, NULL, NULL) == 0);
    double dmax = 0.0;
    for (int i = 0; i < 3 * n; i++)
        dmax = fmax(dmax, fabs(r.x[i] - x[i]));
    printf("  max |F| at rest %.2e N, drift after 50 steps %.2e m\n", fbig, dmax);
    ns_rod_free(&r);
    ENSURE(fbig < 1e-9);
    ENSURE(dmax < 1e-12);
    return 0;
}

/* Same inputs, same bits. */
static int step_is_deterministic(void)
{
    uint64_t h[2];
    for (int run = 0; run < 2; run++) {
        NsRod r;
        ENSURE(make_test_rod(&r, 1.0, 0.5) == 0);
        r.v_insert = 0.01;
        r.twist_rate = 1.0;
        for (int s = 0; s < 100; s++)
            ENSURE(ns_rod_step(&r, 1e-3, NULL, NULL) == 0);
        h[run] = ns_rod_state_hash(&r);
        ns_rod_free(&r);
    }
    ENSURE(h[0] == h[1]);
    return 0;
}

/* Resampling onto the same nodes changes nothing that matters. */
static int resample_identity(void)
{
    NsRod r;
    ENSURE(make_test_rod(&r, 1.0, 0.8) == 0);
    int n = r.nodes;
    double *s = malloc((size_t)n * sizeof *s), *x = malloc(3 * (size_t)n * sizeof *x);
    memcpy(x, r.x, 3 * (size_t)n * sizeof *x);
    s[0] = 0.0;
    for (int i = 1; i < n; i++) {
        double l = 0.0;
        for (int k = 0; k < 3; k++)
            l += (x[3 * i + k] - x[3 * i - 3 + k]) * (x[3 * i + k] - x[3 * i - 3 + k]);
        s[i] = s[i - 1] + sqrt(l);
    }
    double e0 = ns_rod_energy(&r, NULL, NULL, NULL, NULL), m1[3], m2[3], m1b[3];
    ns_rod_tip_frame(&r, NULL, m1, NULL);
    ENSURE(ns_rod_resample(&r, x, s, n) == 0);
    double e1 = ns_rod_energy(&r, NULL, NULL, NULL, NULL);
    ns_rod_tip_frame(&r, NULL, m1b, m2);
    printf("  energy %.12g -> %.12g J\n", e0, e1);
    ENSURE(r.nodes == n);
    ENSURE_SMALL((e1 - e0) / e0, 1e-9);
    for (int k = 0; k < 3; k++)
        ENSURE_SMALL(m1b[k] - m1[k], 1e-9);
    free(s);
    free(x);
    ns_rod_free(&r);
    return 0;
}

/* Insertion grows edge 1 until it splits; nodes already there stay put; the rest length grows by
 * v_insert t. */
static int insertion_splits_at_sleeve(void)
{
    int n = 6;
    double x[3 * 6];
    for (int i = 0; i < n; i++)
        x[3 * i] = x[3 * i + 1] = 0.0, x[3 * i + 2] = 0.01 * i;
    NsRod r;
    ENSURE(ns_rod_init(&r, x, n, NULL, 2, NULL, NULL, 0) == 0);
    double L0 = ns_rod_rest_length(&r), dt = 1e-3, v = 0.02;
    r.v_insert = v;
    NsRodStats st;
    int splits = 0, newton = 0;
    for (int s = 0; s < 1000; s++) {
        ENSURE(ns_rod_step(&r, dt, NULL, &st) == 0);
        splits += st.splits;
        newton += st.newton_iterations;
    }
    double L1 = ns_rod_rest_length(&r), tip = r.x[3 * (r.nodes - 1) + 2];
    printf("  %d splits, %d nodes, rest length %.6f -> %.6f m, tip z %.6f m, %.2f Newton "
           "iterations per step\n",
           splits, r.nodes, L0, L1, tip, newton / 1000.0);
    ENSURE(splits >= 1);
    ENSURE(newton < 1500); /* steady insertion is no reason to iterate (it was 8 per step) */
    ENSURE_SMALL(L1 - L0 - v * 1.0, 1e-9);
    ENSURE_SMALL(tip - (0.05 + v * 1.0), 1e-4);
    for (int j = 1; j + 1 < r.nodes; j++)
        ENSURE(r.rest_len[j] <= r.params.split_factor * r.max_rest_edge);
    ns_rod_free(&r);
    return 0;
}

/* A large time step (20 ms) on a loaded free needle: the single linearized step would stretch
 * edges by percents; the extra Newton iterations keep the length within 0.1%. */
static int large_step_keeps_length(void)
{
    int n = 22;
    double x[3 * 22];
    for (int i = 0; i < n; i++)
        x[3 * i] = x[3 * i + 1] = 0.0, x[3 * i + 2] = 0.005 * (i - 1);
    NsRodParams p = ns_default_rod_params();
    p.gravity[1] = -9.81;
    NsRod r;
    ENSURE(ns_rod_init(&r, x, n, NULL, 2, &p, NULL, 0) == 0);
    double ext[3 * 22] = {0}, L0 = ns_rod_rest_length(&r), worst = 0.0;
    int most = 0;
    for (int s = 0; s < 100; s++) {
        ext[3 * (n - 1) + 1] = 4.0 * fmin(1.0, s / 25.0); /* about P L^2 / EI = 2 */
        NsRodStats st;
        ENSURE(ns_rod_step(&r, 0.02, ext, &st) == 0);
        most = st.newton_iterations > most ? st.newton_iterations : most;
        worst = fmax(worst, fabs(ns_rod_edges_length(&r) / L0 - 1.0));
    }
    printf("  dt 20 ms: worst length error %.2e, most Newton iterations in a step %d\n", worst,
           most);
    ns_rod_free(&r);
    ENSURE(most > 1);
    ENSURE(worst < 1e-3);
    return 0;
}

/* A free rod (not held) whose material frame is turned away from its rest curvature untwists
 * completely: every twist angle, theta_0 included, is free. */
static int free_rod_untwists(void)
{
    int n = 12;
    double x[3 * 12];
    for (int i = 0; i < n; i++) {
        double s = 0.01 * i;
        x[3 * i] = 0.2 * (1.0 - cos(s / 0.2));
        x[3 * i + 1] = 0.0;
        x[3 * i + 2] = 0.2 * sin(s / 0.2);
    }
    NsRod r;
    ENSURE(ns_rod_init(&r, x, n, NULL, 0, NULL, NULL, 0) == 0);
    for (int j = 0; j < n - 1; j++)
        r.theta[j] = 1.0;
    double eb0, eb1;
    ns_rod_energy(&r, NULL, &eb0, NULL, NULL);
    ns_rod_update_frames(&r, NULL);
    ns_rod_energy(&r, NULL, &eb1, NULL, NULL);
    printf("  bending energy %.3e -> %.3e J, theta_0 %.3e\n", eb0, eb1, r.theta[0]);
    ns_rod_free(&r);
    ENSURE(eb0 > 1e-4);
    ENSURE(eb1 < 1e-12 * eb0 + 1e-15);
    return 0;
}

/* The friction step (sim/twist_friction.h) on random definite tridiagonal Hessians, with negative
 * off-diagonals (an M-matrix: the active set) and with either sign (it may cycle: the coordinate
 * descent): at its answer every edge with a bound sticks with |torque| <= bound or slips with a
 * torque of exactly bound against its slip, and every other free edge is in equilibrium. */
static int twist_friction_step_optimal(void)
{
    uint64_t st = 7;
    double worst = 0.0;
    int fallbacks = 0;
    for (int trial = 0; trial < 400; trial++) {
        int ne = 3 + trial % 37, first = trial % 2;
        int mixed = trial % 4 >= 2; /* 3: barely dominant, where the active set may cycle */
        double hd[40], ho[40], g[40], th[40], an[40], c[40], dx[40];
        double work[6 * 40];
        for (int j = 0; j < ne; j++) {
            ho[j] = mixed ? 0.9 * rnd(&st) : -0.9 * fabs(rnd(&st));
            th[j] = rnd(&st);
            an[j] = th[j] + 0.1 * rnd(&st) * (j % 3 == 0);
            c[j] = j % 5 == 4 ? 0.0 : 0.5 * fabs(rnd(&st));
            g[j] = 2.0 * rnd(&st);
        }
        for (int j = 0; j < ne; j++) /* diagonally dominant: definite */
            hd[j] = (trial % 4 == 3 ? 1e-3 : 2.0 + fabs(rnd(&st))) +
                    (j > 0 ? fabs(ho[j - 1]) : 0.0) + fabs(ho[j]);
        int w = ns_twist_friction_step(ne, first, hd, ho, g, th, an, c, dx, work);
        ENSURE(w > 0);
        fallbacks += w > 4 * ne + 20; /* the active set cycled: coordinate descent */
        for (int j = 0; j < first; j++)
            ENSURE(dx[j] == 0.0);
        for (int j = first; j < ne; j++) {
            double r = g[j] + hd[j] * dx[j] + (j > 0 ? ho[j - 1] * dx[j - 1] : 0.0) +
                       (j + 1 < ne ? ho[j] * dx[j + 1] : 0.0);
            double y = th[j] + dx[j] - an[j], e;
            if (c[j] == 0.0)
                e = fabs(r);
            else if (fabs(y) <= 1e-12)
                e = fmax(0.0, fabs(r) - c[j]);
            else
                e = fabs(r + (y > 0.0 ? c[j] : -c[j]));
            worst = fmax(worst, e);
        }
    }
    printf("  worst stick/slip residual %.2e N m (bounds up to 0.5); %d of 400 by the fallback\n",
           worst, fallbacks);
    ENSURE(worst < 1e-9);
    ENSURE(fallbacks > 0); /* both paths are tested */
    return 0;
}

NS_TEST_MAIN({"free_rod_untwists", free_rod_untwists},
             {"twist_friction_step_optimal", twist_friction_step_optimal},
             {"large_step_keeps_length", large_step_keeps_length},
             {"forces_match_energy_bending_twisting", forces_match_energy_bending_twisting},
             {"forces_match_energy_all", forces_match_energy_all},
             {"twist_is_quasi_static", twist_is_quasi_static},
             {"jacobian_exact_when_straight", jacobian_exact_when_straight},
             {"created_shape_is_rest", created_shape_is_rest},
             {"step_is_deterministic", step_is_deterministic},
             {"resample_identity", resample_identity},
             {"insertion_splits_at_sleeve", insertion_splits_at_sleeve})
