/* Signed distances of the planners' obstacles: see obstacle.h. */
#include "obstacle.h"

#include <math.h>
#include <string.h>

#include "err.h"
#include "plan_math.h"

static NsPlanObstacle make(NsPlanObstacleKind kind, const double a[3], const double b[3],
                           double radius)
{
    NsPlanObstacle o;
    memset(&o, 0, sizeof o);
    o.kind = kind;
    memcpy(o.a, a, sizeof o.a);
    if (b)
        memcpy(o.b, b, sizeof o.b);
    o.radius = radius;
    return o;
}

NsPlanObstacle ns_plan_sphere(const double c[3], double radius)
{
    return make(NS_PLAN_SPHERE, c, NULL, radius);
}

NsPlanObstacle ns_plan_capsule(const double a[3], const double b[3], double radius)
{
    return make(NS_PLAN_CAPSULE, a, b, radius);
}

NsPlanObstacle ns_plan_cylinder(const double a[3], const double b[3], double radius)
{
    return make(NS_PLAN_CYLINDER, a, b, radius);
}

NsPlanObstacle ns_plan_box(const double lo[3], const double hi[3])
{
    return make(NS_PLAN_BOX, lo, hi, 0.0);
}

bool ns_plan_obstacle_valid(const NsPlanObstacle *o, char *err, int err_sz)
{
    const char *name = o->name ? o->name : "obstacle";
    bool ok = pm_finite(o->a) && pm_finite(o->b) && isfinite(o->radius);
    switch (o->kind) {
    case NS_PLAN_SPHERE:
        ok = ok && o->radius > 0.0;
        break;
    case NS_PLAN_CAPSULE:
    case NS_PLAN_CYLINDER:
        ok = ok && o->radius > 0.0 && pm_dist(o->a, o->b) > 0.0;
        break;
    case NS_PLAN_BOX:
        ok = ok && o->a[0] < o->b[0] && o->a[1] < o->b[1] && o->a[2] < o->b[2];
        break;
    case NS_PLAN_SHAPE:
        ok = o->shape != NULL;
        break;
    default:
        ok = false;
    }
    if (!ok)
        ns_set_err(err, err_sz,
                   "%s: not a shape (finite numbers, radius > 0, distinct axis ends, box low < "
                   "high, or a shape given)",
                   name);
    return ok;
}

/* the axial coordinate along a->b (0 at a, |b - a| at b) and the distance from the axis line */
static void axial(const NsPlanObstacle *o, const double p[3], double *h, double *r, double *len)
{
    double ax[3], d[3];
    pm_sub(o->b, o->a, ax);
    *len = pm_norm(ax);
    for (int i = 0; i < 3; i++)
        ax[i] /= *len;
    pm_sub(p, o->a, d);
    *h = pm_dot(d, ax);
    double perp[3];
    pm_axpy(d, -*h, ax, perp);
    *r = pm_norm(perp);
}

double ns_plan_obstacle_distance(const NsPlanObstacle *o, const double p[3])
{
    switch (o->kind) {
    case NS_PLAN_SPHERE:
        return pm_dist(p, o->a) - o->radius;
    case NS_PLAN_CAPSULE: {
        double h, r, len;
        axial(o, p, &h, &r, &len);
        double c = h < 0.0 ? -h : h > len ? h - len : 0.0;
        return sqrt(r * r + c * c) - o->radius;
    }
    case NS_PLAN_CYLINDER: {
        double h, r, len;
        axial(o, p, &h, &r, &len);
        double dx = r - o->radius, dy = fabs(h - 0.5 * len) - 0.5 * len;
        double ox = fmax(dx, 0.0), oy = fmax(dy, 0.0);
        return sqrt(ox * ox + oy * oy) + fmin(fmax(dx, dy), 0.0);
    }
    case NS_PLAN_BOX: {
        double q[3], out2 = 0.0, in = -INFINITY;
        for (int i = 0; i < 3; i++) {
            double c = 0.5 * (o->a[i] + o->b[i]), hw = 0.5 * (o->b[i] - o->a[i]);
            q[i] = fabs(p[i] - c) - hw;
            out2 += q[i] > 0.0 ? q[i] * q[i] : 0.0;
            in = fmax(in, q[i]);
        }
        return sqrt(out2) + fmin(in, 0.0);
    }
    case NS_PLAN_SHAPE:
        return ns_shape_eval(o->shape, p);
    }
    return NAN;
}

double ns_plan_obstacles_distance(const NsPlanObstacle *obs, int count, const double p[3],
                                  int *which)
{
    double best = INFINITY;
    int w = -1;
    for (int i = 0; i < count; i++) {
        double d = ns_plan_obstacle_distance(&obs[i], p);
        if (d < best || isnan(d)) {
            best = d;
            w = i;
            if (isnan(d))
                break;
        }
    }
    if (which)
        *which = w;
    return best;
}
