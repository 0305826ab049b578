/* Needle-tissue coupling (sim/coupling.h): the coupled step of Algorithm 1, the friction model of
 * §3.3 (Eq. 7-8; the friction checks of Eq. 9-11 are friction.c, Algorithm 3 with each solver
 * coupled_paper.c and coupled_schur.c), the tip remeshing call (Algorithm 2, sim/remesh.c) and the
 * needle reparameterization of §3.4.2 after each step. */
#include "coupling.h"
#include "coupling_internal.h"
#include "quality.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return 1e3 * (double)ts.tv_sec + 1e-6 * (double)ts.tv_nsec;
}

static double dot3(const double *a, const double *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static double norm3(const double *a)
{
    return sqrt(dot3(a, a));
}

NsCouplingParams ns_default_coupling_params(void)
{
    NsCouplingParams p;
    memset(&p, 0, sizeof p);
    p.f_perlen = 10.0; /* N/m: needle-tissue friction of soft tissue, order of Crouch 2005 */
    p.eta = 0.0;
    /* §3.6.1 used 1e-3 and 1e-5 in its own units. Here the residual is that of the system scaled
     * to a unit diagonal (coupled_paper.c); at 1e-3 / 1e-5 the friction checks flip on solver
     * error (ten-trial failures, a needle that ran away in friction-stick), at 1e-6 / 1e-8 they
     * do not (docs/solvers.md). */
    p.tau_check = 1e-6;
    p.tau_sol = 1e-8;
    p.max_trials = 10;
    p.max_iter = 5000;
    p.solver = NS_COUPLED_SCHUR;
    p.threads = 1;
    p.refresh_iterations = 10;
    p.tip_block = 0;
    p.remesh_dihedral_floor = 12.0;
    p.bevel_model = NS_BEVEL_FORCE;
    for (int k = 0; k < NS_COUPLING_MAX_REGIONS; k++) {
        p.bevel_force[k] = 0.5;      /* N: docs/remeshing.md (bevel steering) */
        p.bevel_curvature[k] = 10.0; /* 1/m: the force model's at 45 deg in the gel (ibid.) */
    }
    return p;
}

const char *ns_coupled_solver_name(NsCoupledSolverKind kind)
{
    return kind == NS_COUPLED_PAPER ? "paper" : kind == NS_COUPLED_SCHUR ? "schur" : "?";
}

int ns_coupled_solver_parse(const char *name)
{
    if (strcmp(name, "paper") == 0)
        return NS_COUPLED_PAPER;
    if (strcmp(name, "schur") == 0)
        return NS_COUPLED_SCHUR;
    return -1;
}

static int reserve(NsCoupled *c, int cap)
{
    if (cap <= c->cap)
        return 0;
    int *ta = realloc(c->ta, (size_t)cap * sizeof *ta);
    if (ta)
        c->ta = ta;
    int *tb = realloc(c->tb, (size_t)cap * sizeof *tb);
    if (tb)
        c->tb = tb;
    double *tw = realloc(c->tw, (size_t)cap * sizeof *tw);
    if (tw)
        c->tw = tw;
    uint8_t *st = realloc(c->state, (size_t)cap);
    if (st)
        c->state = st;
    if (!ta || !tb || !tw || !st)
        return -1;
    for (int i = c->cap; i < cap; i++) {
        c->ta[i] = c->tb[i] = -1;
        c->tw[i] = 0.0;
        c->state[i] = NS_FRICTION_FREE;
    }
    c->cap = cap;
    return 0;
}

static double *scratch(NsCoupled *c, size_t n)
{
    if (n > c->work_cap) {
        double *w = realloc(c->work, n * sizeof *w);
        if (!w)
            return NULL;
        c->work = w;
        c->work_cap = n;
    }
    return c->work;
}

/* Sets the coupling of the rod's nodes from the path: nodes first .. first+behind-1 at path
 * nodes, then the tip on its edge (unless through); others FREE. Keeps states of nodes that stay
 * coupled when keep_state, else STATIC. */
static void couple_from_path(NsCoupled *c, int first, int keep_state)
{
    NsRod *r = c->rod;
    const NsNeedlePath *p = &c->path;
    int nb = c->outside ? 0 : ns_needle_path_behind(p);
    for (int i = 0; i < r->nodes; i++) {
        int k = i - first;
        uint8_t old = c->state[i];
        c->ta[i] = c->tb[i] = -1;
        c->tw[i] = 0.0;
        r->pinned[i] = 0;
        if (k >= 0 && k < nb) {
            c->ta[i] = c->tb[i] = p->node[k];
        } else if (k == nb && i == r->nodes - 1 && !p->through && !c->outside) {
            double w;
            int e = ns_needle_path_tip(p, &w);
            c->ta[i] = p->node[e];
            c->tb[i] = p->node[e + 1];
            c->tw[i] = w;
        }
        if (c->ta[i] >= 0) {
            r->pinned[i] = 1;
            c->state[i] = keep_state && old != NS_FRICTION_FREE ? old : NS_FRICTION_STATIC;
        } else {
            c->state[i] = NS_FRICTION_FREE;
        }
    }
}

static void tissue_point(const NsCoupled *c, int i, const double *v, double *out)
{
    const double *a = v + 3 * c->ta[i], *b = v + 3 * c->tb[i];
    for (int k = 0; k < 3; k++)
        out[k] = (1.0 - c->tw[i]) * a[k] + c->tw[i] * b[k];
}

int ns_coupled_init(NsCoupled *c, NsTissue *tissue, NsRod *rod, NsNeedlePath *path,
                    const NsCouplingParams *params, char *err, int err_sz)
{
    memset(c, 0, sizeof *c);
    c->tissue = tissue;
    c->rod = rod;
    c->params = params ? *params : ns_default_coupling_params();
    const NsCouplingParams *q = &c->params;
    int bad_bevel = q->bevel_model != NS_BEVEL_FORCE && q->bevel_model != NS_BEVEL_DISPLACEMENT &&
                    q->bevel_model != NS_BEVEL_ARC;
    for (int k = 0; k < NS_COUPLING_MAX_REGIONS; k++)
        bad_bevel |= !(q->bevel_force[k] >= 0.0 && isfinite(q->bevel_force[k])) ||
                     !(q->bevel_curvature[k] >= 0.0 && isfinite(q->bevel_curvature[k]));
    if (!(q->f_perlen >= 0.0) || !(q->eta >= 0.0) || !(q->tau_sol > 0.0) ||
        !(q->tau_check >= q->tau_sol) || q->max_trials < 1 || q->max_iter < 1 ||
        q->refresh_iterations < 0 || bad_bevel ||
        !(q->remesh_dihedral_floor >= 0.0 && q->remesh_dihedral_floor <= 60.0) ||
        (q->solver != NS_COUPLED_PAPER && q->solver != NS_COUPLED_SCHUR)) {
        snprintf(err, (size_t)err_sz,
                 "coupling: f_perlen and eta must be >= 0, 0 < tau_sol <= tau_check, "
                 "max_trials and max_iter >= 1, refresh_iterations >= 0, solver schur or paper, "
                 "remesh_dihedral_floor in [0, 60] deg, "
                 "bevel model force, displacement or arc with finite bevel forces and "
                 "curvatures >= 0");
        ns_needle_path_free(path); /* taken over, even on failure */
        return -1;
    }
    if (tissue->params.beta != rod->params.beta || tissue->params.gamma != rod->params.gamma) {
        snprintf(err, (size_t)err_sz,
                 "coupling: tissue and needle must share Newmark's beta and gamma (tissue %g, %g; "
                 "needle %g, %g)",
                 tissue->params.beta, tissue->params.gamma, rod->params.beta, rod->params.gamma);
        ns_needle_path_free(path);
        return -1;
    }
    c->path = *path;
    c->path_cap = path->count;
    *path = (NsNeedlePath){0};
    ns_remesh_stack_init(&c->remesh);
    c->remesh_hint = -1;
    if (q->remesh && (c->path.through || c->path.tip_s < c->path.s[c->path.count - 1] - 1e-12)) {
        snprintf(err, (size_t)err_sz,
                 "coupling: with remeshing the needle's tip must sit at the path's last node");
        ns_coupled_free(c);
        return -1;
    }
    if (q->solver == NS_COUPLED_SCHUR && !(c->schur = coupled_schur_create())) {
        snprintf(err, (size_t)err_sz, "coupling: out of memory");
        ns_coupled_free(c);
        return -1;
    }
    if (reserve(c, rod->cap)) {
        snprintf(err, (size_t)err_sz, "coupling: out of memory");
        ns_coupled_free(c);
        return -1;
    }
    /* Find the rod node at the path's entry, and check the rest against the path. */
    const NsMesh *M = &tissue->mesh;
    int first = -1;
    for (int i = rod->held; i < rod->nodes && first < 0; i++) {
        double d[3];
        for (int k = 0; k < 3; k++)
            d[k] = rod->x[3 * i + k] - M->x[3 * c->path.node[0] + k];
        if (norm3(d) < 1e-9)
            first = i;
    }
    if (first < 0) {
        snprintf(err, (size_t)err_sz, "coupling: no needle node at the path's entry (node %d)",
                 c->path.node[0]);
        ns_coupled_free(c);
        return -1;
    }
    couple_from_path(c, first, 0);
    for (int i = 0; i < rod->nodes; i++) {
        if (c->ta[i] < 0)
            continue;
        double xp[3], d[3];
        tissue_point(c, i, M->x, xp);
        for (int k = 0; k < 3; k++)
            d[k] = rod->x[3 * i + k] - xp[k];
        if (norm3(d) > 1e-9) {
            snprintf(err, (size_t)err_sz,
                     "coupling: needle node %d is %.3g m from its tissue point (path node %d)", i,
                     norm3(d), i - first);
            ns_coupled_free(c);
            return -1;
        }
    }
    if (!c->path.through && c->ta[rod->nodes - 1] < 0) {
        snprintf(err, (size_t)err_sz, "coupling: the needle's tip is not on the path");
        ns_coupled_free(c);
        return -1;
    }
    return 0;
}

void ns_coupled_free(NsCoupled *c)
{
    ns_needle_path_free(&c->path);
    free(c->ta);
    free(c->tb);
    free(c->tw);
    free(c->state);
    free(c->work);
    coupled_schur_destroy(c->schur);
    ns_remesh_stack_free(&c->remesh);
    memset(c, 0, sizeof *c);
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
static void unpin_tip(NsCoupled *c)
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
    unpin_tip(c);
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
static int world_exit_point(const NsMesh *M, const double xa[3], const double xb[3], int hint,
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

/* Algorithm 2 at the tip (§3.4.1): the needle tip's world position, located in the deformed
 * tissue, gives its material position u_new; the tissue is remeshed so a node sits there and
 * the needle's chain of tissue nodes (the path) follows; the tissue then syncs its arrays. */
static int remesh_tip(NsCoupled *c, NsCouplingStats *st)
{
    NsRod *r = c->rod;
    NsTissue *T = c->tissue;
    NsMesh *M = &T->mesh;
    NsNeedlePath *p = &c->path;
    int tipn = p->node[p->count - 1];
    int start = c->remesh_hint >= 0        ? c->remesh_hint
                : M->node_tets[tipn].count ? M->node_tets[tipn].items[0]
                                           : -1;
    double b[4];
    int t = ns_mesh_locate_in(M, M->x, r->x + 3 * (r->nodes - 1), start, 1e-9, b);
    int retracting = c->state[r->nodes - 1] == NS_FRICTION_DYN_NEG;
    double u_new[3] = {0, 0, 0};
    /* The tip left the tissue other than back through its entry: it goes out through the
     * surface (issue 32). Its node is taken to where the needle crosses the surface, the
     * boundary split there, and the needle goes on through (path.through): the part outside is
     * free, the tip no longer cuts. */
    int exiting = 0;
    if (t < 0 && !(retracting && p->count == 2)) {
        if (retracting)
            return -1; /* drawn back out of the tissue elsewhere than at the entry: not modelled */
        t = world_exit_point(M, M->x + 3 * tipn, r->x + 3 * (r->nodes - 1), start, u_new);
        if (t < 0)
            return -1;
        exiting = 1;
    }
    for (int k = 0; k < 4 && t >= 0 && !exiting; k++)
        for (int i = 0; i < 3; i++)
            u_new[i] += b[k] * M->u[3 * M->tet_node[4 * t + k] + i];
    if (retracting && p->count == 2) {
        /* Withdrawn past the entry node (or out of the tissue): the needle leaves. Every split
         * left is undone and every moved node goes back (the original mesh), nothing is
         * coupled any more. */
        const double *ue = M->u + 3 * p->node[0], *ut = M->u + 3 * tipn;
        double along = 0.0;
        for (int i = 0; i < 3; i++)
            along += (u_new[i] - ue[i]) * (ut[i] - ue[i]);
        if (t < 0 || along <= 0.0) {
            /* Algorithm 2 should have undone every split but the one that made the tip's node
             * (undoing that one is the retraction's own last step). */
            st->exit_undone = c->remesh.count - (c->remesh.count > 0 &&
                                                 c->remesh.ops[c->remesh.count - 1].node == tipn);
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
            return ns_tissue_sync_topology(T, err, sizeof err);
        }
    }
    /* A bevel tip (§3.5) cuts sideways: u_new moves by d tan(psi) along the tip frame's m2, d
     * the distance the tip advanced through the material. (m2 is a world direction; the tissue
     * around the tip is taken as locally unrotated for it.) */
    int bevel = r->params.tip == NS_TIP_BEVEL && c->params.bevel_model == NS_BEVEL_DISPLACEMENT &&
                c->state[r->nodes - 1] == NS_FRICTION_DYN_POS && !exiting;
    if (bevel) {
        double tt[3], m1[3], m2[3], d = 0.0;
        ns_rod_tip_frame(r, tt, m1, m2);
        for (int i = 0; i < 3; i++)
            d += (u_new[i] - M->u[3 * tipn + i]) * (u_new[i] - M->u[3 * tipn + i]);
        d = sqrt(d) * tan(r->params.bevel_angle);
        for (int i = 0; i < 3; i++)
            u_new[i] += d * m2[i];
        if (ns_mesh_locate(M, u_new, t, 1e-9, NULL) < 0)
            return -1;
    }
    /* The nonholonomic model (NS_BEVEL_ARC, Webster et al. 2006): the tip cuts along an arc in
     * material space whose heading turns towards m2 at k_c tan(psi) per distance cut (m2 taken
     * as a material direction, the tissue around the tip as locally unrotated, as above). The
     * tip's advance is its mapped world position's progress along the heading; its sideways
     * offset from the arc is dropped, so no strain builds up, and the needle, coupled to the
     * path, follows the cut. The heading persists while the needle is in (pauses and twists
     * included) and is taken afresh from the path (path_heading) after a retraction. */
    int arc = r->params.tip == NS_TIP_BEVEL && c->params.bevel_model == NS_BEVEL_ARC;
    double heading[3];
    if (arc && c->state[r->nodes - 1] == NS_FRICTION_DYN_NEG)
        c->heading_valid = 0;
    arc = arc && c->state[r->nodes - 1] == NS_FRICTION_DYN_POS && t >= 0 && !exiting;
    if (arc) {
        double tt[3], m1[3], m2[3], w[3], adv = 0.0, wn = 0.0;
        ns_rod_tip_frame(r, tt, m1, m2);
        if (c->heading_valid) {
            memcpy(heading, c->heading, sizeof heading);
        } else if (!path_heading(M, p, heading)) {
            double tn = norm3(tt);
            for (int i = 0; i < 3; i++)
                heading[i] = tn > 0.0 ? tt[i] / tn : 0.0;
        }
        arc = norm3(heading) > 0.5; /* no tangent (a degenerate tip edge): no arc this step */
        const double *ut = M->u + 3 * tipn;
        for (int i = 0; i < 3; i++)
            adv += (u_new[i] - ut[i]) * heading[i];
        double mh = m2[0] * heading[0] + m2[1] * heading[1] + m2[2] * heading[2];
        for (int i = 0; i < 3; i++)
            w[i] = m2[i] - mh * heading[i];
        wn = norm3(w);
        int reg = M->tet_region[t];
        double kc =
            reg >= 0 && reg < NS_COUPLING_MAX_REGIONS ? c->params.bevel_curvature[reg] : 0.0;
        double kappa = wn > 1e-12 ? kc * tan(r->params.bevel_angle) : 0.0;
        if (arc && !(adv > 0.0)) {
            memcpy(u_new, ut, sizeof u_new); /* no progress along the arc: the tip stays */
        } else if (arc) {
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
            if (ns_mesh_locate(M, u_new, t, 1e-9, NULL) < 0)
                return -1;
        }
    }
    /* Sub-stepping (§3.4.1: Algorithm 2 presumes the tip moves less than about an element in a
     * step): a move of more than half the mean length of the tip node's edges is cut into
     * equal pieces along the straight line to u_new, each remeshed in turn. */
    double u0[3], du[3], hsum = 0.0;
    int hn = 0;
    memcpy(u0, M->u + 3 * tipn, sizeof u0);
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
    /* Bone (issue 32): a cutting tip whose move enters a rigid region (every node of a tet
     * fixed) stops at its surface, a tenth of the mean edge length short of it: bone is not cut.
     * The needle rests on it (tip_blocked: the sleeve slips, ns_coupled_step) until it is
     * withdrawn. */
    int stopped = 0;
    if (c->state[r->nodes - 1] == NS_FRICTION_DYN_POS && hn) {
        int region = -1;
        double f = rigid_crossing(M, u0, u_new, 2.0 * half, t, &region);
        if (f >= 0.0) {
            /* (A needle being withdrawn that springs forward onto the bone stops there too,
             * but it is not a new contact.) */
            stopped = 1 + (r->v_insert >= 0.0);
            exiting = 0;
            if (stopped == 2) {
                st->bone_contact = c->tip_blocked ? 2 : 1;
                st->bone_region = region;
                c->tip_blocked = 1;
            }
            double go = f * dist - 0.2 * half;
            if (!(go > 1e-3 * half)) { /* already at the surface: the tip stays */
                if (stopped == 2)
                    pin_tip(c, tipn);
                return 0;
            }
            for (int i = 0; i < 3; i++) {
                du[i] *= go / dist;
                u_new[i] = u0[i] + du[i];
            }
            dist = go;
        }
    }
    int K = dist > half ? (int)ceil(dist / half) : 1;
    if (K > 64) {
        snprintf(c->error, sizeof c->error,
                 "the tip moved %.3g m in one step, more than 32 elements: take smaller steps",
                 dist);
        return -1;
    }
    st->remesh_substeps = K;
    /* The chain, tip first (it may grow by one node per sub-step). */
    int len = p->count;
    if (p->count + K + 2 > c->path_cap) {
        int cap = 2 * (p->count + K + 2);
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
    int *chain = malloc((size_t)(len + K + 2) * sizeof *chain);
    if (!chain)
        return -1;
    for (int k = 0; k < len; k++)
        chain[k] = p->node[len - 1 - k];
    int penetrating = c->state[r->nodes - 1] == NS_FRICTION_DYN_POS, hint = t, rc = 0;
    NsRemeshResult res, good;
    memset(&res, 0, sizeof res);
    memset(&good, 0, sizeof good);
    good.tip = chain[0];
    char err[256];
    for (int sub = 1; sub <= K && rc == 0; sub++) {
        double us[3];
        for (int i = 0; i < 3; i++)
            us[i] = sub == K ? u_new[i] : u0[i] + du[i] * sub / K;
        /* Only the exit's last piece may change the boundary (a node on the far surface). */
        NsRemeshTip tip = {chain[0],
                           chain[1],
                           len > 2 ? chain[2] : -1,
                           chain,
                           len,
                           penetrating,
                           exiting && sub == K,
                           hint,
                           c->params.remesh_dihedral_floor};
        rc = ns_remesh_tip(M, &c->remesh, &tip, us, &res, err, sizeof err);
        if (rc != 0 && (stopped || exiting)) {
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
            ns_tissue_sync_topology(T, err2, sizeof err2);
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
    if (rc == 0) {
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
        c->remesh_hint = hint;
        st->remesh_kind = res.kind;
        st->remesh_undone = res.undone;
        st->remesh_candidates = res.candidates;
        /* The bevel's displacement is in material space only (§3.5, Figure 7b): the new tip
         * node stays at the needle's tip in the world, so the tissue around it is strained
         * towards m2 and pushes the tip there in the next steps. */
        if (bevel)
            memcpy(M->x + 3 * res.tip, r->x + 3 * (r->nodes - 1), 3 * sizeof(double));
        if (arc) {
            memcpy(c->heading, heading, sizeof heading);
            c->heading_valid = 1;
        }
        if (exiting) {
            p->through = 1; /* the path ends at the surface; the tip is free beyond it */
            c->heading_valid = 0;
            st->tip_exit = 1;
        }
        rc = ns_tissue_sync_topology(T, err, sizeof err);
        if (rc == 0 && stopped == 2) /* after the sync, which frees a new node's DOFs */
            pin_tip(c, res.tip);
    }
    free(chain);
    return rc;
}

/* ---- reparameterization (§3.4.2) after the step ---- */

/* Moves the tip along the path by its slide through the tissue this step (cutting forward,
 * retracting back), then rebuilds the needle's nodes: the held and free nodes before the entry
 * keep their solved positions, the coupled ones take their tissue points' positions, free
 * nodes past the exit theirs; every node is labelled by its distance from the base along the
 * new polyline, scaled so the tip keeps the old total (the needle is not perfectly
 * inextensible), and the rod's quantities are carried across (ns_rod_resample), then too long
 * free edges split and too short ones merged. Friction states go to the nearest old node. */
static int reparameterize(NsCoupled *c, NsCouplingStats *st)
{
    NsRod *r = c->rod;
    const NsMesh *M = &c->tissue->mesh;
    NsNeedlePath *p = &c->path;
    int n = r->nodes;
    int first = -1, last = -1;
    for (int i = 0; i < n; i++)
        if (c->ta[i] >= 0) {
            first = first < 0 ? i : first;
            last = i;
        }
    if (first < 0) {
        /* Outside the tissue: nothing is coupled. A withdrawn needle pushed back in would pass
         * through the tissue unseen: re-entry is not handled yet, so it is an error. */
        if (c->outside &&
            ns_mesh_locate_in(M, M->x, r->x + 3 * (n - 1), c->remesh_hint, 1e-9, NULL) >= 0) {
            snprintf(c->error, sizeof c->error,
                     "the needle went back into the tissue after leaving it (re-entry is not "
                     "modelled yet)");
            return -1;
        }
        /* Free of the tissue, the rod still splits and merges its edges: a retraction shortens
         * the edge at the sleeve, which must merge with the next to go on. */
        if (c->outside) {
            NsRodStats rs;
            memset(&rs, 0, sizeof rs);
            if (ns_rod_reparameterize(r, &rs) || reserve(c, r->cap))
                return -1;
            st->rod_splits += rs.splits;
            st->rod_merges += rs.merges;
            couple_from_path(c, 0, 0);
        }
        return 0;
    }
    /* The tip's cut (or retreat): its slide along its tangent, mapped into material length on
     * its edge. */
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
        if (c->outside) { /* withdrawn: the needle keeps its solved shape, coupled nowhere */
            couple_from_path(c, 0, 0);
            return 0;
        }
        /* Out through the far side this step: the needle's tip, outside, stays free beyond
         * the exit node. */
        if (st->tip_exit)
            last = n - 2;
        bone_ahead(c, st);
        tip_dihedrals(c, st);
    } else if (!p->through && c->ta[n - 1] >= 0 && c->state[n - 1] != NS_FRICTION_STATIC) {
        double xp[3], t[3], d[3];
        tissue_point(c, n - 1, M->x, xp);
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
    }
    int nb = ns_needle_path_behind(p);
    int m_cap = n + p->count + 2;
    double *buf = malloc((size_t)m_cap * 8 * sizeof *buf);
    uint8_t *cst = malloc((size_t)m_cap);
    if (!buf || !cst) {
        free(buf);
        free(cst);
        return -1;
    }
    double *xn = buf, *s = xn + 3 * (size_t)m_cap, *dold = s + m_cap;
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
        if (rc == 0 && reserve(c, r->cap))
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
        if (rc == 0 && reserve(c, r->cap))
            rc = -1;
        if (rc == 0) {
            /* Split and merge never touch pinned (coupled) nodes: find the first again. */
            int f2 = 0;
            while (f2 < r->nodes && !r->pinned[f2])
                f2++;
            for (int i = 0; i < r->nodes; i++)
                c->state[i] = i >= f2 && i < f2 + ncoup ? cst[i - f2] : NS_FRICTION_STATIC;
            couple_from_path(c, f2, 1);
        }
    }
    free(buf);
    free(cst);
    return rc;
}

/* ---- the step ---- */

/* Local frame at needle node i (§3.3): t the normalized sum of the unit edge directions around
 * it (the last edge's at the tip), n1 and n2 completing it (n1 from the axis least aligned). */
static void local_frame(const NsRod *r, int i, double *R)
{
    double t[3] = {0, 0, 0};
    for (int side = 0; side < 2; side++) {
        int a = side ? i : i - 1, b = a + 1;
        if (a < 0 || b >= r->nodes)
            continue;
        double e[3];
        for (int k = 0; k < 3; k++)
            e[k] = r->x[3 * b + k] - r->x[3 * a + k];
        double l = norm3(e);
        for (int k = 0; k < 3; k++)
            t[k] += e[k] / l;
    }
    double l = norm3(t);
    for (int k = 0; k < 3; k++)
        t[k] /= l;
    int ax = fabs(t[0]) <= fabs(t[1]) && fabs(t[0]) <= fabs(t[2]) ? 0
             : fabs(t[1]) <= fabs(t[2])                           ? 1
                                                                  : 2;
    double n1[3] = {0, 0, 0}, n2[3];
    n1[ax] = 1.0;
    double d = dot3(n1, t);
    for (int k = 0; k < 3; k++)
        n1[k] -= d * t[k];
    l = norm3(n1);
    for (int k = 0; k < 3; k++)
        n1[k] /= l;
    n2[0] = t[1] * n1[2] - t[2] * n1[1];
    n2[1] = t[2] * n1[0] - t[0] * n1[2];
    n2[2] = t[0] * n1[1] - t[1] * n1[0];
    for (int k = 0; k < 3; k++) {
        R[k] = t[k];
        R[3 + k] = n1[k];
        R[6 + k] = n2[k];
    }
}

/* Adds s * (w_a w_b) * B to the tissue blocks of the tissue point's nodes. */
static void add_tissue_point_block(NsBlockMatrix *A, int a, int b, double w, const double *B,
                                   double s)
{
    int nodes[2] = {a, b};
    double ws[2] = {1.0 - w, w};
    for (int i = 0; i < 2; i++)
        for (int j = 0; j < 2; j++) {
            if (ws[i] == 0.0 || ws[j] == 0.0)
                continue;
            double *blk = ns_bsm_get(A, nodes[i], nodes[j]);
            if (blk)
                for (int k = 0; k < 9; k++)
                    blk[k] += s * ws[i] * ws[j] * B[k];
        }
}

/* Our bevel model (NS_BEVEL_FORCE): while the tip cuts (DYNAMIC+ in the last step), a lateral
 * force k_b tan(psi) along the tip frame's m2 on the needle's tip, and its reaction on the
 * tissue at the point a quarter of the last path edge ahead of the tip's node along the tip
 * tangent (barycentric shares of that tet's nodes other than the tip's own). The paper
 * displaces u_new instead (§3.5, Figure 7); docs/remeshing.md compares them. *f: the lateral
 * force [N] (0: none); *et / *er: the caller's external forces copied and added to, to be
 * freed (NULL when there is no force). Returns 0, or -1 (memory). */
static int bevel_force(NsCoupled *c, const double *ext_tissue, const double *ext_rod, double *f_out,
                       double **et, double **er)
{
    NsRod *r = c->rod;
    NsMesh *M = &c->tissue->mesh;
    int n = r->nodes;
    *et = *er = NULL;
    *f_out = 0.0;
    if (!c->params.remesh || c->outside || r->params.tip != NS_TIP_BEVEL ||
        c->params.bevel_model != NS_BEVEL_FORCE || c->ta[n - 1] < 0 || c->path.count < 2 ||
        c->state[n - 1] != NS_FRICTION_DYN_POS)
        return 0;
    int tn = c->path.node[c->path.count - 1], prev = c->path.node[c->path.count - 2];
    if (M->node_tets[tn].count == 0)
        return 0;
    double t[3], m1[3], m2[3], q[3], b[4], d[3];
    ns_rod_tip_frame(r, t, m1, m2);
    for (int i = 0; i < 3; i++)
        d[i] = M->x[3 * tn + i] - M->x[3 * prev + i];
    double h = 0.25 * norm3(d);
    for (int i = 0; i < 3; i++)
        q[i] = M->x[3 * tn + i] + h * t[i];
    int te = ns_mesh_locate_in(M, M->x, q, M->node_tets[tn].items[0], 1e-9, b);
    if (te < 0)
        return 0; /* nothing ahead: the tip is at the surface */
    int reg = M->tet_region[te];
    double kb = reg >= 0 && reg < NS_COUPLING_MAX_REGIONS ? c->params.bevel_force[reg] : 0.0;
    double f = kb * tan(r->params.bevel_angle), wsum = 0.0;
    for (int a = 0; a < 4; a++) {
        if (M->tet_node[4 * te + a] == tn)
            b[a] = 0.0;
        wsum += b[a];
    }
    if (!(f != 0.0) || !(wsum > 0.0))
        return 0;
    size_t nt = 3 * (size_t)M->node_slots, nr = 3 * (size_t)n;
    *et = calloc(nt, sizeof **et);
    *er = calloc(nr, sizeof **er);
    if (!*et || !*er) {
        free(*et);
        free(*er);
        *et = *er = NULL;
        return -1;
    }
    if (ext_tissue)
        memcpy(*et, ext_tissue, nt * sizeof **et);
    if (ext_rod)
        memcpy(*er, ext_rod, nr * sizeof **er);
    for (int i = 0; i < 3; i++) {
        (*er)[3 * (n - 1) + i] += f * m2[i];
        for (int a = 0; a < 4; a++)
            (*et)[3 * M->tet_node[4 * te + a] + i] -= f * m2[i] * b[a] / wsum;
    }
    *f_out = f;
    return 0;
}

/* sum over the rows not fixed of x_i y_i */
static double free_dot(const double *x, const double *y, const uint8_t *fixed, int n)
{
    double s = 0.0;
    for (int i = 0; i < n; i++)
        if (!fixed[i])
            s += x[i] * y[i];
    return s;
}

/* The solve's starting accelerations (both solvers'). Last step's accelerations are a poor guess
 * as they stand: where the tissue is stiff for the step (omega dt >> 1, most of its modes here)
 * Newmark's scheme (gamma >= 1/2) makes the acceleration alternate, a_(n+1) ~ -a_n, and a_n is
 * twice as far from the answer as a zero start (docs/coupling.md, "The starting guess"). Each
 * side's free part d is scaled instead by the alpha that minimizes the error in the norm of its
 * own matrix, alpha = d.(b - A x_held) / d.A d (0 if d.A d is not positive): near -1 in the
 * quasi-static regime, near +1 in a free fall, and never worse than a zero start in that norm.
 * Costs one product with the tissue matrix and two with the needle's band. The constraints are
 * met afterwards by the solver's own feasible start. Returns 0, or -1 (out of memory). */
static int scale_start(CoupledSystem *S)
{
    int n = S->nr3;
    double *w = malloc(((size_t)S->nt3 + 4 * (size_t)n + 1) * sizeof *w);
    if (!w)
        return -1;
    double *Ad = w, *d = w + S->nt3, *h = d + n, *Ah = h + n, *Adn = Ah + n;
    ns_bsm_mul_threads(S->At, S->at, Ad, S->threads);
    double num = free_dot(S->at, S->bt, S->tfixed, S->nt3);
    double den = free_dot(S->at, Ad, S->tfixed, S->nt3);
    double alpha = den > 0.0 && isfinite(num / den) ? num / den : 0.0;
    for (int i = 0; i < S->nt3; i++)
        S->at[i] *= alpha;
    /* The needle: held DOFs keep their prescribed accelerations (x_held), the free ones d. */
    for (int i = 0; i < n; i++) {
        h[i] = S->rfixed[i] ? S->ar[i] : 0.0;
        d[i] = S->rfixed[i] ? 0.0 : S->ar[i];
    }
    ns_banded_mul(S->Ar, h, Ah);
    ns_banded_mul(S->Ar, d, Adn);
    num = 0.0;
    den = 0.0;
    for (int i = 0; i < n; i++)
        if (!S->rfixed[i]) {
            num += d[i] * (S->br[i] - Ah[i]);
            den += d[i] * Adn[i];
        }
    alpha = den > 0.0 && isfinite(num / den) ? num / den : 0.0;
    for (int i = 0; i < n; i++)
        if (!S->rfixed[i])
            S->ar[i] *= alpha;
    free(w);
    return 0;
}

/* A step that fails after the needle's step began: the message, the step's scratch freed, the
 * needle's step undone, the statistics so far reported. Returns -1. */
static int step_failed(NsCoupled *c, const char *msg, int *iw, uint8_t *sw, NsCouplingStats *st,
                       double t0, NsCouplingStats *stats)
{
    snprintf(c->error, sizeof c->error, "%s", msg);
    free(iw);
    free(sw);
    ns_rod_abort_step(c->rod);
    st->total_ms = now_ms() - t0;
    if (stats)
        *stats = *st;
    return -1;
}

static int coupled_step(NsCoupled *c, double dt, const double *ext_tissue, const double *ext_rod,
                        NsCouplingStats *stats);

/* A needle whose tip rests on bone (tip_blocked) does not advance: the commanded insertion is
 * not fed through the sleeve (the needle slips in the holder, as a hand's grip does when the
 * tip meets bone), so the needle is not driven into it step after step. A withdrawal
 * (v_insert < 0) takes it off the bone. */
int ns_coupled_step(NsCoupled *c, double dt, const double *ext_tissue, const double *ext_rod,
                    NsCouplingStats *stats)
{
    NsRod *r = c->rod;
    double v = r->v_insert;
    if (v < 0.0 && c->tip_blocked) {
        c->tip_blocked = 0;
        unpin_tip(c);
    }
    int stall = c->tip_blocked && v > 0.0;
    if (stall)
        r->v_insert = 0.0;
    int rc = coupled_step(c, dt, ext_tissue, ext_rod, stats);
    r->v_insert = v;
    if (stats)
        stats->stalled = stall;
    return rc;
}

static int coupled_step(NsCoupled *c, double dt, const double *ext_tissue, const double *ext_rod,
                        NsCouplingStats *stats)
{
    NsCouplingStats st;
    memset(&st, 0, sizeof st);
    double t0 = now_ms();
    NsTissue *T = c->tissue;
    NsRod *r = c->rod;
    NsMesh *M = &T->mesh;
    double beta = T->params.beta, gamma = T->params.gamma;
    NsRodStats rs;
    memset(&rs, 0, sizeof rs);
    NsRodSystem sys;
    double *bev_t, *bev_r;
    c->error[0] = '\0';
    if (bevel_force(c, ext_tissue, ext_rod, &st.bevel_force, &bev_t, &bev_r)) {
        snprintf(c->error, sizeof c->error, "the bevel force could not be applied");
        if (stats)
            *stats = st;
        return -1;
    }
    double tn = now_ms();
    if (ns_rod_begin_step(r, dt, bev_r ? bev_r : ext_rod, &sys, &rs)) {
        snprintf(c->error, sizeof c->error, "the needle's forces or Jacobians failed (NaN %d)",
                 rs.nan_count);
        free(bev_t);
        free(bev_r);
        st.nan_count = rs.nan_count;
        if (stats)
            *stats = st;
        return -1;
    }
    st.needle_ms = now_ms() - tn;
    double tt = now_ms();
    NsTissueStats ts;
    memset(&ts, 0, sizeof ts);
    double *bt = ns_tissue_begin_step(T, dt, bev_t ? bev_t : ext_tissue, &ts);
    free(bev_t);
    free(bev_r);
    if (!bt)
        return step_failed(c, "out of memory assembling the tissue matrix", NULL, NULL, &st, t0,
                           stats);
    st.tissue_ms = now_ms() - tt;
    double tl = now_ms();

    /* The coupled system of this step. */
    CoupledSystem S;
    memset(&S, 0, sizeof S);
    S.c = c;
    S.nt3 = 3 * M->node_slots;
    S.nr3 = sys.n3;
    S.bdt2 = beta * dt * dt;
    S.At = &T->A;
    S.tfixed = T->dof_fixed;
    S.bt = bt;
    S.Ar = sys.A;
    S.rfixed = sys.dof_fixed;
    S.br = sys.rhs;
    S.ar = sys.anew;
    S.at = bt + S.nt3; /* t->work's second vector */
    S.threads = c->params.threads;
    S.tip = -1;
    int q = 0;
    for (int i = 0; i < r->nodes; i++)
        q += c->ta[i] >= 0;
    S.q = q;
    size_t need = (size_t)q * 24 + 16;
    double *w = scratch(c, need);
    int *iw = malloc((size_t)(3 * q + 1) * sizeof *iw);
    uint8_t *sw = malloc((size_t)q + 1);
    if (!w || !iw || !sw)
        return step_failed(c, "out of memory", iw, sw, &st, t0, stats);
    S.tw = w;
    S.R = S.tw + q;
    S.f = S.R + 9 * q;
    S.e = S.f + q;
    S.yrel = S.e + 3 * q;
    S.cf = S.yrel + 3 * q;
    S.idx = iw;
    S.ta = iw + q;
    S.tb = iw + 2 * q;
    S.st = sw;
    const double *rl = r->rest_len;
    for (int i = 0, k = 0; i < r->nodes; i++) {
        if (c->ta[i] < 0)
            continue;
        S.idx[k] = i;
        S.ta[k] = c->ta[i];
        S.tb[k] = c->tb[i];
        S.tw[k] = c->tw[i];
        S.st[k] = c->state[i];
        local_frame(r, i, S.R + 9 * k);
        /* f_i = f_perlen (l_{i-1} + l_i) / 2 over the halves of edges inside the tissue. */
        double len = 0.0;
        if (i > 0 && c->ta[i - 1] >= 0)
            len += 0.5 * rl[i - 1];
        if (i + 1 < r->nodes && c->ta[i + 1] >= 0)
            len += 0.5 * rl[i];
        S.f[k] = c->params.f_perlen * len;
        if (i == r->nodes - 1 && !c->path.through) {
            S.tip = k;
            S.f_cut =
                ns_needle_path_cut_force(&c->path, M, c->params.cut_force, NS_COUPLING_MAX_REGIONS);
        }
        /* Known part of the step's displacement, tissue minus needle (Eq. 1 without a'). */
        double yh[3], vh[3], ah[3];
        coupled_point(&S, k, M->v, vh);
        coupled_point(&S, k, M->a, ah);
        for (int d = 0; d < 3; d++) {
            yh[d] = dt * vh[d] + dt * dt * (0.5 - beta) * ah[d];
            double yn = dt * r->v[3 * i + d] + dt * dt * (0.5 - beta) * r->a[3 * i + d];
            S.yrel[3 * k + d] = yh[d] - yn;
        }
        /* Eq. 8 in the local axes: R^T (dx_tissue - dx_needle) = 0, i.e. beta dt^2 R^T (a_t -
         * a_n) = -R^T yrel. */
        for (int col = 0; col < 3; col++)
            S.e[3 * k + col] = -dot3(S.R + 9 * k + 3 * col, S.yrel + 3 * k) / S.bdt2;
        /* Viscous friction along t (§3.3), implicit in each side's own velocity: the force on
         * the needle eta_i l (t.(v_t - v_n)) t; A gains gamma dt eta_i l t t^T on both sides. */
        if (c->params.eta > 0.0) {
            double eta = c->params.eta * len, B[9], vrel[3];
            const double *t = S.R + 9 * k;
            for (int a = 0; a < 3; a++)
                for (int b = 0; b < 3; b++)
                    B[3 * a + b] = eta * t[a] * t[b];
            for (int d = 0; d < 3; d++)
                vrel[d] = vh[d] - r->v[3 * i + d];
            double fv = dot3(t, vrel) * eta, an_t = dot3(t, r->a + 3 * i), ah_t = dot3(t, ah);
            for (int d = 0; d < 3; d++) {
                sys.rhs[3 * i + d] += t[d] * (fv - eta * dt * (1.0 - gamma) * an_t);
                double ft = -t[d] * (fv + eta * dt * (1.0 - gamma) * ah_t);
                S.bt[3 * S.ta[k] + d] += (1.0 - S.tw[k]) * ft;
                S.bt[3 * S.tb[k] + d] += S.tw[k] * ft;
            }
            double *nb = ns_banded_block((NsBanded *)sys.A, i, i);
            for (int d = 0; d < 9; d++)
                nb[d] += gamma * dt * B[d];
            add_tissue_point_block(&T->A, S.ta[k], S.tb[k], S.tw[k], B, gamma * dt);
            ns_tissue_a_row_touched(T, S.ta[k]);
            ns_tissue_a_row_touched(T, S.tb[k]);
        }
        k++;
    }
    for (int i = 0; i < S.nt3; i++)
        S.at[i] = T->dof_fixed[i] ? 0.0 : M->a[i];
    if (scale_start(&S))
        return step_failed(c, "out of memory", iw, sw, &st, t0, stats);
    for (int k = 0; k < q; k++)
        for (int d = 0; d < 3; d++)
            S.cf[3 * k + d] = d == 0 ? coupled_known_force(&S, k, S.st[k]) : 0.0;

    if (c->params.solver == NS_COUPLED_SCHUR && !c->schur)
        c->schur = coupled_schur_create(); /* the solver was switched after init */
    int rc = -1;
    if (c->params.solver == NS_COUPLED_PAPER)
        rc = coupled_paper_lcp(&S, &st);
    else if (c->schur)
        rc = coupled_schur_lcp(c->schur, &S, &st);
    int finite = rc == 0;
    for (int i = 0; i < S.nt3 && finite; i++)
        finite = isfinite(S.at[i]);
    for (int i = 0; i < S.nr3 && finite; i++)
        finite = isfinite(S.ar[i]);
    st.lcp_ms = now_ms() - tl;
    if (!finite) {
        st.nan_count += rc == 0;
        return step_failed(c,
                           rc == 0
                               ? "the coupled solve gave non-finite accelerations"
                               : "the coupled solve failed (its linear solves did not complete)",
                           iw, sw, &st, t0, stats);
    }
    st.coupled = q;
    for (int k = 0; k < q; k++) {
        c->state[S.idx[k]] = S.st[k];
        st.n_static += S.st[k] == NS_FRICTION_STATIC;
        st.n_dyn_pos += S.st[k] == NS_FRICTION_DYN_POS;
        st.n_dyn_neg += S.st[k] == NS_FRICTION_DYN_NEG;
        st.axial_force += S.cf[3 * k]; /* the tangential force on the needle */
    }
    ns_tissue_end_step(T, dt, S.at);
    ns_rod_end_step(r, dt, S.ar, &rs);
    free(iw);
    free(sw);
    double tr = now_ms();
    if (reparameterize(c, &st)) {
        if (!c->error[0])
            snprintf(c->error, sizeof c->error, "the needle's reparameterization failed");
        st.total_ms = now_ms() - t0;
        if (stats)
            *stats = st;
        return -1;
    }
    st.remesh_ms = now_ms() - tr;
    /* Inverted tets are counted at the next force evaluation; report the last one's. */
    st.inverted = ts.inverted;
    c->steps++;
    st.total_ms = now_ms() - t0;
    if (stats)
        *stats = st;
    return 0;
}

int ns_coupled_check_structure(const NsCoupled *c, char *err, int err_sz)
{
    const NsMesh *M = &c->tissue->mesh;
    const NsRod *r = c->rod;
    if (ns_mesh_validate(M, err, err_sz))
        return -1;
    int prev = -1;
    for (int i = 0; i < r->nodes; i++) {
        if (c->ta[i] < 0)
            continue;
        /* A coupled needle node sits at a tissue node (the tip on a pre-laid path may sit on an
         * edge: its weights then say where). */
        int node = c->tw[i] == 0.0 ? c->ta[i] : c->tw[i] == 1.0 ? c->tb[i] : -1;
        if (node < 0 && !(i == r->nodes - 1 && !c->params.remesh)) {
            snprintf(err, (size_t)err_sz, "needle node %d is not at a tissue node", i);
            return -1;
        }
        if (node >= 0 && !ns_mesh_node_alive(M, node)) {
            snprintf(err, (size_t)err_sz, "needle node %d is coupled to dead tissue node %d", i,
                     node);
            return -1;
        }
        if (node >= 0 && prev >= 0) {
            int joined = node == prev;
            const NsIntList *l = &M->node_tets[node];
            for (int j = 0; j < l->count && !joined; j++)
                for (int k = 0; k < 4; k++)
                    joined |= M->tet_node[4 * l->items[j] + k] == prev;
            if (!joined) {
                snprintf(err, (size_t)err_sz,
                         "needle nodes %d and %d sit at tissue nodes %d and %d, which share no "
                         "tissue edge",
                         i - 1, i, prev, node);
                return -1;
            }
        }
        prev = node;
    }
    NsQualityStats q;
    ns_mesh_quality(M, false, &q);
    if (q.inverted > 0) {
        snprintf(err, (size_t)err_sz, "%d tets inverted in material space (tet %d)", q.inverted,
                 q.worst_tet);
        return -1;
    }
    return 0;
}

uint64_t ns_coupled_state_hash(const NsCoupled *c)
{
    uint64_t h =
        ns_tissue_state_hash(c->tissue) ^ (ns_rod_state_hash(c->rod) * 0x9E3779B97F4A7C15ull);
    for (int i = 0; i < c->rod->nodes; i++) {
        h ^= c->state[i];
        h *= 0x100000001b3ull;
    }
    if (c->params.bevel_model == NS_BEVEL_ARC && c->heading_valid) { /* the cut's heading */
        uint64_t b[3];
        memcpy(b, c->heading, sizeof b);
        for (int i = 0; i < 3; i++) {
            h ^= b[i];
            h *= 0x100000001b3ull;
        }
    }
    return h;
}
