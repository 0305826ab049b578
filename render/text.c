/* Text rendering with FreeType 2: hinted, anti-aliased glyph bitmaps (8-bit coverage) blended
 * over an NsImage. Glyphs of code points below NS_FONT_CACHE are cached in the font. */
#include "text.h"

#include <errno.h>
#include <ft2build.h>
#include FT_FREETYPE_H
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define NS_FONT_CACHE 512
#define NS_FONT_DIR   "/usr/share/fonts/truetype/dejavu/"

/* One rendered glyph: a w x h coverage bitmap whose top-left pixel lies `left` pixels right of
 * the pen and `top` pixels above the baseline. */
typedef struct Glyph {
    int loaded, w, h, left, top, advance;
    uint8_t *cov;
} Glyph;

struct NsFont {
    FT_Library lib;
    FT_Face face;
    int ascent, line_height;
    Glyph cache[NS_FONT_CACHE];
};

/* FreeType's own message for error e (its error table, built from fterrdef.h). */
static const char *ft_message(FT_Error e, char *buf, size_t n)
{
    /* clang-format off */
#undef FTERRORS_H_
#define FT_ERRORDEF(name, code, text) {code, text},
#define FT_ERROR_START_LIST {
#define FT_ERROR_END_LIST {0, NULL}}
    /* clang-format on */
    static const struct {
        int code;
        const char *text;
    } table[] =
#include FT_ERRORS_H
        ;
    for (int i = 0; table[i].text; i++)
        if (table[i].code == (int)e)
            return table[i].text;
    snprintf(buf, n, "FreeType error %d", (int)e);
    return buf;
}

NsFont *ns_font_open(int px, int mono, char *err, int err_sz)
{
    if (px < 4 || px > 1024) {
        snprintf(err, err_sz, "font pixel height %d out of range (4..1024)", px);
        return NULL;
    }
    const char *env = getenv("NEEDLESIM_FONT");
    const char *path = env && *env ? env
                       : mono      ? NS_FONT_DIR "DejaVuSansMono.ttf"
                                   : NS_FONT_DIR "DejaVuSans.ttf";
    const char *hint = env && *env ? " (from NEEDLESIM_FONT)" : "";
    if (access(path, R_OK) != 0) {
        snprintf(err, err_sz, "cannot open font %s%s: %s; apt install fonts-dejavu-core", path,
                 hint, strerror(errno));
        return NULL;
    }
    NsFont *f = calloc(1, sizeof *f);
    if (!f) {
        snprintf(err, err_sz, "out of memory for a font");
        return NULL;
    }
    char buf[64];
    FT_Error e = FT_Init_FreeType(&f->lib);
    if (e) {
        snprintf(err, err_sz, "cannot start FreeType: %s", ft_message(e, buf, sizeof buf));
        free(f);
        return NULL;
    }
    e = FT_New_Face(f->lib, path, 0, &f->face);
    if (!e)
        e = FT_Set_Pixel_Sizes(f->face, 0, (FT_UInt)px);
    if (e) {
        snprintf(err, err_sz, "cannot load font %s%s: %s; apt install fonts-dejavu-core", path,
                 hint, ft_message(e, buf, sizeof buf));
        ns_font_close(f);
        return NULL;
    }
    const FT_Size_Metrics *m = &f->face->size->metrics;
    f->ascent = (int)((m->ascender + 63) >> 6);
    f->line_height = (int)((m->height + 63) >> 6);
    if (f->line_height < 1)
        f->line_height = px;
    return f;
}

void ns_font_close(NsFont *f)
{
    if (!f)
        return;
    for (int i = 0; i < NS_FONT_CACHE; i++)
        free(f->cache[i].cov);
    if (f->face)
        FT_Done_Face(f->face);
    FT_Done_FreeType(f->lib);
    free(f);
}

int ns_font_line_height(const NsFont *f)
{
    return f->line_height;
}

int ns_font_ascent(const NsFont *f)
{
    return f->ascent;
}

/* Decodes one UTF-8 code point at *s and advances *s; malformed input gives U+FFFD and skips one
 * byte. Returns 0 at the end of the string. */
static unsigned utf8_next(const char **s)
{
    const unsigned char *p = (const unsigned char *)*s;
    unsigned c = p[0];
    if (c == 0)
        return 0;
    int n = c < 0x80             ? 0
            : (c & 0xE0) == 0xC0 ? 1
            : (c & 0xF0) == 0xE0 ? 2
            : (c & 0xF8) == 0xF0 ? 3
                                 : -1;
    static const unsigned min[4] = {0, 0x80, 0x800, 0x10000};
    if (n < 0) {
        *s += 1;
        return 0xFFFD;
    }
    unsigned cp = n == 0 ? c : c & (0x3Fu >> n);
    for (int i = 1; i <= n; i++) {
        if ((p[i] & 0xC0) != 0x80) {
            *s += 1;
            return 0xFFFD;
        }
        cp = cp << 6 | (p[i] & 0x3Fu);
    }
    *s += n + 1;
    if (cp < min[n] || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF))
        return 0xFFFD;
    return cp;
}

/* Renders code point cp into g (g->cov is malloc'ed). A glyph that fails to load or render is
 * left empty with a zero advance. */
static void glyph_render(NsFont *f, unsigned cp, Glyph *g)
{
    memset(g, 0, sizeof *g);
    g->loaded = 1;
    FT_UInt index = FT_Get_Char_Index(f->face, cp); /* 0: the missing glyph */
    if (FT_Load_Glyph(f->face, index, FT_LOAD_RENDER | FT_LOAD_TARGET_NORMAL))
        return;
    FT_GlyphSlot slot = f->face->glyph;
    g->advance = (int)((slot->advance.x + 32) >> 6);
    const FT_Bitmap *b = &slot->bitmap;
    if (b->width == 0 || b->rows == 0 ||
        (b->pixel_mode != FT_PIXEL_MODE_GRAY && b->pixel_mode != FT_PIXEL_MODE_MONO))
        return;
    g->cov = malloc((size_t)b->width * b->rows);
    if (!g->cov)
        return;
    g->w = (int)b->width;
    g->h = (int)b->rows;
    g->left = slot->bitmap_left;
    g->top = slot->bitmap_top;
    int levels = b->num_grays > 1 ? b->num_grays - 1 : 255;
    for (int r = 0; r < g->h; r++) {
        const unsigned char *row = b->buffer + (ptrdiff_t)r * b->pitch;
        uint8_t *out = g->cov + (size_t)r * (size_t)g->w;
        for (int c = 0; c < g->w; c++) {
            if (b->pixel_mode == FT_PIXEL_MODE_MONO)
                out[c] = (row[c >> 3] >> (7 - (c & 7)) & 1) ? 255 : 0;
            else
                out[c] = (uint8_t)(levels == 255 ? row[c] : row[c] * 255 / levels);
        }
    }
}

/* The glyph of cp: from the cache, or rendered into *tmp (which the caller frees). */
static const Glyph *glyph_get(NsFont *f, unsigned cp, Glyph *tmp)
{
    Glyph *g = cp < NS_FONT_CACHE ? &f->cache[cp] : tmp;
    if (!g->loaded)
        glyph_render(f, cp, g);
    return g;
}

int ns_font_measure(NsFont *f, const char *utf8)
{
    int adv = 0;
    unsigned cp;
    while ((cp = utf8_next(&utf8)) != 0) {
        Glyph tmp = {0};
        adv += glyph_get(f, cp, &tmp)->advance;
        free(tmp.cov);
    }
    return adv;
}

static void glyph_blit(const Glyph *g, NsImage *im, int x, int y, const uint8_t rgb[3])
{
    int gx = x + g->left, gy = y - g->top;
    int c0 = gx < 0 ? -gx : 0, r0 = gy < 0 ? -gy : 0;
    int c1 = g->w, r1 = g->h;
    if (gx + c1 > im->w)
        c1 = im->w - gx;
    if (gy + r1 > im->h)
        r1 = im->h - gy;
    for (int r = r0; r < r1; r++) {
        const uint8_t *cov = g->cov + (size_t)r * (size_t)g->w;
        uint8_t *p = im->rgb + ((size_t)(gy + r) * (size_t)im->w + (size_t)(gx + c0)) * 3;
        for (int c = c0; c < c1; c++, p += 3) {
            unsigned a = cov[c];
            if (a == 0)
                continue;
            for (int k = 0; k < 3; k++)
                p[k] = (uint8_t)((p[k] * (255u - a) + rgb[k] * a + 127u) / 255u);
        }
    }
}

int ns_font_draw(NsFont *f, NsImage *im, int x, int y, const char *utf8, const uint8_t rgb[3])
{
    int pen = x;
    unsigned cp;
    while ((cp = utf8_next(&utf8)) != 0) {
        Glyph tmp = {0};
        const Glyph *g = glyph_get(f, cp, &tmp);
        if (g->cov)
            glyph_blit(g, im, pen, y, rgb);
        pen += g->advance;
        free(tmp.cov);
    }
    return pen - x;
}
