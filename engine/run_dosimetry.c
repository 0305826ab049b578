/* A scenario's dosimetry in a run (docs/brachytherapy.md): the TG-43U1 dose of its seeds read as
 * the guidelines' dose-volume figures, once with every seed where the plan puts it and once
 * with every seed where the simulated tissue left it.
 *
 * Both are evaluated in the undeformed anatomy (the mesh as built): a planned seed is a point of
 * it, and a released seed is the material point the tissue carried (ns_run_release_seed), so
 * after the needles are out and the tissue has relaxed its material point is where it lies in
 * the anatomy. The regions' voxels are the centres of a grid at the scenario's spacing that
 * fall in a tet of the region. Each seed lies along the first needle's axis (the template's
 * normal); its turning with the tissue is not followed. */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "dose.h"
#include "dose_table.h"
#include "dvh.h"
#include "err.h"
#include "out_files.h"
#include "remesh.h"
#include "run.h"
#include "scene.h"

enum { PLANNED, DELIVERED };
static const char *const region_key[3] = {"prostate", "urethra", "rectum"};

struct NsRunDose {
    NsTg43Source src;
    double axis[3];
    double *pts;          /* voxel centres in the three regions (n x 3) [m] */
    unsigned char *which; /* (n) 0 prostate, 1 urethra, 2 rectum */
    long n, count[3];
    double *dose[2]; /* (n) planned, delivered [Gy] */
    NsDvh dvh[2][3]; /* [planned|delivered][region] */
    int seeds[2];    /* seed counts */
    double *disp;    /* (disp_n) delivered seed k against planned seed k [m] */
    int disp_n;
    double ms;     /* wall time of all of the above [ms] */
    char *csv_tmp; /* DIR/.dvh.csv.part */
};

/* Labels the voxels (n[0] x n[1] x n[2] of side h from lo, x fastest) that lie in a tet of
 * region q of the three with q, tet by tet over each tet's bounding box of voxels (no point
 * location: a walk from voxel to voxel falls back to a search of every tet for each centre just
 * outside the tissue's warped surface). A centre on a face shared by two tets takes the first
 * tet's region; lab holds -1 elsewhere. */
static void label_voxels(const NsMesh *m, const int region[3], const double lo[3], double h,
                         const int n[3], signed char *lab)
{
    for (int t = 0; t < m->tet_slots; t++) {
        if (!ns_mesh_tet_alive(m, t))
            continue;
        int q = -1;
        for (int k = 0; k < 3; k++)
            if (m->tet_region[t] == region[k])
                q = k;
        if (q < 0)
            continue;
        const int *tn = m->tet_node + 4 * t;
        const double *x0 = m->u + 3 * tn[0];
        double e[3][3], inv[3][3], blo[3] = {INFINITY, INFINITY, INFINITY}, bhi[3];
        for (int c = 0; c < 3; c++)
            bhi[c] = -INFINITY;
        for (int k = 0; k < 4; k++)
            for (int c = 0; c < 3; c++) {
                double v = m->u[3 * tn[k] + c];
                blo[c] = fmin(blo[c], v);
                bhi[c] = fmax(bhi[c], v);
                if (k > 0)
                    e[c][k - 1] = v - x0[c]; /* columns: the edges from node 0 */
            }
        double det = e[0][0] * (e[1][1] * e[2][2] - e[1][2] * e[2][1]) -
                     e[0][1] * (e[1][0] * e[2][2] - e[1][2] * e[2][0]) +
                     e[0][2] * (e[1][0] * e[2][1] - e[1][1] * e[2][0]);
        if (!(fabs(det) > 0.0))
            continue;
        for (int a = 0; a < 3; a++) /* the inverse by cofactors */
            for (int b = 0; b < 3; b++) {
                int a1 = (a + 1) % 3, a2 = (a + 2) % 3, b1 = (b + 1) % 3, b2 = (b + 2) % 3;
                inv[b][a] = (e[a1][b1] * e[a2][b2] - e[a1][b2] * e[a2][b1]) / det;
            }
        int i0[3], i1[3];
        for (int c = 0; c < 3; c++) { /* centres lo + (i + 1/2) h inside [blo, bhi] */
            i0[c] = (int)fmax(0.0, ceil((blo[c] - lo[c]) / h - 0.5));
            i1[c] = (int)fmin(n[c] - 1.0, floor((bhi[c] - lo[c]) / h - 0.5));
        }
        for (int k = i0[2]; k <= i1[2]; k++)
            for (int j = i0[1]; j <= i1[1]; j++)
                for (int i = i0[0]; i <= i1[0]; i++) {
                    long v = ((long)k * n[1] + j) * n[0] + i;
                    if (lab[v] >= 0)
                        continue;
                    double d[3] = {lo[0] + (i + 0.5) * h - x0[0], lo[1] + (j + 0.5) * h - x0[1],
                                   lo[2] + (k + 0.5) * h - x0[2]};
                    double b[3], sum = 0.0;
                    for (int a = 0; a < 3; a++) {
                        b[a] = inv[a][0] * d[0] + inv[a][1] * d[1] + inv[a][2] * d[2];
                        sum += b[a];
                    }
                    if (b[0] >= -1e-12 && b[1] >= -1e-12 && b[2] >= -1e-12 && sum <= 1.0 + 1e-12)
                        lab[v] = (signed char)q;
                }
    }
}

/* The voxel centres of the three regions in the mesh as built. */
static int voxelize(NsRun *r, struct NsRunDose *D, char *err, int err_sz)
{
    const NsMesh *m = &r->orig;
    const NsRunDosimetry *ds = &r->spec.dosimetry;
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int t = 0; t < m->tet_slots; t++) {
        if (!ns_mesh_tet_alive(m, t))
            continue;
        int reg = m->tet_region[t];
        if (reg != ds->region[0] && reg != ds->region[1] && reg != ds->region[2])
            continue;
        for (int k = 0; k < 4; k++)
            for (int c = 0; c < 3; c++) {
                double u = m->u[3 * m->tet_node[4 * t + k] + c];
                lo[c] = fmin(lo[c], u);
                hi[c] = fmax(hi[c], u);
            }
    }
    double h = ds->spacing, cells = 1.0;
    int n[3];
    for (int c = 0; c < 3; c++) {
        if (!(hi[c] > lo[c])) {
            ns_set_err(err, err_sz, "%s: ns.scenario: dosimetry: the regions have no tets",
                       r->sc.where);
            return -1;
        }
        n[c] = (int)fmax(1.0, ceil((hi[c] - lo[c]) / h - 1e-9));
        cells *= n[c];
    }
    if (cells > (double)NS_DOSE_MAX_VOXELS) {
        ns_set_err(err, err_sz,
                   "%s: ns.scenario: dosimetry: the regions' box holds %.3g voxels at spacing %g "
                   "m (at most %ld)",
                   r->sc.where, cells, h, NS_DOSE_MAX_VOXELS);
        return -1;
    }
    long total = (long)cells;
    signed char *lab = malloc((size_t)total);
    if (!lab) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    memset(lab, -1, (size_t)total);
    label_voxels(m, ds->region, lo, h, n, lab);
    for (long v = 0; v < total; v++)
        if (lab[v] >= 0)
            D->count[lab[v]]++;
    D->n = D->count[0] + D->count[1] + D->count[2];
    D->pts = malloc((size_t)(D->n > 0 ? D->n : 1) * 3 * sizeof *D->pts);
    D->which = malloc((size_t)(D->n > 0 ? D->n : 1));
    if (!D->pts || !D->which) {
        free(lab);
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    long w = 0;
    for (int k = 0; k < n[2]; k++)
        for (int j = 0; j < n[1]; j++)
            for (int i = 0; i < n[0]; i++) {
                long v = ((long)k * n[1] + j) * n[0] + i;
                if (lab[v] < 0)
                    continue;
                D->pts[3 * w] = lo[0] + (i + 0.5) * h;
                D->pts[3 * w + 1] = lo[1] + (j + 0.5) * h;
                D->pts[3 * w + 2] = lo[2] + (k + 0.5) * h;
                D->which[w++] = (unsigned char)lab[v];
            }
    free(lab);
    for (int q = 0; q < 3; q++)
        if (D->count[q] == 0) {
            ns_set_err(err, err_sz,
                       "%s: ns.scenario: dosimetry.%s: the region holds no voxel centre at spacing "
                       "%g m",
                       r->sc.where, region_key[q], h);
            return -1;
        }
    return 0;
}

/* The dose at every voxel from seeds at the given material points, and its three DVHs. */
static int dose_of(NsRun *r, struct NsRunDose *D, int which, const double *pos, int n_seeds,
                   char *err, int err_sz)
{
    NsDoseSeed *seeds = malloc((size_t)(n_seeds > 0 ? n_seeds : 1) * sizeof *seeds);
    D->dose[which] = malloc((size_t)D->n * sizeof(double));
    double *split = malloc((size_t)D->n * sizeof(double));
    int rc = seeds && D->dose[which] && split ? 0 : -1;
    if (rc)
        ns_set_err(err, err_sz, "out of memory");
    for (int k = 0; rc == 0 && k < n_seeds; k++) {
        memcpy(seeds[k].pos, pos + 3 * k, sizeof seeds[k].pos);
        memcpy(seeds[k].axis, D->axis, sizeof D->axis);
        seeds[k].sk = r->spec.dosimetry.strength;
    }
    char e2[256];
    if (rc == 0 && ns_dose_points(&D->src, seeds, n_seeds, D->pts, D->n, r->opt.threads,
                                  D->dose[which], e2, sizeof e2)) {
        ns_set_err(err, err_sz, "%s: dosimetry: %s", r->sc.path, e2);
        rc = -1;
    }
    for (int q = 0; rc == 0 && q < 3; q++) {
        long c = 0;
        for (long i = 0; i < D->n; i++)
            if (D->which[i] == q)
                split[c++] = D->dose[which][i];
        double h = r->spec.dosimetry.spacing;
        if (ns_dvh_make(&D->dvh[which][q], split, c, h * h * h, e2, sizeof e2)) {
            ns_set_err(err, err_sz, "%s: dosimetry: %s: %s", r->sc.path, region_key[q], e2);
            rc = -1;
        }
    }
    D->seeds[which] = n_seeds;
    free(seeds);
    free(split);
    return rc;
}

int ns_run_dosimetry_begin(NsRun *r, char *err, int err_sz)
{
    const NsRunDosimetry *ds = &r->spec.dosimetry;
    if (!ds->on)
        return 0;
    double w0 = ns_wall_s();
    struct NsRunDose *D = calloc(1, sizeof *D);
    if (!D) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    r->dose = D;
    /* DIR/dvh.csv will replace only a regular file: checked before the run, not at its end */
    char *old = r->opt.out_dir ? ns_run_path_join(r->opt.out_dir, "dvh.csv") : NULL;
    int bad = old && ns_out_replaceable(old, "the dose-volume histograms", err, err_sz);
    free(old);
    if (bad)
        return -1;
    memcpy(D->axis, r->spec.entry_dir, sizeof D->axis);
    char e2[512];
    if (ns_tg43_load_6711(&D->src, e2, sizeof e2)) {
        ns_set_err(err, err_sz, "%s: ns.scenario: dosimetry: %s", r->sc.where, e2);
        return -1;
    }
    if (voxelize(r, D, err, err_sz) || dose_of(r, D, PLANNED, ds->plan, ds->plan_n, err, err_sz))
        return -1;
    D->ms += 1e3 * (ns_wall_s() - w0);
    return 0;
}

int ns_run_dosimetry_end(NsRun *r, char *err, int err_sz)
{
    struct NsRunDose *D = r->dose;
    if (!D)
        return 0;
    double w0 = ns_wall_s();
    int n = r->seed_n;
    double *u = malloc((size_t)(n > 0 ? n : 1) * 3 * sizeof *u);
    if (!u) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    for (int k = 0; k < n; k++)
        memcpy(u + 3 * k, r->seeds[k].u, 3 * sizeof *u);
    int rc = dose_of(r, D, DELIVERED, u, n, err, err_sz);
    free(u);
    if (rc)
        return -1;
    const NsRunDosimetry *ds = &r->spec.dosimetry;
    D->disp_n = n < ds->plan_n ? n : ds->plan_n;
    D->disp = malloc((size_t)(D->disp_n > 0 ? D->disp_n : 1) * sizeof *D->disp);
    if (!D->disp) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    for (int k = 0; k < D->disp_n; k++) {
        double s = 0.0;
        for (int c = 0; c < 3; c++) {
            double d = r->seeds[k].u[c] - ds->plan[3 * k + c];
            s += d * d;
        }
        D->disp[k] = sqrt(s);
    }
    D->ms += 1e3 * (ns_wall_s() - w0);
    return 0;
}

static void figures_json(NsJson *j, const char *key, const struct NsRunDose *D, int w, double rx)
{
    const NsDvh *p = &D->dvh[w][0], *u = &D->dvh[w][1], *rc = &D->dvh[w][2];
    ns_json_key(j, key);
    ns_json_begin_object(j);
    ns_json_key(j, "seeds");
    ns_json_int(j, D->seeds[w]);
    ns_json_key(j, "prostate_d90_gy");
    ns_json_number(j, ns_dvh_d_pct(p, 90));
    ns_json_key(j, "prostate_d90_pct");
    ns_json_number(j, 100.0 * ns_dvh_d_pct(p, 90) / rx);
    ns_json_key(j, "prostate_v100_pct");
    ns_json_number(j, ns_dvh_v_pct(p, rx));
    ns_json_key(j, "prostate_v150_pct");
    ns_json_number(j, ns_dvh_v_pct(p, 1.5 * rx));
    ns_json_key(j, "prostate_v200_pct");
    ns_json_number(j, ns_dvh_v_pct(p, 2.0 * rx));
    ns_json_key(j, "urethra_d10_gy");
    ns_json_number(j, ns_dvh_d_pct(u, 10));
    ns_json_key(j, "urethra_d30_gy");
    ns_json_number(j, ns_dvh_d_pct(u, 30));
    ns_json_key(j, "rectum_d2cc_gy");
    ns_json_number(j, ns_dvh_d_vol(rc, 2e-6));
    ns_json_key(j, "rectum_v100_cc");
    ns_json_number(j, 1e6 * ns_dvh_v_vol(rc, rx));
    ns_json_end_object(j);
}

/* The guideline criteria (docs/brachytherapy.md, "Dose score"): each met scores 1, the total is
 * their mean x 100. Limits in % of the prescription, % of the region, or cc. */
typedef struct Criterion {
    const char *name, *unit;
    int region;   /* 0 prostate, 1 urethra, 2 rectum */
    int kind;     /* 0: D at % of volume, 1: D at volume (cc), 2: V at % of Rx (%), 3: (cc) */
    double at;    /* the % of volume, the volume [cc] or the dose [% of Rx] read */
    double limit; /* in `unit` */
    int at_least; /* 1: value >= limit, 0: value < limit (or <= for V150) */
} Criterion;

static const Criterion criteria[] = {
    {"prostate_d90", "pct_rx", 0, 0, 90, 100, 1}, {"prostate_v100", "pct", 0, 2, 100, 95, 1},
    {"prostate_v150", "pct", 0, 2, 150, 60, 0},   {"urethra_d10", "pct_rx", 1, 0, 10, 150, 0},
    {"rectum_d2cc", "pct_rx", 2, 1, 2, 100, 0},   {"rectum_v100", "cc", 2, 3, 100, 1, 0},
};
#define N_CRITERIA ((int)(sizeof criteria / sizeof criteria[0]))

static double criterion_value(const Criterion *c, const NsDvh *d, double rx)
{
    switch (c->kind) {
    case 0:
        return 100.0 * ns_dvh_d_pct(d, c->at) / rx;
    case 1:
        return 100.0 * ns_dvh_d_vol(d, 1e-6 * c->at) / rx;
    case 2:
        return ns_dvh_v_pct(d, 1e-2 * c->at * rx);
    default:
        return 1e6 * ns_dvh_v_vol(d, 1e-2 * c->at * rx);
    }
}

static bool criterion_met(const Criterion *c, double v)
{
    return c->at_least ? v >= c->limit : c->kind == 2 ? v <= c->limit : v < c->limit;
}

static void score_json(NsJson *j, const struct NsRunDose *D, double rx)
{
    ns_json_key(j, "score");
    ns_json_begin_object(j);
    ns_json_key(j, "formula");
    ns_json_string(j, "needlesim-dose-score/1");
    int met[2] = {0, 0};
    ns_json_key(j, "criteria");
    ns_json_begin_array(j);
    for (int k = 0; k < N_CRITERIA; k++) {
        const Criterion *c = &criteria[k];
        ns_json_begin_object(j);
        ns_json_key(j, "name");
        ns_json_string(j, c->name);
        ns_json_key(j, "unit");
        ns_json_string(j, c->unit);
        ns_json_key(j, "limit");
        ns_json_number(j, c->limit);
        ns_json_key(j, "at_least");
        ns_json_bool(j, c->at_least);
        for (int w = 0; w < 2; w++) {
            double v = criterion_value(c, &D->dvh[w][c->region], rx);
            bool ok = criterion_met(c, v);
            met[w] += ok;
            ns_json_key(j, w == PLANNED ? "planned" : "delivered");
            ns_json_number(j, v);
            ns_json_key(j, w == PLANNED ? "planned_met" : "delivered_met");
            ns_json_bool(j, ok);
        }
        ns_json_end_object(j);
    }
    ns_json_end_array(j);
    ns_json_key(j, "planned");
    ns_json_number(j, 100.0 * met[PLANNED] / N_CRITERIA);
    ns_json_key(j, "delivered");
    ns_json_number(j, 100.0 * met[DELIVERED] / N_CRITERIA);
    ns_json_end_object(j);
}

void ns_run_dosimetry_json(NsJson *j, const NsRun *r)
{
    const struct NsRunDose *D = r->dose;
    if (!D || !D->dose[DELIVERED])
        return;
    const NsRunDosimetry *ds = &r->spec.dosimetry;
    double h = ds->spacing;
    ns_json_key(j, "dosimetry");
    ns_json_begin_object(j);
    ns_json_key(j, "prescription_gy");
    ns_json_number(j, ds->prescription);
    ns_json_key(j, "source");
    ns_json_string(j, "I-125 model 6711, TG-43U1 line source");
    ns_json_key(j, "strength_u");
    ns_json_number(j, ds->strength / NS_TG43_UNIT_U);
    ns_json_key(j, "spacing_m");
    ns_json_number(j, h);
    ns_json_key(j, "volume_cc");
    ns_json_begin_object(j);
    for (int q = 0; q < 3; q++) {
        ns_json_key(j, region_key[q]);
        ns_json_number(j, 1e6 * (double)D->count[q] * h * h * h);
    }
    ns_json_end_object(j);
    figures_json(j, "planned", D, PLANNED, ds->prescription);
    figures_json(j, "delivered", D, DELIVERED, ds->prescription);
    ns_json_key(j, "seed_displacement_mm");
    ns_json_begin_object(j);
    double sum = 0.0, mx = 0.0;
    for (int k = 0; k < D->disp_n; k++) {
        sum += D->disp[k];
        mx = fmax(mx, D->disp[k]);
    }
    ns_json_key(j, "mean");
    ns_json_number(j, D->disp_n ? 1e3 * sum / D->disp_n : 0.0);
    ns_json_key(j, "max");
    ns_json_number(j, 1e3 * mx);
    ns_json_key(j, "each");
    ns_json_begin_array(j);
    for (int k = 0; k < D->disp_n; k++)
        ns_json_number(j, 1e3 * D->disp[k]);
    ns_json_end_array(j);
    ns_json_end_object(j);
    score_json(j, D, ds->prescription);
    ns_json_key(j, "dose_ms");
    ns_json_number(j, D->ms);
    ns_json_end_object(j);
}

/* DIR/dvh.csv: the cumulative DVHs, % of each region's volume receiving at least each dose,
 * from 0 to 3x the prescription in steps of 1% of it. Written as a part file, renamed by
 * ns_run_dosimetry_commit. */
/* The scene's dose callback: the seeds at their world positions now, the dosimetry's source,
 * strength and axis. */
static int scene_dose(void *ctx, const double *seed_x, int n_seeds, const double *pts, long n,
                      double *out)
{
    const NsRun *r = ctx;
    const struct NsRunDose *D = r->dose;
    NsDoseSeed *seeds = malloc((size_t)(n_seeds > 0 ? n_seeds : 1) * sizeof *seeds);
    if (!seeds)
        return -1;
    for (int k = 0; k < n_seeds; k++) {
        memcpy(seeds[k].pos, seed_x + 3 * k, sizeof seeds[k].pos);
        memcpy(seeds[k].axis, D->axis, sizeof D->axis);
        seeds[k].sk = r->spec.dosimetry.strength;
    }
    int rc = ns_dose_points(&D->src, seeds, n_seeds, pts, n, r->opt.threads, out, NULL, 0);
    free(seeds);
    return rc;
}

void ns_run_dosimetry_isodose(const NsRun *r, NsSceneInput *in)
{
    if (!r->dose)
        return;
    in->dose_points = scene_dose;
    in->dose_ctx = (void *)r; /* read only: the source, the axis and the strength */
    in->iso_levels[0] = r->spec.dosimetry.prescription;
    in->iso_levels[1] = 1.5 * r->spec.dosimetry.prescription;
    in->iso_count = 2;
}

const NsDvh *ns_run_dosimetry_dvh(const NsRun *r, int delivered, int region)
{
    const struct NsRunDose *D = r->dose;
    int w = delivered ? DELIVERED : PLANNED;
    if (!D || !D->dose[DELIVERED] || region < 0 || region > 2)
        return NULL;
    return &D->dvh[w][region];
}

int ns_run_dosimetry_write(NsRun *r, char *err, int err_sz)
{
    struct NsRunDose *D = r->dose;
    if (!D || !D->dose[DELIVERED])
        return 0;
    D->csv_tmp = ns_run_path_join(r->opt.out_dir, ".dvh.csv.part");
    if (!D->csv_tmp) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    FILE *f = ns_out_create_part(D->csv_tmp, "the dose-volume histograms", err, err_sz);
    if (!f)
        return -1;
    fputs("dose_gy", f);
    for (int q = 0; q < 3; q++)
        fprintf(f, ",%s_planned_pct,%s_delivered_pct", region_key[q], region_key[q]);
    fputc('\n', f);
    double rx = r->spec.dosimetry.prescription;
    for (int s = 0; s <= 300; s++) {
        double d = rx * s / 100.0;
        fprintf(f, "%.6g", d);
        for (int q = 0; q < 3; q++)
            fprintf(f, ",%.6g,%.6g", ns_dvh_v_pct(&D->dvh[PLANNED][q], d),
                    ns_dvh_v_pct(&D->dvh[DELIVERED][q], d));
        fputc('\n', f);
    }
    int bad = ferror(f) != 0;
    if ((fclose(f) != 0) | bad) {
        ns_set_err(err, err_sz, "cannot write '%s': %s", D->csv_tmp, strerror(errno));
        return -1;
    }
    return 0;
}

int ns_run_dosimetry_commit(NsRun *r)
{
    struct NsRunDose *D = r->dose;
    if (!D || !D->csv_tmp)
        return 0;
    char *final = ns_run_path_join(r->opt.out_dir, "dvh.csv");
    int rc = !final || ns_out_commit(D->csv_tmp, final) ? -1 : 0;
    free(final);
    if (rc == 0) {
        free(D->csv_tmp);
        D->csv_tmp = NULL;
    }
    return rc;
}

void ns_run_dosimetry_uncommit(NsRun *r)
{
    if (!r->dose || r->dose->csv_tmp || !r->dose->dose[DELIVERED])
        return;
    char *final = ns_run_path_join(r->opt.out_dir, "dvh.csv");
    if (final)
        remove(final);
    free(final);
}

void ns_run_dosimetry_free(NsRun *r)
{
    struct NsRunDose *D = r->dose;
    if (!D)
        return;
    if (D->csv_tmp)
        ns_out_remove_part(D->csv_tmp);
    free(D->csv_tmp);
    free(D->pts);
    free(D->which);
    for (int w = 0; w < 2; w++) {
        free(D->dose[w]);
        for (int q = 0; q < 3; q++)
            ns_dvh_free(&D->dvh[w][q]);
    }
    free(D->disp);
    free(D);
    r->dose = NULL;
}
