/* One debrief frame (issue 8): the scenario's views side by side, each a cutaway of the same
 * state, and the heads-up text over them. */
#ifndef NS_RENDER_FRAME_H
#define NS_RENDER_FRAME_H

#include <stdbool.h>
#include <stdint.h>

#include "gl.h"
#include "image.h"
#include "scene.h"
#include "text.h"

typedef struct NsFrame {
    NsRenderer *gl;
    NsFont *font, *small;
    int w, h;
    NsScene scene; /* reused between views and frames */
    /* the last frame's stages [ms]: building the views' vertex lists; OpenGL (drawing is
     * deferred by llvmpipe to the read-back, so both are here); the HUD text */
    double build_ms, gl_ms, text_ms;
    uint8_t *scratch; /* w * h * 3 bytes for the edge smoothing (one sample a pixel only) */
} NsFrame;

/* A renderer of w x h frames with `samples` samples a pixel and the HUD fonts (1: no
 * multisampling; the OpenGL views' stair steps are then softened on the CPU,
 * ns_image_smooth_edges). */
int ns_frame_open_samples(NsFrame *f, int w, int h, int samples, char *err, int err_sz);
void ns_frame_close(NsFrame *f);

/* Draws views[0 .. nviews) of in side by side into out (w x h), then the HUD lines (top left),
 * the views' names and, with legend, the needle's friction colours. in->px_size is set here. */
int ns_frame_render(NsFrame *f, NsSceneInput *in, const int *views, int nviews,
                    const char *const *hud, int nhud, bool legend, NsImage *out, char *err,
                    int err_sz);

#endif
