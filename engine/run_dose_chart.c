/* The dose-volume histograms on the contact sheet (docs/brachytherapy.md): one chart, the
 * prostate, urethra and rectum each planned (thin, pale) and delivered (thick), dose in % of the
 * prescription across, volume in % of the region up; and two table rows with the figures. */
#include <stdio.h>
#include <string.h>

#include "dvh.h"
#include "err.h"
#include "image.h"
#include "run.h"
#include "text.h"

#define CHART_W  900
#define CHART_H  380
#define LEFT     70
#define RIGHT    210 /* the legend */
#define TOP      36
#define BOTTOM   46
#define DOSE_MAX 2.0 /* x axis: 0 .. 200 % of the prescription */

static const uint8_t bg[3] = {24, 27, 34}, axis[3] = {170, 178, 190}, grid[3] = {60, 66, 78};
static const uint8_t colour[3][3] = {{235, 90, 80}, {240, 200, 70}, {90, 150, 240}};
static const char *const region[3] = {"prostate", "urethra", "rectum"};

/* One DVH as a staircase: every pixel column's V(D), joined to the last by a vertical run. */
static void curve(NsImage *im, const NsDvh *d, double rx, const uint8_t rgb[3], int thick,
                  double alpha)
{
    int pw = CHART_W - LEFT - RIGHT, ph = CHART_H - TOP - BOTTOM, prev = -1;
    for (int i = 0; i <= pw; i++) {
        double v = ns_dvh_v_pct(d, DOSE_MAX * rx * i / pw);
        int y = TOP + (int)((100.0 - v) / 100.0 * ph + 0.5);
        int lo = prev < 0 ? y : (prev < y ? prev : y), hi = prev < 0 ? y : (prev > y ? prev : y);
        ns_image_fill_rect(im, LEFT + i - thick / 2, lo - thick / 2, thick, hi - lo + thick, rgb,
                           alpha);
        prev = y;
    }
}

int ns_run_dosimetry_chart(const NsRun *r, NsImage *im, char *err, int err_sz)
{
    memset(im, 0, sizeof *im);
    if (!ns_run_dosimetry_dvh(r, 1, 0))
        return 0;
    NsFont *f = ns_font_open(15, 0, err, err_sz);
    if (!f)
        return -1;
    if (ns_image_alloc(im, CHART_W, CHART_H, err, err_sz)) {
        ns_font_close(f);
        return -1;
    }
    ns_image_fill(im, bg);
    int pw = CHART_W - LEFT - RIGHT, ph = CHART_H - TOP - BOTTOM, asc = ns_font_ascent(f);
    char s[96];
    for (int k = 0; k <= 4; k++) { /* dose 0, 50, ... 200 %; volume 0, 25, ... 100 % */
        int x = LEFT + k * pw / 4, y = TOP + k * ph / 4;
        ns_image_fill_rect(im, x, TOP, 1, ph, grid, 1.0);
        ns_image_fill_rect(im, LEFT, y, pw, 1, grid, 1.0);
        snprintf(s, sizeof s, "%d%%", 50 * k);
        ns_font_draw(f, im, x - ns_font_measure(f, s) / 2, TOP + ph + 6 + asc, s, axis);
        snprintf(s, sizeof s, "%d%%", 100 - 25 * k);
        ns_font_draw(f, im, LEFT - 8 - ns_font_measure(f, s), y + asc / 2, s, axis);
    }
    ns_image_fill_rect(im, LEFT, TOP, 1, ph + 1, axis, 1.0);
    ns_image_fill_rect(im, LEFT, TOP + ph, pw + 1, 1, axis, 1.0);
    double rx = r->spec.dosimetry.prescription;
    snprintf(s, sizeof s, "dose, %% of the prescription (%.0f Gy)", rx);
    ns_font_draw(f, im, LEFT + pw / 2 - ns_font_measure(f, s) / 2, CHART_H - 10, s, axis);
    ns_font_draw(f, im, 8, 8 + asc, "volume receiving at least the dose, % of the region", axis);
    for (int q = 0; q < 3; q++) {
        curve(im, ns_run_dosimetry_dvh(r, 0, q), rx, colour[q], 2, 0.45);
        curve(im, ns_run_dosimetry_dvh(r, 1, q), rx, colour[q], 3, 1.0);
        int y = TOP + 10 + 26 * q;
        ns_image_fill_rect(im, LEFT + pw + 24, y - 2, 28, 4, colour[q], 1.0);
        ns_font_draw(f, im, LEFT + pw + 60, y + asc / 2 - 1, region[q], axis);
    }
    int y = TOP + 10 + 26 * 3 + 8;
    ns_image_fill_rect(im, LEFT + pw + 24, y - 1, 28, 3, axis, 1.0);
    ns_font_draw(f, im, LEFT + pw + 60, y + asc / 2 - 1, "delivered", axis);
    ns_image_fill_rect(im, LEFT + pw + 24, y + 26 - 1, 28, 2, axis, 0.45);
    ns_font_draw(f, im, LEFT + pw + 60, y + 26 + asc / 2 - 1, "planned", axis);
    ns_font_close(f);
    return 0;
}

int ns_run_dosimetry_rows(const NsRun *r, char (*rows)[128], int max)
{
    int n = 0;
    double rx = r->spec.dosimetry.prescription;
    static const char *const what[2] = {"planned", "delivered"};
    for (int w = 0; w < 2 && n < max; w++) {
        const NsDvh *p = ns_run_dosimetry_dvh(r, w, 0), *u = ns_run_dosimetry_dvh(r, w, 1),
                    *c = ns_run_dosimetry_dvh(r, w, 2);
        if (!p)
            return n;
        snprintf(rows[n++], sizeof rows[0],
                 "%-9s prostate D90 %5.1f Gy (%3.0f%%) V100 %3.0f%% V150 %3.0f%%; urethra D10 "
                 "%5.1f Gy; rectum D2cc %5.1f Gy",
                 what[w], ns_dvh_d_pct(p, 90), 100.0 * ns_dvh_d_pct(p, 90) / rx,
                 ns_dvh_v_pct(p, rx), ns_dvh_v_pct(p, 1.5 * rx), ns_dvh_d_pct(u, 10),
                 ns_dvh_d_vol(c, 2e-6));
    }
    return n;
}
