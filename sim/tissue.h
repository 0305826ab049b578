/* The deformable tissue: a tet mesh with per-region materials, lumped masses, invertible FEM
 * forces (§3.2), lazily updated Jacobians (§3.6.3, Eq. 12) and the Newmark step (§3.1,
 * Eq. 1-5: beta = 1/4, gamma = 1/2, one Newton step on the accelerations).
 *
 * Model (read-only while stepping): materials, densities, gravity, Newmark parameters, lazy
 * threshold, thread count. State: the mesh (positions, velocities, accelerations), the per-tet
 * frames the Jacobians were last built from and those element Jacobians, the assembled
 * K = dF/dx and D = dF/dv. */
#ifndef NS_TISSUE_H
#define NS_TISSUE_H

#include <stddef.h>
#include <stdint.h>

#include "fem.h"
#include "mesh.h"
#include "solver.h"
#include "sparse.h"

/* Smallest singular value below which a tet's stiffness is projected to be definite. */
#define NS_TISSUE_PROJECT_BELOW 0.9

typedef struct NsTissueMaterial {
    NsFemMaterial fem;
    double density; /* [kg/m^3] */
} NsTissueMaterial;

typedef struct NsTissueParams {
    double gravity[3];  /* [m/s^2] */
    double beta, gamma; /* Newmark; 1/4, 1/2 = trapezoidal rule (energy conserving) */
    /* Lazy Jacobian threshold (§3.6.3, Eq. 12): a tet's Jacobian is rebuilt when the largest
     * entry of R = U V^T (corotational) or F = U S V^T (neo-Hookean) has changed by more than
     * this since its last rebuild (dimensionless; for R about the rotation angle in radians;
     * 0 = rebuild every tet every step). Our measure is scale-free, unlike the paper's, so its
     * value is ours: default 1e-2, chosen by validation case fem-lazy (docs/validation.md). */
    double lazy_threshold;
    double solve_tol;   /* relative residual of each linear solve */
    int solve_max_iter; /* CG iteration cap */
    /* Threads for the force and Jacobian assembly (§3.6.3); values < 1 mean 1. The result is
     * bit-identical for every thread count (see ns_tissue_forces). */
    int threads;
} NsTissueParams;

NsTissueParams ns_default_tissue_params(void);

typedef struct NsTissueStats {
    /* Wall times [ms]. ns_tissue_forces adds to force_ms and jacobian_ms: jacobian_ms is the
     * busiest thread's time spent building stale tets' element Jacobians plus gathering the
     * dirty block rows of K and D (with one thread: exactly the Jacobian work), force_ms the
     * rest of the call's wall time (element forces, the force gather, partitioning). */
    double force_ms, jacobian_ms, solve_ms, total_ms;
    int cg_iterations;
    int factorized;           /* the solver factored this step's matrix and used it */
    int refresh_started;      /* the solver scheduled a background refactorization (solver.h) */
    double jacobian_fraction; /* fraction of tets whose Jacobian was rebuilt this step */
    int rows_gathered;        /* block rows of K and D summed again from their tets */
    int rows_changed;         /* block rows updated by their rebuilt tets' changes */
    int nan_count;            /* non-finite values caught (the step is rejected) */
    int inverted;             /* tets with det F <= 0 after the step */
    int unconverged;          /* linear solves that missed their tolerance */
} NsTissueStats;

/* djac_slot of a rebuilt corotational tet whose change its rows take in closed form. */
#define NS_TISSUE_CLOSED_FORM 0x7fffffff

typedef struct NsTissue {
    NsMesh mesh; /* owned */
    NsTissueParams params;
    int material_count;
    NsTissueMaterial *materials; /* (material_count), indexed by tet region */
    NsTetRest *rest;             /* (tet_slots) */
    NsTetFrame *frame;           /* (tet_slots) frame of the last force evaluation */
    NsTetFrame *jframe; /* (tet_slots) frame the tet's Jacobian contribution was built from */
    double *jprod;      /* (tet_slots x 9) R = U V^T of jframe (F = U S V^T for neo-Hookean): the
                           lazy update's reference, kept rather than formed again every step */
    uint8_t *jvalid;    /* (tet_slots) 1 if its rows hold its Jacobians at jframe (kept in
                           tet_jac, or for a corotational tet given by jprod) */
    uint8_t *jnew;      /* (tet_slots) 1 if its Jacobians were rebuilt by the last call */
    /* The last call's changes of the rebuilt tets' Jacobians (new minus old, laid out as
     * tet_jac), which phase 2 adds to their rows instead of gathering them again: djac_slot[e]
     * (tet_slots) is tet e's slot in djac (djac_cap slots), -1 if it has none (then its rows
     * are gathered); djac_count the slots the call asked for. */
    double *djac;
    int *djac_slot;
    /* (tet_slots x 9) a rebuilt corotational tet's jprod before the rebuild: its rows take the
     * change in closed form (ns_fem_corot_row, djac_slot NS_TISSUE_CLOSED_FORM) instead of from
     * djac, and its element Jacobians are never stored in tet_jac */
    double *jprod_old;
    int djac_cap, djac_count;
    int kd_age;        /* calls since every row of K and D was last gathered */
    double *tet_force; /* (tet_slots x 12) element forces of the last evaluation [N] */
    /* (tet_slots x 288) a non-corotational tet's element Jacobians at jframe (a corotational
     * tet's are never stored: ns_fem_corot_row), dF/dx [N/m] and dF/dv [N s/m],
     * each 12 x 12 row-major, stored by node: for local node a, rows 3a..3a+2 of dF/dx (36
     * entries) then the same rows of dF/dv, at 72 a (JAC_STRIP a). A block row of K and D
     * reads one contiguous strip per tet. */
    double *tet_jac;
    double *mass;       /* (node_slots) lumped [kg] */
    double *force;      /* (3 node_slots) total force at the current state [N] */
    uint8_t *dof_fixed; /* (3 node_slots) */
    NsBlockMatrix K, D, A;
    /* scratch, 4 x 3 node_slots: begin_step's right-hand side and the caller's solve until
     * end_step; ns_tissue_sync_topology sums the masses in it (nothing in it survives a sync) */
    double *work;
    uint64_t steps;
    int tet_cap, node_cap; /* slots the per-tet and per-node arrays hold */
    uint8_t *was_alive;    /* (node_cap) node alive at the last init / sync */
    /* (node_cap) 1 if block row i of A is what the system build would write now (its rows of K
     * and D, its mass and the coefficients a_c1, a_c2 unchanged since it was written, and
     * nobody else wrote to it): the build then only takes the row's products (build_row) */
    uint8_t *a_valid;
    double a_c1, a_c2;
    int *rest_region;    /* (tet_cap) region the tet's rest data and Jacobians are for */
    uint64_t kd_version; /* topology version K and D were last gathered for */
    int kd_valid;        /* 0: every block row of K and D must be gathered again */
    /* Work partition (§3.6.3), a function of the topology and the thread count only: part p
     * owns nodes part_nodes[part_node_start[p] .. part_node_start[p+1]) and tets likewise. */
    int part_count;
    uint64_t part_version;
    int part_node_slots, part_tet_slots;
    int *part_node_start; /* (part_count + 1) */
    int *part_nodes;      /* (node_slots) */
    int *part_tet_start;  /* (part_count + 1) */
    int *part_tets;       /* (alive tets) */
    int *part_next;       /* (2 part_count) chunks taken of each part's tets, then nodes */
    int *node_part;       /* (node_part_cap) the part of each node slot at the last partition */
    int node_part_cap;
    int part_metis_age; /* partitions since METIS last ran (the others are patched) */
    int *colpos;       /* (part_count x node_slots) per-thread scratch for the row gather, all -1 */
    size_t colpos_len; /* entries allocated in colpos */
} NsTissue;

/* Takes a copy of mesh. materials[r] is used for tets of region r. Nodes flagged
 * NS_NODE_FIXED are held. Returns 0, or -1 with a message (a flat or inverted rest tet, a
 * region without a material, bad material values, memory). */
int ns_tissue_init(NsTissue *t, const NsMesh *mesh, const NsTissueMaterial *materials,
                   int material_count, const NsTissueParams *params, char *err, int err_sz);
void ns_tissue_free(NsTissue *t);

/* After the mesh was changed in place (t->mesh: nodes or tets added, removed or moved in
 * material space, as the tip remesher does, sim/remesh.h): grows the per-node and per-tet
 * arrays to the mesh's slots, recomputes the rest data of every alive tet and marks the
 * Jacobians of those whose rest data changed for rebuilding, recomputes the lumped masses, and
 * sets the DOFs of new nodes free (fixed if flagged NS_NODE_FIXED) and of removed ones fixed;
 * DOFs of surviving nodes keep what ns_tissue_fix_dof set. O(tets), no factorization. Returns
 * 0, or -1 with a message (a flat or inverted tet in material space, a region without a
 * material, memory: the tissue must not be stepped then). */
int ns_tissue_sync_topology(NsTissue *t, char *err, int err_sz);

/* Fix or free one DOF (node i, axis c) as a Dirichlet condition. */
void ns_tissue_fix_dof(NsTissue *t, int node, int axis, int fixed);

/* Forces (elastic, damping, gravity) at the current state into t->force, and K, D updated
 * lazily (all tets if force_all). Counts NaNs and inverted tets into stats.
 *
 * Parallel in two phases with params.threads threads (OpenMP if built with it, else serial):
 * (1) each tet writes its forces and, if stale, its element K and D into per-tet storage;
 * (2) each node sums its incident tets' force rows, and each block row of K and D touched by a
 * rebuilt tet is zeroed and gathered again from its incident tets' element matrices. A node's
 * force and an entry's sum are taken in the order of the mesh's node->tet list, never in an
 * order that depends on the threads, so the state is bit-identical for every thread count. */
void ns_tissue_forces(NsTissue *t, int force_all, NsTissueStats *stats);

/* One Newmark step of size dt [s] (§3.1): assemble, solve (M - beta dt^2 K - gamma dt D) a' =
 * F + K (dt v + dt^2 (1/2 - beta) a) + D dt (1 - gamma) a, update x, v, a. ext (3 node_slots,
 * may be NULL) adds external forces [N]. Returns 0, or -1 if the solver failed or the result was
 * not finite (the state is then left as before the step, and stats say why). */
int ns_tissue_step(NsTissue *t, NsSolver *solver, double dt, const double *ext,
                   NsTissueStats *stats);

/* The step in parts, for a caller that solves the tissue together with the needle
 * (sim/coupling.h): begin_step evaluates the forces (into stats), assembles t->A and returns
 * the right-hand side (3 node_slots, in t->work; the next 3 x 3 node_slots of t->work are free
 * scratch for the caller), or NULL if the system matrix could not be assembled (out of memory;
 * the state is unchanged); end_step applies the Newmark update with the accelerations anew. */
double *ns_tissue_begin_step(NsTissue *t, double dt, const double *ext, NsTissueStats *st);
void ns_tissue_end_step(NsTissue *t, double dt, const double *anew);

/* The caller changed block row i of t->A (coupling.c's viscous friction): the next system
 * build writes it again. */
void ns_tissue_a_row_touched(NsTissue *t, int i);

/* Static equilibrium by Newton's method on the free DOFs (fixed DOFs keep their x): stops when
 * the free residual force is below tol times the largest applied or reaction force, or after
 * max_newton iterations. ext as above. Returns the number of iterations, or -1. */
int ns_tissue_static_solve(NsTissue *t, NsSolver *solver, const double *ext, double tol,
                           int max_newton, NsTissueStats *stats);

/* Kinetic + elastic energy [J] (for the energy-drift validation). */
double ns_tissue_energy(const NsTissue *t);

/* 64-bit FNV-1a hash of the state: the mesh's topology hash, then the bit patterns of x, v and
 * a of every alive node in node order. Equal states hash equal; any bit of difference in a
 * position, velocity or acceleration (including -0.0 vs 0.0) changes it, as does the topology.
 * For determinism checks across runs and thread counts (STYLE.md 8). */
uint64_t ns_tissue_state_hash(const NsTissue *t);

#endif
