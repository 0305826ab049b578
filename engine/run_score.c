/* Scoring a run (run.h, docs/scenarios.md "Score"). */
#include <errno.h>
#include <lauxlib.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "cleanup.h"
#include "control_log.h"
#include "coupling.h"
#include "err.h"
#include "json.h"
#include "needle_path.h"
#include "ns_config.h"
#include "ns_limits.h"
#include "out_files.h"
#include "quality.h"
#include "remesh.h"
#include "rod.h"
#include "run.h"

/* The score (docs/scenarios.md, formula needlesim-score/1). Each target scores 100 when its
 * error is within its tolerance, falling linearly to 0 at five tolerances; its error is the
 * distance to the nearest seed released for it when there is one, else to the needle tip at
 * the end. The total is the mean over the targets (100 without targets) less 25 for each
 * obstacle the needle entered, kept within [0, 100]. */
static double target_score(double error_mm, double tol_mm)
{
    if (!isfinite(error_mm))
        return 0.0;
    if (error_mm <= tol_mm)
        return 100.0;
    return fmax(0.0, 100.0 * (1.0 - (error_mm - tol_mm) / (4.0 * tol_mm)));
}

double ns_run_dist_mm(const double *a, const double *b)
{
    double d[3] = {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
    return 1e3 * sqrt(ns_run_dot3(d, d));
}

int ns_run_score(NsRun *r, NsRunResults *res)
{
    const NsRunSpec *sp = &r->spec;
    const NsMesh *M = &r->tissue.mesh;
    memset(res, 0, sizeof *res);
    res->targets = calloc((size_t)sp->target_count + 1, sizeof *res->targets);
    res->seeds = calloc((size_t)r->seed_n + 1, sizeof *res->seeds);
    res->markers = calloc((size_t)sp->marker_count + 1, sizeof *res->markers);
    if (!res->targets || !res->seeds || !res->markers)
        return -1;
    for (int i = 0; i < sp->target_count; i++) {
        NsTargetResult *t = &res->targets[i];
        t->error_mm = NAN;
        if (ns_run_world_of(M, sp->targets[i].at, &r->target_hint[i], t->x) != 0)
            t->x[0] = t->x[1] = t->x[2] = NAN;
    }
    for (int k = 0; k < r->seed_n; k++) {
        NsSeedResult *sd = &res->seeds[k];
        if (ns_run_world_of(M, r->seeds[k].u, &r->seeds[k].hint, sd->x) != 0)
            sd->x[0] = sd->x[1] = sd->x[2] = NAN;
        sd->target = r->seeds[k].target;
        if (sd->target < 0) { /* beyond the plan: the nearest target */
            double best = INFINITY;
            for (int i = 0; i < sp->target_count; i++) {
                double d = ns_run_dist_mm(sd->x, res->targets[i].x);
                if (d < best) {
                    best = d;
                    sd->target = i;
                }
            }
        }
        sd->error_mm = sd->target >= 0 ? ns_run_dist_mm(sd->x, res->targets[sd->target].x) : NAN;
        NsTargetResult *t = &res->targets[sd->target >= 0 ? sd->target : 0];
        if (sd->target >= 0 && (!t->by_seed || sd->error_mm < t->error_mm)) {
            t->error_mm = sd->error_mm;
            t->by_seed = true;
        }
    }
    res->target_part = 100.0;
    for (int i = 0; i < sp->target_count; i++) {
        NsTargetResult *t = &res->targets[i];
        if (!t->by_seed)
            t->error_mm = ns_run_dist_mm(ns_run_tip(r), t->x);
        double tol = 1e3 * sp->targets[i].tolerance;
        t->hit = isfinite(t->error_mm) && t->error_mm <= tol;
        t->score = target_score(t->error_mm, tol);
        res->target_part = i ? res->target_part + t->score : t->score;
    }
    if (sp->target_count)
        res->target_part /= sp->target_count;
    for (int k = 0; k < sp->obstacle_count; k++)
        res->violated += r->obst[k].violated;
    res->obstacle_penalty = 25.0 * res->violated;
    res->total = fmin(100.0, fmax(0.0, res->target_part - res->obstacle_penalty));
    for (int i = 0; i < sp->marker_count; i++) {
        int h = -1;
        if (ns_run_world_of(M, sp->markers[i].at, &h, res->markers[i]) != 0)
            res->markers[i][0] = res->markers[i][1] = res->markers[i][2] = NAN;
    }
    return 0;
}

int ns_run_score_peek(NsRun *r, NsRunResults *res)
{
    /* ns_run_score moves the lookups' starting tets (hints); a target on a face between two
     * tets may then be found in the other one, and the final score would depend on how often
     * the state was looked at. */
    const NsRunSpec *sp = &r->spec;
    int nt = sp->target_count,
        *hints = malloc(((size_t)nt + (size_t)r->seed_n + 1) * sizeof *hints);
    if (!hints) {
        memset(res, 0, sizeof *res);
        return -1;
    }
    memcpy(hints, r->target_hint, (size_t)nt * sizeof *hints);
    for (int k = 0; k < r->seed_n; k++)
        hints[nt + k] = r->seeds[k].hint;
    int bad = ns_run_score(r, res);
    memcpy(r->target_hint, hints, (size_t)nt * sizeof *hints);
    for (int k = 0; k < r->seed_n; k++)
        r->seeds[k].hint = hints[nt + k];
    free(hints);
    return bad;
}

void ns_run_results_free(NsRunResults *res)
{
    free(res->targets);
    free(res->seeds);
    free(res->markers);
}
