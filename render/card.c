/* Captions and title cards (render/card.h). */
#include "card.h"

#include <string.h>

static const uint8_t card_bg[3] = {18, 22, 30}, white[3] = {240, 242, 245},
                     accent[3] = {240, 200, 90}, panel[3] = {0, 0, 0};

enum { LINE_BYTES = 512 };

/* The next line of text from *s that fits max_w pixels: broken at the last space that fits (a
 * word longer than the width is cut), leading spaces skipped. Returns 0 when text is done. */
static int next_line(NsFont *font, const char **s, int max_w, char line[LINE_BYTES])
{
    const char *p = *s;
    while (*p == ' ')
        p++;
    if (!*p)
        return 0;
    size_t n = 0, fit = 0;
    while (p[n] && n + 1 < LINE_BYTES) {
        size_t m = n; /* the next word's end */
        while (p[m] == ' ')
            m++;
        while (p[m] && p[m] != ' ' && m + 1 < LINE_BYTES)
            m++;
        memcpy(line, p, m);
        line[m] = '\0';
        if (ns_font_measure(font, line) > max_w)
            break;
        fit = n = m;
    }
    if (fit == 0) { /* one word wider than the line: as many bytes as fit, whole UTF-8 sequences */
        size_t m = 0;
        while (p[m] && p[m] != ' ' && m + 1 < LINE_BYTES) {
            size_t k = m + 1;
            while ((p[k] & 0xC0) == 0x80)
                k++;
            memcpy(line, p, k);
            line[k] = '\0';
            if (m > 0 && ns_font_measure(font, line) > max_w)
                break;
            m = k;
        }
        fit = m;
    }
    memcpy(line, p, fit);
    line[fit] = '\0';
    *s = p + fit;
    return 1;
}

static int lines_of(NsFont *font, const char *text, int max_w, char out[][LINE_BYTES], int max_n)
{
    int n = 0;
    while (n < max_n && next_line(font, &text, max_w, out[n]))
        n++;
    return n;
}

void ns_card_caption(NsImage *im, NsFont *font, const char *text)
{
    char lines[3][LINE_BYTES];
    int n = lines_of(font, text, im->w * 4 / 5, lines, 3);
    if (n == 0)
        return;
    int lh = ns_font_line_height(font), pad = lh / 2, wmax = 0;
    for (int i = 0; i < n; i++) {
        int w = ns_font_measure(font, lines[i]);
        wmax = w > wmax ? w : wmax;
    }
    int bh = n * lh + 2 * pad, y = im->h - bh - im->h / 14;
    ns_image_fill_rect(im, (im->w - wmax) / 2 - pad, y, wmax + 2 * pad, bh, panel, 0.65);
    for (int i = 0; i < n; i++)
        ns_font_draw(font, im, (im->w - ns_font_measure(font, lines[i])) / 2,
                     y + pad + i * lh + ns_font_ascent(font), lines[i], white);
}

void ns_card_title(NsImage *im, NsFont *big, NsFont *font, const char *title, const char *text)
{
    ns_image_fill(im, card_bg);
    char tl[2][LINE_BYTES], bl[8][LINE_BYTES];
    int nt = lines_of(big, title ? title : "", im->w * 4 / 5, tl, 2);
    int nb = lines_of(font, text ? text : "", im->w * 3 / 4, bl, 8);
    int lhb = ns_font_line_height(big), lh = ns_font_line_height(font);
    int total = nt * lhb + (nb ? lh + nb * lh : 0), y = (im->h - total) / 2;
    for (int i = 0; i < nt; i++, y += lhb)
        ns_font_draw(big, im, (im->w - ns_font_measure(big, tl[i])) / 2, y + ns_font_ascent(big),
                     tl[i], white);
    if (nt && nb)
        ns_image_fill_rect(im, im->w / 2 - im->w / 12, y + lh / 3, im->w / 6, 3, accent, 1.0);
    y += nb ? lh : 0;
    for (int i = 0; i < nb; i++, y += lh)
        ns_font_draw(font, im, (im->w - ns_font_measure(font, bl[i])) / 2, y + ns_font_ascent(font),
                     bl[i], white);
}
