/* Akima's interpolation (Akima 1970, J. ACM 17(4)): a C1 piecewise cubic through given points whose
 * slope at each point is a weighted mean of the neighbouring chord slopes, weighted so that a flat
 * run stays flat. Unlike a cubic spline it does not overshoot next to a jump, which is why the
 * needle's reparameterization (paper §3.4.2) carries rest lengths, twist angles and rest curvature
 * across with it. It reproduces linear data exactly. */
#ifndef NS_AKIMA_H
#define NS_AKIMA_H

/* Interpolates the n points (xs[i], ys[i]) (xs strictly increasing, n >= 1) at the m abscissae
 * xq, into yq. With one point the result is constant; with two it is the line through them.
 * Outside [xs[0], xs[n-1]] the end cubic's tangent line is used (linear extrapolation). work
 * holds at least 2 n + 3 doubles. Returns 0, or -1 if n < 1 or xs is not strictly increasing
 * (or not finite). xq and yq may be the same array. */
int ns_akima(const double *xs, const double *ys, int n, const double *xq, double *yq, int m,
             double *work);

#endif
