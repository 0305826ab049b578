/* Tests for sim/quality.c: the quality measure and dihedral angles on tets with known answers;
 * the one-acos minimum against the six angles; sim/quality_watch.c against full scans. */
#include <string.h>

#include "quality.h"
#include "mesh_grid.h"
#include "quality_watch.h"
#include "remesh.h"
#include "ns_test.h"

static int regular_tet(void)
{
    double p[4][3] = {{1, 1, 1}, {-1, 1, -1}, {1, -1, -1}, {-1, -1, 1}};
    ENSURE_SMALL(ns_tet_quality(p[0], p[1], p[2], p[3]) - 1.0, 1e-12);
    double ang[6];
    double mn = ns_tet_dihedrals(p[0], p[1], p[2], p[3], ang);
    double want = acos(1.0 / 3.0) * 180.0 / M_PI; /* 70.5288 degrees */
    for (int i = 0; i < 6; i++)
        ENSURE_SMALL(ang[i] - want, 1e-9);
    ENSURE_SMALL(mn - want, 1e-9);
    /* Swapping two vertices inverts it: negative quality, same angles. */
    ENSURE_SMALL(ns_tet_quality(p[1], p[0], p[2], p[3]) + 1.0, 1e-12);
    return 0;
}

static int corner_tet(void)
{
    /* The corner tet of a unit cube: right dihedral angles at the three edges through the
     * origin; the three edges of the slanted face x+y+z=1 have acos(1/sqrt 3) = 54.7356. */
    double p[4][3] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    double ang[6];
    ns_tet_dihedrals(p[0], p[1], p[2], p[3], ang);
    double slant = acos(1.0 / sqrt(3.0)) * 180.0 / M_PI;
    /* edges 01, 02, 03 meet at the origin: 90 degrees */
    ENSURE_SMALL(ang[0] - 90.0, 1e-9);
    ENSURE_SMALL(ang[1] - 90.0, 1e-9);
    ENSURE_SMALL(ang[2] - 90.0, 1e-9);
    ENSURE_SMALL(ang[3] - slant, 1e-9);
    ENSURE_SMALL(ang[4] - slant, 1e-9);
    ENSURE_SMALL(ang[5] - slant, 1e-9);
    ENSURE_SMALL(ns_tet_volume(p[0], p[1], p[2], p[3]) - 1.0 / 6.0, 1e-15);
    return 0;
}

static int flat_tet(void)
{
    double p[4][3] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}};
    ENSURE_SMALL(ns_tet_quality(p[0], p[1], p[2], p[3]), 1e-15);
    double ang[6];
    double mn = ns_tet_dihedrals(p[0], p[1], p[2], p[3], ang);
    ENSURE_SMALL(mn, 1e-6);
    double coinc[4][3] = {{0, 0, 0}, {0, 0, 0}, {0, 1, 0}, {1, 1, 1}};
    ENSURE(ns_tet_dihedrals(coinc[0], coinc[1], coinc[2], coinc[3], NULL) == 0.0);
    return 0;
}

static int mesh_stats(void)
{
    NsMesh m;
    ns_mesh_init(&m);
    double p[5][3] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 1, 1}};
    for (int i = 0; i < 5; i++)
        ns_mesh_add_node(&m, p[i]);
    int a[4] = {0, 1, 2, 3}, b[4] = {2, 1, 3, 4};
    ns_mesh_add_tet(&m, a, 0);
    ENSURE(ns_tet_volume(p[2], p[1], p[3], p[4]) < 0); /* inverted on purpose */
    ns_mesh_add_tet(&m, b, 1);
    NsQualityStats s;
    ns_mesh_quality(&m, false, &s);
    ENSURE(s.tets == 2 && s.inverted == 1 && s.worst_tet == 1 && s.min_quality < 0);
    ENSURE_SMALL(s.max_dihedral_deg - 90.0, 1e-9);
    /* World coordinates are used when asked: flip the second tet by moving node 4. */
    m.x[3 * 4 + 0] = m.x[3 * 4 + 1] = m.x[3 * 4 + 2] = -1.0;
    ns_mesh_quality(&m, true, &s);
    ENSURE(s.inverted == 0);
    ns_mesh_free(&m);
    return 0;
}

/* ns_tet_min_dihedral (one acos) gives ns_tet_dihedrals' minimum bit for bit, and
 * ns_tet_dihedral_range (two) its minimum and maximum: on random tets,
 * slivers (a vertex near the opposite face), needles, inverted, flat and coincident ones. */
static int min_dihedral_matches(void)
{
    unsigned seed = 7u;
    int checked = 0;
    for (int k = 0; k < 20000; k++) {
        double p[4][3];
        for (int v = 0; v < 4; v++)
            for (int c = 0; c < 3; c++) {
                seed = seed * 1664525u + 1013904223u;
                p[v][c] = (double)(seed >> 8) / 16777216.0 - 0.5;
            }
        int kind = k % 5;
        if (kind == 1) /* a sliver: the last vertex pulled almost into the plane of the others */
            for (int c = 0; c < 3; c++)
                p[3][c] = (p[0][c] + p[1][c] + p[2][c]) / 3.0 + 1e-7 * p[3][c];
        if (kind == 2) /* a needle: two vertices almost together */
            for (int c = 0; c < 3; c++)
                p[1][c] = p[0][c] + 1e-9 * p[1][c];
        if (kind == 3) /* flat */
            p[3][2] = p[0][2] = p[1][2] = p[2][2];
        if (kind == 4) /* coincident */
            for (int c = 0; c < 3; c++)
                p[2][c] = p[1][c];
        double want = ns_tet_dihedrals(p[0], p[1], p[2], p[3], NULL);
        double got = ns_tet_min_dihedral(p[0], p[1], p[2], p[3]);
        ENSURE(ns_same_bits(&got, &want, 1));
        /* the vertices in another order: the same tet */
        double want2 = ns_tet_dihedrals(p[2], p[0], p[3], p[1], NULL);
        double got2 = ns_tet_min_dihedral(p[2], p[0], p[3], p[1]);
        ENSURE(ns_same_bits(&got2, &want2, 1));
        /* ns_tet_dihedral_range: the same minimum, and the six angles' maximum (180 for a
         * degenerate tet, where ns_tet_dihedrals gives zeros). */
        double ang[6], top = 0.0, hi;
        ns_tet_dihedrals(p[0], p[1], p[2], p[3], ang);
        for (int e = 0; e < 6; e++)
            top = fmax(top, ang[e]);
        double lo = ns_tet_dihedral_range(p[0], p[1], p[2], p[3], &hi);
        ENSURE(ns_same_bits(&lo, &want, 1));
        if (top > 0.0)
            ENSURE(ns_same_bits(&hi, &top, 1));
        else
            ENSURE(hi == 180.0);
        checked++;
    }
    ENSURE(checked == 20000);
    return 0;
}

/* ns_dihedral_watch (min_dihedral_deg_any_step) gives, bit for bit, the running minimum of a
 * full scan of every state it is shown: a grid block whose interior nodes move at rest and in the
 * world, and whose tets are split and the splits undone, in a random sequence (each state's
 * full scan, ns_mesh_min_dihedral, the reference). */
static int watch_matches_full_scans(void)
{
    NsMesh m;
    const double lo[3] = {0, 0, 0}, hi[3] = {1, 1, 1};
    char err[256];
    ENSURE(ns_mesh_grid_box(&m, lo, hi, 4, 4, 4, 0, err, sizeof err) == 0);
    NsRemeshStack st;
    ns_remesh_stack_init(&st);
    NsDihedralWatch w;
    ENSURE(ns_dihedral_watch_init(&w, &m) == 0);
    double want_rest = ns_mesh_min_dihedral(&m, false), want_world = ns_mesh_min_dihedral(&m, true);
    ENSURE(ns_same_bits(&w.min_rest_deg, &want_rest, 1));
    unsigned seed = 11u;
    int splits = 0, moves = 0, undos = 0;
    for (int k = 0; k < 300; k++) {
        seed = seed * 1664525u + 1013904223u;
        int what = (int)(seed >> 28) % 4, n = (int)((seed >> 8) % (unsigned)m.node_slots);
        if (what == 0 && ns_mesh_node_alive(&m, n) && !ns_remesh_node_on_boundary(&m, n)) {
            /* a small move at rest (kept only if every tet stays positive) */
            double save[3];
            memcpy(save, m.u + 3 * n, sizeof save);
            for (int c = 0; c < 3; c++)
                m.u[3 * n + c] += 0.02 * ((double)((seed >> (4 * c)) & 15u) / 15.0 - 0.5);
            if (ns_remesh_node_quality(&m, n) <= 0.0)
                memcpy(m.u + 3 * n, save, sizeof save);
            else
                moves++;
        } else if (what == 1) { /* split a tet at its centroid */
            int t = (int)((seed >> 4) % (unsigned)m.tet_slots);
            if (ns_mesh_tet_alive(&m, t)) {
                double c[3] = {0, 0, 0};
                int simplex[4]; /* a copy: the split rewrites the tet's slot */
                memcpy(simplex, m.tet_node + 4 * t, sizeof simplex);
                for (int v = 0; v < 4; v++)
                    for (int i = 0; i < 3; i++)
                        c[i] += 0.25 * m.u[3 * simplex[v] + i];
                if (ns_remesh_split(&m, &st, simplex, 4, c) >= 0)
                    splits++;
            }
        } else if (what == 2 && st.count > 0) {
            undos += ns_remesh_undo(&m, &st) == 0; /* (refused after some moves: no matter) */
        } else if (ns_mesh_node_alive(&m, n)) {    /* the world moves */
            m.x[3 * n + (k % 3)] += 0.03 * ((double)((seed >> 12) & 255u) / 255.0 - 0.5);
        }
        ENSURE(ns_dihedral_watch_look(&w, &m) == 0);
        want_rest = fmin(want_rest, ns_mesh_min_dihedral(&m, false));
        want_world = fmin(want_world, ns_mesh_min_dihedral(&m, true));
        ENSURE(ns_same_bits(&w.min_rest_deg, &want_rest, 1));
        ENSURE(ns_same_bits(&w.min_world_deg, &want_world, 1));
    }
    ENSURE(splits > 5 && moves > 5 && undos > 5 && want_rest < 40.0);
    printf("  %d splits, %d undone, %d moves: worst at rest %.3f deg, in the world %.3f deg\n",
           splits, undos, moves, want_rest, want_world);
    ns_dihedral_watch_free(&w);
    ns_remesh_stack_free(&st);
    ns_mesh_free(&m);
    return 0;
}

NS_TEST_MAIN({"regular_tet", regular_tet}, {"corner_tet", corner_tet}, {"flat_tet", flat_tet},
             {"mesh_stats", mesh_stats}, {"min_dihedral_matches", min_dihedral_matches},
             {"watch_matches_full_scans", watch_matches_full_scans})
