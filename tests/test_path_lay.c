/* Tests for sim/needle_path_lay.c: laying a straight needle path into a mesh, on a grid (the
 * path is already there), on a stuffed mesh (nodes are snapped onto the line) and with moves
 * too small to allow (the mesh is left untouched). */
#include "mesh_grid.h"
#include "mesher.h"
#include "needle_path.h"
#include "quality.h"
#include "ns_test.h"

#include <stdlib.h>
#include <string.h>

#define CAP 256

/* A 4 x 3 x 3 cm box stuffed with spacing 4 mm. */
static int make_box(NsMesh *m)
{
    double c[3] = {0.0, 0.0, 0.0}, size[3] = {0.04, 0.03, 0.03};
    NsShape *box = ns_shape_box(c, size);
    NsMesherRegion r[1] = {{box, false}};
    NsMesherDef d = ns_default_mesher_def();
    d.spacing = 0.004;
    d.regions = r;
    d.region_count = 1;
    for (int k = 0; k < 3; k++) {
        d.lo[k] = -0.5 * size[k];
        d.hi[k] = 0.5 * size[k];
    }
    ns_mesh_init(m);
    char err[256];
    int rc = ns_mesher_stuff(&d, m, NULL, err, sizeof err);
    if (rc)
        fprintf(stderr, "mesher: %s\n", err);
    ns_shape_release(box);
    return rc;
}

static bool share_tet(const NsMesh *m, int p, int q)
{
    const NsIntList *tl = &m->node_tets[p];
    for (int k = 0; k < tl->count; k++)
        for (int j = 0; j < 4; j++)
            if (m->tet_node[4 * tl->items[k] + j] == q)
                return true;
    return false;
}

/* Distance of p from the line through a and b, and its parameter along it [m]. */
static double off_line(const double *a, const double *b, const double *p, double *t)
{
    double d[3], e[3], len = 0.0;
    for (int c = 0; c < 3; c++) {
        d[c] = b[c] - a[c];
        len += d[c] * d[c];
    }
    len = sqrt(len);
    *t = 0.0;
    for (int c = 0; c < 3; c++) {
        d[c] /= len;
        e[c] = p[c] - a[c];
        *t += e[c] * d[c];
    }
    double s = 0.0;
    for (int c = 0; c < 3; c++)
        s += (e[c] - *t * d[c]) * (e[c] - *t * d[c]);
    return sqrt(s);
}

static int grid_line(void)
{
    NsMesh m;
    double lo[3] = {-0.02, -0.015, -0.015}, hi[3] = {0.02, 0.015, 0.015};
    const int nx = 10, ny = 6, nz = 6;
    char err[256];
    ENSURE(ns_mesh_grid_box(&m, lo, hi, nx, ny, nz, 0, err, sizeof err) == 0);
    size_t sz = (size_t)3 * m.node_slots * sizeof(double);
    double *u0 = malloc(sz), *x0 = malloc(sz);
    ENSURE(u0 && x0);
    memcpy(u0, m.u, sz);
    memcpy(x0, m.x, sz);
    /* Along x through grid node (*, 2, 3), from i = 1 to i = 9. */
    const int j = 2, k = 3;
    int first = 1 + (nx + 1) * (j + (ny + 1) * k), last = 9 + (nx + 1) * (j + (ny + 1) * k);
    int nodes[CAP];
    int n =
        ns_needle_path_lay(&m, m.u + 3 * first, m.u + 3 * last, 0.3, nodes, CAP, err, sizeof err);
    if (n < 0)
        fprintf(stderr, "lay: %s\n", err);
    ENSURE(n == 9);
    for (int i = 0; i < n; i++)
        ENSURE(nodes[i] == first + i);
    ENSURE(memcmp(u0, m.u, sz) == 0);
    ENSURE(memcmp(x0, m.x, sz) == 0);
    /* Too little room is an error, and moves nothing. */
    ENSURE(ns_needle_path_lay(&m, m.u + 3 * first, m.u + 3 * last, 0.3, nodes, 5, err,
                              sizeof err) == -1);
    ENSURE(strstr(err, "room") != NULL);
    ENSURE(memcmp(u0, m.u, sz) == 0);
    free(u0);
    free(x0);
    ns_mesh_free(&m);
    return 0;
}

static int stuffed_diagonal(void)
{
    NsMesh m;
    ENSURE(make_box(&m) == 0);
    const double a[3] = {-0.018, -0.01, 0.003}, b[3] = {0.018, 0.008, -0.002};
    int nodes[CAP];
    char err[256];
    /* A 4 mm BCC lattice is up to ~0.56 h from a line; the end node here needs 0.65 of its
     * shortest edge. */
    int n = ns_needle_path_lay(&m, a, b, 0.75, nodes, CAP, err, sizeof err);
    if (n < 0)
        fprintf(stderr, "lay: %s\n", err);
    ENSURE(n >= 8);
    double prev = -INFINITY;
    for (int i = 0; i < n; i++) {
        double t;
        ENSURE(ns_mesh_node_alive(&m, nodes[i]));
        ENSURE_SMALL(off_line(a, b, m.u + 3 * nodes[i], &t), 1e-12);
        ENSURE_SMALL(off_line(a, b, m.x + 3 * nodes[i], &t), 1e-12);
        ENSURE(t > prev);
        prev = t;
        if (i > 0)
            ENSURE(share_tet(&m, nodes[i - 1], nodes[i]));
    }
    /* The path spans most of the segment (ends within an edge of a and b). */
    double t0, t1;
    off_line(a, b, m.u + 3 * nodes[0], &t0);
    off_line(a, b, m.u + 3 * nodes[n - 1], &t1);
    ENSURE(t0 < 0.005 && t1 > sqrt(0.036 * 0.036 + 0.018 * 0.018 + 0.005 * 0.005) - 0.005);
    ENSURE(ns_mesh_validate(&m, err, sizeof err) == 0);
    NsQualityStats s;
    ns_mesh_quality(&m, false, &s);
    ENSURE(s.inverted == 0 && s.min_quality > 0.0);
    ns_mesh_quality(&m, true, &s);
    ENSURE(s.inverted == 0);
    ns_mesh_free(&m);
    return 0;
}

/* Moves too small to allow fail and leave every node where it was: at the first node
 * (max_move 1e-6) and part way along, after earlier nodes have been snapped. */
static int impossible_move(void)
{
    NsMesh m, good;
    ENSURE(make_box(&m) == 0);
    ENSURE(ns_mesh_copy(&good, &m) == 0);
    const double a[3] = {-0.018, -0.01, 0.003}, b[3] = {0.018, 0.008, -0.002};
    int nodes[CAP];
    char err[256] = "";
    int n = ns_needle_path_lay(&good, a, b, 0.75, nodes, CAP, err, sizeof err);
    ENSURE(n >= 2);
    size_t sz = (size_t)3 * m.node_slots * sizeof(double);
    double *u0 = malloc(sz), *x0 = malloc(sz);
    ENSURE(u0 && x0);
    memcpy(u0, m.u, sz);
    memcpy(x0, m.x, sz);
    ENSURE(ns_needle_path_lay(&m, a, b, 1e-6, nodes + n, CAP - n, err, sizeof err) == -1);
    ENSURE(strstr(err, "needs a move") != NULL);
    ENSURE(memcmp(u0, m.u, sz) == 0);
    ENSURE(memcmp(x0, m.x, sz) == 0);
    int later = 0;
    for (double mm = 0.05; mm < 0.62; mm += 0.05) {
        ENSURE(ns_needle_path_lay(&m, a, b, mm, nodes + n, CAP - n, err, sizeof err) == -1);
        ENSURE(memcmp(u0, m.u, sz) == 0);
        ENSURE(memcmp(x0, m.x, sz) == 0);
        int bad;
        ENSURE(sscanf(err, "path node %d", &bad) == 1);
        later |= bad != nodes[0];
    }
    ENSURE(later);
    free(u0);
    free(x0);
    ns_mesh_free(&good);
    ns_mesh_free(&m);
    return 0;
}

NS_TEST_MAIN({"grid_line", grid_line}, {"stuffed_diagonal", stuffed_diagonal},
             {"impossible_move", impossible_move})
