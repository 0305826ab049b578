/* An authored video (docs/rendering.md "Authored videos"): the script's cues for the video's
 * voice (act.caption, act.chapter, act.slow_motion, act.camera, act.card), which change the
 * pictures, never the physics. The actions queue them in sim.control.video; the engine takes
 * them at each tick (ns_run_video_take), and the frames after it ask what is on screen. */
#ifndef NS_RUN_VIDEO_H
#define NS_RUN_VIDEO_H

#include <stdbool.h>

#include "ns_limits.h"

enum { NS_CUE_CAPTION, NS_CUE_SLOW, NS_CUE_CAMERA };

typedef struct NsRunCue {
    int kind;
    double t0, t1;            /* from, to [s of simulated time] */
    double zoom[2], orbit[2]; /* camera: at t0 and t1 (linear between) */
    double factor;            /* slow motion */
    int views[3], nviews;     /* camera: the views from t0 on (nviews 0: unchanged) */
    char text[NS_LIMIT_VIDEO_TEXT + 1];
} NsRunCue;

typedef struct NsRunCues {
    NsRunCue *cue;
    int n, cap;
    long taken;  /* every cue taken, chapters and cards included (NS_LIMIT_VIDEO_CUES) */
    double owed; /* slow motion: frames owed to the video, less than one */
} NsRunCues;

struct NsRunRender;
struct NsSceneInput;
struct lua_State;

/* Takes the cues queued in sim.control.video (the table at stack index ci) at time t into c,
 * and empties the queue: captions, slow motion and camera moves are kept; a chapter starts and
 * a card is drawn in rr's video now (rr NULL: no pictures; apply false: checked and dropped, a
 * resumed run's replayed ticks). Raises a Lua error naming the field on a bad cue. */
void ns_run_video_take(NsRunCues *c, struct NsRunRender *rr, struct lua_State *L, int ci, double t,
                       bool apply);

/* The caption on screen at t, or NULL. */
const char *ns_run_video_caption(const NsRunCues *c, double t);
/* The slow-motion factor at t (1: none). */
double ns_run_video_slow(const NsRunCues *c, double t);
/* The camera at t: in's bounds shrunk about the tip by the zoom and its orbit set; *views and
 * *nviews replaced by the latest camera cue's views (left as they are without one). */
void ns_run_video_camera(const NsRunCues *c, double t, const double tip[3], struct NsSceneInput *in,
                         int *views, int *nviews);

void ns_run_video_free(NsRunCues *c);

#endif
