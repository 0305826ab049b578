/* Torsional friction between the needle's shaft and the tissue (see twist_friction.h): the
 * twist's Newton step with stick/slip torques. */
#include "twist_friction.h"

#include <math.h>
#include <stddef.h>

/* Edge states of the active set. */
#define TF_FIXED 0.0 /* j < first: held (dx 0) */
#define TF_FREE  1.0 /* no friction */
#define TF_STICK 2.0 /* at its anchor */
#define TF_POS   3.0 /* slipping, theta above its anchor (friction torque -bound) */
#define TF_NEG   4.0 /* slipping, theta below its anchor (friction torque +bound) */

/* Tridiagonal solve (Thomas) of sub x_{j-1} + dia x_j + sup x_{j+1} = rhs; -1 if a pivot is not
 * clearly positive (H is definite on the free rows, and the fixed rows are identity rows). */
static int thomas(int ne, const double *sub, const double *dia, const double *sup,
                  const double *rhs, double *x, double *cp)
{
    double piv = dia[0];
    if (!(piv > 0.0) || !isfinite(piv))
        return -1;
    cp[0] = sup[0] / piv;
    x[0] = rhs[0] / piv;
    for (int j = 1; j < ne; j++) {
        piv = dia[j] - sub[j] * cp[j - 1];
        if (!(piv > 1e-12 * fabs(dia[j])) || !isfinite(piv))
            return -1;
        cp[j] = sup[j] / piv;
        x[j] = (rhs[j] - sub[j] * x[j - 1]) / piv;
    }
    for (int j = ne - 2; j >= 0; j--)
        x[j] -= cp[j] * x[j + 1];
    return 0;
}

/* The primal-dual active set from the states in state[] (TF_*): returns the iterations, or -1 if
 * a pivot failed or the sets did not settle in max_it iterations. */
static int active_set(int ne, int first, const double *hd, const double *ho, const double *g,
                      const double *theta, const double *anchor, const double *bound, double *dx,
                      double *work, int max_it)
{
    double *sub = work, *dia = sub + ne, *sup = dia + ne, *rhs = sup + ne, *cp = rhs + ne;
    double *state = cp + ne;
    for (int it = 1; it <= max_it; it++) {
        for (int j = 0; j < ne; j++) {
            double s = state[j];
            if (s == TF_FIXED || s == TF_STICK) {
                sub[j] = sup[j] = 0.0;
                dia[j] = 1.0;
                rhs[j] = s == TF_FIXED ? 0.0 : anchor[j] - theta[j];
                continue;
            }
            sub[j] = j > 0 ? ho[j - 1] : 0.0;
            sup[j] = j + 1 < ne ? ho[j] : 0.0;
            dia[j] = hd[j];
            rhs[j] = -g[j] - (s == TF_POS ? bound[j] : s == TF_NEG ? -bound[j] : 0.0);
        }
        if (thomas(ne, sub, dia, sup, rhs, dx, cp) != 0)
            return -1;
        /* lambda_j = -(H dx + g)_j is the friction torque that holds edge j where it sticks;
         * the complementarity lambda = proj_[-c, c](lambda + hd_j y_j), y_j the slip from the
         * anchor, picks the next sets (stick where it holds, else slip its way). */
        int changed = 0;
        for (int j = first; j < ne; j++) {
            double s = state[j];
            if (s == TF_FREE)
                continue;
            double y = theta[j] + dx[j] - anchor[j], lam;
            if (s == TF_STICK) {
                double hx = hd[j] * dx[j];
                if (j > 0)
                    hx += ho[j - 1] * dx[j - 1];
                if (j + 1 < ne)
                    hx += ho[j] * dx[j + 1];
                lam = -(hx + g[j]);
                y = 0.0;
            } else {
                lam = s == TF_POS ? bound[j] : -bound[j];
            }
            double z = lam + hd[j] * y;
            double next = fabs(z) <= bound[j] ? TF_STICK : z > 0.0 ? TF_POS : TF_NEG;
            if (next != s) {
                state[j] = next;
                changed = 1;
            }
        }
        if (!changed)
            return it;
    }
    return -1;
}

/* Cyclic coordinate descent on the same problem (each coordinate's minimum in closed form: stick
 * at the anchor or slip either way), which converges for any definite H; used when the active
 * set cycles (H not an M-matrix: a bent rod's bending-twist terms). Stops when no coordinate
 * moves by more than 1e-15 of the largest, or after max_sweeps; state[] gets each edge's branch
 * in the last sweep (edges with a bound). Returns the sweeps. */
static int coordinate_descent(int ne, int first, const double *hd, const double *ho,
                              const double *g, const double *theta, const double *anchor,
                              const double *bound, double *dx, double *state, int max_sweeps)
{
    int sw;
    for (sw = 1; sw <= max_sweeps; sw++) {
        double moved = 0.0, big = 0.0;
        for (int j = first; j < ne; j++) {
            double b = g[j];
            if (j > 0)
                b += ho[j - 1] * dx[j - 1];
            if (j + 1 < ne)
                b += ho[j] * dx[j + 1];
            double h = hd[j], c = bound[j] > 0.0 ? bound[j] : 0.0, u0 = anchor[j] - theta[j];
            double u;
            if (c == 0.0) {
                u = -b / h;
            } else {
                double z = h * u0 + b;
                u = z < -c ? -(b + c) / h : z > c ? -(b - c) / h : u0;
                state[j] = z < -c ? TF_POS : z > c ? TF_NEG : TF_STICK;
            }
            moved = fmax(moved, fabs(u - dx[j]));
            dx[j] = u;
            big = fmax(big, fabs(u));
        }
        if (moved <= 1e-15 * big)
            break;
    }
    return sw;
}

int ns_twist_friction_step(int ne, int first, const double *hd, const double *ho, const double *g,
                           const double *theta, const double *anchor, const double *bound,
                           double *dx, double *work)
{
    double *state = work + 5 * (size_t)ne;
    if (ne < 1)
        return 1;
    for (int j = 0; j < ne; j++)
        state[j] = j < first ? TF_FIXED : bound[j] > 0.0 ? TF_STICK : TF_FREE;
    int max_it = 4 * ne + 20;
    int it = active_set(ne, first, hd, ho, g, theta, anchor, bound, dx, work, max_it);
    if (it > 0)
        return it;
    /* The sets cycled (or a pivot of a stick/slip split failed): coordinate descent, whose
     * solution gives the sets to start again from (exact when they hold at once). */
    for (int j = 0; j < ne; j++) {
        if (j >= first && !(hd[j] > 0.0))
            return -1; /* not definite: no coordinate minimum */
        dx[j] = 0.0;
    }
    int sweeps =
        coordinate_descent(ne, first, hd, ho, g, theta, anchor, bound, dx, state, 100 * ne + 1000);
    it = active_set(ne, first, hd, ho, g, theta, anchor, bound, dx, work, max_it);
    if (it > 0)
        return max_it + sweeps + it;
    for (int j = 0; j < ne; j++) /* the polish failed: the descent's answer again */
        dx[j] = 0.0;
    sweeps +=
        coordinate_descent(ne, first, hd, ho, g, theta, anchor, bound, dx, state, 100 * ne + 1000);
    return max_it + sweeps;
}

double ns_twist_friction_energy(int ne, const double *theta, const double *anchor,
                                const double *bound)
{
    double e = 0.0;
    for (int j = 0; j < ne; j++)
        if (bound[j] > 0.0)
            e += bound[j] * fabs(theta[j] - anchor[j]);
    return e;
}
