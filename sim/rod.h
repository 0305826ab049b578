/* The needle: a discrete elastic rod (paper §3.2, §3.5).
 *
 * Centreline nodes x_0 .. x_{n-1} joined by edges e_j = x_{j+1} - x_j (j = 0 .. n-2). Each edge
 * carries a rest length, a reference frame (t_j, d1_j, d2_j) and a twist angle theta_j that turns
 * the reference frame into the material frame (t_j, m1_j, m2_j). Each interior node i (1 .. n-2)
 * carries a rest curvature (two components in the material frame, per unit length).
 *
 * Energies:
 *  - bending and twisting, Bergou et al. 2008 ("Discrete elastic rods", SIGGRAPH), in the form of
 *    Bergou et al. 2010 ("Discrete viscous threads", §4.2) that keeps every force local: the
 *    reference frames are Bishop frames carried by parallel transport in time (from one step to
 *    the next) instead of along the rod, and the angle between neighbouring reference frames, the
 *    reference twist, enters the twist. At creation and after every reparameterization the
 *    reference frames are the space-parallel Bishop frame of Bergou 2008 (reference twist 0);
 *  - stretching, Spillmann & Teschner 2007 ("CoRdE", SCA): stiff springs of stiffness E A on
 *    every edge that push an extended or compressed edge back to its rest length.
 * Twist is quasi-static (Bergou 2008 §5): after every position update the free twist angles are
 * set to minimise the energy. Bending and stretching forces are integrated implicitly with their
 * Jacobians; the twisting force on the centreline is integrated explicitly, its Jacobian left
 * out, as in the paper (§3.2), because it is not symmetric.
 *
 * The implicit step is the paper's Newmark scheme (§3.1, Eq. 1-4, 6) with the Jacobians in a
 * banded matrix of 3x3 blocks, half-bandwidth 2 (sim/banded.h).
 *
 * Torsional friction with the tissue (sim/twist_friction.h) and an end torque enter the
 * quasi-static twist.
 *
 * Base manipulation (§3.5): the guide sleeve holds nodes 0 and 1, which move with the sleeve
 * velocity v_base; each step lengthens edge 1 (the first edge outside the sleeve) by
 * v_insert dt, and adds phi dt to theta_0, the twist of the edge inside the sleeve.
 *
 * Units are SI: metres, seconds, kilograms, newtons, pascals, radians. */
#ifndef NS_ROD_H
#define NS_ROD_H

#include <stdint.h>

#include "banded.h"

typedef enum NsTipKind {
    NS_TIP_SYMMETRIC = 0, /* a conical or blunt tip: cuts straight */
    NS_TIP_BEVEL = 1,     /* a bevel of angle bevel_angle: the tip is pushed along m2 (§3.5) */
} NsTipKind;

typedef struct NsRodMaterial {
    double youngs;         /* E [Pa] */
    double shear;          /* G [Pa]; 0 = from poisson: G = E / (2 (1 + nu)) */
    double poisson;        /* nu, used when shear is 0 */
    double outer_diameter; /* [m] */
    double inner_diameter; /* [m]; 0 for a solid rod, > 0 for a hollow needle (cannula) */
    double density;        /* [kg/m^3] */
} NsRodMaterial;

typedef struct NsRodParams {
    NsRodMaterial material;
    NsTipKind tip;
    double bevel_angle; /* psi [rad], for NS_TIP_BEVEL */
    double gravity[3];  /* [m/s^2] */
    double beta, gamma; /* Newmark; 1/4, 1/2 as the paper */
    /* Damping: a force -damping_mass * m * v on every node [1/s], and along every edge a dashpot
     * -damping_stretch * k_s * (rate of extension) [s] (stiffness-proportional on stretching). */
    double damping_mass, damping_stretch;
    double stretch_scale; /* stretching stiffness k_s = stretch_scale * E * A (1 = the material) */
    /* Reparameterization (§3.4.2): free edges longer than split_factor times the longest edge
     * at creation are split, and those shorter than merge_factor times the shortest merged. */
    double split_factor, merge_factor;
    int auto_reparam; /* split and merge at the end of every ns_rod_step (standalone rod) */
    /* Newton iterations of the step: the paper takes one (§3.1); more are taken, up to
     * newton_max, while an edge is stretched or compressed by more than newton_strain_tol
     * (dimensionless) after the step, a sign that the linearization did not hold. */
    int newton_max;
    double newton_strain_tol;
    int twist_max_iter; /* Newton iterations of the quasi-static twist per update */
    double twist_tol;   /* [rad]: stop when no twist angle moves by more than this */
} NsRodParams;

/* A stainless-steel 18-gauge brachytherapy needle (E 200 GPa, nu 0.3, 1.27 / 0.84 mm,
 * 8000 kg/m^3), no gravity, Newmark 1/4, 1/2, light damping, split 2, merge 0.5, up to 8
 * Newton iterations while a strain exceeds 1e-4. */
NsRodParams ns_default_rod_params(void);

typedef struct NsRodStats {
    double force_ms, solve_ms, twist_ms, total_ms; /* wall times [ms] */
    int newton_iterations; /* of the step (1 = the paper's single linearized solve) */
    int twist_iterations;  /* Newton iterations of the quasi-static twist (last update) */
    int twist_unconverged; /* updates whose twist did not reach twist_tol */
    int solve_failed;      /* banded solves that met a matrix that is not positive definite */
    int nan_count;         /* non-finite values caught (the step is rejected) */
    int splits, merges;    /* reparameterization this step */
} NsRodStats;

typedef struct NsRod {
    NsRodParams params;
    /* Derived from the material at init (constant while stepping). */
    double area;                         /* cross-section A [m^2] */
    double bend_stiff;                   /* E I [N m^2] */
    double twist_stiff;                  /* G J [N m^2] */
    double stretch_stiff;                /* k_s = stretch_scale E A [N] */
    double lin_density;                  /* rho A [kg/m] */
    double min_rest_edge, max_rest_edge; /* shortest and longest edge at creation [m] */

    int nodes;         /* n >= 3; edges = n - 1 */
    int cap;           /* allocated node slots */
    int held;          /* nodes held by the sleeve: 2 (nodes 0 and 1) or 0 (a free rod) */
    double *x, *v, *a; /* (cap x 3) position [m], velocity [m/s], acceleration [m/s^2] */
    double *mass;      /* (cap) lumped [kg] */
    double *force;     /* (cap x 3) total force of the last evaluation [N] */
    double *rest_len;  /* (cap) per edge [m] */
    double *theta;     /* (cap) per edge: material frame angle from the reference frame [rad] */
    double *ref_t;     /* (cap x 3) per edge: the tangent the reference frame was built for */
    double *ref_d1;    /* (cap x 3) per edge: first reference director (unit, normal to ref_t) */
    double *ref_twist; /* (cap) per interior node: reference twist [rad] */
    double *rest_curv; /* (cap x 2) per interior node: rest material curvature [1/m] */
    uint8_t *pinned;   /* (cap) caller's flag: node must survive reparameterization */
    /* Torsional friction (sim/twist_friction.h), per edge (cap): twist_fric is the largest
     * friction torque that can hold edge j's twist [N m] (0: none), set by the caller before a
     * step (the coupling sets it from the tissue contact; reparameterization zeroes it);
     * twist_anchor is theta at the start of the step (or of the static solve), where a sticking
     * edge stays [rad]. */
    double *twist_fric, *twist_anchor;

    /* Controls (§3.5), set by the caller between steps. */
    double v_base[3];  /* sleeve velocity [m/s] */
    double v_insert;   /* insertion speed [m/s] (negative retracts) */
    double twist_rate; /* base angular velocity phi [rad/s] */
    /* An external moment about the tip's tangent on the last edge [N m], acting on its material
     * angle (work tip_torque theta_last in the quasi-static twist). A moment normal to the
     * tangent bends: apply it as a couple of forces through ext. */
    double tip_torque;

    NsBanded K, D, A; /* dF/dx [N/m], dF/dv [N s/m], the Newmark system matrix */
    double *work;     /* scratch */
    uint64_t steps;
    double undo_len1; /* edge 1's rest length before the step's insertion (abort_step) */
} NsRod;

/* Creates a rod through the n points x (n x 3), at rest in that shape: the rest lengths are the
 * edge lengths and the rest curvature is the polygon's, so the rod starts stress-free. d1 (3) is
 * the first reference director of edge 0 (projected normal to the edge; NULL picks one); the
 * other edges get the Bishop frame transported along the rod. held is 2 (sleeve) or 0.
 * Returns 0, or -1 with a message (fewer than 3 nodes, a zero-length edge, a kink of 180
 * degrees, bad material values, memory). */
int ns_rod_init(NsRod *r, const double *x, int n, const double *d1, int held,
                const NsRodParams *params, char *err, int err_sz);
void ns_rod_free(NsRod *r);

/* Sets the rest curvature of interior node i (1 .. n-2) to (k1, k2) [1/m]: at rest the rod
 * there curves towards k1 m1 + k2 m2 (the material directors of the neighbouring edges) with
 * radius 1 / |(k1, k2)|. */
void ns_rod_set_rest_curvature(NsRod *r, int i, double k1, double k2);

/* Derived-quantity helpers. */
double ns_rod_edges_length(const NsRod *r); /* sum of current edge lengths [m] */
double ns_rod_rest_length(const NsRod *r);  /* sum of rest lengths [m] */

/* The material frame of edge j: tangent t, directors m1, m2 (each 3, any may be NULL). */
void ns_rod_material_frame(const NsRod *r, int j, double *t, double *m1, double *m2);
/* The tip frame (§3.5): the material frame of the last edge. m2 is the direction a bevel pushes
 * the tip; bevel_angle is psi. */
void ns_rod_tip_frame(const NsRod *r, double *t, double *m1, double *m2);

/* Energies at positions x ((nodes x 3); NULL = current) with the current twist angles, the
 * reference frames carried by parallel transport from ref_t to the edges of x [J]. Any output
 * may be NULL; returns the total. */
double ns_rod_energy(const NsRod *r, const double *x, double *bend, double *twist, double *stretch);

/* Brings the reference frames to the current edges (parallel transport in time), updates the
 * reference twist and solves the quasi-static twist (theta_0 is held when the rod is held).
 * Called by the step after positions change; call it after editing x by hand. */
void ns_rod_update_frames(NsRod *r, NsRodStats *stats);

/* Forces at the current state into r->force [N] (elastic, twisting, damping, gravity, plus ext
 * (nodes x 3, may be NULL)), and K = dF/dx (bending: Gauss-Newton part, definite; stretching:
 * its transverse part clamped at zero under compression; twisting: left out) and D = dF/dv.
 * Frames must be current (ns_rod_update_frames). */
void ns_rod_forces(NsRod *r, const double *ext);

/* One Newmark step of size dt [s]: applies the controls (sleeve motion, insertion, base twist),
 * assembles and solves (M - beta dt^2 K - gamma dt D) a' = F + K (dt v + dt^2 (1/2-beta) a)
 * + D dt (1-gamma) a (Eq. 4, 6), updates x, v, a, the frames and the twist, and reparameterizes
 * when params.auto_reparam; more Newton iterations follow when the first one visibly stretched
 * an edge (params.newton_max). Returns 0, or -1 when dt is not finite and positive or a control
 * is not finite (nothing changes; stats.nan_count 1), when the solve failed or produced a
 * non-finite value (the state, controls' increments included, is as before the step; stats say
 * why), or when the reparameterization ran out of memory (the step itself has been taken). */
int ns_rod_step(NsRod *r, double dt, const double *ext, NsRodStats *stats);

/* The step in parts, for a caller that solves the rod's system together with something else
 * (the needle-tissue coupling, sim/coupling.h). begin_step refuses a bad dt or control like
 * ns_rod_step (-1, nothing changed), else applies the controls, evaluates the forces and
 * assembles A a' = rhs: sys->anew holds the held nodes' prescribed accelerations and, on free DOFs,
 * the current a (a warm start); DOFs marked in sys->dof_fixed (held nodes and unused slots) keep
 * their anew values. Vectors are sys->n3 = 3 cap long. The caller then either ends the step with
 * its solution (end_step: Newmark update of x and v, frames and twist; no extra Newton iterations,
 * no reparameterization) or aborts it (abort_step: undoes the controls' increments and a). */
typedef struct NsRodSystem {
    const NsBanded *A;
    double *rhs, *anew;
    const uint8_t *dof_fixed;
    int n3;
} NsRodSystem;
int ns_rod_begin_step(NsRod *r, double dt, const double *ext, NsRodSystem *sys, NsRodStats *st);
void ns_rod_end_step(NsRod *r, double dt, const double *anew, NsRodStats *st);
void ns_rod_abort_step(NsRod *r);

/* Static equilibrium under ext (may be NULL) and gravity, held nodes fixed, velocities zeroed:
 * Newton steps with K (with the springs' exact geometric stiffness under compression, shifted
 * Levenberg-Marquardt style where that is not definite) and a backtracking line search on the
 * potential energy; the quasi-static twist is solved at every iterate. Stops when the largest free
 * force is below tol times the largest applied force (or reaction), or after max_iter iterations.
 * Returns the iterations used, or -1 on failure (non-finite values, no descent). */
int ns_rod_static_solve(NsRod *r, const double *ext, double tol, int max_iter, NsRodStats *stats);

/* 1 if the current state is a stable equilibrium configuration under ext and gravity: the exact
 * stiffness (as the static solve's, with the springs' geometric stiffness) is positive definite
 * on the free DOFs; 0 if not (a buckling load has been passed). Overwrites r->force, K and D. */
int ns_rod_is_stable(NsRod *r, const double *ext);

/* 64-bit FNV-1a hash of the node count and the bits of x, v, a, theta and rest_len. */
uint64_t ns_rod_state_hash(const NsRod *r);

/* ---- Reparameterization (§3.4.2), sim/reparam.c ---- */

/* Rebuilds the rod on new nodes: xn (m x 3) are the new positions and s (m) their distances
 * from the base along the old rod (strictly increasing, in the old parameter: old node i sits at
 * the sum of the old edge lengths before it). Rest lengths (through their running sum), twist
 * (the material angle from the space-parallel Bishop frame) and rest curvature are carried by
 * Akima interpolation; velocity and acceleration linearly. Pinned flags follow the old nodes
 * whose parameter the new node shares exactly. The reference frames become the Bishop frame
 * from edge 0 (kept as it was). Returns 0, or -1 on bad input or memory (rod unchanged). */
int ns_rod_resample(NsRod *r, const double *xn, const double *s, int m);

/* Splits free edges (not between two pinned nodes) longer than split_factor x max_rest_edge at the
 * midpoint of an interpolating cubic, and merges edges shorter than merge_factor x min_rest_edge by
 * removing a node that is neither held, pinned nor the tip. Existing nodes keep their positions.
 * Adds the counts into stats (may be NULL). Returns 0, or -1 on memory. */
int ns_rod_reparameterize(NsRod *r, NsRodStats *stats);

#endif
