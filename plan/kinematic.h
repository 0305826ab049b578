/* The bevel-tip needle as a unicycle in SE(3) (Webster, Kim, Cowan, Chirikjian, Okamura,
 * "Nonholonomic modeling of needle steering", IJRR 2006): the tip frame advances along its
 * tangent t and turns at curvature kappa towards the bevel direction m2; a twist of the base
 * turns the frame about t. With the twist rate tau [rad/m] held over an insertion the body
 * velocity is constant, so the tip moves on a screw (a helix; an arc when tau = 0) given in
 * closed form by the exponential of SE(3): no Euler steps.
 *
 * Duty-cycled spinning (Minhas et al. 2007; Engh et al. 2010) spins the needle during a fraction
 * `duty` of the insertion and holds it the rest; averaged over a cycle the tip follows an arc of
 * effective curvature kappa (1 - duty) towards the held bevel direction.
 *
 * The frame is right-handed (m1, m2, t) with m1 = m2 x t. SI units: metres, radians. */
#ifndef NS_PLAN_KINEMATIC_H
#define NS_PLAN_KINEMATIC_H

#include <stdbool.h>

typedef struct NsPlanPose {
    double p[3];  /* tip position [m] */
    double t[3];  /* unit tangent: the direction of insertion */
    double m2[3]; /* unit bevel direction (normal to t): where the tip curves */
} NsPlanPose;

/* A pose at p heading along dir with the bevel towards the part of `toward` normal to dir
 * (any normal when toward is NULL or parallel to dir). Returns false for a zero or non-finite
 * dir or p (out untouched). */
bool ns_plan_pose_make(const double p[3], const double dir[3], const double toward[3],
                       NsPlanPose *out);
/* m1 = m2 x t. */
void ns_plan_pose_m1(const NsPlanPose *pose, double m1[3]);

/* Turns the bevel about the tangent by angle [rad] (right hand about t: m1 towards m2). */
void ns_plan_twist(NsPlanPose *pose, double angle);

/* The effective curvature of duty-cycled spinning [1/m]: kappa (1 - duty), duty in [0, 1]. */
double ns_plan_kappa_eff(double kappa, double duty);

/* Inserts the tip by s [m] (s >= 0) with curvature kappa [1/m] (>= 0) towards m2 while the
 * base turns at tau [rad/m] (rad per metre inserted): the exact screw motion. Returns false
 * for a negative or non-finite argument (out untouched). in and out may be the same. */
bool ns_plan_advance(const NsPlanPose *in, double kappa, double tau, double s, NsPlanPose *out);

/* The closed forms of the helix ns_plan_advance follows (curvature kappa, torsion tau):
 * radius kappa / (kappa^2 + tau^2) [m], pitch 2 pi tau / (kappa^2 + tau^2) [m per turn], and
 * the unit axis in world coordinates with a point on it. A straight line (kappa = 0) has
 * radius 0 and axis t. */
typedef struct NsPlanHelix {
    double radius, pitch; /* [m] */
    double axis[3];       /* unit */
    double point[3];      /* on the axis [m] */
} NsPlanHelix;
void ns_plan_helix(const NsPlanPose *pose, double kappa, double tau, NsPlanHelix *h);

/* The closest approach of the path ns_plan_advance(pose, kappa, tau, s) for s in [0, length]
 * to point q: the distance [m], and the arc length where it happens in *at (may be NULL).
 * Sampled every `step` [m] (<= 0: length / 64) and refined by golden section. */
double ns_plan_closest(const NsPlanPose *pose, double kappa, double tau, double length, double step,
                       const double q[3], double *at);

#endif
