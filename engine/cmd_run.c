/* needlesim run SCENARIO.lua [-o DIR] [--steps N] [--threads N] [--solver NAME]
 *                            [--set KEY=VALUE]... [--record LOG | --replay LOG] [--quiet]
 * needlesim bench SCENARIO.lua [--steps N] [--solver NAME] [--threads N] [--json]
 *
 * The run loop (DESIGN.md "Command line"): the scenario's tissue and needle are built, the
 * needle punctures the tissue's surface at the scenario's entry (skin entry), and every tick the
 * scenario's script (scripts/needlesim/actions.lua, on a coroutine) and its on_tick, or a
 * replayed control log, set the needle's controls; seeds are released, the coupled solver steps
 * (paper Algorithm 1 with remeshing at the tip, Algorithm 2), obstacles are checked and the
 * trajectory is logged. At the end the targets (material points, so they move with the tissue)
 * are scored against their seeds or the needle tip, and DIR/report.json and
 * DIR/trajectory.csv are written (docs/scenarios.md documents both). A failed run writes
 * neither: both are written to temporary names and renamed only when the run succeeded.
 * `bench` runs the same loop for a number of steps and prints the stage timings (with
 * --compare paper, both solvers'). Pictures: engine/run_render.c. */
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

#include "commands.h"
#include "control_log.h"
#include "coupling.h"
#include "err.h"
#include "cleanup.h"
#include "json.h"
#include "out_files.h"
#include "needle_path.h"
#include "ns_limits.h"
#include "ns_config.h"
#include "quality.h"
#include "remesh.h"
#include "rod.h"
#include "run_render.h"
#include "run_spec.h"
#include "scenario.h"
#include "step.h"
#include "tissue.h"

static const char run_usage[] =
    "usage: needlesim run SCENARIO.lua [-o DIR] [--steps N] [--threads N] [--solver NAME]\n"
    "                     [--set KEY=VALUE]... [--record LOG.csv | --replay LOG.csv]\n"
    "                     [--no-render] [--frames] [--video FILE.mp4] [--width W]\n"
    "                     [--height H] [--frame-every K] [--quiet]\n";

typedef struct RunOpts {
    const char *scenario, *out_dir, *record, *replay;
    const char *sets[32]; /* --set KEY=VALUE */
    int nsets;
    long steps; /* 0: the scenario decides */
    int threads;
    int solver; /* NsCoupledSolverKind */
    bool quiet;
    /* pictures (docs/rendering.md): summary.png unless --no-render; frames and video on ask */
    bool no_render, frames;
    const char *video;
    int width, height, frame_every; /* frame_every 0: the scenario's camera decides */
} RunOpts;

/* A bad command line: one line, the usage on --help (the one-line contract for bad input). */
static int usage_error(const char *fmt, const char *arg)
{
    fputs("needlesim run: ", stderr);
    fprintf(stderr, fmt, arg);
    fputs(" (needlesim run --help)\n", stderr);
    return 2;
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* ---- per-step series (medians, percentiles) ---- */

typedef struct Series {
    double *v;
    int n, cap;
} Series;

static int series_push(Series *s, double x)
{
    if (s->n == s->cap) {
        int cap = s->cap ? 2 * s->cap : 256;
        double *v = realloc(s->v, (size_t)cap * sizeof *v);
        if (!v)
            return -1;
        s->v = v;
        s->cap = cap;
    }
    s->v[s->n++] = x;
    return 0;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* The q-quantile (nearest rank) of the series; 0 when empty. Sorts a copy. */
static double series_quantile(const Series *s, double q)
{
    if (s->n == 0)
        return 0.0;
    double *c = malloc((size_t)s->n * sizeof *c);
    if (!c)
        return NAN;
    memcpy(c, s->v, (size_t)s->n * sizeof *c);
    qsort(c, (size_t)s->n, sizeof *c, cmp_double);
    int k = (int)ceil(q * s->n) - 1;
    double v = c[k < 0 ? 0 : k >= s->n ? s->n - 1 : k];
    free(c);
    return v;
}

static void series_range(const Series *s, double *lo, double *mean, double *hi)
{
    *lo = *mean = *hi = 0.0;
    for (int i = 0; i < s->n; i++) {
        *lo = i ? fmin(*lo, s->v[i]) : s->v[i];
        *hi = i ? fmax(*hi, s->v[i]) : s->v[i];
        *mean += s->v[i] / s->n;
    }
}

/* ---- the model ---- */

typedef struct Run {
    RunOpts opt;
    NsScenario sc;
    NsRunSpec spec;
    NsTissue tissue;
    NsRod rod;
    NsCoupled c;
    bool have_sc, have_spec, have_tissue, have_rod, have_c;
    int sim_ref, act_ref,
        co_ref; /* registry refs: `sim`, the actions module, the script's coroutine */
    /* statistics */
    Series step_ms, total_ms, lcp_ms, tissue_ms, needle_ms, remesh_ms, trials, iterations;
    long steps;
    long factorizations; /* of the tissue matrix, made or adopted (schur; the paper's needs none) */
    int consistent, nan, inverted, unconverged, lcp_unresolved;
    int repaired; /* tissue nodes moved by the remesher's repair (ns_remesh_repair) */
    double max_axial, last_axial, path_cut, wall_s, last_tip[3];
    NsMesh orig; /* the tissue's mesh as built: every needle's exit restores it */
    bool have_orig;
    int exited;                   /* the current needle has been withdrawn out of the tissue */
    int needles;                  /* needles used so far */
    int last_fr[3], last_cutting; /* friction-state counts and cutting at the last step */
    int *target_hint, *marker_hint;
    /* seeds released so far: material point, time, target index (-1: nearest at the end) */
    struct Seed {
        double u[3], t;
        int target, hint;
    } * seeds;
    int seed_n, seed_cap;
    /* physical outcomes (issue 32): the tip stopped at bone, the tip out through the surface */
    struct Event {
        double t, x[3];
        int type, region; /* EVENT_*; bone: the region touched */
    } * events;
    int event_n, event_cap;
    /* obstacles: per obstacle, whether the needle entered it, when first, for how many steps,
     * where the tip was when it went in, and the deepest it got from there */
    struct Obstacle {
        bool violated, inside;
        double first_t, entry[3], max_depth;
        int steps_inside;
    } * obst;
    int tip_hint, insertions;
    double prev_v;
    /* output */
    char *traj_tmp, *report_tmp, *rec_tmp;
    FILE *rec;
    NsControlLog replay;
    bool made_dir, progress_shown, script_finished;
    bool time_capped;    /* stopped at NS_LIMIT_DEFAULT_SIM_TIME with the script still running */
    bool stop_when_done; /* bench: the script's end ends the run even before --steps */
    FILE *traj;
    /* pictures */
    bool rendering;
    NsRunRender rr;
    int every;          /* steps between frames */
    int *prev_tet_node; /* the tets before the latest step (what remeshing changed) */
    int prev_slots, prev_cap;
    uint8_t *changed; /* per tet slot */
    bool *obstacle_region;
    double bounds[6];
    bool entered;      /* the entry moment was taken */
    bool *reached;     /* per target: the tip-reached moment was taken */
    double peak_axial; /* the axial force's peak since the last puncture (moments) */
    int punctures;
    double end_s;   /* the run's end: last frame, contact sheet, video closed [s] */
    Series tips[3]; /* bench --compare: the tip after every step [m] */
    bool log_tips;
} Run;

enum { EVENT_BONE_CONTACT, EVENT_TIP_EXIT };
static const char *const event_names[2] = {"bone_contact", "tip_exit"};

/* Records what the step's statistics say happened at the tip (a bone contact's first step, an
 * exit through the surface), at the step's end time. Returns 0, or -1 (memory). */
static int record_events(Run *r, const NsCouplingStats *st, double t, const double tip[3])
{
    for (int type = 0; type < 2; type++) {
        if (type == EVENT_BONE_CONTACT ? st->bone_contact != 1 : !st->tip_exit)
            continue;
        if (r->event_n == r->event_cap) {
            int cap = r->event_cap ? 2 * r->event_cap : 8;
            struct Event *e = realloc(r->events, (size_t)cap * sizeof *e);
            if (!e)
                return -1;
            r->events = e;
            r->event_cap = cap;
        }
        struct Event *e = &r->events[r->event_n++];
        e->t = t;
        e->type = type;
        e->region = type == EVENT_BONE_CONTACT ? st->bone_region : -1;
        memcpy(e->x, tip, sizeof e->x);
    }
    return 0;
}

static const char *event_region(const Run *r, const struct Event *e)
{
    return e->region >= 0 && e->region < r->sc.region_count ? r->sc.regions[e->region].name : "";
}

static double dot3(const double *a, const double *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static const double *tip_of(const Run *r)
{
    return r->rod.x + 3 * (r->rod.nodes - 1);
}

static double depth_of(const Run *r)
{
    const double *t = tip_of(r), *p = r->spec.entry_point;
    double d[3] = {t[0] - p[0], t[1] - p[1], t[2] - p[2]};
    return dot3(d, r->spec.entry_dir);
}

/* The world position of the material point u (a target) in the deformed tissue; the tet found
 * is kept as the next search's start. */
static int world_of(const NsMesh *m, const double u[3], int *hint, double x[3])
{
    double b[4];
    int t = ns_mesh_locate(m, u, *hint, 1e-9, b);
    if (t < 0)
        return -1;
    *hint = t;
    const int *tn = m->tet_node + 4 * t;
    for (int i = 0; i < 3; i++)
        x[i] = b[0] * m->x[3 * tn[0] + i] + b[1] * m->x[3 * tn[1] + i] +
               b[2] * m->x[3 * tn[2] + i] + b[3] * m->x[3 * tn[3] + i];
    return 0;
}

/* The needle at the current entry (spec.entry_*): skin entry (sim/remesh_entry.c: the entry
 * node made on the surface at the entry point, the tip node a tenth of an element inside it,
 * both on the coupling's undo stack), the tissue synced, the rod and the coupling made, and the
 * nodes moved recorded so that they go back when the needle leaves. `what` names the caller
 * for messages. */
static int place_needle(Run *r, const char *what, char *err, int err_sz)
{
    NsScenario *sc = &r->sc;
    NsRunSpec *sp = &r->spec;
    NsMesh *M = &r->tissue.mesh;
    double h = sc->resolution > 0.0 ? sc->resolution : ns_mesh_mean_edge(&r->orig);
    int nodes[2], np = 2;
    char e2[512];
    NsRemeshStack entry;
    ns_remesh_stack_init(&entry);
    if (ns_remesh_skin_entry(M, &entry, sp->entry_point, sp->entry_dir, 0.1 * h, nodes, e2,
                             sizeof e2)) {
        ns_remesh_stack_free(&entry);
        ns_set_err(err, err_sz,
                   "%s: the needle cannot enter at (%g, %g, %g) m along (%g, %g, %g): %s", what,
                   sp->entry_point[0], sp->entry_point[1], sp->entry_point[2], sp->entry_dir[0],
                   sp->entry_dir[1], sp->entry_dir[2], e2);
        return -1;
    }
    if (ns_tissue_sync_topology(&r->tissue, err, err_sz)) {
        ns_remesh_stack_free(&entry);
        return -1;
    }
    /* The needle: four nodes 5 mm apart outside, behind the entry node, then the track. */
    double x[3 * 68], d[3];
    memcpy(d, sp->entry_dir, sizeof d);
    const double *e0 = M->x + 3 * nodes[0];
    for (int i = 0; i < 4; i++)
        for (int k = 0; k < 3; k++)
            x[3 * i + k] = e0[k] - 0.005 * (4 - i) * d[k];
    for (int i = 0; i < np; i++)
        memcpy(x + 3 * (4 + i), M->x + 3 * nodes[i], 3 * sizeof *x);
    NsRodParams rp = ns_default_rod_params();
    rp.gamma = r->tissue.params.gamma;
    rp.beta = r->tissue.params.beta;
    rp.material.youngs = sp->youngs;
    rp.material.outer_diameter = sp->diameter;
    rp.material.inner_diameter = sp->inner_diameter;
    rp.material.density = sp->density;
    if (sp->bevel) {
        rp.tip = NS_TIP_BEVEL;
        rp.bevel_angle = sp->bevel_deg * M_PI / 180.0;
    }
    /* The material frame's d1: the axis least aligned with the needle, made normal to it; or,
     * with entry.bevel_toward b, d1 = b x t, so that m2 = t x d1 = b is where the bevel
     * steers (sim/rod.h: m2 = t x m1). */
    int ax = fabs(d[0]) <= fabs(d[1]) && fabs(d[0]) <= fabs(d[2]) ? 0
             : fabs(d[1]) <= fabs(d[2])                           ? 1
                                                                  : 2;
    double d1[3] = {0.0, 0.0, 0.0};
    d1[ax] = 1.0;
    double dd = dot3(d1, d);
    for (int k = 0; k < 3; k++)
        d1[k] -= dd * d[k];
    if (sp->has_bevel_toward) {
        const double *bt = sp->bevel_toward;
        d1[0] = bt[1] * d[2] - bt[2] * d[1];
        d1[1] = bt[2] * d[0] - bt[0] * d[2];
        d1[2] = bt[0] * d[1] - bt[1] * d[0];
    }
    double n1 = sqrt(dot3(d1, d1));
    for (int k = 0; k < 3; k++)
        d1[k] /= n1;
    if (ns_rod_init(&r->rod, x, 4 + np, d1, 2, &rp, err, err_sz)) {
        ns_remesh_stack_free(&entry);
        return -1;
    }
    r->have_rod = true;
    NsCouplingParams cp = ns_default_coupling_params();
    cp.remesh = 1;
    cp.solver = (NsCoupledSolverKind)r->opt.solver;
    cp.threads = r->opt.threads;
    if (sp->tolerance > 0.0) /* the scenario's solver = {...} */
        cp.tau_sol = sp->tolerance;
    if (sp->check_tolerance > 0.0)
        cp.tau_check = sp->check_tolerance;
    cp.tip_block = sp->tip_block;
    if (cp.tau_check < cp.tau_sol) /* never below (ns.scenario refuses an explicit one) */
        cp.tau_check = cp.tau_sol;
    for (int k = 0; k < sc->region_count; k++)
        cp.cut_force[k] = sc->regions[k].material.cut_force;
    if (sp->steer_arc) { /* needle.steering = "arc" */
        cp.bevel_model = NS_BEVEL_ARC;
        for (int k = 0; k < NS_COUPLING_MAX_REGIONS; k++)
            cp.bevel_curvature[k] = sp->arc_curvature;
    }
    /* One friction per unit length for the whole needle: that of the region at the entry. */
    int t0 = M->node_tets[nodes[0]].items[0];
    cp.f_perlen = sc->regions[M->tet_region[t0]].material.friction;
    double s = 0.0;
    for (int i = 1; i < np; i++) {
        const double *p0 = M->u + 3 * nodes[i - 1], *p1 = M->u + 3 * nodes[i];
        double e[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]};
        s += sqrt(dot3(e, e));
    }
    NsNeedlePath path;
    if (ns_needle_path_init(&path, M, nodes, np, s, err, err_sz) ||
        ns_coupled_init(&r->c, &r->tissue, &r->rod, &path, &cp, err, err_sz)) {
        ns_remesh_stack_free(&entry);
        return -1;
    }
    r->have_c = true;
    /* The skin entry's splits and snap are the first entries of the needle's undo stack. */
    ns_remesh_stack_free(&r->c.remesh);
    r->c.remesh = entry;
    const NsMesh *O = &r->orig;
    for (int i = 0; i < O->node_slots; i++)
        if (ns_mesh_node_alive(O, i) && memcmp(O->u + 3 * i, M->u + 3 * i, 24) != 0 &&
            ns_remesh_record_original(&r->c.remesh, i, O->u + 3 * i)) {
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
    r->exited = 0;
    return 0;
}

/* The tissue (its mesh kept as the original, which every needle's exit restores), the first
 * needle, and the look-up hints. */
static int build(Run *r, char *err, int err_sz)
{
    NsScenario *sc = &r->sc;
    NsRunSpec *sp = &r->spec;
    if (sc->region_count > NS_COUPLING_MAX_REGIONS) {
        ns_set_err(err, err_sz, "%s: the tissue has %d regions; the coupling takes at most %d",
                   sc->tissue_where, sc->region_count, NS_COUPLING_MAX_REGIONS);
        return -1;
    }
    if (ns_mesh_copy(&r->orig, &sc->mesh)) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    r->have_orig = true;
    NsTissueParams tp = ns_default_tissue_params();
    tp.gamma = 0.55; /* slightly dissipative Newmark, as the validation's coupled cases */
    tp.beta = 0.25 * 1.05 * 1.05;
    tp.threads = r->opt.threads;
    if (sp->lazy_threshold >= 0.0)
        tp.lazy_threshold = sp->lazy_threshold;
    if (ns_scenario_tissue(sc, &tp, &r->tissue, err, err_sz))
        return -1;
    r->have_tissue = true;
    char what[600];
    snprintf(what, sizeof what, "%s: ns.scenario: entry", sc->where);
    if (place_needle(r, what, err, err_sz))
        return -1;
    r->target_hint = malloc((size_t)(sp->target_count + 1) * sizeof *r->target_hint);
    r->marker_hint = malloc((size_t)(sp->marker_count + 1) * sizeof *r->marker_hint);
    r->obst = calloc((size_t)sp->obstacle_count + 1, sizeof *r->obst);
    r->tip_hint = -1;
    for (int i = 0; r->marker_hint && i < sp->marker_count; i++)
        r->marker_hint[i] = -1;
    if (!r->target_hint || !r->marker_hint || !r->obst) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    for (int i = 0; i < sp->target_count; i++)
        r->target_hint[i] = -1;
    return 0;
}

/* act.next_needle: the needle, out of the tissue, is replaced by a new one at another entry
 * (the next hole of a brachytherapy template). The tissue keeps its state; its mesh is the
 * original one again since the last needle left (Algorithm 2's undo stack). */
static int next_needle(Run *r, const NsEntry *e, double t, char *err, int err_sz)
{
    if (!r->c.outside) {
        ns_set_err(err, err_sz,
                   "%s: act.next_needle at t = %.3f s: the needle is still in the tissue (retract "
                   "it all the way first)",
                   r->sc.path, t);
        return -1;
    }
    ns_coupled_free(&r->c);
    r->have_c = false;
    ns_rod_free(&r->rod);
    r->have_rod = false;
    memcpy(r->spec.entry_point, e->point, sizeof e->point);
    memcpy(r->spec.entry_dir, e->direction, sizeof e->direction);
    r->spec.has_bevel_toward = e->has_bevel_toward;
    memcpy(r->spec.bevel_toward, e->bevel_toward, sizeof e->bevel_toward);
    char what[600];
    snprintf(what, sizeof what, "%s: act.next_needle at t = %.3f s", r->sc.path, t);
    if (place_needle(r, what, err, err_sz))
        return -1;
    r->needles++;
    memcpy(r->last_tip, tip_of(r), sizeof r->last_tip);
    return 0;
}

/* ---- the script side: the `sim` table and the actions module ---- */

/* Raw sets and gets only on the tables a script can reach: a metatable a script put on `sim`
 * must not run outside a protected call. idx is absolute. */
static void set_vec(lua_State *L, int idx, const char *key, const double v[3])
{
    lua_pushstring(L, key);
    lua_createtable(L, 3, 0);
    for (int i = 0; i < 3; i++) {
        lua_pushnumber(L, v[i]);
        lua_rawseti(L, -2, i + 1);
    }
    lua_rawset(L, idx);
}

static void set_num(lua_State *L, int idx, const char *key, double v)
{
    lua_pushstring(L, key);
    lua_pushnumber(L, v);
    lua_rawset(L, idx);
}

static int get_raw(lua_State *L, int idx, const char *key)
{
    lua_pushstring(L, key);
    return lua_rawget(L, idx);
}

/* Everything that touches the scenario's Lua state runs inside ns_lua_call (a protected call
 * with the instruction budget): a script can replace globals, put metatables on the tables it
 * sees or run out of memory, and none of that may raise outside a protected call. */

typedef struct TickIO {
    Run *r;
    double t;
    int exited;
    int more;      /* out: the script has more to do */
    NsControl ctl; /* out: the controls for this step */
} TickIO;

/* (io) -> (): makes `sim`, loads needlesim.actions through the runtime's own require (kept in
 * the registry by the runtime, not the script's global), and starts the script's coroutine. */
static int start_body(lua_State *L)
{
    TickIO *io = lua_touserdata(L, 1);
    Run *r = io->r;
    lua_newtable(L); /* sim */
    lua_pushstring(L, "control");
    lua_newtable(L);
    set_num(L, lua_gettop(L), "v_insert", 0.0);
    set_num(L, lua_gettop(L), "twist_rate", 0.0);
    lua_rawset(L, -3);
    lua_pushstring(L, "limits"); /* the controls' bounds (sim/ns_limits.h) */
    lua_createtable(L, 0, 4);
    set_num(L, lua_gettop(L), "insert_speed", NS_LIMIT_INSERT_SPEED);
    set_num(L, lua_gettop(L), "twist_rate", NS_LIMIT_TWIST_RATE);
    set_num(L, lua_gettop(L), "base_speed", NS_LIMIT_BASE_SPEED);
    set_num(L, lua_gettop(L), "twist_angle", NS_LIMIT_TWIST_ANGLE);
    lua_rawset(L, -3);
    lua_pushvalue(L, -1);
    r->sim_ref = luaL_ref(L, LUA_REGISTRYINDEX);
    int sim = lua_gettop(L);
    lua_getfield(L, LUA_REGISTRYINDEX, "ns.require"); /* the sandbox's require */
    if (!lua_isfunction(L, -1))
        return luaL_error(L, "needlesim: the sandbox's require is missing");
    lua_pushstring(L, "needlesim.actions");
    lua_call(L, 1, 1);
    if (!lua_istable(L, -1))
        return luaL_error(L, "needlesim: needlesim.actions did not load as a table");
    lua_pushvalue(L, -1);
    r->act_ref = luaL_ref(L, LUA_REGISTRYINDEX);
    lua_pushstring(L, "_bind");
    lua_rawget(L, -2);
    lua_pushvalue(L, sim);
    lua_rawgeti(L, LUA_REGISTRYINDEX, r->sc.table_ref);
    lua_pushstring(L, "script");
    lua_rawget(L, -2);
    lua_remove(L, -2);
    lua_call(L, 2, 1); /* returns the script's coroutine, or nil */
    r->co_ref = luaL_ref(L, LUA_REGISTRYINDEX);
    return 0;
}

static int script_start(Run *r, char *err, int err_sz)
{
    lua_State *L = ns_lua_state(r->sc.lua);
    TickIO io = {.r = r};
    /* One budget for the whole of the run's script and on_tick calls (sim/ns_limits.h). */
    ns_lua_begin_phase(r->sc.lua, "the run's script", NS_LIMIT_RUN_INSTRUCTIONS, 0.0);
    lua_pushcfunction(L, start_body);
    lua_pushlightuserdata(L, &io);
    return ns_lua_call(r->sc.lua, 1, 0, err, err_sz);
}

/* The script's error, with the script's file and line in front when the error value has none
 * (error({}) or error("x", 0)): the deepest frame of the coroutine in a Lua file. */
static void raise_script_error(lua_State *L, lua_State *co, const char *scenario)
{
    const char *msg = lua_tostring(co, -1);
    char buf[900];
    snprintf(buf, sizeof buf, "%s",
             msg                            ? msg
             : lua_type(co, -1) == LUA_TNIL ? "error (nil)"
                                            : "error (not a string)");
    if (msg == NULL || strncmp(msg, scenario, strlen(scenario)) != 0) {
        lua_Debug ar;
        for (int level = 0; lua_getstack(co, level, &ar); level++)
            if (lua_getinfo(co, "Sl", &ar) && ar.currentline > 0 && ar.source[0] == '@') {
                if (strncmp(buf, ar.source + 1, strlen(ar.source + 1)) != 0) {
                    lua_pushfstring(L, "%s:%d: %s", ar.source + 1, ar.currentline, buf);
                    lua_error(L);
                }
                break;
            }
    }
    lua_pushstring(L, buf);
    lua_error(L);
}

/* (io) -> (): updates `sim`, resumes the script for one step, calls on_tick, reads the
 * controls (raw accesses only: metatables a script sets do not run here). */
static int tick_body(lua_State *L)
{
    TickIO *io = lua_touserdata(L, 1);
    Run *r = io->r;
    lua_rawgeti(L, LUA_REGISTRYINDEX, r->sim_ref);
    int si = lua_gettop(L);
    set_num(L, si, "t", io->t);
    set_num(L, si, "dt", r->spec.dt);
    lua_pushstring(L, "step");
    lua_pushinteger(L, r->steps);
    lua_rawset(L, si);
    set_num(L, si, "depth", depth_of(r));
    set_vec(L, si, "tip", tip_of(r));
    set_num(L, si, "axial_force", r->last_axial);
    double tt[3], m1[3], m2[3];
    ns_rod_tip_frame(&r->rod, tt, m1, m2);
    set_vec(L, si, "tip_direction", tt);
    set_vec(L, si, "bevel_direction", m2);
    lua_pushstring(L, "friction"); /* coupling nodes per friction state, last step */
    lua_createtable(L, 0, 4);
    set_num(L, lua_gettop(L), "sticking", r->last_fr[0]);
    set_num(L, lua_gettop(L), "sliding_in", r->last_fr[1]);
    set_num(L, lua_gettop(L), "sliding_out", r->last_fr[2]);
    lua_pushstring(L, "cutting");
    lua_pushboolean(L, r->last_cutting);
    lua_rawset(L, -3);
    lua_rawset(L, si);
    lua_pushstring(L, "seeds_dropped");
    lua_pushinteger(L, r->seed_n);
    lua_rawset(L, si);
    lua_pushstring(L, "exited");
    lua_pushboolean(L, io->exited);
    lua_rawset(L, si);
    lua_pushstring(L, "bone_contact"); /* the tip rests on bone: the insertion stalls */
    lua_pushboolean(L, r->c.tip_blocked);
    lua_rawset(L, si);
    lua_pushstring(L, "tip_exited"); /* the tip is out through the tissue's surface */
    lua_pushboolean(L, r->c.params.remesh && r->c.path.through && !r->c.outside);
    lua_rawset(L, si);
    lua_pushstring(L, "events"); /* a fresh list every step: {t, type, tip, region} */
    lua_createtable(L, r->event_n, 0);
    for (int i = 0; i < r->event_n; i++) {
        const struct Event *e = &r->events[i];
        lua_createtable(L, 0, 4);
        set_num(L, lua_gettop(L), "t", e->t);
        lua_pushstring(L, event_names[e->type]);
        lua_setfield(L, -2, "type");
        set_vec(L, lua_gettop(L), "tip", e->x);
        if (e->type == EVENT_BONE_CONTACT) {
            lua_pushstring(L, event_region(r, e));
            lua_setfield(L, -2, "region");
        }
        lua_rawseti(L, -2, i + 1);
    }
    lua_rawset(L, si);
    lua_pushstring(L, "targets"); /* a fresh table every step */
    lua_newtable(L);
    for (int i = 0; i < r->spec.target_count; i++) {
        /* A copy of the hint: the search the score makes at the end must not depend on
         * whether a script looked at the targets (a replay does not), or the score could
         * differ in its last bits between a run and its replay. */
        double x[3];
        int hint = r->target_hint[i];
        if (world_of(&r->tissue.mesh, r->spec.targets[i].at, &hint, x) != 0)
            return luaL_error(L, "needlesim: target '%s' could not be located in the tissue",
                              r->spec.targets[i].name);
        set_vec(L, lua_gettop(L), r->spec.targets[i].name, x);
    }
    lua_rawset(L, si);
    /* The script: one slice of its coroutine. */
    io->more = 0;
    lua_rawgeti(L, LUA_REGISTRYINDEX, r->co_ref);
    lua_State *co = lua_tothread(L, -1);
    int resumable = co && (lua_status(co) == LUA_YIELD ||
                           (lua_status(co) == LUA_OK && lua_gettop(co) > 0)); /* not yet ended */
    if (resumable) {
        int nres = 0;
        int st = lua_resume(co, L, 0, &nres);
        if (st == LUA_YIELD) {
            lua_pop(co, nres);
            io->more = 1;
        } else if (st == LUA_OK) {
            lua_pop(co, nres);
        } else {
            raise_script_error(L, co, r->sc.path);
        }
    }
    lua_pop(L, 1);
    lua_pushstring(L, "control");
    if (lua_rawget(L, si) != LUA_TTABLE)
        return luaL_error(L, "%s: sim.control must stay a table", r->sc.path);
    int ci = lua_gettop(L);
    if (!io->more && r->spec.has_script) { /* the script ended: the needle stops */
        set_num(L, ci, "v_insert", 0.0);
        set_num(L, ci, "twist_rate", 0.0);
    }
    if (r->spec.has_on_tick) {
        lua_rawgeti(L, LUA_REGISTRYINDEX, r->sc.table_ref);
        lua_pushstring(L, "on_tick");
        lua_rawget(L, -2);
        lua_remove(L, -2);
        lua_pushvalue(L, si);
        lua_call(L, 1, 0);
    }
    static const char *const keys[2] = {"v_insert", "twist_rate"};
    double *dst[2] = {&io->ctl.v_insert, &io->ctl.twist_rate};
    for (int k = 0; k < 2; k++) {
        int ty = get_raw(L, ci, keys[k]);
        double v = lua_tonumber(L, -1);
        if (ty != LUA_TNUMBER || !isfinite(v))
            return luaL_error(L, "%s: sim.control.%s must be a finite number (got %s)", r->sc.path,
                              keys[k],
                              ty == LUA_TNUMBER ? "a non-finite number" : luaL_typename(L, -1));
        double lim = k == 0 ? NS_LIMIT_INSERT_SPEED : NS_LIMIT_TWIST_RATE;
        if (fabs(v) > lim) {
            char buf[160]; /* (lua_pushfstring knows no %g) */
            snprintf(buf, sizeof buf, "sim.control.%s %g is beyond its limit of %g %s", keys[k], v,
                     lim, k == 0 ? "m/s" : "rad/s");
            return luaL_error(L, "%s: %s", r->sc.path, buf);
        }
        *dst[k] = v;
        lua_pop(L, 1);
    }
    /* The sleeve's velocity: {vx, vy, vz} [m/s], absent = still. */
    int bt = get_raw(L, ci, "base_velocity");
    double vb[3] = {0.0, 0.0, 0.0};
    if (bt == LUA_TTABLE) {
        int bi = lua_gettop(L);
        for (int k = 0; k < 3; k++) {
            int ty = lua_rawgeti(L, bi, k + 1);
            vb[k] = lua_tonumber(L, -1);
            if (ty != LUA_TNUMBER || !isfinite(vb[k]) || fabs(vb[k]) > NS_LIMIT_BASE_SPEED)
                bt = LUA_TNONE;
            lua_pop(L, 1);
        }
    }
    if (bt != LUA_TTABLE && bt != LUA_TNIL)
        return luaL_error(L,
                          "%s: sim.control.base_velocity must be {vx, vy, vz}: 3 finite "
                          "numbers within +-%d mm/s, or nil",
                          r->sc.path, (int)(1e3 * NS_LIMIT_BASE_SPEED));
    memcpy(io->ctl.v_base, vb, sizeof vb);
    lua_pop(L, 1);
    /* act.next_needle{} leaves the new entry, checked by the action: {point, direction,
     * bevel_toward or nil}, one-shot */
    if (get_raw(L, ci, "next_needle") == LUA_TTABLE) {
        int ni = lua_gettop(L);
        NsEntry *e = &io->ctl.entry;
        static const char *const keys3[3] = {"point", "direction", "bevel_toward"};
        double *dst3[3] = {e->point, e->direction, e->bevel_toward};
        for (int k = 0; k < 3; k++) {
            int ty = get_raw(L, ni, keys3[k]);
            if (k == 2)
                e->has_bevel_toward = ty == LUA_TTABLE;
            bool ok = true;
            for (int i = 0; ty == LUA_TTABLE && i < 3; i++) {
                ok &= lua_rawgeti(L, -1 - i, i + 1) == LUA_TNUMBER;
                dst3[k][i] = lua_tonumber(L, -1);
                ok &= isfinite(dst3[k][i]) != 0;
            }
            if (ty == LUA_TTABLE && !ok)
                return luaL_error(L,
                                  "%s: sim.control.next_needle.%s must be {x, y, z}: three "
                                  "finite numbers",
                                  r->sc.path, keys3[k]);
            if (ty == LUA_TTABLE)
                lua_pop(L, 3);
            lua_pop(L, 1);
            if (k < 2 && ty != LUA_TTABLE)
                return luaL_error(L, "%s: sim.control.next_needle.%s must be {x, y, z}", r->sc.path,
                                  keys3[k]);
        }
        io->ctl.next_needle = 1;
    }
    lua_pop(L, 1);
    lua_pushstring(L, "next_needle");
    lua_pushnil(L);
    lua_rawset(L, ci);
    /* act.drop_seed{} raises a one-shot flag */
    io->ctl.drop_seed = get_raw(L, ci, "drop_seed") != LUA_TNIL && lua_toboolean(L, -1);
    lua_pop(L, 1);
    lua_pushstring(L, "drop_seed");
    lua_pushnil(L);
    lua_rawset(L, ci);
    return 0;
}

/* One step of the script side. *more: the script has more to do; *ctl: the controls. */
static int script_tick(Run *r, double t, int exited, int *more, NsControl *ctl, char *err,
                       int err_sz)
{
    lua_State *L = ns_lua_state(r->sc.lua);
    TickIO io = {.r = r, .t = t, .exited = exited};
    lua_pushcfunction(L, tick_body);
    lua_pushlightuserdata(L, &io);
    int rc = ns_lua_call(r->sc.lua, 1, 0, err, err_sz);
    *more = io.more;
    *ctl = io.ctl;
    return rc;
}

/* ---- outputs ---- */

static char *path_join(const char *dir, const char *name)
{
    size_t n = strlen(dir) + strlen(name) + 2;
    char *p = malloc(n);
    if (p)
        snprintf(p, n, "%s/%s", dir, name);
    return p;
}

/* Creates DIR (and its parents) when missing, removes the report and trajectory of an earlier
 * run there (this run replaces them; a failed one leaves neither), and opens the trajectory's
 * temporary file, which also proves DIR writable before anything runs. */
static int prepare_outputs(Run *r, char *err, int err_sz)
{
    size_t n = strlen(r->opt.out_dir);
    if (n == 0) {
        ns_set_err(err, err_sz, "-o: the output folder must be named (got an empty path)");
        return -2;
    }
    char *path = malloc(n + 1);
    if (!path) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    memcpy(path, r->opt.out_dir, n + 1);
    for (size_t i = 1; i <= n; i++) { /* mkdir -p */
        if (path[i] != '/' && path[i] != '\0')
            continue;
        char c = path[i];
        path[i] = '\0';
        struct stat sb;
        if (stat(path, &sb) != 0) {
            if (mkdir(path, 0777) != 0) {
                ns_set_err(err, err_sz, "cannot create output folder '%s': %s", path,
                           strerror(errno));
                free(path);
                return -1;
            }
            if (c == '\0')
                r->made_dir = true;
        } else if (!S_ISDIR(sb.st_mode)) {
            ns_set_err(err, err_sz, "cannot create output folder '%s': '%s' is not a folder",
                       r->opt.out_dir, path);
            free(path);
            return -1;
        }
        path[i] = c;
    }
    free(path);
    r->traj_tmp = path_join(r->opt.out_dir, ".trajectory.csv.part");
    r->report_tmp = path_join(r->opt.out_dir, ".report.json.part");
    char *old_t = path_join(r->opt.out_dir, "trajectory.csv");
    char *old_r = path_join(r->opt.out_dir, "report.json");
    int rc = 0;
    if (!r->traj_tmp || !r->report_tmp || !old_t || !old_r) {
        ns_set_err(err, err_sz, "out of memory");
        rc = -1;
    }
    /* Every final name this run will replace must be a regular file (or absent), checked
     * before anything is removed: the run fails whole or not at all. */
    if (rc == 0 &&
        (ns_out_replaceable(old_t, "the trajectory", err, err_sz) ||
         ns_out_replaceable(old_r, "the report", err, err_sz) ||
         (r->opt.record && ns_out_replaceable(r->opt.record, "the control log", err, err_sz)) ||
         (r->opt.video && ns_out_replaceable(r->opt.video, "the video", err, err_sz))))
        rc = -1;
    if (rc == 0) {
        ns_out_remove_old(old_t);
        ns_out_remove_old(old_r);
    }
    free(old_t);
    free(old_r);
    if (rc == 0 && ns_run_render_clear_old(r->opt.out_dir, r->opt.frames, err, err_sz))
        rc = -1;
    if (rc == 0) {
        r->traj = ns_out_create_part(r->traj_tmp, "the trajectory", err, err_sz);
        if (!r->traj)
            rc = -1;
    }
    if (rc != 0 && r->made_dir) {
        rmdir(r->opt.out_dir);
        r->made_dir = false;
    }
    return rc;
}

static void write_traj_header(Run *r)
{
    fprintf(r->traj, "t_s,tip_x_m,tip_y_m,tip_z_m,depth_m,axial_force_n,v_insert_m_s,"
                     "twist_rate_rad_s,n_static,n_dyn_pos,n_dyn_neg,cutting");
    for (int i = 0; i < r->spec.marker_count; i++) {
        const char *n = r->spec.markers[i].name;
        fprintf(r->traj, ",%s_x_m,%s_y_m,%s_z_m", n, n, n);
    }
    fputc('\n', r->traj);
}

static void remove_outputs(Run *r)
{
    if (r->rec)
        fclose(r->rec);
    r->rec = NULL;
    if (r->rec_tmp)
        ns_out_remove_part(r->rec_tmp);
    if (r->traj)
        fclose(r->traj);
    r->traj = NULL;
    if (r->traj_tmp)
        ns_out_remove_part(r->traj_tmp);
    if (r->report_tmp)
        ns_out_remove_part(r->report_tmp);
    if (r->rendering) { /* also closes ffmpeg */
        ns_run_render_abort(&r->rr);
        r->rendering = false;
    }
    if (r->made_dir)
        rmdir(r->opt.out_dir); /* only if empty: it is ours */
}

static void stats_object(NsJson *j, const char *key, const Series *s)
{
    double lo, mean, hi;
    series_range(s, &lo, &mean, &hi);
    ns_json_key(j, key);
    ns_json_begin_object(j);
    ns_json_key(j, "min");
    ns_json_number(j, lo);
    ns_json_key(j, "mean");
    ns_json_number(j, mean);
    ns_json_key(j, "max");
    ns_json_number(j, hi);
    ns_json_end_object(j);
}

typedef struct TargetResult {
    double x[3], error_mm, score;
    bool hit, by_seed;
} TargetResult;

typedef struct SeedResult {
    double x[3], error_mm;
    int target;
} SeedResult;

typedef struct Results {
    TargetResult *targets;
    SeedResult *seeds;
    double (*markers)[3];
    double target_part, obstacle_penalty, total;
    int violated;
} Results;

/* The score (docs/scenarios.md, formula needlesim-score/1). Each target scores 100 when its
 * error is within its tolerance, falling linearly to 0 at five tolerances; its error is the
 * distance to the nearest seed released for it when there is one, else to the needle tip at
 * the end. The total is the mean over the targets (100 without targets) less 25 for each
 * obstacle the needle entered, kept within [0, 100]. */
static double target_score(double error_mm, double tol_mm)
{
    if (!isfinite(error_mm))
        return 0.0;
    if (error_mm <= tol_mm)
        return 100.0;
    return fmax(0.0, 100.0 * (1.0 - (error_mm - tol_mm) / (4.0 * tol_mm)));
}

static double dist_mm(const double *a, const double *b)
{
    double d[3] = {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
    return 1e3 * sqrt(dot3(d, d));
}

static int score_run(Run *r, Results *res)
{
    const NsRunSpec *sp = &r->spec;
    const NsMesh *M = &r->tissue.mesh;
    memset(res, 0, sizeof *res);
    res->targets = calloc((size_t)sp->target_count + 1, sizeof *res->targets);
    res->seeds = calloc((size_t)r->seed_n + 1, sizeof *res->seeds);
    res->markers = calloc((size_t)sp->marker_count + 1, sizeof *res->markers);
    if (!res->targets || !res->seeds || !res->markers)
        return -1;
    for (int i = 0; i < sp->target_count; i++) {
        TargetResult *t = &res->targets[i];
        t->error_mm = NAN;
        if (world_of(M, sp->targets[i].at, &r->target_hint[i], t->x) != 0)
            t->x[0] = t->x[1] = t->x[2] = NAN;
    }
    for (int k = 0; k < r->seed_n; k++) {
        SeedResult *sd = &res->seeds[k];
        if (world_of(M, r->seeds[k].u, &r->seeds[k].hint, sd->x) != 0)
            sd->x[0] = sd->x[1] = sd->x[2] = NAN;
        sd->target = r->seeds[k].target;
        if (sd->target < 0) { /* beyond the plan: the nearest target */
            double best = INFINITY;
            for (int i = 0; i < sp->target_count; i++) {
                double d = dist_mm(sd->x, res->targets[i].x);
                if (d < best) {
                    best = d;
                    sd->target = i;
                }
            }
        }
        sd->error_mm = sd->target >= 0 ? dist_mm(sd->x, res->targets[sd->target].x) : NAN;
        TargetResult *t = &res->targets[sd->target >= 0 ? sd->target : 0];
        if (sd->target >= 0 && (!t->by_seed || sd->error_mm < t->error_mm)) {
            t->error_mm = sd->error_mm;
            t->by_seed = true;
        }
    }
    res->target_part = 100.0;
    for (int i = 0; i < sp->target_count; i++) {
        TargetResult *t = &res->targets[i];
        if (!t->by_seed)
            t->error_mm = dist_mm(tip_of(r), t->x);
        double tol = 1e3 * sp->targets[i].tolerance;
        t->hit = isfinite(t->error_mm) && t->error_mm <= tol;
        t->score = target_score(t->error_mm, tol);
        res->target_part = i ? res->target_part + t->score : t->score;
    }
    if (sp->target_count)
        res->target_part /= sp->target_count;
    for (int k = 0; k < sp->obstacle_count; k++)
        res->violated += r->obst[k].violated;
    res->obstacle_penalty = 25.0 * res->violated;
    res->total = fmin(100.0, fmax(0.0, res->target_part - res->obstacle_penalty));
    for (int i = 0; i < sp->marker_count; i++) {
        int h = -1;
        if (world_of(M, sp->markers[i].at, &h, res->markers[i]) != 0)
            res->markers[i][0] = res->markers[i][1] = res->markers[i][2] = NAN;
    }
    return 0;
}

static void results_free(Results *res)
{
    free(res->targets);
    free(res->seeds);
    free(res->markers);
}

static void json_vec(NsJson *j, const char *key, const double *v)
{
    ns_json_key(j, key);
    ns_json_begin_array(j);
    for (int k = 0; k < 3; k++)
        ns_json_number(j, v[k]);
    ns_json_end_array(j);
}

static double series_mean(const Series *s)
{
    double lo, mean, hi;
    series_range(s, &lo, &mean, &hi);
    return mean;
}

/* The step's wall time (median, mean, p95, max) and each stage's median and mean per step
 * (the paper's Table 2 columns): the means show what the medians hide, the steps that rebuild
 * many Jacobians or refactor. */
static void timing_json(NsJson *j, const Run *r)
{
    ns_json_key(j, "step_ms");
    ns_json_begin_object(j);
    ns_json_key(j, "median");
    ns_json_number(j, series_quantile(&r->step_ms, 0.5));
    ns_json_key(j, "mean");
    ns_json_number(j, series_mean(&r->step_ms));
    ns_json_key(j, "p95");
    ns_json_number(j, series_quantile(&r->step_ms, 0.95));
    ns_json_key(j, "max");
    ns_json_number(j, series_quantile(&r->step_ms, 1.0));
    ns_json_end_object(j);
    const Series *st[5] = {&r->total_ms, &r->lcp_ms, &r->tissue_ms, &r->needle_ms, &r->remesh_ms};
    static const char *const stn[5] = {"total", "lcp", "tissue", "needle", "remesh"};
    for (int m = 0; m < 2; m++) {
        ns_json_key(j, m ? "stages_mean_ms" : "stages_ms");
        ns_json_begin_object(j);
        for (int k = 0; k < 5; k++) {
            ns_json_key(j, stn[k]);
            ns_json_number(j, m ? series_mean(st[k]) : series_quantile(st[k], 0.5));
        }
        ns_json_end_object(j);
    }
}

static int write_report(Run *r, const Results *res, uint64_t hash, char *err, int err_sz)
{
    FILE *f = ns_out_create_part(r->report_tmp, "the report", err, err_sz);
    if (!f)
        return -1;
    NsJson j;
    ns_json_init(&j, f, 2);
    ns_json_begin_object(&j);
    ns_json_key(&j, "schema");
    ns_json_string(&j, "needlesim-report/1");
    ns_json_key(&j, "scenario");
    ns_json_string(&j, r->sc.name);
    ns_json_key(&j, "scenario_file");
    ns_json_string(&j, r->sc.path);
    ns_json_key(&j, "version");
    ns_json_string(&j, NS_VERSION);
    ns_json_key(&j, "solver");
    ns_json_string(&j, ns_coupled_solver_name((NsCoupledSolverKind)r->opt.solver));
    ns_json_key(&j, "threads");
    ns_json_int(&j, r->opt.threads);
    ns_json_key(&j, "solver_settings"); /* what the step ran with (the scenario's solver = {}) */
    ns_json_begin_object(&j);
    ns_json_key(&j, "tolerance");
    ns_json_number(&j, r->c.params.tau_sol);
    ns_json_key(&j, "check_tolerance");
    ns_json_number(&j, r->c.params.tau_check);
    ns_json_key(&j, "lazy_threshold");
    ns_json_number(&j, r->tissue.params.lazy_threshold);
    ns_json_key(&j, "tip_block");
    ns_json_bool(&j, r->c.params.tip_block != 0);
    ns_json_end_object(&j);
    if (r->spec.accuracy > 0.0) { /* the scenario's accuracy = ... (docs/performance.md) */
        ns_json_key(&j, "accuracy");
        ns_json_begin_object(&j);
        ns_json_key(&j, "tip_m");
        ns_json_number(&j, r->spec.accuracy);
        ns_json_key(&j, "front");
        ns_json_string(&j, r->spec.accuracy_front);
        ns_json_key(&j, "chosen");
        ns_json_string(&j, r->spec.accuracy_label);
        ns_json_key(&j, "dt_s");
        ns_json_number(&j, r->spec.dt);
        ns_json_key(&j, "measured_tip_error_m");
        ns_json_number(&j, r->spec.accuracy_tip_error);
        ns_json_key(&j, "measured_cost_ms_per_s");
        ns_json_number(&j, r->spec.accuracy_cost);
        ns_json_end_object(&j);
    }
    ns_json_key(&j, "sets");
    ns_json_begin_array(&j);
    for (int i = 0; i < r->opt.nsets; i++)
        ns_json_string(&j, r->opt.sets[i]);
    ns_json_end_array(&j);
    ns_json_key(&j, "replayed_from");
    ns_json_string(&j, r->opt.replay ? r->opt.replay : "");
    ns_json_key(&j, "steps");
    ns_json_int(&j, r->steps);
    ns_json_key(&j, "script_finished");
    ns_json_bool(&j, r->script_finished);
    ns_json_key(&j, "time_limit_s"); /* > 0: the script was stopped at this simulated time */
    ns_json_number(&j, r->time_capped ? NS_LIMIT_DEFAULT_SIM_TIME : 0.0);
    ns_json_key(&j, "dt_s");
    ns_json_number(&j, r->spec.dt);
    ns_json_key(&j, "sim_time_s");
    ns_json_number(&j, (double)r->steps * r->spec.dt);
    ns_json_key(&j, "wall_time_s");
    ns_json_number(&j, r->wall_s);
    timing_json(&j, r);
    stats_object(&j, "lcp_trials", &r->trials);
    stats_object(&j, "cg_iterations", &r->iterations);
    ns_json_key(&j, "factorizations");
    ns_json_int(&j, r->factorizations);
    ns_json_key(&j, "friction_consistent_fraction");
    ns_json_number(&j, r->steps ? (double)r->consistent / (double)r->steps : 1.0);
    const NsMesh *M = &r->tissue.mesh;
    NsQualityStats q;
    ns_mesh_quality(M, false, &q);
    ns_json_key(&j, "mesh");
    ns_json_begin_object(&j);
    ns_json_key(&j, "tets");
    ns_json_int(&j, M->tet_alive);
    ns_json_key(&j, "nodes");
    ns_json_int(&j, M->node_alive);
    ns_json_key(&j, "min_dihedral_deg");
    ns_json_number(&j, q.min_dihedral_deg);
    ns_json_key(&j, "max_dihedral_deg");
    ns_json_number(&j, q.max_dihedral_deg);
    ns_json_key(&j, "remesh_repaired_nodes");
    ns_json_int(&j, r->repaired);
    ns_json_end_object(&j);
    ns_json_key(&j, "needle");
    ns_json_begin_object(&j);
    ns_json_key(&j, "kind");
    ns_json_string(&j, r->spec.needle_kind);
    ns_json_key(&j, "tip_m");
    ns_json_begin_array(&j);
    for (int k = 0; k < 3; k++)
        ns_json_number(&j, tip_of(r)[k]);
    ns_json_end_array(&j);
    ns_json_key(&j, "depth_m");
    ns_json_number(&j, depth_of(r));
    ns_json_key(&j, "max_axial_force_n");
    ns_json_number(&j, r->max_axial);
    ns_json_key(&j, "path_cut_m");
    ns_json_number(&j, r->path_cut);
    ns_json_end_object(&j);
    ns_json_key(&j, "targets");
    ns_json_begin_array(&j);
    for (int i = 0; i < r->spec.target_count; i++) {
        const NsRunTarget *t = &r->spec.targets[i];
        const TargetResult *tr = &res->targets[i];
        ns_json_begin_object(&j);
        ns_json_key(&j, "name");
        ns_json_string(&j, t->name);
        ns_json_key(&j, "error_mm");
        ns_json_number(&j, tr->error_mm);
        ns_json_key(&j, "tolerance_mm");
        ns_json_number(&j, 1e3 * t->tolerance);
        ns_json_key(&j, "hit");
        ns_json_bool(&j, tr->hit);
        ns_json_key(&j, "by");
        ns_json_string(&j, tr->by_seed ? "seed" : "tip");
        json_vec(&j, "position_m", tr->x);
        ns_json_end_object(&j);
    }
    ns_json_end_array(&j);
    ns_json_key(&j, "seeds");
    ns_json_begin_array(&j);
    for (int k = 0; k < r->seed_n; k++) {
        const SeedResult *sd = &res->seeds[k];
        ns_json_begin_object(&j);
        ns_json_key(&j, "target");
        ns_json_string(&j, sd->target >= 0 ? r->spec.targets[sd->target].name : "");
        ns_json_key(&j, "error_mm");
        ns_json_number(&j, sd->error_mm);
        ns_json_key(&j, "released_s");
        ns_json_number(&j, r->seeds[k].t);
        json_vec(&j, "position_m", sd->x);
        ns_json_end_object(&j);
    }
    ns_json_end_array(&j);
    ns_json_key(&j, "seeds_planned");
    ns_json_int(&j, r->spec.seed_count);
    ns_json_key(&j, "obstacles");
    ns_json_begin_array(&j);
    for (int k = 0; k < r->spec.obstacle_count; k++) {
        const struct Obstacle *o = &r->obst[k];
        ns_json_begin_object(&j);
        ns_json_key(&j, "name");
        ns_json_string(&j, r->spec.obstacles[k].name);
        ns_json_key(&j, "region");
        ns_json_string(&j, r->sc.regions[r->spec.obstacles[k].region].name);
        ns_json_key(&j, "violated");
        ns_json_bool(&j, o->violated);
        ns_json_key(&j, "max_depth_mm");
        ns_json_number(&j, 1e3 * o->max_depth);
        ns_json_key(&j, "first_s");
        ns_json_number(&j, o->violated ? o->first_t : 0.0);
        ns_json_key(&j, "steps_inside");
        ns_json_int(&j, o->steps_inside);
        ns_json_end_object(&j);
    }
    ns_json_end_array(&j);
    ns_json_key(&j, "markers");
    ns_json_begin_array(&j);
    for (int i = 0; i < r->spec.marker_count; i++) {
        ns_json_begin_object(&j);
        ns_json_key(&j, "name");
        ns_json_string(&j, r->spec.markers[i].name);
        json_vec(&j, "position_m", res->markers[i]);
        ns_json_key(&j, "displacement_mm");
        ns_json_number(&j, dist_mm(res->markers[i], r->spec.markers[i].at));
        ns_json_end_object(&j);
    }
    ns_json_end_array(&j);
    ns_json_key(&j, "score");
    ns_json_begin_object(&j);
    ns_json_key(&j, "formula");
    ns_json_string(&j, "needlesim-score/1");
    ns_json_key(&j, "total");
    ns_json_number(&j, res->total);
    ns_json_key(&j, "targets");
    ns_json_number(&j, res->target_part);
    ns_json_key(&j, "obstacle_penalty");
    ns_json_number(&j, res->obstacle_penalty);
    ns_json_key(&j, "obstacles_violated");
    ns_json_int(&j, res->violated);
    ns_json_key(&j, "insertions");
    ns_json_int(&j, r->insertions);
    ns_json_key(&j, "path_cut_mm");
    ns_json_number(&j, 1e3 * r->path_cut);
    ns_json_key(&j, "peak_axial_force_n");
    ns_json_number(&j, r->max_axial);
    ns_json_key(&j, "duration_s");
    ns_json_number(&j, (double)r->steps * r->spec.dt);
    ns_json_end_object(&j);
    ns_json_key(&j, "events");
    ns_json_begin_array(&j);
    for (int i = 0; i < r->event_n; i++) {
        const struct Event *e = &r->events[i];
        ns_json_begin_object(&j);
        ns_json_key(&j, "t_s");
        ns_json_number(&j, e->t);
        ns_json_key(&j, "type");
        ns_json_string(&j, event_names[e->type]);
        ns_json_key(&j, "tip_m");
        ns_json_begin_array(&j);
        for (int k = 0; k < 3; k++)
            ns_json_number(&j, e->x[k]);
        ns_json_end_array(&j);
        if (e->type == EVENT_BONE_CONTACT) {
            ns_json_key(&j, "region");
            ns_json_string(&j, event_region(r, e));
        }
        ns_json_end_object(&j);
    }
    ns_json_end_array(&j);
    ns_json_key(&j, "warnings");
    ns_json_begin_object(&j);
    ns_json_key(&j, "nan");
    ns_json_int(&j, r->nan);
    ns_json_key(&j, "inverted");
    ns_json_int(&j, r->inverted);
    ns_json_key(&j, "unconverged");
    ns_json_int(&j, r->unconverged);
    ns_json_key(&j, "lcp_unresolved");
    ns_json_int(&j, r->lcp_unresolved);
    ns_json_end_object(&j);
    char h[32];
    snprintf(h, sizeof h, "%016llx", (unsigned long long)hash);
    ns_json_key(&j, "render");
    ns_json_begin_object(&j);
    ns_json_key(&j, "enabled");
    ns_json_bool(&j, r->rendering);
    if (r->rendering) {
        double rm, em;
        ns_run_render_medians(&r->rr, &rm, &em);
        ns_json_key(&j, "info");
        ns_json_string(&j, ns_renderer_info(r->rr.frame.gl));
        ns_json_key(&j, "width");
        ns_json_int(&j, r->rr.o.width);
        ns_json_key(&j, "height");
        ns_json_int(&j, r->rr.o.height);
        ns_json_key(&j, "frames");
        ns_json_int(&j, r->rr.frame_count);
        ns_json_key(&j, "frame_every");
        ns_json_int(&j, r->every);
        ns_json_key(&j, "fps");
        ns_json_number(&j, r->rr.o.fps);
        ns_json_key(&j, "video");
        ns_json_string(&j, r->opt.video ? r->opt.video : "");
        ns_json_key(&j, "moments");
        ns_json_int(&j, r->rr.moment_count);
        ns_json_key(&j, "render_ms_median");
        ns_json_number(&j, rm);
        ns_json_key(&j, "encode_ms_median");
        ns_json_number(&j, em);
        ns_json_key(&j, "ffmpeg_cpu_ms_per_frame");
        ns_json_number(&j, r->opt.video && r->rr.frame_count
                               ? 1e3 * r->rr.ffmpeg_cpu_s / (double)r->rr.frame_count
                               : 0.0);
        ns_json_key(&j, "render_s");
        ns_json_number(&j, r->rr.render_s);
        ns_json_key(&j, "share_of_wall");
        ns_json_number(&j, r->rr.render_s / fmax(r->wall_s + r->end_s, 1e-9));
    }
    ns_json_end_object(&j);
    ns_json_key(&j, "state_hash");
    ns_json_string(&j, h);
    ns_json_end_object(&j);
    fputc('\n', f);
    if (fclose(f) != 0) {
        ns_set_err(err, err_sz, "cannot write '%s': %s", r->report_tmp, strerror(errno));
        return -1;
    }
    return 0;
}

/* ---- seeds and obstacles ---- */

/* Releases a seed at the needle tip: the tissue's material point there, which the tissue then
 * carries (a seed is far smaller than an element and is not modelled as a body). The i-th
 * seed released takes the seed plan's i-th target; beyond the plan, the nearest target at the
 * end. */
static int release_seed(Run *r, double t, char *err, int err_sz)
{
    if (r->spec.target_count == 0) {
        ns_set_err(err, err_sz,
                   "%s: act.drop_seed at t = %.3f s: the scenario has no targets "
                   "for seeds",
                   r->sc.path, t);
        return -1;
    }
    const NsMesh *M = &r->tissue.mesh;
    double b[4];
    int tet = ns_mesh_locate_in(M, M->x, tip_of(r), r->tip_hint, 1e-6, b);
    if (tet < 0) {
        ns_set_err(err, err_sz,
                   "%s: act.drop_seed at t = %.3f s: the needle tip is not in the "
                   "tissue",
                   r->sc.path, t);
        return -1;
    }
    r->tip_hint = tet;
    if (r->seed_n == r->seed_cap) {
        int cap = r->seed_cap ? 2 * r->seed_cap : 16;
        struct Seed *sd = realloc(r->seeds, (size_t)cap * sizeof *sd);
        if (!sd) {
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
        r->seeds = sd;
        r->seed_cap = cap;
    }
    struct Seed *sd = &r->seeds[r->seed_n];
    const int *tn = M->tet_node + 4 * tet;
    for (int i = 0; i < 3; i++)
        sd->u[i] = b[0] * M->u[3 * tn[0] + i] + b[1] * M->u[3 * tn[1] + i] +
                   b[2] * M->u[3 * tn[2] + i] + b[3] * M->u[3 * tn[3] + i];
    sd->t = t;
    sd->target = r->seed_n < r->spec.seed_count ? r->spec.seed_target[r->seed_n] : -1;
    sd->hint = tet;
    r->seed_n++;
    return 0;
}

/* Is the needle inside an obstacle's region? The point 0.1 mm behind the tip along the needle
 * is located in the deformed tissue (the tip itself sits on a mesh node, shared by the regions
 * around it); the depth is how far the tip got from where it went in. */
static void check_obstacles(Run *r, double t, int exited)
{
    if (r->spec.obstacle_count == 0)
        return;
    const NsMesh *M = &r->tissue.mesh;
    const double *x = r->rod.x;
    int n = r->rod.nodes;
    const double *tip = x + 3 * (n - 1), *prev = x + 3 * (n - 2);
    double e[3] = {tip[0] - prev[0], tip[1] - prev[1], tip[2] - prev[2]};
    double le = sqrt(dot3(e, e)), p[3];
    for (int i = 0; i < 3; i++)
        p[i] = tip[i] - 1e-4 * e[i] / (le > 0.0 ? le : 1.0);
    int tet = exited ? -1 : ns_mesh_locate_in(M, M->x, p, r->tip_hint, 1e-9, NULL);
    if (tet >= 0)
        r->tip_hint = tet;
    int region = tet >= 0 ? M->tet_region[tet] : -1;
    for (int k = 0; k < r->spec.obstacle_count; k++) {
        struct Obstacle *o = &r->obst[k];
        bool in = region >= 0 && region == r->spec.obstacles[k].region;
        if (in && !o->inside) {
            memcpy(o->entry, tip, sizeof o->entry);
            if (!o->violated)
                o->first_t = t;
            o->violated = true;
        }
        o->inside = in;
        if (in) {
            double d[3] = {tip[0] - o->entry[0], tip[1] - o->entry[1], tip[2] - o->entry[2]};
            o->max_depth = fmax(o->max_depth, sqrt(dot3(d, d)));
            o->steps_inside++;
        }
    }
}

/* ---- pictures (issue 8, docs/rendering.md) ---- */

/* Opens the renderer once the tissue and the needle are built: the camera frames the tissue
 * and the needle as they start. */
static int render_setup(Run *r, char *err, int err_sz)
{
    const NsRunCamera *cam = &r->spec.camera;
    const NsMesh *M = &r->tissue.mesh;
    r->every = r->opt.frame_every > 0 ? r->opt.frame_every : cam->frame_every;
    for (int i = 0; i < 3; i++) {
        r->bounds[i] = INFINITY;
        r->bounds[3 + i] = -INFINITY;
    }
    for (int k = 0; k < M->node_slots + r->rod.nodes; k++) {
        const double *x = k < M->node_slots ? M->x + 3 * k : r->rod.x + 3 * (k - M->node_slots);
        if (k < M->node_slots && M->node_tets[k].count == 0)
            continue; /* a free slot */
        for (int i = 0; i < 3; i++) {
            r->bounds[i] = fmin(r->bounds[i], x[i]);
            r->bounds[3 + i] = fmax(r->bounds[3 + i], x[i]);
        }
    }
    int regions = r->sc.region_count > 0 ? r->sc.region_count : 1;
    r->obstacle_region = calloc((size_t)regions, sizeof *r->obstacle_region);
    r->reached = calloc((size_t)r->spec.target_count + 1, sizeof *r->reached);
    if (!r->obstacle_region || !r->reached) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    for (int k = 0; k < r->spec.obstacle_count; k++)
        if (r->spec.obstacles[k].region < regions)
            r->obstacle_region[r->spec.obstacles[k].region] = true;
    NsRunRenderOpts o = {.out_dir = r->opt.out_dir,
                         .frames = r->opt.frames,
                         .video = r->opt.video,
                         .summary = true,
                         .width = r->opt.width,
                         .height = r->opt.height,
                         .fps = cam->fps,
                         .nviews = cam->view_count,
                         .legend = cam->friction_colours};
    memcpy(o.views, cam->views, sizeof o.views);
    if (ns_run_render_open(&r->rr, &o, err, err_sz)) {
        ns_run_render_abort(&r->rr); /* what it made before it failed */
        return -1;
    }
    r->rendering = true;
    return 0;
}

/* Keeps the tets as they are before a step: the frame after it highlights what changed. */
static int render_before_step(Run *r)
{
    const NsMesh *M = &r->tissue.mesh;
    if (M->tet_slots > r->prev_cap) {
        int cap = M->tet_slots + M->tet_slots / 2;
        int *p = realloc(r->prev_tet_node, (size_t)cap * 4 * sizeof *p);
        uint8_t *c = p ? realloc(r->changed, (size_t)cap) : NULL;
        if (p)
            r->prev_tet_node = p;
        if (c)
            r->changed = c;
        if (!p || !c)
            return -1;
        r->prev_cap = cap;
    }
    memcpy(r->prev_tet_node, M->tet_node, (size_t)M->tet_slots * 4 * sizeof(int));
    r->prev_slots = M->tet_slots;
    return 0;
}

/* A frame (caption NULL) or a key moment of the current state. res: the state's results
 * (score_run), or NULL to have them worked out here. */
static int render_now(Run *r, const char *caption, bool final, const Results *res_in, char *err,
                      int err_sz)
{
    const NsRunSpec *sp = &r->spec;
    const NsMesh *M = &r->tissue.mesh;
    Results own;
    const Results *res = res_in;
    if (M->tet_slots > r->prev_cap) { /* the step added tets: room to mark them */
        uint8_t *c = realloc(r->changed, (size_t)M->tet_slots);
        if (!c) {
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
        r->changed = c;
    }
    if (!res) {
        /* score_run moves the lookups' starting tets (hints); a target on a face between two
         * tets may then be found in the other one, and the final score would depend on the
         * frames drawn. Drawing leaves them as they were. */
        int nt = sp->target_count,
            *hints = malloc(((size_t)nt + (size_t)r->seed_n + 1) * sizeof *hints);
        if (!hints) {
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
        memcpy(hints, r->target_hint, (size_t)nt * sizeof *hints);
        for (int k = 0; k < r->seed_n; k++)
            hints[nt + k] = r->seeds[k].hint;
        int bad = score_run(r, &own);
        memcpy(r->target_hint, hints, (size_t)nt * sizeof *hints);
        for (int k = 0; k < r->seed_n; k++)
            r->seeds[k].hint = hints[nt + k];
        free(hints);
        if (bad) {
            results_free(&own);
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
        res = &own;
    }
    int nt = sp->target_count, ns = r->seed_n, nm = sp->marker_count;
    double *buf = malloc((size_t)(4 * nt + 3 * ns + 3 * nm + 1) * sizeof *buf);
    bool *hit = malloc((size_t)nt + 1);
    int rc = 0;
    if (!buf || !hit) {
        ns_set_err(err, err_sz, "out of memory");
        rc = -1;
    }
    NsSceneInput in;
    memset(&in, 0, sizeof in);
    double near = INFINITY;
    int near_i = -1;
    if (rc == 0) {
        double *tx = buf, *tr = buf + 3 * nt, *sx = tr + nt, *mx = sx + 3 * ns;
        for (int i = 0; i < nt; i++) {
            memcpy(tx + 3 * i, res->targets[i].x, 3 * sizeof(double));
            tr[i] = sp->targets[i].tolerance;
            hit[i] = res->targets[i].hit;
            double d = dist_mm(tip_of(r), res->targets[i].x);
            if (d < near) {
                near = d;
                near_i = i;
            }
        }
        for (int k = 0; k < ns; k++)
            memcpy(sx + 3 * k, res->seeds[k].x, 3 * sizeof(double));
        for (int k = 0; k < nm; k++)
            memcpy(mx + 3 * k, res->markers[k], 3 * sizeof(double));
        for (int e = 0; r->changed && e < M->tet_slots; e++)
            r->changed[e] =
                M->tet_node[4 * e] >= 0 &&
                (e >= r->prev_slots ||
                 memcmp(M->tet_node + 4 * e, r->prev_tet_node + 4 * e, 4 * sizeof(int)) != 0);
        in.mesh = M;
        in.changed = r->changed && r->prev_slots > 0 ? r->changed : NULL;
        in.obstacle_region = r->obstacle_region;
        in.regions = r->sc.region_count;
        in.rod_x = r->rod.x;
        in.rod_nodes = r->rod.nodes;
        in.rod_radius = 0.5 * sp->diameter;
        in.state = sp->camera.friction_colours ? r->c.state : NULL;
        in.cutting = r->last_cutting != 0;
        in.bevel = sp->bevel;
        if (sp->bevel) {
            double t[3], m1[3];
            ns_rod_tip_frame(&r->rod, t, m1, in.m2);
        }
        in.held = r->rod.held;
        in.target_x = tx;
        in.target_r = tr;
        in.target_hit = hit;
        in.targets = nt;
        in.seed_x = sx;
        in.seeds = ns;
        in.marker_x = mx;
        in.markers = nm;
        memcpy(in.axis, sp->entry_dir, sizeof in.axis);
        memcpy(in.entry, sp->entry_point, sizeof in.entry);
        memcpy(in.bounds, r->bounds, sizeof in.bounds);
        in.has_cut_normal = sp->camera.has_cut_normal;
        memcpy(in.cut_normal, sp->camera.cut_normal, sizeof in.cut_normal);
        in.tet_edges = sp->camera.tet_edges;
    }
    char l0[160], l1[160], l2[160], l3[160];
    snprintf(l0, sizeof l0, "%s%s", r->sc.name, r->opt.replay ? " (replay)" : "");
    snprintf(l1, sizeof l1, "t %.2f s   depth %.1f mm   axial force %.2f N",
             (double)r->steps * sp->dt, 1e3 * depth_of(r), r->last_axial);
    if (near_i >= 0)
        snprintf(l2, sizeof l2, "nearest target %s: %.1f mm", sp->targets[near_i].name, near);
    else
        snprintf(l2, sizeof l2, "no targets");
    snprintf(l3, sizeof l3, "score so far %.1f / 100   seeds %d of %d", res->total, r->seed_n,
             sp->seed_count);
    const char *hud[4] = {l0, l1, l2, l3};
    if (rc == 0)
        rc = caption ? ns_run_render_moment(&r->rr, &in, hud, 4, caption, final, err, err_sz)
                     : ns_run_render_frame(&r->rr, &in, hud, 4, err, err_sz);
    free(buf);
    free(hit);
    if (!res_in)
        results_free(&own);
    return rc;
}

/* After a step: the key moments (entry, a seed released, the tip reaching a target, a
 * puncture: the axial force falling by 40 % from its peak while the tip cuts on) and the
 * frame. */
static int render_after_step(Run *r, const NsCouplingStats *st, bool dropped, char *err, int err_sz)
{
    const NsRunSpec *sp = &r->spec;
    double t = (double)r->steps * sp->dt;
    char cap[96];
    if (st->cutting && !r->entered) {
        r->entered = true;
        snprintf(cap, sizeof cap, "entry, t = %.2f s", t);
        if (render_now(r, cap, false, NULL, err, err_sz))
            return -1;
    }
    if (dropped) {
        snprintf(cap, sizeof cap, "seed %d released, t = %.2f s", r->seed_n, t);
        if (render_now(r, cap, false, NULL, err, err_sz))
            return -1;
    }
    for (int i = 0; i < sp->target_count; i++) {
        if (r->reached[i])
            continue;
        double x[3];
        int h = r->target_hint[i];
        if (world_of(&r->tissue.mesh, sp->targets[i].at, &h, x) == 0 &&
            dist_mm(tip_of(r), x) <= 1e3 * sp->targets[i].tolerance) {
            r->reached[i] = true;
            snprintf(cap, sizeof cap, "tip reaches %s, t = %.2f s", sp->targets[i].name, t);
            if (render_now(r, cap, false, NULL, err, err_sz))
                return -1;
        }
    }
    /* a puncture: the tip cut on, through the membrane, with much less force */
    double f = fabs(st->axial_force);
    if (r->punctures < 3 && st->cutting && r->peak_axial > 0.05 && f < 0.6 * r->peak_axial) {
        snprintf(cap, sizeof cap, "puncture: axial force %.2f -> %.2f N, t = %.2f s", r->peak_axial,
                 f, t);
        r->punctures++;
        r->peak_axial = f;
        if (render_now(r, cap, false, NULL, err, err_sz))
            return -1;
    }
    r->peak_axial = st->cutting ? fmax(r->peak_axial, f) : 0.0;
    bool frames = r->opt.frames || r->opt.video;
    if (frames && r->steps % r->every == 0 && render_now(r, NULL, false, NULL, err, err_sz))
        return -1;
    return 0;
}

/* The run's end: its last frame, the end moment and the contact sheet with the score table. */
static int render_end(Run *r, const Results *res, char *err, int err_sz)
{
    const NsRunSpec *sp = &r->spec;
    bool frames = r->opt.frames || r->opt.video;
    if (frames && r->steps % r->every != 0 && render_now(r, NULL, false, res, err, err_sz))
        return -1;
    char cap[96], missed[64] = "";
    for (int i = 0; i < sp->target_count; i++)
        if (!res->targets[i].hit)
            snprintf(missed + strlen(missed), sizeof missed - strlen(missed), "%s%s",
                     missed[0] ? ", " : " (missed: ", sp->targets[i].name);
    if (missed[0])
        snprintf(missed + strlen(missed), sizeof missed - strlen(missed), ")");
    snprintf(cap, sizeof cap, "end, t = %.2f s%s", (double)r->steps * sp->dt, missed);
    if (render_now(r, cap, true, res, err, err_sz))
        return -1;
    enum { ROWS = 32 };
    char rows[ROWS][128];
    int n = 0;
    if (sp->target_count)
        snprintf(rows[n++], sizeof rows[0], "%-22s %9s %8s %5s %4s", "target", "error mm", "tol mm",
                 "by", "hit");
    for (int i = 0; i < sp->target_count && n < ROWS - 4; i++)
        snprintf(rows[n++], sizeof rows[0], "%-22.22s %9.2f %8.2f %5s %4s", sp->targets[i].name,
                 res->targets[i].error_mm, 1e3 * sp->targets[i].tolerance,
                 res->targets[i].by_seed ? "seed" : "tip", res->targets[i].hit ? "yes" : "no");
    if (sp->seed_count || r->seed_n)
        snprintf(rows[n++], sizeof rows[0], "seeds released %d of %d planned", r->seed_n,
                 sp->seed_count);
    for (int k = 0; k < sp->obstacle_count && n < ROWS - 2; k++)
        if (r->obst[k].violated)
            snprintf(rows[n++], sizeof rows[0], "obstacle %s entered at t = %.2f s, %.1f mm deep",
                     sp->obstacles[k].name, r->obst[k].first_t, 1e3 * r->obst[k].max_depth);
    snprintf(rows[n++], sizeof rows[0],
             "score %.1f / 100 (targets %.1f, obstacles -%.0f); insertions %d", res->total,
             res->target_part, res->obstacle_penalty, r->insertions);
    snprintf(rows[n++], sizeof rows[0],
             "warnings: NaN %d, inverted %d, unconverged %d, friction unresolved %d", r->nan,
             r->inverted, r->unconverged, r->lcp_unresolved);
    const char *table[ROWS];
    for (int i = 0; i < n; i++)
        table[i] = rows[i];
    char title[160];
    snprintf(title, sizeof title, "%s: score %.1f / 100, %ld steps, %.2f s", r->sc.name, res->total,
             r->steps, (double)r->steps * sp->dt);
    return ns_run_render_finish(&r->rr, title, table, n, err, err_sz);
}

/* ---- the loop ---- */

static void progress(const Run *r, long total, double t)
{
    int width = 30, filled = total > 0 ? (int)(width * r->steps / total) : 0;
    char bar[64];
    for (int i = 0; i < width; i++)
        bar[i] = i < filled ? '#' : total > 0 ? '.' : (i == (int)(r->steps % width) ? '#' : '.');
    bar[width] = '\0';
    fprintf(stderr, "\r[%s] step %ld, t = %.3f s, depth %.1f mm ", bar, r->steps, t,
            1e3 * depth_of(r));
    fflush(stderr);
}

static int run_loop(Run *r, char *err, int err_sz)
{
    const NsRunSpec *sp = &r->spec;
    /* A run ends after --steps, after the scenario's duration, or when the script ends; a
     * script that has not ended after NS_LIMIT_DEFAULT_SIM_TIME of simulated time (act.wait in
     * a loop) is stopped there, and the report says it had not finished. */
    long max_steps = r->opt.steps > 0 ? r->opt.steps : 0;
    if (max_steps > NS_LIMIT_STEPS) {
        ns_set_err(err, err_sz, "--steps %ld: at most %ld", max_steps, NS_LIMIT_STEPS);
        return -1;
    }
    if (max_steps == 0 && sp->duration > 0.0) {
        double n = ceil(sp->duration / sp->dt - 1e-9);
        if (!(n <= (double)NS_LIMIT_STEPS)) {
            ns_set_err(err, err_sz, "%s: ns.scenario: duration / dt is %.3g steps (at most %ld)",
                       r->sc.where, n, NS_LIMIT_STEPS);
            return -1;
        }
        max_steps = (long)n;
    }
    double cap_n = ceil(NS_LIMIT_DEFAULT_SIM_TIME / sp->dt - 1e-9);
    long time_cap = cap_n < (double)NS_LIMIT_STEPS ? (long)cap_n : NS_LIMIT_STEPS;
    memcpy(r->last_tip, tip_of(r), sizeof r->last_tip);
    bool tty = !r->opt.quiet && isatty(fileno(stderr));
    int more = 1;
    r->needles = 1;
    double t0 = now_s();
    if (r->rendering && (r->opt.frames || r->opt.video) &&
        render_now(r, NULL, false, NULL, err, err_sz))
        return -1;
    while (max_steps > 0 ? r->steps < max_steps : more) {
        if (ns_cleanup_signal() != 0) {
            ns_set_err(err, err_sz, "%s: interrupted at step %ld (signal %d); nothing written",
                       r->sc.path, r->steps, ns_cleanup_signal());
            return -1;
        }
        if (max_steps == 0 && r->steps >= time_cap) {
            r->time_capped = true;
            fprintf(stderr,
                    "%s: the script had not ended after %g s of simulated time (the limit for a "
                    "scenario without a duration): stopped there\n",
                    r->sc.path, NS_LIMIT_DEFAULT_SIM_TIME);
            break;
        }
        double t = (double)r->steps * sp->dt;
        NsControl ctl;
        memset(&ctl, 0, sizeof ctl);
        if (r->opt.replay) { /* the log drives the needle instead of the script */
            more = r->steps < r->replay.n;
            if (!more && max_steps > 0) {
                ns_set_err(err, err_sz, "%s: the log ends after %ld steps, before the run's %ld",
                           r->opt.replay, r->replay.n, max_steps);
                return -1;
            }
            if (more)
                ctl = r->replay.rows[r->steps];
        } else if (script_tick(r, t, r->exited, &more, &ctl, err, err_sz)) {
            return -1;
        }
        /* The script ended at this tick: nothing of it is applied, recorded or stepped. */
        if ((max_steps == 0 || r->stop_when_done) && !more)
            break;
        if (r->rec)
            ns_control_log_write_row(r->rec, t, &ctl);
        if (ctl.next_needle && next_needle(r, &ctl.entry, t, err, err_sz))
            return -1;
        NsStepControls step_ctl = ns_step_controls(ctl.v_insert, ctl.v_base, ctl.twist_rate);
        if (ctl.drop_seed && release_seed(r, t, err, err_sz))
            return -1;
        if (ctl.v_insert > 0.0 && r->prev_v <= 0.0)
            r->insertions++;
        r->prev_v = ctl.v_insert;
        if (r->rendering && render_before_step(r)) {
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
        NsCouplingStats st;
        double w0 = now_s();
        int rc = ns_step(&r->c, &step_ctl, sp->dt, &st);
        double w = 1e3 * (now_s() - w0);
        r->nan += st.nan_count;
        if (rc) {
            const double *tp = tip_of(r);
            const NsMesh *M = &r->tissue.mesh;
            bool outside = ns_mesh_locate_in(M, M->x, tp, r->tip_hint, 1e-6, NULL) < 0;
            ns_set_err(err, err_sz,
                       "%s: step %ld (t = %.4f s, tip at (%.1f, %.1f, %.1f) mm, depth %.1f mm) "
                       "failed: %s (NaN %d, inverted %d, unconverged %d)",
                       r->sc.path, r->steps, t, 1e3 * tp[0], 1e3 * tp[1], 1e3 * tp[2],
                       1e3 * depth_of(r),
                       outside         ? "the needle tip left the tissue other than through its "
                                         "entry or out through its surface"
                       : r->c.error[0] ? r->c.error
                                       : "the coupled step did not produce a valid state",
                       st.nan_count, st.inverted, st.unconverged);
            return -1;
        }
        r->steps++;
        if (record_events(r, &st, (double)r->steps * sp->dt, tip_of(r))) {
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
        r->exited |= st.exited;
        r->inverted += st.inverted;
        r->repaired += st.remesh_repaired;
        r->unconverged += st.unconverged;
        r->consistent += st.consistent != 0;
        r->lcp_unresolved += st.consistent == 0;
        r->max_axial = fmax(r->max_axial, fabs(st.axial_force));
        r->last_axial = st.axial_force;
        r->last_fr[0] = st.n_static;
        r->last_fr[1] = st.n_dyn_pos;
        r->last_fr[2] = st.n_dyn_neg;
        r->last_cutting = st.cutting;
        const double *tp = tip_of(r);
        if (st.cutting) { /* the length of tissue cut: the tip's path */
            double d[3] = {tp[0] - r->last_tip[0], tp[1] - r->last_tip[1], tp[2] - r->last_tip[2]};
            r->path_cut += sqrt(dot3(d, d));
        }
        memcpy(r->last_tip, tp, sizeof r->last_tip);
        if (series_push(&r->step_ms, w) || series_push(&r->total_ms, st.total_ms) ||
            series_push(&r->lcp_ms, st.lcp_ms) || series_push(&r->tissue_ms, st.tissue_ms) ||
            series_push(&r->needle_ms, st.needle_ms) || series_push(&r->remesh_ms, st.remesh_ms) ||
            series_push(&r->trials, st.trials) || series_push(&r->iterations, st.iterations)) {
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
        r->factorizations += st.refactors;
        const double *tip = tip_of(r);
        if (r->log_tips && (series_push(&r->tips[0], tip[0]) || series_push(&r->tips[1], tip[1]) ||
                            series_push(&r->tips[2], tip[2]))) {
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
        if (r->traj)
            fprintf(r->traj, "%.6f,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%d,%d,%d,%d",
                    (double)r->steps * sp->dt, tip[0], tip[1], tip[2], depth_of(r), st.axial_force,
                    r->rod.v_insert, r->rod.twist_rate, st.n_static, st.n_dyn_pos, st.n_dyn_neg,
                    st.cutting);
        for (int i = 0; r->traj && i < sp->marker_count; i++) {
            double x[3] = {NAN, NAN, NAN};
            world_of(&r->tissue.mesh, sp->markers[i].at, &r->marker_hint[i], x);
            fprintf(r->traj, ",%.9g,%.9g,%.9g", x[0], x[1], x[2]);
        }
        if (r->traj)
            fputc('\n', r->traj);
        check_obstacles(r, (double)r->steps * sp->dt, r->exited);
        if (r->rendering && render_after_step(r, &st, ctl.drop_seed, err, err_sz))
            return -1;
        if (tty && (r->steps % 10 == 0)) {
            progress(r, max_steps, (double)r->steps * sp->dt);
            r->progress_shown = true;
        }
    }
    r->script_finished = !r->time_capped && (!more || !sp->has_script || r->opt.replay);
    if (r->progress_shown)
        fputs("\r\033[K", stderr);
    r->progress_shown = false;
    r->wall_s = now_s() - t0;
    return 0;
}

static void run_free(Run *r)
{
    if (r->rendering)
        ns_run_render_free(&r->rr);
    free(r->prev_tet_node);
    free(r->changed);
    free(r->obstacle_region);
    free(r->reached);
    lua_State *L = r->have_sc ? ns_lua_state(r->sc.lua) : NULL;
    if (L && r->sim_ref != LUA_NOREF)
        luaL_unref(L, LUA_REGISTRYINDEX, r->sim_ref);
    if (L && r->act_ref != LUA_NOREF)
        luaL_unref(L, LUA_REGISTRYINDEX, r->act_ref);
    if (L && r->co_ref != LUA_NOREF)
        luaL_unref(L, LUA_REGISTRYINDEX, r->co_ref);
    if (r->have_c)
        ns_coupled_free(&r->c);
    if (r->have_rod)
        ns_rod_free(&r->rod);
    if (r->have_tissue)
        ns_tissue_free(&r->tissue);
    if (r->have_orig)
        ns_mesh_free(&r->orig);
    if (r->have_spec)
        ns_run_spec_free(&r->spec);
    if (r->have_sc)
        ns_scenario_free(&r->sc);
    Series *s[8] = {&r->step_ms,   &r->total_ms,  &r->lcp_ms, &r->tissue_ms,
                    &r->needle_ms, &r->remesh_ms, &r->trials, &r->iterations};
    for (int k = 0; k < 8; k++)
        free(s[k]->v);
    for (int k = 0; k < 3; k++)
        free(r->tips[k].v);
    free(r->target_hint);
    free(r->marker_hint);
    free(r->obst);
    free(r->seeds);
    free(r->events);
    free(r->traj_tmp);
    free(r->report_tmp);
    free(r->rec_tmp);
    ns_control_log_free(&r->replay);
}

static int parse_args(int argc, char **argv, RunOpts *o)
{
    o->out_dir = "needlesim-out";
    o->threads = 1;
    o->solver = NS_COUPLED_SCHUR;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            fputs(run_usage, stdout);
            return 1;
        } else if (strcmp(a, "-o") == 0 || strcmp(a, "--steps") == 0 ||
                   strcmp(a, "--threads") == 0 || strcmp(a, "--solver") == 0 ||
                   strcmp(a, "--record") == 0 || strcmp(a, "--replay") == 0 ||
                   strcmp(a, "--set") == 0) {
            if (!v)
                return usage_error("%s needs a value", a);
            i++;
            char *end;
            if (!v[0])
                return usage_error("%s: expected a path, got an empty string", a);
            if (strcmp(a, "-o") == 0) {
                o->out_dir = v;
            } else if (strcmp(a, "--set") == 0) {
                const char *eq = strchr(v, '=');
                if (!eq || eq == v)
                    return usage_error("--set '%s': expected KEY=VALUE", v);
                if (o->nsets == 32)
                    return usage_error("%s", "at most 32 --set values");
                for (int k = 0; k < o->nsets; k++)
                    if (strncmp(o->sets[k], v, (size_t)(eq - v) + 1) == 0)
                        return usage_error("--set: '%s' is given twice", v);
                o->sets[o->nsets++] = v;
            } else if (strcmp(a, "--record") == 0) {
                o->record = v;
            } else if (strcmp(a, "--replay") == 0) {
                o->replay = v;
            } else if (strcmp(a, "--solver") == 0) {
                o->solver = ns_coupled_solver_parse(v);
                if (o->solver < 0)
                    return usage_error("--solver '%s': unknown solver (schur or paper)", v);
            } else {
                long n = strtol(v, &end, 10);
                if (*end || n < 1 || n > (strcmp(a, "--threads") == 0 ? 64 : NS_LIMIT_STEPS))
                    return usage_error("%s: expected a positive integer", a);
                if (strcmp(a, "--steps") == 0)
                    o->steps = n;
                else
                    o->threads = (int)n;
            }
        } else if (strcmp(a, "--video") == 0) {
            if (!v)
                return usage_error("%s needs a value", a);
            size_t n = strlen(v);
            if (n < 5 || strcasecmp(v + n - 4, ".mp4") != 0 || v[n - 5] == '/')
                return usage_error("--video '%s': expected a FILE.mp4 path", v);
            o->video = v;
            i++;
        } else if (strcmp(a, "--width") == 0 || strcmp(a, "--height") == 0 ||
                   strcmp(a, "--frame-every") == 0) {
            if (!v)
                return usage_error("%s needs a value", a);
            char *end;
            long n = strtol(v, &end, 10);
            bool every = strcmp(a, "--frame-every") == 0;
            if (*end || (every ? (n < 1 || n > 1000000) : (n < 16 || n > 8192 || n % 2)))
                return usage_error(every ? "%s: expected a positive integer"
                                         : "%s: expected an even number of pixels in 16..8192",
                                   a);
            if (every)
                o->frame_every = (int)n;
            else if (a[2] == 'w')
                o->width = (int)n;
            else
                o->height = (int)n;
            i++;
        } else if (strcmp(a, "--frames") == 0) {
            o->frames = true;
        } else if (strcmp(a, "--no-render") == 0) {
            o->no_render = true;
        } else if (strcmp(a, "--quiet") == 0) {
            o->quiet = true;
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
    if (o->record && o->replay && strcmp(o->record, o->replay) == 0)
        return usage_error("--record and --replay name the same file '%s'", o->record);
    if (o->no_render && (o->frames || o->video))
        return usage_error("%s", "--no-render with --frames or --video: which is it?");
    if (o->no_render && (o->width || o->height || o->frame_every))
        return usage_error("%s", "--no-render with --width, --height or --frame-every");
    o->width = o->width ? o->width : 1280;
    o->height = o->height ? o->height : 720;
    return 0;
}

int ns_cmd_run(int argc, char **argv)
{
    Run r;
    memset(&r, 0, sizeof r);
    r.sim_ref = r.act_ref = r.co_ref = LUA_NOREF;
    int pa = parse_args(argc, argv, &r.opt);
    if (pa)
        return pa == 1 ? 0 : pa;
    char err[1024] = "";
    ns_cleanup_install();
    int rc = prepare_outputs(&r, err, sizeof err) ? -2 : -1;
    if (rc == -1 && ns_scenario_load_set(r.opt.scenario, r.opt.sets, r.opt.nsets, &r.sc, err,
                                         sizeof err) == 0) {
        r.have_sc = true;
        if (ns_run_spec_read(&r.sc, &r.spec, err, sizeof err) == 0) {
            r.have_spec = true;
            rc = 0;
        }
    }
    /* `sim` and the actions module are set up also without a script (on_tick uses them). */
    rc = rc ? rc : script_start(&r, err, sizeof err);
    if (rc == 0 && !r.spec.has_script && r.spec.duration <= 0.0 && r.opt.steps == 0 &&
        !r.opt.replay) {
        ns_set_err(err, sizeof err,
                   "%s: ns.scenario: without a script the run needs a duration (or --steps N) "
                   "to know when to stop",
                   r.sc.where);
        rc = -1;
    }
    if (rc == 0 && r.opt.replay)
        rc = ns_control_log_read(r.opt.replay, r.spec.dt, &r.replay, err, sizeof err);
    if (rc == 0 && r.opt.replay) { /* the same --set values as the recording */
        bool same = r.replay.nsets == r.opt.nsets;
        for (int i = 0; same && i < r.opt.nsets; i++) {
            bool found = false;
            for (int k = 0; k < r.replay.nsets && !found; k++)
                found = strcmp(r.replay.sets[k], r.opt.sets[i]) == 0;
            same = found;
        }
        if (!same) {
            char rec[512] = "", now[512] = "";
            for (int k = 0; k < r.replay.nsets; k++)
                snprintf(rec + strlen(rec), sizeof rec - strlen(rec), " --set %s",
                         r.replay.sets[k]);
            for (int i = 0; i < r.opt.nsets; i++)
                snprintf(now + strlen(now), sizeof now - strlen(now), " --set %s", r.opt.sets[i]);
            ns_set_err(err, sizeof err,
                       "%s: the log was recorded with%s, this replay has%s: give the same --set "
                       "values",
                       r.opt.replay, rec[0] ? rec : " no --set", now[0] ? now : " none");
            rc = -1;
        }
    }
    if (rc == 0 && r.opt.record) {
        size_t n = strlen(r.opt.record) + 6;
        r.rec_tmp = malloc(n);
        if (r.rec_tmp)
            snprintf(r.rec_tmp, n, "%s.part", r.opt.record);
        r.rec =
            r.rec_tmp ? ns_out_create_part(r.rec_tmp, "the control log", err, sizeof err) : NULL;
        if (!r.rec) {
            if (!r.rec_tmp)
                ns_set_err(err, sizeof err, "out of memory");
            rc = -1;
        } else {
            ns_control_log_write_header(r.rec, r.opt.sets, r.opt.nsets);
        }
    }
    if (rc == 0)
        write_traj_header(&r);
    rc = rc ? rc : build(&r, err, sizeof err);
    if (rc == 0 && !r.opt.no_render)
        rc = render_setup(&r, err, sizeof err);
    rc = rc ? rc : run_loop(&r, err, sizeof err);
    Results res;
    memset(&res, 0, sizeof res);
    if (rc == 0 && score_run(&r, &res)) {
        ns_set_err(err, sizeof err, "out of memory");
        rc = -1;
    }
    if (rc == 0 && r.rendering) {
        double t0 = now_s();
        rc = render_end(&r, &res, err, sizeof err);
        r.end_s = now_s() - t0;
    }
    uint64_t hash = rc == 0 ? ns_coupled_state_hash(&r.c) : 0;
    if (rc == 0) {
        int bad = ferror(r.traj) != 0;
        if ((fclose(r.traj) != 0) | bad) {
            r.traj = NULL;
            ns_set_err(err, sizeof err, "cannot write the trajectory: %s", strerror(errno));
            rc = -1;
        }
        r.traj = NULL;
    }
    rc = rc ? rc : write_report(&r, &res, hash, err, sizeof err);
    if (rc == 0) {
        char *traj = path_join(r.opt.out_dir, "trajectory.csv");
        char *rep = path_join(r.opt.out_dir, "report.json");
        if (!traj || !rep || ns_out_commit(r.traj_tmp, traj) || ns_out_commit(r.report_tmp, rep)) {
            ns_set_err(err, sizeof err, "cannot write to output folder '%s': %s", r.opt.out_dir,
                       strerror(errno));
            if (traj)
                remove(traj);
            rc = -1;
        }
        /* The pictures before the log: they are part of the run's outputs. */
        if (rc == 0 && r.rendering && ns_run_render_commit(&r.rr, err, sizeof err)) {
            remove(traj);
            remove(rep);
            rc = -1;
        }
        /* The control log last: a log on disk means the run and its report are there. */
        if (rc == 0 && r.rec) {
            int bad = ferror(r.rec) != 0;
            bad |= fclose(r.rec) != 0;
            r.rec = NULL;
            if (bad || ns_out_commit(r.rec_tmp, r.opt.record) != 0) {
                ns_set_err(err, sizeof err, "cannot write the control log '%s': %s", r.opt.record,
                           strerror(errno));
                remove(traj);
                remove(rep);
                rc = -1;
            }
        }
        free(traj);
        free(rep);
    }
    if (rc) {
        remove_outputs(&r);
        /* Messages that name their scenario file and line (or say needlesim) print as they
         * are, as in `needlesim check`; the others get the program's name. */
        if (r.progress_shown)
            fputs("\r\033[K", stderr); /* the progress line goes before the message */
        size_t n = strlen(r.opt.scenario);
        bool located = strncmp(err, "needlesim", 9) == 0 || strncmp(err, r.opt.scenario, n) == 0;
        fprintf(stderr, "%s%s\n", located ? "" : "needlesim: ", err);
    } else if (!r.opt.quiet) {
        printf("%s: %ld steps of %.4g s (%.3g s simulated) in %.2f s wall; median step %.2f ms\n",
               r.sc.name, r.steps, r.spec.dt, (double)r.steps * r.spec.dt, r.wall_s,
               series_quantile(&r.step_ms, 0.5));
        printf("needle tip at (%.2f, %.2f, %.2f) mm, depth %.2f mm, peak axial force %.3f N\n",
               1e3 * tip_of(&r)[0], 1e3 * tip_of(&r)[1], 1e3 * tip_of(&r)[2], 1e3 * depth_of(&r),
               r.max_axial);
        if (r.spec.target_count)
            printf("%-20s %10s %10s %5s %5s\n", "target", "error mm", "tol mm", "by", "hit");
        for (int i = 0; i < r.spec.target_count; i++)
            printf("%-20s %10.2f %10.2f %5s %5s\n", r.spec.targets[i].name, res.targets[i].error_mm,
                   1e3 * r.spec.targets[i].tolerance, res.targets[i].by_seed ? "seed" : "tip",
                   res.targets[i].hit ? "yes" : "no");
        if (r.spec.seed_count || r.seed_n)
            printf("seeds released %d of %d planned\n", r.seed_n, r.spec.seed_count);
        for (int k = 0; k < r.spec.obstacle_count; k++)
            if (r.obst[k].violated)
                printf("obstacle %s entered at t = %.2f s, %.1f mm deep\n",
                       r.spec.obstacles[k].name, r.obst[k].first_t, 1e3 * r.obst[k].max_depth);
        printf("score %.1f / 100 (targets %.1f, obstacles -%.0f); insertions %d; warnings: NaN %d, "
               "inverted %d, unconverged %d, friction unresolved %d\n",
               res.total, res.target_part, res.obstacle_penalty, r.insertions, r.nan, r.inverted,
               r.unconverged, r.lcp_unresolved);
        printf("wrote %s/report.json and %s/trajectory.csv (state hash %016llx)\n", r.opt.out_dir,
               r.opt.out_dir, (unsigned long long)hash);
        if (r.rendering) {
            double rm, em;
            ns_run_render_medians(&r.rr, &rm, &em);
            printf("wrote %s/summary.png (%d moments)", r.opt.out_dir, r.rr.moment_count);
            if (r.opt.frames)
                printf(", %s/frames/ (%ld frames)", r.opt.out_dir, r.rr.frame_count);
            if (r.opt.video)
                printf(", %s (%ld frames at %g fps)", r.opt.video, r.rr.frame_count, r.rr.o.fps);
            printf("\n");
            if (r.rr.frame_count)
                printf("rendering: %.1f ms a frame, writing %.1f ms (medians); %.0f %% of the "
                       "run's wall time",
                       rm, em, 100.0 * r.rr.render_s / fmax(r.wall_s + r.end_s, 1e-9));
            if (r.rr.frame_count && r.opt.video)
                printf("; ffmpeg's encoding %.1f ms of CPU a frame (beside the run)",
                       1e3 * r.rr.ffmpeg_cpu_s / (double)r.rr.frame_count);
            if (r.rr.frame_count)
                printf("\n");
        }
    }
    results_free(&res);
    run_free(&r);
    return rc ? 1 : 0;
}

/* ---- needlesim bench ---- */

static const char bench_usage[] =
    "usage: needlesim bench SCENARIO.lua [--steps N] [--solver NAME] [--threads N]\n"
    "                       [--set KEY=VALUE]... [--compare NAME] [--repeat N] [--json]\n";

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

static void bench_stats_json(NsJson *j, const Run *r)
{
    timing_json(j, r);
    stats_object(j, "lcp_trials", &r->trials);
    stats_object(j, "cg_iterations", &r->iterations);
    ns_json_key(j, "factorizations");
    ns_json_int(j, r->factorizations);
}

/* One bench run of o's scenario with the given solver into r (initialised here). */
static int bench_run(const RunOpts *o, int solver, bool log_tips, Run *r, char *err, int err_sz)
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
    rc = rc ? rc : script_start(r, err, err_sz);
    rc = rc ? rc : build(r, err, err_sz);
    rc = rc ? rc : run_loop(r, err, err_sz);
    if (rc == 0 && r->steps == 0) {
        ns_set_err(err, err_sz, "%s: the script ended before the first step: nothing to time",
                   r->sc.path);
        rc = -1;
    }
    return rc;
}

static void bench_table(const Run *r)
{
    double lo, mean, hi, ilo, imean, ihi;
    series_range(&r->trials, &lo, &mean, &hi);
    series_range(&r->iterations, &ilo, &imean, &ihi);
    printf("%s: %d tets, %d nodes; solver %s, %d thread(s), %ld steps of %g ms\n", r->sc.name,
           r->tissue.mesh.tet_alive, r->tissue.mesh.node_alive,
           ns_coupled_solver_name((NsCoupledSolverKind)r->opt.solver), r->opt.threads, r->steps,
           1e3 * r->spec.dt);
    printf("median ms per step (the paper's Table 2):\n");
    printf("  %8s %8s %8s %8s %8s\n", "Total", "LCP", "Tissue", "Needle", "Remesh");
    printf("  %8.2f %8.2f %8.2f %8.2f %8.2f\n", series_quantile(&r->total_ms, 0.5),
           series_quantile(&r->lcp_ms, 0.5), series_quantile(&r->tissue_ms, 0.5),
           series_quantile(&r->needle_ms, 0.5), series_quantile(&r->remesh_ms, 0.5));
    printf("  %8.2f %8.2f %8.2f %8.2f %8.2f  (means)\n", series_mean(&r->total_ms),
           series_mean(&r->lcp_ms), series_mean(&r->tissue_ms), series_mean(&r->needle_ms),
           series_mean(&r->remesh_ms));
    printf("step wall time: median %.2f ms, mean %.2f ms, p95 %.2f ms, max %.2f ms\n",
           series_quantile(&r->step_ms, 0.5), series_mean(&r->step_ms),
           series_quantile(&r->step_ms, 0.95), series_quantile(&r->step_ms, 1.0));
    printf("per step (the paper's Table 3): LCP trials %.0f / %.2f / %.0f, CG iterations "
           "%.0f / %.1f / %.0f (min / mean / max); tissue factorizations %ld in all\n",
           lo, mean, hi, ilo, imean, ihi, r->factorizations);
}

static void bench_json_fields(NsJson *j, const Run *r)
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
static double tip_difference(const Run *a, const Run *b, long *steps)
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
int ns_cmd_bench(int argc, char **argv)
{
    RunOpts o;
    memset(&o, 0, sizeof o);
    o.threads = 1;
    o.solver = NS_COUPLED_SCHUR;
    o.quiet = true;
    o.no_render = true;
    bool json = false;
    int compare = -1, repeat = 1;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            fputs(bench_usage, stdout);
            return 0;
        } else if (strcmp(a, "--json") == 0) {
            json = true;
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
                    o.solver = k;
                else
                    compare = k;
            } else if (strcmp(a, "--set") == 0) {
                if (!strchr(v, '=') || v[0] == '=' || o.nsets == 32) {
                    fprintf(stderr,
                            "needlesim bench: --set '%s': expected KEY=VALUE (needlesim bench "
                            "--help)\n",
                            v);
                    return 2;
                }
                o.sets[o.nsets++] = v;
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
                    o.steps = n;
                else if (strcmp(a, "--repeat") == 0)
                    repeat = (int)n;
                else
                    o.threads = (int)n;
            }
        } else if (a[0] == '-' && a[1] != '\0') {
            fprintf(stderr, "needlesim bench: unknown option '%s' (needlesim bench --help)\n", a);
            return 2;
        } else if (!o.scenario) {
            o.scenario = a;
        } else {
            fprintf(stderr,
                    "needlesim bench: one scenario only (got '%s' too) (needlesim bench --help)\n",
                    a);
            return 2;
        }
    }
    if (!o.scenario) {
        fprintf(stderr, "needlesim bench: missing SCENARIO.lua (needlesim bench --help)\n");
        return 2;
    }
    if (compare >= 0 && compare == o.solver) {
        fprintf(stderr, "needlesim bench: --compare %s: the same solver as the run's\n",
                ns_coupled_solver_name((NsCoupledSolverKind)compare));
        return 2;
    }
    if (o.steps == 0)
        o.steps = 200;
    char err[1024] = "";
    Run runs[2];
    int nruns = compare >= 0 ? 2 : 1, rc = 0, made = 0, done = 0;
    double meds[2][BENCH_MAX_REPEAT], ratios[BENCH_MAX_REPEAT], worst = 0.0;
    double ratios_mean[BENCH_MAX_REPEAT]; /* the whole runs': mean steps */
    bool all_agree = true;
    for (int rep = 0; rep < repeat && rc == 0; rep++) {
        if (rep > 0) { /* the last repeat's runs are kept for the tables */
            for (int k = 0; k < nruns; k++)
                run_free(&runs[k]);
            made = 0;
        }
        if (repeat > 1 && !json)
            fprintf(stderr, "needlesim bench: repeat %d of %d\n", rep + 1, repeat);
        for (int k = 0; k < nruns && rc == 0; k++) {
            rc = bench_run(&o, k ? compare : o.solver, nruns == 2, &runs[k], err, sizeof err);
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
                meds[k][rep] = series_quantile(&runs[k].step_ms, 0.5);
            ratios[rep] = nruns == 2 ? meds[1][rep] / fmax(meds[0][rep], 1e-12) : 1.0;
            ratios_mean[rep] = nruns == 2 ? series_mean(&runs[1].step_ms) /
                                                fmax(series_mean(&runs[0].step_ms), 1e-12)
                                          : 1.0;
            done = rep + 1;
        }
    }
    if (rc) {
        size_t n = strlen(o.scenario);
        bool located = strncmp(err, "needlesim", 9) == 0 || strncmp(err, o.scenario, n) == 0;
        fprintf(stderr, "%s%s\n", located ? "" : "needlesim: ", err);
        for (int k = 0; k < made; k++)
            run_free(&runs[k]);
        return 1;
    }
    const Run *r = &runs[0];
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
    if (json) {
        NsJson j;
        ns_json_init(&j, stdout, 1);
        ns_json_begin_object(&j);
        ns_json_key(&j, "scenario");
        ns_json_string(&j, r->sc.name);
        ns_json_key(&j, "solver");
        ns_json_string(&j, ns_coupled_solver_name((NsCoupledSolverKind)o.solver));
        ns_json_key(&j, "threads");
        ns_json_int(&j, o.threads);
        bench_json_fields(&j, r);
        if (nruns == 2) {
            for (int k = 0; k < 2; k++) {
                ns_json_key(&j, ns_coupled_solver_name((NsCoupledSolverKind)runs[k].opt.solver));
                ns_json_begin_object(&j);
                bench_json_fields(&j, &runs[k]);
                ns_json_end_object(&j);
            }
            ns_json_key(&j, "speedup");
            ns_json_number(&j, speedup);
            ns_json_key(&j, "speedup_mean");
            ns_json_number(&j, speedup_mean);
            ns_json_key(&j, "max_tip_difference_m");
            ns_json_number(&j, diff);
            ns_json_key(&j, "agree");
            ns_json_bool(&j, agree);
        }
        if (repeat > 1) { /* medians of the per-repeat medians, and their range */
            ns_json_key(&j, "repeat");
            ns_json_begin_object(&j);
            ns_json_key(&j, "runs");
            ns_json_int(&j, done);
            static const char *const what[4] = {"step_ms", "compared_step_ms", "speedup",
                                                "speedup_mean"};
            for (int k = 0; k < 4; k++) {
                if (k > 0 && nruns == 1)
                    break;
                ns_json_key(&j, what[k]);
                ns_json_begin_object(&j);
                ns_json_key(&j, "median");
                ns_json_number(&j, rmed[k]);
                ns_json_key(&j, "min");
                ns_json_number(&j, rlo[k]);
                ns_json_key(&j, "max");
                ns_json_number(&j, rhi[k]);
                ns_json_end_object(&j);
            }
            ns_json_end_object(&j);
        }
        ns_json_end_object(&j);
        fputc('\n', stdout);
    } else {
        for (int k = 0; k < nruns; k++) {
            if (k)
                printf("\n");
            bench_table(&runs[k]);
        }
        if (nruns == 2)
            printf("\nspeed-up (median step of %s / median step of %s): %.2fx; tips within %.4f mm "
                   "over %ld "
                   "steps (want <= 0.05 mm)\n",
                   ns_coupled_solver_name((NsCoupledSolverKind)compare),
                   ns_coupled_solver_name((NsCoupledSolverKind)o.solver), speedup, 1e3 * diff,
                   compared);
        if (nruns == 2) /* the refactorizations and slow steps the medians leave out */
            printf("whole run (mean step of %s / mean step of %s): %.2fx\n",
                   ns_coupled_solver_name((NsCoupledSolverKind)compare),
                   ns_coupled_solver_name((NsCoupledSolverKind)o.solver), speedup_mean);
        if (repeat > 1) {
            printf("\nover %d repeats (median step, ms: median [min, max]):\n", done);
            for (int k = 0; k < nruns; k++)
                printf("  %-6s %8.2f [%.2f, %.2f]\n",
                       ns_coupled_solver_name((NsCoupledSolverKind)runs[k].opt.solver), rmed[k],
                       rlo[k], rhi[k]);
            if (nruns == 2)
                printf("  speed-up %.2fx [%.2f, %.2f]; whole run (mean steps) %.2fx [%.2f, %.2f]\n",
                       rmed[2], rlo[2], rhi[2], rmed[3], rlo[3], rhi[3]);
        }
    }
    if (!agree)
        fprintf(stderr,
                "needlesim bench: the two solvers' tips differ by %.4f mm (%ld and %ld steps): "
                "more than 0.05 mm\n",
                1e3 * diff, runs[0].steps, runs[1].steps);
    for (int k = 0; k < nruns; k++)
        run_free(&runs[k]);
    return agree ? 0 : 1;
}
