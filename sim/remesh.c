/* Tissue remeshing at the needle tip (sim/remesh.h): point location, and Algorithm 2's choice
 * among candidate operations by the lexicographic quality vector (paper §3.4.1). The snap and
 * split operations with their undo stack are remesh_stack.c. */
#include "remesh.h"

#include <math.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "quality.h"
#include "remesh_internal.h"

/* ---- geometry ---- */

/* Barycentric coordinates of p in tet t with node coordinates X (m->u: material space, m->x:
 * world space). Returns 0, or -1 for a flat tet. */
static int tet_bary(const NsMesh *m, const double *X, int t, const double p[3], double b[4])
{
    const int *tn = m->tet_node + 4 * t;
    const double *u0 = X + 3 * tn[0];
    double A[9], r[3];
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++)
            A[3 * i + j] = X[3 * tn[j + 1] + i] - u0[i];
        r[i] = p[i] - u0[i];
    }
    double det = A[0] * (A[4] * A[8] - A[5] * A[7]) - A[1] * (A[3] * A[8] - A[5] * A[6]) +
                 A[2] * (A[3] * A[7] - A[4] * A[6]);
    if (!(fabs(det) > 0.0))
        return -1;
    /* Cramer's rule for A l = r. */
    for (int c = 0; c < 3; c++) {
        double M[9];
        memcpy(M, A, sizeof M);
        for (int i = 0; i < 3; i++)
            M[3 * i + c] = r[i];
        b[c + 1] = (M[0] * (M[4] * M[8] - M[5] * M[7]) - M[1] * (M[3] * M[8] - M[5] * M[6]) +
                    M[2] * (M[3] * M[7] - M[4] * M[6])) /
                   det;
    }
    b[0] = 1.0 - b[1] - b[2] - b[3];
    return 0;
}

static double min4(const double b[4])
{
    return fmin(fmin(b[0], b[1]), fmin(b[2], b[3]));
}

int ns_mesh_locate(const NsMesh *m, const double p[3], int start, double tol, double bary[4])
{
    return ns_mesh_locate_in(m, m->u, p, start, tol, bary);
}

/* The search when the walk fails: the tet of cand[0..n) (every slot when cand is NULL), in
 * increasing order, whose least barycentric coordinate of p is the greatest. */
static int scan(const NsMesh *m, const double *X, const double p[3], double tol, double bary[4],
                const int *cand, int n)
{
    double b[4];
    int best = -1;
    double best_min = -INFINITY;
    for (int i = 0; i < (cand ? n : m->tet_slots); i++) {
        int e = cand ? cand[i] : i;
        if (!ns_mesh_tet_alive(m, e) || tet_bary(m, X, e, p, b))
            continue;
        if (min4(b) > best_min) {
            best_min = min4(b);
            best = e;
            if (bary)
                memcpy(bary, b, sizeof b);
        }
    }
    return best_min >= -tol ? best : -1;
}

/* Walks across the face opposite the most negative coordinate from start: the tet found, or -2
 * when the walk left the mesh (a concave boundary) or cycled. */
int ns_mesh_walk(const NsMesh *m, const double *X, const double p[3], int start, double tol,
                 double bary[4])
{
    double b[4];
    int t = start;
    if (!ns_mesh_tet_alive(m, t))
        for (t = 0; t < m->tet_slots && !ns_mesh_tet_alive(m, t); t++)
            ;
    for (int step = 0; step < 4 * m->tet_alive + 16 && ns_mesh_tet_alive(m, t); step++) {
        if (tet_bary(m, X, t, p, b))
            break;
        int k = 0;
        for (int i = 1; i < 4; i++)
            if (b[i] < b[k])
                k = i;
        if (b[k] >= -tol) {
            if (bary)
                memcpy(bary, b, sizeof b);
            return t;
        }
        t = m->tet_adj[4 * t + k];
    }
    return -2;
}

int ns_mesh_locate_in(const NsMesh *m, const double *X, const double p[3], int start, double tol,
                      double bary[4])
{
    int t = ns_mesh_walk(m, X, p, start, tol, bary);
    return t != -2 ? t : scan(m, X, p, tol, bary, NULL, 0);
}

int ns_mesh_search_among(const NsMesh *m, const double *X, const double p[3], double tol,
                         double bary[4], const int *cand, int n)
{
    return scan(m, X, p, tol, bary, cand, n);
}

int ns_mesh_tets_in_box(const NsMesh *m, const double *X, const double lo[3], const double hi[3],
                        int *out)
{
    int n = 0;
    for (int e = 0; e < m->tet_slots; e++) {
        if (!ns_mesh_tet_alive(m, e))
            continue;
        const int *tn = m->tet_node + 4 * e;
        bool meets = true;
        for (int i = 0; i < 3 && meets; i++) {
            double a = X[3 * tn[0] + i], z = a;
            for (int k = 1; k < 4; k++) {
                a = fmin(a, X[3 * tn[k] + i]);
                z = fmax(z, X[3 * tn[k] + i]);
            }
            meets = z >= lo[i] && a <= hi[i];
        }
        if (meets)
            out[n++] = e;
    }
    return n;
}

/* World state (x, v, a) at barycentric b of tet t. */
void remesh_interp_state(const NsMesh *m, int t, const double b[4], double x[3], double v[3],
                         double a[3])
{
    for (int i = 0; i < 3; i++)
        x[i] = v[i] = a[i] = 0.0;
    for (int k = 0; k < 4; k++) {
        int n = m->tet_node[4 * t + k];
        for (int i = 0; i < 3; i++) {
            x[i] += b[k] * m->x[3 * n + i];
            v[i] += b[k] * m->v[3 * n + i];
            a[i] += b[k] * m->a[3 * n + i];
        }
    }
}

int remesh_tet_has(const NsMesh *m, int t, int n)
{
    const int *tn = m->tet_node + 4 * t;
    return tn[0] == n || tn[1] == n || tn[2] == n || tn[3] == n;
}

static double tet_quality_of(const NsMesh *m, const int *tn)
{
    return ns_tet_quality(m->u + 3 * tn[0], m->u + 3 * tn[1], m->u + 3 * tn[2], m->u + 3 * tn[3]);
}

double ns_remesh_node_quality(const NsMesh *m, int n)
{
    double q = INFINITY;
    const NsIntList *l = &m->node_tets[n];
    for (int i = 0; i < l->count; i++)
        q = fmin(q, tet_quality_of(m, m->tet_node + 4 * l->items[i]));
    return q;
}

int ns_remesh_node_on_boundary(const NsMesh *m, int n)
{
    const NsIntList *l = &m->node_tets[n];
    for (int i = 0; i < l->count; i++) {
        int t = l->items[i];
        for (int k = 0; k < 4; k++)
            if (m->tet_adj[4 * t + k] < 0 && m->tet_node[4 * t + k] != n)
                return 1; /* face k (opposite vertex k) holds n and is a boundary face */
    }
    return 0;
}

int ns_remesh_joined(const NsMesh *m, int a, int b)
{
    if (a == b)
        return 1;
    const NsIntList *l = &m->node_tets[a];
    for (int i = 0; i < l->count; i++)
        if (remesh_tet_has(m, l->items[i], b))
            return 1;
    return 0;
}

/* ---- Algorithm 2 ---- */

int ns_quality_vector_cmp(const double *a, int na, const double *b, int nb)
{
    int n = na < nb ? na : nb;
    for (int i = 0; i < n; i++)
        if (a[i] != b[i])
            return a[i] > b[i] ? 1 : -1;
    return (na < nb) - (na > nb); /* fewer tets left to compare: the other has more bad ones */
}

typedef struct Candidate {
    int undo;       /* undo the top of the stack first */
    int kind;       /* NS_REMESH_SNAP or a split's node count */
    int simplex[4]; /* split: its nodes; snap: [0] the snapped node */
    int move;       /* node repositioned on a segment after the operation (-1 none) */
    int seg_b;      /* ... on the segment from the placed node to this one */
    int release;    /* retraction: u1 leaves the needle and goes back to its original position */
} Candidate;

/* Saved state of a node, to put back after scoring. */
typedef struct NodeSave {
    int n;
    double u[3], x[3], v[3], a[3];
} NodeSave;

static void node_save(const NsMesh *m, int n, NodeSave *s)
{
    s->n = n;
    memcpy(s->u, m->u + 3 * n, sizeof s->u);
    memcpy(s->x, m->x + 3 * n, sizeof s->x);
    memcpy(s->v, m->v + 3 * n, sizeof s->v);
    memcpy(s->a, m->a + 3 * n, sizeof s->a);
}

static void node_restore(NsMesh *m, const NodeSave *s)
{
    if (s->n >= 0)
        remesh_set_node(m, s->n, s->u, s->x, s->v, s->a);
}

/* The searches below ask of a trial position only whether node n's worst tet quality beats
 * the best so far. So the scan of its tets stops at the first tet at or below cut, and returns
 * that tet's quality (which answers the question as the full minimum would); above cut it is
 * the full minimum, ns_remesh_node_quality's value. It starts at the tet that was worst at the
 * last call with the same *hint, which rarely changes while one node moves, so a rejected
 * position usually costs one tet instead of twenty. A minimum does not depend on the order it
 * is taken in, so every decision, and the mesh, are the same bits as with full scans. */
static double node_quality_cut(const NsMesh *m, int n, double cut, int *hint)
{
    const NsIntList *l = &m->node_tets[n];
    int count = l->count, start = *hint >= 0 && *hint < count ? *hint : 0;
    double q = INFINITY;
    for (int k = 0; k < count; k++) {
        int i = start + k < count ? start + k : start + k - count;
        double qi = tet_quality_of(m, m->tet_node + 4 * l->items[i]);
        if (qi < q) { /* as fmin: a NaN quality is passed over */
            q = qi;
            *hint = i;
        }
        if (q <= cut)
            break;
    }
    return q;
}

/* Moves node n to the point of segment [p (node pn), node b] that maximizes the worst quality of
 * its tets (16 samples, then golden-section refinement); its world state is interpolated along
 * the segment. */
static void reposition(NsMesh *m, int n, int pn, int b)
{
    double up[3], ub[3], xp[3], xb[3], vp[3], vb[3], ap[3], ab[3];
    memcpy(up, m->u + 3 * pn, sizeof up);
    memcpy(ub, m->u + 3 * b, sizeof ub);
    memcpy(xp, m->x + 3 * pn, sizeof xp);
    memcpy(xb, m->x + 3 * b, sizeof xb);
    memcpy(vp, m->v + 3 * pn, sizeof vp);
    memcpy(vb, m->v + 3 * b, sizeof vb);
    memcpy(ap, m->a + 3 * pn, sizeof ap);
    memcpy(ab, m->a + 3 * b, sizeof ab);
#define AT(s_)                                                                                     \
    do {                                                                                           \
        for (int i_ = 0; i_ < 3; i_++) {                                                           \
            m->u[3 * n + i_] = up[i_] + (s_) * (ub[i_] - up[i_]);                                  \
            m->x[3 * n + i_] = xp[i_] + (s_) * (xb[i_] - xp[i_]);                                  \
            m->v[3 * n + i_] = vp[i_] + (s_) * (vb[i_] - vp[i_]);                                  \
            m->a[3 * n + i_] = ap[i_] + (s_) * (ab[i_] - ap[i_]);                                  \
        }                                                                                          \
    } while (0)
    double best_s = 0.5, best_q = -INFINITY;
    int hint = 0;
    for (int i = 1; i < 16; i++) {
        double sv = i / 16.0;
        AT(sv);
        double q = node_quality_cut(m, n, best_q, &hint);
        if (q > best_q) {
            best_q = q;
            best_s = sv;
        }
    }
    double lo = fmax(best_s - 1.0 / 16, 1e-3), hi = fmin(best_s + 1.0 / 16, 1.0 - 1e-3);
    const double g = 0.5 * (sqrt(5.0) - 1.0);
    for (int it = 0; it < 12; it++) {
        double s1 = hi - g * (hi - lo), s2 = lo + g * (hi - lo);
        AT(s1);
        double q1 = node_quality_cut(m, n, -INFINITY, &hint);
        AT(s2);
        /* q2 matters only above q1 (then it is exact): at or below it, q1 >= q2 holds and q2
         * cannot beat best_q, which q1 has reached. */
        double q2 = node_quality_cut(m, n, q1, &hint);
        if (q1 > best_q) {
            best_q = q1;
            best_s = s1;
        }
        if (q2 > best_q) {
            best_q = q2;
            best_s = s2;
        }
        if (q1 >= q2)
            hi = s2;
        else
            lo = s1;
    }
    AT(best_s);
#undef AT
}

/* Moves node n, which has just left the needle, to the material position that maximizes the
 * worst quality of its tets (Algorithm 2 line 10: "freely optimize the position of u1"). The
 * search is a compass search in 3D started from the better of where the node is and its
 * original position (where it returns when the needle has left; ns_remesh_release_all); its
 * world state is then interpolated at the new point. A boundary node stays: moving it would
 * change the boundary. */
static void place_free(NsMesh *m, const NsRemeshStack *s, int n, int allow_boundary)
{
    const NsIntList *l = &m->node_tets[n];
    if (l->count == 0 || (m->flags[n] & NS_NODE_FIXED) ||
        (!allow_boundary && ns_remesh_node_on_boundary(m, n)))
        return;
    double *un = m->u + 3 * n, u_old[3], p[3], h = 0.0;
    memcpy(u_old, un, sizeof u_old);
    int ne = 0;
    for (int i = 0; i < l->count; i++)
        for (int k = 0; k < 4; k++) {
            int o = m->tet_node[4 * l->items[i] + k];
            if (o != n) {
                double d2 = 0.0;
                for (int j = 0; j < 3; j++)
                    d2 += (m->u[3 * o + j] - un[j]) * (m->u[3 * o + j] - un[j]);
                h += sqrt(d2);
                ne++;
            }
        }
    h = 0.25 * h / ne; /* a quarter of the mean length of the node's edges */
    int hint = 0;
    double best = node_quality_cut(m, n, -INFINITY, &hint), u0[3];
    memcpy(p, un, sizeof p);
    if (ns_remesh_original(s, n, u0)) {
        memcpy(un, u0, sizeof u0);
        double q = node_quality_cut(m, n, best, &hint);
        if (q > best) {
            best = q;
            memcpy(p, u0, sizeof p);
        }
    }
    const double h_min = 1e-3 * h;
    for (int it = 0; it < 200 && h > h_min; it++) {
        int improved = 0;
        for (int d = 0; d < 6 && !improved; d++) {
            memcpy(un, p, sizeof p);
            un[d / 2] += d % 2 ? -h : h;
            double q = node_quality_cut(m, n, best, &hint);
            if (q > best) {
                best = q;
                memcpy(p, un, sizeof p);
                improved = 1;
            }
        }
        if (!improved)
            h *= 0.5;
    }
    /* The world state at p, interpolated in the mesh as it was (n at its old place). */
    memcpy(un, u_old, sizeof u_old);
    double b[4], x[3], v[3], a[3];
    int loc = ns_mesh_locate(m, p, l->items[0], 1e-9, b);
    if (loc < 0)
        return;
    remesh_interp_state(m, loc, b, x, v, a);
    remesh_set_node(m, n, p, x, v, a);
}

/* Tets of a scored region at most. */
#define REGION_CAP 1024

/* The region's tets (incident to the region nodes, alive now), their qualities sorted. */
static int region_quality(const NsMesh *m, const int *nodes, int nn, double *q, int cap)
{
    int *seen = (int *)(q + cap); /* the caller gives 2 cap doubles: tet ids after the values */
    /* The tets seen so far, also in an open-addressed set (the region has ~170 tets on the
     * brachytherapy bench and is scored ~12 times a step: a scan of the list for every
     * incident tet was most of the scoring). The list keeps the order of first sight. */
    enum { SET = 4 * REGION_CAP };
    int set[SET];
    if (cap > REGION_CAP) /* the set stays at most a quarter full */
        cap = REGION_CAP;
    for (int k = 0; k < SET; k++)
        set[k] = -1;
    int n = 0;
    for (int i = 0; i < nn; i++) {
        if (!ns_mesh_node_alive(m, nodes[i]))
            continue;
        const NsIntList *l = &m->node_tets[nodes[i]];
        for (int j = 0; j < l->count; j++) {
            int t = l->items[j];
            unsigned h = ((unsigned)t * 2654435761u) % SET;
            while (set[h] >= 0 && set[h] != t)
                h = (h + 1) % SET;
            if (set[h] == t || n == cap)
                continue;
            set[h] = t;
            seen[n] = t;
            q[n++] = tet_quality_of(m, m->tet_node + 4 * t);
        }
    }
    /* Insertion sort, ascending: the region is small. */
    for (int i = 1; i < n; i++) {
        double v = q[i];
        int j = i - 1;
        while (j >= 0 && q[j] > v) {
            q[j + 1] = q[j];
            j--;
        }
        q[j + 1] = v;
    }
    return n;
}

/* The worst dihedral angle of tets ids[0 .. n) in material space [deg]. */
static double region_min_dihedral(const NsMesh *m, const int *ids, int n)
{
    double lo = 180.0;
    for (int k = 0; k < n; k++) {
        const int *tn = m->tet_node + 4 * ids[k];
        lo = fmin(lo, ns_tet_min_dihedral(m->u + 3 * tn[0], m->u + 3 * tn[1], m->u + 3 * tn[2],
                                          m->u + 3 * tn[3]));
    }
    return lo;
}

typedef struct Applied {
    int ok;
    int placed; /* the node at u_new */
    int pushed; /* a split was pushed */
    int undone; /* the top was undone (its state saved in `top`) */
    NodeSave snap, moved, released, undone_node;
    NsRemeshOp top; /* copy of the undone operation's simplex/kind */
    double top_u[3];
} Applied;

/* Gives node n (just placed at its material position) the world state xva (x, v, a) unless
 * one of its tets would be inverted in the world with it; then n keeps the state it has. */
static void keep_world_state(NsMesh *m, int n, const double xva[9])
{
    NodeSave was;
    node_save(m, n, &was);
    remesh_set_node(m, n, was.u, xva, xva + 3, xva + 6);
    const NsIntList *l = &m->node_tets[n];
    for (int i = 0; i < l->count; i++) {
        const int *tn = m->tet_node + 4 * l->items[i];
        if (!(ns_tet_volume(m->x + 3 * tn[0], m->x + 3 * tn[1], m->x + 3 * tn[2],
                            m->x + 3 * tn[3]) > 0.0)) {
            node_restore(m, &was);
            return;
        }
    }
}

/* Applies candidate c for u_new (the caller checks the result); returns 0 or -1 (not
 * applicable: the mesh is then as before). xva: the world state (x, v, a) at u_new in the mesh
 * before the operation, which the placed node takes. */
static int apply(NsMesh *m, NsRemeshStack *s, const NsRemeshTip *tip, const Candidate *c,
                 const double u_new[3], const double xva[9], Applied *ap)
{
    memset(ap, 0, sizeof *ap);
    ap->snap.n = ap->moved.n = ap->released.n = ap->undone_node.n = -1;
    if (c->undo) {
        NsRemeshOp *op = &s->ops[s->count - 1];
        node_save(m, op->node, &ap->undone_node);
        ap->top.kind = op->kind;
        memcpy(ap->top.simplex, op->simplex, sizeof op->simplex);
        memcpy(ap->top_u, m->u + 3 * op->node, sizeof ap->top_u);
        if (ns_remesh_undo(m, s))
            return -1;
        ap->undone = 1;
    }
    int placed = -1;
    if (c->kind == NS_REMESH_SNAP) {
        int n = c->simplex[0];
        if (!ns_mesh_node_alive(m, n) || (m->flags[n] & NS_NODE_FIXED))
            goto fail;
        node_save(m, n, &ap->snap);
        NsRemeshStack dummy; /* snaps while scoring must not record originals */
        ns_remesh_stack_init(&dummy);
        int rc = ns_remesh_snap(m, &dummy, n, u_new);
        ns_remesh_stack_free(&dummy);
        if (rc)
            goto fail;
        placed = n;
    } else {
        placed = ns_remesh_split(m, s, c->simplex, c->kind, u_new);
        if (placed < 0)
            goto fail;
        ap->pushed = 1;
    }
    ap->placed = placed;
    /* After an undo (lines 6-8), where the tip asks for it, the placed node takes the world
     * state of u_new in the mesh before the operation (with the tip's node): the undo removes
     * the tip's node first, so the split would take it from the tets around the undone node, the
     * tissue away from the needle, and the tip jumped sideways to their interpolated
     * displacement (0.2-0.7 mm in double-bend). Without an undo the operation interpolates in
     * that same mesh. */
    if (ap->undone && tip->undo_keeps_world)
        keep_world_state(m, placed, xva);
    if (c->release) {
        /* u1 leaves the needle and moves freely (line 10): to the best place for its tets. */
        node_save(m, tip->u1, &ap->released);
        place_free(m, s, tip->u1, tip->allow_boundary);
    }
    /* The needle node behind the new tip slides to its best place on the segment, unless it
     * is fixed or on the boundary (moving it would change the boundary; skin entry allows). */
    if (c->move >= 0 && ns_mesh_node_alive(m, c->move) && ns_mesh_node_alive(m, c->seg_b) &&
        !(m->flags[c->move] & NS_NODE_FIXED) && c->move != placed &&
        (tip->allow_boundary || !ns_remesh_node_on_boundary(m, c->move))) {
        node_save(m, c->move, &ap->moved);
        reposition(m, c->move, placed, c->seg_b);
    }
    ap->ok = 1;
    return 0;
fail:
    if (ap->undone) {
        /* Redo the undone split exactly (same node and slots, LIFO free lists) and its state. */
        ns_remesh_split(m, s, ap->top.simplex, (int)ap->top.kind, ap->top_u);
        node_restore(m, &ap->undone_node);
        ap->undone = 0;
    }
    return -1;
}

/* Reverts what apply did. */
static void revert(NsMesh *m, NsRemeshStack *s, Applied *ap)
{
    node_restore(m, &ap->moved);
    node_restore(m, &ap->released);
    if (ap->pushed)
        ns_remesh_undo(m, s);
    node_restore(m, &ap->snap);
    if (ap->undone) {
        ns_remesh_split(m, s, ap->top.simplex, (int)ap->top.kind, ap->top_u);
        node_restore(m, &ap->undone_node);
    }
}

/* The fifteen standard operations on tet t placing a node at u_new: 4 snaps, 6 edge splits,
 * 4 face splits, the tet split. */
static int standard_ops(const NsMesh *m, int t, Candidate *out)
{
    const int *tn = m->tet_node + 4 * t;
    int n = 0;
    for (int i = 0; i < 4; i++)
        out[n++] = (Candidate){0, NS_REMESH_SNAP, {tn[i], -1, -1, -1}, -1, -1, 0};
    for (int i = 0; i < 4; i++)
        for (int j = i + 1; j < 4; j++)
            out[n++] = (Candidate){0, 2, {tn[i], tn[j], -1, -1}, -1, -1, 0};
    for (int f = 0; f < 4; f++)
        out[n++] = (Candidate){
            0,  3,  {tn[ns_tet_face[f][0]], tn[ns_tet_face[f][1]], tn[ns_tet_face[f][2]], -1},
            -1, -1, 0};
    out[n++] = (Candidate){0, 4, {tn[0], tn[1], tn[2], tn[3]}, -1, -1, 0};
    return n;
}

static int chain_index(const NsRemeshTip *tip, int n)
{
    for (int i = 0; i < tip->chain_len; i++)
        if (tip->chain[i] == n)
            return i;
    return -1;
}

/* Would the candidate move a needle node off the needle or split a needle segment? Snapping is
 * allowed for u1 (the tip snap) and for u2 when u1 leaves (undo or release); a split may not
 * contain two consecutive needle nodes, except u1-u2 when u1 leaves (released, or undone). */
static int breaks_chain(const NsRemeshTip *tip, const Candidate *c)
{
    if (c->kind == NS_REMESH_SNAP) {
        int n = c->simplex[0], i = chain_index(tip, n);
        if (i < 0 || n == tip->u1)
            return 0;
        /* u2 takes the tip only if a node stays behind it (the chain never folds onto one). */
        return !(n == tip->u2 && tip->u3 >= 0 && (c->undo || c->release));
    }
    for (int a = 0; a < c->kind; a++)
        for (int b = 0; b < c->kind; b++) {
            int ia = chain_index(tip, c->simplex[a]), ib = chain_index(tip, c->simplex[b]);
            if (ia < 0 || ib != ia + 1)
                continue;
            if (c->release && ia == 0)
                continue; /* u1 leaves: the placed node may sit on the u1-u2 segment */
            if (c->undo && ia == 0)
                continue; /* u1 is gone after the undo */
            return 1;
        }
    return 0;
}

/* Algorithm 2's candidate operations for the tip at u_new in tet t: line 2 (the tip node
 * snaps), line 5 (penetrating: a node at u_new, u1 sliding), line 10 (retracting: u1 leaves the
 * needle), lines 6-8 (the split that made u1 undone first: top_made_u1) and our addition for a
 * snapped tip. undo_nodes: the tet holding u_new after that undo (-1s: none). Returns the
 * count. */
static int tip_candidates(NsMesh *m, NsRemeshStack *s, const NsRemeshTip *tip, int t,
                          const double u_new[3], int top_made_u1, Candidate *cand,
                          int undo_nodes[4])
{
    int u1 = tip->u1, u2 = tip->u2, u3 = tip->u3;
    int nc = 0;
    /* Line 2: the tip node snaps to u_new. */
    cand[nc++] = (Candidate){0, NS_REMESH_SNAP, {u1, -1, -1, -1}, -1, -1, 0};
    Candidate std[15];
    int ns = standard_ops(m, t, std);
    if (tip->penetrating) {
        /* Line 5: a node other than u1 at u_new, joined to u1; u1 then slides on [u_new, u2]. */
        for (int i = 0; i < ns; i++) {
            if (std[i].kind == NS_REMESH_SNAP && std[i].simplex[0] == u1)
                continue;
            Candidate c = std[i];
            c.move = u1;
            c.seg_b = u2;
            cand[nc++] = c;
        }
        /* Our addition: when u1 was placed by a snap, it may leave the needle (as a split u1 is
         * undone, lines 6-8), moving freely; a node at u_new joined to (or being) u2, which
         * slides on [u_new, u3]. Without it a snapped tip can only drag its node along. */
        if (!top_made_u1 && u3 >= 0)
            for (int i = 0; i < ns && nc < 64; i++) {
                if (std[i].kind == NS_REMESH_SNAP && std[i].simplex[0] == u1)
                    continue;
                Candidate c = std[i];
                c.release = 1;
                c.move = u2;
                c.seg_b = u3;
                cand[nc++] = c;
            }
    } else if (!top_made_u1) {
        /* Line 10: a node at u_new joined to (or being) u2; u1 leaves the needle. */
        for (int i = 0; i < ns; i++) {
            if (std[i].kind == NS_REMESH_SNAP && std[i].simplex[0] == u1)
                continue;
            Candidate c = std[i];
            c.release = 1;
            cand[nc++] = c;
        }
    }
    int t_undo = -1;
    if (top_made_u1) {
        /* Lines 6-8: undo the split that made u1, then a standard operation on the tet that will
         * contain u_new, joined to (or being) u2; u2 then slides on [u_new, u3]. The tet after
         * the undo is found by doing the undo and redoing it. */
        NsRemeshOp *op = &s->ops[s->count - 1];
        NodeSave keep;
        node_save(m, op->node, &keep);
        NsRemeshKind kind = op->kind;
        int simplex[4];
        memcpy(simplex, op->simplex, sizeof simplex);
        double uo[3];
        memcpy(uo, m->u + 3 * op->node, sizeof uo);
        if (ns_remesh_undo(m, s) == 0) {
            t_undo = ns_mesh_locate(
                m, u_new, m->node_tets[u2].count ? m->node_tets[u2].items[0] : -1, 1e-9, NULL);
            if (t_undo >= 0)
                memcpy(undo_nodes, m->tet_node + 4 * t_undo, 4 * sizeof *undo_nodes);
            Candidate su[15];
            int nsu = t_undo >= 0 ? standard_ops(m, t_undo, su) : 0;
            for (int i = 0; i < nsu && nc < 64; i++) {
                Candidate c = su[i];
                c.undo = 1;
                c.move = u3 >= 0 ? u2 : -1;
                c.seg_b = u3;
                cand[nc++] = c;
            }
            ns_remesh_split(m, s, simplex, (int)kind, uo);
            node_restore(m, &keep);
        }
    }
    return nc;
}

static void add_node(int *rn, int *nrn, int n)
{
    int d = 0;
    for (int k = 0; k < *nrn && !d; k++)
        d = rn[k] == n;
    if (!d && n >= 0 && *nrn < 64)
        rn[(*nrn)++] = n;
}

/* The region scored: the nodes of t (and of the tet after an undo), u1, u2, u3 and u1's
 * neighbours, at most 64 (rn). Returns the count. */
static int tip_region(const NsMesh *m, const NsRemeshTip *tip, int t, const int undo_nodes[4],
                      int *rn)
{
    int nrn = 0, u1 = tip->u1, u2 = tip->u2, u3 = tip->u3;
    for (int k = 0; k < 4; k++) {
        add_node(rn, &nrn, m->tet_node[4 * t + k]);
        add_node(rn, &nrn, undo_nodes[k]);
    }
    add_node(rn, &nrn, u1);
    add_node(rn, &nrn, u2);
    add_node(rn, &nrn, u3);
    const NsIntList *l1 = &m->node_tets[u1];
    for (int i = 0; i < l1->count; i++)
        for (int k = 0; k < 4; k++)
            add_node(rn, &nrn, m->tet_node[4 * l1->items[i] + k]);
    return nrn;
}

/* Scores every candidate that keeps the needle's chain: applied, checked (the chain joined,
 * the boundary kept unless allowed, no tet inverted), its region's quality vector taken, and
 * reverted. The best ranks first by the region's worst dihedral angle clipped at the floor
 * (ours), then by the paper's lexicographic quality vector. qbest, qcur: (4 REGION_CAP)
 * scratch; qbest holds the best's vector. Counts res->candidates. Returns the best, or -1. */
static int best_candidate(NsMesh *m, NsRemeshStack *s, const NsRemeshTip *tip,
                          const Candidate *cand, int nc, const int *rn, int nrn,
                          const double u_new[3], const double xva[9], double *qbest, double *qcur,
                          NsRemeshResult *res)
{
    int best = -1, nbest = 0;
    double dbest = 0.0, floor_deg = tip->dihedral_floor_deg;
    int u1 = tip->u1, u2 = tip->u2;
    for (int i = 0; i < nc; i++) {
        const Candidate *c = &cand[i];
        if (breaks_chain(tip, c))
            continue;
        Applied ap;
        if (apply(m, s, tip, c, u_new, xva, &ap))
            continue;
        int ok = 1;
        /* Connectivity of the needle's chain. */
        if (c->undo || c->release)
            ok = ns_remesh_joined(m, ap.placed, u2);
        else if (c->kind != NS_REMESH_SNAP || c->simplex[0] != u1)
            ok = ns_remesh_joined(m, ap.placed, u1);
        /* The boundary: a placed or moved boundary node changes it. */
        if (ok && !tip->allow_boundary) {
            if (ns_remesh_node_on_boundary(m, ap.placed))
                ok = 0;
            if (ap.moved.n >= 0 && ns_remesh_node_on_boundary(m, ap.moved.n))
                ok = 0;
        }
        int nq = 0;
        if (ok) {
            int rn2[65];
            memcpy(rn2, rn, (size_t)nrn * sizeof *rn2);
            rn2[nrn] = ap.placed;
            nq = region_quality(m, rn2, nrn + 1, qcur, REGION_CAP);
            ok = nq > 0 && qcur[0] > 0.0;
        }
        /* Our addition: the region's worst dihedral angle, clipped at the floor, ranks first. A
         * tet's quality can stay fair with a flat dihedral angle (a sliver-like cap); ranking
         * by quality alone let 8.8 deg angles through in remesh-cycles with skin entry. */
        double dcur =
            ok && floor_deg > 0.0
                ? fmin(region_min_dihedral(m, (const int *)(qcur + REGION_CAP), nq), floor_deg)
                : 0.0;
        if (ok) {
            res->candidates++;
            if (best < 0 || dcur > dbest ||
                (dcur == dbest && ns_quality_vector_cmp(qcur, nq, qbest, nbest) > 0)) {
                best = i;
                dbest = dcur;
                nbest = nq;
                memcpy(qbest, qcur, (size_t)nq * sizeof *qbest);
            }
        }
        revert(m, s, &ap);
    }
    return best;
}

/* The repair (sim/remesh_repair.c) after the chosen operation: the free nodes of the region's
 * tets below the floor (angles too small, or too large) move, where one is 1.5 deg or more
 * below it. The needle's nodes stay: the chain as it was, the placed node and the one slid
 * along the needle. qcur: (4 REGION_CAP) scratch. Returns 0, or -1 (memory). */
static int repair_region(NsMesh *m, NsRemeshStack *s, const NsRemeshTip *tip, const Applied *ap,
                         const int *rn, int nrn, double *qcur, NsRemeshResult *res, char *err,
                         int err_sz)
{
    double floor_deg = tip->dihedral_floor_deg;
    if (!(floor_deg > 0.0))
        return 0;
    int *pin = malloc((size_t)(tip->chain_len + 2) * sizeof *pin);
    if (!pin) {
        snprintf(err, (size_t)err_sz, "remesh: out of memory for the repair");
        return -1;
    }
    int np = 0;
    for (int i = 0; i < tip->chain_len; i++)
        pin[np++] = tip->chain[i];
    pin[np++] = ap->placed;
    if (ap->moved.n >= 0)
        pin[np++] = ap->moved.n;
    int rn2[65];
    memcpy(rn2, rn, (size_t)nrn * sizeof *rn2);
    rn2[nrn] = ap->placed;
    int nq = region_quality(m, rn2, nrn + 1, qcur, REGION_CAP);
    res->repaired =
        ns_remesh_repair(m, s, (const int *)(qcur + REGION_CAP), nq, pin, np, floor_deg);
    free(pin);
    return 0;
}

int ns_remesh_tip(NsMesh *m, NsRemeshStack *s, NsRemeshTip *tip, const double u_new[3],
                  NsRemeshResult *res, char *err, int err_sz)
{
    memset(res, 0, sizeof *res);
    int u1 = tip->u1;
    if (!ns_mesh_node_alive(m, u1) || !ns_mesh_node_alive(m, tip->u2)) {
        snprintf(err, (size_t)err_sz, "remesh: the needle's tip nodes are not alive");
        return -1;
    }
    double bt[4], xva[9];
    int t = ns_mesh_locate(m, u_new, tip->hint_tet, 1e-9, bt);
    if (t < 0) {
        snprintf(err, (size_t)err_sz, "remesh: the tip (%.4g, %.4g, %.4g) m is outside the tissue",
                 u_new[0], u_new[1], u_new[2]);
        return -1;
    }
    remesh_interp_state(m, t, bt, xva, xva + 3, xva + 6);
    int top_made_u1 = s->count > 0 && s->ops[s->count - 1].node == u1;
    Candidate cand[64];
    int undo_nodes[4] = {-1, -1, -1, -1};
    int nc = tip_candidates(m, s, tip, t, u_new, top_made_u1, cand, undo_nodes);
    int rn[64], nrn = tip_region(m, tip, t, undo_nodes, rn);
    double *qbest = malloc(4 * REGION_CAP * sizeof *qbest);
    if (!qbest) {
        snprintf(err, (size_t)err_sz, "remesh: out of memory");
        return -1;
    }
    double *qcur = qbest + 2 * REGION_CAP;
    int best = best_candidate(m, s, tip, cand, nc, rn, nrn, u_new, xva, qbest, qcur, res);
    if (best < 0) {
        free(qbest);
        snprintf(err, (size_t)err_sz,
                 "remesh: no valid operation places the tip at (%.4g, %.4g, %.4g) m", u_new[0],
                 u_new[1], u_new[2]);
        return -1;
    }
    Applied ap;
    const Candidate *c = &cand[best];
    if (apply(m, s, tip, c, u_new, xva, &ap)) {
        free(qbest);
        snprintf(err, (size_t)err_sz, "remesh: the chosen operation failed");
        return -1;
    }
    if (c->kind == NS_REMESH_SNAP) {
        /* Record the first original position of the snapped node (scoring did not). */
        double u0[3];
        int n = c->simplex[0];
        if (!ns_remesh_original(s, n, u0)) {
            NodeSave now;
            node_save(m, n, &now);
            node_restore(m, &ap.snap);
            ns_remesh_snap(m, s, n, now.u);
            node_restore(m, &now);
        }
    }
    if (repair_region(m, s, tip, &ap, rn, nrn, qcur, res, err, err_sz)) {
        free(qbest);
        return -1;
    }
    res->kind = c->kind == NS_REMESH_SNAP ? NS_REMESH_SNAP : (NsRemeshKind)c->kind;
    res->undone = c->undo;
    res->tip = ap.placed;
    res->dropped = c->undo || c->release;
    res->min_quality = qbest[0];
    tip->hint_tet = m->node_tets[ap.placed].count ? m->node_tets[ap.placed].items[0] : -1;
    free(qbest);
    return 0;
}
