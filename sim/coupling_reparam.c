/* The needle's reparameterization after the step (§3.4.2; sim/coupling_internal.h,
 * coupled_reparameterize): after the tip's cut (coupling_tip.c), the needle's nodes are rebuilt
 * on the tissue points they are coupled to, and the rod's quantities carried across
 * (ns_rod_resample: Akima for the rest quantities, linear for v and a), then its free edges are
 * split and merged (ns_rod_reparameterize). */
#include "coupling_internal.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static double dot3(const double *a, const double *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static double norm3(const double *a)
{
    return sqrt(dot3(a, a));
}

/* Outside the tissue: nothing is coupled (a needle pushed back in enters afresh in the tip's
 * cut, coupling_reentry.c; one whose tip is not yet deeper than it was as it left, nor a
 * fiftieth of an element in, waits). Free
 * of the tissue, the rod still splits and merges its edges: a retraction shortens the edge at
 * the sleeve, which must merge with the next to go on. */
static int reparameterize_free(NsCoupled *c, NsCouplingStats *st)
{
    NsRod *r = c->rod;
    if (!c->outside)
        return 0;
    NsRodStats rs;
    memset(&rs, 0, sizeof rs);
    if (ns_rod_reparameterize(r, &rs) || coupled_reserve(c, r->cap))
        return -1;
    st->rod_splits += rs.splits;
    st->rod_merges += rs.merges;
    coupled_from_path(c, 0, 0);
    return 0;
}

/* The new polyline of the needle, m nodes: the held and free nodes before the entry keep their
 * solved positions (a free node the needle pushed into the tissue is dropped), the coupled ones
 * (from cfirst on) take their tissue points' positions, free nodes past the exit keep theirs. */
typedef struct Polyline {
    double *xn;   /* (m x 3) new node positions [m] */
    double *s;    /* (m) their parameters: distance from the base [m] */
    double *dold; /* (old nodes) the old parameters, along the solved polyline [m] */
    int m, cfirst, nb;
} Polyline;

static void new_polyline(const NsCoupled *c, int first, int last, Polyline *L)
{
    const NsRod *r = c->rod;
    const NsMesh *M = &c->tissue->mesh;
    const NsNeedlePath *p = &c->path;
    int n = r->nodes, nb = L->nb;
    double *xn = L->xn, *dold = L->dold;
    /* Old parameters: distance from the base along the solved polyline. */
    dold[0] = 0.0;
    for (int i = 1; i < n; i++) {
        double e[3];
        for (int k = 0; k < 3; k++)
            e[k] = r->x[3 * i + k] - r->x[3 * (i - 1) + k];
        dold[i] = dold[i - 1] + norm3(e);
    }
    double minlen = 0.25 * r->min_rest_edge;
    int m = 0;
    for (int i = 0; i < first; i++) {
        /* Free nodes before the entry stay unless the needle slid them into the tissue (past
         * the entry node along the path's first edge; right after skin entry that edge runs
         * to the tip's node). */
        if (i >= r->held && p->count > 1) {
            double t[3], d[3];
            for (int k = 0; k < 3; k++) {
                t[k] = M->x[3 * p->node[1] + k] - M->x[3 * p->node[0] + k];
                d[k] = r->x[3 * i + k] - M->x[3 * p->node[0] + k];
            }
            if (dot3(d, t) / norm3(t) > -minlen)
                continue;
        }
        memcpy(xn + 3 * m, r->x + 3 * i, 3 * sizeof *xn);
        m++;
    }
    int cfirst = m;
    for (int k = 0; k < nb; k++, m++)
        memcpy(xn + 3 * m, M->x + 3 * p->node[k], 3 * sizeof *xn);
    if (!p->through) {
        double w;
        int e = ns_needle_path_tip(p, &w);
        for (int k = 0; k < 3; k++)
            xn[3 * m + k] = (1.0 - w) * M->x[3 * p->node[e] + k] + w * M->x[3 * p->node[e + 1] + k];
        m++;
    } else {
        int pe = p->node[p->count - 1], pd = p->node[p->count - 2];
        for (int i = last + 1; i < n; i++) {
            double t[3], d[3];
            for (int k = 0; k < 3; k++) {
                t[k] = M->x[3 * pe + k] - M->x[3 * pd + k];
                d[k] = r->x[3 * i + k] - M->x[3 * pe + k];
            }
            if (i < n - 1 && dot3(d, t) / norm3(t) < minlen)
                continue;
            memcpy(xn + 3 * m, r->x + 3 * i, 3 * sizeof *xn);
            m++;
        }
    }
    L->m = m;
    L->cfirst = cfirst;
}

/* Every new node labelled by its distance from the base along the new polyline, scaled so the
 * tip keeps the old total (the needle is not perfectly inextensible); the rod's quantities
 * carried across, then too long free edges split and too short ones merged (coupled nodes
 * pinned). Friction states go to the nearest old coupled node's. cst: (m) scratch. Returns 0 or
 * -1. */
static int resample_needle(NsCoupled *c, NsCouplingStats *st, int first, int last,
                           const Polyline *L, uint8_t *cst)
{
    NsRod *r = c->rod;
    const NsNeedlePath *p = &c->path;
    int n = r->nodes, m = L->m, cfirst = L->cfirst, nb = L->nb;
    double *xn = L->xn, *s = L->s;
    const double *dold = L->dold;
    int rc = 0;
    if (m < 3)
        rc = -1;
    s[0] = 0.0;
    for (int j = 1; j < m && rc == 0; j++) {
        double e[3];
        for (int k = 0; k < 3; k++)
            e[k] = xn[3 * j + k] - xn[3 * (j - 1) + k];
        s[j] = s[j - 1] + norm3(e);
        if (!(s[j] > s[j - 1]))
            rc = -1;
    }
    if (rc == 0) {
        double scale = dold[n - 1] / s[m - 1];
        for (int j = 0; j < m; j++)
            s[j] *= scale;
        /* Friction states of the coupled new nodes: the nearest old coupled node's. */
        int ncoup = nb + !p->through;
        for (int j = 0; j < ncoup; j++) {
            double best = INFINITY;
            cst[j] = NS_FRICTION_STATIC;
            for (int i = first; i <= last; i++)
                if (fabs(dold[i] - s[cfirst + j]) < best) {
                    best = fabs(dold[i] - s[cfirst + j]);
                    cst[j] = c->state[i];
                }
        }
        rc = ns_rod_resample(r, xn, s, m);
        if (rc == 0 && coupled_reserve(c, r->cap))
            rc = -1;
        if (rc == 0) {
            for (int i = 0; i < r->nodes; i++)
                r->pinned[i] = i >= cfirst && i < cfirst + ncoup;
            NsRodStats rs;
            memset(&rs, 0, sizeof rs);
            rc = ns_rod_reparameterize(r, &rs);
            st->rod_splits += rs.splits;
            st->rod_merges += rs.merges;
        }
        if (rc == 0 && coupled_reserve(c, r->cap))
            rc = -1;
        if (rc == 0) {
            /* Split and merge never touch pinned (coupled) nodes: find the first again. */
            int f2 = 0;
            while (f2 < r->nodes && !r->pinned[f2])
                f2++;
            for (int i = 0; i < r->nodes; i++)
                c->state[i] = i >= f2 && i < f2 + ncoup ? cst[i - f2] : NS_FRICTION_STATIC;
            coupled_from_path(c, f2, 1);
        }
    }
    return rc;
}

int coupled_reparameterize(NsCoupled *c, NsCouplingStats *st)
{
    NsRod *r = c->rod;
    const NsNeedlePath *p = &c->path;
    int n = r->nodes;
    int first = -1, last = -1;
    for (int i = 0; i < n; i++)
        if (c->ta[i] >= 0) {
            first = first < 0 ? i : first;
            last = i;
        }
    if (first < 0 && st->reentered) { /* entered afresh: rebuilt from its first node inside */
        first = st->reentry_first;
        last = n - 1;
    }
    if (first < 0)
        return reparameterize_free(c, st);
    if (c->outside) { /* withdrawn this step: the needle keeps its solved shape, coupled nowhere,
                       * and its edges split and merge as a free needle's (a retraction that ate
                       * the edge at the sleeve this step must merge it before the next) */
        coupled_from_path(c, 0, 0);
        return reparameterize_free(c, st);
    }
    /* Out through the far side this step: the needle's tip, outside, stays free beyond the exit
     * node. */
    if (st->tip_exit)
        last = n - 2;
    Polyline L;
    L.nb = ns_needle_path_behind(p);
    int m_cap = n + p->count + 2;
    double *buf = ns_arena_push(&c->arena, (size_t)m_cap * 8 * sizeof *buf);
    uint8_t *cst = ns_arena_push(&c->arena, (size_t)m_cap);
    if (!buf || !cst) {
        ns_arena_pop(&c->arena, cst);
        ns_arena_pop(&c->arena, buf);
        return -1;
    }
    L.xn = buf;
    L.s = L.xn + 3 * (size_t)m_cap;
    L.dold = L.s + m_cap;
    new_polyline(c, first, last, &L);
    int rc = resample_needle(c, st, first, last, &L, cst);
    ns_arena_pop(&c->arena, cst);
    ns_arena_pop(&c->arena, buf);
    return rc;
}
