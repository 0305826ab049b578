/* Vector kernels shared by the coupled solvers' conjugate-gradient loops (coupled_schur.c,
 * coupled_paper.c), so that our solver and the paper's baseline run the same code for the same
 * operation. */
#ifndef NS_VEC_H
#define NS_VEC_H

#include "ns_config.h"
#include "sparse.h"

/* sum a[i] b[i]: four interleaved partial sums, added as (s0 + s1) + (s2 + s3), then the tail
 * one by one. A fixed order whatever the thread count, and four independent chains of
 * additions instead of one (GCC runs them as one vector of four). */
static inline double ns_vec_dot(const double *a, const double *b, int n)
{
    double s[4] = {0.0, 0.0, 0.0, 0.0};
    int i = 0;
    for (; i + 4 <= n; i += 4)
        for (int l = 0; l < 4; l++)
            s[l] += a[i + l] * b[i + l];
    double sum = (s[0] + s[1]) + (s[2] + s[3]);
    for (; i < n; i++)
        sum += a[i] * b[i];
    return sum;
}

/* keep[i] = 0 on the fixed DOFs of a tissue-then-needle(-then-more) vector, 1 elsewhere: a
 * select in the loops instead of a branch on two arrays. */
static inline void ns_vec_keep(const unsigned char *tfixed, int nt3, const unsigned char *rfixed,
                               int nr3, int n, double *keep)
{
    for (int i = 0; i < n; i++)
        keep[i] = (i < nt3 ? tfixed[i] : i < nt3 + nr3 ? rfixed[i - nt3] : 0) ? 0.0 : 1.0;
}

/* Where a tissue-then-rest vector of n entries (the tissue's nt3 first) is cut in two for two
 * threads: at the middle node, where ns_bsm_mul_threads's static split of the tissue matrix's
 * rows (one per node) puts it on two threads (the first takes the first half, rounded up), so
 * that each thread's vector work is mostly on entries its product wrote (with more threads the
 * product splits finer; only the speed depends on that); 0 (no cut) below
 * NS_BSM_PARALLEL_MIN_ROWS nodes, where the product runs on one thread. The cut depends on the
 * sizes alone, never on the thread count. */
static inline int ns_vec_cut(int nt3, int n)
{
    int nodes = nt3 / 3;
    return nodes >= NS_BSM_PARALLEL_MIN_ROWS && n > 0 ? 3 * ((nodes + 1) / 2) : 0;
}

/* One part [i0, i1) of a pass over vectors: the work, and up to two sums into sums[0..1]. */
typedef void (*NsVecPart)(void *ctx, int i0, int i1, double sums[2]);

/* A pass over the two parts [0, cut) and [cut, n) of vectors, at once on two threads when nth
 * is 2; sums[k] is part 0's sum k plus part 1's, the same bits on any thread count. */
static inline void ns_vec_pass(NsVecPart part, void *ctx, int n, int cut, int nth, double sums[2])
{
    double s[2][2] = {{0.0, 0.0}, {0.0, 0.0}};
#if NS_HAVE_OPENMP
#pragma omp parallel for num_threads(nth) schedule(static) if (nth > 1)
#endif
    for (int c = 0; c < 2; c++)
        part(ctx, c ? cut : 0, c ? n : cut, s[c]);
    (void)nth;
    sums[0] = s[0][0] + s[1][0];
    sums[1] = s[0][1] + s[1][1];
}

#endif
