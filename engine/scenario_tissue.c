/* From a loaded scenario to the simulation's tissue (sim/tissue.h): the one place where the
 * scenario's material records become FEM materials. */
#include <stdio.h>
#include <stdlib.h>

#include "scenario.h"
#include "tissue.h"

int ns_scenario_tissue(const NsScenario *sc, const NsTissueParams *params, NsTissue *t, char *err,
                       int err_sz)
{
    if (sc->region_count < 1) {
        snprintf(err, (size_t)err_sz, "%s: the scenario's tissue has no regions", sc->path);
        return -1;
    }
    NsTissueMaterial *mats = calloc((size_t)sc->region_count, sizeof *mats);
    if (!mats) {
        snprintf(err, (size_t)err_sz, "out of memory");
        return -1;
    }
    for (int r = 0; r < sc->region_count; r++) {
        const NsMaterial *m = &sc->regions[r].material;
        mats[r].fem = ns_fem_material(m->model, m->youngs, m->poisson, m->damping, 0.0);
        mats[r].density = m->density;
    }
    int rc = ns_tissue_init(t, &sc->mesh, mats, sc->region_count, params, err, err_sz);
    free(mats);
    return rc;
}
