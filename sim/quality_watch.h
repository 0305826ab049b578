/* The worst dihedral angle of a tissue mesh over every state it is shown (issue 35's
 * min_dihedral_deg_any_step): at rest (material coordinates, the remesher's quality, §3.4.1)
 * and deformed (world coordinates).
 *
 * Rest. The material mesh changes only where the remesher works (a split's new tets, a snapped
 * or repaired node, an undo, a needle's exit restoring the mesh), so a look compares the mesh
 * with its copy from the last look (material positions bit for bit, each tet slot's nodes) and
 * measures only the tets that hold a moved node or whose slot changed: the minimum over every
 * alive tet of every state shown, exactly (an unchanged tet has the angles it had at a look
 * already counted), for two memory comparisons of the mesh per look and the dihedral angles of
 * the few tets that changed.
 *
 * World. Every node moves every step: a look measures every alive tet (one acos per tet). */
#ifndef NS_QUALITY_WATCH_H
#define NS_QUALITY_WATCH_H

#include "mesh.h"

typedef struct NsDihedralWatch {
    int node_cap, tet_cap;
    int node_slots, tet_slots; /* of the copies */
    double *u;                 /* material positions at the last look (3 node_slots) */
    int *tet_node;             /* 4 per tet slot at the last look, -1s for a free slot */
    unsigned char *moved;      /* scratch: per node slot */
    double min_rest_deg;       /* worst dihedral angle at rest over every look [deg] */
    double min_world_deg;      /* ... in the world (deformed) [deg] */
    double last_rest_deg;      /* worst at rest among the tets measured at the last look */
    long looks;
} NsDihedralWatch;

/* Takes the first look at m: both minima over all its alive tets. Returns 0, or -1 (memory). */
int ns_dihedral_watch_init(NsDihedralWatch *w, const NsMesh *m);
/* Another look at m (the same mesh, after a step): the rest minimum lowered to the worst of the
 * tets changed since the last look, the world minimum to the worst of all tets. Returns 0, or
 * -1 (memory: the minima stay as they were). */
int ns_dihedral_watch_look(NsDihedralWatch *w, const NsMesh *m);
void ns_dihedral_watch_free(NsDihedralWatch *w);

/* The worst dihedral angle of m's alive tets [deg] (material or world coordinates), one acos per
 * tet (ns_tet_min_dihedral); 180 with none. */
double ns_mesh_min_dihedral(const NsMesh *m, bool use_world);

#endif
