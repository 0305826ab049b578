/* The Lua bridge of a run (run.h): the `sim` table a script sees, its coroutine, on_tick and
 * the controls they set. */
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
#include "needle_path.h"
#include "ns_config.h"
#include "ns_limits.h"
#include "out_files.h"
#include "quality.h"
#include "remesh.h"
#include "rod.h"
#include "run.h"

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
    NsRun *r;
    double t;
    long step;
    int exited;
    const NsTickView *view; /* a resumed run's replay: what the script saw then, else NULL */
    const double *view_tx;  /* ... and the targets it saw (3 per target) */
    const NsControl *given; /* a live session's controls (NULL: the script's) */
    int more;               /* out: the script has more to do */
    NsControl ctl;          /* out: the controls for this step */
} TickIO;

/* (io) -> (): makes `sim`, loads needlesim.actions through the runtime's own require (kept in
 * the registry by the runtime, not the script's global), and starts the script's coroutine. */
static int start_body(lua_State *L)
{
    TickIO *io = lua_touserdata(L, 1);
    NsRun *r = io->r;
    lua_newtable(L); /* sim */
    lua_pushstring(L, "control");
    lua_newtable(L);
    set_num(L, lua_gettop(L), "v_insert", 0.0);
    set_num(L, lua_gettop(L), "twist_rate", 0.0);
    lua_rawset(L, -3);
    lua_pushstring(L, "limits"); /* the controls' bounds (sim/ns_limits.h) */
    lua_createtable(L, 0, 10);
    set_num(L, lua_gettop(L), "insert_speed", NS_LIMIT_INSERT_SPEED);
    set_num(L, lua_gettop(L), "twist_rate", NS_LIMIT_TWIST_RATE);
    set_num(L, lua_gettop(L), "base_speed", NS_LIMIT_BASE_SPEED);
    set_num(L, lua_gettop(L), "twist_angle", NS_LIMIT_TWIST_ANGLE);
    set_num(L, lua_gettop(L), "video_text", NS_LIMIT_VIDEO_TEXT); /* the video's cues */
    set_num(L, lua_gettop(L), "video_duration", NS_LIMIT_VIDEO_DURATION);
    set_num(L, lua_gettop(L), "video_card", NS_LIMIT_VIDEO_CARD_S);
    set_num(L, lua_gettop(L), "video_slow", NS_LIMIT_VIDEO_SLOW);
    set_num(L, lua_gettop(L), "video_zoom", NS_LIMIT_VIDEO_ZOOM);
    set_num(L, lua_gettop(L), "video_orbit", NS_LIMIT_VIDEO_ORBIT);
    lua_rawset(L, -3);
    lua_pushstring(L, "entry"); /* the scenario's entry: the first needle's (act.needle) */
    lua_createtable(L, 0, 2);
    set_vec(L, lua_gettop(L), "point", r->spec.entry_point);
    set_vec(L, lua_gettop(L), "direction", r->spec.entry_dir);
    lua_rawset(L, -3);
    lua_pushstring(L, "template"); /* the scenario's ns.template (act.needle), or nil */
    lua_rawgeti(L, LUA_REGISTRYINDEX, r->sc.table_ref);
    lua_pushstring(L, "template");
    lua_rawget(L, -2);
    lua_remove(L, -2);
    lua_rawset(L, -3);
    lua_pushstring(L, "planner"); /* act.steer's and ns.plan's planners (run_steer.c) */
    ns_run_steer_push(L, r);
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

int ns_run_script_start(NsRun *r, char *err, int err_sz)
{
    lua_State *L = ns_lua_state(r->sc.lua);
    TickIO io = {.r = r};
    if (!r->have_steer) { /* before the phase: it calls into the scenario's Lua state */
        if (ns_run_steer_setup(r, err, err_sz) != 0)
            return -1;
        r->have_steer = true;
    }
    /* One budget for the whole of the run's script and on_tick calls (sim/ns_limits.h). */
    ns_lua_begin_phase(r->sc.lua, "a tick of the run's script", NS_LIMIT_RUN_INSTRUCTIONS, 0.0,
                       NS_LIMIT_TICK_SECONDS);
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

/* What the script sees of the simulation at a tick (`sim`'s fields), taken from the run
 * (targets: r->spec.target_count positions into tx, 3 each). */
static void view_of_run(lua_State *L, TickIO *io, NsTickView *v, double *tx)
{
    NsRun *r = io->r;
    memset(v, 0, sizeof *v);
    v->depth = ns_run_depth(r);
    memcpy(v->tip, ns_run_tip(r), sizeof v->tip);
    v->axial = r->last_axial;
    double m1[3];
    ns_rod_tip_frame(&r->rod, v->tip_dir, m1, v->bevel_dir);
    memcpy(v->fr, r->last_fr, sizeof v->fr);
    v->cutting = r->last_cutting;
    v->seeds = r->seed_n;
    v->exited = io->exited;
    v->bone_contact = r->c.tip_blocked;
    v->tip_exited = r->c.params.remesh && r->c.path.through && !r->c.outside;
    v->events = r->event_n;
    for (int i = 0; i < r->spec.target_count; i++) {
        /* A copy of the hint: the search the score makes at the end must not depend on
         * whether a script looked at the targets (a replay does not), or the score could
         * differ in its last bits between a run and its replay. */
        int hint = r->target_hint[i];
        if (ns_run_world_of(&r->tissue.mesh, r->spec.targets[i].at, &hint, tx + 3 * i) != 0)
            luaL_error(L, "needlesim: target '%s' could not be located in the tissue",
                       r->spec.targets[i].name);
    }
}

/* Updates `sim` (at stack index si) for the tick from the view v: time, tip, forces, friction,
 * events, the targets where the tissue has carried them (tx). */
static void fill_sim(lua_State *L, TickIO *io, int si, const NsTickView *v, const double *tx)
{
    NsRun *r = io->r;
    set_num(L, si, "t", io->t);
    set_num(L, si, "dt", r->spec.dt);
    lua_pushstring(L, "step");
    lua_pushinteger(L, io->step);
    lua_rawset(L, si);
    set_num(L, si, "depth", v->depth);
    set_vec(L, si, "tip", v->tip);
    set_num(L, si, "axial_force", v->axial);
    set_vec(L, si, "tip_direction", v->tip_dir);
    set_vec(L, si, "bevel_direction", v->bevel_dir);
    lua_pushstring(L, "friction"); /* coupling nodes per friction state, last step */
    lua_createtable(L, 0, 4);
    set_num(L, lua_gettop(L), "sticking", v->fr[0]);
    set_num(L, lua_gettop(L), "sliding_in", v->fr[1]);
    set_num(L, lua_gettop(L), "sliding_out", v->fr[2]);
    lua_pushstring(L, "cutting");
    lua_pushboolean(L, v->cutting);
    lua_rawset(L, -3);
    lua_rawset(L, si);
    lua_pushstring(L, "seeds_dropped");
    lua_pushinteger(L, v->seeds);
    lua_rawset(L, si);
    lua_pushstring(L, "exited");
    lua_pushboolean(L, v->exited);
    lua_rawset(L, si);
    lua_pushstring(L, "bone_contact"); /* the tip rests on bone: the insertion stalls */
    lua_pushboolean(L, v->bone_contact);
    lua_rawset(L, si);
    lua_pushstring(L, "tip_exited"); /* the tip is out through the tissue's surface */
    lua_pushboolean(L, v->tip_exited);
    lua_rawset(L, si);
    lua_pushstring(L, "events"); /* a fresh list every step: {t, type, tip, region} */
    lua_createtable(L, v->events, 0);
    for (int i = 0; i < v->events && i < r->event_n; i++) {
        const struct Event *e = &r->events[i];
        lua_createtable(L, 0, 4);
        set_num(L, lua_gettop(L), "t", e->t);
        lua_pushstring(L, ns_run_event_names[e->type]);
        lua_setfield(L, -2, "type");
        set_vec(L, lua_gettop(L), "tip", e->x);
        if (e->type == EVENT_BONE_CONTACT) {
            lua_pushstring(L, ns_run_event_region(r, e));
            lua_setfield(L, -2, "region");
        }
        lua_rawseti(L, -2, i + 1);
    }
    lua_rawset(L, si);
    lua_pushstring(L, "targets"); /* a fresh table every step */
    lua_newtable(L);
    for (int i = 0; i < r->spec.target_count; i++)
        set_vec(L, lua_gettop(L), r->spec.targets[i].name, tx + 3 * i);
    lua_rawset(L, si);
}

/* One slice of the script's coroutine; io->more says whether it has more to do. */
static void resume_script(lua_State *L, TickIO *io)
{
    NsRun *r = io->r;
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
}

/* Reads the controls from sim.control (at stack index ci), raw, each checked and bounded
 * (sim/ns_limits.h), into io->ctl; the one-shot events are cleared. */
static int read_controls(lua_State *L, TickIO *io, int ci)
{
    NsRun *r = io->r;
    static const char *const keys[2] = {"v_insert", "twist_rate"};
    double *dst[2] = {&io->ctl.v_insert, &io->ctl.twist_rate};
    for (int k = 0; k < 2; k++) {
        int ty = get_raw(L, ci, keys[k]);
        double v = lua_tonumber(L, -1);
        if (ty != LUA_TNUMBER || !isfinite(v))
            return luaL_error(L, "sim.control.%s must be a finite number (got %s)", keys[k],
                              ty == LUA_TNUMBER ? "a non-finite number" : luaL_typename(L, -1));
        double lim = k == 0 ? NS_LIMIT_INSERT_SPEED : NS_LIMIT_TWIST_RATE;
        if (fabs(v) > lim) {
            char buf[160]; /* (lua_pushfstring knows no %g) */
            snprintf(buf, sizeof buf, "sim.control.%s %g is beyond its limit of %g %s", keys[k], v,
                     lim, k == 0 ? "m/s" : "rad/s");
            return luaL_error(L, "%s", buf);
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
                          "sim.control.base_velocity must be {vx, vy, vz}: 3 finite "
                          "numbers within +-%d mm/s, or nil",
                          (int)(1e3 * NS_LIMIT_BASE_SPEED));
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
                                  "sim.control.next_needle.%s must be {x, y, z}: three "
                                  "finite numbers",
                                  keys3[k]);
            if (ty == LUA_TTABLE)
                lua_pop(L, 3);
            lua_pop(L, 1);
            if (k < 2 && ty != LUA_TTABLE)
                return luaL_error(L, "sim.control.next_needle.%s must be {x, y, z}", keys3[k]);
        }
        io->ctl.next_needle = 1;
    }
    lua_pop(L, 1);
    lua_pushstring(L, "next_needle");
    lua_pushnil(L);
    lua_rawset(L, ci);
    /* the video's cues (act.caption, ...): not controls, and not in a recorded log */
    ns_run_video_take(&r->cues, r->rendering ? &r->rr : NULL, L, ci, io->t, io->view == NULL);
    /* act.drop_seed{} raises a one-shot flag */
    io->ctl.drop_seed = get_raw(L, ci, "drop_seed") != LUA_TNIL && lua_toboolean(L, -1);
    lua_pop(L, 1);
    lua_pushstring(L, "drop_seed");
    lua_pushnil(L);
    lua_rawset(L, ci);
    return 0;
}

/* A live session's controls into sim.control (at stack index ci), for on_tick to see and
 * change: the trainee's speeds and this step's events. */
static void seed_controls(lua_State *L, int ci, const NsControl *g)
{
    set_num(L, ci, "v_insert", g->v_insert);
    set_num(L, ci, "twist_rate", g->twist_rate);
    set_vec(L, ci, "base_velocity", g->v_base);
    lua_pushstring(L, "drop_seed");
    lua_pushboolean(L, g->drop_seed);
    lua_rawset(L, ci);
    lua_pushstring(L, "next_needle");
    if (g->next_needle) {
        lua_createtable(L, 0, 3);
        int ni = lua_gettop(L);
        set_vec(L, ni, "point", g->entry.point);
        set_vec(L, ni, "direction", g->entry.direction);
        if (g->entry.has_bevel_toward)
            set_vec(L, ni, "bevel_toward", g->entry.bevel_toward);
    } else {
        lua_pushnil(L);
    }
    lua_rawset(L, ci);
}

/* (io) -> (): updates `sim`, resumes the script for one step (in a live session only while
 * live.script has it drive), calls on_tick, reads the controls (raw accesses only: metatables a
 * script sets do not run here). */
static int tick_body(lua_State *L)
{
    TickIO *io = lua_touserdata(L, 1);
    NsRun *r = io->r;
    lua_rawgeti(L, LUA_REGISTRYINDEX, r->sim_ref);
    int si = lua_gettop(L);
    if (io->view) {
        fill_sim(L, io, si, io->view, io->view_tx);
    } else {
        NsTickView v;
        double *tx =
            lua_newuserdatauv(L, sizeof(double) * 3 * (size_t)(r->spec.target_count + 1), 0);
        view_of_run(L, io, &v, tx);
        fill_sim(L, io, si, &v, tx);
        lua_pop(L, 1);
        if (r->keep_views && ns_run_views_push(r, &v, tx) != 0)
            return luaL_error(L, "needlesim: out of memory");
    }
    bool scripted = !io->given || r->live_scripted;
    if (scripted)
        resume_script(L, io);
    lua_pushstring(L, "control");
    if (lua_rawget(L, si) != LUA_TTABLE)
        return luaL_error(L, "sim.control must stay a table");
    int ci = lua_gettop(L);
    if (io->given && !io->more) { /* the trainee drives */
        r->live_scripted = false;
        seed_controls(L, ci, io->given);
    } else if (!io->more && r->spec.has_script) { /* the script ended: the needle stops */
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
    return read_controls(L, io, ci);
}

/* One step of the script side. *more: the script has more to do; *ctl: the controls. */
int ns_run_script_tick(NsRun *r, double t, int exited, const NsControl *given, int *more,
                       NsControl *ctl, char *err, int err_sz)
{
    lua_State *L = ns_lua_state(r->sc.lua);
    TickIO io = {.r = r, .t = t, .step = r->steps, .exited = exited, .given = given};
    lua_pushcfunction(L, tick_body);
    lua_pushlightuserdata(L, &io);
    int rc = ns_lua_call(r->sc.lua, 1, 0, err, err_sz);
    *more = io.more;
    *ctl = io.ctl;
    if (rc == 0 && r->keep_views) { /* the view taken above gets what the script set */
        NsTickView *v = &r->views[r->view_n - 1];
        v->more = io.more;
        v->ctl = io.ctl;
    }
    return rc;
}

static bool entry_same(const NsEntry *a, const NsEntry *b)
{
    return memcmp(a->point, b->point, sizeof a->point) == 0 &&
           memcmp(a->direction, b->direction, sizeof a->direction) == 0 &&
           memcmp(a->bevel_toward, b->bevel_toward, sizeof a->bevel_toward) == 0 &&
           a->has_bevel_toward == b->has_bevel_toward;
}

int ns_run_script_replay_tick(NsRun *r, long k, char *err, int err_sz)
{
    lua_State *L = ns_lua_state(r->sc.lua);
    const NsTickView *v = &r->views[k];
    TickIO io = {.r = r,
                 .t = (double)k * r->spec.dt,
                 .step = k,
                 .exited = v->exited,
                 .view = v,
                 .view_tx = r->view_tx + 3 * (size_t)r->spec.target_count * (size_t)k};
    lua_pushcfunction(L, tick_body);
    lua_pushlightuserdata(L, &io);
    if (ns_lua_call(r->sc.lua, 1, 0, err, err_sz) != 0)
        return -1;
    const NsControl *a = &v->ctl, *b = &io.ctl;
    bool same =
        io.more == v->more && a->v_insert == b->v_insert && a->twist_rate == b->twist_rate &&
        memcmp(a->v_base, b->v_base, sizeof a->v_base) == 0 && a->drop_seed == b->drop_seed &&
        a->next_needle == b->next_needle && (!a->next_needle || entry_same(&a->entry, &b->entry));
    if (!same)
        ns_set_err(err, err_sz,
                   "%s: the script did not repeat its course at step %ld of the checkpoint (does "
                   "it depend on something besides `sim`?)",
                   r->sc.path, k);
    return same ? 0 : -1;
}
