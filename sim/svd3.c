/* Inversion-safe 3x3 SVD (Irving et al. 2004, §3.2 of the paper).
 *
 * V and the squared singular values come from a cyclic Jacobi eigen-solve of the symmetric
 * F^T F, which converges quadratically and is unconditionally stable. U follows column by
 * column from F V, with Gram-Schmidt so that rank-deficient F (flat or collapsed elements)
 * still gives an orthonormal U; its last column is the cross product of the first two, which
 * makes det U = +1 and leaves the sign of the last singular value to carry det F. */
#include "svd3.h"

#include <math.h>

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

void ns_svd3(const double F[9], double U[9], double s[3], double V[9])
{
    double A[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            A[3 * i + j] = F[i] * F[j] + F[3 + i] * F[3 + j] + F[6 + i] * F[6 + j];
    ns_sym3_eigen(A, V);
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
