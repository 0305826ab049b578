/* The trus view (render/trus.h). */
#include "trus.h"

#include <math.h>
#include <stdint.h>
#include <string.h>

#include "remesh.h"

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

void ns_trus_draw(const NsSceneInput *in, NsImage *im, int x0, int w, int h)
{
    NsTrusPose p;
    ns_trus_pose(in, &p);
    double s, ax, ay;
    layout(&p, w, h, &s, &ax, &ay);
    const NsMesh *m = in->mesh;
    int hint = -1;
    for (int y = 0; y < h; y += STEP) {
        int prev_region = -2;
        for (int x = 0; x < w; x += STEP) {
            double qs = (x + 0.5 * STEP - ax) / s, qu = (ay - y - 0.5 * STEP) / s;
            double r = hypot(qs, qu), th = atan2(qs, qu), v = 0.0;
            if (r <= p.range && fabs(th) <= HALF_ANGLE && qu > 0.0) {
                double wpt[3], b[4];
                for (int i = 0; i < 3; i++)
                    wpt[i] = p.apex[i] + qs * p.side[i] + qu * p.up[i];
                bool boxed = true; /* (a point outside the tissue's box would be searched for in
                                    * every tet) */
                for (int i = 0; i < 3; i++)
                    boxed &= wpt[i] >= in->bounds[i] && wpt[i] <= in->bounds[3 + i];
                int e = m && boxed ? ns_mesh_locate_in(m, m->x, wpt, hint, 1e-9, b) : -1;
                if (e >= 0) {
                    hint = e;
                    double u[3] = {0, 0, 0};
                    const int *tn = m->tet_node + 4 * e;
                    for (int k = 0; k < 4; k++)
                        for (int i = 0; i < 3; i++)
                            u[i] += b[k] * m->u[3 * tn[k] + i];
                    int region = m->tet_region[e];
                    /* speckle about the region's level, fading with depth; an interface with
                     * the region beside it along the row bright */
                    v = echo(in, region) * (0.35 + 1.3 * speckle(u)) * (1.0 - 0.35 * r / p.range);
                    if (prev_region >= 0 && region != prev_region)
                        v = fmax(v, 0.85);
                    prev_region = region;
                } else {
                    prev_region = -2;
                }
            }
            for (int dy = 0; dy < STEP; dy++)
                for (int dx = 0; dx < STEP && x + dx < w; dx++)
                    put(im, x0 + x + dx, y + dy, v);
        }
    }
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
