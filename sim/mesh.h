/* The tetrahedral tissue mesh: nodes and tets that can be inserted and deleted while the
 * simulation runs (paper §3.4.1 remeshing, §3.6.2 "free node indices" reuse).
 *
 * Arrays are flat with their shapes in comments. A slot is either alive or on a free list;
 * freed indices are reused last-in first-out, so a delete followed by a re-insert gives the
 * same indices back. Units: metres, seconds. */
#ifndef NS_MESH_H
#define NS_MESH_H

#include <stdbool.h>
#include <stdint.h>

enum {
    NS_NODE_ALIVE = 1 << 0,    /* slot holds a node */
    NS_NODE_FIXED = 1 << 1,    /* held in place (bone, clamps) */
    NS_NODE_BOUNDARY = 1 << 2, /* on the outer boundary (see ns_mesh_mark_boundary) */
};

/* A growable list of ints (node -> incident tets). */
typedef struct NsIntList {
    int *items;
    int count;
    int cap;
} NsIntList;

typedef struct NsMesh {
    /* nodes: slots [0, node_slots), of which node_alive are in use */
    int node_slots;
    int node_cap;
    int node_alive;
    double *u;              /* (node_cap x 3) material (rest) coordinates [m] */
    double *x;              /* (node_cap x 3) world coordinates [m] */
    double *v;              /* (node_cap x 3) velocity [m/s] */
    double *a;              /* (node_cap x 3) acceleration [m/s^2] */
    uint8_t *flags;         /* (node_cap) NS_NODE_* bits */
    NsIntList *node_tets;   /* (node_cap) incident alive tets, unordered */
    uint64_t *node_changed; /* (node_cap) topology_version when node_tets[i] last changed */

    /* tets: slots [0, tet_slots), of which tet_alive are in use */
    int tet_slots;
    int tet_cap;
    int tet_alive;
    int *tet_node;   /* (tet_cap x 4) node indices; [0] = -1 marks a free slot */
    int *tet_region; /* (tet_cap) region / material id, >= 0 */
    int *tet_adj;    /* (tet_cap x 4) tet across the face opposite local vertex k, -1 = boundary */

    /* free lists (stacks): most recently freed index is reused first */
    int *free_nodes;
    int free_node_count;
    int free_node_cap;
    int *free_tets;
    int free_tet_count;
    int free_tet_cap;

    uint64_t topology_version; /* bumped by every insert/delete */
} NsMesh;

void ns_mesh_init(NsMesh *m);
void ns_mesh_free(NsMesh *m);
/* Deep copy (dst is initialised by the call). Returns 0, or -1 when out of memory. */
int ns_mesh_copy(NsMesh *dst, const NsMesh *src);

/* Insert a node at material position u (world position = u, velocity and acceleration 0).
 * Returns its index, or -1 when out of memory. */
int ns_mesh_add_node(NsMesh *m, const double u[3]);
/* Delete a node; it must have no incident tets. Returns 0, or -1 if it is still used. */
int ns_mesh_remove_node(NsMesh *m, int node);

/* Insert a tet; the caller orients it (positive signed volume in material space is expected
 * but not enforced here). Face adjacency with existing tets is linked. Returns the tet index,
 * or -1 on bad nodes or out of memory. */
int ns_mesh_add_tet(NsMesh *m, const int nodes[4], int region);
void ns_mesh_remove_tet(NsMesh *m, int tet);

static inline bool ns_mesh_node_alive(const NsMesh *m, int i)
{
    return i >= 0 && i < m->node_slots && (m->flags[i] & NS_NODE_ALIVE);
}
static inline bool ns_mesh_tet_alive(const NsMesh *m, int t)
{
    return t >= 0 && t < m->tet_slots && m->tet_node[4 * t] >= 0;
}

/* Hash of the topology: alive node indices and the set of tets (sorted nodes + region).
 * Independent of insertion order, so equal meshes hash equal whatever their history. */
uint64_t ns_mesh_topology_hash(const NsMesh *m);

/* Local vertex indices of the face opposite local vertex k, ordered so that the face normal
 * (right hand) points out of a positively oriented tet. */
extern const int ns_tet_face[4][3];

/* Walks the whole mesh and checks every invariant: alive tets reference alive, distinct nodes;
 * node->tet lists match the tets exactly; face adjacency is symmetric and every face is shared
 * by at most two tets; free lists hold exactly the dead slots. Returns 0, or -1 with a message
 * naming the first broken element or node. */
int ns_mesh_validate(const NsMesh *m, char *err, int err_sz);

/* Boundary faces (faces with one tet) as a triangle surface. */
typedef struct NsBoundaryStats {
    int faces;       /* boundary triangles */
    bool closed;     /* every boundary edge has an even number (>0) of boundary faces */
    bool manifold;   /* every boundary edge has exactly two faces and every boundary
                        vertex's faces form a single fan */
    int bad_edge[2]; /* first edge breaking closed/manifold, or -1 -1 */
    int bad_vertex;  /* first vertex whose fan is not a single cycle, or -1 */
} NsBoundaryStats;
/* Also sets NS_NODE_BOUNDARY on boundary nodes (and clears it elsewhere). */
int ns_mesh_boundary(NsMesh *m, NsBoundaryStats *out);

/* Nodes referenced by no tet are "unreferenced". Returns the first one, or -1. */
int ns_mesh_first_unreferenced_node(const NsMesh *m);

/* Compact: renumber alive nodes and tets densely (0..n-1) in their current order and empty
 * the free lists. Used after mesh generation and before export. Returns 0 or -1 (memory). */
int ns_mesh_compact(NsMesh *m);

#endif
