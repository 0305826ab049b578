/* Pictures of a run (run.h, docs/rendering.md): the key moments on the contact sheet, frames
 * and video (engine/run_render.c draws them). */
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
#include "plan_path_csv.h"
#include "quality.h"
#include "remesh.h"
#include "rod.h"
#include "run.h"

/* ---- pictures (issue 8, docs/rendering.md) ---- */

/* Opens the renderer once the tissue and the needle are built: the camera frames the tissue
 * and the needle as they start. */
int ns_run_prior_plan_read(NsRun *r, char *err, int err_sz)
{
    if (!r->opt.plan_dir)
        return 0;
    size_t n = strlen(r->opt.plan_dir) + 16;
    char *path = malloc(n);
    if (!path) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    snprintf(path, n, "%s/path.csv", r->opt.plan_dir);
    int rc = ns_plan_path_csv_read(path, &r->prior_plan, &r->prior_plan_n, err, err_sz);
    free(path);
    return rc;
}

int ns_run_render_setup(NsRun *r, char *err, int err_sz)
{
    const NsRunCamera *cam = &r->spec.camera;
    const NsMesh *M = &r->tissue.mesh;
    r->every = r->opt.frame_every > 0 ? r->opt.frame_every : cam->frame_every;
    for (int i = 0; i < 3; i++) {
        r->bounds[i] = INFINITY;
        r->bounds[3 + i] = -INFINITY;
    }
    for (int k = 0; k < M->node_slots + r->rod.nodes; k++) {
        const double *x = k < M->node_slots ? M->x + 3 * k : r->rod.x + 3 * (k - M->node_slots);
        if (k < M->node_slots && M->node_tets[k].count == 0)
            continue; /* a free slot */
        for (int i = 0; i < 3; i++) {
            r->bounds[i] = fmin(r->bounds[i], x[i]);
            r->bounds[3 + i] = fmax(r->bounds[3 + i], x[i]);
        }
    }
    int regions = r->sc.region_count > 0 ? r->sc.region_count : 1;
    r->obstacle_region = calloc((size_t)regions, sizeof *r->obstacle_region);
    r->reached = calloc((size_t)r->spec.target_count + 1, sizeof *r->reached);
    if (!r->obstacle_region || !r->reached) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    for (int k = 0; k < r->spec.obstacle_count; k++)
        if (r->spec.obstacles[k].region < regions)
            r->obstacle_region[r->spec.obstacles[k].region] = true;
    NsRunRenderOpts o = {.out_dir = r->opt.out_dir,
                         .frames = r->opt.frames,
                         .video = r->opt.video,
                         .summary = true,
                         .width = r->opt.width,
                         .height = r->opt.height,
                         .samples = r->opt.samples,
                         .fps = cam->fps,
                         .nviews = cam->view_count,
                         .legend = cam->friction_colours};
    memcpy(o.views, cam->views, sizeof o.views);
    if (r->opt.nviews > 0) { /* --view, --layout */
        memcpy(o.views, r->opt.views, sizeof o.views);
        o.nviews = r->opt.nviews;
    }
    if (ns_run_render_open(&r->rr, &o, err, err_sz)) {
        ns_run_render_abort(&r->rr); /* what it made before it failed */
        return -1;
    }
    r->rendering = true;
    return 0;
}

/* Keeps the tets as they are before a step: the frame after it highlights what changed. */
int ns_run_render_before_step(NsRun *r)
{
    const NsMesh *M = &r->tissue.mesh;
    if (M->tet_slots > r->prev_cap) {
        int cap = M->tet_slots + M->tet_slots / 2;
        int *p = realloc(r->prev_tet_node, (size_t)cap * 4 * sizeof *p);
        uint8_t *c = p ? realloc(r->changed, (size_t)cap) : NULL;
        if (p)
            r->prev_tet_node = p;
        if (c)
            r->changed = c;
        if (!p || !c)
            return -1;
        r->prev_cap = cap;
    }
    memcpy(r->prev_tet_node, M->tet_node, (size_t)M->tet_slots * 4 * sizeof(int));
    r->prev_slots = M->tet_slots;
    return 0;
}

/* A frame (caption NULL) or a key moment of the current state. res: the state's results
 * (ns_run_score), or NULL to have them worked out here. */
int ns_run_render_now(NsRun *r, const char *caption, bool final, const NsRunResults *res_in,
                      char *err, int err_sz)
{
    const NsRunSpec *sp = &r->spec;
    const NsMesh *M = &r->tissue.mesh;
    NsRunResults own;
    const NsRunResults *res = res_in;
    if (M->tet_slots > r->prev_cap) { /* the step added tets: room to mark them */
        uint8_t *c = realloc(r->changed, (size_t)M->tet_slots);
        if (!c) {
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
        r->changed = c;
    }
    if (!res) { /* drawing leaves the hints as they were (ns_run_score_peek) */
        if (ns_run_score_peek(r, &own)) {
            ns_run_results_free(&own);
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
        res = &own;
    }
    int nt = sp->target_count, ns = r->seed_n, nm = sp->marker_count;
    double *buf = malloc((size_t)(7 * nt + 3 * ns + 3 * nm + 1) * sizeof *buf);
    bool *hit = malloc((size_t)nt + 1);
    int rc = 0;
    if (!buf || !hit) {
        ns_set_err(err, err_sz, "out of memory");
        rc = -1;
    }
    NsSceneInput in;
    memset(&in, 0, sizeof in);
    double near = INFINITY;
    int near_i = -1;
    if (rc == 0) {
        double *tx = buf, *tr = buf + 3 * nt, *sx = tr + nt, *mx = sx + 3 * ns, *x0 = mx + 3 * nm;
        for (int i = 0; i < nt; i++) /* where the targets started (the mesh as built) */
            memcpy(x0 + 3 * i, sp->targets[i].at, 3 * sizeof(double));
        for (int i = 0; i < nt; i++) {
            memcpy(tx + 3 * i, res->targets[i].x, 3 * sizeof(double));
            tr[i] = sp->targets[i].tolerance;
            hit[i] = res->targets[i].hit;
            double d = ns_run_dist_mm(ns_run_tip(r), res->targets[i].x);
            if (d < near) {
                near = d;
                near_i = i;
            }
        }
        for (int k = 0; k < ns; k++)
            memcpy(sx + 3 * k, res->seeds[k].x, 3 * sizeof(double));
        for (int k = 0; k < nm; k++)
            memcpy(mx + 3 * k, res->markers[k], 3 * sizeof(double));
        for (int e = 0; r->changed && e < M->tet_slots; e++)
            r->changed[e] =
                M->tet_node[4 * e] >= 0 &&
                (e >= r->prev_slots ||
                 memcmp(M->tet_node + 4 * e, r->prev_tet_node + 4 * e, 4 * sizeof(int)) != 0);
        in.mesh = M;
        in.changed = r->changed && r->prev_slots > 0 ? r->changed : NULL;
        in.obstacle_region = r->obstacle_region;
        in.regions = r->sc.region_count;
        in.rod_x = r->rod.x;
        in.rod_nodes = r->rod.nodes;
        in.rod_radius = 0.5 * sp->diameter;
        in.state = sp->camera.friction_colours ? r->c.state : NULL;
        in.cutting = r->last_cutting != 0;
        in.bevel = sp->bevel;
        if (sp->bevel) {
            double t[3], m1[3];
            ns_rod_tip_frame(&r->rod, t, m1, in.m2);
        }
        in.held = r->rod.held;
        in.target_x = tx;
        in.target_r = tr;
        in.target_hit = hit;
        in.target_x0 = x0;
        in.targets = nt;
        in.seed_x = sx;
        in.seeds = ns;
        in.marker_x = mx;
        in.markers = nm;
        memcpy(in.axis, sp->entry_dir, sizeof in.axis);
        memcpy(in.entry, sp->entry_point, sizeof in.entry);
        memcpy(in.bounds, r->bounds, sizeof in.bounds);
        in.has_cut_normal = sp->camera.has_cut_normal;
        memcpy(in.cut_normal, sp->camera.cut_normal, sizeof in.cut_normal);
        in.tet_edges = sp->camera.tet_edges;
        if (r->have_steer) { /* act.steer's predicted arc ahead of the tip */
            in.plan_x = r->steer.plan;
            in.plan_n = r->steer.plan_n;
        }
        in.prior_x = r->prior_plan; /* --plan DIR */
        in.prior_n = r->prior_plan_n;
        ns_run_dosimetry_isodose(r, &in); /* the 100 % and 150 % lines, with dosimetry */
    }
    char l0[160], l1[160], l2[160], l3[160];
    snprintf(l0, sizeof l0, "%s%s", r->sc.name, r->opt.replay ? " (replay)" : "");
    snprintf(l1, sizeof l1, "t %.2f s   depth %.1f mm   axial force %.2f N",
             (double)r->steps * sp->dt, 1e3 * ns_run_depth(r), r->last_axial);
    if (near_i >= 0)
        snprintf(l2, sizeof l2, "nearest target %s: %.1f mm", sp->targets[near_i].name, near);
    else
        snprintf(l2, sizeof l2, "no targets");
    snprintf(l3, sizeof l3, "score so far %.1f / 100   seeds %d of %d", res->total, r->seed_n,
             sp->seed_count);
    const char *hud[4] = {l0, l1, l2, l3};
    if (rc == 0 && !caption) { /* the authored video's caption and camera (run_video.h) */
        double t = (double)r->steps * sp->dt;
        memcpy(r->rr.frame_views, r->rr.o.views, sizeof r->rr.frame_views);
        r->rr.frame_nviews = r->rr.o.nviews;
        ns_run_video_camera(&r->cues, t, ns_run_tip(r), &in, r->rr.frame_views,
                            &r->rr.frame_nviews);
        r->rr.caption = ns_run_video_caption(&r->cues, t);
    }
    if (rc == 0)
        rc = caption ? ns_run_render_moment(&r->rr, &in, hud, 4, caption, final, err, err_sz)
                     : ns_run_render_frame(&r->rr, &in, hud, 4, err, err_sz);
    free(buf);
    free(hit);
    if (!res_in)
        ns_run_results_free(&own);
    return rc;
}

/* After a step: the key moments (entry, a seed released, the tip reaching a target, a
 * puncture: the axial force falling by 40 % from its peak while the tip cuts on) and the
 * frame. */
int ns_run_render_after_step(NsRun *r, const NsCouplingStats *st, bool dropped, char *err,
                             int err_sz)
{
    const NsRunSpec *sp = &r->spec;
    double t = (double)r->steps * sp->dt;
    char cap[96];
    if (st->cutting && !r->entered) {
        r->entered = true;
        snprintf(cap, sizeof cap, "entry, t = %.2f s", t);
        if (ns_run_render_now(r, cap, false, NULL, err, err_sz))
            return -1;
    }
    if (dropped) {
        snprintf(cap, sizeof cap, "seed %d released, t = %.2f s", r->seed_n, t);
        if (ns_run_render_now(r, cap, false, NULL, err, err_sz))
            return -1;
    }
    for (int i = 0; i < sp->target_count; i++) {
        if (r->reached[i])
            continue;
        double x[3];
        int h = r->target_hint[i];
        if (ns_run_world_of(&r->tissue.mesh, sp->targets[i].at, &h, x) == 0 &&
            ns_run_dist_mm(ns_run_tip(r), x) <= 1e3 * sp->targets[i].tolerance) {
            r->reached[i] = true;
            snprintf(cap, sizeof cap, "tip reaches %s, t = %.2f s", sp->targets[i].name, t);
            if (ns_run_render_now(r, cap, false, NULL, err, err_sz))
                return -1;
        }
    }
    /* a puncture: the tip cut on, through the membrane, with much less force */
    double f = fabs(st->axial_force);
    if (r->punctures < 3 && st->cutting && r->peak_axial > 0.05 && f < 0.6 * r->peak_axial) {
        snprintf(cap, sizeof cap, "puncture: axial force %.2f -> %.2f N, t = %.2f s", r->peak_axial,
                 f, t);
        r->punctures++;
        r->peak_axial = f;
        if (ns_run_debrief_mark(r, NS_MARK_PUNCTURE) ||
            ns_run_render_now(r, cap, false, NULL, err, err_sz))
            return -1;
    }
    /* the debrief's moments (run_debrief.c): the base starting to turn (the first three times),
     * an obstacle entered (the first time), the tip stopped by bone */
    if (r->debrief.began && r->debrief.twists <= 3) {
        snprintf(cap, sizeof cap, "the base turns (%d), t = %.2f s", r->debrief.twists, t);
        if (ns_run_render_now(r, cap, false, NULL, err, err_sz))
            return -1;
    }
    for (int k = 0; k < sp->obstacle_count; k++)
        if (r->obst[k].inside && r->obst[k].steps_inside == 1) {
            snprintf(cap, sizeof cap, "enters %.40s, t = %.2f s", sp->obstacles[k].name, t);
            if (ns_run_render_now(r, cap, false, NULL, err, err_sz))
                return -1;
        }
    const struct Event *ev = r->event_n ? &r->events[r->event_n - 1] : NULL;
    if (ev && ev->type == EVENT_BONE_CONTACT && ev->t == t) {
        snprintf(cap, sizeof cap, "bone contact (%.40s), t = %.2f s", ns_run_event_region(r, ev),
                 t);
        if (ns_run_render_now(r, cap, false, NULL, err, err_sz))
            return -1;
    }
    r->peak_axial = st->cutting ? fmax(r->peak_axial, f) : 0.0;
    bool frames = r->opt.frames || r->opt.video;
    double slow = ns_run_video_slow(&r->cues, t);
    if (frames && slow > 1.0) { /* slow motion: factor / every frames a step (run_video.h) */
        r->cues.owed += slow / r->every;
        long k = (long)r->cues.owed;
        r->cues.owed -= (double)k;
        if (k > 0 && (ns_run_render_now(r, NULL, false, NULL, err, err_sz) ||
                      ns_run_render_repeat(&r->rr, k - 1, err, err_sz)))
            return -1;
        return 0;
    }
    r->cues.owed = 0.0;
    if (frames && r->steps % r->every == 0 && ns_run_render_now(r, NULL, false, NULL, err, err_sz))
        return -1;
    return 0;
}

/* The run's end: its last frame, the end moment and the contact sheet with the score table. */
int ns_run_render_end(NsRun *r, const NsRunResults *res, char *err, int err_sz)
{
    const NsRunSpec *sp = &r->spec;
    bool frames = r->opt.frames || r->opt.video;
    if (frames && r->steps % r->every != 0 && ns_run_render_now(r, NULL, false, res, err, err_sz))
        return -1;
    char cap[96], missed[64] = "";
    for (int i = 0; i < sp->target_count; i++)
        if (!res->targets[i].hit)
            snprintf(missed + strlen(missed), sizeof missed - strlen(missed), "%s%s",
                     missed[0] ? ", " : " (missed: ", sp->targets[i].name);
    if (missed[0])
        snprintf(missed + strlen(missed), sizeof missed - strlen(missed), ")");
    snprintf(cap, sizeof cap, "end, t = %.2f s%s", (double)r->steps * sp->dt, missed);
    if (ns_run_render_now(r, cap, true, res, err, err_sz))
        return -1;
    enum { ROWS = 56 };
    char rows[ROWS][128];
    int n = 0;
    if (sp->target_count)
        snprintf(rows[n++], sizeof rows[0], "%-22s %9s %8s %5s %4s", "target", "error mm", "tol mm",
                 "by", "hit");
    for (int i = 0; i < sp->target_count && n < ROWS - 28; i++)
        snprintf(rows[n++], sizeof rows[0], "%-22.22s %9.2f %8.2f %5s %4s", sp->targets[i].name,
                 res->targets[i].error_mm, 1e3 * sp->targets[i].tolerance,
                 res->targets[i].by_seed ? "seed" : "tip", res->targets[i].hit ? "yes" : "no");
    if (sp->seed_count || r->seed_n)
        snprintf(rows[n++], sizeof rows[0], "seeds released %d of %d planned", r->seed_n,
                 sp->seed_count);
    for (int k = 0; k < sp->obstacle_count && n < ROWS - 2; k++)
        if (r->obst[k].violated)
            snprintf(rows[n++], sizeof rows[0], "obstacle %s entered at t = %.2f s, %.1f mm deep",
                     sp->obstacles[k].name, r->obst[k].first_t, 1e3 * r->obst[k].max_depth);
    n += ns_run_dosimetry_rows(r, rows + n, ROWS - 3 - n);
    snprintf(rows[n++], sizeof rows[0],
             "score %.1f / 100 (targets %.1f, obstacles -%.0f); insertions %d", res->total,
             res->target_part, res->obstacle_penalty, r->insertions);
    ns_run_warnings_line(&r->warn, rows[n++], sizeof rows[0]);
    n += ns_run_debrief_rows(r, res, rows + n, ROWS - n);
    const char *table[ROWS];
    for (int i = 0; i < n; i++)
        table[i] = rows[i];
    char title[160];
    snprintf(title, sizeof title, "%s: score %.1f / 100, %ld steps, %.2f s", r->sc.name, res->total,
             r->steps, (double)r->steps * sp->dt);
    /* the charts, one above the other: force against depth, then the DVHs */
    NsImage force = {0}, dose = {0}, both = {0};
    int rc = ns_run_debrief_chart(r, &force, err, err_sz) ||
                     ns_run_dosimetry_chart(r, &dose, err, err_sz)
                 ? -1
                 : 0;
    const NsImage *chart = dose.rgb ? &dose : &force;
    if (rc == 0 && force.rgb && dose.rgb) {
        int w = force.w > dose.w ? force.w : dose.w;
        rc = ns_image_alloc(&both, w, force.h + dose.h, err, err_sz);
        if (rc == 0) {
            static const uint8_t bg[3] = {24, 27, 34};
            ns_image_fill(&both, bg);
            ns_image_blit_scaled(&both, 0, 0, force.w, force.h, &force);
            ns_image_blit_scaled(&both, 0, force.h, dose.w, dose.h, &dose);
            chart = &both;
        }
    }
    if (rc == 0)
        rc = ns_run_render_finish(&r->rr, title, table, n, chart, err, err_sz);
    ns_image_free(&force);
    ns_image_free(&dose);
    ns_image_free(&both);
    return rc;
}
