/* Block sparse matrix with per-row growable storage (§3.6.2). */
#include "sparse.h"
#include "snapshot.h"

#include "ns_config.h"

#include <stdlib.h>
#include <string.h>

void ns_bsm_init(NsBlockMatrix *m)
{
    memset(m, 0, sizeof *m);
}

void ns_bsm_free(NsBlockMatrix *m)
{
    for (int i = 0; i < m->cap; i++) {
        free(m->rows[i].col);
        free(m->rows[i].val);
    }
    free(m->rows);
    ns_bsm_init(m);
}

int ns_bsm_resize(NsBlockMatrix *m, int n)
{
    if (n > m->cap) {
        int nc = m->cap ? m->cap : 16;
        while (nc < n)
            nc *= 2;
        NsBlockRow *r = realloc(m->rows, (size_t)nc * sizeof *r);
        if (!r)
            return -1;
        memset(r + m->cap, 0, (size_t)(nc - m->cap) * sizeof *r);
        m->rows = r;
        m->cap = nc;
    }
    for (int i = n; i < m->n; i++)
        m->rows[i].count = 0;
    for (int i = m->n; i < n; i++)
        m->rows[i].count = 0;
    m->n = n;
    return 0;
}

/* First position in row r whose column is >= j. */
static int lower_bound(const NsBlockRow *r, int j)
{
    int lo = 0, hi = r->count;
    while (lo < hi) {
        int mid = (lo + hi) / 2;
        if (r->col[mid] < j)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

double *ns_bsm_find(const NsBlockMatrix *m, int i, int j)
{
    if (i < 0 || i >= m->n || j < 0 || j >= m->n)
        return NULL;
    const NsBlockRow *r = &m->rows[i];
    int p = lower_bound(r, j);
    return p < r->count && r->col[p] == j ? r->val + 9 * p : NULL;
}

double *ns_bsm_get(NsBlockMatrix *m, int i, int j)
{
    if (i < 0 || i >= m->n || j < 0 || j >= m->n)
        return NULL;
    NsBlockRow *r = &m->rows[i];
    int p = lower_bound(r, j);
    if (p < r->count && r->col[p] == j)
        return r->val + 9 * p;
    if (r->count == r->cap) {
        int nc = r->cap ? 2 * r->cap : 16;
        int *c = realloc(r->col, (size_t)nc * sizeof(int));
        if (!c)
            return NULL;
        r->col = c;
        double *v = realloc(r->val, (size_t)nc * 9 * sizeof(double));
        if (!v)
            return NULL;
        r->val = v;
        r->cap = nc;
    }
    memmove(r->col + p + 1, r->col + p, (size_t)(r->count - p) * sizeof(int));
    memmove(r->val + 9 * (p + 1), r->val + 9 * p, (size_t)(r->count - p) * 9 * sizeof(double));
    r->col[p] = j;
    memset(r->val + 9 * p, 0, 9 * sizeof(double));
    r->count++;
    return r->val + 9 * p;
}

int ns_bsm_add(NsBlockMatrix *m, int i, int j, const double b[9])
{
    double *d = ns_bsm_get(m, i, j);
    if (!d)
        return -1;
    for (int k = 0; k < 9; k++)
        d[k] += b[k];
    return 0;
}

void ns_bsm_zero(NsBlockMatrix *m)
{
    for (int i = 0; i < m->n; i++)
        if (m->rows[i].count)
            memset(m->rows[i].val, 0, (size_t)m->rows[i].count * 9 * sizeof(double));
}

void ns_bsm_zero_node(NsBlockMatrix *m, int i)
{
    if (i < 0 || i >= m->n)
        return;
    NsBlockRow *r = &m->rows[i];
    for (int p = 0; p < r->count; p++) {
        double *t = ns_bsm_find(m, r->col[p], i); /* the symmetric partner, if stored */
        if (t)
            memset(t, 0, 9 * sizeof(double));
    }
    if (r->count)
        memset(r->val, 0, (size_t)r->count * 9 * sizeof(double));
}

void ns_bsm_prune(NsBlockMatrix *m)
{
    for (int i = 0; i < m->n; i++) {
        NsBlockRow *r = &m->rows[i];
        int w = 0;
        for (int p = 0; p < r->count; p++) {
            const double *b = r->val + 9 * p;
            bool zero = true;
            for (int k = 0; k < 9; k++)
                zero &= b[k] == 0.0;
            if (zero)
                continue;
            if (w != p) {
                r->col[w] = r->col[p];
                memcpy(r->val + 9 * w, b, 9 * sizeof(double));
            }
            w++;
        }
        r->count = w;
    }
}

int ns_bsm_block_count(const NsBlockMatrix *m)
{
    int c = 0;
    for (int i = 0; i < m->n; i++)
        c += m->rows[i].count;
    return c;
}

/* One block row of y = A x, summed in ascending column order. */
static void mul_row(const NsBlockMatrix *m, int i, const double *x, double *y)
{
    const NsBlockRow *r = &m->rows[i];
    double s0 = 0.0, s1 = 0.0, s2 = 0.0;
    for (int p = 0; p < r->count; p++) {
        const double *b = r->val + 9 * p, *xj = x + 3 * r->col[p];
        s0 += b[0] * xj[0] + b[1] * xj[1] + b[2] * xj[2];
        s1 += b[3] * xj[0] + b[4] * xj[1] + b[5] * xj[2];
        s2 += b[6] * xj[0] + b[7] * xj[1] + b[8] * xj[2];
    }
    y[3 * i] = s0;
    y[3 * i + 1] = s1;
    y[3 * i + 2] = s2;
}

void ns_bsm_mul(const NsBlockMatrix *m, const double *x, double *y)
{
    for (int i = 0; i < m->n; i++)
        mul_row(m, i, x, y);
}

void ns_bsm_mul_threads(const NsBlockMatrix *m, const double *x, double *y, int threads)
{
#if NS_HAVE_OPENMP
    /* Each row is computed whole by one thread, so the split never changes a result; it only
     * pays above a few hundred rows (the fork/join costs a few microseconds). */
    if (threads > 1 && m->n >= NS_BSM_PARALLEL_MIN_ROWS) {
#pragma omp parallel for num_threads(threads) schedule(static)
        for (int i = 0; i < m->n; i++)
            mul_row(m, i, x, y);
        return;
    }
#else
    (void)threads;
#endif
    ns_bsm_mul(m, x, y);
}

static void row_blank(void *e)
{
    NsBlockRow *r = e;
    r->col = NULL;
    r->val = NULL;
}

/* Every row slot of cap (rows beyond n keep their storage for regrowth), each row's blocks in an
 * allocation of its cap. */
static void matrix_blank(void *e)
{
    ((NsBlockMatrix *)e)->rows = NULL;
}

int ns_block_matrix_pack(NsPack *p, NsBlockMatrix *A)
{
    ns_pack_struct(p, "BSMX", A, sizeof *A, matrix_blank);
    size_t cap = (size_t)A->cap;
    NS_PACK_ARRAY_BLANK(p, A->rows, cap, cap, row_blank);
    for (size_t i = 0; A->rows && i < cap; i++) {
        NsBlockRow *r = &A->rows[i];
        NS_PACK_ARRAY(p, r->col, (size_t)r->count, (size_t)r->cap);
        NS_PACK_ARRAY(p, r->val, 9 * (size_t)r->count, 9 * (size_t)r->cap);
    }
    if (!p->writing && !A->rows)
        A->n = A->cap = 0; /* what ns_bsm_free walks */
    return p->failed ? -1 : 0;
}
