/* needlesim bench --planning [--layouts N] [--seed S] [--json]
 *
 * Open loop against closed loop in the simulator (issue 36; docs/planning.md is the contract).
 * Each layout is assets/bench/planning_layout.lua with values drawn from the seed (plan/rng.h:
 * the same layouts on every machine): a target 45-58 mm ahead, off the axis by what 10-50% of the
 * model's curvature reaches; 0, 1 or 2 fixed obstacles (spheres, or cylinders across the block)
 * beside the model's direct arc; the gel's modulus scaled by 0.5-2. Each layout runs twice:
 * open loop (ns.plan once at the entry, its actions run unchanged) and closed loop (act.steer
 * with the RRT). A run succeeds when the tip ends within 2 mm of the target and no obstacle was
 * entered. */
#include <lauxlib.h>
#include <math.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "commands.h"
#include "coupling.h"
#include "data_dir.h"
#include "err.h"
#include "json.h"
#include "rng.h"
#include "run.h"

#define PLAN_BENCH_MAX_LAYOUTS 1000
#define PLAN_BENCH_SUCCESS_MM  2.0  /* the bar for one run [mm] */
#define LAYOUT_L               0.07 /* the layout's block [m] (planning_layout.lua) */
#define LAYOUT_W               0.03
#define LAYOUT_H               0.03
#define LAYOUT_KAPPA           5.7735 /* the model's curvature the targets are drawn with [1/m] */

static const char planning_usage[] =
    "usage: needlesim bench --planning [--layouts N] [--seed S] [--json]\n"
    "  --layouts N   generated layouts, 1..1000 (default 30); each runs open and closed loop\n"
    "  --seed S      the layouts' seed (default 1)\n"
    "  --json        one object on stdout (docs/planning.md)\n";

typedef struct Layout {
    char sets[24][64];
    int nsets;
    int obstacles;
    double stiffness;
} Layout;

typedef struct Outcome {
    double error_mm, clearance_mm; /* clearance: INFINITY without obstacles */
    bool entered, ok;
    int replans;
} Outcome;

static void add_set(Layout *l, const char *key, double v)
{
    snprintf(l->sets[l->nsets++], sizeof l->sets[0], "%s=%.9g", key, v);
}

/* Layout i of the seed: see the top of the file. */
static void make_layout(unsigned long long seed, int i, Layout *l)
{
    memset(l, 0, sizeof *l);
    NsPlanRng g = ns_plan_rng(seed * 1000003ull + (unsigned long long)i);
    l->stiffness = exp(ns_plan_rng_range(&g, log(0.5), log(2.0)));
    double tx = ns_plan_rng_range(&g, 0.045, 0.058);
    double frac = ns_plan_rng_range(&g, 0.1, 0.5), phi = ns_plan_rng_range(&g, 0.0, 2.0 * M_PI);
    double b = 0.5 * frac * LAYOUT_KAPPA * tx * tx; /* off the axis [m] */
    double cy = 0.5 * LAYOUT_W, cz = 0.5 * LAYOUT_H;
    add_set(l, "stiffness", l->stiffness);
    add_set(l, "tx", tx);
    add_set(l, "ty", cy + b * cos(phi));
    add_set(l, "tz", cz + b * sin(phi));
    l->obstacles = i % 3;
    add_set(l, "obstacles", l->obstacles);
    for (int k = 0; k < l->obstacles; k++) {
        /* beside the direct arc (a parabola b (x / tx)^2 to this accuracy) at 35-70% of the
         * way, its surface 1.5-3.5 mm from it */
        double x = tx * ns_plan_rng_range(&g, 0.35, 0.7), s = (x / tx) * (x / tx);
        double py = cy + b * s * cos(phi), pz = cz + b * s * sin(phi);
        int kind = (int)(ns_plan_rng_uniform(&g) * 3.0); /* sphere, cyl_y, cyl_z */
        double r =
            kind == 0 ? ns_plan_rng_range(&g, 0.003, 0.004) : ns_plan_rng_range(&g, 0.0025, 0.0035);
        double gap = r + ns_plan_rng_range(&g, 0.0015, 0.0035);
        double dir = ns_plan_rng_range(&g, 0.0, 2.0 * M_PI);
        /* a cylinder along y is moved off the arc in z, one along z in y */
        double oy = kind == 1 ? 0.0 : kind == 2 ? (cos(dir) < 0 ? -1.0 : 1.0) : cos(dir);
        double oz = kind == 2 ? 0.0 : kind == 1 ? (sin(dir) < 0 ? -1.0 : 1.0) : sin(dir);
        char key[32];
        snprintf(l->sets[l->nsets++], sizeof l->sets[0], "o%d_kind=%s", k + 1,
                 kind == 0   ? "sphere"
                 : kind == 1 ? "cyl_y"
                             : "cyl_z");
        snprintf(key, sizeof key, "o%d_x", k + 1);
        add_set(l, key, x);
        snprintf(key, sizeof key, "o%d_y", k + 1);
        add_set(l, key, py + gap * oy);
        snprintf(key, sizeof key, "o%d_z", k + 1);
        add_set(l, key, pz + gap * oz);
        snprintf(key, sizeof key, "o%d_r", k + 1);
        add_set(l, key, r);
    }
}

/* One run of the layout in mode "open" or "closed"; its planning times go to ms. */
static int run_layout(const char *file, const Layout *l, const char *mode, Outcome *out,
                      NsSeries *ms, char *err, int err_sz)
{
    NsRunOpts o;
    memset(&o, 0, sizeof o);
    o.scenario = file;
    o.threads = 1;
    o.solver = NS_COUPLED_SCHUR;
    o.quiet = true;
    o.no_render = true;
    char modeset[32];
    snprintf(modeset, sizeof modeset, "mode=%s", mode);
    for (int k = 0; k < l->nsets; k++)
        o.sets[o.nsets++] = l->sets[k];
    o.sets[o.nsets++] = modeset;
    NsRun r;
    int rc = ns_bench_run(&o, o.solver, false, &r, err, err_sz);
    if (rc == 0) {
        NsRunResults res;
        memset(&res, 0, sizeof res);
        if (ns_run_score(&r, &res) != 0) {
            ns_set_err(err, err_sz, "needlesim bench: scoring a layout failed");
            rc = -1;
        } else {
            out->error_mm = res.targets[0].error_mm;
            out->entered = false;
            for (int k = 0; k < r.spec.obstacle_count; k++)
                out->entered |= r.obst[k].violated;
            out->clearance_mm = 1e3 * r.steer.min_clear;
            out->entered |= out->clearance_mm < 0.0; /* the shape as written, not the tets */
            out->replans = r.steer.replans;
            out->ok = out->error_mm <= PLAN_BENCH_SUCCESS_MM && !out->entered;
            for (int k = 0; k < r.steer.ms.n && rc == 0; k++)
                if (ns_series_push(ms, r.steer.ms.v[k]) != 0)
                    rc = -1;
        }
        ns_run_results_free(&res);
    }
    ns_run_free(&r);
    return rc;
}

typedef struct Summary {
    double success_rate, mean_error_mm, min_clearance_mm, replans;
} Summary;

static Summary summarize(const Outcome *o, int n)
{
    Summary s = {0.0, 0.0, INFINITY, 0.0};
    for (int i = 0; i < n; i++) {
        s.success_rate += o[i].ok;
        s.mean_error_mm += o[i].error_mm;
        s.min_clearance_mm = fmin(s.min_clearance_mm, o[i].clearance_mm);
        s.replans += o[i].replans;
    }
    s.success_rate /= n;
    s.mean_error_mm /= n;
    s.replans /= n;
    return s;
}

static void summary_json(NsJson *j, const char *key, const Summary *s)
{
    ns_json_key(j, key);
    ns_json_begin_object(j);
    ns_json_key(j, "success_rate");
    ns_json_number(j, s->success_rate);
    ns_json_key(j, "mean_error_mm");
    ns_json_number(j, s->mean_error_mm);
    ns_json_key(j, "min_clearance_mm");
    if (isfinite(s->min_clearance_mm))
        ns_json_number(j, s->min_clearance_mm);
    else
        ns_json_null(j);
    ns_json_key(j, "replans");
    ns_json_number(j, s->replans);
    ns_json_end_object(j);
}

static void write_json(int n, unsigned long long seed, const Layout *lay, const Outcome *open,
                       const Outcome *closed, const NsSeries *ms)
{
    Summary so = summarize(open, n), sc = summarize(closed, n);
    NsJson j;
    ns_json_init(&j, stdout, 2);
    ns_json_begin_object(&j);
    ns_json_key(&j, "layouts");
    ns_json_int(&j, n);
    ns_json_key(&j, "seed");
    ns_json_int(&j, (long long)seed);
    ns_json_key(&j, "success_mm");
    ns_json_number(&j, PLAN_BENCH_SUCCESS_MM);
    summary_json(&j, "open_loop", &so);
    summary_json(&j, "closed_loop", &sc);
    ns_json_key(&j, "planning_ms");
    ns_json_begin_object(&j);
    ns_json_key(&j, "median");
    ns_json_number(&j, ns_series_quantile(ms, 0.5));
    ns_json_key(&j, "p95");
    ns_json_number(&j, ns_series_quantile(ms, 0.95));
    ns_json_end_object(&j);
    ns_json_key(&j, "runs");
    ns_json_begin_array(&j);
    for (int i = 0; i < n; i++) {
        ns_json_begin_object(&j);
        ns_json_key(&j, "stiffness");
        ns_json_number(&j, lay[i].stiffness);
        ns_json_key(&j, "obstacles");
        ns_json_int(&j, lay[i].obstacles);
        const Outcome *oc[2] = {&open[i], &closed[i]};
        for (int m = 0; m < 2; m++) {
            ns_json_key(&j, m ? "closed_error_mm" : "open_error_mm");
            ns_json_number(&j, oc[m]->error_mm);
            ns_json_key(&j, m ? "closed_ok" : "open_ok");
            ns_json_bool(&j, oc[m]->ok);
        }
        ns_json_end_object(&j);
    }
    ns_json_end_array(&j);
    ns_json_end_object(&j);
    fputc('\n', stdout);
}

static void print_table(int n, const Layout *lay, const Outcome *open, const Outcome *closed,
                        const NsSeries *ms)
{
    printf("%6s %6s %4s | %9s %9s %4s | %9s %9s %7s %4s\n", "layout", "stiff", "obst", "open mm",
           "clear mm", "ok", "closed mm", "clear mm", "replans", "ok");
    for (int i = 0; i < n; i++)
        printf("%6d %6.2f %4d | %9.3f %9.2f %4s | %9.3f %9.2f %7d %4s\n", i, lay[i].stiffness,
               lay[i].obstacles, open[i].error_mm, open[i].clearance_mm, open[i].ok ? "yes" : "no",
               closed[i].error_mm, closed[i].clearance_mm, closed[i].replans,
               closed[i].ok ? "yes" : "no");
    Summary so = summarize(open, n), sc = summarize(closed, n);
    printf("open loop:   success %.0f%%, mean error %.3f mm, least clearance %.2f mm\n",
           100.0 * so.success_rate, so.mean_error_mm, so.min_clearance_mm);
    printf("closed loop: success %.0f%%, mean error %.3f mm, least clearance %.2f mm, %.1f "
           "replans per layout\n",
           100.0 * sc.success_rate, sc.mean_error_mm, sc.min_clearance_mm, sc.replans);
    printf("planning time per replan: median %.2f ms, p95 %.2f ms (%d replans)\n",
           ns_series_quantile(ms, 0.5), ns_series_quantile(ms, 0.95), ms->n);
}

int ns_bench_planning(int argc, char **argv)
{
    int n = 30;
    unsigned long long seed = 1;
    bool json = false;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (strcmp(a, "--planning") == 0) {
            continue;
        } else if (strcmp(a, "--json") == 0) {
            json = true;
        } else if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            fputs(planning_usage, stdout);
            return 0;
        } else if ((strcmp(a, "--layouts") == 0 || strcmp(a, "--seed") == 0) && i + 1 < argc) {
            char *end;
            double v = strtod(argv[++i], &end);
            bool layouts = strcmp(a, "--layouts") == 0;
            if (*end != '\0' || v != floor(v) || v < (layouts ? 1 : 0) ||
                v > (layouts ? PLAN_BENCH_MAX_LAYOUTS : 1e15)) {
                fprintf(stderr,
                        "needlesim bench: %s must be an integer in %s (got '%s') (needlesim bench "
                        "--planning --help)\n",
                        a, layouts ? "1..1000" : "0..1e15", argv[i]);
                return 2;
            }
            if (layouts)
                n = (int)v;
            else
                seed = (unsigned long long)v;
        } else {
            fprintf(stderr, "needlesim bench --planning: unknown argument '%s'\n%s", a,
                    planning_usage);
            return 2;
        }
    }
    char file[4096];
    snprintf(file, sizeof file, "%s/bench/planning_layout.lua", ns_data_dir("assets"));
    Layout *lay = calloc((size_t)n, sizeof *lay);
    Outcome *open = calloc((size_t)n, sizeof *open), *closed = calloc((size_t)n, sizeof *closed);
    NsSeries ms = {0};
    int rc = lay && open && closed ? 0 : 1;
    if (rc)
        fprintf(stderr, "needlesim bench: out of memory\n");
    char err[1024];
    for (int i = 0; i < n && rc == 0; i++) {
        make_layout(seed, i, &lay[i]);
        if (!json)
            fprintf(stderr, "needlesim bench --planning: layout %d of %d\n", i + 1, n);
        if (run_layout(file, &lay[i], "open", &open[i], &ms, err, sizeof err) != 0 ||
            run_layout(file, &lay[i], "closed", &closed[i], &ms, err, sizeof err) != 0) {
            fprintf(stderr, "needlesim bench --planning: layout %d: %s\n", i, err);
            rc = 1;
        }
    }
    if (rc == 0) {
        if (json)
            write_json(n, seed, lay, open, closed, &ms);
        else
            print_table(n, lay, open, closed, &ms);
    }
    free(ms.v);
    free(lay);
    free(open);
    free(closed);
    return rc;
}
