/* Isosurface stuffing, single and multi-region (Labelle & Shewchuk 2007, "Isosurface Stuffing:
 * Fast Tetrahedral Meshes with Good Dihedral Angles"; below "L&S").
 *
 * Outline (ns_mesher_stuff):
 *   1. lay a body-centred cubic (BCC) lattice over the box and label its vertices by region;
 *   2. cut every lattice edge whose endpoints have different labels (bisection on the label);
 *   3. warp lattice vertices that lie too close to a cut point onto it (L&S §3);
 *   4. fill every lattice tet from the stencil table (L&S §3), on both sides of the interface
 *      it holds, with a cone fallback for the rare tet that holds three labels;
 *   5. flag nodes of fixed regions and compact the mesh.
 *
 * Combinatorics never look at floating-point positions: lattice vertices live on an integer
 * grid of half-units (cube corners have even coordinates, cube centres odd ones), and every
 * choice (edge identity, quad diagonals, visiting order) is a function of those integers. Only
 * the cut positions, the warped positions and the label function are floating point. */
#include "mesher.h"
#include "ns_limits.h"

#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "err.h"
#include "quality.h"

enum { OUTSIDE = -1 };

/* L&S's published warp thresholds: with them every dihedral angle of a one-surface mesh lies
 * in [10.7, 164.8] degrees (the paper's main result). */
#define NS_ALPHA_LONG  0.24999
#define NS_ALPHA_SHORT 0.41189
/* Thresholds for interfaces meshed on both sides (between two regions). There a lattice tet
 * whose four vertices were all warped must be kept - dropping it would open a crack - and with
 * the one-sided thresholds such a tet can be nearly flat (we measured 7.5 degrees). These are
 * the "two-sided" values other implementations of L&S use; we did not find their bound in the
 * paper and rely on our measurements (docs/mesher.md). */
#define NS_ALPHA2_LONG          0.21509
#define NS_ALPHA2_SHORT         0.35900
#define NS_MAX_LATTICE_VERTICES 50000000LL
/* Peak bytes a lattice vertex costs, the mesh built from it included: 513 measured on a 0.1 m
 * gel box at 1.4 mm (827,099 lattice vertices, 4.4 million tets, 415 MB peak resident for
 * `needlesim check`), rounded up. */
#define NS_MESHER_BYTES_PER_VERTEX 560.0
#define NS_BISECTION_STEPS         40

NsMesherDef ns_default_mesher_def(void)
{
    NsMesherDef d;
    memset(&d, 0, sizeof d);
    d.spacing = 0.0;
    d.alpha_long = NS_ALPHA_LONG;
    d.alpha_short = NS_ALPHA_SHORT;
    d.lo[0] = 1.0; /* lo > hi: take the box from the regions */
    d.hi[0] = -1.0;
    return d;
}

/* ---- open-addressing map from a 64-bit edge key to a cut index ------------------------------ */

typedef struct EdgeMap {
    uint64_t *keys; /* 0 = empty (keys are stored + 1) */
    int *vals;
    size_t cap; /* power of two */
    size_t count;
} EdgeMap;

static size_t hash_key(uint64_t k)
{
    k ^= k >> 33;
    k *= 0xff51afd7ed558ccdULL;
    k ^= k >> 33;
    k *= 0xc4ceb9fe1a85ec53ULL;
    k ^= k >> 33;
    return (size_t)k;
}

static int map_grow(EdgeMap *m)
{
    size_t cap = m->cap ? 2 * m->cap : 1024;
    uint64_t *keys = calloc(cap, sizeof *keys);
    int *vals = malloc(cap * sizeof *vals);
    if (!keys || !vals) {
        free(keys);
        free(vals);
        return -1;
    }
    for (size_t i = 0; i < m->cap; i++) {
        if (!m->keys[i])
            continue;
        size_t j = hash_key(m->keys[i]) & (cap - 1);
        while (keys[j])
            j = (j + 1) & (cap - 1);
        keys[j] = m->keys[i];
        vals[j] = m->vals[i];
    }
    free(m->keys);
    free(m->vals);
    m->keys = keys;
    m->vals = vals;
    m->cap = cap;
    return 0;
}

static int map_put(EdgeMap *m, uint64_t key, int val)
{
    if (2 * (m->count + 1) > m->cap && map_grow(m))
        return -1;
    uint64_t k = key + 1;
    size_t j = hash_key(k) & (m->cap - 1);
    while (m->keys[j] && m->keys[j] != k)
        j = (j + 1) & (m->cap - 1);
    if (!m->keys[j])
        m->count++;
    m->keys[j] = k;
    m->vals[j] = val;
    return 0;
}

static int map_get(const EdgeMap *m, uint64_t key)
{
    if (!m->cap)
        return -1;
    uint64_t k = key + 1;
    size_t j = hash_key(k) & (m->cap - 1);
    while (m->keys[j]) {
        if (m->keys[j] == k)
            return m->vals[j];
        j = (j + 1) & (m->cap - 1);
    }
    return -1;
}

/* ---- the lattice ---------------------------------------------------------------------------- */

typedef struct Cut {
    double p[3]; /* position [m] */
    double t;    /* parameter from the edge's base vertex (0) to its other end (1) */
    int64_t
        base; /* vertex ids: base is the lower end of a long edge or the centre of a short one */
    int64_t other;
    int alive; /* 0 once an endpoint has been warped (L&S §3) */
    int node;  /* output node, -1 until used */
} Cut;

typedef struct Ctx {
    const NsMesherDef *def;
    double lo[3]; /* corner (i, j, k) sits at lo + h (i, j, k) */
    double h;
    int nc[3]; /* corners per axis; corner half-unit coordinate I = 2 (i + 1) */
    int nz[3]; /* centres per axis; centre half-unit coordinate I = 2 m + 1 */
    int64_t ncorner, nvert;
    int *label;        /* (nvert) region index or OUTSIDE */
    int *warp;         /* (nvert) cut the vertex was warped onto, or -1 */
    int *node;         /* (nvert) output node, or -1 */
    uint8_t *near_cut; /* (nvert) 1 if some adjacent edge was cut */
    Cut *cuts;
    int ncuts, cuts_cap;
    EdgeMap map;
    /* region bounds, slightly enlarged, to skip evaluations far from a region */
    double (*rlo)[3], (*rhi)[3];
    bool *rbounded;
    /* first NaN met */
    bool nan;
    double nan_p[3];
    bool oom;
    NsMesh *out;
    NsMesherStats stats;
} Ctx;

static int64_t vertex_id(const Ctx *c, const int I[3])
{
    for (int a = 0; a < 3; a++)
        if (I[a] < 0 || I[a] > 2 * (c->nc[a] - 1))
            return -1;
    if ((I[0] & 1) == 0) {
        return (int64_t)(I[0] / 2) +
               (int64_t)c->nc[0] * ((int64_t)(I[1] / 2) + (int64_t)c->nc[1] * (I[2] / 2));
    }
    return c->ncorner + (int64_t)((I[0] - 1) / 2) +
           (int64_t)c->nz[0] * ((int64_t)((I[1] - 1) / 2) + (int64_t)c->nz[1] * ((I[2] - 1) / 2));
}

static void vertex_coords(const Ctx *c, int64_t id, int I[3])
{
    if (id < c->ncorner) {
        I[0] = (int)(id % c->nc[0]) * 2;
        id /= c->nc[0];
        I[1] = (int)(id % c->nc[1]) * 2;
        I[2] = (int)(id / c->nc[1]) * 2;
    } else {
        id -= c->ncorner;
        I[0] = (int)(id % c->nz[0]) * 2 + 1;
        id /= c->nz[0];
        I[1] = (int)(id % c->nz[1]) * 2 + 1;
        I[2] = (int)(id / c->nz[1]) * 2 + 1;
    }
}

/* Corner coordinate I = 2 (i + 1) sits at lo + h i = lo + (h / 2)(I - 2); both factors are
 * exact multiples for corners, so a box face on lo + k h is hit exactly. */
static void lattice_pos(const Ctx *c, const int I[3], double p[3])
{
    for (int a = 0; a < 3; a++)
        p[a] = c->lo[a] + (0.5 * c->h) * (double)(I[a] - 2);
}

/* A lattice edge between half-unit points A and B (a long edge differs by 2 along one axis, a
 * short one by 1 along all three) gets a key from its base vertex and its direction. */
static uint64_t edge_key(const Ctx *c, const int A[3], const int B[3], int64_t *base,
                         int64_t *other, bool *is_long)
{
    int d[3] = {B[0] - A[0], B[1] - A[1], B[2] - A[2]};
    int code;
    const int *Pb, *Po;
    if (abs(d[0]) == 1) { /* short: base is the centre (odd coordinates) */
        bool a_centre = (A[0] & 1) != 0;
        Pb = a_centre ? A : B;
        Po = a_centre ? B : A;
        code = 3 + (Po[0] > Pb[0]) + 2 * (Po[1] > Pb[1]) + 4 * (Po[2] > Pb[2]);
        *is_long = false;
    } else {
        int ax = d[0] ? 0 : d[1] ? 1 : 2;
        Pb = d[ax] > 0 ? A : B;
        Po = d[ax] > 0 ? B : A;
        code = ax;
        *is_long = true;
    }
    *base = vertex_id(c, Pb);
    *other = vertex_id(c, Po);
    return (uint64_t)*base * 16u + (uint64_t)code;
}

/* The label function: the last region containing p (later regions paint over earlier ones),
 * or OUTSIDE. A NaN is recorded and reported by the caller. */
static int label_at(Ctx *c, const double p[3])
{
    const NsMesherDef *def = c->def;
    for (int r = def->region_count - 1; r >= 0; r--) {
        if (c->rbounded[r]) {
            if (p[0] < c->rlo[r][0] || p[0] > c->rhi[r][0] || p[1] < c->rlo[r][1] ||
                p[1] > c->rhi[r][1] || p[2] < c->rlo[r][2] || p[2] > c->rhi[r][2])
                continue;
        }
        double v = ns_shape_eval(def->regions[r].shape, p);
        if (isnan(v)) {
            if (!c->nan) {
                c->nan = true;
                memcpy(c->nan_p, p, sizeof c->nan_p);
            }
            return OUTSIDE;
        }
        if (v <= 0.0)
            return r;
    }
    return OUTSIDE;
}

static int add_cut(Ctx *c, const int Ib[3], const int Io[3], int64_t base, int64_t other,
                   uint64_t key)
{
    if (c->ncuts == c->cuts_cap) {
        int cap = c->cuts_cap ? 2 * c->cuts_cap : 1024;
        Cut *nc = realloc(c->cuts, (size_t)cap * sizeof *nc);
        if (!nc)
            return -1;
        c->cuts = nc;
        c->cuts_cap = cap;
    }
    double pb[3], po[3], q[3];
    lattice_pos(c, Ib, pb);
    lattice_pos(c, Io, po);
    /* Bisection on the label: keep label(t0) == label(base) and label(t1) != label(base). It
     * is deterministic and needs only the sign of the shapes (L&S only need some point where
     * the region changes). Of the two final ends we return the one in the later region (the
     * region that was painted last, OUTSIDE counting as earliest): its set {eval <= 0} is
     * closed, so a surface that passes exactly through a probe point - a box face on a lattice
     * plane, a surface through a lattice vertex - is met exactly, not 2^-40 off. */
    int l0 = c->label[base], l1 = c->label[other];
    double t0 = 0.0, t1 = 1.0;
    for (int it = 0; it < NS_BISECTION_STEPS; it++) {
        double tm = 0.5 * (t0 + t1);
        for (int a = 0; a < 3; a++)
            q[a] = (1.0 - tm) * pb[a] + tm * po[a];
        int l = label_at(c, q);
        if (l == l0) {
            t0 = tm;
        } else {
            t1 = tm;
            l1 = l;
        }
    }
    double t = l0 > l1 ? t0 : t1;
    Cut *k = &c->cuts[c->ncuts];
    for (int a = 0; a < 3; a++)
        k->p[a] = (1.0 - t) * pb[a] + t * po[a];
    k->t = t;
    k->base = base;
    k->other = other;
    k->alive = 1;
    k->node = -1;
    if (map_put(&c->map, key, c->ncuts))
        return -1;
    c->near_cut[base] = 1;
    c->near_cut[other] = 1;
    c->ncuts++;
    return 0;
}

/* Half-unit offsets of the 14 lattice neighbours: 6 along the axes (long edges), 8 diagonal
 * (short edges; only centres and corners are diagonal neighbours of each other, which holds
 * automatically since the parities differ). */
static const int nbr_off[14][3] = {
    {2, 0, 0},   {-2, 0, 0},  {0, 2, 0},  {0, -2, 0},  {0, 0, 2},  {0, 0, -2}, {-1, -1, -1},
    {1, -1, -1}, {-1, 1, -1}, {1, 1, -1}, {-1, -1, 1}, {1, -1, 1}, {-1, 1, 1}, {1, 1, 1},
};

static int compute_cuts(Ctx *c)
{
    for (int64_t u = 0; u < c->nvert; u++) {
        int U[3];
        vertex_coords(c, u, U);
        /* Each edge once: long edges from their lower end, short edges from their centre. */
        int first = 0, last = (U[0] & 1) ? 14 : 6;
        for (int n = first; n < last; n++) {
            if (n < 6 && (n & 1))
                continue; /* the -axis long edges belong to the other end */
            int V[3] = {U[0] + nbr_off[n][0], U[1] + nbr_off[n][1], U[2] + nbr_off[n][2]};
            int64_t v = vertex_id(c, V);
            if (v < 0 || c->label[u] == c->label[v])
                continue;
            int64_t base, other;
            bool is_long;
            uint64_t key = edge_key(c, U, V, &base, &other, &is_long);
            if (add_cut(c, base == u ? U : V, base == u ? V : U, base, other, key))
                return -1;
            if (c->nan)
                return 0;
        }
    }
    return 0;
}

/* L&S §3 warping: a lattice vertex closer than alpha (a fraction of the edge) to a cut point on
 * one of its edges moves onto the closest such cut point (relative to its edge), becomes part
 * of the interface, and every cut on its edges is discarded. Visiting in vertex id order makes
 * it deterministic; the cut points themselves were all computed on the unwarped lattice.
 * Cuts on the outer boundary (a region against OUTSIDE) use the caller's alphas; cuts between
 * two regions use at most the two-sided ones (NS_ALPHA2_*), see stuff_tet. */
static void warp_vertices(Ctx *c)
{
    const double alpha_long = c->def->alpha_long, alpha_short = c->def->alpha_short;
    for (int64_t v = 0; v < c->nvert; v++) {
        if (!c->near_cut[v])
            continue;
        int V[3];
        vertex_coords(c, v, V);
        int cut_ids[14];
        int best = -1;
        double best_rel = INFINITY;
        for (int n = 0; n < 14; n++) {
            cut_ids[n] = -1;
            int W[3] = {V[0] + nbr_off[n][0], V[1] + nbr_off[n][1], V[2] + nbr_off[n][2]};
            if (vertex_id(c, W) < 0)
                continue;
            int64_t base, other;
            bool is_long;
            uint64_t key = edge_key(c, V, W, &base, &other, &is_long);
            int k = map_get(&c->map, key);
            if (k < 0 || !c->cuts[k].alive)
                continue;
            cut_ids[n] = k;
            double rel = base == v ? c->cuts[k].t : 1.0 - c->cuts[k].t;
            bool internal =
                c->label[c->cuts[k].base] != OUTSIDE && c->label[c->cuts[k].other] != OUTSIDE;
            double alpha = is_long ? (internal ? fmin(alpha_long, NS_ALPHA2_LONG) : alpha_long)
                                   : (internal ? fmin(alpha_short, NS_ALPHA2_SHORT) : alpha_short);
            if (rel < alpha && rel < best_rel) {
                best_rel = rel;
                best = k;
            }
        }
        if (best < 0)
            continue;
        c->warp[v] = best;
        c->stats.warped_vertices++;
        for (int n = 0; n < 14; n++)
            if (cut_ids[n] >= 0)
                c->cuts[cut_ids[n]].alive = 0;
    }
}

/* ---- one lattice tet ------------------------------------------------------------------------ */

/* Points of a lattice tet's stencils: 0..3 its vertices, 4 + e the cut on local edge e, and
 * CENTROID the junction fallback's extra vertex. */
enum { CENTROID = 10, MAX_OUT = 24 };

static const int edge_of[4][4] = {
    {-1, 0, 1, 2},
    {0, -1, 3, 4},
    {1, 3, -1, 5},
    {2, 4, 5, -1},
};

static int cut_pt(int i, int j)
{
    return 4 + edge_of[i][j];
}

typedef struct Local {
    int64_t id[4];
    int I[4][3];  /* half-unit coordinates */
    int lab[4];   /* label, meaningless where zero[] */
    bool zero[4]; /* warped onto the interface */
    /* Local vertices 0-1 and 2-3 are the tet's two long edges (so i ^ 1 is i's long partner);
     * the other four edges are short. */
} Local;

typedef struct TetOut {
    int v[MAX_OUT][4];
    int lab[MAX_OUT];
    int n;
} TetOut;

static void push_tet(TetOut *o, int a, int b, int cc, int d, int lab)
{
    o->v[o->n][0] = a;
    o->v[o->n][1] = b;
    o->v[o->n][2] = cc;
    o->v[o->n][3] = d;
    o->lab[o->n] = lab;
    o->n++;
}

/* Diagonal of the quad (P, Q, c(QR), c(PR)) that a lattice face (P, Q, R) leaves when P and Q
 * are kept and R is not. Returns true for P-c(QR), false for Q-c(PR). It must depend on the
 * face alone, so that both tets sharing the face split it alike.
 *  (a) P-Q long: L&S's parity rule. With a the axis of P-Q and b, c the others, the parity of
 *      [(Q-P)_a < 0] + [(R-P)_b < 0] + [(R-P)_c < 0] is compared with "P is a cube corner";
 *      swapping P and Q flips both the first term and the corner bit, so the rule is symmetric.
 *  (b) P-Q short: the face's long edge joins R to P or to Q; the diagonal joins the cut on that
 *      long edge to the kept vertex that is not on it. */
static bool quad_diag(const Local *L, int P, int Q, int R)
{
    if ((P ^ 1) == Q) {
        const int *p = L->I[P], *q = L->I[Q], *r = L->I[R];
        int a = p[0] != q[0] ? 0 : p[1] != q[1] ? 1 : 2;
        int b = (a + 1) % 3, cax = (a + 2) % 3;
        int odd = ((q[a] - p[a] < 0) + (r[b] - p[b] < 0) + (r[cax] - p[cax] < 0)) & 1;
        int corner = (p[0] & 1) == 0;
        return corner == odd;
    }
    return (R ^ 1) == Q;
}

static void pyramid(TetOut *o, int apex, const int u[4], bool diag02, int lab)
{
    if (diag02) {
        push_tet(o, apex, u[0], u[1], u[2], lab);
        push_tet(o, apex, u[0], u[2], u[3], lab);
    } else {
        push_tet(o, apex, u[1], u[2], u[3], lab);
        push_tet(o, apex, u[1], u[3], u[0], lab);
    }
}

/* A triangular prism with bottom b[0..2] and top t[0..2] (b[i] below t[i]); side quad q joins
 * columns q and q+1 (mod 3) and its diagonal is b[q]-t[q+1] when diag[q] is 1, b[q+1]-t[q]
 * when 0, and undecided when -1 (at most one). Three tets fill it exactly when some vertex
 * carries two diagonals, i.e. when the diagonals are not all "rotating" the same way; an
 * undecided diagonal is set to break the rotation. Returns -1 if the rotation is forced. */
static int prism(TetOut *o, const int b[3], const int t[3], int diag[3], int lab)
{
    for (int q = 0; q < 3; q++) {
        if (diag[q] >= 0)
            continue;
        int x = diag[(q + 1) % 3], y = diag[(q + 2) % 3];
        diag[q] = x == y ? 1 - x : 1; /* free only when the others differ; any choice works */
    }
    if (diag[0] == diag[1] && diag[1] == diag[2])
        return -1;
    for (int k = 0; k < 3; k++) {
        int k1 = (k + 1) % 3, k2 = (k + 2) % 3;
        int quad[4] = {b[k1], b[k2], t[k2], t[k1]};
        if (diag[k] == 1 && diag[k2] == 0) { /* b[k] carries two diagonals */
            push_tet(o, b[k], t[0], t[1], t[2], lab);
            pyramid(o, b[k], quad, diag[k1] == 1, lab);
            return 0;
        }
        if (diag[k] == 0 && diag[k2] == 1) { /* t[k] carries two diagonals */
            push_tet(o, t[k], b[0], b[1], b[2], lab);
            pyramid(o, t[k], quad, diag[k1] == 1, lab);
            return 0;
        }
    }
    return -1;
}

/* One side of the interface in a lattice tet: the stencils of L&S §3, with sg[i] = +1 for
 * the kept side, 0 for warped vertices, -1 for the other side. *interior carries the diagonal
 * of the interior quad of the ++-- wedge (a pair of cut points, as 16 * lo + hi, or -1): set
 * it to force the same split from the other side, read it back after. Returns -1 when a
 * stencil cannot be filled (a bug). */
static int stuff_side(TetOut *o, const Local *L, const int sg[4], int lab, int *interior)
{
    int P[4], Z[4], M[4], np = 0, nz = 0, nm = 0;
    for (int i = 0; i < 4; i++) {
        if (sg[i] > 0)
            P[np++] = i;
        else if (sg[i] == 0)
            Z[nz++] = i;
        else
            M[nm++] = i;
    }
    if (np == 0)
        return 0;
    if (nm == 0) { /* all kept or on the interface */
        push_tet(o, 0, 1, 2, 3, lab);
        return 0;
    }
    if (np == 1) { /* a corner of the tet: the kept vertex, the zeros, and the cuts */
        int v[4];
        for (int i = 0; i < 4; i++)
            v[i] = sg[i] > 0 ? i : sg[i] == 0 ? i : cut_pt(P[0], i);
        push_tet(o, v[0], v[1], v[2], v[3], lab);
        return 0;
    }
    if (np == 2 && nz == 1) { /* pyramid with apex the zero over the quad on face (P, Q, R) */
        int p = P[0], q = P[1], r = M[0];
        int quad[4] = {p, q, cut_pt(q, r), cut_pt(p, r)};
        pyramid(o, Z[0], quad, quad_diag(L, p, q, r), lab);
        return 0;
    }
    if (np == 3) { /* prism: kept triangle below, the three cuts from the outside vertex above */
        int r = M[0];
        int b[3] = {P[0], P[1], P[2]};
        int t[3] = {cut_pt(P[0], r), cut_pt(P[1], r), cut_pt(P[2], r)};
        int diag[3];
        for (int q = 0; q < 3; q++)
            diag[q] = quad_diag(L, b[q], b[(q + 1) % 3], r) ? 1 : 0;
        return prism(o, b, t, diag, lab);
    }
    /* np == 2, nm == 2: a wedge whose columns are P-Q, c(PR)-c(QR) and c(PS)-c(QS). Quads 0
     * and 2 lie on lattice faces (P, Q, R) and (P, Q, S); quad 1 is interior. */
    int p = P[0], q = P[1], r = M[0], s = M[1];
    int b[3] = {p, cut_pt(p, r), cut_pt(p, s)};
    int t[3] = {q, cut_pt(q, r), cut_pt(q, s)};
    int diag[3];
    diag[0] = quad_diag(L, p, q, r) ? 1 : 0;
    diag[2] = quad_diag(L, p, q, s) ? 0 : 1; /* quad 2 runs from column 2 to column 0 */
    diag[1] = -1;
    if (*interior >= 0) {
        int d1 = b[1] < t[2] ? 16 * b[1] + t[2] : 16 * t[2] + b[1];
        diag[1] = *interior == d1 ? 1 : 0;
    }
    if (prism(o, b, t, diag, lab))
        return -1;
    int x = diag[1] ? b[1] : b[2], y = diag[1] ? t[2] : t[1];
    *interior = x < y ? 16 * x + y : 16 * y + x;
    return 0;
}

/* The faces of a junction tet, split exactly as the neighbouring tet splits them: triangles
 * (as point triples) appended to tri. */
static int face_triangles(const Local *L, const int f[3], int tri[][3])
{
    int n = 0, nl = 0, lab[3];
    for (int i = 0; i < 3; i++) {
        if (L->zero[f[i]])
            continue;
        bool seen = false;
        for (int j = 0; j < nl; j++)
            seen |= lab[j] == L->lab[f[i]];
        if (!seen)
            lab[nl++] = L->lab[f[i]];
    }
    if (nl <= 1) {
        tri[n][0] = f[0], tri[n][1] = f[1], tri[n][2] = f[2], n++;
        return n;
    }
    if (nl == 3) { /* three cuts: a middle triangle and one per corner */
        int a = f[0], b = f[1], c = f[2];
        int ab = cut_pt(a, b), bc = cut_pt(b, c), ca = cut_pt(c, a);
        tri[n][0] = ab, tri[n][1] = bc, tri[n][2] = ca, n++;
        tri[n][0] = a, tri[n][1] = ab, tri[n][2] = ca, n++;
        tri[n][0] = b, tri[n][1] = bc, tri[n][2] = ab, n++;
        tri[n][0] = c, tri[n][1] = ca, tri[n][2] = bc, n++;
        return n;
    }
    /* two labels */
    for (int i = 0; i < 3; i++) {
        int x = f[i], y = f[(i + 1) % 3], z = f[(i + 2) % 3];
        if (L->zero[x]) { /* y and z differ: split at their cut, through the zero */
            int c = cut_pt(y, z);
            tri[n][0] = x, tri[n][1] = y, tri[n][2] = c, n++;
            tri[n][0] = x, tri[n][1] = c, tri[n][2] = z, n++;
            return n;
        }
    }
    for (int i = 0; i < 3; i++) {
        int p = f[i], q = f[(i + 1) % 3], r = f[(i + 2) % 3];
        if (L->lab[p] != L->lab[q])
            continue;
        /* p, q share a label, r has the other: the quad as in the stencils, plus r's corner */
        int cqr = cut_pt(q, r), cpr = cut_pt(p, r);
        if (quad_diag(L, p, q, r)) {
            tri[n][0] = p, tri[n][1] = q, tri[n][2] = cqr, n++;
            tri[n][0] = p, tri[n][1] = cqr, tri[n][2] = cpr, n++;
        } else {
            tri[n][0] = p, tri[n][1] = q, tri[n][2] = cpr, n++;
            tri[n][0] = q, tri[n][1] = cqr, tri[n][2] = cpr, n++;
        }
        tri[n][0] = r, tri[n][1] = cpr, tri[n][2] = cqr, n++;
        return n;
    }
    return n;
}

/* ---- output --------------------------------------------------------------------------------- */

static Cut *local_cut(Ctx *c, const Local *L, int code)
{
    static const int ends[6][2] = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}};
    int e = code - 4;
    int64_t base, other;
    bool is_long;
    uint64_t key = edge_key(c, L->I[ends[e][0]], L->I[ends[e][1]], &base, &other, &is_long);
    int k = map_get(&c->map, key);
    if (k < 0 || !c->cuts[k].alive)
        return NULL;
    return &c->cuts[k];
}

static int point_pos(Ctx *c, const Local *L, const double centroid[3], int code, double p[3])
{
    if (code < 4) {
        int64_t v = L->id[code];
        if (c->warp[v] >= 0)
            memcpy(p, c->cuts[c->warp[v]].p, 3 * sizeof *p);
        else
            lattice_pos(c, L->I[code], p);
        return 0;
    }
    if (code == CENTROID) {
        memcpy(p, centroid, 3 * sizeof *p);
        return 0;
    }
    Cut *k = local_cut(c, L, code);
    if (!k)
        return -1;
    memcpy(p, k->p, 3 * sizeof *p);
    return 0;
}

static int point_node(Ctx *c, const Local *L, const double centroid[3], int *centroid_node,
                      int code)
{
    int *slot;
    double p[3];
    if (code < 4)
        slot = &c->node[L->id[code]];
    else if (code == CENTROID)
        slot = centroid_node;
    else
        slot = &local_cut(c, L, code)->node;
    if (*slot < 0) {
        point_pos(c, L, centroid, code, p);
        *slot = ns_mesh_add_node(c->out, p);
    }
    return *slot;
}

static int emit(Ctx *c, const Local *L, const TetOut *o, const double centroid[3], char *err,
                int err_sz)
{
    int centroid_node = -1;
    for (int k = 0; k < o->n; k++) {
        if (o->lab[k] < 0)
            continue;
        int v[4];
        double p[4][3];
        memcpy(v, o->v[k], sizeof v);
        for (int i = 0; i < 4; i++) {
            if (point_pos(c, L, centroid, v[i], p[i])) {
                ns_set_err(err, err_sz, "mesher: internal error: missing cut point in lattice tet");
                return -1;
            }
        }
        /* Orient positively (L&S's stencils are drawn unoriented). */
        double vol = ns_tet_volume(p[0], p[1], p[2], p[3]);
        if (!(vol != 0.0)) {
            ns_set_err(err, err_sz,
                       "mesher: internal error: flat tet near (%g, %g, %g) (region %d)", p[0][0],
                       p[0][1], p[0][2], o->lab[k]);
            return -1;
        }
        if (vol < 0) {
            int s = v[2];
            v[2] = v[3];
            v[3] = s;
        }
        int nodes[4];
        for (int i = 0; i < 4; i++) {
            nodes[i] = point_node(c, L, centroid, &centroid_node, v[i]);
            if (nodes[i] < 0) {
                c->oom = true;
                return -1;
            }
        }
        if (ns_mesh_add_tet(c->out, nodes, o->lab[k]) < 0) {
            c->oom = true;
            return -1;
        }
    }
    return 0;
}

/* Fill one lattice tet. */
static int stuff_tet(Ctx *c, const Local *L, char *err, int err_sz)
{
    int labs[4], nl = 0;
    for (int i = 0; i < 4; i++) {
        if (L->zero[i])
            continue;
        bool seen = false;
        for (int j = 0; j < nl; j++)
            seen |= labs[j] == L->lab[i];
        if (!seen)
            labs[nl++] = L->lab[i];
    }
    TetOut o;
    o.n = 0;
    double centroid[3] = {0, 0, 0};
    if (nl <= 1) {
        int lab = nl == 1 ? labs[0] : OUTSIDE;
        if (nl == 0) {
            /* All four vertices were warped onto interfaces. L&S's one-sided stencils have no
             * '+' vertex here and output nothing, and with the one-sided thresholds such a tet
             * can be nearly flat (four points on one smooth surface: we measured 1.3 degrees
             * when keeping them), so on the domain's outer boundary (every vertex warped onto
             * a cut with OUTSIDE) it is dropped. Between two regions dropping it would open a
             * crack, so it is kept with the label at its centroid; its vertices were warped
             * with the two-sided thresholds (warp_vertices), which keep it from going flat. */
            bool internal = false;
            for (int i = 0; i < 4; i++) {
                const Cut *k = &c->cuts[c->warp[L->id[i]]];
                internal |= c->label[k->base] != OUTSIDE && c->label[k->other] != OUTSIDE;
            }
            if (!internal)
                return 0;
            for (int i = 0; i < 4; i++) {
                double p[3];
                point_pos(c, L, centroid, i, p);
                for (int a = 0; a < 3; a++)
                    centroid[a] += 0.25 * p[a];
            }
            lab = label_at(c, centroid);
        }
        if (lab == OUTSIDE)
            return 0;
        push_tet(&o, 0, 1, 2, 3, lab);
        return emit(c, L, &o, centroid, err, err_sz);
    }
    if (nl == 2) {
        /* Two-sided stuffing: each label in turn is the kept side, sharing the cut points; the
         * interior quad of a wedge is split once and the other side is made to agree. */
        int lo = labs[0] < labs[1] ? labs[0] : labs[1], hi = labs[0] ^ labs[1] ^ lo;
        int interior = -1;
        for (int side = 0; side < 2; side++) {
            int keep = side == 0 ? lo : hi, sg[4];
            for (int i = 0; i < 4; i++)
                sg[i] = L->zero[i] ? 0 : L->lab[i] == keep ? 1 : -1;
            int before = interior;
            if (stuff_side(&o, L, sg, keep, &interior) ||
                (side == 1 && before >= 0 && before != interior)) {
                ns_set_err(err, err_sz,
                           "mesher: internal error: the two sides of an interface disagree in the "
                           "lattice tet at vertex %lld",
                           (long long)L->id[0]);
                return -1;
            }
        }
        return emit(c, L, &o, centroid, err, err_sz);
    }
    /* Three or more labels (a junction of regions inside one lattice tet): split each face as
     * its neighbour does, and cone the faces to the centroid. Not covered by L&S's guarantee. */
    c->stats.junction_tets++;
    double p[4][3];
    for (int i = 0; i < 4; i++) {
        point_pos(c, L, centroid, i, p[i]);
        for (int a = 0; a < 3; a++)
            centroid[a] += 0.25 * p[i][a];
    }
    static const int faces[4][3] = {{1, 2, 3}, {0, 2, 3}, {0, 1, 3}, {0, 1, 2}};
    for (int f = 0; f < 4; f++) {
        int tri[4][3];
        int nt = face_triangles(L, faces[f], tri);
        for (int k = 0; k < nt; k++) {
            double q[3][3], mid[3];
            for (int j = 0; j < 3; j++)
                if (point_pos(c, L, centroid, tri[k][j], q[j])) {
                    ns_set_err(err, err_sz,
                               "mesher: internal error: missing cut point in junction tet");
                    return -1;
                }
            for (int a = 0; a < 3; a++)
                mid[a] = 0.25 * (q[0][a] + q[1][a] + q[2][a] + centroid[a]);
            int lab = label_at(c, mid);
            if (lab == OUTSIDE) {
                /* Keep the whole junction tet: a cone tet dropped here leaves boundary faces
                 * that meet the apex, and two such can touch at an edge or a vertex only (a
                 * non-manifold boundary). Kept, it takes the region of the nearest lattice
                 * vertex inside; the boundary then follows this lattice tet's faces, one cell
                 * at most from the surface. */
                double best = INFINITY;
                for (int i = 0; i < 4; i++) {
                    if (L->lab[i] == OUTSIDE)
                        continue;
                    double d2 = 0.0;
                    for (int a = 0; a < 3; a++)
                        d2 += (p[i][a] - mid[a]) * (p[i][a] - mid[a]);
                    if (d2 < best) {
                        best = d2;
                        lab = L->lab[i];
                    }
                }
            }
            push_tet(&o, CENTROID, tri[k][0], tri[k][1], tri[k][2], lab);
        }
    }
    return emit(c, L, &o, centroid, err, err_sz);
}

/* Every lattice tet once: for each pair of centres C0, C1 = C0 + 2 e_a, the four corners of the
 * square face between them form a ring; each ring edge (a long edge) and C0-C1 span a tet. */
/* The caller asked the mesher to stop (NsMesherDef.cancel). */
static bool cancelled(const Ctx *c, char *err, int err_sz)
{
    if (!c->def->cancel || *c->def->cancel == 0)
        return false;
    ns_set_err(err, err_sz, "mesher: interrupted");
    return true;
}

static int stuff_all(Ctx *c, char *err, int err_sz)
{
    static const int ring[4][2] = {{-1, -1}, {1, -1}, {1, 1}, {-1, 1}};
    for (int64_t id = c->ncorner; id < c->nvert; id++) {
        if ((id & 1023) == 0 && cancelled(c, err, err_sz))
            return -1;
        int C0[3];
        vertex_coords(c, id, C0);
        for (int a = 0; a < 3; a++) {
            int C1[3] = {C0[0], C0[1], C0[2]};
            C1[a] += 2;
            int64_t id1 = vertex_id(c, C1);
            if (id1 < 0)
                continue;
            int b = (a + 1) % 3, cax = (a + 2) % 3;
            for (int r = 0; r < 4; r++) {
                Local L;
                memcpy(L.I[0], C0, sizeof C0);
                memcpy(L.I[1], C1, sizeof C1);
                for (int k = 0; k < 2; k++) {
                    int *K = L.I[2 + k];
                    K[a] = C0[a] + 1;
                    K[b] = C0[b] + ring[(r + k) % 4][0];
                    K[cax] = C0[cax] + ring[(r + k) % 4][1];
                }
                bool any_in = false, mixed = false;
                for (int i = 0; i < 4; i++) {
                    L.id[i] = i == 0 ? id : i == 1 ? id1 : vertex_id(c, L.I[i]);
                    L.lab[i] = c->label[L.id[i]];
                    L.zero[i] = c->warp[L.id[i]] >= 0;
                    any_in |= L.lab[i] != OUTSIDE || L.zero[i];
                    mixed |= L.zero[i] || L.lab[i] != L.lab[0];
                }
                if (!any_in)
                    continue;
                if (!mixed) { /* fast path: one label, nothing warped */
                    TetOut o;
                    o.n = 0;
                    push_tet(&o, 0, 1, 2, 3, L.lab[0]);
                    if (emit(c, &L, &o, NULL, err, err_sz))
                        return -1;
                    continue;
                }
                if (stuff_tet(c, &L, err, err_sz))
                    return -1;
                if (c->nan)
                    return 0;
            }
        }
    }
    return 0;
}

/* ---- driver --------------------------------------------------------------------------------- */

static int setup(Ctx *c, const NsMesherDef *def, char *err, int err_sz)
{
    if (!(def->spacing > 0) || !isfinite(def->spacing)) {
        ns_set_err(err, err_sz, "mesher: spacing must be positive (got %g m)", def->spacing);
        return -1;
    }
    if (!def->regions || def->region_count <= 0) {
        ns_set_err(err, err_sz, "mesher: no regions to mesh");
        return -1;
    }
    /* Below 0.5 no cut point can be too close to both ends of its edge; above 0 a cut point
     * exactly on a lattice vertex is always warped away (else it would make flat tets). */
    if (!(def->alpha_long > 0 && def->alpha_long < 0.5) ||
        !(def->alpha_short > 0 && def->alpha_short < 0.5)) {
        ns_set_err(err, err_sz,
                   "mesher: alpha_long and alpha_short must lie in (0, 0.5) (got %g, %g)",
                   def->alpha_long, def->alpha_short);
        return -1;
    }
    int nr = def->region_count;
    c->rlo = malloc((size_t)nr * sizeof *c->rlo);
    c->rhi = malloc((size_t)nr * sizeof *c->rhi);
    c->rbounded = malloc((size_t)nr * sizeof *c->rbounded);
    if (!c->rlo || !c->rhi || !c->rbounded) {
        c->oom = true;
        return -1;
    }
    double blo[3] = {INFINITY, INFINITY, INFINITY}, bhi[3] = {-INFINITY, -INFINITY, -INFINITY};
    bool all_bounded = true;
    for (int r = 0; r < nr; r++) {
        if (!def->regions[r].shape) {
            ns_set_err(err, err_sz, "mesher: region %d has no shape", r);
            return -1;
        }
        c->rbounded[r] = ns_shape_bounds(def->regions[r].shape, c->rlo[r], c->rhi[r]);
        if (!c->rbounded[r]) {
            all_bounded = false;
            continue;
        }
        bool empty = false; /* e.g. an intersection of disjoint shapes */
        for (int a = 0; a < 3; a++)
            empty |= !(c->rlo[r][a] <= c->rhi[r][a]);
        for (int a = 0; a < 3; a++) {
            if (!empty) {
                blo[a] = fmin(blo[a], c->rlo[r][a]);
                bhi[a] = fmax(bhi[a], c->rhi[r][a]);
            }
            /* a little slack so rounding in the bounds never hides a point the shape holds */
            double slack = 1e-9 * (c->rhi[r][a] - c->rlo[r][a]) + 1e-9 * def->spacing;
            c->rlo[r][a] -= slack;
            c->rhi[r][a] += slack;
        }
    }
    double lo[3], hi[3];
    if (def->lo[0] > def->hi[0]) {
        if (!all_bounded) {
            ns_set_err(err, err_sz, "mesher: a region is unbounded; set the lattice box (lo, hi)");
            return -1;
        }
        if (!(blo[0] <= bhi[0])) {
            ns_set_err(err, err_sz, "mesher: every region is empty (its bounds hold nothing)");
            return -1;
        }
        memcpy(lo, blo, sizeof lo);
        memcpy(hi, bhi, sizeof hi);
    } else {
        memcpy(lo, def->lo, sizeof lo);
        memcpy(hi, def->hi, sizeof hi);
    }
    double h = def->spacing;
    double count = 1.0;
    for (int a = 0; a < 3; a++) {
        if (!isfinite(lo[a]) || !isfinite(hi[a]) || !(lo[a] <= hi[a])) {
            ns_set_err(err, err_sz, "mesher: empty or invalid lattice box on axis %d ([%g, %g] m)",
                       a, lo[a], hi[a]);
            return -1;
        }
        /* corners lo + h i for i = -1 .. n + 1 cover [lo - h, hi + h] */
        double n = ceil((hi[a] - lo[a]) / h - 1e-9);
        if (n < 1)
            n = 1;
        if (n > 1e6) {
            ns_set_err(err, err_sz, "mesher: lattice too large (spacing %g m for a %g m box)", h,
                       hi[a] - lo[a]);
            return -1;
        }
        c->nc[a] = (int)n + 3;
        c->nz[a] = (int)n + 2;
        c->lo[a] = lo[a];
        count *= n + 3;
    }
    count += (double)c->nz[0] * c->nz[1] * c->nz[2];
    /* The memory the mesh will take, estimated before anything is allocated (sim/ns_limits.h):
     * the lattice's arrays, the cut-point table and the output mesh come to about
     * NS_MESHER_BYTES_PER_VERTEX a lattice vertex (measured: docs/mesher.md). The spacing that
     * would fit scales with the cube root. */
    double bytes = count * NS_MESHER_BYTES_PER_VERTEX;
    double most = def->max_bytes > 0.0 ? def->max_bytes : (double)NS_LIMIT_MESHER_BYTES;
    if (count > (double)NS_MAX_LATTICE_VERTICES || bytes > most) {
        double fit = h * cbrt(bytes / most) * 1.02;
        ns_set_err(err, err_sz,
                   "mesher: spacing %g m needs %.0f lattice vertices, about %.1f GiB (at most "
                   "%.1f GiB): a spacing of %.2g m or more fits",
                   h, count, bytes / 1073741824.0, most / 1073741824.0, fit);
        return -1;
    }
    c->h = h;
    c->ncorner = (int64_t)c->nc[0] * c->nc[1] * c->nc[2];
    c->nvert = c->ncorner + (int64_t)c->nz[0] * c->nz[1] * c->nz[2];
    c->label = malloc((size_t)c->nvert * sizeof *c->label);
    c->warp = malloc((size_t)c->nvert * sizeof *c->warp);
    c->node = malloc((size_t)c->nvert * sizeof *c->node);
    c->near_cut = calloc((size_t)c->nvert, 1);
    if (!c->label || !c->warp || !c->node || !c->near_cut) {
        c->oom = true;
        return -1;
    }
    c->stats.lattice_vertices = (int)c->nvert;
    for (int64_t v = 0; v < c->nvert; v++) {
        if ((v & 4095) == 0 && cancelled(c, err, err_sz))
            return -1;
        int I[3];
        double p[3];
        vertex_coords(c, v, I);
        lattice_pos(c, I, p);
        c->label[v] = label_at(c, p);
        c->warp[v] = -1;
        c->node[v] = -1;
        if (c->nan)
            return 0;
    }
    return 0;
}

static void ctx_free(Ctx *c)
{
    free(c->label);
    free(c->warp);
    free(c->node);
    free(c->near_cut);
    free(c->cuts);
    free(c->map.keys);
    free(c->map.vals);
    free(c->rlo);
    free(c->rhi);
    free(c->rbounded);
}

int ns_mesher_stuff(const NsMesherDef *def, NsMesh *out, NsMesherStats *stats, char *err,
                    int err_sz)
{
    Ctx c;
    memset(&c, 0, sizeof c);
    c.def = def;
    c.out = out;
    if (err && err_sz > 0)
        err[0] = '\0';
    int rc = def ? setup(&c, def, err, err_sz) : -1;
    if (!def)
        ns_set_err(err, err_sz, "mesher: no definition");
    if (rc == 0 && !c.nan)
        rc = compute_cuts(&c);
    if (rc == 0 && !c.nan) {
        warp_vertices(&c);
        rc = stuff_all(&c, err, err_sz);
    }
    if (rc == 0 && c.nan) {
        ns_set_err(err, err_sz, "shape evaluated to NaN at (%g, %g, %g)", c.nan_p[0], c.nan_p[1],
                   c.nan_p[2]);
        rc = -1;
    }
    if (rc == 0 && out->tet_alive == 0) {
        ns_set_err(err, err_sz, "the regions produced no tets (resolution too coarse?)");
        rc = -1;
    }
    if (rc == 0) {
        for (int t = 0; t < out->tet_slots; t++) {
            if (!def->regions[out->tet_region[t]].fixed)
                continue;
            for (int k = 0; k < 4; k++)
                out->flags[out->tet_node[4 * t + k]] |= NS_NODE_FIXED;
        }
        if (ns_mesh_compact(out))
            c.oom = true;
    }
    if (c.oom) {
        ns_set_err(err, err_sz, "mesher: out of memory");
        rc = -1;
    }
    if (rc == 0) {
        for (int k = 0; k < c.ncuts; k++)
            c.stats.cut_points += c.cuts[k].alive;
        if (stats)
            *stats = c.stats;
    } else {
        ns_mesh_free(out);
        ns_mesh_init(out);
    }
    ctx_free(&c);
    return rc;
}
