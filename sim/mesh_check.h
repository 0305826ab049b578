/* Whole-mesh checks for meshes that come from files (mesh_io.c): one connected solid, and no
 * two tets covering the same space.
 *
 * Why not a volume comparison: for positive tets whose shared faces pair up with opposite
 * orientations, the divergence theorem makes the volume the boundary encloses (the sum of
 * (1/6) a·(b×c) over the outward boundary faces) equal to the tets' total volume *exactly*,
 * since every interior face cancels: two interpenetrating copies of a cube enclose twice the
 * cube's volume by that sum, as their tets do. Overlap has to be found geometrically. */
#ifndef NS_MESH_CHECK_H
#define NS_MESH_CHECK_H

#include "mesh.h"

/* Solid parts: alive tets joined through shared faces (tet_adj). part (tet_slots) gets each
 * alive tet's part, numbered in the order of their lowest tet, -1 for free slots; tets (may be
 * NULL, part count entries, caller-sized to tet_slots) the tets in each part; volume (may be
 * NULL, likewise) each part's volume [m^3] in material coordinates. Returns the number of
 * parts, or -1 when out of memory. */
int ns_mesh_parts(const NsMesh *m, int *part, int *tets, double *volume);

/* Where two tets were found to overlap: a point strictly inside tet `outer` (beyond a
 * millionth of its barycentric range from every face) that belongs to tet `inner`: one of its
 * nodes (node >= 0), its centroid (node = -1) or another point inside it (node = -2). */
typedef struct NsTetOverlap {
    int outer, inner, node;
} NsTetOverlap;

/* Looks for tets that overlap, in material coordinates: every node, and two points inside
 * every tet (its centroid and an off-centre point), are tested against the tets near them
 * (a uniform grid), and must lie strictly inside none of them but their own. That finds two copies
 * of a part however they are placed (the inner points of coincident copies, the nodes or inner
 * points of shifted ones), a part folded through itself, and a part nested inside another, whenever
 * the overlap is at least about an element across; two tets that overlap only in a sliver thinner
 * than that, with no node or centroid in it, are not seen. Returns 1 with *o filled when an overlap
 * is found, 0 when none, -1 when out of memory. Cost: about (nodes + tets) x (tets per grid cell)
 * point-in-tet tests. */
int ns_mesh_find_overlap(const NsMesh *m, NsTetOverlap *o);

#endif
