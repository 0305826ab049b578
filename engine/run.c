/* The run (run.h): the tissue and needle built, the loop that ticks them, seeds, obstacles and
 * the events at the tip. */
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
#include "step.h"

const char *const ns_run_event_names[3] = {"bone_contact", "tip_exit", "needle_reentry"};

/* Records what the step's statistics say happened at the tip (a bone contact's first step, an
 * exit through the surface, a withdrawn needle's re-entry), at the step's end time. Returns 0,
 * or -1 (memory). */
int ns_run_record_events(NsRun *r, const NsCouplingStats *st, double t, const double tip[3])
{
    for (int type = 0; type < 3; type++) {
        int happened = type == EVENT_BONE_CONTACT ? st->bone_contact == 1
                       : type == EVENT_TIP_EXIT   ? st->tip_exit
                                                  : st->reentered;
        if (!happened)
            continue;
        if (r->event_n == r->event_cap) {
            int cap = r->event_cap ? 2 * r->event_cap : 8;
            struct Event *e = realloc(r->events, (size_t)cap * sizeof *e);
            if (!e)
                return -1;
            r->events = e;
            r->event_cap = cap;
        }
        struct Event *e = &r->events[r->event_n++];
        e->t = t;
        e->type = type;
        e->region = type == EVENT_BONE_CONTACT ? st->bone_region : -1;
        memcpy(e->x, tip, sizeof e->x);
    }
    return 0;
}

const char *ns_run_event_region(const NsRun *r, const struct Event *e)
{
    return e->region >= 0 && e->region < r->sc.region_count ? r->sc.regions[e->region].name : "";
}

const double *ns_run_tip(const NsRun *r)
{
    return r->rod.x + 3 * (r->rod.nodes - 1);
}

double ns_run_depth(const NsRun *r)
{
    const double *t = ns_run_tip(r), *p = r->spec.entry_point;
    double d[3] = {t[0] - p[0], t[1] - p[1], t[2] - p[2]};
    return ns_run_dot3(d, r->spec.entry_dir);
}

/* The world position of the material point u (a target) in the deformed tissue; the tet found
 * is kept as the next search's start. */
int ns_run_world_of(const NsMesh *m, const double u[3], int *hint, double x[3])
{
    double b[4];
    int t = ns_mesh_locate(m, u, *hint, 1e-9, b);
    if (t < 0)
        return -1;
    *hint = t;
    const int *tn = m->tet_node + 4 * t;
    for (int i = 0; i < 3; i++)
        x[i] = b[0] * m->x[3 * tn[0] + i] + b[1] * m->x[3 * tn[1] + i] +
               b[2] * m->x[3 * tn[2] + i] + b[3] * m->x[3 * tn[3] + i];
    return 0;
}

/* The needle at the current entry (spec.entry_*): skin entry (sim/remesh_entry.c: the entry
 * node made on the surface at the entry point, the tip node a tenth of an element inside it,
 * both on the coupling's undo stack), the tissue synced, the rod and the coupling made, and the
 * nodes moved recorded so that they go back when the needle leaves. `what` names the caller
 * for messages. */
int ns_run_place_needle(NsRun *r, const char *what, char *err, int err_sz)
{
    NsScenario *sc = &r->sc;
    NsRunSpec *sp = &r->spec;
    NsMesh *M = &r->tissue.mesh;
    double h = sc->resolution > 0.0 ? sc->resolution : ns_mesh_mean_edge(&r->orig);
    int nodes[2], np = 2;
    char e2[512];
    NsRemeshStack entry;
    ns_remesh_stack_init(&entry);
    if (ns_remesh_skin_entry(M, &entry, sp->entry_point, sp->entry_dir, 0.1 * h, nodes, e2,
                             sizeof e2)) {
        ns_remesh_stack_free(&entry);
        ns_set_err(err, err_sz,
                   "%s: the needle cannot enter at (%g, %g, %g) m along (%g, %g, %g): %s", what,
                   sp->entry_point[0], sp->entry_point[1], sp->entry_point[2], sp->entry_dir[0],
                   sp->entry_dir[1], sp->entry_dir[2], e2);
        return -1;
    }
    if (ns_tissue_sync_topology(&r->tissue, err, err_sz)) {
        ns_remesh_stack_free(&entry);
        return -1;
    }
    /* The needle: four nodes 5 mm apart outside, behind the entry node, then the track. */
    double x[3 * 68], d[3];
    memcpy(d, sp->entry_dir, sizeof d);
    const double *e0 = M->x + 3 * nodes[0];
    for (int i = 0; i < 4; i++)
        for (int k = 0; k < 3; k++)
            x[3 * i + k] = e0[k] - 0.005 * (4 - i) * d[k];
    for (int i = 0; i < np; i++)
        memcpy(x + 3 * (4 + i), M->x + 3 * nodes[i], 3 * sizeof *x);
    NsRodParams rp = ns_default_rod_params();
    rp.gamma = r->tissue.params.gamma;
    rp.beta = r->tissue.params.beta;
    rp.material.youngs = sp->youngs;
    rp.material.outer_diameter = sp->diameter;
    rp.material.inner_diameter = sp->inner_diameter;
    rp.material.density = sp->density;
    if (sp->bevel) {
        rp.tip = NS_TIP_BEVEL;
        rp.bevel_angle = sp->bevel_deg * M_PI / 180.0;
    }
    /* The material frame's d1: the axis least aligned with the needle, made normal to it; or,
     * with entry.bevel_toward b, d1 = b x t, so that m2 = t x d1 = b is where the bevel
     * steers (sim/rod.h: m2 = t x m1). */
    int ax = fabs(d[0]) <= fabs(d[1]) && fabs(d[0]) <= fabs(d[2]) ? 0
             : fabs(d[1]) <= fabs(d[2])                           ? 1
                                                                  : 2;
    double d1[3] = {0.0, 0.0, 0.0};
    d1[ax] = 1.0;
    double dd = ns_run_dot3(d1, d);
    for (int k = 0; k < 3; k++)
        d1[k] -= dd * d[k];
    if (sp->has_bevel_toward) {
        const double *bt = sp->bevel_toward;
        d1[0] = bt[1] * d[2] - bt[2] * d[1];
        d1[1] = bt[2] * d[0] - bt[0] * d[2];
        d1[2] = bt[0] * d[1] - bt[1] * d[0];
    }
    double n1 = sqrt(ns_run_dot3(d1, d1));
    for (int k = 0; k < 3; k++)
        d1[k] /= n1;
    if (ns_rod_init(&r->rod, x, 4 + np, d1, 2, &rp, err, err_sz)) {
        ns_remesh_stack_free(&entry);
        return -1;
    }
    r->have_rod = true;
    NsCouplingParams cp = ns_default_coupling_params();
    cp.remesh = 1;
    cp.solver = (NsCoupledSolverKind)r->opt.solver;
    cp.threads = r->opt.threads;
    if (sp->tolerance > 0.0) /* the scenario's solver = {...} */
        cp.tau_sol = sp->tolerance;
    if (sp->check_tolerance > 0.0)
        cp.tau_check = sp->check_tolerance;
    cp.tip_block = sp->tip_block;
    if (cp.tau_check < cp.tau_sol) /* never below (ns.scenario refuses an explicit one) */
        cp.tau_check = cp.tau_sol;
    for (int k = 0; k < sc->region_count; k++)
        cp.cut_force[k] = sc->regions[k].material.cut_force;
    cp.twist_friction = sp->twist_friction;      /* needle.twist_friction */
    cp.bevel_model = (NsBevelModel)sp->steering; /* needle.steering */
    if (sp->steering == NS_BEVEL_ARC)
        for (int k = 0; k < NS_COUPLING_MAX_REGIONS; k++)
            cp.bevel_curvature[k] = sp->arc_curvature;
    if (sp->steering == NS_BEVEL_FORCE) /* needle.bevel_force */
        for (int k = 0; k < NS_COUPLING_MAX_REGIONS; k++)
            cp.bevel_force[k] = sp->bevel_force;
    /* One friction per unit length for the whole needle: that of the region at the entry. */
    int t0 = M->node_tets[nodes[0]].items[0];
    cp.f_perlen = sc->regions[M->tet_region[t0]].material.friction;
    double s = 0.0;
    for (int i = 1; i < np; i++) {
        const double *p0 = M->u + 3 * nodes[i - 1], *p1 = M->u + 3 * nodes[i];
        double e[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]};
        s += sqrt(ns_run_dot3(e, e));
    }
    NsNeedlePath path;
    if (ns_needle_path_init(&path, M, nodes, np, s, err, err_sz) ||
        ns_coupled_init(&r->c, &r->tissue, &r->rod, &path, &cp, err, err_sz)) {
        ns_remesh_stack_free(&entry);
        return -1;
    }
    r->have_c = true;
    /* The skin entry's splits and snap are the first entries of the needle's undo stack. */
    ns_remesh_stack_free(&r->c.remesh);
    r->c.remesh = entry;
    const NsMesh *O = &r->orig;
    for (int i = 0; i < O->node_slots; i++)
        if (ns_mesh_node_alive(O, i) && memcmp(O->u + 3 * i, M->u + 3 * i, 24) != 0 &&
            ns_remesh_record_original(&r->c.remesh, i, O->u + 3 * i)) {
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
    r->exited = 0;
    return 0;
}

/* The tissue (its mesh kept as the original, which every needle's exit restores), the first
 * needle, and the look-up hints. */
int ns_run_build(NsRun *r, char *err, int err_sz)
{
    NsScenario *sc = &r->sc;
    NsRunSpec *sp = &r->spec;
    if (sc->region_count > NS_COUPLING_MAX_REGIONS) {
        ns_set_err(err, err_sz, "%s: the tissue has %d regions; the coupling takes at most %d",
                   sc->tissue_where, sc->region_count, NS_COUPLING_MAX_REGIONS);
        return -1;
    }
    if (ns_mesh_copy(&r->orig, &sc->mesh)) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    r->have_orig = true;
    NsTissueParams tp = ns_default_tissue_params();
    tp.gamma = 0.55; /* slightly dissipative Newmark, as the validation's coupled cases */
    tp.beta = 0.25 * 1.05 * 1.05;
    tp.threads = r->opt.threads;
    if (sp->lazy_threshold >= 0.0)
        tp.lazy_threshold = sp->lazy_threshold;
    if (ns_scenario_tissue(sc, &tp, &r->tissue, err, err_sz))
        return -1;
    r->have_tissue = true;
    /* The mesh as built: the first state min_dihedral_deg_any_step covers. */
    if (ns_dihedral_watch_init(&r->dw, &r->tissue.mesh)) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    r->have_dw = true;
    char what[600];
    snprintf(what, sizeof what, "%s: ns.scenario: entry", sc->where);
    if (ns_run_place_needle(r, what, err, err_sz))
        return -1;
    r->target_hint = malloc((size_t)(sp->target_count + 1) * sizeof *r->target_hint);
    r->marker_hint = malloc((size_t)(sp->marker_count + 1) * sizeof *r->marker_hint);
    r->obst = calloc((size_t)sp->obstacle_count + 1, sizeof *r->obst);
    r->tip_hint = -1;
    for (int i = 0; r->marker_hint && i < sp->marker_count; i++)
        r->marker_hint[i] = -1;
    if (!r->target_hint || !r->marker_hint || !r->obst) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    for (int i = 0; i < sp->target_count; i++)
        r->target_hint[i] = -1;
    return ns_run_dosimetry_begin(r, err, err_sz);
}

/* act.next_needle: the needle, out of the tissue, is replaced by a new one at another entry
 * (the next hole of a brachytherapy template). The tissue keeps its state; its mesh is the
 * original one again since the last needle left (Algorithm 2's undo stack). */
int ns_run_next_needle(NsRun *r, const NsEntry *e, double t, char *err, int err_sz)
{
    if (!r->c.outside) {
        ns_set_err(err, err_sz,
                   "%s: act.next_needle at t = %.3f s: the needle is still in the tissue (retract "
                   "it all the way first)",
                   r->sc.path, t);
        return -1;
    }
    ns_coupled_free(&r->c);
    r->have_c = false;
    ns_rod_free(&r->rod);
    r->have_rod = false;
    memcpy(r->spec.entry_point, e->point, sizeof e->point);
    memcpy(r->spec.entry_dir, e->direction, sizeof e->direction);
    r->spec.has_bevel_toward = e->has_bevel_toward;
    memcpy(r->spec.bevel_toward, e->bevel_toward, sizeof e->bevel_toward);
    char what[600];
    snprintf(what, sizeof what, "%s: act.next_needle at t = %.3f s", r->sc.path, t);
    if (ns_run_place_needle(r, what, err, err_sz))
        return -1;
    r->needles++;
    memcpy(r->last_tip, ns_run_tip(r), sizeof r->last_tip);
    return 0;
}

/* ---- seeds and obstacles ---- */

/* Inverted tets beside the world point p (sharing a node with the tet p lies in, whose nodes
 * a reading at p interpolates; run_warnings.h), found from the world positions' signed
 * volumes. 0 outside the tissue, and at once when the latest step inverted none. */
static int inverted_beside(NsRun *r, const double p[3], int *hint)
{
    if (r->warn.last[NS_WARN_INVERTED] == 0)
        return 0;
    const NsMesh *M = &r->tissue.mesh;
    int tet = ns_mesh_locate_in(M, M->x, p, *hint, 1e-6, NULL);
    if (tet < 0)
        return 0;
    *hint = tet;
    enum { SEEN = 512 };
    int seen[SEEN], ns = 0, n = 0;
    for (int a = 0; a < 4; a++) {
        const NsIntList *l = &M->node_tets[M->tet_node[4 * tet + a]];
        for (int i = 0; i < l->count; i++) {
            int e = l->items[i], dup = 0;
            for (int j = 0; j < ns && !dup; j++)
                dup = seen[j] == e;
            if (dup)
                continue;
            if (ns < SEEN)
                seen[ns++] = e;
            const int *tn = M->tet_node + 4 * e;
            n += ns_tet_volume(M->x + 3 * tn[0], M->x + 3 * tn[1], M->x + 3 * tn[2],
                               M->x + 3 * tn[3]) <= 0.0;
        }
    }
    return n;
}

/* The final state's readings (run_warnings.h): the tip, the targets, the seeds. */
static void read_final(NsRun *r)
{
    const NsRunSpec *sp = &r->spec;
    const NsMesh *M = &r->tissue.mesh;
    int h = r->tip_hint;
    int n = inverted_beside(r, ns_run_tip(r), &h);
    for (int i = 0; i < sp->target_count; i++) {
        double x[3];
        int th = r->target_hint[i];
        if (ns_run_world_of(M, sp->targets[i].at, &th, x) == 0)
            n += inverted_beside(r, x, &th);
    }
    for (int k = 0; k < r->seed_n; k++) {
        double x[3];
        int sh = r->seeds[k].hint;
        if (ns_run_world_of(M, r->seeds[k].u, &sh, x) == 0)
            n += inverted_beside(r, x, &sh);
    }
    ns_run_warnings_read(&r->warn, n);
}

/* Releases a seed at the needle tip: the tissue's material point there, which the tissue then
 * carries (a seed is far smaller than an element and is not modelled as a body). The i-th
 * seed released takes the seed plan's i-th target; beyond the plan, the nearest target at the
 * end. */
int ns_run_release_seed(NsRun *r, double t, char *err, int err_sz)
{
    if (r->spec.target_count == 0) {
        ns_set_err(err, err_sz,
                   "%s: act.drop_seed at t = %.3f s: the scenario has no targets "
                   "for seeds",
                   r->sc.path, t);
        return -1;
    }
    const NsMesh *M = &r->tissue.mesh;
    double b[4];
    int tet = ns_mesh_locate_in(M, M->x, ns_run_tip(r), r->tip_hint, 1e-6, b);
    if (tet < 0) {
        ns_set_err(err, err_sz,
                   "%s: act.drop_seed at t = %.3f s: the needle tip is not in the "
                   "tissue",
                   r->sc.path, t);
        return -1;
    }
    r->tip_hint = tet;
    int h = tet;
    ns_run_warnings_read(&r->warn, inverted_beside(r, ns_run_tip(r), &h)); /* its material point */
    if (r->seed_n == r->seed_cap) {
        int cap = r->seed_cap ? 2 * r->seed_cap : 16;
        struct Seed *sd = realloc(r->seeds, (size_t)cap * sizeof *sd);
        if (!sd) {
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
        r->seeds = sd;
        r->seed_cap = cap;
    }
    struct Seed *sd = &r->seeds[r->seed_n];
    const int *tn = M->tet_node + 4 * tet;
    for (int i = 0; i < 3; i++)
        sd->u[i] = b[0] * M->u[3 * tn[0] + i] + b[1] * M->u[3 * tn[1] + i] +
                   b[2] * M->u[3 * tn[2] + i] + b[3] * M->u[3 * tn[3] + i];
    sd->t = t;
    sd->target = r->seed_n < r->spec.seed_count ? r->spec.seed_target[r->seed_n] : -1;
    sd->hint = tet;
    r->seed_n++;
    return 0;
}

/* Is the needle inside an obstacle's region? The point 0.1 mm behind the tip along the needle
 * is located in the deformed tissue (the tip itself sits on a mesh node, shared by the regions
 * around it); the depth is how far the tip got from where it went in. */
void ns_run_check_obstacles(NsRun *r, double t, int exited)
{
    if (r->spec.obstacle_count == 0)
        return;
    const NsMesh *M = &r->tissue.mesh;
    const double *x = r->rod.x;
    int n = r->rod.nodes;
    const double *tip = x + 3 * (n - 1), *prev = x + 3 * (n - 2);
    double e[3] = {tip[0] - prev[0], tip[1] - prev[1], tip[2] - prev[2]};
    double le = sqrt(ns_run_dot3(e, e)), p[3];
    for (int i = 0; i < 3; i++)
        p[i] = tip[i] - 1e-4 * e[i] / (le > 0.0 ? le : 1.0);
    int tet = exited ? -1 : ns_mesh_locate_in(M, M->x, p, r->tip_hint, 1e-9, NULL);
    if (tet >= 0)
        r->tip_hint = tet;
    int region = tet >= 0 ? M->tet_region[tet] : -1;
    for (int k = 0; k < r->spec.obstacle_count; k++) {
        struct Obstacle *o = &r->obst[k];
        bool in = region >= 0 && region == r->spec.obstacles[k].region;
        if (in && !o->inside) {
            memcpy(o->entry, tip, sizeof o->entry);
            (void)ns_run_debrief_mark(r, NS_MARK_OBSTACLE); /* (out of memory: a chart mark less) */
            if (!o->violated)
                o->first_t = t;
            o->violated = true;
        }
        o->inside = in;
        if (in) {
            double d[3] = {tip[0] - o->entry[0], tip[1] - o->entry[1], tip[2] - o->entry[2]};
            o->max_depth = fmax(o->max_depth, sqrt(ns_run_dot3(d, d)));
            o->steps_inside++;
        }
    }
}

/* ---- the loop ---- */

static void progress(const NsRun *r, long total, double t)
{
    int width = 30, filled = total > 0 ? (int)(width * r->steps / total) : 0;
    char bar[64];
    for (int i = 0; i < width; i++)
        bar[i] = i < filled ? '#' : total > 0 ? '.' : (i == (int)(r->steps % width) ? '#' : '.');
    bar[width] = '\0';
    fprintf(stderr, "\r[%s] step %ld, t = %.3f s, depth %.1f mm ", bar, r->steps, t,
            1e3 * ns_run_depth(r));
    fflush(stderr);
}

/* The run's length (run.h): --steps, else the scenario's duration, else until the script
 * ends; a script that has not ended after NS_LIMIT_DEFAULT_SIM_TIME of simulated time (act.wait
 * in a loop) is stopped there, and the report says it had not finished. */
static int run_length(NsRun *r, char *err, int err_sz)
{
    const NsRunSpec *sp = &r->spec;
    long max_steps = r->opt.steps > 0 ? r->opt.steps : 0;
    if (max_steps > NS_LIMIT_STEPS) {
        ns_set_err(err, err_sz, "--steps %ld: at most %ld", max_steps, NS_LIMIT_STEPS);
        return -1;
    }
    if (max_steps == 0 && sp->duration > 0.0) {
        double n = ceil(sp->duration / sp->dt - 1e-9);
        if (!(n <= (double)NS_LIMIT_STEPS)) {
            ns_set_err(err, err_sz, "%s: ns.scenario: duration / dt is %.3g steps (at most %ld)",
                       r->sc.where, n, NS_LIMIT_STEPS);
            return -1;
        }
        max_steps = (long)n;
    }
    /* A live session's log (#source live) may end before the duration: its replay ends there. */
    if (r->opt.replay && r->replay.live && (max_steps == 0 || max_steps > r->replay.n))
        max_steps = r->replay.n;
    /* A live session without a duration lasts until the trainee ends it, up to an hour. */
    double cap_s = r->opt.live ? NS_LIMIT_SIM_TIME_MAX : NS_LIMIT_DEFAULT_SIM_TIME;
    double cap_n = ceil(cap_s / sp->dt - 1e-9);
    long time_cap = cap_n < (double)NS_LIMIT_STEPS ? (long)cap_n : NS_LIMIT_STEPS;
    r->max_steps = max_steps;
    r->time_cap = time_cap;
    return 0;
}

int ns_run_begin(NsRun *r, char *err, int err_sz)
{
    if (run_length(r, err, err_sz))
        return -1;
    memcpy(r->last_tip, ns_run_tip(r), sizeof r->last_tip);
    r->tty = !r->opt.quiet && isatty(fileno(stderr));
    r->more = 1;
    r->needles = 1;
    r->live_scripted = r->opt.live && r->spec.live_script && r->spec.has_script;
    r->t0 = ns_wall_s();
    /* (a resumed run's first frame is of the checkpoint's world: ns_run_checkpoint_resume) */
    if (r->rendering && (r->opt.frames || r->opt.video) && !r->opt.resume &&
        ns_run_render_now(r, NULL, false, NULL, err, err_sz))
        return -1;
    return 0;
}

/* The controls of the tick at time t: given, else the replayed log's row, else the script's
 * (and on_tick's). Returns 0, or -1 with a message; r->more says whether the source has more. */
static int tick_controls(NsRun *r, const NsControl *given, double t, NsControl *ctl, char *err,
                         int err_sz)
{
    memset(ctl, 0, sizeof *ctl);
    if (given && r->opt.live) { /* on_tick (and a live.script set-up) run; the session goes on */
        int more = 1;
        int rc = ns_run_script_tick(r, t, r->exited, given, &more, ctl, err, err_sz);
        r->more = 1;
        return rc;
    }
    if (given) {
        *ctl = *given;
        return 0;
    }
    if (r->opt.replay) { /* the log drives the needle instead of the script */
        r->more = r->steps < r->replay.n;
        if (!r->more && r->max_steps > 0) {
            ns_set_err(err, err_sz, "%s: the log ends after %ld steps, before the run's %ld",
                       r->opt.replay, r->replay.n, r->max_steps);
            return -1;
        }
        if (r->more)
            *ctl = r->replay.rows[r->steps];
        return 0;
    }
    return ns_run_script_tick(r, t, r->exited, NULL, &r->more, ctl, err, err_sz);
}

/* Applies the controls and takes one coupled step (paper Algorithm 1, sim/), then the run's
 * bookkeeping: statistics, events, the trajectory, obstacles, pictures. */
static int run_step(NsRun *r, NsControl ctl, double t, char *err, int err_sz)
{
    const NsRunSpec *sp = &r->spec;
    if (r->rec)
        ns_control_log_write_row(r->rec, t, &ctl);
    if (ctl.next_needle && ns_run_next_needle(r, &ctl.entry, t, err, err_sz))
        return -1;
    NsStepControls step_ctl = ns_step_controls(ctl.v_insert, ctl.v_base, ctl.twist_rate);
    if (ctl.drop_seed && ns_run_release_seed(r, t, err, err_sz))
        return -1;
    if (ctl.drop_seed && ns_run_debrief_mark(r, NS_MARK_SEED)) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    if (ctl.v_insert > 0.0 && r->prev_v <= 0.0)
        r->insertions++;
    r->prev_v = ctl.v_insert;
    if (r->rendering && ns_run_render_before_step(r)) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    NsCouplingStats st;
    double w0 = ns_wall_s();
    int rc = ns_step(&r->c, &step_ctl, sp->dt, &st);
    double w = 1e3 * (ns_wall_s() - w0);
    int warned[NS_WARN_KINDS] = {[NS_WARN_NAN] = st.nan_count,
                                 [NS_WARN_INVERTED] = st.inverted,
                                 [NS_WARN_UNCONVERGED] = st.unconverged,
                                 [NS_WARN_LCP] = st.consistent == 0};
    ns_run_warnings_step(&r->warn, warned);
    if (rc) {
        const double *tp = ns_run_tip(r);
        const NsMesh *M = &r->tissue.mesh;
        bool outside = ns_mesh_locate_in(M, M->x, tp, r->tip_hint, 1e-6, NULL) < 0;
        ns_set_err(err, err_sz,
                   "%s: step %ld (t = %.4f s, tip at (%.1f, %.1f, %.1f) mm, depth %.1f mm) "
                   "failed: %s (NaN %d, inverted %d, unconverged %d)",
                   r->sc.path, r->steps, t, 1e3 * tp[0], 1e3 * tp[1], 1e3 * tp[2],
                   1e3 * ns_run_depth(r),
                   r->c.error[0] ? r->c.error
                   : outside     ? "the needle tip left the tissue other than through its "
                                   "entry or out through its surface"
                                 : "the coupled step did not produce a valid state",
                   st.nan_count, st.inverted, st.unconverged);
        return -1;
    }
    r->steps++;
    /* The mesh after the step, with what came before it (a needle's entry or exit). */
    if (r->have_dw && ns_dihedral_watch_look(&r->dw, &r->tissue.mesh)) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    if (ns_run_debrief_step(r, ctl.twist_rate, ns_run_depth(r), st.axial_force)) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    int events = r->event_n;
    if (ns_run_record_events(r, &st, (double)r->steps * sp->dt, ns_run_tip(r))) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    r->exited = st.reentered ? 0 : r->exited | st.exited; /* out, until it enters again */
    r->repaired += st.remesh_repaired;
    r->consistent += st.consistent != 0;
    r->max_axial = fmax(r->max_axial, fabs(st.axial_force));
    r->last_axial = st.axial_force;
    r->last_fr[0] = st.n_static;
    r->last_fr[1] = st.n_dyn_pos;
    r->last_fr[2] = st.n_dyn_neg;
    r->last_cutting = st.cutting;
    const double *tp = ns_run_tip(r);
    if (st.cutting) { /* the length of tissue cut: the tip's path */
        double d[3] = {tp[0] - r->last_tip[0], tp[1] - r->last_tip[1], tp[2] - r->last_tip[2]};
        r->path_cut += sqrt(ns_run_dot3(d, d));
    }
    memcpy(r->last_tip, tp, sizeof r->last_tip);
    if (ns_series_push(&r->step_ms, w) || ns_series_push(&r->total_ms, st.total_ms) ||
        ns_series_push(&r->lcp_ms, st.lcp_ms) || ns_series_push(&r->tissue_ms, st.tissue_ms) ||
        ns_series_push(&r->needle_ms, st.needle_ms) ||
        ns_series_push(&r->remesh_ms, st.remesh_ms) || ns_series_push(&r->trials, st.trials) ||
        ns_series_push(&r->iterations, st.iterations)) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    r->factorizations += st.refactors;
    const double *tip = ns_run_tip(r);
    if (r->log_tips &&
        (ns_series_push(&r->tips[0], tip[0]) || ns_series_push(&r->tips[1], tip[1]) ||
         ns_series_push(&r->tips[2], tip[2]))) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    if (r->traj)
        fprintf(r->traj, "%.6f,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%d,%d,%d,%d",
                (double)r->steps * sp->dt, tip[0], tip[1], tip[2], ns_run_depth(r), st.axial_force,
                r->rod.v_insert, r->rod.twist_rate, st.n_static, st.n_dyn_pos, st.n_dyn_neg,
                st.cutting);
    for (int i = 0; r->traj && i < sp->marker_count; i++) {
        double x[3] = {NAN, NAN, NAN};
        ns_run_world_of(&r->tissue.mesh, sp->markers[i].at, &r->marker_hint[i], x);
        fprintf(r->traj, ",%.9g,%.9g,%.9g", x[0], x[1], x[2]);
    }
    if (r->traj)
        fputc('\n', r->traj);
    ns_run_check_obstacles(r, (double)r->steps * sp->dt, r->exited);
    ns_run_debrief_closest(r, tip, (double)r->steps * sp->dt);
    for (int i = events; i < r->event_n; i++)
        if (r->events[i].type == EVENT_BONE_CONTACT && ns_run_debrief_mark(r, NS_MARK_BONE)) {
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
    /* results read from this state: an event's place, an obstacle's depth (run_warnings.h) */
    bool inside = false;
    for (int k = 0; k < sp->obstacle_count; k++)
        inside |= r->obst[k].inside;
    if (inside || r->event_n > events) {
        int h = r->tip_hint;
        ns_run_warnings_read(&r->warn, inverted_beside(r, tip, &h));
    }
    if (r->rendering && ns_run_render_after_step(r, &st, ctl.drop_seed, err, err_sz))
        return -1;
    return 0;
}

int ns_run_tick(NsRun *r, const NsControl *given, char *err, int err_sz)
{
    const NsRunSpec *sp = &r->spec;
    if (!(r->max_steps > 0 ? r->steps < r->max_steps : r->more))
        return 0;
    if (ns_cleanup_signal() != 0) {
        ns_set_err(err, err_sz, "%s: interrupted at step %ld (signal %d); nothing written",
                   r->sc.path, r->steps, ns_cleanup_signal());
        return -1;
    }
    if (r->max_steps == 0 && r->steps >= r->time_cap) {
        r->time_capped = true;
        fprintf(stderr,
                "%s: the script had not ended after %g s of simulated time (the limit for a "
                "scenario without a duration): stopped there\n",
                r->sc.path, NS_LIMIT_DEFAULT_SIM_TIME);
        return 0;
    }
    double t = (double)r->steps * sp->dt;
    NsControl ctl;
    if (tick_controls(r, given, t, &ctl, err, err_sz))
        return -1;
    /* The script ended at this tick: nothing of it is applied, recorded or stepped. */
    if ((r->max_steps == 0 || r->stop_when_done) && !r->more)
        return 0;
    if (run_step(r, ctl, t, err, err_sz) || ns_run_checkpoint_maybe(r, err, err_sz))
        return -1;
    if (r->tty && (r->steps % 10 == 0)) {
        progress(r, r->max_steps, (double)r->steps * sp->dt);
        r->progress_shown = true;
    }
    return 1;
}

void ns_run_finish(NsRun *r)
{
    const NsRunSpec *sp = &r->spec;
    r->script_finished = !r->time_capped && (!r->more || !sp->has_script || r->opt.replay);
    if (r->progress_shown)
        fputs("\r\033[K", stderr);
    r->progress_shown = false;
    r->wall_s = ns_wall_s() - r->t0;
}

int ns_run_loop(NsRun *r, char *err, int err_sz)
{
    if (ns_run_begin(r, err, err_sz) || (r->opt.resume && ns_run_checkpoint_resume(r, err, err_sz)))
        return -1;
    int rc;
    while ((rc = ns_run_tick(r, NULL, err, err_sz)) > 0)
        ;
    if (rc < 0)
        return -1;
    ns_run_finish(r);
    if (r->opt.checkpoint && !r->checkpointed) {
        ns_set_err(err, err_sz, "%s: the run ended at t = %g s, before --checkpoint-at %g s",
                   r->opt.checkpoint, (double)r->steps * r->spec.dt, r->opt.checkpoint_at);
        return -1;
    }
    return 0;
}

int ns_run_load(NsRun *r, char *err, int err_sz)
{
    int rc = -1;
    if (ns_scenario_load_set(r->opt.scenario, r->opt.sets, r->opt.nsets, &r->sc, err, err_sz) ==
        0) {
        r->have_sc = true;
        if (ns_run_spec_read(&r->sc, &r->spec, err, err_sz) == 0) {
            r->have_spec = true;
            rc = 0;
        }
    }
    /* `sim` and the actions module are set up also without a script (on_tick uses them). */
    rc = rc ? rc : ns_run_script_start(r, err, err_sz);
    if (rc == 0 && !r->spec.has_script && r->spec.duration <= 0.0 && r->opt.steps == 0 &&
        !r->opt.replay && !r->opt.live) {
        ns_set_err(err, err_sz,
                   "%s: ns.scenario: without a script the run needs a duration (or --steps N) "
                   "to know when to stop",
                   r->sc.where);
        rc = -1;
    }
    return rc;
}

int ns_run_end(NsRun *r, NsRunResults *res, uint64_t *hash, char *err, int err_sz)
{
    int rc = 0;
    read_final(r); /* the targets, the tip, the seeds, the dose */
    if (rc == 0 && ns_run_score(r, res)) {
        ns_set_err(err, err_sz, "out of memory");
        rc = -1;
    }
    if (rc == 0)
        rc = ns_run_dosimetry_end(r, err, err_sz);
    if (rc == 0 && r->rendering) {
        double t0 = ns_wall_s();
        rc = ns_run_render_end(r, res, err, err_sz);
        r->end_s = ns_wall_s() - t0;
    }
    *hash = rc == 0 ? ns_coupled_state_hash(&r->c) : 0;
    return rc;
}

void ns_run_free(NsRun *r)
{
    if (r->rendering)
        ns_run_render_free(&r->rr);
    free(r->prev_tet_node);
    free(r->changed);
    free(r->obstacle_region);
    free(r->reached);
    lua_State *L = r->have_sc ? ns_lua_state(r->sc.lua) : NULL;
    if (L && r->sim_ref != LUA_NOREF)
        luaL_unref(L, LUA_REGISTRYINDEX, r->sim_ref);
    if (L && r->act_ref != LUA_NOREF)
        luaL_unref(L, LUA_REGISTRYINDEX, r->act_ref);
    if (L && r->co_ref != LUA_NOREF)
        luaL_unref(L, LUA_REGISTRYINDEX, r->co_ref);
    if (r->have_steer)
        ns_run_steer_free(&r->steer);
    free(r->prior_plan);
    ns_run_dosimetry_free(r);
    ns_run_video_free(&r->cues);
    ns_run_debrief_free(&r->debrief);
    if (r->have_c)
        ns_coupled_free(&r->c);
    if (r->have_rod)
        ns_rod_free(&r->rod);
    if (r->have_tissue)
        ns_tissue_free(&r->tissue);
    if (r->have_orig)
        ns_mesh_free(&r->orig);
    if (r->have_dw)
        ns_dihedral_watch_free(&r->dw);
    if (r->have_spec)
        ns_run_spec_free(&r->spec);
    if (r->have_sc)
        ns_scenario_free(&r->sc);
    NsSeries *s[8] = {&r->step_ms,   &r->total_ms,  &r->lcp_ms, &r->tissue_ms,
                      &r->needle_ms, &r->remesh_ms, &r->trials, &r->iterations};
    for (int k = 0; k < 8; k++)
        free(s[k]->v);
    for (int k = 0; k < 3; k++)
        free(r->tips[k].v);
    free(r->target_hint);
    free(r->marker_hint);
    free(r->obst);
    free(r->seeds);
    free(r->events);
    free(r->traj_tmp);
    free(r->report_tmp);
    free(r->row_tmp);
    free(r->rec_tmp);
    ns_control_log_free(&r->replay);
    free(r->views);
    free(r->view_tx);
    ns_run_checkpoint_free(r);
}
