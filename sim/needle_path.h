/* The needle's path through the tissue before remeshing exists: a chain of tissue nodes joined by
 * tissue edges, laid out in advance (a mesh that already contains the needle track), along which
 * the tip cuts and retracts. It stands in for the tip remeshing of §3.4.1 (Algorithm 2): the
 * coupling (sim/coupling.h) is tested on its own, on meshes that conform to the path.
 *
 * The tip lies on the path at material arc length tip_s: on the edge between two path nodes, as
 * a weighted tissue point (the tissue point the tip is coupled to), or past the last node when the
 * needle has gone through (`through`: the tip is outside, FREE). Path nodes at least `margin`
 * (a fraction of their edge) behind the tip are the coupled shaft nodes; the entry is node 0.
 * Cutting moves tip_s forward by the tip's slide through the tissue, mapped to material length
 * along the edge it is on; retraction moves it back over the path already cut. */
#ifndef NS_NEEDLE_PATH_H
#define NS_NEEDLE_PATH_H

#include "mesh.h"

typedef struct NsNeedlePath {
    int count;     /* path nodes */
    int *node;     /* (count) tissue node indices, consecutive ones joined by a tissue edge */
    double *s;     /* (count) material arc length from node 0 [m] */
    double tip_s;  /* material arc length of the tip [m], in [0, s[count-1]] unless through */
    int through;   /* the tip has passed the last node: outside the tissue */
    double margin; /* fraction of an edge: closer path nodes behind the tip are not coupled */
} NsNeedlePath;

/* Takes the chain nodes[0..count) (count >= 2) of mesh m, with the tip at tip_s (> s[count-1]:
 * through). Returns 0, or -1 with a message (a node not alive, consecutive nodes not sharing a
 * tet, a repeated node, memory). */
int ns_needle_path_init(NsNeedlePath *p, const NsMesh *m, const int *nodes, int count, double tip_s,
                        char *err, int err_sz);
void ns_needle_path_free(NsNeedlePath *p);

/* The tip's tissue point: on edge (node[k], node[k+1]) with weight w on node[k+1]; returns k,
 * or -1 when through. */
int ns_needle_path_tip(const NsNeedlePath *p, double *w);
/* Path nodes coupled behind the tip: node[0 .. n) (all of them when through). */
int ns_needle_path_behind(const NsNeedlePath *p);
/* The largest cutting force among the regions of the tets around the tip's edge
 * (cut_force[region], regions >= count give 0). */
double ns_needle_path_cut_force(const NsNeedlePath *p, const NsMesh *m, const double *cut_force,
                                int count);

/* Lays a straight path from a to b into m: walks from the node nearest a along the mesh edges
 * that best follow the line, then snaps every chain node onto the line in material and world
 * coordinates, moving no node by more than max_move (a fraction of its shortest edge) and
 * inverting no tet. For meshes that do not contain the track already (benchmarks). Returns the
 * node count written to nodes (cap entries), or -1 with a message. */
int ns_needle_path_lay(NsMesh *m, const double a[3], const double b[3], double max_move, int *nodes,
                       int cap, char *err, int err_sz);

#endif
