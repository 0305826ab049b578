/* Our linear-solver path for the coupled system Eq. 7 and Algorithm 3 on top of it
 * (docs/coupling.md, "Solver: ours"). Written H x + B^T c = b, with x = (a_t, a_n), H =
 * diag(A_t, A_n), c the constraint forces on the needle in the local frames (only the active
 * components: all three at a STATIC node, the two normal ones at a DYNAMIC one, whose tangent
 * carries the known friction in b) and B^T c = (G_t c, -G_n c), G the local frames spread onto
 * the tissue point's nodes (weights) and the needle node.
 *
 * 1. A CHOLMOD factor F of a recent tissue matrix A_t (stale by a few steps: refreshed when the
 *    solves start to need many iterations), the needle's band matrix solved exactly.
 * 2. The compliance of the coupling DOFs, C = G_t^T F^-1 G_t + G_n^T A_n^-1 G_n (3q x 3q,
 *    dense), from columns F^-1 e cached per coupled tissue node (3 each; computed once per
 *    factor, so a needle that advances by one node costs 3 solves) and 3q band solves.
 * 3. The exact solve for a friction configuration: projected preconditioned CG (Gould, Hribar &
 *    Nocedal 2001) with the constraint preconditioner [F~ B^T; B 0] (F~ = diag(F, A_n)), applied
 *    through C's active block: every iterate meets the constraints, so CG runs on the
 *    constraints' null space, where H is definite, preconditioned by the stale factor; a few
 *    iterations per solve. The residual is the first block's, H x + B^T c - b, scaled as the
 *    paper solver's (unit diagonal) and relative to its right-hand side; c is minus the sum of
 *    the projections' multipliers ("residual update").
 * 4. Algorithm 3: after an exact solve whose states are inconsistent, the next configurations
 *    are tried on C alone: their forces and slides predicted by a dense solve of C's active
 *    block (the response of x to a change dc of the forces is (-F^-1 G_t dc, A_n^-1 G_n dc)),
 *    flipped and tried again until one is consistent; only that one gets an exact solve (which
 *    checks it again). So a flip costs a ~3q-sized dense factorization instead of a CG run.
 *
 * SI units; the stale factor and the predictions affect only how fast the solve converges and
 * which configurations are tried, never the tolerance of the accepted solution. */
#include "coupling_internal.h"
#include "ns_config.h"
#include "snapshot.h"
#include "vec.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Iterations of one exact solve before the stale factor is given up for a fresh one. */
#define STALE_MAX_ITER 200

struct CoupledSchur {
    NsSolver *fac;   /* factor of a recent tissue matrix */
    long fac_count;  /* the factor the cache belongs to */
    int n3;          /* tissue vector length of the factor */
    int refresh;     /* a solve was slow: schedule a refactorization at the end of the step */
    int refresh_now; /* scheduling failed: refactor at the start of the next step */
    uint8_t *fixed;  /* (n3) the tissue's fixed DOFs when it was factored */
    /* Column cache: slot s holds F^-1 e_(3 node[s] + d), d = 0..2, at cols + (3 s + d) n3. */
    int *slot, slot_cap; /* per tissue node: its slot, -1 */
    int *node, count, cap;
    double *cols;
    size_t cols_cap; /* doubles allocated in cols */
    /* Per step: needle compliance columns Zn (nr3 x 3q), C (3q x 3q), factor of an active
     * block (3q x 3q), the PPCG vectors, scratch. */
    double *buf;
    size_t buf_cap;
    double *Zn, *C, *L, *sc, *small;
    int *act;
    int na;
    int act_cap;
    double *vec; /* 6 vectors of nt3 + nr3 */
    size_t vec_cap;
    /* add_response's terms: up to 6q cached columns and their scales */
    const double **term_col;
    double *term_s;
    int term_cap;
    int refreshed; /* refactored in this step */
    /* A refactorization scheduled at the end of a step (on the second core with 2 threads) and
     * adopted at the start of the next, with the columns of the nodes coupled then. */
    int pending;
    int *job_node, job_count, job_cap;
    double *job_B, *job_Z;
    size_t job_len; /* doubles in each (of the last scheduling that allocated both) */
    /* The projection in the middle (docs/coupling.md): for cached slot s and direction d, column
     * j = 3 s + d, Y_j = L_f^-1 P e_(3 node + d) with the factor's single-precision copy L_f as
     * it is now (its trailing block made current every step), in the copy's numbering. Below
     * the tail, sparse: yi/yv from yp[j], yn[j] entries; the tail's k rows: yw (W = L22 y2,
     * fixed for the factor) and yt (y2 = L22_now^-1 W, refreshed each step). ycount slots are
     * made; ymode says whether the projection uses them (the copy exists). */
    int ymode, ycount, yk, yn_free;
    int *yi;
    float *yv;
    size_t ylen, ycap;
    size_t *yp;
    int *yn, ycols_cap;
    double *yw;
    float *yt;
    size_t ytail_cap;
    float *ydense; /* (yn_free) zero between uses */
    int ydense_cap;
    double *Cp, *Lp; /* C with L_f (3q x 3q) and its active block's factor */
    /* The used columns' products (6q), multipliers' terms (6q) and Gram matrix (6q x 6q) */
    double *yu;
    int yu_cap;
    int *yplace, yplace_cap; /* each slot's place among the used ones, then the list (y_used) */
};

CoupledSchur *coupled_schur_create(void)
{
    CoupledSchur *w = calloc(1, sizeof *w);
    if (!w)
        return NULL;
    w->fac = ns_solver_create(NS_SOLVER_DIRECT);
    if (!w->fac) {
        free(w);
        return NULL;
    }
    return w;
}

void coupled_schur_destroy(CoupledSchur *w)
{
    if (!w)
        return;
    ns_solver_destroy(w->fac); /* waits for a scheduled refactorization */
    free(w->slot);
    free(w->node);
    free(w->cols);
    free(w->buf);
    free(w->act);
    free(w->vec);
    free(w->term_col);
    free(w->term_s);
    free(w->fixed);
    free(w->job_node);
    free(w->job_B);
    free(w->job_Z);
    free(w->yi);
    free(w->yv);
    free(w->yp);
    free(w->yn);
    free(w->yw);
    free(w->yt);
    free(w->ydense);
    free(w->yu);
    free(w->yplace);
    free(w);
}

/* ---- the tissue factor and its cached columns ---- */

/* Node e (0 or 1) of coupling node k's tissue point and its weight (0: not a node of it). */
static double point_node(const CoupledSystem *S, int k, int e, int *node)
{
    *node = e ? S->tb[k] : S->ta[k];
    return e ? S->tw[k] : 1.0 - S->tw[k];
}

static void cache_clear(CoupledSchur *w)
{
    for (int s = 0; s < w->count; s++)
        w->slot[w->node[s]] = -1;
    w->count = 0;
    w->ycount = 0;
    w->ylen = 0;
}

/* Asks the factor's next analysis to order the tip's ring last (docs/solvers.md, "The tail"):
 * the tissue nodes of the tip's point and their neighbours in A_t, whose block changes most
 * from step to step as the tip node slides through the material (Algorithm 2). */
static void set_tail(CoupledSchur *w, const CoupledSystem *S)
{
    int nodes[256], m = 0;
    if (S->tip >= 0)
        for (int e = 0; e < 2; e++) {
            int a;
            if (point_node(S, S->tip, e, &a) == 0.0)
                continue;
            const NsBlockRow *r = &S->At->rows[a];
            for (int p = 0; p < r->count && m < 256; p++) {
                int dup = 0;
                for (int i = 0; i < m && !dup; i++)
                    dup = nodes[i] == r->col[p];
                if (!dup)
                    nodes[m++] = r->col[p];
            }
        }
    ns_solver_set_tail(w->fac, nodes, m);
}

static int refactor(CoupledSchur *w, const CoupledSystem *S, NsCouplingStats *st)
{
    cache_clear(w);
    if (S->c->params.tip_block)
        set_tail(w, S);
    else
        ns_solver_set_tail(w->fac, NULL, 0);
    uint8_t *fx = realloc(w->fixed, (size_t)S->nt3 + 1);
    if (!fx)
        return -1;
    w->fixed = fx;
    if (ns_solver_factor(w->fac, S->At, S->tfixed)) {
        w->fac_count = 0; /* no factor now: the next step must make one */
        return -1;
    }
    memcpy(w->fixed, S->tfixed, (size_t)S->nt3);
    w->fac_count = ns_solver_factor_count(w->fac);
    w->n3 = S->nt3;
    w->refresh = 0;
    w->refresh_now = 0;
    st->refactors++;
    return 0;
}

/* Makes sure every tissue node of the coupling nodes has its three columns: all missing ones in
 * one multi-column solve. Columns of nodes no longer coupled are dropped when they pile up. */
static int cache_fill(CoupledSchur *w, const CoupledSystem *S)
{
    int nn = S->nt3 / 3;
    if (w->slot_cap < nn) {
        int *p = realloc(w->slot, (size_t)nn * sizeof *p);
        if (!p)
            return -1;
        for (int i = w->slot_cap; i < nn; i++)
            p[i] = -1;
        w->slot = p;
        w->slot_cap = nn;
    }
    int need = 2 * S->q;
    if (w->count > need + 64) /* a needle that moved on: forget the nodes it left */
        cache_clear(w);
    int *missing = malloc((size_t)(2 * S->q + 1) * sizeof *missing), nm = 0;
    if (!missing)
        return -1;
    for (int k = 0; k < S->q; k++)
        for (int e = 0; e < 2; e++) {
            int a;
            double wt = point_node(S, k, e, &a);
            if (wt == 0.0 || w->slot[a] >= 0)
                continue;
            int dup = 0;
            for (int i = 0; i < nm && !dup; i++)
                dup = missing[i] == a;
            if (!dup)
                missing[nm++] = a;
        }
    if (nm > 0) {
        int cap = w->count + nm;
        if (cap > w->cap) {
            cap = cap > 2 * w->cap ? cap : 2 * w->cap;
            int *nd = realloc(w->node, (size_t)cap * sizeof *nd);
            if (!nd) {
                free(missing);
                return -1;
            }
            w->node = nd;
            w->cap = cap;
        }
        /* The stride is the tissue's vector length, which may have changed since the last
         * fill (a refactor cleared the cache then). */
        size_t need_d = (size_t)w->cap * 3 * (size_t)S->nt3;
        if (need_d > w->cols_cap) {
            double *cl = realloc(w->cols, need_d * sizeof *cl);
            if (!cl) {
                free(missing);
                return -1;
            }
            w->cols = cl;
            w->cols_cap = need_d;
        }
        int rc = 0;
        double *B = calloc((size_t)nm * 3 * (size_t)S->nt3, sizeof *B);
        if (!B)
            rc = -1;
        for (int i = 0; i < nm && rc == 0; i++)
            for (int d = 0; d < 3; d++)
                B[(size_t)(3 * i + d) * (size_t)S->nt3 + 3 * (size_t)missing[i] + d] = 1.0;
        if (rc == 0 && ns_solver_apply(w->fac, S->nt3, 3 * nm, B,
                                       w->cols + (size_t)w->count * 3 * (size_t)S->nt3))
            rc = -1;
        if (rc == 0)
            for (int i = 0; i < nm; i++) {
                w->node[w->count] = missing[i];
                w->slot[missing[i]] = w->count++;
            }
        free(B);
        if (rc) {
            free(missing);
            return -1;
        }
    }
    free(missing);
    return 0;
}

/* Schedules the refactorization of this step's tissue matrix, with the columns of the tissue
 * nodes coupled now, for adoption at the next step (ns_solver_factor_async: in the background
 * with 2 threads, here with 1; the same factor either way). Returns 0, or -1 (nothing
 * scheduled). */
static int schedule_refresh(CoupledSchur *w, const CoupledSystem *S)
{
    int cap = 2 * S->q, nt3 = S->nt3, m = 0;
    if (cap > w->job_cap) {
        int *nd = realloc(w->job_node, (size_t)cap * sizeof *nd);
        if (!nd)
            return -1;
        w->job_node = nd;
        w->job_cap = cap;
    }
    for (int k = 0; k < S->q; k++)
        for (int e = 0; e < 2; e++) {
            int a, dup = 0;
            if (point_node(S, k, e, &a) == 0.0)
                continue;
            for (int i = 0; i < m && !dup; i++)
                dup = w->job_node[i] == a;
            if (!dup)
                w->job_node[m++] = a;
        }
    free(w->job_B);
    free(w->job_Z);
    w->job_B = calloc((size_t)m * 3 * (size_t)nt3 + 1, sizeof *w->job_B);
    w->job_Z = malloc(((size_t)m * 3 * (size_t)nt3 + 1) * sizeof *w->job_Z);
    if (!w->job_B || !w->job_Z)
        return -1;
    w->job_len = (size_t)m * 3 * (size_t)nt3 + 1;
    for (int i = 0; i < m; i++)
        for (int d = 0; d < 3; d++)
            w->job_B[(size_t)(3 * i + d) * (size_t)nt3 + 3 * (size_t)w->job_node[i] + d] = 1.0;
    w->job_count = m;
    if (ns_solver_factor_async(w->fac, S->At, S->tfixed, 3 * m, w->job_B, w->job_Z))
        return -1;
    w->pending = 1;
    return 0;
}

/* Adopts the scheduled factor and its columns (the cache starts from them). Returns 1 if a new
 * factor is in use, 0 if not, -1 on failure. */
static int adopt_refresh(CoupledSchur *w, const CoupledSystem *S)
{
    int cols_ok = 0;
    w->pending = 0;
    if (!ns_solver_factor_adopt(w->fac, &cols_ok))
        return 0;
    cache_clear(w);
    w->fac_count = ns_solver_factor_count(w->fac);
    if (!cols_ok || w->job_count == 0 || S->nt3 != w->n3)
        return 1; /* the columns are filled as needed */
    size_t need_d = (size_t)w->job_count * 3 * (size_t)S->nt3;
    if (w->job_count > w->cap) {
        int *nd = realloc(w->node, (size_t)w->job_count * sizeof *nd);
        if (!nd)
            return -1;
        w->node = nd;
        w->cap = w->job_count;
    }
    if ((size_t)w->cap * 3 * (size_t)S->nt3 > w->cols_cap) {
        size_t nd_ = (size_t)w->cap * 3 * (size_t)S->nt3;
        double *cl = realloc(w->cols, nd_ * sizeof *cl);
        if (!cl)
            return -1;
        w->cols = cl;
        w->cols_cap = nd_;
    }
    memcpy(w->cols, w->job_Z, need_d * sizeof *w->cols);
    for (int i = 0; i < w->job_count; i++) {
        w->node[i] = w->job_node[i];
        w->slot[w->job_node[i]] = i;
    }
    w->count = w->job_count;
    return 1;
}

/* ---- the compliance C and its active block ---- */

static int ensure_buf(CoupledSchur *w, const CoupledSystem *S)
{
    size_t q3 = 3 * (size_t)S->q, n = (size_t)(S->nt3 + S->nr3);
    size_t need = (size_t)S->nr3 * q3 + 4 * q3 * q3 + n + 9 * q3 + 8;
    if (need > w->buf_cap) {
        double *b = realloc(w->buf, need * sizeof *b);
        if (!b)
            return -1;
        w->buf = b;
        w->buf_cap = need;
    }
    if ((int)q3 + 1 > w->act_cap) {
        int *a = realloc(w->act, (q3 + 1) * sizeof *a);
        if (!a)
            return -1;
        w->act = a;
        w->act_cap = (int)q3 + 1;
    }
    w->Zn = w->buf;
    w->C = w->Zn + (size_t)S->nr3 * q3;
    w->L = w->C + q3 * q3;
    w->Cp = w->L + q3 * q3;
    w->Lp = w->Cp + q3 * q3;
    w->sc = w->Lp + q3 * q3;
    w->small = w->sc + n; /* 9 vectors of 3q */
    if (6 * (int)S->q + 1 > w->term_cap) {
        int cap = 6 * (int)S->q + 1;
        const double **c = realloc(w->term_col, (size_t)cap * sizeof *c);
        if (c)
            w->term_col = c;
        double *ts = c ? realloc(w->term_s, (size_t)cap * sizeof *ts) : NULL;
        if (!ts)
            return -1;
        w->term_s = ts;
        w->term_cap = cap;
    }
    if (6 * n > w->vec_cap) {
        double *v = realloc(w->vec, 6 * n * sizeof *v);
        if (!v)
            return -1;
        w->vec = v;
        w->vec_cap = 6 * n;
    }
    return 0;
}

/* Local component j = 3k + col of the frame of coupling node k. */
static const double *frame_col(const CoupledSystem *S, int j)
{
    return S->R + 9 * (j / 3) + 3 * (j % 3);
}

/* C += the tissue part of a compliance: the sum over the tissue point nodes a of k and b of l
 * of w_a w_b R_k^T M(a, b) R_l, M(a, b) the 3 x 3 block of F^-1 from the cached columns (G NULL)
 * or of Y_a^T Y_b from the Gram matrix G of the used columns (ng x ng, place: each slot's index
 * among them). */
static void add_tissue_part(const CoupledSchur *w, const CoupledSystem *S, double *C,
                            const double *G, int ng, const int *place)
{
    int q3 = 3 * S->q, nt3 = S->nt3;
    for (int k = 0; k < S->q; k++)
        for (int ea = 0; ea < 2; ea++) {
            int a, b;
            double wa = point_node(S, k, ea, &a);
            if (wa == 0.0)
                continue;
            for (int l = 0; l < S->q; l++)
                for (int eb = 0; eb < 2; eb++) {
                    double wb = point_node(S, l, eb, &b);
                    if (wb == 0.0)
                        continue;
                    double M[9]; /* M[3 i + d] = F^-1[3a + i, 3b + d], or Y_(a,i) . Y_(b,d) */
                    if (G) {
                        int pa = place[w->slot[a]], pb = place[w->slot[b]];
                        for (int i = 0; i < 3; i++)
                            for (int d = 0; d < 3; d++)
                                M[3 * i + d] = G[(size_t)(3 * pa + i) * (size_t)ng + 3 * pb + d];
                    } else {
                        const double *col = w->cols + (size_t)w->slot[b] * 3 * (size_t)nt3;
                        for (int i = 0; i < 3; i++)
                            for (int d = 0; d < 3; d++)
                                M[3 * i + d] = col[(size_t)d * (size_t)nt3 + 3 * (size_t)a + i];
                    }
                    for (int c1 = 0; c1 < 3; c1++) {
                        const double *r1 = frame_col(S, 3 * k + c1);
                        for (int c2 = 0; c2 < 3; c2++) {
                            const double *r2 = frame_col(S, 3 * l + c2);
                            double v = 0.0;
                            for (int i = 0; i < 3; i++)
                                for (int d = 0; d < 3; d++)
                                    v += r1[i] * M[3 * i + d] * r2[d];
                            C[(size_t)(3 * k + c1) * (size_t)q3 + 3 * l + c2] += wa * wb * v;
                        }
                    }
                }
        }
}

static int build_compliance(CoupledSchur *w, const CoupledSystem *S, double *nscratch)
{
    int q3 = 3 * S->q, nr3 = S->nr3;
    double *C = w->C;
    memset(C, 0, (size_t)q3 * (size_t)q3 * sizeof *C);
    add_tissue_part(w, S, C, NULL, 0, NULL);
    /* Needle: Zn column j = A_n^-1 (R_l col at node idx_l), exact band solves. */
    for (int j = 0; j < q3; j++) {
        double *z = w->Zn + (size_t)j * (size_t)nr3;
        memset(nscratch, 0, (size_t)nr3 * sizeof *nscratch);
        memset(z, 0, (size_t)nr3 * sizeof *z);
        const double *r = frame_col(S, j);
        for (int i = 0; i < 3; i++)
            nscratch[3 * S->idx[j / 3] + i] = r[i];
        ns_banded_solve_factored(S->Ar, S->rfixed, nscratch, z, NULL); /* factored in _lcp */
        for (int k = 0; k < S->q; k++)
            for (int c1 = 0; c1 < 3; c1++) {
                const double *r1 = frame_col(S, 3 * k + c1);
                const double *zk = z + 3 * S->idx[k];
                double v = r1[0] * zk[0] + r1[1] * zk[1] + r1[2] * zk[2];
                C[(size_t)(3 * k + c1) * (size_t)q3 + j] += v;
                if (w->ymode) /* Cp (build_cp) has the same needle part */
                    w->Cp[(size_t)(3 * k + c1) * (size_t)q3 + j] += v;
            }
    }
    return 0;
}

static int is_active(int s, int col)
{
    return col > 0 || s == NS_FRICTION_STATIC;
}

/* Cholesky of C's active block (w->act, w->na) into L (na x na): a block that is not
 * numerically definite gets a tiny diagonal shift (then the constraints hold only to that
 * shift's size); a zero block (every active direction fixed on both sides: nothing can move to
 * meet the constraints) fails (-1). */
static int factor_block(const CoupledSchur *w, int q3, const double *C, double *L)
{
    int na = w->na;
    double dmax = 0.0;
    for (int i = 0; i < na; i++)
        dmax = fmax(dmax, C[(size_t)w->act[i] * (size_t)q3 + w->act[i]]);
    for (double shift = 0.0;
         shift<1e-4 * dmax + 1e-300; shift = shift> 0 ? 100 * shift : 1e-14 * dmax) {
        int ok = 1;
        for (int i = 0; i < na && ok; i++)
            for (int j = 0; j <= i && ok; j++) {
                double s = C[(size_t)w->act[i] * (size_t)q3 + w->act[j]] + (i == j ? shift : 0.0);
                for (int k = 0; k < j; k++)
                    s -= L[(size_t)i * (size_t)na + k] * L[(size_t)j * (size_t)na + k];
                if (i == j) {
                    ok = s > 0.0;
                    L[(size_t)i * (size_t)na + i] = ok ? sqrt(s) : 0.0;
                } else {
                    L[(size_t)i * (size_t)na + j] = s / L[(size_t)j * (size_t)na + j];
                }
            }
        if (ok)
            return 0;
        if (dmax == 0.0)
            break;
    }
    return -1;
}

/* The active components for the states st (w->act, w->na) and the Cholesky factors of their
 * blocks: C's into w->L, and Cp's into w->Lp when the projection uses it. */
static int factor_active(CoupledSchur *w, const CoupledSystem *S, const uint8_t *st)
{
    int q3 = 3 * S->q, na = 0;
    for (int j = 0; j < q3; j++)
        if (is_active(st[j / 3], j % 3))
            w->act[na++] = j;
    w->na = na;
    if (factor_block(w, q3, w->C, w->L))
        return -1;
    return w->ymode ? factor_block(w, q3, w->Cp, w->Lp) : 0;
}

/* Solves the active block: y (na) in place. */
static void solve_active(const CoupledSchur *w, const double *L, double *y)
{
    int na = w->na;
    for (int i = 0; i < na; i++) {
        double s = y[i];
        for (int k = 0; k < i; k++)
            s -= L[(size_t)i * (size_t)na + k] * y[k];
        y[i] = s / L[(size_t)i * (size_t)na + i];
    }
    for (int i = na - 1; i >= 0; i--) {
        double s = y[i];
        for (int k = i + 1; k < na; k++)
            s -= L[(size_t)k * (size_t)na + i] * y[k];
        y[i] = s / L[(size_t)i * (size_t)na + i];
    }
}

/* ---- products with the pieces ---- */

/* h (3q) = B x in the local frames: R_k^T (tissue point of xt - xn[idx_k]) for every
 * component (the constraint rows' left-hand side, for active and inactive ones alike). */
static void constraint_rows(const CoupledSystem *S, const double *xt, const double *xn, double *h)
{
    for (int k = 0; k < S->q; k++) {
        double pt[3];
        coupled_point(S, k, xt, pt);
        for (int i = 0; i < 3; i++)
            pt[i] -= xn[3 * S->idx[k] + i];
        for (int col = 0; col < 3; col++) {
            const double *r = S->R + 9 * k + 3 * col;
            h[3 * k + col] = r[0] * pt[0] + r[1] * pt[1] + r[2] * pt[2];
        }
    }
}

/* (rt, rn) += s B^T lam = s (G_t lam, -G_n lam), lam over all 3q components. */
static void add_bt(const CoupledSystem *S, const double *lam, double s, double *rt, double *rn)
{
    for (int k = 0; k < S->q; k++) {
        double g[3] = {0, 0, 0};
        for (int col = 0; col < 3; col++)
            for (int i = 0; i < 3; i++)
                g[i] += S->R[9 * k + 3 * col + i] * lam[3 * k + col];
        double wt = S->tw[k];
        for (int i = 0; i < 3; i++) {
            rt[3 * S->ta[k] + i] += s * (1.0 - wt) * g[i];
            rt[3 * S->tb[k] + i] += s * wt * g[i];
            rn[3 * S->idx[k] + i] -= s * g[i];
        }
    }
}

/* The response to forces lam (3q, on the needle): xt -= F^-1 G_t lam, xn += A_n^-1 G_n lam. The
 * tissue part is a sum of up to 6q cached columns, each a dense nt3-vector (F^-1 is dense), so
 * it reads megabytes: it is split by rows over the threads, each entry's terms subtracted in the
 * same order whatever the split (the same bits on any thread count). */
static void add_response(const CoupledSchur *w, const CoupledSystem *S, const double *lam,
                         double *xt, double *xn)
{
    int nt3 = S->nt3, nr3 = S->nr3, nterm = 0;
    for (int k = 0; k < S->q; k++) {
        double g[3] = {0, 0, 0};
        for (int col = 0; col < 3; col++)
            for (int i = 0; i < 3; i++)
                g[i] += S->R[9 * k + 3 * col + i] * lam[3 * k + col];
        if (g[0] == 0.0 && g[1] == 0.0 && g[2] == 0.0)
            continue;
        for (int e = 0; e < 2; e++) {
            int a;
            double wt = point_node(S, k, e, &a);
            if (wt == 0.0)
                continue;
            const double *col = w->cols + (size_t)w->slot[a] * 3 * (size_t)nt3;
            for (int d = 0; d < 3; d++) {
                w->term_col[nterm] = col + (size_t)d * (size_t)nt3;
                w->term_s[nterm++] = wt * g[d];
            }
        }
    }
    const double *const *tc = w->term_col;
    const double *ts = w->term_s;
    int chunks = 1;
#if NS_HAVE_OPENMP
    /* Below ~100k terms x entries the fork costs more than it saves. */
    if (S->threads > 1 && (double)nterm * nt3 >= 1e5)
        chunks = S->threads;
#pragma omp parallel for num_threads(chunks) schedule(static) if (chunks > 1)
#endif
    for (int part = 0; part < chunks; part++) {
        int i0 = (int)((long)nt3 * part / chunks), i1 = (int)((long)nt3 * (part + 1) / chunks);
        for (int m = 0; m < nterm; m++) {
            const double *cd = tc[m];
            double s = ts[m];
            for (int i = i0; i < i1; i++)
                xt[i] -= s * cd[i];
        }
    }
    for (int j = 0; j < 3 * S->q; j++) {
        if (lam[j] == 0.0)
            continue;
        const double *z = w->Zn + (size_t)j * (size_t)nr3;
        for (int i = 0; i < nr3; i++)
            xn[i] += lam[j] * z[i];
    }
}

/* Zeroes the fixed DOFs' entries of a tissue-then-needle vector. */
static void mask_fixed(const CoupledSystem *S, double *v)
{
    for (int i = 0; i < S->nt3; i++)
        if (S->tfixed[i])
            v[i] = 0.0;
    for (int i = 0; i < S->nr3; i++)
        if (S->rfixed[i])
            v[S->nt3 + i] = 0.0;
}

/* out = H x, the fixed rows included (hmul zeroes them). */
static void hmul_all(const CoupledSystem *S, const double *x, double *out)
{
    ns_bsm_mul_threads(S->At, x, out, S->threads);
    ns_banded_mul(S->Ar, x + S->nt3, out + S->nt3);
}

/* out = H x on the free rows (fixed rows 0). */
static void hmul(const CoupledSystem *S, const double *x, double *out)
{
    hmul_all(S, x, out);
    mask_fixed(S, out);
}

/* Multipliers lam (3q, 0 on inactive components) with C_aa lam_a = rhs_a. */
static void active_solve_with(const CoupledSchur *w, const double *L, const CoupledSystem *S,
                              const double *rhs, double *lam, double *tmp)
{
    for (int i = 0; i < w->na; i++)
        tmp[i] = rhs[w->act[i]];
    solve_active(w, L, tmp);
    memset(lam, 0, 3 * (size_t)S->q * sizeof *lam);
    for (int i = 0; i < w->na; i++)
        lam[w->act[i]] = tmp[i];
}

static void active_solve(const CoupledSchur *w, const CoupledSystem *S, const double *rhs,
                         double *lam, double *tmp)
{
    active_solve_with(w, w->L, S, rhs, lam, tmp);
}

/* ---- the projection in the middle (docs/coupling.md) ---- */

/* Room for `more` entries in the pool of the columns' parts below the tail. */
static int y_pool(CoupledSchur *w, size_t more)
{
    if (w->ylen + more <= w->ycap)
        return 0;
    size_t cap = w->ylen + more > 2 * w->ycap ? w->ylen + more : 2 * w->ycap;
    int *ii = realloc(w->yi, cap * sizeof *ii);
    if (ii)
        w->yi = ii;
    float *vv = realloc(w->yv, cap * sizeof *vv);
    if (vv)
        w->yv = vv;
    if (!ii || !vv)
        return -1;
    w->ycap = cap;
    return 0;
}

/* Makes the columns Y of the slots cached since the last call (with the copy as it is now, its
 * tail block current) and refreshes every column's tail rows for the tail block now. Sets
 * ymode (0: no copy, the projection uses F's own columns). Returns 0 or -1 (memory). */
static int y_prepare(CoupledSchur *w, const CoupledSystem *S)
{
    w->ymode = 0;
    int nt3 = S->nt3;
    int nf = ns_solver_forward_dof(w->fac, nt3, 0, NULL);
    if (nf <= 0)
        return 0;
    const double *L22;
    int k = ns_solver_tail_block(w->fac, nt3, &L22);
    if (w->ycount > 0 && (k != w->yk || nf != w->yn_free)) {
        w->ycount = 0;
        w->ylen = 0;
    }
    w->yk = k;
    w->yn_free = nf;
    int ncol = 3 * w->count, t0 = nf - k;
    if (ncol > w->ycols_cap) {
        size_t *yp = realloc(w->yp, (size_t)ncol * sizeof *yp);
        if (yp)
            w->yp = yp;
        int *yn = realloc(w->yn, (size_t)ncol * sizeof *yn);
        if (yn)
            w->yn = yn;
        if (!yp || !yn)
            return -1;
        w->ycols_cap = ncol;
    }
    size_t tail_need = (size_t)ncol * (size_t)k + 1;
    if (tail_need > w->ytail_cap) {
        double *yw = realloc(w->yw, tail_need * sizeof *yw);
        if (yw)
            w->yw = yw;
        float *yt = realloc(w->yt, tail_need * sizeof *yt);
        if (yt)
            w->yt = yt;
        if (!yw || !yt)
            return -1;
        w->ytail_cap = tail_need;
    }
    if (nf > w->ydense_cap) {
        free(w->ydense);
        w->ydense = calloc((size_t)nf, sizeof *w->ydense);
        if (!w->ydense) {
            w->ydense_cap = 0;
            return -1;
        }
        w->ydense_cap = nf;
    }
    int need = 12 * S->q + 36 * S->q * S->q + 1, pneed = w->count + 2 * S->q + 1;
    if (need > w->yu_cap) {
        double *u = realloc(w->yu, (size_t)need * sizeof *u);
        if (!u)
            return -1;
        w->yu = u;
        w->yu_cap = need;
    }
    if (pneed > w->yplace_cap) {
        int *pl = realloc(w->yplace, (size_t)pneed * sizeof *pl);
        if (!pl)
            return -1;
        w->yplace = pl;
        w->yplace_cap = pneed;
    }
    float *y = w->ydense;
    for (int j = 3 * w->ycount; j < ncol; j++) {
        double *yw = w->yw + (size_t)j * (size_t)k;
        w->yp[j] = w->ylen;
        w->yn[j] = 0;
        int r = ns_solver_forward_dof(w->fac, nt3, 3 * w->node[j / 3] + j % 3, y);
        if (r < 0) {
            w->ycount = 0;
            w->ylen = 0;
            return 0;
        }
        if (r == 0) { /* a fixed DOF: no column */
            memset(yw, 0, (size_t)k * sizeof *yw);
            continue;
        }
        int cnt = 0;
        for (int i = 0; i < t0; i++)
            cnt += y[i] != 0.0f;
        if (y_pool(w, (size_t)cnt)) {
            memset(y, 0, (size_t)nf * sizeof *y); /* zero between uses */
            w->ycount = 0;
            w->ylen = 0;
            return -1;
        }
        for (int i = 0; i < t0; i++)
            if (y[i] != 0.0f) {
                w->yi[w->ylen] = i;
                w->yv[w->ylen++] = y[i];
                y[i] = 0.0f;
            }
        w->yn[j] = cnt;
        for (int i = 0; i < k; i++) { /* W = L22 y2: what the tail's solve started from */
            double v = 0.0;
            for (int m = 0; m <= i; m++)
                v += L22[i + (size_t)k * m] * (double)y[t0 + m];
            yw[i] = v;
        }
        for (int i = 0; i < k; i++)
            y[t0 + i] = 0.0f;
    }
    w->ycount = w->count;
    for (int j = 0; j < ncol; j++) { /* y2 = L22_now^-1 W */
        const double *yw = w->yw + (size_t)j * (size_t)k;
        float *yt = w->yt + (size_t)j * (size_t)k;
        for (int i = 0; i < k; i++) {
            double v = yw[i];
            for (int m = 0; m < i; m++)
                v -= L22[i + (size_t)k * m] * (double)yt[m];
            yt[i] = (float)(v / L22[i + (size_t)k * i]);
        }
    }
    w->ymode = 1;
    return 0;
}

/* The slots the coupling points use, in order of first use: *use lists them, place[slot] is a
 * slot's index in that list (-1: unused). Returns their count. */
static int y_used(const CoupledSchur *w, const CoupledSystem *S, int **place, int **use)
{
    int *pl = w->yplace, *us = pl + w->count, nuse = 0;
    for (int s = 0; s < w->count; s++)
        pl[s] = -1;
    for (int k = 0; k < S->q; k++)
        for (int e = 0; e < 2; e++) {
            int a;
            if (point_node(S, k, e, &a) == 0.0 || pl[w->slot[a]] >= 0)
                continue;
            pl[w->slot[a]] = nuse;
            us[nuse++] = w->slot[a];
        }
    *place = pl;
    *use = us;
    return nuse;
}

/* Y_j . y (y in the copy's numbering, t0 its first tail row). */
static double ycol_dot(const CoupledSchur *w, int j, const float *y, int t0)
{
    const int *ii = w->yi + w->yp[j];
    const float *vv = w->yv + w->yp[j];
    double sum = 0.0;
    for (int e = 0; e < w->yn[j]; e++)
        sum += (double)(vv[e] * y[ii[e]]);
    const float *yt = w->yt + (size_t)j * (size_t)w->yk;
    for (int t = 0; t < w->yk; t++)
        sum += (double)(yt[t] * y[t0 + t]);
    return sum;
}

/* Cp's tissue part: the sum over the tissue point nodes a of k and b of l of
 * w_a w_b R_k^T (Y_a^T Y_b) R_l (build_compliance adds the needle's part). */
static void build_cp(CoupledSchur *w, const CoupledSystem *S)
{
    int q3 = 3 * S->q, *place, *use, nuse = y_used(w, S, &place, &use), ng = 3 * nuse;
    int t0 = w->yn_free - w->yk;
    double *G = w->yu + 12 * S->q; /* (ng x ng) Gram matrix of the used columns */
    float *y = w->ydense;
    for (int a = 0; a < ng; a++) {
        int ja = 3 * use[a / 3] + a % 3;
        for (int e = 0; e < w->yn[ja]; e++)
            y[w->yi[w->yp[ja] + e]] = w->yv[w->yp[ja] + e];
        for (int t = 0; t < w->yk; t++)
            y[t0 + t] = w->yt[(size_t)ja * (size_t)w->yk + t];
        for (int b = 0; b <= a; b++) {
            int jb = 3 * use[b / 3] + b % 3;
            double v = ycol_dot(w, jb, y, t0);
            G[(size_t)a * (size_t)ng + b] = v;
            G[(size_t)b * (size_t)ng + a] = v;
        }
        for (int e = 0; e < w->yn[ja]; e++)
            y[w->yi[w->yp[ja] + e]] = 0.0f;
        for (int t = 0; t < w->yk; t++)
            y[t0 + t] = 0.0f;
    }
    memset(w->Cp, 0, (size_t)q3 * (size_t)q3 * sizeof *w->Cp);
    add_tissue_part(w, S, w->Cp, G, ng, place);
}

typedef struct MidCtx {
    CoupledSchur *w;
    const CoupledSystem *S;
    const double *gn0; /* A_n^-1 r_n */
    double *lam, *h, *tmp;
} MidCtx;

/* Between the copy's substitutions, with y = L_f^-1 P r_t (scaled by down): the multipliers v
 * of [F_f B^T; B 0] [g; v] = [r; 0] from h = B (F_f^-1 r_t, A_n^-1 r_n), whose tissue part is
 * Y^T y, and then y -= L_f^-1 P G_t v (a sum of Y's columns), so that the backward substitution
 * gives F_f^-1 (r_t - G_t v). */
static void mid_project(void *ctx, float *y, int n, double down, double up)
{
    MidCtx *m = ctx;
    CoupledSchur *w = m->w;
    const CoupledSystem *S = m->S;
    int t0 = n - w->yk, *place, *use, nuse = y_used(w, S, &place, &use);
    double *u = w->yu, *coef = u + 6 * S->q;
    for (int p = 0; p < 3 * nuse; p++)
        u[p] = up * ycol_dot(w, 3 * use[p / 3] + p % 3, y, t0);
    for (int k = 0; k < S->q; k++) {
        double pt[3] = {0.0, 0.0, 0.0};
        for (int e = 0; e < 2; e++) {
            int a;
            double wt = point_node(S, k, e, &a);
            if (wt == 0.0)
                continue;
            for (int i = 0; i < 3; i++)
                pt[i] += wt * u[3 * place[w->slot[a]] + i];
        }
        for (int i = 0; i < 3; i++)
            pt[i] -= m->gn0[3 * S->idx[k] + i];
        for (int col = 0; col < 3; col++) {
            const double *r = S->R + 9 * k + 3 * col;
            m->h[3 * k + col] = r[0] * pt[0] + r[1] * pt[1] + r[2] * pt[2];
        }
    }
    active_solve_with(w, w->Lp, S, m->h, m->lam, m->tmp);
    memset(coef, 0, 3 * (size_t)nuse * sizeof *coef);
    for (int k = 0; k < S->q; k++) {
        double g[3] = {0, 0, 0};
        for (int col = 0; col < 3; col++)
            for (int i = 0; i < 3; i++)
                g[i] += S->R[9 * k + 3 * col + i] * m->lam[3 * k + col];
        for (int e = 0; e < 2; e++) {
            int a;
            double wt = point_node(S, k, e, &a);
            if (wt == 0.0)
                continue;
            for (int d = 0; d < 3; d++)
                coef[3 * place[w->slot[a]] + d] += wt * g[d];
        }
    }
    for (int p = 0; p < 3 * nuse; p++) {
        if (coef[p] == 0.0)
            continue;
        int j = 3 * use[p / 3] + p % 3;
        float c = (float)(down * coef[p]);
        const int *ii = w->yi + w->yp[j];
        const float *vv = w->yv + w->yp[j];
        for (int e = 0; e < w->yn[j]; e++)
            y[ii[e]] -= c * vv[e];
        const float *yt = w->yt + (size_t)j * (size_t)w->yk;
        for (int t = 0; t < w->yk; t++)
            y[t0 + t] -= c * yt[t];
    }
}

/* The projection: g = the preconditioned residual in the constraints' null space, v its
 * multipliers, [F~ B^T; B 0] [g; v] = [r; 0] (F~ = diag(F, A_n) for the active rows; with
 * tip_block F's copy with its tail block current, projected between the substitutions). */
static int project(CoupledSchur *w, const CoupledSystem *S, const double *r, double *g, double *v,
                   double *h, double *tmp)
{
    int nt3 = S->nt3, q3 = 3 * S->q;
    memset(g + nt3, 0, (size_t)S->nr3 * sizeof *g);
    ns_banded_solve_factored(S->Ar, S->rfixed, r + nt3, g + nt3, NULL);
    if (w->ymode) {
        MidCtx m = {w, S, g + nt3, v, h, tmp};
        if (ns_solver_precondition_mid(w->fac, nt3, r, g, mid_project, &m) == 0) {
            for (int j = 0; j < q3; j++) { /* the needle's part: g_n += A_n^-1 G_n v */
                if (v[j] == 0.0)
                    continue;
                const double *z = w->Zn + (size_t)j * (size_t)S->nr3;
                for (int i = 0; i < S->nr3; i++)
                    g[nt3 + i] += v[j] * z[i];
            }
            /* The float substitutions leave B g at ~1e-7 of g's scale: met exactly by one
             * projection with the factor's own double columns, which C holds. */
            double *v2 = w->small + 8 * (size_t)q3;
            constraint_rows(S, g, g + nt3, h);
            active_solve(w, S, h, v2, tmp);
            add_response(w, S, v2, g, g + nt3);
            for (int j = 0; j < q3; j++)
                v[j] += v2[j];
            return 0;
        }
    }
    /* F^-1 with the factor's single-precision copy: a preconditioner needs no more; C and the
     * cached columns below stay double, so every iterate still meets the constraints. */
    if (ns_solver_precondition(w->fac, nt3, r, g))
        return -1;
    constraint_rows(S, g, g + nt3, h);
    active_solve(w, S, h, v, tmp);
    add_response(w, S, v, g, g + nt3);
    return 0;
}

/* The exact solve for the states S->st (w->L factored for them) by projected PCG, from the
 * accelerations in S->at / S->ar. With next given, the states are checked (Eq. 9-11) when the
 * residual first reaches tol_check, within the same run: a violation stops it there, with
 * *violations set and next holding the flips (so the check costs no restart, unlike the paper
 * solver's two solves). Returns 0 (S->converged says whether it reached tol), 1 if the stale
 * factor made it give up, -1 on failure. */
static void forces_from(const CoupledSystem *S, const double *acc)
{
    for (int k = 0; k < S->q; k++)
        for (int col = 0; col < 3; col++)
            S->cf[3 * k + col] =
                is_active(S->st[k], col) ? -acc[3 * k + col] : coupled_known_force(S, k, S->st[k]);
}

/* The projected PCG iteration's vectors (docs/coupling.md, "Solver: ours", step 3; tissue then
 * needle, the iterate in S->at and S->ar), the step's scalar s (alpha, then beta) and the pass
 * under way. */
typedef struct PcgVecs {
    double *xt, *xn, *r, *g, *p, *hp;
    const double *sc, *keep;
    int nt3, op;
    double s;
} PcgVecs;

enum {
    PCG_PRODUCT,   /* hp's fixed rows zeroed; sums p.hp */
    PCG_STEP,      /* x += alpha p, r += alpha hp */
    PCG_RESIDUAL,  /* r's fixed rows zeroed; sums r.g and the scaled |r|^2 */
    PCG_DIRECTION, /* p = -g + beta p */
};

/* One part [i0, i1) of pass v->op, each sum in four partial sums as ns_vec_dot's. */
static void pcg_part(void *ctx, int i0, int i1, double sums[2])
{
    const PcgVecs *v = ctx;
    double *restrict r = v->r, *restrict p = v->p, *restrict hp = v->hp;
    const double *g = v->g, *sc = v->sc, *keep = v->keep, a = v->s;
    double s4[4] = {0.0, 0.0, 0.0, 0.0}, t4[4] = {0.0, 0.0, 0.0, 0.0};
    int i = i0;
    sums[0] = sums[1] = 0.0;
    if (v->op == PCG_PRODUCT) {
        for (; i + 4 <= i1; i += 4)
            for (int l = 0; l < 4; l++) {
                double h = keep[i + l] != 0.0 ? hp[i + l] : 0.0;
                hp[i + l] = h;
                s4[l] += p[i + l] * h;
            }
        sums[0] = (s4[0] + s4[1]) + (s4[2] + s4[3]);
        for (; i < i1; i++) {
            hp[i] = keep[i] != 0.0 ? hp[i] : 0.0;
            sums[0] += p[i] * hp[i];
        }
    } else if (v->op == PCG_STEP) {
        int mid = i1 < v->nt3 ? i1 : v->nt3 > i0 ? v->nt3 : i0;
        for (; i < mid; i++)
            v->xt[i] += a * p[i];
        for (; i < i1; i++)
            v->xn[i - v->nt3] += a * p[i];
        for (i = i0; i < i1; i++)
            r[i] += a * hp[i];
    } else if (v->op == PCG_RESIDUAL) {
        for (; i + 4 <= i1; i += 4)
            for (int l = 0; l < 4; l++) {
                double ri = keep[i + l] != 0.0 ? r[i + l] : 0.0, si = sc[i + l] * ri;
                r[i + l] = ri;
                s4[l] += ri * g[i + l];
                t4[l] += si * si;
            }
        sums[0] = (s4[0] + s4[1]) + (s4[2] + s4[3]);
        sums[1] = (t4[0] + t4[1]) + (t4[2] + t4[3]);
        for (; i < i1; i++) {
            double ri = keep[i] != 0.0 ? r[i] : 0.0, si = sc[i] * ri;
            r[i] = ri;
            sums[0] += ri * g[i];
            sums[1] += si * si;
        }
    } else {
        for (; i < i1; i++)
            p[i] = -g[i] + a * p[i];
    }
}

static int ppcg(CoupledSchur *w, CoupledSystem *S, double tol_check, double tol, int max_iter,
                int *iterations, uint8_t *next, int *violations)
{
    int nt3 = S->nt3, n = S->nt3 + S->nr3, q3 = 3 * S->q;
    double *b = w->vec, *r = b + n, *g = r + n, *p = g + n, *hp = p + n, *keep = hp + n;
    double *lam = w->small, *acc = lam + q3, *h = acc + q3, *tmp = h + q3;
    double *xt = S->at, *xn = S->ar;
    /* x as one vector: tissue then needle (S->at and S->ar are separate arrays). */
#define X_GET(out)                                                                                 \
    do {                                                                                           \
        memcpy(out, xt, (size_t)nt3 * sizeof *out);                                                \
        memcpy(out + nt3, xn, (size_t)S->nr3 * sizeof *out);                                       \
    } while (0)
    ns_vec_keep(S->tfixed, nt3, S->rfixed, S->nr3, n, keep);
    /* The right-hand side with the known dynamic friction. */
    memcpy(b, S->bt, (size_t)nt3 * sizeof *b);
    memcpy(b + nt3, S->br, (size_t)S->nr3 * sizeof *b);
    memset(lam, 0, (size_t)q3 * sizeof *lam);
    for (int k = 0; k < S->q; k++)
        if (!is_active(S->st[k], 0))
            lam[3 * k] = coupled_known_force(S, k, S->st[k]);
    add_bt(S, lam, -1.0, b, b + nt3);
    /* Reference norm: b - H x_fixed, scaled (as coupled_paper.c's). */
    X_GET(p);
    for (int i = 0; i < nt3; i++)
        if (!S->tfixed[i])
            p[i] = 0.0;
    for (int i = 0; i < S->nr3; i++)
        if (!S->rfixed[i])
            p[nt3 + i] = 0.0;
    int tissue_held = 0; /* a held tissue DOF with a nonzero acceleration (none, as a rule) */
    for (int i = 0; i < nt3 && !tissue_held; i++)
        tissue_held = p[i] != 0.0;
    if (tissue_held) {
        hmul(S, p, hp);
    } else { /* the same numbers without the product of A_t with zeros */
        memset(hp, 0, (size_t)nt3 * sizeof *hp);
        ns_banded_mul(S->Ar, p + nt3, hp + nt3);
        mask_fixed(S, hp);
    }
    double bnorm = 0.0;
    for (int i = 0; i < n; i++) {
        int fixed = i < nt3 ? S->tfixed[i] : S->rfixed[i - nt3];
        if (!fixed)
            bnorm += (w->sc[i] * (b[i] - hp[i])) * (w->sc[i] * (b[i] - hp[i]));
    }
    bnorm = sqrt(bnorm);
    /* A feasible start: the warm start moved onto the constraints (B x = e on active rows). */
    constraint_rows(S, xt, xn, h);
    for (int j = 0; j < q3; j++)
        h[j] -= S->e[j];
    active_solve(w, S, h, lam, tmp);
    add_response(w, S, lam, xt, xn);
    /* r = H x - b, projected; the multipliers accumulate in acc (c = -acc). */
    X_GET(p);
    hmul(S, p, r);
    for (int i = 0; i < n; i++)
        r[i] -= b[i];
    mask_fixed(S, r);
    memset(acc, 0, (size_t)q3 * sizeof *acc);
    if (project(w, S, r, g, lam, h, tmp))
        return -1;
    add_bt(S, lam, -1.0, r, r + nt3);
    mask_fixed(S, r);
    for (int j = 0; j < q3; j++)
        acc[j] += lam[j];
    double rg = ns_vec_dot(r, g, n);
    for (int i = 0; i < n; i++)
        p[i] = -g[i];
    int it = 0, cap = max_iter < STALE_MAX_ITER ? max_iter : STALE_MAX_ITER;
    double rn2 = 0.0;
    for (int i = 0; i < n; i++)
        rn2 += (w->sc[i] * r[i]) * (w->sc[i] * r[i]);
    int checked = next == NULL;
    if (violations)
        *violations = 0;
    /* The iteration's vector work in four passes, each over the two parts of the vectors that
     * the tissue product gives its two threads, run at once on them (vec.h). */
    PcgVecs v = {xt, xn, r, g, p, hp, w->sc, keep, nt3, PCG_PRODUCT, 0.0};
    int cut = ns_vec_cut(nt3, n), nth = S->threads > 1 && cut > 0 ? 2 : 1;
    while (bnorm > 0.0 && it < cap) {
        if (!checked && sqrt(rn2) <= tol_check * bnorm) {
            checked = 1;
            forces_from(S, acc);
            if ((*violations = coupled_check(S, S->st, S->cf, S->at, S->ar, next)) > 0)
                break;
        }
        if (sqrt(rn2) <= tol * bnorm)
            break;
        hmul_all(S, p, hp);
        double sums[2];
        v.op = PCG_PRODUCT;
        ns_vec_pass(pcg_part, &v, n, cut, nth, sums);
        double php = sums[0];
        if (!(php > 0.0))
            break;
        v.s = rg / php;
        v.op = PCG_STEP;
        ns_vec_pass(pcg_part, &v, n, cut, nth, sums);
        if (project(w, S, r, g, lam, h, tmp))
            return -1;
        add_bt(S, lam, -1.0, r, r + nt3);
        for (int j = 0; j < q3; j++)
            acc[j] += lam[j];
        /* The fixed entries of r zeroed (mask_fixed), r.g and the scaled |r|^2 in one pass. */
        v.op = PCG_RESIDUAL;
        ns_vec_pass(pcg_part, &v, n, cut, nth, sums);
        double rg2 = sums[0];
        rn2 = sums[1];
        v.s = rg2 / rg;
        rg = rg2;
        v.op = PCG_DIRECTION;
        ns_vec_pass(pcg_part, &v, n, cut, nth, sums);
        it++;
    }
#undef X_GET
    *iterations += it;
    S->converged = bnorm == 0.0 || sqrt(rn2) <= tol * bnorm;
    if (it > S->c->params.refresh_iterations)
        w->refresh = 1;
    forces_from(S, acc);
    if (violations && *violations > 0)
        return 0;
    return S->converged || it < cap ? 0 : 1;
}

/* What the step's solves need from the factor in use: the columns of the coupled nodes
 * (F^-1 e, double) and the compliance C, and with tip_block its trailing block made current
 * (docs/solvers.md, "The tail"), the projection's columns Y and Cp. Returns 0 or -1. */
static int prepare(CoupledSchur *w, const CoupledSystem *S, double *nscratch)
{
    int on = S->c->params.tip_block;
    if (on)
        ns_solver_tail_update(w->fac, S->At);
    else
        w->ymode = 0;
    if (cache_fill(w, S) || (on && y_prepare(w, S)))
        return -1;
    if (w->ymode)
        build_cp(w, S);
    return build_compliance(w, S, nscratch);
}

/* Refactor now (the stale factor failed): the cache and C follow. */
static int refresh_now(CoupledSchur *w, CoupledSystem *S, NsCouplingStats *st, double *nscratch)
{
    if (refactor(w, S, st) || prepare(w, S, nscratch))
        return -1;
    w->refreshed = 1;
    return factor_active(w, S, S->st);
}

/* An exact solve of the states S->st to tol (checked at tol_check if next is given, see
 * ppcg); a stale factor that fails gets refreshed once per step and the solve repeated. */
static int solve_exact(CoupledSchur *w, CoupledSystem *S, double tol_check, double tol,
                       uint8_t *next, int *violations, NsCouplingStats *st, double *nscratch)
{
    int max_iter = S->c->params.max_iter;
    int rc = ppcg(w, S, tol_check, tol, max_iter, &st->iterations, next, violations);
    if (rc == 1 && !w->refreshed) {
        if (refresh_now(w, S, st, nscratch))
            return -1;
        rc = ppcg(w, S, tol_check, tol, max_iter, &st->iterations, next, violations);
    }
    return rc < 0 ? -1 : 0;
}

/* Predicts, on C alone, the forces c2 and constraint residuals h2 of the states S->st (w->L
 * factored for them) from an exact solution's c1, h1: dc = c2 - c1 is the known friction's
 * change on inactive components and solves C_aa dc_a = h1_a - C_ak dc_k on active ones;
 * h2 = h1 - C dc. */
static void predict(const CoupledSchur *w, const CoupledSystem *S, const double *c1,
                    const double *h1, double *dc, double *c2, double *h2, double *tmp)
{
    int q3 = 3 * S->q;
    double *rhs = h2; /* used as scratch first */
    for (int j = 0; j < q3; j++) {
        int k = j / 3;
        dc[j] = is_active(S->st[k], j % 3) ? 0.0 : coupled_known_force(S, k, S->st[k]) - c1[j];
    }
    for (int j = 0; j < q3; j++) {
        double s = h1[j];
        for (int l = 0; l < q3; l++)
            if (dc[l] != 0.0)
                s -= w->C[(size_t)j * (size_t)q3 + l] * dc[l];
        rhs[j] = s;
    }
    double *lam = c2; /* scratch */
    active_solve(w, S, rhs, lam, tmp);
    for (int j = 0; j < q3; j++)
        if (is_active(S->st[j / 3], j % 3))
            dc[j] = lam[j];
    for (int j = 0; j < q3; j++) {
        double s = h1[j];
        for (int l = 0; l < q3; l++)
            s -= w->C[(size_t)j * (size_t)q3 + l] * dc[l];
        h2[j] = s;
        c2[j] = c1[j] + dc[j];
    }
}

/* c1, h1 of the current exact solution. */
static void exact_base(const CoupledSystem *S, double *c1, double *h1)
{
    memcpy(c1, S->cf, 3 * (size_t)S->q * sizeof *c1);
    constraint_rows(S, S->at, S->ar, h1);
    for (int j = 0; j < 3 * S->q; j++)
        h1[j] -= S->e[j];
}

int coupled_schur_lcp(CoupledSchur *w, CoupledSystem *S, NsCouplingStats *st)
{
    const NsCouplingParams *prm = &S->c->params;
    int q = S->q, q3 = 3 * q;
    if (ensure_buf(w, S))
        return -1;
    double *c1 = w->small + 4 * (size_t)q3, *h1 = c1 + q3, *dc = h1 + q3, *c2 = dc + q3;
    double *h2 = ns_arena_push(S->arena, (size_t)(2 * q3 + q + S->nr3 + 1) * sizeof *h2);
    uint8_t *next = ns_arena_push(S->arena, (size_t)q + 1);
    uint8_t *cfg = ns_arena_push(S->arena, (size_t)(q > 0 ? q : 1) * (size_t)prm->max_trials);
    if (!h2 || !next || !cfg) {
        ns_arena_pop(S->arena, cfg);
        ns_arena_pop(S->arena, next);
        ns_arena_pop(S->arena, h2);
        return -1;
    }
    double *slide = h2 + q3, *ptmp = slide + q, *nscratch = ptmp + q3;
    /* Scaling of the residual norm: as the paper solver's, a unit diagonal. */
    coupled_unit_scale(S, w->sc);
    int rc = 0;
    w->refreshed = 0;
    ns_solver_set_threads(w->fac, S->threads);
    if (w->pending) {
        int ad = adopt_refresh(w, S);
        if (ad < 0)
            rc = -1;
        st->refactors += ad > 0;
    }
    if (rc == 0 && (w->fac_count == 0 || w->refresh_now || w->n3 != S->nt3 ||
                    ns_solver_factor_count(w->fac) != w->fac_count ||
                    memcmp(w->fixed, S->tfixed, (size_t)S->nt3) != 0)) {
        rc = refactor(w, S, st);
        w->refreshed = rc == 0;
        if (rc)
            S->why = "the tissue matrix could not be factored (not positive definite, or out of "
                     "memory)";
    }
    /* The needle's band matrix is the same through the whole LCP: factored once here for the
     * compliance's 3q solves and one solve per PCG iteration. */
    if (rc == 0 && ns_banded_factor(S->Ar, S->rfixed)) {
        S->why = "the needle's band matrix could not be factored";
        rc = -1;
    }
    if (rc == 0 && prepare(w, S, nscratch))
        rc = -1;
    TriedSet T;
    tried_init(&T, q, cfg, prm->max_trials);
    int have_base = 0;
    st->consistent = 0;
    for (int trial = 0; trial < prm->max_trials && rc == 0; trial++) {
        if (tried_add(&T, S->st)) {
            S->why = "out of memory";
            rc = -1;
            break;
        }
        if (factor_active(w, S, S->st)) {
            S->why = "the contact block of the friction states tried is not positive definite, "
                     "even shifted";
            rc = -1;
            break;
        }
        st->trials++;
        if (have_base) {
            /* A flip: tried on C first; only a configuration consistent there is solved. */
            predict(w, S, c1, h1, dc, c2, h2, ptmp);
            for (int k = 0; k < q; k++)
                slide[k] = S->bdt2 * h2[3 * k];
            if (coupled_check_slides(S, S->st, c2, slide, next)) {
                memcpy(S->st, next, (size_t)q);
                tried_next(&T, S->st);
                continue;
            }
            add_response(w, S, dc, S->at, S->ar); /* warm start: the prediction */
        }
        int bad = 0;
        if (solve_exact(w, S, prm->tau_check, prm->tau_sol, next, &bad, st, nscratch)) {
            if (!S->why)
                S->why = "the preconditioned solve of the coupled system, or the tissue "
                         "matrix's refactorization it asked for, failed";
            rc = -1;
            break;
        }
        exact_base(S, c1, h1);
        have_base = 1;
        if (bad == 0 && coupled_check(S, S->st, S->cf, S->at, S->ar, next) == 0) {
            st->consistent = 1;
            break;
        }
        memcpy(S->st, next, (size_t)q);
        tried_next(&T, S->st);
    }
    if (rc == 0 && !st->consistent) {
        /* Accept the last configuration (§3.6.1), solved exactly. */
        if (factor_active(w, S, S->st))
            rc = -1;
        if (rc == 0 && have_base) {
            predict(w, S, c1, h1, dc, c2, h2, ptmp);
            add_response(w, S, dc, S->at, S->ar);
        }
        if (rc == 0 && solve_exact(w, S, prm->tau_sol, prm->tau_sol, NULL, NULL, st, nscratch))
            rc = -1;
        st->consistent = rc == 0 && coupled_check(S, S->st, S->cf, S->at, S->ar, next) == 0;
    }
    st->unconverged = rc == 0 && !S->converged;
    if (rc == 0 && w->refresh && !w->pending) {
        w->refresh = 0;
        w->refresh_now = schedule_refresh(w, S) != 0;
    }
    tried_free(&T);
    ns_arena_pop(S->arena, cfg);
    ns_arena_pop(S->arena, next);
    ns_arena_pop(S->arena, h2);
    return rc;
}

/* ---- snapshots (sim/snapshot.h) ----
 *
 * Held: the scalars, the factor's solver (ns_solver_pack), the column cache, the scheduled
 * refactorization's nodes and columns, the projection's caches (ydense whole: an entry that
 * came out -0.0f stays so between uses). Scratch that every step writes before it reads it
 * (buf, act, vec, term_col, term_s, yu, yplace) is held as room, not contents; the views into
 * buf as offsets. fixed is read only while a factor is in use (fac_count), job_B and job_Z
 * only while a refactorization is pending. */

/* Every pointer of w NULL: the copy a writer writes, and a read structure before its arrays
 * are read. */
static void schur_forget(void *obj)
{
    CoupledSchur *w = obj;
    w->fac = NULL;
    w->fixed = NULL;
    w->slot = w->node = w->act = w->job_node = w->yi = w->yn = w->yplace = NULL;
    w->cols = w->buf = w->vec = w->term_s = w->job_B = w->job_Z = w->yw = w->yu = NULL;
    w->Zn = w->C = w->L = w->sc = w->small = w->Cp = w->Lp = NULL;
    w->term_col = NULL;
    w->yv = w->yt = w->ydense = NULL;
    w->yp = NULL;
}

/* The arrays of w (malloc'd). */
static void schur_pack_arrays(NsPack *p, CoupledSchur *w)
{
    uint8_t *fixed = w->fac_count ? w->fixed : NULL;
    uint8_t has_fixed = fixed != NULL; /* (a reader's pointers are NULL yet) */
    NS_PACK(p, has_fixed);
    NS_PACK_ARRAY(p, fixed, has_fixed ? w->n3 : 0, has_fixed ? w->n3 + 1 : 0);
    NS_PACK_ARRAY(p, w->slot, w->slot_cap, w->slot_cap);
    NS_PACK_ARRAY(p, w->node, w->count, w->cap);
    NS_PACK_ARRAY(p, w->cols, (size_t)w->count * 3 * (size_t)w->n3, w->cols_cap);
    NS_PACK_ARRAY(p, w->buf, 0, w->buf_cap);
    NS_PACK_ARRAY(p, w->act, 0, w->act_cap);
    NS_PACK_ARRAY(p, w->vec, 0, w->vec_cap);
    NS_PACK_ARRAY(p, w->term_col, 0, w->term_cap);
    NS_PACK_ARRAY(p, w->term_s, 0, w->term_cap);
    NS_PACK_ARRAY(p, w->job_node, w->job_count, w->job_cap);
    double *jb = w->pending ? w->job_B : NULL, *jz = w->pending ? w->job_Z : NULL;
    NS_PACK_ARRAY(p, jb, w->job_len, w->job_len);
    NS_PACK_ARRAY(p, jz, w->job_len, w->job_len);
    NS_PACK_ARRAY(p, w->yi, w->ylen, w->ycap);
    NS_PACK_ARRAY(p, w->yv, w->ylen, w->ycap);
    NS_PACK_ARRAY(p, w->yp, 3 * w->ycount, w->ycols_cap);
    NS_PACK_ARRAY(p, w->yn, 3 * w->ycount, w->ycols_cap);
    size_t ny = (size_t)(3 * w->ycount) * (size_t)w->yk;
    ny = ny < w->ytail_cap ? ny : w->ytail_cap;
    NS_PACK_ARRAY(p, w->yw, ny, w->ytail_cap);
    NS_PACK_ARRAY(p, w->yt, ny, w->ytail_cap);
    NS_PACK_ARRAY(p, w->ydense, w->ydense_cap, w->ydense_cap);
    NS_PACK_ARRAY(p, w->yu, 0, w->yu_cap);
    NS_PACK_ARRAY(p, w->yplace, 0, w->yplace_cap);
    if (!p->writing) {
        w->fixed = fixed;
        w->job_B = jb;
        w->job_Z = jz;
    }
}

static void schur_pack(NsPack *p, CoupledSchur *w)
{
    uint32_t size = sizeof *w;
    NS_PACK(p, size);
    if (!p->writing && !p->failed && size != sizeof *w)
        ns_pack_fail(p, "schur: written by another build (%u bytes, here %zu)", size, sizeof *w);
    double **views[7] = {&w->Zn, &w->C, &w->L, &w->Cp, &w->Lp, &w->sc, &w->small};
    int64_t at[7]; /* their offsets in buf, -1: NULL */
    for (int k = 0; k < 7 && p->writing; k++)
        at[k] = *views[k] ? *views[k] - w->buf : -1;
    ns_pack_scalars(p, w, sizeof *w, schur_forget);
    NS_PACK(p, at);
    ns_solver_pack(p, &w->fac); /* first: waits for the job that writes job_Z */
    schur_pack_arrays(p, w);
    if (p->writing || p->failed)
        return;
    for (int k = 0; k < 7; k++) {
        if (at[k] < -1 || (at[k] >= 0 && (!w->buf || (uint64_t)at[k] > w->buf_cap)))
            ns_pack_fail(p, "schur: bad view of the scratch (%lld)", (long long)at[k]);
        *views[k] = at[k] >= 0 && !p->failed ? w->buf + at[k] : NULL;
    }
    if (w->pending) /* the solver's job computed its columns into job_Z: now these arrays */
        ns_solver_factor_async_moved(w->fac, w->job_B, w->job_Z);
}

int coupled_schur_pack(NsPack *p, CoupledSchur **wp)
{
    CoupledSchur *w = ns_pack_object(p, (void **)wp, sizeof **wp, "schur");
    if (w)
        schur_pack(p, w);
    return p->failed ? -1 : 0;
}

int coupled_schur_pending(const CoupledSchur *w)
{
    return w && w->pending;
}
