/* An 8-bit RGB image in memory (row 0 is the top row), with the few drawing operations the
 * offscreen renderer needs (fill, alpha-blended rectangle, scaled blit) and PNG input/output
 * through libpng. Coordinates and sizes are in pixels. */
#ifndef NS_IMAGE_H
#define NS_IMAGE_H

#include <stdint.h>

typedef struct NsImage {
    int w, h;
    uint8_t *rgb; /* w * h * 3 bytes, row-major, row 0 is the top row */
} NsImage;

/* Allocates a w x h image filled with black; w and h must be in 1..16384. Returns 0, or -1 with a
 * message in err (im is then zeroed). */
int ns_image_alloc(NsImage *im, int w, int h, char *err, int err_sz);

/* Frees the pixels and zeroes im; safe on a zeroed struct and when called twice. */
void ns_image_free(NsImage *im);

/* Sets every pixel to rgb. */
void ns_image_fill(NsImage *im, const uint8_t rgb[3]);

/* Blends a solid rectangle of colour rgb with opacity alpha (clamped to [0, 1]) over the pixels
 * x .. x+w-1, y .. y+h-1, clipped to the image. */
void ns_image_fill_rect(NsImage *im, int x, int y, int w, int h, const uint8_t rgb[3],
                        double alpha);

/* Draws src resampled into the rectangle (x, y, w, h) of dst, clipped to dst: in each direction
 * an area average when shrinking and the nearest source pixel when growing. */
void ns_image_blit_scaled(NsImage *dst, int x, int y, int w, int h, const NsImage *src);

/* Softens the stair steps of an unsampled rasterization in columns [x, x + w) (rows 1 .. h-2):
 * where the lumas of a pixel and its four neighbours span 24 or more, it is averaged half and
 * half with the two neighbours across the edge (the direction whose second difference is larger).
 * A cheap stand-in for multisampling, which costs llvmpipe about as much as the rest of a frame
 * (docs/rendering.md). scratch: w * h + 6 w bytes of the caller's (w * h * 3 holds it). */
void ns_image_smooth_edges(NsImage *im, int x, int w, uint8_t *scratch);

/* Writes im as an 8-bit RGB PNG to exactly path (no temporary name; the caller handles that).
 * Returns 0, or -1 with a message in err; a half-written file is removed. */
int ns_image_write_png(const NsImage *im, const char *path, char *err, int err_sz);

/* Reads an 8-bit RGB or RGBA PNG (the alpha channel is dropped) into a freshly allocated im.
 * Returns 0, or -1 with a message in err (im is then zeroed). */
int ns_image_read_png(NsImage *im, const char *path, char *err, int err_sz);

#endif
