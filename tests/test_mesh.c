/* Tests for sim/mesh.c: insertion and deletion keep every invariant (checked by walking the
 * whole mesh), free lists reuse indices, the topology hash ignores history, boundary checks. */
#include "mesh.h"
#include "mesh_grid.h"
#include "quality.h"
#include "ns_test.h"

#include <stdint.h>
#include <stdlib.h>

/* An nx*ny*nz grid of cubes (edge h) from sim/mesh_grid.c, with regions in a checkerboard
 * (tet 6 c + p belongs to cube c). */
static void build_grid(NsMesh *m, int nx, int ny, int nz, double h)
{
    const double lo[3] = {0.0, 0.0, 0.0}, hi[3] = {nx * h, ny * h, nz * h};
    char err[256];
    if (ns_mesh_grid_box(m, lo, hi, nx, ny, nz, 0, err, sizeof err))
        return;
    for (int t = 0; t < m->tet_slots; t++) {
        int c = t / 6, i = c % nx, j = (c / nx) % ny, k = c / (nx * ny);
        m->tet_region[t] = (i + j + k) % 2;
    }
}

static int grid_is_valid(void)
{
    NsMesh m;
    build_grid(&m, 3, 2, 2, 0.01);
    char err[256];
    ENSURE(ns_mesh_validate(&m, err, sizeof err) == 0);
    ENSURE(m.tet_alive == 3 * 2 * 2 * 6);
    ENSURE(m.node_alive == 4 * 3 * 3);
    NsBoundaryStats b;
    ENSURE(ns_mesh_boundary(&m, &b) == 0);
    ENSURE(b.closed && b.manifold);
    ENSURE(b.faces == 2 * 2 * (3 * 2 + 2 * 2 + 3 * 2));
    ENSURE(ns_mesh_first_unreferenced_node(&m) < 0);
    double volume = 0.0;
    for (int t = 0; t < m.tet_slots; t++) {
        const int *tn = m.tet_node + 4 * t;
        double v =
            ns_tet_volume(m.u + 3 * tn[0], m.u + 3 * tn[1], m.u + 3 * tn[2], m.u + 3 * tn[3]);
        ENSURE(v > 0.0);
        volume += v;
    }
    ENSURE_SMALL(volume - 3 * 2 * 2 * 1e-6, 1e-18);
    /* Interior nodes of a 3x2x2 grid: (2)(1)(1) = 2 are not on the boundary. */
    int interior = 0;
    for (int i = 0; i < m.node_slots; i++)
        interior += !(m.flags[i] & NS_NODE_BOUNDARY);
    ENSURE(interior == 2);
    NsQualityStats q;
    ns_mesh_quality(&m, false, &q);
    ENSURE(q.inverted == 0 && q.tets == m.tet_alive);
    ns_mesh_free(&m);
    return 0;
}

static int insert_delete_keeps_invariants(void)
{
    NsMesh m;
    build_grid(&m, 3, 3, 3, 0.01);
    char err[256];
    /* Delete a pseudo-random half of the tets, validating after each, then re-insert them. */
    int n = m.tet_slots;
    int *saved = malloc((size_t)n * 5 * sizeof(int));
    int removed = 0;
    uint32_t rng = 12345;
    for (int t = 0; t < n; t++) {
        rng = rng * 1664525u + 1013904223u;
        if ((rng >> 16) & 1) {
            for (int k = 0; k < 4; k++)
                saved[5 * removed + k] = m.tet_node[4 * t + k];
            saved[5 * removed + 4] = m.tet_region[t];
            ns_mesh_remove_tet(&m, t);
            removed++;
            if (ns_mesh_validate(&m, err, sizeof err) != 0) {
                fprintf(stderr, "after removing tet %d: %s\n", t, err);
                return 1;
            }
        }
    }
    ENSURE(removed > n / 4);
    ENSURE(m.tet_alive == n - removed);
    /* Removing a tet twice is a no-op. */
    ENSURE(m.free_tet_count == removed);
    for (int i = removed - 1; i >= 0; i--) {
        ENSURE(ns_mesh_add_tet(&m, saved + 5 * i, saved[5 * i + 4]) >= 0);
        if (ns_mesh_validate(&m, err, sizeof err) != 0) {
            fprintf(stderr, "after re-inserting: %s\n", err);
            return 1;
        }
    }
    ENSURE(m.tet_alive == n && m.free_tet_count == 0);
    NsBoundaryStats b;
    ns_mesh_boundary(&m, &b);
    ENSURE(b.closed && b.manifold);
    free(saved);
    ns_mesh_free(&m);
    return 0;
}

static int hash_ignores_history(void)
{
    NsMesh a, b;
    build_grid(&a, 2, 2, 2, 0.01);
    build_grid(&b, 2, 2, 2, 0.01);
    uint64_t h0 = ns_mesh_topology_hash(&a);
    ENSURE(h0 == ns_mesh_topology_hash(&b));
    /* Delete a node's whole star and the node, then re-insert them: the free lists hand back
     * the same indices, so the mesh and its hash are as before. */
    int node = 13; /* the centre node of a 3x3x3 node grid */
    NsIntList star = a.node_tets[node];
    int cnt = star.count;
    int saved[64][5];
    ENSURE(cnt > 0 && cnt <= 64);
    for (int i = 0; i < cnt; i++) {
        int t = a.node_tets[node].items[0];
        for (int k = 0; k < 4; k++)
            saved[i][k] = a.tet_node[4 * t + k];
        saved[i][4] = a.tet_region[t];
        ns_mesh_remove_tet(&a, t);
    }
    double u[3];
    for (int k = 0; k < 3; k++)
        u[k] = a.u[3 * node + k];
    ENSURE(ns_mesh_remove_node(&a, node) == 0);
    ENSURE(ns_mesh_topology_hash(&a) != h0);
    ENSURE(ns_mesh_add_node(&a, u) == node);
    for (int i = cnt - 1; i >= 0; i--)
        ENSURE(ns_mesh_add_tet(&a, saved[i], saved[i][4]) >= 0);
    char err[256];
    ENSURE(ns_mesh_validate(&a, err, sizeof err) == 0);
    ENSURE(ns_mesh_topology_hash(&a) == h0);
    /* Re-inserting in a different order gives other tet slots but the same hash. */
    ENSURE(a.topology_version > b.topology_version);
    /* A different region changes the hash. */
    int t0 = 0;
    a.tet_region[t0] ^= 1;
    ENSURE(ns_mesh_topology_hash(&a) != h0);
    ns_mesh_free(&a);
    ns_mesh_free(&b);
    return 0;
}

static int node_in_use_cannot_be_removed(void)
{
    NsMesh m;
    build_grid(&m, 1, 1, 1, 1.0);
    ENSURE(ns_mesh_remove_node(&m, 0) == -1);
    int bad[4] = {0, 1, 2, 2};
    ENSURE(ns_mesh_add_tet(&m, bad, 0) == -1);
    int dead[4] = {0, 1, 2, 99};
    ENSURE(ns_mesh_add_tet(&m, dead, 0) == -1);
    char err[128];
    ENSURE(ns_mesh_validate(&m, err, sizeof err) == 0);
    ns_mesh_free(&m);
    return 0;
}

static int boundary_detects_nonmanifold(void)
{
    /* Two tets touching at a single vertex: closed at every edge but not vertex-manifold. */
    NsMesh m;
    ns_mesh_init(&m);
    double p[7][3] = {{0, 0, 0},  {1, 0, 0},  {0, 1, 0}, {0, 0, 1},
                      {-1, 0, 0}, {0, -1, 0}, {0, 0, -1}};
    for (int i = 0; i < 7; i++)
        ns_mesh_add_node(&m, p[i]);
    int t1[4] = {0, 1, 2, 3}, t2[4] = {0, 5, 4, 6};
    ENSURE(ns_mesh_add_tet(&m, t1, 0) >= 0);
    ENSURE(ns_mesh_add_tet(&m, t2, 0) >= 0);
    ENSURE(ns_tet_volume(p[0], p[5], p[4], p[6]) > 0);
    NsBoundaryStats b;
    ns_mesh_boundary(&m, &b);
    ENSURE(b.closed);
    ENSURE(!b.manifold && b.bad_vertex == 0);
    /* Two tets sharing only an edge: edge (0,1) has four boundary faces. */
    NsMesh e;
    ns_mesh_init(&e);
    double q[6][3] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {0, -1, 0}, {0, 0, -1}};
    for (int i = 0; i < 6; i++)
        ns_mesh_add_node(&e, q[i]);
    int s1[4] = {0, 1, 2, 3}, s2[4] = {0, 1, 4, 5};
    ENSURE(ns_tet_volume(q[0], q[1], q[4], q[5]) > 0);
    ns_mesh_add_tet(&e, s1, 0);
    ns_mesh_add_tet(&e, s2, 0);
    ns_mesh_boundary(&e, &b);
    ENSURE(!b.manifold && b.bad_edge[0] == 0 && b.bad_edge[1] == 1);
    /* A lone node is unreferenced. */
    double far[3] = {5, 5, 5};
    int lone = ns_mesh_add_node(&e, far);
    ENSURE(ns_mesh_first_unreferenced_node(&e) == lone);
    ns_mesh_free(&m);
    ns_mesh_free(&e);
    return 0;
}

static int compact_and_copy(void)
{
    NsMesh m, c;
    build_grid(&m, 2, 2, 1, 0.5);
    ns_mesh_remove_tet(&m, 3);
    ns_mesh_remove_tet(&m, 7);
    ENSURE(ns_mesh_copy(&c, &m) == 0);
    ENSURE(ns_mesh_topology_hash(&c) == ns_mesh_topology_hash(&m));
    char err[256];
    ENSURE(ns_mesh_validate(&c, err, sizeof err) == 0);
    int alive = m.tet_alive;
    ENSURE(ns_mesh_compact(&m) == 0);
    ENSURE(ns_mesh_validate(&m, err, sizeof err) == 0);
    ENSURE(m.tet_slots == alive && m.free_tet_count == 0);
    ns_mesh_free(&m);
    ns_mesh_free(&c);
    return 0;
}

NS_TEST_MAIN({"grid_is_valid", grid_is_valid},
             {"insert_delete_keeps_invariants", insert_delete_keeps_invariants},
             {"hash_ignores_history", hash_ignores_history},
             {"node_in_use_cannot_be_removed", node_in_use_cannot_be_removed},
             {"boundary_detects_nonmanifold", boundary_detects_nonmanifold},
             {"compact_and_copy", compact_and_copy})
