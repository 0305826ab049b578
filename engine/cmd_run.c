/* needlesim run SCENARIO.lua [-o DIR] [--steps N] [--threads N] [--solver NAME] [--no-render]
 *                            [--quiet]
 *
 * The run loop (DESIGN.md "Command line"): the scenario's tissue and needle are built, the
 * needle's entry track is laid into the mesh at the scenario's entry, and every tick the
 * scenario's script (scripts/needlesim/actions.lua, on a coroutine) and its on_tick set the
 * needle's controls, the coupled solver steps (paper Algorithm 1 with remeshing at the tip,
 * Algorithm 2), and the trajectory is logged. At the end the targets (material points, so they
 * move with the tissue) are scored against the needle tip, and DIR/report.json and
 * DIR/trajectory.csv are written (docs/scenarios.md documents both). A failed run writes
 * neither: both are written to temporary names and renamed only when the run succeeded.
 *
 * Not in this version yet (exit 2 with a message): --frames, --video, --set, --record,
 * --replay; seeds, obstacles and markers. */
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
#include "coupling.h"
#include "err.h"
#include "json.h"
#include "needle_path.h"
#include "ns_config.h"
#include "quality.h"
#include "remesh.h"
#include "rod.h"
#include "run_spec.h"
#include "scenario.h"
#include "tissue.h"

static const char run_usage[] =
    "usage: needlesim run SCENARIO.lua [-o DIR] [--steps N] [--threads N] [--solver NAME]\n"
    "                     [--no-render] [--quiet]\n";

typedef struct RunOpts {
    const char *scenario, *out_dir;
    long steps; /* 0: the scenario decides */
    int threads;
    int solver; /* NsCoupledSolverKind */
    bool quiet;
} RunOpts;

static int usage_error(const char *fmt, const char *arg)
{
    fputs("needlesim run: ", stderr);
    fprintf(stderr, fmt, arg);
    fputc('\n', stderr);
    fputs(run_usage, stderr);
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
    int sim_ref, act_ref; /* registry refs: the `sim` table, the actions module */
    /* statistics */
    Series step_ms, total_ms, lcp_ms, tissue_ms, needle_ms, remesh_ms, trials, iterations;
    long steps;
    int consistent, nan, inverted, unconverged, lcp_unresolved;
    double max_axial, last_axial, path_cut, wall_s, last_tip[3];
    int *target_hint;
    /* output */
    char *dir, *traj_tmp, *report_tmp;
    FILE *traj;
} Run;

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

/* Tissue, entry track, needle and coupling (the set-up of the validation's remeshing cases,
 * engine/validate_remesh.c, at the scenario's entry). */
static int build(Run *r, char *err, int err_sz)
{
    NsScenario *sc = &r->sc;
    NsRunSpec *sp = &r->spec;
    NsMesh orig;
    if (ns_mesh_copy(&orig, &sc->mesh)) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    /* The entry track: about one and a half elements along the entry direction, so that the
     * needle starts with two tissue nodes (skin entry itself is not modelled yet, issue 6). */
    double h = sc->resolution > 0.0 ? sc->resolution : ns_mesh_mean_edge(&orig);
    double a[3], b[3];
    for (int i = 0; i < 3; i++) {
        a[i] = sp->entry_point[i];
        b[i] = a[i] + 1.5 * h * sp->entry_dir[i];
    }
    int nodes[64];
    char e2[512];
    int np = ns_needle_path_lay(&sc->mesh, a, b, 0.75, nodes, 64, e2, sizeof e2);
    if (np < 2) {
        ns_set_err(err, err_sz,
                   "%s: ns.scenario: entry: no needle track can start at (%g, %g, %g) m along "
                   "(%g, %g, %g): %s",
                   sc->where, a[0], a[1], a[2], sp->entry_dir[0], sp->entry_dir[1],
                   sp->entry_dir[2], np < 0 ? e2 : "it crosses fewer than 2 mesh nodes");
        ns_mesh_free(&orig);
        return -1;
    }
    NsTissueParams tp = ns_default_tissue_params();
    tp.gamma = 0.55; /* slightly dissipative Newmark, as the validation's coupled cases */
    tp.beta = 0.25 * 1.05 * 1.05;
    tp.threads = r->opt.threads;
    if (sc->region_count > NS_COUPLING_MAX_REGIONS) {
        ns_set_err(err, err_sz, "%s: the tissue has %d regions; the coupling takes at most %d",
                   sc->tissue_where, sc->region_count, NS_COUPLING_MAX_REGIONS);
        ns_mesh_free(&orig);
        return -1;
    }
    if (ns_scenario_tissue(sc, &tp, &r->tissue, err, err_sz)) {
        ns_mesh_free(&orig);
        return -1;
    }
    r->have_tissue = true;
    const NsMesh *M = &r->tissue.mesh;
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
    rp.gamma = tp.gamma;
    rp.beta = tp.beta;
    rp.material.youngs = sp->youngs;
    rp.material.outer_diameter = sp->diameter;
    rp.material.inner_diameter = sp->inner_diameter;
    rp.material.density = sp->density;
    if (sp->bevel) {
        rp.tip = NS_TIP_BEVEL;
        rp.bevel_angle = sp->bevel_deg * M_PI / 180.0;
    }
    /* The material frame's d1: the axis least aligned with the needle, made normal to it. */
    int ax = fabs(d[0]) <= fabs(d[1]) && fabs(d[0]) <= fabs(d[2]) ? 0
             : fabs(d[1]) <= fabs(d[2])                           ? 1
                                                                  : 2;
    double d1[3] = {0.0, 0.0, 0.0};
    d1[ax] = 1.0;
    double dd = dot3(d1, d);
    for (int k = 0; k < 3; k++)
        d1[k] -= dd * d[k];
    double n1 = sqrt(dot3(d1, d1));
    for (int k = 0; k < 3; k++)
        d1[k] /= n1;
    if (ns_rod_init(&r->rod, x, 4 + np, d1, 2, &rp, err, err_sz)) {
        ns_mesh_free(&orig);
        return -1;
    }
    r->have_rod = true;
    NsCouplingParams cp = ns_default_coupling_params();
    cp.remesh = 1;
    cp.solver = (NsCoupledSolverKind)r->opt.solver;
    cp.threads = r->opt.threads;
    for (int k = 0; k < sc->region_count; k++)
        cp.cut_force[k] = sc->regions[k].material.cut_force;
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
        ns_mesh_free(&orig);
        return -1;
    }
    r->have_c = true;
    /* The nodes the track moved go back when the needle leaves (sim/remesh.h). */
    for (int i = 0; i < orig.node_slots; i++)
        if (ns_mesh_node_alive(&orig, i) && memcmp(orig.u + 3 * i, M->u + 3 * i, 24) != 0 &&
            ns_remesh_record_original(&r->c.remesh, i, orig.u + 3 * i)) {
            ns_set_err(err, err_sz, "out of memory");
            ns_mesh_free(&orig);
            return -1;
        }
    ns_mesh_free(&orig);
    r->target_hint = malloc((size_t)(sp->target_count + 1) * sizeof *r->target_hint);
    if (!r->target_hint) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    for (int i = 0; i < sp->target_count; i++)
        r->target_hint[i] = -1;
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

static int script_start(Run *r, char *err, int err_sz)
{
    NsLua *rt = r->sc.lua;
    lua_State *L = ns_lua_state(rt);
    lua_newtable(L); /* sim */
    lua_pushstring(L, "control");
    lua_newtable(L);
    set_num(L, lua_gettop(L), "v_insert", 0.0);
    set_num(L, lua_gettop(L), "twist_rate", 0.0);
    lua_rawset(L, -3);
    r->sim_ref = luaL_ref(L, LUA_REGISTRYINDEX);
    lua_getglobal(L, "require");
    lua_pushstring(L, "needlesim.actions");
    if (ns_lua_call(rt, 1, 1, err, err_sz))
        return -1;
    r->act_ref = luaL_ref(L, LUA_REGISTRYINDEX);
    lua_rawgeti(L, LUA_REGISTRYINDEX, r->act_ref);
    lua_getfield(L, -1, "_bind");
    lua_remove(L, -2);
    lua_rawgeti(L, LUA_REGISTRYINDEX, r->sim_ref);
    lua_rawgeti(L, LUA_REGISTRYINDEX, r->sc.table_ref);
    lua_getfield(L, -1, "script");
    lua_remove(L, -2);
    return ns_lua_call(rt, 2, 0, err, err_sz);
}

/* Updates `sim` with the state, runs the script's next slice and on_tick, and reads the
 * controls. *more: the script has more to do. */
static int script_tick(Run *r, double t, int exited, int *more, char *err, int err_sz)
{
    NsLua *rt = r->sc.lua;
    lua_State *L = ns_lua_state(rt);
    int top = lua_gettop(L);
    lua_rawgeti(L, LUA_REGISTRYINDEX, r->sim_ref);
    int si = lua_gettop(L);
    set_num(L, si, "t", t);
    set_num(L, si, "dt", r->spec.dt);
    set_num(L, si, "step", (double)r->steps);
    set_num(L, si, "depth", depth_of(r));
    set_vec(L, si, "tip", tip_of(r));
    set_num(L, si, "axial_force", r->last_axial);
    lua_pushstring(L, "exited");
    lua_pushboolean(L, exited);
    lua_rawset(L, si);
    lua_pushstring(L, "targets"); /* a fresh table every step */
    lua_newtable(L);
    for (int i = 0; i < r->spec.target_count; i++) {
        double x[3];
        if (world_of(&r->tissue.mesh, r->spec.targets[i].at, &r->target_hint[i], x) == 0)
            set_vec(L, lua_gettop(L), r->spec.targets[i].name, x);
    }
    lua_rawset(L, si);
    *more = 0;
    lua_rawgeti(L, LUA_REGISTRYINDEX, r->act_ref);
    lua_getfield(L, -1, "_tick");
    lua_remove(L, -2);
    if (ns_lua_call(rt, 0, 1, err, err_sz)) {
        lua_settop(L, top);
        return -1;
    }
    *more = lua_toboolean(L, -1);
    lua_pop(L, 1);
    if (r->spec.has_on_tick) {
        lua_rawgeti(L, LUA_REGISTRYINDEX, r->sc.table_ref);
        lua_getfield(L, -1, "on_tick");
        lua_remove(L, -2);
        lua_pushvalue(L, si);
        if (ns_lua_call(rt, 1, 0, err, err_sz)) {
            lua_settop(L, top);
            return -1;
        }
    }
    int rc = 0;
    if (get_raw(L, si, "control") != LUA_TTABLE) {
        ns_set_err(err, err_sz, "%s: sim.control must stay a table", r->sc.path);
        rc = -1;
    } else {
        static const char *const keys[2] = {"v_insert", "twist_rate"};
        double *dst[2] = {&r->rod.v_insert, &r->rod.twist_rate};
        for (int k = 0; k < 2 && rc == 0; k++) {
            int ty = get_raw(L, lua_gettop(L), keys[k]);
            double v = lua_tonumber(L, -1);
            if (ty != LUA_TNUMBER || !isfinite(v)) {
                ns_set_err(err, err_sz, "%s: sim.control.%s must be a finite number (got %s)",
                           r->sc.path, keys[k], luaL_typename(L, -1));
                rc = -1;
            }
            *dst[k] = v;
            lua_pop(L, 1);
        }
    }
    lua_settop(L, top);
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

static int open_outputs(Run *r, char *err, int err_sz)
{
    if (mkdir(r->opt.out_dir, 0777) != 0 && errno != EEXIST) {
        ns_set_err(err, err_sz, "cannot create output folder '%s': %s", r->opt.out_dir,
                   strerror(errno));
        return -1;
    }
    r->traj_tmp = path_join(r->opt.out_dir, ".trajectory.csv.part");
    r->report_tmp = path_join(r->opt.out_dir, ".report.json.part");
    if (!r->traj_tmp || !r->report_tmp) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    r->traj = fopen(r->traj_tmp, "w");
    if (!r->traj) {
        ns_set_err(err, err_sz, "cannot write to output folder '%s': %s", r->opt.out_dir,
                   strerror(errno));
        return -1;
    }
    fprintf(r->traj, "t_s,tip_x_m,tip_y_m,tip_z_m,depth_m,axial_force_n,v_insert_m_s,"
                     "twist_rate_rad_s,n_static,n_dyn_pos,n_dyn_neg,cutting\n");
    return 0;
}

static void remove_outputs(Run *r)
{
    if (r->traj)
        fclose(r->traj);
    r->traj = NULL;
    if (r->traj_tmp)
        remove(r->traj_tmp);
    if (r->report_tmp)
        remove(r->report_tmp);
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
    double x[3], error_mm;
    bool hit, located;
} TargetResult;

/* The provisional score (docs/scenarios.md): per target 100 within its tolerance, falling
 * linearly to 0 at five tolerances; the total is their mean (100 without targets). */
static double target_score(const TargetResult *t, double tol_mm)
{
    if (!t->located)
        return 0.0;
    if (t->error_mm <= tol_mm)
        return 100.0;
    return fmax(0.0, 100.0 * (1.0 - (t->error_mm - tol_mm) / (4.0 * tol_mm)));
}

static int write_report(Run *r, const TargetResult *tr, double score, uint64_t hash, char *err,
                        int err_sz)
{
    FILE *f = fopen(r->report_tmp, "w");
    if (!f) {
        ns_set_err(err, err_sz, "cannot write '%s': %s", r->report_tmp, strerror(errno));
        return -1;
    }
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
    ns_json_key(&j, "steps");
    ns_json_int(&j, r->steps);
    ns_json_key(&j, "dt_s");
    ns_json_number(&j, r->spec.dt);
    ns_json_key(&j, "sim_time_s");
    ns_json_number(&j, (double)r->steps * r->spec.dt);
    ns_json_key(&j, "wall_time_s");
    ns_json_number(&j, r->wall_s);
    ns_json_key(&j, "step_ms");
    ns_json_begin_object(&j);
    ns_json_key(&j, "median");
    ns_json_number(&j, series_quantile(&r->step_ms, 0.5));
    ns_json_key(&j, "p95");
    ns_json_number(&j, series_quantile(&r->step_ms, 0.95));
    ns_json_key(&j, "max");
    ns_json_number(&j, series_quantile(&r->step_ms, 1.0));
    ns_json_end_object(&j);
    ns_json_key(&j, "stages_ms");
    ns_json_begin_object(&j);
    const Series *st[5] = {&r->total_ms, &r->lcp_ms, &r->tissue_ms, &r->needle_ms, &r->remesh_ms};
    static const char *const stn[5] = {"total", "lcp", "tissue", "needle", "remesh"};
    for (int k = 0; k < 5; k++) {
        ns_json_key(&j, stn[k]);
        ns_json_number(&j, series_quantile(st[k], 0.5));
    }
    ns_json_end_object(&j);
    stats_object(&j, "lcp_trials", &r->trials);
    stats_object(&j, "cg_iterations", &r->iterations);
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
        ns_json_begin_object(&j);
        ns_json_key(&j, "name");
        ns_json_string(&j, t->name);
        ns_json_key(&j, "error_mm");
        ns_json_number(&j, tr[i].error_mm);
        ns_json_key(&j, "tolerance_mm");
        ns_json_number(&j, 1e3 * t->tolerance);
        ns_json_key(&j, "hit");
        ns_json_bool(&j, tr[i].hit);
        ns_json_key(&j, "position_m");
        ns_json_begin_array(&j);
        for (int k = 0; k < 3; k++)
            ns_json_number(&j, tr[i].x[k]);
        ns_json_end_array(&j);
        ns_json_end_object(&j);
    }
    ns_json_end_array(&j);
    ns_json_key(&j, "seeds");
    ns_json_begin_array(&j);
    ns_json_end_array(&j);
    ns_json_key(&j, "obstacles");
    ns_json_begin_array(&j);
    ns_json_end_array(&j);
    ns_json_key(&j, "score");
    ns_json_begin_object(&j);
    ns_json_key(&j, "total");
    ns_json_number(&j, score);
    ns_json_key(&j, "formula");
    ns_json_string(&j, "provisional-targets-only/1");
    ns_json_end_object(&j);
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
    long max_steps = r->opt.steps > 0     ? r->opt.steps
                     : sp->duration > 0.0 ? (long)ceil(sp->duration / sp->dt - 1e-9)
                                          : 0; /* until the script ends */
    const long hard_cap = 10000000;
    bool tty = !r->opt.quiet && isatty(fileno(stderr));
    int exited = 0, more = 1;
    double t0 = now_s();
    while (max_steps > 0 ? r->steps < max_steps : more) {
        if (r->steps >= hard_cap) {
            ns_set_err(err, err_sz, "%s: the script did not end within %ld steps", r->sc.path,
                       hard_cap);
            return -1;
        }
        double t = (double)r->steps * sp->dt;
        if (script_tick(r, t, exited, &more, err, err_sz))
            return -1;
        if (max_steps == 0 && !more)
            break;
        NsCouplingStats st;
        double w0 = now_s();
        int rc = ns_coupled_step(&r->c, sp->dt, NULL, NULL, &st);
        double w = 1e3 * (now_s() - w0);
        r->nan += st.nan_count;
        if (rc) {
            ns_set_err(err, err_sz,
                       "step %ld (t = %.4f s) failed: the coupled solve did not produce a valid "
                       "state (NaN %d, inverted %d, unconverged %d)",
                       r->steps, t, st.nan_count, st.inverted, st.unconverged);
            return -1;
        }
        r->steps++;
        exited |= st.exited;
        r->inverted += st.inverted;
        r->unconverged += st.unconverged;
        r->consistent += st.consistent != 0;
        r->lcp_unresolved += st.consistent == 0;
        r->max_axial = fmax(r->max_axial, fabs(st.axial_force));
        r->last_axial = st.axial_force;
        const double *tp = tip_of(r);
        if (st.cutting && r->steps > 1) { /* the length of tissue cut: the tip's path */
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
        const double *tip = tip_of(r);
        fprintf(r->traj, "%.6f,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%d,%d,%d,%d\n",
                (double)r->steps * sp->dt, tip[0], tip[1], tip[2], depth_of(r), st.axial_force,
                r->rod.v_insert, r->rod.twist_rate, st.n_static, st.n_dyn_pos, st.n_dyn_neg,
                st.cutting);
        if (tty && (r->steps % 10 == 0))
            progress(r, max_steps, (double)r->steps * sp->dt);
    }
    if (tty)
        fputs("\r\033[K", stderr);
    r->wall_s = now_s() - t0;
    return 0;
}

static void run_free(Run *r)
{
    lua_State *L = r->have_sc ? ns_lua_state(r->sc.lua) : NULL;
    if (L && r->sim_ref != LUA_NOREF)
        luaL_unref(L, LUA_REGISTRYINDEX, r->sim_ref);
    if (L && r->act_ref != LUA_NOREF)
        luaL_unref(L, LUA_REGISTRYINDEX, r->act_ref);
    if (r->have_c)
        ns_coupled_free(&r->c);
    if (r->have_rod)
        ns_rod_free(&r->rod);
    if (r->have_tissue)
        ns_tissue_free(&r->tissue);
    if (r->have_spec)
        ns_run_spec_free(&r->spec);
    if (r->have_sc)
        ns_scenario_free(&r->sc);
    Series *s[8] = {&r->step_ms,   &r->total_ms,  &r->lcp_ms, &r->tissue_ms,
                    &r->needle_ms, &r->remesh_ms, &r->trials, &r->iterations};
    for (int k = 0; k < 8; k++)
        free(s[k]->v);
    free(r->target_hint);
    free(r->traj_tmp);
    free(r->report_tmp);
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
                   strcmp(a, "--threads") == 0 || strcmp(a, "--solver") == 0) {
            if (!v)
                return usage_error("%s needs a value", a);
            i++;
            char *end;
            if (strcmp(a, "-o") == 0) {
                o->out_dir = v;
            } else if (strcmp(a, "--solver") == 0) {
                o->solver = ns_coupled_solver_parse(v);
                if (o->solver < 0)
                    return usage_error("--solver '%s': unknown solver (schur or paper)", v);
            } else {
                long n = strtol(v, &end, 10);
                if (*end || n < 1 || n > (strcmp(a, "--threads") == 0 ? 64 : 100000000))
                    return usage_error("%s: expected a positive integer", a);
                if (strcmp(a, "--steps") == 0)
                    o->steps = n;
                else
                    o->threads = (int)n;
            }
        } else if (strcmp(a, "--no-render") == 0) {
            /* rendering is not built yet: nothing to turn off */
        } else if (strcmp(a, "--quiet") == 0) {
            o->quiet = true;
        } else if (strcmp(a, "--frames") == 0 || strcmp(a, "--video") == 0 ||
                   strcmp(a, "--set") == 0 || strcmp(a, "--record") == 0 ||
                   strcmp(a, "--replay") == 0 || strcmp(a, "--width") == 0 ||
                   strcmp(a, "--height") == 0) {
            fprintf(stderr, "needlesim run: %s is not available in this version yet\n", a);
            return 2;
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
    return 0;
}

int ns_cmd_run(int argc, char **argv)
{
    Run r;
    memset(&r, 0, sizeof r);
    r.sim_ref = r.act_ref = LUA_NOREF;
    int pa = parse_args(argc, argv, &r.opt);
    if (pa)
        return pa == 1 ? 0 : pa;
    char err[1024] = "";
    int rc = -1;
    if (ns_scenario_load(r.opt.scenario, &r.sc, err, sizeof err) == 0) {
        r.have_sc = true;
        if (ns_run_spec_read(&r.sc, &r.spec, err, sizeof err) == 0) {
            r.have_spec = true;
            rc = 0;
        }
    }
    /* The actions module is bound also without a script (its _tick then answers "done"). */
    rc = rc ? rc : script_start(&r, err, sizeof err);
    rc = rc ? rc : open_outputs(&r, err, sizeof err);
    rc = rc ? rc : build(&r, err, sizeof err);
    rc = rc ? rc : run_loop(&r, err, sizeof err);
    TargetResult *tr = NULL;
    double score = 100.0;
    if (rc == 0) {
        tr = calloc((size_t)r.spec.target_count + 1, sizeof *tr);
        if (!tr) {
            ns_set_err(err, sizeof err, "out of memory");
            rc = -1;
        }
    }
    if (rc == 0 && r.spec.target_count > 0) {
        score = 0.0;
        const double *tip = tip_of(&r);
        for (int i = 0; i < r.spec.target_count; i++) {
            tr[i].located =
                world_of(&r.tissue.mesh, r.spec.targets[i].at, &r.target_hint[i], tr[i].x) == 0;
            double d[3] = {tip[0] - tr[i].x[0], tip[1] - tr[i].x[1], tip[2] - tr[i].x[2]};
            tr[i].error_mm = tr[i].located ? 1e3 * sqrt(dot3(d, d)) : NAN;
            tr[i].hit = tr[i].located && tr[i].error_mm <= 1e3 * r.spec.targets[i].tolerance;
            score += target_score(&tr[i], 1e3 * r.spec.targets[i].tolerance) / r.spec.target_count;
        }
    }
    uint64_t hash = rc == 0 ? ns_coupled_state_hash(&r.c) : 0;
    if (rc == 0) {
        if (fclose(r.traj) != 0) {
            r.traj = NULL;
            ns_set_err(err, sizeof err, "cannot write the trajectory: %s", strerror(errno));
            rc = -1;
        }
        r.traj = NULL;
    }
    rc = rc ? rc : write_report(&r, tr, score, hash, err, sizeof err);
    if (rc == 0) {
        char *traj = path_join(r.opt.out_dir, "trajectory.csv");
        char *rep = path_join(r.opt.out_dir, "report.json");
        if (!traj || !rep || rename(r.traj_tmp, traj) || rename(r.report_tmp, rep)) {
            ns_set_err(err, sizeof err, "cannot write to output folder '%s': %s", r.opt.out_dir,
                       strerror(errno));
            if (traj)
                remove(traj);
            rc = -1;
        }
        free(traj);
        free(rep);
    }
    if (rc) {
        remove_outputs(&r);
        /* Messages that name their scenario file and line (or say needlesim) print as they
         * are, as in `needlesim check`; the others get the program's name. */
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
            printf("%-20s %10s %10s %5s\n", "target", "error mm", "tol mm", "hit");
        for (int i = 0; i < r.spec.target_count; i++)
            printf("%-20s %10.2f %10.2f %5s\n", r.spec.targets[i].name, tr[i].error_mm,
                   1e3 * r.spec.targets[i].tolerance, tr[i].hit ? "yes" : "no");
        printf("score %.1f / 100; warnings: NaN %d, inverted %d, unconverged %d, friction "
               "unresolved %d\n",
               score, r.nan, r.inverted, r.unconverged, r.lcp_unresolved);
        printf("wrote %s/report.json and %s/trajectory.csv (state hash %016llx)\n", r.opt.out_dir,
               r.opt.out_dir, (unsigned long long)hash);
    }
    free(tr);
    run_free(&r);
    return rc ? 1 : 0;
}
