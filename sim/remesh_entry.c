/* Skin entry (paper §3.4.1): the needle's first penetration, the one remeshing step allowed to
 * change the tissue's boundary. The entry node is made on the surface at the entry point (a
 * nearby surface node snapped there, or the surface face or edge split there), and the tip node
 * just inside it, a short edge away (the split of the simplex containing it). From then on
 * Algorithm 2 (remesh.c) moves the tip; the paper's "very short edge connecting the needle tip to
 * the mesh surface, with flat tetrahedra adjoining it" is the edge made here. Ours (issue 35):
 * the edge is made long enough (up to half an element) that the tets adjoining it are not flat
 * (dihedral angles of 12 deg or more where the depth allows, then repaired), since every step's
 * mesh counts (min_dihedral_deg_any_step). Both splits go on the needle's undo stack,
 * and the snap is recorded, so that the needle's exit gives back the original mesh. */
#include "remesh.h"

#include "err.h"
#include "quality.h"

#include <math.h>
#include <string.h>

/* A surface node is snapped to the entry point if that moves it by at most this fraction of its
 * shortest edge (else the surface simplex there is split: no sliver next to a node). */
#define ENTRY_SNAP 0.75
/* Barycentric coordinates below this make a point lie on the opposite face. */
#define ENTRY_ON 1e-6
/* A snap may not bring an incident tet's quality below this (unless it was lower already). */
#define ENTRY_MIN_QUALITY 0.05
/* The tip node's tets should reach this worst dihedral angle [deg] (the remesher's default
 * floor, NsCouplingParams.remesh_dihedral_floor). */
#define ENTRY_DIHEDRAL_DEG 12.0
/* The depths tried for the tip node, as multiples of the depth asked, while within
 * ENTRY_DEPTH_CAP of the entry node's mean edge. */
static const double entry_grow[] = {1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0};
#define ENTRY_DEPTH_CAP 0.5

/* Unit outward normal of face f (opposite node f) of tet t in material space; 0 if degenerate. */
static int face_normal(const NsMesh *m, int t, int f, double n[3])
{
    const int *tn = m->tet_node + 4 * t;
    int v[3], k = 0;
    for (int j = 0; j < 4; j++)
        if (j != f)
            v[k++] = tn[j];
    const double *p0 = m->u + 3 * v[0], *p1 = m->u + 3 * v[1], *p2 = m->u + 3 * v[2];
    const double *po = m->u + 3 * tn[f];
    double e1[3], e2[3], c[3];
    for (int i = 0; i < 3; i++) {
        e1[i] = p1[i] - p0[i];
        e2[i] = p2[i] - p0[i];
    }
    c[0] = e1[1] * e2[2] - e1[2] * e2[1];
    c[1] = e1[2] * e2[0] - e1[0] * e2[2];
    c[2] = e1[0] * e2[1] - e1[1] * e2[0];
    double cn = sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]), side = 0.0;
    if (!(cn > 0.0))
        return 0;
    for (int i = 0; i < 3; i++)
        side += c[i] * (po[i] - p0[i]);
    for (int i = 0; i < 3; i++) /* away from the opposite node: outward */
        n[i] = (side > 0.0 ? -c[i] : c[i]) / cn;
    return 1;
}

static double dist(const double *p, const double *q)
{
    return sqrt((p[0] - q[0]) * (p[0] - q[0]) + (p[1] - q[1]) * (p[1] - q[1]) +
                (p[2] - q[2]) * (p[2] - q[2]));
}

static double shortest_edge(const NsMesh *m, int n)
{
    double e = INFINITY;
    const NsIntList *l = &m->node_tets[n];
    for (int i = 0; i < l->count; i++)
        for (int k = 0; k < 4; k++) {
            int o = m->tet_node[4 * l->items[i] + k];
            if (o != n)
                e = fmin(e, dist(m->u + 3 * n, m->u + 3 * o));
        }
    return e;
}

/* Does node n's star stay positive in material and world space, and of fair quality, at its
 * current position? (quality is compared with q_before, the star's worst before the move) */
static int star_ok(const NsMesh *m, int n, double q_before)
{
    const NsIntList *l = &m->node_tets[n];
    for (int i = 0; i < l->count; i++) {
        const int *tn = m->tet_node + 4 * l->items[i];
        const double *u[4], *x[4];
        for (int k = 0; k < 4; k++) {
            u[k] = m->u + 3 * tn[k];
            x[k] = m->x + 3 * tn[k];
        }
        double q = ns_tet_quality(u[0], u[1], u[2], u[3]);
        if (!(ns_tet_volume(u[0], u[1], u[2], u[3]) > 0.0) ||
            !(ns_tet_volume(x[0], x[1], x[2], x[3]) > 0.0) ||
            (q < ENTRY_MIN_QUALITY && q < q_before))
            return 0;
    }
    return 1;
}

/* Puts node n's saved state back after a snap that is not kept, and drops the original
 * position the snap recorded (unless one was recorded before it). */
static void put_back(NsMesh *m, NsRemeshStack *s, int n, const double su[3], const double sx[3],
                     const double sv[3], const double sa[3], int recorded_before)
{
    memcpy(m->u + 3 * n, su, 3 * sizeof *su);
    memcpy(m->x + 3 * n, sx, 3 * sizeof *sx);
    memcpy(m->v + 3 * n, sv, 3 * sizeof *sv);
    memcpy(m->a + 3 * n, sa, 3 * sizeof *sa);
    if (!recorded_before)
        ns_remesh_forget_original(s, n);
}

/* Unit outward normal (material space) of a boundary face of tet t holding the point of
 * barycentric coordinates b (a face whose opposite coordinate is about 0). Returns 1, or 0 if
 * the point is on no boundary face of t. */
static int surface_normal_at(const NsMesh *m, int t, const double b[4], double n[3])
{
    for (int f = 0; f < 4; f++)
        if (b[f] <= ENTRY_ON && m->tet_adj[4 * t + f] < 0 && face_normal(m, t, f, n))
            return 1;
    return 0;
}

/* Is every boundary face around node n within about 5 degrees of the plane of normal fn? (A
 * snap then slides the node in the surface: an edge or corner of the tissue keeps its shape.) */
static int flat_around(const NsMesh *m, int n, const double fn[3])
{
    const NsIntList *l = &m->node_tets[n];
    for (int i = 0; i < l->count; i++)
        for (int f = 0; f < 4; f++) {
            int t = l->items[i];
            double g[3];
            if (m->tet_adj[4 * t + f] >= 0 || m->tet_node[4 * t + f] == n)
                continue; /* not a boundary face, or not one of n's */
            if (!face_normal(m, t, f, g) || g[0] * fn[0] + g[1] * fn[1] + g[2] * fn[2] < 0.996)
                return 0;
        }
    return 1;
}

/* The mean length of node n's edges (each counted once per tet) [m]. */
static double mean_edge(const NsMesh *m, int n)
{
    double h = 0.0;
    int ne = 0;
    const NsIntList *l = &m->node_tets[n];
    for (int i = 0; i < l->count; i++)
        for (int k = 0; k < 4; k++) {
            int o = m->tet_node[4 * l->items[i] + k];
            if (o != n) {
                h += dist(m->u + 3 * n, m->u + 3 * o);
                ne++;
            }
        }
    return ne ? h / ne : 0.0;
}

static int remesh_has(const int *list, int n, int v)
{
    for (int i = 0; i < n; i++)
        if (list[i] == v)
            return 1;
    return 0;
}

/* The worst dihedral angle of node n's tets in material space [deg]. */
static double node_min_dihedral(const NsMesh *m, int n)
{
    double lo = 180.0;
    const NsIntList *l = &m->node_tets[n];
    for (int i = 0; i < l->count; i++) {
        const int *tn = m->tet_node + 4 * l->items[i];
        lo = fmin(lo, ns_tet_min_dihedral(m->u + 3 * tn[0], m->u + 3 * tn[1], m->u + 3 * tn[2],
                                          m->u + 3 * tn[3]));
    }
    return lo;
}

/* A node at material point p in tet t (barycentric b): the simplex of the nodes with weight
 * above ENTRY_ON is split at p (an edge, a face or the tet), or, if p is at a node, that node.
 * Returns the node, or -1. */
static int node_at(NsMesh *m, NsRemeshStack *s, int t, const double b[4], const double p[3])
{
    int simplex[4], k = 0;
    for (int j = 0; j < 4; j++)
        if (b[j] > ENTRY_ON)
            simplex[k++] = m->tet_node[4 * t + j];
    if (k == 1)
        return simplex[0];
    return k >= 2 ? ns_remesh_split(m, s, simplex, k, p) : -1;
}

int ns_remesh_skin_entry(NsMesh *m, NsRemeshStack *s, const double a[3], const double d[3],
                         double depth, int nodes[2], char *err, int err_sz)
{
    double dn = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if (!(dn > 0.0) || !isfinite(dn) || !(depth > 0.0) || !isfinite(depth) ||
        !isfinite(a[0] + a[1] + a[2])) {
        ns_set_err(err, err_sz, "skin entry: a finite point, a direction and a depth > 0 needed");
        return -1;
    }
    double u[3] = {d[0] / dn, d[1] / dn, d[2] / dn}, b[4], behind[3], ahead[3];
    int t = ns_mesh_locate(m, a, -1, ENTRY_ON, b);
    if (t < 0) {
        ns_set_err(err, err_sz, "the entry point is not on the tissue (outside its mesh)");
        return -1;
    }
    /* On the surface, facing it: just behind the point is outside, just ahead inside. */
    double probe = 0.01 * depth;
    for (int i = 0; i < 3; i++) {
        behind[i] = a[i] - probe * u[i];
        ahead[i] = a[i] + probe * u[i];
    }
    if (ns_mesh_locate(m, behind, t, 0.0, NULL) >= 0) {
        ns_set_err(err, err_sz,
                   "the entry point is not on the tissue's surface (the tissue goes on behind "
                   "it, against the direction)");
        return -1;
    }
    /* (ahead with a little tolerance: on a lattice line it lies on tets' faces and edges) */
    if (ns_mesh_locate(m, ahead, t, ENTRY_ON, NULL) < 0) {
        ns_set_err(err, err_sz, "the direction does not point into the tissue at the entry point");
        return -1;
    }
    int base = s->count;
    /* 1. The entry node: the nearest surface node of the tet snapped onto the point if it is
     *    close and its surface is flat there, else a new node where the point lies (a surface
     *    face or edge split). */
    double fn[3];
    int have_fn = surface_normal_at(m, t, b, fn);
    int entry = -1, near = -1;
    double nd = INFINITY;
    for (int j = 0; j < 4; j++) {
        int n = m->tet_node[4 * t + j];
        double e = dist(m->u + 3 * n, a);
        if (e < nd && ns_remesh_node_on_boundary(m, n) && !(m->flags[n] & NS_NODE_FIXED)) {
            nd = e;
            near = n;
        }
    }
    /* The snap's saved state, put back if the entry fails later. */
    double su[3], sx[3], sv[3], sa[3], u0[3];
    int snapped = 0, recorded_before = near >= 0 && ns_remesh_original(s, near, u0);
    if (near >= 0 && nd <= ENTRY_SNAP * shortest_edge(m, near) && have_fn &&
        flat_around(m, near, fn)) {
        double q0 = ns_remesh_node_quality(m, near);
        memcpy(su, m->u + 3 * near, sizeof su);
        memcpy(sx, m->x + 3 * near, sizeof sx);
        memcpy(sv, m->v + 3 * near, sizeof sv);
        memcpy(sa, m->a + 3 * near, sizeof sa);
        if (nd == 0.0 || (ns_remesh_snap(m, s, near, a) == 0 && star_ok(m, near, q0))) {
            entry = near;
            snapped = nd > 0.0;
        } else {
            put_back(m, s, near, su, sx, sv, sa, recorded_before);
        }
    }
    if (entry < 0)
        entry = node_at(m, s, t, b, a);
    if (entry < 0) {
        ns_set_err(err, err_sz, "the surface could not be split at the entry point");
        return -1;
    }
    /* From here a failure undoes the splits and the snap: the mesh is left as it was. */
    /* 2. The tip node along the direction: the simplex containing it split there, the point
     *    inside one of the entry node's tets (so that the new node is joined to the entry node).
     *    Ours (issue 35): a node at depth e below the entry node makes tets with the entry node
     *    and two far nodes of its star, whose dihedral angle at the far edge is about e / h (h
     *    the element size): 0.6 deg at the tenth of an element the callers ask for. So the depth
     *    asked is the least one: the deeper ones of entry_grow, up to ENTRY_DEPTH_CAP of the
     *    entry node's mean edge, are tried in turn (each split made, measured and undone), and
     *    the first whose tip node's tets reach ENTRY_DIHEDRAL_DEG is taken, else the best. Where
     *    no depth lies inside the entry node's tets, the depth is halved instead, down to a
     *    thousandth of the one asked for, as long as a point inside them is found. */
    int tip = -1;
    double cap = ENTRY_DEPTH_CAP * mean_edge(m, entry), best_deg = -1.0, best_depth = 0.0;
    for (int g = 0; g < (int)(sizeof entry_grow / sizeof entry_grow[0]); g++) {
        double dg = depth * entry_grow[g], p[3];
        if (g > 0 && dg > cap)
            break;
        for (int i = 0; i < 3; i++)
            p[i] = m->u[3 * entry + i] + dg * u[i];
        int tt = ns_mesh_locate(m, p, m->node_tets[entry].items[0], ENTRY_ON, b);
        int inside = 0;
        for (int j = 0; tt >= 0 && j < 4; j++)
            inside |= m->tet_node[4 * tt + j] == entry && b[j] <= 1.0 - ENTRY_ON;
        int before = s->count, n = inside ? node_at(m, s, tt, b, p) : -1;
        if (n < 0)
            continue;
        double deg = n != entry && ns_remesh_joined(m, entry, n) ? node_min_dihedral(m, n) : -1.0;
        if (s->count > before)
            ns_remesh_undo(m, s);
        if (deg > best_deg) {
            best_deg = deg;
            best_depth = dg;
        }
        if (deg >= ENTRY_DIHEDRAL_DEG)
            break;
    }
    if (best_deg >= 0.0)
        depth = best_depth;
    for (int halvings = 0; halvings <= 10 && tip < 0; halvings++, depth *= 0.5) {
        double p[3];
        for (int i = 0; i < 3; i++)
            p[i] = m->u[3 * entry + i] + depth * u[i];
        int tt = ns_mesh_locate(m, p, m->node_tets[entry].items[0], ENTRY_ON, b);
        int inside = 0; /* the tet holding p is one of the entry node's */
        for (int j = 0; tt >= 0 && j < 4; j++)
            inside |= m->tet_node[4 * tt + j] == entry && b[j] <= 1.0 - ENTRY_ON;
        if (inside)
            tip = node_at(m, s, tt, b, p);
    }
    if (tip < 0 || tip == entry || !ns_remesh_joined(m, entry, tip)) {
        while (s->count > base) /* the splits made here, the tip's first */
            if (ns_remesh_undo(m, s))
                break;
        if (snapped)
            put_back(m, s, entry, su, sx, sv, sa, recorded_before);
        ns_set_err(err, err_sz,
                   "no tip node could be made inside the entry point, joined to it by an edge");
        return -1;
    }
    /* Where the tip node's tets are still below the floor, the repair (remesh_repair.c) moves
     * the free nodes of the entry's tets, the entry and tip nodes held: the flat tets that the
     * entry node's snap along the surface left in its star. Its moves are snaps, recorded. */
    const NsIntList *le = &m->node_tets[entry], *lt = &m->node_tets[tip];
    if (node_min_dihedral(m, tip) < ENTRY_DIHEDRAL_DEG && le->count + lt->count <= 256) {
        int tets[256], nt = 0, pin[2] = {entry, tip};
        for (int i = 0; i < le->count; i++)
            tets[nt++] = le->items[i];
        for (int i = 0; i < lt->count; i++)
            if (!remesh_has(tets, nt, lt->items[i]))
                tets[nt++] = lt->items[i];
        ns_remesh_repair(m, s, tets, nt, pin, 2, ENTRY_DIHEDRAL_DEG);
    }
    nodes[0] = entry;
    nodes[1] = tip;
    return 0;
}
