/* Isosurface stuffing (Labelle & Shewchuk, SIGGRAPH 2007), the paper's mesh generator (§4):
 * a body-centred cubic lattice is laid over the domain, lattice edges are cut where the region
 * changes, lattice vertices too close to a cut point are warped onto it, and each lattice tet
 * is filled from a small table of stencils.
 *
 * Several regions are meshed at once into one conforming mesh: each lattice vertex takes the
 * label of the region containing it (later regions override earlier ones; no region = outside),
 * and each lattice tet is stuffed on both sides of the interface it contains. See
 * docs/mesher.md for the guarantee and what holds at junctions of three regions. */
#ifndef NS_MESHER_H
#define NS_MESHER_H

#include <signal.h>

#include <stdbool.h>

#include "mesh.h"
#include "shape.h"

typedef struct NsMesherRegion {
    const NsShape *shape; /* the region is {shape <= 0} minus the later regions */
    bool fixed;           /* its nodes get NS_NODE_FIXED (bone) */
} NsMesherRegion;

typedef struct NsMesherDef {
    double spacing; /* lattice spacing h: the long (axis-aligned) lattice edge [m] */
    /* Warp thresholds, fractions of the edge, for cuts against OUTSIDE (the outer boundary).
     * Cuts between two regions warp with at most 0.21509 / 0.35900 ("two-sided" values, see
     * docs/mesher.md), since both sides of such an interface are kept. */
    double alpha_long;  /* on long edges, in (0, 0.5) */
    double alpha_short; /* on short edges, in (0, 0.5) */
    const NsMesherRegion *regions;
    int region_count;
    /* Lattice box. If lo[0] > hi[0] it is taken from the regions' bounds. The lattice is
     * anchored at lo, so a box whose faces lie on lo + k*h is meshed with flat faces. */
    double lo[3], hi[3];
    /* The memory the mesh may take [bytes], estimated before anything is allocated; 0:
     * NS_LIMIT_MESHER_BYTES (sim/ns_limits.h). */
    double max_bytes;
    /* When set and *cancel becomes non-zero (a stop signal), the mesher stops with an error
     * "interrupted" within a few thousand lattice vertices. */
    const volatile sig_atomic_t *cancel;
} NsMesherDef;

/* Spacing 0 (must be set), the published parameters alpha_long = 0.24999,
 * alpha_short = 0.41189 (dihedral angles in [10.7, 164.8] degrees for one surface),
 * bounds from the regions. */
NsMesherDef ns_default_mesher_def(void);

typedef struct NsMesherStats {
    int lattice_vertices;
    int warped_vertices;
    int cut_points;
    int junction_tets; /* lattice tets with three or more labels (see docs/mesher.md) */
} NsMesherStats;

/* Builds the mesh into out (which must be freshly initialised). Tet regions are indices into
 * def->regions. Returns 0, or -1 with a message (bad parameters, a shape that evaluates to NaN,
 * an empty result, out of memory). stats may be NULL. */
int ns_mesher_stuff(const NsMesherDef *def, NsMesh *out, NsMesherStats *stats, char *err,
                    int err_sz);

#endif
