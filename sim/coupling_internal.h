/* Shared between the coupling driver (coupling.c) and its two linear-solver paths
 * (coupled_paper.c, coupled_schur.c): the coupled system of one step, Eq. 7. */
#ifndef NS_COUPLING_INTERNAL_H
#define NS_COUPLING_INTERNAL_H

#include "coupling.h"

typedef struct CoupledSystem {
    NsCoupled *c;
    int nt3, nr3; /* tissue (3 node_slots) and needle (3 cap) vector lengths */
    int q;        /* coupling nodes */
    int *idx;     /* (q) needle node of coupling node k */
    int *ta, *tb; /* (q) tissue point: (1 - tw) x[ta] + tw x[tb] */
    double *tw;   /* (q) */
    double *R;    /* (q x 9) local frame, columns t, n1, n2: R[9k + 3 col + i] */
    double *f;    /* (q) friction threshold / dynamic magnitude [N] */
    double f_cut; /* cutting force at the tip [N] */
    int tip;      /* coupling index of the tip if it is inside the tissue (can cut), else -1 */
    double *e;    /* (3q) local constraint right-hand sides [m/s^2] */
    double *yrel; /* (3q) world: tissue minus needle known displacement part of the step [m] */
    double bdt2;  /* beta dt^2 */
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
} CoupledSystem;

/* The tissue point's value of a 3-vector field v (nodes x 3). */
void coupled_point(const CoupledSystem *S, int k, const double *v, double *out);
/* sc (nt3 + nr3) = 1 / sqrt of each unknown's diagonal entry in A_t or A_n (1 where that is
 * not positive): the scaling to a unit diagonal that both solvers measure residuals in. */
void coupled_unit_scale(const CoupledSystem *S, double *sc);
/* Known tangential force on the needle of coupling node k in state s (DYNAMIC: -sign f). */
double coupled_known_force(const CoupledSystem *S, int k, int s);
/* Relative tangential displacement of the step, tissue minus needle, at node k for the
 * accelerations at, ar [m]. */
double coupled_rel_slide(const CoupledSystem *S, int k, const double *at, const double *ar);
/* Checks Eq. 9-11 for the states st with forces cf and the accelerations (at, ar); writes the
 * states a flip would give into next (unchanged where consistent). Returns violations. */
int coupled_check(const CoupledSystem *S, const uint8_t *st, const double *cf, const double *at,
                  const double *ar, uint8_t *next);
/* The same with the relative tangential slides (tissue minus needle, per coupling node [m])
 * given instead of the accelerations. */
int coupled_check_slides(const CoupledSystem *S, const uint8_t *st, const double *cf,
                         const double *slide, uint8_t *next);
/* The tried-configuration memory of Algorithm 3. */
typedef struct TriedSet {
    int count, cap, q;
    uint8_t *cfg;
} TriedSet;
int tried_add(TriedSet *T, const uint8_t *st);
/* Makes st untried: unchanged if new, else the next configurations in lexicographic order
 * (coupling node 0, the entry, least significant). */
void tried_next(const TriedSet *T, uint8_t *st);

/* Our solver (coupled_schur.c): its state kept between steps, and Algorithm 3 with it. */
typedef struct CoupledSchur CoupledSchur;
CoupledSchur *coupled_schur_create(void);
void coupled_schur_destroy(CoupledSchur *w);
int coupled_schur_lcp(CoupledSchur *w, CoupledSystem *S, NsCouplingStats *st);

/* The linear solves: for the states S->st, to relative residual tol, warm-started from at, ar,
 * cf. Return 0 or -1; add their iterations. */
int coupled_paper_solve(CoupledSystem *S, double tol, int max_iter, int *iterations);

#endif
