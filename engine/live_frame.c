/* A live session's frames (live_frame.h): the copy of a step's state, and the frame and state
 * message drawn from it. */
#include "live_frame.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "err.h"
#include "json.h"
#include "rod.h"
#include "series.h"

/* Grows *p to hold n items of size sz (capacity in *cap, in items). */
static int reserve(void **p, int *cap, int n, size_t sz)
{
    if (n <= *cap && *p)
        return 0;
    int c = n + n / 2 + 16;
    void *q = realloc(*p, (size_t)c * sz);
    if (!q)
        return -1;
    *p = q;
    *cap = c;
    return 0;
}

/* The tissue: world positions every step; the tets and the nodes' material points (the trus
 * view's speckle) when the topology changed. */
static int take_mesh(NsLiveSnap *s, const NsMesh *M)
{
    NsMesh *m = &s->mesh;
    int nc = s->node_cap, nu = s->node_cap;
    if (reserve((void **)&m->x, &nc, M->node_slots, 3 * sizeof *m->x) ||
        reserve((void **)&m->u, &nu, M->node_slots, 3 * sizeof *m->u))
        return -1;
    s->node_cap = nc < nu ? nc : nu;
    memcpy(m->x, M->x, (size_t)M->node_slots * 3 * sizeof *m->x);
    m->node_slots = M->node_slots;
    if (m->tet_node && s->topology == M->topology_version && m->tet_slots == M->tet_slots)
        return 0;
    int tc = s->tet_cap, tc2 = s->tet_cap, tc3 = s->tet_cap;
    if (reserve((void **)&m->tet_node, &tc, M->tet_slots, 4 * sizeof(int)) ||
        reserve((void **)&m->tet_adj, &tc2, M->tet_slots, 4 * sizeof(int)) ||
        reserve((void **)&m->tet_region, &tc3, M->tet_slots, sizeof(int)))
        return -1;
    s->tet_cap = tc < tc2 ? (tc < tc3 ? tc : tc3) : (tc2 < tc3 ? tc2 : tc3);
    memcpy(m->tet_node, M->tet_node, (size_t)M->tet_slots * 4 * sizeof(int));
    memcpy(m->tet_adj, M->tet_adj, (size_t)M->tet_slots * 4 * sizeof(int));
    memcpy(m->tet_region, M->tet_region, (size_t)M->tet_slots * sizeof(int));
    memcpy(m->u, M->u, (size_t)M->node_slots * 3 * sizeof *m->u);
    m->tet_slots = M->tet_slots;
    s->topology = M->topology_version;
    return 0;
}

static void add_event(NsLiveSnap *s, double t, const char *type)
{
    if (s->event_n == NS_LIVE_EVENTS) {
        memmove(s->events, s->events + 1, (NS_LIVE_EVENTS - 1) * sizeof s->events[0]);
        s->event_n--;
    }
    s->events[s->event_n++] = (NsLiveEvent){t, type};
}

/* The run's events (bone contact, tip exit) and the session's, merged by time, the latest. */
static void take_events(NsLiveSnap *s, const NsRun *r, const NsLiveEvent *ev, int ev_n)
{
    s->event_n = 0;
    int i = r->event_n > NS_LIVE_EVENTS ? r->event_n - NS_LIVE_EVENTS : 0, k = 0;
    while (i < r->event_n || k < ev_n) {
        bool run = k == ev_n || (i < r->event_n && r->events[i].t <= ev[k].t);
        if (run) {
            add_event(s, r->events[i].t, ns_run_event_names[r->events[i].type]);
            i++;
        } else {
            add_event(s, ev[k].t, ev[k].type);
            k++;
        }
    }
}

int ns_live_snap_take(NsLiveSnap *s, NsRun *r, const NsLiveEvent *events, int event_n)
{
    const NsRunSpec *sp = &r->spec;
    if (take_mesh(s, &r->tissue.mesh))
        return -1;
    int n = r->rod.nodes, rc = s->rod_cap, rc2 = s->rod_cap;
    if (reserve((void **)&s->rod_x, &rc, n, 3 * sizeof *s->rod_x) ||
        reserve((void **)&s->state, &rc2, n, 1))
        return -1;
    s->rod_cap = rc < rc2 ? rc : rc2;
    memcpy(s->rod_x, r->rod.x, (size_t)n * 3 * sizeof *s->rod_x);
    memcpy(s->state, r->c.state, (size_t)n);
    s->rod_nodes = n;
    s->cutting = r->last_cutting != 0;
    s->bevel = sp->bevel;
    if (sp->bevel) {
        double t[3], m1[3];
        ns_rod_tip_frame(&r->rod, t, m1, s->m2);
    }
    s->held = r->rod.held;
    NsRunResults res;
    if (ns_run_score_peek(r, &res)) {
        ns_run_results_free(&res);
        return -1;
    }
    int nt = sp->target_count, ns = r->seed_n, nm = sp->marker_count, sc = s->seed_cap;
    if (!s->target_x) {
        s->target_x = calloc((size_t)nt * 3 + 1, sizeof *s->target_x);
        s->target_r = calloc((size_t)nt + 1, sizeof *s->target_r);
        s->target_err = calloc((size_t)nt + 1, sizeof *s->target_err);
        s->target_hit = calloc((size_t)nt + 1, sizeof *s->target_hit);
        s->marker_x = calloc((size_t)nm * 3 + 1, sizeof *s->marker_x);
    }
    if (!s->target_x || !s->target_r || !s->target_err || !s->target_hit || !s->marker_x ||
        reserve((void **)&s->seed_x, &sc, ns, 3 * sizeof *s->seed_x)) {
        ns_run_results_free(&res);
        return -1;
    }
    s->seed_cap = sc;
    for (int i = 0; i < nt; i++) {
        memcpy(s->target_x + 3 * i, res.targets[i].x, 3 * sizeof(double));
        s->target_r[i] = sp->targets[i].tolerance;
        s->target_err[i] = res.targets[i].error_mm;
        s->target_hit[i] = res.targets[i].hit;
    }
    for (int k = 0; k < ns; k++)
        memcpy(s->seed_x + 3 * k, res.seeds[k].x, 3 * sizeof(double));
    for (int k = 0; k < nm; k++)
        memcpy(s->marker_x + 3 * k, res.markers[k], 3 * sizeof(double));
    s->targets = nt;
    s->seeds = ns;
    s->markers = nm;
    s->score = res.total;
    ns_run_results_free(&res);
    memcpy(s->axis, sp->entry_dir, sizeof s->axis);
    memcpy(s->entry, sp->entry_point, sizeof s->entry);
    s->step = r->steps;
    s->t = (double)r->steps * sp->dt;
    s->depth = ns_run_depth(r);
    memcpy(s->tip, ns_run_tip(r), sizeof s->tip);
    s->axial = r->last_axial;
    memcpy(s->fr, r->last_fr, sizeof s->fr);
    s->needles = r->needles;
    s->seeds_planned = sp->seed_count;
    s->scripted = r->live_scripted;
    take_events(s, r, events, event_n);
    return 0;
}

void ns_live_snap_free(NsLiveSnap *s)
{
    free(s->mesh.x);
    free(s->mesh.u);
    free(s->mesh.tet_node);
    free(s->mesh.tet_adj);
    free(s->mesh.tet_region);
    free(s->rod_x);
    free(s->state);
    free(s->target_x);
    free(s->target_r);
    free(s->target_err);
    free(s->target_hit);
    free(s->seed_x);
    free(s->marker_x);
    memset(s, 0, sizeof *s);
}

/* ---- the render thread ---- */

int ns_live_render_open(NsLiveRender *lr, const NsRun *r, int w, int h, int samples, int quality,
                        char *err, int err_sz)
{
    memset(lr, 0, sizeof *lr);
    lr->run = r;
    lr->quality = quality;
    if (ns_frame_open_samples(&lr->frame, w, h, samples, err, err_sz))
        return -1;
    lr->open = true;
    return 0;
}

void ns_live_state_json(FILE *f, const NsRun *r, const NsLiveSnap *s, double fps)
{
    NsJson j;
    ns_json_init(&j, f, 0);
    ns_json_begin_object(&j);
    ns_json_key(&j, "t_s");
    ns_json_number(&j, s->t);
    ns_json_key(&j, "step");
    ns_json_int(&j, s->step);
    ns_json_key(&j, "depth_m");
    ns_json_number(&j, s->depth);
    ns_run_json_vec(&j, "tip_m", s->tip);
    ns_json_key(&j, "axial_force_n");
    ns_json_number(&j, s->axial);
    ns_json_key(&j, "rtf");
    ns_json_number(&j, s->rtf);
    ns_json_key(&j, "fps");
    ns_json_number(&j, fps);
    ns_json_key(&j, "score");
    ns_json_number(&j, s->score);
    ns_json_key(&j, "targets");
    ns_json_begin_array(&j);
    for (int i = 0; i < s->targets; i++) {
        ns_json_begin_object(&j);
        ns_json_key(&j, "name");
        ns_json_string(&j, r->spec.targets[i].name);
        ns_json_key(&j, "error_mm");
        ns_json_number(&j, s->target_err[i]);
        ns_json_key(&j, "hit");
        ns_json_bool(&j, s->target_hit[i]);
        ns_json_end_object(&j);
    }
    ns_json_end_array(&j);
    ns_json_key(&j, "events");
    ns_json_begin_array(&j);
    for (int i = 0; i < s->event_n; i++) {
        ns_json_begin_object(&j);
        ns_json_key(&j, "t_s");
        ns_json_number(&j, s->events[i].t);
        ns_json_key(&j, "type");
        ns_json_string(&j, s->events[i].type);
        ns_json_end_object(&j);
    }
    ns_json_end_array(&j);
    ns_json_key(&j, "friction");
    ns_json_begin_object(&j);
    static const char *const fr[3] = {"sticking", "sliding_in", "sliding_out"};
    for (int k = 0; k < 3; k++) {
        ns_json_key(&j, fr[k]);
        ns_json_int(&j, s->fr[k]);
    }
    ns_json_key(&j, "cutting");
    ns_json_bool(&j, s->cutting);
    ns_json_end_object(&j);
    ns_json_key(&j, "seeds");
    ns_json_int(&j, s->seeds);
    ns_json_key(&j, "seeds_planned");
    ns_json_int(&j, s->seeds_planned);
    ns_json_key(&j, "needles");
    ns_json_int(&j, s->needles);
    ns_json_key(&j, "paused");
    ns_json_bool(&j, s->paused);
    ns_json_key(&j, "scripted");
    ns_json_bool(&j, s->scripted);
    ns_json_key(&j, "ended");
    ns_json_bool(&j, s->ended);
    ns_json_end_object(&j);
}

int ns_live_render_draw(NsLiveRender *lr, const NsLiveSnap *s, double fps, double *render_ms,
                        double *encode_ms, char *err, int err_sz)
{
    const NsRun *r = lr->run;
    const NsRunSpec *sp = &r->spec;
    NsSceneInput in;
    memset(&in, 0, sizeof in);
    in.mesh = &s->mesh;
    in.obstacle_region = r->obstacle_region;
    in.regions = r->sc.region_count;
    in.rod_x = s->rod_x;
    in.rod_nodes = s->rod_nodes;
    in.rod_radius = 0.5 * sp->diameter;
    in.state = sp->camera.friction_colours ? s->state : NULL;
    in.cutting = s->cutting;
    in.bevel = s->bevel;
    memcpy(in.m2, s->m2, sizeof in.m2);
    in.held = s->held;
    in.target_x = s->target_x;
    in.target_r = s->target_r;
    in.target_hit = s->target_hit;
    in.targets = s->targets;
    in.seed_x = s->seed_x;
    in.seeds = s->seeds;
    in.marker_x = s->marker_x;
    in.markers = s->markers;
    memcpy(in.axis, s->axis, sizeof in.axis);
    memcpy(in.entry, s->entry, sizeof in.entry);
    memcpy(in.bounds, r->bounds, sizeof in.bounds);
    in.has_cut_normal = sp->camera.has_cut_normal;
    memcpy(in.cut_normal, sp->camera.cut_normal, sizeof in.cut_normal);
    in.tet_edges = sp->camera.tet_edges;
    /* the 100 % and 150 % isodose lines of the seeds placed so far, with dosimetry (the
     * callback reads only what the run set up before the session: the render thread may) */
    ns_run_dosimetry_isodose(r, &in);
    int near_i = -1;
    double near = INFINITY;
    for (int i = 0; i < s->targets; i++) {
        double d = ns_run_dist_mm(s->tip, s->target_x + 3 * i);
        if (d < near) {
            near = d;
            near_i = i;
        }
    }
    char l0[160], l1[160], l2[160], l3[160];
    snprintf(l0, sizeof l0, "%s (live)%s%s", r->sc.name, s->paused ? "   PAUSED" : "",
             s->scripted ? "   scripted set-up" : "");
    snprintf(l1, sizeof l1, "t %.2f s   depth %.1f mm   axial force %.2f N", s->t, 1e3 * s->depth,
             s->axial);
    if (near_i >= 0)
        snprintf(l2, sizeof l2, "nearest target %s: %.1f mm", sp->targets[near_i].name, near);
    else
        snprintf(l2, sizeof l2, "no targets");
    snprintf(l3, sizeof l3, "score so far %.1f / 100   seeds %d of %d   rtf %.2f   %.0f fps",
             s->score, s->seeds, s->seeds_planned, s->rtf, fps);
    const char *hud[4] = {l0, l1, l2, l3};
    double t0 = ns_wall_s();
    const int *views = lr->nviews > 0 ? lr->views : sp->camera.views;
    int nviews = lr->nviews > 0 ? lr->nviews : sp->camera.view_count;
    if (ns_frame_render(&lr->frame, &in, views, nviews, hud, 4, sp->camera.friction_colours,
                        &lr->image, err, err_sz))
        return -1;
    double t1 = ns_wall_s();
    if (ns_jpeg_encode(&lr->image, lr->quality, &lr->jpeg, err, err_sz))
        return -1;
    *render_ms = 1e3 * (t1 - t0);
    *encode_ms = 1e3 * (ns_wall_s() - t1);
    free(lr->json); /* open_memstream makes a new buffer */
    lr->json = NULL;
    FILE *f = open_memstream(&lr->json, &lr->json_n);
    if (!f) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    ns_live_state_json(f, r, s, fps);
    if (fclose(f) != 0) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    return 0;
}

void ns_live_render_close(NsLiveRender *lr)
{
    if (lr->open)
        ns_frame_close(&lr->frame);
    ns_image_free(&lr->image);
    ns_jpeg_buf_free(&lr->jpeg);
    free(lr->json);
    memset(lr, 0, sizeof *lr);
}
