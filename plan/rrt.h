/* A rapidly-exploring random tree over constant-curvature arcs (after Patil, Burgner, Webster,
 * Alterovitz, "Needle steering in 3-D via rapid replanning", IEEE T-RO 2014): each extension
 * turns the bevel so that the sample lies in its plane and inserts along the arc through it,
 * duty-cycled to the curvature that reaches it (kappa (1 - duty) <= kappa), at most `step`
 * long. An arc is kept only if every point checked along it (every check_step or closer) stays
 * clearance + h / 2 or more from every obstacle, h the spacing of the checks, and inside the
 * workspace: with exact signed distances the whole arc then keeps the clearance. After each new
 * node the planner tries the arc from it to the target; the first such arc that is clear ends the
 * search.
 *
 * Deterministic: its own PRNG (rng.h) seeded by params.seed, fixed iteration order. */
#ifndef NS_PLAN_RRT_H
#define NS_PLAN_RRT_H

#include <stdbool.h>
#include <stdint.h>

#include "kinematic.h"
#include "obstacle.h"
#include "path.h"

typedef struct NsRrtParams {
    double kappa;        /* the needle's curvature with the bevel held [1/m], > 0 */
    double clearance;    /* least distance from the needle's axis to an obstacle [m], >= 0 */
    double tolerance;    /* the target counts as reached within this [m], > 0 */
    double step;         /* longest arc of one extension [m] (default 5 mm) */
    double check_step;   /* spacing of the clearance checks along an arc [m] (default 0.25 mm) */
    double lo[3], hi[3]; /* workspace: samples and the path stay inside [m] */
    double max_length;   /* longest insertion [m]; <= 0: no limit */
    double goal_bias;    /* probability of sampling the target, [0, 1] (default 0.1) */
    int max_nodes;       /* tree size limit, 2..1000000 (default 20000) */
    int max_iterations;  /* samples drawn, >= 1 (default 100000) */
    uint64_t seed;
} NsRrtParams;

/* Defaults for a needle of curvature kappa in the box lo..hi. */
NsRrtParams ns_rrt_default(double kappa, const double lo[3], const double hi[3]);

typedef struct NsRrtStats {
    int nodes, iterations;
    int rejected; /* extensions refused by the clearance, the workspace or max_length */
} NsRrtStats;

/* Plans from start to target around the obstacles. Returns 0 with the path (path->error: the
 * end's distance to the target, path->clearance: the least checked distance to an obstacle);
 * 1 when no path was found within the limits (path freed, err says why); -1 for bad input
 * (err says which). stats may be NULL. */
int ns_rrt_plan(const NsRrtParams *prm, const NsPlanObstacle *obs, int obstacle_count,
                const NsPlanPose *start, const double target[3], NsPlanPath *path,
                NsRrtStats *stats, char *err, int err_sz);

/* The least distance to the obstacles along the path, checked every `step` [m] (INFINITY when
 * there are none; NAN when out of memory). */
double ns_plan_path_clearance(const NsPlanPath *path, const NsPlanObstacle *obs, int count,
                              double step);

#endif
