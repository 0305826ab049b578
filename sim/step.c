/* One time step (sim/step.h): the outline of Algorithm 1, each stage a named call timed into
 * the step's statistics. */
#include "step.h"
#include "coupling_internal.h"

#include <assert.h>
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

/* The step in progress: its inputs, the systems its stages build, its statistics. */
typedef struct Step {
    NsCoupled *c;
    double dt;
    const NsStepControls *ctl;
    double *bev_t; /* the caller's tissue loads with the bevel's added, or NULL */
    NsCouplingStats st;
    NsRodStats rs;
    NsRodSystem sys;
    NsTissueStats ts;
    double *bt; /* the tissue's right-hand side, then its accelerations (ns_tissue_begin_step) */
    CoupledSystem S;
    int mark;    /* the arena's depth at the step's start (0) */
    int begun;   /* the needle's step began: a failure before the update undoes it */
    int updated; /* the Newmark update is applied */
} Step;

NsStepControls ns_step_controls(double v_insert, const double v_base[3], double twist_rate)
{
    NsStepControls k;
    memset(&k, 0, sizeof k);
    k.v_insert = v_insert;
    k.twist_rate = twist_rate;
    memcpy(k.v_base, v_base, sizeof k.v_base);
    return k;
}

/* The controls go to the needle for this step. A needle whose tip rests on bone (tip_blocked)
 * does not advance: the commanded insertion is not fed through the sleeve (the needle slips in
 * the holder, as a hand's grip does when the tip meets bone), so the needle is not driven into
 * it step after step. A withdrawal (v_insert < 0) takes it off the bone. Returns whether the
 * insertion stalls. */
static int controls_in(NsCoupled *c, const NsStepControls *ctl)
{
    NsRod *r = c->rod;
    if (ctl->v_insert < 0.0 && c->tip_blocked) {
        c->tip_blocked = 0;
        coupled_unpin_tip(c);
    }
    int stall = c->tip_blocked && ctl->v_insert > 0.0;
    r->v_insert = stall ? 0.0 : ctl->v_insert;
    r->twist_rate = ctl->twist_rate;
    memcpy(r->v_base, ctl->v_base, sizeof r->v_base);
    return stall;
}

static int fail(Step *s, const char *msg)
{
    snprintf(s->c->error, sizeof s->c->error, "%s", msg);
    return -1;
}

/* §3.5, ours (NS_BEVEL_FORCE): the bevel's lateral load, a pair of body forces in the tissue
 * about the tip (sim/coupled_tip_load.c), with the caller's loads. */
static int bevel_load(Step *s)
{
    if (coupled_tip_load(s->c, s->ctl->ext_tissue, &s->st.bevel_force, &s->bev_t))
        return fail(s, "the tip's loads could not be applied");
    return 0;
}

/* 1. The needle's forces and Jacobians (§3.2: discrete elastic rod, the controls at its base). */
static int needle_forces(Step *s)
{
    const double *ext = s->ctl->ext_rod;
    coupled_twist_bounds(s->c); /* torsional friction of the edges inside (twist_friction.h) */
    if (ns_rod_begin_step(s->c->rod, s->dt, ext, &s->sys, &s->rs)) {
        char msg[96];
        snprintf(msg, sizeof msg, "the needle's forces or Jacobians failed (NaN %d)",
                 s->rs.nan_count);
        s->st.nan_count = s->rs.nan_count;
        return fail(s, msg);
    }
    s->begun = 1;
    return 0;
}

/* 1. The tissue's forces and Jacobians (§3.2: invertible FEM; lazy Jacobian update, §3.6.3). */
static int tissue_forces(Step *s)
{
    const double *ext = s->bev_t ? s->bev_t : s->ctl->ext_tissue;
    s->bt = ns_tissue_begin_step(s->c->tissue, s->dt, ext, &s->ts);
    ns_arena_pop(&s->c->arena, s->bev_t);
    s->bev_t = NULL;
    return s->bt ? 0 : fail(s, "out of memory assembling the tissue matrix");
}

/* 2. The coupled system (Eq. 7-8, viscous friction §3.3) and the solvers' start. */
static int assemble(Step *s)
{
    NsArena *a = &s->c->arena;
    int q = coupled_count(s->c);
    double *w = ns_arena_push(a, coupled_system_doubles(q) * sizeof *w);
    int *iw = ns_arena_push(a, coupled_system_ints(q) * sizeof *iw);
    uint8_t *sw = ns_arena_push(a, (size_t)q + 1);
    if (!w || !iw || !sw)
        return fail(s, "out of memory");
    coupled_assemble(s->c, s->dt, &s->sys, s->bt, w, iw, sw, &s->S);
    if (coupled_scale_start(&s->S))
        return fail(s, "out of memory");
    coupled_known_forces(&s->S);
    return 0;
}

/* 2. The friction LCP (Algorithm 3, Eq. 9-11), with our solver or the paper's. */
static int friction_lcp(Step *s)
{
    NsCoupled *c = s->c;
    CoupledSystem *S = &s->S;
    if (c->params.solver == NS_COUPLED_SCHUR && !c->schur)
        c->schur = coupled_schur_create(); /* the solver was switched after init */
    int rc = -1;
    if (c->params.solver == NS_COUPLED_PAPER)
        rc = coupled_paper_lcp(S, &s->st);
    else if (c->schur)
        rc = coupled_schur_lcp(c->schur, S, &s->st);
    int finite = rc == 0;
    for (int i = 0; i < S->nt3 && finite; i++)
        finite = isfinite(S->at[i]);
    for (int i = 0; i < S->nr3 && finite; i++)
        finite = isfinite(S->ar[i]);
    if (finite)
        return 0;
    s->st.nan_count += rc == 0;
    if (rc == 0)
        return fail(s, "the coupled solve gave non-finite accelerations");
    snprintf(s->c->error, sizeof s->c->error, "the coupled solve failed (%s)",
             S->why ? S->why : "its linear solves did not complete");
    return -1;
}

/* 3. The accepted friction states, and the Newmark update of both (§3.1). */
static int newmark_update(Step *s)
{
    NsCoupled *c = s->c;
    const CoupledSystem *S = &s->S;
    s->st.coupled = S->q;
    for (int k = 0; k < S->q; k++) {
        c->state[S->idx[k]] = S->st[k];
        s->st.n_static += S->st[k] == NS_FRICTION_STATIC;
        s->st.n_dyn_pos += S->st[k] == NS_FRICTION_DYN_POS;
        s->st.n_dyn_neg += S->st[k] == NS_FRICTION_DYN_NEG;
        s->st.axial_force += S->cf[3 * k]; /* the tangential force on the needle */
    }
    ns_tissue_end_step(c->tissue, s->dt, S->at);
    ns_rod_end_step(c->rod, s->dt, S->ar, &s->rs);
    s->updated = 1;
    return 0;
}

/* 4. The tip's cut: along the pre-laid path, or remeshing when it cuts or retracts
 * (Algorithm 2, §3.4.1; the paper's bevel, §3.5). */
static int cut_tip(Step *s)
{
    return coupled_cut_tip(s->c, &s->st);
}

/* 5. The needle's reparameterization (§3.4.2). */
static int reparameterize(Step *s)
{
    return coupled_reparameterize(s->c, &s->st);
}

static int timed(int (*stage)(Step *), Step *s, double *ms)
{
    double t0 = now_ms();
    int rc = stage(s);
    *ms += now_ms() - t0;
    return rc;
}

/* The step's end: a failure before the update undoes the needle's step; the arena emptied
 * (and grown to this step's peak, so the next step allocates nothing);
 * the controls' insertion speed left on the needle; the statistics reported. */
static int step_end(Step *s, int rc, int stall, double t0, NsCouplingStats *stats)
{
    NsCoupled *c = s->c;
    if (rc && s->begun && !s->updated)
        ns_rod_abort_step(c->rod);
    if (rc && s->updated && !c->error[0])
        snprintf(c->error, sizeof c->error, "the needle's reparameterization failed");
    /* The step's own blocks (the system's arrays, the bevel's loads after a failure) go; every
     * stage popped its own. */
    ns_arena_reset(&c->arena, s->mark);
    assert(ns_arena_mark(&c->arena) == 0);
    ns_arena_grow(&c->arena);
    if (rc == 0) {
        /* Inverted tets are counted at the next force evaluation; report the last one's. */
        s->st.inverted = s->ts.inverted;
        c->steps++;
    }
    c->rod->v_insert = s->ctl->v_insert;
    s->st.stalled = stall;
    s->st.total_ms = now_ms() - t0;
    if (stats)
        *stats = s->st;
    return rc ? -1 : 0;
}

int ns_step(NsCoupled *c, const NsStepControls *ctl, double dt, NsCouplingStats *stats)
{
    double t0 = now_ms();
    Step s;
    memset(&s, 0, sizeof s);
    s.c = c;
    s.ctl = ctl;
    s.dt = dt;
    s.mark = ns_arena_mark(&c->arena);
    c->error[0] = '\0';
    int stall = controls_in(c, ctl);
    int rc = bevel_load(&s);
    /* 1. Forces and Jacobians (§3.2): the needle's, then the tissue's. */
    if (rc == 0)
        rc = timed(needle_forces, &s, &s.st.needle_ms);
    if (rc == 0)
        rc = timed(tissue_forces, &s, &s.st.tissue_ms);
    /* 2. The coupled system (Eq. 7-8) and its friction LCP (Algorithm 3, Eq. 9-11). */
    if (rc == 0)
        rc = timed(assemble, &s, &s.st.lcp_ms);
    if (rc == 0)
        rc = timed(friction_lcp, &s, &s.st.lcp_ms);
    /* 3. Newmark update (§3.1). */
    if (rc == 0)
        rc = newmark_update(&s);
    /* 4. The tip's cut, remeshing the tissue (Algorithm 2, §3.4.1), and 5. the needle's
     * reparameterization (§3.4.2). */
    if (rc == 0)
        rc = timed(cut_tip, &s, &s.st.remesh_ms);
    if (rc == 0)
        rc = timed(reparameterize, &s, &s.st.remesh_ms);
    return step_end(&s, rc, stall, t0, stats);
}

/* The step with the controls the needle holds (v_insert, twist_rate, v_base). */
int ns_coupled_step(NsCoupled *c, double dt, const double *ext_tissue, const double *ext_rod,
                    NsCouplingStats *stats)
{
    const NsRod *r = c->rod;
    NsStepControls ctl = ns_step_controls(r->v_insert, r->v_base, r->twist_rate);
    ctl.ext_tissue = ext_tissue;
    ctl.ext_rod = ext_rod;
    return ns_step(c, &ctl, dt, stats);
}
