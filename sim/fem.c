/* Invertible FEM for one tetrahedron (paper §3.2 after Irving, Teran & Fedkiw 2004).
 *
 * F = Ds Bm, F = U diag(s) V^T (inversion-safe SVD), P = U P^(s) V^T with the model's stress
 * P^ evaluated on the diagonal, forces f_a = -W P g_a where g_a are the rest shape gradients
 * (rows of Bm; g_0 = -(g_1 + g_2 + g_3)). The Jacobians hold U and V fixed (§3.2): in the
 * rotated frame a perturbation dF^ = U^T dF V maps to dP^ through a 3x3 block on the diagonal
 * entries and a 2x2 block on each off-diagonal pair (F^_ij, F^_ji) (Teran et al. 2005), which is
 * also where the neo-Hookean tangent is made definite. */
#include "fem.h"

#include <math.h>
#include <string.h>

#include "mutate.h"
#include "svd3.h"

NsFemMaterial ns_fem_material(NsElasticModel model, double youngs, double poisson, double damp_mu,
                              double damp_lambda)
{
    NsFemMaterial m;
    m.model = model;
    youngs = NS_MUTATE("youngs", youngs);
    m.mu = youngs / (2.0 * (1.0 + poisson));
    m.lambda = youngs * poisson / ((1.0 + poisson) * (1.0 - 2.0 * poisson));
    m.damp_mu = damp_mu;
    m.damp_lambda = damp_lambda;
    return m;
}

static double det3(const double *M)
{
    return M[0] * (M[4] * M[8] - M[5] * M[7]) - M[1] * (M[3] * M[8] - M[5] * M[6]) +
           M[2] * (M[3] * M[7] - M[4] * M[6]);
}

int ns_fem_rest(const double *u0, const double *u1, const double *u2, const double *u3,
                NsTetRest *out)
{
    double Dm[9];
    for (int i = 0; i < 3; i++) {
        Dm[3 * i + 0] = u1[i] - u0[i];
        Dm[3 * i + 1] = u2[i] - u0[i];
        Dm[3 * i + 2] = u3[i] - u0[i];
    }
    double d = det3(Dm);
    out->W = d / 6.0;
    if (!(d > 0.0))
        return -1;
    double *B = out->Bm;
    B[0] = (Dm[4] * Dm[8] - Dm[5] * Dm[7]) / d;
    B[1] = (Dm[2] * Dm[7] - Dm[1] * Dm[8]) / d;
    B[2] = (Dm[1] * Dm[5] - Dm[2] * Dm[4]) / d;
    B[3] = (Dm[5] * Dm[6] - Dm[3] * Dm[8]) / d;
    B[4] = (Dm[0] * Dm[8] - Dm[2] * Dm[6]) / d;
    B[5] = (Dm[2] * Dm[3] - Dm[0] * Dm[5]) / d;
    B[6] = (Dm[3] * Dm[7] - Dm[4] * Dm[6]) / d;
    B[7] = (Dm[1] * Dm[6] - Dm[0] * Dm[7]) / d;
    B[8] = (Dm[0] * Dm[4] - Dm[1] * Dm[3]) / d;
    return 0;
}

/* Rest shape gradients g (4 x 3): F = sum_a x_a g_a^T. */
static void shape_gradients(const NsTetRest *r, double g[12])
{
    for (int k = 0; k < 3; k++) {
        g[3 + k] = r->Bm[0 + k];
        g[6 + k] = r->Bm[3 + k];
        g[9 + k] = r->Bm[6 + k];
        g[k] = -(g[3 + k] + g[6 + k] + g[9 + k]);
    }
}

/* M = sum_a y_a g_a^T for four vectors y (F from positions, dF/dt from velocities). */
static void gradient_of(const double g[12], const double *const y[4], double M[9])
{
    memset(M, 0, 9 * sizeof(double));
    for (int a = 0; a < 4; a++)
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                M[3 * i + j] += y[a][i] * g[3 * a + j];
}

/* out = A^T M B (all 3x3 row-major). */
static void rot_in(const double *A, const double *M, const double *B, double *out)
{
    double T[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            T[3 * i + j] =
                M[3 * i + 0] * B[0 + j] + M[3 * i + 1] * B[3 + j] + M[3 * i + 2] * B[6 + j];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            out[3 * i + j] = A[0 + i] * T[0 + j] + A[3 + i] * T[3 + j] + A[6 + i] * T[6 + j];
}

/* out = A M B^T. */
static void rot_out(const double *A, const double *M, const double *B, double *out)
{
    double T[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            T[3 * i + j] = M[3 * i + 0] * B[3 * j + 0] + M[3 * i + 1] * B[3 * j + 1] +
                           M[3 * i + 2] * B[3 * j + 2];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            out[3 * i + j] =
                A[3 * i + 0] * T[0 + j] + A[3 * i + 1] * T[3 + j] + A[3 * i + 2] * T[6 + j];
}

/* Diagonal stress P^(s) of the model, with Irving's linear extrapolation of the neo-Hookean
 * stress below NS_FEM_NEOHOOKEAN_S_MIN (it has a log J that is undefined when inverted). */
static void diag_stress(const NsFemMaterial *m, const double s[3], double P[3])
{
    if (m->model == NS_MODEL_COROTATIONAL) {
        double tr = s[0] + s[1] + s[2] - 3.0;
        for (int i = 0; i < 3; i++)
            P[i] = 2.0 * m->mu * (s[i] - 1.0) + m->lambda * tr;
        return;
    }
    double c[3];
    for (int i = 0; i < 3; i++)
        c[i] = s[i] > NS_FEM_NEOHOOKEAN_S_MIN ? s[i] : NS_FEM_NEOHOOKEAN_S_MIN;
    double lj = log(c[0] * c[1] * c[2]);
    for (int i = 0; i < 3; i++) {
        P[i] = m->mu * (c[i] - 1.0 / c[i]) + m->lambda * lj / c[i];
        if (c[i] != s[i]) { /* first-order extrapolation along s_i */
            double dP =
                m->mu * (1.0 + 1.0 / (c[i] * c[i])) + m->lambda * (1.0 - lj) / (c[i] * c[i]);
            P[i] += dP * (s[i] - c[i]);
        }
    }
}

/* Tangent of the stress in the rotated frame: dP^_ii = sum_k A_ik dF^_kk and
 * dP^_ij = a_ij dF^_ij + b_ij dF^_ji for the pairs (0,1), (0,2), (1,2). */
typedef struct Tangent {
    double A[9];
    double a[3], b[3];
} Tangent;

static const int pair_ij[3][2] = {{0, 1}, {0, 2}, {1, 2}};

static void elastic_tangent(const NsFemMaterial *m, const double s[3], Tangent *t)
{
    if (m->model == NS_MODEL_COROTATIONAL) {
        /* dP^ = mu (dF^ + dF^T) + lambda tr(dF^) I */
        for (int i = 0; i < 3; i++)
            for (int k = 0; k < 3; k++)
                t->A[3 * i + k] = m->lambda + (i == k ? 2.0 * m->mu : 0.0);
        for (int p = 0; p < 3; p++)
            t->a[p] = t->b[p] = m->mu;
        return;
    }
    /* Neo-Hookean, P = mu (F - F^-T) + lambda log J F^-T, differentiated at F^ = diag(c):
     * A_ik = (mu + (mu - lambda log J) / c_i^2) delta_ik + lambda / (c_i c_k),
     * a_ij = mu, b_ij = (mu - lambda log J) / (c_i c_j). */
    double c[3];
    for (int i = 0; i < 3; i++)
        c[i] = s[i] > NS_FEM_NEOHOOKEAN_S_MIN ? s[i] : NS_FEM_NEOHOOKEAN_S_MIN;
    double lj = log(c[0] * c[1] * c[2]);
    double q = m->mu - m->lambda * lj;
    for (int i = 0; i < 3; i++)
        for (int k = 0; k < 3; k++)
            t->A[3 * i + k] =
                m->lambda / (c[i] * c[k]) + (i == k ? m->mu + q / (c[i] * c[i]) : 0.0);
    for (int p = 0; p < 3; p++) {
        t->a[p] = m->mu;
        t->b[p] = q / (c[pair_ij[p][0]] * c[pair_ij[p][1]]);
    }
}

/* Clamp the eigenvalues of the symmetric 3x3 A at zero. */
static void project_psd3(double A[9])
{
    double V[9], M[9];
    memcpy(M, A, sizeof M);
    ns_sym3_eigen(M, V);
    double lam[3] = {M[0] > 0 ? M[0] : 0, M[4] > 0 ? M[4] : 0, M[8] > 0 ? M[8] : 0};
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            A[3 * i + j] = V[3 * i + 0] * lam[0] * V[3 * j + 0] +
                           V[3 * i + 1] * lam[1] * V[3 * j + 1] +
                           V[3 * i + 2] * lam[2] * V[3 * j + 2];
}

static void project_tangent(Tangent *t)
{
    project_psd3(t->A);
    for (int p = 0; p < 3; p++) {
        /* [[a, b], [b, a]] has eigenvalues a + b and a - b on (1, 1) and (1, -1). */
        double l1 = t->a[p] + t->b[p], l2 = t->a[p] - t->b[p];
        l1 = l1 > 0 ? l1 : 0;
        l2 = l2 > 0 ? l2 : 0;
        t->a[p] = 0.5 * (l1 + l2);
        t->b[p] = 0.5 * (l1 - l2);
    }
}

static void apply_tangent(const Tangent *t, const double dF[9], double dP[9])
{
    for (int i = 0; i < 3; i++)
        dP[4 * i] = t->A[3 * i + 0] * dF[0] + t->A[3 * i + 1] * dF[4] + t->A[3 * i + 2] * dF[8];
    for (int p = 0; p < 3; p++) {
        int i = pair_ij[p][0], j = pair_ij[p][1];
        dP[3 * i + j] = t->a[p] * dF[3 * i + j] + t->b[p] * dF[3 * j + i];
        dP[3 * j + i] = t->a[p] * dF[3 * j + i] + t->b[p] * dF[3 * i + j];
    }
}

/* Damping stress in the rotated frame: P^d = dmu (dF^ + dF^T) + dlambda tr(dF^) I. */
static void damping_tangent(const NsFemMaterial *m, Tangent *t)
{
    for (int i = 0; i < 3; i++)
        for (int k = 0; k < 3; k++)
            t->A[3 * i + k] = m->damp_lambda + (i == k ? 2.0 * m->damp_mu : 0.0);
    for (int p = 0; p < 3; p++)
        t->a[p] = t->b[p] = m->damp_mu;
}

/* f_a -= W P g_a */
static void add_forces(const NsTetRest *r, const double g[12], const double P[9], double f[12])
{
    for (int a = 0; a < 4; a++)
        for (int i = 0; i < 3; i++)
            f[3 * a + i] -= r->W * (P[3 * i + 0] * g[3 * a + 0] + P[3 * i + 1] * g[3 * a + 1] +
                                    P[3 * i + 2] * g[3 * a + 2]);
}

/* Whether the material damps at all (damping_forces does nothing otherwise). */
static int has_damping(const NsFemMaterial *m)
{
    return !(m->damp_mu == 0.0 && m->damp_lambda == 0.0);
}

static void damping_forces(const NsTetRest *r, const NsFemMaterial *mat, const NsTetFrame *fr,
                           const double g[12], const double *const v[4], double f[12])
{
    if (!has_damping(mat))
        return;
    double Fd[9], Fdh[9], Pdh[9], Pd[9];
    gradient_of(g, v, Fd);
    rot_in(fr->U, Fd, fr->V, Fdh);
    Tangent t;
    damping_tangent(mat, &t);
    apply_tangent(&t, Fdh, Pdh);
    rot_out(fr->U, Pdh, fr->V, Pd);
    add_forces(r, g, Pd, f);
}

void ns_fem_tet_gradient(const NsTetRest *r, const double *const x[4], double F[9])
{
    double g[12];
    shape_gradients(r, g);
    gradient_of(g, x, F);
}

void ns_fem_tet_forces(const NsTetRest *r, const NsFemMaterial *mat, const double *const x[4],
                       const double *const v[4], double f[12], NsTetFrame *frame)
{
    double F[9];
    ns_fem_tet_gradient(r, x, F);
    ns_svd3(F, frame->U, frame->s, frame->V);
    ns_fem_tet_forces_svd(r, mat, v, f, frame);
}

void ns_fem_tet_forces_svd(const NsTetRest *r, const NsFemMaterial *mat, const double *const v[4],
                           double f[12], const NsTetFrame *frame)
{
    double g[12], Ph[9] = {0}, P[9], ps[3];
    shape_gradients(r, g);
    diag_stress(mat, frame->s, ps);
    Ph[0] = ps[0];
    Ph[4] = ps[1];
    Ph[8] = ps[2];
    rot_out(frame->U, Ph, frame->V, P);
    memset(f, 0, 12 * sizeof(double));
    add_forces(r, g, P, f);
    damping_forces(r, mat, frame, g, v, f);
}

/* Kernels that run several tets, or several columns, on vector lanes: with GCC on x86-64 also
 * built for AVX2 (four doubles a vector) and picked at load time. */
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) &&                             \
    !defined(__SANITIZE_ADDRESS__)
#define COLS_KERNEL __attribute__((target_clones("avx2", "default")))
#else
#define COLS_KERNEL
#endif

/* ---- ns_fem_tet_forces_svd for several tets at once ----
 * Four tets side by side (an entry of each in a row: [entry][lane]), every lane doing the scalar
 * code's operations above in their order, products with the zeros of a diagonal stress
 * included, so the compiler can run the lanes on vector registers and each lane keeps the bits of
 * a tet done alone. The model's diagonal stress (a logarithm for neo-Hookean) stays per tet. */
#define FL 4

/* The statement after it, once for each lane l. */
#define LANES_FOR for (int l = 0; l < FL; l++)

COLS_KERNEL static void forces_lanes(const NsTetRest *const r[FL], const NsFemMaterial *const m[FL],
                                     const double *const *const v[FL],
                                     const NsTetFrame *const fr[FL], const int damp[FL],
                                     double out[FL][12])
{
    double g[12][FL], U[9][FL], V[9][FL], W[FL], T[9][FL], P[9][FL], f[12][FL];
    LANES_FOR
    {
        for (int k = 0; k < 3; k++) {
            g[3 + k][l] = r[l]->Bm[0 + k];
            g[6 + k][l] = r[l]->Bm[3 + k];
            g[9 + k][l] = r[l]->Bm[6 + k];
        }
        for (int k = 0; k < 9; k++) {
            U[k][l] = fr[l]->U[k];
            V[k][l] = fr[l]->V[k];
        }
        W[l] = r[l]->W;
    }
    for (int k = 0; k < 3; k++)
        LANES_FOR g[k][l] = -(g[3 + k][l] + g[6 + k][l] + g[9 + k][l]);
    /* The elastic stress: P = U diag(ps) V^T, rot_out's products (zeros included). */
    double Ph[9][FL];
    LANES_FOR
    {
        double ps[3];
        diag_stress(m[l], fr[l]->s, ps);
        for (int k = 0; k < 9; k++)
            Ph[k][l] = 0.0;
        Ph[0][l] = ps[0];
        Ph[4][l] = ps[1];
        Ph[8][l] = ps[2];
    }
#define ROT_OUT(M, OUT)                                                                            \
    do {                                                                                           \
        for (int i = 0; i < 3; i++)                                                                \
            for (int j = 0; j < 3; j++)                                                            \
                LANES_FOR T[3 * i + j][l] = M[3 * i + 0][l] * V[3 * j + 0][l] +                    \
                                            M[3 * i + 1][l] * V[3 * j + 1][l] +                    \
                                            M[3 * i + 2][l] * V[3 * j + 2][l];                     \
        for (int i = 0; i < 3; i++)                                                                \
            for (int j = 0; j < 3; j++)                                                            \
                LANES_FOR OUT[3 * i + j][l] = U[3 * i + 0][l] * T[0 + j][l] +                      \
                                              U[3 * i + 1][l] * T[3 + j][l] +                      \
                                              U[3 * i + 2][l] * T[6 + j][l];                       \
    } while (0)
#define ADD_FORCES(M, MASK)                                                                        \
    do {                                                                                           \
        for (int a = 0; a < 4; a++)                                                                \
            for (int i = 0; i < 3; i++)                                                            \
                LANES_FOR                                                                          \
                {                                                                                  \
                    double d = f[3 * a + i][l] - W[l] * (M[3 * i + 0][l] * g[3 * a + 0][l] +       \
                                                         M[3 * i + 1][l] * g[3 * a + 1][l] +       \
                                                         M[3 * i + 2][l] * g[3 * a + 2][l]);       \
                    f[3 * a + i][l] = (MASK) ? d : f[3 * a + i][l];                                \
                }                                                                                  \
    } while (0)
    ROT_OUT(Ph, P);
    for (int k = 0; k < 12; k++)
        LANES_FOR f[k][l] = 0.0;
    ADD_FORCES(P, 1);
    /* Damping (damping_forces): dF/dt, rotated in, the damping tangent, rotated out. */
    int any = 0;
    LANES_FOR any |= damp[l];
    if (any) {
        double Fd[9][FL], Fdh[9][FL], Pdh[9][FL], Pd[9][FL], TA[9][FL], ta[3][FL], tb[3][FL];
        LANES_FOR
        {
            Tangent t;
            damping_tangent(m[l], &t);
            for (int k = 0; k < 9; k++)
                TA[k][l] = t.A[k];
            for (int p = 0; p < 3; p++) {
                ta[p][l] = t.a[p];
                tb[p][l] = t.b[p];
            }
        }
        for (int k = 0; k < 9; k++)
            LANES_FOR Fd[k][l] = 0.0;
        for (int a = 0; a < 4; a++)
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++)
                    LANES_FOR Fd[3 * i + j][l] += v[l][a][i] * g[3 * a + j][l];
        /* rot_in: T = Fd V, then U^T T */
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                LANES_FOR T[3 * i + j][l] = Fd[3 * i + 0][l] * V[0 + j][l] +
                                            Fd[3 * i + 1][l] * V[3 + j][l] +
                                            Fd[3 * i + 2][l] * V[6 + j][l];
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                LANES_FOR Fdh[3 * i + j][l] = U[0 + i][l] * T[0 + j][l] +
                                              U[3 + i][l] * T[3 + j][l] + U[6 + i][l] * T[6 + j][l];
        /* apply_tangent */
        for (int i = 0; i < 3; i++)
            LANES_FOR Pdh[4 * i][l] = TA[3 * i + 0][l] * Fdh[0][l] + TA[3 * i + 1][l] * Fdh[4][l] +
                                      TA[3 * i + 2][l] * Fdh[8][l];
        for (int p = 0; p < 3; p++) {
            int i = pair_ij[p][0], j = pair_ij[p][1];
            LANES_FOR
            {
                Pdh[3 * i + j][l] = ta[p][l] * Fdh[3 * i + j][l] + tb[p][l] * Fdh[3 * j + i][l];
                Pdh[3 * j + i][l] = ta[p][l] * Fdh[3 * j + i][l] + tb[p][l] * Fdh[3 * i + j][l];
            }
        }
        ROT_OUT(Pdh, Pd);
        ADD_FORCES(Pd, damp[l]);
    }
#undef ROT_OUT
#undef ADD_FORCES
    LANES_FOR for (int k = 0; k < 12; k++) out[l][k] = f[k][l];
}

void ns_fem_tet_forces_svd_n(int n, const NsTetRest *const r[], const NsFemMaterial *const mat[],
                             const double *const *const v[], double *const f[],
                             const NsTetFrame *const frame[])
{
    for (int k0 = 0; k0 < n; k0 += FL) {
        /* A short last group repeats its first tet in the spare lanes (their results dropped). */
        const NsTetRest *rl[FL];
        const NsFemMaterial *ml[FL];
        const double *const *vl[FL];
        const NsTetFrame *fl[FL];
        int damp[FL];
        double out[FL][12];
        for (int l = 0; l < FL; l++) {
            int k = k0 + l < n ? k0 + l : k0;
            rl[l] = r[k];
            ml[l] = mat[k];
            vl[l] = v[k];
            fl[l] = frame[k];
            damp[l] = has_damping(mat[k]);
        }
        forces_lanes(rl, ml, vl, fl, damp, out);
        for (int l = 0; l < FL && k0 + l < n; l++)
            memcpy(f[k0 + l], out[l], sizeof out[l]);
    }
}
#undef LANES_FOR
#undef FL

static void inverse3(const double *M, double *out)
{
    double d = det3(M);
    out[0] = (M[4] * M[8] - M[5] * M[7]) / d;
    out[1] = (M[2] * M[7] - M[1] * M[8]) / d;
    out[2] = (M[1] * M[5] - M[2] * M[4]) / d;
    out[3] = (M[5] * M[6] - M[3] * M[8]) / d;
    out[4] = (M[0] * M[8] - M[2] * M[6]) / d;
    out[5] = (M[2] * M[3] - M[0] * M[5]) / d;
    out[6] = (M[3] * M[7] - M[4] * M[6]) / d;
    out[7] = (M[1] * M[6] - M[0] * M[7]) / d;
    out[8] = (M[0] * M[4] - M[1] * M[3]) / d;
}

void ns_fem_tet_forces_fixed_frame(const NsTetRest *r, const NsFemMaterial *mat,
                                   const NsTetFrame *frame, const double *const x[4],
                                   const double *const v[4], double f[12])
{
    double g[12], F[9], Fh[9], Ph[9], P[9];
    shape_gradients(r, g);
    gradient_of(g, x, F);
    rot_in(frame->U, F, frame->V, Fh);
    if (mat->model == NS_MODEL_COROTATIONAL) {
        double tr = Fh[0] + Fh[4] + Fh[8] - 3.0;
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                Ph[3 * i + j] = mat->mu * (Fh[3 * i + j] + Fh[3 * j + i]) +
                                (i == j ? mat->lambda * tr - 2.0 * mat->mu : 0.0);
    } else {
        /* The full-matrix neo-Hookean stress (valid where det F^ > 0). */
        double Fi[9];
        inverse3(Fh, Fi);
        double lj = log(det3(Fh));
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                Ph[3 * i + j] =
                    mat->mu * (Fh[3 * i + j] - Fi[3 * j + i]) + mat->lambda * lj * Fi[3 * j + i];
    }
    rot_out(frame->U, Ph, frame->V, P);
    memset(f, 0, 12 * sizeof(double));
    add_forces(r, g, P, f);
    damping_forces(r, mat, frame, g, v, f);
}

/* The Jacobians' 12 columns side by side (structure of arrays: an entry of every column in a
 * row), so that the compiler runs the columns on vector lanes. Each column's arithmetic is that of
 * one column done alone, in the same order (no reassociation, no contraction), so the lanes give
 * the bits of a column at a time. With GCC on x86-64 also built for AVX2 (four columns a
 * vector) and picked at load time. */
#define NCOL 12

/* Column 3b + d's direction in the rotated frame: dF^ = (U^T e_d) (V^T g_b)^T, an entry a row. */
typedef struct Dirs {
    double dF[9][NCOL];
    double Vg[12]; /* V^T g_b */
} Dirs;

COLS_KERNEL static void directions(const NsTetFrame *fr, const double g[12], Dirs *o)
{
    for (int b = 0; b < 4; b++)
        for (int j = 0; j < 3; j++)
            o->Vg[3 * b + j] = fr->V[0 + j] * g[3 * b + 0] + fr->V[3 + j] * g[3 * b + 1] +
                               fr->V[6 + j] * g[3 * b + 2];
    double u[3][NCOL], vg[3][NCOL];
    for (int c = 0; c < NCOL; c++)
        for (int i = 0; i < 3; i++) {
            u[i][c] = fr->U[3 * (c % 3) + i];
            vg[i][c] = o->Vg[3 * (c / 3) + i];
        }
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            for (int c = 0; c < NCOL; c++)
                o->dF[3 * i + j][c] = u[i][c] * vg[j][c];
}

/* J (12 x 12) block (a, b) = -W U [tangent dF^] V^T g_a for the directions of column 3b + d
 * (the differential of f_a = -W P g_a): the tangent (apply_tangent's arithmetic), Y = U dP^,
 * then the contraction with V^T g_a, every step on all 12 columns at once. */
COLS_KERNEL static void assemble(const NsTetRest *r, const NsTetFrame *fr, const Dirs *dd,
                                 const Tangent *t, double J[144])
{
    double dP[9][NCOL], Y[9][NCOL];
    const double(*dF)[NCOL] = dd->dF;
    for (int i = 0; i < 3; i++)
        for (int c = 0; c < NCOL; c++)
            dP[4 * i][c] = t->A[3 * i + 0] * dF[0][c] + t->A[3 * i + 1] * dF[4][c] +
                           t->A[3 * i + 2] * dF[8][c];
    for (int p = 0; p < 3; p++) {
        int i = pair_ij[p][0], j = pair_ij[p][1];
        for (int c = 0; c < NCOL; c++) {
            dP[3 * i + j][c] = t->a[p] * dF[3 * i + j][c] + t->b[p] * dF[3 * j + i][c];
            dP[3 * j + i][c] = t->a[p] * dF[3 * j + i][c] + t->b[p] * dF[3 * i + j][c];
        }
    }
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            for (int c = 0; c < NCOL; c++)
                Y[3 * i + j][c] = fr->U[3 * i + 0] * dP[0 + j][c] +
                                  fr->U[3 * i + 1] * dP[3 + j][c] + fr->U[3 * i + 2] * dP[6 + j][c];
    const double mw = -r->W, *Vg = dd->Vg;
    for (int a = 0; a < 4; a++)
        for (int i = 0; i < 3; i++)
            for (int c = 0; c < NCOL; c++)
                J[12 * (3 * a + i) + c] =
                    mw * (Y[3 * i + 0][c] * Vg[3 * a + 0] + Y[3 * i + 1][c] * Vg[3 * a + 1] +
                          Y[3 * i + 2][c] * Vg[3 * a + 2]);
}

void ns_fem_tet_jacobians(const NsTetRest *r, const NsFemMaterial *mat, const NsTetFrame *frame,
                          int project, double K[144], double D[144])
{
    double g[12];
    shape_gradients(r, g);
    Dirs dd;
    directions(frame, g, &dd); /* the same for K and D */
    Tangent t;
    if (K) {
        elastic_tangent(mat, frame->s, &t);
        if (project)
            project_tangent(&t);
        assemble(r, frame, &dd, &t, K);
    }
    if (D) {
        damping_tangent(mat, &t);
        assemble(r, frame, &dd, &t, D);
    }
}

/* h_b = R g_b for the four shape-function gradients. */
static void rotate_gradients(const double R[9], const double g[12], double h[12])
{
    for (int b = 0; b < 4; b++)
        for (int i = 0; i < 3; i++)
            h[3 * b + i] = R[3 * i + 0] * g[3 * b + 0] + R[3 * i + 1] * g[3 * b + 1] +
                           R[3 * i + 2] * g[3 * b + 2];
}

void ns_fem_corot_row(const NsTetRest *r, const NsFemMaterial *mat, const double R[9],
                      const double *R_old, int a, double *const kb[4], double *const db[4])
{
    double g[12], h[12], o[12];
    shape_gradients(r, g);
    rotate_gradients(R, g, h);
    if (R_old)
        rotate_gradients(R_old, g, o);
    const double mw = -r->W, *ha = h + 3 * a, *oa = o + 3 * a, *ga = g + 3 * a;
    for (int b = 0; b < 4; b++) {
        /* P = h_b h_a^T (minus the old one): block (a, b) of K is -W [mu (g_a . g_b) I +
         * mu P + lambda P^T] (§3.2: dP = mu (dF + R dF^T R) + lambda tr(R^T dF) R), of D the
         * same with the damping coefficients; the identity term does not change with R. */
        const double *hb = h + 3 * b, *ob = o + 3 * b, *gb = g + 3 * b;
        double P[9];
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                P[3 * i + j] = R_old ? hb[i] * ha[j] - ob[i] * oa[j] : hb[i] * ha[j];
        double gg = R_old ? 0.0 : ga[0] * gb[0] + ga[1] * gb[1] + ga[2] * gb[2];
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) {
                double d = i == j ? gg : 0.0;
                kb[b][3 * i + j] +=
                    mw * (mat->mu * (P[3 * i + j] + d) + mat->lambda * P[3 * j + i]);
                db[b][3 * i + j] +=
                    mw * (mat->damp_mu * (P[3 * i + j] + d) + mat->damp_lambda * P[3 * j + i]);
            }
    }
}

double ns_fem_tet_energy(const NsTetRest *r, const NsFemMaterial *mat, const double *const x[4])
{
    double g[12], F[9], U[9], V[9], s[3];
    shape_gradients(r, g);
    gradient_of(g, x, F);
    ns_svd3(F, U, s, V);
    if (mat->model == NS_MODEL_COROTATIONAL) {
        double tr = s[0] + s[1] + s[2] - 3.0, e = 0.0;
        for (int i = 0; i < 3; i++)
            e += (s[i] - 1.0) * (s[i] - 1.0);
        return r->W * (mat->mu * e + 0.5 * mat->lambda * tr * tr);
    }
    double lj = log(s[0] * s[1] * s[2]);
    return r->W * (0.5 * mat->mu * (s[0] * s[0] + s[1] * s[1] + s[2] * s[2] - 3.0) - mat->mu * lj +
                   0.5 * mat->lambda * lj * lj);
}
