/* Tests for sim/tissue.c on small meshes from the mesher: free vibration conserves energy under
 * the trapezoidal rule; after remeshing, the rows of K and D gathered again only where nodes'
 * tets changed equal a full gather, bit for bit; the rows of A the system build keeps equal
 * what it would write. The patch test and the other cases with analytic
 * answers are in `needlesim validate` (engine/validate_fem.c, docs/validation.md, run by
 * tests/test_validate.sh); determinism across thread counts is in test_threads.c. */
#include "mesher.h"
#include "remesh.h"
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

/* Every block of K and D, in row order: (row, column, 9 values) each. */
static double *snapshot(const NsTissue *t, int *count)
{
    int n = 0;
    for (int i = 0; i < t->K.n; i++)
        n += t->K.rows[i].count + t->D.rows[i].count;
    double *v = malloc((size_t)(n > 0 ? n : 1) * 11 * sizeof(double)), *p = v;
    for (int w = 0; v && w < 2; w++) {
        const NsBlockMatrix *B = w ? &t->D : &t->K;
        for (int i = 0; i < B->n; i++)
            for (int q = 0; q < B->rows[i].count; q++) {
                *p++ = i;
                *p++ = B->rows[i].col[q];
                memcpy(p, B->rows[i].val + 9 * q, 9 * sizeof(double));
                p += 9;
            }
    }
    *count = n;
    return v;
}

/* K and D of t equal those of a full gather of the same element matrices (bitwise). */
static int rows_match_full_gather(NsTissue *t)
{
    int na, nb;
    double *a = snapshot(t, &na);
    t->kd_valid = 0; /* every row gathered again, from the same element matrices */
    ns_tissue_forces(t, 0, NULL);
    double *b = snapshot(t, &nb);
    int same = a && b && na == nb && memcmp(a, b, (size_t)na * 11 * sizeof(double)) == 0;
    free(a);
    free(b);
    ENSURE(same);
    return 0;
}

/* The work partition lists every node slot and every alive tet exactly once. */
static int partition_covers(const NsTissue *t)
{
    const NsMesh *M = &t->mesh;
    int parts = t->part_count;
    ENSURE(parts >= 1);
    ENSURE(t->part_node_start[parts] == M->node_slots);
    int alive = 0;
    for (int e = 0; e < M->tet_slots; e++)
        alive += ns_mesh_tet_alive(M, e);
    ENSURE(t->part_tet_start[parts] == alive);
    char *seen = calloc((size_t)(M->node_slots + M->tet_slots) + 1, 1);
    ENSURE(seen != NULL);
    for (int k = 0; k < M->node_slots; k++)
        ENSURE(seen[t->part_nodes[k]]++ == 0);
    for (int k = 0; k < alive; k++) {
        ENSURE(ns_mesh_tet_alive(M, t->part_tets[k]));
        ENSURE(seen[M->node_slots + t->part_tets[k]]++ == 0);
    }
    free(seen);
    return 0;
}

/* A corotational sphere (8 mm spacing) with the given threads and lazy threshold. */
static int sphere_tissue(NsMesh *m, NsTissue *t, int threads, double lazy_threshold)
{
    ENSURE(make_mesh(m, 0.008) == 0);
    NsTissueMaterial mat = {ns_fem_material(NS_MODEL_COROTATIONAL, 20e3, 0.3, 3, 3), 1000.0};
    NsTissueParams p = ns_default_tissue_params();
    p.lazy_threshold = lazy_threshold;
    p.threads = threads;
    char err[256];
    ENSURE(ns_tissue_init(t, m, &mat, 1, &p, err, sizeof err) == 0);
    return 0;
}

static int remesh_rows_gathered_with(int threads)
{
    NsMesh m;
    NsTissue t;
    char err[256];
    /* no Jacobian rebuilt but the changed tets' */
    ENSURE(sphere_tissue(&m, &t, threads, 1e9) == 0);
    for (int i = 0; i < t.mesh.node_slots; i++)
        t.mesh.x[3 * i] *= 1.01; /* stretched, so that the blocks are not the rest ones */
    ns_tissue_forces(&t, 0, NULL);
    /* An interior edge split at its midpoint, then undone: the new node's row loses every tet
     * without any tet of its own being rebuilt. */
    NsMesh *M = &t.mesh;
    int e = -1;
    for (int k = 0; k < M->tet_slots && e < 0; k++)
        if (ns_mesh_tet_alive(M, k) && M->tet_adj[4 * k] >= 0 && M->tet_adj[4 * k + 1] >= 0 &&
            M->tet_adj[4 * k + 2] >= 0 && M->tet_adj[4 * k + 3] >= 0)
            e = k;
    ENSURE(e >= 0);
    int edge[2] = {M->tet_node[4 * e], M->tet_node[4 * e + 1]};
    double u[3];
    for (int c = 0; c < 3; c++)
        u[c] = 0.5 * (M->u[3 * edge[0] + c] + M->u[3 * edge[1] + c]);
    NsRemeshStack s;
    ns_remesh_stack_init(&s);
    int node = ns_remesh_split(M, &s, edge, 2, u);
    ENSURE(node >= 0);
    ENSURE(ns_tissue_sync_topology(&t, err, sizeof err) == 0);
    ns_tissue_forces(&t, 0, NULL);
    ENSURE(rows_match_full_gather(&t) == 0);
    /* With parts, the split's partition was the last one patched (the new node placed among
     * its neighbours' parts), not METIS's again. */
    ENSURE(partition_covers(&t) == 0);
    if (t.part_count > 1)
        ENSURE(t.part_metis_age == 1);
    ENSURE(ns_remesh_undo(M, &s) == 0);
    ENSURE(ns_tissue_sync_topology(&t, err, sizeof err) == 0);
    ns_tissue_forces(&t, 0, NULL);
    ENSURE(rows_match_full_gather(&t) == 0);
    /* A tet removed and added again on the same nodes: its slot and rest data are the same, so
     * its Jacobian is kept, but its nodes' lists of tets are in another order (the sum too). */
    int tn[4] = {M->tet_node[4 * e], M->tet_node[4 * e + 1], M->tet_node[4 * e + 2],
                 M->tet_node[4 * e + 3]},
        region = M->tet_region[e];
    ns_mesh_remove_tet(M, e);
    ENSURE(ns_mesh_add_tet(M, tn, region) == e);
    ENSURE(ns_tissue_sync_topology(&t, err, sizeof err) == 0);
    ns_tissue_forces(&t, 0, NULL);
    ENSURE(rows_match_full_gather(&t) == 0);
    ENSURE(partition_covers(&t) == 0);
    ns_remesh_stack_free(&s);
    ns_tissue_free(&t);
    ns_mesh_free(&m);
    return 0;
}

static int remesh_rows_gathered(void)
{
    ENSURE(remesh_rows_gathered_with(1) == 0);
    ENSURE(remesh_rows_gathered_with(2) == 0); /* the partitioned (OpenMP) path */
    return 0;
}

/* 0 if every block of A on K's pattern is what the system build writes, M - c1 K - c2 D, bit
 * for bit (the rows it kept from the last build included). */
static int system_matches(const NsTissue *t, double c1, double c2)
{
    for (int i = 0; i < t->K.n; i++) {
        const NsBlockRow *kr = &t->K.rows[i];
        for (int p = 0; p < kr->count; p++) {
            int j = kr->col[p];
            const double *kb = kr->val + 9 * p, *db = ns_bsm_find(&t->D, i, j);
            const double *ab = ns_bsm_find(&t->A, i, j);
            ENSURE(ab != NULL);
            double want[9];
            for (int q = 0; q < 9; q++)
                want[q] = -c1 * kb[q] - c2 * (db ? db[q] : 0.0);
            if (i == j)
                for (int c = 0; c < 3; c++)
                    want[4 * c] += t->mass[i] > 0.0 ? t->mass[i] : 1.0;
            ENSURE(ns_same_bits(ab, want, 9));
        }
    }
    return 0;
}

/* The system build writes only the rows of A that change (docs/solvers.md): after steps in
 * which a part of the tissue turns (some Jacobians rebuilt, most kept), a row written by
 * someone else, a node moved in material space (its tets' rest data and its mass change) and a
 * new time step, A is still what writing every row gives. */
static int system_rows_kept_with(int threads)
{
    NsMesh m;
    NsTissue t;
    char err[256];
    ENSURE(sphere_tissue(&m, &t, threads, ns_default_tissue_params().lazy_threshold) == 0);
    NsMesh *M = &t.mesh;
    double dt = 1e-3, beta = t.params.beta, gamma = t.params.gamma;
    int n3 = 3 * M->node_slots, kept = 0;
    double *anew = calloc((size_t)n3, sizeof *anew);
    ENSURE(anew != NULL);
    for (int step = 0; step < 8; step++) {
        /* the nodes with x > 0 turned about z by a further 2 degrees */
        double c = cos(0.035), sn = sin(0.035);
        for (int i = 0; i < M->node_slots; i++)
            if (M->u[3 * i] > 0.0) {
                double *x = M->x + 3 * i, x0 = x[0], x1 = x[1];
                x[0] = c * x0 - sn * x1;
                x[1] = sn * x0 + c * x1;
            }
        if (step == 3) { /* someone else writes to a row the build would keep, and says so */
            int i = 0;
            while (i < M->node_slots && !(ns_mesh_node_alive(M, i) && M->u[3 * i] < -0.01))
                i++;
            ENSURE(i < M->node_slots && t.a_valid[i]);
            double *d = ns_bsm_get(&t.A, i, i);
            ENSURE(d != NULL);
            d[0] += 1.0;
            ns_tissue_a_row_touched(&t, i);
        }
        if (step == 5) { /* a node moved in material space */
            int i = M->tet_node[0];
            M->u[3 * i] += 1e-4;
            ENSURE(ns_tissue_sync_topology(&t, err, sizeof err) == 0);
        }
        if (step == 6)
            dt = 2e-3;
        for (int i = 0; i < t.K.n; i++)
            kept += t.a_valid[i];
        ENSURE(ns_tissue_begin_step(&t, dt, NULL, NULL) != NULL);
        ENSURE(system_matches(&t, beta * dt * dt, gamma * dt) == 0);
        ns_tissue_end_step(&t, dt, anew);
    }
    ENSURE(kept > 0); /* rows were kept, or this tested nothing */
    free(anew);
    ns_tissue_free(&t);
    ns_mesh_free(&m);
    return 0;
}

static int system_rows_kept(void)
{
    ENSURE(system_rows_kept_with(1) == 0);
    ENSURE(system_rows_kept_with(2) == 0);
    return 0;
}

NS_TEST_MAIN({"vibration_conserves_energy", vibration_conserves_energy},
             {"remesh_rows_gathered", remesh_rows_gathered}, {"system_rows_kept", system_rows_kept})
