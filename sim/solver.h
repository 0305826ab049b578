/* Linear solvers for the symmetric positive definite systems of the implicit step (§3.1,
 * Eq. 5-6), behind one interface:
 *   CG          conjugate gradients, warm-started from x (the paper's choice, §3.6.2)
 *   JACOBI_PCG  the same with the diagonal as preconditioner
 *   DIRECT      CHOLMOD supernodal Cholesky of the current matrix
 *   STALE_PCG   CG preconditioned by a Cholesky factor of an *earlier* matrix, refactored when
 *               the iteration count grows past refresh_iterations (DESIGN.md: 3-19 iterations
 *               for the changes a step makes, against ~200 for plain CG)
 * Fixed DOFs are Dirichlet: their entries of x are kept as given, and the system is solved
 * for the others (A_ff x_f = b_f - A_fc x_c). A DOF mask (not a node mask) lets a node slide
 * along a plane (fixed in one direction, free in the others). */
#ifndef NS_SOLVER_H
#define NS_SOLVER_H

#include <stdint.h>

#include "sparse.h"

typedef enum NsSolverKind {
    NS_SOLVER_CG,
    NS_SOLVER_JACOBI_PCG,
    NS_SOLVER_DIRECT,
    NS_SOLVER_STALE_PCG,
} NsSolverKind;

typedef struct NsSolveStats {
    int iterations;  /* CG iterations (0 for DIRECT) */
    double residual; /* final ||b - A x|| / ||b|| over free DOFs */
    int converged;   /* residual <= tol */
    int factorized;  /* a numeric factorization was made in this solve */
    int analyzed;    /* a symbolic analysis (ordering) was made in this solve */
} NsSolveStats;

typedef struct NsSolver NsSolver;

NsSolver *ns_solver_create(NsSolverKind kind);
void ns_solver_destroy(NsSolver *s);
NsSolverKind ns_solver_kind(const NsSolver *s);
const char *ns_solver_name(NsSolverKind kind);

/* For STALE_PCG: refactor when a solve needs more iterations than this (default 25). */
void ns_solver_set_refresh_iterations(NsSolver *s, int iterations);
/* Drop the factor: the next DIRECT / STALE_PCG solve factors the matrix it is given. */
void ns_solver_refresh(NsSolver *s);

/* Solves A x = b. dof_fixed (3n entries, may be NULL) marks Dirichlet DOFs. x holds the
 * initial guess (and the fixed values) on entry. tol is relative to ||b_f - A_fc x_c||.
 * Returns 0, or -1 on a CHOLMOD failure (not positive definite, memory) with stats filled as
 * far as they got. Non-convergence within max_iter is reported in stats, not as an error. */
int ns_solver_solve(NsSolver *s, const NsBlockMatrix *A, const uint8_t *dof_fixed, const double *b,
                    double *x, double tol, int max_iter, NsSolveStats *stats);

#endif
