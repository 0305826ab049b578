/* Validation cases for the needle-tissue coupling (sim/coupling.c; docs/validation.md): stick
 * and slip against the friction law, the friction-state sequence at a reversal, capsule
 * puncture, and our solver against the paper's on the same insertion.
 *
 * The scenes: a gel block (corotational, E 30 kPa, nu 0.45) on a structured grid whose centre
 * line along x is a chain of tissue edges, the needle's path (sim/needle_path.h); the block's
 * four side faces are clamped; the default 18 G steel needle lies on the centre line, in from
 * the entry face at x = 0. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "coupling.h"
#include "mesh_grid.h"
#include "validate.h"

static int fail(NsValidateResult *r, const char *why)
{
    ns_validate_detail(r, "%s", why);
    r->pass = false;
    return -1;
}

typedef struct SceneDef {
    double len, width; /* block [m] */
    int nx, nyz;       /* cells along the path and across (even) */
    double mem0, mem1; /* membrane region (region 1) between these x [m]; mem1 <= mem0: none */
    int held;          /* 2: held by a sleeve; 0: a free needle */
    int out_edges;     /* needle edges before the entry face */
    int tip_node;      /* path node at the tip; -1: through the block */
    int beyond_edges;  /* needle edges past the exit face when through */
    double f_perlen, cut[2];
    NsCoupledSolverKind solver;
    double eta;   /* viscous friction per length [N s/m^2] */
    double gamma; /* Newmark gamma of tissue and needle; beta = (gamma + 1/2)^2 / 4 */
    int remesh;   /* remesh at the tip (the path then ends at the tip node) */
    int flexible; /* 1: the solid nitinol needle of 0.83 mm (Webster et al. 2006) */
} SceneDef;

typedef struct Scene {
    NsMesh mesh;
    NsTissue tissue;
    NsRod rod;
    NsCoupled cpl;
    int init; /* bit 1 tissue, 2 rod, 4 coupling */
} Scene;

/* Newmark gamma 0.55, not the paper's trapezoid (0.5): with the trapezoid, a velocity jump forced
 * through the constraints (the sleeve reversing) leaves a velocity that alternates about the
 * true one every step and never decays, and the friction states chatter with it: in
 * friction-reversal the majority state went +S-S-S-S-S-S-S- at 2 ms and +S+S- at 1 ms
 * (ten-trial failures), against +S- at every step size with 0.55 (docs/coupling.md). */
static SceneDef default_scene(void)
{
    SceneDef d = {0.024, 0.012, 12, 6, 0.0, 0.0, 2, 6, -1, 4, 20.0, {0.0, 0.0}, NS_COUPLED_SCHUR,
                  0.0,   0.55,  0,  0};
    return d;
}

static void scene_free(Scene *s)
{
    if (s->init & 4)
        ns_coupled_free(&s->cpl);
    if (s->init & 2)
        ns_rod_free(&s->rod);
    if (s->init & 1)
        ns_tissue_free(&s->tissue);
    ns_mesh_free(&s->mesh);
    s->init = 0;
}

static int scene_make(Scene *s, const SceneDef *d, NsValidateResult *r)
{
    memset(s, 0, sizeof *s);
    char err[256];
    double lo[3] = {0.0, -0.5 * d->width, -0.5 * d->width},
           hi[3] = {d->len, 0.5 * d->width, 0.5 * d->width};
    if (ns_mesh_grid_box(&s->mesh, lo, hi, d->nx, d->nyz, d->nyz, 0, err, sizeof err))
        return fail(r, err);
    NsMesh *m = &s->mesh;
    int regions = 1;
    for (int e = 0; e < m->tet_slots && d->mem1 > d->mem0; e++) {
        if (!ns_mesh_tet_alive(m, e))
            continue;
        double cx = 0.0;
        for (int k = 0; k < 4; k++)
            cx += 0.25 * m->u[3 * m->tet_node[4 * e + k]];
        if (cx > d->mem0 && cx < d->mem1) {
            m->tet_region[e] = 1;
            regions = 2;
        }
    }
    NsTissueMaterial mats[2] = {
        {ns_fem_material(NS_MODEL_COROTATIONAL, 30e3, 0.45, 3.0, 3.0), 1000.0},
        {ns_fem_material(NS_MODEL_COROTATIONAL, 60e3, 0.45, 3.0, 3.0), 1000.0},
    };
    NsTissueParams tp = ns_default_tissue_params();
    tp.gamma = d->gamma;
    tp.beta = 0.25 * (d->gamma + 0.5) * (d->gamma + 0.5);
    if (ns_tissue_init(&s->tissue, m, mats, regions, &tp, err, sizeof err))
        return fail(r, err);
    s->init |= 1;
    NsMesh *M = &s->tissue.mesh;
    double eps = 1e-9;
    for (int i = 0; i < M->node_slots; i++) {
        const double *u = M->u + 3 * i;
        if (fabs(fabs(u[1]) - 0.5 * d->width) < eps || fabs(fabs(u[2]) - 0.5 * d->width) < eps)
            for (int c = 0; c < 3; c++)
                ns_tissue_fix_dof(&s->tissue, i, c, 1);
    }
    /* The path: the centre line's grid nodes. */
    int np = d->nx + 1, *path = malloc((size_t)np * sizeof *path);
    int tip = d->tip_node < 0 ? d->nx : d->tip_node;
    int n = d->out_edges + 1 + tip + 1 + (d->tip_node < 0 ? d->beyond_edges : 0);
    double *x = calloc(3 * (size_t)n, sizeof *x);
    if (!path || !x) {
        free(path);
        free(x);
        return fail(r, "out of memory");
    }
    double h = d->len / d->nx;
    int j = d->nyz / 2;
    for (int i = 0; i < np; i++)
        path[i] = i + (d->nx + 1) * (j + (d->nyz + 1) * j);
    for (int i = 0; i < n; i++)
        x[3 * i] = (i - d->out_edges - 1) * h;
    double d1[3] = {0.0, 1.0, 0.0};
    NsRodParams rp = ns_default_rod_params();
    rp.gamma = tp.gamma;
    rp.beta = tp.beta;
    if (d->flexible) {
        rp.material.youngs = 50e9;
        rp.material.outer_diameter = 0.83e-3;
        rp.material.inner_diameter = 0.0;
        rp.material.density = 6450.0;
    }
    int rc = ns_rod_init(&s->rod, x, n, d1, d->held, &rp, err, sizeof err);
    free(x);
    if (rc) {
        free(path);
        return fail(r, err);
    }
    s->init |= 2;
    NsNeedlePath np_;
    double tip_s = d->tip_node < 0 ? 2.0 * d->len : tip * h;
    rc = ns_needle_path_init(&np_, M, path, d->remesh ? tip + 1 : np, tip_s, err, sizeof err);
    free(path);
    if (rc)
        return fail(r, err);
    NsCouplingParams cp = ns_default_coupling_params();
    cp.f_perlen = d->f_perlen;
    cp.cut_force[0] = d->cut[0];
    cp.cut_force[1] = d->cut[1];
    cp.solver = d->solver;
    cp.eta = d->eta;
    cp.remesh = d->remesh;
    if (ns_coupled_init(&s->cpl, &s->tissue, &s->rod, &np_, &cp, err, sizeof err))
        return fail(r, err);
    s->init |= 4;
    return 0;
}

/* Rest length of the needle from its base to its first coupled node: shrinks by what slid in. */
static double length_outside(const Scene *s)
{
    double l = 0.0;
    for (int i = 0; i + 1 < s->rod.nodes && s->cpl.ta[i] < 0; i++)
        l += s->rod.rest_len[i];
    return l;
}

/* World length of the coupled part of the needle. */
static double length_inside(const Scene *s)
{
    double l = 0.0;
    for (int i = 0; i + 1 < s->rod.nodes; i++)
        if (s->cpl.ta[i] >= 0 && s->cpl.ta[i + 1] >= 0) {
            double e[3];
            for (int k = 0; k < 3; k++)
                e[k] = s->rod.x[3 * (i + 1) + k] - s->rod.x[3 * i + k];
            l += sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]);
        }
    return l;
}

/* A force P along +x (out through the far face) on the free needle's tip, ramped over `ramp`
 * steps and held; returns the relative slide (outside length change) and the worst LCP trials. */
static int pull_free(Scene *s, double P, int steps, int ramp, double dt, double *slide,
                     int *max_trials, int *all_dyn_steps, double *resist, NsValidateResult *r)
{
    double l0 = length_outside(s);
    double *ext = calloc(3 * (size_t)s->rod.cap, sizeof *ext);
    if (!ext)
        return fail(r, "out of memory");
    *max_trials = 0;
    *all_dyn_steps = 0;
    *resist = 0.0;
    for (int k = 0; k < steps; k++) {
        memset(ext, 0, 3 * (size_t)s->rod.cap * sizeof *ext);
        ext[3 * (s->rod.nodes - 1)] = P * (k < ramp ? (k + 1.0) / ramp : 1.0);
        NsCouplingStats st;
        if (ns_coupled_step(&s->cpl, dt, NULL, ext, &st)) {
            free(ext);
            return fail(r, "coupled step failed");
        }
        *max_trials = st.trials > *max_trials ? st.trials : *max_trials;
        if (st.n_dyn_pos == st.coupled) {
            (*all_dyn_steps)++;
            *resist = -st.axial_force;
        }
    }
    free(ext);
    *slide = l0 - length_outside(s);
    return 0;
}

static int friction_stick(NsValidateResult *r)
{
    SceneDef d = default_scene();
    d.held = 0;
    Scene s;
    if (scene_make(&s, &d, r)) {
        scene_free(&s);
        return -1;
    }
    double cap = d.f_perlen * length_inside(&s), P = 0.5 * cap, slide, res;
    int trials, dyn;
    int rc = pull_free(&s, P, 200, 50, 1e-3, &slide, &trials, &dyn, &res, r);
    if (rc == 0) {
        snprintf(r->metric, sizeof r->metric, "relative slide [m]");
        r->value = fabs(slide);
        r->reference = 0.0;
        r->error = fabs(slide);
        r->tolerance = 1e-6;
        r->pass = r->error <= r->tolerance && dyn == 0;
        ns_validate_detail(r,
                           "free needle through a %.0f mm gel block, pulled at the tip with %.3f N "
                           "= 0.5 f_perlen L_in (%.3f N), ramped over 50 ms, 200 steps of 1 ms: "
                           "slide %.2e m, steps all sliding %d, worst LCP trials %d",
                           1e3 * d.len, P, cap, slide, dyn, trials);
    }
    scene_free(&s);
    return rc;
}

static int friction_slip(NsValidateResult *r)
{
    SceneDef d = default_scene();
    Scene s;
    if (scene_make(&s, &d, r)) {
        scene_free(&s);
        return -1;
    }
    /* Pulled out through the sleeve at 10 mm/s: once every node slides, the tissue's resistance
     * is the friction f_perlen L_in. */
    s.rod.v_insert = -0.01;
    int steps = 100, sliding = 0, maxt = 0, rc = 0;
    double resist = 0.0, lin = 0.0;
    for (int k = 0; k < steps && rc == 0; k++) {
        NsCouplingStats st;
        if (ns_coupled_step(&s.cpl, 2e-3, NULL, NULL, &st)) {
            rc = fail(r, "coupled step failed");
            break;
        }
        maxt = st.trials > maxt ? st.trials : maxt;
        if (st.n_dyn_neg == st.coupled) {
            sliding++;
            resist = st.axial_force; /* on the needle, +x: resisting the pull out */
            lin = length_inside(&s);
        }
    }
    if (rc == 0) {
        double ref = d.f_perlen * lin;
        snprintf(r->metric, sizeof r->metric, "sliding resistance [N]");
        r->value = resist;
        r->reference = ref;
        r->error = ref > 0.0 ? fabs(resist - ref) / ref : 1.0;
        r->tolerance = 0.02;
        r->pass = r->error <= r->tolerance && sliding > steps / 2;
        ns_validate_detail(r,
                           "needle pulled out through the sleeve at 10 mm/s, 100 steps of 2 ms: "
                           "%d steps with every coupled node DYNAMIC-, resistance %.4f N against "
                           "f_perlen L_in = %.4f N (L_in %.2f mm), worst trials %d",
                           sliding, resist, ref, 1e3 * lin, maxt);
    }
    scene_free(&s);
    return rc;
}

/* One step's record for the cases below. */
typedef struct StepLog {
    int coupled, n_static, n_pos, n_neg, trials, consistent, cutting;
    double axial, tip[3], l_in;
    double tip_s; /* the tip's material depth along the path [m] */
    int remesh_kind;
    double min_dihedral, max_dihedral;
} StepLog;

/* Steps the scene with the sleeve's insertion speed v[k] at step k, logging each step. */
static int drive(Scene *s, double dt, int steps, const double *v, StepLog *log, NsValidateResult *r)
{
    for (int k = 0; k < steps; k++) {
        s->rod.v_insert = v[k];
        NsCouplingStats st;
        if (ns_coupled_step(&s->cpl, dt, NULL, NULL, &st))
            return fail(r, "coupled step failed");
        StepLog *g = log + k;
        g->coupled = st.coupled;
        g->n_static = st.n_static;
        g->n_pos = st.n_dyn_pos;
        g->n_neg = st.n_dyn_neg;
        g->trials = st.trials;
        g->consistent = st.consistent;
        g->cutting = st.cutting;
        g->axial = st.axial_force;
        memcpy(g->tip, s->rod.x + 3 * (s->rod.nodes - 1), sizeof g->tip);
        g->l_in = length_inside(s);
        g->tip_s = s->cpl.path.tip_s;
        g->remesh_kind = st.remesh_kind;
        g->min_dihedral = st.min_dihedral_deg;
        g->max_dihedral = st.max_dihedral_deg;
        if (getenv("NS_VALIDATE_TRACE"))
            fprintf(stderr,
                    "%4d v %+.4f coupled %2d S %2d + %2d - %2d trials %2d cons %d cut %d "
                    "axial %+.5f tip %.6f s %.6f l_in %.5f remesh %d dihedral %.1f %.1f\n",
                    k, v[k], g->coupled, g->n_static, g->n_pos, g->n_neg, g->trials, g->consistent,
                    g->cutting, g->axial, g->tip[0], g->tip_s, g->l_in, g->remesh_kind,
                    g->min_dihedral, g->max_dihedral);
    }
    return 0;
}

/* The step's friction picture: the state of more than half the coupled nodes ('+' DYNAMIC+,
 * 'S' STATIC, '-' DYNAMIC-), or 'm' (mixed) if none has a majority. */
static char step_class(const StepLog *g)
{
    if (2 * g->n_static > g->coupled)
        return 'S';
    if (2 * g->n_pos > g->coupled)
        return '+';
    if (2 * g->n_neg > g->coupled)
        return '-';
    return 'm';
}

static int friction_reversal(NsValidateResult *r)
{
    SceneDef d = default_scene();
    d.tip_node = 6; /* tip 12 mm deep in the 24 mm block */
    d.cut[0] = 0.05;
    Scene s;
    if (scene_make(&s, &d, r)) {
        scene_free(&s);
        return -1;
    }
    /* In at 10 mm/s for 0.2 s, then out at 10 mm/s for 0.4 s. */
    double dt = 2e-3;
    int PUSH = (int)lround(0.2 / dt), N = PUSH + (int)lround(0.4 / dt);
    double *v = malloc((size_t)N * sizeof *v);
    StepLog *log = malloc((size_t)N * sizeof *log);
    char *seq = malloc((size_t)N + 2);
    if (!v || !log || !seq) {
        free(v);
        free(log);
        free(seq);
        scene_free(&s);
        return fail(r, "out of memory");
    }
    for (int k = 0; k < N; k++)
        v[k] = k < PUSH ? 0.01 : -0.01;
    int rc = drive(&s, dt, N, v, log, r);
    if (rc == 0) {
        /* The sequence of step classes from the reversal on, 'm' dropped and repeats merged;
         * the push's last class before it. */
        int n = 0, maxt = 0, incons = 0, first_s = -1, first_n = -1, all_n = -1;
        seq[n++] = step_class(&log[PUSH - 1]);
        for (int k = PUSH; k < N; k++) {
            char c = step_class(&log[k]);
            maxt = log[k].trials > maxt ? log[k].trials : maxt;
            incons += !log[k].consistent;
            if (c == 'S' && first_s < 0)
                first_s = k - PUSH;
            if (c == '-' && first_n < 0)
                first_n = k - PUSH;
            if (log[k].n_neg == log[k].coupled && all_n < 0)
                all_n = k - PUSH;
            if (c != 'm' && c != seq[n - 1])
                seq[n++] = c;
        }
        seq[n] = 0;
        /* The trial count stays within max_trials (10) by construction; what the bar asks is
         * that Algorithm 3 resolves every step within them: no step left inconsistent. */
        snprintf(r->metric, sizeof r->metric, "steps unresolved in 10 trials");
        r->value = incons;
        r->reference = 0;
        r->error = incons;
        r->tolerance = 0;
        r->pass = strcmp(seq, "+S-") == 0 && incons == 0;
        ns_validate_detail(r,
                           "tip 12 mm deep, pushed in at 10 mm/s for 0.2 s, then pulled at 10 "
                           "mm/s, 2 ms steps: majority state sequence %s (+ DYNAMIC+, S STATIC, "
                           "- DYNAMIC-; want +S-): mostly STATIC %d steps after the reversal, "
                           "mostly DYNAMIC- after %d, all after %d; worst trials %d, "
                           "inconsistent steps %d",
                           seq, first_s, first_n, all_n, maxt, incons);
    }
    free(v);
    free(log);
    free(seq);
    scene_free(&s);
    return rc;
}

/* A 1 mm stiffer membrane (the capsule) across the block at 10-11 mm depth; 1 mm cells along
 * the path; cutting force 0.05 N in the gel and 0.5 N in the membrane; the tip 4 mm deep. */
static SceneDef puncture_scene(void)
{
    SceneDef d = default_scene();
    d.nx = 24;
    d.mem0 = 0.010;
    d.mem1 = 0.011;
    d.tip_node = 4;
    d.cut[0] = 0.05;
    d.cut[1] = 0.5;
    return d;
}

static int puncture(NsValidateResult *r)
{
    SceneDef d = puncture_scene();
    Scene s;
    if (scene_make(&s, &d, r)) {
        scene_free(&s);
        return -1;
    }
    /* In at 10 mm/s for 1.4 s (the tip from 4 mm to past the membrane), steps of 5 ms. */
    double dt = 5e-3;
    enum { N = 280 };
    double v[N];
    for (int k = 0; k < N; k++)
        v[k] = 0.01;
    StepLog *log = malloc(N * sizeof *log);
    if (!log) {
        scene_free(&s);
        return fail(r, "out of memory");
    }
    int rc = drive(&s, dt, N, v, log, r);
    if (rc == 0) {
        int kp = 0;
        for (int k = 0; k < N; k++)
            if (-log[k].axial > -log[kp].axial)
                kp = k;
        double peak = -log[kp].axial, ref = d.cut[1] + d.f_perlen * log[kp].l_in;
        /* After the puncture: the force once the tip is 1 mm past the membrane (material
         * depth: the membrane is pushed ahead of the tip before it is cut). */
        double after = NAN, tip_after = NAN;
        for (int k = kp; k < N && isnan(after); k++)
            if (log[k].tip_s > d.mem1 + 1e-3) {
                after = -log[k].axial;
                tip_after = log[k].tip_s;
            }
        double drop = peak - after, want_drop = 0.5 * (d.cut[1] - d.cut[0]);
        /* Before the membrane: the force when the tip is 1 mm short of it. */
        double before = NAN;
        for (int k = 0; k < kp && isnan(before); k++)
            if (log[k].tip_s > d.mem0 - 1e-3)
                before = -log[k].axial;
        snprintf(r->metric, sizeof r->metric, "peak axial force [N]");
        r->value = peak;
        r->reference = ref;
        r->error = fabs(peak - ref) / ref;
        r->tolerance = 0.05;
        int at_membrane = log[kp].tip_s > d.mem0 - 1e-4 && log[kp].tip_s < d.mem1 + 1e-4;
        double pushed = 0.0; /* how far the membrane was pushed before it was cut */
        for (int k = 0; k < N; k++)
            if (log[k].tip_s < d.mem0 + 1e-4)
                pushed = fmax(pushed, log[k].tip[0] - log[k].tip_s);
        r->pass = r->error <= r->tolerance && at_membrane && drop >= want_drop &&
                  peak - before >= want_drop;
        ns_validate_detail(r,
                           "18 G needle driven at 10 mm/s through gel (f_cut 0.05 N) with a 1 mm "
                           "membrane at 10-11 mm (f_cut 0.5 N), f_perlen 20 N/m, 5 ms steps: peak "
                           "%.4f N with the tip at %.2f mm material depth (f_cut + f_perlen L_in "
                           "= %.4f N), the membrane pushed %.2f mm ahead before it was cut; %.4f "
                           "N 1 mm before the membrane, %.4f N at %.2f mm after it (drop %.4f N, "
                           "at least %.3f N wanted)",
                           peak, 1e3 * log[kp].tip_s, ref, 1e3 * pushed, before, after,
                           1e3 * tip_after, drop, want_drop);
    }
    free(log);
    scene_free(&s);
    return rc;
}

/* The twist of edge j about its tangent from its material frame's m1 at the start (m0, per
 * edge), measured on the directors [rad]. */
static double edge_turn(const NsRod *rod, int j, const double *m0)
{
    double m[3], t[3];
    ns_rod_material_frame(rod, j, t, m, NULL);
    const double *b = m0 + 3 * j;
    double c[3] = {b[1] * m[2] - b[2] * m[1], b[2] * m[0] - b[0] * m[2], b[0] * m[1] - b[1] * m[0]};
    return atan2(c[0] * t[0] + c[1] * t[1] + c[2] * t[2], b[0] * m[0] + b[1] * m[1] + b[2] * m[2]);
}

/* Torsional friction: the base of a needle inserted L into the block turns by 3 dtheta and back.
 * While the whole inserted length slips, the torque a distance u from the tip is tau_f u, so the
 * tip lags the base by dtheta = tau_f L (L / 2 + L_out) / GJ (docs/validation.md), tau_f =
 * f_perlen d_o / 2; at a reversal the tip stays until the base has turned back 2 dtheta. */
static int twist_friction(NsValidateResult *r)
{
    snprintf(r->metric, sizeof r->metric, "steady lag of the tip behind the base [rad]");
    SceneDef d = default_scene();
    d.len = 0.06;
    d.width = 0.016;
    d.nx = 15;
    d.nyz = 4;
    d.out_edges = 5;
    d.tip_node = 15;
    d.f_perlen = 20.0;
    d.flexible = 1;
    Scene s;
    if (scene_make(&s, &d, r)) {
        scene_free(&s);
        return -1;
    }
    NsRod *rod = &s.rod;
    int ne = rod->nodes - 1, tipe = ne - 1;
    /* The closed form, from the scene's own numbers. */
    double h = d.len / d.nx, L = d.len, L_out = d.out_edges * h, dia = 0.83e-3;
    double GJ = 50e9 / (2.0 * (1.0 + 0.3)) * M_PI * dia * dia * dia * dia / 32.0;
    double tau_f = d.f_perlen * 0.5 * dia, lag = tau_f * L * (0.5 * L + L_out) / GJ;
    double *m0 = malloc(3 * (size_t)rod->nodes * sizeof *m0);
    if (!m0) {
        scene_free(&s);
        return fail(r, "out of memory");
    }
    for (int j = 0; j < ne; j++)
        ns_rod_material_frame(rod, j, NULL, m0 + 3 * j, NULL);
    int steps = 300;
    double dt = 1e-3, rate = 3.0 * lag / (steps * dt);
    double start = -1.0, base_max = 0.0, tip_max = 0.0, back = -1.0, still = 0.0;
    double lag_fwd = 0.0, lag_rev = 0.0;
    int rc = 0;
    for (int k = 0; k < 2 * steps && rc == 0; k++) {
        rod->twist_rate = k < steps ? rate : -rate;
        NsCouplingStats st;
        if (ns_coupled_step(&s.cpl, dt, NULL, NULL, &st)) {
            rc = fail(r, "coupled step failed");
            break;
        }
        double base = edge_turn(rod, 0, m0), tip = edge_turn(rod, tipe, m0);
        /* Once the tip moves it follows the base one for one: where it first moved, the base had
         * turned by (its turn then) - (the tip's) before the tip took up. */
        if (k < steps) {
            if (start < 0.0 && tip > 1e-9 * lag)
                start = base - tip;
            if (start < 0.0)
                still = fmax(still, fabs(tip));
            base_max = base;
            tip_max = tip;
            lag_fwd = base - tip;
        } else {
            if (back < 0.0 && tip < tip_max - 1e-9 * lag)
                back = (base_max - base) - (tip_max - tip);
            if (back < 0.0)
                still = fmax(still, fabs(tip - tip_max));
            lag_rev = tip - base;
        }
    }
    free(m0);
    scene_free(&s);
    if (rc)
        return rc;
    r->value = lag_fwd;
    r->reference = lag;
    r->error = fabs(lag_fwd - lag) / lag;
    r->tolerance = 0.01;
    double e_start = fabs(start - lag) / lag, e_back = fabs(back - 2.0 * lag) / (2.0 * lag);
    double e_rev = fabs(lag_rev - lag) / lag;
    ns_validate_detail(r,
                       "nitinol needle (0.83 mm, GJ %.4e N m^2) %.0f mm into a gel block, %.0f mm "
                       "free, f_perlen %.0f N/m, tau_f = f_perlen d_o / 2 = %.3e N m/m; base "
                       "turned %.4f rad in %d steps of 1 ms and back: tip took up after %.6f rad "
                       "(err %.1e), steady lag %.6f against tau_f L (L/2 + L_out) / GJ = %.6f "
                       "rad (%.2f deg); after the reversal it stayed until the base had turned "
                       "back %.6f against 2 dtheta %.6f (err %.1e), then lagged %.6f (err %.1e); "
                       "largest tip turn while stuck %.1e rad (bars 1%%, 1e-6 dtheta)",
                       GJ, 1e3 * L, 1e3 * L_out, d.f_perlen, tau_f, 3.0 * lag, steps, start,
                       e_start, lag_fwd, lag, lag * 180.0 / M_PI, back, 2.0 * lag, e_back, lag_rev,
                       e_rev, still);
    r->pass = r->error <= r->tolerance && start >= 0.0 && back >= 0.0 && e_start <= 0.01 &&
              e_back <= 0.01 && e_rev <= 0.01 && still <= 1e-6 * lag;
    return 0;
}

static int solver_agreement(NsValidateResult *r)
{
    /* The puncture scene, the needle driven in at 10 mm/s for 0.8 s (through the membrane) and
     * back out for 0.4 s, 5 ms steps, once with each solver, in lockstep. */
    SceneDef d = puncture_scene();
    Scene a, b;
    memset(&b, 0, sizeof b);
    d.solver = NS_COUPLED_SCHUR;
    int rc = scene_make(&a, &d, r);
    d.solver = NS_COUPLED_PAPER;
    if (rc == 0)
        rc = scene_make(&b, &d, r);
    enum { PUSH = 160, N = 240 };
    double worst = 0.0, ms[2] = {0.0, 0.0};
    long agree = 0, total = 0;
    int worst_step = -1, trials[2] = {0, 0};
    for (int k = 0; k < N && rc == 0; k++) {
        Scene *sc[2] = {&a, &b};
        for (int j = 0; j < 2 && rc == 0; j++) {
            NsCouplingStats st;
            sc[j]->rod.v_insert = k < PUSH ? 0.01 : -0.01;
            if (ns_coupled_step(&sc[j]->cpl, 5e-3, NULL, NULL, &st))
                rc = fail(r, j ? "coupled step failed (paper)" : "coupled step failed (schur)");
            ms[j] += st.lcp_ms;
            trials[j] = st.trials > trials[j] ? st.trials : trials[j];
        }
        if (rc)
            break;
        const double *ta = a.rod.x + 3 * (a.rod.nodes - 1), *tb = b.rod.x + 3 * (b.rod.nodes - 1);
        double dd = sqrt((ta[0] - tb[0]) * (ta[0] - tb[0]) + (ta[1] - tb[1]) * (ta[1] - tb[1]) +
                         (ta[2] - tb[2]) * (ta[2] - tb[2]));
        if (dd > worst) {
            worst = dd;
            worst_step = k;
        }
        /* Friction states node by node (a differing node count: every node of the longer one
         * counts as a disagreement). */
        if (a.rod.nodes == b.rod.nodes) {
            for (int i = 0; i < a.rod.nodes; i++)
                if (a.cpl.ta[i] >= 0 || b.cpl.ta[i] >= 0) {
                    total++;
                    agree += a.cpl.state[i] == b.cpl.state[i];
                }
        } else {
            total += a.rod.nodes > b.rod.nodes ? a.rod.nodes : b.rod.nodes;
        }
    }
    if (rc == 0) {
        double frac = total > 0 ? (double)agree / (double)total : 0.0;
        snprintf(r->metric, sizeof r->metric, "worst tip distance [m]");
        r->value = worst;
        r->reference = 0.0;
        r->error = worst;
        r->tolerance = 5e-5;
        r->pass = worst <= r->tolerance && frac >= 0.99;
        ns_validate_detail(r,
                           "the puncture scene, in at 10 mm/s for 0.8 s and out for 0.4 s, 5 ms "
                           "steps, schur and paper solvers in lockstep: worst tip distance %.2e m "
                           "(step %d), friction states agree on %.2f%% of %ld node-steps (want "
                           ">= 99%%); worst trials %d / %d; LCP time %.0f / %.0f ms",
                           worst, worst_step, 100.0 * frac, total, trials[0], trials[1], ms[0],
                           ms[1]);
    }
    scene_free(&a);
    scene_free(&b);
    return rc;
}

const NsValidateCase ns_validate_coupling_cases[] = {
    {"friction-stick", "needle pulled below the static friction: no slide", friction_stick},
    {"friction-slip", "needle pulled out: resistance equals f_perlen L_in", friction_slip},
    {"friction-reversal", "push then pull: DYNAMIC+ -> STATIC -> DYNAMIC-, trials <= 10",
     friction_reversal},
    {"puncture", "membrane crossed: force peaks at f_cut(membrane) + friction, then drops",
     puncture},
    {"twist-friction", "base of an inserted needle turned and back: lag tau_f L (L/2 + L_out) / GJ",
     twist_friction},
    {"solver-agreement", "schur and paper solvers: tips within 0.05 mm, states >= 99% alike",
     solver_agreement},
};
const int ns_validate_coupling_case_count =
    (int)(sizeof ns_validate_coupling_cases / sizeof ns_validate_coupling_cases[0]);
