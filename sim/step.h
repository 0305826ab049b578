/* One time step of the coupled needle-tissue system: the outline of the paper's Algorithm 1
 * (sim/step.c, docs/coupling.md "One step").
 *
 *   ns_step(c, controls, dt, stats)
 *     bevel load (ours, §3.5)      coupled_tip_load            NS_BEVEL_FORCE only
 *     1. needle forces, Jacobians  ns_rod_begin_step           §3.2    -> stats.needle_ms
 *        tissue forces, Jacobians  ns_tissue_begin_step        §3.2, §3.6.3 -> stats.tissue_ms
 *     2. coupled system            coupled_assemble            Eq. 7-8, viscous friction §3.3
 *        friction LCP              coupled_schur_lcp / coupled_paper_lcp
 *                                                              Algorithm 3, Eq. 9-11 -> lcp_ms
 *     3. Newmark update            ns_tissue_end_step, ns_rod_end_step   §3.1
 *     4. the tip's cut             coupled_cut_tip             Algorithm 2, §3.4.1, §3.5
 *     5. reparameterization        coupled_reparameterize      §3.4.2   -> remesh_ms (4 and 5)
 *
 * The controls are an input of the step: ns_step hands them to the needle for this step only
 * (a needle resting on bone is not fed forward: the sleeve slips).
 *
 * Model and world. NsCoupled holds both; while stepping, ns_step reads the model and changes
 * only the world:
 *   model (read-only while stepping): params (NsCouplingParams: friction, cutting forces,
 *     tolerances, solver, bevel model, remesh options); the tissue's NsTissueParams and
 *     materials and the needle's NsRodParams (borrowed, not changed by the step); dt (an
 *     argument); the controls (an argument).
 *   world (the state the step advances): the tissue's mesh (x, v, a; and, by remeshing, its
 *     topology), the rod (nodes, x, v, a, twist, rest quantities after reparameterization),
 *     path, ta, tb, tw, state (the coupling and friction states), remesh (the undo stack),
 *     remesh_hint, outside, heading, heading_valid, tip_blocked, pinned_node, steps.
 *   caches and scratch (results do not depend on them): schur (the stale factor and its
 *     columns), arena (the step's scratch, empty between steps), cap, path_cap, error.
 * The one exception to a read-only model is remeshing (stage 4): it changes the tissue mesh's
 * topology, and with it the tissue's per-node arrays (ns_tissue_sync_topology), as an explicit
 * stage of the step. */
#ifndef NS_STEP_H
#define NS_STEP_H

#include "coupling.h"

/* What the user does to the needle this step, and external loads. SI units. */
typedef struct NsStepControls {
    double v_insert;          /* insertion speed at the sleeve [m/s] (negative retracts) */
    double twist_rate;        /* base angular velocity [rad/s] */
    double v_base[3];         /* sleeve velocity [m/s] */
    const double *ext_tissue; /* external forces on the tissue (3 node_slots) [N], or NULL */
    const double *ext_rod;    /* external forces on the needle (3 nodes) [N], or NULL */
} NsStepControls;

/* Controls with no external loads. */
NsStepControls ns_step_controls(double v_insert, const double v_base[3], double twist_rate);

/* One step of Algorithm 1 (the outline above). Returns 0, or -1: a bad dt or control, a failed
 * solve or non-finite values leave the state as before the step; a failure after the update
 * (the reparameterization, remeshing: a tip that left the tissue other than by withdrawal, a
 * withdrawn needle pushed back in) leaves the step's update applied and the tissue's arrays in
 * step with its mesh. c->error and stats (may be NULL) say why. */
int ns_step(NsCoupled *c, const NsStepControls *controls, double dt, NsCouplingStats *stats);

#endif
