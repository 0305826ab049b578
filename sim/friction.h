/* Stick-slip friction at the coupling nodes (§3.3, Eq. 9-11; Algorithm 3's memory of the
 * configurations tried). The friction states, the known (dynamic) tangential force of a state,
 * the checks of a solution against its states with the flips they call for, and the
 * lexicographic search over untried configurations. Both LCP solvers (coupled_paper.c,
 * coupled_schur.c) use these; the step's assembly uses the known forces. */
#ifndef NS_FRICTION_H
#define NS_FRICTION_H

#include <stdint.h>

typedef enum NsFriction {
    NS_FRICTION_FREE = 0,
    NS_FRICTION_STATIC = 1,
    NS_FRICTION_DYN_NEG = 2, /* the needle slides backward (out of the tissue) */
    NS_FRICTION_DYN_POS = 3, /* the needle slides forward (towards its tip) */
} NsFriction;

typedef struct CoupledSystem CoupledSystem; /* sim/coupled_system.h */

/* Known tangential force on the needle of coupling node k in state s (DYNAMIC: -sign f, the tip
 * cutting forward with f_cut added, Eq. 10) [N]. */
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

/* The tried-configuration memory of Algorithm 3: count configurations of q states each. */
typedef struct TriedSet {
    int count, cap, q;
    uint8_t *cfg;
    int owned; /* cfg was allocated here (it outgrew the caller's buffer) */
} TriedSet;
/* Empty, in the caller's buffer of cap configurations (buf may be NULL, cap 0). */
void tried_init(TriedSet *T, int q, uint8_t *buf, int cap);
void tried_free(TriedSet *T);
int tried_add(TriedSet *T, const uint8_t *st);
/* Makes st untried: unchanged if new, else the next configurations in lexicographic order
 * (coupling node 0, the entry, least significant). */
void tried_next(const TriedSet *T, uint8_t *st);

#endif
