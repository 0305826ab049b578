/* __ns_plan_implant, the engine's half of ns.plan_implant (scripts/needlesim.lua): the tissue's
 * region shapes become NsShapes as the mesher's are made (scenario.c), the TG-43 source is
 * model 6711's (assets/tg43/), and plan/implant.c makes the plan. The Lua half checks the
 * fields, names the holes and raises the error with the caller's file and line. */
#include <lauxlib.h>
#include <lua.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "dose_table.h"
#include "implant.h"
#include "scenario_internal.h"

enum { REGIONS_MAX = 64 };

/* t[key] as a number (the Lua half put it there). */
static double num(lua_State *L, int t, const char *key)
{
    scn_rawfield(L, t, key);
    double v = lua_tonumber(L, -1);
    lua_pop(L, 1);
    return v;
}

/* t[key] as an int in [lo, hi], or lo - 1 when it is not one (no out-of-range cast). */
static int integer(lua_State *L, int t, const char *key, int lo, int hi)
{
    scn_rawfield(L, t, key);
    int ok;
    lua_Integer v = lua_tointegerx(L, -1, &ok);
    lua_pop(L, 1);
    return ok && v >= lo && v <= hi ? (int)v : lo - 1;
}

/* The list t[key] of n numbers into out (n at most max); -1 if it is not one. */
static int numbers(lua_State *L, int t, const char *key, double *out, int max, int *n)
{
    if (scn_rawfield(L, t, key) != LUA_TTABLE) {
        lua_pop(L, 1);
        return -1;
    }
    int l = (int)lua_rawlen(L, -1);
    if (l > max) {
        lua_pop(L, 1);
        return -1;
    }
    for (int i = 0; i < l; i++) {
        scn_rawindex(L, -1, i + 1);
        int ok;
        out[i] = lua_tonumberx(L, -1, &ok);
        lua_pop(L, 1);
        if (!ok) {
            lua_pop(L, 1);
            return -1;
        }
    }
    lua_pop(L, 1);
    *n = l;
    return 0;
}

/* What the protected part fills. */
typedef struct ImplantIO {
    NsShape *shapes[REGIONS_MAX];
    int nshapes;
    int avoid[NS_IMPLANT_MAX_AVOID];
    double *holes;
    NsImplantPlan plan;
    Builder b;
    int rc;
    char err[512];
} ImplantIO;

/* Reads the arguments and plans; -1 with io->err. */
static int plan(lua_State *L, Builder *b, ImplantIO *io)
{
    const int t = 1;
    NsImplantParams p = {0};
    if (scn_rawfield(L, t, "regions") != LUA_TTABLE)
        return scn_fail(b, "regions must be a list of shapes");
    int nr = (int)lua_rawlen(L, -1);
    if (nr < 1 || nr > REGIONS_MAX)
        return scn_fail(b, "the tissue has %d regions (1 to %d)", nr, REGIONS_MAX);
    for (int i = 0; i < nr; i++) {
        scn_rawindex(L, -1, i + 1);
        io->shapes[i] = scn_shape_from_lua(b, -1, "ns.plan_implant", "tissue", 0);
        lua_pop(L, 1);
        if (!io->shapes[i])
            return -1;
        io->nshapes++;
    }
    lua_pop(L, 1);
    if (b->nfns > 0) /* evaluating one needs the scenario's runtime, which is not built yet */
        return scn_fail(b, "the tissue has a region shaped by a Lua function: plan on "
                           "ns.shape.* regions");
    double v[NS_IMPLANT_MAX_AVOID * 3 > 3 ? NS_IMPLANT_MAX_AVOID * 3 : 3];
    int n = 0;
    if (numbers(L, t, "avoid", v, NS_IMPLANT_MAX_AVOID, &n))
        return scn_fail(b, "avoid must be a list of at most %d region indices",
                        NS_IMPLANT_MAX_AVOID);
    for (int i = 0; i < n; i++) /* 1-based; anything else is refused by the planner as -1 */
        io->avoid[i] = v[i] >= 1 && v[i] <= nr && v[i] == floor(v[i]) ? (int)v[i] - 1 : -1;
    p.avoid = io->avoid;
    p.avoid_count = n;
    if (numbers(L, t, "direction", p.direction, 3, &n) || n != 3)
        return scn_fail(b, "direction must be {x, y, z}");
    if (scn_rawfield(L, t, "holes") != LUA_TTABLE)
        return scn_fail(b, "holes must be a list of points");
    int nh = (int)lua_rawlen(L, -1);
    lua_pop(L, 1);
    if (nh < 1 || nh > NS_IMPLANT_MAX_HOLES)
        return scn_fail(b, "the template has %d holes (1 to %d)", nh, NS_IMPLANT_MAX_HOLES);
    io->holes = malloc((size_t)nh * 3 * sizeof *io->holes);
    if (!io->holes)
        return scn_fail(b, "out of memory");
    scn_rawfield(L, t, "holes");
    for (int i = 0; i < nh; i++) {
        scn_rawindex(L, -1, i + 1);
        int k = 0;
        int bad = lua_type(L, -1) != LUA_TTABLE || lua_rawlen(L, -1) != 3;
        for (int j = 0; !bad && j < 3; j++, k++) {
            scn_rawindex(L, -1, j + 1);
            int ok;
            io->holes[3 * i + j] = lua_tonumberx(L, -1, &ok);
            bad = !ok;
            lua_pop(L, 1);
        }
        lua_pop(L, 1);
        if (bad) {
            lua_pop(L, 1);
            return scn_fail(b, "holes[%d] must be {x, y, z}", i + 1);
        }
    }
    lua_pop(L, 1);
    NsTg43Source src;
    if (ns_tg43_load_6711(&src, b->err, b->err_sz))
        return -1;
    p.regions = (const NsShape *const *)io->shapes;
    p.region_count = nr;
    p.target = integer(L, t, "target", 1, nr) - 1;
    p.holes = io->holes;
    p.hole_count = nh;
    p.clearance = num(L, t, "clearance");
    p.spacing = num(L, t, "spacing");
    p.seeds_per_needle = integer(L, t, "seeds_per_needle", 1, 1000);
    p.tip_offset = num(L, t, "tip_offset");
    p.margin = num(L, t, "margin");
    p.seeds_max = integer(L, t, "seeds", 1, NS_DOSE_MAX_SEEDS);
    p.needles_max = integer(L, t, "needles", 1, NS_IMPLANT_MAX_HOLES);
    p.prescription = num(L, t, "prescription");
    p.coverage = num(L, t, "coverage");
    p.v150_max = num(L, t, "v150_max");
    p.grid = num(L, t, "grid");
    p.source = &src;
    p.sk = num(L, t, "strength") * NS_TG43_UNIT_U;
    if (ns_plan_implant(&p, &io->plan, b->err, b->err_sz))
        return -1;
    return 0;
}

static void set_number(lua_State *L, const char *key, double v)
{
    lua_pushnumber(L, v);
    lua_setfield(L, -2, key);
}

static void set_integer(lua_State *L, const char *key, lua_Integer v)
{
    lua_pushinteger(L, v);
    lua_setfield(L, -2, key);
}

/* The plan as {needles = {{hole = i, seeds = n, deepest = s}, ...}, seeds = {{x, y, z}, ...},
 * v100, v150, d90, voxels, candidates, blocked, reached}. */
static void push_plan(lua_State *L, const NsImplantPlan *pl)
{
    lua_createtable(L, 0, 9);
    lua_createtable(L, pl->needle_count, 0);
    for (int i = 0; i < pl->needle_count; i++) {
        lua_createtable(L, 0, 3);
        set_integer(L, "hole", pl->hole[i] + 1);
        set_integer(L, "seeds", pl->seeds[i]);
        set_number(L, "deepest", pl->deepest[i]);
        lua_rawseti(L, -2, i + 1);
    }
    lua_setfield(L, -2, "needles");
    lua_createtable(L, pl->seed_count, 0);
    for (int i = 0; i < pl->seed_count; i++) {
        lua_createtable(L, 3, 0);
        for (int k = 0; k < 3; k++) {
            lua_pushnumber(L, pl->seed_pos[3 * i + k]);
            lua_rawseti(L, -2, k + 1);
        }
        lua_rawseti(L, -2, i + 1);
    }
    lua_setfield(L, -2, "seeds");
    set_number(L, "v100", pl->v100);
    set_number(L, "v150", pl->v150);
    set_number(L, "d90", pl->d90);
    set_integer(L, "voxels", pl->voxels);
    set_integer(L, "candidates", pl->candidates);
    set_integer(L, "blocked", pl->blocked);
    lua_pushboolean(L, pl->reached);
    lua_setfield(L, -2, "reached");
}

/* (io) -> (): plan() inside a protected call, so that a Lua error in a push comes back here. */
static int plan_body(lua_State *L)
{
    ImplantIO *io = lua_touserdata(L, 2);
    lua_settop(L, 1);
    io->rc = plan(L, &io->b, io);
    return 0;
}

/* (plan) -> the plan's table, inside a protected call for the same reason. */
static int push_body(lua_State *L)
{
    push_plan(L, lua_touserdata(L, 1));
    return 1;
}

/* __ns_plan_implant(args) -> plan, or nil and the reason. Whatever fails, nothing it
 * allocates outlives it. */
int scn_l_plan_implant(lua_State *L)
{
    luaL_checktype(L, 1, LUA_TTABLE);
    lua_settop(L, 1);
    ImplantIO *io = calloc(1, sizeof *io);
    if (!io)
        return luaL_error(L, "ns.plan_implant: out of memory");
    io->b = (Builder){.L = L, .err = io->err, .err_sz = (int)sizeof io->err};
    io->rc = -1;
    lua_pushcfunction(L, plan_body);
    lua_pushvalue(L, 1);
    lua_pushlightuserdata(L, io);
    if (lua_pcall(L, 2, 0, 0) != LUA_OK) {
        snprintf(io->err, sizeof io->err, "%s", lua_tostring(L, -1) ? lua_tostring(L, -1) : "?");
        lua_pop(L, 1);
        io->rc = -1;
    }
    for (int i = 0; i < io->nshapes; i++)
        ns_shape_release(io->shapes[i]);
    for (int i = 0; i < io->b.nfns; i++) {
        luaL_unref(L, LUA_REGISTRYINDEX, io->b.fns[i]->ref);
        free(io->b.fns[i]);
    }
    free(io->b.fns);
    free(io->holes);
    NsImplantPlan pl = io->plan;
    int rc = io->rc;
    char err[512];
    snprintf(err, sizeof err, "%s", io->err);
    free(io);
    if (rc) {
        ns_implant_plan_free(&pl);
        lua_pushnil(L);
        lua_pushstring(L, err);
        return 2;
    }
    lua_pushcfunction(L, push_body);
    lua_pushlightuserdata(L, &pl);
    int st = lua_pcall(L, 1, 1, 0);
    ns_implant_plan_free(&pl);
    return st == LUA_OK ? 1 : lua_error(L);
}
