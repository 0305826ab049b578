/* A live session (live_session.h). Threads, and what each owns:
 *   - the caller's (the solver's): the run, its world, Lua, the run's own pictures (summary.png);
 *     it steps when the wall clock says, applies the controls received, and after each step
 *     copies what a frame needs into the back buffer of a triple buffer (NsLiveSnap);
 *   - the render thread: its EGL context; it takes the newest completed copy, draws, encodes
 *     and posts the frame on the board, at most fps times a second (stale copies are dropped);
 *   - the server's threads: they post messages (ns_live_session_control) and copy frames off
 *     the board (ns_live_session_frame).
 * `mu` guards the controls, the triple buffer's exchange and the latency marks; `board_mu` the
 * finished frame. Nothing in the world is read outside the solver's thread. */
#include "live_session.h"

#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

#include "cleanup.h"
#include "err.h"
#include "live_frame.h"
#include "ns_limits.h"
#include "series.h"

enum { PENDING_MAX = 64, MARKS_MAX = 256 };

/* The rate a {"twist": rad} turns at [rad/s] (act.twist's default). */
#define TWIST_RATE_DEFAULT M_PI

struct NsLiveSession {
    NsRun *r;
    NsLiveOpts o;
    pthread_mutex_t mu;
    pthread_cond_t ctl_cv, snap_cv;
    /* the controls (mu): speeds hold until changed, events wait for the next step */
    double insert_speed, twist_rate, twist_left, vb[3];
    int seeds_pending;
    bool needle_pending, paused, end;
    bool scripted;               /* the run's live_scripted after the last step */
    double pending[PENDING_MAX]; /* arrival times of messages not yet applied [s] */
    int pending_n;
    struct Mark {
        double arrival;
        long step; /* the first state that shows it */
    } marks[MARKS_MAX];
    int mark_n;
    /* the triple buffer (mu): back is the solver's, front the renderer's, mid the newest */
    NsLiveSnap snaps[3];
    int back, mid, front;
    bool fresh, stop_render, render_failed;
    bool answer; /* the newest copy is the first to show a message's effect (drawn at once) */
    bool redraw; /* the views changed: the front copy drawn again */
    int views[3], nviews; /* {"views": ...}: what the frames show (0: the scenario's views) */
    long shown_step;      /* the step of the copy the renderer took last */
    char render_err[512];
    int pause_epoch; /* bumped on every pause and resume: fps windows across one are dropped */
    /* the board (board_mu) */
    pthread_mutex_t board_mu;
    pthread_cond_t board_cv;
    NsLiveBytes jpeg, json;
    uint64_t seq, notice_seq;
    char notice[256];
    bool over;
    /* figures */
    NsSeries fps, rtf, latency, render_ms, encode_ms, snap_ms, scene_ms, gl_ms, step_cpu, frame_cpu;
    double rtf_now, fps_now;
    int clients_now, clients_total;
    long frames;
    /* the session's own events (seeds, needles), for the state messages */
    NsLiveEvent events[NS_LIVE_EVENTS];
    int event_n;
    int entry_next;
    NsEntry first_entry;
    pthread_t render;
    bool render_started;
    const char *end_reason;
};

NsLiveOpts ns_default_live_opts(void)
{
    return (NsLiveOpts){
        .width = 960, .height = 540, .fps = 25.0, .quality = 80, .samples = 1, .max_lag_s = 0.2};
}

static void abs_time(double wall_s, struct timespec *ts)
{
    /* ns_wall_s is CLOCK_MONOTONIC, as the condition variables' clock */
    double sec = floor(wall_s);
    ts->tv_sec = (time_t)sec;
    ts->tv_nsec = (long)((wall_s - sec) * 1e9);
    if (ts->tv_nsec >= 1000000000L) {
        ts->tv_sec++;
        ts->tv_nsec -= 1000000000L;
    }
}

static int cond_init(pthread_cond_t *cv)
{
    pthread_condattr_t a;
    if (pthread_condattr_init(&a))
        return -1;
    pthread_condattr_setclock(&a, CLOCK_MONOTONIC);
    int rc = pthread_cond_init(cv, &a);
    pthread_condattr_destroy(&a);
    return rc ? -1 : 0;
}

NsLiveSession *ns_live_session_new(NsRun *r, const NsLiveOpts *o, char *err, int err_sz)
{
    NsLiveSession *s = calloc(1, sizeof *s);
    if (!s || pthread_mutex_init(&s->mu, NULL) || pthread_mutex_init(&s->board_mu, NULL) ||
        cond_init(&s->ctl_cv) || cond_init(&s->snap_cv) || cond_init(&s->board_cv)) {
        free(s);
        ns_set_err(err, err_sz, "cannot set up the session's threads");
        return NULL;
    }
    s->r = r;
    s->o = *o;
    s->back = 0;
    s->mid = 1;
    s->front = 2;
    s->rtf_now = 1.0;
    s->scripted = r->live_scripted;
    const NsRunSpec *sp = &r->spec;
    memcpy(s->first_entry.point, sp->entry_point, sizeof s->first_entry.point);
    memcpy(s->first_entry.direction, sp->entry_dir, sizeof s->first_entry.direction);
    memcpy(s->first_entry.bevel_toward, sp->bevel_toward, sizeof s->first_entry.bevel_toward);
    s->first_entry.has_bevel_toward = sp->has_bevel_toward;
    return s;
}

/* ---- messages (any thread) ---- */

int ns_live_session_control(NsLiveSession *s, const NsLiveMsg *m, double arrival_s, char *err,
                            int err_sz)
{
    int rc = 0;
    pthread_mutex_lock(&s->mu);
    if (s->end || s->over) {
        ns_set_err(err, err_sz, "the session has ended");
        rc = -1;
    } else if (s->scripted && (m->has & ~(unsigned)(NS_LIVE_PAUSE | NS_LIVE_END | NS_LIVE_VIEWS))) {
        ns_set_err(err, err_sz, "the scenario's script drives the needle until its set-up ends");
        rc = -1;
    } else if ((m->has & NS_LIVE_DROP_SEED) && m->drop_seed && s->seeds_pending >= 8) {
        ns_set_err(err, err_sz, "drop_seed: 8 seeds are waiting for the next step already");
        rc = -1;
    }
    if (rc == 0) {
        bool steps = m->has & ~(unsigned)(NS_LIVE_PAUSE | NS_LIVE_END | NS_LIVE_VIEWS);
        if (m->has & NS_LIVE_VIEWS) { /* the frames only: not a control, not logged */
            memcpy(s->views, m->views, sizeof s->views);
            s->nviews = m->nviews;
            s->redraw = true;
            pthread_cond_broadcast(&s->snap_cv);
        }
        if (m->has & NS_LIVE_INSERT_SPEED)
            s->insert_speed = m->insert_speed;
        if (m->has & NS_LIVE_TWIST_RATE)
            s->twist_rate = m->twist_rate;
        if (m->has & NS_LIVE_TWIST)
            s->twist_left += m->twist;
        if (fabs(s->twist_left) > NS_LIMIT_TWIST_ANGLE)
            s->twist_left = copysign(NS_LIMIT_TWIST_ANGLE, s->twist_left);
        if (m->has & NS_LIVE_BASE_VELOCITY)
            memcpy(s->vb, m->base_velocity, sizeof s->vb);
        if ((m->has & NS_LIVE_DROP_SEED) && m->drop_seed)
            s->seeds_pending++;
        if ((m->has & NS_LIVE_NEXT_NEEDLE) && m->next_needle)
            s->needle_pending = true;
        if ((m->has & NS_LIVE_PAUSE) && m->pause != s->paused) {
            s->paused = m->pause;
            s->pause_epoch++;
        }
        if ((m->has & NS_LIVE_END) && m->end)
            s->end = true;
        if (steps && !s->paused && s->pending_n < PENDING_MAX)
            s->pending[s->pending_n++] = arrival_s;
        pthread_cond_broadcast(&s->ctl_cv);
    }
    pthread_mutex_unlock(&s->mu);
    return rc;
}

/* ---- the board (render thread in, server threads out) ---- */

static int bytes_set(NsLiveBytes *b, const void *p, size_t n)
{
    if (n + 1 > b->cap) {
        size_t cap = n + n / 2 + 64;
        char *q = realloc(b->p, cap);
        if (!q)
            return -1;
        b->p = q;
        b->cap = cap;
    }
    memcpy(b->p, p, n);
    b->p[n] = '\0';
    b->n = n;
    return 0;
}

static void post_frame(NsLiveSession *s, const NsJpegBuf *jpeg, const char *json, size_t json_n)
{
    pthread_mutex_lock(&s->board_mu);
    if (bytes_set(&s->jpeg, jpeg->data, jpeg->size) == 0 && bytes_set(&s->json, json, json_n) == 0)
        s->seq++;
    pthread_cond_broadcast(&s->board_cv);
    pthread_mutex_unlock(&s->board_mu);
}

static void post_notice(NsLiveSession *s, const char *msg)
{
    pthread_mutex_lock(&s->board_mu);
    snprintf(s->notice, sizeof s->notice, "%s", msg);
    s->notice_seq++;
    pthread_cond_broadcast(&s->board_cv);
    pthread_mutex_unlock(&s->board_mu);
}

int ns_live_session_frame(NsLiveSession *s, uint64_t *seq, NsLiveBytes *jpeg, NsLiveBytes *json,
                          int timeout_ms)
{
    struct timespec until;
    abs_time(ns_wall_s() + 1e-3 * timeout_ms, &until);
    int rc = 0;
    pthread_mutex_lock(&s->board_mu);
    while (s->seq <= *seq && !s->over)
        if (pthread_cond_timedwait(&s->board_cv, &s->board_mu, &until) == ETIMEDOUT)
            break;
    if (s->seq > *seq) {
        rc =
            bytes_set(jpeg, s->jpeg.p, s->jpeg.n) || bytes_set(json, s->json.p, s->json.n) ? -2 : 1;
        *seq = s->seq;
    } else if (s->over) {
        rc = -1;
    }
    pthread_mutex_unlock(&s->board_mu);
    return rc;
}

int ns_live_session_notice(NsLiveSession *s, uint64_t *seq, char *out, int out_sz)
{
    int rc = 0;
    pthread_mutex_lock(&s->board_mu);
    if (s->notice_seq > *seq) {
        snprintf(out, (size_t)out_sz, "%s", s->notice);
        *seq = s->notice_seq;
        rc = 1;
    }
    pthread_mutex_unlock(&s->board_mu);
    return rc;
}

bool ns_live_session_over(NsLiveSession *s)
{
    pthread_mutex_lock(&s->board_mu);
    bool over = s->over;
    pthread_mutex_unlock(&s->board_mu);
    return over;
}

void ns_live_session_clients(NsLiveSession *s, int delta)
{
    pthread_mutex_lock(&s->mu);
    s->clients_now += delta;
    if (delta > 0)
        s->clients_total += delta;
    pthread_mutex_unlock(&s->mu);
}

const char *ns_live_session_end_reason(const NsLiveSession *s)
{
    return s->end_reason ? s->end_reason : "";
}

/* ---- the render thread ---- */

/* After a frame of state `step` is out: the latency of every message that step shows. */
static void latency_marks(NsLiveSession *s, long step, double now)
{
    pthread_mutex_lock(&s->mu);
    int k = 0;
    for (int i = 0; i < s->mark_n; i++) {
        if (s->marks[i].step <= step)
            ns_series_push(&s->latency, 1e3 * (now - s->marks[i].arrival));
        else
            s->marks[k++] = s->marks[i];
    }
    s->mark_n = k;
    pthread_mutex_unlock(&s->mu);
}

/* Takes the newest copy (front), waiting up to `until` for one, and the views to draw it in
 * (lr). 1: taken (or the views changed: the front copy again), 0: none, -1: stop. */
static int take_newest(NsLiveSession *s, double until_s, bool *paused, int *epoch, NsLiveRender *lr)
{
    struct timespec until;
    abs_time(until_s, &until);
    pthread_mutex_lock(&s->mu);
    while (!s->fresh && !s->redraw && !s->stop_render)
        if (pthread_cond_timedwait(&s->snap_cv, &s->mu, &until) == ETIMEDOUT)
            break;
    int rc = s->fresh || s->redraw ? 1 : s->stop_render ? -1 : 0;
    s->redraw = false;
    memcpy(lr->views, s->views, sizeof lr->views);
    lr->nviews = s->nviews;
    if (s->fresh) {
        int t = s->front;
        s->front = s->mid;
        s->mid = t;
        s->fresh = false;
        s->answer = false;
        s->shown_step = s->snaps[s->front].step;
    }
    *paused = s->paused;
    *epoch = s->pause_epoch;
    pthread_mutex_unlock(&s->mu);
    return rc;
}

static void *render_main(void *arg)
{
    NsLiveSession *s = arg;
    /* The solver's thread keeps the upper hand on a loaded machine: the frames give way
     * first (the nice value is per thread on Linux, and llvmpipe's threads inherit it). */
    (void)setpriority(PRIO_PROCESS, (id_t)gettid(), 5);
    NsLiveRender lr;
    char err[512] = "";
    if (ns_live_render_open(&lr, s->r, s->o.width, s->o.height, s->o.samples, s->o.quality, err,
                            sizeof err)) {
        pthread_mutex_lock(&s->mu);
        s->render_failed = true;
        snprintf(s->render_err, sizeof s->render_err, "%s", err);
        pthread_cond_broadcast(&s->ctl_cv);
        pthread_mutex_unlock(&s->mu);
        return NULL;
    }
    double period = 1.0 / s->o.fps, next = ns_wall_s(), win0 = next;
    long win_frames = 0;
    int win_epoch = -1;
    for (;;) {
        bool paused;
        int epoch, got = take_newest(s, ns_wall_s() + 0.5, &paused, &epoch, &lr);
        if (got < 0)
            break;
        if (got == 0)
            continue;
        double rm, em, cpu0 = ns_thread_cpu_s();
        const NsLiveSnap *snap = &s->snaps[s->front];
        if (ns_live_render_draw(&lr, snap, s->fps_now, &rm, &em, err, sizeof err)) {
            pthread_mutex_lock(&s->mu);
            s->render_failed = true;
            snprintf(s->render_err, sizeof s->render_err, "%s", err);
            pthread_cond_broadcast(&s->ctl_cv);
            pthread_mutex_unlock(&s->mu);
            break;
        }
        post_frame(s, &lr.jpeg, lr.json, lr.json_n);
        double now = ns_wall_s();
        latency_marks(s, snap->step, now);
        ns_series_push(&s->render_ms, rm);
        ns_series_push(&s->encode_ms, em);
        ns_series_push(&s->frame_cpu, 1e3 * (ns_thread_cpu_s() - cpu0));
        ns_series_push(&s->scene_ms, lr.frame.build_ms);
        ns_series_push(&s->gl_ms, lr.frame.gl_ms);
        s->frames++;
        /* the delivered rate over windows of a second, none across a pause */
        win_frames++;
        if (epoch != win_epoch || paused) {
            win_epoch = epoch;
            win0 = now;
            win_frames = 0;
        } else if (now - win0 >= 1.0) {
            s->fps_now = (double)win_frames / (now - win0);
            ns_series_push(&s->fps, s->fps_now);
            win0 = now;
            win_frames = 0;
        }
        /* the next frame a period after this one (a late frame is not caught up), or as soon
         * as a state answers a message, a quarter period on at the least: the trainee's input
         * shows without waiting for the frame clock */
        next = fmax(next + period, now);
        struct timespec soonest, due;
        abs_time(now + 0.25 * period, &soonest);
        abs_time(next, &due);
        pthread_mutex_lock(&s->mu);
        while (!s->stop_render && pthread_cond_timedwait(&s->snap_cv, &s->mu, &soonest) == 0)
            ;
        while (!s->stop_render && !s->answer && !s->redraw &&
               pthread_cond_timedwait(&s->snap_cv, &s->mu, &due) == 0)
            ;
        pthread_mutex_unlock(&s->mu);
    }
    ns_live_render_close(&lr);
    return NULL;
}

/* ---- the solver's thread ---- */

static void session_event(NsLiveSession *s, double t, const char *type)
{
    if (s->event_n == NS_LIVE_EVENTS) {
        memmove(s->events, s->events + 1, (NS_LIVE_EVENTS - 1) * sizeof s->events[0]);
        s->event_n--;
    }
    s->events[s->event_n++] = (NsLiveEvent){t, type};
}

/* Copies the state into the back buffer and makes it the newest. */
static int publish(NsLiveSession *s, bool ended)
{
    double t0 = ns_wall_s();
    NsLiveSnap *b = &s->snaps[s->back];
    if (ns_live_snap_take(b, s->r, s->events, s->event_n))
        return -1;
    b->rtf = s->rtf_now;
    b->ended = ended;
    ns_series_push(&s->snap_ms, 1e3 * (ns_wall_s() - t0));
    pthread_mutex_lock(&s->mu);
    b->paused = s->paused;
    s->scripted = s->r->live_scripted;
    int t = s->mid;
    s->mid = s->back;
    s->back = t;
    s->fresh = true;
    for (int i = 0; i < s->mark_n; i++) /* (marks the frame being drawn shows are not news) */
        s->answer |= s->marks[i].step <= s->r->steps && s->marks[i].step > s->shown_step;
    pthread_cond_signal(&s->snap_cv);
    pthread_mutex_unlock(&s->mu);
    return 0;
}

/* Why an event asked for cannot happen at this step (NULL: it can). Checked here, as
 * ns_run_release_seed and ns_run_next_needle would find it, so that a trainee's mistake is a
 * refusal and not the run's error. */
static const char *seed_refusal(NsRun *r)
{
    const NsMesh *M = &r->tissue.mesh;
    if (r->spec.target_count == 0)
        return "drop_seed: the scenario has no targets for seeds";
    if (ns_mesh_locate_in(M, M->x, ns_run_tip(r), r->tip_hint, 1e-6, NULL) < 0)
        return "drop_seed: the needle tip is not in the tissue";
    return NULL;
}

/* The controls of the next step, under mu: the speeds, a share of a twist by an angle, one
 * waiting seed, a waiting needle. The messages they apply are marked for the latency. */
static void next_controls(NsLiveSession *s, NsControl *c)
{
    NsRun *r = s->r;
    double dt = r->spec.dt;
    memset(c, 0, sizeof *c);
    c->v_insert = s->insert_speed;
    memcpy(c->v_base, s->vb, sizeof c->v_base);
    double w = 0.0;
    if (s->twist_left != 0.0) {
        double room = fmax(0.0, NS_LIMIT_TWIST_RATE - fabs(s->twist_rate));
        double step = fmin(fmin(TWIST_RATE_DEFAULT, room) * dt, fabs(s->twist_left));
        w = copysign(step / dt, s->twist_left);
        s->twist_left =
            fabs(s->twist_left) <= step ? 0.0 : s->twist_left - copysign(step, s->twist_left);
    }
    c->twist_rate = s->twist_rate + w;
    if (s->seeds_pending > 0) {
        s->seeds_pending--;
        const char *why = seed_refusal(r);
        if (why)
            post_notice(s, why);
        else
            c->drop_seed = 1;
    }
    if (s->needle_pending) {
        s->needle_pending = false;
        if (!r->c.outside) {
            post_notice(s, "next_needle: the needle is still in the tissue: retract it all the way "
                           "first");
        } else {
            const NsRunSpec *sp = &r->spec;
            int n = sp->live_entry_count;
            c->next_needle = 1;
            c->entry = n ? sp->live_entries[s->entry_next++ % n] : s->first_entry;
        }
    }
    for (int i = 0; i < s->pending_n && s->mark_n < MARKS_MAX; i++)
        s->marks[s->mark_n++] = (struct Mark){s->pending[i], r->steps + 1};
    s->pending_n = 0;
}

/* Waits, under mu, until wall time `due`, a message, or the pause's end. */
static void wait_until(NsLiveSession *s, double due)
{
    struct timespec ts;
    abs_time(due, &ts);
    pthread_cond_timedwait(&s->ctl_cv, &s->mu, &ts);
}

/* The loop: a step whenever the wall clock reaches its simulated time. origin is the wall time
 * of simulated time t0; when the solver falls more than max_lag behind, origin moves on, so the
 * session slows (real-time factor < 1) instead of skipping physics. */
static int solver_loop(NsLiveSession *s, char *err, int err_sz)
{
    NsRun *r = s->r;
    double dt = r->spec.dt, origin = ns_wall_s(), t0 = 0.0;
    double win0 = origin, win_t0 = 0.0;
    int epoch = 0;
    for (;;) {
        if (ns_cleanup_signal()) {
            s->end_reason = "signal";
            return 0;
        }
        pthread_mutex_lock(&s->mu);
        if (s->render_failed) {
            pthread_mutex_unlock(&s->mu);
            ns_set_err(err, err_sz, "the live frames: %s", s->render_err);
            return -1;
        }
        if (s->end) {
            pthread_mutex_unlock(&s->mu);
            s->end_reason = "client";
            return 0;
        }
        double now = ns_wall_s(), t = (double)r->steps * dt;
        if (s->pause_epoch != epoch) { /* paused or resumed: the clock restarts from here */
            epoch = s->pause_epoch;
            origin = now;
            t0 = t;
            win0 = now;
            win_t0 = t;
            pthread_mutex_unlock(&s->mu);
            if (publish(s, false))
                goto oom;
            continue;
        }
        if (s->paused) {
            wait_until(s, now + 0.5);
            pthread_mutex_unlock(&s->mu);
            continue;
        }
        double due = origin + (t - t0);
        if (now < due) {
            wait_until(s, due);
            pthread_mutex_unlock(&s->mu);
            continue;
        }
        if (now - due > s->o.max_lag_s)
            origin += now - due - s->o.max_lag_s;
        NsControl c;
        next_controls(s, &c);
        pthread_mutex_unlock(&s->mu);
        if (c.drop_seed)
            session_event(s, t, "seed");
        if (c.next_needle)
            session_event(s, t, "next_needle");
        double cpu0 = ns_thread_cpu_s();
        int rc = ns_run_tick(r, &c, err, err_sz);
        ns_series_push(&s->step_cpu, 1e3 * (ns_thread_cpu_s() - cpu0));
        if (rc < 0 && ns_cleanup_signal()) { /* stopped inside the tick: nothing was stepped */
            s->end_reason = "signal";
            return 0;
        }
        if (rc < 0)
            return -1;
        if (rc == 0) {
            s->end_reason = "scenario";
            return 0;
        }
        now = ns_wall_s();
        if (now - win0 >= 1.0) {
            s->rtf_now = ((double)r->steps * dt - win_t0) / (now - win0);
            ns_series_push(&s->rtf, s->rtf_now);
            win0 = now;
            win_t0 = (double)r->steps * dt;
        }
        if (publish(s, false))
            goto oom;
    }
oom:
    ns_set_err(err, err_sz, "out of memory");
    return -1;
}

/* The board says the session is over: the clients' senders send the end and stop. */
static void board_over(NsLiveSession *s)
{
    pthread_mutex_lock(&s->board_mu);
    s->over = true;
    pthread_cond_broadcast(&s->board_cv);
    pthread_mutex_unlock(&s->board_mu);
}

int ns_live_session_run(NsLiveSession *s, char *err, int err_sz)
{
    if (publish(s, false)) { /* the first frame: the state as built */
        ns_set_err(err, err_sz, "out of memory");
        board_over(s);
        return -1;
    }
    if (pthread_create(&s->render, NULL, render_main, s)) {
        ns_set_err(err, err_sz, "cannot start the render thread");
        board_over(s);
        return -1;
    }
    s->render_started = true;
    int rc = solver_loop(s, err, err_sz);
    /* the last state, marked ended, then the render thread stops once it has drawn it */
    if (rc == 0 && publish(s, true)) {
        ns_set_err(err, err_sz, "out of memory");
        rc = -1;
    }
    pthread_mutex_lock(&s->mu);
    while (rc == 0 && s->fresh && !s->render_failed) {
        struct timespec ts;
        abs_time(ns_wall_s() + 0.05, &ts);
        pthread_cond_timedwait(&s->ctl_cv, &s->mu, &ts);
    }
    s->stop_render = true;
    s->end = true;
    pthread_cond_broadcast(&s->snap_cv);
    pthread_mutex_unlock(&s->mu);
    pthread_join(s->render, NULL);
    s->render_started = false;
    board_over(s);
    return rc;
}

/* ---- figures ---- */

void ns_live_session_figures(const NsLiveSession *s, NsLiveFigures *f)
{
    memset(f, 0, sizeof *f);
    f->fps_median = ns_series_quantile(&s->fps, 0.5);
    f->fps_p5 = ns_series_quantile(&s->fps, 0.05);
    f->rtf_median = ns_series_quantile(&s->rtf, 0.5);
    f->rtf_min = ns_series_quantile(&s->rtf, 0.0);
    f->latency_median = ns_series_quantile(&s->latency, 0.5);
    f->latency_p95 = ns_series_quantile(&s->latency, 0.95);
    f->render_ms = ns_series_quantile(&s->render_ms, 0.5);
    f->encode_ms = ns_series_quantile(&s->encode_ms, 0.5);
    f->snapshot_ms = ns_series_quantile(&s->snap_ms, 0.5);
    f->scene_ms = ns_series_quantile(&s->scene_ms, 0.5);
    f->gl_ms = ns_series_quantile(&s->gl_ms, 0.5);
    f->step_cpu_ms = ns_series_quantile(&s->step_cpu, 0.5);
    f->frame_cpu_ms = ns_series_quantile(&s->frame_cpu, 0.5);
    f->step_ms = ns_series_quantile(&s->r->step_ms, 0.5);
    f->frames = s->frames;
    f->latency_samples = s->latency.n;
    f->clients = s->clients_total;
}

static void pair(NsJson *j, const char *key, const char *k1, double v1, const char *k2, double v2)
{
    ns_json_key(j, key);
    ns_json_begin_object(j);
    ns_json_key(j, k1);
    ns_json_number(j, v1);
    ns_json_key(j, k2);
    ns_json_number(j, v2);
    ns_json_end_object(j);
}

/* The time step and solver settings the session ran with, and where they came from. */
static void model_json(NsJson *j, const NsRun *r)
{
    const NsRunSpec *sp = &r->spec;
    static const char *const keys[7] = {"dt_s",
                                        "tolerance",
                                        "check_tolerance",
                                        "lazy_threshold",
                                        "accuracy_tip_m",
                                        "measured_tip_error_m",
                                        "measured_cost_ms_per_s"};
    const double v[7] = {sp->dt,
                         r->c.params.tau_sol,
                         r->c.params.tau_check,
                         r->tissue.params.lazy_threshold,
                         sp->accuracy,
                         sp->accuracy_tip_error,
                         sp->accuracy_cost};
    ns_json_key(j, "model");
    ns_json_begin_object(j);
    ns_json_key(j, "chosen_by");
    ns_json_string(j, sp->model_chosen ? "accuracy" : "scenario");
    for (int k = 0; k < (sp->model_chosen ? 7 : 4); k++) {
        ns_json_key(j, keys[k]);
        ns_json_number(j, v[k]);
    }
    if (sp->model_chosen) { /* the front's setting (live --accuracy) */
        ns_json_key(j, "front");
        ns_json_string(j, sp->accuracy_front);
        ns_json_key(j, "chosen");
        ns_json_string(j, sp->accuracy_label);
    }
    ns_json_end_object(j);
}

void ns_live_session_report(NsJson *j, void *ctx)
{
    const NsLiveSession *s = ctx;
    NsLiveFigures f;
    ns_live_session_figures(s, &f);
    ns_json_key(j, "live");
    ns_json_begin_object(j);
    pair(j, "fps", "median", f.fps_median, "p5", f.fps_p5);
    pair(j, "rtf", "median", f.rtf_median, "min", f.rtf_min);
    pair(j, "input_latency_ms", "median", f.latency_median, "p95", f.latency_p95);
    pair(j, "frame_ms", "render", f.render_ms, "encode", f.encode_ms);
    ns_json_key(j, "clients");
    ns_json_int(j, f.clients);
    ns_json_key(j, "frames");
    ns_json_int(j, f.frames);
    ns_json_key(j, "latency_samples");
    ns_json_int(j, f.latency_samples);
    ns_json_key(j, "snapshot_ms");
    ns_json_number(j, f.snapshot_ms);
    ns_json_key(j, "width");
    ns_json_int(j, s->o.width);
    ns_json_key(j, "height");
    ns_json_int(j, s->o.height);
    ns_json_key(j, "fps_asked");
    ns_json_number(j, s->o.fps);
    ns_json_key(j, "ended_by");
    ns_json_string(j, ns_live_session_end_reason(s));
    model_json(j, s->r);
    ns_json_end_object(j);
}

void ns_live_session_free(NsLiveSession *s)
{
    if (!s)
        return;
    if (s->render_started) { /* not run to its end: stop the render thread */
        pthread_mutex_lock(&s->mu);
        s->stop_render = true;
        pthread_cond_broadcast(&s->snap_cv);
        pthread_mutex_unlock(&s->mu);
        pthread_join(s->render, NULL);
    }
    for (int k = 0; k < 3; k++)
        ns_live_snap_free(&s->snaps[k]);
    free(s->jpeg.p);
    free(s->json.p);
    NsSeries *series[10] = {&s->fps,     &s->rtf,      &s->latency, &s->render_ms, &s->encode_ms,
                            &s->snap_ms, &s->scene_ms, &s->gl_ms,   &s->step_cpu,  &s->frame_cpu};
    for (int k = 0; k < 10; k++)
        free(series[k]->v);
    pthread_cond_destroy(&s->ctl_cv);
    pthread_cond_destroy(&s->snap_cv);
    pthread_cond_destroy(&s->board_cv);
    pthread_mutex_destroy(&s->mu);
    pthread_mutex_destroy(&s->board_mu);
    free(s);
}
