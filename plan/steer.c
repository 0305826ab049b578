/* Hauser-style closed-loop steering on the kinematic model: see steer.h. */
#include "steer.h"

#include <math.h>
#include <string.h>

#include "err.h"
#include "plan_math.h"

NsSteerParams ns_steer_default(double kappa)
{
    NsSteerParams p;
    memset(&p, 0, sizeof p);
    p.kappa = kappa;
    p.angle_count = 32;
    p.exact_angle = true;
    p.duty_cycle = true;
    return p;
}

/* angle in (-pi, pi] */
static double wrap(double a)
{
    a = fmod(a, 2.0 * M_PI);
    if (a > M_PI)
        a -= 2.0 * M_PI;
    else if (a <= -M_PI)
        a += 2.0 * M_PI;
    return a;
}

/* One candidate: twist by phi, then the arc (or helix at rate) it implies; its miss. */
static void evaluate(const NsSteerParams *prm, const NsPlanPose *tip, const double q[3],
                     double horizon, double phi, double rate, bool choose_duty, NsSteerAction *c)
{
    NsPlanPose p = *tip;
    ns_plan_twist(&p, phi);
    double duty = 0.0;
    if (choose_duty) {
        /* the arc tangent to t at p through the target's projection on the (t, m2) plane:
         * kappa = 2 b / (a^2 + b^2), a along t, b along m2 */
        double d[3];
        pm_sub(q, p.p, d);
        double a = pm_dot(d, p.t), b = pm_dot(d, p.m2), r2 = a * a + b * b;
        double need = b > 0.0 && r2 > 0.0 ? 2.0 * b / r2 : 0.0;
        duty = need >= prm->kappa ? 0.0 : 1.0 - need / prm->kappa;
    }
    double k = ns_plan_kappa_eff(prm->kappa, duty), at;
    c->twist = wrap(phi);
    c->duty = duty;
    c->rate = rate;
    c->miss = ns_plan_closest(&p, k, rate, horizon, horizon / 96.0, q, &at);
    c->at = at;
}

static bool better(const NsSteerAction *c, const NsSteerAction *best)
{
    const double tie = 1e-9; /* [m] */
    if (c->miss < best->miss - tie)
        return true;
    return c->miss <= best->miss + tie && fabs(c->twist) < fabs(best->twist);
}

int ns_steer_choose(const NsSteerParams *prm, const NsPlanPose *tip, const double target[3],
                    NsSteerAction *out, char *err, int err_sz)
{
    if (!prm || !tip || !target || !out) {
        ns_set_err(err, err_sz, "ns_steer_choose: a NULL argument");
        return -1;
    }
    if (!(prm->kappa > 0.0) || !isfinite(prm->kappa) || prm->angle_count < 1 ||
        prm->angle_count > 4096 || prm->rate_count < 0 || prm->rate_count > 256 ||
        (prm->rate_count > 0 && !prm->rates) || !isfinite(prm->horizon)) {
        ns_set_err(err, err_sz,
                   "ns_steer_choose: kappa %g 1/m must be > 0, angle_count %d in 1..4096, "
                   "rate_count %d in 0..256 with rates, horizon finite",
                   prm->kappa, prm->angle_count, prm->rate_count);
        return -1;
    }
    if (!pm_finite(target) || !pm_finite(tip->p) || !pm_finite(tip->t) || !pm_finite(tip->m2)) {
        ns_set_err(err, err_sz, "ns_steer_choose: a non-finite tip pose or target");
        return -1;
    }
    double dist = pm_dist(target, tip->p);
    double horizon = prm->horizon > 0.0 ? prm->horizon : 1.5 * dist + 1e-6;
    NsSteerAction best = {0.0, 0.0, 0.0, INFINITY, 0.0};
    NsSteerAction c;
    if (prm->exact_angle) {
        double d[3], m1[3];
        pm_sub(target, tip->p, d);
        ns_plan_pose_m1(tip, m1);
        /* m2' = -sin(phi) m1 + cos(phi) m2 along the target's part normal to t */
        double phi = atan2(-pm_dot(d, m1), pm_dot(d, tip->m2));
        evaluate(prm, tip, target, horizon, phi, 0.0, prm->duty_cycle, &c);
        best = c;
    }
    for (int i = 0; i < prm->angle_count; i++) {
        evaluate(prm, tip, target, horizon, 2.0 * M_PI * i / prm->angle_count, 0.0, prm->duty_cycle,
                 &c);
        if (better(&c, &best))
            best = c;
    }
    for (int i = 0; i < prm->rate_count; i++) {
        if (!isfinite(prm->rates[i])) {
            ns_set_err(err, err_sz, "ns_steer_choose: rates[%d] is not finite", i);
            return -1;
        }
        evaluate(prm, tip, target, horizon, 0.0, prm->rates[i], false, &c);
        if (better(&c, &best))
            best = c;
    }
    *out = best;
    return 0;
}

static void target_now(const NsSteerLoop *loop, double inserted, double q[3])
{
    if (loop->target_fn)
        loop->target_fn(loop->user, inserted, q);
    else
        memcpy(q, loop->target, sizeof(double) * 3);
}

int ns_steer_rollout(const NsSteerParams *prm, const NsSteerLoop *loop, const NsPlanPose *start,
                     NsPlanPath *path, char *err, int err_sz)
{
    if (!prm || !loop || !start || !path || !(loop->replan_every > 0.0) ||
        !(loop->max_length > 0.0) || !isfinite(loop->max_length) || !(loop->kappa_true >= 0.0) ||
        !isfinite(loop->kappa_true) || (!loop->target && !loop->target_fn) ||
        loop->max_length / loop->replan_every > 1e6) {
        ns_set_err(err, err_sz,
                   "ns_steer_rollout: replan_every and max_length must be > 0 (at most 1e6 "
                   "replans), kappa_true >= 0, and a target given");
        return -1;
    }
    if (!ns_plan_path_init(path, start, loop->kappa_true)) {
        ns_set_err(err, err_sz, "ns_steer_rollout: out of memory");
        return -1;
    }
    double inserted = 0.0, turned = 0.0, straightness = 0.0;
    NsSteerParams model = *prm;
    while (inserted < loop->max_length) {
        /* a copy: pushing the action may move path->poses */
        const NsPlanPose tip_pose = path->poses[path->action_count], *tip = &tip_pose;
        double q[3], d[3];
        target_now(loop, inserted, q);
        pm_sub(q, tip->p, d);
        if (pm_dot(d, tip->t) <= 0.0 && path->action_count > 0)
            break; /* the target is behind the tip: it has passed its closest approach */
        NsSteerAction act;
        if (ns_steer_choose(&model, tip, q, &act, err, err_sz) != 0) {
            ns_plan_path_free(path);
            return -1;
        }
        double len = fmin(loop->replan_every, loop->max_length - inserted);
        NsPlanAction a = {act.twist, len, act.duty, act.rate};
        if (!ns_plan_path_push(path, &a)) {
            ns_set_err(err, err_sz, "ns_steer_rollout: out of memory");
            ns_plan_path_free(path);
            return -1;
        }
        inserted += len;
        /* this segment's closest approach to where the target is at its end */
        double qe[3];
        target_now(loop, inserted, qe);
        NsPlanPose p = *tip;
        ns_plan_twist(&p, a.twist);
        double e = ns_plan_closest(&p, ns_plan_kappa_eff(loop->kappa_true, a.duty), a.rate, len,
                                   len / 32.0, qe, NULL);
        if (e < path->error)
            path->error = e;
        const NsPlanPose *end = &path->poses[path->action_count];
        if (loop->adapt && a.rate == 0.0 && a.duty < 1.0) {
            turned += acos(fmax(-1.0, fmin(1.0, pm_dot(p.t, end->t))));
            straightness += (1.0 - a.duty) * len;
            if (straightness * prm->kappa > 1e-3) /* at least a milliradian expected */
                model.kappa =
                    fmax(0.1 * prm->kappa, fmin(10.0 * prm->kappa, turned / straightness));
        }
    }
    return 0;
}
