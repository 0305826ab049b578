/* Validation cases for the needle-tissue coupling (sim/coupling.c; docs/validation.md): stick
 * and slip against the friction law, the friction-state sequence at a reversal, capsule
 * (the paper's solver; the puncture, reversal and solver-agreement cases are still to come).
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
} SceneDef;

typedef struct Scene {
    NsMesh mesh;
    NsTissue tissue;
    NsRod rod;
    NsCoupled cpl;
    int init; /* bit 1 tissue, 2 rod, 4 coupling */
} Scene;

static SceneDef default_scene(void)
{
    SceneDef d = {0.024, 0.012, 12, 6, 0.0, 0.0, 2, 6, -1, 4, 20.0, {0.0, 0.0}};
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
    int rc = ns_rod_init(&s->rod, x, n, d1, d->held, &rp, err, sizeof err);
    free(x);
    if (rc) {
        free(path);
        return fail(r, err);
    }
    s->init |= 2;
    NsNeedlePath np_;
    double tip_s = d->tip_node < 0 ? 2.0 * d->len : tip * h;
    rc = ns_needle_path_init(&np_, M, path, np, tip_s, err, sizeof err);
    free(path);
    if (rc)
        return fail(r, err);
    NsCouplingParams cp = ns_default_coupling_params();
    cp.f_perlen = d->f_perlen;
    cp.cut_force[0] = d->cut[0];
    cp.cut_force[1] = d->cut[1];
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

const NsValidateCase ns_validate_coupling_cases[] = {
    {"friction-stick", "needle pulled below the static friction: no slide", friction_stick},
    {"friction-slip", "needle pulled out: resistance equals f_perlen L_in", friction_slip},
};
const int ns_validate_coupling_case_count =
    (int)(sizeof ns_validate_coupling_cases / sizeof ns_validate_coupling_cases[0]);
