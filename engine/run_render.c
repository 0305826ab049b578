/* Frames, video and contact sheet of a run (run_render.h). */
#include "run_render.h"

#include "card.h"
#include "cleanup.h"
#include "out_files.h"

#include <dirent.h>
#include <stdbool.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "err.h"

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* CPU seconds of the waited-for child processes (ffmpeg). */
static double children_cpu_s(void)
{
    struct rusage ru;
    if (getrusage(RUSAGE_CHILDREN, &ru) != 0)
        return 0.0;
    return (double)ru.ru_utime.tv_sec + 1e-6 * (double)ru.ru_utime.tv_usec +
           (double)ru.ru_stime.tv_sec + 1e-6 * (double)ru.ru_stime.tv_usec;
}

static char *join(const char *dir, const char *name, const char *suffix)
{
    size_t n = strlen(dir) + strlen(name) + strlen(suffix) + 2;
    char *p = malloc(n);
    if (p)
        snprintf(p, n, "%s/%s%s", dir, name, suffix);
    return p;
}

static char *dup_suffix(const char *path, const char *suffix)
{
    size_t n = strlen(path) + strlen(suffix) + 1;
    char *p = malloc(n);
    if (p)
        snprintf(p, n, "%s%s", path, suffix);
    return p;
}

/* A frame's file name: NNNNNN.png (six digits). */
static bool is_frame_name(const char *name)
{
    return strlen(name) == 10 && strcmp(name + 6, ".png") == 0 && strspn(name, "0123456789") == 6;
}

/* Whether dir holds only frames (1), is missing (0), or holds something else or cannot be
 * read (-1). */
static int frames_only(const char *dir)
{
    DIR *d = opendir(dir);
    if (!d)
        return errno == ENOENT ? 0 : -1;
    struct dirent *e;
    int rc = 1;
    while (rc == 1 && (e = readdir(d)))
        if (strcmp(e->d_name, ".") != 0 && strcmp(e->d_name, "..") != 0 &&
            !is_frame_name(e->d_name))
            rc = -1;
    closedir(d);
    return rc;
}

/* Removes the NNNNNN.png files in dir and dir itself (if it then is empty). */
static int remove_frames_dir(const char *dir)
{
    DIR *d = opendir(dir);
    if (!d)
        return errno == ENOENT ? 0 : -1;
    struct dirent *e;
    size_t n = strlen(dir);
    char path[4096];
    while ((e = readdir(d))) {
        size_t len = strlen(e->d_name);
        if (!is_frame_name(e->d_name) || n + len + 2 > sizeof path)
            continue;
        snprintf(path, sizeof path, "%s/%s", dir, e->d_name);
        remove(path);
    }
    closedir(d);
    return rmdir(dir);
}

int ns_run_render_check_old(const char *out_dir, bool frames, char *err, int err_sz)
{
    char *sheet = join(out_dir, "summary.png", ""), *dir = join(out_dir, "frames", "");
    int rc = 0;
    if (!sheet || !dir) {
        ns_set_err(err, err_sz, "out of memory");
        rc = -1;
    } else if (ns_out_replaceable(sheet, "the contact sheet", err, err_sz)) {
        rc = -1;
    } else {
        struct stat st;
        if (lstat(dir, &st) == 0 && !S_ISDIR(st.st_mode)) {
            ns_set_err(err, err_sz,
                       "'%s' exists and is not a folder: refusing to write frames there or "
                       "remove it",
                       dir);
            free(sheet);
            free(dir);
            return -1;
        }
        int only = frames_only(dir);
        if (only < 0 && frames) {
            ns_set_err(err, err_sz,
                       "--frames: '%s' holds files other than frames (NNNNNN.png): move them "
                       "or write to another folder",
                       dir);
            rc = -1;
        }
        /* The old sheet and frames stay until this run's replace them (ns_run_render_commit):
         * a failed run leaves them as they were. */
    }
    free(sheet);
    free(dir);
    return rc;
}

int ns_run_render_open(NsRunRender *rr, const NsRunRenderOpts *o, char *err, int err_sz)
{
    memset(rr, 0, sizeof *rr);
    rr->o = *o;
    if (o->video && !ns_video_have_ffmpeg()) {
        ns_set_err(err, err_sz,
                   "--video needs the ffmpeg program (apt install ffmpeg): not found on PATH");
        return -1;
    }
    if (o->frames) {
        rr->frames_dir = join(o->out_dir, "frames", "");
        rr->frames_tmp = join(o->out_dir, "frames", ".part");
        if (!rr->frames_dir || !rr->frames_tmp) {
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
        struct stat st;
        if (lstat(rr->frames_tmp, &st) == 0 && !S_ISDIR(st.st_mode)) {
            ns_set_err(err, err_sz, "'%s' exists and is not a folder: refusing to replace it",
                       rr->frames_tmp);
            return -1;
        }
        remove_frames_dir(rr->frames_tmp); /* a crashed run's leftovers */
        if (mkdir(rr->frames_tmp, 0777) != 0 || ns_cleanup_add(rr->frames_tmp) != 0) {
            ns_set_err(err, err_sz, "cannot make the frames folder '%s': %s", rr->frames_tmp,
                       strerror(errno));
            return -1;
        }
    }
    if (o->summary) {
        rr->summary_path = join(o->out_dir, "summary.png", "");
        rr->summary_tmp = join(o->out_dir, "summary.png", ".part");
        if (!rr->summary_path || !rr->summary_tmp) {
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
        if (ns_out_replaceable(rr->summary_tmp, "the contact sheet", err, err_sz) ||
            ns_cleanup_add(rr->summary_tmp) != 0)
            return -1;
    }
    if (ns_frame_open_samples(&rr->frame, o->width, o->height, o->samples ? o->samples : 1, err,
                              err_sz))
        return -1;
    if (o->video) {
        rr->video_tmp = dup_suffix(o->video, ".part");
        if (!rr->video_tmp) {
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
        if (ns_out_replaceable(rr->video_tmp, "the video", err, err_sz) ||
            ns_cleanup_add(rr->video_tmp) != 0)
            return -1;
        ns_out_remove_old(rr->video_tmp);
        rr->children_cpu0 = children_cpu_s();
        rr->video = ns_video_open(rr->video_tmp, o->width, o->height, o->fps, err, err_sz);
        if (!rr->video)
            return -1;
    }
    return 0;
}

static int push_timing(NsRunRender *rr, double render_ms, double encode_ms)
{
    if (rr->timed >= rr->timing_cap) {
        long cap = rr->timing_cap ? 2 * rr->timing_cap : 256;
        double *a = realloc(rr->render_ms, (size_t)cap * sizeof *a);
        if (a)
            rr->render_ms = a;
        double *b = a ? realloc(rr->encode_ms, (size_t)cap * sizeof *b) : NULL;
        if (b)
            rr->encode_ms = b;
        if (!a || !b)
            return -1;
        rr->timing_cap = cap;
    }
    rr->render_ms[rr->timed] = render_ms;
    rr->encode_ms[rr->timed] = encode_ms;
    rr->timed++;
    return 0;
}

/* rr->image to the frames folder (its next number) and the video. */
static int emit(NsRunRender *rr, char *err, int err_sz)
{
    if (rr->frame_count >= 1000000) {
        ns_set_err(err, err_sz, "more than 999,999 frames: give a larger --frame-every");
        return -1;
    }
    if (rr->o.frames) {
        char name[32];
        snprintf(name, sizeof name, "%06ld.png", rr->frame_count);
        char *path = join(rr->frames_tmp, name, "");
        int rc = path ? ns_image_write_png(&rr->image, path, err, err_sz) : -1;
        if (!path)
            ns_set_err(err, err_sz, "out of memory");
        free(path);
        if (rc)
            return -1;
    }
    if (rr->video && ns_video_frame(rr->video, &rr->image, err, err_sz))
        return -1;
    rr->frame_count++;
    return 0;
}

/* The authored video's fonts, opened at its first caption or card. */
static int video_fonts(NsRunRender *rr, char *err, int err_sz)
{
    int h = rr->o.height;
    if (!rr->caption_font)
        rr->caption_font = ns_font_open(h / 24 < 12 ? 12 : h / 24, 0, err, err_sz);
    if (rr->caption_font && !rr->title_font)
        rr->title_font = ns_font_open(h / 12 < 16 ? 16 : h / 12, 0, err, err_sz);
    return rr->title_font ? 0 : -1;
}

int ns_run_render_repeat(NsRunRender *rr, long n, char *err, int err_sz)
{
    for (long i = 0; i < n && (rr->o.frames || rr->video); i++)
        if (emit(rr, err, err_sz))
            return -1;
    return 0;
}

int ns_run_render_card(NsRunRender *rr, const char *title, const char *text, long frames, char *err,
                       int err_sz)
{
    if (!rr->o.frames && !rr->video)
        return 0;
    if (video_fonts(rr, err, err_sz))
        return -1;
    ns_card_title(&rr->image, rr->title_font, rr->caption_font, title, text);
    return ns_run_render_repeat(rr, frames, err, err_sz);
}

int ns_run_render_chapter(NsRunRender *rr, const char *title, char *err, int err_sz)
{
    if (!rr->video)
        return 0;
    if (rr->chapters == rr->chapter_cap) {
        int cap = rr->chapter_cap ? 2 * rr->chapter_cap : 8;
        char **t = realloc(rr->chapter_title, (size_t)cap * sizeof *t);
        if (t)
            rr->chapter_title = t;
        double *c = t ? realloc(rr->chapter_s, (size_t)cap * sizeof *c) : NULL;
        if (c)
            rr->chapter_s = c;
        if (!t || !c) {
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
        rr->chapter_cap = cap;
    }
    char *dup = strdup(title);
    if (!dup) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    rr->chapter_title[rr->chapters] = dup;
    rr->chapter_s[rr->chapters++] = (double)rr->frame_count / rr->o.fps;
    return 0;
}

int ns_run_render_frame(NsRunRender *rr, NsSceneInput *in, const char *const *hud, int nhud,
                        char *err, int err_sz)
{
    if (!rr->o.frames && !rr->o.video)
        return 0;
    double t0 = now_s();
    const int *views = rr->frame_nviews > 0 ? rr->frame_views : rr->o.views;
    int nviews = rr->frame_nviews > 0 ? rr->frame_nviews : rr->o.nviews;
    if (ns_frame_render(&rr->frame, in, views, nviews, hud, nhud, rr->o.legend, &rr->image, err,
                        err_sz))
        return -1;
    if (rr->caption && rr->caption[0]) {
        if (video_fonts(rr, err, err_sz))
            return -1;
        ns_card_caption(&rr->image, rr->caption_font, rr->caption);
    }
    double t1 = now_s();
    if (emit(rr, err, err_sz))
        return -1;
    double t2 = now_s();
    rr->render_s += t2 - t0;
    if (push_timing(rr, 1e3 * (t1 - t0), 1e3 * (t2 - t1))) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    return 0;
}

int ns_run_render_moment(NsRunRender *rr, NsSceneInput *in, const char *const *hud, int nhud,
                         const char *caption, bool final, char *err, int err_sz)
{
    if (!rr->o.summary)
        return 0;
    int slot = rr->moment_count;
    if (final)
        slot = slot < NS_RUN_MOMENTS ? slot : NS_RUN_MOMENTS - 1;
    else if (slot >= NS_RUN_MOMENTS - 1)
        return 0; /* the sheet is full: the last slot is the end's */
    double t0 = now_s();
    if (ns_frame_render(&rr->frame, in, rr->o.views, rr->o.nviews, hud, nhud, false, &rr->image,
                        err, err_sz))
        return -1;
    NsRunMoment *m = &rr->moments[slot];
    int tw = rr->o.width / 3, th = rr->o.height / 3;
    if (!m->thumb.rgb && ns_image_alloc(&m->thumb, tw, th, err, err_sz))
        return -1;
    ns_image_blit_scaled(&m->thumb, 0, 0, tw, th, &rr->image);
    snprintf(m->caption, sizeof m->caption, "%s", caption);
    if (slot == rr->moment_count)
        rr->moment_count++;
    rr->render_s += now_s() - t0;
    return 0;
}

/* The sheet: a title, the moments three a row with their captions, the score table, a chart. */
static int write_sheet(NsRunRender *rr, const char *title, const char *const *table, int rows,
                       const NsImage *chart, char *err, int err_sz)
{
    static const uint8_t bg[3] = {24, 27, 34}, fg[3] = {235, 238, 242}, dim[3] = {170, 178, 190};
    NsFont *big = ns_font_open(28, 0, err, err_sz);
    NsFont *small = big ? ns_font_open(17, 0, err, err_sz) : NULL;
    NsFont *mono = small ? ns_font_open(17, 1, err, err_sz) : NULL;
    if (!mono) {
        ns_font_close(small);
        ns_font_close(big);
        return -1;
    }
    int n = rr->moment_count, cols = n < 3 ? (n > 0 ? n : 1) : 3, rows_m = (n + cols - 1) / cols;
    int tw = rr->o.width / 3, th = rr->o.height / 3, pad = 16;
    int cap_h = ns_font_line_height(small) + 8, lh = ns_font_line_height(mono);
    int title_h = ns_font_line_height(big) + 2 * pad;
    int W = 3 * tw + 4 * pad, H = title_h + rows_m * (th + cap_h + pad) + pad + rows * lh + pad;
    int wt = ns_font_measure(big, title) + 2 * pad;
    W = wt > W ? wt : W;
    if (chart && chart->rgb) {
        W = chart->w + 2 * pad > W ? chart->w + 2 * pad : W;
        H += chart->h + pad;
    }
    for (int i = 0; i < rows; i++) {
        int wr = ns_font_measure(mono, table[i]) + 2 * pad;
        W = wr > W ? wr : W;
    }
    NsImage sheet = {0};
    if (ns_image_alloc(&sheet, W, H, err, err_sz)) {
        ns_font_close(mono);
        ns_font_close(small);
        ns_font_close(big);
        return -1;
    }
    ns_image_fill(&sheet, bg);
    ns_font_draw(big, &sheet, pad, pad + ns_font_ascent(big), title, fg);
    for (int i = 0; i < n; i++) {
        int x = pad + (i % cols) * (tw + pad), y = title_h + (i / cols) * (th + cap_h + pad);
        ns_image_blit_scaled(&sheet, x, y, tw, th, &rr->moments[i].thumb);
        char label[112];
        snprintf(label, sizeof label, "%d. %s", i + 1, rr->moments[i].caption);
        ns_font_draw(small, &sheet, x, y + th + 4 + ns_font_ascent(small), label, dim);
    }
    int y0 = title_h + rows_m * (th + cap_h + pad) + pad;
    for (int i = 0; i < rows; i++)
        ns_font_draw(mono, &sheet, pad, y0 + i * lh + ns_font_ascent(mono), table[i], fg);
    if (chart && chart->rgb)
        ns_image_blit_scaled(&sheet, pad, y0 + rows * lh + pad, chart->w, chart->h, chart);
    /* A fresh file: whatever is at the temporary name (a hard link to another file, say) is
     * unlinked, not written through; a non-regular one was refused at open. */
    ns_out_remove_old(rr->summary_tmp);
    int rc = ns_out_replaceable(rr->summary_tmp, "the contact sheet", err, err_sz)
                 ? -1
                 : ns_image_write_png(&sheet, rr->summary_tmp, err, err_sz);
    ns_image_free(&sheet);
    ns_font_close(mono);
    ns_font_close(small);
    ns_font_close(big);
    return rc;
}

/* The finished video copied with its chapters, then put in its place (video_tmp). */
static int video_chapters(NsRunRender *rr, char *err, int err_sz)
{
    rr->video_chap_tmp = dup_suffix(rr->o.video, ".chapters.part");
    if (!rr->video_chap_tmp) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    if (ns_out_replaceable(rr->video_chap_tmp, "the video", err, err_sz) ||
        ns_cleanup_add(rr->video_chap_tmp) != 0)
        return -1;
    ns_out_remove_old(rr->video_chap_tmp);
    double end = (double)rr->frame_count / rr->o.fps;
    int rc =
        ns_video_chapters(rr->video_tmp, rr->video_chap_tmp, (const char *const *)rr->chapter_title,
                          rr->chapter_s, rr->chapters, end, err, err_sz);
    if (rc == 0 && rename(rr->video_chap_tmp, rr->video_tmp) != 0) {
        ns_set_err(err, err_sz, "cannot write '%s': %s", rr->video_tmp, strerror(errno));
        rc = -1;
    }
    ns_out_remove_part(rr->video_chap_tmp);
    return rc;
}

int ns_run_render_finish(NsRunRender *rr, const char *title, const char *const *table, int rows,
                         const NsImage *chart, char *err, int err_sz)
{
    double t0 = now_s();
    if (rr->o.summary && write_sheet(rr, title, table, rows, chart, err, err_sz))
        return -1;
    if (rr->video) {
        NsVideo *v = rr->video;
        rr->video = NULL;
        if (ns_video_close(v, err, err_sz))
            return -1;
        rr->ffmpeg_cpu_s = children_cpu_s() - rr->children_cpu0;
        if (rr->chapters > 0 && video_chapters(rr, err, err_sz))
            return -1;
    }
    rr->render_s += now_s() - t0;
    return 0;
}

int ns_run_render_commit(NsRunRender *rr, char *err, int err_sz)
{
    /* Each rename is recorded, so that a failure here or after (the control log) takes every
     * picture back out (ns_run_render_uncommit). */
    if (rr->o.frames) {
        remove_frames_dir(rr->frames_dir); /* frames only: ns_run_render_check_old checked */
        if (rename(rr->frames_tmp, rr->frames_dir) != 0) { /* (a folder: checked at open) */
            ns_set_err(err, err_sz, "cannot write '%s': %s", rr->frames_dir, strerror(errno));
            return -1;
        }
        ns_cleanup_forget(rr->frames_tmp);
        rr->committed |= 1;
    }
    if (rr->o.video) {
        if (ns_out_commit(rr->video_tmp, rr->o.video) != 0) {
            ns_set_err(err, err_sz, "cannot write '%s': %s", rr->o.video, strerror(errno));
            ns_run_render_uncommit(rr);
            return -1;
        }
        rr->committed |= 2;
    }
    if (rr->o.summary) {
        if (ns_out_commit(rr->summary_tmp, rr->summary_path) != 0) {
            ns_set_err(err, err_sz, "cannot write '%s': %s", rr->summary_path, strerror(errno));
            ns_run_render_uncommit(rr);
            return -1;
        }
        rr->committed |= 4;
    }
    return 0;
}

void ns_run_render_uncommit(NsRunRender *rr)
{
    if (rr->committed & 1)
        remove_frames_dir(rr->frames_dir);
    if (rr->committed & 2)
        ns_out_remove_old(rr->o.video);
    if (rr->committed & 4)
        ns_out_remove_old(rr->summary_path);
    rr->committed = 0;
}

void ns_run_render_abort(NsRunRender *rr)
{
    ns_run_render_uncommit(rr);
    if (rr->video) {
        ns_video_abort(rr->video);
        rr->video = NULL;
    }
    if (rr->video_tmp)
        ns_out_remove_part(rr->video_tmp);
    if (rr->video_chap_tmp)
        ns_out_remove_part(rr->video_chap_tmp);
    if (rr->summary_tmp)
        ns_out_remove_part(rr->summary_tmp);
    if (rr->frames_tmp) {
        remove_frames_dir(rr->frames_tmp);
        ns_cleanup_forget(rr->frames_tmp);
    }
    ns_run_render_free(rr);
}

void ns_run_render_free(NsRunRender *rr)
{
    if (rr->video)
        ns_video_abort(rr->video);
    ns_frame_close(&rr->frame);
    ns_image_free(&rr->image);
    for (int i = 0; i < NS_RUN_MOMENTS; i++)
        ns_image_free(&rr->moments[i].thumb);
    free(rr->frames_tmp);
    free(rr->frames_dir);
    free(rr->video_tmp);
    free(rr->summary_tmp);
    free(rr->summary_path);
    free(rr->render_ms);
    free(rr->encode_ms);
    for (int i = 0; i < rr->chapters; i++)
        free(rr->chapter_title[i]);
    free(rr->chapter_title);
    free(rr->chapter_s);
    free(rr->video_chap_tmp);
    ns_font_close(rr->caption_font);
    ns_font_close(rr->title_font);
    memset(rr, 0, sizeof *rr);
}

static int cmp(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double median(const double *v, long n)
{
    if (n <= 0)
        return 0.0;
    double *c = malloc((size_t)n * sizeof *c);
    if (!c)
        return 0.0;
    memcpy(c, v, (size_t)n * sizeof *c);
    qsort(c, (size_t)n, sizeof *c, cmp);
    double m = n % 2 ? c[n / 2] : 0.5 * (c[n / 2 - 1] + c[n / 2]);
    free(c);
    return m;
}

void ns_run_render_medians(const NsRunRender *rr, double *render_ms, double *encode_ms)
{
    *render_ms = median(rr->render_ms, rr->timed);
    *encode_ms = median(rr->encode_ms, rr->timed);
}
