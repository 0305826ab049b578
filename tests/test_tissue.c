/* Tests for sim/tissue.c on small meshes from the mesher: free vibration conserves energy under
 * the trapezoidal rule. The patch test and the other cases with analytic answers are in
 * `needlesim validate` (engine/validate_fem.c, docs/validation.md, run by tests/test_validate.sh);
 * determinism across thread counts is in test_threads.c. */
#include "mesher.h"
#include "tissue.h"
#include "ns_test.h"

#include <stdlib.h>
#include <string.h>

static int make_mesh(NsMesh *m, double h)
{
    double c[3] = {0.0, 0.0, 0.0};
    NsShape *s = ns_shape_sphere(c, 0.02);
    NsMesherRegion r = {s, false};
    NsMesherDef d = ns_default_mesher_def();
    d.spacing = h;
    d.regions = &r;
    d.region_count = 1;
    ns_mesh_init(m);
    char err[256];
    int rc = ns_mesher_stuff(&d, m, NULL, err, sizeof err);
    ns_shape_release(s);
    return rc;
}

static int vibration_conserves_energy(void)
{
    NsMesh m;
    ENSURE(make_mesh(&m, 0.008) == 0);
    NsTissueMaterial mat = {ns_fem_material(NS_MODEL_COROTATIONAL, 20e3, 0.3, 0, 0), 1000.0};
    NsTissueParams p = ns_default_tissue_params();
    p.lazy_threshold = 0.0;
    p.solve_tol = 1e-12;
    NsTissue t;
    char err[256];
    ENSURE(ns_tissue_init(&t, &m, &mat, 1, &p, err, sizeof err) == 0);
    /* A small initial stretch, released from rest. */
    for (int i = 0; i < m.node_slots; i++)
        t.mesh.x[3 * i] *= 1.01;
    NsSolver *s = ns_solver_create(NS_SOLVER_DIRECT);
    double e0 = ns_tissue_energy(&t), emax = 0.0;
    NsTissueStats st;
    for (int k = 0; k < 300; k++) {
        ENSURE(ns_tissue_step(&t, s, 1e-3, NULL, &st) == 0);
        double de = fabs(ns_tissue_energy(&t) - e0) / e0;
        emax = de > emax ? de : emax;
    }
    printf("  max relative energy drift over 300 steps: %.3e\n", emax);
    ENSURE(emax < 0.01);
    ns_solver_destroy(s);
    ns_tissue_free(&t);
    ns_mesh_free(&m);
    return 0;
}

NS_TEST_MAIN({"vibration_conserves_energy", vibration_conserves_energy})
