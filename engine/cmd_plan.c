/* needlesim plan SCENARIO.lua --target NAME [--json] [-o DIR] [--clearance M]
 *                             [--method rrt|helix] [--seed N]
 *
 * Plans a bevel-tip insertion from the scenario's entry to one of its targets on the kinematic
 * model (plan/kinematic.h) with curvature k_c tan(psi) (the arc model's, docs/needle.md), around
 * the scenario's obstacles, and prints the plan's predicted error, least clearance, length and
 * planning time: a few lines for people, or with --json one object. -o DIR writes DIR/plan.json
 * (the same object) and DIR/path.csv (its path, for `run --plan DIR`), through temporary files
 * renamed into place. Exit 0 when the plan reaches
 * the target within its tolerance and keeps the clearance, 1 when it does not or the input is
 * bad (one line on stderr), 2 for a bad command line. docs/planning.md is the contract. */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#include "commands.h"
#include "json.h"
#include "mesh.h"
#include "ns_config.h"
#include "obstacle.h"
#include "out_files.h"
#include "path.h"
#include "plan_obs.h"
#include "plan_path_csv.h"
#include "rrt.h"
#include "run_spec.h"
#include "scenario.h"
#include "shape.h"
#include "steer.h"

static const char plan_usage[] =
    "usage: needlesim plan SCENARIO.lua --target NAME [--json] [-o DIR] [--clearance M]\n"
    "                      [--method rrt|helix] [--seed N]\n"
    "  --target NAME   the scenario's target to reach\n"
    "  --json          one JSON object on stdout (docs/planning.md)\n"
    "  -o DIR          write DIR/plan.json\n"
    "  --clearance M   least distance from the needle's axis to an obstacle [m] (default 0.001)\n"
    "  --method NAME   rrt (default: around the obstacles) or helix (the closed-loop controller\n"
    "                  run on the model; it does not see the obstacles)\n"
    "  --seed N        the RRT's seed (default 1)\n";

#define PLAN_PATH_STEP 1e-3 /* spacing of the printed path's points [m] */

typedef struct PlanOpt {
    const char *scenario, *target, *out_dir, *method;
    bool json;
    double clearance; /* [m] */
    unsigned long long seed;
} PlanOpt;

static int usage_error(const char *fmt, const char *arg)
{
    fputs("needlesim plan: ", stderr);
    fprintf(stderr, fmt, arg);
    fputs(" (needlesim plan --help)\n", stderr);
    return 2;
}

static int parse_args(int argc, char **argv, PlanOpt *o)
{
    memset(o, 0, sizeof *o);
    o->clearance = 1e-3;
    o->method = "rrt";
    o->seed = 1;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        bool has_value = i + 1 < argc;
        if (strcmp(a, "--json") == 0) {
            o->json = true;
        } else if (strcmp(a, "--target") == 0 || strcmp(a, "-o") == 0 ||
                   strcmp(a, "--method") == 0 || strcmp(a, "--clearance") == 0 ||
                   strcmp(a, "--seed") == 0) {
            if (!has_value)
                return usage_error("%s needs a value", a);
            const char *v = argv[++i];
            char *end;
            if (strcmp(a, "--target") == 0) {
                o->target = v;
            } else if (strcmp(a, "-o") == 0) {
                if (!v[0])
                    return usage_error("%s: the output folder must be named", a);
                o->out_dir = v;
            } else if (strcmp(a, "--method") == 0) {
                if (strcmp(v, "rrt") != 0 && strcmp(v, "helix") != 0)
                    return usage_error("--method must be rrt or helix, not '%s'", v);
                o->method = v;
            } else if (strcmp(a, "--clearance") == 0) {
                errno = 0;
                o->clearance = strtod(v, &end);
                if (errno || end == v || *end || !(o->clearance >= 0.0) || o->clearance > 0.1)
                    return usage_error("--clearance must be a number of metres in [0, 0.1], not "
                                       "'%s'",
                                       v);
            } else {
                errno = 0;
                o->seed = strtoull(v, &end, 10);
                if (errno || end == v || *end || v[0] == '-')
                    return usage_error("--seed must be a whole number >= 0, not '%s'", v);
            }
        } else if (a[0] == '-' && a[1]) {
            return usage_error("unknown option '%s'", a);
        } else if (!o->scenario) {
            o->scenario = a;
        } else {
            return usage_error("one scenario only ('%s' is a second)", a);
        }
    }
    if (!o->scenario)
        return usage_error("%s", "no scenario given");
    if (!o->target)
        return usage_error("%s", "--target NAME is required");
    return 0;
}

typedef struct PlanResult {
    NsPlanPath path;
    double ms, kappa;
    int nodes; /* RRT nodes (0 for helix) */
    const NsRunTarget *target;
    bool ok;
} PlanResult;

static double now_ms(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return 1e3 * (double)t.tv_sec + 1e-6 * (double)t.tv_nsec;
}

static int plan(const PlanOpt *opt, const NsScenario *sc, const NsPlanObs *po,
                const NsPlanPose *start, PlanResult *res, char *err, int err_sz)
{
    const NsRunTarget *tg = res->target;
    int rc;
    double t0 = now_ms();
    if (strcmp(opt->method, "rrt") == 0) {
        double lo[3], hi[3];
        ns_plan_mesh_box(&sc->mesh, -1, lo, hi);
        NsRrtParams prm = ns_rrt_default(res->kappa, lo, hi);
        prm.clearance = opt->clearance;
        prm.tolerance = tg->tolerance;
        prm.seed = opt->seed;
        NsRrtStats st = {0};
        rc = ns_rrt_plan(&prm, po->obs, po->count, start, tg->at, &res->path, &st, err, err_sz);
        res->nodes = st.nodes;
    } else {
        NsSteerParams prm = ns_steer_default(res->kappa);
        double reach = 0.0;
        for (int k = 0; k < 3; k++)
            reach += (tg->at[k] - start->p[k]) * (tg->at[k] - start->p[k]);
        NsSteerLoop loop = {1e-3, 2.0 * sqrt(reach) + 1e-3, res->kappa, tg->at, NULL, NULL, false};
        rc = ns_steer_rollout(&prm, &loop, start, &res->path, err, err_sz) == 0 ? 0 : -1;
        if (rc == 0)
            res->path.clearance = ns_plan_path_clearance(&res->path, po->obs, po->count, 0.25e-3);
    }
    res->ms = now_ms() - t0;
    if (rc != 0) {
        char tmp[512];
        snprintf(tmp, sizeof tmp, "%.500s", err);
        snprintf(err, (size_t)err_sz, "%s: target '%s': %s", sc->path, tg->name, tmp);
        return rc;
    }
    res->ok = res->path.error <= tg->tolerance && res->path.clearance >= opt->clearance;
    return 0;
}

static void write_json(FILE *f, const PlanOpt *opt, const NsScenario *sc, const NsPlanObs *po,
                       const PlanResult *res, const double *xyz, int npts)
{
    NsJson j;
    ns_json_init(&j, f, 1);
    ns_json_begin_object(&j);
    ns_json_key(&j, "scenario");
    ns_json_string(&j, sc->name);
    ns_json_key(&j, "version");
    ns_json_string(&j, NS_VERSION);
    ns_json_key(&j, "target");
    ns_json_string(&j, res->target->name);
    ns_json_key(&j, "method");
    ns_json_string(&j, opt->method);
    ns_json_key(&j, "ok");
    ns_json_bool(&j, res->ok);
    ns_json_key(&j, "error_mm");
    ns_json_number(&j, 1e3 * res->path.error);
    ns_json_key(&j, "tolerance_mm");
    ns_json_number(&j, 1e3 * res->target->tolerance);
    ns_json_key(&j, "clearance_mm");
    ns_json_number(&j, 1e3 * res->path.clearance);
    ns_json_key(&j, "requested_clearance_mm");
    ns_json_number(&j, 1e3 * opt->clearance);
    ns_json_key(&j, "length_mm");
    ns_json_number(&j, 1e3 * res->path.length);
    ns_json_key(&j, "planning_ms");
    ns_json_number(&j, res->ms);
    ns_json_key(&j, "kappa_per_m");
    ns_json_number(&j, res->kappa);
    ns_json_key(&j, "seed");
    ns_json_int(&j, (long long)opt->seed);
    ns_json_key(&j, "nodes");
    ns_json_int(&j, res->nodes);
    ns_json_key(&j, "obstacles");
    ns_json_begin_array(&j);
    for (int i = 0; i < po->count; i++) {
        ns_json_begin_object(&j);
        ns_json_key(&j, "name");
        ns_json_string(&j, po->obs[i].name);
        ns_json_key(&j, "geometry");
        ns_json_string(&j, po->obs[i].kind == NS_PLAN_SHAPE ? "shape" : "bounding_box");
        ns_json_end_object(&j);
    }
    ns_json_end_array(&j);
    ns_json_key(&j, "path");
    ns_json_begin_array(&j);
    for (int i = 0; i < npts; i++) {
        ns_json_begin_array(&j);
        for (int k = 0; k < 3; k++)
            ns_json_number(&j, xyz[3 * i + k]);
        ns_json_end_array(&j);
    }
    ns_json_end_array(&j);
    ns_json_key(&j, "actions");
    ns_json_begin_array(&j);
    for (int i = 0; i < res->path.action_count; i++) {
        const NsPlanAction *a = &res->path.actions[i];
        ns_json_begin_object(&j);
        ns_json_key(&j, "twist_rad");
        ns_json_number(&j, a->twist);
        ns_json_key(&j, "insert_mm");
        ns_json_number(&j, 1e3 * a->length);
        ns_json_key(&j, "duty");
        ns_json_number(&j, a->duty);
        ns_json_key(&j, "rate_rad_per_m");
        ns_json_number(&j, a->rate);
        ns_json_end_object(&j);
    }
    ns_json_end_array(&j);
    ns_json_end_object(&j);
    fputc('\n', f);
}

static void print_text(const PlanOpt *opt, const NsScenario *sc, const NsPlanObs *po,
                       const PlanResult *res)
{
    printf("plan: %s, target '%s', method %s\n", sc->name, res->target->name, opt->method);
    printf("  predicted error  %.3f mm (tolerance %.3f mm)\n", 1e3 * res->path.error,
           1e3 * res->target->tolerance);
    printf("  min clearance    %.3f mm (asked %.3f mm) from", 1e3 * res->path.clearance,
           1e3 * opt->clearance);
    for (int i = 0; i < po->count; i++)
        printf("%s %s (%s)", i ? "," : "", po->obs[i].name,
               po->obs[i].kind == NS_PLAN_SHAPE ? "shape" : "bounding box");
    printf("%s\n", po->count ? "" : " no obstacles");
    printf("  path length      %.1f mm in %d actions (curvature %.3f 1/m)\n",
           1e3 * res->path.length, res->path.action_count, res->kappa);
    printf("  planning time    %.2f ms\n", res->ms);
}

/* DIR/plan.json and DIR/path.csv (the path alone, for `run --plan DIR` to draw:
 * plan_path_csv.h), each through DIR/.NAME.part; both are renamed into place once both are
 * written, neither when either fails. DIR is made when absent (its parent must exist). */
static int write_out(const char *dir, const PlanOpt *opt, const NsScenario *sc, const NsPlanObs *po,
                     const PlanResult *res, const double *xyz, int npts)
{
    struct stat sb;
    if (stat(dir, &sb) != 0) {
        if (mkdir(dir, 0777) != 0) {
            fprintf(stderr, "needlesim plan: cannot create output folder '%s': %s\n", dir,
                    strerror(errno));
            return 1;
        }
    } else if (!S_ISDIR(sb.st_mode)) {
        fprintf(stderr, "needlesim plan: -o '%s' is not a folder\n", dir);
        return 1;
    }
    static const char *const names[2] = {"plan.json", "path.csv"};
    static const char *const whats[2] = {"the plan", "the plan's path"};
    size_t n = strlen(dir) + 32;
    char *fin[2] = {malloc(n), malloc(n)}, *part[2] = {malloc(n), malloc(n)};
    bool made[2] = {false, false};
    char err[1024];
    int rc = 1;
    if (!fin[0] || !fin[1] || !part[0] || !part[1]) {
        fprintf(stderr, "needlesim plan: out of memory\n");
        goto done;
    }
    for (int k = 0; k < 2; k++) {
        snprintf(fin[k], n, "%s/%s", dir, names[k]);
        snprintf(part[k], n, "%s/.%s.part", dir, names[k]);
        FILE *f = ns_out_replaceable(fin[k], whats[k], err, sizeof err) == 0
                      ? ns_out_create_part(part[k], whats[k], err, sizeof err)
                      : NULL;
        if (!f) {
            fprintf(stderr, "needlesim plan: %s\n", err);
            goto done;
        }
        made[k] = true;
        if (k == 0)
            write_json(f, opt, sc, po, res, xyz, npts);
        else
            ns_plan_path_csv_write(f, xyz, npts);
        bool bad = ferror(f) != 0;
        bad |= fclose(f) != 0;
        if (bad) {
            fprintf(stderr, "needlesim plan: cannot write '%s': %s\n", fin[k], strerror(errno));
            goto done;
        }
    }
    for (int k = 1; k >= 0; k--) { /* path.csv first: plan.json's rename marks the plan */
        if (ns_out_commit(part[k], fin[k]) != 0) {
            fprintf(stderr, "needlesim plan: cannot write '%s': %s\n", fin[k], strerror(errno));
            goto done;
        }
        made[k] = false;
    }
    rc = 0;
done:
    for (int k = 0; k < 2; k++) {
        if (made[k])
            ns_out_remove_part(part[k]);
        free(fin[k]);
        free(part[k]);
    }
    return rc;
}

/* The target named `name`, or NULL after a message listing the known ones. */
static const NsRunTarget *find_target(const NsScenario *sc, const NsRunSpec *spec, const char *name)
{
    for (int i = 0; i < spec->target_count; i++)
        if (strcmp(spec->targets[i].name, name) == 0)
            return &spec->targets[i];
    fprintf(stderr, "needlesim plan: %s: no target named '%s' (targets:", sc->path, name);
    for (int i = 0; i < spec->target_count; i++)
        fprintf(stderr, "%s '%s'", i ? "," : "", spec->targets[i].name);
    fprintf(stderr, "%s)\n", spec->target_count ? "" : " none");
    return NULL;
}

/* Plans and reports, once the scenario and its run fields are read. */
static int plan_loaded(const PlanOpt *opt, const NsScenario *sc, const NsRunSpec *spec)
{
    PlanResult res;
    memset(&res, 0, sizeof res);
    res.target = find_target(sc, spec, opt->target);
    if (!res.target)
        return 1;
    if (!spec->bevel) {
        fprintf(stderr,
                "needlesim plan: %s: the needle has a symmetric tip: it cannot be steered "
                "(ns.needle{tip = \"bevel\"})\n",
                sc->path);
        return 1;
    }
    /* the arc model's curvature, k_c tan(psi) (docs/needle.md) */
    res.kappa = ns_plan_model_kappa(spec);
    NsPlanPose start;
    if (!ns_plan_pose_make(spec->entry_point, spec->entry_dir,
                           spec->has_bevel_toward ? spec->bevel_toward : NULL, &start)) {
        fprintf(stderr, "needlesim plan: %s: the entry is not a pose\n", sc->path);
        return 1;
    }
    char err[1536];
    NsPlanObs po;
    if (ns_plan_obs_make(sc, spec, &po, err, sizeof err) != 0) {
        fprintf(stderr, "%s\n", err);
        return 1;
    }
    int rc = plan(opt, sc, &po, &start, &res, err, sizeof err);
    if (rc != 0) {
        fprintf(stderr, "needlesim plan: %s\n", err);
        ns_plan_obs_free(&po);
        return 1;
    }
    double *xyz = NULL;
    int npts = ns_plan_path_points(&res.path, PLAN_PATH_STEP, &xyz);
    if (npts < 0) {
        fprintf(stderr, "needlesim plan: out of memory\n");
        rc = 1;
    } else {
        if (opt->json)
            write_json(stdout, opt, sc, &po, &res, xyz, npts);
        else
            print_text(opt, sc, &po, &res);
        if (!res.ok)
            fprintf(stderr,
                    "needlesim plan: %s: the plan misses '%s' by %.3f mm (tolerance %.3f) or "
                    "comes within %.3f mm of an obstacle (asked %.3f)\n",
                    sc->path, res.target->name, 1e3 * res.path.error, 1e3 * res.target->tolerance,
                    1e3 * res.path.clearance, 1e3 * opt->clearance);
        rc = res.ok ? 0 : 1;
        if (rc == 0 && opt->out_dir)
            rc = write_out(opt->out_dir, opt, sc, &po, &res, xyz, npts);
    }
    free(xyz);
    ns_plan_path_free(&res.path);
    ns_plan_obs_free(&po);
    return rc;
}

int ns_cmd_plan(int argc, char **argv)
{
    for (int i = 1; i < argc; i++)
        if (strcmp(argv[i], "--help") == 0 || strcmp(argv[i], "-h") == 0) {
            fputs(plan_usage, stdout);
            return 0;
        }
    PlanOpt opt;
    int rc = parse_args(argc, argv, &opt);
    if (rc != 0)
        return rc;
    NsScenario sc;
    char err[1024];
    if (ns_scenario_load(opt.scenario, &sc, err, sizeof err) != 0) {
        fprintf(stderr, "%s\n", err);
        return 1;
    }
    NsRunSpec spec;
    if (ns_run_spec_read(&sc, &spec, err, sizeof err) != 0) {
        fprintf(stderr, "%s\n", err);
        ns_scenario_free(&sc);
        return 1;
    }
    rc = plan_loaded(&opt, &sc, &spec);
    ns_run_spec_free(&spec);
    ns_scenario_free(&sc);
    return rc;
}
