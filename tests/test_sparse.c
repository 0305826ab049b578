/* Tests for sim/sparse.c: block insertion, deletion by zeroing, pruning and row reuse agree
 * with a dense reference; products match the dense product exactly. */
#include "sparse.h"
#include "ns_test.h"

#include <stdint.h>
#include <stdlib.h>

static double rnd(uint64_t *st)
{
    *st = *st * 6364136223846793005ull + 1442695040888963407ull;
    return (double)(*st >> 11) / 9007199254740992.0 * 2.0 - 1.0;
}

static int matches_dense(const NsBlockMatrix *m, const double *dense, int n)
{
    for (int i = 0; i < 3 * n; i++)
        for (int j = 0; j < 3 * n; j++) {
            const double *b = ns_bsm_find(m, i / 3, j / 3);
            double v = b ? b[3 * (i % 3) + j % 3] : 0.0;
            if (v != dense[3 * n * i + j])
                return 0;
        }
    return 1;
}

static int insert_delete_against_dense(void)
{
    const int n = 30;
    uint64_t st = 11;
    NsBlockMatrix m;
    ns_bsm_init(&m);
    ENSURE(ns_bsm_resize(&m, n) == 0);
    double *dense = calloc((size_t)9 * n * n, sizeof(double));
    for (int it = 0; it < 2000; it++) {
        int i = (int)((rnd(&st) + 1) * 0.5 * n) % n, j = (int)((rnd(&st) + 1) * 0.5 * n) % n;
        double b[9];
        for (int k = 0; k < 9; k++)
            b[k] = rnd(&st);
        /* Stiffness matrices are symmetric: add b at (i, j) and b^T at (j, i). */
        double bt[9];
        for (int k = 0; k < 9; k++)
            bt[k] = b[3 * (k % 3) + k / 3];
        ENSURE(ns_bsm_add(&m, i, j, b) == 0);
        for (int k = 0; k < 9; k++)
            dense[3 * n * (3 * i + k / 3) + 3 * j + k % 3] += b[k];
        if (i != j) {
            ENSURE(ns_bsm_add(&m, j, i, bt) == 0);
            for (int k = 0; k < 9; k++)
                dense[3 * n * (3 * j + k / 3) + 3 * i + k % 3] += bt[k];
        }
        if (it % 97 == 0) { /* delete a node: zero its row and column */
            int d = it % n;
            ns_bsm_zero_node(&m, d);
            for (int r = 0; r < 3 * n; r++)
                for (int c = 0; c < 3; c++) {
                    dense[3 * n * r + 3 * d + c] = 0;
                    dense[3 * n * (3 * d + c) + r] = 0;
                }
        }
    }
    ENSURE(matches_dense(&m, dense, n));
    /* Columns stay sorted within each row. */
    for (int i = 0; i < n; i++)
        for (int p = 1; p < m.rows[i].count; p++)
            ENSURE(m.rows[i].col[p - 1] < m.rows[i].col[p]);
    int before = ns_bsm_block_count(&m);
    ns_bsm_prune(&m);
    ENSURE(ns_bsm_block_count(&m) <= before);
    ENSURE(matches_dense(&m, dense, n));
    /* y = A x against the dense product. */
    double x[90], y[90];
    for (int k = 0; k < 3 * n; k++)
        x[k] = rnd(&st);
    ns_bsm_mul(&m, x, y);
    for (int r = 0; r < 3 * n; r++) {
        double s = 0;
        for (int c = 0; c < 3 * n; c++)
            s += dense[3 * n * r + c] * x[c];
        ENSURE_SMALL(s - y[r], 1e-12);
    }
    /* Growing and shrinking keeps the surviving rows. */
    ENSURE(ns_bsm_resize(&m, n + 5) == 0);
    ENSURE(m.rows[n + 4].count == 0);
    ENSURE(ns_bsm_get(&m, n + 4, 0) != NULL);
    ENSURE(ns_bsm_get(&m, n + 5, 0) == NULL);
    ENSURE(ns_bsm_resize(&m, n) == 0);
    ENSURE(matches_dense(&m, dense, n));
    free(dense);
    ns_bsm_free(&m);
    return 0;
}

/* The threaded product is bit-identical to the serial one for every thread count, on a matrix
 * large enough for the parallel path (rows of random lengths, so the threads' shares differ). */
static int threaded_product_is_identical(void)
{
    const int n = 4 * NS_BSM_PARALLEL_MIN_ROWS + 3;
    uint64_t st = 5;
    NsBlockMatrix m;
    ns_bsm_init(&m);
    ENSURE(ns_bsm_resize(&m, n) == 0);
    for (int i = 0; i < n; i++) {
        int count = 1 + (int)((rnd(&st) + 1) * 20);
        for (int e = 0; e < count; e++) {
            int j = (int)((rnd(&st) + 1) * 0.5 * n) % n;
            double b[9];
            for (int k = 0; k < 9; k++)
                b[k] = rnd(&st) * pow(10.0, 8 * rnd(&st)); /* wide range: order matters */
            ENSURE(ns_bsm_add(&m, i, j, b) == 0);
        }
    }
    double *x = malloc((size_t)3 * n * sizeof(double)),
           *y1 = malloc((size_t)3 * n * sizeof(double));
    double *y = malloc((size_t)3 * n * sizeof(double));
    for (int k = 0; k < 3 * n; k++)
        x[k] = rnd(&st) * pow(10.0, 8 * rnd(&st));
    ns_bsm_mul(&m, x, y1);
    for (int threads = 1; threads <= 4; threads++) {
        for (int k = 0; k < 3 * n; k++)
            y[k] = NAN; /* every entry must be written */
        ns_bsm_mul_threads(&m, x, y, threads);
        ENSURE(memcmp(y, y1, (size_t)3 * n * sizeof(double)) == 0);
    }
    free(x);
    free(y1);
    free(y);
    ns_bsm_free(&m);
    return 0;
}

NS_TEST_MAIN({"insert_delete_against_dense", insert_delete_against_dense},
             {"threaded_product_is_identical", threaded_product_is_identical})
