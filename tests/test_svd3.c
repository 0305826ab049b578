/* Tests for sim/svd3.c: reconstruction, proper rotations, ordering and the inversion-safe sign
 * on random, reflected and near-degenerate matrices. */
#include "svd3.h"
#include "ns_test.h"

#include <stdint.h>
#include <stdio.h>
#include <string.h>

static double det3(const double *M)
{
    return M[0] * (M[4] * M[8] - M[5] * M[7]) - M[1] * (M[3] * M[8] - M[5] * M[6]) +
           M[2] * (M[3] * M[7] - M[4] * M[6]);
}

/* Checks every property of one decomposition; returns 0 or 1 (with a message). */
static int check(const double F[9], double rel_tol)
{
    double U[9], s[3], V[9];
    ns_svd3(F, U, s, V);
    double fnorm = 0.0;
    for (int i = 0; i < 9; i++)
        fnorm += F[i] * F[i];
    fnorm = sqrt(fnorm);
    double scale = fnorm > 0 ? fnorm : 1.0;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            double r = 0.0;
            for (int k = 0; k < 3; k++)
                r += U[3 * i + k] * s[k] * V[3 * j + k];
            ENSURE_SMALL((r - F[3 * i + j]) / scale, rel_tol);
            double uu = 0.0, vv = 0.0;
            for (int k = 0; k < 3; k++) {
                uu += U[3 * k + i] * U[3 * k + j];
                vv += V[3 * k + i] * V[3 * k + j];
            }
            ENSURE_SMALL(uu - (i == j), 1e-12);
            ENSURE_SMALL(vv - (i == j), 1e-12);
        }
    ENSURE_SMALL(det3(U) - 1.0, 1e-12);
    ENSURE_SMALL(det3(V) - 1.0, 1e-12);
    ENSURE(s[0] >= s[1] - 1e-12 * scale);
    ENSURE(s[1] >= fabs(s[2]) - 1e-12 * scale);
    ENSURE(s[1] >= 0.0);
    double d = det3(F);
    if (fabs(d) > 1e-9 * scale * scale * scale)
        ENSURE((d < 0) == (s[2] < 0));
    return 0;
}

static double rnd(uint64_t *st)
{
    *st = *st * 6364136223846793005ull + 1442695040888963407ull;
    return (double)(*st >> 11) / 9007199254740992.0 * 2.0 - 1.0;
}

static int random_matrices(void)
{
    uint64_t st = 7;
    for (int n = 0; n < 20000; n++) {
        double F[9];
        for (int i = 0; i < 9; i++)
            F[i] = rnd(&st);
        if (check(F, 1e-12))
            return 1;
    }
    return 0;
}

static int reflections(void)
{
    double R[9] = {1, 0, 0, 0, 1, 0, 0, 0, -1};
    double U[9], s[3], V[9];
    ns_svd3(R, U, s, V);
    ENSURE_SMALL(s[0] - 1, 1e-14);
    ENSURE_SMALL(s[1] - 1, 1e-14);
    ENSURE_SMALL(s[2] + 1, 1e-14);
    ENSURE(check(R, 1e-13) == 0);
    /* An inverted element: a rotation composed with a reflection and a stretch. */
    double c = cos(0.7), sn = sin(0.7);
    double F[9] = {2 * c, -sn, 0, 2 * sn, c, 0, 0, 0, -0.5};
    ns_svd3(F, U, s, V);
    ENSURE_SMALL(s[0] - 2, 1e-13);
    ENSURE_SMALL(s[1] - 1, 1e-13);
    ENSURE_SMALL(s[2] + 0.5, 1e-13);
    ENSURE(check(F, 1e-13) == 0);
    /* Point reflection -I: det -1, singular values (1, 1, -1). */
    double M[9] = {-1, 0, 0, 0, -1, 0, 0, 0, -1};
    ns_svd3(M, U, s, V);
    ENSURE_SMALL(s[2] + 1, 1e-14);
    ENSURE(check(M, 1e-13) == 0);
    return 0;
}

static int near_degenerate(void)
{
    double zero[9] = {0};
    ENSURE(check(zero, 1e-14) == 0);
    double I[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    ENSURE(check(I, 1e-14) == 0);
    /* Rank 2 (a flattened element), rank 1 (collapsed to a line), and nearly flat. */
    double flat[9] = {1, 0.3, 0, 0.2, 1, 0, 0, 0, 0};
    ENSURE(check(flat, 1e-13) == 0);
    double line[9] = {1, 2, 3, 0.5, 1, 1.5, -1, -2, -3};
    ENSURE(check(line, 1e-13) == 0);
    uint64_t st = 99;
    for (int n = 0; n < 2000; n++) {
        /* Random rotation-ish matrix times diag(1, a, eps) with tiny eps of either sign. */
        double a = 0.5 + 0.5 * fabs(rnd(&st)), eps = 1e-10 * rnd(&st);
        double th = 3.0 * rnd(&st), ph = 3.0 * rnd(&st);
        double Rz[9] = {cos(th), -sin(th), 0, sin(th), cos(th), 0, 0, 0, 1};
        double Rx[9] = {1, 0, 0, 0, cos(ph), -sin(ph), 0, sin(ph), cos(ph)};
        double D[3] = {1, a, eps}, F[9];
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) {
                double v = 0;
                for (int k = 0; k < 3; k++)
                    v += Rz[3 * i + k] * Rx[3 * k + j];
                F[3 * i + j] = v * D[j];
            }
        if (check(F, 1e-12))
            return 1;
    }
    /* Repeated singular values: a scaled rotation. */
    double c = cos(1.1), sn = sin(1.1);
    double rot[9] = {3 * c, 0, 3 * sn, 0, 3, 0, -3 * sn, 0, 3 * c};
    ENSURE(check(rot, 1e-13) == 0);
    return 0;
}

/* ns_svd3_n gives ns_svd3's bits for every matrix of a batch, whatever its lane: random
 * matrices at scales from 1e-8 to 1e16 (a sliver's Jacobian entries reach ~1e17), rank-deficient,
 * reflected, diagonal (no rotation at all), and non-finite ones, in batches of 1 to 9. */
static int batch_matches_single(void)
{
    enum { COUNT = 4000 };
    static double F[COUNT][9], U[COUNT][9], s[COUNT][3], V[COUNT][9];
    uint64_t st = 2024;
    for (int n = 0; n < COUNT; n++) {
        double scale = pow(10.0, -8.0 + 24.0 * (0.5 + 0.5 * rnd(&st)));
        for (int i = 0; i < 9; i++)
            F[n][i] = scale * rnd(&st);
        switch (n % 13) {
        case 1: /* rank 1 */
            for (int i = 0; i < 3; i++)
                F[n][3 * i + 1] = 2.0 * F[n][3 * i], F[n][3 * i + 2] = -F[n][3 * i];
            break;
        case 2: /* diagonal: nothing to rotate */
            for (int i = 0; i < 9; i++)
                F[n][i] = i % 4 ? 0.0 : F[n][i];
            break;
        case 3: /* nearly the identity, as most tets at rest */
            for (int i = 0; i < 9; i++)
                F[n][i] = (i % 4 == 0) + 1e-9 * F[n][i] / scale;
            break;
        case 4:
            memset(F[n], 0, sizeof F[n]);
            break;
        case 5:
            F[n][4] = NAN;
            break;
        case 6:
            F[n][7] = INFINITY;
            break;
        default:
            break;
        }
    }
    int done = 0;
    for (int batch = 1; done < COUNT; batch = batch % 9 + 1) {
        int m = COUNT - done < batch ? COUNT - done : batch;
        const double *Fp[9];
        double *Up[9], *sp[9], *Vp[9];
        for (int k = 0; k < m; k++) {
            Fp[k] = F[done + k];
            Up[k] = U[done + k];
            sp[k] = s[done + k];
            Vp[k] = V[done + k];
        }
        ns_svd3_n(m, Fp, Up, sp, Vp);
        done += m;
    }
    for (int n = 0; n < COUNT; n++) {
        double U1[9], s1[3], V1[9];
        ns_svd3(F[n], U1, s1, V1);
        if (!ns_same_bits(U1, U[n], 9) || !ns_same_bits(s1, s[n], 3) ||
            !ns_same_bits(V1, V[n], 9)) {
            fprintf(stderr, "matrix %d: the batch's decomposition differs from ns_svd3's\n", n);
            return 1;
        }
    }
    return 0;
}

NS_TEST_MAIN({"random_matrices", random_matrices}, {"reflections", reflections},
             {"near_degenerate", near_degenerate}, {"batch_matches_single", batch_matches_single})
