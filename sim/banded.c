/* Banded 3x3-block SPD matrix and band Cholesky solver for the needle rod (§3.1). */
#include "banded.h"
#include "snapshot.h"

#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* Scalar half-bandwidth of the factor: a scalar row r in block I reaches the last scalar
 * column of block I + half, at most 3 * (half + 1) - 1 to its right. */
static int scalar_band(const NsBanded *m)
{
    return 3 * (m->half + 1) - 1;
}

int ns_banded_init(NsBanded *m, int n, int half)
{
    memset(m, 0, sizeof *m);
    if (n < 1 || half < 0 || half > 1000 || n > INT32_MAX / 3)
        return -1;
    size_t w = (size_t)(2 * half + 1), nr = (size_t)3 * (size_t)n;
    size_t p1 = (size_t)(3 * (half + 1));
    if ((size_t)n > SIZE_MAX / sizeof(double) / 9 / w || nr > SIZE_MAX / sizeof(double) / (p1 + 1))
        return -1;
    m->val = calloc((size_t)n * w * 9, sizeof(double));
    m->fac = calloc(nr * (p1 + 1), sizeof(double));
    if (!m->val || !m->fac) {
        ns_banded_free(m);
        return -1;
    }
    m->n = n;
    m->half = half;
    return 0;
}

void ns_banded_free(NsBanded *m)
{
    free(m->val);
    free(m->fac);
    memset(m, 0, sizeof *m);
}

void ns_banded_zero(NsBanded *m)
{
    if (m->val)
        memset(m->val, 0, (size_t)m->n * (size_t)(2 * m->half + 1) * 9 * sizeof(double));
}

static size_t block_offset(const NsBanded *m, int i, int j)
{
    return ((size_t)(2 * m->half + 1) * (size_t)i + (size_t)(j - i + m->half)) * 9;
}

double *ns_banded_block(NsBanded *m, int i, int j)
{
    if (i < 0 || j < 0 || i >= m->n || j >= m->n || abs(i - j) > m->half)
        return NULL;
    return m->val + block_offset(m, i, j);
}

void ns_banded_mul(const NsBanded *m, const double *x, double *y)
{
    for (int i = 0; i < m->n; i++) {
        double s[3] = {0, 0, 0};
        int j0 = i - m->half < 0 ? 0 : i - m->half;
        int j1 = i + m->half > m->n - 1 ? m->n - 1 : i + m->half;
        for (int j = j0; j <= j1; j++) {
            const double *b = m->val + block_offset(m, i, j), *xj = x + 3 * j;
            for (int a = 0; a < 3; a++)
                s[a] += b[3 * a] * xj[0] + b[3 * a + 1] * xj[1] + b[3 * a + 2] * xj[2];
        }
        y[3 * i] = s[0];
        y[3 * i + 1] = s[1];
        y[3 * i + 2] = s[2];
    }
}

/* Scalar entry A(r, c) of the stored band, 0 outside it. */
static double entry(const NsBanded *m, int r, int c)
{
    int bi = r / 3, bj = c / 3;
    if (abs(bi - bj) > m->half)
        return 0.0;
    return m->val[block_offset(m, bi, bj) + (size_t)(3 * (r % 3) + c % 3)];
}

/* The band Cholesky factor of A (with dof_fixed's rows and columns as the identity) into
 * m->fac. Returns 0, or -1 if A_ff is not (numerically) positive definite. */
int ns_banded_factor(const NsBanded *m, const uint8_t *dof_fixed)
{
    const int nr = 3 * m->n, p = scalar_band(m), w = p + 1;
    double *L = m->fac; /* L(r, c) for r - p <= c <= r at L[w * r + (c - r + p)] */
#define LF(r, c) L[(size_t)w * (size_t)(r) + (size_t)((c) - (r) + p)]
    /* Band Cholesky, row by row: L(r, c) = (A(r, c) - sum_k L(r, k) L(c, k)) / L(c, c), where
     * k runs over the columns both rows reach. Fixed rows and columns are the identity. A pivot
     * that is not clearly positive (relative to its diagonal entry, or NaN) means A_ff is not
     * positive definite. */
    for (int r = 0; r < nr; r++) {
        int c0 = r - p < 0 ? 0 : r - p;
        int rfix = dof_fixed && dof_fixed[r];
        for (int c = c0; c <= r; c++) {
            double a;
            if (rfix || (dof_fixed && dof_fixed[c]))
                a = r == c ? 1.0 : 0.0;
            else
                a = entry(m, r, c);
            double s = a;
            for (int k = c0; k < c; k++)
                s -= LF(r, k) * LF(c, k);
            if (c < r) {
                LF(r, c) = s / LF(c, c);
            } else {
                if (!(s > 8.0 * DBL_EPSILON * fabs(a)) || !isfinite(s))
                    return -1;
                LF(r, r) = sqrt(s);
            }
        }
    }

#undef LF
    return 0;
}

/* The right-hand side with the fixed DOFs moved over into y, then the two triangular solves
 * with the factor in m->fac, in y. */
static void solve_band(const NsBanded *m, const uint8_t *dof_fixed, const double *b,
                       const double *x, double *y)
{
    const int nr = 3 * m->n, p = scalar_band(m), w = p + 1;
    const double *L = m->fac;
#define LF(r, c) L[(size_t)w * (size_t)(r) + (size_t)((c) - (r) + p)]
    /* Right-hand side with the fixed DOFs moved over; fixed rows become x_c = x_c. The full
     * row is read from the stored band, so columns right of the diagonal count too. */
    for (int r = 0; r < nr; r++) {
        if (dof_fixed && dof_fixed[r]) {
            y[r] = x[r];
            continue;
        }
        double s = b[r];
        if (dof_fixed) {
            int c0 = r - p < 0 ? 0 : r - p, c1 = r + p > nr - 1 ? nr - 1 : r + p;
            for (int c = c0; c <= c1; c++)
                if (dof_fixed[c])
                    s -= entry(m, r, c) * x[c];
        }
        y[r] = s;
    }

    /* L z = y, then L^T x = z, both in y. */
    for (int r = 0; r < nr; r++) {
        int c0 = r - p < 0 ? 0 : r - p;
        double s = y[r];
        for (int k = c0; k < r; k++)
            s -= LF(r, k) * y[k];
        y[r] = s / LF(r, r);
    }
    for (int r = nr - 1; r >= 0; r--) {
        int k1 = r + p > nr - 1 ? nr - 1 : r + p;
        double s = y[r];
        for (int k = r + 1; k <= k1; k++)
            s -= LF(k, r) * y[k];
        y[r] = s / LF(r, r);
    }
#undef LF
}

int ns_banded_solve_factored(const NsBanded *m, const uint8_t *dof_fixed, const double *b,
                             double *x, double *work)
{
    const int nr = 3 * m->n;
    double *y = work ? work : m->fac + (size_t)nr * (size_t)(scalar_band(m) + 1);
    solve_band(m, dof_fixed, b, x, y);
    /* Fixed entries come out exactly as they went in (identity rows, zero couplings). */
    memcpy(x, y, (size_t)nr * sizeof(double));
    return 0;
}

int ns_banded_solve(const NsBanded *m, const uint8_t *dof_fixed, const double *b, double *x,
                    double *work)
{
    if (ns_banded_factor(m, dof_fixed))
        return -1; /* x unchanged */
    return ns_banded_solve_factored(m, dof_fixed, b, x, work);
}

static void banded_blank(void *e)
{
    NsBanded *h = e;
    h->val = h->fac = NULL;
}

/* The blocks and the factor buffer (the last factor and the solve's scratch), whole. */
int ns_banded_pack(NsPack *p, NsBanded *B)
{
    ns_pack_struct(p, "BAND", B, sizeof *B, banded_blank);
    size_t n = B->n > 0 ? (size_t)B->n : 0, half = B->half > 0 ? (size_t)B->half : 0;
    size_t nval = n * (2 * half + 1) * 9, nfac = 3 * n * (3 * (half + 1) + 1);
    NS_PACK_ARRAY(p, B->val, nval, nval);
    NS_PACK_ARRAY(p, B->fac, nfac, nfac);
    return p->failed ? -1 : 0;
}
