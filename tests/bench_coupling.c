/* Unit benchmark (not a test: it asserts nothing about time) of the coupled needle-tissue step:
 * our solver (schur, the default) against the paper's (CG on Eq. 7), on a scenario's tissue
 * with a straight needle path laid into its mesh beforehand (sim/needle_path.h; remeshing comes
 * later). Both are stepped in lockstep in one process, so machine noise hits them alike; the
 * figures are medians.
 *
 *   build/tests/bench_coupling [SCENARIO.lua] [--steps N] [--dt S] [--threads N]
 *
 * The default scenario is scenarios/brachytherapy.lua (~13.7k tets): the path runs from the
 * perineum (z = 0) 8 cm along +z, 8 mm lateral to the urethra; the needle's tip starts at the
 * path node nearest 3 cm deep and is driven in at 10 mm/s through its sleeve. Friction 10 N/m,
 * cutting force 0.2 N in every region, Newmark gamma 0.55 (docs/coupling.md). Columns: medians
 * per step of the whole step and of the stages (the paper's Table 2), the LCP trials (mean and
 * max, Table 3), the iterations per step, the tissue refactorizations in all, and the worst
 * inconsistency/unconverged counts. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "coupling.h"
#include "ns_config.h"
#include "scenario.h"
#include "step.h"

#define KINDS    2
#define PATH_CAP 256

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double median(const double *v, int n)
{
    double *c = malloc((size_t)n * sizeof *c);
    if (!c)
        return NAN;
    memcpy(c, v, (size_t)n * sizeof *c);
    qsort(c, (size_t)n, sizeof *c, cmp_double);
    double m = n % 2 ? c[n / 2] : 0.5 * (c[n / 2 - 1] + c[n / 2]);
    free(c);
    return m;
}

int main(int argc, char **argv)
{
    const char *path = NS_SOURCE_DIR "/scenarios/brachytherapy.lua";
    int steps = 60, threads = 1, remesh = 0;
    double dt = 5e-3;
    for (int a = 1; a < argc; a++) {
        if (strcmp(argv[a], "--steps") == 0 && a + 1 < argc)
            steps = atoi(argv[++a]);
        else if (strcmp(argv[a], "--dt") == 0 && a + 1 < argc)
            dt = atof(argv[++a]);
        else if (strcmp(argv[a], "--threads") == 0 && a + 1 < argc)
            threads = atoi(argv[++a]);
        else if (strcmp(argv[a], "--remesh") == 0)
            remesh = 1;
        else if (argv[a][0] != '-')
            path = argv[a];
        else {
            fprintf(stderr,
                    "usage: bench_coupling [SCENARIO.lua] [--steps N] [--dt S] [--threads N] "
                    "[--remesh]\n");
            return 2;
        }
    }
    if (steps < 1 || threads < 1 || !(dt > 0.0)) {
        fprintf(stderr, "bench_coupling: --steps, --dt and --threads must be positive\n");
        return 2;
    }
    NsScenario sc;
    char err[1024];
    if (ns_scenario_load(path, &sc, err, sizeof err)) {
        fprintf(stderr, "bench_coupling: %s\n", err);
        return 1;
    }
    /* The path, laid into the scenario's mesh before the tissues are made from it. */
    /* Lateral offsets tried in turn (the first line the mesh can take without inverting). */
    const double off[][2] = {{0.008, 0.0},   {-0.008, 0.0},   {0.010, -0.004}, {-0.010, -0.004},
                             {0.008, 0.004}, {-0.008, 0.004}, {0.012, 0.0},    {-0.012, 0.0}};
    int nodes[PATH_CAP], np = -1;
    double a[3] = {0}, b[3] = {0};
    for (size_t o = 0; o < sizeof off / sizeof off[0] && np < 3; o++) {
        a[0] = b[0] = off[o][0];
        a[1] = b[1] = off[o][1];
        a[2] = 0.0;
        b[2] = remesh ? 0.02 : 0.08; /* remesh: only the entry track is laid */
        np = ns_needle_path_lay(&sc.mesh, a, b, 0.75, nodes, PATH_CAP, err, sizeof err);
    }
    if (np < 3) {
        fprintf(stderr, "bench_coupling: laying the path: %s\n", np < 0 ? err : "too short");
        ns_scenario_free(&sc);
        return 1;
    }
    int tipn = 1;
    for (int i = 1; i < np; i++)
        if (fabs(sc.mesh.u[3 * nodes[i] + 2] - 0.03) < fabs(sc.mesh.u[3 * nodes[tipn] + 2] - 0.03))
            tipn = i;
    if (remesh) {
        tipn = np - 1; /* the tip at the track's end, the path ending there */
        np = tipn + 1;
    }
    const NsCoupledSolverKind kinds[KINDS] = {NS_COUPLED_SCHUR, NS_COUPLED_PAPER};
    NsTissueParams tp = ns_default_tissue_params();
    tp.gamma = 0.55;
    tp.beta = 0.25 * (tp.gamma + 0.5) * (tp.gamma + 0.5);
    tp.threads = threads;
    NsRodParams rp = ns_default_rod_params();
    rp.gamma = tp.gamma;
    rp.beta = tp.beta;
    NsCouplingParams cp = ns_default_coupling_params();
    cp.threads = threads;
    cp.remesh = remesh;
    for (int r = 0; r < NS_COUPLING_MAX_REGIONS; r++)
        cp.cut_force[r] = 0.2;
    NsTissue t[KINDS];
    NsRod rod[KINDS];
    NsCoupled c[KINDS];
    memset(t, 0, sizeof t);
    memset(rod, 0, sizeof rod);
    memset(c, 0, sizeof c);
    int rc = 1, made = 0;
    /* Per step and solver: total, tissue, needle, lcp, remesh, trials, iterations. */
    enum { SERIES = 7 };
    double *buf = malloc((size_t)SERIES * KINDS * steps * sizeof *buf);
    int refactors[KINDS] = {0}, incons[KINDS] = {0}, unconv[KINDS] = {0}, maxt[KINDS] = {0};
    int ops[KINDS][5] = {{0}};
    double dih[2] = {180.0, 0.0};
    double worst_tip = 0.0;
    if (!buf) {
        fprintf(stderr, "bench_coupling: out of memory\n");
        goto done;
    }
    for (int k = 0; k < KINDS; k++, made++) {
        if (ns_scenario_tissue(&sc, &tp, &t[k], err, sizeof err)) {
            fprintf(stderr, "bench_coupling: %s\n", err);
            goto done;
        }
        /* The needle: 4 edges of 5 mm outside (base held by the sleeve), then the path nodes
         * up to the tip. */
        int n = 4 + tipn + 1;
        double x[3 * (4 + PATH_CAP)];
        const double *u0 = t[k].mesh.x + 3 * nodes[0];
        for (int i = 0; i < 4; i++) {
            x[3 * i] = u0[0];
            x[3 * i + 1] = u0[1];
            x[3 * i + 2] = u0[2] - 0.005 * (4 - i);
        }
        for (int i = 0; i <= tipn; i++)
            memcpy(x + 3 * (4 + i), t[k].mesh.x + 3 * nodes[i], 3 * sizeof *x);
        double d1[3] = {1.0, 0.0, 0.0};
        if (ns_rod_init(&rod[k], x, n, d1, 2, &rp, err, sizeof err)) {
            fprintf(stderr, "bench_coupling: %s\n", err);
            ns_tissue_free(&t[k]);
            goto done;
        }
        NsNeedlePath p;
        double s = 0.0;
        for (int i = 1; i <= tipn; i++) {
            const double *p0 = t[k].mesh.u + 3 * nodes[i - 1], *p1 = t[k].mesh.u + 3 * nodes[i];
            s += sqrt((p1[0] - p0[0]) * (p1[0] - p0[0]) + (p1[1] - p0[1]) * (p1[1] - p0[1]) +
                      (p1[2] - p0[2]) * (p1[2] - p0[2]));
        }
        cp.solver = kinds[k];
        if (ns_needle_path_init(&p, &t[k].mesh, nodes, np, s, err, sizeof err) ||
            ns_coupled_init(&c[k], &t[k], &rod[k], &p, &cp, err, sizeof err)) {
            fprintf(stderr, "bench_coupling: %s\n", err);
            ns_rod_free(&rod[k]);
            ns_tissue_free(&t[k]);
            goto done;
        }
    }
    const double v_base[3] = {0, 0, 0};
    NsStepControls ctl = ns_step_controls(0.01, v_base, 0.0); /* in at 10 mm/s */
    printf("%s: %d tets, %d nodes; path of %d nodes laid along +z at x %.0f mm, y %.0f mm, tip "
           "starting %d nodes in; %d steps of %.0f ms at 10 mm/s, %d thread(s)\n",
           sc.name, sc.mesh.tet_alive, sc.mesh.node_alive, np, 1e3 * a[0], 1e3 * a[1], tipn, steps,
           1e3 * dt, threads);
    for (int i = 0; i < steps; i++) {
        for (int k = 0; k < KINDS; k++) {
            NsCouplingStats st;
            if (ns_step(&c[k], &ctl, dt, &st)) {
                fprintf(stderr, "bench_coupling: %s: step %d failed\n",
                        ns_coupled_solver_name(kinds[k]), i);
                goto done;
            }
            double *v = buf + (size_t)k * SERIES * steps;
            v[0 * steps + i] = st.total_ms;
            v[1 * steps + i] = st.tissue_ms;
            v[2 * steps + i] = st.needle_ms;
            v[3 * steps + i] = st.lcp_ms;
            v[4 * steps + i] = st.remesh_ms;
            v[5 * steps + i] = st.trials;
            v[6 * steps + i] = st.iterations;
            refactors[k] += st.refactors;
            incons[k] += !st.consistent;
            unconv[k] += st.unconverged;
            maxt[k] = st.trials > maxt[k] ? st.trials : maxt[k];
            ops[k][st.remesh_kind]++;
            if (remesh && k == 0) {
                dih[0] = st.min_dihedral_deg < dih[0] ? st.min_dihedral_deg : dih[0];
                dih[1] = st.max_dihedral_deg > dih[1] ? st.max_dihedral_deg : dih[1];
                char e2[256];
                if (ns_coupled_check_structure(&c[k], e2, sizeof e2))
                    fprintf(stderr, "bench_coupling: step %d: %s\n", i, e2);
            }
        }
        const double *xa = rod[0].x + 3 * (rod[0].nodes - 1),
                     *xb = rod[1].x + 3 * (rod[1].nodes - 1);
        double d = sqrt((xa[0] - xb[0]) * (xa[0] - xb[0]) + (xa[1] - xb[1]) * (xa[1] - xb[1]) +
                        (xa[2] - xb[2]) * (xa[2] - xb[2]));
        worst_tip = d > worst_tip ? d : worst_tip;
    }
    printf("%-7s %8s %8s %8s %8s %8s %7s %6s %8s %6s %6s %6s\n", "solver", "step ms", "tissue",
           "needle", "lcp", "remesh", "trials", "max", "iters", "refact", "incons", "unconv");
    double med[KINDS];
    for (int k = 0; k < KINDS; k++) {
        const double *v = buf + (size_t)k * SERIES * steps;
        double mean_t = 0.0;
        for (int i = 0; i < steps; i++)
            mean_t += v[5 * steps + i] / steps;
        med[k] = median(v, steps);
        printf("%-7s %8.2f %8.2f %8.2f %8.2f %8.2f %7.2f %6d %8.0f %6d %6d %6d\n",
               ns_coupled_solver_name(kinds[k]), med[k], median(v + steps, steps),
               median(v + 2 * steps, steps), median(v + 3 * steps, steps),
               median(v + 4 * steps, steps), mean_t, maxt[k], median(v + 6 * steps, steps),
               refactors[k], incons[k], unconv[k]);
    }
    printf("median step, paper / schur: %.2fx; tips differ by at most %.2e m; tip depth %.1f mm\n",
           med[1] / med[0], worst_tip, 1e3 * rod[0].x[3 * (rod[0].nodes - 1) + 2]);
    if (remesh)
        printf("remesh (schur run): %d none, %d snaps, %d edge, %d face, %d tet splits; dihedral "
               "angles near the needle in [%.1f, %.1f] deg\n",
               ops[0][0], ops[0][1], ops[0][2], ops[0][3], ops[0][4], dih[0], dih[1]);
    rc = 0;
done:
    for (int k = 0; k < made; k++) {
        ns_coupled_free(&c[k]);
        ns_rod_free(&rod[k]);
        ns_tissue_free(&t[k]);
    }
    free(buf);
    ns_scenario_free(&sc);
    return rc;
}
