/* Scenario loading: run the Lua file, read back the tables scripts/needlesim.lua built, and
 * build the tissue with sim/ (see scenario.h).
 *
 * The Lua side has already validated every field and recorded where each table was written
 * (`where`), so errors here are about what only C can know (a file that does not open, a mesh
 * whose tags have no material, a shape function that fails while the mesher runs). Each one
 * still names the `where` of the table it is about. Fields are read defensively anyway: a
 * scenario can change a table after its constructor checked it. */
#include "scenario.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#include <lauxlib.h>

#include "err.h"
#include "mesh_io.h"
#include "ns_limits.h"
#include "quality.h"
#include "scenario_internal.h"
#include "shape.h"

int scn_cmp_int(const void *a, const void *b)
{
    int x = *(const int *)a, y = *(const int *)b;
    return (x > y) - (x < y);
}

char *scn_dup_string(const char *s)
{
    if (!s)
        return NULL;
    size_t n = strlen(s) + 1;
    char *d = malloc(n);
    if (d)
        memcpy(d, s, n);
    return d;
}

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return 1e3 * (double)ts.tv_sec + 1e-6 * (double)ts.tv_nsec;
}

int scn_fail(Builder *b, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(b->err, (size_t)b->err_sz, fmt, ap);
    va_end(ap);
    return -1;
}

/* ---- reading tables ------------------------------------------------------------------------ */

/* t[key] and t[i] without metamethods, pushed, their type returned; nil when t is not a table.
 * A scenario may put metatables on the tables it returns (an erroring __index, a __len that
 * returns 1.5): none of that code may run here. Everything below reads through these. */
int scn_rawfield(lua_State *L, int idx, const char *key)
{
    idx = lua_absindex(L, idx);
    if (!lua_istable(L, idx)) {
        lua_pushnil(L);
        return LUA_TNIL;
    }
    lua_pushstring(L, key);
    return lua_rawget(L, idx);
}

int scn_rawindex(lua_State *L, int idx, lua_Integer i)
{
    idx = lua_absindex(L, idx);
    if (!lua_istable(L, idx)) {
        lua_pushnil(L);
        return LUA_TNIL;
    }
    return lua_rawgeti(L, idx, i);
}

/* The __ns_kind of the metatable of the value at idx ("shape", "material", ...), or "". */
static const char *kind_of(lua_State *L, int idx, char *buf, size_t n)
{
    buf[0] = '\0';
    if (lua_type(L, idx) != LUA_TTABLE || !lua_getmetatable(L, idx))
        return buf;
    if (scn_rawfield(L, -1, "__ns_kind") == LUA_TSTRING)
        snprintf(buf, n, "%s", lua_tostring(L, -1));
    lua_pop(L, 2);
    return buf;
}

bool scn_is_kind(lua_State *L, int idx, const char *kind)
{
    char buf[32];
    return strcmp(kind_of(L, idx, buf, sizeof buf), kind) == 0;
}

/* The table's `where` ("file:line"), or the fallback. */
void scn_get_where(lua_State *L, int idx, const char *fallback, char *out, size_t n)
{
    if (scn_rawfield(L, idx, "where") == LUA_TSTRING)
        snprintf(out, n, "%s", lua_tostring(L, -1));
    else
        snprintf(out, n, "%s", fallback);
    lua_pop(L, 1);
}

int scn_get_string(Builder *b, int idx, const char *key, const char *where, const char *ctor,
                   bool required, char **out)
{
    lua_State *L = b->L;
    int t = scn_rawfield(L, idx, key);
    *out = NULL;
    if (t == LUA_TNIL && !required) {
        lua_pop(L, 1);
        return 0;
    }
    if (t != LUA_TSTRING) {
        lua_pop(L, 1);
        return scn_fail(b, "%s: %s: %s must be a string (got %s)", where, ctor, key,
                        lua_typename(L, t));
    }
    *out = scn_dup_string(lua_tostring(L, -1));
    lua_pop(L, 1);
    return *out ? 0 : scn_fail(b, "%s: %s: out of memory", where, ctor);
}

int scn_get_number(Builder *b, int idx, const char *key, const char *where, const char *ctor,
                   double *out)
{
    lua_State *L = b->L;
    int t = scn_rawfield(L, idx, key);
    double x = lua_tonumber(L, -1);
    lua_pop(L, 1);
    if (t != LUA_TNUMBER || !isfinite(x))
        return scn_fail(b, "%s: %s: %s must be a finite number", where, ctor, key);
    *out = x;
    return 0;
}

/* A list of n finite numbers. */
int scn_get_vector(Builder *b, int idx, const char *key, int n, const char *where, const char *ctor,
                   double *out)
{
    lua_State *L = b->L;
    if (scn_rawfield(L, idx, key) != LUA_TTABLE) {
        lua_pop(L, 1);
        return scn_fail(b, "%s: %s: %s must be a list of %d numbers", where, ctor, key, n);
    }
    for (int i = 0; i < n; i++) {
        int t = scn_rawindex(L, -1, i + 1);
        out[i] = lua_tonumber(L, -1);
        lua_pop(L, 1);
        if (t != LUA_TNUMBER || !isfinite(out[i])) {
            lua_pop(L, 1);
            return scn_fail(b, "%s: %s: %s[%d] must be a finite number", where, ctor, key, i + 1);
        }
    }
    lua_pop(L, 1);
    return 0;
}

bool scn_get_bool(lua_State *L, int idx, const char *key)
{
    scn_rawfield(L, idx, key);
    bool v = lua_toboolean(L, -1);
    lua_pop(L, 1);
    return v;
}

/* ---- materials ----------------------------------------------------------------------------- */

const char *ns_material_model_name(NsElasticModel m)
{
    return m == NS_MODEL_NEOHOOKEAN ? "neohookean" : "corotational";
}

void scn_material_free(NsMaterial *m)
{
    free(m->name);
    m->name = NULL;
}

/* The material table at idx, used by the table described by (where, ctor). */
int scn_material_from_lua(Builder *b, int idx, const char *where, const char *ctor, NsMaterial *m)
{
    lua_State *L = b->L;
    memset(m, 0, sizeof *m);
    idx = lua_absindex(L, idx);
    if (!scn_is_kind(L, idx, "material"))
        return scn_fail(b,
                        "%s: %s: material must be a material (ns.material{...} or "
                        "ns.materials.<name>)",
                        where, ctor);
    char mwhere[WHERE_MAX];
    scn_get_where(L, idx, where, mwhere, sizeof mwhere);
    const char *mc = "ns.material";
    if (scn_get_string(b, idx, "name", mwhere, mc, true, &m->name) ||
        scn_get_number(b, idx, "youngs", mwhere, mc, &m->youngs) ||
        scn_get_number(b, idx, "poisson", mwhere, mc, &m->poisson) ||
        scn_get_number(b, idx, "density", mwhere, mc, &m->density) ||
        scn_get_number(b, idx, "damping", mwhere, mc, &m->damping) ||
        scn_get_number(b, idx, "friction", mwhere, mc, &m->friction) ||
        scn_get_number(b, idx, "cut_force", mwhere, mc, &m->cut_force))
        return -1;
    /* The same ranges the constructor checks (the table may have been changed since). */
    const char *bad = NULL;
    if (!(m->youngs > 0))
        bad = "youngs must be > 0";
    else if (!(m->poisson >= 0 && m->poisson < 0.5))
        bad = "poisson must be in [0, 0.5)";
    else if (!(m->density > 0))
        bad = "density must be > 0";
    else if (!(m->damping >= 0) || !(m->friction >= 0) || !(m->cut_force >= 0))
        bad = "damping, friction and cut_force must be >= 0";
    if (bad)
        return scn_fail(b, "%s: %s: %s", mwhere, mc, bad);
    char *model = NULL;
    if (scn_get_string(b, idx, "model", mwhere, mc, false, &model))
        return -1;
    if (!model || strcmp(model, "corotational") == 0) {
        m->model = NS_MODEL_COROTATIONAL;
    } else if (strcmp(model, "neohookean") == 0) {
        m->model = NS_MODEL_NEOHOOKEAN;
    } else {
        scn_fail(b, "%s: %s: model must be 'corotational' or 'neohookean' (got '%s')", mwhere, mc,
                 model);
        free(model);
        return -1;
    }
    free(model);
    int t = scn_rawfield(L, idx, "membrane");
    if (t == LUA_TTABLE) {
        int mi = lua_gettop(L);
        m->has_membrane = true;
        int rc = scn_get_number(b, mi, "thickness", mwhere, "ns.material: membrane",
                                &m->membrane_thickness);
        if (rc == 0)
            rc = scn_get_number(b, mi, "cut_force", mwhere, "ns.material: membrane",
                                &m->membrane_cut_force);
        lua_pop(L, 1);
        if (rc)
            return -1;
        if (!(m->membrane_thickness > 0) || !(m->membrane_cut_force >= 0))
            return scn_fail(
                b, "%s: ns.material: membrane: thickness must be > 0 and cut_force >= 0", mwhere);
    } else {
        lua_pop(L, 1);
        if (t != LUA_TNIL)
            return scn_fail(b, "%s: ns.material: membrane must be a table {thickness, cut_force}",
                            mwhere);
    }
    return 0;
}

/* ---- shapes -------------------------------------------------------------------------------- */

/* ns_shape_callback's function for a Lua function shape: d = f(x, y, z). The first failure
 * is kept in b->fn_err and every later call returns NaN at once, which stops the mesher. */
static double lua_shape_eval(void *user, const double p[3])
{
    LuaShapeFn *f = user;
    Builder *b = f->b;
    if (b->fn_failed)
        return NAN;
    lua_State *L = b->L;
    lua_rawgeti(L, LUA_REGISTRYINDEX, f->ref);
    lua_pushnumber(L, p[0]);
    lua_pushnumber(L, p[1]);
    lua_pushnumber(L, p[2]);
    if (ns_lua_call(b->sc->lua, 3, 1, b->fn_err, (int)sizeof b->fn_err) != 0) {
        b->fn_failed = true;
        return NAN;
    }
    int t = lua_type(L, -1);
    double d = lua_tonumber(L, -1);
    lua_pop(L, 1);
    if (t == LUA_TNUMBER && isfinite(d))
        return d;
    char got[64];
    if (t == LUA_TNUMBER)
        snprintf(got, sizeof got, "%g", d);
    else
        snprintf(got, sizeof got, "%s", lua_typename(L, t));
    lua_Debug ar;
    lua_rawgeti(L, LUA_REGISTRYINDEX, f->ref);
    lua_getinfo(L, ">S", &ar);
    const char *src = ar.source[0] == '@' ? ar.source + 1 : ar.short_src;
    snprintf(b->fn_err, sizeof b->fn_err,
             "%s:%d: shape function returned %s at (%g, %g, %g) (expected a finite signed "
             "distance in metres, negative inside)",
             src, ar.linedefined, got, p[0], p[1], p[2]);
    b->fn_failed = true;
    return NAN;
}

static NsShape *function_shape(Builder *b, int idx, const char *where)
{
    lua_State *L = b->L;
    if (b->nfns == b->capfns) {
        int cap = b->capfns ? 2 * b->capfns : 8;
        LuaShapeFn **fns = realloc(b->fns, (size_t)cap * sizeof *fns);
        if (!fns) {
            scn_fail(b, "%s: out of memory", where);
            return NULL;
        }
        b->fns = fns;
        b->capfns = cap;
    }
    LuaShapeFn *f = malloc(sizeof *f);
    if (!f) {
        scn_fail(b, "%s: out of memory", where);
        return NULL;
    }
    f->b = b;
    lua_pushvalue(L, idx);
    f->ref = luaL_ref(L, LUA_REGISTRYINDEX);
    b->fns[b->nfns++] = f;
    /* Without tissue bounds the function is unbounded; an enclosing intersection or
     * difference may still bound it, and build_shapes checks the final bounds. */
    double lo[3] = {-INFINITY, -INFINITY, -INFINITY}, hi[3] = {INFINITY, INFINITY, INFINITY};
    NsShape *s = ns_shape_callback(lua_shape_eval, f, b->have_bounds ? b->blo : lo,
                                   b->have_bounds ? b->bhi : hi);
    if (!s)
        scn_fail(b, "%s: out of memory", where);
    return s;
}

NsShape *scn_shape_from_lua(Builder *b, int idx, const char *ctx_where, const char *ctx, int depth);

/* Converts the list field `key` of the shape table at idx into shapes (count in *n). */
NsShape **scn_shape_list(Builder *b, int idx, const char *key, const char *where, const char *ctor,
                         int depth, int *n)
{
    lua_State *L = b->L;
    *n = 0;
    if (scn_rawfield(L, idx, key) != LUA_TTABLE) {
        lua_pop(L, 1);
        scn_fail(b, "%s: %s: %s must be a list of shapes", where, ctor, key);
        return NULL;
    }
    int li = lua_gettop(L);
    lua_Integer count = (lua_Integer)lua_rawlen(L, li);
    if (count < 1 || count > 1000000) {
        lua_pop(L, 1);
        scn_fail(b, "%s: %s: needs at least one shape", where, ctor);
        return NULL;
    }
    NsShape **kids = calloc((size_t)count, sizeof *kids);
    if (!kids) {
        lua_pop(L, 1);
        scn_fail(b, "%s: out of memory", where);
        return NULL;
    }
    for (lua_Integer i = 0; i < count; i++) {
        scn_rawindex(L, li, i + 1);
        kids[i] = scn_shape_from_lua(b, -1, where, ctor, depth + 1);
        lua_pop(L, 1);
        if (!kids[i]) {
            for (lua_Integer k = 0; k < i; k++)
                ns_shape_release(kids[k]);
            free(kids);
            lua_pop(L, 1);
            return NULL;
        }
    }
    lua_pop(L, 1);
    *n = (int)count;
    return kids;
}

NsShape *scn_shape_field(Builder *b, int idx, const char *key, const char *where, const char *ctor,
                         int depth)
{
    scn_rawfield(b->L, idx, key);
    NsShape *s = scn_shape_from_lua(b, -1, where, ctor, depth + 1);
    lua_pop(b->L, 1);
    return s;
}

/* The shape (a table made by ns.shape.* or a Lua function) at idx, inside the table
 * described by (ctx_where, ctx). Returns a new reference, or NULL with b->err set. */
NsShape *scn_shape_from_lua(Builder *b, int idx, const char *ctx_where, const char *ctx, int depth)
{
    lua_State *L = b->L;
    idx = lua_absindex(L, idx);
    if (depth > SHAPE_DEPTH_MAX) {
        scn_fail(b, "%s: %s: shapes nested more than %d deep (does a shape contain itself?)",
                 ctx_where, ctx, SHAPE_DEPTH_MAX);
        return NULL;
    }
    /* A shape used twice is copied twice (a tree, not a graph): s = union(s, s) forty times is
     * 2^40 nodes. The whole tissue's count is bounded (sim/ns_limits.h). */
    if (++b->shape_nodes > NS_LIMIT_SHAPE_NODES) {
        scn_fail(b,
                 "%s: %s: the shapes have more than %d nodes in all (a shape used many "
                 "times over is copied each time)",
                 ctx_where, ctx, NS_LIMIT_SHAPE_NODES);
        return NULL;
    }
    if (!lua_checkstack(L, 8)) {
        scn_fail(b, "%s: %s: out of memory", ctx_where, ctx);
        return NULL;
    }
    if (lua_type(L, idx) == LUA_TFUNCTION)
        return function_shape(b, idx, ctx_where);
    if (!scn_is_kind(L, idx, "shape")) {
        scn_fail(b, "%s: %s: expected a shape (ns.shape.* or function(x, y, z)), got a %s",
                 ctx_where, ctx, luaL_typename(L, idx));
        return NULL;
    }
    char where[WHERE_MAX], type[32];
    scn_get_where(L, idx, ctx_where, where, sizeof where);
    if (scn_rawfield(L, idx, "type") == LUA_TSTRING)
        snprintf(type, sizeof type, "%s", lua_tostring(L, -1));
    else
        type[0] = '\0';
    lua_pop(L, 1);
    char ctor[48];
    snprintf(ctor, sizeof ctor, "ns.shape.%s", type);

    NsShape *s = NULL;
    double c[3] = {0}, d[3] = {0}, r = 0;
    if (strcmp(type, "sphere") == 0) {
        if (scn_get_vector(b, idx, "center", 3, where, ctor, c) ||
            scn_get_number(b, idx, "radius", where, ctor, &r))
            return NULL;
        if (!(r > 0)) {
            scn_fail(b, "%s: %s: radius must be > 0", where, ctor);
            return NULL;
        }
        s = ns_shape_sphere(c, r);
    } else if (strcmp(type, "ellipsoid") == 0 || strcmp(type, "box") == 0) {
        bool box = type[0] == 'b';
        const char *dk = box ? "size" : "radii";
        if (scn_get_vector(b, idx, "center", 3, where, ctor, c) ||
            scn_get_vector(b, idx, dk, 3, where, ctor, d))
            return NULL;
        if (!(d[0] > 0 && d[1] > 0 && d[2] > 0)) {
            scn_fail(b, "%s: %s: %s must be > 0", where, ctor, dk);
            return NULL;
        }
        s = box ? ns_shape_box(c, d) : ns_shape_ellipsoid(c, d);
    } else if (strcmp(type, "cylinder") == 0 || strcmp(type, "capsule") == 0) {
        if (scn_get_vector(b, idx, "a", 3, where, ctor, c) ||
            scn_get_vector(b, idx, "b", 3, where, ctor, d) ||
            scn_get_number(b, idx, "radius", where, ctor, &r))
            return NULL;
        if (!(r > 0)) {
            scn_fail(b, "%s: %s: radius must be > 0", where, ctor);
            return NULL;
        }
        s = type[1] == 'y' ? ns_shape_cylinder(c, d, r) : ns_shape_capsule(c, d, r);
    } else if (strcmp(type, "union") == 0 || strcmp(type, "intersection") == 0) {
        int n;
        NsShape **kids = scn_shape_list(b, idx, "children", where, ctor, depth, &n);
        if (!kids)
            return NULL;
        s = type[0] == 'u' ? ns_shape_union(kids, n) : ns_shape_intersection(kids, n);
        for (int i = 0; i < n; i++)
            ns_shape_release(kids[i]);
        free(kids);
    } else if (strcmp(type, "difference") == 0) {
        NsShape *a = scn_shape_field(b, idx, "a", where, ctor, depth);
        if (!a)
            return NULL;
        NsShape *bb = scn_shape_field(b, idx, "b", where, ctor, depth);
        if (!bb) {
            ns_shape_release(a);
            return NULL;
        }
        s = ns_shape_difference(a, bb);
        ns_shape_release(a);
        ns_shape_release(bb);
    } else if (strcmp(type, "transform") == 0) {
        double rot[9] = {0}, t[3] = {0}, k = 0;
        if (scn_get_vector(b, idx, "rotation", 9, where, ctor, rot) ||
            scn_get_vector(b, idx, "translate", 3, where, ctor, t) ||
            scn_get_number(b, idx, "scale", where, ctor, &k))
            return NULL;
        if (!(k > 0)) {
            scn_fail(b, "%s: %s: scale must be > 0", where, ctor);
            return NULL;
        }
        NsShape *child = scn_shape_field(b, idx, "child", where, ctor, depth);
        if (!child)
            return NULL;
        s = ns_shape_transform(child, rot, t, k);
        ns_shape_release(child);
    } else {
        scn_fail(b, "%s: unknown shape type '%s'", where, type);
        return NULL;
    }
    if (!s)
        scn_fail(b, "%s: %s: out of memory", where, ctor);
    return s;
}

/* ---- load / free --------------------------------------------------------------------------- */

int ns_scenario_load(const char *path, NsScenario *sc, char *err, int err_sz)
{
    return ns_scenario_load_set(path, NULL, 0, sc, err, err_sz);
}

/* The --set values as the global table __ns_sets (KEY -> VALUE string) that ns.param reads,
 * before the scenario runs; afterwards every key must have been read by an ns.param call. */
static void push_sets(lua_State *L, const char *const *sets, int nsets)
{
    lua_newtable(L);
    for (int i = 0; i < nsets; i++) {
        const char *eq = strchr(sets[i], '=');
        lua_pushlstring(L, sets[i], (size_t)(eq - sets[i]));
        lua_pushstring(L, eq + 1);
        lua_rawset(L, -3);
    }
    lua_setglobal(L, "__ns_sets");
    lua_pushcfunction(L, scn_l_plan_implant);
    lua_setglobal(L, "__ns_plan_implant");
    lua_newtable(L);
    lua_setglobal(L, "__ns_params");
}

static int check_sets(Builder *b, const char *const *sets, int nsets)
{
    lua_State *L = b->L;
    int rc = 0;
    /* KEY -> true for every ns.param the scenario called; read raw from the globals table (a
     * scenario may have put a metatable on _G). */
    lua_rawgeti(L, LUA_REGISTRYINDEX, LUA_RIDX_GLOBALS);
    lua_pushstring(L, "__ns_params");
    lua_rawget(L, -2);
    lua_remove(L, -2);
    for (int i = 0; i < nsets && rc == 0; i++) {
        const char *eq = strchr(sets[i], '=');
        lua_pushlstring(L, sets[i], (size_t)(eq - sets[i]));
        int used = lua_istable(L, -2) && lua_rawget(L, -2) != LUA_TNIL;
        lua_pop(L, 1);
        if (!used) {
            char known[512] = "";
            if (lua_istable(L, -1)) {
                lua_pushnil(L);
                while (lua_next(L, -2)) {
                    lua_pop(L, 1);
                    if (lua_type(L, -1) == LUA_TSTRING)
                        snprintf(known + strlen(known), sizeof known - strlen(known), "%s%s",
                                 known[0] ? ", " : "", lua_tostring(L, -1));
                }
            }
            rc = scn_fail(b, "%s: --set %.*s: the scenario has no parameter '%.*s' (%s%s)",
                          b->sc->path, (int)(eq - sets[i]), sets[i], (int)(eq - sets[i]), sets[i],
                          known[0] ? "its parameters: " : "it reads none with ns.param", known);
        }
    }
    lua_pop(L, 1);
    return rc;
}

/* What ns_scenario_load_set does inside one protected call. */
typedef struct LoadIO {
    Builder *b;
    const char *path;
    const char *const *sets;
    int nsets;
    int rc; /* out: 0, or -1 with b->err filled */
} LoadIO;

/* (io) -> (): runs the scenario file and builds its tissue. It runs as a protected call, so a
 * Lua error raised anywhere in it (out of memory in a push, say) comes back as a message, not
 * as a panic; everything it allocates is owned by the scenario or by the Builder, which the
 * caller frees either way. */
static int load_body(lua_State *L)
{
    LoadIO *io = lua_touserdata(L, 1);
    lua_settop(L, 0);
    Builder *b = io->b;
    NsScenario *sc = b->sc;
    push_sets(L, io->sets, io->nsets);
    if (ns_lua_run_scenario(sc->lua, io->path, b->err, b->err_sz) != 0) {
        io->rc = -1;
        return 0;
    }
    int si = lua_gettop(L);
    int rc = 0;
    if (!scn_is_kind(L, si, "scenario")) {
        rc = scn_fail(b, "%s: the scenario file must return ns.scenario{...} (it returned %s)",
                      io->path,
                      lua_isnil(L, si)     ? "nothing"
                      : lua_istable(L, si) ? "a plain table: wrap it in ns.scenario{...}"
                                           : luaL_typename(L, si));
    }
    if (rc == 0) {
        char where[WHERE_MAX];
        scn_get_where(L, si, io->path, where, sizeof where);
        sc->where = scn_dup_string(where);
        rc = sc->where ? scn_get_string(b, si, "name", where, "ns.scenario", true, &sc->name)
                       : scn_fail(b, "needlesim: out of memory");
    }
    if (rc == 0 && strlen(sc->name) > NS_LIMIT_SCENARIO_NAME)
        rc = scn_fail(b, "%s: ns.scenario: name is %zu bytes long (at most %d)", sc->where,
                      strlen(sc->name), NS_LIMIT_SCENARIO_NAME);
    if (rc == 0)
        rc =
            scn_get_string(b, si, "description", sc->where, "ns.scenario", false, &sc->description);
    if (rc == 0)
        rc = check_sets(b, io->sets, io->nsets);
    if (rc == 0)
        rc = scn_build_tissue(b, si);
    if (rc == 0) {
        lua_pushvalue(L, si);
        sc->table_ref = luaL_ref(L, LUA_REGISTRYINDEX);
    }
    io->rc = rc;
    return 0;
}

int ns_scenario_load_set(const char *path, const char *const *sets, int nsets, NsScenario *sc,
                         char *err, int err_sz)
{
    double t0 = now_ms();
    memset(sc, 0, sizeof *sc);
    ns_mesh_init(&sc->mesh);
    sc->table_ref = LUA_NOREF;
    Builder b = {.sc = sc, .err = err, .err_sz = err_sz};

    sc->path = scn_dup_string(path);
    sc->lua = ns_lua_open(path, err, err_sz);
    if (!sc->path || !sc->lua) {
        if (sc->lua)
            scn_fail(&b, "needlesim: out of memory");
        ns_scenario_free(sc);
        return -1;
    }
    lua_State *L = ns_lua_state(sc->lua);
    b.L = L;
    int top = lua_gettop(L);
    LoadIO io = {.b = &b, .path = path, .sets = sets, .nsets = nsets, .rc = -1};
    lua_pushcfunction(L, load_body);
    lua_pushlightuserdata(L, &io);
    int rc = ns_lua_call(sc->lua, 1, 0, err, err_sz) != 0 ? -1 : io.rc;
    lua_settop(L, top);

    /* Function shapes are not needed after meshing (later stages will keep their own). */
    for (int i = 0; i < b.nfns; i++) {
        luaL_unref(L, LUA_REGISTRYINDEX, b.fns[i]->ref);
        free(b.fns[i]);
    }
    free(b.fns);

    if (rc != 0) {
        ns_scenario_free(sc);
        return -1;
    }
    sc->build_ms = now_ms() - t0;
    return 0;
}

void ns_scenario_free(NsScenario *sc)
{
    if (!sc)
        return;
    if (sc->lua && sc->table_ref != LUA_NOREF)
        luaL_unref(ns_lua_state(sc->lua), LUA_REGISTRYINDEX, sc->table_ref);
    ns_lua_close(sc->lua);
    ns_mesh_free(&sc->mesh);
    for (int i = 0; i < sc->region_count; i++) {
        free(sc->regions[i].name);
        scn_material_free(&sc->regions[i].material);
    }
    free(sc->regions);
    free(sc->path);
    free(sc->name);
    free(sc->description);
    free(sc->where);
    free(sc->tissue_where);
    free(sc->mesh_path);
    memset(sc, 0, sizeof *sc);
    ns_mesh_init(&sc->mesh);
    sc->table_ref = LUA_NOREF;
}

const char **ns_scenario_region_names(const NsScenario *sc)
{
    const char **names =
        malloc((size_t)(sc->region_count > 0 ? sc->region_count : 1) * sizeof *names);
    if (!names)
        return NULL;
    for (int i = 0; i < sc->region_count; i++)
        names[i] = sc->regions[i].name;
    return names;
}

typedef struct RegionShapeIO {
    Builder *b;
    int region;
    NsShape *shape;
} RegionShapeIO;

/* Under lua_pcall: the shape of tissue.regions[region + 1] from the scenario's table. */
static int region_shape_body(lua_State *L)
{
    RegionShapeIO *io = lua_touserdata(L, 1);
    Builder *b = io->b;
    const NsScenario *sc = b->sc;
    lua_rawgeti(L, LUA_REGISTRYINDEX, sc->table_ref);
    if (scn_rawfield(L, -1, "tissue") != LUA_TTABLE ||
        scn_rawfield(L, -1, "regions") != LUA_TTABLE ||
        scn_rawindex(L, -1, io->region + 1) != LUA_TTABLE) {
        scn_fail(b, "%s: region '%s' has no shape in the scenario's table", sc->path,
                 sc->regions[io->region].name);
        return 0;
    }
    char ctx[96];
    snprintf(ctx, sizeof ctx, "ns.tissue.shapes: regions[%d]", io->region + 1);
    io->shape = scn_shape_field(b, lua_gettop(L), "shape", sc->tissue_where ? sc->tissue_where : "",
                                ctx, 0);
    return 0;
}

NsShape *ns_scenario_region_shape(const NsScenario *sc, int region, char *err, int err_sz)
{
    if (!sc || !sc->lua || sc->table_ref == LUA_NOREF || region < 0 || region >= sc->region_count) {
        ns_set_err(err, err_sz, "needlesim: no region %d in the scenario", region);
        return NULL;
    }
    if (sc->tissue_kind != NS_TISSUE_SHAPES) {
        ns_set_err(err, err_sz,
                   "%s: region '%s' is not a shape (the tissue is not ns.tissue.shapes)", sc->path,
                   sc->regions[region].name);
        return NULL;
    }
    Builder b = {.sc = (NsScenario *)sc, .err = err, .err_sz = err_sz};
    lua_State *L = ns_lua_state(sc->lua);
    b.L = L;
    int top = lua_gettop(L);
    RegionShapeIO io = {.b = &b, .region = region, .shape = NULL};
    lua_pushcfunction(L, region_shape_body);
    lua_pushlightuserdata(L, &io);
    int rc = ns_lua_call(sc->lua, 1, 0, err, err_sz);
    lua_settop(L, top);
    if (b.nfns > 0 && io.shape) {
        ns_shape_release(io.shape);
        io.shape = NULL;
        ns_set_err(err, err_sz, "%s: region '%s' uses a Lua function shape", sc->path,
                   sc->regions[region].name);
    }
    for (int i = 0; i < b.nfns; i++) {
        luaL_unref(L, LUA_REGISTRYINDEX, b.fns[i]->ref);
        free(b.fns[i]);
    }
    free(b.fns);
    if (rc != 0 && io.shape) {
        ns_shape_release(io.shape);
        io.shape = NULL;
    }
    return io.shape;
}
