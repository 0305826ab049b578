/* Torsional friction between the needle's shaft and the tissue (see twist_friction.h): the
 * twist's Newton step with stick/slip torques, and the bounds the coupling sets per edge. */
#include "twist_friction.h"

#include <math.h>
#include <stddef.h>

#include "coupling.h"
#include "rod.h"

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

int ns_twist_friction_step(int ne, int first, const double *hd, const double *ho, const double *g,
                           const double *theta, const double *anchor, const double *bound,
                           double *dx, double *work)
{
    double *sub = work, *dia = sub + ne, *sup = dia + ne, *rhs = sup + ne, *cp = rhs + ne;
    double *state = cp + ne;
    if (ne < 1)
        return 1;
    for (int j = 0; j < ne; j++)
        state[j] = j < first ? TF_FIXED : bound[j] > 0.0 ? TF_STICK : TF_FREE;
    int max_it = 4 * ne + 20;
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

double ns_twist_friction_energy(int ne, const double *theta, const double *anchor,
                                const double *bound)
{
    double e = 0.0;
    for (int j = 0; j < ne; j++)
        if (bound[j] > 0.0)
            e += bound[j] * fabs(theta[j] - anchor[j]);
    return e;
}

void ns_coupled_twist_bounds(NsCoupled *c)
{
    NsRod *r = c->rod;
    int ne = r->nodes - 1;
    double tau_f = c->params.twist_friction
                       ? c->params.f_perlen * 0.5 * r->params.material.outer_diameter
                       : 0.0;
    for (int j = 0; j < ne; j++)
        r->twist_fric[j] =
            tau_f > 0.0 && c->ta[j] >= 0 && c->ta[j + 1] >= 0 ? tau_f * r->rest_len[j] : 0.0;
}
