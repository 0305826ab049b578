/* The debrief (run.h, docs/rendering.md "The debrief"): sentences, the report's `debrief`, the
 * closest approach to each obstacle, and the force-depth chart. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "err.h"
#include "image.h"
#include "quality.h"
#include "run.h"
#include "text.h"

/* ---- closest approach ---- */

static void sub3(const double *a, const double *b, double *d)
{
    for (int i = 0; i < 3; i++)
        d[i] = a[i] - b[i];
}

/* The squared distance from p to the triangle (a, b, c): its closest point by the regions of
 * the triangle's plane (Ericson, Real-Time Collision Detection, 5.1.5). */
static double tri_dist2(const double *p, const double *a, const double *b, const double *c)
{
    double ab[3], ac[3], ap[3], q[3];
    sub3(b, a, ab);
    sub3(c, a, ac);
    sub3(p, a, ap);
    double d1 = ns_run_dot3(ab, ap), d2 = ns_run_dot3(ac, ap);
    double bp[3], cp[3];
    sub3(p, b, bp);
    sub3(p, c, cp);
    double d3 = ns_run_dot3(ab, bp), d4 = ns_run_dot3(ac, bp);
    double d5 = ns_run_dot3(ab, cp), d6 = ns_run_dot3(ac, cp);
    double va = d3 * d6 - d5 * d4, vb = d5 * d2 - d1 * d6, vc = d1 * d4 - d3 * d2;
    if (d1 <= 0 && d2 <= 0) {
        memcpy(q, a, sizeof q);
    } else if (d3 >= 0 && d4 <= d3) {
        memcpy(q, b, sizeof q);
    } else if (d6 >= 0 && d5 <= d6) {
        memcpy(q, c, sizeof q);
    } else if (vc <= 0 && d1 >= 0 && d3 <= 0) {
        double v = d1 / (d1 - d3);
        for (int i = 0; i < 3; i++)
            q[i] = a[i] + v * ab[i];
    } else if (vb <= 0 && d2 >= 0 && d6 <= 0) {
        double w = d2 / (d2 - d6);
        for (int i = 0; i < 3; i++)
            q[i] = a[i] + w * ac[i];
    } else if (va <= 0 && d4 - d3 >= 0 && d5 - d6 >= 0) {
        double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        for (int i = 0; i < 3; i++)
            q[i] = b[i] + w * (c[i] - b[i]);
    } else {
        double den = 1.0 / (va + vb + vc), v = vb * den, w = vc * den;
        for (int i = 0; i < 3; i++)
            q[i] = a[i] + v * ab[i] + w * ac[i];
    }
    double d[3];
    sub3(p, q, d);
    return ns_run_dot3(d, d);
}

double ns_run_tet_distance(const double *x, const int *tet_node, int e, const double p[3])
{
    const int *t = tet_node + 4 * e;
    const double *v[4] = {x + 3 * t[0], x + 3 * t[1], x + 3 * t[2], x + 3 * t[3]};
    double vol = ns_tet_volume(v[0], v[1], v[2], v[3]);
    /* inside: p on the inner side of every face (sub-volumes of vol's sign) */
    double s0 = ns_tet_volume(p, v[1], v[2], v[3]), s1 = ns_tet_volume(v[0], p, v[2], v[3]);
    double s2 = ns_tet_volume(v[0], v[1], p, v[3]), s3 = ns_tet_volume(v[0], v[1], v[2], p);
    if (vol != 0.0 && s0 * vol >= 0 && s1 * vol >= 0 && s2 * vol >= 0 && s3 * vol >= 0)
        return 0.0;
    double best = tri_dist2(p, v[1], v[2], v[3]);
    best = fmin(best, tri_dist2(p, v[0], v[2], v[3]));
    best = fmin(best, tri_dist2(p, v[0], v[1], v[3]));
    best = fmin(best, tri_dist2(p, v[0], v[1], v[2]));
    return sqrt(best);
}

void ns_run_debrief_closest(NsRun *r, const double p[3], double t)
{
    const NsRunSpec *sp = &r->spec;
    const NsMesh *M = &r->tissue.mesh;
    for (int k = 0; k < sp->obstacle_count; k++) {
        struct Obstacle *o = &r->obst[k];
        if (o->inside) {
            o->closest = 0.0;
            o->approached = true;
            continue;
        }
        int region = sp->obstacles[k].region;
        double best = o->approached ? o->closest : INFINITY;
        bool closer = false;
        for (int e = 0; e < M->tet_slots; e++) {
            const int *tn = M->tet_node + 4 * e;
            if (tn[0] < 0 || M->tet_region[e] != region)
                continue;
            /* a lower bound: the nearest node less the tet's longest reach from it */
            double dn = INFINITY, reach = 0.0;
            for (int a = 0; a < 4; a++) {
                double d[3];
                sub3(M->x + 3 * tn[a], p, d);
                dn = fmin(dn, sqrt(ns_run_dot3(d, d)));
                for (int b = a + 1; b < 4; b++) {
                    sub3(M->x + 3 * tn[a], M->x + 3 * tn[b], d);
                    reach = fmax(reach, sqrt(ns_run_dot3(d, d)));
                }
            }
            if (dn - reach >= best)
                continue;
            double d = ns_run_tet_distance(M->x, M->tet_node, e, p);
            if (d < best) {
                best = d;
                closer = true;
            }
        }
        if (closer) {
            o->closest = best;
            o->closest_t = t;
            o->approached = true;
        }
    }
}

/* ---- per step ---- */

int ns_run_debrief_step(NsRun *r, double twist_rate, double depth, double axial)
{
    NsRunDebrief *d = &r->debrief;
    bool turning = twist_rate != 0.0;
    d->began = turning && !d->twisting;
    if (d->began) {
        d->twists++;
        if (ns_run_debrief_mark(r, NS_MARK_TWIST))
            return -1;
    }
    d->twisting = turning;
    if (!r->rendering)
        return 0;
    return ns_series_push(&d->depth, depth) || ns_series_push(&d->force, axial) ? -1 : 0;
}

int ns_run_debrief_mark(NsRun *r, int kind)
{
    NsRunDebrief *d = &r->debrief;
    if (!r->rendering)
        return 0;
    if (d->mark_n == d->mark_cap) {
        int cap = d->mark_cap ? 2 * d->mark_cap : 32;
        struct NsDebriefMark *m = realloc(d->marks, (size_t)cap * sizeof *m);
        if (!m)
            return -1;
        d->marks = m;
        d->mark_cap = cap;
    }
    /* at the step's chart point: the one about to be pushed when called before it */
    d->marks[d->mark_n++] = (struct NsDebriefMark){kind, d->depth.n > 0 ? d->depth.n - 1 : 0};
    return 0;
}

void ns_run_debrief_free(NsRunDebrief *d)
{
    free(d->depth.v);
    free(d->force.v);
    free(d->marks);
    memset(d, 0, sizeof *d);
}

/* ---- sentences ---- */

/* Where target i's error was read from (the seed that scored it, else the tip) and its error
 * split along the insertion axis (positive: past it) and across it [mm]. */
static void target_error(const NsRun *r, const NsRunResults *res, int i, double *along,
                         double *across)
{
    const NsTargetResult *t = &res->targets[i];
    const double *from = ns_run_tip(r);
    double best = INFINITY;
    for (int k = 0; t->by_seed && k < r->seed_n; k++)
        if (res->seeds[k].target == i && res->seeds[k].error_mm < best) {
            best = res->seeds[k].error_mm;
            from = res->seeds[k].x;
        }
    double d[3], a[3];
    sub3(from, t->x, d);
    memcpy(a, r->spec.entry_dir, sizeof a);
    double la = sqrt(ns_run_dot3(a, a));
    double s = la > 0.0 ? ns_run_dot3(d, a) / la : 0.0;
    *along = 1e3 * s;
    *across = 1e3 * sqrt(fmax(0.0, ns_run_dot3(d, d) - s * s));
}

static double moved_mm(const NsRun *r, const NsRunResults *res, int i)
{
    return ns_run_dist_mm(res->targets[i].x, r->spec.targets[i].at);
}

int ns_run_debrief_sentences(const NsRun *r, const NsRunResults *res, char (*out)[256], int max)
{
    const NsRunSpec *sp = &r->spec;
    int n = 0;
    if (sp->target_count > 0 && sp->target_count <= 4) {
        for (int i = 0; i < sp->target_count && n < max; i++) {
            const NsTargetResult *t = &res->targets[i];
            if (!isfinite(t->error_mm))
                continue;
            double along, across;
            target_error(r, res, i, &along, &across);
            snprintf(out[n++], sizeof out[0],
                     "The %s ended %.1f mm from target \"%.60s\" (%.1f mm %s it along the "
                     "insertion, %.1f mm to the side): %s its %.1f mm tolerance; the tissue "
                     "carried the target %.1f mm from where it started.",
                     t->by_seed ? "seed" : "tip", t->error_mm, sp->targets[i].name, fabs(along),
                     along >= 0 ? "past" : "short of", across, t->hit ? "within" : "outside",
                     1e3 * sp->targets[i].tolerance, moved_mm(r, res, i));
        }
    } else if (sp->target_count > 4 && n < max) {
        int hit = 0, worst = 0;
        double sum = 0.0, moved = 0.0;
        int m = 0;
        for (int i = 0; i < sp->target_count; i++) {
            if (!isfinite(res->targets[i].error_mm))
                continue;
            hit += res->targets[i].hit;
            sum += res->targets[i].error_mm;
            moved += moved_mm(r, res, i);
            m++;
            if (!isfinite(res->targets[worst].error_mm) ||
                res->targets[i].error_mm > res->targets[worst].error_mm)
                worst = i;
        }
        if (m > 0)
            snprintf(out[n++], sizeof out[0],
                     "%d of %d targets were hit, %.1f mm off on average, the worst %s at %.1f mm; "
                     "the tissue carried the targets %.1f mm on average.",
                     hit, sp->target_count, sum / m, sp->targets[worst].name,
                     res->targets[worst].error_mm, moved / m);
    }
    for (int k = 0; k < sp->obstacle_count && n < max; k++) {
        const struct Obstacle *o = &r->obst[k];
        if (o->violated)
            snprintf(out[n++], sizeof out[0],
                     "The needle entered the %.60s at t = %.2f s, %.1f mm deep, for %d steps.",
                     sp->obstacles[k].name, o->first_t, 1e3 * o->max_depth, o->steps_inside);
        else if (o->approached && o->closest < 0.05e-3) /* (the tip at its surface) */
            snprintf(out[n++], sizeof out[0],
                     "The tip reached the %.60s at t = %.2f s without entering it.",
                     sp->obstacles[k].name, o->closest_t);
        else if (o->approached)
            snprintf(out[n++], sizeof out[0],
                     "The %.60s was missed by %.1f mm at its closest (t = %.2f s).",
                     sp->obstacles[k].name, 1e3 * o->closest, o->closest_t);
    }
    int bone = 0;
    for (int i = 0; i < r->event_n; i++)
        bone += r->events[i].type == EVENT_BONE_CONTACT;
    if (bone && n < max)
        snprintf(out[n++], sizeof out[0], "The tip met bone %d time%s and was taken back.", bone,
                 bone > 1 ? "s" : "");
    if (r->debrief.twists && n < max)
        snprintf(out[n++], sizeof out[0], "The base began to turn %d time%s.", r->debrief.twists,
                 r->debrief.twists > 1 ? "s" : "");
    if ((sp->seed_count || r->seed_n) && n < max) {
        double sum = 0.0, worst = 0.0;
        int m = 0;
        for (int k = 0; k < r->seed_n; k++)
            if (isfinite(res->seeds[k].error_mm)) {
                sum += res->seeds[k].error_mm;
                worst = fmax(worst, res->seeds[k].error_mm);
                m++;
            }
        snprintf(out[n++], sizeof out[0],
                 "%d of %d planned seeds were released, %.1f mm from their targets on average "
                 "(the worst %.1f mm).",
                 r->seed_n, sp->seed_count, m ? sum / m : 0.0, worst);
    }
    int affected = 0, total = 0;
    for (int k = 0; k < NS_WARN_KINDS; k++) {
        affected += ns_run_warnings_affected(&r->warn, k);
        total += r->warn.total[k];
    }
    if (n < max) {
        if (affected)
            snprintf(out[n++], sizeof out[0],
                     "Numerics: %d warning%s bore on the result (report.json "
                     "warnings_explained): read those figures with care.",
                     affected, affected > 1 ? "s" : "");
        else
            snprintf(out[n++], sizeof out[0], "Numerics: %s.",
                     total ? "every warning was transient or away from what the result reads"
                           : "no warnings");
    }
    return n;
}

void ns_run_debrief_report(NsJson *j, const NsRun *r, const NsRunResults *res)
{
    char s[16][256];
    int n = ns_run_debrief_sentences(r, res, s, 16);
    ns_json_key(j, "debrief");
    ns_json_begin_object(j);
    ns_json_key(j, "sentences");
    ns_json_begin_array(j);
    for (int i = 0; i < n; i++)
        ns_json_string(j, s[i]);
    ns_json_end_array(j);
    ns_json_key(j, "targets");
    ns_json_begin_array(j);
    for (int i = 0; i < r->spec.target_count; i++) {
        ns_json_begin_object(j);
        ns_json_key(j, "name");
        ns_json_string(j, r->spec.targets[i].name);
        if (isfinite(res->targets[i].error_mm)) { /* (a target the tissue lost has none) */
            double along, across;
            target_error(r, res, i, &along, &across);
            ns_json_key(j, "moved_mm");
            ns_json_number(j, moved_mm(r, res, i));
            ns_json_key(j, "along_mm");
            ns_json_number(j, along);
            ns_json_key(j, "across_mm");
            ns_json_number(j, across);
        }
        ns_json_end_object(j);
    }
    ns_json_end_array(j);
    ns_json_key(j, "twists");
    ns_json_int(j, r->debrief.twists);
    ns_json_end_object(j);
}

int ns_run_debrief_rows(const NsRun *r, const NsRunResults *res, char (*rows)[128], int max)
{
    char s[16][256];
    int ns = ns_run_debrief_sentences(r, res, s, 16), n = 0;
    if (ns == 0 || max < 2)
        return 0;
    snprintf(rows[n++], sizeof rows[0], "debrief:");
    for (int i = 0; i < ns && n < max; i++) { /* broken at spaces to 100 columns, indented */
        const char *p = s[i];
        bool first = true;
        while (*p && n < max) {
            size_t len = strlen(p), cut = len;
            if (len > 100) {
                cut = 100;
                while (cut > 0 && p[cut] != ' ')
                    cut--;
                if (cut == 0)
                    cut = 100;
            }
            snprintf(rows[n++], sizeof rows[0], "%s%.*s", first ? "- " : "  ", (int)cut, p);
            first = false;
            p += cut;
            while (*p == ' ')
                p++;
        }
    }
    return n;
}

/* ---- the chart ---- */

#define CW     900
#define CH     320
#define LEFT   70
#define RIGHT  190
#define TOP    36
#define BOTTOM 46

static const uint8_t bg[3] = {24, 27, 34}, axis[3] = {170, 178, 190}, grid[3] = {60, 66, 78},
                     line[3] = {235, 238, 242};
static const uint8_t mark_rgb[5][3] = {
    {90, 150, 240}, {240, 200, 70}, {120, 210, 120}, {235, 90, 80}, {200, 200, 200}};
static const char *const mark_name[5] = {"twist", "puncture", "seed", "obstacle entered",
                                         "bone contact"};

/* A round number of at least x / 4 for the axis' ticks. */
static double tick_of(double x)
{
    double p = pow(10.0, floor(log10(x / 4.0))), m = x / 4.0 / p;
    return p * (m <= 1 ? 1 : m <= 2 ? 2 : m <= 5 ? 5 : 10);
}

int ns_run_debrief_chart(const NsRun *r, NsImage *im, char *err, int err_sz)
{
    const NsRunDebrief *d = &r->debrief;
    memset(im, 0, sizeof *im);
    int n = d->depth.n;
    if (n < 2)
        return 0;
    double dmax = 1e-3, flo = 0.0, fhi = 0.1;
    for (int i = 0; i < n; i++) {
        dmax = fmax(dmax, 1e3 * d->depth.v[i]);
        flo = fmin(flo, d->force.v[i]);
        fhi = fmax(fhi, d->force.v[i]);
    }
    double dt = tick_of(dmax), ft = tick_of(fhi - flo);
    dmax = ceil(dmax / dt) * dt;
    flo = floor(flo / ft) * ft;
    fhi = ceil(fhi / ft) * ft;
    NsFont *f = ns_font_open(15, 0, err, err_sz);
    if (!f)
        return -1;
    if (ns_image_alloc(im, CW, CH, err, err_sz)) {
        ns_font_close(f);
        return -1;
    }
    ns_image_fill(im, bg);
    int pw = CW - LEFT - RIGHT, ph = CH - TOP - BOTTOM, asc = ns_font_ascent(f);
    char s[96];
#define PX(depth_mm) (LEFT + (int)((depth_mm) / dmax * pw + 0.5))
#define PY(force)    (TOP + (int)((fhi - (force)) / (fhi - flo) * ph + 0.5))
    for (double x = 0.0; x <= dmax + 1e-9; x += dt) {
        ns_image_fill_rect(im, PX(x), TOP, 1, ph, grid, 1.0);
        snprintf(s, sizeof s, "%g", x);
        ns_font_draw(f, im, PX(x) - ns_font_measure(f, s) / 2, TOP + ph + 6 + asc, s, axis);
    }
    for (double y = flo; y <= fhi + 1e-9; y += ft) {
        ns_image_fill_rect(im, LEFT, PY(y), pw, 1, grid, 1.0);
        snprintf(s, sizeof s, "%g", fabs(y) < 1e-12 ? 0.0 : y);
        ns_font_draw(f, im, LEFT - 8 - ns_font_measure(f, s), PY(y) + asc / 2, s, axis);
    }
    ns_font_draw(f, im, LEFT + pw / 2 - 60, CH - 10, "tip depth [mm]", axis);
    ns_font_draw(f, im, 8, 8 + asc, "axial force on the needle [N], against depth", axis);
    for (int k = 0; k < d->mark_n; k++) { /* under the curve: a vertical line at each event */
        const struct NsDebriefMark *m = &d->marks[k];
        int at = m->at < n ? m->at : n - 1;
        ns_image_fill_rect(im, PX(1e3 * d->depth.v[at]), TOP, 2, ph, mark_rgb[m->kind], 0.55);
    }
    for (int i = 1; i < n; i++) { /* the curve, each step joined to the last */
        int x0 = PX(1e3 * d->depth.v[i - 1]), x1 = PX(1e3 * d->depth.v[i]);
        int y0 = PY(d->force.v[i - 1]), y1 = PY(d->force.v[i]);
        int steps = abs(x1 - x0) > abs(y1 - y0) ? abs(x1 - x0) : abs(y1 - y0);
        for (int k = 0; k <= steps; k++) {
            double t = steps ? (double)k / steps : 0.0;
            ns_image_fill_rect(im, (int)lround(x0 + t * (x1 - x0)), (int)lround(y0 + t * (y1 - y0)),
                               2, 2, line, 0.8);
        }
    }
#undef PX
#undef PY
    for (int q = 0; q < 5; q++) {
        int y = TOP + 10 + 24 * q;
        ns_image_fill_rect(im, LEFT + pw + 20, y - 2, 24, 4, mark_rgb[q], 1.0);
        ns_font_draw(f, im, LEFT + pw + 52, y + asc / 2 - 1, mark_name[q], axis);
    }
    ns_font_close(f);
    return 0;
}
