/* Linear solvers for the symmetric positive definite systems of the implicit step (§3.1,
 * Eq. 5-6), behind one interface:
 *   CG          conjugate gradients, warm-started from x (the paper's choice, §3.6.2)
 *   JACOBI_PCG  the same with the diagonal as preconditioner
 *   DIRECT      CHOLMOD supernodal Cholesky of the current matrix
 *   STALE_PCG   CG preconditioned by a Cholesky factor of an *earlier* matrix (DESIGN.md: 3-19
 *               iterations for the changes a step makes, against ~200 for plain CG)
 * Fixed DOFs are Dirichlet: their entries of x are kept as given, and the system is solved
 * for the others (A_ff x_f = b_f - A_fc x_c). A DOF mask (not a node mask) lets a node slide
 * along a plane (fixed in one direction, free in the others).
 *
 * Threads (ns_solver_set_threads, default 1). The SpMV and the vector operations of CG run on
 * up to that many OpenMP threads, and x is bit-identical for every thread count: a row of the
 * product is summed by one thread in column order, and every dot product is the sum of fixed
 * 1024-entry chunk partials added in chunk order, whichever thread computed them. CHOLMOD and
 * BLAS run on one thread: CHOLMOD 3.0's own OpenMP loops (num_threads(4), fixed at compile time,
 * so OMP_NUM_THREADS does not reach them) made its factorization slower on 2 cores, 44-52 ms
 * against 32 ms (DESIGN.md).
 *
 * Refreshing a stale factor in the background (STALE_PCG). A factorization (~32 ms on the
 * 13k-tet box) costs several stale-PCG solves (3-19 iterations, ~5-30 ms; DESIGN.md), and the
 * second core is idle during the serial parts of a step. So when a solve converges but needs
 * more than refresh_iterations iterations, the solver copies that solve's matrix and factors it
 * on a background thread (its own cholmod_common, the symbolic analysis reused), while the
 * following solves keep the old factor. The new factor is adopted by the refresh_lag-th solve
 * after the one that scheduled it (default 2), which waits for the thread if it is not done.
 * The adoption point depends only on the count of solve calls, never on timing, so every
 * result is bit-identical whether the factorization ran in the background or not: with one
 * thread it is made synchronously by the scheduling solve and still adopted refresh_lag solves
 * later. A factor is made synchronously, in the solve that needs it (any pending refresh is
 * waited for and dropped), when there is none, when the pattern or the fixed DOFs changed, or
 * when the stale one failed to reach tol within max_iter (the solve then restarts with it).
 * refresh_lag 0 refactors synchronously as soon as a solve is slow and re-solves. */
#ifndef NS_SOLVER_H
#define NS_SOLVER_H

#include <stddef.h>
#include <stdint.h>

#include "sparse.h"

typedef enum NsSolverKind {
    NS_SOLVER_CG,
    NS_SOLVER_JACOBI_PCG,
    NS_SOLVER_DIRECT,
    NS_SOLVER_STALE_PCG,
} NsSolverKind;

typedef struct NsSolveStats {
    int iterations;      /* CG iterations (0 for DIRECT) */
    double residual;     /* final ||b - A x|| / ||b|| over free DOFs */
    int converged;       /* residual <= tol */
    int factorized;      /* a numeric factorization of this solve's matrix was made and used in
                          * this solve (not a scheduled refresh, even one made here with one
                          * thread: that is refresh_started) */
    int analyzed;        /* a symbolic analysis (ordering) was made in this solve */
    int refresh_started; /* STALE_PCG: this solve scheduled a refactorization of its matrix */
    int refresh_adopted; /* STALE_PCG: this solve switched to a factor scheduled earlier */
    int factor_age;      /* solves since the matrix of the factor used was given (0: this
                          * solve's own); -1 for CG and JACOBI_PCG */
} NsSolveStats;

typedef struct NsSolver NsSolver;

NsSolver *ns_solver_create(NsSolverKind kind);
/* Waits for a background refactorization, if one is running. */
void ns_solver_destroy(NsSolver *s);
NsSolverKind ns_solver_kind(const NsSolver *s);
const char *ns_solver_name(NsSolverKind kind);

/* Threads for the SpMV and vector operations and, if 2 or more, a background thread for
 * STALE_PCG's refactorizations (default 1). Results do not depend on it. */
void ns_solver_set_threads(NsSolver *s, int threads);
/* For STALE_PCG: refactor when a solve needs more iterations than this (default 25). */
void ns_solver_set_refresh_iterations(NsSolver *s, int iterations);
/* For STALE_PCG: a refactorization scheduled by solve k is used from solve k + lag on
 * (default 2; 0: refactor synchronously and re-solve). */
void ns_solver_set_refresh_lag(NsSolver *s, int lag);
/* Drop the factor and any pending refactorization (waiting for its thread): the next DIRECT /
 * STALE_PCG solve factors the matrix it is given. */
void ns_solver_refresh(NsSolver *s);

/* Solves A x = b. dof_fixed (3n entries, may be NULL) marks Dirichlet DOFs. x holds the
 * initial guess (and the fixed values) on entry. tol is relative to ||b_f - A_fc x_c||.
 * Returns 0, or -1 on a CHOLMOD failure (not positive definite, memory) or a NULL solver (its
 * creation failed), with stats filled as far as they got. Non-convergence within max_iter is
 * reported in stats, not as an error. */
int ns_solver_solve(NsSolver *s, const NsBlockMatrix *A, const uint8_t *dof_fixed, const double *b,
                    double *x, double tol, int max_iter, NsSolveStats *stats);

/* ---- The factor on its own (DIRECT or STALE_PCG solvers), for callers that build on it: the
 * coupled solver (sim/coupled_schur.c) factors the tissue matrix now and then and applies the
 * (possibly stale) factor as a preconditioner and to many columns at once. ---- */

/* Factors A's free block now (a symbolic analysis only if the pattern or the fixed DOFs
 * changed); a pending refactorization is dropped. Returns 0, or -1 (not positive definite,
 * memory, or a solver of another kind). */
int ns_solver_factor(NsSolver *s, const NsBlockMatrix *A, const uint8_t *dof_fixed);
/* Z = A^-1 B with the current factor for ncols columns of n3 entries each (column j at
 * B + j n3; n3 = 3 x the nodes of the factored matrix): fixed DOFs' entries of B are ignored
 * and those of Z are 0. B and Z must not overlap. Returns 0, or -1 (no factor, n3 differs,
 * memory). */
int ns_solver_apply(NsSolver *s, int n3, int ncols, const double *B, double *Z);
/* z ~ A^-1 r with the current factor's single-precision copy (supernodal.h), on the solver's
 * threads (two at most, one while a refactorization runs in the background; z is the same for
 * every count): a preconditioner whose answer differs from ns_solver_apply's by ~1e-7 times
 * A's condition number (relative), two to five times as fast. Falls back to ns_solver_apply's
 * solve if the copy could not be made or its vector not allocated. Fixed DOFs as
 * ns_solver_apply. Returns 0, or -1 (no factor, n3 differs, memory). */
int ns_solver_precondition(NsSolver *s, int n3, const double *r, double *z);
/* The stored values in each part of the single-precision copy's two-thread cut (bin 0, bin 1,
 * the top; supernodal.h). Returns 0, or -1 if there is no copy (not made yet, or it could not
 * be: memory, or a factor that is not supernodal). */
int ns_solver_precondition_cut(const NsSolver *s, size_t entries[3]);
/* Counts the factors made so far: it changes whenever the factor in use changes. */
long ns_solver_factor_count(const NsSolver *s);
/* Schedules a factorization of A (which must have the pattern and fixed DOFs of the factor in
 * use) and, with ncols > 0, the columns Z = A^-1 B with it: on a background thread (its own
 * CHOLMOD common) when the solver has 2 or more threads, else right here. The factor in use does
 * not change until ns_solver_factor_adopt, so the results are the same either way. B and Z (ncols
 * columns of 3n) must stay alive and untouched until then. A pending refactorization is dropped.
 * Returns 0, or -1 (another pattern, no factor yet, memory: nothing scheduled). */
int ns_solver_factor_async(NsSolver *s, const NsBlockMatrix *A, const uint8_t *dof_fixed, int ncols,
                           const double *B, double *Z);
/* After ns_solver_pack read a solver whose ns_solver_factor_async was pending: the caller's B
 * and Z read back by the caller (at new addresses). The job had finished when it was written,
 * so Z must hold what it held then. Does nothing if none is pending. */
void ns_solver_factor_async_moved(NsSolver *s, const double *B, double *Z);
/* Waits for the scheduled factorization and puts it in use. Returns 1 if it was adopted (then
 * *cols_ok says whether its columns were computed), 0 if none was pending or it failed (the old
 * factor stays). */
int ns_solver_factor_adopt(NsSolver *s, int *cols_ok);
/* The tail (docs/solvers.md, "The tail"): asks the next symbolic analysis to order the free
 * DOFs of these nodes last (a copy is kept; count 0 asks for none). Returns 0 or -1 (memory). */
int ns_solver_set_tail(NsSolver *s, const int *nodes, int count);
/* Makes the preconditioner's trailing block current: refactors A's tail block minus the rest's
 * part of the Schur complement, as of the factor in use, into the single-precision copy (so
 * ns_solver_precondition applies the exact factor of the stale matrix with A's tail block).
 * Keeps the factor's own block if that is not positive definite. Returns the tail's size in
 * DOFs if it was updated, else 0 (no tail, no copy). */
int ns_solver_tail_update(NsSolver *s, const NsBlockMatrix *A);
/* The trailing block L22 now in the copy (k x k, column-major; *L22 = NULL and 0 without a
 * tail). Valid until the factor or the tail changes. */
int ns_solver_tail_block(NsSolver *s, int n3, const double **L22);
/* ns_solver_precondition with a step between the copy's substitutions (supernodal.h,
 * ns_super_solve_mid). Returns 0, or 1 if there is no copy (nothing done). */
typedef void (*NsSolverMid)(void *ctx, float *y, int n, double down, double up);
int ns_solver_precondition_mid(NsSolver *s, int n3, const double *r, double *z, NsSolverMid mid,
                               void *ctx);
/* y = L_f^-1 P e_dof with the copy (y: the free DOF count of floats, zero on entry, in the
 * copy's numbering). Returns that count (y NULL: only that), 0 for a fixed DOF (y untouched),
 * -1 without a copy. */
int ns_solver_forward_dof(NsSolver *s, int n3, int dof, float *y);

#endif
