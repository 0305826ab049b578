/* Tests for sim/quality.c: the quality measure and dihedral angles on tets with known answers;
 * the one-acos minimum against the six angles. */
#include "quality.h"
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

NS_TEST_MAIN({"regular_tet", regular_tet}, {"corner_tet", corner_tet}, {"flat_tet", flat_tet},
             {"mesh_stats", mesh_stats}, {"min_dihedral_matches", min_dihedral_matches})
