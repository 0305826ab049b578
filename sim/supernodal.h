/* A single-precision copy of a CHOLMOD supernodal Cholesky factor, applied as a preconditioner
 * on up to two threads (docs/solvers.md, "The preconditioner's own triangular solves").
 *
 * The stale-factor PCG of the coupled solve (sim/coupled_schur.c, §3.6.2's linear solve done
 * our way) spent nearly half the step in one forward and one backward substitution an iteration.
 * Those stream the whole factor (2.4 M entries, 19 MB, on the 13.7k-tet prostate) through the
 * cache for a single right-hand side, two flops an entry, so memory traffic counts: storing
 * the factor's values as floats halves it, and running the substitutions in float too (their
 * vectors and sums, eight to a 256-bit vector) takes a quarter to a third off an application
 * again. The operator applied is the inverse of L_f L_f^T, L_f the rounded factor, up to the
 * float rounding of the substitutions: within ~1e-7 (relative) of the double solve on the test
 * matrix, no longer exactly linear, but far closer to the stale factor than that factor is to the
 * current matrix. That changes how fast PCG converges, never the tolerance it converges to. The
 * right-hand side is scaled by a power of two (exact) into floats' range and the answer back.
 *
 * Two threads: the supernodal elimination tree is cut once, when the copy is made, into two
 * bins of whole subtrees of about equal size and a top part (their common ancestors, the last
 * separators of the nested dissection). The forward substitution runs the two bins at once,
 * each adding its contributions to the top part's rows into its own accumulator, then sums
 * the two accumulators in a fixed order and finishes the top; the backward substitution does
 * the top first, then the bins at once. The top's large supernodes are split too, in column
 * blocks whose rows or columns go to two fixed halves. The cut and every sum's order are fixed by
 * the factor alone, so x is bit-identical whether one thread or two run it. */
#ifndef NS_SUPERNODAL_H
#define NS_SUPERNODAL_H

#include <cholmod.h>

typedef struct NsSuperFactor NsSuperFactor;

/* The copy of a numeric supernodal LL^T factor (its structure copied, its values rounded to
 * float). NULL if L is not one (simplicial, LDL^T, symbolic) or memory ran out. */
NsSuperFactor *ns_super_from_cholmod(const cholmod_factor *L);
void ns_super_free(NsSuperFactor *f);
/* The order of the factored matrix. */
int ns_super_n(const NsSuperFactor *f);
/* Stored values of the two-thread cut's parts: bin 0, bin 1, the top (tests, diagnostics). */
void ns_super_cut(const NsSuperFactor *f, size_t entries[3]);
/* x ~ (P^T L_f L_f^T P)^-1 b, to the float rounding of the substitutions (b and x of length n,
 * in the factored matrix's numbering; they may be the same array), with up to `threads`
 * threads (two are used at most). b is scaled into floats' range, not the factor: the answer
 * must itself fit floats once b is scaled, which holds while the matrix's eigenvalues stay
 * well inside 1e-30..1e30 (the brachytherapy tissue factor's entries are at most 0.43). Not
 * re-entrant: the copy keeps its workspace. */
void ns_super_solve(NsSuperFactor *f, const double *b, double *x, int threads);
/* The same with the factored matrix's entry k at b[at[k]] and x[at[k]] (at: n distinct
 * indices; x's other entries are left alone), so a caller's longer vectors need no copies. */
void ns_super_solve_at(NsSuperFactor *f, const int *at, const double *b, double *x, int threads);
/* ns_super_solve_at with a step between the forward and the backward substitutions: mid(ctx,
 * y, n, down, up) gets y = L_f^-1 P b scaled by down (a power of two: y is in float), in the
 * factor's numbering, and may change it; the backward substitution then runs on what it left
 * (up = 1 / down). NULL mid: ns_super_solve_at. */
typedef void (*NsSuperMid)(void *ctx, float *y, int n, double down, double up);
void ns_super_solve_mid(NsSuperFactor *f, const int *at, const double *b, double *x, int threads,
                        NsSuperMid mid, void *ctx);
/* perm: entry k of the factor's numbering is entry perm[k] of the matrix's. */
const int *ns_super_perm(const NsSuperFactor *f);
/* y = L_f^-1 e_k in the factor's numbering, in float (y: n floats, all zero on entry; only the
 * elimination tree's path above k is touched). Not re-entrant (the copy's workspace). */
void ns_super_forward_unit(NsSuperFactor *f, int k, float *y);
/* Overwrites the factor's trailing k x k block (its last k columns, rows n-k.. of them) with
 * L22 (k x k, column-major, lower triangle read), rounded to float: the factor of a matrix
 * whose trailing block was changed (solver.c's tail update). */
void ns_super_set_tail(NsSuperFactor *f, int k, const double *L22);

#endif
