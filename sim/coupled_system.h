/* The coupled system of one step, Eq. 7 (§3.3): what the step's assembly builds and both linear
 * solvers (coupled_paper.c, coupled_schur.c) and the friction checks (friction.c) read. Kept
 * apart from sim/coupling.h so that the friction file needs nothing of the driver. */
#ifndef NS_COUPLED_SYSTEM_H
#define NS_COUPLED_SYSTEM_H

#include <stdint.h>

#include "arena.h"
#include "banded.h"
#include "sparse.h"

typedef struct NsCoupled NsCoupled;

typedef struct CoupledSystem {
    NsCoupled *c;
    NsArena *arena; /* the step's scratch: blocks pushed are popped before returning */
    int nt3, nr3;   /* tissue (3 node_slots) and needle (3 cap) vector lengths */
    int q;          /* coupling nodes */
    int *idx;       /* (q) needle node of coupling node k */
    int *ta, *tb;   /* (q) tissue point: (1 - tw) x[ta] + tw x[tb] */
    double *tw;     /* (q) */
    double *R;      /* (q x 9) local frame, columns t, n1, n2: R[9k + 3 col + i] */
    double *f;      /* (q) friction threshold / dynamic magnitude [N] */
    double f_cut;   /* cutting force at the tip [N] */
    int tip;        /* coupling index of the tip if it is inside the tissue (can cut), else -1 */
    double *e;      /* (3q) local constraint right-hand sides [m/s^2] */
    double *yrel;   /* (3q) world: tissue minus needle known displacement part of the step [m] */
    double bdt2;    /* beta dt^2 */
    const NsBlockMatrix *At;
    const uint8_t *tfixed;
    double *bt; /* tissue right-hand side (nt3) */
    const NsBanded *Ar;
    const uint8_t *rfixed;
    double *br;      /* needle right-hand side (nr3) */
    double *at, *ar; /* solution accelerations, warm start on entry; fixed DOFs hold their values */
    double *cf;      /* (3q) local constraint force on the needle, known dynamic part included */
    uint8_t *st;     /* (q) friction states of the trial */
    int threads;
    int converged; /* the last solve reached its tolerance */
    /* a failed solve: which linear solve failed (static text), or NULL */
    const char *why;
} CoupledSystem;

/* The tissue point's value of a 3-vector field v (nodes x 3). */
void coupled_point(const CoupledSystem *S, int k, const double *v, double *out);
/* sc (nt3 + nr3) = 1 / sqrt of each unknown's diagonal entry in A_t or A_n (1 where that is
 * not positive): the scaling to a unit diagonal that both solvers measure residuals in. */
void coupled_unit_scale(const CoupledSystem *S, double *sc);

#endif
