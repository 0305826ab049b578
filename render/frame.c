/* Composing a debrief frame: views side by side, HUD text over them (render/frame.h). */
#include "frame.h"

#include "trus.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static const uint8_t background[3] = {28, 32, 40}, white[3] = {240, 242, 245}, panel[3] = {0, 0, 0};

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return 1e3 * (double)ts.tv_sec + 1e-6 * (double)ts.tv_nsec;
}

int ns_frame_open_samples(NsFrame *f, int w, int h, int samples, char *err, int err_sz)
{
    memset(f, 0, sizeof *f);
    f->w = w;
    f->h = h;
    int px = h / 34 < 11 ? 11 : h / 34;
    f->scratch = samples <= 1 ? malloc((size_t)w * h * 3) : NULL;
    if (samples <= 1 && !f->scratch) {
        snprintf(err, (size_t)err_sz, "out of memory for %dx%d frames", w, h);
        return -1;
    }
    f->gl = ns_renderer_open(w, h, samples, err, err_sz);
    f->font = f->gl ? ns_font_open(px, 0, err, err_sz) : NULL;
    f->small = f->font ? ns_font_open(px * 3 / 4 < 9 ? 9 : px * 3 / 4, 0, err, err_sz) : NULL;
    if (!f->small) {
        ns_frame_close(f);
        return -1;
    }
    return 0;
}

void ns_frame_close(NsFrame *f)
{
    ns_font_close(f->small);
    ns_font_close(f->font);
    ns_renderer_close(f->gl);
    ns_scene_free(&f->scene);
    free(f->scratch);
    memset(f, 0, sizeof *f);
}

/* Text lines in a dark translucent box at (x, y) (top left). */
static void text_box(NsFont *font, NsImage *im, int x, int y, const char *const *lines, int n)
{
    if (n <= 0)
        return;
    int lh = ns_font_line_height(font), wmax = 0, pad = lh / 3;
    for (int i = 0; i < n; i++) {
        int w = ns_font_measure(font, lines[i]);
        wmax = w > wmax ? w : wmax;
    }
    ns_image_fill_rect(im, x, y, wmax + 2 * pad, n * lh + 2 * pad, panel, 0.55);
    for (int i = 0; i < n; i++)
        ns_font_draw(font, im, x + pad, y + pad + i * lh + ns_font_ascent(font), lines[i], white);
}

static void legend_box(NsFont *font, NsImage *im, int x, int y_bottom)
{
    static const char *names[5] = {"outside", "sticking", "sliding out", "sliding in", "cutting"};
    int lh = ns_font_line_height(font), pad = lh / 3, sw = lh * 2 / 3, wmax = 0;
    for (int i = 0; i < 5; i++) {
        int w = ns_font_measure(font, names[i]);
        wmax = w > wmax ? w : wmax;
    }
    int bw = wmax + sw + 3 * pad, bh = 5 * lh + 2 * pad, y = y_bottom - bh;
    ns_image_fill_rect(im, x, y, bw, bh, panel, 0.55);
    for (int i = 0; i < 5; i++) {
        int yy = y + pad + i * lh;
        ns_image_fill_rect(im, x + pad, yy + (lh - sw) / 2, sw, sw, ns_scene_needle_rgb[i], 1.0);
        ns_font_draw(font, im, x + 2 * pad + sw, yy + ns_font_ascent(font), names[i], white);
    }
}

int ns_frame_render(NsFrame *f, NsSceneInput *in, const int *views, int nviews,
                    const char *const *hud, int nhud, bool legend, NsImage *out, char *err,
                    int err_sz)
{
    double t0 = now_ms(), build = 0.0;
    int vw = f->w / (nviews > 0 ? nviews : 1);
    /* the columns OpenGL draws: every view's but the ones drawn on the CPU at either end
     * (cleared, resolved and read back; a frame of CPU views only skips OpenGL) */
    int nv = nviews > 0 ? nviews : 0, g0 = 0, g1 = nv;
    while (g0 < g1 && views[g0] == NS_VIEW_TRUS)
        g0++;
    while (g1 > g0 && views[g1 - 1] == NS_VIEW_TRUS)
        g1--;
    int gx = g0 * vw, gw = nv == 0 ? f->w : g1 == g0 ? 0 : (g1 == nv ? f->w : g1 * vw) - gx;
    if (gw > 0)
        ns_renderer_clear(f->gl, background, gx, gw);
    for (int k = 0; k < nviews; k++) {
        int x = k * vw, w = k == nviews - 1 ? f->w - x : vw;
        if (views[k] == NS_VIEW_TRUS)
            continue; /* drawn on the read-back image, below */
        NsCamera cam;
        ns_scene_camera(in, (NsView)views[k], (double)w / f->h, &cam);
        double d[3] = {cam.target[0] - cam.eye[0], cam.target[1] - cam.eye[1],
                       cam.target[2] - cam.eye[2]};
        in->px_size = 2.0 * sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) *
                      tan(0.5 * cam.fov_deg * M_PI / 180.0) / f->h;
        double tb = now_ms();
        int built = ns_scene_build(in, (NsView)views[k], (double)w / f->h, &f->scene);
        build += now_ms() - tb;
        if (built) {
            snprintf(err, (size_t)err_sz, "out of memory building the %s view",
                     ns_view_name((NsView)views[k]));
            return -1;
        }
        if (ns_renderer_draw(f->gl, &f->scene, x, 0, w, f->h, err, err_sz))
            return -1;
    }
    /* The views drawn on the CPU outside OpenGL's columns, while OpenGL rasterizes (once the
     * image has the frame's size: before the read-back waits for OpenGL); those between
     * OpenGL's views (read back as background), and all of them in a first frame, after it. */
    bool sized = out->w == f->w && out->h == f->h && out->rgb;
    if (gw > 0 && sized)
        ns_renderer_flush(f->gl);
    if (!sized && gw <= 0) {
        ns_image_free(out);
        if (ns_image_alloc(out, f->w, f->h, err, err_sz))
            return -1;
        sized = true;
    }
    for (int k = 0; sized && k < nviews; k++)
        if (views[k] == NS_VIEW_TRUS && (k < g0 || k >= g1))
            ns_trus_draw(in, out, k * vw, k == nviews - 1 ? f->w - k * vw : vw, f->h);
    if (gw > 0 && ns_renderer_read(f->gl, out, gx, gw, err, err_sz))
        return -1;
    if (gw > 0 && f->scratch)
        ns_image_smooth_edges(out, gx, gw, f->scratch);
    for (int k = 0; k < nviews; k++)
        if (views[k] == NS_VIEW_TRUS && (!sized || (k >= g0 && k < g1)))
            ns_trus_draw(in, out, k * vw, k == nviews - 1 ? f->w - k * vw : vw, f->h);
    double t1 = now_ms();
    f->build_ms = build;
    f->gl_ms = t1 - t0 - build;
    int margin = f->h / 60 + 2;
    for (int k = 0; nviews > 1 && k < nviews; k++) { /* the views' names, bottom right */
        const char *name = ns_view_name((NsView)views[k]);
        int x = (k + 1) * vw - ns_font_measure(f->small, name) - margin * 2;
        if (k == nviews - 1)
            x = f->w - ns_font_measure(f->small, name) - margin * 2;
        text_box(f->small, out, x, f->h - margin - ns_font_line_height(f->small) * 3 / 2, &name, 1);
    }
    text_box(f->font, out, margin, margin, hud, nhud);
    if (legend)
        legend_box(f->small, out, margin, f->h - margin);
    f->text_ms = now_ms() - t1;
    return 0;
}
