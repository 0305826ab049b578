/* The run's pictures (issue 8): frames (DIR/frames/NNNNNN.png), the video (ffmpeg, H.264) and
 * the debrief contact sheet (DIR/summary.png: the key moments and the score table). Everything
 * is written under temporary names and renamed by ns_run_render_commit, so a failed run leaves
 * none of it. */
#ifndef NS_RUN_RENDER_H
#define NS_RUN_RENDER_H

#include <stdbool.h>

#include "frame.h"
#include "video.h"

typedef struct NsRunRenderOpts {
    const char *out_dir;
    bool frames;       /* DIR/frames/NNNNNN.png */
    const char *video; /* an .mp4 path, or NULL */
    bool summary;      /* DIR/summary.png */
    int width, height; /* even */
    int samples;       /* OpenGL's samples a pixel (0: 1, the edges smoothed after) */
    double fps;
    int views[3], nviews;
    bool legend; /* the friction-state colour key */
} NsRunRenderOpts;

typedef struct NsRunMoment {
    NsImage thumb;
    char caption[96];
} NsRunMoment;

enum { NS_RUN_MOMENTS = 12 };

typedef struct NsRunRender {
    NsRunRenderOpts o;
    NsFrame frame;
    NsImage image;
    NsVideo *video;
    char *frames_tmp, *frames_dir, *video_tmp, *summary_tmp, *summary_path;
    long frame_count;
    NsRunMoment moments[NS_RUN_MOMENTS];
    int moment_count;
    double *render_ms, *encode_ms; /* per frame */
    long timing_cap;
    double render_s; /* all rendering and encoding, moments and sheet included [s] */
    double children_cpu0, ffmpeg_cpu_s; /* ffmpeg's CPU time (it encodes on another core) */
    int committed; /* bits: frames (1), video (2), sheet (4) renamed into place */
    long timed;    /* frames rendered (render_ms, encode_ms); frame_count counts repeats too */
    /* an authored video (engine/run_video.c): the caption of the next frames (NULL: none), the
     * chapters' titles and starts in the video [s] */
    const char *caption;
    int frame_views[3], frame_nviews; /* the next frames' views (0: o.views) */
    NsFont *caption_font, *title_font;
    char **chapter_title;
    double *chapter_s;
    int chapters, chapter_cap;
    char *video_chap_tmp; /* the video with its chapters, before it replaces video_tmp */
} NsRunRender;

/* Before a run writes anything in out_dir: an earlier summary.png must be a regular file and
 * frames/ a folder; with frames (the run will write frames/), a frames/ holding files other
 * than NNNNNN.png is an error. Nothing is removed here: the earlier pictures stay until this
 * run's replace them (ns_run_render_commit). */
int ns_run_render_check_old(const char *out_dir, bool frames, char *err, int err_sz);
/* Opens the renderer (and ffmpeg for a video). Nothing is written yet. */
int ns_run_render_open(NsRunRender *rr, const NsRunRenderOpts *o, char *err, int err_sz);
/* A frame of the run to the frames folder and the video. */
int ns_run_render_frame(NsRunRender *rr, NsSceneInput *in, const char *const *hud, int nhud,
                        char *err, int err_sz);
/* The last frame again, n times, to the frames folder and the video (slow motion). */
int ns_run_render_repeat(NsRunRender *rr, long n, char *err, int err_sz);
/* A title card (render/card.h) as `frames` frames of the frames folder and the video. */
int ns_run_render_card(NsRunRender *rr, const char *title, const char *text, long frames, char *err,
                       int err_sz);
/* A chapter of the video, titled title, from the next frame on (ffmpeg's chapter metadata,
 * added when the video is finished). */
int ns_run_render_chapter(NsRunRender *rr, const char *title, char *err, int err_sz);
/* A key moment for the contact sheet (the last of NS_RUN_MOMENTS slots is kept for the end:
 * later moments past the others are dropped, `final` always replaces the last). */
int ns_run_render_moment(NsRunRender *rr, NsSceneInput *in, const char *const *hud, int nhud,
                         const char *caption, bool final, char *err, int err_sz);
/* Writes the contact sheet (chart, when not NULL, below the table) and closes the video, under
 * their temporary names. */
int ns_run_render_finish(NsRunRender *rr, const char *title, const char *const *table, int rows,
                         const NsImage *chart, char *err, int err_sz);
/* Moves the frames folder, the video and the sheet to their names: all or none. */
int ns_run_render_commit(NsRunRender *rr, char *err, int err_sz);
/* Removes what ns_run_render_commit put in place (a later output failed). */
void ns_run_render_uncommit(NsRunRender *rr);
/* Removes whatever was written, committed or not (a failed run), and frees. */
void ns_run_render_abort(NsRunRender *rr);
void ns_run_render_free(NsRunRender *rr);
/* Median milliseconds a frame took to render (draw and read back, HUD included) and to encode
 * (PNG and video). */
void ns_run_render_medians(const NsRunRender *rr, double *render_ms, double *encode_ms);

#endif
