/* Torsional friction between the needle's shaft and the tissue: a stick/slip torque on the twist
 * of every edge inside the tissue (the paper's §5 lists torsional friction as future work; the
 * model follows Reed, Okamura and Cowan 2009, "Modeling and control of needles with torsional
 * friction", IEEE TBME 56(12):2905-2916: Coulomb friction distributed along the inserted shaft).
 *
 * Edge j's material angle theta_j (relative to its reference frame, which is carried by parallel
 * transport in time and so has no spin about the tangent, Bergou et al. 2010 §4.2) is held by a
 * friction torque of at most c_j [N m]: it keeps the angle it had at the start of the step
 * (theta_anchor_j, stick) unless the elastic torque on it exceeds c_j, and then it turns with a
 * torque of exactly c_j against its turn (slip). The quasi-static twist (rod.c) minimises the
 * incremental potential
 *     E_twist+bend(theta) - tip_torque theta_last + sum_j c_j |theta_j - theta_anchor_j|,
 * convex where E is, whose optimality conditions are exactly stick (|torque| <= c_j) or slip
 * (torque c_j against the turn).
 *
 * The bound per unit length inside the tissue is tau_f = f_perlen r_o: the sliding friction per
 * unit length f_perlen (sim/coupling.h) is the integral of the shear traction the tissue can hold
 * around the shaft's circumference; the same traction acting tangentially around a shaft of outer
 * radius r_o gives at most f_perlen r_o of torque per unit length. The coupling sets the bounds
 * per edge (coupled_twist_bounds, sim/coupled_assemble.c); the rod solves the twist with them
 * (sim/rod.c). */
#ifndef NS_TWIST_FRICTION_H
#define NS_TWIST_FRICTION_H

/* Work doubles ns_twist_friction_step needs for ne edges. */
#define NS_TWIST_FRICTION_WORK(ne) (6 * (size_t)(ne))

/* One Newton step of the twist with friction: minimises, over dx with dx_j = 0 for j < first,
 *     1/2 dx^T H dx + g^T dx + sum_j bound_j |theta_j + dx_j - anchor_j|
 * for the tridiagonal H (diagonal hd (ne), off-diagonal ho (ne - 1): H_{j,j+1} = ho_j) by a
 * primal-dual active set (each edge with a bound either sticks at its anchor or slips with a
 * constant torque of bound_j; Hintermueller, Ito and Kunisch 2002, SIAM J. Optim. 13(3)), exact
 * when the sets stop changing. Where the sets cycle (H not an M-matrix: a bent rod's
 * bending-twist terms), cyclic coordinate descent (converging for any definite H) gives the sets
 * to start again from, or, if those do not settle either, its own answer. Returns the work done
 * (>= 1), or -1 if H is not definite. */
int ns_twist_friction_step(int ne, int first, const double *hd, const double *ho, const double *g,
                           const double *theta, const double *anchor, const double *bound,
                           double *dx, double *work);

/* sum_j bound_j |theta_j - anchor_j| over the ne edges [J]. */
double ns_twist_friction_energy(int ne, const double *theta, const double *anchor,
                                const double *bound);

#endif
