/* Building a scenario's tissue (scenario.h): a meshed box, meshed shapes, or a mesh file, with
 * its regions, materials and fixed nodes. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include <lauxlib.h>

#include "cleanup.h"
#include "mesh_io.h"
#include "mesher.h"
#include "ns_limits.h"
#include "quality.h"
#include "scenario_internal.h"

/* ---- tissue -------------------------------------------------------------------------------- */

static int alloc_regions(Builder *b, int n, const char *where)
{
    b->sc->regions = calloc((size_t)n, sizeof *b->sc->regions);
    if (!b->sc->regions)
        return scn_fail(b, "%s: out of memory", where);
    b->sc->region_count = n;
    return 0;
}

/* Runs the mesher and turns its failure into one line naming the tissue: a function shape's
 * own error first (it is why the mesher stopped), then the mesher's message. */
/* The mesher's memory budget (0: NS_LIMIT_MESHER_BYTES); see scenario.h. */
static double mesher_budget;

void ns_scenario_set_mesher_budget(double bytes)
{
    mesher_budget = bytes;
}

static int run_mesher(Builder *b, const NsMesherDef *def_in, const char *where, const char *ctor)
{
    NsMesherDef d = *def_in;
    d.max_bytes = mesher_budget;
    d.cancel = ns_cleanup_stop_flag(); /* a stop signal ends the meshing, not just the run */
    const NsMesherDef *def = &d;
    char merr[512];
    NsScenario *sc = b->sc;
    if (ns_mesher_stuff(def, &sc->mesh, &sc->mesher_stats, merr, (int)sizeof merr) != 0) {
        if (b->fn_failed)
            return scn_fail(b, "%s", b->fn_err);
        return scn_fail(b, "%s: %s: resolution %g m: %s", where, ctor, def->spacing, merr);
    }
    if (b->fn_failed) /* a failure the mesher did not notice must not pass either */
        return scn_fail(b, "%s", b->fn_err);
    sc->meshed = true;
    return 0;
}

static const char *const face_names[6] = {"xmin", "xmax", "ymin", "ymax", "zmin", "zmax"};

static int build_box(Builder *b, int ti, const char *where)
{
    lua_State *L = b->L;
    NsScenario *sc = b->sc;
    const char *ctor = "ns.tissue.box";
    double size[3] = {0}, origin[3] = {0}, h = 0;
    if (scn_get_vector(b, ti, "size", 3, where, ctor, size) ||
        scn_get_vector(b, ti, "origin", 3, where, ctor, origin) ||
        scn_get_number(b, ti, "resolution", where, ctor, &h))
        return -1;
    if (!(size[0] > 0 && size[1] > 0 && size[2] > 0))
        return scn_fail(b, "%s: %s: size must be > 0", where, ctor);
    if (!(h > 0))
        return scn_fail(b, "%s: %s: resolution must be > 0", where, ctor);
    sc->resolution = h;
    if (alloc_regions(b, 1, where))
        return -1;
    NsRegionInfo *reg = &sc->regions[0];
    reg->name = scn_dup_string("tissue");
    reg->tag = 1;
    scn_rawfield(L, ti, "material");
    int rc = scn_material_from_lua(b, -1, where, ctor, &reg->material);
    lua_pop(L, 1);
    if (rc)
        return -1;
    if (!reg->name)
        return scn_fail(b, "%s: out of memory", where);

    /* Which faces are held. */
    bool fixed_face[6] = {false};
    if (scn_rawfield(L, ti, "fixed_faces") == LUA_TTABLE) {
        lua_Integer n = (lua_Integer)lua_rawlen(L, -1);
        for (lua_Integer i = 1; i <= n; i++) {
            scn_rawindex(L, -1, i);
            const char *f = lua_tostring(L, -1);
            int k = 0;
            while (k < 6 && !(f && strcmp(f, face_names[k]) == 0))
                k++;
            lua_pop(L, 1);
            if (k == 6) {
                lua_pop(L, 1);
                return scn_fail(b,
                                "%s: %s: fixed_faces[%d] must be one of xmin, xmax, ymin, ymax, "
                                "zmin, zmax",
                                where, ctor, (int)i);
            }
            fixed_face[k] = true;
        }
    }
    lua_pop(L, 1);

    double center[3], hi[3];
    for (int a = 0; a < 3; a++) {
        center[a] = origin[a] + 0.5 * size[a];
        hi[a] = origin[a] + size[a];
    }
    NsShape *shape = ns_shape_box(center, size);
    if (!shape)
        return scn_fail(b, "%s: out of memory", where);
    NsMesherRegion region = {.shape = shape, .fixed = false};
    NsMesherDef def = ns_default_mesher_def();
    def.spacing = h;
    def.regions = &region;
    def.region_count = 1;
    /* Anchor the lattice at the min corner: the min faces lie on lattice planes and stay
     * flat without warping. */
    memcpy(def.lo, origin, sizeof def.lo);
    memcpy(def.hi, hi, sizeof def.hi);
    rc = run_mesher(b, &def, where, ctor);
    ns_shape_release(shape);
    if (rc)
        return -1;

    /* Hold the nodes on the fixed faces. The min faces are exact lattice planes; the max
     * faces are found by bisection to ~h 2^-40, far inside this tolerance. */
    double tol = 1e-6 * h;
    NsMesh *m = &sc->mesh;
    for (int v = 0; v < m->node_slots; v++) {
        if (!ns_mesh_node_alive(m, v))
            continue;
        for (int k = 0; k < 6; k++) {
            int axis = k / 2;
            double plane = (k % 2) ? hi[axis] : origin[axis];
            if (fixed_face[k] && fabs(m->u[3 * v + axis] - plane) <= tol)
                m->flags[v] |= NS_NODE_FIXED;
        }
    }
    return 0;
}

static int build_shapes(Builder *b, int ti, const char *where)
{
    lua_State *L = b->L;
    NsScenario *sc = b->sc;
    const char *ctor = "ns.tissue.shapes";
    double h = 0;
    if (scn_get_number(b, ti, "resolution", where, ctor, &h))
        return -1;
    if (!(h > 0))
        return scn_fail(b, "%s: %s: resolution must be > 0", where, ctor);
    sc->resolution = h;

    if (scn_rawfield(L, ti, "bounds") == LUA_TTABLE) {
        int bi = lua_gettop(L);
        scn_rawindex(L, bi, 1);
        scn_rawindex(L, bi, 2);
        b->have_bounds = lua_istable(L, -2) && lua_istable(L, -1);
        for (int a = 0; b->have_bounds && a < 3; a++) {
            scn_rawindex(L, -2, a + 1);
            scn_rawindex(L, -2, a + 1);
            b->blo[a] = lua_tonumber(L, -2);
            b->bhi[a] = lua_tonumber(L, -1);
            lua_pop(L, 2);
            if (!(isfinite(b->blo[a]) && isfinite(b->bhi[a]) && b->blo[a] < b->bhi[a]))
                b->have_bounds = false;
        }
        lua_pop(L, 2);
        if (!b->have_bounds) {
            lua_pop(L, 1);
            return scn_fail(b,
                            "%s: %s: bounds must be {{x0, y0, z0}, {x1, y1, z1}} with x0 < x1, "
                            "y0 < y1, z0 < z1",
                            where, ctor);
        }
    }
    lua_pop(L, 1);

    if (scn_rawfield(L, ti, "regions") != LUA_TTABLE) {
        lua_pop(L, 1);
        return scn_fail(b, "%s: %s: regions must be a list of regions", where, ctor);
    }
    int ri = lua_gettop(L);
    lua_Integer n = (lua_Integer)lua_rawlen(L, ri);
    if (n < 1 || n > 65535) {
        lua_pop(L, 1);
        return scn_fail(b, "%s: %s: regions must be a list of 1 to 65535 regions", where, ctor);
    }
    NsMesherRegion *mr = calloc((size_t)n, sizeof *mr);
    if (!mr) {
        lua_pop(L, 1);
        return scn_fail(b, "%s: out of memory", where);
    }
    if (alloc_regions(b, (int)n, where)) {
        free(mr);
        lua_pop(L, 1);
        return -1;
    }
    int rc = 0;
    for (lua_Integer i = 0; i < n && rc == 0; i++) {
        char rctx[96];
        snprintf(rctx, sizeof rctx, "%s: regions[%d]", ctor, (int)(i + 1));
        scn_rawindex(L, ri, i + 1);
        int gi = lua_gettop(L);
        NsRegionInfo *reg = &sc->regions[i];
        reg->tag = (int)i + 1;
        if (!lua_istable(L, gi)) {
            rc = scn_fail(b, "%s: %s must be a table {name, shape, material, fixed}", where, rctx);
        } else {
            rc = scn_get_string(b, gi, "name", where, rctx, true, &reg->name);
            if (rc == 0) {
                scn_rawfield(L, gi, "material");
                rc = scn_material_from_lua(b, -1, where, rctx, &reg->material);
                lua_pop(L, 1);
            }
            if (rc == 0) {
                reg->fixed = scn_get_bool(L, gi, "fixed");
                mr[i].fixed = reg->fixed;
                mr[i].shape = scn_shape_field(b, gi, "shape", where, rctx, 0);
                if (!mr[i].shape)
                    rc = -1;
            }
            if (rc == 0) {
                double lo[3], hi[3];
                bool ok = ns_shape_bounds(mr[i].shape, lo, hi);
                for (int a = 0; ok && a < 3; a++)
                    ok = isfinite(lo[a]) && isfinite(hi[a]);
                if (!ok && !b->have_bounds)
                    rc = scn_fail(b,
                                  "%s: %s: the extent of region '%s' is unknown (it uses a Lua "
                                  "function shape): give bounds = {{x0, y0, z0}, {x1, y1, z1}}",
                                  where, ctor, reg->name);
            }
        }
        lua_pop(L, 1);
    }
    lua_pop(L, 1);

    if (rc == 0) {
        NsMesherDef def = ns_default_mesher_def();
        def.spacing = h;
        def.regions = mr;
        def.region_count = (int)n;
        if (b->have_bounds) {
            memcpy(def.lo, b->blo, sizeof def.lo);
            memcpy(def.hi, b->bhi, sizeof def.hi);
        }
        rc = run_mesher(b, &def, where, ctor);
    }
    for (lua_Integer i = 0; i < n; i++)
        ns_shape_release((NsShape *)mr[i].shape);
    free(mr);
    return rc;
}

static int build_file(Builder *b, int ti, const char *where)
{
    lua_State *L = b->L;
    NsScenario *sc = b->sc;
    const char *ctor = "ns.tissue.file";
    char *rel = NULL;
    if (scn_get_string(b, ti, "path", where, ctor, true, &rel))
        return -1;
    /* Relative paths are relative to the scenario's folder, not the working directory. */
    const char *dir = ns_lua_scenario_dir(sc->lua);
    size_t need = strlen(dir) + strlen(rel) + 2;
    sc->mesh_path = malloc(need);
    if (!sc->mesh_path) {
        free(rel);
        return scn_fail(b, "%s: out of memory", where);
    }
    if (rel[0] == '/' || strcmp(dir, ".") == 0)
        snprintf(sc->mesh_path, need, "%s", rel);
    else
        snprintf(sc->mesh_path, need, "%s/%s", dir, rel);
    free(rel);

    struct stat st;
    if (stat(sc->mesh_path, &st) != 0)
        return scn_fail(b, "%s: %s: cannot open '%s': %s", where, ctor, sc->mesh_path,
                        strerror(errno));
    if (S_ISDIR(st.st_mode))
        return scn_fail(b, "%s: %s: cannot open '%s': Is a directory", where, ctor, sc->mesh_path);
    /* A FIFO would block for ever and /dev/zero never end: regular files of a bounded size
     * only (sim/ns_limits.h; the reader checks again on the descriptor it opens). */
    if (!S_ISREG(st.st_mode))
        return scn_fail(b, "%s: %s: cannot read '%s': not a regular file", where, ctor,
                        sc->mesh_path);
    if ((long long)st.st_size > NS_LIMIT_MESH_FILE_BYTES)
        return scn_fail(b, "%s: %s: '%s' has %lld bytes, more than a mesh file may have (%lld)",
                        where, ctor, sc->mesh_path, (long long)st.st_size,
                        (long long)NS_LIMIT_MESH_FILE_BYTES);
    char merr[512];
    if (ns_mesh_read_msh(sc->mesh_path, &sc->mesh, merr, (int)sizeof merr) != 0)
        return scn_fail(b, "%s: %s: %s", where, ctor, merr);
    NsMesh *m = &sc->mesh;
    if (ns_mesh_compact(m) != 0)
        return scn_fail(b, "%s: out of memory", where);

    /* Physical tags present (mesh region r is tag r + 1), distinct and ascending. Sorted, not
     * indexed by tag: a tag may be as large as INT_MAX. */
    int *present = malloc((size_t)(m->tet_slots > 0 ? m->tet_slots : 1) * sizeof *present);
    if (!present)
        return scn_fail(b, "%s: out of memory", where);
    int count = 0;
    for (int t = 0; t < m->tet_slots; t++)
        if (ns_mesh_tet_alive(m, t))
            present[count++] = m->tet_region[t];
    if (count == 0) {
        free(present);
        return scn_fail(b, "%s: %s: '%s' has no tetrahedra", where, ctor, sc->mesh_path);
    }
    qsort(present, (size_t)count, sizeof *present, scn_cmp_int);
    int distinct = 0;
    for (int i = 0; i < count; i++)
        if (i == 0 || present[i] != present[distinct - 1])
            present[distinct++] = present[i];
    count = distinct;
    if (alloc_regions(b, count, where)) {
        free(present);
        return -1;
    }

    scn_rawfield(L, ti, "regions");
    scn_rawfield(L, ti, "names");
    scn_rawfield(L, ti, "fixed");
    int regions_i = lua_gettop(L) - 2, names_i = regions_i + 1, fixed_i = regions_i + 2;
    int rc = 0;
    if (!lua_istable(L, regions_i))
        rc = scn_fail(b, "%s: %s: regions must be a table {[tag] = material, ...}", where, ctor);
    for (int i = 0; i < count && rc == 0; i++) {
        int tag = present[i] + 1;
        NsRegionInfo *reg = &sc->regions[i];
        reg->tag = tag;
        char rctx[64];
        snprintf(rctx, sizeof rctx, "%s: regions[%d]", ctor, tag);
        if (scn_rawindex(L, regions_i, tag) == LUA_TNIL) {
            rc = scn_fail(b,
                          "%s: %s: '%s' has tets with physical tag %d but regions has no entry "
                          "for it (add [%d] = <material>)",
                          where, ctor, sc->mesh_path, tag, tag);
        } else {
            rc = scn_material_from_lua(b, -1, where, rctx, &reg->material);
        }
        lua_pop(L, 1);
        if (rc)
            break;
        if (lua_istable(L, names_i) && scn_rawindex(L, names_i, tag) == LUA_TSTRING)
            reg->name = scn_dup_string(lua_tostring(L, -1));
        else
            reg->name = scn_dup_string(reg->material.name);
        if (lua_istable(L, names_i))
            lua_pop(L, 1);
        if (!reg->name)
            rc = scn_fail(b, "%s: out of memory", where);
        if (lua_istable(L, fixed_i)) {
            scn_rawindex(L, fixed_i, tag);
            reg->fixed = lua_toboolean(L, -1);
            lua_pop(L, 1);
        }
    }
    lua_pop(L, 3);
    if (rc == 0) {
        for (int t = 0; t < m->tet_slots; t++) {
            if (!ns_mesh_tet_alive(m, t))
                continue;
            const int *hit =
                bsearch(&m->tet_region[t], present, (size_t)count, sizeof *present, scn_cmp_int);
            int r = (int)(hit - present);
            m->tet_region[t] = r;
            if (sc->regions[r].fixed)
                for (int k = 0; k < 4; k++)
                    m->flags[m->tet_node[4 * t + k]] |= NS_NODE_FIXED;
        }
    }
    free(present);
    return rc;
}

/* Per-region counts and volumes, fixed-node count. */
static void region_stats(NsScenario *sc)
{
    const NsMesh *m = &sc->mesh;
    for (int t = 0; t < m->tet_slots; t++) {
        if (!ns_mesh_tet_alive(m, t))
            continue;
        const int *v = &m->tet_node[4 * t];
        NsRegionInfo *reg = &sc->regions[m->tet_region[t]];
        reg->tets++;
        reg->volume_m3 +=
            ns_tet_volume(&m->u[3 * v[0]], &m->u[3 * v[1]], &m->u[3 * v[2]], &m->u[3 * v[3]]);
    }
    sc->fixed_nodes = 0;
    for (int v = 0; v < m->node_slots; v++)
        if (ns_mesh_node_alive(m, v) && (m->flags[v] & NS_NODE_FIXED))
            sc->fixed_nodes++;
}

int scn_build_tissue(Builder *b, int si)
{
    lua_State *L = b->L;
    NsScenario *sc = b->sc;
    scn_rawfield(L, si, "tissue");
    int ti = lua_gettop(L);
    if (!scn_is_kind(L, ti, "tissue")) {
        lua_pop(L, 1);
        return scn_fail(b,
                        "%s: ns.scenario: tissue must be ns.tissue.box{...}, ns.tissue.shapes{...} "
                        "or ns.tissue.file{...}",
                        sc->where);
    }
    char where[WHERE_MAX], type[16] = "";
    scn_get_where(L, ti, sc->where, where, sizeof where);
    sc->tissue_where = scn_dup_string(where);
    if (scn_rawfield(L, ti, "type") == LUA_TSTRING)
        snprintf(type, sizeof type, "%s", lua_tostring(L, -1));
    lua_pop(L, 1);
    int rc;
    if (strcmp(type, "box") == 0) {
        sc->tissue_kind = NS_TISSUE_BOX;
        rc = build_box(b, ti, where);
    } else if (strcmp(type, "shapes") == 0) {
        sc->tissue_kind = NS_TISSUE_SHAPES;
        rc = build_shapes(b, ti, where);
    } else if (strcmp(type, "file") == 0) {
        sc->tissue_kind = NS_TISSUE_FILE;
        rc = build_file(b, ti, where);
    } else {
        rc = scn_fail(b, "%s: unknown tissue type '%s'", where, type);
    }
    lua_pop(L, 1);
    if (rc == 0)
        region_stats(sc);
    /* Nothing held: the needle's push would carry the whole tissue away for as long as a
     * script chased it (issue 32: a liver moved 4.9 m in 11 minutes). */
    if (rc == 0 && sc->fixed_nodes == 0)
        rc =
            scn_fail(b,
                     "%s: ns.tissue.%s: nothing holds the tissue in place (no fixed nodes), so the "
                     "needle would push it away: hold it with fixed_faces = {\"zmax\", ...} on "
                     "ns.tissue.box, fixed = true on a region of ns.tissue.shapes (bone), or fixed "
                     "= {tag, ...} on ns.tissue.file",
                     where, type);
    return rc;
}
