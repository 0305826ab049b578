/* A live session's frames (docs/live.md): what a frame needs, copied from the run after a step
 * (NsLiveSnap, on the solver's thread), and the frame drawn and encoded from that copy (on the
 * render thread, which owns its EGL context and never reads the run's world). */
#ifndef NS_LIVE_FRAME_H
#define NS_LIVE_FRAME_H

#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>

#include "frame.h"
#include "jpeg.h"
#include "mesh.h"
#include "run.h"

enum { NS_LIVE_EVENTS = 16 }; /* the latest events a state message carries */

typedef struct NsLiveEvent {
    double t;         /* [s] */
    const char *type; /* static: bone_contact, tip_exit, seed, next_needle */
} NsLiveEvent;

/* One step's state, as a frame and the state message need it. */
typedef struct NsLiveSnap {
    NsMesh mesh; /* node_slots, tet_slots, x, tet_node, tet_region, tet_adj only */
    int node_cap, tet_cap;
    uint64_t topology; /* the mesh's topology_version when its tets were copied */
    double *rod_x;     /* (rod_nodes x 3) */
    uint8_t *state;    /* (rod_nodes) friction states */
    int rod_nodes, rod_cap;
    bool cutting, bevel;
    double m2[3];
    int held;
    double *target_x, *target_r, *target_err; /* (targets x 3), (targets), (targets) [m, m, mm] */
    bool *target_hit;
    int targets;
    double *seed_x; /* (seeds x 3) */
    int seeds, seed_cap;
    double *marker_x; /* (markers x 3) */
    int markers;
    double axis[3], entry[3];
    /* the HUD and the state message */
    long step;
    double t, depth, tip[3], axial, score, rtf;
    int fr[3], needles, seeds_planned;
    bool paused, scripted, ended;
    NsLiveEvent events[NS_LIVE_EVENTS];
    int event_n; /* in events[] (the latest) */
} NsLiveSnap;

/* Copies the run's state after a step into s (its buffers reused). The solver's thread only.
 * events: the latest session events (seeds, needles) beside the run's own. Returns 0, or -1 out
 * of memory. */
int ns_live_snap_take(NsLiveSnap *s, NsRun *r, const NsLiveEvent *events, int event_n);
void ns_live_snap_free(NsLiveSnap *s);

/* The render thread's side: its renderer, image, JPEG and state message buffers. */
typedef struct NsLiveRender {
    NsFrame frame;
    bool open;
    NsImage image;
    NsJpegBuf jpeg;
    char *json;
    size_t json_n;
    int quality;
    int views[3], nviews; /* the views the trainee chose ({"views": ...}); 0: the scenario's */
    /* what does not change during a session (read-only in the run) */
    const NsRun *run;
} NsLiveRender;

/* Opens the renderer on the calling thread (its EGL context is current there). */
int ns_live_render_open(NsLiveRender *lr, const NsRun *r, int w, int h, int samples, int quality,
                        char *err, int err_sz);
/* Draws s and encodes it (lr->jpeg), and writes its state message (lr->json): fps is the
 * delivered frame rate to report. render_ms and encode_ms: what each took. */
int ns_live_render_draw(NsLiveRender *lr, const NsLiveSnap *s, double fps, double *render_ms,
                        double *encode_ms, char *err, int err_sz);
void ns_live_render_close(NsLiveRender *lr);

/* The state message of s (docs/live.md) on f, one line. */
void ns_live_state_json(FILE *f, const NsRun *r, const NsLiveSnap *s, double fps);

#endif
