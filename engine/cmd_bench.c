/* needlesim bench SCENARIO.lua [--steps N] [--solver NAME] [--threads N] [--compare NAME]
 *                              [--repeat N] [--json] [--snapshot]
 * The run's loop for a number of steps with the stage timings (the paper's Tables 2 and 3);
 * with --compare, both solvers in one process; with --snapshot, the cost of snapshotting the
 * world (sim/snapshot.h). */
#include "commands.h"
#include <errno.h>
#include <lauxlib.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "cleanup.h"
#include "control_log.h"
#include "coupling.h"
#include "err.h"
#include "json.h"
#include "snapshot.h"
#include "names.h"
#include "needle_path.h"
#include "ns_config.h"
#include "ns_limits.h"
#include "out_files.h"
#include "quality.h"
#include "remesh.h"
#include "rod.h"
#include "run.h"

/* ---- needlesim bench ---- */

static const char bench_usage[] =
    "usage: needlesim bench SCENARIO.lua [--steps N] [--solver NAME] [--threads N]\n"
    "                       [--set KEY=VALUE]... [--compare NAME] [--repeat N] [--json]\n"
    "                       [--snapshot]\n"
    "       needlesim bench --live SCENARIO.lua [--seconds S] [--json] (a live session)\n"
    "       needlesim bench --dose [--repeat N] [--threads N] [--json] (TG-43 dose grid)\n"
    "       needlesim bench --planning [--layouts N] [--seed S] [--json] (open against closed\n"
    "                       loop steering over generated layouts: docs/planning.md)\n";

#define BENCH_MAX_REPEAT 100

/* Median, min and max of v[0 .. n) (n >= 1; v is sorted in place). */
static void median_range(double *v, int n, double *med, double *lo, double *hi)
{
    for (int i = 1; i < n; i++) /* insertion sort: n is small */
        for (int k = i; k > 0 && v[k - 1] > v[k]; k--) {
            double t = v[k];
            v[k] = v[k - 1];
            v[k - 1] = t;
        }
    *med = n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
    *lo = v[0];
    *hi = v[n - 1];
}

static void bench_stats_json(NsJson *j, const NsRun *r)
{
    ns_run_timing_json(j, r);
    ns_run_stats_object(j, "lcp_trials", &r->trials);
    ns_run_stats_object(j, "cg_iterations", &r->iterations);
    ns_json_key(j, "factorizations");
    ns_json_int(j, r->factorizations);
}

/* One bench run of o's scenario with the given solver into r (initialised here; commands.h). */
int ns_bench_run(const NsRunOpts *o, int solver, bool log_tips, NsRun *r, char *err, int err_sz)
{
    memset(r, 0, sizeof *r);
    r->sim_ref = r->act_ref = r->co_ref = LUA_NOREF;
    r->opt = *o;
    r->opt.solver = solver;
    r->log_tips = log_tips;
    int rc = -1;
    if (ns_scenario_load_set(o->scenario, o->sets, o->nsets, &r->sc, err, err_sz) == 0) {
        r->have_sc = true;
        if (ns_run_spec_read(&r->sc, &r->spec, err, err_sz) == 0) {
            r->have_spec = true;
            rc = 0;
        }
    }
    r->stop_when_done = rc == 0 && r->spec.has_script; /* a script's end ends a bench early */
    rc = rc ? rc : ns_run_script_start(r, err, err_sz);
    rc = rc ? rc : ns_run_build(r, err, err_sz);
    rc = rc ? rc : ns_run_loop(r, err, err_sz);
    if (rc == 0 && r->steps == 0) {
        ns_set_err(err, err_sz, "%s: the script ended before the first step: nothing to time",
                   r->sc.path);
        rc = -1;
    }
    return rc;
}

static void bench_table(const NsRun *r)
{
    double lo, mean, hi, ilo, imean, ihi;
    ns_series_range(&r->trials, &lo, &mean, &hi);
    ns_series_range(&r->iterations, &ilo, &imean, &ihi);
    printf("%s: %d tets, %d nodes; solver %s, %d thread(s), %ld steps of %g ms\n", r->sc.name,
           r->tissue.mesh.tet_alive, r->tissue.mesh.node_alive,
           ns_coupled_solver_name((NsCoupledSolverKind)r->opt.solver), r->opt.threads, r->steps,
           1e3 * r->spec.dt);
    printf("median ms per step (the paper's Table 2):\n");
    printf("  %8s %8s %8s %8s %8s\n", "Total", "LCP", "Tissue", "Needle", "Remesh");
    printf("  %8.2f %8.2f %8.2f %8.2f %8.2f\n", ns_series_quantile(&r->total_ms, 0.5),
           ns_series_quantile(&r->lcp_ms, 0.5), ns_series_quantile(&r->tissue_ms, 0.5),
           ns_series_quantile(&r->needle_ms, 0.5), ns_series_quantile(&r->remesh_ms, 0.5));
    printf("  %8.2f %8.2f %8.2f %8.2f %8.2f  (means)\n", ns_series_mean(&r->total_ms),
           ns_series_mean(&r->lcp_ms), ns_series_mean(&r->tissue_ms), ns_series_mean(&r->needle_ms),
           ns_series_mean(&r->remesh_ms));
    printf("step wall time: median %.2f ms, mean %.2f ms, p95 %.2f ms, max %.2f ms\n",
           ns_series_quantile(&r->step_ms, 0.5), ns_series_mean(&r->step_ms),
           ns_series_quantile(&r->step_ms, 0.95), ns_series_quantile(&r->step_ms, 1.0));
    printf("per step (the paper's Table 3): LCP trials %.0f / %.2f / %.0f, CG iterations "
           "%.0f / %.1f / %.0f (min / mean / max); tissue factorizations %ld in all\n",
           lo, mean, hi, ilo, imean, ihi, r->factorizations);
}

static void bench_json_fields(NsJson *j, const NsRun *r)
{
    ns_json_key(j, "steps");
    ns_json_int(j, r->steps);
    ns_json_key(j, "tets");
    ns_json_int(j, r->tissue.mesh.tet_alive);
    ns_json_key(j, "nodes");
    ns_json_int(j, r->tissue.mesh.node_alive);
    bench_stats_json(j, r);
}

/* The largest distance between the two runs' tips over the steps both made [m]; *steps the
 * number compared. */
static double tip_difference(const NsRun *a, const NsRun *b, long *steps)
{
    long n = a->tips[0].n < b->tips[0].n ? a->tips[0].n : b->tips[0].n;
    double worst = 0.0;
    for (long k = 0; k < n; k++) {
        double d2 = 0.0;
        for (int i = 0; i < 3; i++) {
            double d = a->tips[i].v[k] - b->tips[i].v[k];
            d2 += d * d;
        }
        double d = sqrt(d2);
        if (!(d <= worst)) /* a NaN counts as a disagreement */
            worst = isnan(d) ? INFINITY : d;
    }
    *steps = n;
    return worst;
}

/* needlesim bench SCENARIO.lua: the scenario's script for --steps steps (default 200, fewer if
 * the script ends first), nothing written; the per-stage medians in the form of the paper's
 * Table 2 (Total, LCP, Tissue, Needle, Remesh), the LCP trials and CG iterations of its Table 3
 * and the tissue factorizations over the run. With --compare paper the same run again with the
 * paper's solver, in this process: both tables, the ratios of their median and of their mean
 * step times (the whole run's), and whether the two tips stayed within 0.05 mm of each other at
 * every step (exit 1 if not). --repeat N does all of it N times (the solvers alternating) and
 * adds the median, min and max over the repeats of each solver's median step and of the two
 * ratios; the tables and ratios printed with them are the last repeat's. */
/* What bench's command line asks beyond a run's options. */
typedef struct BenchArgs {
    bool json;
    bool snapshot; /* --snapshot: measure the world's in-memory snapshot and restore at the end */
    int compare;   /* the solver to compare with, or -1 */
    int repeat;
} BenchArgs;

/* Parses bench's command line into o and b. Returns -1 to go on, else the exit status (0 after
 * --help, 2 for a bad command line, with one line on stderr). */
static int parse_bench(int argc, char **argv, NsRunOpts *o, BenchArgs *b)
{
    b->json = false;
    b->snapshot = false;
    b->compare = -1;
    b->repeat = 1;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            fputs(bench_usage, stdout);
            return 0; /* --help */
        } else if (strcmp(a, "--json") == 0) {
            b->json = true;
        } else if (strcmp(a, "--snapshot") == 0) {
            b->snapshot = true;
        } else if (strcmp(a, "--steps") == 0 || strcmp(a, "--threads") == 0 ||
                   strcmp(a, "--solver") == 0 || strcmp(a, "--set") == 0 ||
                   strcmp(a, "--compare") == 0 || strcmp(a, "--repeat") == 0) {
            if (!v) {
                fprintf(stderr, "needlesim bench: %s needs a value (needlesim bench --help)\n", a);
                return 2;
            }
            i++;
            char *end;
            if (strcmp(a, "--solver") == 0 || strcmp(a, "--compare") == 0) {
                int k = ns_coupled_solver_parse(v);
                if (k < 0) {
                    fprintf(stderr,
                            "needlesim bench: %s '%s': unknown solver (schur or "
                            "paper)\n",
                            a, v);
                    return 2;
                }
                if (strcmp(a, "--solver") == 0)
                    o->solver = k;
                else
                    b->compare = k;
            } else if (strcmp(a, "--set") == 0) {
                if (!strchr(v, '=') || v[0] == '=' || o->nsets == 32) {
                    fprintf(stderr,
                            "needlesim bench: --set '%s': expected KEY=VALUE (needlesim bench "
                            "--help)\n",
                            v);
                    return 2;
                }
                o->sets[o->nsets++] = v;
            } else {
                long n = strtol(v, &end, 10);
                long most = strcmp(a, "--threads") == 0  ? 64
                            : strcmp(a, "--repeat") == 0 ? BENCH_MAX_REPEAT
                                                         : 1000000;
                if (*end || n < 1 || n > most) {
                    fprintf(stderr,
                            "needlesim bench: %s: expected an integer in [1, %ld] (needlesim bench "
                            "--help)\n",
                            a, most);
                    return 2;
                }
                if (strcmp(a, "--steps") == 0)
                    o->steps = n;
                else if (strcmp(a, "--repeat") == 0)
                    b->repeat = (int)n;
                else
                    o->threads = (int)n;
            }
        } else if (a[0] == '-' && a[1] != '\0') {
            fprintf(stderr, "needlesim bench: unknown option '%s' (needlesim bench --help)\n", a);
            return 2;
        } else if (!o->scenario) {
            o->scenario = a;
        } else {
            fprintf(stderr,
                    "needlesim bench: one scenario only (got '%s' too) (needlesim bench --help)\n",
                    a);
            return 2;
        }
    }
    if (!o->scenario) {
        fprintf(stderr, "needlesim bench: missing SCENARIO.lua (needlesim bench --help)\n");
        return 2;
    }
    if (b->compare >= 0 && b->compare == o->solver) {
        fprintf(stderr, "needlesim bench: --compare %s: the same solver as the run's\n",
                ns_coupled_solver_name((NsCoupledSolverKind)b->compare));
        return 2;
    }
    return -1;
}

/* --snapshot: the cost of an in-memory snapshot of the world at the run's end and of restoring
 * it (sim/snapshot.h; what a planner pays per rollout), medians of SNAPSHOT_REPEAT of each; a
 * restored world must snapshot to the same bytes. */
#define SNAPSHOT_REPEAT 9
typedef struct SnapshotCost {
    double bytes, snapshot_ms, restore_ms;
    bool same;
} SnapshotCost;

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static int snapshot_cost(NsRun *r, SnapshotCost *out, char *err, int err_sz)
{
    double ts[SNAPSHOT_REPEAT], tr[SNAPSHOT_REPEAT];
    NsWorldSnapshot s = {0};
    out->same = true;
    for (int k = 0; k < SNAPSHOT_REPEAT; k++) {
        ns_world_snapshot_free(&s);
        double t0 = ns_wall_s();
        if (ns_world_snapshot(&r->tissue, &r->rod, &r->c, &s, err, err_sz))
            return -1;
        double t1 = ns_wall_s();
        NsTissue t;
        NsRod rod;
        NsCoupled c;
        int rc = ns_world_restore(&s, &t, &rod, &c, err, err_sz);
        double t2 = ns_wall_s();
        NsWorldSnapshot again = {0};
        if (rc == 0 && k == 0) { /* the restored world is the same world */
            rc = ns_world_snapshot(&t, &rod, &c, &again, err, err_sz);
            out->same = rc == 0 && again.len == s.len && memcmp(again.bytes, s.bytes, s.len) == 0;
            ns_world_snapshot_free(&again);
        }
        ns_coupled_free(&c);
        ns_rod_free(&rod);
        ns_tissue_free(&t);
        if (rc) {
            ns_world_snapshot_free(&s);
            return -1;
        }
        ts[k] = 1e3 * (t1 - t0);
        tr[k] = 1e3 * (t2 - t1);
    }
    out->bytes = (double)s.len;
    ns_world_snapshot_free(&s);
    qsort(ts, SNAPSHOT_REPEAT, sizeof *ts, cmp_double);
    qsort(tr, SNAPSHOT_REPEAT, sizeof *tr, cmp_double);
    out->snapshot_ms = ts[SNAPSHOT_REPEAT / 2];
    out->restore_ms = tr[SNAPSHOT_REPEAT / 2];
    return 0;
}

/* What bench prints: the last repeat's runs and the figures over the repeats. */
typedef struct BenchOut {
    const NsRunOpts *o;
    const NsRun *runs; /* (nruns) */
    int nruns, compare, repeat, done;
    double speedup, speedup_mean, diff; /* the last repeat's ratios; the worst tip difference */
    bool agree;
    long compared;                  /* the steps compared in the last repeat */
    double rmed[4], rlo[4], rhi[4]; /* ours, compared, ratio, ratio of means */
    const SnapshotCost *snap;       /* --snapshot, else NULL */
} BenchOut;

static void bench_print_json(const BenchOut *b)
{
    const NsRun *r = &b->runs[0];
    NsJson j;
    ns_json_init(&j, stdout, 1);
    ns_json_begin_object(&j);
    ns_json_key(&j, "scenario");
    ns_json_string(&j, r->sc.name);
    ns_json_key(&j, "solver");
    ns_json_string(&j, ns_coupled_solver_name((NsCoupledSolverKind)b->o->solver));
    ns_json_key(&j, "threads");
    ns_json_int(&j, b->o->threads);
    bench_json_fields(&j, r);
    if (b->nruns == 2) {
        for (int k = 0; k < 2; k++) {
            ns_json_key(&j, ns_coupled_solver_name((NsCoupledSolverKind)b->runs[k].opt.solver));
            ns_json_begin_object(&j);
            bench_json_fields(&j, &b->runs[k]);
            ns_json_end_object(&j);
        }
        ns_json_key(&j, "speedup");
        ns_json_number(&j, b->speedup);
        ns_json_key(&j, "speedup_mean");
        ns_json_number(&j, b->speedup_mean);
        ns_json_key(&j, "max_tip_difference_m");
        ns_json_number(&j, b->diff);
        ns_json_key(&j, "agree");
        ns_json_bool(&j, b->agree);
    }
    if (b->repeat > 1) { /* medians of the per-repeat medians, and their range */
        ns_json_key(&j, "repeat");
        ns_json_begin_object(&j);
        ns_json_key(&j, "runs");
        ns_json_int(&j, b->done);
        static const char *const what[4] = {"step_ms", "compared_step_ms", "speedup",
                                            "speedup_mean"};
        for (int k = 0; k < 4; k++) {
            if (k > 0 && b->nruns == 1)
                break;
            ns_json_key(&j, what[k]);
            ns_json_begin_object(&j);
            ns_json_key(&j, "median");
            ns_json_number(&j, b->rmed[k]);
            ns_json_key(&j, "min");
            ns_json_number(&j, b->rlo[k]);
            ns_json_key(&j, "max");
            ns_json_number(&j, b->rhi[k]);
            ns_json_end_object(&j);
        }
        ns_json_end_object(&j);
    }
    if (b->snap) {
        ns_json_key(&j, "snapshot");
        ns_json_begin_object(&j);
        ns_json_key(&j, "bytes");
        ns_json_number(&j, b->snap->bytes);
        ns_json_key(&j, "snapshot_ms");
        ns_json_number(&j, b->snap->snapshot_ms);
        ns_json_key(&j, "restore_ms");
        ns_json_number(&j, b->snap->restore_ms);
        ns_json_key(&j, "restored_same");
        ns_json_bool(&j, b->snap->same);
        ns_json_end_object(&j);
    }
    ns_json_end_object(&j);
    fputc('\n', stdout);
}

static void bench_print_text(const BenchOut *b)
{
    for (int k = 0; k < b->nruns; k++) {
        if (k)
            printf("\n");
        bench_table(&b->runs[k]);
    }
    if (b->nruns == 2)
        printf("\nspeed-up (median step of %s / median step of %s): %.2fx; tips within %.4f mm "
               "over %ld "
               "steps (want <= 0.05 mm)\n",
               ns_coupled_solver_name((NsCoupledSolverKind)b->compare),
               ns_coupled_solver_name((NsCoupledSolverKind)b->o->solver), b->speedup, 1e3 * b->diff,
               b->compared);
    if (b->nruns == 2) /* the refactorizations and slow steps the medians leave out */
        printf("whole run (mean step of %s / mean step of %s): %.2fx\n",
               ns_coupled_solver_name((NsCoupledSolverKind)b->compare),
               ns_coupled_solver_name((NsCoupledSolverKind)b->o->solver), b->speedup_mean);
    if (b->repeat > 1) {
        printf("\nover %d repeats (median step, ms: median [min, max]):\n", b->done);
        for (int k = 0; k < b->nruns; k++)
            printf("  %-6s %8.2f [%.2f, %.2f]\n",
                   ns_coupled_solver_name((NsCoupledSolverKind)b->runs[k].opt.solver), b->rmed[k],
                   b->rlo[k], b->rhi[k]);
        if (b->nruns == 2)
            printf("  speed-up %.2fx [%.2f, %.2f]; whole run (mean steps) %.2fx [%.2f, %.2f]\n",
                   b->rmed[2], b->rlo[2], b->rhi[2], b->rmed[3], b->rlo[3], b->rhi[3]);
    }
    if (b->snap)
        printf(
            "\nworld snapshot at step %ld (in memory, medians of %d): %.1f MB, snapshot %.2f ms, "
            "restore %.2f ms; the restored world %s\n",
            b->runs[0].steps, SNAPSHOT_REPEAT, 1e-6 * b->snap->bytes, b->snap->snapshot_ms,
            b->snap->restore_ms,
            b->snap->same ? "snapshots to the same bytes" : "DIFFERS from the original");
}

int ns_cmd_bench(int argc, char **argv)
{
    for (int i = 1; i < argc; i++)
        if (strcmp(argv[i], "--live") == 0)
            return ns_bench_live(argc, argv);
    for (int i = 1; i < argc; i++)
        if (strcmp(argv[i], "--dose") == 0)
            return ns_bench_dose(argc, argv);
    for (int i = 1; i < argc; i++)
        if (strcmp(argv[i], "--planning") == 0)
            return ns_bench_planning(argc, argv);
    NsRunOpts o;
    memset(&o, 0, sizeof o);
    o.threads = 1;
    o.solver = NS_COUPLED_SCHUR;
    o.quiet = true;
    o.no_render = true;
    BenchArgs args;
    int pa = parse_bench(argc, argv, &o, &args);
    if (pa >= 0)
        return pa;
    bool json = args.json;
    int compare = args.compare, repeat = args.repeat;
    if (o.steps == 0)
        o.steps = 200;
    char err[1024] = "";
    NsRun runs[2];
    int nruns = compare >= 0 ? 2 : 1, rc = 0, made = 0, done = 0;
    double meds[2][BENCH_MAX_REPEAT], ratios[BENCH_MAX_REPEAT], worst = 0.0;
    double ratios_mean[BENCH_MAX_REPEAT]; /* the whole runs': mean steps */
    bool all_agree = true;
    for (int rep = 0; rep < repeat && rc == 0; rep++) {
        if (rep > 0) { /* the last repeat's runs are kept for the tables */
            for (int k = 0; k < nruns; k++)
                ns_run_free(&runs[k]);
            made = 0;
        }
        if (repeat > 1 && !json)
            fprintf(stderr, "needlesim bench: repeat %d of %d\n", rep + 1, repeat);
        for (int k = 0; k < nruns && rc == 0; k++) {
            rc = ns_bench_run(&o, k ? compare : o.solver, nruns == 2, &runs[k], err, sizeof err);
            if (rc && nruns == 2) { /* say which of the two failed: err gets a prefix */
                char pre[64];
                int np =
                    snprintf(pre, sizeof pre,
                             "with --solver %s: ", ns_coupled_solver_name(k ? compare : o.solver));
                size_t ne = strlen(err);
                if (np > 0 && (size_t)np < sizeof pre) {
                    if ((size_t)np + ne >= sizeof err)
                        ne = sizeof err - 1 - (size_t)np;
                    memmove(err + np, err, ne);
                    memcpy(err, pre, (size_t)np);
                    err[(size_t)np + ne] = '\0';
                }
            }
            made = k + 1;
        }
        if (rc == 0) {
            long cmp_n = 0;
            double d = nruns == 2 ? tip_difference(&runs[0], &runs[1], &cmp_n) : 0.0;
            worst = d > worst || isnan(d) ? d : worst;
            all_agree =
                all_agree && (nruns == 1 || (d <= 0.05e-3 && runs[0].steps == runs[1].steps));
            for (int k = 0; k < nruns; k++)
                meds[k][rep] = ns_series_quantile(&runs[k].step_ms, 0.5);
            ratios[rep] = nruns == 2 ? meds[1][rep] / fmax(meds[0][rep], 1e-12) : 1.0;
            ratios_mean[rep] = nruns == 2 ? ns_series_mean(&runs[1].step_ms) /
                                                fmax(ns_series_mean(&runs[0].step_ms), 1e-12)
                                          : 1.0;
            done = rep + 1;
        }
    }
    if (rc) {
        size_t n = strlen(o.scenario);
        bool located = strncmp(err, "needlesim", 9) == 0 || strncmp(err, o.scenario, n) == 0;
        ns_one_line(err);
        fprintf(stderr, "%s%s\n", located ? "" : "needlesim: ", err);
        for (int k = 0; k < made; k++)
            ns_run_free(&runs[k]);
        return 1;
    }
    long compared = 0; /* the steps compared in the last repeat */
    if (nruns == 2)
        tip_difference(&runs[0], &runs[1], &compared);
    bool agree = all_agree;
    double diff = worst;                              /* over every repeat */
    double rmed[4] = {0}, rlo[4] = {0}, rhi[4] = {0}; /* ours, compared, ratio, ratio of means */
    /* the last repeat's ratios, read before median_range sorts the arrays in place */
    double speedup = ratios[done - 1], speedup_mean = ratios_mean[done - 1];
    for (int k = 0; k < nruns; k++)
        median_range(meds[k], done, &rmed[k], &rlo[k], &rhi[k]);
    median_range(ratios, done, &rmed[2], &rlo[2], &rhi[2]);
    median_range(ratios_mean, done, &rmed[3], &rlo[3], &rhi[3]);
    SnapshotCost snap = {0};
    if (args.snapshot && snapshot_cost(&runs[0], &snap, err, sizeof err)) {
        fprintf(stderr, "needlesim bench: --snapshot: %s\n", err);
        for (int k = 0; k < nruns; k++)
            ns_run_free(&runs[k]);
        return 1;
    }
    BenchOut out = {&o,   runs,  nruns,    compare, repeat, done, speedup, speedup_mean,
                    diff, agree, compared, {0},     {0},    {0},  NULL};
    out.snap = args.snapshot ? &snap : NULL;
    memcpy(out.rmed, rmed, sizeof rmed);
    memcpy(out.rlo, rlo, sizeof rlo);
    memcpy(out.rhi, rhi, sizeof rhi);
    if (json)
        bench_print_json(&out);
    else
        bench_print_text(&out);
    if (!agree)
        fprintf(stderr,
                "needlesim bench: the two solvers' tips differ by %.4f mm (%ld and %ld steps): "
                "more than 0.05 mm\n",
                1e3 * diff, runs[0].steps, runs[1].steps);
    for (int k = 0; k < nruns; k++)
        ns_run_free(&runs[k]);
    return agree && (!args.snapshot || snap.same) ? 0 : 1;
}
