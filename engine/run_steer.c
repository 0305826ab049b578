/* The planners inside a run (docs/planning.md): `sim.planner`, the C side of act.steer and
 * ns.plan. Its functions take the tip pose and the target from what the script sees in `sim`
 * (not from the run itself), so a resumed run that replays its script gets the same answers;
 * they read the scenario's obstacles (plan_obs.h) and the run's bounds, and record each
 * replan's planning time (wall clock: measured, never used to decide) and the least clearance
 * of the tip for the report's `steering` object. */
#include <lauxlib.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "err.h"
#include "json.h"
#include "path.h"
#include "plan_obs.h"
#include "rrt.h"
#include "run.h"
#include "steer.h"

#define STEER_PATH_STEP        1e-3    /* spacing of ns.plan's path points [m] */
#define STEER_CHECK_STEP       0.25e-3 /* spacing of the clearance checks along a plan [m] */
#define STEER_RRT_NODES        5000    /* an RRT per replan: smaller than needlesim plan's limits */
#define STEER_RRT_ITERATIONS   20000
#define STEER_TWIST_GAIN       0.5e-3 /* least predicted gain for which act.steer twists [m], */
#define STEER_TWIST_GAIN_PER_M 0.02   /* ... or 2% of the distance to the target, if less */
#define STEER_WAY_AHEAD        2e-3   /* a waypoint counts when this far ahead of the tip [m] */
#define STEER_WAY_MISS         0.5e-3 /* ... and the helix choice reaches it this close [m] */
#define STEER_RRT_MARGIN       0.85   /* act.steer's RRT plans with this much of the curvature */

int ns_run_steer_setup(NsRun *r, char *err, int err_sz)
{
    NsRunSteer *s = &r->steer;
    memset(s, 0, sizeof *s);
    s->min_clear = INFINITY;
    s->target = -1;
    s->kappa = ns_plan_model_kappa(&r->spec);
    if (!ns_plan_mesh_box(&r->sc.mesh, -1, s->lo, s->hi)) {
        ns_set_err(err, err_sz, "%s: the tissue has no tets", r->sc.path);
        return -1;
    }
    s->avoided = calloc((size_t)(r->spec.obstacle_count + 1), sizeof *s->avoided);
    if (!s->avoided) {
        ns_set_err(err, err_sz, "needlesim: out of memory");
        return -1;
    }
    /* A scenario whose obstacles cannot be made into distances runs on; act.steer with
     * `avoid` then says why. */
    if (r->spec.obstacle_count > 0)
        s->have_obs =
            ns_plan_obs_make(&r->sc, &r->spec, &s->obs, s->obs_err, (int)sizeof s->obs_err) == 0;
    else
        s->have_obs = true;
    return 0;
}

void ns_run_steer_free(NsRunSteer *s)
{
    if (s->have_obs)
        ns_plan_obs_free(&s->obs);
    free(s->avoided);
    free(s->way);
    free(s->plan);
    free(s->ms.v);
    free(s->rollout_ms.v);
    memset(s, 0, sizeof *s);
}

/* ---- arguments: one table, fields checked (act.steer and ns.plan check the user's first) ---- */

static NsRun *self(lua_State *L)
{
    return lua_touserdata(L, lua_upvalueindex(1));
}

static void vec_field(lua_State *L, const char *key, double v[3])
{
    if (lua_getfield(L, 1, key) != LUA_TTABLE)
        luaL_error(L, "sim.planner: '%s' must be {x, y, z}", key);
    for (int k = 0; k < 3; k++) {
        lua_rawgeti(L, -1, k + 1);
        int ok = 0;
        v[k] = lua_tonumberx(L, -1, &ok);
        if (!ok || !isfinite(v[k]))
            luaL_error(L, "sim.planner: '%s' must be {x, y, z}: 3 finite numbers", key);
        lua_pop(L, 1);
    }
    lua_pop(L, 1);
}

static double num_field(lua_State *L, const char *key, double def)
{
    int ty = lua_getfield(L, 1, key);
    int ok = 0;
    double v = lua_tonumberx(L, -1, &ok);
    lua_pop(L, 1);
    if (ty == LUA_TNIL)
        return def;
    if (!ok || !isfinite(v))
        luaL_error(L, "sim.planner: '%s' must be a finite number", key);
    return v;
}

/* The obstacles named in args.avoid (a list of names) into out (count returned). */
static int avoid_field(lua_State *L, NsRun *r, NsPlanObstacle *out)
{
    NsRunSteer *s = &r->steer;
    int n = 0;
    if (lua_getfield(L, 1, "avoid") == LUA_TNIL) {
        lua_pop(L, 1);
        return 0;
    }
    if (!lua_istable(L, -1))
        luaL_error(L, "sim.planner: 'avoid' must be a list of obstacle names");
    for (lua_Integer i = 1; lua_rawgeti(L, -1, i) != LUA_TNIL; i++) {
        const char *name = lua_tostring(L, -1);
        int k = 0;
        while (name && k < r->spec.obstacle_count && strcmp(r->spec.obstacles[k].name, name) != 0)
            k++;
        if (!name || k == r->spec.obstacle_count)
            luaL_error(L, "sim.planner: avoid[%d] is not an obstacle of the scenario", (int)i);
        if (!s->have_obs)
            luaL_error(L, "%s", s->obs_err);
        if (n < r->spec.obstacle_count)
            out[n++] = s->obs.obs[k];
        lua_pop(L, 1);
    }
    lua_pop(L, 2);
    return n;
}

typedef struct SteerArgs {
    NsPlanPose pose;
    double target[3], kappa, clearance, tolerance;
    bool rrt;
    unsigned long long seed;
    NsPlanObstacle *obs;
    int nobs;
} SteerArgs;

/* args: {tip, t, m2, target, kappa, method, avoid, clearance, tolerance, seed}; obs: room for
 * every obstacle of the scenario. */
static void read_args(lua_State *L, NsRun *r, SteerArgs *a, NsPlanObstacle *obs)
{
    luaL_checktype(L, 1, LUA_TTABLE);
    double p[3], t[3], m2[3];
    vec_field(L, "tip", p);
    vec_field(L, "t", t);
    vec_field(L, "m2", m2);
    vec_field(L, "target", a->target);
    if (!ns_plan_pose_make(p, t, m2, &a->pose))
        luaL_error(L, "sim.planner: the tip's direction is zero");
    a->kappa = num_field(L, "kappa", r->steer.kappa);
    a->clearance = num_field(L, "clearance", 1e-3);
    a->tolerance = num_field(L, "tolerance", 1e-3);
    double seed = num_field(L, "seed", 1.0);
    if (!(a->kappa > 0.0) || a->clearance < 0.0 || !(a->tolerance > 0.0) || seed < 0.0 ||
        seed > 1e15)
        luaL_error(L, "sim.planner: kappa and tolerance must be > 0, clearance >= 0, seed in "
                      "0..1e15");
    a->seed = (unsigned long long)seed;
    lua_getfield(L, 1, "method");
    const char *m = lua_tostring(L, -1);
    if (!m || (strcmp(m, "helix") != 0 && strcmp(m, "rrt") != 0))
        luaL_error(L, "sim.planner: method must be \"helix\" or \"rrt\"");
    a->rrt = strcmp(m, "rrt") == 0;
    lua_pop(L, 1);
    a->obs = obs;
    a->nobs = avoid_field(L, r, obs);
}

static NsRrtParams rrt_params(const NsRun *r, const SteerArgs *a)
{
    NsRrtParams prm = ns_rrt_default(a->kappa, r->steer.lo, r->steer.hi);
    prm.clearance = a->clearance;
    prm.tolerance = a->tolerance;
    prm.seed = a->seed;
    prm.max_nodes = STEER_RRT_NODES;
    prm.max_iterations = STEER_RRT_ITERATIONS;
    return prm;
}

static void set_field(lua_State *L, const char *key, double v)
{
    lua_pushnumber(L, v);
    lua_setfield(L, -2, key);
}

/* The least distance to the obstacles of the arc the action predicts, up to its closest
 * approach to the target. */
static double arc_clearance(lua_State *L, const SteerArgs *a, const NsSteerAction *act)
{
    NsPlanPath arc;
    NsPlanAction pa = {act->twist, fmax(act->at, 1e-4), act->duty, act->rate};
    if (!ns_plan_path_init(&arc, &a->pose, a->kappa) || !ns_plan_path_push(&arc, &pa)) {
        ns_plan_path_free(&arc);
        luaL_error(L, "needlesim: out of memory");
    }
    double c = ns_plan_path_clearance(&arc, a->obs, a->nobs, STEER_CHECK_STEP);
    ns_plan_path_free(&arc);
    return c;
}

/* Keeps the chosen action's predicted arc, from the tip to its closest approach, for the
 * frames (the planned path drawn ahead of the needle). A picture only: out of memory, none is
 * kept and the run goes on. */
static void keep_plan(NsRunSteer *s, const SteerArgs *a, const NsSteerAction *act)
{
    NsPlanPath arc;
    NsPlanAction pa = {act->twist, fmax(act->at, 1e-4), act->duty, act->rate};
    double *xyz = NULL;
    int np = -1;
    if (ns_plan_path_init(&arc, &a->pose, a->kappa) && ns_plan_path_push(&arc, &pa))
        np = ns_plan_path_points(&arc, STEER_PATH_STEP, &xyz);
    ns_plan_path_free(&arc);
    free(s->plan);
    s->plan = np > 0 ? xyz : NULL;
    s->plan_n = np > 0 ? np : 0;
    if (np <= 0)
        free(xyz);
}

/* The helix choice towards the target, else the farthest kept waypoint at least STEER_WAY_AHEAD
 * ahead of the tip, that it reaches within STEER_WAY_MISS with its predicted arc keeping the
 * clearance. */
static bool toward_waypoint(lua_State *L, const NsRunSteer *s, const SteerArgs *a,
                            NsSteerAction *out)
{
    for (int i = s->way_n; i >= 0; i--) { /* the target first, then the waypoints back */
        const double *w = i == s->way_n ? a->target : &s->way[3 * i];
        double d[3] = {w[0] - a->pose.p[0], w[1] - a->pose.p[1], w[2] - a->pose.p[2]};
        if (d[0] * a->pose.t[0] + d[1] * a->pose.t[1] + d[2] * a->pose.t[2] < STEER_WAY_AHEAD)
            continue;
        NsSteerParams sp = ns_steer_default(a->kappa);
        NsSteerAction act;
        char err[256];
        if (ns_steer_choose(&sp, &a->pose, w, &act, err, sizeof err) != 0)
            continue;
        if (act.miss <= STEER_WAY_MISS && arc_clearance(L, a, &act) >= a->clearance) {
            *out = act;
            return true;
        }
    }
    return false;
}

/* An RRT from the pose; its nodes' positions become the kept waypoints (the target last).
 * false when none is found (the waypoints then dropped). */
static bool replan_rrt(NsRun *r, const SteerArgs *a, char *err, int err_sz)
{
    NsRunSteer *s = &r->steer;
    NsRrtParams prm = rrt_params(r, a);
    prm.kappa = STEER_RRT_MARGIN * a->kappa; /* a path the needle can follow with some to spare */
    NsPlanPath path;
    s->way_n = 0;
    if (ns_rrt_plan(&prm, a->obs, a->nobs, &a->pose, a->target, &path, NULL, err, err_sz) != 0)
        return false;
    bool path_found = true;
    double *w = realloc(s->way, sizeof *w * 3 * (size_t)(path.action_count + 1));
    if (w) {
        s->way = w;
        for (int i = 1; i < path.action_count; i++) /* the last node: the target's place */
            memcpy(&w[3 * (i - 1)], path.poses[i].p, sizeof(double) * 3);
        s->way_n = path.action_count - 1;
    }
    ns_plan_path_free(&path);
    return s->way_n > 0 || path_found;
}

/* planner.choose(args) -> {twist, duty, rate, miss, fallback}: the action to apply now. With
 * method "rrt" the first action of an RRT planned from the pose (the helix choice when the
 * RRT finds no path: fallback = true). Counts one replan and its planning time. */
static int l_choose(lua_State *L)
{
    NsRun *r = self(L);
    NsRunSteer *s = &r->steer;
    NsPlanObstacle *obs =
        lua_newuserdatauv(L, sizeof *obs * (size_t)(r->spec.obstacle_count + 1), 0);
    SteerArgs a;
    read_args(L, r, &a, obs);
    char err[512];
    double t0 = ns_wall_s();
    NsSteerAction act = {0};
    bool fallback = false; /* the RRT found no path: the direct choice is taken */
    NsSteerParams sp = ns_steer_default(a.kappa);
    if (ns_steer_choose(&sp, &a.pose, a.target, &act, err, sizeof err) != 0)
        luaL_error(L, "sim.planner: %s", err);
    /* A dead band: the bevel as it is (no twist, its own duty cycle) unless turning it gains
     * more than STEER_TWIST_GAIN (or 2% of the distance, near the target) of predicted miss. Near
     * the line to the target the best angle swings with the tip's jitter, and each swing costs a
     * twist that shakes the tissue. */
    NsSteerParams hold = sp;
    hold.angle_count = 1;
    hold.exact_angle = false;
    NsSteerAction still;
    double far = sqrt((a.target[0] - a.pose.p[0]) * (a.target[0] - a.pose.p[0]) +
                      (a.target[1] - a.pose.p[1]) * (a.target[1] - a.pose.p[1]) +
                      (a.target[2] - a.pose.p[2]) * (a.target[2] - a.pose.p[2]));
    if (ns_steer_choose(&hold, &a.pose, a.target, &still, err, sizeof err) == 0 &&
        still.miss <= act.miss + fmin(STEER_TWIST_GAIN, STEER_TWIST_GAIN_PER_M * far))
        act = still;
    if (a.rrt && a.nobs > 0) {
        /* Along an RRT path around the obstacles, through its waypoints (the nodes' positions,
         * the target last): towards the farthest one ahead that the helix choice reaches with
         * its predicted arc clear. The path is kept from one replan to the next (a tree planned
         * afresh every time gives a different first action each time, and the needle twists
         * back and forth); it is planned again, from the pose, only when no waypoint ahead can
         * be reached clear of the obstacles. */
        fallback = !toward_waypoint(L, s, &a, &act);
        if (fallback && replan_rrt(r, &a, err, sizeof err))
            fallback = !toward_waypoint(L, s, &a, &act);
    }
    double ms = 1e3 * (ns_wall_s() - t0);
    keep_plan(s, &a, &act); /* after the clock: drawing is not planning */
    if (ns_series_push(&s->ms, ms) != 0)
        luaL_error(L, "needlesim: out of memory");
    s->replans++;
    s->fallbacks += fallback;
    s->used = true;
    s->kappa_estimate = a.kappa;
    s->rrt = a.rrt;
    lua_createtable(L, 0, 5);
    set_field(L, "twist", act.twist);
    set_field(L, "duty", act.duty);
    set_field(L, "rate", act.rate);
    set_field(L, "miss", act.miss);
    lua_pushboolean(L, fallback);
    lua_setfield(L, -2, "fallback");
    return 1;
}

/* planner.finish(): act.steer has ended; its predicted arc is no longer drawn. */
static int l_finish(lua_State *L)
{
    NsRunSteer *s = &self(L)->steer;
    free(s->plan);
    s->plan = NULL;
    s->plan_n = 0;
    return 0;
}

/* planner.track(args{tip, avoid, target_index}) -> distance [m] from the tip to the nearest
 * avoided obstacle (inf: none); the least one is the report's min_clearance_mm. */
static int l_track(lua_State *L)
{
    NsRun *r = self(L);
    NsRunSteer *s = &r->steer;
    luaL_checktype(L, 1, LUA_TTABLE);
    NsPlanObstacle *obs =
        lua_newuserdatauv(L, sizeof *obs * (size_t)(r->spec.obstacle_count + 1), 0);
    double p[3];
    vec_field(L, "tip", p);
    int n = avoid_field(L, r, obs);
    double target = num_field(L, "target_index", 0.0);
    if (target >= 1.0 && target <= r->spec.target_count)
        s->target = (int)target - 1;
    for (int i = 0; i < n; i++)
        for (int k = 0; k < r->spec.obstacle_count; k++)
            if (strcmp(r->spec.obstacles[k].name, obs[i].name) == 0)
                s->avoided[k] = true;
    double d = ns_plan_obstacles_distance(obs, n, p, NULL);
    if (d < s->min_clear)
        s->min_clear = d;
    lua_pushnumber(L, d);
    return 1;
}

/* planner.plan(args) -> {ok, path = {{x, y, z}, ...}, actions = {{twist, insert, duty,
 * rate}, ...}, error_mm, clearance_mm, length_mm, planning_ms, message}: a whole plan from the
 * pose on the kinematic model (ns.plan); nothing is run. */
static int l_plan(lua_State *L)
{
    NsRun *r = self(L);
    NsPlanObstacle *obs =
        lua_newuserdatauv(L, sizeof *obs * (size_t)(r->spec.obstacle_count + 1), 0);
    SteerArgs a;
    read_args(L, r, &a, obs);
    char err[512] = "";
    NsPlanPath path;
    int rc;
    double t0 = ns_wall_s();
    if (a.rrt) {
        NsRrtParams prm = rrt_params(r, &a);
        prm.max_nodes = 20000;
        prm.max_iterations = 100000;
        rc = ns_rrt_plan(&prm, a.obs, a.nobs, &a.pose, a.target, &path, NULL, err, sizeof err);
    } else {
        NsSteerParams prm = ns_steer_default(a.kappa);
        double reach = sqrt((a.target[0] - a.pose.p[0]) * (a.target[0] - a.pose.p[0]) +
                            (a.target[1] - a.pose.p[1]) * (a.target[1] - a.pose.p[1]) +
                            (a.target[2] - a.pose.p[2]) * (a.target[2] - a.pose.p[2]));
        NsSteerLoop loop = {1e-3, 2.0 * reach + 1e-3, a.kappa, a.target, NULL, NULL, false};
        rc = ns_steer_rollout(&prm, &loop, &a.pose, &path, err, sizeof err);
        if (rc == 0)
            path.clearance = ns_plan_path_clearance(&path, a.obs, a.nobs, STEER_CHECK_STEP);
    }
    double ms = 1e3 * (ns_wall_s() - t0);
    if (rc < 0)
        luaL_error(L, "sim.planner: %s", err);
    lua_createtable(L, 0, 9);
    lua_pushboolean(L, rc == 0);
    lua_setfield(L, -2, "ok");
    set_field(L, "planning_ms", ms);
    if (rc != 0) {
        lua_pushstring(L, err);
        lua_setfield(L, -2, "message");
        return 1;
    }
    double *xyz = NULL;
    int np = ns_plan_path_points(&path, STEER_PATH_STEP, &xyz);
    if (np < 0) {
        ns_plan_path_free(&path);
        luaL_error(L, "needlesim: out of memory");
    }
    lua_createtable(L, np, 0);
    for (int i = 0; i < np; i++) {
        lua_createtable(L, 3, 0);
        for (int k = 0; k < 3; k++) {
            lua_pushnumber(L, xyz[3 * i + k]);
            lua_rawseti(L, -2, k + 1);
        }
        lua_rawseti(L, -2, i + 1);
    }
    free(xyz);
    lua_setfield(L, -2, "path");
    lua_createtable(L, path.action_count, 0);
    for (int i = 0; i < path.action_count; i++) {
        const NsPlanAction *pa = &path.actions[i];
        lua_createtable(L, 0, 4);
        set_field(L, "twist", pa->twist);
        set_field(L, "insert", pa->length);
        set_field(L, "duty", pa->duty);
        set_field(L, "rate", pa->rate);
        lua_rawseti(L, -2, i + 1);
    }
    lua_setfield(L, -2, "actions");
    set_field(L, "error_mm", 1e3 * path.error);
    set_field(L, "clearance_mm", isfinite(path.clearance) ? 1e3 * path.clearance : HUGE_VAL);
    set_field(L, "length_mm", 1e3 * path.length);
    ns_plan_path_free(&path);
    return 1;
}

void ns_run_steer_push(lua_State *L, NsRun *r)
{
    static const luaL_Reg fns[] = {
        {"choose", l_choose},          {"track", l_track}, {"plan", l_plan}, {"finish", l_finish},
        {"rollout", ns_run_l_rollout}, {NULL, NULL}};
    lua_createtable(L, 0, 6);
    lua_pushlightuserdata(L, r);
    luaL_setfuncs(L, fns, 1);
    lua_pushnumber(L, r->steer.kappa);
    lua_setfield(L, -2, "kappa");
    lua_createtable(L, r->spec.obstacle_count, 0); /* the obstacles' names */
    for (int k = 0; k < r->spec.obstacle_count; k++) {
        lua_pushstring(L, r->spec.obstacles[k].name);
        lua_rawseti(L, -2, k + 1);
    }
    lua_setfield(L, -2, "obstacles");
    lua_createtable(L, r->spec.target_count, 0); /* the targets' names, in the report's order */
    for (int k = 0; k < r->spec.target_count; k++) {
        lua_pushstring(L, r->spec.targets[k].name);
        lua_rawseti(L, -2, k + 1);
    }
    lua_setfield(L, -2, "target_names");
}

/* report.json's `steering` (only when act.steer ran): docs/planning.md is the contract. */
void ns_run_steer_report(NsJson *j, const NsRun *r, const NsRunResults *res)
{
    const NsRunSteer *s = &r->steer;
    if (!s->used)
        return;
    ns_json_key(j, "steering");
    ns_json_begin_object(j);
    ns_json_key(j, "method");
    ns_json_string(j, s->rrt ? "rrt" : "helix");
    ns_json_key(j, "target");
    ns_json_string(j, s->target >= 0 ? r->spec.targets[s->target].name : "");
    ns_json_key(j, "replans");
    ns_json_int(j, s->replans);
    ns_json_key(j, "rrt_fallbacks");
    ns_json_int(j, s->fallbacks);
    ns_json_key(j, "planning_ms");
    ns_json_begin_object(j);
    ns_json_key(j, "median");
    ns_json_number(j, ns_series_quantile(&s->ms, 0.5));
    ns_json_key(j, "p95");
    ns_json_number(j, ns_series_quantile(&s->ms, 0.95));
    ns_json_end_object(j);
    ns_json_key(j, "min_clearance_mm");
    if (isfinite(s->min_clear))
        ns_json_number(j, 1e3 * s->min_clear);
    else
        ns_json_null(j);
    ns_json_key(j, "final_error_mm");
    if (s->target >= 0)
        ns_json_number(j, res->targets[s->target].error_mm);
    else
        ns_json_null(j);
    bool entered = false;
    for (int k = 0; k < r->spec.obstacle_count; k++)
        entered |= s->avoided[k] && r->obst[k].violated;
    ns_json_key(j, "obstacle_entered");
    ns_json_bool(j, entered);
    ns_json_key(j, "kappa_model_per_m");
    ns_json_number(j, s->kappa);
    ns_json_key(j, "kappa_estimate_per_m");
    ns_json_number(j, s->kappa_estimate);
    ns_json_key(j, "rollouts");
    ns_json_int(j, s->rollouts);
    ns_json_key(j, "rollout_steps");
    ns_json_int(j, (int)s->rollout_steps);
    ns_json_key(j, "rollout_ms_median"); /* 0 without rollouts: a report holds no null */
    ns_json_number(j, s->rollouts > 0 ? ns_series_quantile(&s->rollout_ms, 0.5) : 0.0);
    ns_json_end_object(j);
}
