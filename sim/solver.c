/* Linear solvers behind one interface (§3.1 Eq. 5-6, §3.6.2): CG and Jacobi-PCG on the block
 * matrix, CHOLMOD supernodal Cholesky, and CG preconditioned by a stale Cholesky factor.
 *
 * Fixed (Dirichlet) DOFs are removed by working on full-length vectors whose fixed entries are
 * held at zero in every search direction, after moving A_fc x_c to the right-hand side. The
 * CHOLMOD paths copy the free-free block into compressed-column form (upper triangle); the
 * symbolic analysis (METIS ordering) is redone only when the sparsity pattern changes. */
#include "solver.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include <cholmod.h>

struct NsSolver {
    NsSolverKind kind;
    int refresh_iterations;
    cholmod_common cm;
    int cm_started;
    cholmod_factor *L; /* factor of the last factorized matrix (possibly stale) */
    uint64_t pattern;  /* hash of the pattern L was analyzed for */
    int nfree;         /* scalar free DOFs L was built for */
    int *dof;          /* (3n) free index of each scalar DOF, -1 if fixed */
    int dof_cap;
    double *work; /* 5 vectors of 3n for CG */
    int work_cap;
};

const char *ns_solver_name(NsSolverKind kind)
{
    switch (kind) {
    case NS_SOLVER_CG:
        return "cg";
    case NS_SOLVER_JACOBI_PCG:
        return "jacobi-pcg";
    case NS_SOLVER_DIRECT:
        return "cholmod";
    case NS_SOLVER_STALE_PCG:
        return "stale-pcg";
    }
    return "?";
}

NsSolver *ns_solver_create(NsSolverKind kind)
{
    NsSolver *s = calloc(1, sizeof *s);
    if (!s)
        return NULL;
    s->kind = kind;
    s->refresh_iterations = 25;
    if (kind == NS_SOLVER_DIRECT || kind == NS_SOLVER_STALE_PCG) {
        cholmod_start(&s->cm);
        s->cm_started = 1;
        s->cm.supernodal = CHOLMOD_SUPERNODAL;
        /* One ordering, METIS nested dissection: the fill-reducing choice for 3D meshes. */
        s->cm.nmethods = 1;
        s->cm.method[0].ordering = CHOLMOD_METIS;
        s->cm.postorder = 1;
        s->cm.print = 0;
        s->cm.error_handler = NULL;
    }
    return s;
}

void ns_solver_destroy(NsSolver *s)
{
    if (!s)
        return;
    if (s->cm_started) {
        if (s->L)
            cholmod_free_factor(&s->L, &s->cm);
        cholmod_finish(&s->cm);
    }
    free(s->dof);
    free(s->work);
    free(s);
}

NsSolverKind ns_solver_kind(const NsSolver *s)
{
    return s->kind;
}

void ns_solver_set_refresh_iterations(NsSolver *s, int iterations)
{
    s->refresh_iterations = iterations > 0 ? iterations : 1;
}

void ns_solver_refresh(NsSolver *s)
{
    if (s->L)
        cholmod_free_factor(&s->L, &s->cm);
}

static int ensure(void **p, int *cap, int need, size_t elem)
{
    if (need <= *cap)
        return 0;
    void *q = realloc(*p, (size_t)need * elem);
    if (!q)
        return -1;
    *p = q;
    *cap = need;
    return 0;
}

/* Number the free scalar DOFs in node order; returns their count, or -1 (memory). */
static int number_dofs(NsSolver *s, int n, const uint8_t *fixed)
{
    if (ensure((void **)&s->dof, &s->dof_cap, 3 * n > 0 ? 3 * n : 1, sizeof(int)))
        return -1;
    int f = 0;
    for (int i = 0; i < 3 * n; i++)
        s->dof[i] = (fixed && fixed[i]) ? -1 : f++;
    return f;
}

static uint64_t pattern_hash(const NsBlockMatrix *A, const int *dof)
{
    uint64_t h = 1469598103934665603ull;
    for (int i = 0; i < A->n; i++) {
        for (int c = 0; c < 3; c++)
            h = (h ^ (uint64_t)(uint32_t)(dof[3 * i + c] >= 0)) * 1099511628211ull;
        for (int p = 0; p < A->rows[i].count; p++)
            h = (h ^ (uint64_t)(uint32_t)A->rows[i].col[p]) * 1099511628211ull;
        h = (h ^ 0xFFFFu) * 1099511628211ull;
    }
    return h;
}

/* The free-free block of A, upper triangle, compressed columns (row q = (J, c) of A gives
 * column q of the upper triangle by symmetry). */
static cholmod_sparse *to_cholmod(NsSolver *s, const NsBlockMatrix *A, int nfree)
{
    size_t nnz = 0;
    for (int J = 0; J < A->n; J++)
        nnz += (size_t)A->rows[J].count * 9;
    cholmod_sparse *M =
        cholmod_allocate_sparse((size_t)nfree, (size_t)nfree, nnz, 1, 1, 1, CHOLMOD_REAL, &s->cm);
    if (!M)
        return NULL;
    int *Ap = M->p, *Ai = M->i;
    double *Ax = M->x;
    size_t k = 0;
    for (int J = 0; J < A->n; J++)
        for (int c = 0; c < 3; c++) {
            int q = s->dof[3 * J + c];
            if (q < 0)
                continue;
            Ap[q] = (int)k;
            const NsBlockRow *r = &A->rows[J];
            for (int e = 0; e < r->count; e++) {
                int I = r->col[e];
                for (int c2 = 0; c2 < 3; c2++) {
                    int p = s->dof[3 * I + c2];
                    if (p < 0 || p > q)
                        continue;
                    Ai[k] = p;
                    Ax[k] = r->val[9 * e + 3 * c + c2];
                    k++;
                }
            }
        }
    Ap[nfree] = (int)k;
    return M;
}

/* Factor A's free block into s->L (analysis only if the pattern changed). */
static int factorize(NsSolver *s, const NsBlockMatrix *A, int nfree, NsSolveStats *st)
{
    cholmod_sparse *M = to_cholmod(s, A, nfree);
    if (!M)
        return -1;
    uint64_t h = pattern_hash(A, s->dof);
    if (s->L && (h != s->pattern || nfree != s->nfree))
        cholmod_free_factor(&s->L, &s->cm);
    if (!s->L) {
        s->L = cholmod_analyze(M, &s->cm);
        if (!s->L || s->cm.status < CHOLMOD_OK) {
            cholmod_free_sparse(&M, &s->cm);
            return -1;
        }
        s->pattern = h;
        s->nfree = nfree;
        st->analyzed = 1;
    }
    int ok = cholmod_factorize(M, s->L, &s->cm);
    cholmod_free_sparse(&M, &s->cm);
    st->factorized = 1;
    if (!ok || s->cm.status != CHOLMOD_OK || s->L->minor < (size_t)nfree) {
        cholmod_free_factor(&s->L, &s->cm);
        return -1;
    }
    return 0;
}

/* z = L^-1 r on the free DOFs of full-length vectors. */
static int apply_factor(NsSolver *s, int n3, const double *r, double *z)
{
    cholmod_dense *B =
        cholmod_allocate_dense((size_t)s->nfree, 1, (size_t)s->nfree, CHOLMOD_REAL, &s->cm);
    if (!B)
        return -1;
    double *bx = B->x;
    for (int i = 0; i < n3; i++)
        if (s->dof[i] >= 0)
            bx[s->dof[i]] = r[i];
    cholmod_dense *X = cholmod_solve(CHOLMOD_A, s->L, B, &s->cm);
    cholmod_free_dense(&B, &s->cm);
    if (!X)
        return -1;
    const double *xx = X->x;
    for (int i = 0; i < n3; i++)
        z[i] = s->dof[i] >= 0 ? xx[s->dof[i]] : 0.0;
    cholmod_free_dense(&X, &s->cm);
    return 0;
}

static double dot_free(const int *dof, int n3, const double *a, const double *b)
{
    double d = 0.0;
    for (int i = 0; i < n3; i++)
        if (dof[i] >= 0)
            d += a[i] * b[i];
    return d;
}

int ns_solver_solve(NsSolver *s, const NsBlockMatrix *A, const uint8_t *node_fixed, const double *b,
                    double *x, double tol, int max_iter, NsSolveStats *stats)
{
    NsSolveStats st = {0, 0.0, 0, 0, 0};
    int n3 = 3 * A->n;
    int nfree = number_dofs(s, A->n, node_fixed);
    if (nfree < 0)
        return -1;
    if (ensure((void **)&s->work, &s->work_cap, 5 * (n3 > 0 ? n3 : 1), sizeof(double)))
        return -1;
    double *r = s->work, *z = r + n3, *p = z + n3, *q = p + n3, *diag = q + n3;
    const int *dof = s->dof;

    /* r = b - A x over free DOFs (fixed entries of x act through A_fc). */
    ns_bsm_mul(A, x, q);
    for (int i = 0; i < n3; i++)
        r[i] = dof[i] >= 0 ? b[i] - q[i] : 0.0;
    /* The reference norm: b_f - A_fc x_c, i.e. the residual at x_f = 0. */
    for (int i = 0; i < n3; i++)
        p[i] = dof[i] >= 0 ? 0.0 : x[i];
    ns_bsm_mul(A, p, q);
    double bnorm = 0.0;
    for (int i = 0; i < n3; i++)
        if (dof[i] >= 0)
            bnorm += (b[i] - q[i]) * (b[i] - q[i]);
    bnorm = sqrt(bnorm);
    if (bnorm == 0.0) {
        for (int i = 0; i < n3; i++)
            if (dof[i] >= 0)
                x[i] = 0.0;
        st.converged = 1;
        if (stats)
            *stats = st;
        return 0;
    }

    if (s->kind == NS_SOLVER_DIRECT) {
        if (factorize(s, A, nfree, &st) || apply_factor(s, n3, r, z)) {
            if (stats)
                *stats = st;
            return -1;
        }
        for (int i = 0; i < n3; i++)
            if (dof[i] >= 0)
                x[i] += z[i];
        ns_bsm_mul(A, x, q);
        double rr = 0.0;
        for (int i = 0; i < n3; i++)
            if (dof[i] >= 0)
                rr += (b[i] - q[i]) * (b[i] - q[i]);
        st.residual = sqrt(rr) / bnorm;
        st.converged = st.residual <= tol || tol <= 0.0;
        if (stats)
            *stats = st;
        return 0;
    }

    if (s->kind == NS_SOLVER_STALE_PCG) {
        uint64_t h = pattern_hash(A, dof);
        if (!s->L || h != s->pattern || nfree != s->nfree)
            if (factorize(s, A, nfree, &st)) {
                if (stats)
                    *stats = st;
                return -1;
            }
    }
    if (s->kind == NS_SOLVER_JACOBI_PCG)
        for (int i = 0; i < A->n; i++) {
            const double *blk = ns_bsm_find(A, i, i);
            for (int c = 0; c < 3; c++)
                diag[3 * i + c] = blk && blk[4 * c] > 0.0 ? 1.0 / blk[4 * c] : 1.0;
        }

    /* Preconditioned conjugate gradients, warm-started from x. */
    int retried = 0;
restart:;
    double rnorm = sqrt(dot_free(dof, n3, r, r));
    int it = 0;
    double rz = 0.0;
    while (rnorm > tol * bnorm && it < max_iter) {
        if (s->kind == NS_SOLVER_STALE_PCG) {
            if (apply_factor(s, n3, r, z)) {
                if (stats)
                    *stats = st;
                return -1;
            }
        } else if (s->kind == NS_SOLVER_JACOBI_PCG) {
            for (int i = 0; i < n3; i++)
                z[i] = dof[i] >= 0 ? diag[i] * r[i] : 0.0;
        } else {
            memcpy(z, r, (size_t)n3 * sizeof(double));
        }
        double rz_new = dot_free(dof, n3, r, z);
        if (it == 0) {
            memcpy(p, z, (size_t)n3 * sizeof(double));
        } else {
            double beta = rz_new / rz;
            for (int i = 0; i < n3; i++)
                p[i] = z[i] + beta * p[i];
        }
        rz = rz_new;
        ns_bsm_mul(A, p, q);
        double pq = dot_free(dof, n3, p, q);
        if (!(pq > 0.0))
            break; /* not positive definite along p: stop, report unconverged */
        double alpha = rz / pq;
        for (int i = 0; i < n3; i++)
            if (dof[i] >= 0) {
                x[i] += alpha * p[i];
                r[i] -= alpha * q[i];
            }
        rnorm = sqrt(dot_free(dof, n3, r, r));
        it++;
    }
    st.iterations += it;
    /* A stale factor that no longer preconditions well is replaced, and the solve finished
     * with the fresh one (DESIGN.md: refresh when iterations grow). */
    if (s->kind == NS_SOLVER_STALE_PCG && !retried &&
        (it > s->refresh_iterations || rnorm > tol * bnorm) && !st.factorized) {
        retried = 1;
        if (factorize(s, A, nfree, &st) == 0) {
            ns_bsm_mul(A, x, q);
            for (int i = 0; i < n3; i++)
                r[i] = dof[i] >= 0 ? b[i] - q[i] : 0.0;
            goto restart;
        }
    }
    st.residual = rnorm / bnorm;
    st.converged = rnorm <= tol * bnorm;
    if (stats)
        *stats = st;
    return 0;
}
