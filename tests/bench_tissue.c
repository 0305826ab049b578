/* Unit benchmark (not a test: it asserts nothing about time): the tissue step with the paper's
 * solver (CG, §3.6.2) against ours (PCG preconditioned by a stale Cholesky factor, DESIGN.md),
 * on a scenario's tissue sagging under gravity. Both tissues are stepped in lockstep in one
 * process, so machine noise hits them alike; the figures are medians.
 *
 *   build/tests/bench_tissue [SCENARIO.lua] [--steps N] [--threads N] [--refresh ITERATIONS]
 *
 * --refresh sets the stale-factor solver's refresh threshold (sim/solver.h; default 25).
 *
 * The default scenario is scenarios/brachytherapy.lua (~13.7k tets). Columns: medians per step of
 * the whole step, the force pass, the Jacobian rebuilds and row gathers, the linear solve
 * (system build included), the share of tets whose Jacobian was rebuilt and the iterations;
 * "factor" counts factorizations (synchronous and background refreshes). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ns_config.h"
#include "scenario.h"
#include "tissue.h"

#define KINDS 3

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double median(double *v, int n)
{
    qsort(v, (size_t)n, sizeof *v, cmp_double);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

int main(int argc, char **argv)
{
    const char *path = NS_SOURCE_DIR "/scenarios/brachytherapy.lua";
    int steps = 100, threads = 1, refresh = 0;
    for (int a = 1; a < argc; a++) {
        if (strcmp(argv[a], "--steps") == 0 && a + 1 < argc)
            steps = atoi(argv[++a]);
        else if (strcmp(argv[a], "--threads") == 0 && a + 1 < argc)
            threads = atoi(argv[++a]);
        else if (strcmp(argv[a], "--refresh") == 0 && a + 1 < argc)
            refresh = atoi(argv[++a]);
        else if (argv[a][0] != '-')
            path = argv[a];
        else {
            fprintf(stderr, "usage: bench_tissue [SCENARIO.lua] [--steps N] [--threads N] "
                            "[--refresh ITERATIONS]\n");
            return 2;
        }
    }
    if (steps < 1 || threads < 1) {
        fprintf(stderr, "bench_tissue: --steps and --threads must be positive\n");
        return 2;
    }
    NsScenario sc;
    char err[1024];
    if (ns_scenario_load(path, &sc, err, sizeof err)) {
        fprintf(stderr, "bench_tissue: %s\n", err);
        return 1;
    }
    const NsSolverKind kinds[KINDS] = {NS_SOLVER_CG, NS_SOLVER_JACOBI_PCG, NS_SOLVER_STALE_PCG};
    NsTissueParams p = ns_default_tissue_params();
    p.gravity[1] = -9.81; /* lithotomy position: the patient lies on the back (-y posterior) */
    p.solve_tol = 1e-6;   /* relative residual, as an interactive step would use */
    p.threads = threads;
    NsTissue t[KINDS];
    NsSolver *s[KINDS] = {NULL};
    memset(t, 0, sizeof t); /* ns_tissue_free is safe on a zeroed tissue */
    int rc = 1;
    /* Six per-step series per solver: total, solve, iterations, force, Jacobian, fraction. */
    double *buf = malloc((size_t)6 * KINDS * steps * sizeof(double));
    size_t stride = (size_t)KINDS * steps;
    double *total = buf, *solve = buf + stride, *iters = buf + 2 * stride,
           *force = buf + 3 * stride, *jac = buf + 4 * stride, *frac = buf + 5 * stride;
    int refactors[KINDS] = {0}, warnings[KINDS] = {0};
    if (!buf) {
        fprintf(stderr, "bench_tissue: out of memory\n");
        goto done;
    }
    for (int k = 0; k < KINDS; k++) {
        if (ns_scenario_tissue(&sc, &p, &t[k], err, sizeof err)) {
            fprintf(stderr, "bench_tissue: %s\n", err);
            goto done;
        }
        s[k] = ns_solver_create(kinds[k]);
        if (!s[k]) {
            fprintf(stderr, "bench_tissue: out of memory\n");
            goto done;
        }
        ns_solver_set_threads(s[k], threads);
        if (refresh > 0)
            ns_solver_set_refresh_iterations(s[k], refresh);
    }
    printf("%s: %d tets, %d nodes, %d steps of 1 ms under gravity, %d thread(s), solve tol "
           "%.0e\n",
           sc.name, sc.mesh.tet_alive, sc.mesh.node_alive, steps, threads, p.solve_tol);
    const double dt = 1e-3;
    for (int i = 0; i < steps; i++)
        for (int k = 0; k < KINDS; k++) {
            NsTissueStats st;
            if (ns_tissue_step(&t[k], s[k], dt, NULL, &st)) {
                fprintf(stderr, "bench_tissue: %s: step %d failed\n", ns_solver_name(kinds[k]), i);
                goto done;
            }
            total[k * steps + i] = st.total_ms;
            solve[k * steps + i] = st.solve_ms;
            iters[k * steps + i] = st.cg_iterations;
            force[k * steps + i] = st.force_ms;
            jac[k * steps + i] = st.jacobian_ms;
            frac[k * steps + i] = st.jacobian_fraction;
            refactors[k] += st.factorized + st.refresh_started;
            warnings[k] += st.nan_count + st.unconverged;
        }
    double med[KINDS];
    printf("%-12s %8s %8s %8s %8s %9s %6s %6s %5s\n", "solver", "step ms", "force", "jacobian",
           "solve", "rebuilt %", "iters", "factor", "warn");
    for (int k = 0; k < KINDS; k++) {
        med[k] = median(total + k * steps, steps);
        printf("%-12s %8.2f %8.2f %8.2f %8.2f %9.1f %6.0f %6d %5d\n", ns_solver_name(kinds[k]),
               med[k], median(force + k * steps, steps), median(jac + k * steps, steps),
               median(solve + k * steps, steps), 100.0 * median(frac + k * steps, steps),
               median(iters + k * steps, steps), refactors[k], warnings[k]);
    }
    double dmax = 0.0;
    for (int i = 0; i < 3 * t[0].mesh.node_slots; i++) {
        double d = t[0].mesh.x[i] - t[KINDS - 1].mesh.x[i];
        dmax = d > dmax ? d : (-d > dmax ? -d : dmax);
    }
    printf("median step, cg / stale-pcg: %.2fx; final positions differ by %.2e m\n",
           med[0] / med[KINDS - 1], dmax);
    rc = 0;
done:
    for (int k = 0; k < KINDS; k++) {
        ns_solver_destroy(s[k]);
        ns_tissue_free(&t[k]);
    }
    free(buf);
    ns_scenario_free(&sc);
    return rc;
}
