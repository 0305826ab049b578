/* 3x3 block sparse matrix with growable rows (paper §3.6.2): each block row keeps its own
 * sorted array of (column, 3x3 block), so remeshing can add entries for new edges, write zeros
 * for deleted ones and reuse the rows of deleted nodes, without rebuilding the matrix.
 * Blocks are row-major 3x3. Column order within a row is ascending, which keeps products
 * deterministic and conversion to compressed-column form a plain copy. */
#ifndef NS_SPARSE_H
#define NS_SPARSE_H

#include <stdbool.h>

typedef struct NsBlockRow {
    int *col;    /* (cap) block column indices, ascending over [0, count) */
    double *val; /* (cap x 9) blocks */
    int count;
    int cap;
} NsBlockRow;

typedef struct NsBlockMatrix {
    int n; /* block rows (= block columns) */
    int cap;
    NsBlockRow *rows;
} NsBlockMatrix;

void ns_bsm_init(NsBlockMatrix *m);
void ns_bsm_free(NsBlockMatrix *m);
/* Grow (new rows empty) or shrink to n block rows. Returns 0 or -1 (memory). */
int ns_bsm_resize(NsBlockMatrix *m, int n);

/* The block (i, j), or NULL if it is not stored. */
double *ns_bsm_find(const NsBlockMatrix *m, int i, int j);
/* The block (i, j), inserted as zeros if absent; NULL on bad indices or out of memory. */
double *ns_bsm_get(NsBlockMatrix *m, int i, int j);
/* Adds the 3x3 block b to (i, j). Returns 0 or -1. */
int ns_bsm_add(NsBlockMatrix *m, int i, int j, const double b[9]);

/* Write zeros into every stored block (structure kept). */
void ns_bsm_zero(NsBlockMatrix *m);
/* Write zeros into row i and column i (a deleted node, §3.6.2); structure kept. The matrix is
 * assumed structurally symmetric (stiffness matrices are): column i is found through row i. */
void ns_bsm_zero_node(NsBlockMatrix *m, int i);
/* Drop stored blocks that are exactly zero from every row. */
void ns_bsm_prune(NsBlockMatrix *m);
int ns_bsm_block_count(const NsBlockMatrix *m);

/* y = A x (length 3n), on the calling thread. */
void ns_bsm_mul(const NsBlockMatrix *m, const double *x, double *y);
/* The same product with up to `threads` OpenMP threads (one below NS_BSM_PARALLEL_MIN_ROWS
 * block rows, or without OpenMP). Each row is summed in column order by one thread, so y is
 * bit-identical to ns_bsm_mul's for every thread count. */
#define NS_BSM_PARALLEL_MIN_ROWS 512
void ns_bsm_mul_threads(const NsBlockMatrix *m, const double *x, double *y, int threads);

#endif
