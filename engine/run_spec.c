/* Reading a scenario's run fields (run_spec.h). */
#include "run_spec.h"

#include <lauxlib.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "coupling.h"
#include "dose.h"
#include "err.h"
#include "mesh.h"
#include "names.h"
#include "ns_limits.h"
#include "remesh.h"
#include "scene.h"

/* t[key] without metamethods (pushed; its type returned): a scenario may put metatables on
 * the tables it returns, and none of them may run outside a protected call. Not a table:
 * nil. */
static int raw_field(lua_State *L, int idx, const char *key)
{
    idx = lua_absindex(L, idx);
    if (!lua_istable(L, idx)) {
        lua_pushnil(L);
        return LUA_TNIL;
    }
    lua_pushstring(L, key);
    return lua_rawget(L, idx);
}

/* t[key] as a number: dflt when absent, NaN when it is anything but a number (check_spec then
 * names the field: a table may have been changed after its constructor checked it). */
static double num_field(lua_State *L, int idx, const char *key, double dflt)
{
    double v = dflt;
    int t = raw_field(L, idx, key);
    if (t == LUA_TNUMBER)
        v = lua_tonumber(L, -1);
    else if (t != LUA_TNIL)
        v = NAN;
    lua_pop(L, 1);
    return v;
}

/* t[key] as {x, y, z}: NaN in every component that is not a number, and in all three when
 * the field is absent or not a table (every vector read here is required). */
static void vec_field(lua_State *L, int idx, const char *key, double out[3])
{
    out[0] = out[1] = out[2] = NAN;
    if (raw_field(L, idx, key) == LUA_TTABLE)
        for (int i = 0; i < 3; i++) { /* (a table: rawgeti is safe) */
            int t = lua_rawgeti(L, -1, i + 1);
            out[i] = t == LUA_TNUMBER ? lua_tonumber(L, -1) : NAN;
            lua_pop(L, 1);
        }
    lua_pop(L, 1);
}

static char *str_field(lua_State *L, int idx, const char *key, const char *dflt)
{
    const char *s = dflt;
    if (raw_field(L, idx, key) == LUA_TSTRING)
        s = lua_tostring(L, -1);
    size_t n = strlen(s);
    char *out = malloc(n + 1);
    if (out)
        memcpy(out, s, n + 1);
    lua_pop(L, 1);
    return out;
}

static bool bool_field(lua_State *L, int idx, const char *key, bool dflt)
{
    bool v = dflt;
    if (raw_field(L, idx, key) == LUA_TBOOLEAN)
        v = lua_toboolean(L, -1);
    lua_pop(L, 1);
    return v;
}

/* camera = {...} (the Lua side checked it and filled in its defaults). */
static void read_camera(lua_State *L, int si, NsRunCamera *cam)
{
    cam->views[0] = 0;
    cam->view_count = 1;
    cam->fps = 25.0;
    cam->frame_every = 1;
    cam->tet_edges = cam->friction_colours = true;
    if (raw_field(L, si, "camera") == LUA_TTABLE) {
        int ci = lua_gettop(L);
        if (raw_field(L, ci, "views") == LUA_TTABLE) {
            int n = (int)lua_rawlen(L, -1);
            cam->view_count = 0;
            for (int i = 0; i < n && i < 3; i++) {
                lua_rawgeti(L, -1, i + 1);
                const char *v = lua_tostring(L, -1);
                int view = v ? ns_view_parse(v) : -1; /* (checked in needlesim.lua) */
                cam->views[cam->view_count++] = view >= 0 ? view : NS_VIEW_SIDE;
                lua_pop(L, 1);
            }
            if (cam->view_count == 0)
                cam->view_count = 1;
        }
        lua_pop(L, 1);
        cam->fps = num_field(L, ci, "fps", 25.0);
        double every = num_field(L, ci, "frame_every", 1.0);
        /* checked by check_spec; kept in range here so that the int holds it */
        cam->frame_every = every >= 1.0 && every <= 1e6 && every == floor(every) ? (int)every : 0;
        raw_field(L, ci, "cut_normal");
        cam->has_cut_normal = lua_istable(L, -1);
        lua_pop(L, 1);
        if (cam->has_cut_normal)
            vec_field(L, ci, "cut_normal", cam->cut_normal);
        cam->tet_edges = bool_field(L, ci, "tet_edges", true);
        cam->friction_colours = bool_field(L, ci, "friction_colours", true);
    }
    lua_pop(L, 1);
}

/* Markers, obstacles (their region names resolved) and the seed plan (target names resolved;
 * the Lua side checked that they name targets). */
static int read_lists(const NsScenario *sc, NsRunSpec *spec, lua_State *L, int si, char *err,
                      int err_sz)
{
    int rc = 0;
    if (raw_field(L, si, "markers") == LUA_TTABLE) {
        int li = lua_gettop(L), n = (int)lua_rawlen(L, li);
        spec->markers = calloc((size_t)n + 1, sizeof *spec->markers);
        if (!spec->markers)
            rc = -1;
        for (int i = 0; rc == 0 && i < n; i++) {
            lua_rawgeti(L, li, i + 1);
            NsRunMarker *m = &spec->markers[i];
            m->name = str_field(L, lua_gettop(L), "name", "?");
            vec_field(L, lua_gettop(L), "at", m->at);
            spec->marker_count = i + 1;
            lua_pop(L, 1);
            if (!m->name)
                rc = -1;
            else if (!(isfinite(m->at[0]) && isfinite(m->at[1]) && isfinite(m->at[2]))) {
                ns_set_err(err, err_sz,
                           "%s: ns.scenario: markers[%d].at must be {x, y, z}: three finite "
                           "numbers",
                           sc->where, i + 1);
                return -1;
            } else if (ns_mesh_locate(&sc->mesh, m->at, -1, 1e-9, NULL) < 0) {
                ns_set_err(err, err_sz,
                           "%s: ns.scenario: markers[%d] '%s' at (%g, %g, %g) m is outside the "
                           "tissue",
                           sc->where, i + 1, m->name, m->at[0], m->at[1], m->at[2]);
                return -1;
            }
        }
    }
    lua_pop(L, 1);
    if (rc == 0 && raw_field(L, si, "obstacles") == LUA_TTABLE) {
        int li = lua_gettop(L), n = (int)lua_rawlen(L, li);
        spec->obstacles = calloc((size_t)n + 1, sizeof *spec->obstacles);
        if (!spec->obstacles)
            rc = -1;
        for (int i = 0; rc == 0 && i < n; i++) {
            lua_rawgeti(L, li, i + 1);
            NsRunObstacle *o = &spec->obstacles[i];
            o->name = str_field(L, lua_gettop(L), "name", "?");
            char *region = str_field(L, lua_gettop(L), "region", "?");
            spec->obstacle_count = i + 1;
            lua_pop(L, 1);
            o->region = -1;
            for (int k = 0; region && k < sc->region_count; k++)
                if (strcmp(sc->regions[k].name, region) == 0)
                    o->region = k;
            if (!o->name || !region)
                rc = -1;
            else if (o->region < 0) {
                char known[512] = "";
                for (int k = 0; k < sc->region_count; k++)
                    snprintf(known + strlen(known), sizeof known - strlen(known), "%s'%s'",
                             k ? ", " : "", sc->regions[k].name);
                ns_set_err(err, err_sz,
                           "%s: ns.scenario: obstacles[%d] '%s': region '%s' is not a region of "
                           "the tissue (its regions: %s)",
                           sc->where, i + 1, o->name, region, known);
                free(region);
                return -1;
            }
            free(region);
        }
    }
    lua_pop(L, 1);
    if (rc == 0 && raw_field(L, si, "seeds") == LUA_TTABLE) {
        int li = lua_gettop(L), n = (int)lua_rawlen(L, li);
        spec->seed_target = calloc((size_t)n + 1, sizeof *spec->seed_target);
        if (!spec->seed_target)
            rc = -1;
        for (int i = 0; rc == 0 && i < n; i++) {
            lua_rawgeti(L, li, i + 1);
            char *target = str_field(L, lua_gettop(L), "target", "?");
            lua_pop(L, 1);
            spec->seed_target[i] = -1;
            for (int k = 0; target && k < spec->target_count; k++)
                if (strcmp(spec->targets[k].name, target) == 0)
                    spec->seed_target[i] = k;
            free(target);
            spec->seed_count = i + 1;
            if (spec->seed_target[i] < 0) {
                ns_set_err(err, err_sz, "%s: ns.scenario: seeds[%d]: unknown target", sc->where,
                           i + 1);
                return -1;
            }
        }
    }
    lua_pop(L, 1);
    if (rc && !err[0])
        ns_set_err(err, err_sz, "out of memory");
    return rc;
}

void ns_run_spec_free(NsRunSpec *spec)
{
    free(spec->needle_kind);
    for (int i = 0; i < spec->target_count; i++)
        free(spec->targets[i].name);
    free(spec->targets);
    for (int i = 0; i < spec->marker_count; i++)
        free(spec->markers[i].name);
    free(spec->markers);
    for (int i = 0; i < spec->obstacle_count; i++)
        free(spec->obstacles[i].name);
    free(spec->obstacles);
    free(spec->seed_target);
    free(spec->live_entries);
    free(spec->dosimetry.plan);
    memset(spec, 0, sizeof *spec);
}

static bool finite3(const double v[3])
{
    return isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]);
}

static bool nonzero3(const double v[3])
{
    return finite3(v) && (v[0] != 0.0 || v[1] != 0.0 || v[2] != 0.0);
}

static bool in_range(double x, double lo, double hi)
{
    return isfinite(x) && x >= lo && x <= hi;
}

#if defined(__GNUC__)
__attribute__((format(printf, 4, 5)))
#endif
static int
bad(char *err, int err_sz, const char *where, const char *fmt, ...)
{
    int n = snprintf(err, (size_t)err_sz, "%s: ns.scenario: ", where);
    if (n >= 0 && n < err_sz) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(err + n, (size_t)(err_sz - n), fmt, ap);
        va_end(ap);
    }
    return -1;
}

/* Every value the run uses, checked here in C where it is read, whatever scripts/needlesim.lua
 * checked when the table was made: a scenario can change its tables afterwards (sc.dt = 0,
 * camera.frame_every = 0, entry.point = {"a"}), and a bad value must be named, not divided
 * by. Ranges: sim/ns_limits.h and the constructors' own. */
/* live = {script, entries} (the Lua side checked the shapes; the values are checked here). */
static int read_live(const NsScenario *sc, NsRunSpec *spec, lua_State *L, int si, char *err,
                     int err_sz)
{
    if (raw_field(L, si, "live") != LUA_TTABLE)
        return 0;
    int li = lua_gettop(L);
    spec->live_script = bool_field(L, li, "script", false);
    if (raw_field(L, li, "accuracy") != LUA_TNIL) {
        spec->live_accuracy = lua_isnumber(L, -1) ? lua_tonumber(L, -1) : NAN;
        if (!in_range(spec->live_accuracy, 1e-9, 1.0)) {
            ns_set_err(err, err_sz,
                       "%s: ns.scenario: live.accuracy must be a number in [1e-9, 1] m", sc->where);
            return -1;
        }
    }
    lua_pop(L, 1);
    raw_field(L, li, "front");
    const char *front = lua_type(L, -1) == LUA_TSTRING ? lua_tostring(L, -1) : "phantom";
    if (strlen(front) >= sizeof spec->live_front) {
        ns_set_err(err, err_sz, "%s: ns.scenario: live.front: no such measured front", sc->where);
        return -1;
    }
    snprintf(spec->live_front, sizeof spec->live_front, "%s", front);
    lua_pop(L, 1);
    if (raw_field(L, li, "entries") != LUA_TTABLE)
        return 0;
    int ei = lua_gettop(L);
    int n = (int)lua_rawlen(L, ei);
    if (n < 0 || n > 64) {
        ns_set_err(err, err_sz, "%s: ns.scenario: live.entries: at most 64", sc->where);
        return -1;
    }
    spec->live_entries = calloc((size_t)n + 1, sizeof *spec->live_entries);
    if (!spec->live_entries) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    for (int i = 0; i < n; i++) {
        NsEntry *e = &spec->live_entries[i];
        lua_rawgeti(L, ei, i + 1);
        int ti = lua_gettop(L);
        bool table = lua_istable(L, ti);
        if (table) {
            vec_field(L, ti, "point", e->point);
            vec_field(L, ti, "direction", e->direction);
            raw_field(L, ti, "bevel_toward");
            e->has_bevel_toward = lua_istable(L, -1);
            lua_pop(L, 1);
            if (e->has_bevel_toward)
                vec_field(L, ti, "bevel_toward", e->bevel_toward);
        }
        lua_pop(L, 1);
        if (!table || !finite3(e->point) || !nonzero3(e->direction) ||
            (e->has_bevel_toward && !nonzero3(e->bevel_toward))) {
            ns_set_err(err, err_sz,
                       "%s: ns.scenario: live.entries[%d] must be {point = {x, y, z}, direction "
                       "= {x, y, z}}: finite numbers, the direction not zero",
                       sc->where, i + 1);
            return -1;
        }
        spec->live_entry_count = i + 1;
    }
    return 0;
}

static int check_spec(const NsScenario *sc, const NsRunSpec *s, char *err, int err_sz)
{
    const char *w = sc->where;
    if (!in_range(s->dt, NS_LIMIT_DT_MIN, NS_LIMIT_DT_MAX))
        return bad(err, err_sz, w, "dt must be a number in [%g, %g] s (got %g)", NS_LIMIT_DT_MIN,
                   NS_LIMIT_DT_MAX, s->dt);
    if (!in_range(s->duration, 0.0, NS_LIMIT_SIM_TIME_MAX))
        return bad(err, err_sz, w, "duration must be a number in [0, %g] s (got %g)",
                   NS_LIMIT_SIM_TIME_MAX, s->duration);
    if (!in_range(s->diameter, 1e-5, 0.02) || !in_range(s->inner_diameter, 0.0, s->diameter) ||
        s->inner_diameter >= s->diameter)
        return bad(err, err_sz, w,
                   "needle.diameter must be in [1e-05, 0.02] m and inner_diameter in [0, "
                   "diameter) (got %g and %g)",
                   s->diameter, s->inner_diameter);
    if (!in_range(s->youngs, 1e6, 1e13) || !in_range(s->density, 10.0, 1e5))
        return bad(err, err_sz, w,
                   "needle.youngs must be in [1e6, 1e13] Pa and density in [10, 1e5] kg/m^3 "
                   "(got %g and %g)",
                   s->youngs, s->density);
    if (s->steering < 0)
        return bad(err, err_sz, w,
                   "needle.steering must be \"force\", \"displacement\" or \"arc\"");
    if (!in_range(s->bevel_deg, 1.0, 89.0) || !in_range(s->arc_curvature, 0.0, 1000.0))
        return bad(err, err_sz, w,
                   "needle.bevel_deg must be in [1, 89] and curvature in [0, 1000] 1/m (got %g "
                   "and %g)",
                   s->bevel_deg, s->arc_curvature);
    if (!in_range(s->bevel_force, 0.0, NS_LIMIT_BEVEL_FORCE))
        return bad(err, err_sz, w, "needle.bevel_force must be in [0, %g] N (got %g)",
                   NS_LIMIT_BEVEL_FORCE, s->bevel_force);
    if (!finite3(s->entry_point))
        return bad(err, err_sz, w, "entry.point must be {x, y, z}: three finite numbers [m]");
    if (!nonzero3(s->entry_dir))
        return bad(err, err_sz, w,
                   "entry.direction must be {x, y, z}: three finite numbers, not all zero");
    if (s->has_bevel_toward && !nonzero3(s->bevel_toward))
        return bad(err, err_sz, w,
                   "entry.bevel_toward must be {x, y, z}: three finite numbers, not all zero");
    for (int i = 0; i < s->target_count; i++) {
        const NsRunTarget *t = &s->targets[i];
        if (!finite3(t->at))
            return bad(err, err_sz, w, "targets[%d].at must be {x, y, z}: three finite numbers",
                       i + 1);
        if (!in_range(t->tolerance, 1e-6, 1.0))
            return bad(err, err_sz, w,
                       "targets[%d].tolerance must be a number in [1e-06, 1] m (got %g)", i + 1,
                       t->tolerance);
    }
    for (int i = 0; i < s->marker_count; i++)
        if (!finite3(s->markers[i].at))
            return bad(err, err_sz, w, "markers[%d].at must be {x, y, z}: three finite numbers",
                       i + 1);
    const NsRunCamera *c = &s->camera;
    if (!in_range(c->fps, 0.1, 1000.0))
        return bad(err, err_sz, w, "camera.fps must be a number in [0.1, 1000] (got %g)", c->fps);
    if (c->frame_every < 1)
        return bad(err, err_sz, w, "camera.frame_every must be a whole number in [1, 1e6]");
    if (c->has_cut_normal && !nonzero3(c->cut_normal))
        return bad(err, err_sz, w,
                   "camera.cut_normal must be {x, y, z}: three finite numbers, not all zero");
    const double solver[3] = {s->tolerance, s->check_tolerance, s->lazy_threshold};
    static const char *const names[3] = {"tolerance", "check_tolerance", "lazy_threshold"};
    for (int k = 0; k < 3; k++)
        if (solver[k] != -1.0 && !in_range(solver[k], k == 2 ? 0.0 : 1e-15, 1.0))
            return bad(err, err_sz, w, "solver.%s must be a number in (0, 1] (got %g)", names[k],
                       solver[k]);
    if (!in_range(s->accuracy, 0.0, 1.0) || !in_range(s->accuracy_tip_error, 0.0, 1e3) ||
        !in_range(s->accuracy_cost, 0.0, 1e12))
        return bad(err, err_sz, w, "accuracy must hold finite, non-negative numbers");
    return 0;
}

/* The name as a message may show it: at most 40 bytes, unprintable bytes as '?'. */
static const char *shown(const char *s, char out[48])
{
    size_t n = 0;
    for (; s[n] && n < 40; n++)
        out[n] = (unsigned char)s[n] < 0x20 || (unsigned char)s[n] > 0x7e ? '?' : s[n];
    if (s[n])
        memcpy(out + n, "...", 4);
    else
        out[n] = '\0';
    return out;
}

static int check_one(const NsScenario *sc, const char *list, int i, const char *name, char *err,
                     int err_sz)
{
    char why[64], show[48];
    if (ns_name_check(name, why, sizeof why) == 0)
        return 0;
    ns_set_err(err, err_sz, "%s: ns.scenario: %s[%d]: name must be " NS_NAME_RULE " (got '%s': %s)",
               sc->where, list, i + 1, shown(name, show), why);
    return -1;
}

/* Every name of the scenario's regions and of the run's targets, markers and obstacles
 * (names.h's rule): 0, or -1 with "file:line: ns.scenario: markers[2] name must be ... (got
 * '...': byte 3 is 0x0a)" in err (the place of the ns.scenario{} call). */
static int names_check_run(const NsScenario *sc, const NsRunSpec *spec, char *err, int err_sz)
{
    for (int i = 0; i < sc->region_count; i++)
        if (check_one(sc, "regions", i, sc->regions[i].name, err, err_sz))
            return -1;
    for (int i = 0; i < spec->target_count; i++)
        if (check_one(sc, "targets", i, spec->targets[i].name, err, err_sz))
            return -1;
    for (int i = 0; i < spec->marker_count; i++)
        if (check_one(sc, "markers", i, spec->markers[i].name, err, err_sz))
            return -1;
    for (int i = 0; i < spec->obstacle_count; i++)
        if (check_one(sc, "obstacles", i, spec->obstacles[i].name, err, err_sz))
            return -1;
    return 0;
}

/* dosimetry = {...}: the Lua side (dosimetry_of) checked each field; this checks them again,
 * resolves the region names and reads the plan (else the seed plan's targets), each planned
 * seed inside the tissue. */
static int read_dosimetry(const NsScenario *sc, NsRunSpec *spec, lua_State *L, int si, char *err,
                          int err_sz)
{
    NsRunDosimetry *d = &spec->dosimetry;
    if (raw_field(L, si, "dosimetry") != LUA_TTABLE)
        return 0;
    int di = lua_gettop(L);
    d->on = true;
    d->prescription = num_field(L, di, "prescription", NAN);
    d->strength = num_field(L, di, "strength", NAN) * NS_TG43_UNIT_U;
    d->spacing = num_field(L, di, "spacing", NAN);
    if (!(d->prescription > 0.0 && d->prescription <= NS_LIMIT_DOSE_PRESCRIPTION) ||
        !(d->strength > 0.0 && d->strength <= NS_LIMIT_DOSE_STRENGTH * NS_TG43_UNIT_U) ||
        !(d->spacing >= NS_LIMIT_DOSE_SPACING_MIN && d->spacing <= NS_LIMIT_DOSE_SPACING_MAX)) {
        ns_set_err(err, err_sz,
                   "%s: ns.scenario: dosimetry: prescription, strength or spacing out of range",
                   sc->where);
        return -1;
    }
    static const char *const keys[3] = {"prostate", "urethra", "rectum"};
    for (int k = 0; k < 3; k++) {
        char *name = str_field(L, di, keys[k], "?");
        d->region[k] = -1;
        for (int i = 0; name && i < sc->region_count; i++)
            if (strcmp(sc->regions[i].name, name) == 0)
                d->region[k] = i;
        if (d->region[k] < 0) {
            ns_set_err(err, err_sz,
                       "%s: ns.scenario: dosimetry.%s: '%s' is not a region of the tissue",
                       sc->where, keys[k], name ? name : "?");
            free(name);
            return -1;
        }
        free(name);
    }
    int n = 0;
    if (raw_field(L, di, "plan") == LUA_TTABLE)
        n = (int)lua_rawlen(L, -1);
    if (n > NS_LIMIT_DOSE_PLAN_SEEDS) {
        ns_set_err(err, err_sz, "%s: ns.scenario: dosimetry.plan: more than %d seeds", sc->where,
                   NS_LIMIT_DOSE_PLAN_SEEDS);
        return -1;
    }
    int from_targets = n == 0;
    if (from_targets)
        n = spec->seed_count;
    if (n < 1) {
        ns_set_err(err, err_sz, "%s: ns.scenario: dosimetry: no planned seed (give plan or seeds)",
                   sc->where);
        return -1;
    }
    d->plan = malloc((size_t)n * 3 * sizeof *d->plan);
    if (!d->plan) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    d->plan_n = n;
    for (int i = 0; i < n; i++) {
        double *p = d->plan + 3 * i;
        if (from_targets) {
            memcpy(p, spec->targets[spec->seed_target[i]].at, 3 * sizeof *p);
        } else {
            lua_rawgeti(L, -1, i + 1);
            p[0] = p[1] = p[2] = NAN;
            for (int c = 0; lua_istable(L, -1) && c < 3; c++) {
                if (lua_rawgeti(L, -1, c + 1) == LUA_TNUMBER)
                    p[c] = lua_tonumber(L, -1);
                lua_pop(L, 1);
            }
            lua_pop(L, 1);
        }
        if (!finite3(p) || ns_mesh_locate(&sc->mesh, p, -1, 1e-9, NULL) < 0) {
            ns_set_err(err, err_sz,
                       "%s: ns.scenario: dosimetry.plan[%d] at (%g, %g, %g) m is not a point "
                       "inside the tissue",
                       sc->where, i + 1, p[0], p[1], p[2]);
            return -1;
        }
    }
    return 0;
}

int ns_run_spec_read(const NsScenario *sc, NsRunSpec *spec, char *err, int err_sz)
{
    memset(spec, 0, sizeof *spec);
    lua_State *L = ns_lua_state(sc->lua);
    int top = lua_gettop(L);
    lua_rawgeti(L, LUA_REGISTRYINDEX, sc->table_ref);
    int si = lua_gettop(L);
    int rc = 0;
    /* The needle: the stiff 18 G default when none is given (scripts/needlesim.lua). */
    if (raw_field(L, si, "needle") == LUA_TTABLE) {
        int ni = lua_gettop(L);
        spec->needle_kind = str_field(L, ni, "kind", "stiff");
        spec->diameter = num_field(L, ni, "diameter", 0.0);
        spec->inner_diameter = num_field(L, ni, "inner_diameter", 0.0);
        spec->youngs = num_field(L, ni, "youngs", 0.0);
        spec->density = num_field(L, ni, "density", 0.0);
        char *tip = str_field(L, ni, "tip", "symmetric");
        spec->bevel = tip && strcmp(tip, "bevel") == 0;
        free(tip);
        spec->bevel_deg = num_field(L, ni, "bevel_deg", 30.0);
        char *steer = str_field(L, ni, "steering", "force");
        /* ns.needle has checked the name; a raw table that names none of the three fails
         * here rather than steering silently with the default */
        spec->steering = !steer                               ? -1
                         : strcmp(steer, "force") == 0        ? NS_BEVEL_FORCE
                         : strcmp(steer, "displacement") == 0 ? NS_BEVEL_DISPLACEMENT
                         : strcmp(steer, "arc") == 0          ? NS_BEVEL_ARC
                                                              : -1;
        free(steer);
        spec->arc_curvature = num_field(L, ni, "curvature", 10.0);
        spec->bevel_force =
            num_field(L, ni, "bevel_force", ns_default_coupling_params().bevel_force[0]);
        spec->twist_friction = bool_field(L, ni, "twist_friction", true);
    } else {
        spec->needle_kind = malloc(6);
        if (spec->needle_kind)
            memcpy(spec->needle_kind, "stiff", 6);
        spec->diameter = 1.27e-3;
        spec->inner_diameter = 0.84e-3;
        spec->youngs = 200e9;
        spec->density = 8000.0;
        spec->bevel = false;
        spec->bevel_deg = 30.0;
        spec->steering = NS_BEVEL_FORCE;
        spec->arc_curvature = 10.0;
        spec->bevel_force = ns_default_coupling_params().bevel_force[0];
        spec->twist_friction = true;
    }
    lua_pop(L, 1);
    if (raw_field(L, si, "entry") == LUA_TTABLE) {
        vec_field(L, lua_gettop(L), "point", spec->entry_point);
        vec_field(L, lua_gettop(L), "direction", spec->entry_dir);
        raw_field(L, lua_gettop(L), "bevel_toward");
        spec->has_bevel_toward = lua_istable(L, -1);
        lua_pop(L, 1);
        if (spec->has_bevel_toward)
            vec_field(L, lua_gettop(L), "bevel_toward", spec->bevel_toward);
    } else {
        ns_set_err(err, err_sz,
                   "%s: ns.scenario: missing field 'entry' ({point = {x, y, z}, direction = "
                   "{x, y, z}}): `needlesim run` needs to know where the needle goes in",
                   sc->where);
        rc = -1;
    }
    lua_pop(L, 1);
    spec->dt = num_field(L, si, "dt", 0.01);
    spec->duration = num_field(L, si, "duration", 0.0);
    raw_field(L, si, "script");
    spec->has_script = lua_isfunction(L, -1);
    lua_pop(L, 1);
    raw_field(L, si, "on_tick");
    spec->has_on_tick = lua_isfunction(L, -1);
    lua_pop(L, 1);
    if (rc == 0 && raw_field(L, si, "targets") == LUA_TTABLE) {
        int ti = lua_gettop(L);
        int n = (int)lua_rawlen(L, ti);
        spec->targets = calloc(n > 0 ? (size_t)n : 1, sizeof *spec->targets);
        if (!spec->targets) {
            ns_set_err(err, err_sz, "out of memory");
            rc = -1;
        }
        for (int i = 0; rc == 0 && i < n; i++) {
            lua_rawgeti(L, ti, i + 1);
            NsRunTarget *t = &spec->targets[i];
            t->name = str_field(L, lua_gettop(L), "name", "?");
            vec_field(L, lua_gettop(L), "at", t->at);
            t->tolerance = num_field(L, lua_gettop(L), "tolerance", 0.0);
            spec->target_count = i + 1;
            lua_pop(L, 1);
            if (!(isfinite(t->at[0]) && isfinite(t->at[1]) && isfinite(t->at[2]))) {
                ns_set_err(err, err_sz,
                           "%s: ns.scenario: targets[%d].at must be {x, y, z}: three finite "
                           "numbers",
                           sc->where, i + 1);
                rc = -1;
            } else if (ns_mesh_locate(&sc->mesh, t->at, -1, 1e-9, NULL) < 0) {
                ns_set_err(err, err_sz,
                           "%s: ns.scenario: targets[%d] '%s' at (%g, %g, %g) m is outside the "
                           "tissue",
                           sc->where, i + 1, t->name, t->at[0], t->at[1], t->at[2]);
                rc = -1;
            }
        }
    }
    lua_settop(L, si);
    if (rc == 0)
        read_camera(L, si, &spec->camera);
    spec->tolerance = spec->check_tolerance = spec->lazy_threshold = -1.0;
    if (rc == 0 && raw_field(L, si, "solver") == LUA_TTABLE) {
        int vi = lua_gettop(L);
        spec->tolerance = num_field(L, vi, "tolerance", -1.0);
        spec->check_tolerance = num_field(L, vi, "check_tolerance", -1.0);
        spec->lazy_threshold = num_field(L, vi, "lazy_threshold", -1.0);
        spec->tip_block = bool_field(L, vi, "tip_block", false);
    }
    lua_settop(L, si);
    if (rc == 0 && raw_field(L, si, "accuracy") == LUA_TTABLE) {
        int ai = lua_gettop(L);
        spec->accuracy = num_field(L, ai, "tip", 0.0);
        spec->accuracy_tip_error = num_field(L, ai, "tip_error", 0.0);
        spec->accuracy_cost = num_field(L, ai, "cost", 0.0);
        char *f = str_field(L, ai, "front", ""), *l = str_field(L, ai, "label", "");
        snprintf(spec->accuracy_front, sizeof spec->accuracy_front, "%s", f ? f : "");
        snprintf(spec->accuracy_label, sizeof spec->accuracy_label, "%s", l ? l : "");
        free(f);
        free(l);
    }
    lua_settop(L, si);
    if (rc == 0)
        rc = read_live(sc, spec, L, si, err, err_sz);
    lua_settop(L, si);
    if (rc == 0)
        rc = read_lists(sc, spec, L, si, err, err_sz);
    lua_settop(L, si);
    if (rc == 0)
        rc = read_dosimetry(sc, spec, L, si, err, err_sz);
    rc = rc ? rc : names_check_run(sc, spec, err, err_sz); /* names.h: CSV- and JSON-safe */
    lua_settop(L, top);
    if (rc == 0)
        rc = check_spec(sc, spec, err, err_sz);
    if (rc)
        ns_run_spec_free(spec);
    return rc;
}
