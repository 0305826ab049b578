/* Signed-distance shapes for the mesher (see shape.h).
 *
 * Each node is immutable after construction and reference counted, so one primitive can be
 * shared by several CSG trees and by several mesher regions. The mesher only needs the sign
 * and continuity of eval() (isosurface stuffing finds the surface by bisection on the sign,
 * Labelle & Shewchuk 2007 §3), so the ellipsoid may use an approximate distance; the other
 * primitives are exact so that callers may also use them as distances. */
#include "shape.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

struct NsShape {
    NsShapeKind kind;
    int refs;
    /* primitives */
    double c[3]; /* sphere/ellipsoid/box centre; cylinder/capsule end a */
    double d[3]; /* ellipsoid radii; box half size; cylinder/capsule end b */
    double r;    /* sphere/cylinder/capsule radius */
    /* transform: eval(p) = s * child(R^T (p - t) / s) */
    double rot[9]; /* row-major */
    double t[3];
    double s;
    /* CSG children (own a reference each) */
    NsShape **kids;
    int nkids;
    /* callback */
    NsShapeFn fn;
    void *user;
    /* bounds of the interior */
    bool bounded;
    double lo[3], hi[3];
};

static NsShape *shape_new(NsShapeKind kind)
{
    NsShape *s = calloc(1, sizeof *s);
    if (!s)
        return NULL;
    s->kind = kind;
    s->refs = 1;
    s->bounded = true;
    return s;
}

static double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static double norm3(const double a[3])
{
    return sqrt(dot3(a, a));
}

NsShape *ns_shape_sphere(const double center[3], double radius)
{
    NsShape *s = shape_new(NS_SHAPE_SPHERE);
    if (!s)
        return NULL;
    memcpy(s->c, center, sizeof s->c);
    s->r = radius;
    for (int k = 0; k < 3; k++) {
        s->lo[k] = center[k] - radius;
        s->hi[k] = center[k] + radius;
    }
    return s;
}

NsShape *ns_shape_ellipsoid(const double center[3], const double radii[3])
{
    NsShape *s = shape_new(NS_SHAPE_ELLIPSOID);
    if (!s)
        return NULL;
    memcpy(s->c, center, sizeof s->c);
    for (int k = 0; k < 3; k++) {
        s->d[k] = fabs(radii[k]);
        s->lo[k] = center[k] - s->d[k];
        s->hi[k] = center[k] + s->d[k];
    }
    return s;
}

NsShape *ns_shape_box(const double center[3], const double size[3])
{
    NsShape *s = shape_new(NS_SHAPE_BOX);
    if (!s)
        return NULL;
    memcpy(s->c, center, sizeof s->c);
    for (int k = 0; k < 3; k++) {
        s->d[k] = 0.5 * fabs(size[k]);
        s->lo[k] = center[k] - s->d[k];
        s->hi[k] = center[k] + s->d[k];
    }
    return s;
}

/* Tight box of a cylinder: an end disc of radius r with unit normal n extends
 * r * sqrt(1 - n_k^2) along axis k (the largest |component| of a unit vector in the disc's
 * plane along e_k). */
static void disc_bounds(NsShape *s, double radius)
{
    double axis[3] = {s->d[0] - s->c[0], s->d[1] - s->c[1], s->d[2] - s->c[2]};
    double len = norm3(axis);
    for (int k = 0; k < 3; k++) {
        double n = len > 0 ? axis[k] / len : 0.0;
        double e = radius * sqrt(fmax(0.0, 1.0 - n * n));
        s->lo[k] = fmin(s->c[k], s->d[k]) - e;
        s->hi[k] = fmax(s->c[k], s->d[k]) + e;
    }
}

NsShape *ns_shape_cylinder(const double a[3], const double b[3], double radius)
{
    NsShape *s = shape_new(NS_SHAPE_CYLINDER);
    if (!s)
        return NULL;
    memcpy(s->c, a, sizeof s->c);
    memcpy(s->d, b, sizeof s->d);
    s->r = radius;
    disc_bounds(s, radius);
    return s;
}

NsShape *ns_shape_capsule(const double a[3], const double b[3], double radius)
{
    NsShape *s = shape_new(NS_SHAPE_CAPSULE);
    if (!s)
        return NULL;
    memcpy(s->c, a, sizeof s->c);
    memcpy(s->d, b, sizeof s->d);
    s->r = radius;
    for (int k = 0; k < 3; k++) {
        s->lo[k] = fmin(a[k], b[k]) - radius;
        s->hi[k] = fmax(a[k], b[k]) + radius;
    }
    return s;
}

static NsShape *csg_new(NsShapeKind kind, NsShape *const *children, int count)
{
    if (!children || count <= 0)
        return NULL;
    for (int i = 0; i < count; i++)
        if (!children[i])
            return NULL;
    NsShape *s = shape_new(kind);
    if (!s)
        return NULL;
    s->kids = malloc((size_t)count * sizeof *s->kids);
    if (!s->kids) {
        free(s);
        return NULL;
    }
    s->nkids = count;
    for (int i = 0; i < count; i++) {
        s->kids[i] = children[i];
        ns_shape_retain(children[i]);
    }
    return s;
}

NsShape *ns_shape_union(NsShape *const *children, int count)
{
    NsShape *s = csg_new(NS_SHAPE_UNION, children, count);
    if (!s)
        return NULL;
    /* Any unbounded child makes the union unbounded. */
    for (int i = 0; i < count && s->bounded; i++) {
        const NsShape *k = children[i];
        if (!k->bounded) {
            s->bounded = false;
            break;
        }
        for (int a = 0; a < 3; a++) {
            s->lo[a] = i == 0 ? k->lo[a] : fmin(s->lo[a], k->lo[a]);
            s->hi[a] = i == 0 ? k->hi[a] : fmax(s->hi[a], k->hi[a]);
        }
    }
    return s;
}

NsShape *ns_shape_intersection(NsShape *const *children, int count)
{
    NsShape *s = csg_new(NS_SHAPE_INTERSECTION, children, count);
    if (!s)
        return NULL;
    /* Bounded as soon as one child is; the box is the intersection of the bounded ones (it may
     * be empty, lo > hi, which still contains the empty interior). */
    bool any = false;
    for (int i = 0; i < count; i++) {
        const NsShape *k = children[i];
        if (!k->bounded)
            continue;
        for (int a = 0; a < 3; a++) {
            s->lo[a] = any ? fmax(s->lo[a], k->lo[a]) : k->lo[a];
            s->hi[a] = any ? fmin(s->hi[a], k->hi[a]) : k->hi[a];
        }
        any = true;
    }
    s->bounded = any;
    return s;
}

NsShape *ns_shape_difference(NsShape *a, NsShape *b)
{
    NsShape *pair[2] = {a, b};
    NsShape *s = csg_new(NS_SHAPE_DIFFERENCE, pair, 2);
    if (!s)
        return NULL;
    s->bounded = a->bounded;
    memcpy(s->lo, a->lo, sizeof s->lo);
    memcpy(s->hi, a->hi, sizeof s->hi);
    return s;
}

NsShape *ns_shape_transform(NsShape *child, const double rotation[9], const double translate[3],
                            double scale)
{
    if (!(scale > 0))
        return NULL;
    NsShape *s = csg_new(NS_SHAPE_TRANSFORM, &child, 1);
    if (!s)
        return NULL;
    memcpy(s->rot, rotation, sizeof s->rot);
    memcpy(s->t, translate, sizeof s->t);
    s->s = scale;
    s->bounded = child->bounded;
    if (child->bounded) {
        /* The interior maps to t + R (s q) for q in the child's interior, so the image of the
         * child's eight box corners bounds it (the box is convex). */
        for (int corner = 0; corner < 8; corner++) {
            double q[3], p[3];
            for (int a = 0; a < 3; a++)
                q[a] = scale * ((corner >> a & 1) ? child->hi[a] : child->lo[a]);
            for (int a = 0; a < 3; a++)
                p[a] = translate[a] + rotation[3 * a] * q[0] + rotation[3 * a + 1] * q[1] +
                       rotation[3 * a + 2] * q[2];
            for (int a = 0; a < 3; a++) {
                s->lo[a] = corner == 0 ? p[a] : fmin(s->lo[a], p[a]);
                s->hi[a] = corner == 0 ? p[a] : fmax(s->hi[a], p[a]);
            }
        }
    }
    return s;
}

NsShape *ns_shape_callback(NsShapeFn fn, void *user, const double lo[3], const double hi[3])
{
    if (!fn)
        return NULL;
    NsShape *s = shape_new(NS_SHAPE_CALLBACK);
    if (!s)
        return NULL;
    s->fn = fn;
    s->user = user;
    memcpy(s->lo, lo, sizeof s->lo);
    memcpy(s->hi, hi, sizeof s->hi);
    return s;
}

void ns_shape_retain(NsShape *s)
{
    if (s)
        s->refs++;
}

void ns_shape_release(NsShape *s)
{
    if (!s || --s->refs > 0)
        return;
    for (int i = 0; i < s->nkids; i++)
        ns_shape_release(s->kids[i]);
    free(s->kids);
    free(s);
}

/* Exact distance to a box of half size h centred at the origin, at q (Quilez's formulation:
 * outside, the distance to the nearest point of the clamped box; inside, minus the distance
 * to the nearest face). */
static double box_sdf(const double q[3], const double h[3])
{
    double out2 = 0.0, in = -INFINITY;
    for (int k = 0; k < 3; k++) {
        double e = fabs(q[k]) - h[k];
        if (e > 0)
            out2 += e * e;
        in = fmax(in, e);
    }
    return sqrt(out2) + fmin(in, 0.0);
}

static double eval_cylinder(const NsShape *s, const double p[3])
{
    double axis[3] = {s->d[0] - s->c[0], s->d[1] - s->c[1], s->d[2] - s->c[2]};
    double len = norm3(axis);
    double mid[3], w[3];
    for (int k = 0; k < 3; k++) {
        mid[k] = 0.5 * (s->c[k] + s->d[k]);
        w[k] = p[k] - mid[k];
    }
    double along = 0.0, radial2 = dot3(w, w);
    if (len > 0) {
        along = dot3(w, axis) / len;
        radial2 -= along * along;
    }
    /* In the (radial, axial) half plane the cylinder is a rectangle; its 2D box distance is
     * the exact 3D distance because the cylinder is a solid of revolution. */
    double e0 = sqrt(fmax(radial2, 0.0)) - s->r;
    double e1 = fabs(along) - 0.5 * len;
    double o0 = fmax(e0, 0.0), o1 = fmax(e1, 0.0);
    return sqrt(o0 * o0 + o1 * o1) + fmin(fmax(e0, e1), 0.0);
}

static double eval_capsule(const NsShape *s, const double p[3])
{
    double ab[3], ap[3];
    for (int k = 0; k < 3; k++) {
        ab[k] = s->d[k] - s->c[k];
        ap[k] = p[k] - s->c[k];
    }
    double l2 = dot3(ab, ab);
    double t = l2 > 0 ? fmin(fmax(dot3(ap, ab) / l2, 0.0), 1.0) : 0.0;
    double w[3] = {ap[0] - t * ab[0], ap[1] - t * ab[1], ap[2] - t * ab[2]};
    return norm3(w) - s->r;
}

static double eval_ellipsoid(const NsShape *s, const double p[3])
{
    /* Quilez's bound k0 (k0 - 1) / k1 with k0 = |q/r|, k1 = |q/r^2|: its sign is that of
     * k0 - 1, which is exactly inside/outside, and it is continuous away from the centre. */
    double q0[3], q1[3];
    for (int k = 0; k < 3; k++) {
        double q = p[k] - s->c[k];
        q0[k] = q / s->d[k];
        q1[k] = q / (s->d[k] * s->d[k]);
    }
    double k0 = norm3(q0), k1 = norm3(q1);
    if (k1 == 0.0) /* the centre: the distance to the nearest surface point */
        return -fmin(s->d[0], fmin(s->d[1], s->d[2]));
    return k0 * (k0 - 1.0) / k1;
}

double ns_shape_eval(const NsShape *s, const double p[3])
{
    switch (s->kind) {
    case NS_SHAPE_SPHERE: {
        double w[3] = {p[0] - s->c[0], p[1] - s->c[1], p[2] - s->c[2]};
        return norm3(w) - s->r;
    }
    case NS_SHAPE_ELLIPSOID:
        return eval_ellipsoid(s, p);
    case NS_SHAPE_BOX: {
        double q[3] = {p[0] - s->c[0], p[1] - s->c[1], p[2] - s->c[2]};
        return box_sdf(q, s->d);
    }
    case NS_SHAPE_CYLINDER:
        return eval_cylinder(s, p);
    case NS_SHAPE_CAPSULE:
        return eval_capsule(s, p);
    case NS_SHAPE_UNION: {
        double v = ns_shape_eval(s->kids[0], p);
        for (int i = 1; i < s->nkids; i++)
            v = fmin(v, ns_shape_eval(s->kids[i], p));
        return v;
    }
    case NS_SHAPE_INTERSECTION: {
        double v = ns_shape_eval(s->kids[0], p);
        for (int i = 1; i < s->nkids; i++)
            v = fmax(v, ns_shape_eval(s->kids[i], p));
        return v;
    }
    case NS_SHAPE_DIFFERENCE:
        return fmax(ns_shape_eval(s->kids[0], p), -ns_shape_eval(s->kids[1], p));
    case NS_SHAPE_TRANSFORM: {
        double w[3] = {p[0] - s->t[0], p[1] - s->t[1], p[2] - s->t[2]};
        double q[3];
        for (int a = 0; a < 3; a++) /* R^T w: column a of R */
            q[a] = (s->rot[a] * w[0] + s->rot[3 + a] * w[1] + s->rot[6 + a] * w[2]) / s->s;
        return s->s * ns_shape_eval(s->kids[0], q);
    }
    case NS_SHAPE_CALLBACK:
        return s->fn(s->user, p);
    }
    return NAN;
}

bool ns_shape_bounds(const NsShape *s, double lo[3], double hi[3])
{
    if (!s->bounded)
        return false;
    memcpy(lo, s->lo, 3 * sizeof *lo);
    memcpy(hi, s->hi, 3 * sizeof *hi);
    return true;
}

NsShapeKind ns_shape_kind(const NsShape *s)
{
    return s->kind;
}
