/* Banded symmetric positive definite matrix of 3x3 blocks and its direct solver, for the needle
 * rod (paper §3.1). The rod's implicit bending and stretching Jacobians couple each node only to
 * the nodes at most two segments away, so block (i, j) is nonzero only for |i - j| <= 2: a
 * bandwidth of 5 blocks. A general sparse factorisation would spend its time on bookkeeping; a
 * band Cholesky factorises and solves in O(n * bw^2) = O(n) for a fixed band, with one buffer
 * allocated once and reused every step.
 *
 * Storage: block row i keeps the 2*half+1 blocks (i, i-half) .. (i, i+half), each row-major 3x3,
 * in val[((2*half+1) * i + (j - i + half)) * 9]; blocks that fall outside [0, n) are unused.
 * Both triangles are stored (so ns_banded_mul is a plain row sweep); the caller keeps them
 * symmetric. ns_banded_solve assumes symmetry and reads only the lower triangle (column <= row). */
#ifndef NS_BANDED_H
#define NS_BANDED_H

#include <stdint.h>

typedef struct NsBanded {
    int n;       /* block rows (= block columns); 3n scalar unknowns */
    int half;    /* block half-bandwidth: block (i, j) stored for |i - j| <= half */
    double *val; /* (n x (2*half+1) x 9) blocks, see above */
    double *fac; /* (3n x (3*half+3)) band Cholesky factor, then 3n right-hand side: scratch */
} NsBanded;

/* Allocates an all-zero n-block matrix of block half-bandwidth half (n >= 1, 0 <= half <= 1000).
 * Returns 0, or -1 on bad arguments or out of memory (then m is left empty and freeable). */
int ns_banded_init(NsBanded *m, int n, int half);
void ns_banded_free(NsBanded *m);
/* Write zeros into every stored block. */
void ns_banded_zero(NsBanded *m);
/* The 3x3 block (i, j), or NULL if (i, j) lies outside the matrix or the band. */
double *ns_banded_block(NsBanded *m, int i, int j);

/* y = A x over every stored block (length 3n; x and y must not overlap). */
void ns_banded_mul(const NsBanded *m, const double *x, double *y);

/* Solves A x = b by band Cholesky (A = L L^T, scalar half-bandwidth 3*(half+1)-1) in
 * O(n * bw^2). dof_fixed (3n, may be NULL) marks Dirichlet DOFs: they keep the value x holds on
 * entry, and the free DOFs solve A_ff x_f = b_f - A_fc x_c (fixed rows and columns act as the
 * identity with the moved right-hand side). work is 3n doubles of scratch, or NULL to use the
 * matrix's own buffer; b and x may be the same array. The factor is written into m's scratch
 * buffer, so one matrix must not be solved from two threads at once.
 * Returns 0, or -1 if the free block A_ff is not (numerically) positive definite; x is then
 * unchanged. */
int ns_banded_solve(const NsBanded *m, const uint8_t *dof_fixed, const double *b, double *x,
                    double *work);

/* ns_banded_solve in two parts, for many right-hand sides with one matrix: the factor into m's
 * buffer (0, or -1 if A_ff is not positive definite), then solves with it, each the same bits
 * as ns_banded_solve's. A solve uses the factor of the last ns_banded_factor of m, which the
 * caller keeps current (the same values and dof_fixed); it always returns 0. */
int ns_banded_factor(const NsBanded *m, const uint8_t *dof_fixed);
int ns_banded_solve_factored(const NsBanded *m, const uint8_t *dof_fixed, const double *b,
                             double *x, double *work);

#endif
