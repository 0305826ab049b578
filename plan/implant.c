/* Implant planning by greedy set cover (implant.h). */
#include "implant.h"

#include <math.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>

#include "dvh.h"
#include "err.h"
#include "plan_math.h"

/* Steps along a track when finding the region's span and the clearance [m]. */
#define TRACK_STEP 0.25e-3

typedef struct Cand {
    int hole;
    int seeds;
    double deepest; /* along the track [m] */
    double *dose;   /* its seeds' dose at every voxel (voxels) [Gy] */
} Cand;

/* True if p lies in region t: inside its shape and in no later region's (later ones override). */
static bool in_region(const NsImplantParams *p, int t, const double x[3])
{
    if (ns_shape_eval(p->regions[t], x) > 0.0)
        return false;
    for (int k = t + 1; k < p->region_count; k++)
        if (ns_shape_eval(p->regions[k], x) <= 0.0)
            return false;
    return true;
}

/* The nearest avoided region's signed distance at x [m] (+inf with none). */
static double avoid_distance(const NsImplantParams *p, const double x[3])
{
    double d = INFINITY;
    for (int i = 0; i < p->avoid_count; i++) {
        double e = ns_shape_eval(p->regions[p->avoid[i]], x);
        d = e < d ? e : d;
    }
    return d;
}

static int check_params(const NsImplantParams *p, char *err, int err_sz)
{
    const char *why = NULL;
    if (!p->regions || p->region_count < 1 || p->target < 0 || p->target >= p->region_count)
        why = "the target region is not one of the regions";
    else if (p->avoid_count < 0 || p->avoid_count > NS_IMPLANT_MAX_AVOID ||
             (p->avoid_count > 0 && !p->avoid))
        why = "too many avoided regions";
    else if (p->hole_count < 1 || p->hole_count > NS_IMPLANT_MAX_HOLES || !p->holes)
        why = "the template has no holes, or too many";
    else if (!(p->clearance >= 0.0 && p->clearance < 0.1))
        why = "clearance must be in [0, 0.1) m";
    else if (!(p->spacing >= 1e-3 && p->spacing <= 0.05))
        why = "spacing must be in [1e-3, 0.05] m";
    else if (!(p->margin >= 0.0 && p->margin <= 0.05))
        why = "margin must be in [0, 0.05] m";
    else if (p->seeds_max < 1 || p->needles_max < 1 || p->seeds_per_needle < 1)
        why = "the seed and needle budgets must be >= 1";
    else if (!(p->tip_offset >= 0.0 && p->tip_offset <= 0.05))
        why = "the tip's offset must be in [0, 0.05] m";
    else if (!(p->prescription > 0.0 && isfinite(p->prescription)))
        why = "the prescription must be > 0 Gy";
    else if (!(p->coverage > 0.0 && p->coverage <= 1.0))
        why = "coverage must be in (0, 1]";
    else if (!(p->v150_max > 0.0 && p->v150_max <= 100.0))
        why = "v150_max must be in (0, 100] %";
    else if (!(p->grid >= 0.5e-3 && p->grid <= 0.01))
        why = "the planning grid must be in [0.5e-3, 0.01] m";
    else if (!p->source || !(p->sk > 0.0 && isfinite(p->sk)))
        why = "the seeds need a source and a strength > 0";
    for (int i = 0; !why && i < p->avoid_count; i++)
        if (p->avoid[i] < 0 || p->avoid[i] >= p->region_count || p->avoid[i] == p->target)
            why = "an avoided region is not one of the regions, or is the target";
    for (int i = 0; !why && i < 3 * p->hole_count; i++)
        if (!isfinite(p->holes[i]))
            why = "a hole is not a finite point";
    double d[3] = {p->direction[0], p->direction[1], p->direction[2]};
    if (!why && (!pm_finite(d) || !pm_unit(d)))
        why = "the direction must be a finite non-zero vector";
    if (why) {
        ns_set_err(err, err_sz, "implant plan: %s", why);
        return -1;
    }
    return ns_tg43_check(p->source, err, err_sz);
}

/* The region's voxel centres on the planning grid (*n of them, malloc'd). */
static double *region_voxels(const NsImplantParams *p, long *n, char *err, int err_sz)
{
    double lo[3], hi[3];
    if (!ns_shape_bounds(p->regions[p->target], lo, hi)) {
        ns_set_err(err, err_sz, "implant plan: the target region is unbounded");
        return NULL;
    }
    for (int k = 0; k < 3; k++)
        if (!(hi[k] - lo[k] <= NS_IMPLANT_MAX_REACH)) { /* the tracks are walked across it */
            ns_set_err(err, err_sz,
                       "implant plan: the target region's box is more than %g m across",
                       NS_IMPLANT_MAX_REACH);
            return NULL;
        }
    double mk[3], total = 1.0; /* counted in double: a huge box is refused before a cast */
    for (int k = 0; k < 3; k++) {
        mk[k] = fmax(ceil((hi[k] - lo[k]) / p->grid), 1.0);
        total *= mk[k];
    }
    if (!(total <= 2.0 * NS_IMPLANT_MAX_VOXELS)) {
        ns_set_err(err, err_sz,
                   "implant plan: the region's box holds %.3g voxels at grid %g m (at most %ld)",
                   total, p->grid, 2 * NS_IMPLANT_MAX_VOXELS);
        return NULL;
    }
    long m[3] = {(long)mk[0], (long)mk[1], (long)mk[2]};
    double *pts = NULL;
    long cap = 0, count = 0;
    for (long k = 0; k < m[2]; k++)
        for (long j = 0; j < m[1]; j++)
            for (long i = 0; i < m[0]; i++) {
                double x[3] = {lo[0] + ((double)i + 0.5) * p->grid,
                               lo[1] + ((double)j + 0.5) * p->grid,
                               lo[2] + ((double)k + 0.5) * p->grid};
                if (!in_region(p, p->target, x))
                    continue;
                if (count == NS_IMPLANT_MAX_VOXELS) {
                    free(pts);
                    ns_set_err(err, err_sz,
                               "implant plan: the region holds more than %ld voxels "
                               "at grid %g m",
                               NS_IMPLANT_MAX_VOXELS, p->grid);
                    return NULL;
                }
                if (count == cap) {
                    cap = cap ? 2 * cap : 4096;
                    double *q = realloc(pts, (size_t)cap * 3 * sizeof *q);
                    if (!q) {
                        free(pts);
                        ns_set_err(err, err_sz, "implant plan: out of memory");
                        return NULL;
                    }
                    pts = q;
                }
                memcpy(pts + 3 * count++, x, sizeof x);
            }
    if (count == 0) {
        free(pts);
        ns_set_err(err, err_sz,
                   "implant plan: the target region holds no voxel centre at grid %g m", p->grid);
        return NULL;
    }
    *n = count;
    return pts;
}

/* The part [*t0, *t1] of the ray e + s dir (s >= 0) inside the box [lo, hi]; false if none. */
static bool clip_ray(const double e[3], const double dir[3], const double lo[3], const double hi[3],
                     double *t0, double *t1)
{
    double a = 0.0, b = INFINITY;
    for (int k = 0; k < 3; k++) {
        if (fabs(dir[k]) < 1e-300) {
            if (e[k] < lo[k] || e[k] > hi[k])
                return false;
            continue;
        }
        double u = (lo[k] - e[k]) / dir[k], v = (hi[k] - e[k]) / dir[k];
        a = fmax(a, fmin(u, v));
        b = fmin(b, fmax(u, v));
    }
    *t0 = a;
    *t1 = b;
    return a <= b;
}

/* Hole h's track: the region's first span along it [s0, s1] (walked within the region's box
 * only), its load (centred, at most seeds_per_needle), and whether the needle up to its tip
 * keeps the clearance. 0: no span (or no seed past the skin); 1: a candidate (c filled); 2:
 * blocked. */
static int track(const NsImplantParams *p, const double dir[3], const double lo[3],
                 const double hi[3], int h, Cand *c)
{
    const double *e = p->holes + 3 * h;
    double a, b, s0 = -1.0, s1 = -1.0;
    if (!clip_ray(e, dir, lo, hi, &a, &b))
        return 0;
    for (double s = a; s <= b; s += TRACK_STEP) {
        double x[3];
        pm_axpy(e, s, dir, x);
        if (in_region(p, p->target, x)) {
            s0 = s0 < 0.0 ? s : s0;
            s1 = s;
        } else if (s0 >= 0.0) {
            break;
        }
    }
    if (s0 < 0.0)
        return 0;
    double len = s1 - s0, mid = 0.5 * (s0 + s1);
    int n = len > 2.0 * p->margin ? (int)floor((len - 2.0 * p->margin) / p->spacing) + 1 : 1;
    n = n < p->seeds_per_needle ? n : p->seeds_per_needle;
    c->hole = h;
    c->seeds = n;
    c->deepest = mid + 0.5 * (n - 1) * p->spacing;
    if (c->deepest - (n - 1) * p->spacing <= p->tip_offset)
        return 0; /* the shallowest seed would sit at the skin */
    for (double s = 0.0; s <= c->deepest + p->tip_offset; s += TRACK_STEP) {
        double x[3];
        pm_axpy(e, s, dir, x);
        if (avoid_distance(p, x) < p->clearance)
            return 2;
    }
    return 1;
}

/* Candidate c's seeds (c->seeds of them) into s: centres along the track, deepest first. */
static void cand_seeds(const NsImplantParams *p, const double dir[3], const Cand *c, NsDoseSeed *s)
{
    for (int i = 0; i < c->seeds; i++) {
        pm_axpy(p->holes + 3 * c->hole, c->deepest - i * p->spacing, dir, s[i].pos);
        memcpy(s[i].axis, dir, sizeof s[i].axis);
        s[i].sk = p->sk;
    }
}

static long count_at_least(const double *dose, long n, double level)
{
    long k = 0;
    for (long i = 0; i < n; i++)
        k += dose[i] >= level;
    return k;
}

/* dose = sum of the chosen candidates' doses. */
static void sum_dose(const Cand *c, const bool *chosen, int nc, long n, double *dose)
{
    memset(dose, 0, (size_t)n * sizeof *dose);
    for (int j = 0; j < nc; j++)
        if (chosen[j])
            for (long i = 0; i < n; i++)
                dose[i] += c[j].dose[i];
}

void ns_implant_plan_free(NsImplantPlan *plan)
{
    if (!plan)
        return;
    free(plan->hole);
    free(plan->seeds);
    free(plan->deepest);
    free(plan->seed_pos);
    memset(plan, 0, sizeof *plan);
}

/* The greedy choice over the candidates (chosen[] out). */
static void choose(const NsImplantParams *p, const Cand *c, int nc, long n, double *cur,
                   double *tmp, bool *chosen)
{
    const double rx = p->prescription;
    const long need = (long)ceil(p->coverage * (double)n);
    int needles = 0, seeds = 0;
    memset(cur, 0, (size_t)n * sizeof *cur);
    long covered = 0;
    const long hot_max = (long)floor(0.01 * p->v150_max * (double)n);
    while (covered < need && needles < p->needles_max) {
        int best = -1;
        long best_gain = 0, best_hot = 0;
        bool best_ok = false;
        for (int j = 0; j < nc; j++) {
            if (chosen[j] || seeds + c[j].seeds > p->seeds_max)
                continue;
            long gain = 0, hot = 0;
            for (long i = 0; i < n; i++) {
                double d = cur[i] + c[j].dose[i];
                gain += cur[i] < rx && d >= rx;
                hot += d >= 1.5 * rx;
            }
            if (gain == 0)
                continue;
            /* a needle that keeps V150 within its bound first; then the most newly covered
             * volume; then the least at 150 %; then the first hole */
            bool ok = hot <= hot_max;
            if (best < 0 || (ok && !best_ok) ||
                (ok == best_ok && (gain > best_gain || (gain == best_gain && hot < best_hot)))) {
                best = j;
                best_gain = gain;
                best_hot = hot;
                best_ok = ok;
            }
        }
        if (best < 0)
            break;
        chosen[best] = true;
        needles++;
        seeds += c[best].seeds;
        for (long i = 0; i < n; i++)
            cur[i] += c[best].dose[i];
        covered += best_gain;
    }
    /* fewest insertions: drop a needle (the smallest load first) the coverage does not need */
    if (covered < need)
        return;
    for (bool dropped = true; dropped;) {
        dropped = false;
        int drop = -1;
        for (int j = 0; j < nc; j++) {
            if (!chosen[j] || (drop >= 0 && c[j].seeds >= c[drop].seeds))
                continue;
            for (long i = 0; i < n; i++)
                tmp[i] = cur[i] - c[j].dose[i];
            if (count_at_least(tmp, n, rx) >= need)
                drop = j;
        }
        if (drop >= 0) {
            chosen[drop] = false;
            sum_dose(c, chosen, nc, n, cur);
            dropped = true;
        }
    }
}

/* Fills out from the chosen candidates and the dose they give (cur). */
static int fill(const NsImplantParams *p, const double dir[3], const Cand *c, int nc,
                const bool *chosen, const double *cur, long n, NsImplantPlan *out, char *err,
                int err_sz)
{
    int nn = 0, ns = 0;
    for (int j = 0; j < nc; j++)
        if (chosen[j]) {
            nn++;
            ns += c[j].seeds;
        }
    out->hole = malloc((size_t)(nn ? nn : 1) * sizeof *out->hole);
    out->seeds = malloc((size_t)(nn ? nn : 1) * sizeof *out->seeds);
    out->deepest = malloc((size_t)(nn ? nn : 1) * sizeof *out->deepest);
    out->seed_pos = malloc((size_t)(ns ? ns : 1) * 3 * sizeof *out->seed_pos);
    NsDoseSeed *tmp = malloc((size_t)(ns ? ns : 1) * sizeof *tmp);
    NsDvh dvh = {0};
    int rc = -1;
    if (!out->hole || !out->seeds || !out->deepest || !out->seed_pos || !tmp) {
        ns_set_err(err, err_sz, "implant plan: out of memory");
        goto done;
    }
    for (int j = 0, k = 0, m = 0; j < nc; j++) {
        if (!chosen[j])
            continue;
        out->hole[k] = c[j].hole;
        out->seeds[k] = c[j].seeds;
        out->deepest[k++] = c[j].deepest;
        cand_seeds(p, dir, &c[j], tmp);
        for (int i = 0; i < c[j].seeds; i++, m++)
            memcpy(out->seed_pos + 3 * m, tmp[i].pos, sizeof tmp[i].pos);
    }
    out->needle_count = nn;
    out->seed_count = ns;
    if (ns_dvh_make(&dvh, cur, n, p->grid * p->grid * p->grid, err, err_sz))
        goto done;
    out->v100 = ns_dvh_v_pct(&dvh, p->prescription);
    out->v150 = ns_dvh_v_pct(&dvh, 1.5 * p->prescription);
    out->d90 = ns_dvh_d_pct(&dvh, 90.0);
    out->reached = out->v100 >= 100.0 * p->coverage - 1e-9;
    rc = 0;
done:
    ns_dvh_free(&dvh);
    free(tmp);
    return rc;
}

int ns_plan_implant(const NsImplantParams *p, NsImplantPlan *out, char *err, int err_sz)
{
    memset(out, 0, sizeof *out);
    if (check_params(p, err, err_sz))
        return -1;
    double dir[3] = {p->direction[0], p->direction[1], p->direction[2]};
    pm_unit(dir);
    long n = 0;
    double *pts = region_voxels(p, &n, err, err_sz);
    if (!pts)
        return -1;
    /* the region's box, grown by a step; every hole within NS_IMPLANT_MAX_REACH of it (a
     * track is walked from its hole to past its tip, in steps) */
    double lo[3], hi[3];
    ns_shape_bounds(p->regions[p->target], lo, hi);
    for (int k = 0; k < 3; k++) {
        lo[k] -= TRACK_STEP;
        hi[k] += TRACK_STEP;
    }
    for (int h = 0; h < p->hole_count; h++) {
        double d2 = 0.0;
        for (int k = 0; k < 3; k++) {
            double x = p->holes[3 * h + k], d = x < lo[k] ? lo[k] - x : x > hi[k] ? x - hi[k] : 0;
            d2 += d * d;
        }
        if (!(d2 <= NS_IMPLANT_MAX_REACH * NS_IMPLANT_MAX_REACH)) {
            free(pts);
            ns_set_err(err, err_sz,
                       "implant plan: hole %d is more than %g m from the target region's box",
                       h + 1, NS_IMPLANT_MAX_REACH);
            return -1;
        }
    }
    Cand *c = calloc((size_t)p->hole_count, sizeof *c);
    double *cur = malloc((size_t)n * sizeof *cur), *tmp = malloc((size_t)n * sizeof *tmp);
    NsDoseSeed *seeds = NULL;
    bool *chosen = calloc((size_t)p->hole_count, sizeof *chosen);
    int nc = 0, rc = -1;
    if (!c || !cur || !tmp || !chosen) {
        ns_set_err(err, err_sz, "implant plan: out of memory");
        goto done;
    }
    double work = 0.0; /* seed-voxel dose evaluations */
    for (int h = 0; h < p->hole_count; h++) {
        int t = track(p, dir, lo, hi, h, &c[nc]);
        out->candidates += t != 0;
        out->blocked += t == 2;
        if (t == 1)
            work += (double)c[nc++].seeds * (double)n;
    }
    /* the dose vectors' memory and the greedy choice's work, before either is spent */
    double bytes = (double)nc * (double)n * sizeof(double);
    double greedy = (double)(p->needles_max < nc ? p->needles_max : nc) * (double)nc * (double)n;
    if (work > NS_IMPLANT_MAX_WORK || bytes > NS_IMPLANT_MAX_BYTES ||
        greedy > NS_IMPLANT_MAX_CHOICE) {
        ns_set_err(err, err_sz,
                   "implant plan: %d candidate tracks over %ld voxels need %.3g dose evaluations "
                   "(at most %.3g), %.3g MB (at most %.3g) and %.3g steps to choose (at most "
                   "%.3g): a coarser grid, fewer holes or fewer needles",
                   nc, n, work, NS_IMPLANT_MAX_WORK, bytes / 1e6, NS_IMPLANT_MAX_BYTES / 1e6,
                   greedy, NS_IMPLANT_MAX_CHOICE);
        nc = 0;
        goto done;
    }
    for (int j = 0; j < nc; j++) {
        NsDoseSeed *s = realloc(seeds, (size_t)c[j].seeds * sizeof *s);
        c[j].dose = malloc((size_t)n * sizeof *c[j].dose);
        if (s)
            seeds = s;
        if (!s || !c[j].dose) {
            ns_set_err(err, err_sz, "implant plan: out of memory");
            goto done;
        }
        cand_seeds(p, dir, &c[j], seeds);
        if (ns_dose_points(p->source, seeds, c[j].seeds, pts, n, 1, c[j].dose, err, err_sz))
            goto done;
    }
    if (nc == 0) {
        if (out->candidates == 0)
            ns_set_err(err, err_sz, "implant plan: no hole's track crosses the target region");
        else
            ns_set_err(err, err_sz,
                       "implant plan: each of the %d tracks that cross the target region comes "
                       "within %g mm of an avoided region",
                       out->candidates, 1e3 * p->clearance);
        goto done;
    }
    choose(p, c, nc, n, cur, tmp, chosen);
    rc = fill(p, dir, c, nc, chosen, cur, n, out, err, err_sz);
    out->voxels = n;
done:
    for (int j = 0; j < nc; j++)
        free(c[j].dose);
    free(c);
    free(cur);
    free(tmp);
    free(seeds);
    free(chosen);
    free(pts);
    if (rc)
        ns_implant_plan_free(out);
    return rc;
}
