/* Tests for the parallel assembly of sim/tissue.c (§3.6.3): the state after a run is
 * bit-identical for every thread count, and the lazily maintained K and D equal matrices
 * assembled from scratch, serially, from the same element Jacobians. */
#include "mesher.h"
#include "tissue.h"
#include "ns_test.h"

#include <stdlib.h>
#include <string.h>

#define BOX_LO_Z (-0.015)

/* A 4 x 3 x 3 cm box (corotational gel) with a neo-Hookean sphere inside. */
static int make_mesh(NsMesh *m)
{
    double c[3] = {0.0, 0.0, 0.0}, size[3] = {0.04, 0.03, 0.03};
    NsShape *box = ns_shape_box(c, size);
    NsShape *ball = ns_shape_sphere(c, 0.008);
    NsMesherRegion r[2] = {{box, false}, {ball, false}};
    NsMesherDef d = ns_default_mesher_def();
    d.spacing = 0.004;
    d.regions = r;
    d.region_count = 2;
    for (int k = 0; k < 3; k++) {
        d.lo[k] = -0.5 * size[k];
        d.hi[k] = 0.5 * size[k];
    }
    ns_mesh_init(m);
    char err[256];
    int rc = ns_mesher_stuff(&d, m, NULL, err, sizeof err);
    if (rc)
        fprintf(stderr, "mesher: %s\n", err);
    ns_shape_release(box);
    ns_shape_release(ball);
    return rc;
}

/* A lazy threshold below the default (1e-2, tuned for needle loads by fem-lazy), so that the
 * small loads here rebuild some tets and keep others in most steps: the mixed case. */
#define TEST_THRESHOLD 1e-3

static int make_tissue(NsTissue *t, const NsMesh *m, int threads, double lazy_threshold)
{
    NsTissueMaterial mats[2] = {
        {ns_fem_material(NS_MODEL_COROTATIONAL, 20e3, 0.45, 2.0, 2.0), 1000.0},
        {ns_fem_material(NS_MODEL_NEOHOOKEAN, 8e3, 0.45, 1.0, 1.0), 1050.0},
    };
    NsTissueParams p = ns_default_tissue_params();
    p.gravity[2] = -9.81;
    p.threads = threads;
    if (lazy_threshold >= 0.0)
        p.lazy_threshold = lazy_threshold;
    char err[256];
    if (ns_tissue_init(t, m, mats, 2, &p, err, sizeof err)) {
        fprintf(stderr, "tissue: %s\n", err);
        return -1;
    }
    for (int i = 0; i < m->node_slots; i++)
        if ((m->flags[i] & NS_NODE_ALIVE) && m->u[3 * i + 2] < BOX_LO_Z + 1e-9)
            for (int c = 0; c < 3; c++)
                ns_tissue_fix_dof(t, i, c, 1);
    return 0;
}

/* Time-varying loads on the top face: everywhere (the whole block sways, nearly every tet's
 * Jacobian is rebuilt), or on a patch 5 mm around the centre (a needle-like load: the lazy
 * update rebuilds the tets near it and keeps the rest). */
static void external_force(const NsTissue *t, int step, int local, double *ext)
{
    const NsMesh *M = &t->mesh;
    memset(ext, 0, (size_t)3 * M->node_slots * sizeof(double));
    double s = sin(0.3 * step);
    for (int i = 0; i < M->node_slots; i++) {
        const double *u = M->u + 3 * i;
        if (!(M->flags[i] & NS_NODE_ALIVE) || u[2] < -BOX_LO_Z - 1e-9)
            continue;
        if (!local) {
            ext[3 * i] = 2e-3 * s;
            ext[3 * i + 1] = 1e-3 * s * s;
        } else if (u[0] * u[0] + u[1] * u[1] < 0.005 * 0.005) {
            ext[3 * i] = 5e-4 * s;
            ext[3 * i + 2] = -1e-3 * s * s;
        }
    }
}

/* Brings the tissue to rest under gravity (static Newton solve with CG). */
static int settle(NsTissue *t)
{
    NsSolver *s = ns_solver_create(NS_SOLVER_CG);
    if (s)
        ns_solver_set_threads(s, t->params.threads);
    NsTissueStats st;
    int it = s ? ns_tissue_static_solve(t, s, NULL, 1e-9, 20, &st) : -1;
    ns_solver_destroy(s);
    return it >= 0 && st.unconverged == 0 ? 0 : -1;
}

/* Runs `steps` Newmark steps of 10 ms, with CG for a global load and with stale-factor PCG
 * (refreshed in the background when there are threads to spare) for a local one, the solver on
 * the tissue's thread count; reports the largest displacement over the run and
 * how many steps rebuilt some tets' Jacobians but fewer than a fraction `below` of them (the
 * steps that update some block rows and keep others), and into *by_change (may be NULL) how many
 * block rows of K and D took their rebuilt tets' changes instead of being gathered again.
 * Returns 0 or -1. */
static int run_counted(NsTissue *t, int steps, int local, double below, double *moved, int *partial,
                       int *by_change)
{
    int n3 = 3 * t->mesh.node_slots;
    NsSolver *s = ns_solver_create(local ? NS_SOLVER_STALE_PCG : NS_SOLVER_CG);
    if (s) {
        ns_solver_set_threads(s, t->params.threads);
        ns_solver_set_refresh_iterations(s, 2); /* refresh often: exercise the background */
    }
    double *ext = malloc((size_t)n3 * sizeof(double));
    double *x0 = malloc((size_t)n3 * sizeof(double));
    int rc = s && ext && x0 ? 0 : -1;
    if (x0)
        memcpy(x0, t->mesh.x, (size_t)n3 * sizeof(double));
    *partial = 0;
    int refreshes = 0;
    for (int k = 0; k < steps && rc == 0; k++) {
        NsTissueStats st;
        external_force(t, k, local, ext);
        rc = ns_tissue_step(t, s, 0.01, ext, &st);
        *partial += st.jacobian_fraction > 0.0 && st.jacobian_fraction < below;
        if (by_change)
            *by_change += st.rows_changed;
        refreshes += st.refresh_started;
        if (st.nan_count || st.unconverged)
            rc = -1;
    }
    *moved = 0.0;
    for (int i = 0; i < n3 && x0; i++) {
        double d = fabs(t->mesh.x[i] - x0[i]);
        *moved = d > *moved ? d : *moved;
    }
    free(x0);
    free(ext);
    ns_solver_destroy(s);
    if (local && rc == 0 && refreshes == 0) {
        fprintf(stderr, "  the stale-factor solver never refreshed: the run tests less\n");
        rc = -1;
    }
    return rc;
}

static int run(NsTissue *t, int steps, int local, double below, double *moved, int *partial)
{
    return run_counted(t, steps, local, below, moved, partial, NULL);
}

/* The same run with each thread count in threads[] must end in the same state, bit for bit. */
static int same_state(const NsMesh *m, const int *threads, int runs, int settled, int local,
                      int steps)
{
    uint64_t hash0 = 0;
    double moved0 = 0.0;
    for (int r = 0; r < runs; r++) {
        NsTissue t;
        ENSURE(make_tissue(&t, m, threads[r], TEST_THRESHOLD) == 0);
        if (settled)
            ENSURE(settle(&t) == 0);
        double moved;
        int partial;
        ENSURE(run(&t, steps, local, local ? 0.5 : 1.0, &moved, &partial) == 0);
        uint64_t hash = ns_tissue_state_hash(&t);
        printf("  threads %d: state hash %016llx, moved %.3e m, %d steps rebuilt some tets\n",
               threads[r], (unsigned long long)hash, moved, partial);
        ENSURE(partial >= (local ? 5 : 1)); /* steps that kept some rows and rebuilt others */
        /* Every thread got a non-empty share of the nodes. */
        ENSURE(t.part_count == threads[r]);
        for (int p = 0; p < t.part_count; p++)
            ENSURE(t.part_node_start[p + 1] > t.part_node_start[p]);
        if (r == 0) {
            hash0 = hash;
            moved0 = moved;
            /* The run did something: equal hashes of a resting state would prove little. */
            ENSURE(moved > (local ? 1e-5 : 1e-4));
        }
        ENSURE(hash == hash0);
        ENSURE(moved == moved0);
        ns_tissue_free(&t);
    }
    return 0;
}

/* From rest under gravity with a load on the whole top face. */
static int same_state_for_any_thread_count(void)
{
    NsMesh m;
    ENSURE(make_mesh(&m) == 0);
    int neo = 0;
    for (int e = 0; e < m.tet_slots; e++)
        neo += ns_mesh_tet_alive(&m, e) && m.tet_region[e] == 1;
    printf("  %d tets (%d neo-Hookean), %d nodes\n", m.tet_alive, neo, m.node_alive);
    ENSURE(neo > 100 && neo < m.tet_alive - 100); /* both models are exercised */
    const int threads[4] = {1, 2, 3, 4};
    ENSURE(same_state(&m, threads, 4, 0, 0, 30) == 0);
    ns_mesh_free(&m);
    return 0;
}

/* Settled under gravity, then a local load: most block rows are kept from step to step. */
static int same_state_with_local_rebuilds(void)
{
    NsMesh m;
    ENSURE(make_mesh(&m) == 0);
    const int threads[3] = {1, 2, 3};
    ENSURE(same_state(&m, threads, 3, 1, 1, 20) == 0);
    ns_mesh_free(&m);
    return 0;
}

/* max |A - B| over all blocks stored in either, and max |B|. */
static void compare(const NsBlockMatrix *A, const NsBlockMatrix *B, double *diff, double *scale)
{
    static const double zero[9] = {0};
    *diff = *scale = 0.0;
    for (int pass = 0; pass < 2; pass++) {
        const NsBlockMatrix *P = pass ? B : A, *Q = pass ? A : B;
        for (int i = 0; i < P->n; i++)
            for (int p = 0; p < P->rows[i].count; p++) {
                const double *a = P->rows[i].val + 9 * p;
                const double *b = ns_bsm_find(Q, i, P->rows[i].col[p]);
                b = b ? b : zero;
                for (int k = 0; k < 9; k++) {
                    double d = fabs(a[k] - b[k]);
                    *diff = d > *diff ? d : *diff;
                    *scale = fabs(pass ? a[k] : b[k]) > *scale ? fabs(pass ? a[k] : b[k]) : *scale;
                }
            }
    }
}

static double max_rel_diff(const double *a, const double *b, int n)
{
    double d = 0.0, s = 1e-300;
    for (int i = 0; i < n; i++) {
        d = fabs(a[i] - b[i]) > d ? fabs(a[i] - b[i]) : d;
        s = fabs(b[i]) > s ? fabs(b[i]) : s;
    }
    return d / s;
}

/* With threshold 0 every moving tet is rebuilt each step: the lazily maintained K and D must
 * equal a from-scratch serial assembly (force_all) on a tissue in the same state. */
static int matches_from_scratch_assembly(void)
{
    NsMesh m;
    ENSURE(make_mesh(&m) == 0);
    NsTissue t, ref;
    ENSURE(make_tissue(&t, &m, 2, 0.0) == 0);
    ENSURE(make_tissue(&ref, &m, 1, 0.0) == 0);
    double moved;
    int partial;
    ENSURE(run(&t, 10, 0, 1.0, &moved, &partial) == 0);
    ENSURE(moved > 1e-5);
    size_t bytes = (size_t)3 * m.node_slots * sizeof(double);
    memcpy(ref.mesh.x, t.mesh.x, bytes);
    memcpy(ref.mesh.v, t.mesh.v, bytes);
    memcpy(ref.mesh.a, t.mesh.a, bytes);
    ns_tissue_forces(&t, 0, NULL);
    ns_tissue_forces(&ref, 1, NULL);
    double dk, sk, dd, sd;
    compare(&t.K, &ref.K, &dk, &sk);
    compare(&t.D, &ref.D, &dd, &sd);
    double df = max_rel_diff(t.force, ref.force, 3 * m.node_slots);
    printf("  K: %.2e of %.2e, D: %.2e of %.2e, force: %.2e relative\n", dk, sk, dd, sd, df);
    ENSURE(sk > 0.0 && sd > 0.0);
    ENSURE(dk <= 1e-12 * sk);
    ENSURE(dd <= 1e-12 * sd);
    ENSURE(df <= 1e-12);
    ns_tissue_free(&t);
    ns_tissue_free(&ref);
    ns_mesh_free(&m);
    return 0;
}

/* With a local load only some rows are gathered again each step: K and D must still equal a serial
 * scatter of every tet's Jacobians at the frame they were last built from, and the forces a serial
 * sum in tet order. */
static int lazy_rows_match_serial_scatter(void)
{
    NsMesh m;
    ENSURE(make_mesh(&m) == 0);
    NsTissue t;
    ENSURE(make_tissue(&t, &m, 2, TEST_THRESHOLD) == 0);
    ENSURE(settle(&t) == 0);
    double moved;
    int partial;
    int by_change = 0;
    ENSURE(run_counted(&t, 15, 1, 0.5, &moved, &partial, &by_change) == 0);
    printf("  moved %.3e m, %d steps rebuilt some tets, %d rows updated by changes\n", moved,
           partial, by_change);
    /* The rows taken by their tets' changes (ns_tissue_forces) are what this compares. */
    ENSURE(moved > 1e-5 && partial >= 3 && by_change > 0);
    NsTissueStats st;
    memset(&st, 0, sizeof st);
    ns_tissue_forces(&t, 0, &st);
    printf("  last call rebuilt %.1f%% of the tets\n", 100.0 * st.jacobian_fraction);

    const NsMesh *M = &t.mesh;
    NsBlockMatrix K, D;
    ns_bsm_init(&K);
    ns_bsm_init(&D);
    ENSURE(ns_bsm_resize(&K, M->node_slots) == 0 && ns_bsm_resize(&D, M->node_slots) == 0);
    double *f = calloc((size_t)3 * M->node_slots, sizeof(double));
    ENSURE(f);
    for (int e = 0; e < M->tet_slots; e++) {
        if (!ns_mesh_tet_alive(M, e))
            continue;
        const int *tn = M->tet_node + 4 * e;
        const NsFemMaterial *mat = &t.materials[M->tet_region[e]].fem;
        double Ke[144], De[144], fe[12];
        ns_fem_tet_jacobians(&t.rest[e], mat, &t.jframe[e],
                             t.jframe[e].s[2] < NS_TISSUE_PROJECT_BELOW, Ke, De);
        for (int a = 0; a < 4; a++)
            for (int b = 0; b < 4; b++) {
                double kb[9], db[9];
                for (int r = 0; r < 3; r++)
                    for (int c = 0; c < 3; c++) {
                        kb[3 * r + c] = Ke[12 * (3 * a + r) + 3 * b + c];
                        db[3 * r + c] = De[12 * (3 * a + r) + 3 * b + c];
                    }
                ENSURE(ns_bsm_add(&K, tn[a], tn[b], kb) == 0);
                ENSURE(ns_bsm_add(&D, tn[a], tn[b], db) == 0);
            }
        const double *x[4], *v[4];
        for (int k = 0; k < 4; k++) {
            x[k] = M->x + 3 * tn[k];
            v[k] = M->v + 3 * tn[k];
        }
        NsTetFrame frame;
        ns_fem_tet_forces(&t.rest[e], mat, x, v, fe, &frame);
        for (int k = 0; k < 12; k++)
            f[3 * tn[k / 3] + k % 3] += fe[k];
    }
    for (int i = 0; i < M->node_slots; i++)
        for (int c = 0; c < 3; c++)
            f[3 * i + c] += t.mass[i] * t.params.gravity[c];
    double dk, sk, dd, sd;
    compare(&t.K, &K, &dk, &sk);
    compare(&t.D, &D, &dd, &sd);
    double df = max_rel_diff(t.force, f, 3 * M->node_slots);
    printf("  K: %.2e of %.2e, D: %.2e of %.2e, force: %.2e relative\n", dk, sk, dd, sd, df);
    ENSURE(sk > 0.0 && sd > 0.0);
    ENSURE(dk <= 1e-12 * sk);
    ENSURE(dd <= 1e-12 * sd);
    ENSURE(df <= 1e-12);
    free(f);
    ns_bsm_free(&K);
    ns_bsm_free(&D);
    ns_tissue_free(&t);
    ns_mesh_free(&m);
    return 0;
}

static int state_hash_sees_one_bit(void)
{
    NsMesh m;
    ENSURE(make_mesh(&m) == 0);
    NsTissue t;
    ENSURE(make_tissue(&t, &m, 1, -1.0) == 0);
    uint64_t h0 = ns_tissue_state_hash(&t);
    ENSURE(ns_tissue_state_hash(&t) == h0);
    int i = m.node_slots / 2;
    ENSURE(m.flags[i] & NS_NODE_ALIVE);
    double saved = t.mesh.v[3 * i + 1];
    t.mesh.v[3 * i + 1] = -0.0; /* 0.0 -> -0.0: the sign bit alone */
    ENSURE(ns_tissue_state_hash(&t) != h0);
    t.mesh.v[3 * i + 1] = saved;
    ENSURE(ns_tissue_state_hash(&t) == h0);
    t.mesh.x[3 * i] = nextafter(t.mesh.x[3 * i], 1.0);
    ENSURE(ns_tissue_state_hash(&t) != h0);
    ns_tissue_free(&t);
    ns_mesh_free(&m);
    return 0;
}

NS_TEST_MAIN({"same_state_for_any_thread_count", same_state_for_any_thread_count},
             {"same_state_with_local_rebuilds", same_state_with_local_rebuilds},
             {"matches_from_scratch_assembly", matches_from_scratch_assembly},
             {"lazy_rows_match_serial_scatter", lazy_rows_match_serial_scatter},
             {"state_hash_sees_one_bit", state_hash_sees_one_bit})
