/* Shared between the coupling driver (coupling.c) and its two LCP solvers
 * (coupled_paper.c, coupled_schur.c), each complete in its file: Algorithm 3 on the coupled
 * system of one step (Eq. 7, sim/coupled_system.h) with the friction checks of sim/friction.h. */
#ifndef NS_COUPLING_INTERNAL_H
#define NS_COUPLING_INTERNAL_H

#include "coupled_system.h"
#include "coupling.h"
#include "friction.h"

/* Our solver (coupled_schur.c): its state kept between steps, and Algorithm 3 with it. */
typedef struct CoupledSchur CoupledSchur;
CoupledSchur *coupled_schur_create(void);
void coupled_schur_destroy(CoupledSchur *w);
int coupled_schur_lcp(CoupledSchur *w, CoupledSystem *S, NsCouplingStats *st);

/* The paper's solver (coupled_paper.c): Algorithm 3 with CG on Eq. 7 per trial. */
int coupled_paper_lcp(CoupledSystem *S, NsCouplingStats *st);

#endif
