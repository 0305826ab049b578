/* Needle-tissue coupling with stick-slip friction and cutting (paper §3.3, §3.6.1, Algorithm 3,
 * Eq. 7-11), solved every step together with the tissue (sim/tissue.h) and the needle
 * (sim/rod.h).
 *
 * Coupling nodes. A needle node inside the tissue sits at a tissue point: a tissue node, or, for
 * the tip, a point on a tissue edge (weights 1 - w and w on its two nodes; see sim/needle_path.h).
 * Each needle node has a friction state: FREE (outside the tissue), STATIC (needle and tissue move
 * together there), DYNAMIC+ (the needle slides forward, towards its tip, through the tissue) or
 * DYNAMIC- (backward). At coupling node i the local frame R_i = [t_i n1_i n2_i] has the tangent of
 * §3.3; the constraint force c_i (on the needle; the tissue gets -c_i) is unknown in the
 * constrained directions: all three for STATIC, the two normal ones for DYNAMIC, whose tangential
 * component is the known friction -s_i f_i (s_i = +1 for DYNAMIC+). The constraints (Eq. 8) keep
 * the tissue point and the needle node moving together in the constrained directions over the
 * step. Friction per node f_i = f_perlen (l_{i-1} + l_i) / 2 (only the halves of needle edges that
 * lie inside the tissue count, so the needle's total is f_perlen times the length inside); at a
 * cutting tip (DYNAMIC+ inside the tissue) f_cut of the tissue it cuts is added: per tissue
 * region, so a membrane region (prostate capsule, skin) gets a large one (capsule puncture).
 * Viscous friction eta (l_{i-1} + l_i) / 2 (v_tissue - v_needle) along t acts on both sides,
 * implicit in each side's own velocity.
 *
 * Friction states (Algorithm 3, §3.6.1): guessed from the previous step, checked against
 * Eq. 9-11 (a STATIC node's tangential force within [-f, f], at the tip [-(f + f_cut), f]; a
 * DYNAMIC node's relative tangential motion in its sign's direction), violators flipped (DYNAMIC
 * -> STATIC; STATIC -> DYNAMIC in the direction the force pushes the needle), a configuration
 * tried before replaced by the next one in lexicographic order (entry node least significant),
 * at most max_trials trials, checked at tau_check before finishing to tau_sol.
 *
 * Linear solvers (one interface, NsCoupledSolverKind):
 *   SCHUR  ours, the default (sim/coupled_schur.c, docs/coupling.md): a stale CHOLMOD factor of
 *          the tissue matrix, the dense compliance of the coupling DOFs from cached factor
 *          columns, projected PCG with the constraint preconditioner for the exact solves, and
 *          flipped friction configurations tried on the dense compliance first.
 *   PAPER  CG on the whole indefinite system Eq. 7, the constraint rows applied node by node and
 *          never assembled, warm-started from the previous trial (§3.6.1-3.6.2). The baseline
 *          every speed claim is measured against.
 *
 * SI units throughout. */
#ifndef NS_COUPLING_H
#define NS_COUPLING_H

#include <stddef.h>
#include <stdint.h>

#include "arena.h"
#include "friction.h"
#include "needle_path.h"
#include "remesh.h"
#include "rod.h"
#include "solver.h"
#include "tissue.h"

typedef enum NsCoupledSolverKind {
    NS_COUPLED_SCHUR = 0, /* ours, the default: stale factor, dense compliance, projected PCG */
    NS_COUPLED_PAPER = 1, /* CG on Eq. 7, the paper's */
} NsCoupledSolverKind;

/* "schur" / "paper", and back (-1 for an unknown name). */
const char *ns_coupled_solver_name(NsCoupledSolverKind kind);
int ns_coupled_solver_parse(const char *name);

#define NS_COUPLING_MAX_REGIONS 32

/* How a bevel tip (NsRodParams.tip = NS_TIP_BEVEL, angle psi) steers when the tissue is remeshed
 * at the tip (docs/remeshing.md compares the two). */
typedef enum NsBevelModel {
    /* Ours, the default: while the tip cuts, the bevel pushes the tissue ahead of the tip
     * against the tip frame's m2 with k_b tan(psi), k_b = bevel_force[region], and the tissue
     * around the needle's end takes the needle's push along m2: a pair of body forces, each
     * spread over a ball of radius tip_load_radius (ahead of the tip and behind it), so the
     * load does not depend on the mesh once its elements resolve the balls. */
    NS_BEVEL_FORCE = 0,
    /* The paper's (§3.5): u_new is displaced by d tan(psi) along m2 in material space only.
     * The strain it leaves builds up at the tip's node to about (element size) tan(psi), so
     * the steering depends on the element size. */
    NS_BEVEL_DISPLACEMENT = 1,
    /* The nonholonomic model (Webster et al. 2006): the cut's heading in material space turns
     * towards the tip frame's m2 at the curvature k_c tan(psi), k_c = bevel_curvature[region],
     * per distance cut; u_new is the tip's advance along that arc, and the needle, coupled to
     * its path, follows it. The bend reverses where the bevel turns. */
    NS_BEVEL_ARC = 2,
} NsBevelModel;

typedef struct NsCouplingParams {
    double f_perlen; /* friction per unit length inside the tissue [N/m] */
    double eta;      /* viscous friction per unit length [N s/m^2] */
    /* 1: torsional stick/slip friction on the twist of the edges inside the tissue, bounded by
     * f_perlen r_o per unit length (sim/twist_friction.h); 0: the paper's model (none) */
    int twist_friction;
    double cut_force[NS_COUPLING_MAX_REGIONS]; /* f_cut by tissue region [N] */
    double tau_check, tau_sol;                 /* relative residuals (§3.6.1: 1e-3, 1e-5) */
    int max_trials;                            /* friction configurations tried per step (10) */
    int max_iter;                              /* iterations per linear solve */
    NsCoupledSolverKind solver;
    int threads; /* for the SpMV and vector loops and (schur) a background refactorization;
                    results do not depend on it */
    /* schur: a solve needing more iterations than this schedules a refactorization of the
     * tissue matrix, adopted at the next step (10: a factorization and its columns cost about
     * ten iterations; lower pays only with a second core, docs/coupling.md) */
    int refresh_iterations;
    /* schur: order the tip's ring last in the tissue factor and make its block current every
     * step, projecting between the preconditioner's substitutions (docs/solvers.md, "The
     * tail"): about a fifth fewer PCG iterations. 0 by default: docs/performance.md, "Settings
     * measured but not default", says why */
    int tip_block;
    /* 0: the tip cuts along the pre-laid path (sim/needle_path.h); 1: the tissue is remeshed
     * at the tip every step it slides (Algorithm 2, sim/remesh.h), the path then being the
     * needle's chain of tissue nodes with the tip at its last node */
    int remesh;
    /* remesh: candidates whose region's worst dihedral angle is below this [deg] rank below
     * those above it, before the paper's quality vector is compared (sim/remesh.h; 0: the
     * paper's choice; 12 by default, docs/remeshing.md) */
    double remesh_dihedral_floor;
    NsBevelModel bevel_model;
    double bevel_force[NS_COUPLING_MAX_REGIONS]; /* k_b by tissue region [N] (NS_BEVEL_FORCE) */
    /* k_c by tissue region: the cut's curvature at tan(psi) = 1 [1/m] (NS_BEVEL_ARC) */
    double bevel_curvature[NS_COUPLING_MAX_REGIONS];
    /* the radius R of the two balls, ahead of the tip and behind it, over which the tissue takes
     * the bevel force's pair (NS_BEVEL_FORCE; sim/coupled_tip_load.c, docs/needle.md): at least
     * about the element size [m] */
    double tip_load_radius;
} NsCouplingParams;

NsCouplingParams ns_default_coupling_params(void);

typedef struct NsCouplingStats {
    double total_ms, tissue_ms, needle_ms, lcp_ms, remesh_ms; /* the paper's Table 2 columns */
    int trials;     /* friction configurations tried (Table 3): each an exact solve of Eq. 7
                       (paper), or a dense solve on the compliance and, if consistent there,
                       an exact one (schur) */
    int iterations; /* CG iterations (paper) or projected PCG iterations (schur), all trials */
    int refactors;  /* schur: factorizations of the tissue matrix this step */
    int consistent; /* the accepted friction states satisfy Eq. 9-11 */
    int coupled;    /* coupling nodes this step */
    int n_static, n_dyn_pos, n_dyn_neg;
    int cutting;        /* the tip cut this step (DYNAMIC+ inside the tissue) */
    double bevel_force; /* the bevel's lateral force on the tip this step (NS_BEVEL_FORCE) [N] */
    double axial_force; /* force the tissue puts on the needle along its axis, summed [N]:
                           negative = resisting insertion */
    double tip_slide;   /* the tip's slide through the tissue this step [m], + = forward */
    int unconverged;    /* the final solve missed tau_sol */
    int nan_count;      /* non-finite values caught (the step is rejected) */
    int inverted;       /* inverted tets after the step */
    int rod_splits, rod_merges;
    /* remesh: the operation at the tip this step (NsRemeshKind, 0 none), whether the top of
     * the stack was undone first, candidates scored, and the worst and largest dihedral angle
     * of the tets around the needle's last three tissue nodes after it [deg] */
    int remesh_kind, remesh_undone, remesh_candidates;
    int remesh_substeps; /* pieces the tip's move was cut into (§3.4.1; 1 = none, 0 = no remesh) */
    int remesh_repaired; /* nodes moved by the remesher's repair (ns_remesh_repair), all pieces */
    int exited;          /* remesh: the needle was withdrawn out of the tissue this step */
    int exit_undone;     /* ... and the splits the exit had to undo beyond the one that made
                            the tip's node (after skin entry: the entry's own surface split, if
                            it made one; beyond that, 0 when Algorithm 2 undid the rest) */
    double min_dihedral_deg, max_dihedral_deg;
    /* remesh: physical outcomes (docs/remeshing.md, "Bone contact and far-side exit").
     * bone_contact: the cutting tip met a rigid tissue region (every node of a tet fixed: bone)
     * this step and was stopped at its surface: 1 on the first step of a contact, 2 on later
     * steps of the same one; bone_region: that tet's region. stalled: the needle rested on it
     * and the commanded insertion was not fed through the sleeve this step. tip_exit: the tip
     * left the tissue through its surface this step (not back through its entry); tip_returned:
     * a needle through the far side was drawn back in until its tip was at the exit again. */
    int bone_contact, bone_region, stalled, tip_exit, tip_returned;
    /* remesh: a withdrawn needle entered the tissue again this step (a fresh skin entry where
     * it crossed the surface, sim/coupling_reentry.c); reentry_first: its first node inside */
    int reentered, reentry_first;
} NsCouplingStats;

typedef struct NsCoupled {
    NsTissue *tissue; /* borrowed */
    NsRod *rod;       /* borrowed */
    NsNeedlePath path;
    NsCouplingParams params;
    /* Per needle node (cap): tissue nodes and weight of its tissue point (ta -1: FREE) and its
     * friction state. */
    int cap;
    int *ta, *tb;
    double *tw;
    uint8_t *state;
    NsArena arena;              /* the step's scratch (sim/arena.h), empty between steps */
    struct CoupledSchur *schur; /* our solver's state between steps (NS_COUPLED_SCHUR) */
    NsRemeshStack remesh;       /* params.remesh: the undo stack of the tip's splits */
    int remesh_hint;            /* a tet near the tip, where point location starts */
    int path_cap;               /* entries allocated in path.node and path.s */
    int outside;                /* params.remesh: the needle was withdrawn out of the tissue */
    /* outside: how deep the tip still was as the needle left (material space, along its track)
     * [m]: it leaves with its tip up to that far in (coupling_tip.c, EXIT_MARGIN), and re-enters
     * only once pushed deeper (coupling_reentry.c) */
    double exit_depth;
    double heading[3]; /* NS_BEVEL_ARC: the cut's unit heading in material space */
    int heading_valid; /* 0: taken from the needle's tip tangent when it next cuts */
    /* params.remesh: the tip rests on a rigid region (bone): a commanded insertion is not fed
     * through the sleeve (it slips) until the needle is withdrawn (v_insert < 0) */
    int tip_blocked;
    int pinned_node; /* tip_blocked: 1 + the tip's tissue node, held where it met the bone */
    uint64_t steps;
    char error[256]; /* why the last failed ns_coupled_step failed ("" after a good step) */
} NsCoupled;

/* Couples rod to tissue along path: the rod's nodes from node `first` on must sit at the path's
 * nodes 0, 1, ... (within 1e-9 m), up to the tip, which lies on the path (at a node, or on an
 * edge) or, if the rod goes on beyond the path's last node, past it. Friction states start
 * STATIC. Takes over path. Returns 0, or -1 with a message. */
int ns_coupled_init(NsCoupled *c, NsTissue *tissue, NsRod *rod, NsNeedlePath *path,
                    const NsCouplingParams *params, char *err, int err_sz);
void ns_coupled_free(NsCoupled *c);

/* One step of Algorithm 1: forces and Jacobians (tissue, needle, rod controls applied), the
 * coupled solve with friction (Eq. 7, Algorithm 3), the Newmark update of both, the tip's cut
 * (along the pre-laid path, or by remeshing with params.remesh, Algorithm 2), and the needle's
 * reparameterization (§3.4.2). ext_tissue (3 node_slots, which remeshing changes between steps)
 * and ext_rod (3 nodes) may be NULL. Returns 0, or -1: a bad dt or control, a failed solve or
 * non-finite values leave the state as before the step; a failure after the update (the
 * reparameterization, remeshing: a tip that left the tissue other than by withdrawal, a
 * withdrawn needle pushed back in) leaves the step's update applied and the tissue's arrays in
 * step with its mesh. stats say why. */
int ns_coupled_step(NsCoupled *c, double dt, const double *ext_tissue, const double *ext_rod,
                    NsCouplingStats *stats);

/* The structural checks of remeshing (issue 6): the tissue mesh valid, every coupled needle
 * node at a tissue node (the tip of a pre-laid path may sit on an edge), consecutive coupled
 * nodes joined by a tissue edge, no tet inverted in material space. O(tets). Returns 0, or -1
 * with a message naming the first failure. */
int ns_coupled_check_structure(const NsCoupled *c, char *err, int err_sz);

/* Hash of the tissue's and the needle's states and the friction states. */
uint64_t ns_coupled_state_hash(const NsCoupled *c);

#endif
