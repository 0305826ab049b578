/* Tests for sim/solver.c: every solver kind solves an SPD block system (a 3D grid Laplacian-like
 * stiffness with fixed nodes) to its tolerance and agrees with the others; the stale-factor PCG
 * needs few iterations after a small change and refreshes after a large one. */
#include "solver.h"
#include "ns_test.h"

#include <stdint.h>
#include <stdlib.h>

/* An SPD block matrix on an m^3 grid: for each grid edge (i, j) with weight w and direction d,
 * add w (I + k d d^T) to (i,i), (j,j) and subtract it from (i,j), (j,i); plus a mass shift. */
static void grid_matrix(NsBlockMatrix *A, int m, double stiff_scale, double mass)
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
                    double w = stiff_scale * (1.0 + 0.5 * ((i * 7 + j * 3) % 5));
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

NS_TEST_MAIN({"all_kinds_agree", all_kinds_agree},
             {"stale_factor_preconditions_and_refreshes", stale_factor_preconditions_and_refreshes})
