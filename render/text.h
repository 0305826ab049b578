/* Anti-aliased text on an NsImage with FreeType 2 and the DejaVu fonts (Debian package
 * fonts-dejavu-core). Glyphs for code points below 512 are rendered once and cached in the font,
 * so drawing a HUD line every frame is cheap. Sizes and positions are in pixels; no kerning. */
#ifndef NS_TEXT_H
#define NS_TEXT_H

#include "image.h"

typedef struct NsFont NsFont;

/* Opens DejaVuSansMono (mono != 0) or DejaVuSans at a pixel height of px (4..1024). The
 * environment variable NEEDLESIM_FONT, a .ttf path, overrides the file. Returns NULL with a
 * message in err naming the path tried (and suggesting `apt install fonts-dejavu-core`). */
NsFont *ns_font_open(int px, int mono, char *err, int err_sz);

/* Frees the font and its glyph cache; NULL is ignored. */
void ns_font_close(NsFont *f);

/* Pixels from one baseline to the next. */
int ns_font_line_height(const NsFont *f);

/* Pixels above the baseline (the font's ascender). */
int ns_font_ascent(const NsFont *f);

/* The advance width of the UTF-8 string in pixels (what ns_font_draw returns). */
int ns_font_measure(NsFont *f, const char *utf8);

/* Draws the UTF-8 string with its baseline at row y, starting at column x, blending rgb over the
 * image by each glyph's anti-aliased coverage, clipped to the image. Code points without a glyph
 * (and malformed UTF-8, as U+FFFD) draw the font's missing glyph. Returns the advance width. */
int ns_font_draw(NsFont *f, NsImage *im, int x, int y, const char *utf8, const uint8_t rgb[3]);

#endif
