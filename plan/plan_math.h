/* 3-vector helpers for plan/ (pure functions on double[3]; not for other folders). */
#ifndef NS_PLAN_MATH_H
#define NS_PLAN_MATH_H

#include <math.h>
#include <stdbool.h>

static inline double pm_dot(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static inline void pm_cross(const double a[3], const double b[3], double out[3])
{
    double c[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
    out[0] = c[0];
    out[1] = c[1];
    out[2] = c[2];
}

static inline double pm_norm(const double a[3])
{
    return sqrt(pm_dot(a, a));
}

static inline void pm_sub(const double a[3], const double b[3], double out[3])
{
    for (int i = 0; i < 3; i++)
        out[i] = a[i] - b[i];
}

/* out = a + s b */
static inline void pm_axpy(const double a[3], double s, const double b[3], double out[3])
{
    for (int i = 0; i < 3; i++)
        out[i] = a[i] + s * b[i];
}

static inline double pm_dist(const double a[3], const double b[3])
{
    double d[3];
    pm_sub(a, b, d);
    return pm_norm(d);
}

/* a / |a|; false (a untouched) when |a| is zero or not finite */
static inline bool pm_unit(double a[3])
{
    double n = pm_norm(a);
    if (!(n > 1e-300) || !isfinite(n))
        return false;
    for (int i = 0; i < 3; i++)
        a[i] /= n;
    return true;
}

static inline bool pm_finite(const double a[3])
{
    return isfinite(a[0]) && isfinite(a[1]) && isfinite(a[2]);
}

#endif
