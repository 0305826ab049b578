/* 3x3 singular value decomposition with the inversion-safe sign convention of Irving, Teran
 * and Fedkiw 2004 (paper §3.2): F = U diag(s) V^T with U and V proper rotations (det +1),
 * s[0] >= s[1] >= |s[2]|, and s[2] < 0 exactly when det F < 0 (an inverted element). */
#ifndef NS_SVD3_H
#define NS_SVD3_H

/* Matrices are row-major 3x3. */

/* Eigen-decomposition of the symmetric A by cyclic Jacobi rotations: on return A is diagonal
 * (the eigenvalues, unsorted) and the columns of V are the eigenvectors. */
void ns_sym3_eigen(double A[9], double V[9]);

void ns_svd3(const double F[9], double U[9], double s[3], double V[9]);

/* ns_svd3 of n matrices F[k] into U[k], s[k], V[k]: the same results, bit for bit, as n calls
 * of ns_svd3. Where the CPU has AVX2 the decompositions of eight matrices run at once, one per
 * vector lane, each lane doing ns_svd3's operations and stopping where ns_svd3 would. */
void ns_svd3_n(int n, const double *const F[], double *const U[], double *const s[],
               double *const V[]);

#endif
