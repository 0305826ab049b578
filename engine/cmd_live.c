/* needlesim live SCENARIO.lua [--port N] [--bind ADDR] [--width W --height H] [--fps F]
 *                             [--record LOG.csv] [-o DIR] [--set KEY=VALUE]... [--threads N]
 *                             [--trainee ID] [--session ID] [--quiet] [--samples N]
 *                             [--accuracy TIP [--front NAME]]
 *
 * A trainee drives the needle from a browser (docs/live.md): the scenario is built, a server
 * listens (engine/live_server.c), and the session (engine/live_session.c) steps the run in
 * real time with the controls the page sends, until the page's End, the scenario's end or a
 * stop signal. Then, as `needlesim run` does: DIR/report.json (with `live`), trajectory.csv,
 * summary.png and the control log (--record LOG.csv, else DIR/controls.csv), which
 * `needlesim run SCENARIO --replay LOG.csv` replays to the same state hash and score.
 *
 * The first line on stdout is the URL to open (flushed at once):
 *     needlesim live: open http://127.0.0.1:8080/
 * with ?token=... when the server is bound to another address than 127.0.0.1. */
#include "commands.h"

#include <lauxlib.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cleanup.h"
#include "err.h"
#include "live_server.h"
#include "live_session.h"
#include "lua_runtime.h"
#include "names.h"
#include "ns_limits.h"
#include "run.h"

static const char live_usage[] =
    "usage: needlesim live SCENARIO.lua [--port N] [--bind ADDR] [--width W --height H]\n"
    "                      [--fps F] [--record LOG.csv] [-o DIR] [--set KEY=VALUE]...\n"
    "                      [--threads N] [--trainee ID] [--session ID] [--quiet]\n"
    "                      [--samples N] [--accuracy TIP [--front NAME]]\n"
    "  defaults: --bind 127.0.0.1 --port 8080 (0: a free port) --width 960 --height 540\n"
    "  --fps 25 --samples 1 (multisampling) -o needlesim-out; the control log goes to\n"
    "  DIR/controls.csv unless --record\n";

typedef struct LiveArgs {
    NsRunOpts run;
    NsLiveOpts live;
    double accuracy;   /* --accuracy [m] (0: the scenario's dt and solver settings) */
    const char *front; /* --front: the measured front it is taken from */
    const char *bind;
    int port;
    NsLiveHook hook; /* bench --live: its client starts once the server listens */
    NsLiveRunResult *result;
} LiveArgs;

static int usage_error(const char *fmt, const char *arg)
{
    char shown[200], line[600];
    snprintf(shown, sizeof shown, "%s", arg);
    snprintf(line, sizeof line, fmt, shown);
    ns_one_line(line);
    fprintf(stderr, "needlesim live: %s (needlesim live --help)\n", line);
    return 2;
}

/* A number option's value in [lo, hi] (integers when whole). */
static int number_arg(const char *a, const char *v, double lo, double hi, bool whole, double *x)
{
    char *end;
    if (!v)
        return usage_error("%s needs a value", a);
    *x = strtod(v, &end);
    if (!v[0] || *end || !(*x >= lo && *x <= hi) || (whole && *x != floor(*x))) {
        char what[160];
        snprintf(what, sizeof what, "%%s: expected %s in [%g, %g]",
                 whole ? "a whole number" : "a number", lo, hi);
        return usage_error(what, a);
    }
    return 0;
}

static int parse_args(int argc, char **argv, LiveArgs *la)
{
    NsRunOpts *o = &la->run;
    o->out_dir = "needlesim-out";
    o->threads = 1;
    o->solver = NS_COUPLED_SCHUR;
    o->live = true;
    la->live = ns_default_live_opts();
    la->bind = "127.0.0.1";
    la->port = 8080;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        double x;
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            fputs(live_usage, stdout);
            return 1;
        } else if (strcmp(a, "--quiet") == 0) {
            o->quiet = true;
        } else if (strcmp(a, "--accuracy") == 0) {
            if (number_arg(a, v, 1e-9, 1.0, false, &la->accuracy))
                return 2;
            i++;
        } else if (strcmp(a, "--front") == 0) {
            if (!v || !v[0])
                return usage_error("%s needs a value", a);
            la->front = v;
            i++;
        } else if (strcmp(a, "--samples") == 0) {
            if (number_arg(a, v, 1, 16, true, &x))
                return 2;
            la->live.samples = (int)x;
            i++;
        } else if (strcmp(a, "--port") == 0 || strcmp(a, "--threads") == 0 ||
                   strcmp(a, "--fps") == 0 || strcmp(a, "--width") == 0 ||
                   strcmp(a, "--height") == 0) {
            bool port = a[2] == 'p', threads = a[2] == 't', fps = a[2] == 'f';
            if (number_arg(a, v,
                           port      ? 0
                           : threads ? 1
                           : fps     ? 1
                                     : 16,
                           port      ? 65535
                           : threads ? 64
                           : fps     ? NS_LIMIT_LIVE_FPS
                                     : 8192,
                           !fps, &x))
                return 2;
            if (!port && !threads && !fps && (long)x % 2)
                return usage_error("%s: expected an even number of pixels", a);
            if (port)
                la->port = (int)x;
            else if (threads)
                o->threads = (int)x;
            else if (fps)
                la->live.fps = x;
            else
                *(a[2] == 'w' ? &la->live.width : &la->live.height) = (int)x;
            i++;
        } else if (strcmp(a, "--bind") == 0 || strcmp(a, "--record") == 0 || strcmp(a, "-o") == 0 ||
                   strcmp(a, "--set") == 0 || strcmp(a, "--trainee") == 0 ||
                   strcmp(a, "--session") == 0) {
            if (!v || !v[0])
                return usage_error("%s needs a value", a);
            const char *why = NULL;
            if (strcmp(a, "--bind") == 0)
                la->bind = v;
            else if (strcmp(a, "--record") == 0)
                o->record = v;
            else if (strcmp(a, "-o") == 0)
                o->out_dir = v;
            else if (strcmp(a, "--set") == 0)
                why = ns_run_opt_set(o, v);
            else if (!ns_control_log_id_ok(v))
                why = "%s: 1 to 64 characters of A-Z a-z 0-9 . _ - only";
            else
                *(a[2] == 't' ? &o->trainee : &o->session) = v;
            if (why)
                return usage_error(why, strcmp(a, "--set") == 0 ? v : a);
            i++;
        } else if (a[0] == '-' && a[1] != '\0') {
            return usage_error("unknown option '%s'", a);
        } else if (!o->scenario) {
            o->scenario = a;
        } else {
            return usage_error("one scenario only (got '%s' too)", a);
        }
    }
    if (!o->scenario)
        return usage_error("%s", "missing SCENARIO.lua");
    if (la->front && la->accuracy <= 0.0)
        return usage_error("%s", "--front without --accuracy TIP");
    o->width = la->live.width;
    o->height = la->live.height;
    return 0;
}

/* --accuracy: the cheapest setting on the named front (scripts/needlesim/fronts.lua) measured
 * on the scenario's own mesh whose tip error is within tip, as the scenario's accuracy field
 * chooses (docs/performance.md); it replaces the scenario's dt and solver settings. */
static int choose_model(NsRun *r, double tip, const char *front, bool from_scenario, char *err,
                        int err_sz)
{
    lua_State *L = ns_lua_state(r->sc.lua);
    int top = lua_gettop(L);
    lua_getfield(L, LUA_REGISTRYINDEX, "ns.require");
    lua_pushstring(L, "needlesim.fronts");
    if (lua_pcall(L, 1, 1, 0) != LUA_OK || !lua_istable(L, -1) ||
        lua_getfield(L, -1, front) != LUA_TTABLE) {
        ns_set_err(err, err_sz, "needlesim live: %s '%s': no such measured front",
                   from_scenario ? "the scenario's live.front" : "--front", front);
        lua_settop(L, top);
        return -1;
    }
    NsRunSpec *sp = &r->spec;
    double best = INFINITY;
    bool found = false;
    for (lua_Integer i = 1; !found && lua_rawgeti(L, -1, i) == LUA_TTABLE; i++) { /* by cost */
        double v[6];
        static const char *const keys[6] = {"dt",        "refine", "tolerance",
                                            "tip_error", "cost",   "lazy_threshold"};
        for (int k = 0; k < 6; k++) {
            lua_getfield(L, -1, keys[k]);
            v[k] = lua_isnumber(L, -1) ? lua_tonumber(L, -1) : NAN;
            lua_pop(L, 1);
        }
        best = fmin(best, v[3]);
        if (v[1] == 1.0 && v[3] <= tip && v[0] > 0.0 && v[2] > 0.0 && v[2] < 1.0 && v[5] >= 0.0 &&
            v[5] < 1.0) {
            lua_getfield(L, -1, "label");
            snprintf(sp->accuracy_label, sizeof sp->accuracy_label, "%s",
                     lua_isstring(L, -1) ? lua_tostring(L, -1) : "");
            lua_pop(L, 1);
            sp->dt = v[0];
            sp->tolerance = v[2];
            sp->check_tolerance = fmin(0.5, 100.0 * v[2]); /* as ns.scenario's accuracy */
            sp->lazy_threshold = v[5];
            sp->accuracy = tip;
            sp->accuracy_tip_error = v[3];
            sp->accuracy_cost = v[4];
            snprintf(sp->accuracy_front, sizeof sp->accuracy_front, "%s", front);
            sp->model_chosen = found = true;
        }
        lua_pop(L, 1);
    }
    lua_settop(L, top);
    if (!found)
        ns_set_err(err, err_sz,
                   "needlesim live: %s %g m: no setting measured on the '%s' front "
                   "reaches it on the scenario's own mesh (the best is %g m; docs/performance.md)",
                   from_scenario ? "the scenario's live.accuracy" : "--accuracy", tip, front, best);
    return found ? 0 : -1;
}

/* The session's end on stdout. */
static void print_summary(const NsRun *r, const NsLiveSession *s, const NsRunResults *res,
                          uint64_t hash)
{
    NsLiveFigures f;
    ns_live_session_figures(s, &f);
    printf("needlesim live: ended by %s after %ld steps (%.3g s simulated, %.1f s wall)\n",
           ns_live_session_end_reason(s), r->steps, (double)r->steps * r->spec.dt, r->wall_s);
    printf("score %.1f / 100; seeds %d; needles %d; state hash %016llx\n", res->total, r->seed_n,
           r->needles, (unsigned long long)hash);
    printf("frames %ld: %.1f fps (median), real-time factor %.3f (median), input latency "
           "%.0f / %.0f ms (median / p95); render %.1f ms, encode %.1f ms, step %.1f ms\n",
           f.frames, f.fps_median, f.rtf_median, f.latency_median, f.latency_p95, f.render_ms,
           f.encode_ms, f.step_ms);
    printf("wrote %s/report.json, %s/trajectory.csv, %s/summary.png and %s\n", r->opt.out_dir,
           r->opt.out_dir, r->opt.out_dir, r->opt.record);
}

/* Build, serve, run, write: the session from its scenario to its outputs. */
static int live_session(NsRun *r, LiveArgs *la, char *record_path, char *err, int err_sz)
{
    int rc = ns_run_outputs_prepare(r, err, err_sz) ? -1 : 0;
    if (rc == 0 && !r->opt.record) {
        snprintf(record_path, 4096, "%s/controls.csv", r->opt.out_dir);
        r->opt.record = record_path;
    }
    if (rc == 0 && ns_run_check_record_path(&r->opt))
        return -2;
    rc = rc ? rc : ns_run_load(r, err, err_sz);
    if (rc == 0 && la->accuracy > 0.0)
        rc = choose_model(r, la->accuracy, la->front ? la->front : "phantom", false, err, err_sz);
    else if (rc == 0 && r->spec.live_accuracy > 0.0) /* the scenario's live = {accuracy, front} */
        rc = choose_model(r, r->spec.live_accuracy, r->spec.live_front, true, err, err_sz);
    rc = rc ? rc : ns_run_open_logs(r, err, err_sz);
    if (rc == 0)
        ns_run_traj_header(r);
    rc = rc ? rc : ns_run_build(r, err, err_sz);
    /* llvmpipe (no GPU) starts a rasterizer thread per core for each context unless told: on
     * two cores those would compete with the solver (docs/live.md, "Threads"). */
    setenv("LP_NUM_THREADS", "1", 0);
    rc = rc ? rc : ns_run_render_setup(r, err, err_sz);
    rc = rc ? rc : ns_run_begin(r, err, err_sz);
    if (rc)
        return rc;
    NsLiveSession *s = ns_live_session_new(r, &la->live, err, err_sz);
    if (!s)
        return -1;
    r->report_extra = ns_live_session_report;
    r->report_ctx = s;
    NsLiveServer *srv = ns_live_server_start(s, la->bind, la->port, err, err_sz);
    if (!srv) {
        ns_live_session_free(s);
        return -1;
    }
    char url[256];
    ns_live_server_url(srv, url, sizeof url);
    if (la->hook.fn) { /* bench --live: its client, not a person, opens it */
        la->hook.fn(url, ns_live_server_port(srv), la->hook.ctx);
    } else {
        printf("needlesim live: open %s\n", url);
        fflush(stdout);
    }
    if (!r->opt.quiet)
        fprintf(stderr, "needlesim live: %s; End on the page, or Ctrl-C, ends the session\n",
                r->sc.name);
    rc = ns_live_session_run(s, err, err_sz);
    ns_run_finish(r);
    ns_live_server_stop(srv); /* the clients have had the last frame and the end */
    NsRunResults res;
    memset(&res, 0, sizeof res);
    uint64_t hash = 0;
    rc = rc ? rc : ns_run_end(r, &res, &hash, err, err_sz);
    rc = rc ? rc : ns_run_write_report(r, &res, hash, err, err_sz);
    rc = rc ? rc : ns_run_outputs_commit(r, err, err_sz);
    if (rc == 0 && !r->opt.quiet)
        print_summary(r, s, &res, hash);
    if (rc == 0 && la->result) {
        NsLiveRunResult *o = la->result;
        ns_live_session_figures(s, &o->fig);
        o->hash = hash;
        o->score = res.total;
        o->steps = r->steps;
        o->sim_s = (double)r->steps * r->spec.dt;
        o->wall_s = r->wall_s;
        o->seeds_planned = r->spec.seed_count;
    }
    ns_run_results_free(&res);
    r->report_extra = NULL;
    ns_live_session_free(s);
    return rc;
}

int ns_cmd_live(int argc, char **argv)
{
    return ns_live_run(argc, argv, (NsLiveHook){NULL, NULL}, NULL);
}

int ns_live_run(int argc, char **argv, NsLiveHook hook, NsLiveRunResult *result)
{
    NsRun r;
    memset(&r, 0, sizeof r);
    r.sim_ref = r.act_ref = r.co_ref = LUA_NOREF;
    LiveArgs la;
    memset(&la, 0, sizeof la);
    int pa = parse_args(argc, argv, &la);
    if (pa)
        return pa == 1 ? 0 : pa;
    la.hook = hook;
    la.result = result;
    r.opt = la.run;
    char err[1024] = "", record_path[4096];
    ns_cleanup_install();
    int rc = live_session(&r, &la, record_path, err, sizeof err);
    if (rc) {
        ns_run_outputs_remove(&r);
        if (rc == -1) {
            size_t n = strlen(r.opt.scenario);
            bool located =
                strncmp(err, "needlesim", 9) == 0 || strncmp(err, r.opt.scenario, n) == 0;
            ns_one_line(err);
            fprintf(stderr, "%s%s\n", located ? "" : "needlesim live: ", err);
        }
    }
    ns_run_free(&r);
    return rc == -2 ? 2 : rc ? 1 : 0;
}
