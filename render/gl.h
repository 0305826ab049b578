/* The offscreen renderer (issue 8): an EGL context with no window (the EGL device platform
 * when a GPU is there, Mesa's surfaceless platform and llvmpipe otherwise), OpenGL 3.3 core
 * into a multisampled framebuffer, read back as RGB. It draws NsScene views (render/scene.h). */
#ifndef NS_RENDER_GL_H
#define NS_RENDER_GL_H

#include <stdint.h>

#include "image.h"
#include "scene.h"

typedef struct NsRenderer NsRenderer;

/* A w x h frame with `samples` samples a pixel (1: none). NEEDLESIM_EGL=surfaceless skips the
 * device platform, NEEDLESIM_EGL=device insists on it. NULL with one line in err. */
NsRenderer *ns_renderer_open(int w, int h, int samples, char *err, int err_sz);
void ns_renderer_close(NsRenderer *r);
/* "EGL <platform>, <GL renderer string>, OpenGL <version>". */
const char *ns_renderer_info(const NsRenderer *r);

/* Clears columns [x, x + w) of the frame to bg (the frame's other columns are left as they are:
 * a view drawn on the CPU covers them). */
void ns_renderer_clear(NsRenderer *r, const uint8_t bg[3], int x, int w);
/* Draws s into the viewport (x, y, w, h) of the frame (y counted from the top). -1 on a GL
 * error (err says which). */
int ns_renderer_draw(NsRenderer *r, const NsScene *s, int x, int y, int w, int h, char *err,
                     int err_sz);
/* Starts the drawing queued so far (glFlush): with a software rasterizer the frame is drawn on
 * its threads while the caller goes on, until ns_renderer_read waits for it. */
void ns_renderer_flush(NsRenderer *r);
/* Resolves the samples of columns [x, x + w) and reads them into im (allocated to the frame's
 * size; where it had to be, its other columns are black). */
int ns_renderer_read(NsRenderer *r, NsImage *im, int x, int w, char *err, int err_sz);

#endif
