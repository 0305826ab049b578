/* Laying a straight needle path into a mesh that does not contain it: a walk along the mesh
 * edges that follow the line best, then a snap of the chain's nodes onto the line. */
#include "needle_path.h"

#include "err.h"
#include "quality.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Walk score: progress along the line minus this times the distance from it. */
#define LAY_PENALTY 2.0
/* A snap may not bring an incident tet's quality below this (unless it was already lower and
 * does not get worse). */
#define LAY_MIN_QUALITY 0.05
/* Nodes closer to the line than this fraction of their shortest edge are not moved. */
#define LAY_ON_LINE 1e-12

typedef struct Line {
    double a[3], d[3]; /* start, unit direction */
    double len;        /* |b - a| [m] */
} Line;

static double line_param(const Line *l, const double *p)
{
    return (p[0] - l->a[0]) * l->d[0] + (p[1] - l->a[1]) * l->d[1] + (p[2] - l->a[2]) * l->d[2];
}

static double line_dist(const Line *l, const double *p, double t)
{
    double s = 0.0;
    for (int c = 0; c < 3; c++) {
        double e = p[c] - (l->a[c] + t * l->d[c]);
        s += e * e;
    }
    return sqrt(s);
}

static double dist2(const double *p, const double *q)
{
    double s = 0.0;
    for (int c = 0; c < 3; c++)
        s += (p[c] - q[c]) * (p[c] - q[c]);
    return s;
}

static bool usable(const NsMesh *m, int i)
{
    return ns_mesh_node_alive(m, i) && !(m->flags[i] & NS_NODE_FIXED) && m->node_tets[i].count > 0;
}

static int nearest_node(const NsMesh *m, const double *p)
{
    int best = -1;
    double bd = INFINITY;
    for (int i = 0; i < m->node_slots; i++) {
        if (!usable(m, i))
            continue;
        double d = dist2(m->u + 3 * i, p);
        if (d < bd) {
            bd = d;
            best = i;
        }
    }
    return best;
}

/* The neighbour of node c that follows the line best, or -1 when none makes progress. */
static int next_node(const NsMesh *m, const Line *l, int c)
{
    const double *uc = m->u + 3 * c;
    double tc = line_param(l, uc), best_score = -INFINITY;
    int best = -1;
    const NsIntList *tl = &m->node_tets[c];
    for (int k = 0; k < tl->count; k++) {
        const int *tn = m->tet_node + 4 * tl->items[k];
        for (int j = 0; j < 4; j++) {
            int n = tn[j];
            if (n == c || !usable(m, n))
                continue;
            const double *un = m->u + 3 * n;
            double tn_ = line_param(l, un);
            double half_edge = 0.5 * sqrt(dist2(un, uc));
            if (!(tn_ > tc) || tn_ > l->len + half_edge)
                continue;
            double score = (tn_ - tc) - LAY_PENALTY * line_dist(l, un, tn_);
            if (score > best_score || (score == best_score && n < best)) {
                best_score = score;
                best = n;
            }
        }
    }
    return best;
}

static double shortest_edge(const NsMesh *m, int i)
{
    double best = INFINITY;
    const NsIntList *tl = &m->node_tets[i];
    for (int k = 0; k < tl->count; k++) {
        const int *tn = m->tet_node + 4 * tl->items[k];
        for (int j = 0; j < 4; j++)
            if (tn[j] != i) {
                double d = dist2(m->u + 3 * i, m->u + 3 * tn[j]);
                if (d < best)
                    best = d;
            }
    }
    return sqrt(best);
}

/* Incident tets of node i after moving it to (u, x), with the others where they are: returns
 * the first tet the move inverts or flattens (volume <= 0 in material or world coordinates,
 * quality below LAY_MIN_QUALITY and lower than before), or -1. */
static int bad_tet_after_move(const NsMesh *m, int i, const double *u, const double *x,
                              double *q_out)
{
    const NsIntList *tl = &m->node_tets[i];
    for (int k = 0; k < tl->count; k++) {
        int t = tl->items[k];
        const int *tn = m->tet_node + 4 * t;
        const double *pu[4], *px[4];
        for (int j = 0; j < 4; j++) {
            pu[j] = tn[j] == i ? u : m->u + 3 * tn[j];
            px[j] = tn[j] == i ? x : m->x + 3 * tn[j];
        }
        double q_old =
            ns_tet_quality(m->u + 3 * tn[0], m->u + 3 * tn[1], m->u + 3 * tn[2], m->u + 3 * tn[3]);
        double q = ns_tet_quality(pu[0], pu[1], pu[2], pu[3]);
        double vu = ns_tet_volume(pu[0], pu[1], pu[2], pu[3]);
        double vx = ns_tet_volume(px[0], px[1], px[2], px[3]);
        if (!(vu > 0.0) || !(vx > 0.0) || (q < LAY_MIN_QUALITY && q < q_old)) {
            *q_out = q;
            return t;
        }
    }
    return -1;
}

int ns_needle_path_lay(NsMesh *m, const double a[3], const double b[3], double max_move, int *nodes,
                       int cap, char *err, int err_sz)
{
    Line l;
    l.len = sqrt(dist2(a, b));
    if (!(l.len > 0.0) || !isfinite(l.len)) {
        ns_set_err(err, err_sz, "path ends must be distinct and finite");
        return -1;
    }
    if (!(max_move >= 0.0)) {
        ns_set_err(err, err_sz, "max_move must be >= 0 (got %g)", max_move);
        return -1;
    }
    if (!nodes || cap < 2) {
        ns_set_err(err, err_sz, "room for at least 2 path nodes needed (cap %d)", cap);
        return -1;
    }
    for (int c = 0; c < 3; c++) {
        l.a[c] = a[c];
        l.d[c] = (b[c] - a[c]) / l.len;
    }
    int start = nearest_node(m, a), end = nearest_node(m, b);
    if (start < 0) {
        ns_set_err(err, err_sz, "mesh has no movable node");
        return -1;
    }

    /* 1. Walk: every step makes progress along the line, so no node repeats. */
    int *chain = malloc((size_t)m->node_slots * sizeof(int));
    double *saved = NULL;
    if (!chain)
        goto oom;
    int count = 0;
    chain[count++] = start;
    for (int c = start; c != end;) {
        c = next_node(m, &l, c);
        if (c < 0)
            break;
        chain[count++] = c;
    }
    if (count < 2) {
        ns_set_err(err, err_sz, "no mesh edge from node %d leads along the path", start);
        goto fail;
    }
    if (count > cap) {
        ns_set_err(err, err_sz, "path has %d nodes, room for %d", count, cap);
        goto fail;
    }

    /* 2. Snap onto the line, keeping the old positions to undo a failed snap. */
    saved = malloc((size_t)count * 6 * sizeof(double));
    if (!saved)
        goto oom;
    int moved = 0;
    for (; moved < count; moved++) {
        int i = chain[moved];
        double *u = m->u + 3 * i, *x = m->x + 3 * i;
        memcpy(saved + 6 * moved, u, 3 * sizeof(double));
        memcpy(saved + 6 * moved + 3, x, 3 * sizeof(double));
        double t = fmin(fmax(line_param(&l, u), 0.0), l.len);
        double nu[3], nx[3];
        for (int c = 0; c < 3; c++)
            nu[c] = l.a[c] + t * l.d[c];
        double move = sqrt(dist2(nu, u)), edge = shortest_edge(m, i);
        if (move <= LAY_ON_LINE * edge)
            continue;
        if (move > max_move * edge) {
            ns_set_err(err, err_sz,
                       "path node %d needs a move of %.3g m (%.3g of its shortest edge, at most "
                       "%.3g allowed)",
                       i, move, move / edge, max_move);
            goto undo;
        }
        for (int c = 0; c < 3; c++)
            nx[c] = x[c] + (nu[c] - u[c]);
        double q;
        int bad = bad_tet_after_move(m, i, nu, nx, &q);
        if (bad >= 0) {
            ns_set_err(err, err_sz,
                       "moving path node %d by %.3g m onto the path leaves tet %d with quality "
                       "%.3g",
                       i, move, bad, q);
            goto undo;
        }
        memcpy(u, nu, sizeof nu);
        memcpy(x, nx, sizeof nx);
    }

    /* 3. The snapped chain must run forward along the line. */
    for (int k = 1; k < count; k++) {
        double t0 = line_param(&l, m->u + 3 * chain[k - 1]),
               t1 = line_param(&l, m->u + 3 * chain[k]);
        if (!(t1 > t0)) {
            ns_set_err(err, err_sz,
                       "path nodes %d and %d do not advance along the path (%.6g, %.6g m)",
                       chain[k - 1], chain[k], t0, t1);
            goto undo;
        }
    }
    memcpy(nodes, chain, (size_t)count * sizeof(int));
    free(saved);
    free(chain);
    return count;

undo:
    while (moved-- > 0) {
        int i = chain[moved];
        memcpy(m->u + 3 * i, saved + 6 * moved, 3 * sizeof(double));
        memcpy(m->x + 3 * i, saved + 6 * moved + 3, 3 * sizeof(double));
    }
    goto fail;
oom:
    ns_set_err(err, err_sz, "out of memory laying the path");
fail:
    free(saved);
    free(chain);
    return -1;
}
