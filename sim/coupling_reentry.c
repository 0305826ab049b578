/* Re-entry of a withdrawn needle (sim/coupling_internal.h, coupled_reenter): a needle drawn
 * all the way out (coupling_tip.c, tip_target: every split undone, the original mesh back,
 * nothing coupled) that is pushed into the tissue again makes a fresh skin entry (§3.4.1,
 * sim/remesh_entry.c) where it crosses the surface, through its old hole or anywhere else: the
 * entry node on the surface, the tip node a short edge inside, the path those two, friction
 * states STATIC as at the first entry. Algorithm 2 then carries the tip node to the needle's
 * tip in the same step (coupled_cut_tip) and the needle is rebuilt on its new tissue nodes
 * (coupled_reparameterize, from the first needle node inside). */
#include "coupling_internal.h"
#include "quality.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The skin entry's tip node goes this fraction of the tissue's mean edge inside the surface
 * (the first entry's, engine/run.c), or half the way to the needle's tip if that is shorter. */
#define REENTRY_DEPTH 0.1
/* A tip less than this fraction of the mean edge inside is left for the next step (a skin
 * entry that shallow makes flat tets that invert under the needle's first push). */
#define REENTRY_MIN 0.02

static double dist3(const double *a, const double *b)
{
    double d[3] = {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
    return sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
}

/* The material point of the world point x in tet t of the deformed tissue (barycentric b). */
static void material_of(const NsMesh *M, int t, const double b[4], double u[3])
{
    for (int i = 0; i < 3; i++) {
        u[i] = 0.0;
        for (int k = 0; k < 4; k++)
            u[i] += b[k] * M->u[3 * M->tet_node[4 * t + k] + i];
    }
}

int coupled_reenter(NsCoupled *c, NsCouplingStats *st)
{
    NsRod *r = c->rod;
    NsTissue *T = c->tissue;
    NsMesh *M = &T->mesh;
    NsNeedlePath *p = &c->path;
    int n = r->nodes;
    double b[4];
    int t = ns_mesh_locate_in(M, M->x, r->x + 3 * (n - 1), c->remesh_hint, 1e-9, b);
    if (t < 0)
        return 0; /* still outside */
    /* The needle's first node inside, behind the tip: its nodes from there on are in the
     * tissue; the one before it is outside. */
    int first = n - 1;
    while (first > 0 && ns_mesh_locate_in(M, M->x, r->x + 3 * (first - 1), t, 1e-9, NULL) >= 0)
        first--;
    if (first < r->held) {
        snprintf(c->error, sizeof c->error,
                 "re-entry: the needle is inside the tissue up to its holder (it re-entered "
                 "more than its free length in one step): take smaller steps");
        return -1;
    }
    /* Where it crossed the surface: the last point inside from the first inside node back
     * towards the node before it, in material space. */
    double a[3], ut[3];
    if (coupled_world_exit_point(M, r->x + 3 * first, r->x + 3 * (first - 1), t, a) < 0)
        return 0;
    material_of(M, t, b, ut);
    double d[3], len = dist3(ut, a), h = ns_mesh_mean_edge(M);
    /* A needle still drawn out (or held) whose tip is no deeper than it was as the needle left
     * (it leaves a little way inside, coupling_tip.c, EXIT_MARGIN) is not pushed in: that is the
     * withdrawal's tail. Pushed in (v_insert > 0), or deeper, it enters afresh. */
    if (!(len > REENTRY_MIN * h) || (!(r->v_insert > 0.0) && !(len > c->exit_depth)))
        return 0;
    for (int i = 0; i < 3; i++)
        d[i] = (ut[i] - a[i]) / len;
    double depth = fmin(REENTRY_DEPTH * h, 0.5 * len);
    int nodes[2];
    char err[200];
    if (ns_remesh_skin_entry(M, &c->remesh, a, d, depth, nodes, err, sizeof err)) {
        snprintf(c->error, sizeof c->error, "re-entry at (%.4g, %.4g, %.4g) m: %s", a[0], a[1],
                 a[2], err);
        return -1;
    }
    char err2[200];
    if (ns_tissue_sync_topology(T, err2, sizeof err2)) {
        snprintf(c->error, sizeof c->error, "re-entry: %s", err2);
        return -1;
    }
    if (c->path_cap < 2) {
        int *nd = realloc(p->node, 2 * sizeof *nd);
        if (nd)
            p->node = nd;
        double *sv = realloc(p->s, 2 * sizeof *sv);
        if (sv)
            p->s = sv;
        if (!nd || !sv)
            return -1;
        c->path_cap = 2;
    }
    /* A fresh path, the two new nodes; nothing carried over from the last insertion. */
    p->node[0] = nodes[0];
    p->node[1] = nodes[1];
    p->count = 2;
    p->s[0] = 0.0;
    p->s[1] = dist3(M->u + 3 * nodes[0], M->u + 3 * nodes[1]);
    p->tip_s = p->s[1];
    p->through = 0;
    c->outside = 0;
    c->heading_valid = 0;
    c->remesh_hint = -1;
    coupled_unpin_tip(c);
    c->tip_blocked = 0;
    for (int i = 0; i < n; i++)
        c->state[i] = NS_FRICTION_STATIC;
    /* The tip cuts in: Algorithm 2 moves the tip node to it (coupled_cut_tip). */
    c->state[n - 1] = NS_FRICTION_DYN_POS;
    st->reentered = 1;
    st->reentry_first = first;
    return 1;
}
