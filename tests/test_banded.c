/* Tests for sim/banded.c: the band Cholesky solve and the band product agree with dense
 * references on random SPD rod-like matrices; Dirichlet DOFs keep their values while the free
 * equations hold; an indefinite or singular matrix is refused. */
#include "banded.h"
#include "ns_test.h"

#include <stdint.h>
#include <stdlib.h>

static double rnd(uint64_t *st)
{
    *st = *st * 6364136223846793005ull + 1442695040888963407ull;
    return (double)(*st >> 11) / 9007199254740992.0 * 2.0 - 1.0;
}

/* Dense A = B^T B + shift I with B block tridiagonal (3n x 3n), so A has blocks only for
 * |i - j| <= 2, like the rod's bending Jacobian (§3.1). Row-major, caller frees. */
static double *random_spd(int n, double shift, uint64_t *st)
{
    int nr = 3 * n;
    double *B = calloc((size_t)nr * nr, sizeof(double));
    double *A = calloc((size_t)nr * nr, sizeof(double));
    for (int r = 0; r < nr; r++)
        for (int c = 0; c < nr; c++)
            if (abs(r / 3 - c / 3) <= 1)
                B[nr * r + c] = rnd(st);
    for (int r = 0; r < nr; r++)
        for (int c = 0; c < nr; c++) {
            double s = r == c ? shift : 0.0;
            for (int k = 0; k < nr; k++)
                s += B[nr * k + r] * B[nr * k + c];
            A[nr * r + c] = s;
        }
    free(B);
    return A;
}

/* Copies the band of the dense A into m; returns 0 if A has nothing outside the band. */
static int fill_from_dense(NsBanded *m, const double *A)
{
    int nr = 3 * m->n;
    for (int r = 0; r < nr; r++)
        for (int c = 0; c < nr; c++) {
            double *b = ns_banded_block(m, r / 3, c / 3);
            if (b)
                b[3 * (r % 3) + c % 3] = A[nr * r + c];
            else if (A[nr * r + c] != 0.0)
                return 1;
        }
    return 0;
}

/* Dense Gaussian elimination with partial pivoting: x = A^-1 b. Returns 0 or 1 (singular). */
static int dense_solve(int nr, const double *A0, const double *b0, double *x)
{
    double *A = malloc((size_t)nr * nr * sizeof(double));
    memcpy(A, A0, (size_t)nr * nr * sizeof(double));
    memcpy(x, b0, (size_t)nr * sizeof(double));
    for (int k = 0; k < nr; k++) {
        int piv = k;
        for (int r = k + 1; r < nr; r++)
            if (fabs(A[nr * r + k]) > fabs(A[nr * piv + k]))
                piv = r;
        if (A[nr * piv + k] == 0.0) {
            free(A);
            return 1;
        }
        if (piv != k) {
            for (int c = 0; c < nr; c++) {
                double t = A[nr * k + c];
                A[nr * k + c] = A[nr * piv + c];
                A[nr * piv + c] = t;
            }
            double t = x[k];
            x[k] = x[piv];
            x[piv] = t;
        }
        for (int r = k + 1; r < nr; r++) {
            double f = A[nr * r + k] / A[nr * k + k];
            for (int c = k; c < nr; c++)
                A[nr * r + c] -= f * A[nr * k + c];
            x[r] -= f * x[k];
        }
    }
    for (int r = nr - 1; r >= 0; r--) {
        double s = x[r];
        for (int c = r + 1; c < nr; c++)
            s -= A[nr * r + c] * x[c];
        x[r] = s / A[nr * r + r];
    }
    free(A);
    return 0;
}

static double rel_err(int nr, const double *x, const double *ref)
{
    double d = 0, s = 0;
    for (int k = 0; k < nr; k++) {
        d += (x[k] - ref[k]) * (x[k] - ref[k]);
        s += ref[k] * ref[k];
    }
    return sqrt(d / (s > 0 ? s : 1));
}

static const int sizes[] = {1, 2, 5, 40};

static int solve_matches_dense(void)
{
    uint64_t st = 7;
    for (int t = 0; t < 4; t++) {
        for (int rep = 0; rep < 3; rep++) {
            int n = sizes[t], nr = 3 * n;
            double *A = random_spd(n, rep == 0 ? 1e-3 : 0.5, &st);
            NsBanded m;
            ENSURE(ns_banded_init(&m, n, 2) == 0);
            ENSURE(fill_from_dense(&m, A) == 0);
            double *b = malloc((size_t)nr * sizeof(double));
            double *x = malloc((size_t)nr * sizeof(double));
            double *ref = malloc((size_t)nr * sizeof(double));
            double *work = malloc((size_t)nr * sizeof(double));
            for (int k = 0; k < nr; k++)
                b[k] = rnd(&st);
            ENSURE(dense_solve(nr, A, b, ref) == 0);
            ENSURE(ns_banded_solve(&m, NULL, b, x, NULL) == 0);
            ENSURE_SMALL(rel_err(nr, x, ref), 1e-10);
            /* A caller's work buffer gives the same answer bit for bit. */
            double *x2 = malloc((size_t)nr * sizeof(double));
            ENSURE(ns_banded_solve(&m, NULL, b, x2, work) == 0);
            ENSURE(memcmp(x, x2, (size_t)nr * sizeof(double)) == 0);
            /* In place (b and x the same array), and reusing the factor buffer. */
            memcpy(x2, b, (size_t)nr * sizeof(double));
            ENSURE(ns_banded_solve(&m, NULL, x2, x2, NULL) == 0);
            ENSURE(memcmp(x, x2, (size_t)nr * sizeof(double)) == 0);
            free(x2);
            free(A), free(b), free(x), free(ref), free(work);
            ns_banded_free(&m);
        }
    }
    return 0;
}

static int mul_matches_dense(void)
{
    uint64_t st = 3;
    for (int t = 0; t < 4; t++) {
        int n = sizes[t], nr = 3 * n;
        double *A = random_spd(n, 0.1, &st);
        NsBanded m;
        ENSURE(ns_banded_init(&m, n, 2) == 0);
        ENSURE(fill_from_dense(&m, A) == 0);
        double *x = malloc((size_t)nr * sizeof(double));
        double *y = malloc((size_t)nr * sizeof(double));
        for (int k = 0; k < nr; k++)
            x[k] = rnd(&st);
        ns_banded_mul(&m, x, y);
        for (int r = 0; r < nr; r++) {
            double s = 0, mag = 0;
            for (int c = 0; c < nr; c++) {
                s += A[nr * r + c] * x[c];
                mag += fabs(A[nr * r + c] * x[c]);
            }
            ENSURE_SMALL(s - y[r], 1e-13 * (mag + 1));
        }
        /* Zeroing clears the product. */
        ns_banded_zero(&m);
        ns_banded_mul(&m, x, y);
        for (int r = 0; r < nr; r++)
            ENSURE(y[r] == 0.0);
        free(A), free(x), free(y);
        ns_banded_free(&m);
    }
    return 0;
}

static int fixed_dofs_honored(void)
{
    uint64_t st = 19;
    for (int t = 0; t < 4; t++) {
        int n = sizes[t], nr = 3 * n;
        double *A = random_spd(n, 1e-2, &st);
        NsBanded m;
        ENSURE(ns_banded_init(&m, n, 2) == 0);
        ENSURE(fill_from_dense(&m, A) == 0);
        uint8_t *fixed = calloc((size_t)nr, 1);
        double *b = malloc((size_t)nr * sizeof(double));
        double *x = malloc((size_t)nr * sizeof(double));
        double *x0 = malloc((size_t)nr * sizeof(double));
        double *ref = malloc((size_t)nr * sizeof(double));
        double *Am = malloc((size_t)nr * nr * sizeof(double));
        double *bm = malloc((size_t)nr * sizeof(double));
        for (int k = 0; k < nr; k++) {
            fixed[k] = rnd(&st) < -0.4; /* about 30% */
            b[k] = rnd(&st);
            x0[k] = x[k] = rnd(&st);
        }
        fixed[0] = 1; /* a clamped first node, as for the needle base */
        memcpy(x, x0, (size_t)nr * sizeof(double));
        ENSURE(ns_banded_solve(&m, fixed, b, x, NULL) == 0);
        /* Fixed entries unchanged, bit for bit. */
        for (int k = 0; k < nr; k++)
            if (fixed[k])
                ENSURE(x[k] == x0[k]);
        /* Free equations satisfied: (A x - b)_r = 0 for every free r. */
        double bn = 0;
        for (int k = 0; k < nr; k++)
            bn = fmax(bn, fabs(b[k]));
        for (int r = 0; r < nr; r++) {
            if (fixed[r])
                continue;
            double s = -b[r];
            for (int c = 0; c < nr; c++)
                s += A[nr * r + c] * x[c];
            ENSURE_SMALL(s, 1e-9 * (bn + 1));
        }
        /* And the same as the dense solve of the modified system. */
        for (int r = 0; r < nr; r++) {
            bm[r] = fixed[r] ? x0[r] : b[r];
            for (int c = 0; c < nr; c++) {
                if (fixed[r] || fixed[c])
                    Am[nr * r + c] = r == c;
                else
                    Am[nr * r + c] = A[nr * r + c];
                if (!fixed[r] && fixed[c])
                    bm[r] -= A[nr * r + c] * x0[c];
            }
        }
        ENSURE(dense_solve(nr, Am, bm, ref) == 0);
        ENSURE_SMALL(rel_err(nr, x, ref), 1e-10);
        /* Factored once, solved for several right-hand sides (the coupled solve's way): each
         * the bits of a whole ns_banded_solve. */
        ENSURE(ns_banded_factor(&m, fixed) == 0);
        for (int j = 0; j < 3; j++) {
            double *x1 = ref, *x2 = bm; /* reused as scratch */
            for (int k = 0; k < nr; k++) {
                b[k] = rnd(&st);
                x1[k] = x2[k] = x0[k];
            }
            ENSURE(ns_banded_solve_factored(&m, fixed, b, x1, NULL) == 0);
            ENSURE(ns_banded_solve(&m, fixed, b, x2, NULL) == 0);
            ENSURE(memcmp(x1, x2, (size_t)nr * sizeof(double)) == 0);
            ENSURE(ns_banded_factor(&m, fixed) == 0); /* ns_banded_solve refactored in place */
        }
        free(A), free(fixed), free(b), free(x), free(x0), free(ref), free(Am), free(bm);
        ns_banded_free(&m);
    }
    return 0;
}

static int not_spd_refused(void)
{
    uint64_t st = 23;
    const int n = 5, nr = 15;
    double *A = random_spd(n, 0.5, &st);
    NsBanded m;
    ENSURE(ns_banded_init(&m, n, 2) == 0);
    double b[15], x[15], x0[15];
    for (int k = 0; k < nr; k++) {
        b[k] = rnd(&st);
        x0[k] = x[k] = rnd(&st);
    }
    /* A negative diagonal entry: indefinite. x is left alone. */
    ENSURE(fill_from_dense(&m, A) == 0);
    ns_banded_block(&m, 2, 2)[4] = -1.0;
    ENSURE(ns_banded_solve(&m, NULL, b, x, NULL) == -1);
    ENSURE(memcmp(x, x0, sizeof x) == 0);
    /* The same bad DOF fixed: the free block is SPD again. */
    uint8_t fixed[15] = {0};
    fixed[7] = 1;
    ENSURE(ns_banded_solve(&m, fixed, b, x, NULL) == 0);
    ENSURE(x[7] == x0[7]);
    /* Positive diagonal but indefinite: a 2x2 [[1, 2], [2, 1]] inside a block. */
    ns_banded_zero(&m);
    for (int i = 0; i < n; i++)
        for (int a = 0; a < 3; a++)
            ns_banded_block(&m, i, i)[4 * a] = 1.0;
    ns_banded_block(&m, 3, 3)[1] = ns_banded_block(&m, 3, 3)[3] = 2.0;
    ENSURE(ns_banded_solve(&m, NULL, b, x, NULL) == -1);
    /* Indefinite through an off-diagonal block: [[I, 2I], [2I, I]] across blocks 1 and 3. */
    ns_banded_block(&m, 3, 3)[1] = ns_banded_block(&m, 3, 3)[3] = 0.0;
    for (int a = 0; a < 3; a++)
        ns_banded_block(&m, 1, 3)[4 * a] = ns_banded_block(&m, 3, 1)[4 * a] = 2.0;
    ENSURE(ns_banded_solve(&m, NULL, b, x, NULL) == -1);
    /* Singular: the zero matrix. x is left alone again. */
    ns_banded_zero(&m);
    memcpy(x, x0, sizeof x);
    ENSURE(ns_banded_solve(&m, NULL, b, x, NULL) == -1);
    ENSURE(memcmp(x, x0, sizeof x) == 0);
    free(A);
    ns_banded_free(&m);
    return 0;
}

static int layout_and_bad_args(void)
{
    NsBanded m;
    ENSURE(ns_banded_init(&m, 0, 2) == -1);
    ENSURE(ns_banded_init(&m, 4, -1) == -1);
    ns_banded_free(&m); /* an empty matrix frees cleanly */
    ENSURE(ns_banded_init(&m, 6, 2) == 0);
    ENSURE(ns_banded_block(&m, 0, 3) == NULL);
    ENSURE(ns_banded_block(&m, 5, 2) == NULL);
    ENSURE(ns_banded_block(&m, -1, 0) == NULL);
    ENSURE(ns_banded_block(&m, 5, 6) == NULL);
    ENSURE(ns_banded_block(&m, 0, 2) != NULL);
    ENSURE(ns_banded_block(&m, 5, 3) != NULL);
    /* Distinct blocks never share storage. */
    for (int i = 0; i < 6; i++)
        for (int j = 0; j < 6; j++) {
            double *b = ns_banded_block(&m, i, j);
            if (b)
                for (int k = 0; k < 9; k++)
                    b[k] = 100 * i + 10 * j + k;
        }
    for (int i = 0; i < 6; i++)
        for (int j = 0; j < 6; j++) {
            double *b = ns_banded_block(&m, i, j);
            if (b)
                for (int k = 0; k < 9; k++)
                    ENSURE(b[k] == 100 * i + 10 * j + k);
        }
    ns_banded_free(&m);
    ENSURE(m.val == NULL && m.n == 0);
    return 0;
}

NS_TEST_MAIN({"solve_matches_dense", solve_matches_dense}, {"mul_matches_dense", mul_matches_dense},
             {"fixed_dofs_honored", fixed_dofs_honored}, {"not_spd_refused", not_spd_refused},
             {"layout_and_bad_args", layout_and_bad_args})
