/* Tests for render/image.c, render/text.c and render/video.c: PNG round trip, scaled blit and
 * alpha rectangle arithmetic, text bounds, widths and determinism, and an H.264 MP4 from ffmpeg
 * checked with ffprobe (ffmpeg is a declared dependency: its absence fails the test). */
#include "image.h"
#include "ns_test.h"
#include "text.h"
#include "video.h"

#include <stdlib.h>
#include <unistd.h>

/* Makes a fresh directory under /tmp into dir (at least 64 bytes). */
static int make_tmp_dir(char *dir)
{
    snprintf(dir, 64, "/tmp/ns_render_io_XXXXXX");
    return mkdtemp(dir) ? 0 : -1;
}

static int png_round_trip(void)
{
    char dir[64], path[96], err[256] = "";
    ENSURE(make_tmp_dir(dir) == 0);
    snprintf(path, sizeof path, "%s/a.png", dir);
    NsImage a = {0}, b = {0};
    ENSURE(ns_image_alloc(&a, 37, 23, err, sizeof err) == 0);
    for (int i = 0; i < 37 * 23 * 3; i++)
        a.rgb[i] = (uint8_t)(i * 7 + i / 111);
    int wrote = ns_image_write_png(&a, path, err, sizeof err);
    int read = wrote == 0 ? ns_image_read_png(&b, path, err, sizeof err) : -1;
    int same = read == 0 && b.w == 37 && b.h == 23 && memcmp(a.rgb, b.rgb, 37 * 23 * 3) == 0;
    unlink(path);
    rmdir(dir);
    ns_image_free(&a);
    ns_image_free(&b);
    ENSURE(wrote == 0 && read == 0 && same);
    /* Errors: a missing file, a directory that does not exist, a bad size. */
    ENSURE(ns_image_read_png(&b, "/nonexistent/x.png", err, sizeof err) == -1);
    ENSURE(strstr(err, "/nonexistent/x.png") != NULL && b.rgb == NULL);
    ENSURE(ns_image_alloc(&a, 2, 2, err, sizeof err) == 0);
    ENSURE(ns_image_write_png(&a, "/nonexistent/y.png", err, sizeof err) == -1);
    ns_image_free(&a);
    ENSURE(ns_image_alloc(&a, 0, 5, err, sizeof err) == -1 && a.rgb == NULL);
    ns_image_free(&a);
    return 0;
}

static int blit_scaled_averages(void)
{
    char err[256];
    NsImage src = {0}, dst = {0};
    ENSURE(ns_image_alloc(&src, 4, 4, err, sizeof err) == 0);
    ENSURE(ns_image_alloc(&dst, 4, 4, err, sizeof err) == 0);
    /* Columns alternate red / blue; row 3 is all green. */
    for (int r = 0; r < 4; r++)
        for (int c = 0; c < 4; c++) {
            uint8_t *p = src.rgb + (r * 4 + c) * 3;
            p[0] = r < 3 && c % 2 == 0 ? 200 : 0;
            p[1] = r == 3 ? 100 : 0;
            p[2] = r < 3 && c % 2 == 1 ? 60 : 0;
        }
    ns_image_blit_scaled(&dst, 1, 1, 2, 2, &src);
    const uint8_t want_top[3] = {100, 0, 30}, want_bottom[3] = {50, 50, 15}, zero[3] = {0};
    for (int c = 1; c <= 2; c++) {
        ENSURE(memcmp(dst.rgb + (1 * 4 + c) * 3, want_top, 3) == 0);
        ENSURE(memcmp(dst.rgb + (2 * 4 + c) * 3, want_bottom, 3) == 0);
    }
    ENSURE(memcmp(dst.rgb, zero, 3) == 0 && memcmp(dst.rgb + 15 * 3, zero, 3) == 0);
    /* Growing is nearest-pixel: 4x4 into 8x8 (clipped at the image's corner) repeats pixels. */
    NsImage big = {0};
    ENSURE(ns_image_alloc(&big, 8, 8, err, sizeof err) == 0);
    ns_image_blit_scaled(&big, -2, -2, 8, 8, &src); /* source pixel (c, r) -> 2c-2.., 2r-2.. */
    for (int r = 0; r < 6; r++)
        for (int c = 0; c < 6; c++)
            ENSURE(memcmp(big.rgb + (r * 8 + c) * 3, src.rgb + ((r + 2) / 2 * 4 + (c + 2) / 2) * 3,
                          3) == 0);
    ENSURE(memcmp(big.rgb + (7 * 8 + 7) * 3, zero, 3) == 0);
    ns_image_free(&big);
    ns_image_free(&src);
    ns_image_free(&dst);
    return 0;
}

static int fill_rect_blends(void)
{
    char err[256];
    NsImage im = {0};
    ENSURE(ns_image_alloc(&im, 5, 4, err, sizeof err) == 0);
    const uint8_t grey[3] = {100, 100, 100}, white[3] = {255, 255, 255}, red[3] = {255, 0, 0};
    ns_image_fill(&im, grey);
    ns_image_fill_rect(&im, 3, -1, 10, 3, white, 0.25); /* clipped to x 3..4, y 0..1 */
    ns_image_fill_rect(&im, 0, 3, 2, 1, red, 1.0);
    ns_image_fill_rect(&im, 0, 0, 1, 1, red, 0.0);
    for (int r = 0; r < 4; r++)
        for (int c = 0; c < 5; c++) {
            const uint8_t *p = im.rgb + (r * 5 + c) * 3;
            if (c >= 3 && r <= 1) /* 100 + 0.25 (255 - 100) = 138.75 */
                ENSURE(p[0] == 139 && p[1] == 139 && p[2] == 139);
            else if (r == 3 && c < 2)
                ENSURE(p[0] == 255 && p[1] == 0 && p[2] == 0);
            else
                ENSURE(p[0] == 100 && p[1] == 100 && p[2] == 100);
        }
    ns_image_fill_rect(&im, 0, 0, 5, 4, grey, 0.5); /* 0.5 (255 + 100) = 177.5 -> 178 */
    ENSURE(im.rgb[(3 * 5) * 3] == 178 && im.rgb[(3 * 5) * 3 + 1] == 50);
    ns_image_free(&im);
    return 0;
}

static int font_draws_inside_bounds(void)
{
    char err[256];
    NsFont *f = ns_font_open(16, 0, err, sizeof err);
    if (!f)
        fprintf(stderr, "%s\n", err);
    ENSURE(f != NULL);
    NsImage a = {0}, b = {0};
    ENSURE(ns_image_alloc(&a, 200, 40, err, sizeof err) == 0);
    ENSURE(ns_image_alloc(&b, 200, 40, err, sizeof err) == 0);
    const uint8_t white[3] = {255, 255, 255};
    const char *s = "Depth 12.5 mm";
    const int x = 10, y = 25, asc = ns_font_ascent(f), lh = ns_font_line_height(f);
    const int m = ns_font_measure(f, s);
    ENSURE(asc > 8 && asc < 20 && lh >= asc && lh < 30 && m > 50 && m < 150);
    ENSURE(ns_font_draw(f, &a, x, y, s, white) == m);
    ENSURE(ns_font_draw(f, &b, x, y, s, white) == m);
    ENSURE(memcmp(a.rgb, b.rgb, 200 * 40 * 3) == 0);
    int lit = 0, full = 0;
    for (int r = 0; r < 40; r++)
        for (int c = 0; c < 200; c++) {
            const uint8_t *p = a.rgb + (r * 200 + c) * 3;
            if (p[0] == 0)
                continue;
            ENSURE(p[0] == p[1] && p[1] == p[2]); /* white over black stays grey */
            ENSURE(c >= x && c <= x + m && r >= y - asc && r <= y + lh);
            lit++;
            full += p[0] == 255;
        }
    ENSURE(lit > 100 && full > 20);
    ENSURE(ns_font_measure(f, "MM") > ns_font_measure(f, "ii"));
    /* UTF-8: two-byte signs are real glyphs, an unknown code point still advances. */
    ENSURE(ns_font_measure(f, "\xC2\xB0") > 0 && ns_font_measure(f, "\xCE\xBC\xC2\xB1") > 0);
    ENSURE(ns_font_measure(f, "\xEE\x80\x80") > 0); /* U+E000, private use: missing glyph */
    ENSURE(ns_font_measure(f, "a\xFF") > ns_font_measure(f, "a")); /* bad byte: U+FFFD */
    ENSURE(ns_font_draw(f, &a, -500, 1000, s, white) == m);        /* fully clipped */
    ns_font_close(f);
    f = ns_font_open(16, 1, err, sizeof err); /* monospace: equal advances */
    ENSURE(f != NULL);
    ENSURE(ns_font_measure(f, "MM") == ns_font_measure(f, "ii"));
    ns_font_close(f);
    ENSURE(ns_font_open(1, 0, err, sizeof err) == NULL);
    ns_image_free(&a);
    ns_image_free(&b);
    return 0;
}

static int video_encodes_h264(void)
{
    char err[512] = "";
    ENSURE(ns_video_open("/tmp/never.mp4", 63, 48, 25.0, err, sizeof err) == NULL);
    ENSURE(strstr(err, "63") != NULL && strstr(err, "even") != NULL);
    if (!ns_video_have_ffmpeg()) {
        fprintf(stderr, "ffmpeg not found on PATH (apt install ffmpeg)\n");
        return 1;
    }
    char dir[64], path[96];
    ENSURE(make_tmp_dir(dir) == 0);
    snprintf(path, sizeof path, "%s/out 'x'.mp4.part", dir); /* odd characters, no extension */
    NsImage im = {0};
    ENSURE(ns_image_alloc(&im, 64, 48, err, sizeof err) == 0);
    NsVideo *v = ns_video_open(path, 64, 48, 25.0, err, sizeof err);
    int ok = v != NULL;
    const uint8_t bg[3] = {20, 30, 40}, fg[3] = {250, 200, 0};
    for (int i = 0; i < 10 && ok; i++) {
        ns_image_fill(&im, bg);
        ns_image_fill_rect(&im, 4 * i, 10, 16, 16, fg, 1.0);
        ok = ns_video_frame(v, &im, err, sizeof err) == 0;
    }
    NsImage wrong = {0};
    if (ok && ns_image_alloc(&wrong, 32, 48, err, sizeof err) == 0)
        ok = ns_video_frame(v, &wrong, err, sizeof err) == -1; /* wrong size refused */
    ns_image_free(&wrong);
    if (v)
        ok = ns_video_close(v, err, sizeof err) == 0 && ok;
    char out[256] = "", cmd[512];
    if (ok) {
        snprintf(cmd, sizeof cmd,
                 "ffprobe -v error -select_streams v:0 -count_frames -show_entries "
                 "stream=codec_name,width,height,pix_fmt,nb_read_frames -of csv=p=0 "
                 "'%s/out '\\''x'\\''.mp4.part'",
                 dir);
        FILE *p = popen(cmd, "r");
        if (p) {
            size_t n = fread(out, 1, sizeof out - 1, p);
            out[n] = '\0';
            ok = pclose(p) == 0;
        }
    }
    if (!ok)
        fprintf(stderr, "video: %s\n", err);
    unlink(path);
    rmdir(dir);
    ns_image_free(&im);
    ENSURE(ok);
    ENSURE(strcmp(out, "h264,64,48,yuv420p,10\n") == 0);
    /* A failing ffmpeg (an unwritable directory) reports its last line; abort is clean. */
    v = ns_video_open("/nonexistent/dir/x.mp4", 64, 48, 25.0, err, sizeof err);
    ENSURE(v != NULL);
    ENSURE(ns_video_close(v, err, sizeof err) == -1);
    ENSURE(strstr(err, "ffmpeg failed") != NULL && strchr(err, '\n') == NULL);
    v = ns_video_open("/tmp/ns_render_io_never.mp4", 64, 48, 25.0, err, sizeof err);
    ENSURE(v != NULL);
    ns_video_abort(v);
    unlink("/tmp/ns_render_io_never.mp4");
    return 0;
}

NS_TEST_MAIN({"png_round_trip", png_round_trip}, {"blit_scaled_averages", blit_scaled_averages},
             {"fill_rect_blends", fill_rect_blends},
             {"font_draws_inside_bounds", font_draws_inside_bounds},
             {"video_encodes_h264", video_encodes_h264})
