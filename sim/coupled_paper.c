/* The paper's linear solver for the coupled system (§3.6.1-3.6.2): conjugate gradients directly
 * on the symmetric indefinite system Eq. 7,
 *
 *   [ A_t   0     W_t R' ] [ a_t ]   [ b_t - W_t g ]
 *   [ 0     A_n  -W_n R' ] [ a_n ] = [ b_n + W_n g ]
 *   [ (W_t R')^T -(W_n R')^T  Z ] [ c ]   [ e ]
 *
 * where R' is the local frames with the tangent column zeroed at DYNAMIC nodes, Z is 1 on those
 * tangents' rows and 0 elsewhere, and g the known dynamic friction (on the needle). The tissue
 * and needle blocks are multiplied as stored (block CSR and band); the constraint rows and
 * columns are applied node by node, never assembled, so a new friction configuration changes no
 * matrix. The solve is warm-started from the previous trial's solution. Fixed DOFs (tissue
 * Dirichlet nodes, the needle's held nodes) keep their values.
 *
 * Scaling: the constraint unknowns are c = kappa c' and the constraint rows are multiplied by
 * kappa, the mean diagonal of A_t at the coupled nodes, which keeps the matrix symmetric and its
 * blocks of one magnitude (in SI units the tissue's diagonal is ~1e-2 and the constraint
 * entries 1; unscaled, CG stalls). The paper does not say how it scaled; its units differ. */
#include "coupling_internal.h"
#include "ns_config.h"
#include "vec.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Columns of R' for node k in state s: the tangent dropped when DYNAMIC. */
static int col_active(int s, int col)
{
    return col > 0 || s == NS_FRICTION_STATIC;
}

static void apply(const CoupledSystem *S, double kappa, const double *z, double *out)
{
    const double *zt = z, *zr = z + S->nt3, *zc = zr + S->nr3;
    double *ot = out, *orr = out + S->nt3, *oc = orr + S->nr3;
    ns_bsm_mul_threads(S->At, zt, ot, S->threads);
    ns_banded_mul(S->Ar, zr, orr);
    for (int k = 0; k < S->q; k++) {
        const double *R = S->R + 9 * k;
        double g[3] = {0, 0, 0}, pt[3];
        for (int col = 0; col < 3; col++)
            if (col_active(S->st[k], col))
                for (int i = 0; i < 3; i++)
                    g[i] += R[3 * col + i] * kappa * zc[3 * k + col];
        double w = S->tw[k];
        for (int i = 0; i < 3; i++) {
            ot[3 * S->ta[k] + i] += (1.0 - w) * g[i];
            ot[3 * S->tb[k] + i] += w * g[i];
            orr[3 * S->idx[k] + i] -= g[i];
        }
        coupled_point(S, k, zt, pt);
        for (int i = 0; i < 3; i++)
            pt[i] -= zr[3 * S->idx[k] + i];
        for (int col = 0; col < 3; col++)
            oc[3 * k + col] =
                col_active(S->st[k], col)
                    ? kappa * (R[3 * col] * pt[0] + R[3 * col + 1] * pt[1] + R[3 * col + 2] * pt[2])
                    : zc[3 * k + col]; /* Z's 1 */
    }
}

/* The vectors of the CG iteration (§3.6.2; scaled), and the step's scalar s (alpha, then beta). */
typedef struct CgVecs {
    double *x, *r, *p, *qv, *tmp;
    const double *sc, *keep;
    double s;
    int op; /* the CgPass under way */
} CgVecs;

typedef enum CgPass {
    CG_PRODUCT,   /* qv = sc (A sc p) on the free rows, 0 on the fixed; returns p.qv */
    CG_STEP,      /* x += alpha p, r -= alpha qv; returns r.r */
    CG_DIRECTION, /* p = r + beta p, and tmp = sc p for the next product */
} CgPass;

/* One part [i0, i1) of pass v->op; its sum in four partial sums as ns_vec_dot's. */
static void cg_part(void *ctx, int i0, int i1, double sums[2])
{
    const CgVecs *v = ctx;
    double s4[4] = {0.0, 0.0, 0.0, 0.0}, a = v->s, sum = 0.0;
    double *restrict x = v->x, *restrict r = v->r, *restrict p = v->p, *restrict qv = v->qv,
                     *restrict tmp = v->tmp;
    const double *sc = v->sc, *keep = v->keep;
    int i = i0;
    if (v->op == CG_PRODUCT) {
        for (; i + 4 <= i1; i += 4)
            for (int l = 0; l < 4; l++) {
                double q = keep[i + l] != 0.0 ? qv[i + l] * sc[i + l] : 0.0;
                qv[i + l] = q;
                s4[l] += p[i + l] * q;
            }
        sum = (s4[0] + s4[1]) + (s4[2] + s4[3]);
        for (; i < i1; i++) {
            qv[i] = keep[i] != 0.0 ? qv[i] * sc[i] : 0.0;
            sum += p[i] * qv[i];
        }
    } else if (v->op == CG_STEP) {
        for (; i + 4 <= i1; i += 4)
            for (int l = 0; l < 4; l++) {
                x[i + l] += a * p[i + l];
                double ri = r[i + l] - a * qv[i + l];
                r[i + l] = ri;
                s4[l] += ri * ri;
            }
        sum = (s4[0] + s4[1]) + (s4[2] + s4[3]);
        for (; i < i1; i++) {
            x[i] += a * p[i];
            r[i] -= a * qv[i];
            sum += r[i] * r[i];
        }
    } else {
        for (; i < i1; i++) {
            p[i] = r[i] + a * p[i];
            tmp[i] = sc[i] * p[i];
        }
    }
    sums[0] = sum;
}

/* Pass op over the two parts of the vectors; returns its sum. */
static double cg_pass(CgPass op, CgVecs *v, int n, int cut, int nth)
{
    double sums[2];
    v->op = op;
    ns_vec_pass(cg_part, v, n, cut, nth, sums);
    return sums[0];
}

/* The linear solve: for the states S->st, to relative residual tol, warm-started from at, ar,
 * cf. Returns 0 or -1; adds its iterations. */
static int coupled_paper_solve(CoupledSystem *S, double tol, int max_iter, int *iterations)
{
    int n = S->nt3 + S->nr3 + 3 * S->q;
    double *buf = ns_arena_push(S->arena, (size_t)n * 8 * sizeof *buf);
    if (!buf)
        return -1;
    double *x = buf, *b = x + n, *r = b + n, *p = r + n, *qv = p + n, *sc = qv + n, *tmp = sc + n;
    double *keep = tmp + n;
    ns_vec_keep(S->tfixed, S->nt3, S->rfixed, S->nr3, n, keep);
    /* Units: every unknown scaled so that the tissue and needle blocks have a unit diagonal,
     * the constraint forces by sqrt(kappa), kappa the mean diagonal of A_t at the coupled nodes
     * (see the top of the file). */
    double kappa = 0.0;
    for (int k = 0; k < S->q; k++) {
        const double *blk = ns_bsm_find(S->At, S->ta[k], S->ta[k]);
        kappa += blk ? (blk[0] + blk[4] + blk[8]) / 3.0 : 1.0;
    }
    kappa = S->q > 0 ? kappa / S->q : 1.0;
    coupled_unit_scale(S, sc);
    for (int i = S->nt3 + S->nr3; i < n; i++)
        sc[i] = sqrt(kappa);
    /* Right-hand side with the known dynamic friction, and the starting point. */
    memcpy(b, S->bt, (size_t)S->nt3 * sizeof *b);
    memcpy(b + S->nt3, S->br, (size_t)S->nr3 * sizeof *b);
    memcpy(x, S->at, (size_t)S->nt3 * sizeof *x);
    memcpy(x + S->nt3, S->ar, (size_t)S->nr3 * sizeof *x);
    double *bc = b + S->nt3 + S->nr3, *xc = x + S->nt3 + S->nr3;
    for (int k = 0; k < S->q; k++) {
        double gk = coupled_known_force(S, k, S->st[k]), w = S->tw[k];
        const double *t = S->R + 9 * k;
        for (int i = 0; i < 3; i++) {
            b[3 * S->ta[k] + i] -= (1.0 - w) * gk * t[i];
            b[3 * S->tb[k] + i] -= w * gk * t[i];
            b[S->nt3 + 3 * S->idx[k] + i] += gk * t[i];
        }
        for (int col = 0; col < 3; col++) {
            int act = col_active(S->st[k], col);
            bc[3 * k + col] = act ? S->e[3 * k + col] : 0.0;
            xc[3 * k + col] = act ? S->cf[3 * k + col] : 0.0;
        }
    }
    /* The scaled system: x = sc x', b' = sc b, A' = sc A sc. */
    for (int i = 0; i < n; i++) {
        x[i] /= sc[i];
        b[i] *= sc[i];
    }
#define APPLY(in, out)                                                                             \
    do {                                                                                           \
        for (int i_ = 0; i_ < n; i_++)                                                             \
            tmp[i_] = sc[i_] * (in)[i_];                                                           \
        apply(S, 1.0, tmp, out);                                                                   \
        for (int i_ = 0; i_ < n; i_++)                                                             \
            (out)[i_] *= sc[i_];                                                                   \
    } while (0)
    /* r = b - A x on free DOFs; the reference norm is that of b - A x_fixed. */
    for (int i = 0; i < n; i++)
        p[i] = keep[i] == 0.0 ? x[i] : 0.0;
    APPLY(p, qv);
    double bnorm = 0.0;
    for (int i = 0; i < n; i++)
        if (keep[i] != 0.0)
            bnorm += (b[i] - qv[i]) * (b[i] - qv[i]);
    bnorm = sqrt(bnorm);
    APPLY(x, qv);
    for (int i = 0; i < n; i++)
        r[i] = keep[i] == 0.0 ? 0.0 : b[i] - qv[i];
    double rr = ns_vec_dot(r, r, n);
    int it = 0;
    /* The iteration's vector work in three passes (below), each over the two parts of the
     * vector that the tissue product gives its two threads, run at once on them. */
    CgVecs v = {x, r, p, qv, tmp, sc, keep, 0.0, CG_PRODUCT};
    int cut = ns_vec_cut(S->nt3, n), nth = S->threads > 1 && cut > 0 ? 2 : 1;
    if (bnorm > 0.0) {
        memcpy(p, r, (size_t)n * sizeof *p);
        for (int i = 0; i < n; i++)
            tmp[i] = sc[i] * p[i];
        while (sqrt(rr) > tol * bnorm && it < max_iter) {
            apply(S, 1.0, tmp, qv);
            double pq = cg_pass(CG_PRODUCT, &v, n, cut, nth);
            if (pq == 0.0 || !isfinite(pq))
                break; /* breakdown of CG on the indefinite system */
            v.s = rr / pq;
            double rr2 = cg_pass(CG_STEP, &v, n, cut, nth);
            v.s = rr2 / rr;
            rr = rr2;
            cg_pass(CG_DIRECTION, &v, n, cut, nth);
            it++;
        }
    }
#undef APPLY
    *iterations += it;
    S->converged = bnorm == 0.0 || sqrt(rr) <= tol * bnorm;
    for (int i = 0; i < n; i++)
        x[i] *= sc[i];
    memcpy(S->at, x, (size_t)S->nt3 * sizeof *x);
    memcpy(S->ar, x + S->nt3, (size_t)S->nr3 * sizeof *x);
    for (int k = 0; k < S->q; k++)
        for (int col = 0; col < 3; col++)
            S->cf[3 * k + col] =
                col_active(S->st[k], col) ? xc[3 * k + col] : coupled_known_force(S, k, S->st[k]);
    ns_arena_pop(S->arena, buf);
    return 0;
}

/* Algorithm 3 with the paper's solver: CG on Eq. 7 per trial, warm-started from the previous
 * trial, checked at tau_check, finished to tau_sol. */
int coupled_paper_lcp(CoupledSystem *S, NsCouplingStats *st)
{
    const NsCouplingParams *p = &S->c->params;
    size_t qb = (size_t)(S->q > 0 ? S->q : 1);
    uint8_t *next = ns_arena_push(S->arena, qb);
    uint8_t *cfg = ns_arena_push(S->arena, qb * (size_t)p->max_trials);
    TriedSet T;
    tried_init(&T, S->q, cfg, p->max_trials);
    int rc = next && cfg ? 0 : -1;
    st->consistent = 0;
    for (int trial = 0; trial < p->max_trials && rc == 0; trial++) {
        if (tried_add(&T, S->st)) {
            rc = -1;
            break;
        }
        st->trials++;
        if (coupled_paper_solve(S, p->tau_check, p->max_iter, &st->iterations)) {
            rc = -1;
            break;
        }
        if (coupled_check(S, S->st, S->cf, S->at, S->ar, next) == 0) {
            if (coupled_paper_solve(S, p->tau_sol, p->max_iter, &st->iterations)) {
                rc = -1;
                break;
            }
            if (coupled_check(S, S->st, S->cf, S->at, S->ar, next) == 0) {
                st->consistent = 1;
                break;
            }
        }
        memcpy(S->st, next, (size_t)S->q);
        tried_next(&T, S->st);
    }
    if (rc == 0 && !st->consistent) { /* accept the last configuration (§3.6.1) */
        rc = coupled_paper_solve(S, p->tau_sol, p->max_iter, &st->iterations);
        st->consistent = rc == 0 && coupled_check(S, S->st, S->cf, S->at, S->ar, next) == 0;
    }
    st->unconverged = rc == 0 && !S->converged;
    tried_free(&T);
    ns_arena_pop(S->arena, cfg);
    ns_arena_pop(S->arena, next);
    return rc;
}
