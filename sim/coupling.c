/* Needle-tissue coupling (sim/coupling.h): parameters, the coupling of the needle's nodes to
 * tissue points along the path, set-up and checks. The step is sim/step.c; its stages are
 * coupled_assemble.c (Eq. 7-8), friction.c (Eq. 9-11), coupled_schur.c and coupled_paper.c
 * (Algorithm 3), coupling_tip.c (Algorithm 2 at the tip, §3.5) and coupling_reparam.c
 * (§3.4.2). */
#include "coupling.h"
#include "coupling_internal.h"
#include "mutate.h"
#include "quality.h"
#include "snapshot.h"

#include <assert.h>
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

NsCouplingParams ns_default_coupling_params(void)
{
    NsCouplingParams p;
    memset(&p, 0, sizeof p);
    p.f_perlen = 10.0; /* N/m: needle-tissue friction of soft tissue, order of Crouch 2005 */
    p.eta = 0.0;
    p.twist_friction = 1;
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
    p.tip_load_radius = 15e-3; /* m: docs/needle.md, "The bevel force's reaction" */
    for (int k = 0; k < NS_COUPLING_MAX_REGIONS; k++) {
        p.bevel_force[k] = 0.5;      /* N: docs/remeshing.md (bevel steering) */
        p.bevel_curvature[k] = 10.0; /* 1/m: docs/remeshing.md (bevel steering) */
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

int coupled_reserve(NsCoupled *c, int cap)
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

/* Sets the coupling of the rod's nodes from the path: nodes first .. first+behind-1 at path
 * nodes, then the tip on its edge (unless through); others FREE. Keeps states of nodes that stay
 * coupled when keep_state, else STATIC. */
void coupled_from_path(NsCoupled *c, int first, int keep_state)
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

void coupled_tissue_point(const NsCoupled *c, int i, const double *v, double *out)
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
    c->params.f_perlen = NS_MUTATE("friction", c->params.f_perlen);
    for (int k = 0; k < NS_COUPLING_MAX_REGIONS; k++) {
        c->params.bevel_force[k] = NS_MUTATE("bevel_force", c->params.bevel_force[k]);
        c->params.bevel_curvature[k] = NS_MUTATE("bevel_arc", c->params.bevel_curvature[k]);
    }
    const NsCouplingParams *q = &c->params;
    int bad_bevel = q->bevel_model != NS_BEVEL_FORCE && q->bevel_model != NS_BEVEL_DISPLACEMENT &&
                    q->bevel_model != NS_BEVEL_ARC;
    for (int k = 0; k < NS_COUPLING_MAX_REGIONS; k++)
        bad_bevel |= !(q->bevel_force[k] >= 0.0 && isfinite(q->bevel_force[k])) ||
                     !(q->bevel_curvature[k] >= 0.0 && isfinite(q->bevel_curvature[k]));
    if (!(q->f_perlen >= 0.0) || !(q->eta >= 0.0) || !(q->tau_sol > 0.0) ||
        !(q->tau_check >= q->tau_sol) || q->max_trials < 1 || q->max_iter < 1 ||
        q->refresh_iterations < 0 || bad_bevel || (q->twist_friction & ~1) ||
        !(q->tip_load_radius > 0.0 && isfinite(q->tip_load_radius)) ||
        !(q->remesh_dihedral_floor >= 0.0 && q->remesh_dihedral_floor <= 60.0) ||
        (q->solver != NS_COUPLED_PAPER && q->solver != NS_COUPLED_SCHUR)) {
        snprintf(err, (size_t)err_sz,
                 "coupling: f_perlen and eta must be >= 0, 0 < tau_sol <= tau_check, "
                 "max_trials and max_iter >= 1, refresh_iterations >= 0, solver schur or paper, "
                 "twist_friction 0 or 1, "
                 "remesh_dihedral_floor in [0, 60] deg, tip_load_radius > 0, "
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
    if (coupled_reserve(c, rod->cap)) {
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
    coupled_from_path(c, first, 0);
    for (int i = 0; i < rod->nodes; i++) {
        if (c->ta[i] < 0)
            continue;
        double xp[3], d[3];
        coupled_tissue_point(c, i, M->x, xp);
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
    ns_arena_free(&c->arena);
    coupled_schur_destroy(c->schur);
    ns_remesh_stack_free(&c->remesh);
    memset(c, 0, sizeof *c);
}

/* The arena: its size only (a reader starts an empty arena grown to it, so that the next step
 * allocates no more than the original's would); its blocks are a step's scratch, none live
 * between steps. */
static void arena_pack(NsPack *p, NsArena *a)
{
    size_t cap = a->cap;
    if (p->writing) {
        assert(ns_arena_mark(a) == 0);
        if (ns_arena_mark(a) != 0)
            ns_pack_fail(p, "coupling: a snapshot taken inside a step (%d scratch blocks live)",
                         ns_arena_mark(a));
    } else {
        ns_arena_init(a);
    }
    NS_PACK(p, cap);
    if (p->writing || p->failed)
        return;
    if (cap % NS_ARENA_ALIGN != 0 || cap > NS_PACK_MAX_BYTES - p->allocated) {
        ns_pack_fail(p, "coupling: a scratch arena of %zu bytes", cap);
        return;
    }
    a->peak = cap;
    ns_arena_grow(a); /* out of memory: the arena still works, from malloc */
    a->peak = 0;
}

static void coupled_blank(void *e)
{
    NsCoupled *h = e;
    h->tissue = NULL;
    h->rod = NULL;
    memset(&h->path, 0, sizeof h->path);
    memset(&h->remesh, 0, sizeof h->remesh);
    memset(&h->arena, 0, sizeof h->arena);
    h->schur = NULL;
    h->ta = h->tb = NULL;
    h->tw = NULL;
    h->state = NULL;
}

/* The coupling's own arrays (cap), the path (path_cap), the remesh stack, our solver's state
 * (coupled_schur_pack) and the arena's size; tissue and rod are borrowed (a reader takes those
 * given, already read). */
int ns_coupled_pack(NsPack *p, NsCoupled *c, NsTissue *tissue, NsRod *rod)
{
    ns_pack_struct(p, "CPLD", c, sizeof *c, coupled_blank);
    if (!p->writing) {
        c->tissue = tissue;
        c->rod = rod;
    }
    size_t cap = (size_t)c->cap;
    NS_PACK_ARRAY(p, c->ta, cap, cap);
    NS_PACK_ARRAY(p, c->tb, cap, cap);
    NS_PACK_ARRAY(p, c->tw, cap, cap);
    NS_PACK_ARRAY(p, c->state, cap, cap);
    ns_needle_path_pack_cap(p, &c->path, c->path_cap);
    ns_remesh_stack_pack(p, &c->remesh);
    coupled_schur_pack(p, &c->schur);
    arena_pack(p, &c->arena);
    return p->failed ? -1 : 0;
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
