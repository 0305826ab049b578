/* plan/kinematic.c against closed forms: an arc ends on its circle, a twisted insertion is the
 * helix of radius kappa / (kappa^2 + tau^2) and pitch 2 pi tau / (kappa^2 + tau^2), a duty
 * cycle of 1 is a straight line, and the frame stays orthonormal. */
#include <math.h>
#include <stdio.h>

#include "kinematic.h"
#include "ns_test.h"

static NsPlanPose start(void)
{
    NsPlanPose p;
    double o[3] = {0.01, -0.02, 0.03}, x[3] = {1, 0, 0}, y[3] = {0, 1, 0};
    ns_plan_pose_make(o, x, y, &p);
    return p;
}

static int arc_on_circle(void)
{
    const double kappa = 5.77, o[3] = {0.01, -0.02, 0.03};
    for (int i = 1; i <= 20; i++) {
        double s = 0.01 * i; /* up to 0.2 m: past a quarter turn */
        NsPlanPose p = start(), q;
        ENSURE(ns_plan_advance(&p, kappa, 0.0, s, &q));
        double th = kappa * s;
        ENSURE_SMALL(q.p[0] - (o[0] + sin(th) / kappa), 1e-12);
        ENSURE_SMALL(q.p[1] - (o[1] + (1.0 - cos(th)) / kappa), 1e-12);
        ENSURE_SMALL(q.p[2] - o[2], 1e-12);
        ENSURE_SMALL(q.t[0] - cos(th), 1e-12);
        ENSURE_SMALL(q.t[1] - sin(th), 1e-12);
        ENSURE_SMALL(q.m2[0] + sin(th), 1e-12);
        ENSURE_SMALL(q.m2[1] - cos(th), 1e-12);
    }
    return 0;
}

/* Advancing by a then b is advancing by a + b (the screw is a one-parameter group). */
static int advance_composes(void)
{
    NsPlanPose p = start(), a, b, c;
    ns_plan_twist(&p, 0.7);
    ENSURE(ns_plan_advance(&p, 8.0, 30.0, 0.013, &a));
    ENSURE(ns_plan_advance(&a, 8.0, 30.0, 0.029, &b));
    ENSURE(ns_plan_advance(&p, 8.0, 30.0, 0.042, &c));
    for (int i = 0; i < 3; i++) {
        ENSURE_SMALL(b.p[i] - c.p[i], 1e-13);
        ENSURE_SMALL(b.t[i] - c.t[i], 1e-12);
        ENSURE_SMALL(b.m2[i] - c.m2[i], 1e-12);
    }
    double m1[3];
    ns_plan_pose_m1(&c, m1);
    ENSURE_SMALL(c.t[0] * c.m2[0] + c.t[1] * c.m2[1] + c.t[2] * c.m2[2], 1e-14);
    ENSURE_SMALL(sqrt(m1[0] * m1[0] + m1[1] * m1[1] + m1[2] * m1[2]) - 1.0, 1e-14);
    return 0;
}

/* Spinning at tau while inserting: every point is at the helix radius from its axis, and one
 * turn (s = 2 pi / sqrt(kappa^2 + tau^2)) advances one pitch along it. */
static int helix_closed_form(void)
{
    const double cases[][2] = {{5.0, 20.0}, {10.0, 3.0}, {2.0, -40.0}, {7.0, 7.0}};
    for (int c = 0; c < 4; c++) {
        double kappa = cases[c][0], tau = cases[c][1], w2 = kappa * kappa + tau * tau;
        NsPlanPose p = start();
        ns_plan_twist(&p, 0.3 * c);
        NsPlanHelix h;
        ns_plan_helix(&p, kappa, tau, &h);
        ENSURE_SMALL(h.radius - kappa / w2, 1e-15);
        ENSURE_SMALL(h.pitch - 2.0 * M_PI * tau / w2, 1e-15);
        double turn = 2.0 * M_PI / sqrt(w2);
        for (int i = 0; i <= 40; i++) {
            NsPlanPose q;
            ns_plan_advance(&p, kappa, tau, turn * i / 16.0, &q);
            double d[3], along = 0.0, r2 = 0.0;
            for (int k = 0; k < 3; k++)
                d[k] = q.p[k] - h.point[k];
            for (int k = 0; k < 3; k++)
                along += d[k] * h.axis[k];
            for (int k = 0; k < 3; k++)
                r2 += (d[k] - along * h.axis[k]) * (d[k] - along * h.axis[k]);
            ENSURE_SMALL(sqrt(r2) - h.radius, 1e-12);
            /* the axial advance grows linearly: pitch per turn */
            ENSURE_SMALL(along - h.pitch * i / 16.0, 1e-12);
        }
    }
    return 0;
}

static int duty_one_is_straight(void)
{
    NsPlanPose p = start(), q;
    double k = ns_plan_kappa_eff(5.77, 1.0);
    ENSURE(k == 0.0);
    ENSURE(ns_plan_advance(&p, k, 0.0, 0.08, &q));
    ENSURE_SMALL(q.p[0] - (p.p[0] + 0.08), 1e-15);
    ENSURE_SMALL(q.p[1] - p.p[1], 0.0);
    ENSURE_SMALL(q.p[2] - p.p[2], 0.0);
    ENSURE_SMALL(ns_plan_kappa_eff(6.0, 0.25) - 4.5, 1e-15);
    ENSURE(ns_plan_kappa_eff(6.0, -1.0) == 6.0 && ns_plan_kappa_eff(6.0, 2.0) == 0.0);
    return 0;
}

/* A twist of pi turns the bevel around: the arc bends the other way. */
static int twist_turns_bevel(void)
{
    NsPlanPose p = start(), q;
    ns_plan_twist(&p, M_PI);
    ENSURE_SMALL(p.m2[1] + 1.0, 1e-15);
    ns_plan_twist(&p, M_PI / 2);
    /* after the half turn m2 = -y and m1 = m2 x t = +z; a quarter turn more takes m2 to
     * -m1 = -z */
    ENSURE_SMALL(p.m2[2] + 1.0, 1e-15);
    ns_plan_advance(&p, 10.0, 0.0, 0.05, &q);
    ENSURE(q.p[2] < p.p[2] - 0.01);
    return 0;
}

static int bad_input_refused(void)
{
    NsPlanPose p = start(), q = start();
    double zero[3] = {0, 0, 0}, o[3] = {0, 0, 0}, nan3[3] = {NAN, 0, 0};
    ENSURE(!ns_plan_pose_make(o, zero, NULL, &q));
    ENSURE(!ns_plan_pose_make(nan3, o, NULL, &q));
    ENSURE(!ns_plan_advance(&p, -1.0, 0.0, 0.01, &q));
    ENSURE(!ns_plan_advance(&p, 1.0, 0.0, -0.01, &q));
    ENSURE(!ns_plan_advance(&p, NAN, 0.0, 0.01, &q));
    ENSURE(!ns_plan_advance(&p, 1.0, INFINITY, 0.01, &q));
    /* a bevel direction parallel to the tangent still gives a frame */
    double x[3] = {0, 0, 2};
    ENSURE(ns_plan_pose_make(o, x, x, &q));
    ENSURE_SMALL(q.m2[0] * q.t[0] + q.m2[1] * q.t[1] + q.m2[2] * q.t[2], 1e-15);
    return 0;
}

static int closest_on_arc(void)
{
    NsPlanPose p = start();
    const double kappa = 5.0, o[3] = {0.01, -0.02, 0.03};
    /* a point 3 mm outside the circle, at 0.4 rad along it */
    double r = 1.0 / kappa + 0.003, th = 0.4;
    double q[3] = {o[0] + r * sin(th), o[1] + 1.0 / kappa - r * cos(th), o[2]}, at;
    double d = ns_plan_closest(&p, kappa, 0.0, 0.2, 0.0, q, &at);
    ENSURE_SMALL(d - 0.003, 1e-9);
    ENSURE_SMALL(at - th / kappa, 1e-5);
    return 0;
}

NS_TEST_MAIN({"arc_on_circle", arc_on_circle}, {"advance_composes", advance_composes},
             {"helix_closed_form", helix_closed_form},
             {"duty_one_is_straight", duty_one_is_straight},
             {"twist_turns_bevel", twist_turns_bevel}, {"bad_input_refused", bad_input_refused},
             {"closest_on_arc", closest_on_arc})
