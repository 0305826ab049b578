/* The cohort report of `needlesim score` (score.h, docs/scoring.md): OUT/cohort.json,
 * OUT/cohort.html (self-contained: inline SVG and CSS) and OUT/cohort.png, all from
 * scores.csv's rows, so that a local batch and a Slurm batch give the same report. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cleanup.h"
#include "err.h"
#include "image.h"
#include "json.h"
#include "out_files.h"
#include "score.h"
#include "score_csv.h"
#include "text.h"

#define REVIEW_MAX 10

typedef struct Row {
    char buf[NS_SCORE_ROW_MAX + 1];
    char *f[NS_SCORE_COLUMNS];
    bool ok;
    double score, err_mm; /* NAN when absent */
    int violated;
    int trainee, scenario; /* indexes into the lists of names */
} Row;

typedef struct Cohort {
    Row *rows;
    int n;
    const char **trainees, **scenarios; /* in order of first appearance */
    int nt, ns;
    int review[REVIEW_MAX], nreview;
} Cohort;

static int name_index(const char **list, int *n, const char *name)
{
    for (int i = 0; i < *n; i++)
        if (strcmp(list[i], name) == 0)
            return i;
    list[*n] = name;
    return (*n)++;
}

static double num(const char *s)
{
    char *end;
    double v = strtod(s, &end);
    return *s && !*end ? v : NAN;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* The rank of a row for review: errors first, then obstacles entered, then by score. */
static double review_rank(const Row *r)
{
    if (!r->ok)
        return -2e9;
    if (r->violated > 0)
        return -1e9 + r->score;
    return r->score;
}

static int parse(Cohort *c, char *const *rows, int n)
{
    c->rows = calloc((size_t)(n ? n : 1), sizeof *c->rows);
    c->trainees = calloc((size_t)(n ? n : 1), sizeof *c->trainees);
    c->scenarios = calloc((size_t)(n ? n : 1), sizeof *c->scenarios);
    if (!c->rows || !c->trainees || !c->scenarios)
        return -1;
    c->n = n;
    for (int i = 0; i < n; i++) {
        Row *r = &c->rows[i];
        snprintf(r->buf, sizeof r->buf, "%s", rows[i] ? rows[i] : "");
        if (ns_csv_split(r->buf, r->f, NS_SCORE_COLUMNS) != NS_SCORE_COLUMNS)
            for (int k = 0; k < NS_SCORE_COLUMNS; k++)
                r->f[k] = (char *)"";
        r->ok = strcmp(r->f[NS_SC_STATUS], "ok") == 0;
        r->score = r->ok ? num(r->f[NS_SC_SCORE]) : NAN;
        r->err_mm = r->ok ? num(r->f[NS_SC_TARGET_ERROR_MAX]) : NAN;
        r->violated = r->ok ? atoi(r->f[NS_SC_OBSTACLES_VIOLATED]) : 0;
        r->trainee = name_index(c->trainees, &c->nt, r->f[NS_SC_TRAINEE]);
        r->scenario = name_index(c->scenarios, &c->ns, r->f[NS_SC_SCENARIO]);
    }
    /* the sessions to review first: the REVIEW_MAX lowest ranks, ties in the order given */
    for (int i = 0; i < n; i++) {
        int at = c->nreview;
        while (at > 0 && review_rank(&c->rows[i]) < review_rank(&c->rows[c->review[at - 1]]))
            at--;
        if (at >= REVIEW_MAX)
            continue;
        int last = c->nreview < REVIEW_MAX ? c->nreview : REVIEW_MAX - 1;
        memmove(c->review + at + 1, c->review + at, (size_t)(last - at) * sizeof(int));
        c->review[at] = i;
        if (c->nreview < REVIEW_MAX)
            c->nreview++;
    }
    return 0;
}

/* Quantiles of the scenario's ok scores: min, q1, median, q3, max, mean; the count. */
static int scenario_stats(const Cohort *c, int sc, double q[6])
{
    double *v = malloc((size_t)(c->n ? c->n : 1) * sizeof *v);
    int k = 0;
    for (int i = 0; v && i < c->n; i++)
        if (c->rows[i].scenario == sc && c->rows[i].ok && isfinite(c->rows[i].score))
            v[k++] = c->rows[i].score;
    for (int j = 0; j < 6; j++)
        q[j] = NAN;
    if (k > 0) {
        qsort(v, (size_t)k, sizeof *v, cmp_double);
        double sum = 0;
        for (int j = 0; j < k; j++)
            sum += v[j];
        for (int j = 0; j < 5; j++) { /* linear interpolation between order statistics */
            double p = 0.25 * j * (k - 1);
            int lo = (int)floor(p);
            int hi = lo + 1 < k ? lo + 1 : lo;
            q[j] = v[lo] + (p - lo) * (v[hi] - v[lo]);
        }
        q[5] = sum / k;
    }
    free(v);
    return k;
}

static const char *review_reason(const Row *r, char *buf, size_t n)
{
    if (!r->ok)
        snprintf(buf, n, "error: %s", r->f[NS_SC_ERROR]);
    else if (r->violated)
        snprintf(buf, n, "entered %d obstacle(s): %s", r->violated, r->f[NS_SC_OBSTACLES_ENTERED]);
    else
        snprintf(buf, n, "score %s, largest target error %s mm", r->f[NS_SC_SCORE],
                 r->f[NS_SC_TARGET_ERROR_MAX]);
    return buf;
}

static void write_json(const Cohort *c, FILE *f)
{
    NsJson j;
    ns_json_init(&j, f, 3);
    ns_json_begin_object(&j);
    ns_json_key(&j, "schema");
    ns_json_int(&j, 1);
    int ok = 0;
    for (int i = 0; i < c->n; i++)
        ok += c->rows[i].ok;
    ns_json_key(&j, "sessions");
    ns_json_int(&j, c->n);
    ns_json_key(&j, "ok");
    ns_json_int(&j, ok);
    ns_json_key(&j, "errors");
    ns_json_int(&j, c->n - ok);
    ns_json_key(&j, "trainees");
    ns_json_begin_array(&j);
    for (int t = 0; t < c->nt; t++) {
        ns_json_begin_object(&j);
        ns_json_key(&j, "trainee");
        ns_json_string(&j, c->trainees[t]);
        ns_json_key(&j, "sessions");
        ns_json_begin_array(&j);
        double first = NAN, last = NAN, sum = 0;
        int k = 0;
        for (int i = 0; i < c->n; i++) {
            const Row *r = &c->rows[i];
            if (r->trainee != t)
                continue;
            ns_json_begin_object(&j);
            ns_json_key(&j, "session");
            ns_json_string(&j, r->f[NS_SC_SESSION]);
            ns_json_key(&j, "scenario");
            ns_json_string(&j, r->f[NS_SC_SCENARIO]);
            ns_json_key(&j, "log");
            ns_json_string(&j, r->f[NS_SC_LOG]);
            ns_json_key(&j, "status");
            ns_json_string(&j, r->f[NS_SC_STATUS]);
            ns_json_key(&j, "score");
            ns_json_number(&j, r->score);
            ns_json_key(&j, "target_error_mm_max");
            ns_json_number(&j, r->err_mm);
            ns_json_end_object(&j);
            if (isfinite(r->score)) {
                first = k ? first : r->score;
                last = r->score;
                sum += r->score;
                k++;
            }
        }
        ns_json_end_array(&j);
        ns_json_key(&j, "score_first");
        ns_json_number(&j, first);
        ns_json_key(&j, "score_last");
        ns_json_number(&j, last);
        ns_json_key(&j, "score_mean");
        ns_json_number(&j, k ? sum / k : NAN);
        ns_json_end_object(&j);
    }
    ns_json_end_array(&j);
    ns_json_key(&j, "scenarios");
    ns_json_begin_array(&j);
    static const char *const qn[6] = {"min", "q1", "median", "q3", "max", "mean"};
    for (int s = 0; s < c->ns; s++) {
        double q[6];
        int k = scenario_stats(c, s, q);
        ns_json_begin_object(&j);
        ns_json_key(&j, "scenario");
        ns_json_string(&j, c->scenarios[s]);
        ns_json_key(&j, "scored");
        ns_json_int(&j, k);
        ns_json_key(&j, "score");
        ns_json_begin_object(&j);
        for (int m = 0; m < 6; m++) {
            ns_json_key(&j, qn[m]);
            ns_json_number(&j, q[m]);
        }
        ns_json_end_object(&j);
        ns_json_end_object(&j);
    }
    ns_json_end_array(&j);
    ns_json_key(&j, "review");
    ns_json_begin_array(&j);
    for (int k = 0; k < c->nreview; k++) {
        const Row *r = &c->rows[c->review[k]];
        char why[1200];
        ns_json_begin_object(&j);
        ns_json_key(&j, "log");
        ns_json_string(&j, r->f[NS_SC_LOG]);
        ns_json_key(&j, "trainee");
        ns_json_string(&j, r->f[NS_SC_TRAINEE]);
        ns_json_key(&j, "session");
        ns_json_string(&j, r->f[NS_SC_SESSION]);
        ns_json_key(&j, "score");
        ns_json_number(&j, r->score);
        ns_json_key(&j, "reason");
        ns_json_string(&j, review_reason(r, why, sizeof why));
        ns_json_end_object(&j);
    }
    ns_json_end_array(&j);
    ns_json_end_object(&j);
    fputc('\n', f);
}

/* s with &, <, >, " escaped for HTML. */
static void html_text(FILE *f, const char *s)
{
    for (; *s; s++)
        switch (*s) {
        case '&':
            fputs("&amp;", f);
            break;
        case '<':
            fputs("&lt;", f);
            break;
        case '>':
            fputs("&gt;", f);
            break;
        case '"':
            fputs("&quot;", f);
            break;
        default:
            fputc(*s, f);
        }
}

/* One trainee's learning curve: score (0..100, blue) and largest target error (mm, orange,
 * scaled to the cohort's largest) over their sessions in the order given. */
static void svg_curve(const Cohort *c, int t, double err_max, FILE *f)
{
    const int W = 360, H = 140, L = 34, B = 20;
    int k = 0, m = 0;
    for (int i = 0; i < c->n; i++)
        k += c->rows[i].trainee == t;
    fprintf(f, "<svg width=\"%d\" height=\"%d\" viewBox=\"0 0 %d %d\">", W, H, W, H);
    fprintf(f, "<rect x=\"%d\" y=\"4\" width=\"%d\" height=\"%d\" class=\"frame\"/>", L, W - L - 8,
            H - B - 4);
    fprintf(f,
            "<text x=\"2\" y=\"14\" class=\"s\">100</text><text x=\"14\" y=\"%d\" "
            "class=\"s\">0</text>",
            H - B);
    for (int pass = 0; pass < 2; pass++) {
        fprintf(f, "<polyline class=\"%s\" points=\"", pass ? "e" : "sc");
        m = 0;
        for (int i = 0; i < c->n; i++) {
            const Row *r = &c->rows[i];
            if (r->trainee != t)
                continue;
            double v = pass ? r->err_mm / fmax(err_max, 1e-9) : r->score / 100.0;
            double x = L + 8 + (k > 1 ? (double)m / (k - 1) : 0.5) * (W - L - 24);
            m++;
            if (isfinite(v))
                fprintf(f, "%.1f,%.1f ", x, 4 + (1 - fmin(fmax(v, 0), 1)) * (H - B - 4));
        }
        fputs("\"/>", f);
    }
    fprintf(f, "<text x=\"%d\" y=\"%d\" class=\"s\">session 1 .. %d (in the order given)</text>", L,
            H - 4, k);
    fputs("</svg>", f);
}

/* The cohort's distribution per scenario: each session a dot, the quartiles a box. */
static void svg_scenario(const Cohort *c, int s, FILE *f)
{
    const int W = 520, H = 44, L = 10;
    double q[6];
    scenario_stats(c, s, q);
    fprintf(f, "<svg width=\"%d\" height=\"%d\" viewBox=\"0 0 %d %d\">", W, H, W, H);
#define X(v) (L + (v) / 100.0 * (W - 2 * L))
    fprintf(f, "<line x1=\"%d\" y1=\"22\" x2=\"%d\" y2=\"22\" class=\"frame\"/>", L, W - L);
    if (isfinite(q[0]))
        fprintf(f,
                "<line x1=\"%.1f\" y1=\"22\" x2=\"%.1f\" y2=\"22\" class=\"sc\"/><rect "
                "x=\"%.1f\" y=\"12\" width=\"%.1f\" height=\"20\" class=\"box\"/><line "
                "x1=\"%.1f\" y1=\"10\" x2=\"%.1f\" y2=\"34\" class=\"sc\"/>",
                X(q[0]), X(q[4]), X(q[1]), fmax(X(q[3]) - X(q[1]), 1), X(q[2]), X(q[2]));
    for (int i = 0; i < c->n; i++)
        if (c->rows[i].scenario == s && isfinite(c->rows[i].score))
            fprintf(f, "<circle cx=\"%.1f\" cy=\"22\" r=\"3\" class=\"dot\"/>",
                    X(c->rows[i].score));
#undef X
    fprintf(f,
            "<text x=\"%d\" y=\"%d\" class=\"s\">0</text><text x=\"%d\" y=\"%d\" "
            "class=\"s\">100</text></svg>",
            L, H - 1, W - L - 20, H - 1);
}

static void write_html(const Cohort *c, FILE *f)
{
    double err_max = 0;
    for (int i = 0; i < c->n; i++)
        if (isfinite(c->rows[i].err_mm))
            err_max = fmax(err_max, c->rows[i].err_mm);
    fputs("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>needlesim "
          "cohort report</title>\n<style>body{font-family:sans-serif;margin:24px;color:#222}"
          "h2{margin-top:28px}table{border-collapse:collapse}td,th{border:1px solid #ccc;"
          "padding:3px 8px;text-align:left}.frame{fill:none;stroke:#999}.sc{fill:none;stroke:"
          "#1f5fbf;stroke-width:2}.e{fill:none;stroke:#e07b00;stroke-width:2;stroke-dasharray:"
          "4 3}.box{fill:#cfe0f7;stroke:#1f5fbf}.dot{fill:#222;fill-opacity:.6}.s{font-size:"
          "10px;fill:#555}.err{color:#b00}</style></head><body>\n<h1>Cohort report</h1>\n",
          f);
    int ok = 0;
    for (int i = 0; i < c->n; i++)
        ok += c->rows[i].ok;
    fprintf(f,
            "<p>%d sessions, %d scored, %d errors (needlesim score; the rows are in "
            "scores.csv).</p>\n<h2>Sessions to review first</h2>\n<table><tr><th>trainee"
            "</th><th>session</th><th>log</th><th>score</th><th>why</th></tr>\n",
            c->n, ok, c->n - ok);
    for (int k = 0; k < c->nreview; k++) {
        const Row *r = &c->rows[c->review[k]];
        char why[1200];
        const char *cells[5] = {r->f[NS_SC_TRAINEE], r->f[NS_SC_SESSION], r->f[NS_SC_LOG],
                                r->f[NS_SC_SCORE], review_reason(r, why, sizeof why)};
        fputs(r->ok ? "<tr>" : "<tr class=\"err\">", f);
        for (int m = 0; m < 5; m++) {
            fputs("<td>", f);
            html_text(f, cells[m]);
            fputs("</td>", f);
        }
        fputs("</tr>\n", f);
    }
    fprintf(f,
            "</table>\n<h2>Learning curves</h2>\n<p>Per trainee, over their sessions in "
            "the order the logs were given: the score (solid, 0 to 100) and the largest "
            "target error (dashed, 0 to %.2f mm).</p>\n",
            err_max);
    for (int t = 0; t < c->nt; t++) {
        fputs("<div style=\"display:inline-block;margin:6px\"><b>", f);
        html_text(f, c->trainees[t][0] ? c->trainees[t] : "(no trainee)");
        fputs("</b><br>", f);
        svg_curve(c, t, err_max, f);
        fputs("</div>\n", f);
    }
    fputs("<h2>Score distribution per scenario</h2>\n<table>", f);
    for (int s = 0; s < c->ns; s++) {
        double q[6];
        int k = scenario_stats(c, s, q);
        fputs("<tr><td>", f);
        html_text(f, c->scenarios[s][0] ? c->scenarios[s] : "(unknown)");
        fprintf(f, "<br><span class=\"s\">%d scored, median %.1f</span></td><td>", k, q[2]);
        svg_scenario(c, s, f);
        fputs("</td></tr>\n", f);
    }
    fputs("</table>\n</body></html>\n", f);
}

/* ---- cohort.png: the learning curves (left) and the distributions (right) ---- */

static void dot(NsImage *im, double x, double y, int r, const uint8_t rgb[3])
{
    ns_image_fill_rect(im, (int)lround(x) - r, (int)lround(y) - r, 2 * r + 1, 2 * r + 1, rgb, 1.0);
}

static void line(NsImage *im, double x0, double y0, double x1, double y1, const uint8_t rgb[3])
{
    int steps = (int)fmax(fabs(x1 - x0), fabs(y1 - y0)) + 1;
    for (int i = 0; i <= steps; i++)
        dot(im, x0 + (x1 - x0) * i / steps, y0 + (y1 - y0) * i / steps, 1, rgb);
}

static int write_png(const Cohort *c, const char *path, char *err, int err_sz)
{
    static const uint8_t white[3] = {255, 255, 255}, grey[3] = {150, 150, 150},
                         ink[3] = {30, 30, 30}, box[3] = {207, 224, 247};
    static const uint8_t pal[6][3] = {{31, 95, 191}, {224, 123, 0},   {44, 160, 44},
                                      {214, 39, 40}, {148, 103, 189}, {140, 86, 75}};
    const int W = 1200, H = 600, PX = 60, PY = 50, PW = 500, PH = 480;
    NsImage im;
    if (ns_image_alloc(&im, W, H, err, err_sz))
        return -1;
    ns_image_fill(&im, white);
    char ferr[256];
    NsFont *font = ns_font_open(16, 0, ferr, (int)sizeof ferr); /* no font: no labels */
    /* left: score (top) and largest target error (bottom) over session number, one colour
     * per trainee */
    int kmax = 1;
    double emax = 1e-9;
    for (int t = 0; t < c->nt; t++) {
        int k = 0;
        for (int i = 0; i < c->n; i++)
            k += c->rows[i].trainee == t;
        kmax = k > kmax ? k : kmax;
    }
    for (int i = 0; i < c->n; i++)
        if (isfinite(c->rows[i].err_mm))
            emax = fmax(emax, c->rows[i].err_mm);
    const int GH = PH / 2 - 20; /* each graph's height */
    for (int g = 0; g < 2; g++) {
        int y0 = PY + g * (GH + 40);
        ns_image_fill_rect(&im, PX, y0, 1, GH, grey, 1.0);
        ns_image_fill_rect(&im, PX, y0 + GH, PW, 1, grey, 1.0);
        for (int t = 0; t < c->nt; t++) {
            double px = NAN, py = NAN;
            int m = 0;
            for (int i = 0; i < c->n; i++) {
                const Row *r = &c->rows[i];
                if (r->trainee != t)
                    continue;
                double v = g ? r->err_mm / emax : r->score / 100.0;
                double x = PX + 10 + (kmax > 1 ? (double)m / (kmax - 1) : 0.5) * (PW - 20);
                double y = y0 + (1 - fmin(fmax(v, 0), 1)) * GH;
                m++;
                if (!isfinite(v))
                    continue;
                if (isfinite(px))
                    line(&im, px, py, x, y, pal[t % 6]);
                dot(&im, x, y, 3, pal[t % 6]);
                px = x, py = y;
            }
        }
    }
    /* right: per scenario, the quartile box and each session's dot, score 0..100 across */
    int RX = PX + PW + 80, RW = W - RX - 40;
    for (int s = 0; s < c->ns; s++) {
        double q[6], y = PY + 30 + s * 60.0;
        if (y > PY + PH)
            break;
        if (scenario_stats(c, s, q) == 0)
            continue; /* no session of it scored (error rows) */
        ns_image_fill_rect(&im, RX, (int)y, RW, 1, grey, 1.0);
        ns_image_fill_rect(&im, RX + (int)(q[1] / 100 * RW), (int)y - 10,
                           (int)fmax((q[3] - q[1]) / 100 * RW, 2), 21, box, 1.0);
        ns_image_fill_rect(&im, RX + (int)(q[2] / 100 * RW) - 1, (int)y - 12, 3, 25, pal[0],
                           1.0); /* the median */
        for (int i = 0; i < c->n; i++)
            if (c->rows[i].scenario == s && isfinite(c->rows[i].score))
                dot(&im, RX + c->rows[i].score / 100 * RW, y, 3, ink);
        if (font)
            ns_font_draw(font, &im, RX, (int)y - 14, c->scenarios[s], ink);
    }
    if (font) {
        char lab[96];
        ns_font_draw(font, &im, PX, 28, "score over each trainee's sessions (0 to 100)", ink);
        snprintf(lab, sizeof lab, "largest target error (0 to %.2f mm)", emax);
        ns_font_draw(font, &im, PX, PY + GH + 32, lab, ink);
        ns_font_draw(font, &im, RX, 28, "score per scenario (0 to 100): quartiles, sessions", ink);
        for (int t = 0; t < c->nt && t < 12; t++)
            ns_font_draw(font, &im, PX + 10 + (t % 4) * 120, PY + PH + 24 + (t / 4) * 20,
                         c->trainees[t][0] ? c->trainees[t] : "(none)", pal[t % 6]);
        ns_font_close(font);
    }
    int rc = ns_image_write_png(&im, path, err, err_sz);
    ns_image_free(&im);
    return rc;
}

/* Writes the text of fn(c) to OUT/name through a .part file. */
static int write_text(const char *out, const char *name, void (*fn)(const Cohort *, FILE *),
                      const Cohort *c, char *err, int err_sz)
{
    char *text = NULL;
    size_t len = 0;
    FILE *m = open_memstream(&text, &len);
    if (!m)
        return ns_set_err(err, err_sz, "out of memory"), -1;
    fn(c, m);
    fclose(m);
    int rc = ns_score_write_file(out, name, text, len, err, err_sz);
    free(text);
    return rc;
}

int ns_score_write_cohort(const char *out, char *const *rows, int n, char *err, int err_sz)
{
    Cohort c;
    memset(&c, 0, sizeof c);
    int rc = parse(&c, rows, n);
    if (rc)
        ns_set_err(err, err_sz, "out of memory");
    rc = rc ? rc : write_text(out, "cohort.json", write_json, &c, err, err_sz);
    rc = rc ? rc : write_text(out, "cohort.html", write_html, &c, err, err_sz);
    char part[4400], final[4400];
    snprintf(part, sizeof part, "%s/.cohort.png.part", out);
    snprintf(final, sizeof final, "%s/cohort.png", out);
    if (rc == 0 && ns_out_replaceable(final, "cohort.png", err, err_sz))
        rc = -1;
    if (rc == 0) {
        ns_out_remove_part(part);
        ns_cleanup_add(part);
        rc = write_png(&c, part, err, err_sz);
        if (rc == 0 && ns_out_commit(part, final)) {
            ns_set_err(err, err_sz, "cannot write '%s'", final);
            rc = -1;
        }
        if (rc)
            ns_out_remove_part(part);
    }
    free(c.rows);
    free(c.trainees);
    free(c.scenarios);
    return rc;
}
