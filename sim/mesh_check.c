/* Whole-mesh checks for meshes read from files (mesh_check.h). */
#include "mesh_check.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "quality.h"

int ns_mesh_parts(const NsMesh *m, int *part, int *tets, double *volume)
{
    int n = m->tet_slots;
    for (int t = 0; t < n; t++)
        part[t] = -1;
    int *stack = malloc((size_t)(n > 0 ? n : 1) * sizeof *stack);
    if (!stack)
        return -1;
    int parts = 0;
    for (int seed = 0; seed < n; seed++) {
        if (!ns_mesh_tet_alive(m, seed) || part[seed] >= 0)
            continue;
        int top = 0, count = 0;
        double vol = 0.0;
        stack[top++] = seed;
        part[seed] = parts;
        while (top > 0) {
            int t = stack[--top];
            const int *v = &m->tet_node[4 * t];
            count++;
            vol +=
                ns_tet_volume(&m->u[3 * v[0]], &m->u[3 * v[1]], &m->u[3 * v[2]], &m->u[3 * v[3]]);
            for (int k = 0; k < 4; k++) {
                int a = m->tet_adj[4 * t + k];
                if (a >= 0 && part[a] < 0) {
                    part[a] = parts;
                    stack[top++] = a;
                }
            }
        }
        if (tets)
            tets[parts] = count;
        if (volume)
            volume[parts] = vol;
        parts++;
    }
    free(stack);
    return parts;
}

/* ---- overlap ---------------------------------------------------------------------------- */

typedef struct Grid {
    double lo[3], cell; /* origin and cell size [m] */
    int n[3];
    size_t *start; /* (cells + 1) CSR offsets into item */
    int *item;     /* tets overlapping each cell */
    double *box;   /* (tet_slots x 6) each tet's bounding box: lo xyz, hi xyz [m] */
} Grid;

static size_t cell_index(const Grid *g, const int c[3])
{
    return ((size_t)c[2] * (size_t)g->n[1] + (size_t)c[1]) * (size_t)g->n[0] + (size_t)c[0];
}

static int cell_coord(const Grid *g, double x, int d)
{
    double f = floor((x - g->lo[d]) / g->cell);
    if (!(f >= 0.0))
        return 0;
    return f >= (double)(g->n[d] - 1) ? g->n[d] - 1 : (int)f;
}

static void tet_box(const NsMesh *m, int t, double lo[3], double hi[3])
{
    const int *v = &m->tet_node[4 * t];
    for (int d = 0; d < 3; d++) {
        lo[d] = hi[d] = m->u[3 * v[0] + d];
        for (int k = 1; k < 4; k++) {
            double x = m->u[3 * v[k] + d];
            lo[d] = x < lo[d] ? x : lo[d];
            hi[d] = x > hi[d] ? x : hi[d];
        }
    }
}

/* Cells a tet's bounding box overlaps, as coordinate ranges. */
static size_t tet_cells(const Grid *g, const NsMesh *m, int t, int c0[3], int c1[3])
{
    double lo[3], hi[3];
    tet_box(m, t, lo, hi);
    size_t count = 1;
    for (int d = 0; d < 3; d++) {
        c0[d] = cell_coord(g, lo[d], d);
        c1[d] = cell_coord(g, hi[d], d);
        count *= (size_t)(c1[d] - c0[d] + 1);
    }
    return count;
}

/* A grid whose cell is about a tet's size, with at most about 4 cells a tet and 32 tet
 * entries a tet (a few huge tets among small ones make the cells larger). */
static int grid_build(Grid *g, const NsMesh *m)
{
    memset(g, 0, sizeof *g);
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    double extent = 0.0;
    int nt = 0;
    for (int t = 0; t < m->tet_slots; t++) {
        if (!ns_mesh_tet_alive(m, t))
            continue;
        double a[3], b[3], e = 0.0;
        tet_box(m, t, a, b);
        for (int d = 0; d < 3; d++) {
            lo[d] = a[d] < lo[d] ? a[d] : lo[d];
            hi[d] = b[d] > hi[d] ? b[d] : hi[d];
            e = b[d] - a[d] > e ? b[d] - a[d] : e;
        }
        extent += e;
        nt++;
    }
    if (nt == 0)
        return 0;
    memcpy(g->lo, lo, sizeof lo);
    g->cell = extent / nt;
    for (;;) {
        double cells = 1.0;
        for (int d = 0; d < 3; d++) {
            double k = floor((hi[d] - lo[d]) / g->cell) + 1.0;
            g->n[d] = k < 1e9 ? (int)k : 1000000000;
            cells *= k;
        }
        if (cells <= 4.0 * nt + 64.0) {
            size_t entries = 0;
            int c0[3], c1[3];
            for (int t = 0; t < m->tet_slots; t++)
                if (ns_mesh_tet_alive(m, t))
                    entries += tet_cells(g, m, t, c0, c1);
            if (entries <= (size_t)32 * (size_t)nt && entries < (size_t)INT32_MAX)
                break;
        }
        g->cell *= 2.0;
    }
    size_t ncell = (size_t)g->n[0] * (size_t)g->n[1] * (size_t)g->n[2];
    g->start = calloc(ncell + 1, sizeof *g->start);
    g->box = malloc((size_t)m->tet_slots * 6 * sizeof *g->box);
    if (!g->start || !g->box)
        return -1;
    for (int t = 0; t < m->tet_slots; t++)
        if (ns_mesh_tet_alive(m, t))
            tet_box(m, t, &g->box[6 * t], &g->box[6 * t + 3]);
    int c0[3], c1[3], c[3];
    for (int t = 0; t < m->tet_slots; t++) {
        if (!ns_mesh_tet_alive(m, t))
            continue;
        tet_cells(g, m, t, c0, c1);
        for (c[2] = c0[2]; c[2] <= c1[2]; c[2]++)
            for (c[1] = c0[1]; c[1] <= c1[1]; c[1]++)
                for (c[0] = c0[0]; c[0] <= c1[0]; c[0]++)
                    g->start[cell_index(g, c) + 1]++;
    }
    for (size_t i = 0; i < ncell; i++)
        g->start[i + 1] += g->start[i];
    g->item = malloc((g->start[ncell] > 0 ? g->start[ncell] : 1) * sizeof *g->item);
    size_t *fill = malloc((ncell > 0 ? ncell : 1) * sizeof *fill);
    if (!g->item || !fill) {
        free(fill);
        return -1;
    }
    memcpy(fill, g->start, ncell * sizeof *fill);
    for (int t = 0; t < m->tet_slots; t++) {
        if (!ns_mesh_tet_alive(m, t))
            continue;
        tet_cells(g, m, t, c0, c1);
        for (c[2] = c0[2]; c[2] <= c1[2]; c[2]++)
            for (c[1] = c0[1]; c[1] <= c1[1]; c[1]++)
                for (c[0] = c0[0]; c[0] <= c1[0]; c[0]++)
                    g->item[fill[cell_index(g, c)]++] = t;
    }
    free(fill);
    return 0;
}

static void grid_free(Grid *g)
{
    free(g->start);
    free(g->item);
    free(g->box);
}

/* p strictly inside tet t: each barycentric coordinate above 1e-6 (the sub-volumes are
 * computed relative to a vertex of t, so their rounding is relative to t's size, not to how far
 * it sits from the origin). */
static int strictly_inside(const Grid *g, const NsMesh *m, int t, const double p[3])
{
    const int *v = &m->tet_node[4 * t];
    const double *b = &g->box[6 * t];
    for (int d = 0; d < 3; d++)
        if (!(p[d] > b[d] && p[d] < b[3 + d]))
            return 0;
    double q[4][3], r[3];
    for (int k = 0; k < 4; k++)
        for (int d = 0; d < 3; d++)
            q[k][d] = m->u[3 * v[k] + d] - m->u[3 * v[0] + d];
    for (int d = 0; d < 3; d++)
        r[d] = p[d] - m->u[3 * v[0] + d];
    double vol = ns_tet_volume(q[0], q[1], q[2], q[3]);
    if (!(vol > 0.0))
        return 0;
    const double eps = 1e-6 * vol;
    for (int k = 0; k < 4; k++) {
        const double *s[4] = {q[0], q[1], q[2], q[3]};
        s[k] = r;
        if (!(ns_tet_volume(s[0], s[1], s[2], s[3]) > eps))
            return 0;
    }
    return 1;
}

/* A tet near p (other than `self` and the tets of `node`) that holds p strictly, or -1. */
static int holder(const Grid *g, const NsMesh *m, const double p[3], int self, int node)
{
    int c[3];
    for (int d = 0; d < 3; d++)
        c[d] = cell_coord(g, p[d], d);
    size_t i = cell_index(g, c);
    for (size_t k = g->start[i]; k < g->start[i + 1]; k++) {
        int t = g->item[k];
        if (t == self)
            continue;
        const int *v = &m->tet_node[4 * t];
        if (node >= 0 && (v[0] == node || v[1] == node || v[2] == node || v[3] == node))
            continue;
        if (strictly_inside(g, m, t, p))
            return t;
    }
    return -1;
}

int ns_mesh_find_overlap(const NsMesh *m, NsTetOverlap *o)
{
    Grid g;
    if (grid_build(&g, m)) {
        grid_free(&g);
        return -1;
    }
    int found = 0;
    if (g.start) {
        for (int i = 0; i < m->node_slots && !found; i++) {
            if (!ns_mesh_node_alive(m, i) || m->node_tets[i].count == 0)
                continue;
            int t = holder(&g, m, &m->u[3 * i], -1, i);
            if (t >= 0) {
                *o = (NsTetOverlap){t, m->node_tets[i].items[0], i};
                found = 1;
            }
        }
        /* The centroid, and an off-centre point whose weights are not simple fractions: a copy
         * shifted by half a lattice cell puts its nodes and centroids on the other copy's
         * faces and edges, where no strict test sees them. */
        static const double w[2][4] = {{0.25, 0.25, 0.25, 0.25}, {0.47, 0.26, 0.17, 0.10}};
        for (int s = 0; s < m->tet_slots && !found; s++) {
            if (!ns_mesh_tet_alive(m, s))
                continue;
            const int *v = &m->tet_node[4 * s];
            for (int j = 0; j < 2 && !found; j++) {
                double p[3];
                for (int d = 0; d < 3; d++)
                    p[d] = w[j][0] * m->u[3 * v[0] + d] + w[j][1] * m->u[3 * v[1] + d] +
                           w[j][2] * m->u[3 * v[2] + d] + w[j][3] * m->u[3 * v[3] + d];
                int t = holder(&g, m, p, s, -1);
                if (t >= 0) {
                    *o = (NsTetOverlap){t, s, j == 0 ? -1 : -2};
                    found = 1;
                }
            }
        }
    }
    grid_free(&g);
    return found;
}
