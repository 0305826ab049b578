/* needlesim check SCENARIO.lua [--json] [--mesh-out FILE.vtu|FILE.msh] [--set KEY=VALUE]...
 *
 * Runs the scenario, builds its tissue and prints mesh and model statistics: a table for
 * people, or with --json exactly one JSON object on stdout. --mesh-out writes the mesh
 * (atomically: sim/mesh_io.h). Errors are one line on stderr and exit 1, before anything is
 * written. */
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "commands.h"
#include "json.h"
#include "names.h"
#include "mesh.h"
#include "mesh_io.h"
#include "ns_config.h"
#include "quality.h"
#include "run.h"
#include "scenario.h"

static const char check_usage[] =
    "usage: needlesim check SCENARIO.lua [--json] [--mesh-out FILE.vtu|FILE.msh] "
    "[--set KEY=VALUE]...\n";

typedef enum MeshFormat { FORMAT_NONE, FORMAT_VTU, FORMAT_MSH } MeshFormat;

static bool has_suffix(const char *s, const char *suffix)
{
    size_t n = strlen(s), k = strlen(suffix);
    return n >= k && strcasecmp(s + n - k, suffix) == 0;
}

/* A bad command line: one line, the usage on --help (the one-line contract for bad input). */
static int usage_error(const char *fmt, const char *arg)
{
    fputs("needlesim check: ", stderr);
    fprintf(stderr, fmt, arg);
    fputs(" (needlesim check --help)\n", stderr);
    return 2;
}

typedef struct CheckStats {
    NsQualityStats quality;
    NsBoundaryStats boundary;
} CheckStats;

static const char *tissue_kind_name(NsTissueKind k)
{
    switch (k) {
    case NS_TISSUE_BOX:
        return "box";
    case NS_TISSUE_SHAPES:
        return "shapes";
    case NS_TISSUE_FILE:
        return "file";
    }
    return "?";
}

static void print_json(const NsScenario *sc, const CheckStats *st)
{
    NsJson j;
    ns_json_init(&j, stdout, 2);
    ns_json_begin_object(&j);
    ns_json_key(&j, "scenario");
    ns_json_string(&j, sc->name);
    ns_json_key(&j, "version");
    ns_json_string(&j, NS_VERSION);
    ns_json_key(&j, "tissue");
    ns_json_string(&j, tissue_kind_name(sc->tissue_kind));
    ns_json_key(&j, "resolution_m");
    if (sc->tissue_kind == NS_TISSUE_FILE)
        ns_json_null(&j);
    else
        ns_json_number(&j, sc->resolution);
    ns_json_key(&j, "tets");
    ns_json_int(&j, sc->mesh.tet_alive);
    ns_json_key(&j, "nodes");
    ns_json_int(&j, sc->mesh.node_alive);
    ns_json_key(&j, "regions");
    ns_json_begin_array(&j);
    for (int i = 0; i < sc->region_count; i++) {
        const NsRegionInfo *r = &sc->regions[i];
        ns_json_begin_object(&j);
        ns_json_key(&j, "name");
        ns_json_string(&j, r->name);
        ns_json_key(&j, "material");
        ns_json_string(&j, r->material.name);
        ns_json_key(&j, "tets");
        ns_json_int(&j, r->tets);
        ns_json_key(&j, "volume_m3");
        ns_json_number(&j, r->volume_m3);
        ns_json_key(&j, "fixed");
        ns_json_bool(&j, r->fixed);
        ns_json_key(&j, "tag");
        ns_json_int(&j, r->tag);
        ns_json_end_object(&j);
    }
    ns_json_end_array(&j);
    ns_json_key(&j, "min_dihedral_deg");
    ns_json_number(&j, st->quality.min_dihedral_deg);
    ns_json_key(&j, "max_dihedral_deg");
    ns_json_number(&j, st->quality.max_dihedral_deg);
    ns_json_key(&j, "min_quality");
    ns_json_number(&j, st->quality.min_quality);
    ns_json_key(&j, "inverted_tets");
    ns_json_int(&j, st->quality.inverted);
    ns_json_key(&j, "boundary_closed");
    ns_json_bool(&j, st->boundary.closed);
    ns_json_key(&j, "boundary_manifold");
    ns_json_bool(&j, st->boundary.manifold);
    ns_json_key(&j, "boundary_faces");
    ns_json_int(&j, st->boundary.faces);
    ns_json_key(&j, "fixed_nodes");
    ns_json_int(&j, sc->fixed_nodes);
    ns_json_key(&j, "junction_tets");
    ns_json_int(&j, sc->meshed ? sc->mesher_stats.junction_tets : 0);
    if (sc->meshed) {
        ns_json_key(&j, "lattice_vertices");
        ns_json_int(&j, sc->mesher_stats.lattice_vertices);
        ns_json_key(&j, "warped_vertices");
        ns_json_int(&j, sc->mesher_stats.warped_vertices);
        ns_json_key(&j, "cut_points");
        ns_json_int(&j, sc->mesher_stats.cut_points);
    }
    ns_json_key(&j, "build_ms");
    ns_json_number(&j, sc->build_ms);
    ns_json_end_object(&j);
}

static const char *yes_no(bool b)
{
    return b ? "yes" : "no";
}

static void print_table(const NsScenario *sc, const CheckStats *st)
{
    printf("scenario   %s  (%s)\n", sc->name, sc->path);
    if (sc->description)
        printf("           %s\n", sc->description);
    if (sc->tissue_kind == NS_TISSUE_FILE)
        printf("tissue     file %s\n", sc->mesh_path);
    else
        printf("tissue     %s, resolution %g mm\n", tissue_kind_name(sc->tissue_kind),
               sc->resolution * 1e3);
    printf("mesh       %d tets, %d nodes (%d fixed), built in %.1f ms\n", sc->mesh.tet_alive,
           sc->mesh.node_alive, sc->fixed_nodes, sc->build_ms);
    printf("regions\n");
    int wname = 4, wmat = 8;
    for (int i = 0; i < sc->region_count; i++) {
        int n = (int)strlen(sc->regions[i].name), k = (int)strlen(sc->regions[i].material.name);
        wname = n > wname ? n : wname;
        wmat = k > wmat ? k : wmat;
    }
    wname = wname > 40 ? 40 : wname;
    wmat = wmat > 40 ? 40 : wmat;
    printf("  %3s  %-*s  %-*s  %7s  %12s  %12s  %s\n", "#", wname, "name", wmat, "material", "tets",
           "volume cm^3", "volume m^3", "fixed");
    for (int i = 0; i < sc->region_count; i++) {
        const NsRegionInfo *r = &sc->regions[i];
        printf("  %3d  %-*s  %-*s  %7d  %12.3f  %12.4e  %s\n", i, wname, r->name, wmat,
               r->material.name, r->tets, r->volume_m3 * 1e6, r->volume_m3, yes_no(r->fixed));
    }
    printf("quality    dihedral angles %.2f to %.2f deg, min quality %.4f, inverted %d\n",
           st->quality.min_dihedral_deg, st->quality.max_dihedral_deg, st->quality.min_quality,
           st->quality.inverted);
    printf("boundary   %d faces, closed %s, manifold %s\n", st->boundary.faces,
           yes_no(st->boundary.closed), yes_no(st->boundary.manifold));
    if (sc->meshed)
        printf("mesher     %d lattice vertices, %d warped, %d cut points, %d junction tets\n",
               sc->mesher_stats.lattice_vertices, sc->mesher_stats.warped_vertices,
               sc->mesher_stats.cut_points, sc->mesher_stats.junction_tets);
}

int ns_cmd_check(int argc, char **argv)
{
    const char *scenario = NULL, *mesh_out = NULL;
    bool json = false, options_done = false;
    NsRunOpts sets = {0}; /* --set KEY=VALUE, checked as run checks them */
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (options_done || a[0] != '-' || strcmp(a, "-") == 0) {
            if (scenario)
                return usage_error("unexpected argument '%s'", a);
            scenario = a;
        } else if (strcmp(a, "--") == 0) {
            options_done = true;
        } else if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            fputs(check_usage, stdout);
            return 0;
        } else if (strcmp(a, "--json") == 0) {
            json = true;
        } else if (strcmp(a, "--mesh-out") == 0) {
            if (i + 1 >= argc)
                return usage_error("%s needs a file name", a);
            mesh_out = argv[++i];
        } else if (strncmp(a, "--mesh-out=", 11) == 0) {
            mesh_out = a + 11;
        } else if (strcmp(a, "--set") == 0) {
            if (i + 1 >= argc)
                return usage_error("%s needs a value", a);
            const char *why = ns_run_opt_set(&sets, argv[++i]);
            if (why)
                return usage_error(why, argv[i]);
        } else {
            return usage_error("unknown option '%s'", a);
        }
    }
    if (!scenario)
        return usage_error("%s", "missing SCENARIO.lua");
    MeshFormat format = FORMAT_NONE;
    if (mesh_out) {
        if (has_suffix(mesh_out, ".vtu"))
            format = FORMAT_VTU;
        else if (has_suffix(mesh_out, ".msh"))
            format = FORMAT_MSH;
        else
            return usage_error("--mesh-out '%s': unknown mesh format (use .vtu or .msh)", mesh_out);
    }
    if (has_suffix(scenario, ".msh") || has_suffix(scenario, ".vtu")) {
        fprintf(stderr,
                "needlesim: %s: check takes a scenario (.lua); to check a mesh file, load it "
                "from a scenario with ns.tissue.file{path = ...}\n",
                scenario);
        return 1;
    }

    NsScenario sc;
    char err[2048];
    if (ns_scenario_load_set(scenario, sets.sets, sets.nsets, &sc, err, (int)sizeof err) != 0) {
        ns_one_line(err);
        fprintf(stderr, "%s\n", err);
        return 1;
    }
    int status = 0;
    if (ns_mesh_validate(&sc.mesh, err, (int)sizeof err) != 0) {
        fprintf(stderr, "needlesim: %s: the built mesh is invalid: %s\n", scenario, err);
        status = 1;
    }
    CheckStats st;
    memset(&st, 0, sizeof st);
    if (status == 0) {
        ns_mesh_quality(&sc.mesh, false, &st.quality);
        ns_mesh_boundary(&sc.mesh, &st.boundary);
    }
    if (status == 0 && format != FORMAT_NONE) {
        int rc;
        if (format == FORMAT_VTU) {
            rc = ns_mesh_write_vtu(mesh_out, &sc.mesh, err, (int)sizeof err);
        } else {
            const char **names = ns_scenario_region_names(&sc);
            rc = names ? ns_mesh_write_msh(mesh_out, &sc.mesh, names, sc.region_count, err,
                                           (int)sizeof err)
                       : (snprintf(err, sizeof err, "out of memory"), -1);
            free(names);
        }
        if (rc != 0) {
            fprintf(stderr, "needlesim: --mesh-out: %s\n", err);
            status = 1;
        }
    }
    if (status == 0) {
        for (int i = 0; i < sc.region_count; i++)
            if (sc.regions[i].tets == 0)
                fprintf(stderr,
                        "needlesim: warning: %s: region '%s' has no tets (smaller than the "
                        "resolution, or covered by later regions)\n",
                        sc.tissue_where ? sc.tissue_where : scenario, sc.regions[i].name);
        if (st.quality.inverted > 0)
            fprintf(stderr, "needlesim: warning: %d inverted tets\n", st.quality.inverted);
        if (json)
            print_json(&sc, &st);
        else
            print_table(&sc, &st);
        if (fflush(stdout) != 0 || ferror(stdout)) {
            fprintf(stderr, "needlesim: cannot write to standard output\n");
            status = 1;
        }
    }
    ns_scenario_free(&sc);
    return status;
}
