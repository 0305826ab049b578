/* The needle tip's cut through the tissue after the step (sim/coupling_internal.h,
 * coupled_cut_tip): along the pre-laid path, or by remeshing at the tip (Algorithm 2, §3.4.1,
 * sim/remesh.c), with the bevel's steering (§3.5: the paper's displacement, or the arc model)
 * and the physical outcomes at the tip (bone contact, far-side exit, withdrawal; issue 32,
 * docs/remeshing.md). */
#include "coupling_internal.h"
#include "mutate.h"
#include "quality.h"

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

/* Worst and largest dihedral angles of the tets around the path's last three nodes. */
static void tip_dihedrals(const NsCoupled *c, NsCouplingStats *st)
{
    const NsMesh *M = &c->tissue->mesh;
    const NsNeedlePath *p = &c->path;
    st->min_dihedral_deg = 180.0;
    st->max_dihedral_deg = 0.0;
    for (int k = p->count - 1; k >= 0 && k >= p->count - 3; k--) {
        const NsIntList *l = &M->node_tets[p->node[k]];
        for (int i = 0; i < l->count; i++) {
            const int *tn = M->tet_node + 4 * l->items[i];
            double d[6];
            ns_tet_dihedrals(M->u + 3 * tn[0], M->u + 3 * tn[1], M->u + 3 * tn[2], M->u + 3 * tn[3],
                             d);
            for (int j = 0; j < 6; j++) {
                st->min_dihedral_deg = fmin(st->min_dihedral_deg, d[j]);
                st->max_dihedral_deg = fmax(st->max_dihedral_deg, d[j]);
            }
        }
    }
}

/* A needle drawn back leaves the tissue once its tip is within this fraction of the entry
 * node's mean edge from it (tip_target). */
#define EXIT_MARGIN 0.25

/* A fresh heading for the arc model: the cut's direction at the tip in material space, the
 * chord from the tip's node back along the path to the first node at least the mean length of
 * the tip node's edges away (or the path's start). The world tangent of the rod's last edge is
 * no substitute: right after skin entry that edge is a tenth of an element long, and the strain
 * of the tissue around it tilts it by ten degrees or more. Returns 1, or 0 with no chord. */
/* The mean material length of node n's edges (each counted once per tet) [m]; 0 with none. */
static double node_edge_mean(const NsMesh *M, int n)
{
    const double *ut = M->u + 3 * n;
    const NsIntList *l = &M->node_tets[n];
    double h = 0.0;
    int ne = 0;
    for (int i = 0; i < l->count; i++)
        for (int k = 0; k < 4; k++) {
            int o = M->tet_node[4 * l->items[i] + k];
            if (o != n) {
                double e[3] = {M->u[3 * o] - ut[0], M->u[3 * o + 1] - ut[1],
                               M->u[3 * o + 2] - ut[2]};
                h += norm3(e);
                ne++;
            }
        }
    return ne ? h / ne : 0.0;
}

static int path_heading(const NsMesh *M, const NsNeedlePath *p, double heading[3])
{
    int tipn = p->node[p->count - 1];
    const double *ut = M->u + 3 * tipn;
    double h = node_edge_mean(M, tipn);
    double d[3] = {0, 0, 0}, dn = 0.0;
    for (int j = p->count - 2; j >= 0 && !(dn >= h); j--) {
        for (int i = 0; i < 3; i++)
            d[i] = ut[i] - M->u[3 * p->node[j] + i];
        dn = norm3(d);
    }
    if (!(dn > 0.0))
        return 0;
    for (int i = 0; i < 3; i++)
        heading[i] = d[i] / dn;
    return 1;
}

/* ---- physical outcomes at the tip (issue 32; docs/remeshing.md, "Bone contact and far-side
 * exit") ---- */

/* Is tet t rigid: every one of its nodes held in place (bone: a fixed region)? */
static int tet_rigid(const NsMesh *M, int t)
{
    for (int k = 0; k < 4; k++)
        if (!(M->flags[M->tet_node[4 * t + k]] & NS_NODE_FIXED))
            return 0;
    return 1;
}

/* The tip's tissue node while the tip rests on bone: held where it is (its DOFs fixed, at
 * rest), so the needle's push does not drive it, and the soft layer between it and the bone,
 * into the bone. Released (free again, unless the mesh fixes it) on withdrawal. */
void coupled_unpin_tip(NsCoupled *c)
{
    NsTissue *T = c->tissue;
    int n = c->pinned_node - 1;
    c->pinned_node = 0;
    if (n < 0 || !ns_mesh_node_alive(&T->mesh, n) || (T->mesh.flags[n] & NS_NODE_FIXED))
        return;
    for (int k = 0; k < 3; k++)
        ns_tissue_fix_dof(T, n, k, 0);
}

static void pin_tip(NsCoupled *c, int node)
{
    NsTissue *T = c->tissue;
    if (c->pinned_node == node + 1)
        return;
    coupled_unpin_tip(c);
    for (int k = 0; k < 3; k++) {
        ns_tissue_fix_dof(T, node, k, 1);
        T->mesh.v[3 * node + k] = 0.0;
        T->mesh.a[3 * node + k] = 0.0;
    }
    c->pinned_node = node + 1;
}

/* Where the material segment a -> b first enters a rigid tet: sampled at most h/4 apart, the
 * crossing bisected. Returns the fraction of the way along (0, 1], or -1 if it enters none;
 * *region: that tet's region. */
static double rigid_crossing(const NsMesh *M, const double a[3], const double b[3], double h,
                             int hint, int *region)
{
    double d[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, len = norm3(d);
    if (!(len > 0.0) || !(h > 0.0))
        return -1.0;
    int n = (int)ceil(len / (0.25 * h));
    n = n < 1 ? 1 : n > 4096 ? 4096 : n;
    for (int k = 1; k <= n; k++) {
        double f = (double)k / n, q[3];
        for (int i = 0; i < 3; i++)
            q[i] = a[i] + f * d[i];
        int t = ns_mesh_locate(M, q, hint, 1e-9, NULL);
        if (t < 0)
            continue;
        hint = t;
        if (!tet_rigid(M, t))
            continue;
        double lo = (double)(k - 1) / n, hi = f;
        *region = M->tet_region[t];
        for (int it = 0; it < 40; it++) {
            double mid = 0.5 * (lo + hi);
            for (int i = 0; i < 3; i++)
                q[i] = a[i] + mid * d[i];
            int tm = ns_mesh_locate(M, q, hint, 1e-9, NULL);
            if (tm >= 0 && tet_rigid(M, tm)) {
                hi = mid;
                *region = M->tet_region[tm];
            } else {
                lo = mid;
            }
        }
        return hi;
    }
    return -1.0;
}

/* The last point inside the deformed tissue on the world segment xa (inside) -> xb (outside),
 * by bisection, as a material point u and the tet holding it. Returns the tet, or -1 when xa is
 * not inside either. */
int coupled_world_exit_point(const NsMesh *M, const double xa[3], const double xb[3], int hint,
                             double u[3])
{
    double b[4], bm[4], q[3];
    int t = ns_mesh_locate_in(M, M->x, xa, hint, 1e-9, b);
    if (t < 0)
        return -1;
    double lo = 0.0, hi = 1.0;
    for (int it = 0; it < 50; it++) {
        double mid = 0.5 * (lo + hi);
        for (int i = 0; i < 3; i++)
            q[i] = xa[i] + mid * (xb[i] - xa[i]);
        int tm = ns_mesh_locate_in(M, M->x, q, t, 1e-9, bm);
        if (tm >= 0) {
            lo = mid;
            t = tm;
            memcpy(b, bm, sizeof b);
        } else {
            hi = mid;
        }
    }
    for (int i = 0; i < 3; i++) {
        u[i] = 0.0;
        for (int k = 0; k < 4; k++)
            u[i] += b[k] * M->u[3 * M->tet_node[4 * t + k] + i];
    }
    return t;
}

/* A tip resting against bone without cutting (sticking, or pushed by the tissue): its node
 * within a quarter of its mean edge length of a rigid region straight ahead along the needle's
 * tip tangent (taken as a material direction, the tissue by the bone being held) is in contact
 * too: pinned there, or the needle would carry it, and the soft layer in front of it, into the
 * bone (inverting the tets between). Not for a needle being withdrawn. */
static void bone_ahead(NsCoupled *c, NsCouplingStats *st)
{
    NsRod *r = c->rod;
    NsMesh *M = &c->tissue->mesh;
    NsNeedlePath *p = &c->path;
    if (c->tip_blocked || p->through || c->outside || p->count < 2 || !(r->v_insert >= 0.0))
        return;
    int tipn = p->node[p->count - 1];
    double tt[3], m1[3], m2[3], b[3], h = node_edge_mean(M, tipn);
    ns_rod_tip_frame(r, tt, m1, m2);
    double tn = norm3(tt);
    if (!(tn > 0.0) || !(h > 0.0) || M->node_tets[tipn].count == 0)
        return;
    for (int i = 0; i < 3; i++)
        b[i] = M->u[3 * tipn + i] + 0.25 * h * tt[i] / tn;
    int region = -1;
    if (rigid_crossing(M, M->u + 3 * tipn, b, h, M->node_tets[tipn].items[0], &region) < 0.0)
        return;
    st->bone_contact = 1;
    st->bone_region = region;
    c->tip_blocked = 1;
    pin_tip(c, tipn);
}

/* ---- Algorithm 2 at the tip (§3.4.1) ---- */

/* One step's cut at the tip, carried from stage to stage of remesh_tip. */
typedef struct TipCut {
    int tipn;        /* the tip's tissue node before the cut */
    int t;           /* the tet holding u_new (-1: none, the needle withdrawn out) */
    int exiting;     /* the tip goes out through the tissue's surface this step */
    int bevel;       /* NS_BEVEL_DISPLACEMENT moved u_new */
    int arc;         /* NS_BEVEL_ARC: u_new is on the arc, heading its end's */
    int stopped;     /* bone ahead: 1 a withdrawn needle springing onto it, 2 a contact */
    int K;           /* pieces of the move */
    double u_new[3]; /* the tip's new material position [m] */
    double u0[3], du[3], dist, half; /* the move from the tip's node, its length, half the edge */
    double heading[3];
} TipCut;

/* Where the tip goes in material space (u_new, the tet holding it): the needle tip's world
 * position located in the deformed tissue, or where the needle crosses the surface when it
 * left the tissue other than back through its entry (issue 32: its node is taken there, the
 * boundary split, and the needle goes on through, path.through, free outside). A needle drawn
 * back past its entry node leaves the tissue: every split is undone, every moved node goes back
 * (the original mesh), nothing is coupled any more. Returns 0 (go on), 1 (withdrawn: done) or
 * -1. */
static int tip_target(NsCoupled *c, NsCouplingStats *st, TipCut *m)
{
    NsRod *r = c->rod;
    NsTissue *T = c->tissue;
    NsMesh *M = &T->mesh;
    NsNeedlePath *p = &c->path;
    int tipn = m->tipn;
    int start = c->remesh_hint >= 0        ? c->remesh_hint
                : M->node_tets[tipn].count ? M->node_tets[tipn].items[0]
                                           : -1;
    double b[4];
    int t = ns_mesh_locate_in(M, M->x, r->x + 3 * (r->nodes - 1), start, 1e-9, b);
    int retracting = c->state[r->nodes - 1] == NS_FRICTION_DYN_NEG;
    double *u_new = m->u_new;
    if (t < 0 && !retracting) {
        t = coupled_world_exit_point(M, M->x + 3 * tipn, r->x + 3 * (r->nodes - 1), start, u_new);
        if (t < 0)
            return -1;
        m->exiting = 1;
    }
    m->t = t;
    for (int k = 0; k < 4 && t >= 0 && !m->exiting; k++)
        for (int i = 0; i < 3; i++)
            u_new[i] += b[k] * M->u[3 * M->tet_node[4 * t + k] + i];
    /* Withdrawn: a retracting tip outside the tissue (a retracting needle goes back along its
     * own track, so it left through its entry, in one step when the step draws it back further
     * than its remaining depth), or, its path down to the skin entry's two nodes, within
     * EXIT_MARGIN of the entry node's mean edge of it along the track (ours, issue 35): the last
     * node the tip drags towards the entry node makes tets with it and its star's far edges
     * whose dihedral angles shrink with the distance between the two (2.8 deg at a twelfth of an
     * element in remesh-cycles), the exit's counterpart of the skin entry's short edge
     * (remesh_entry.c). The tip, then that little way inside, is free; pushed in again deeper
     * than that, it enters afresh (coupling_reentry.c). */
    if (!retracting || (t >= 0 && p->count != 2))
        return 0;
    int en = p->node[0];
    double along = 0.0;
    if (t >= 0) {
        const double *ue = M->u + 3 * en, *ut = M->u + 3 * tipn;
        double track = 0.0;
        for (int i = 0; i < 3; i++) {
            along += (u_new[i] - ue[i]) * (ut[i] - ue[i]);
            track += (ut[i] - ue[i]) * (ut[i] - ue[i]);
        }
        along = track > 0.0 ? along / sqrt(track) : 0.0; /* the tip's depth along the track [m] */
        if (!(along <= EXIT_MARGIN * node_edge_mean(M, en)))
            return 0;
    }
    /* How deep the tip still is as it leaves (material space): coupled_reenter waits until the
     * needle is pushed deeper than that. */
    c->exit_depth = t >= 0 ? fmax(along, 0.0) : 0.0;
    /* Algorithm 2 should have undone every split but the one that made the tip's node (undoing
     * that one is the retraction's own last step). */
    st->exit_undone =
        c->remesh.count - (c->remesh.count > 0 && c->remesh.ops[c->remesh.count - 1].node == tipn);
    while (c->remesh.count > 0)
        if (ns_remesh_undo(M, &c->remesh)) {
            char err2[256];
            ns_tissue_sync_topology(T, err2, sizeof err2);
            return -1;
        }
    ns_remesh_release_all(M, &c->remesh);
    c->outside = 1;
    c->heading_valid = 0;
    st->exited = 1;
    char err[256];
    return ns_tissue_sync_topology(T, err, sizeof err) ? -1 : 1;
}

/* The paper's bevel (§3.5, NS_BEVEL_DISPLACEMENT): a bevel tip cuts sideways, u_new moving by
 * d tan(psi) along the tip frame's m2, d the distance the tip advanced through the material.
 * (m2 is a world direction; the tissue around the tip is taken as locally unrotated for it.)
 * Returns 0, or -1 when the displaced point is outside the tissue. */
static int bevel_displace(const NsCoupled *c, TipCut *m)
{
    const NsRod *r = c->rod;
    const NsMesh *M = &c->tissue->mesh;
    m->bevel = r->params.tip == NS_TIP_BEVEL && c->params.bevel_model == NS_BEVEL_DISPLACEMENT &&
               c->state[r->nodes - 1] == NS_FRICTION_DYN_POS && !m->exiting;
    if (!m->bevel)
        return 0;
    double tt[3], m1[3], m2[3], d = 0.0, *u_new = m->u_new;
    ns_rod_tip_frame(r, tt, m1, m2);
    for (int i = 0; i < 3; i++)
        d += (u_new[i] - M->u[3 * m->tipn + i]) * (u_new[i] - M->u[3 * m->tipn + i]);
    d = sqrt(d) * NS_MUTATE("bevel_disp", tan(r->params.bevel_angle));
    for (int i = 0; i < 3; i++)
        u_new[i] += d * m2[i];
    return ns_mesh_locate(M, u_new, m->t, 1e-9, NULL) < 0 ? -1 : 0;
}

/* The nonholonomic model (NS_BEVEL_ARC, Webster et al. 2006): the tip cuts along an arc in
 * material space whose heading turns towards m2 at k_c tan(psi) per distance cut (m2 taken as a
 * material direction, the tissue around the tip as locally unrotated, as above). The tip's
 * advance is its mapped world position's progress along the heading; its sideways offset from
 * the arc is dropped, so no strain builds up, and the needle, coupled to the path, follows the
 * cut. The heading persists while the needle is in (pauses and twists included) and is taken
 * afresh from the path (path_heading) after a retraction. Returns 0, or -1 when the arc's end
 * is outside the tissue. */
static int bevel_arc(NsCoupled *c, TipCut *m)
{
    const NsRod *r = c->rod;
    const NsMesh *M = &c->tissue->mesh;
    double *u_new = m->u_new, *heading = m->heading;
    int arc = r->params.tip == NS_TIP_BEVEL && c->params.bevel_model == NS_BEVEL_ARC;
    if (arc && c->state[r->nodes - 1] == NS_FRICTION_DYN_NEG)
        c->heading_valid = 0;
    m->arc = arc && c->state[r->nodes - 1] == NS_FRICTION_DYN_POS && m->t >= 0 && !m->exiting;
    if (!m->arc)
        return 0;
    double tt[3], m1[3], m2[3], w[3], adv = 0.0, wn = 0.0;
    ns_rod_tip_frame(r, tt, m1, m2);
    if (c->heading_valid) {
        memcpy(heading, c->heading, 3 * sizeof *heading);
    } else if (!path_heading(M, &c->path, heading)) {
        double tn = norm3(tt);
        for (int i = 0; i < 3; i++)
            heading[i] = tn > 0.0 ? tt[i] / tn : 0.0;
    }
    m->arc = norm3(heading) > 0.5; /* no tangent (a degenerate tip edge): no arc this step */
    const double *ut = M->u + 3 * m->tipn;
    for (int i = 0; i < 3; i++)
        adv += (u_new[i] - ut[i]) * heading[i];
    double mh = m2[0] * heading[0] + m2[1] * heading[1] + m2[2] * heading[2];
    for (int i = 0; i < 3; i++)
        w[i] = m2[i] - mh * heading[i];
    wn = norm3(w);
    int reg = M->tet_region[m->t];
    double kc = reg >= 0 && reg < NS_COUPLING_MAX_REGIONS ? c->params.bevel_curvature[reg] : 0.0;
    double kappa = wn > 1e-12 ? kc * tan(r->params.bevel_angle) : 0.0;
    if (m->arc && !(adv > 0.0)) {
        memcpy(u_new, ut, 3 * sizeof *u_new); /* no progress along the arc: the tip stays */
    } else if (m->arc) {
        /* The arc of length adv: its chord (half the turn, 2 sin(a/2) / kappa long), and the
         * heading at its end (the whole turn). */
        double a = kappa * adv, chord = kappa > 0.0 ? 2.0 * sin(0.5 * a) / kappa : adv;
        for (int i = 0; i < 3; i++) {
            double wi = wn > 1e-12 ? w[i] / wn : 0.0;
            u_new[i] = ut[i] + chord * (cos(0.5 * a) * heading[i] + sin(0.5 * a) * wi);
            heading[i] = cos(a) * heading[i] + sin(a) * wi;
        }
        double hn = norm3(heading);
        for (int i = 0; i < 3; i++)
            heading[i] /= hn;
        if (ns_mesh_locate(M, u_new, m->t, 1e-9, NULL) < 0)
            return -1;
    }
    return 0;
}

/* Sub-stepping (§3.4.1: Algorithm 2 presumes the tip moves less than about an element in a
 * step): a move of more than half the mean length of the tip node's edges is cut into K equal
 * pieces along the straight line to u_new, each remeshed in turn. Bone (issue 32): a cutting
 * tip whose move enters a rigid region (every node of a tet fixed) stops at its surface, a
 * tenth of the mean edge length short of it: bone is not cut. The needle rests on it
 * (tip_blocked: the sleeve slips, ns_step) until it is withdrawn. Returns 0 (go on), 1 (the tip
 * stays: done) or -1. */
static int plan_pieces(NsCoupled *c, NsCouplingStats *st, TipCut *m)
{
    const NsRod *r = c->rod;
    const NsMesh *M = &c->tissue->mesh;
    int tipn = m->tipn;
    double *u0 = m->u0, *du = m->du, *u_new = m->u_new, hsum = 0.0;
    int hn = 0;
    memcpy(u0, M->u + 3 * tipn, 3 * sizeof *u0);
    for (int i = 0; i < 3; i++)
        du[i] = u_new[i] - u0[i];
    const NsIntList *lt = &M->node_tets[tipn];
    for (int j = 0; j < lt->count; j++)
        for (int k = 0; k < 4; k++) {
            int o = M->tet_node[4 * lt->items[j] + k];
            if (o == tipn)
                continue;
            double e[3];
            for (int i = 0; i < 3; i++)
                e[i] = M->u[3 * o + i] - u0[i];
            hsum += norm3(e);
            hn++;
        }
    double half = hn ? 0.5 * hsum / hn : INFINITY, dist = norm3(du);
    m->half = half;
    if (c->state[r->nodes - 1] == NS_FRICTION_DYN_POS && hn) {
        int region = -1;
        double f = rigid_crossing(M, u0, u_new, 2.0 * half, m->t, &region);
        if (f >= 0.0) {
            /* (A needle being withdrawn that springs forward onto the bone stops there too,
             * but it is not a new contact.) */
            m->stopped = 1 + (r->v_insert >= 0.0);
            m->exiting = 0;
            if (m->stopped == 2) {
                st->bone_contact = c->tip_blocked ? 2 : 1;
                st->bone_region = region;
                c->tip_blocked = 1;
            }
            double go = f * dist - 0.2 * half;
            if (!(go > 1e-3 * half)) { /* already at the surface: the tip stays */
                if (m->stopped == 2)
                    pin_tip(c, tipn);
                return 1;
            }
            for (int i = 0; i < 3; i++) {
                du[i] *= go / dist;
                u_new[i] = u0[i] + du[i];
            }
            dist = go;
        }
    }
    m->dist = dist;
    m->K = dist > half ? (int)ceil(dist / half) : 1;
    if (m->K > 64) {
        snprintf(c->error, sizeof c->error,
                 "the tip moved %.3g m in one step, more than 32 elements: take smaller steps",
                 dist);
        return -1;
    }
    st->remesh_substeps = m->K;
    return 0;
}

/* Algorithm 2 (ns_remesh_tip) on each piece of the move in turn; chain (len entries, tip first)
 * follows the tip's node, res is the last accepted result. Returns 0 or -1. */
static int cut_pieces(NsCoupled *c, NsCouplingStats *st, const TipCut *m, int *chain, int *len_io,
                      NsRemeshResult *res_out)
{
    NsMesh *M = &c->tissue->mesh;
    int len = *len_io, K = m->K, hint = m->t, rc = 0;
    int penetrating = c->state[c->rod->nodes - 1] == NS_FRICTION_DYN_POS;
    NsRemeshResult res, good;
    memset(&res, 0, sizeof res);
    memset(&good, 0, sizeof good);
    good.tip = chain[0];
    char err[256];
    for (int sub = 1; sub <= K && rc == 0; sub++) {
        double us[3];
        for (int i = 0; i < 3; i++)
            us[i] = sub == K ? m->u_new[i] : m->u0[i] + m->du[i] * sub / K;
        /* Only the exit's last piece may change the boundary (a node on the far surface). */
        NsRemeshTip tip = {chain[0],
                           chain[1],
                           len > 2 ? chain[2] : -1,
                           chain,
                           len,
                           penetrating,
                           m->exiting && sub == K,
                           hint,
                           c->params.remesh_dihedral_floor,
                           m->arc};
        rc = ns_remesh_tip(M, &c->remesh, &tip, us, &res, err, sizeof err);
        if (rc != 0 && (m->stopped || m->exiting)) {
            /* Next to bone or at the surface no operation may place the tip there: it stays
             * where the last piece put it (at bone, it stops a little shorter; at the exit,
             * the needle goes through from that node). */
            rc = 0;
            res = good;
            break;
        }
        if (rc != 0) {
            snprintf(c->error, sizeof c->error, "%s", err);
            /* Scoring may have grown the mesh's slots even though nothing was accepted: the
             * tissue's arrays must follow before it is touched again. */
            char err2[256];
            ns_tissue_sync_topology(c->tissue, err2, sizeof err2);
            break;
        }
        good = res;
        if (res.dropped) {
            chain[0] = res.tip;
            if (len > 2 && chain[1] == res.tip) {
                memmove(chain, chain + 1, (size_t)(len - 1) * sizeof *chain);
                len--;
            }
        } else if (res.tip != chain[0]) {
            memmove(chain + 1, chain, (size_t)len * sizeof *chain);
            chain[0] = res.tip;
            len++;
        }
        hint = tip.hint_tet;
        st->remesh_repaired += res.repaired;
        st->cutting |= res.kind != NS_REMESH_NONE && penetrating;
    }
    if (rc == 0)
        c->remesh_hint = hint;
    *len_io = len;
    *res_out = res;
    return rc;
}

/* The path after the cut: the chain (tip first) in path order with its material arc lengths,
 * the bevel's and the arc's state, a far-side exit, the tissue's arrays synced to the mesh, and
 * the tip pinned on bone. Returns 0 or -1. */
static int commit_path(NsCoupled *c, NsCouplingStats *st, const TipCut *m, const int *chain,
                       int len, const NsRemeshResult *res)
{
    NsRod *r = c->rod;
    NsMesh *M = &c->tissue->mesh;
    NsNeedlePath *p = &c->path;
    p->count = len;
    for (int k = 0; k < len; k++)
        p->node[k] = chain[len - 1 - k];
    p->s[0] = 0.0;
    for (int k = 1; k < len; k++) {
        double d[3];
        for (int i = 0; i < 3; i++)
            d[i] = M->u[3 * p->node[k] + i] - M->u[3 * p->node[k - 1] + i];
        p->s[k] = p->s[k - 1] + norm3(d);
    }
    p->tip_s = p->s[len - 1];
    st->remesh_kind = res->kind;
    st->remesh_undone = res->undone;
    st->remesh_candidates = res->candidates;
    /* The bevel's displacement is in material space only (§3.5, Figure 7b): the new tip node
     * stays at the needle's tip in the world, so the tissue around it is strained towards m2
     * and pushes the tip there in the next steps. */
    if (m->bevel)
        memcpy(M->x + 3 * res->tip, r->x + 3 * (r->nodes - 1), 3 * sizeof(double));
    if (m->arc) {
        memcpy(c->heading, m->heading, sizeof c->heading);
        c->heading_valid = 1;
    }
    if (m->exiting) {
        p->through = 1; /* the path ends at the surface; the tip is free beyond it */
        c->heading_valid = 0;
        st->tip_exit = 1;
    }
    char err[256];
    int rc = ns_tissue_sync_topology(c->tissue, err, sizeof err);
    if (rc == 0 && m->stopped == 2) /* after the sync, which frees a new node's DOFs */
        pin_tip(c, res->tip);
    return rc;
}

/* Algorithm 2 at the tip (§3.4.1): the needle tip's world position, located in the deformed
 * tissue, gives its material position u_new (moved by the bevel, or along the arc); the tissue
 * is remeshed so a node sits there, piece by piece, and the needle's chain of tissue nodes (the
 * path) follows; the tissue then syncs its arrays. */
static int remesh_tip(NsCoupled *c, NsCouplingStats *st)
{
    NsNeedlePath *p = &c->path;
    TipCut m;
    memset(&m, 0, sizeof m);
    m.tipn = p->node[p->count - 1];
    int rc = tip_target(c, st, &m);
    if (rc == 0)
        rc = bevel_displace(c, &m);
    if (rc == 0)
        rc = bevel_arc(c, &m);
    if (rc == 0)
        rc = plan_pieces(c, st, &m);
    if (rc != 0)
        return rc < 0 ? -1 : 0;
    /* The chain, tip first (it may grow by one node per piece). */
    int len = p->count;
    if (p->count + m.K + 2 > c->path_cap) {
        int cap = 2 * (p->count + m.K + 2);
        int *nd = realloc(p->node, (size_t)cap * sizeof *nd);
        if (!nd)
            return -1;
        p->node = nd;
        double *sv = realloc(p->s, (size_t)cap * sizeof *sv);
        if (!sv)
            return -1;
        p->s = sv;
        c->path_cap = cap;
    }
    int *chain = ns_arena_push(&c->arena, (size_t)(len + m.K + 2) * sizeof *chain);
    if (!chain)
        return -1;
    for (int k = 0; k < len; k++)
        chain[k] = p->node[len - 1 - k];
    NsRemeshResult res;
    rc = cut_pieces(c, st, &m, chain, &len, &res);
    if (rc == 0)
        rc = commit_path(c, st, &m, chain, len, &res);
    ns_arena_pop(&c->arena, chain);
    return rc;
}

/* ---- the tip's cut after the step ---- */

int coupled_cut_tip(NsCoupled *c, NsCouplingStats *st)
{
    NsRod *r = c->rod;
    const NsMesh *M = &c->tissue->mesh;
    NsNeedlePath *p = &c->path;
    int n = r->nodes, coupled = 0;
    for (int i = 0; i < n; i++)
        coupled |= c->ta[i] >= 0;
    if (!coupled && !(c->params.remesh && c->outside))
        return 0;
    if (!coupled) {
        /* Withdrawn: nothing cuts until the needle is pushed in again, a fresh skin entry
         * (coupling_reentry.c), whose tip node Algorithm 2 then takes to the needle's tip. */
        int rc = coupled_reenter(c, st);
        if (rc <= 0)
            return rc;
        rc = remesh_tip(c, st);
        c->state[n - 1] = NS_FRICTION_STATIC; /* a fresh entry's states, all STATIC */
        if (rc == 0 && !c->outside)
            tip_dihedrals(c, st);
        return rc;
    }
    st->tip_slide = 0.0;
    if (c->params.remesh) {
        /* Through the far side (issue 32): drawn back until its tip is within a quarter of the
         * needle's shortest edge of the exit node (or behind it), the needle's tip is at the
         * exit again, and cuts or retracts from there as before. */
        if (p->through && p->count >= 2) {
            int pe = p->node[p->count - 1], pd = p->node[p->count - 2];
            double t[3], d[3];
            for (int k = 0; k < 3; k++) {
                t[k] = M->x[3 * pe + k] - M->x[3 * pd + k];
                d[k] = r->x[3 * (n - 1) + k] - M->x[3 * pe + k];
            }
            if (dot3(d, t) / norm3(t) < 0.25 * r->min_rest_edge) {
                p->through = 0;
                p->tip_s = p->s[p->count - 1];
                st->tip_returned = 1;
            }
        }
        /* The tip's node follows the needle tip by remeshing (skipped while it sticks). */
        if (!p->through && !st->tip_returned && c->ta[n - 1] >= 0 &&
            c->state[n - 1] != NS_FRICTION_STATIC && remesh_tip(c, st))
            return -1;
        if (c->outside) /* withdrawn this step: coupled_reparameterize uncouples it */
            return 0;
        bone_ahead(c, st);
        tip_dihedrals(c, st);
        return 0;
    }
    /* Along the pre-laid path: the tip's slide along its tangent, mapped into material length
     * on its edge. */
    if (p->through || c->ta[n - 1] < 0 || c->state[n - 1] == NS_FRICTION_STATIC)
        return 0;
    double xp[3], t[3], d[3];
    coupled_tissue_point(c, n - 1, M->x, xp);
    for (int k = 0; k < 3; k++) {
        t[k] = r->x[3 * (n - 1) + k] - r->x[3 * (n - 2) + k];
        d[k] = r->x[3 * (n - 1) + k] - xp[k];
    }
    double lt = norm3(t), slide = lt > 0.0 ? dot3(d, t) / lt : 0.0;
    double ew[3], eu[3];
    int a = c->ta[n - 1], b = c->tb[n - 1];
    for (int k = 0; k < 3; k++) {
        ew[k] = M->x[3 * b + k] - M->x[3 * a + k];
        eu[k] = M->u[3 * b + k] - M->u[3 * a + k];
    }
    st->tip_slide = slide;
    st->cutting = slide > 0.0 && c->state[n - 1] == NS_FRICTION_DYN_POS;
    p->tip_s += slide * norm3(eu) / norm3(ew);
    if (p->tip_s > p->s[p->count - 1])
        p->through = 1; /* out through the far side: the tip is free */
    if (p->tip_s < 0.0)
        p->tip_s = 0.0;
    return 0;
}
