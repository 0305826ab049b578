/* Tests for sim/solver.c: every solver kind solves an SPD block system (a 3D grid Laplacian-like
 * stiffness with fixed nodes) to its tolerance and agrees with the others; the stale-factor PCG
 * needs few iterations after a small change and refreshes after a large one. */
#include "solver.h"
#include "ns_test.h"

#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* An SPD block matrix on an m^3 grid: for each grid edge (i, j) with weight w and direction d,
 * add w (I + k d d^T) to (i,i), (j,j) and subtract it from (i,j), (j,i); plus a mass shift.
 * drift != 0 scales each edge's weight by its own factor exp(drift sin(0.7 i + 0.3 j)), a local
 * change that a factor of the drift-0 matrix preconditions less and less well. */
static void grid_matrix_drift(NsBlockMatrix *A, int m, double stiff_scale, double mass,
                              double drift)
{
    int n = m * m * m;
    ns_bsm_init(A);
    ns_bsm_resize(A, n);
    for (int z = 0; z < m; z++)
        for (int y = 0; y < m; y++)
            for (int x = 0; x < m; x++) {
                int i = x + m * (y + m * z);
                double Mi[9] = {mass, 0, 0, 0, mass, 0, 0, 0, mass};
                ns_bsm_add(A, i, i, Mi);
                int nb[3][3] = {{x + 1, y, z}, {x, y + 1, z}, {x, y, z + 1}};
                for (int d = 0; d < 3; d++) {
                    if (nb[d][0] >= m || nb[d][1] >= m || nb[d][2] >= m)
                        continue;
                    int j = nb[d][0] + m * (nb[d][1] + m * nb[d][2]);
                    double w = stiff_scale * (1.0 + 0.5 * ((i * 7 + j * 3) % 5)) *
                               exp(drift * sin(0.7 * i + 0.3 * j));
                    double B[9] = {w, 0, 0, 0, w, 0, 0, 0, w}, N[9];
                    B[4 * d] += 2.0 * w;
                    for (int k = 0; k < 9; k++)
                        N[k] = -B[k];
                    ns_bsm_add(A, i, i, B);
                    ns_bsm_add(A, j, j, B);
                    ns_bsm_add(A, i, j, N);
                    ns_bsm_add(A, j, i, N);
                }
            }
}

static void grid_matrix(NsBlockMatrix *A, int m, double stiff_scale, double mass)
{
    grid_matrix_drift(A, m, stiff_scale, mass, 0.0);
}

/* True residual ||b_f - A x||, relative to ||b_f - A_fc x_c|| (the solvers' reference). */
static double residual(const NsBlockMatrix *A, const uint8_t *fixed, const double *b,
                       const double *x)
{
    int n3 = 3 * A->n;
    double *q = malloc((size_t)n3 * sizeof(double)), *xc = malloc((size_t)n3 * sizeof(double));
    double *q0 = malloc((size_t)n3 * sizeof(double)), rr = 0, bb = 0;
    for (int i = 0; i < n3; i++)
        xc[i] = fixed[i] ? x[i] : 0.0;
    ns_bsm_mul(A, x, q);
    ns_bsm_mul(A, xc, q0);
    for (int i = 0; i < n3; i++)
        if (!fixed[i]) {
            rr += (b[i] - q[i]) * (b[i] - q[i]);
            bb += (b[i] - q0[i]) * (b[i] - q0[i]);
        }
    free(q);
    free(xc);
    free(q0);
    return sqrt(rr / bb);
}

static int all_kinds_agree(void)
{
    const int m = 9, n = m * m * m;
    NsBlockMatrix A;
    grid_matrix(&A, m, 1e3, 1.0);
    uint8_t *fixed = calloc((size_t)3 * n, 1);
    for (int i = 0; i < 3 * m * m; i++)
        fixed[i] = 1;           /* the z = 0 face is clamped */
    fixed[3 * (n - 1) + 2] = 1; /* and one far node slides in its xy plane */
    double *b = malloc((size_t)3 * n * sizeof(double));
    double *ref = calloc((size_t)3 * n, sizeof(double));
    for (int i = 0; i < 3 * n; i++)
        b[i] = sin(0.37 * i) + 0.1;
    for (int i = 0; i < 3 * n; i++)
        ref[i] = fixed[i] ? 0.01 * cos(0.5 * i) : 0.0; /* prescribed values on fixed DOFs */
    NsSolveStats st;
    NsSolver *direct = ns_solver_create(NS_SOLVER_DIRECT);
    ENSURE(ns_solver_solve(direct, &A, fixed, b, ref, 1e-10, 0, &st) == 0);
    ENSURE(st.factorized && st.analyzed && st.converged);
    for (int i = 0; i < 3 * n; i++)
        if (fixed[i])
            ENSURE(ref[i] == 0.01 * cos(0.5 * i)); /* fixed values untouched */
    for (int kind = 0; kind < 4; kind++) {
        NsSolver *s = ns_solver_create((NsSolverKind)kind);
        double *x = calloc((size_t)3 * n, sizeof(double));
        for (int i = 0; i < 3 * n; i++)
            x[i] = fixed[i] ? ref[i] : 0.0;
        ENSURE(ns_solver_solve(s, &A, fixed, b, x, 1e-9, 5000, &st) == 0);
        ENSURE(st.converged);
        double err = 0, nrm = 0;
        for (int i = 0; i < 3 * n; i++) {
            err += (x[i] - ref[i]) * (x[i] - ref[i]);
            nrm += ref[i] * ref[i];
        }
        ENSURE(sqrt(err / nrm) < 1e-7);
        ENSURE(residual(&A, fixed, b, x) < 1e-8); /* 1e-9 asked; CG's recursive residual drifts */
        printf("  %-10s iterations %d\n", ns_solver_name((NsSolverKind)kind), st.iterations);
        free(x);
        ns_solver_destroy(s);
    }
    ns_solver_destroy(direct);
    ns_bsm_free(&A);
    free(fixed);
    free(b);
    free(ref);
    return 0;
}

static int stale_factor_preconditions_and_refreshes(void)
{
    const int m = 8, n = m * m * m;
    NsBlockMatrix A, A2, A3;
    grid_matrix(&A, m, 1e3, 1.0);
    grid_matrix(&A2, m, 1.05e3, 1.0); /* stiffness changed by 5% */
    grid_matrix(&A3, m, 4e3, 1.0);    /* changed 4x */
    uint8_t *fixed = calloc((size_t)3 * n, 1);
    fixed[0] = fixed[1] = fixed[2] = 1;
    double *b = malloc((size_t)3 * n * sizeof(double)), *x = calloc((size_t)3 * n, 8);
    for (int i = 0; i < 3 * n; i++)
        b[i] = cos(0.11 * i);
    NsSolver *s = ns_solver_create(NS_SOLVER_STALE_PCG);
    ns_solver_set_refresh_iterations(s, 10);
    NsSolveStats st;
    ENSURE(ns_solver_solve(s, &A, fixed, b, x, 1e-8, 500, &st) == 0);
    ENSURE(st.factorized && st.iterations <= 2 && st.converged);
    for (int i = 0; i < 3 * n; i++)
        x[i] = 0;
    ENSURE(ns_solver_solve(s, &A2, fixed, b, x, 1e-8, 500, &st) == 0);
    ENSURE(!st.factorized && st.converged && st.iterations <= 10);
    printf("  5%% change: %d iterations with the stale factor\n", st.iterations);
    for (int i = 0; i < 3 * n; i++)
        x[i] = 0;
    ENSURE(ns_solver_solve(s, &A3, fixed, b, x, 1e-8, 500, &st) == 0);
    ENSURE(st.converged);
    printf("  4x change: %d iterations, refactored: %d\n", st.iterations, st.factorized);
    ENSURE(residual(&A3, fixed, b, x) < 1e-7);
    ns_solver_destroy(s);
    ns_bsm_free(&A);
    ns_bsm_free(&A2);
    ns_bsm_free(&A3);
    free(fixed);
    free(b);
    free(x);
    return 0;
}

/* A sequence of solves as a time stepper makes them: matrix k drifts away from matrix 0
 * (edge weights by up to exp(+-0.06 k), the diagonal by 5 k), the right-hand side changes a
 * little, and x is warm-started from the previous solution. Every x is kept (xs: solves x 3n)
 * with its stats; every solve must converge to tol. */
typedef struct SeqRun {
    NsSolverKind kind;
    int threads;
    int lag;     /* refresh_lag; -1 for the default */
    int refresh; /* refresh_iterations */
    int m;       /* grid side (m^3 nodes) */
    int solves;
    double *xs;
    NsSolveStats *st;
} SeqRun;

#define SEQ_TOL 1e-8

static int run_sequence(SeqRun *run)
{
    const int m = run->m, n = m * m * m, n3 = 3 * n;
    uint8_t *fixed = calloc((size_t)n3, 1);
    for (int i = 0; i < 3 * m * m; i++)
        fixed[i] = 1; /* the z = 0 face is clamped */
    double *b = malloc((size_t)n3 * sizeof(double)), *x = calloc((size_t)n3, sizeof(double));
    NsSolver *s = ns_solver_create(run->kind);
    ns_solver_set_threads(s, run->threads);
    ns_solver_set_refresh_iterations(s, run->refresh);
    if (run->lag >= 0)
        ns_solver_set_refresh_lag(s, run->lag);
    run->xs = malloc((size_t)run->solves * n3 * sizeof(double));
    run->st = calloc((size_t)run->solves, sizeof(NsSolveStats));
    for (int k = 0; k < run->solves; k++) {
        NsBlockMatrix A;
        grid_matrix_drift(&A, m, 1e3, 1.0 + 5.0 * k, 0.06 * k);
        for (int i = 0; i < n3; i++)
            b[i] = sin(0.37 * i + 0.05 * k) + 0.1;
        ENSURE(ns_solver_solve(s, &A, fixed, b, x, SEQ_TOL, 5000, &run->st[k]) == 0);
        ENSURE(run->st[k].converged);
        ENSURE(residual(&A, fixed, b, x) < 10 * SEQ_TOL); /* CG's recursive residual drifts */
        memcpy(run->xs + (size_t)k * n3, x, (size_t)n3 * sizeof(double));
        ns_bsm_free(&A);
    }
    ns_solver_destroy(s);
    free(fixed);
    free(b);
    free(x);
    return 0;
}

static void free_run(SeqRun *run)
{
    free(run->xs);
    free(run->st);
}

/* Two runs made the same solves: bit-identical x, and the same iterations and refresh events. */
static int same_runs(const SeqRun *a, const SeqRun *b)
{
    size_t n3 = 3 * (size_t)a->m * a->m * a->m;
    ENSURE(memcmp(a->xs, b->xs, (size_t)a->solves * n3 * sizeof(double)) == 0);
    for (int k = 0; k < a->solves; k++) {
        const NsSolveStats *p = &a->st[k], *q = &b->st[k];
        ENSURE(p->iterations == q->iterations && p->residual == q->residual);
        ENSURE(p->factorized == q->factorized && p->analyzed == q->analyzed);
        ENSURE(p->refresh_started == q->refresh_started);
        ENSURE(p->refresh_adopted == q->refresh_adopted && p->factor_age == q->factor_age);
    }
    return 0;
}

/* STYLE.md §8: the thread count must not change a bit of the result. The 12^3 grid (5184 DOF)
 * is large enough for the parallel paths of the SpMV and of the vector operations. */
static int threads_give_identical_iterates(void)
{
    const NsSolverKind kinds[3] = {NS_SOLVER_CG, NS_SOLVER_JACOBI_PCG, NS_SOLVER_STALE_PCG};
    for (int k = 0; k < 3; k++) {
        SeqRun one = {kinds[k], 1, -1, 4, 12, 6, NULL, NULL};
        ENSURE(run_sequence(&one) == 0);
        for (int threads = 2; threads <= 3; threads++) {
            SeqRun more = {kinds[k], threads, -1, 4, 12, 6, NULL, NULL};
            ENSURE(run_sequence(&more) == 0);
            ENSURE(same_runs(&one, &more) == 0);
            free_run(&more);
        }
        int its = 0;
        for (int i = 0; i < one.solves; i++)
            its += one.st[i].iterations;
        printf("  %-10s %d iterations in %d solves, identical for 1, 2 and 3 threads\n",
               ns_solver_name(kinds[k]), its, one.solves);
        free_run(&one);
    }
    return 0;
}

/* A slow stale-PCG solve schedules a refactorization of its matrix; the factor is adopted by
 * exactly the lag-th solve after it, the iterations drop there, and the whole run is
 * bit-identical whether the factorization ran in the background (2 threads) or in the
 * scheduling solve (1 thread). */
static int background_refresh_adopted_on_schedule(void)
{
    const int lags[3] = {-1, 1, 3}; /* -1: the default, 2 */
    for (int l = 0; l < 3; l++) {
        int lag = lags[l] < 0 ? 2 : lags[l];
        SeqRun bg = {NS_SOLVER_STALE_PCG, 2, lags[l], 4, 10, 14, NULL, NULL};
        SeqRun fg = {NS_SOLVER_STALE_PCG, 1, lags[l], 4, 10, 14, NULL, NULL};
        SeqRun never = {NS_SOLVER_STALE_PCG, 1, lags[l], 1000, 10, 14, NULL, NULL};
        ENSURE(run_sequence(&bg) == 0);
        ENSURE(run_sequence(&fg) == 0);
        ENSURE(run_sequence(&never) == 0);
        ENSURE(same_runs(&bg, &fg) == 0);
        const NsSolveStats *st = bg.st;
        ENSURE(st[0].factorized && st[0].analyzed && st[0].factor_age == 0);
        int started = 0, adopted = 0, pending_since = -1;
        printf("  lag %d:", lag);
        for (int k = 0; k < bg.solves; k++) {
            printf(" %d%s%s", st[k].iterations, st[k].refresh_started ? "s" : "",
                   st[k].refresh_adopted ? "a" : "");
            ENSURE(k == 0 || !st[k].factorized); /* no synchronous factorization after the first */
            if (pending_since >= 0 && k == pending_since + lag) {
                ENSURE(st[k].refresh_adopted);
                ENSURE(st[k].factor_age == lag);
                /* The fresher factor needs fewer iterations than the first one still would. */
                ENSURE(st[k].iterations < never.st[k].iterations);
                pending_since = -1;
                adopted++;
            } else {
                ENSURE(!st[k].refresh_adopted);
            }
            if (k > 0 && !st[k].refresh_adopted)
                ENSURE(st[k].factor_age == st[k - 1].factor_age + 1);
            if (st[k].refresh_started) {
                ENSURE(pending_since < 0); /* one refresh at a time */
                ENSURE(st[k].iterations > 4);
                pending_since = k;
                started++;
            } else if (pending_since < 0) {
                ENSURE(st[k].iterations <= 4); /* a slow solve always schedules one */
            }
        }
        printf("  (s: refresh started, a: adopted)\n");
        ENSURE(started >= 2 && adopted >= 2);
        free_run(&bg);
        free_run(&fg);
        free_run(&never);
    }
    /* lag 0: the slow solve refactors its own matrix and finishes with the new factor. */
    SeqRun sync = {NS_SOLVER_STALE_PCG, 2, 0, 4, 10, 8, NULL, NULL};
    ENSURE(run_sequence(&sync) == 0);
    int refactored = 0;
    for (int k = 0; k < sync.solves; k++) {
        const NsSolveStats *st = &sync.st[k];
        ENSURE(!st->refresh_started && !st->refresh_adopted);
        if (st->factorized)
            refactored++;
        ENSURE(st->factorized ? st->factor_age == 0 : st->iterations <= 4);
    }
    ENSURE(refactored >= 3);
    free_run(&sync);
    return 0;
}

/* The synchronous paths drop a pending refresh: a solve that the stale factor cannot finish
 * within max_iter, a change of the fixed DOFs (pattern), ns_solver_refresh; and destroying the
 * solver waits for a running refactorization. */
static int fallbacks_drop_pending_refresh(void)
{
    const int m = 10, n = m * m * m, n3 = 3 * n;
    uint8_t *fixed = calloc((size_t)n3, 1);
    for (int i = 0; i < 3 * m * m; i++)
        fixed[i] = 1;
    double *b = malloc((size_t)n3 * sizeof(double)), *x = calloc((size_t)n3, sizeof(double));
    for (int i = 0; i < n3; i++)
        b[i] = cos(0.21 * i);
    NsBlockMatrix A[4];
    for (int k = 0; k < 4; k++)
        grid_matrix_drift(&A[k], m, 1e3, 1.0 + 20.0 * k, 0.3 * k);
    NsSolver *s = ns_solver_create(NS_SOLVER_STALE_PCG);
    ns_solver_set_threads(s, 2);
    ns_solver_set_refresh_iterations(s, 3);
    NsSolveStats st;
    for (int round = 0; round < 4; round++) {
        int last = 1; /* the matrix factored by the synchronous path */
        /* A fresh factor of A[0], then a slow solve of A[2] schedules a refresh. */
        ns_solver_refresh(s);
        ENSURE(ns_solver_solve(s, &A[0], fixed, b, x, SEQ_TOL, 500, &st) == 0);
        ENSURE(st.factorized && st.converged && st.factor_age == 0);
        ENSURE(ns_solver_solve(s, &A[2], fixed, b, x, SEQ_TOL, 500, &st) == 0);
        ENSURE(st.refresh_started && st.converged && !st.factorized && st.factor_age == 1);
        if (round == 0) {
            /* Too few iterations for the stale factor: factored now, and the solve finished. */
            ENSURE(ns_solver_solve(s, &A[3], fixed, b, x, SEQ_TOL, 2, &st) == 0);
            ENSURE(st.factorized && !st.analyzed && st.converged && st.factor_age == 0);
            ENSURE(residual(&A[3], fixed, b, x) < 10 * SEQ_TOL);
            last = 3;
        } else if (round == 1) {
            /* One more fixed DOF: a new pattern, analyzed and factored now. */
            fixed[3 * n - 1] = 1;
            ENSURE(ns_solver_solve(s, &A[1], fixed, b, x, SEQ_TOL, 500, &st) == 0);
            ENSURE(st.factorized && st.analyzed && st.converged && st.factor_age == 0);
        } else if (round == 2) {
            ns_solver_refresh(s);
            ENSURE(ns_solver_solve(s, &A[1], fixed, b, x, SEQ_TOL, 500, &st) == 0);
            ENSURE(st.factorized && !st.analyzed && st.converged && st.factor_age == 0);
        } else {
            break; /* destroyed with the refactorization (probably) still running */
        }
        /* The dropped refresh is never adopted. */
        for (int k = 0; k < 3; k++) {
            ENSURE(ns_solver_solve(s, &A[last], fixed, b, x, SEQ_TOL, 500, &st) == 0);
            ENSURE(!st.refresh_adopted && !st.factorized && st.converged);
            ENSURE(st.factor_age == k + 1);
        }
    }
    ns_solver_destroy(s);
    for (int k = 0; k < 4; k++)
        ns_bsm_free(&A[k]);
    free(fixed);
    free(b);
    free(x);
    return 0;
}

/* The factor on its own: ns_solver_apply on many columns (and on one) gives A^-1 B on the free
 * DOFs, 0 on the fixed ones; the count changes with each factor; a wrong length or no factor is
 * an error. */
static int factor_applied_to_columns(void)
{
    const int m = 6, n = m * m * m, n3 = 3 * n, cols = 5;
    NsBlockMatrix A;
    grid_matrix(&A, m, 1e3, 1.0);
    uint8_t *fixed = calloc((size_t)n3, 1);
    for (int i = 0; i < 3 * m * m; i++)
        fixed[i] = 1;
    double *B = malloc((size_t)n3 * cols * sizeof *B), *Z = malloc((size_t)n3 * cols * sizeof *Z);
    double *x = malloc((size_t)n3 * sizeof *x);
    for (int i = 0; i < n3 * cols; i++)
        B[i] = cos(0.11 * i) + 0.2;
    NsSolver *s = ns_solver_create(NS_SOLVER_DIRECT);
    ENSURE(ns_solver_apply(s, n3, 1, B, Z) == -1); /* no factor yet */
    ENSURE(ns_solver_factor_count(s) == 0);
    ENSURE(ns_solver_factor(s, &A, fixed) == 0);
    ENSURE(ns_solver_factor_count(s) == 1);
    ENSURE(ns_solver_apply(s, n3 - 3, 1, B, Z) == -1); /* not the factored size */
    ENSURE(ns_solver_apply(s, n3, cols, B, Z) == 0);
    for (int j = 0; j < cols; j++) {
        const double *b = B + (size_t)j * n3, *z = Z + (size_t)j * n3;
        for (int i = 0; i < n3; i++)
            x[i] = 0.0;
        NsSolveStats st;
        NsSolver *d = ns_solver_create(NS_SOLVER_DIRECT);
        ENSURE(ns_solver_solve(d, &A, fixed, b, x, 1e-12, 0, &st) == 0);
        ns_solver_destroy(d);
        double err = 0.0, nrm = 0.0;
        for (int i = 0; i < n3; i++) {
            if (fixed[i])
                ENSURE(z[i] == 0.0);
            err += (z[i] - x[i]) * (z[i] - x[i]);
            nrm += x[i] * x[i];
        }
        ENSURE(sqrt(err / nrm) < 1e-12);
    }
    double *z1 = malloc((size_t)n3 * sizeof *z1);
    ENSURE(ns_solver_apply(s, n3, 1, B + n3, z1) == 0);
    for (int i = 0; i < n3; i++)
        ENSURE(fabs(z1[i] - Z[n3 + i]) <= 1e-12 * (fabs(Z[n3 + i]) + 1e-30));
    ENSURE(ns_solver_factor(s, &A, fixed) == 0);
    ENSURE(ns_solver_factor_count(s) == 2);
    /* Scheduled: another matrix of the same pattern factored with its columns (in the
     * background with 2 threads), in use only once adopted. */
    NsBlockMatrix A2;
    grid_matrix(&A2, m, 2e3, 1.0);
    double *Z2 = malloc((size_t)n3 * cols * sizeof *Z2), *Z3 = malloc((size_t)n3 * sizeof *Z3);
    int ok = 0;
    for (int th = 1; th <= 2; th++) {
        ns_solver_set_threads(s, th);
        long before = ns_solver_factor_count(s);
        ENSURE(ns_solver_factor_async(s, &A2, fixed, cols, B, Z2) == 0);
        ENSURE(ns_solver_apply(s, n3, 1, B + n3, Z3) == 0); /* still the old factor */
        ENSURE(memcmp(Z3, z1, (size_t)n3 * sizeof *Z3) == 0);
        ENSURE(ns_solver_factor_adopt(s, &ok) == 1 && ok);
        ENSURE(ns_solver_factor_count(s) == before + 1);
        ENSURE(ns_solver_factor_adopt(s, &ok) == 0); /* nothing pending */
        ENSURE(ns_solver_apply(s, n3, 1, B + n3, Z3) == 0);
        for (int i = 0; i < n3; i++)
            ENSURE(fabs(Z3[i] - Z2[n3 + i]) <= 1e-12 * (fabs(Z2[n3 + i]) + 1e-30));
        ENSURE(ns_solver_factor(s, &A, fixed) == 0); /* back to A for the next round */
        ENSURE(ns_solver_apply(s, n3, 1, B + n3, z1) == 0);
    }
    ns_bsm_free(&A2);
    free(Z2);
    free(Z3);
    NsSolver *cg = ns_solver_create(NS_SOLVER_CG);
    ENSURE(ns_solver_factor(cg, &A, fixed) == -1); /* CG has no factor */
    ns_solver_destroy(cg);
    ns_solver_destroy(s);
    ns_bsm_free(&A);
    free(fixed);
    free(B);
    free(Z);
    free(x);
    free(z1);
    return 0;
}

/* The factor's single-precision copy and substitutions (sim/supernodal.c): close to the double
 * solve, not the same operator (so it is in use), bit-identical on one thread and two. */
static int single_precision_preconditioner(void)
{
    const int m = 12, n = m * m * m, n3 = 3 * n;
    NsBlockMatrix A;
    grid_matrix(&A, m, 1e3, 1.0);
    uint8_t *fixed = calloc((size_t)n3, 1);
    for (int i = 0; i < 3 * m * m; i++)
        fixed[i] = 1;
    double *b = malloc((size_t)n3 * sizeof *b), *z = malloc((size_t)n3 * sizeof *z);
    double *z1 = malloc((size_t)n3 * sizeof *z1), *z2 = malloc((size_t)n3 * sizeof *z2);
    for (int i = 0; i < n3; i++)
        b[i] = cos(0.37 * i) + 0.1;
    NsSolver *s = ns_solver_create(NS_SOLVER_DIRECT);
    ENSURE(ns_solver_precondition(s, n3, b, z1) == -1); /* no factor yet */
    ENSURE(ns_solver_factor(s, &A, fixed) == 0);
    ENSURE(ns_solver_precondition(s, n3 - 3, b, z1) == -1); /* not the factored size */
    ENSURE(ns_solver_apply(s, n3, 1, b, z) == 0);
    ns_solver_set_threads(s, 1);
    ENSURE(ns_solver_precondition(s, n3, b, z1) == 0);
    ns_solver_set_threads(s, 2);
    ENSURE(ns_solver_precondition(s, n3, b, z2) == 0);
    ENSURE(memcmp(z1, z2, (size_t)n3 * sizeof *z1) == 0);
    /* The cut gives each thread work: both bins are non-empty and of comparable size, and the
     * top (the last separators) is a part of the factor, not all of it. */
    size_t cut[3];
    ENSURE(ns_solver_precondition_cut(s, cut) == 0);
    printf("  cut: bins %zu and %zu stored values, top %zu\n", cut[0], cut[1], cut[2]);
    ENSURE(cut[0] > 0 && cut[1] > 0 && cut[2] > 0);
    ENSURE(cut[0] <= 2 * cut[1] && cut[1] <= 2 * cut[0]);
    ENSURE(cut[2] < cut[0] + cut[1]);
    double err = 0.0, nrm = 0.0;
    for (int i = 0; i < n3; i++) {
        if (fixed[i])
            ENSURE(z1[i] == 0.0);
        err += (z1[i] - z[i]) * (z1[i] - z[i]);
        nrm += z[i] * z[i];
    }
    err = sqrt(err / nrm);
    printf("  relative difference from the double solve: %.2g\n", err);
    ENSURE(err > 1e-12 && err < 1e-5); /* floats' rounding, not a double solve, not garbage */
    /* Right-hand sides beyond the range of floats, both ways: the same accuracy. */
    for (int k = 0; k < 2; k++) {
        double scale = k ? 1e40 : 1e-40;
        for (int i = 0; i < n3; i++)
            z2[i] = b[i] * scale;
        ENSURE(ns_solver_precondition(s, n3, z2, z2) == 0);
        double e2 = 0.0;
        for (int i = 0; i < n3; i++)
            e2 += (z2[i] / scale - z[i]) * (z2[i] / scale - z[i]);
        ENSURE(sqrt(e2 / nrm) < 1e-5);
    }
    /* A refactorization's copy replaces the old one: the new matrix's answer. */
    NsBlockMatrix A2;
    grid_matrix(&A2, m, 2e3, 1.0);
    ENSURE(ns_solver_factor(s, &A2, fixed) == 0);
    ENSURE(ns_solver_apply(s, n3, 1, b, z) == 0);
    ENSURE(ns_solver_precondition(s, n3, b, z2) == 0);
    err = nrm = 0.0;
    for (int i = 0; i < n3; i++) {
        err += (z2[i] - z[i]) * (z2[i] - z[i]);
        nrm += z[i] * z[i];
    }
    ENSURE(sqrt(err / nrm) < 1e-5);
    ns_solver_destroy(s);
    ns_bsm_free(&A);
    ns_bsm_free(&A2);
    free(fixed);
    free(b);
    free(z);
    free(z1);
    free(z2);
    return 0;
}

/* The tail (docs/solvers.md, "The tail"): nodes asked for are ordered last, and after
 * ns_solver_tail_update the copy applies the exact factor of the old matrix with the new
 * matrix's tail block (so A2 x comes back as x where A2 differs from A only there), the same on
 * one thread and two; the substitutions' middle step sees L^-1 P b. */
static void mid_record(void *ctx, float *y, int n, double down, double up)
{
    float *out = ctx;
    (void)up;
    for (int i = 0; i < n; i++)
        out[i] = (float)(y[i] / down);
}

static int tail_block_made_current(void)
{
    const int m = 10, n = m * m * m, n3 = 3 * n;
    NsBlockMatrix A, A2;
    grid_matrix(&A, m, 1e3, 1.0);
    grid_matrix(&A2, m, 1e3, 1.0);
    uint8_t *fixed = calloc((size_t)n3, 1);
    for (int i = 0; i < 3 * m * m; i++)
        fixed[i] = 1;
    /* The ring of the middle node: itself and its six neighbours. */
    int c = m / 2 + m * (m / 2 + m * (m / 2));
    int ring[7] = {c, c - 1, c + 1, c - m, c + m, c - m * m, c + m * m};
    /* A2 = A plus a change inside the ring's block only (a positive semidefinite one: the
     * ring's own springs stiffened, the masses raised). */
    for (int a = 1; a < 7; a++) {
        double w = 4e3 * a, B[9] = {w, 0, 0, 0, w, 0, 0, 0, w}, N[9];
        for (int k = 0; k < 9; k++)
            N[k] = -B[k];
        ns_bsm_add(&A2, c, c, B);
        ns_bsm_add(&A2, ring[a], ring[a], B);
        ns_bsm_add(&A2, c, ring[a], N);
        ns_bsm_add(&A2, ring[a], c, N);
        double Mi[9] = {3.0, 0, 0, 0, 3.0, 0, 0, 0, 3.0};
        ns_bsm_add(&A2, ring[a], ring[a], Mi);
    }
    double *x = malloc((size_t)n3 * sizeof *x), *b = malloc((size_t)n3 * sizeof *b);
    double *z1 = malloc((size_t)n3 * sizeof *z1), *z2 = malloc((size_t)n3 * sizeof *z2);
    for (int i = 0; i < n3; i++)
        x[i] = fixed[i] ? 0.0 : cos(0.23 * i) + 0.3;
    ns_bsm_mul(&A2, x, b);
    NsSolver *s = ns_solver_create(NS_SOLVER_DIRECT);
    ENSURE(ns_solver_set_tail(s, ring, 7) == 0);
    ENSURE(ns_solver_factor(s, &A, fixed) == 0);
    const double *L22;
    ENSURE(ns_solver_tail_block(s, n3, &L22) == 21 && L22 != NULL);
    /* Before the update the copy is A's factor: A2 x does not come back as x. */
    ENSURE(ns_solver_precondition(s, n3, b, z1) == 0);
    double e0 = 0.0, nx = 0.0;
    for (int i = 0; i < n3; i++) {
        e0 += (z1[i] - x[i]) * (z1[i] - x[i]);
        nx += x[i] * x[i];
    }
    e0 = sqrt(e0 / nx);
    ENSURE(ns_solver_tail_update(s, &A2) == 21);
    ns_solver_set_threads(s, 1);
    ENSURE(ns_solver_precondition(s, n3, b, z1) == 0);
    ns_solver_set_threads(s, 2);
    ENSURE(ns_solver_precondition(s, n3, b, z2) == 0);
    ENSURE(memcmp(z1, z2, (size_t)n3 * sizeof *z1) == 0);
    double e1 = 0.0;
    for (int i = 0; i < n3; i++)
        e1 += (z1[i] - x[i]) * (z1[i] - x[i]);
    e1 = sqrt(e1 / nx);
    printf("  A2 x back: %.2g relative with the tail made current, %.2g without\n", e1, e0);
    ENSURE(e0 > 1e-2 && e1 < 1e-5);
    /* Back to A's block: A's own factor again. */
    ENSURE(ns_solver_tail_update(s, &A) == 21);
    ns_bsm_mul(&A, x, b);
    ENSURE(ns_solver_precondition(s, n3, b, z1) == 0);
    e1 = 0.0;
    for (int i = 0; i < n3; i++)
        e1 += (z1[i] - x[i]) * (z1[i] - x[i]);
    ENSURE(sqrt(e1 / nx) < 1e-5);
    /* The middle step: with a step that changes nothing, the same bits; for a unit right-hand
     * side it sees what ns_solver_forward_dof gives. */
    int nf = ns_solver_forward_dof(s, n3, 0, NULL);
    ENSURE(nf == n3 - 3 * m * m);
    ENSURE(ns_solver_forward_dof(s, n3, 0, (float *)z2) == 0); /* a fixed DOF: no column */
    float *ymid = calloc((size_t)nf, sizeof *ymid), *yfw = calloc((size_t)nf, sizeof *yfw);
    ENSURE(ns_solver_precondition_mid(s, n3, b, z2, mid_record, ymid) == 0);
    ENSURE(ns_solver_precondition(s, n3, b, z1) == 0);
    ENSURE(memcmp(z1, z2, (size_t)n3 * sizeof *z1) == 0);
    int dof = 3 * (c + 2) + 1;
    for (int i = 0; i < n3; i++)
        b[i] = i == dof ? 1.0 : 0.0;
    ENSURE(ns_solver_precondition_mid(s, n3, b, z2, mid_record, ymid) == 0);
    ENSURE(ns_solver_forward_dof(s, n3, dof, yfw) == nf);
    double d = 0.0, ny = 0.0;
    int touched = 0;
    for (int i = 0; i < nf; i++) {
        d += (double)(ymid[i] - yfw[i]) * (ymid[i] - yfw[i]);
        ny += (double)yfw[i] * yfw[i];
        touched += yfw[i] != 0.0f;
    }
    printf("  L^-1 e: %d of %d entries, %.2g from the middle step's\n", touched, nf, sqrt(d / ny));
    ENSURE(ny > 0.0 && sqrt(d / ny) < 1e-6 && touched < nf);
    ns_solver_destroy(s);
    ns_bsm_free(&A);
    ns_bsm_free(&A2);
    free(fixed);
    free(x);
    free(b);
    free(z1);
    free(z2);
    free(ymid);
    free(yfw);
    return 0;
}

NS_TEST_MAIN({"all_kinds_agree", all_kinds_agree},
             {"stale_factor_preconditions_and_refreshes", stale_factor_preconditions_and_refreshes},
             {"threads_give_identical_iterates", threads_give_identical_iterates},
             {"background_refresh_adopted_on_schedule", background_refresh_adopted_on_schedule},
             {"fallbacks_drop_pending_refresh", fallbacks_drop_pending_refresh},
             {"factor_applied_to_columns", factor_applied_to_columns},
             {"single_precision_preconditioner", single_precision_preconditioner},
             {"tail_block_made_current", tail_block_made_current})
