/* Shared between the coupling driver (coupling.c, step.c) and its two LCP solvers
 * (coupled_paper.c, coupled_schur.c), each complete in its file: Algorithm 3 on the coupled
 * system of one step (Eq. 7, sim/coupled_system.h) with the friction checks of sim/friction.h. */
#ifndef NS_COUPLING_INTERNAL_H
#define NS_COUPLING_INTERNAL_H

#include "coupled_system.h"
#include "coupling.h"
#include "friction.h"

/* coupling.c: the coupling arrays grown to cap needle nodes (0, or -1: memory); the needle's
 * nodes from `first` on coupled to the path (keep_state: the states of nodes that stay coupled
 * kept, else STATIC); needle node i's tissue point of the field v. */
int coupled_reserve(NsCoupled *c, int cap);
void coupled_from_path(NsCoupled *c, int first, int keep_state);
void coupled_tissue_point(const NsCoupled *c, int i, const double *v, double *out);

/* coupled_assemble.c: the coupled system of one step (Eq. 7-8, §3.3). */
/* coupled_tip_load.c: our bevel force (NS_BEVEL_FORCE) as a pair of body forces in the tissue,
 * -m2 over a ball of radius tip_load_radius ahead of the tip and +m2 over its mirror behind.
 * *f_out the bevel's lateral force [N] (0: none); *et the caller's tissue loads copied with the
 * pair added, pushed on c->arena (NULL: no load). 0, or -1 (memory). */
int coupled_tip_load(NsCoupled *c, const double *ext_tissue, double *f_out, double **et);
int coupled_count(const NsCoupled *c); /* coupling nodes now */
/* Sets c->rod->twist_fric for the step about to be taken (sim/twist_friction.h): tau_f l_j (l_j
 * the rest length) on every edge whose two nodes are coupled to the tissue (the edges the sliding
 * friction counts), tau_f = f_perlen r_o, and 0 elsewhere; all 0 when params.twist_friction is
 * 0. */
void coupled_twist_bounds(NsCoupled *c);
/* Scratch sizes of the system of q coupling nodes: doubles, ints (and q + 1 bytes). */
size_t coupled_system_doubles(int q);
size_t coupled_system_ints(int q);
/* Builds S from the needle's system sys and the tissue's right-hand side bt
 * (ns_tissue_begin_step) in the scratch w, iw, sw: frames, thresholds, constraint right-hand
 * sides, viscous friction (added to sys, bt and the tissue matrix), the tissue's accelerations
 * as the start. */
void coupled_assemble(NsCoupled *c, double dt, NsRodSystem *sys, double *bt, double *w, int *iw,
                      uint8_t *sw, CoupledSystem *S);
/* The solvers' starting accelerations (docs/coupling.md, "The starting guess"). 0, or -1. */
int coupled_scale_start(CoupledSystem *S);
/* cf: the known (dynamic) tangential forces of the states S->st, 0 elsewhere. */
void coupled_known_forces(CoupledSystem *S);

/* coupling_tip.c: the tip's cut after the update (along the path, or remeshing, Algorithm 2);
 * the tip's node released from bone. */
int coupled_cut_tip(NsCoupled *c, NsCouplingStats *st);
void coupled_unpin_tip(NsCoupled *c);
/* The last point inside the deformed tissue on the world segment xa (inside) -> xb (outside),
 * as a material point u; returns its tet, or -1 when xa is not inside. */
int coupled_world_exit_point(const NsMesh *M, const double xa[3], const double xb[3], int hint,
                             double u[3]);
/* coupling_reentry.c: a withdrawn needle whose tip is in the tissue again enters afresh where
 * it crosses the surface (skin entry; path, states and tip reset). 0 (still outside, or not
 * deep enough yet), 1 (entered: the caller cuts to the tip), -1 (c->error says why). */
int coupled_reenter(NsCoupled *c, NsCouplingStats *st);
/* coupling_reparam.c: the needle rebuilt on its tissue points (§3.4.2). */
int coupled_reparameterize(NsCoupled *c, NsCouplingStats *st);

/* Our solver (coupled_schur.c): its state kept between steps, and Algorithm 3 with it. */
typedef struct CoupledSchur CoupledSchur;
CoupledSchur *coupled_schur_create(void);
void coupled_schur_destroy(CoupledSchur *w);
/* Our solver's state between steps, packed (sim/snapshot.h; *w NULL allowed both ways). */
struct NsPack;
int coupled_schur_pack(struct NsPack *p, CoupledSchur **w);
/* A refactorization is scheduled for the next step (tests). */
int coupled_schur_pending(const CoupledSchur *w);
int coupled_schur_lcp(CoupledSchur *w, CoupledSystem *S, NsCouplingStats *st);

/* The paper's solver (coupled_paper.c): Algorithm 3 with CG on Eq. 7 per trial. */
int coupled_paper_lcp(CoupledSystem *S, NsCouplingStats *st);

#endif
