/* The scenario's obstacles as the planners' signed distances (plan/obstacle.h): each obstacle
 * region's shape as written in an ns.tissue.shapes scenario, else the bounding box of its tets.
 * Shared by `needlesim plan`, a run's act.steer / ns.plan (engine/run_steer.c) and
 * `needlesim bench --planning`. */
#ifndef NS_PLAN_OBS_H
#define NS_PLAN_OBS_H

#include <stdbool.h>

#include "mesh.h"
#include "obstacle.h"
#include "run_spec.h"
#include "scenario.h"

typedef struct NsPlanObs {
    NsPlanObstacle *obs;     /* (count), one per spec obstacle, in its order */
    struct NsShape **shapes; /* (count), NULL where the bounding box stands in */
    int count;
} NsPlanObs;

/* The bounding box of region r's tets, or of the whole mesh for r < 0 [m]; false: no tets. */
bool ns_plan_mesh_box(const NsMesh *m, int r, double lo[3], double hi[3]);
/* Builds po from the scenario's obstacles; 0, or -1 with a message (po then empty). Calls
 * into the scenario's Lua state: not from inside another of its protected calls. */
int ns_plan_obs_make(const NsScenario *sc, const NsRunSpec *spec, NsPlanObs *po, char *err,
                     int err_sz);
void ns_plan_obs_free(NsPlanObs *po);
/* The arc model's curvature k_c tan(psi) [1/m] (docs/needle.md) the planners assume. */
double ns_plan_model_kappa(const NsRunSpec *spec);

#endif
