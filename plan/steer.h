/* Closed-loop steering in the manner of Hauser, Alterovitz, Chentanez, Okamura, Goldberg,
 * "Feedback control for steering needles through 3D deformable tissue using helical paths"
 * (RSS 2009): at every replanning step read the tip pose and where the target is now, predict
 * the path of each candidate action with the kinematic model (kinematic.h), apply the one whose
 * predicted path passes closest to the target, insert a little, repeat.
 *
 * Candidates: `angle_count` twist angles evenly around the tangent, plus the angle that puts the
 * target in the bevel's plane; for each, the duty cycle whose effective arc passes through the
 * target's projection on that plane (clamped to [0, 1]); plus optional helices (twist rates,
 * no duty cycling). Ties go to the smaller twist. */
#ifndef NS_PLAN_STEER_H
#define NS_PLAN_STEER_H

#include <stdbool.h>

#include "kinematic.h"
#include "path.h"

typedef struct NsSteerParams {
    double kappa;        /* the model's curvature [1/m], > 0 */
    int angle_count;     /* twist angles around the tangent, 1..4096 (default 32) */
    bool exact_angle;    /* also the angle that puts the target in the bevel plane (default) */
    bool duty_cycle;     /* choose a duty cycle per angle; else always 0 (default true) */
    const double *rates; /* helix candidates' twist rates [rad/m] (may be NULL) */
    int rate_count;      /* 0..256 */
    double horizon;      /* predicted length [m]; <= 0: 1.5 x the distance to the target */
} NsSteerParams;

NsSteerParams ns_steer_default(double kappa);

typedef struct NsSteerAction {
    double twist; /* turn the base by this now [rad], in (-pi, pi] */
    double duty;  /* duty cycle for the next insertion [0, 1] */
    double rate;  /* twist rate for the next insertion [rad/m] (helix candidates; else 0) */
    double miss;  /* the predicted closest approach to the target [m] */
    double at;    /* insertion length at which it happens [m] */
} NsSteerAction;

/* Chooses the action for a tip at `tip` and a target at `target`. Returns 0, or -1 with a
 * message for bad parameters or a non-finite input. */
int ns_steer_choose(const NsSteerParams *prm, const NsPlanPose *tip, const double target[3],
                    NsSteerAction *out, char *err, int err_sz);

/* Where the target is after `inserted` metres of insertion (the tissue carries it). */
typedef void (*NsSteerTargetFn)(void *user, double inserted, double out[3]);

typedef struct NsSteerLoop {
    double replan_every;  /* insertion between two replans [m], > 0 */
    double max_length;    /* give up after this much insertion [m], > 0 */
    double kappa_true;    /* the curvature the "true" needle follows [1/m] (>= 0) */
    const double *target; /* the target, when target_fn is NULL */
    NsSteerTargetFn target_fn;
    void *user;
    /* Estimate the curvature from the tip's observed turning (our addition to Hauser 2009):
     * after each arc, kappa_hat = (sum of the tangent's turning angles) / (sum of (1 - duty)
     * x length), clamped to [0.1, 10] x prm->kappa, predicts the next choice. */
    bool adapt;
} NsSteerLoop;

/* Runs the closed loop on the kinematic model: the needle follows kappa_true while the
 * controller predicts with prm->kappa. path (initialised here, with kappa = kappa_true) gets one
 * action per replan; path->error is the least distance from the tip's path to the target (as it
 * is at the end of each segment). With loop->adapt the controller's curvature is re-estimated
 * after every arc. Stops when the target is behind the tip or after max_length.
 * Returns 0, or -1 with a message (path then freed). */
int ns_steer_rollout(const NsSteerParams *prm, const NsSteerLoop *loop, const NsPlanPose *start,
                     NsPlanPath *path, char *err, int err_sz);

#endif
