/* The bevel-tip unicycle (Webster et al. 2006) in closed form: see kinematic.h. */
#include "kinematic.h"

#include <math.h>
#include <string.h>

#include "plan_math.h"

bool ns_plan_pose_make(const double p[3], const double dir[3], const double toward[3],
                       NsPlanPose *out)
{
    if (!p || !dir || !out || !pm_finite(p) || !pm_finite(dir))
        return false;
    double t[3] = {dir[0], dir[1], dir[2]};
    if (!pm_unit(t))
        return false;
    double m2[3] = {0.0, 0.0, 0.0};
    bool have = false;
    if (toward && pm_finite(toward)) {
        pm_axpy(toward, -pm_dot(toward, t), t, m2);
        have = pm_norm(m2) > 1e-9 * (pm_norm(toward) + 1e-300) && pm_unit(m2);
    }
    if (!have) {
        /* any normal: the axis least aligned with t, made normal to it */
        int k = fabs(t[0]) <= fabs(t[1]) && fabs(t[0]) <= fabs(t[2]) ? 0
                : fabs(t[1]) <= fabs(t[2])                           ? 1
                                                                     : 2;
        double e[3] = {0.0, 0.0, 0.0};
        e[k] = 1.0;
        pm_axpy(e, -pm_dot(e, t), t, m2);
        pm_unit(m2);
    }
    memcpy(out->p, p, sizeof out->p);
    memcpy(out->t, t, sizeof out->t);
    memcpy(out->m2, m2, sizeof out->m2);
    return true;
}

void ns_plan_pose_m1(const NsPlanPose *pose, double m1[3])
{
    pm_cross(pose->m2, pose->t, m1);
}

void ns_plan_twist(NsPlanPose *pose, double angle)
{
    double m1[3];
    ns_plan_pose_m1(pose, m1);
    double c = cos(angle), s = sin(angle);
    /* m1' = c m1 + s m2, m2' = -s m1 + c m2 (right hand about t) */
    for (int i = 0; i < 3; i++)
        pose->m2[i] = -s * m1[i] + c * pose->m2[i];
    pm_unit(pose->m2);
}

double ns_plan_kappa_eff(double kappa, double duty)
{
    double d = duty < 0.0 ? 0.0 : duty > 1.0 ? 1.0 : duty;
    return kappa * (1.0 - d);
}

/* Rodrigues: v turned by angle th about the unit axis k */
static void rotate(const double k[3], double th, const double v[3], double out[3])
{
    double kv[3];
    pm_cross(k, v, kv);
    double c = cos(th), s = sin(th), kd = pm_dot(k, v) * (1.0 - c);
    for (int i = 0; i < 3; i++)
        out[i] = v[i] * c + kv[i] * s + k[i] * kd;
}

bool ns_plan_advance(const NsPlanPose *in, double kappa, double tau, double s, NsPlanPose *out)
{
    if (!in || !out || !(kappa >= 0.0) || !isfinite(kappa) || !isfinite(tau) || !(s >= 0.0) ||
        !isfinite(s))
        return false;
    double m1[3];
    ns_plan_pose_m1(in, m1);
    /* body twist in (m1, m2, t): v = e3, w = (-kappa, 0, tau) (Webster 2006, Eq. 2 with the
     * base's rotation folded in); g(s) = g0 exp(s xi). */
    double w = sqrt(kappa * kappa + tau * tau), th = w * s;
    double A, B; /* V(s) = s I + A w^ + B w^2 */
    if (th < 1e-4) {
        /* series to the order that keeps double precision at th < 1e-4 */
        A = s * s * (0.5 - th * th / 24.0);
        B = s * s * s * (1.0 / 6.0 - th * th / 120.0);
    } else {
        A = (1.0 - cos(th)) / (w * w);
        B = (th - sin(th)) / (w * w * w);
    }
    /* V e3 = s e3 + A (w x e3) + B w x (w x e3) = (-B tau kappa, A kappa, s - B kappa^2) */
    double db[3] = {-B * tau * kappa, A * kappa, s - B * kappa * kappa};
    NsPlanPose r;
    for (int i = 0; i < 3; i++)
        r.p[i] = in->p[i] + m1[i] * db[0] + in->m2[i] * db[1] + in->t[i] * db[2];
    if (w > 0.0) {
        double k[3] = {-kappa / w, 0.0, tau / w}, e2[3] = {0, 1, 0}, e3[3] = {0, 0, 1}, b2[3],
               b3[3];
        rotate(k, th, e2, b2);
        rotate(k, th, e3, b3);
        for (int i = 0; i < 3; i++) {
            r.m2[i] = m1[i] * b2[0] + in->m2[i] * b2[1] + in->t[i] * b2[2];
            r.t[i] = m1[i] * b3[0] + in->m2[i] * b3[1] + in->t[i] * b3[2];
        }
        /* keep the frame orthonormal against rounding */
        pm_unit(r.t);
        pm_axpy(r.m2, -pm_dot(r.m2, r.t), r.t, r.m2);
        pm_unit(r.m2);
    } else {
        memcpy(r.t, in->t, sizeof r.t);
        memcpy(r.m2, in->m2, sizeof r.m2);
    }
    *out = r;
    return true;
}

void ns_plan_helix(const NsPlanPose *pose, double kappa, double tau, NsPlanHelix *h)
{
    double w2 = kappa * kappa + tau * tau;
    if (!(w2 > 0.0) || !(kappa > 0.0)) {
        h->radius = 0.0;
        h->pitch = 0.0;
        memcpy(h->axis, pose->t, sizeof h->axis);
        memcpy(h->point, pose->p, sizeof h->point);
        return;
    }
    double w = sqrt(w2), m1[3];
    ns_plan_pose_m1(pose, m1);
    h->radius = kappa / w2;
    h->pitch = 2.0 * M_PI * tau / w2;
    for (int i = 0; i < 3; i++) {
        h->axis[i] = (-kappa * m1[i] + tau * pose->t[i]) / w;
        /* the principal normal m2 points at the axis */
        h->point[i] = pose->p[i] + h->radius * pose->m2[i];
    }
}

static double dist_at(const NsPlanPose *pose, double kappa, double tau, double s, const double q[3])
{
    NsPlanPose o;
    ns_plan_advance(pose, kappa, tau, s, &o);
    return pm_dist(o.p, q);
}

double ns_plan_closest(const NsPlanPose *pose, double kappa, double tau, double length, double step,
                       const double q[3], double *at)
{
    if (!(length > 0.0) || !isfinite(length)) {
        if (at)
            *at = 0.0;
        return pm_dist(pose->p, q);
    }
    if (!(step > 0.0))
        step = length / 64.0;
    int n = (int)ceil(length / step);
    if (n < 1)
        n = 1;
    if (n > 1000000)
        n = 1000000;
    double h = length / n, best = INFINITY;
    int bi = 0;
    for (int i = 0; i <= n; i++) {
        double d = dist_at(pose, kappa, tau, i * h, q);
        if (d < best) {
            best = d;
            bi = i;
        }
    }
    /* golden section on the bracket around the best sample */
    double lo = bi > 0 ? (bi - 1) * h : 0.0, hi = bi < n ? (bi + 1) * h : length;
    const double g = 0.5 * (sqrt(5.0) - 1.0);
    double x1 = hi - g * (hi - lo), x2 = lo + g * (hi - lo);
    double f1 = dist_at(pose, kappa, tau, x1, q), f2 = dist_at(pose, kappa, tau, x2, q);
    for (int it = 0; it < 60 && hi - lo > 1e-12; it++) {
        if (f1 < f2) {
            hi = x2;
            x2 = x1;
            f2 = f1;
            x1 = hi - g * (hi - lo);
            f1 = dist_at(pose, kappa, tau, x1, q);
        } else {
            lo = x1;
            x1 = x2;
            f1 = f2;
            x2 = lo + g * (hi - lo);
            f2 = dist_at(pose, kappa, tau, x2, q);
        }
    }
    double sm = 0.5 * (lo + hi), dm = dist_at(pose, kappa, tau, sm, q);
    double s_best = bi * h;
    if (dm < best) {
        best = dm;
        s_best = sm;
    }
    if (at)
        *at = s_best;
    return best;
}
