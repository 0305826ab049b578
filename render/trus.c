/* The trus view (render/trus.h). */
#include "trus.h"

#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define HALF_ANGLE (60.0 * M_PI / 180.0)
#define STEP       2 /* pixels between samples (each fills STEP x STEP) */

static double dot3(const double *a, const double *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static double unit(double *a)
{
    double n = sqrt(dot3(a, a));
    for (int i = 0; n > 0.0 && i < 3; i++)
        a[i] /= n;
    return n;
}

void ns_trus_pose(const NsSceneInput *in, NsTrusPose *p)
{
    memset(p, 0, sizeof *p);
    memcpy(p->axis, in->axis, sizeof p->axis);
    if (unit(p->axis) == 0.0)
        p->axis[0] = 1.0;
    /* the world's up (+z, or +y when the needle goes along z: render/scene.c), across the axis */
    double up[3] = {0.0, fabs(p->axis[2]) > 0.9 ? 1.0 : 0.0, fabs(p->axis[2]) > 0.9 ? 0.0 : 1.0};
    double k = dot3(up, p->axis);
    for (int i = 0; i < 3; i++)
        p->up[i] = up[i] - k * p->axis[i];
    unit(p->up);
    p->side[0] = p->axis[1] * p->up[2] - p->axis[2] * p->up[1];
    p->side[1] = p->axis[2] * p->up[0] - p->axis[0] * p->up[2];
    p->side[2] = p->axis[0] * p->up[1] - p->axis[1] * p->up[0];
    double lo_u = INFINITY, hi_u = -INFINITY, lo_s = INFINITY, hi_s = -INFINITY;
    for (int c = 0; c < 8; c++) {
        double q[3];
        for (int i = 0; i < 3; i++)
            q[i] = (c >> i) & 1 ? in->bounds[3 + i] : in->bounds[i];
        lo_u = fmin(lo_u, dot3(q, p->up));
        hi_u = fmax(hi_u, dot3(q, p->up));
        lo_s = fmin(lo_s, dot3(q, p->side));
        hi_s = fmax(hi_s, dot3(q, p->side));
    }
    const double *tip = in->rod_nodes > 0 ? in->rod_x + 3 * (in->rod_nodes - 1) : in->entry;
    double along = dot3(tip, p->axis), level = lo_u + 0.15 * (hi_u - lo_u);
    for (int i = 0; i < 3; i++)
        p->apex[i] = along * p->axis[i] + level * p->up[i] + 0.5 * (lo_s + hi_s) * p->side[i];
    p->range = fmax(1e-3, hi_u - level);
}

/* Pixels per metre, and the apex's pixel, in a w x h panel: the fan's depth fills 90 % of the
 * height, its apex near the bottom centre (the probe below, anterior up, as on a scanner). */
static void layout(const NsTrusPose *p, int w, int h, double *scale, double *ax, double *ay)
{
    *scale = fmin(0.9 * h / p->range, 0.95 * w / (2.0 * p->range * sin(HALF_ANGLE)));
    *ax = 0.5 * w;
    *ay = 0.95 * h;
}

int ns_trus_project(const NsTrusPose *p, int w, int h, const double x[3], double px[2])
{
    double s, ax, ay, q[3];
    layout(p, w, h, &s, &ax, &ay);
    for (int i = 0; i < 3; i++)
        q[i] = x[i] - p->apex[i];
    px[0] = ax + s * dot3(q, p->side);
    px[1] = ay - s * dot3(q, p->up);
    return px[0] >= 0 && px[1] >= 0 && px[0] < w && px[1] < h;
}

/* A hash of a material point's 0.25 mm cell, in [0, 1): the speckle, fixed in the tissue. */
static double speckle(const double u[3])
{
    uint64_t h = 1469598103934665603ull;
    for (int i = 0; i < 3; i++) {
        int64_t c = (int64_t)floor(u[i] / 0.25e-3);
        h = (h ^ (uint64_t)c) * 1099511628211ull;
        h ^= h >> 29;
    }
    h *= 0xbf58476d1ce4e5b9ull;
    h ^= h >> 31;
    return (double)(h >> 11) / 9007199254740992.0;
}

/* Each region's echo level (regions by index; obstacle regions, vessels and ducts, darker). */
static double echo(const NsSceneInput *in, int region)
{
    static const double level[6] = {0.42, 0.30, 0.50, 0.36, 0.46, 0.55};
    if (in->obstacle_region && region >= 0 && region < in->regions && in->obstacle_region[region])
        return 0.16;
    return level[(region < 0 ? 0 : region) % 6];
}

static void put(NsImage *im, int x, int y, double v)
{
    if (x < 0 || y < 0 || x >= im->w || y >= im->h)
        return;
    uint8_t g = (uint8_t)(255.0 * fmin(1.0, fmax(0.0, v)));
    uint8_t *c = im->rgb + 3 * ((size_t)y * im->w + x);
    c[0] = c[1] = c[2] = g;
}

static double get(const NsImage *im, int x, int y)
{
    if (x < 0 || y < 0 || x >= im->w || y >= im->h)
        return 0.0;
    return im->rgb[3 * ((size_t)y * im->w + x)] / 255.0;
}

/* A bright spot at world point x (the needle crossing the plane, a seed), its comet tail
 * (reverberation, away from the probe) and the acoustic shadow beyond it. */
static void reflector(const NsTrusPose *p, NsImage *im, int x0, int w, int h, const double x[3],
                      double radius_px, bool tail)
{
    double px[2];
    if (!ns_trus_project(p, w, h, x, px))
        return;
    double s, ax, ay;
    layout(p, w, h, &s, &ax, &ay);
    double d[2] = {px[0] - ax, px[1] - ay}, n = hypot(d[0], d[1]);
    if (n < 1.0)
        return;
    d[0] /= n;
    d[1] /= n;
    for (double t = 0.0; tail && t < 0.6 * h; t += 1.0) { /* the shadow and the tail */
        double v = t < 24.0 && fmod(t, 6.0) < 2.5 ? 0.85 * (1.0 - t / 24.0) : -1.0;
        for (double a = -radius_px; a <= radius_px; a += 0.5) {
            int xx = (int)lround(px[0] + t * d[0] - a * d[1]),
                yy = (int)lround(px[1] + t * d[1] + a * d[0]);
            if (xx < 0 || xx >= w)
                continue;
            put(im, x0 + xx, yy,
                v >= 0.0 ? fmax(v, get(im, x0 + xx, yy)) : 0.35 * get(im, x0 + xx, yy));
        }
    }
    for (int yy = (int)floor(px[1] - radius_px - 1); yy <= (int)ceil(px[1] + radius_px + 1); yy++)
        for (int xx = (int)floor(px[0] - radius_px - 1); xx <= (int)ceil(px[0] + radius_px + 1);
             xx++)
            if (xx >= 0 && xx < w && hypot(xx + 0.5 - px[0], yy + 0.5 - px[1]) <= radius_px + 0.5)
                put(im, x0 + xx, yy, 1.0);
}

/* The image plane's samples, one every STEP pixels: the region and the material point of the
 * deformed tissue there (region -1: no tissue). */
typedef struct Slice {
    int gw, gh;
    int *region;
    double *u; /* (gw x gh x 3) */
} Slice;

/* Fills the samples that lie in tet e: the tet is cut by the plane, the cut's samples found from
 * its bounding box, and each one's barycentric coordinates, affine in the plane's two
 * coordinates, tested and used to interpolate the material point. */
static void slice_tet(const NsMesh *m, int e, const NsTrusPose *p, double s, double ax, double ay,
                      Slice *sl)
{
    const int *tn = m->tet_node + 4 * e;
    double d[4], q[4][2];
    for (int k = 0; k < 4; k++) {
        double r[3];
        for (int i = 0; i < 3; i++)
            r[i] = m->x[3 * tn[k] + i] - p->apex[i];
        d[k] = dot3(r, p->axis);
        q[k][0] = dot3(r, p->side);
        q[k][1] = dot3(r, p->up);
    }
    if (fmin(fmin(d[0], d[1]), fmin(d[2], d[3])) > 0.0 ||
        fmax(fmax(d[0], d[1]), fmax(d[2], d[3])) < 0.0)
        return;
    /* the cut polygon's box: the plane's crossings of the tet's edges */
    double lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
    for (int a = 0; a < 4; a++)
        for (int b = a; b < 4; b++) {
            if (a == b ? d[a] != 0.0 : (d[a] < 0.0) == (d[b] < 0.0) || d[a] == d[b])
                continue;
            double t = a == b ? 0.0 : d[a] / (d[a] - d[b]);
            for (int i = 0; i < 2; i++) {
                double c = q[a][i] + t * (q[b][i] - q[a][i]);
                lo[i] = fmin(lo[i], c);
                hi[i] = fmax(hi[i], c);
            }
        }
    if (!(lo[0] <= hi[0]))
        return;
    /* barycentric coordinates b_k = c_k + g_k . (x - x0) with the inverse of [x1-x0 x2-x0 x3-x0],
     * restricted to the plane: b_k(qs, qu) = b_k(0) + qs b_k,s + qu b_k,u */
    double e1[3][3], X0[3];
    for (int i = 0; i < 3; i++)
        X0[i] = m->x[3 * tn[0] + i];
    for (int c = 0; c < 3; c++)
        for (int i = 0; i < 3; i++)
            e1[c][i] = m->x[3 * tn[c + 1] + i] - X0[i];
    double g[3][3]; /* rows: gradients of b_1..b_3 (cofactors / det) */
    double det = e1[0][0] * (e1[1][1] * e1[2][2] - e1[1][2] * e1[2][1]) -
                 e1[1][0] * (e1[0][1] * e1[2][2] - e1[0][2] * e1[2][1]) +
                 e1[2][0] * (e1[0][1] * e1[1][2] - e1[0][2] * e1[1][1]);
    if (!(fabs(det) > 1e-30))
        return;
    for (int i = 0; i < 3; i++) {
        const double *b1 = e1[(i + 1) % 3], *b2 = e1[(i + 2) % 3];
        g[i][0] = (b1[1] * b2[2] - b1[2] * b2[1]) / det;
        g[i][1] = (b1[2] * b2[0] - b1[0] * b2[2]) / det;
        g[i][2] = (b1[0] * b2[1] - b1[1] * b2[0]) / det;
    }
    double base[4], ds[4], du[4], r0[3];
    for (int i = 0; i < 3; i++)
        r0[i] = p->apex[i] - X0[i];
    base[0] = 1.0;
    ds[0] = du[0] = 0.0;
    for (int k = 1; k < 4; k++) {
        base[k] = dot3(g[k - 1], r0);
        ds[k] = dot3(g[k - 1], p->side);
        du[k] = dot3(g[k - 1], p->up);
        base[0] -= base[k];
        ds[0] -= ds[k];
        du[0] -= du[k];
    }
    /* the samples in the box (with a little slack: a sample on a face two tets share is kept by
     * the barycentric test, not lost to the boxes' rounding), clamped before the casts */
    double box[4] = {
        ceil((ax + lo[0] * s) / STEP - 0.5 - 1e-6), floor((ax + hi[0] * s) / STEP - 0.5 + 1e-6),
        ceil((ay - hi[1] * s) / STEP - 0.5 - 1e-6), floor((ay - lo[1] * s) / STEP - 0.5 + 1e-6)};
    int x_lo = (int)fmax(0.0, fmin(box[0], sl->gw)),
        x_hi = (int)fmax(-1.0, fmin(box[1], sl->gw - 1));
    int y_lo = (int)fmax(0.0, fmin(box[2], sl->gh)),
        y_hi = (int)fmax(-1.0, fmin(box[3], sl->gh - 1));
    for (int gy = y_lo; gy <= y_hi; gy++) {
        double qu = (ay - (gy + 0.5) * STEP) / s;
        for (int gx = x_lo; gx <= x_hi; gx++) {
            double qs = ((gx + 0.5) * STEP - ax) / s, b[4];
            bool in = true;
            for (int k = 0; k < 4; k++) {
                b[k] = base[k] + qs * ds[k] + qu * du[k];
                in &= b[k] >= -1e-9;
            }
            if (!in)
                continue;
            size_t at = (size_t)gy * sl->gw + gx;
            sl->region[at] = m->tet_region[e];
            for (int i = 0; i < 3; i++)
                sl->u[3 * at + i] = b[0] * m->u[3 * tn[0] + i] + b[1] * m->u[3 * tn[1] + i] +
                                    b[2] * m->u[3 * tn[2] + i] + b[3] * m->u[3 * tn[3] + i];
        }
    }
}

static void fill(NsImage *im, int x, int y, int w, double v)
{
    uint8_t g = (uint8_t)(255.0 * fmin(1.0, fmax(0.0, v)));
    for (int dy = 0; dy < STEP && y + dy < im->h; dy++)
        memset(im->rgb + 3 * ((size_t)(y + dy) * im->w + x), g, 3 * (size_t)(STEP < w ? STEP : w));
}

void ns_trus_draw(const NsSceneInput *in, NsImage *im, int x0, int w, int h)
{
    NsTrusPose p;
    ns_trus_pose(in, &p);
    double s, ax, ay;
    layout(&p, w, h, &s, &ax, &ay);
    const NsMesh *m = in->mesh;
    Slice sl = {(w + STEP - 1) / STEP, (h + STEP - 1) / STEP, NULL, NULL};
    size_t n = (size_t)sl.gw * sl.gh;
    sl.region = malloc(n * sizeof *sl.region);
    sl.u = malloc(3 * n * sizeof *sl.u);
    for (size_t i = 0; sl.region && i < n; i++)
        sl.region[i] = -1;
    for (int e = 0; m && sl.region && sl.u && e < m->tet_slots; e++)
        if (ns_mesh_tet_alive(m, e))
            slice_tet(m, e, &p, s, ax, ay, &sl);
    const double tan_half = tan(HALF_ANGLE); /* inside the fan: |qs| <= qu tan(half angle) */
    for (int gy = 0; gy < sl.gh; gy++) {
        int prev_region = -2;
        for (int gx = 0; gx < sl.gw; gx++) {
            double qs = ((gx + 0.5) * STEP - ax) / s, qu = (ay - (gy + 0.5) * STEP) / s;
            double r = sqrt(qs * qs + qu * qu), v = 0.0;
            size_t at = (size_t)gy * sl.gw + gx;
            int region = sl.region && sl.u ? sl.region[at] : -1;
            if (r <= p.range && fabs(qs) <= qu * tan_half && qu > 0.0 && region >= 0) {
                /* speckle about the region's level, fading with depth; an interface with the
                 * region beside it along the row bright */
                v = echo(in, region) * (0.35 + 1.3 * speckle(sl.u + 3 * at)) *
                    (1.0 - 0.35 * r / p.range);
                if (prev_region >= 0 && region != prev_region)
                    v = fmax(v, 0.85);
                prev_region = region;
            } else {
                prev_region = -2;
            }
            fill(im, x0 + gx * STEP, gy * STEP, w - gx * STEP, v);
        }
    }
    free(sl.region);
    free(sl.u);
    /* the fan's edges and a tick every 10 mm of depth along them */
    for (int side = -1; side <= 1; side += 2)
        for (double r = 0.0; r <= p.range * s; r += 0.5) {
            double dx = side * sin(HALF_ANGLE), dy = -cos(HALF_ANGLE);
            int xx = (int)lround(ax + r * dx), yy = (int)lround(ay + r * dy);
            if (xx >= 0 && xx < w)
                put(im, x0 + xx, yy, 0.6);
            bool tick = fmod(r / s + 1e-9, 0.01) < 0.5 / s;
            for (int t = 1; tick && t <= 6; t++)
                if (xx - side * t >= 0 && xx - side * t < w)
                    put(im, x0 + xx + side * t, yy, 0.9);
        }
    /* seeds near the plane (within 1 mm), then the needle where it crosses the plane */
    for (int i = 0; i < in->seeds; i++) {
        double q[3];
        for (int k = 0; k < 3; k++)
            q[k] = in->seed_x[3 * i + k] - p.apex[k];
        if (fabs(dot3(q, p.axis)) < 1e-3)
            reflector(&p, im, x0, w, h, in->seed_x + 3 * i, fmax(1.5, 0.4e-3 * s), true);
    }
    for (int k = 0; k + 1 < in->rod_nodes; k++) { /* the segment crossing the plane, or the tip */
        const double *a = in->rod_x + 3 * k, *c = in->rod_x + 3 * (k + 1);
        double da = dot3(a, p.axis) - dot3(p.apex, p.axis),
               dc = dot3(c, p.axis) - dot3(p.apex, p.axis);
        if ((da < 0.0) == (dc < 0.0) && !(k + 2 == in->rod_nodes && fabs(dc) < 1e-9))
            continue;
        double t = dc != da ? da / (da - dc) : 1.0, x[3];
        for (int i = 0; i < 3; i++)
            x[i] = a[i] + t * (c[i] - a[i]);
        reflector(&p, im, x0, w, h, x, fmax(2.0, in->rod_radius * s), true);
    }
}
