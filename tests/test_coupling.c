/* Tests of the coupled step (sim/coupling.c, coupled_paper.c, coupled_schur.c) beyond the
 * validation cases (engine/validate_coupling.c): determinism and thread independence of both
 * solvers, switching solvers between steps, and the checks of ns_coupled_init. The
 * scene: a 16 x 8 x 8 mm gel block with clamped sides, a held 18 G needle entering along the
 * centre line with its tip 8 mm deep, cutting forward. */
#include <stdlib.h>

#include "coupling.h"
#include "coupling_internal.h"
#include "mesh_grid.h"
#include "ns_test.h"
#include "snapshot.h"
#include "step.h"

typedef struct Scene {
    NsMesh mesh;
    NsTissue tissue;
    NsRod rod;
    NsCoupled cpl;
} Scene;

enum { NX = 8, NYZ = 4 };
#define LEN   0.016
#define WIDTH 0.008

static void scene_free(Scene *s)
{
    ns_coupled_free(&s->cpl);
    ns_rod_free(&s->rod);
    ns_tissue_free(&s->tissue);
    ns_mesh_free(&s->mesh);
}

/* Builds the scene up to the coupling's parameters; path_out gets the path (not yet taken). */
static int scene_parts(Scene *s, double gamma_rod, int threads, NsNeedlePath *path_out)
{
    memset(s, 0, sizeof *s);
    char err[256];
    double lo[3] = {0.0, -0.5 * WIDTH, -0.5 * WIDTH}, hi[3] = {LEN, 0.5 * WIDTH, 0.5 * WIDTH};
    ENSURE(ns_mesh_grid_box(&s->mesh, lo, hi, NX, NYZ, NYZ, 0, err, sizeof err) == 0);
    NsTissueMaterial mat = {ns_fem_material(NS_MODEL_COROTATIONAL, 30e3, 0.45, 3.0, 3.0), 1000.0};
    NsTissueParams tp = ns_default_tissue_params();
    tp.gamma = 0.55;
    tp.beta = 0.25 * 1.05 * 1.05;
    tp.threads = threads;
    ENSURE(ns_tissue_init(&s->tissue, &s->mesh, &mat, 1, &tp, err, sizeof err) == 0);
    const NsMesh *M = &s->tissue.mesh;
    for (int i = 0; i < M->node_slots; i++) {
        const double *u = M->u + 3 * i;
        if (fabs(fabs(u[1]) - 0.5 * WIDTH) < 1e-9 || fabs(fabs(u[2]) - 0.5 * WIDTH) < 1e-9)
            for (int c = 0; c < 3; c++)
                ns_tissue_fix_dof(&s->tissue, i, c, 1);
    }
    int path[NX + 1], tip = NX / 2, out = 4, n = out + 1 + tip + 1;
    double x[3 * 16] = {0}, h = LEN / NX;
    for (int i = 0; i <= NX; i++)
        path[i] = i + (NX + 1) * (NYZ / 2 + (NYZ + 1) * (NYZ / 2));
    for (int i = 0; i < n; i++)
        x[3 * i] = (i - out - 1) * h;
    double d1[3] = {0.0, 1.0, 0.0};
    NsRodParams rp = ns_default_rod_params();
    rp.gamma = gamma_rod;
    rp.beta = 0.25 * (gamma_rod + 0.5) * (gamma_rod + 0.5);
    ENSURE(ns_rod_init(&s->rod, x, n, d1, 2, &rp, err, sizeof err) == 0);
    ENSURE(ns_needle_path_init(path_out, M, path, NX + 1, tip * h, err, sizeof err) == 0);
    return 0;
}

static int scene_make(Scene *s, NsCoupledSolverKind solver, int threads, int refresh)
{
    NsNeedlePath p;
    ENSURE(scene_parts(s, 0.55, threads, &p) == 0);
    NsCouplingParams cp = ns_default_coupling_params();
    cp.f_perlen = 20.0;
    cp.cut_force[0] = 0.05;
    cp.solver = solver;
    cp.threads = threads;
    cp.refresh_iterations = refresh;
    char err[256];
    ENSURE(ns_coupled_init(&s->cpl, &s->tissue, &s->rod, &p, &cp, err, sizeof err) == 0);
    return 0;
}

/* In at 10 mm/s, then out, 5 ms steps; returns the final state hash (0 on failure). */
static uint64_t run(NsCoupledSolverKind solver, int threads, int refresh, int *refactors)
{
    Scene s;
    uint64_t h = 0;
    if (scene_make(&s, solver, threads, refresh) == 0) {
        int ok = 1;
        *refactors = 0;
        for (int k = 0; k < 60 && ok; k++) {
            NsCouplingStats st;
            s.rod.v_insert = k < 40 ? 0.01 : -0.01;
            ok = ns_coupled_step(&s.cpl, 5e-3, NULL, NULL, &st) == 0 && st.consistent &&
                 !st.unconverged;
            *refactors += st.refactors;
        }
        h = ok ? ns_coupled_state_hash(&s.cpl) : 0;
    }
    scene_free(&s);
    return h;
}

static int deterministic_for_any_threads(void)
{
    NsCoupledSolverKind kinds[2] = {NS_COUPLED_SCHUR, NS_COUPLED_PAPER};
    for (int k = 0; k < 2; k++) {
        int r1, r2, r3;
        uint64_t h1 = run(kinds[k], 1, 10, &r1), h2 = run(kinds[k], 1, 10, &r2),
                 h3 = run(kinds[k], 2, 10, &r3);
        printf("  %s: hash %016llx, tissue factorizations %d\n", ns_coupled_solver_name(kinds[k]),
               (unsigned long long)h1, r1);
        ENSURE(h1 != 0);
        ENSURE(h1 == h2);
        ENSURE(h1 == h3);
        ENSURE(k == 1 || r1 >= 1); /* ours factors the tissue at least once */
        ENSURE(k == 0 || r1 == 0); /* the paper's never */
    }
    return 0;
}

/* Refactorizations scheduled after every solve that needs more than one iteration: made in
 * the background with 2 threads, here with 1, adopted at the next step either way, so the
 * state is the same bit for bit. */
static int background_refresh_is_deterministic(void)
{
    int r1, r2, r3;
    uint64_t h1 = run(NS_COUPLED_SCHUR, 1, 1, &r1), h2 = run(NS_COUPLED_SCHUR, 2, 1, &r2);
    uint64_t h3 = run(NS_COUPLED_SCHUR, 1, 10, &r3);
    printf("  refresh after 1 iteration: %d factorizations, hash %016llx; after 10: %d\n", r1,
           (unsigned long long)h1, r3);
    ENSURE(h1 != 0 && h3 != 0);
    ENSURE(h1 == h2);
    ENSURE(r1 == r2);
    ENSURE(r1 > r3 + 5); /* the background path was taken, many times */
    return 0;
}

/* A coupling made with the paper's solver and switched to ours between steps (ours is then
 * created on the first step that needs it): it steps, consistent. */
static int switch_solver_between_steps(void)
{
    Scene s;
    ENSURE(scene_make(&s, NS_COUPLED_PAPER, 1, 10) == 0);
    for (int k = 0; k < 10; k++) {
        NsCouplingStats st;
        s.cpl.params.solver = k < 5 ? NS_COUPLED_PAPER : NS_COUPLED_SCHUR;
        s.rod.v_insert = 0.01;
        ENSURE(ns_coupled_step(&s.cpl, 5e-3, NULL, NULL, &st) == 0);
        ENSURE(st.consistent && !st.unconverged);
        ENSURE((k < 5) == (st.refactors == 0) || k > 5);
    }
    scene_free(&s);
    return 0;
}

/* With tip_block (docs/solvers.md, "The tail") ours orders the tip's ring last, makes its block
 * current every step and projects between the substitutions: the same trajectory as without,
 * to the solve's tolerance, on any thread count, but not the same iterates (it is in use). */
static uint64_t run_tip_block(int threads, int tip_block, double *tips, int *iterations)
{
    Scene s;
    uint64_t h = 0;
    NsNeedlePath p;
    if (scene_parts(&s, 0.55, threads, &p) != 0)
        return 0;
    NsCouplingParams cp = ns_default_coupling_params();
    cp.f_perlen = 20.0;
    cp.cut_force[0] = 0.05;
    cp.threads = threads;
    cp.tip_block = tip_block;
    char err[256];
    int ok = ns_coupled_init(&s.cpl, &s.tissue, &s.rod, &p, &cp, err, sizeof err) == 0;
    *iterations = 0;
    for (int k = 0; k < 60 && ok; k++) {
        NsCouplingStats st;
        s.rod.v_insert = k < 40 ? 0.01 : -0.01;
        ok =
            ns_coupled_step(&s.cpl, 5e-3, NULL, NULL, &st) == 0 && st.consistent && !st.unconverged;
        *iterations += st.iterations;
        for (int c = 0; c < 3; c++)
            tips[3 * k + c] = s.rod.x[3 * (s.rod.nodes - 1) + c];
    }
    h = ok ? ns_coupled_state_hash(&s.cpl) : 0;
    scene_free(&s);
    return h;
}

static int tip_block_same_trajectory(void)
{
    double t0[180], t1[180], t2[180];
    int i0, i1, i2;
    uint64_t h0 = run_tip_block(1, 0, t0, &i0), h1 = run_tip_block(1, 1, t1, &i1),
             h2 = run_tip_block(2, 1, t2, &i2);
    double d = 0.0;
    for (int k = 0; k < 180; k++)
        d = fmax(d, fabs(t1[k] - t0[k]));
    printf("  PCG iterations %d without, %d with; tips within %.2g m\n", i0, i1, d);
    ENSURE(h0 != 0 && h1 != 0);
    ENSURE(h1 == h2 && i1 == i2);
    ENSURE(h1 != h0); /* another preconditioner: other iterates */
    ENSURE(d < 1e-9);
    return 0;
}

static int init_checks(void)
{
    Scene s;
    NsNeedlePath p;
    char err[256];
    /* Tissue and needle with different Newmark parameters: refused, the path freed (ASan). */
    ENSURE(scene_parts(&s, 0.5, 1, &p) == 0);
    NsCouplingParams cp = ns_default_coupling_params();
    ENSURE(ns_coupled_init(&s.cpl, &s.tissue, &s.rod, &p, &cp, err, sizeof err) == -1);
    ENSURE(strstr(err, "Newmark") != NULL);
    ENSURE(p.node == NULL);
    scene_free(&s);
    /* An unknown solver kind: refused. */
    ENSURE(scene_parts(&s, 0.55, 1, &p) == 0);
    cp.solver = (NsCoupledSolverKind)7;
    ENSURE(ns_coupled_init(&s.cpl, &s.tissue, &s.rod, &p, &cp, err, sizeof err) == -1);
    ENSURE(strstr(err, "solver") != NULL);
    scene_free(&s);
    /* An unknown bevel model, a negative or NaN bevel force: refused. */
    for (int k = 0; k < 3; k++) {
        ENSURE(scene_parts(&s, 0.55, 1, &p) == 0);
        cp = ns_default_coupling_params();
        if (k == 0)
            cp.bevel_model = (NsBevelModel)5;
        else
            cp.bevel_force[3] = k == 1 ? -0.1 : NAN;
        ENSURE(ns_coupled_init(&s.cpl, &s.tissue, &s.rod, &p, &cp, err, sizeof err) == -1);
        ENSURE(strstr(err, "bevel") != NULL);
        scene_free(&s);
    }
    /* Names. */
    ENSURE(ns_coupled_solver_parse("schur") == NS_COUPLED_SCHUR);
    ENSURE(ns_coupled_solver_parse("paper") == NS_COUPLED_PAPER);
    ENSURE(ns_coupled_solver_parse("cg") == -1);
    ENSURE(strcmp(ns_coupled_solver_name(NS_COUPLED_SCHUR), "schur") == 0);
    return 0;
}

/* The step's scratch comes from its arena, empty after every step; once a step of the same
 * sizes has run, the next allocates nothing from it (the controls are ns_step's input). */
static int arena_empty_and_steady(void)
{
    Scene s;
    ENSURE(scene_make(&s, NS_COUPLED_SCHUR, 1, 10) == 0);
    const double vb[3] = {0, 0, 0};
    NsStepControls ctl = ns_step_controls(0.0, vb, 0.0);
    long spills = 0;
    for (int k = 0; k < 12; k++) {
        NsCouplingStats st;
        ENSURE(ns_step(&s.cpl, &ctl, 5e-3, &st) == 0);
        ENSURE(ns_arena_mark(&s.cpl.arena) == 0);
        if (k == 1)
            spills = s.cpl.arena.spills;
        if (k > 1)
            ENSURE(s.cpl.arena.spills == spills);
    }
    ENSURE(spills > 0 && s.cpl.arena.cap > 0);
    scene_free(&s);
    return 0;
}

/* Steps a and b alike (in at 10 mm/s for 40 steps, then out) from step k0 to k1: their tissues,
 * needles and couplings stay bit-identical. */
static int step_twins(Scene *a, Scene *b, int k0, int k1)
{
    for (int k = k0; k < k1; k++) {
        Scene *sc[2] = {a, b};
        for (int i = 0; i < 2; i++) {
            NsCouplingStats st;
            sc[i]->rod.v_insert = k < 40 ? 0.01 : -0.01;
            ENSURE(ns_coupled_step(&sc[i]->cpl, 5e-3, NULL, NULL, &st) == 0);
            ENSURE(st.consistent && !st.unconverged);
        }
        ENSURE(ns_tissue_state_hash(&a->tissue) == ns_tissue_state_hash(&b->tissue));
        ENSURE(ns_rod_state_hash(&a->rod) == ns_rod_state_hash(&b->rod));
        ENSURE(ns_coupled_state_hash(&a->cpl) == ns_coupled_state_hash(&b->cpl));
    }
    return 0;
}

/* Our solver's state (coupled_schur_pack) written from one of two twin scenes after k0 steps
 * and read back in place of the other's: both go on alike, bit for bit, on 2 threads. With a
 * refactorization scheduled at the snapshot (refresh after 1 iteration: made in the background,
 * adopted at the next step) and without, with and without tip_block. */
static int schur_snapshot_resumes(void)
{
    const struct {
        int refresh, tip_block, k0;
    } cases[] = {{1, 0, 9}, {10, 0, 9}, {1, 1, 23}, {10, 1, 38}, {1, 0, 45}};
    int pending_at = 0, idle_at = 0;
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
        Scene x, y;
        ENSURE(scene_make(&x, NS_COUPLED_SCHUR, 2, cases[c].refresh) == 0);
        ENSURE(scene_make(&y, NS_COUPLED_SCHUR, 2, cases[c].refresh) == 0);
        x.cpl.params.tip_block = y.cpl.params.tip_block = cases[c].tip_block;
        ENSURE(step_twins(&x, &y, 0, cases[c].k0) == 0);
        int pending = coupled_schur_pending(x.cpl.schur);
        pending_at += pending;
        idle_at += !pending;
        NsPack w, r, again;
        ns_pack_writer(&w, NULL);
        ENSURE(coupled_schur_pack(&w, &x.cpl.schur) == 0 && ns_pack_checksum(&w) == 0);
        coupled_schur_destroy(y.cpl.schur);
        ns_pack_reader(&r, NULL, w.buf, w.len);
        int rc = coupled_schur_pack(&r, &y.cpl.schur);
        if (rc == 0)
            rc = ns_pack_checksum(&r);
        if (rc)
            fprintf(stderr, "read back: %s\n", r.err);
        ENSURE(rc == 0 && r.pos == w.len && coupled_schur_pending(y.cpl.schur) == pending);
        ns_pack_writer(&again, NULL); /* the copy writes the same bytes again */
        ENSURE(coupled_schur_pack(&again, &y.cpl.schur) == 0 && ns_pack_checksum(&again) == 0);
        ENSURE(again.len == w.len && memcmp(again.buf, w.buf, w.len) == 0);
        printf("  refresh %d, tip_block %d, after %d steps: %zu bytes, %s\n", cases[c].refresh,
               cases[c].tip_block, cases[c].k0, w.len, pending ? "pending" : "none pending");
        for (int i = 0; c == 0 && i < 32; i++) { /* cut short: refused, what was read freed */
            CoupledSchur *d = NULL;
            ns_pack_reader(&r, NULL, w.buf, w.len * (size_t)i / 32);
            ENSURE(coupled_schur_pack(&r, &d) == -1 && r.err[0] != '\0');
            coupled_schur_destroy(d);
        }
        ns_pack_free(&w);
        ns_pack_free(&again);
        ENSURE(step_twins(&x, &y, cases[c].k0, cases[c].k0 + 12) == 0);
        scene_free(&x);
        scene_free(&y);
    }
    ENSURE(pending_at >= 2 && idle_at >= 2);
    return 0;
}

NS_TEST_MAIN({"deterministic_for_any_threads", deterministic_for_any_threads},
             {"background_refresh_is_deterministic", background_refresh_is_deterministic},
             {"switch_solver_between_steps", switch_solver_between_steps},
             {"tip_block_same_trajectory", tip_block_same_trajectory}, {"init_checks", init_checks},
             {"arena_empty_and_steady", arena_empty_and_steady},
             {"schur_snapshot_resumes", schur_snapshot_resumes})
