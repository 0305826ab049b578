/* RGB8 images: allocation, fills, an alpha-blended rectangle, a scaled blit (separable area
 * average when shrinking, nearest pixel when growing) and PNG input/output with libpng. */
#include "image.h"

#include <errno.h>
#include <png.h>
#include <setjmp.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define NS_IMAGE_MAX 16384

int ns_image_alloc(NsImage *im, int w, int h, char *err, int err_sz)
{
    memset(im, 0, sizeof *im);
    if (w < 1 || h < 1 || w > NS_IMAGE_MAX || h > NS_IMAGE_MAX) {
        snprintf(err, err_sz, "image size %d x %d out of range (1..%d each)", w, h, NS_IMAGE_MAX);
        return -1;
    }
    im->rgb = calloc((size_t)w * (size_t)h, 3);
    if (!im->rgb) {
        snprintf(err, err_sz, "out of memory for a %d x %d image", w, h);
        return -1;
    }
    im->w = w;
    im->h = h;
    return 0;
}

void ns_image_free(NsImage *im)
{
    free(im->rgb);
    memset(im, 0, sizeof *im);
}

void ns_image_fill(NsImage *im, const uint8_t rgb[3])
{
    size_t n = (size_t)im->w * (size_t)im->h;
    for (size_t i = 0; i < n; i++)
        memcpy(im->rgb + 3 * i, rgb, 3);
}

/* Clips the span [pos, pos + len) to [0, limit); returns 0 if nothing is left. */
static int clip_span(int pos, int len, int limit, int *lo, int *hi)
{
    long long a = pos, b = (long long)pos + len;
    if (a < 0)
        a = 0;
    if (b > limit)
        b = limit;
    if (len <= 0 || a >= b)
        return 0;
    *lo = (int)a;
    *hi = (int)b;
    return 1;
}

void ns_image_fill_rect(NsImage *im, int x, int y, int w, int h, const uint8_t rgb[3], double alpha)
{
    int x0, x1, y0, y1;
    if (!(alpha > 0.0) || !clip_span(x, w, im->w, &x0, &x1) || !clip_span(y, h, im->h, &y0, &y1))
        return;
    if (alpha > 1.0)
        alpha = 1.0;
    for (int r = y0; r < y1; r++) {
        uint8_t *p = im->rgb + ((size_t)r * (size_t)im->w + (size_t)x0) * 3;
        for (int c = x0; c < x1; c++, p += 3)
            for (int k = 0; k < 3; k++) {
                double v = p[k] + (rgb[k] - p[k]) * alpha;
                p[k] = (uint8_t)(v + 0.5);
            }
    }
}

/* Resampling taps along one axis for destination pixels d0 .. d1-1 of a destination of size dn
 * drawn from a source of size sn: pixel d reads the source pixels first[d-d0] ..
 * first[d-d0]+count[d-d0]-1 with integer weights wts[(d-d0)*taps + k], which sum to *total. */
typedef struct Taps {
    int taps, total;
    int *first, *count, *wts;
} Taps;

static int taps_build(Taps *t, int sn, int dn, int d0, int d1)
{
    int n = d1 - d0;
    t->taps = dn >= sn ? 1 : sn / dn + 2;
    t->total = dn >= sn ? 1 : sn;
    t->first = malloc(sizeof(int) * (size_t)n);
    t->count = malloc(sizeof(int) * (size_t)n);
    t->wts = malloc(sizeof(int) * (size_t)n * (size_t)t->taps);
    if (!t->first || !t->count || !t->wts)
        return -1;
    for (int d = d0; d < d1; d++) {
        int i = d - d0;
        if (dn >= sn) { /* nearest: the source pixel under the destination pixel's centre */
            t->first[i] = (int)(((2LL * d + 1) * sn) / (2LL * dn));
            t->count[i] = 1;
            t->wts[i] = 1;
            continue;
        }
        /* Area: destination pixel d covers [d sn, (d+1) sn), source pixel s covers
         * [s dn, (s+1) dn), both in units of 1 / (sn dn) of the full extent. */
        long long lo = (long long)d * sn, hi = lo + sn;
        int s0 = (int)(lo / dn), k = 0;
        t->first[i] = s0;
        for (int s = s0; s < sn && (long long)s * dn < hi; s++) {
            long long a = (long long)s * dn, b = a + dn;
            if (a < lo)
                a = lo;
            if (b > hi)
                b = hi;
            t->wts[(size_t)i * (size_t)t->taps + (size_t)k++] = (int)(b - a);
        }
        t->count[i] = k;
    }
    return 0;
}

static void taps_free(Taps *t)
{
    free(t->first);
    free(t->count);
    free(t->wts);
}

void ns_image_blit_scaled(NsImage *dst, int x, int y, int w, int h, const NsImage *src)
{
    int x0, x1, y0, y1;
    if (!src->rgb || src->w < 1 || src->h < 1 || !clip_span(x, w, dst->w, &x0, &x1) ||
        !clip_span(y, h, dst->h, &y0, &y1))
        return;
    Taps tx = {0}, ty = {0};
    if (taps_build(&tx, src->w, w, x0 - x, x1 - x) == 0 &&
        taps_build(&ty, src->h, h, y0 - y, y1 - y) == 0) {
        unsigned long long total = (unsigned long long)tx.total * (unsigned long long)ty.total;
        for (int r = y0; r < y1; r++) {
            int iy = r - y0;
            const int *wy = ty.wts + (size_t)iy * (size_t)ty.taps;
            uint8_t *out = dst->rgb + ((size_t)r * (size_t)dst->w + (size_t)x0) * 3;
            for (int c = x0; c < x1; c++, out += 3) {
                int ix = c - x0;
                const int *wx = tx.wts + (size_t)ix * (size_t)tx.taps;
                unsigned long long acc[3] = {0, 0, 0};
                for (int j = 0; j < ty.count[iy]; j++) {
                    const uint8_t *row = src->rgb + (size_t)(ty.first[iy] + j) * (size_t)src->w * 3;
                    for (int i = 0; i < tx.count[ix]; i++) {
                        const uint8_t *p = row + (size_t)(tx.first[ix] + i) * 3;
                        unsigned long long wgt =
                            (unsigned long long)wy[j] * (unsigned long long)wx[i];
                        acc[0] += wgt * p[0];
                        acc[1] += wgt * p[1];
                        acc[2] += wgt * p[2];
                    }
                }
                for (int k = 0; k < 3; k++)
                    out[k] = (uint8_t)((acc[k] + total / 2) / total);
            }
        }
    }
    taps_free(&tx);
    taps_free(&ty);
}

/* libpng error context: the message of the first error, then a longjmp back. */
typedef struct PngErr {
    char *err;
    int err_sz;
    const char *path;
} PngErr;

static void png_err_fn(png_structp png, png_const_charp msg)
{
    PngErr *e = png_get_error_ptr(png);
    snprintf(e->err, e->err_sz, "PNG %s: %s", e->path, msg);
    png_longjmp(png, 1);
}

static void png_warn_fn(png_structp png, png_const_charp msg)
{
    (void)png;
    (void)msg;
}

int ns_image_write_png(const NsImage *im, const char *path, char *err, int err_sz)
{
    if (!im->rgb || im->w < 1 || im->h < 1) {
        snprintf(err, err_sz, "cannot write PNG %s: empty image", path);
        return -1;
    }
    FILE *fp = fopen(path, "wb");
    if (!fp) {
        snprintf(err, err_sz, "cannot create PNG %s: %s", path, strerror(errno));
        return -1;
    }
    PngErr e = {err, err_sz, path};
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &e, png_err_fn, png_warn_fn);
    png_infop info = png ? png_create_info_struct(png) : NULL;
    if (!info) {
        snprintf(err, err_sz, "cannot write PNG %s: out of memory", path);
        png_destroy_write_struct(&png, NULL);
        fclose(fp);
        remove(path);
        return -1;
    }
    if (setjmp(png_jmpbuf(png))) {
        png_destroy_write_struct(&png, &info);
        fclose(fp);
        remove(path);
        return -1;
    }
    png_init_io(png, fp);
    png_set_IHDR(png, info, (png_uint_32)im->w, (png_uint_32)im->h, 8, PNG_COLOR_TYPE_RGB,
                 PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_write_info(png, info);
    for (int r = 0; r < im->h; r++)
        png_write_row(png, im->rgb + (size_t)r * (size_t)im->w * 3);
    png_write_end(png, NULL);
    png_destroy_write_struct(&png, &info);
    int bad = ferror(fp);
    if (fclose(fp) != 0 || bad) {
        snprintf(err, err_sz, "cannot write PNG %s: %s", path, strerror(errno ? errno : EIO));
        remove(path);
        return -1;
    }
    return 0;
}

int ns_image_read_png(NsImage *im, const char *path, char *err, int err_sz)
{
    memset(im, 0, sizeof *im);
    FILE *fp = fopen(path, "rb");
    if (!fp) {
        snprintf(err, err_sz, "cannot open PNG %s: %s", path, strerror(errno));
        return -1;
    }
    PngErr e = {err, err_sz, path};
    png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &e, png_err_fn, png_warn_fn);
    png_infop info = png ? png_create_info_struct(png) : NULL;
    if (!info) {
        snprintf(err, err_sz, "cannot read PNG %s: out of memory", path);
        png_destroy_read_struct(&png, NULL, NULL);
        fclose(fp);
        return -1;
    }
    if (setjmp(png_jmpbuf(png))) {
        png_destroy_read_struct(&png, &info, NULL);
        fclose(fp);
        ns_image_free(im);
        return -1;
    }
    png_init_io(png, fp);
    png_read_info(png, info);
    png_uint_32 w = png_get_image_width(png, info), h = png_get_image_height(png, info);
    int depth = png_get_bit_depth(png, info), type = png_get_color_type(png, info);
    if (depth != 8 || (type != PNG_COLOR_TYPE_RGB && type != PNG_COLOR_TYPE_RGB_ALPHA))
        png_error(png, "not an 8-bit RGB or RGBA image");
    if (type == PNG_COLOR_TYPE_RGB_ALPHA)
        png_set_strip_alpha(png);
    int passes = png_set_interlace_handling(png);
    png_read_update_info(png, info);
    if (w > NS_IMAGE_MAX || h > NS_IMAGE_MAX)
        png_error(png, "image too large");
    char aerr[160];
    if (ns_image_alloc(im, (int)w, (int)h, aerr, (int)sizeof aerr) != 0)
        png_error(png, aerr);
    for (int p = 0; p < passes; p++)
        for (int r = 0; r < im->h; r++)
            png_read_row(png, im->rgb + (size_t)r * (size_t)im->w * 3, NULL);
    png_read_end(png, NULL);
    png_destroy_read_struct(&png, &info, NULL);
    fclose(fp);
    return 0;
}

static uint8_t luma(const uint8_t *c)
{
    return (uint8_t)((2 * c[0] + 5 * c[1] + c[2]) >> 3);
}

void ns_image_smooth_edges(NsImage *im, int x, int w, uint8_t *scratch)
{
    if (!im->rgb || x < 0 || w < 3 || x + w > im->w || im->h < 3)
        return;
    size_t row = (size_t)w * 3, stride = (size_t)im->w * 3;
    /* the lumas first; then each row blended from an unchanged copy of it and of the row above
     * (the row below is not changed yet) */
    uint8_t *L = scratch, *prev = scratch + (size_t)w * im->h, *cur = prev + row;
    for (int y = 0; y < im->h; y++) {
        const uint8_t *src = im->rgb + y * stride + (size_t)x * 3;
        for (int i = 0; i < w; i++)
            L[(size_t)y * w + i] = luma(src + 3 * i);
    }
    memcpy(prev, im->rgb + (size_t)x * 3, row);
    for (int y = 1; y + 1 < im->h; y++) {
        uint8_t *out = im->rgb + y * stride + (size_t)x * 3;
        const uint8_t *down = out + stride, *ly = L + (size_t)y * w;
        memcpy(cur, out, row);
        for (int i = 1; i + 1 < w; i++) {
            int lc = ly[i], ln = ly[i - w], ls = ly[i + w], le = ly[i + 1], lw = ly[i - 1];
            int lo = lc < ln ? lc : ln, hi = lc > ln ? lc : ln;
            lo = ls < lo ? ls : lo;
            hi = ls > hi ? ls : hi;
            lo = le < lo ? le : lo;
            hi = le > hi ? le : hi;
            lo = lw < lo ? lw : lo;
            hi = lw > hi ? lw : hi;
            if (hi - lo < 24)
                continue;
            bool vertical = abs(ln + ls - 2 * lc) >= abs(le + lw - 2 * lc);
            const uint8_t *c = cur + 3 * i, *a = vertical ? prev + 3 * i : c + 3,
                          *b = vertical ? down + 3 * i : c - 3;
            for (int k = 0; k < 3; k++)
                out[3 * i + k] = (uint8_t)((2 * c[k] + a[k] + b[k] + 2) >> 2);
        }
        uint8_t *t = prev;
        prev = cur;
        cur = t;
    }
}
