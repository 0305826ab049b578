/* Tissue remeshing at the needle tip (paper §3.4.1, Algorithm 2, Figure 3), in material space.
 *
 * Operations. A node snap moves an existing node to the new tip position u_new. A split of a
 * simplex S (an edge, a face or a tet: k = 2, 3 or 4 nodes) inserts a node m at u_new and
 * replaces every tet that contains S by k tets, each with one node of S replaced by m: the edge,
 * face and tet splits of the paper are the same operation on simplices of three sizes. Splits
 * change the topology; they are kept on a stack (NsRemeshStack) with what they removed, so that
 * popping the stack restores the earlier topology exactly, tet by tet (a full retraction gives
 * back the original mesh). Snaps are not on the stack; the first snap of a node records its
 * original position, so a node the needle leaves can go back to it.
 *
 * Choice (ns_remesh_tip, Algorithm 2). The candidates are the snap of the needle's tip node u1,
 * the fifteen standard operations on the tet containing u_new (point location by walking from
 * a hint), and, when u1 was created by the operation atop the stack, "undo it, then a standard
 * operation" composites. Candidates that would change the boundary (unless allowed: skin entry)
 * or leave the needle's chain disconnected are discarded. Each candidate is applied for real,
 * with the repositioning of u1 (or u2) along the needle segment that maximizes its tets' worst
 * quality, scored by the quality vector of the region (sorted worst first, compared
 * lexicographically), and undone; the best is applied. Quality is signed volume over rms edge
 * length cubed (sim/quality.h), in material coordinates. Ours: with a dihedral floor
 * (NsRemeshTip.dihedral_floor_deg), the region's worst dihedral angle clipped at the floor ranks
 * first, the quality vector breaking ties.
 *
 * World position, velocity and acceleration of a new or moved node come from barycentric
 * interpolation in the tet containing its new material position. No Lua, no I/O. */
#ifndef NS_REMESH_H
#define NS_REMESH_H

#include <stdbool.h>

#include "mesh.h"

typedef enum NsRemeshKind {
    NS_REMESH_NONE = 0,
    NS_REMESH_SNAP = 1,
    NS_REMESH_EDGE_SPLIT = 2,
    NS_REMESH_FACE_SPLIT = 3,
    NS_REMESH_TET_SPLIT = 4,
} NsRemeshKind;

/* A split as applied: enough to undo it exactly. */
typedef struct NsRemeshOp {
    NsRemeshKind kind;
    int node;         /* the node it created */
    int simplex[4];   /* the split simplex's nodes (kind = its node count) */
    int removed;      /* tets removed */
    int *removed_tet; /* (removed x 6) slot, region, 4 nodes, in removal order */
    int added;        /* tets added */
    int *added_tet;   /* (added) slots, in order */
} NsRemeshOp;

typedef struct NsRemeshStack {
    int count, cap;
    NsRemeshOp *ops;
    /* First-snap records: node, original material position. */
    int snaps, snap_cap;
    int *snap_node;
    double *snap_u;
} NsRemeshStack;

void ns_remesh_stack_init(NsRemeshStack *s);
void ns_remesh_stack_free(NsRemeshStack *s);

/* The tet containing material point p (barycentric coordinates into bary, may be NULL), walking
 * across faces from tet `start` (any alive tet if start is not), then by a full search if the
 * walk fails. Points within tol (barycentric) of a tet count as inside. Returns -1 if p is
 * outside the mesh. */
int ns_mesh_locate(const NsMesh *m, const double p[3], int start, double tol, double bary[4]);
/* The same with the node coordinates X (3 node_slots): m->x locates a world point in the
 * deformed mesh (its material point is then the same barycentric combination of m->u). */
int ns_mesh_locate_in(const NsMesh *m, const double *X, const double p[3], int start, double tol,
                      double bary[4]);
/* The tets alive whose box meets the box [lo, hi] of coordinates X, in increasing order, into
 * out (room for m->tet_slots); returns their count. A tet whose barycentric coordinates of p
 * are all >= -tol lies within 3 tol times its own extent of p along each axis, so it meets any
 * box that holds p widened by that much. */
int ns_mesh_tets_in_box(const NsMesh *m, const double *X, const double lo[3], const double hi[3],
                        int *out);
/* ns_mesh_locate_in's two parts: the walk alone (the tet, or -2 when it left the mesh or
 * cycled), and the search that follows it, confined to cand[0..n) (increasing): the same answer
 * as the full search when cand holds every tet that meets such a box about p
 * (ns_mesh_tets_in_box), since only those can hold p within tol. */
int ns_mesh_walk(const NsMesh *m, const double *X, const double p[3], int start, double tol,
                 double bary[4]);
int ns_mesh_search_among(const NsMesh *m, const double *X, const double p[3], double tol,
                         double bary[4], const int *cand, int n);

/* Splits the simplex of k nodes (2: edge, 3: face, 4: tet; every tet containing them) at
 * material point u and pushes the operation; the new node's world state is interpolated in
 * the tet containing u (or the simplex's own tets). Returns the new node, or -1 (no tet contains
 * the simplex, a created tet would not be positive in material space, memory: mesh unchanged). */
int ns_remesh_split(NsMesh *m, NsRemeshStack *s, const int *simplex, int k, const double u[3]);
/* Undoes and pops the operation atop the stack (its node must have no tets beyond the ones it
 * made). Returns 0, or -1 (empty stack, memory). */
int ns_remesh_undo(NsMesh *m, NsRemeshStack *s);
/* Moves node n to material point u (world state interpolated as for a split), recording its
 * first original position. Returns 0, or -1 (u outside the mesh, memory). */
int ns_remesh_snap(NsMesh *m, NsRemeshStack *s, int n, const double u[3]);
/* Moves nodes[i] to material point u[3i..3i+3) for every i < count at once: each world state
 * interpolated in the mesh as it was before any of them moved (so the result does not depend
 * on their order). Returns 0, or -1 (a point outside the mesh, memory: mesh unchanged; some
 * originals may be recorded, which is harmless as the nodes have not moved). */
int ns_remesh_snap_all(NsMesh *m, NsRemeshStack *s, const int *nodes, const double *u, int count);
/* The original material position of a snapped node (1), or 0 if it was never snapped. */
int ns_remesh_original(const NsRemeshStack *s, int n, double u[3]);
/* Records u as node n's original material position (if none is recorded yet): for nodes moved
 * before the remesher took over (a laid entry track), so that they go back when released.
 * Returns 0, or -1 (memory). */
int ns_remesh_record_original(NsRemeshStack *s, int n, const double u[3]);
/* Puts every recorded node back at its original material position (world state interpolated
 * there, as for a snap) and forgets the records: the needle has left the tissue. */
void ns_remesh_release_all(NsMesh *m, NsRemeshStack *s);

/* Worst material quality of the tets around node n (INFINITY with none). */
double ns_remesh_node_quality(const NsMesh *m, int n);
/* Is node n on the boundary (on a face of one of its tets with no tet across)? */
int ns_remesh_node_on_boundary(const NsMesh *m, int n);
/* Are nodes a and b joined by an edge (in a common tet; a node is joined to itself)? */
int ns_remesh_joined(const NsMesh *m, int a, int b);

/* Forgets node n's recorded original position (if any). */
void ns_remesh_forget_original(NsRemeshStack *s, int n);

/* Skin entry (§3.4.1, sim/remesh_entry.c): the needle's first penetration at material point a on
 * the tissue's surface, along direction d. The entry node is made at a (a free surface node of
 * the tet there within 0.75 of its shortest edge, its surrounding surface flat within about 5
 * degrees, snapped there; else the surface face or edge split at a), then the tip node at depth
 * along d (the simplex containing it split there), joined to the entry node by an edge: the
 * short edge at the skin. Ours (issue 35): depth is the least depth; deeper ones, up to half the
 * entry node's mean edge, are taken where the tip node's tets would otherwise have dihedral
 * angles under 12 deg, and then the repair (ns_remesh_repair) moves free nodes of the entry's
 * tets; where the point at depth lies beyond the entry node's tets, the depth is halved. The
 * splits are pushed on s and the snaps recorded, so that undoing s and releasing its records
 * restores the mesh. nodes[0]: the entry node, nodes[1]: the tip node. Returns 0, or -1 with a
 * message (a not on the surface, d not into the tissue there, or no valid split), the mesh and
 * s then as they were. */
int ns_remesh_skin_entry(NsMesh *m, NsRemeshStack *s, const double a[3], const double d[3],
                         double depth, int nodes[2], char *err, int err_sz);

/* Needle tip state for Algorithm 2. */
typedef struct NsRemeshTip {
    int u1, u2, u3;   /* tissue nodes of the needle: the tip, the one behind it, the one
                         behind that (-1 if none) */
    const int *chain; /* every tissue node of the needle, tip first (chain[0] = u1) */
    int chain_len;
    int penetrating;     /* 1: DYNAMIC+ (cutting forward); 0: DYNAMIC- (retracting) */
    bool allow_boundary; /* skin entry: operations may change the boundary */
    int hint_tet;        /* where the point location starts (updated on return) */
    /* Our addition to the choice (§3.4.1): candidates are ranked first by their region's worst
     * dihedral angle clipped at this floor [deg], then by the sorted quality vector; 0: by the
     * quality vector alone, as in the paper */
    double dihedral_floor_deg;
    /* After an undo (lines 6-8) the node placed at u_new takes u_new's world state from the mesh
     * before the undo, with the tip's node (the nonholonomic arc model sets it: without it the
     * tip's world path jumped sideways at undo steps in double-bend); false: from the mesh after
     * the undo, the tissue around the undone node, which relaxes the tip's displacement (bone
     * contact depends on that: docs/remeshing.md, "The placed node's world state") */
    bool undo_keeps_world;
} NsRemeshTip;

typedef struct NsRemeshResult {
    NsRemeshKind kind;  /* the standard operation performed (SNAP for the tip snap) */
    int undone;         /* the top of the stack was popped first */
    int tip;            /* the needle's new tip node (at u_new) */
    int dropped;        /* u1 left the needle (the chain is now ... u2, tip) */
    int candidates;     /* candidates scored */
    double min_quality; /* worst quality in the region after the operation */
    int repaired;       /* nodes the repair moved (ns_remesh_repair) */
} NsRemeshResult;

/* Algorithm 2: remeshes around the needle tip moving to material point u_new. Returns 0, or
 * -1 with a message (u_new outside the tissue, no valid candidate, memory). */
int ns_remesh_tip(NsMesh *m, NsRemeshStack *s, NsRemeshTip *tip, const double u_new[3],
                  NsRemeshResult *res, char *err, int err_sz);

/* Our addition to Algorithm 2 (sim/remesh_repair.c): the repair after the choice. A tet's angle
 * score is its smallest dihedral angle or, if worse, 180 deg less its largest scaled so that 155
 * deg scores the floor, clipped at floor_deg. For each tet of tets[0 .. nt) scoring 1.5 deg or
 * more below the floor, the nodes that may move (not in pinned[0 .. npinned): the needle's; not
 * fixed; not on the boundary) of the tets below the floor are moved, each towards the material
 * point that maximizes its tets' worst score, then their worst quality (a compass search), as
 * far as the score needs (a bisection), all together: Jacobi sweeps, up to three, so that the
 * result does not depend on the order of tets. A sweep's moves are kept only if
 * together they raise the worst score of the moved nodes' tets, keep those tets positive at rest
 * and in the world (each world point interpolated at its new material point) and leave every
 * tet a stacked split removed positive (so that undoing the split stays valid); else they are
 * halved towards the start, up to six times. They are snaps (ns_remesh_snap_all: originals
 * recorded, world states interpolated). No topology changes. Returns the number of node moves. */
int ns_remesh_repair(NsMesh *m, NsRemeshStack *s, const int *tets, int nt, const int *pinned,
                     int npinned, double floor_deg);

/* Sorted quality vector comparison: > 0 if a (na values, sorted ascending) is lexicographically
 * better than b. */
int ns_quality_vector_cmp(const double *a, int na, const double *b, int nb);

#endif
