/* Tests for sim/akima.c: exact on linear data (inside and outside the points), no overshoot next
 * to a step, the points themselves reproduced, a continuous first derivative, and bad input
 * refused. */
#include "akima.h"
#include "ns_test.h"

#include <stdlib.h>

static double urand(unsigned *state)
{
    *state = *state * 1664525u + 1013904223u;
    return (double)(*state >> 8) / 16777216.0;
}

/* Irregular increasing abscissae. */
static void abscissae(double *xs, int n, unsigned *state)
{
    double x = -0.3;
    for (int i = 0; i < n; i++) {
        xs[i] = x;
        x += 0.05 + urand(state);
    }
}

static int exact_on_linear_data(void)
{
    unsigned state = 7;
    for (int n = 1; n <= 12; n++) {
        double xs[12], ys[12], work[2 * 12 + 3], xq[200], yq[200];
        abscissae(xs, n, &state);
        const double a = 0.37, b = n == 1 ? 0.0 : -2.5; /* one point: a constant */
        for (int i = 0; i < n; i++)
            ys[i] = a + b * xs[i];
        for (int k = 0; k < 200; k++) /* inside and a little outside */
            xq[k] = xs[0] - 0.5 + (xs[n - 1] - xs[0] + 1.0) * k / 199.0;
        ENSURE(ns_akima(xs, ys, n, xq, yq, 200, work) == 0);
        for (int k = 0; k < 200; k++)
            ENSURE_SMALL(yq[k] - (a + b * xq[k]), 1e-12);
    }
    return 0;
}

/* A step: flat, one jump, flat. A cubic spline rings on both sides; Akima must not leave [0, 1],
 * must stay exactly flat away from the jump, and must rise monotonically across it. */
static int no_overshoot_on_a_step(void)
{
    const double xs[8] = {0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0};
    const double ys[8] = {0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0};
    double work[2 * 8 + 3], xq[701], yq[701];
    for (int k = 0; k <= 700; k++)
        xq[k] = 0.01 * k;
    ENSURE(ns_akima(xs, ys, 8, xq, yq, 701, work) == 0);
    for (int k = 0; k <= 700; k++) {
        ENSURE(yq[k] >= 0.0 && yq[k] <= 1.0);
        if (xq[k] <= 3.0)
            ENSURE(yq[k] == 0.0);
        if (xq[k] >= 4.0)
            ENSURE(yq[k] == 1.0);
        if (k > 0)
            ENSURE(yq[k] >= yq[k - 1]);
    }
    ENSURE(yq[350] > 0.4 && yq[350] < 0.6); /* it does rise in between */
    return 0;
}

static int reproduces_points_and_is_c1(void)
{
    unsigned state = 3;
    const int n = 9;
    double xs[9], ys[9], work[2 * 9 + 3];
    abscissae(xs, n, &state);
    for (int i = 0; i < n; i++)
        ys[i] = sin(3.0 * xs[i]) + 0.2 * urand(&state);
    double yq[9];
    ENSURE(ns_akima(xs, ys, n, xs, yq, n, work) == 0);
    for (int i = 0; i < n; i++)
        ENSURE_SMALL(yq[i] - ys[i], 1e-13);
    /* One-sided difference quotients agree at every interior point (C1), and differ from the
     * chords (it is not just the polyline). */
    const double h = 1e-6;
    for (int i = 1; i + 1 < n; i++) {
        double q[3] = {xs[i] - h, xs[i], xs[i] + h}, v[3];
        ENSURE(ns_akima(xs, ys, n, q, v, 3, work) == 0);
        double left = (v[1] - v[0]) / h, right = (v[2] - v[1]) / h;
        ENSURE_SMALL(left - right, 1e-4 * (1.0 + fabs(left)));
    }
    /* Also in place (xq = yq). */
    double inplace[3] = {xs[0], 0.5 * (xs[3] + xs[4]), xs[n - 1]}, ref[3];
    ENSURE(ns_akima(xs, ys, n, inplace, ref, 3, work) == 0);
    ENSURE(ns_akima(xs, ys, n, inplace, inplace, 3, work) == 0);
    for (int k = 0; k < 3; k++)
        ENSURE(inplace[k] == ref[k]);
    return 0;
}

static int bad_input_refused(void)
{
    double xs[3] = {0.0, 1.0, 1.0}, ys[3] = {0.0, 1.0, 2.0}, work[9], q = 0.5, y;
    ENSURE(ns_akima(xs, ys, 3, &q, &y, 1, work) == -1); /* repeated abscissa */
    xs[2] = 0.5;
    ENSURE(ns_akima(xs, ys, 3, &q, &y, 1, work) == -1); /* decreasing */
    xs[2] = NAN;
    ENSURE(ns_akima(xs, ys, 3, &q, &y, 1, work) == -1);
    ENSURE(ns_akima(xs, ys, 0, &q, &y, 1, work) == -1);
    return 0;
}

NS_TEST_MAIN({"exact_on_linear_data", exact_on_linear_data},
             {"no_overshoot_on_a_step", no_overshoot_on_a_step},
             {"reproduces_points_and_is_c1", reproduces_points_and_is_c1},
             {"bad_input_refused", bad_input_refused})
