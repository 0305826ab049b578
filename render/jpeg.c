/* JPEG encoding into memory (render/jpeg.h). libjpeg reports errors through a longjmp from its
 * error handler; the handler here keeps the message and jumps back to ns_jpeg_encode. */
#include "jpeg.h"

#include <setjmp.h>
#include <stdio.h> /* before jpeglib.h, which uses FILE */
#include <stdlib.h>
#include <string.h>

#include <jpeglib.h>

#include "err.h"

typedef struct Fail {
    struct jpeg_error_mgr mgr;
    jmp_buf jump;
    char msg[JMSG_LENGTH_MAX];
    /* the destination, which jpeg_mem_dest may replace by a larger malloc'd buffer (the old
     * one stays the caller's): kept here, in memory, so it is valid after the longjmp */
    unsigned char *data;
    unsigned long size;
} Fail;

static void on_error(j_common_ptr c)
{
    Fail *f = (Fail *)c->err;
    c->err->format_message(c, f->msg);
    longjmp(f->jump, 1);
}

static void on_message(j_common_ptr c)
{
    (void)c; /* warnings: not printed (stderr belongs to the program's own messages) */
}

int ns_jpeg_encode(const NsImage *im, int quality, NsJpegBuf *out, char *err, int err_sz)
{
    struct jpeg_compress_struct c;
    Fail fail;
    memset(&c, 0, sizeof c);
    c.err = jpeg_std_error(&fail.mgr);
    fail.mgr.error_exit = on_error;
    fail.mgr.output_message = on_message;
    fail.msg[0] = '\0';
    fail.data = out->data;
    fail.size = out->cap;
    if (setjmp(fail.jump)) {
        jpeg_destroy_compress(&c);
        if (fail.data != out->data)
            free(fail.data);
        ns_set_err(err, err_sz, "JPEG encoding failed: %s", fail.msg);
        return -1;
    }
    jpeg_create_compress(&c);
    jpeg_mem_dest(&c, &fail.data, &fail.size);
    c.image_width = (JDIMENSION)im->w;
    c.image_height = (JDIMENSION)im->h;
    c.input_components = 3;
    c.in_color_space = JCS_RGB;
    jpeg_set_defaults(&c);
    jpeg_set_quality(&c, quality < 1 ? 1 : quality > 100 ? 100 : quality, TRUE);
    c.dct_method = JDCT_ISLOW;
    jpeg_start_compress(&c, TRUE);
    while (c.next_scanline < c.image_height) {
        JSAMPROW row = im->rgb + (size_t)c.next_scanline * (size_t)im->w * 3;
        jpeg_write_scanlines(&c, &row, 1);
    }
    jpeg_finish_compress(&c);
    jpeg_destroy_compress(&c);
    if (fail.data != out->data) { /* libjpeg made a larger buffer: at least this size */
        free(out->data);
        out->data = fail.data;
        out->cap = fail.size;
    }
    out->size = fail.size;
    return 0;
}

void ns_jpeg_buf_free(NsJpegBuf *b)
{
    free(b->data);
    memset(b, 0, sizeof *b);
}
