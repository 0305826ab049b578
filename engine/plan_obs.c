/* The scenario's obstacles for the planners: see plan_obs.h. */
#include "plan_obs.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "shape.h"

/* The bounding box of region r's tets, or of the whole mesh for r < 0 [m]. */
bool ns_plan_mesh_box(const NsMesh *m, int r, double lo[3], double hi[3])
{
    bool any = false;
    for (int k = 0; k < 3; k++) {
        lo[k] = INFINITY;
        hi[k] = -INFINITY;
    }
    for (int t = 0; t < m->tet_slots; t++) {
        if (!ns_mesh_tet_alive(m, t) || (r >= 0 && m->tet_region[t] != r))
            continue;
        for (int c = 0; c < 4; c++) {
            const double *x = &m->x[3 * m->tet_node[4 * t + c]];
            for (int k = 0; k < 3; k++) {
                lo[k] = fmin(lo[k], x[k]);
                hi[k] = fmax(hi[k], x[k]);
            }
        }
        any = true;
    }
    return any;
}

void ns_plan_obs_free(NsPlanObs *po)
{
    for (int i = 0; i < po->count; i++)
        if (po->shapes && po->shapes[i])
            ns_shape_release(po->shapes[i]);
    free(po->shapes);
    free(po->obs);
    memset(po, 0, sizeof *po);
}

/* The scenario's obstacles: each region's shape as written, else its tets' bounding box. */
int ns_plan_obs_make(const NsScenario *sc, const NsRunSpec *spec, NsPlanObs *po, char *err,
                     int err_sz)
{
    memset(po, 0, sizeof *po);
    int n = spec->obstacle_count;
    po->obs = calloc((size_t)(n > 0 ? n : 1), sizeof *po->obs);
    po->shapes = calloc((size_t)(n > 0 ? n : 1), sizeof *po->shapes);
    if (!po->obs || !po->shapes) {
        ns_plan_obs_free(po);
        snprintf(err, (size_t)err_sz, "needlesim: obstacles: out of memory");
        return -1;
    }
    for (int i = 0; i < n; i++) {
        int r = spec->obstacles[i].region;
        char why[512];
        NsShape *s = ns_scenario_region_shape(sc, r, why, sizeof why);
        NsPlanObstacle *o = &po->obs[i];
        if (s) {
            po->shapes[i] = s;
            memset(o, 0, sizeof *o);
            o->kind = NS_PLAN_SHAPE;
            o->shape = s;
        } else {
            double lo[3], hi[3];
            if (!ns_plan_mesh_box(&sc->mesh, r, lo, hi)) {
                snprintf(err, (size_t)err_sz, "%s: obstacle '%s': its region has no tets", sc->path,
                         spec->obstacles[i].name);
                ns_plan_obs_free(po);
                return -1;
            }
            *o = ns_plan_box(lo, hi);
        }
        o->name = spec->obstacles[i].name;
        po->count = i + 1;
    }
    return 0;
}

double ns_plan_model_kappa(const NsRunSpec *spec)
{
    return spec->arc_curvature * tan(spec->bevel_deg * M_PI / 180.0);
}
