/* The coupled system of one step (sim/coupled_system.h): tissue points and the unit-diagonal
 * scaling both solvers measure their residuals in. */
#include "coupled_system.h"

#include <math.h>

void coupled_point(const CoupledSystem *S, int k, const double *v, double *out)
{
    const double *a = v + 3 * S->ta[k], *b = v + 3 * S->tb[k];
    for (int i = 0; i < 3; i++)
        out[i] = (1.0 - S->tw[k]) * a[i] + S->tw[k] * b[i];
}

void coupled_unit_scale(const CoupledSystem *S, double *sc)
{
    for (int i = 0; i < S->nt3; i += 3) { /* one look-up per node */
        const double *blk = ns_bsm_find(S->At, i / 3, i / 3);
        for (int c = 0; c < 3 && i + c < S->nt3; c++)
            sc[i + c] = blk && blk[4 * c] > 0.0 ? 1.0 / sqrt(blk[4 * c]) : 1.0;
    }
    for (int i = 0; i < S->nr3; i++) {
        const double *blk = ns_banded_block((NsBanded *)S->Ar, i / 3, i / 3);
        sc[S->nt3 + i] = blk && blk[4 * (i % 3)] > 0.0 ? 1.0 / sqrt(blk[4 * (i % 3)]) : 1.0;
    }
}
