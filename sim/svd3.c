/* Inversion-safe 3x3 SVD (Irving et al. 2004, §3.2 of the paper).
 *
 * V and the squared singular values come from a cyclic Jacobi eigen-solve of the symmetric
 * F^T F, which converges quadratically and is unconditionally stable. U follows column by
 * column from F V, with Gram-Schmidt so that rank-deficient F (flat or collapsed elements)
 * still gives an orthonormal U; its last column is the cross product of the first two, which
 * makes det U = +1 and leaves the sign of the last singular value to carry det F. */
#include "svd3.h"

#include <math.h>
#include <string.h>

void ns_sym3_eigen(double A[9], double V[9])
{
    for (int i = 0; i < 9; i++)
        V[i] = (i % 4 == 0) ? 1.0 : 0.0;
    for (int sweep = 0; sweep < 30; sweep++) {
        double off = A[1] * A[1] + A[2] * A[2] + A[5] * A[5];
        double diag = A[0] * A[0] + A[4] * A[4] + A[8] * A[8];
        if (off <= 1e-30 * diag || off == 0.0)
            break;
        static const int pairs[3][2] = {{0, 1}, {0, 2}, {1, 2}};
        for (int k = 0; k < 3; k++) {
            int p = pairs[k][0], q = pairs[k][1];
            double apq = A[3 * p + q];
            if (apq == 0.0)
                continue;
            /* Rotation that zeroes A[p][q] (Golub & Van Loan, symmetric Schur). */
            double tau = (A[3 * q + q] - A[3 * p + p]) / (2.0 * apq);
            double t = (tau >= 0.0 ? 1.0 : -1.0) / (fabs(tau) + sqrt(1.0 + tau * tau));
            double c = 1.0 / sqrt(1.0 + t * t), s = t * c;
            for (int r = 0; r < 3; r++) { /* A <- A J */
                double arp = A[3 * r + p], arq = A[3 * r + q];
                A[3 * r + p] = c * arp - s * arq;
                A[3 * r + q] = s * arp + c * arq;
            }
            for (int r = 0; r < 3; r++) { /* A <- J^T A */
                double apr = A[3 * p + r], aqr = A[3 * q + r];
                A[3 * p + r] = c * apr - s * aqr;
                A[3 * q + r] = s * apr + c * aqr;
            }
            for (int r = 0; r < 3; r++) { /* V <- V J */
                double vrp = V[3 * r + p], vrq = V[3 * r + q];
                V[3 * r + p] = c * vrp - s * vrq;
                V[3 * r + q] = s * vrp + c * vrq;
            }
        }
    }
}

static double norm3(const double *v)
{
    return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

/* A unit vector orthogonal to the unit vector a. */
static void any_orthogonal(const double *a, double *out)
{
    /* Cross with the coordinate axis least aligned with a. */
    double ax = fabs(a[0]), ay = fabs(a[1]), az = fabs(a[2]);
    double e[3] = {0, 0, 0};
    if (ax <= ay && ax <= az)
        e[0] = 1;
    else if (ay <= az)
        e[1] = 1;
    else
        e[2] = 1;
    out[0] = a[1] * e[2] - a[2] * e[1];
    out[1] = a[2] * e[0] - a[0] * e[2];
    out[2] = a[0] * e[1] - a[1] * e[0];
    double n = norm3(out);
    for (int i = 0; i < 3; i++)
        out[i] /= n;
}

/* A = F^T F. */
static void gram(const double F[9], double A[9])
{
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            A[3 * i + j] = F[i] * F[j] + F[3 + i] * F[3 + j] + F[6 + i] * F[6 + j];
}

/* The SVD from the eigen-decomposition A (diagonal), V of F^T F. */
static void finish(const double F[9], const double A[9], double U[9], double s[3], double V[9])
{
    double lam[3] = {A[0], A[4], A[8]};
    /* Sort eigenpairs in decreasing order (columns of V move with them). */
    for (int i = 0; i < 2; i++)
        for (int j = 0; j < 2 - i; j++)
            if (lam[j] < lam[j + 1]) {
                double t = lam[j];
                lam[j] = lam[j + 1];
                lam[j + 1] = t;
                for (int r = 0; r < 3; r++) {
                    t = V[3 * r + j];
                    V[3 * r + j] = V[3 * r + j + 1];
                    V[3 * r + j + 1] = t;
                }
            }
    /* Make V a rotation. */
    double det_v = V[0] * (V[4] * V[8] - V[5] * V[7]) - V[1] * (V[3] * V[8] - V[5] * V[6]) +
                   V[2] * (V[3] * V[7] - V[4] * V[6]);
    if (det_v < 0.0)
        for (int r = 0; r < 3; r++)
            V[3 * r + 2] = -V[3 * r + 2];
    /* B = F V: its columns are s_i u_i. */
    double B[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            B[3 * i + j] =
                F[3 * i + 0] * V[0 + j] + F[3 * i + 1] * V[3 + j] + F[3 * i + 2] * V[6 + j];
    double u0[3] = {B[0], B[3], B[6]}, u1[3] = {B[1], B[4], B[7]}, u2[3];
    double scale = sqrt(fabs(lam[0])) + 1e-300;
    double n0 = norm3(u0);
    if (n0 <= 1e-14 * scale || n0 == 0.0) {
        u0[0] = 1.0;
        u0[1] = u0[2] = 0.0;
    } else {
        for (int i = 0; i < 3; i++)
            u0[i] /= n0;
    }
    double d = u1[0] * u0[0] + u1[1] * u0[1] + u1[2] * u0[2];
    for (int i = 0; i < 3; i++)
        u1[i] -= d * u0[i];
    double n1 = norm3(u1);
    if (n1 <= 1e-12 * scale || n1 == 0.0) {
        any_orthogonal(u0, u1);
    } else {
        for (int i = 0; i < 3; i++)
            u1[i] /= n1;
    }
    u2[0] = u0[1] * u1[2] - u0[2] * u1[1];
    u2[1] = u0[2] * u1[0] - u0[0] * u1[2];
    u2[2] = u0[0] * u1[1] - u0[1] * u1[0];
    for (int r = 0; r < 3; r++) {
        U[3 * r + 0] = u0[r];
        U[3 * r + 1] = u1[r];
        U[3 * r + 2] = u2[r];
    }
    /* s_i = u_i . (F v_i): non-negative for the first two by construction, signed for the last. */
    s[0] = u0[0] * B[0] + u0[1] * B[3] + u0[2] * B[6];
    s[1] = u1[0] * B[1] + u1[1] * B[4] + u1[2] * B[7];
    s[2] = u2[0] * B[2] + u2[1] * B[5] + u2[2] * B[8];
}

void ns_svd3(const double F[9], double U[9], double s[3], double V[9])
{
    double A[9];
    gram(F, A);
    ns_sym3_eigen(A, V);
    finish(F, A, U, s, V);
}

/* Eight Jacobi eigen-solves at once, one per lane of two interleaved 4-wide double vectors:
 * each lane performs exactly the operations of ns_sym3_eigen on its own matrix, in the same
 * order (IEEE basic operations only: add, multiply, divide, square root, each correctly rounded
 * in a lane as in a scalar register; no contraction, as the build says -ffp-contract=off), and
 * stops where ns_sym3_eigen would stop. A rotation that ns_sym3_eigen skips (a zero pivot, or a
 * lane that has converged) is computed but not stored. So each lane's result is
 * ns_sym3_eigen's, bit for bit, and the decomposition stays a function of F alone (a warm start
 * from the last step's V was faster but made it depend on a tet's history: docs/performance.md).
 * The rotations of one matrix are a chain of dependent divisions and square roots; eight chains
 * side by side took 0.11 us a matrix against 0.38 us one at a time (this machine). The rest of
 * the SVD (finish4) runs four lanes at a time the same way: the whole SVD 0.15 us against 0.46.
 */
#if defined(__GNUC__) && defined(__x86_64__) && !defined(__SANITIZE_ADDRESS__)
#include <immintrin.h>
#define NS_SVD3_LANES 1

/* G groups of four lanes. */
#define G     2
#define LANES (4 * G)

/* (x, y) <- (c x - s y, s x + c y) in the lanes of m; the others keep theirs. */
__attribute__((target("avx2"), always_inline)) static inline void
rotate(__m256d *x, __m256d *y, __m256d c, __m256d s, __m256d m)
{
    __m256d x0 = *x, y0 = *y;
    *x = _mm256_blendv_pd(x0, _mm256_sub_pd(_mm256_mul_pd(c, x0), _mm256_mul_pd(s, y0)), m);
    *y = _mm256_blendv_pd(y0, _mm256_add_pd(_mm256_mul_pd(s, x0), _mm256_mul_pd(c, y0)), m);
}

__attribute__((target("avx2"))) static void sym3_eigen_lanes(double *const A[LANES],
                                                             double *const V[LANES])
{
    __m256d a[G][9], v[G][9], live[G];
    for (int g = 0; g < G; g++) {
        const int l = 4 * g;
        for (int i = 0; i < 9; i++) {
            a[g][i] = _mm256_set_pd(A[l + 3][i], A[l + 2][i], A[l + 1][i], A[l][i]);
            v[g][i] = _mm256_set1_pd((i % 4 == 0) ? 1.0 : 0.0);
        }
        live[g] = _mm256_castsi256_pd(_mm256_set1_epi64x(-1));
    }
    const __m256d one = _mm256_set1_pd(1.0), two = _mm256_set1_pd(2.0), zero = _mm256_setzero_pd(),
                  eps = _mm256_set1_pd(1e-30), sign = _mm256_set1_pd(-0.0),
                  minus = _mm256_set1_pd(-1.0);
    for (int sweep = 0; sweep < 30; sweep++) {
        int any = 0;
        for (int g = 0; g < G; g++) {
            const __m256d *b = a[g];
            __m256d off =
                _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(b[1], b[1]), _mm256_mul_pd(b[2], b[2])),
                              _mm256_mul_pd(b[5], b[5]));
            __m256d diag =
                _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(b[0], b[0]), _mm256_mul_pd(b[4], b[4])),
                              _mm256_mul_pd(b[8], b[8]));
            __m256d done = _mm256_or_pd(_mm256_cmp_pd(off, _mm256_mul_pd(eps, diag), _CMP_LE_OQ),
                                        _mm256_cmp_pd(off, zero, _CMP_EQ_OQ));
            live[g] = _mm256_andnot_pd(done, live[g]);
            any |= _mm256_movemask_pd(live[g]);
        }
        if (!any)
            break;
        static const int pairs[3][2] = {{0, 1}, {0, 2}, {1, 2}};
        for (int k = 0; k < 3; k++) {
            const int p = pairs[k][0], q = pairs[k][1];
            for (int g = 0; g < G; g++) {
                __m256d *b = a[g], *w = v[g];
                __m256d apq = b[3 * p + q];
                __m256d m = _mm256_and_pd(live[g], _mm256_cmp_pd(apq, zero, _CMP_NEQ_UQ));
                if (_mm256_movemask_pd(m) == 0)
                    continue;
                __m256d tau = _mm256_div_pd(_mm256_sub_pd(b[3 * q + q], b[3 * p + p]),
                                            _mm256_mul_pd(two, apq));
                __m256d sg = _mm256_blendv_pd(minus, one, _mm256_cmp_pd(tau, zero, _CMP_GE_OQ));
                __m256d t = _mm256_div_pd(
                    sg, _mm256_add_pd(_mm256_andnot_pd(sign, tau),
                                      _mm256_sqrt_pd(_mm256_add_pd(one, _mm256_mul_pd(tau, tau)))));
                __m256d c =
                    _mm256_div_pd(one, _mm256_sqrt_pd(_mm256_add_pd(one, _mm256_mul_pd(t, t))));
                __m256d s = _mm256_mul_pd(t, c);
                for (int r = 0; r < 3; r++) /* A <- A J */
                    rotate(&b[3 * r + p], &b[3 * r + q], c, s, m);
                for (int r = 0; r < 3; r++) /* A <- J^T A */
                    rotate(&b[3 * p + r], &b[3 * q + r], c, s, m);
                for (int r = 0; r < 3; r++) /* V <- V J */
                    rotate(&w[3 * r + p], &w[3 * r + q], c, s, m);
            }
        }
    }
    for (int g = 0; g < G; g++)
        for (int i = 0; i < 9; i++) {
            double la[4], lv[4];
            _mm256_storeu_pd(la, a[g][i]);
            _mm256_storeu_pd(lv, v[g][i]);
            for (int l = 0; l < 4; l++) {
                A[4 * g + l][i] = la[l];
                V[4 * g + l][i] = lv[l];
            }
        }
}

/* finish() on four lanes: the same operations in the same order, lane by lane, with branches
 * made blends. A lane whose U needs its rank-deficient fallback for the second column
 * (any_orthogonal) is left to the scalar finish: the result is that lane's mask (bit l). */
__attribute__((target("avx2"), always_inline)) static inline __m256d blend(__m256d a, __m256d b,
                                                                           __m256d m)
{
    return _mm256_blendv_pd(a, b, m);
}

__attribute__((target("avx2"))) static int finish4(const double *const F[4], double *const A[4],
                                                   double *const W[4], double *const U[4],
                                                   double *const S[4], double *const V[4])
{
#define LANE_LOAD(P, i) _mm256_set_pd((P)[3][i], (P)[2][i], (P)[1][i], (P)[0][i])
    const __m256d zero = _mm256_setzero_pd(), sign = _mm256_set1_pd(-0.0),
                  one = _mm256_set1_pd(1.0);
    __m256d lam[3] = {LANE_LOAD(A, 0), LANE_LOAD(A, 4), LANE_LOAD(A, 8)}, v[9], f[9], B[9];
    for (int i = 0; i < 9; i++) {
        v[i] = LANE_LOAD(W, i);
        f[i] = LANE_LOAD(F, i);
    }
#undef LANE_LOAD
    for (int i = 0; i < 2; i++) /* sort, decreasing */
        for (int j = 0; j < 2 - i; j++) {
            __m256d m = _mm256_cmp_pd(lam[j], lam[j + 1], _CMP_LT_OQ), lo = lam[j];
            lam[j] = blend(lo, lam[j + 1], m);
            lam[j + 1] = blend(lam[j + 1], lo, m);
            for (int r = 0; r < 3; r++) {
                __m256d t = v[3 * r + j];
                v[3 * r + j] = blend(t, v[3 * r + j + 1], m);
                v[3 * r + j + 1] = blend(v[3 * r + j + 1], t, m);
            }
        }
#define MUL _mm256_mul_pd
#define ADD _mm256_add_pd
#define SUB _mm256_sub_pd
    __m256d det = ADD(SUB(MUL(v[0], SUB(MUL(v[4], v[8]), MUL(v[5], v[7]))),
                          MUL(v[1], SUB(MUL(v[3], v[8]), MUL(v[5], v[6])))),
                      MUL(v[2], SUB(MUL(v[3], v[7]), MUL(v[4], v[6]))));
    __m256d flip = _mm256_cmp_pd(det, zero, _CMP_LT_OQ);
    for (int r = 0; r < 3; r++)
        v[3 * r + 2] = blend(v[3 * r + 2], _mm256_xor_pd(v[3 * r + 2], sign), flip);
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            B[3 * i + j] = ADD(ADD(MUL(f[3 * i + 0], v[0 + j]), MUL(f[3 * i + 1], v[3 + j])),
                               MUL(f[3 * i + 2], v[6 + j]));
    __m256d u0[3] = {B[0], B[3], B[6]}, u1[3] = {B[1], B[4], B[7]}, u2[3];
    __m256d scale = ADD(_mm256_sqrt_pd(_mm256_andnot_pd(sign, lam[0])), _mm256_set1_pd(1e-300));
    __m256d n0 = _mm256_sqrt_pd(ADD(ADD(MUL(u0[0], u0[0]), MUL(u0[1], u0[1])), MUL(u0[2], u0[2])));
    __m256d deg0 = _mm256_or_pd(_mm256_cmp_pd(n0, MUL(_mm256_set1_pd(1e-14), scale), _CMP_LE_OQ),
                                _mm256_cmp_pd(n0, zero, _CMP_EQ_OQ));
    for (int i = 0; i < 3; i++)
        u0[i] = blend(_mm256_div_pd(u0[i], n0), i == 0 ? one : zero, deg0);
    __m256d d = ADD(ADD(MUL(u1[0], u0[0]), MUL(u1[1], u0[1])), MUL(u1[2], u0[2]));
    for (int i = 0; i < 3; i++)
        u1[i] = SUB(u1[i], MUL(d, u0[i]));
    __m256d n1 = _mm256_sqrt_pd(ADD(ADD(MUL(u1[0], u1[0]), MUL(u1[1], u1[1])), MUL(u1[2], u1[2])));
    __m256d deg1 = _mm256_or_pd(_mm256_cmp_pd(n1, MUL(_mm256_set1_pd(1e-12), scale), _CMP_LE_OQ),
                                _mm256_cmp_pd(n1, zero, _CMP_EQ_OQ));
    for (int i = 0; i < 3; i++)
        u1[i] = _mm256_div_pd(u1[i], n1);
    u2[0] = SUB(MUL(u0[1], u1[2]), MUL(u0[2], u1[1]));
    u2[1] = SUB(MUL(u0[2], u1[0]), MUL(u0[0], u1[2]));
    u2[2] = SUB(MUL(u0[0], u1[1]), MUL(u0[1], u1[0]));
    __m256d sv[3] = {ADD(ADD(MUL(u0[0], B[0]), MUL(u0[1], B[3])), MUL(u0[2], B[6])),
                     ADD(ADD(MUL(u1[0], B[1]), MUL(u1[1], B[4])), MUL(u1[2], B[7])),
                     ADD(ADD(MUL(u2[0], B[2]), MUL(u2[1], B[5])), MUL(u2[2], B[8]))};
#undef MUL
#undef ADD
#undef SUB
    double t[4];
    for (int r = 0; r < 3; r++) {
        const __m256d *col[3] = {u0, u1, u2};
        for (int c = 0; c < 3; c++) {
            _mm256_storeu_pd(t, col[c][r]);
            for (int l = 0; l < 4; l++)
                U[l][3 * r + c] = t[l];
        }
        _mm256_storeu_pd(t, sv[r]);
        for (int l = 0; l < 4; l++)
            S[l][r] = t[l];
    }
    for (int i = 0; i < 9; i++) {
        _mm256_storeu_pd(t, v[i]);
        for (int l = 0; l < 4; l++)
            V[l][i] = t[l];
    }
    return _mm256_movemask_pd(deg1);
}
#endif

void ns_svd3_n(int n, const double *const F[], double *const U[], double *const s[],
               double *const V[])
{
#ifdef NS_SVD3_LANES
    if (__builtin_cpu_supports("avx2")) {
        static const double I[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
        for (int k = 0; k < n; k += LANES) {
            int m = n - k < LANES ? n - k : LANES;
            /* Lanes beyond m decompose the identity into scratch. */
            double A[LANES][9], W[LANES][9], scratch[LANES][21];
            double *Ap[LANES], *Wp[LANES], *Ul[LANES], *sl[LANES], *Vl[LANES];
            const double *Fl[LANES];
            for (int l = 0; l < LANES; l++) {
                Fl[l] = l < m ? F[k + l] : I;
                Ul[l] = l < m ? U[k + l] : scratch[l];
                sl[l] = l < m ? s[k + l] : scratch[l] + 9;
                Vl[l] = l < m ? V[k + l] : scratch[l] + 12;
                gram(Fl[l], A[l]);
                Ap[l] = A[l];
                Wp[l] = W[l];
            }
            sym3_eigen_lanes(Ap, Wp);
            for (int g = 0; g < G; g++) {
                int l0 = 4 * g;
                int rest = finish4(Fl + l0, Ap + l0, Wp + l0, Ul + l0, sl + l0, Vl + l0);
                for (int l = l0; l < l0 + 4 && l < m; l++)
                    if (rest & (1 << (l - l0))) { /* U's rank-deficient fallback, scalar */
                        memcpy(V[k + l], W[l], sizeof W[l]);
                        finish(F[k + l], A[l], U[k + l], s[k + l], V[k + l]);
                    }
            }
        }
        return;
    }
#endif
    for (int k = 0; k < n; k++)
        ns_svd3(F[k], U[k], s[k], V[k]);
}
