/* A planned insertion: the actions (twist, then insert at a duty cycle) and the tip poses
 * between them, with what the planner predicts for it. Shared by the closed-loop controller
 * (steer.h) and the RRT (rrt.h). */
#ifndef NS_PLAN_PATH_H
#define NS_PLAN_PATH_H

#include <stdbool.h>

#include "kinematic.h"

/* One step of a plan: turn the base by `twist`, then insert `length` with the bevel held
 * (duty-cycled at `duty`: curvature kappa (1 - duty)) while the base turns at `rate`. */
typedef struct NsPlanAction {
    double twist;  /* [rad], applied before inserting, in (-pi, pi] */
    double length; /* insertion [m], >= 0 */
    double duty;   /* spinning duty cycle [0, 1] */
    double rate;   /* base twist rate during the insertion [rad/m]; 0 for an arc */
} NsPlanAction;

typedef struct NsPlanPath {
    NsPlanPose *poses;     /* (action_count + 1): poses[i] before action i's twist */
    NsPlanAction *actions; /* (action_count) */
    int action_count, cap;
    double kappa;     /* the curvature the actions were planned with [1/m] */
    double length;    /* sum of the actions' lengths [m] */
    double error;     /* predicted closest approach to the target [m] */
    double clearance; /* least predicted distance to an obstacle [m] (INFINITY: none) */
    bool reached;     /* error within the tolerance asked for */
} NsPlanPath;

/* An empty path starting at pose (false when out of memory). */
bool ns_plan_path_init(NsPlanPath *path, const NsPlanPose *start, double kappa);
/* Appends an action and the pose it ends at, computed with the path's kappa; false when out of
 * memory or an argument is out of range (path unchanged). */
bool ns_plan_path_push(NsPlanPath *path, const NsPlanAction *a);
void ns_plan_path_free(NsPlanPath *path);

/* The pose after following the action from `from`, with curvature kappa [1/m]. */
bool ns_plan_action_apply(const NsPlanPose *from, const NsPlanAction *a, double kappa,
                          NsPlanPose *to);

/* Tip positions along the path every `step` [m] or closer (both ends included): *xyz gets
 * (count x 3) doubles the caller frees. Returns count, or -1 when out of memory or step <= 0. */
int ns_plan_path_points(const NsPlanPath *path, double step, double **xyz);

#endif
