/* plan/steer.c: the Hauser-style closed loop on the kinematic model. The needle follows a
 * "true" curvature 0.5x or 2x the model's while the tissue carries the target a few mm; the
 * closed loop (replanning every 2 mm, estimating the curvature from the tip's turning) must end
 * within 1 mm of every target, and its mean error (with or without the estimate) must be at
 * least 3x smaller than the open loop's (planned once at the entry, never corrected),
 * over 30 seeded random layouts. Prints the figures docs/planning.md quotes. */
#include <math.h>
#include <stdio.h>
#include <stdbool.h>
#include <stdlib.h>

#include "ns_test.h"
#include "rng.h"
#include "steer.h"

#define KAPPA   5.77 /* the arc model's k_c tan(30 deg) = 10 x 0.577 [1/m] */
#define LAYOUTS 30

typedef struct Layout {
    double nominal[3]; /* where the target is before the insertion [m] */
    double offset[3];  /* where the tissue carries it, reached halfway in [m] */
    double depth;      /* [m] */
} Layout;

static void moving_target(void *user, double inserted, double out[3])
{
    const Layout *l = user;
    double f = fmin(1.0, inserted / (0.5 * l->depth));
    for (int i = 0; i < 3; i++)
        out[i] = l->nominal[i] + f * l->offset[i];
}

/* Targets 50-100 mm ahead in any direction around the axis, needing at most 40% of the model's
 * curvature from the entry (so that a needle of half the curvature still reaches them),
 * carried 1-3 mm in a random direction. */
static Layout layout(uint64_t seed)
{
    NsPlanRng r = ns_plan_rng(seed);
    Layout l;
    l.depth = ns_plan_rng_range(&r, 0.05, 0.10);
    double need = ns_plan_rng_range(&r, 0.05, 0.40) * KAPPA;
    /* the lateral offset b with 2 b / (a^2 + b^2) = need, the small root */
    double a = l.depth, b = (1.0 - sqrt(1.0 - need * need * a * a)) / need;
    double psi = ns_plan_rng_range(&r, 0.0, 2.0 * M_PI);
    l.nominal[0] = a;
    l.nominal[1] = b * cos(psi);
    l.nominal[2] = b * sin(psi);
    double u = ns_plan_rng_range(&r, -1.0, 1.0), v = ns_plan_rng_range(&r, 0.0, 2.0 * M_PI);
    double m = ns_plan_rng_range(&r, 0.001, 0.003), s = sqrt(1.0 - u * u);
    l.offset[0] = m * s * cos(v);
    l.offset[1] = m * s * sin(v);
    l.offset[2] = m * u;
    return l;
}

static NsPlanPose entry(void)
{
    NsPlanPose p;
    double o[3] = {0, 0, 0}, x[3] = {1, 0, 0}, y[3] = {0, 1, 0};
    ns_plan_pose_make(o, x, y, &p);
    return p;
}

static double run(Layout *l, double scale, double replan_every, bool adapt)
{
    NsSteerParams prm = ns_steer_default(KAPPA);
    NsSteerLoop loop = {replan_every, 1.5 * l->depth, KAPPA * scale, NULL, moving_target, l, adapt};
    NsPlanPose start = entry();
    NsPlanPath path;
    char err[256];
    if (ns_steer_rollout(&prm, &loop, &start, &path, err, sizeof err) != 0) {
        fprintf(stderr, "%s\n", err);
        return INFINITY;
    }
    double e = path.error;
    ns_plan_path_free(&path);
    return e;
}

/* Mean and max error [m] and how many within 1 mm over the layouts, for one way of steering:
 * replanning every `every` metres (1 m: once, at the entry), adapting the curvature or not. */
typedef struct Tally {
    double sum, max;
    int within;
} Tally;

static void tally(Tally *t, double e)
{
    t->sum += e;
    t->max = fmax(t->max, e);
    t->within += e <= 1e-3;
}

static int closed_beats_open(void)
{
    const double scales[] = {0.5, 2.0, 1.0};
    Tally pert[3] = {{0}}; /* open, closed (Hauser), closed + adapted curvature */
    for (int k = 0; k < 3; k++) {
        Tally t[3] = {{0}};
        for (int i = 0; i < LAYOUTS; i++) {
            Layout l = layout(1000 + (uint64_t)i);
            double e[3] = {run(&l, scales[k], 1.0, false), run(&l, scales[k], 0.002, false),
                           run(&l, scales[k], 0.002, true)};
            for (int m = 0; m < 3; m++) {
                tally(&t[m], e[m]);
                if (scales[k] != 1.0)
                    tally(&pert[m], e[m]);
            }
        }
        printf("  kappa_true = %.1f x model (%d layouts): open loop mean %.3f mm max %.3f; "
               "closed mean %.3f max %.3f (%d within 1 mm); closed+adapt mean %.3f max %.3f "
               "(%d within 1 mm)\n",
               scales[k], LAYOUTS, 1e3 * t[0].sum / LAYOUTS, 1e3 * t[0].max,
               1e3 * t[1].sum / LAYOUTS, 1e3 * t[1].max, t[1].within, 1e3 * t[2].sum / LAYOUTS,
               1e3 * t[2].max, t[2].within);
    }
    int n = 2 * LAYOUTS;
    printf("  perturbed (0.5x and 2x, %d runs): open mean %.3f mm; closed mean %.3f mm (%.1fx "
           "smaller, %d within 1 mm); closed+adapt mean %.3f mm (%.1fx smaller, %d within 1 "
           "mm, max %.3f)\n",
           n, 1e3 * pert[0].sum / n, 1e3 * pert[1].sum / n, pert[0].sum / pert[1].sum,
           pert[1].within, 1e3 * pert[2].sum / n, pert[0].sum / pert[2].sum, pert[2].within,
           1e3 * pert[2].max);
    ENSURE(pert[0].sum >= 3.0 * pert[1].sum);
    ENSURE(pert[0].sum >= 3.0 * pert[2].sum);
    ENSURE(pert[2].within == n && pert[2].max <= 1e-3);
    return 0;
}

/* A target on the full-curvature arc in some plane is hit exactly, with the twist to that
 * plane and no duty cycle. */
static int choose_reachable(void)
{
    NsPlanPose p = entry();
    double th = 0.3, psi = 2.0;
    double b = (1.0 - cos(th)) / KAPPA;
    double q[3] = {sin(th) / KAPPA, b * cos(psi), b * sin(psi)};
    NsSteerParams prm = ns_steer_default(KAPPA);
    NsSteerAction a;
    char err[256];
    ENSURE(ns_steer_choose(&prm, &p, q, &a, err, sizeof err) == 0);
    ENSURE_SMALL(a.miss, 1e-9);
    ENSURE_SMALL(a.duty, 1e-9);
    ENSURE_SMALL(a.at - th / KAPPA, 1e-5);
    /* m2 = y, m1 = -z: the twist psi takes m2 to cos(psi) y + sin(psi) z */
    ENSURE_SMALL(a.twist - psi, 1e-12);
    /* straight ahead: no twist, full duty */
    double ahead[3] = {0.05, 0, 0};
    ENSURE(ns_steer_choose(&prm, &p, ahead, &a, err, sizeof err) == 0);
    ENSURE_SMALL(a.twist, 0.0);
    ENSURE_SMALL(a.duty - 1.0, 1e-12);
    ENSURE_SMALL(a.miss, 1e-9);
    return 0;
}

/* With helix candidates only (no angle grid worth having, no duty cycling), a target on one of
 * the offered helices is found. */
static int choose_helix(void)
{
    NsPlanPose p = entry(), q;
    const double rates[] = {-40.0, -10.0, 0.0, 15.0, 60.0};
    ns_plan_advance(&p, KAPPA, 15.0, 0.08, &q);
    NsSteerParams prm = ns_steer_default(KAPPA);
    prm.angle_count = 1;
    prm.exact_angle = false;
    prm.duty_cycle = false;
    prm.rates = rates;
    prm.rate_count = 5;
    NsSteerAction a;
    char err[256];
    ENSURE(ns_steer_choose(&prm, &p, q.p, &a, err, sizeof err) == 0);
    ENSURE(a.rate == 15.0);
    ENSURE_SMALL(a.miss, 1e-9);
    return 0;
}

static int bad_input(void)
{
    NsPlanPose p = entry();
    double q[3] = {0.05, 0, 0}, nanq[3] = {NAN, 0, 0};
    NsSteerAction a;
    char err[256] = "";
    NsSteerParams prm = ns_steer_default(0.0);
    ENSURE(ns_steer_choose(&prm, &p, q, &a, err, sizeof err) == -1 && err[0]);
    prm = ns_steer_default(KAPPA);
    prm.angle_count = 0;
    ENSURE(ns_steer_choose(&prm, &p, q, &a, err, sizeof err) == -1);
    prm = ns_steer_default(KAPPA);
    ENSURE(ns_steer_choose(&prm, &p, nanq, &a, err, sizeof err) == -1);
    prm.rate_count = 2; /* rates NULL */
    ENSURE(ns_steer_choose(&prm, &p, q, &a, err, sizeof err) == -1);
    prm = ns_steer_default(KAPPA);
    NsSteerLoop loop = {0.0, 0.1, KAPPA, q, NULL, NULL, false};
    NsPlanPath path;
    ENSURE(ns_steer_rollout(&prm, &loop, &p, &path, err, sizeof err) == -1);
    loop.replan_every = 0.002;
    loop.target = NULL;
    ENSURE(ns_steer_rollout(&prm, &loop, &p, &path, err, sizeof err) == -1);
    return 0;
}

NS_TEST_MAIN({"closed_beats_open", closed_beats_open}, {"choose_reachable", choose_reachable},
             {"choose_helix", choose_helix}, {"bad_input", bad_input})
