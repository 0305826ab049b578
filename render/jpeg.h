/* JPEG encoding of an NsImage into memory (libjpeg-turbo): the live session's frames. */
#ifndef NS_RENDER_JPEG_H
#define NS_RENDER_JPEG_H

#include <stddef.h>

#include "image.h"

/* A growable output buffer, reused between frames. */
typedef struct NsJpegBuf {
    unsigned char *data;
    unsigned long size; /* bytes of the last image */
    unsigned long cap;  /* bytes allocated */
} NsJpegBuf;

/* Encodes im (RGB) at quality 1..100 into out (baseline, 4:2:0). Returns 0, or -1 with a
 * message in err. */
int ns_jpeg_encode(const NsImage *im, int quality, NsJpegBuf *out, char *err, int err_sz);
void ns_jpeg_buf_free(NsJpegBuf *b);

#endif
