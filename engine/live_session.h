/* A live session (docs/live.md): a run stepped on the calling thread so that simulated time
 * follows wall time, with the controls a client sends, and its frames drawn and encoded on a
 * render thread from a copy of each step's state. The server (live_server.h) only passes
 * messages in (ns_live_session_control) and copies finished frames out
 * (ns_live_session_frame); it never touches the run. */
#ifndef NS_LIVE_SESSION_H
#define NS_LIVE_SESSION_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "json.h"
#include "live_protocol.h"
#include "run.h"

typedef struct NsLiveOpts {
    int width, height; /* the frames [pixels] */
    double fps;        /* frames a second asked for */
    int quality;       /* JPEG quality 1..100 */
    int samples;       /* multisampling of the frames (1: none) */
    double max_lag_s;  /* how far simulated time may fall behind before the session slows */
} NsLiveOpts;

NsLiveOpts ns_default_live_opts(void);

typedef struct NsLiveSession NsLiveSession;

/* A growable byte buffer a frame is copied into. */
typedef struct NsLiveBytes {
    char *p;
    size_t n, cap;
} NsLiveBytes;

/* A session for r, built and begun (ns_run_build, ns_run_begin) by the caller. NULL with a
 * message in err. */
NsLiveSession *ns_live_session_new(NsRun *r, const NsLiveOpts *o, char *err, int err_sz);
/* Runs the session on the calling thread until a client ends it, the scenario ends, or a stop
 * signal (SIGINT, SIGTERM) comes: starts and stops the render thread. Returns 0, or -1 with a
 * message in err (the run failed). */
int ns_live_session_run(NsLiveSession *s, char *err, int err_sz);
/* Applies a client's message from any thread (it takes effect at the next step). arrival_s:
 * when it arrived (ns_wall_s). Returns 0, or -1 with why it was refused in err. */
int ns_live_session_control(NsLiveSession *s, const NsLiveMsg *m, double arrival_s, char *err,
                            int err_sz);
/* Copies the newest frame (JPEG) and its state message newer than *seq into jpeg and json,
 * waiting up to timeout_ms for one. Returns 1 (a frame; *seq is its number), 0 (none yet), -1
 * (the session is over and no frame is newer), -2 (out of memory). */
int ns_live_session_frame(NsLiveSession *s, uint64_t *seq, NsLiveBytes *jpeg, NsLiveBytes *json,
                          int timeout_ms);
/* A refusal decided at a step (a seed asked for with the tip outside the tissue) newer than
 * *seq, for the controlling client: 1 with the message in out, else 0. */
int ns_live_session_notice(NsLiveSession *s, uint64_t *seq, char *out, int out_sz);
bool ns_live_session_over(NsLiveSession *s);
/* A WebSocket client connected (+1) or left (-1): the report's `clients`. */
void ns_live_session_clients(NsLiveSession *s, int delta);
/* Why the session ended: "client", "scenario", "signal" (after ns_live_session_run). */
const char *ns_live_session_end_reason(const NsLiveSession *s);
/* The `live` object of report.json (NsRun.report_extra; ctx is the session). */
void ns_live_session_report(NsJson *j, void *ctx);
/* The figures `needlesim bench --live` prints: medians and percentiles over the session. */
typedef struct NsLiveFigures {
    double fps_median, fps_p5, rtf_median, rtf_min, latency_median, latency_p95;
    double render_ms, encode_ms, snapshot_ms, step_ms;
    double scene_ms, gl_ms; /* render_ms's parts: the views' vertex lists; OpenGL with read-back */
    double step_cpu_ms,
        frame_cpu_ms; /* the solver's and render thread's CPU time a step, a frame */
    long frames, latency_samples;
    int clients;
} NsLiveFigures;
void ns_live_session_figures(const NsLiveSession *s, NsLiveFigures *f);

/* engine/cmd_live.c: `needlesim live` with its own arguments (argv[0] is "live"), and a hook
 * called with the URL and port once the server listens (bench --live starts its client there);
 * the session's figures and outcome in *result when it is not NULL. Returns the exit status. */
typedef struct NsLiveHook {
    void (*fn)(const char *url, int port, void *ctx);
    void *ctx;
} NsLiveHook;
typedef struct NsLiveRunResult {
    NsLiveFigures fig;
    uint64_t hash;
    double score, sim_s, wall_s;
    long steps;
    int seeds_planned;
} NsLiveRunResult;
int ns_live_run(int argc, char **argv, NsLiveHook hook, NsLiveRunResult *result);
void ns_live_session_free(NsLiveSession *s);

#endif
