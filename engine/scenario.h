/* A scenario: the Lua file run in its sandbox, and the model built from what it returned
 * (for now the tissue: mesh, regions and their materials). The C side of the sim boundary:
 * Lua tables in, sim/ structures out.
 *
 *     NsScenario sc;
 *     char err[1024];
 *     if (ns_scenario_load("scenarios/phantom.lua", &sc, err, sizeof err) != 0)
 *         fprintf(stderr, "%s\n", err);   // "scenarios/phantom.lua:9: ns.tissue.box: ..."
 *     ...
 *     ns_scenario_free(&sc);
 *
 * Errors are one line naming the scenario file and line where the offending table was
 * written, the constructor and the field. */
#ifndef NS_SCENARIO_H
#define NS_SCENARIO_H

#include <stdbool.h>

#include "fem.h"
#include "lua_runtime.h"
#include "mesh.h"
#include "mesher.h"

/* A tissue material (scripts/needlesim.lua: ns.material). SI units. */
typedef struct NsMaterial {
    char *name;
    double youngs;        /* Young's modulus E [Pa] */
    double poisson;       /* Poisson's ratio nu [-], 0 <= nu < 0.5 */
    double density;       /* [kg/m^3] */
    double damping;       /* viscous damping coefficient [Pa s] */
    double friction;      /* needle-tissue friction per unit length f_perlen [N/m] (paper §3.3) */
    double cut_force;     /* force to cut through this tissue at the tip f_cut [N] (§3.3) */
    NsElasticModel model; /* sim/fem.h */
    bool has_membrane;    /* a capsule at the region's surface (§3.3 capsule puncture) */
    double membrane_thickness; /* [m] */
    double membrane_cut_force; /* [N] */
} NsMaterial;

typedef struct NsRegionInfo {
    char *name;
    NsMaterial material;
    bool fixed;       /* its nodes are held in place */
    int tag;          /* Gmsh physical tag in the source mesh (file tissue), else index + 1 */
    int tets;         /* tets of this region in the built mesh */
    double volume_m3; /* their rest volume [m^3] */
} NsRegionInfo;

typedef enum NsTissueKind {
    NS_TISSUE_BOX,
    NS_TISSUE_SHAPES,
    NS_TISSUE_FILE,
} NsTissueKind;

typedef struct NsScenario {
    char *path;        /* the scenario file as given */
    char *name;        /* ns.scenario{name = ...} */
    char *description; /* may be NULL */
    char *where;       /* "file:line" of the ns.scenario{} call */

    NsTissueKind tissue_kind;
    char *tissue_where; /* "file:line" of the ns.tissue.*{} call */
    double resolution;  /* lattice spacing [m] (box, shapes); 0 for a file */
    char *mesh_path;    /* the file read (file tissue), else NULL */

    NsMesh mesh;           /* compact, material coordinates = world coordinates */
    NsRegionInfo *regions; /* (region_count); mesh->tet_region indexes this */
    int region_count;
    int fixed_nodes;
    bool meshed; /* built by the mesher (mesher_stats valid) */
    NsMesherStats mesher_stats;
    double build_ms; /* wall time of the whole load: Lua + meshing [ms] */

    NsLua *lua;    /* the sandbox, kept for later stages (script, on_tick) */
    int table_ref; /* registry ref to the scenario table in lua */
} NsScenario;

/* Runs the scenario file and builds its tissue. On failure sc is left freed (safe to pass to
 * ns_scenario_free again) and err holds one line. Returns 0 or -1. */
int ns_scenario_load(const char *path, NsScenario *sc, char *err, int err_sz);
/* The same with `needlesim run --set KEY=VALUE` values (each string holds a '='): the scenario
 * reads them with ns.param(KEY, default); a KEY it never reads is an error. */
int ns_scenario_load_set(const char *path, const char *const *sets, int nsets, NsScenario *sc,
                         char *err, int err_sz);
void ns_scenario_free(NsScenario *sc);

/* Region names as an array for ns_mesh_write_msh (valid while sc lives). Caller frees the
 * array (not the strings). */
const char **ns_scenario_region_names(const NsScenario *sc);

const char *ns_material_model_name(NsElasticModel m);

/* The shape written for region `region` of an ns.tissue.shapes tissue, read again from the
 * scenario's table: a new reference (ns_shape_release it), or NULL with a message when the
 * tissue is not made of shapes or the region uses a Lua function shape. The region's meshed
 * volume is this shape less what later regions in the list take from it. */
struct NsShape;
struct NsShape *ns_scenario_region_shape(const NsScenario *sc, int region, char *err, int err_sz);

/* The memory the mesher may plan to use for the process's later loads [bytes]; 0 (the
 * default): NS_LIMIT_MESHER_BYTES. The fuzz harness lowers it, so that every input meshes in
 * well under its time limit. */
void ns_scenario_set_mesher_budget(double bytes);

/* The scenario's tissue as a simulation model: region r's material becomes material r
 * (damping as the shear damping coefficient), fixed regions' nodes are held. params may be
 * NULL (defaults). Returns 0, or -1 with a message. */
struct NsTissue;
struct NsTissueParams;
int ns_scenario_tissue(const NsScenario *sc, const struct NsTissueParams *params,
                       struct NsTissue *t, char *err, int err_sz);

#endif
