/* Linear solvers behind one interface (§3.1 Eq. 5-6, §3.6.2): CG and Jacobi-PCG on the block
 * matrix, CHOLMOD supernodal Cholesky, and CG preconditioned by a stale Cholesky factor that is
 * refreshed on a background thread (solver.h).
 *
 * Fixed (Dirichlet) DOFs are removed by working on full-length vectors whose fixed entries are
 * held at zero in every search direction, after moving A_fc x_c to the right-hand side. The
 * CHOLMOD paths copy the free-free block into compressed-column form (upper triangle); the
 * symbolic analysis (METIS ordering) is redone only when the sparsity pattern changes, and kept
 * apart (Lsym) so that a refactorization only copies it.
 *
 * Determinism (STYLE.md §8) across thread counts: the vector operations work on fixed chunks of
 * CHUNK entries; a chunk is computed whole by one thread, and a dot product is the sum of the
 * chunk partials taken in chunk order on the calling thread. */
#include "solver.h"
#include "snapshot.h"

#include "ns_config.h"
#include "supernodal.h"

#include <limits.h>
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#include <cholmod.h>

#if NS_HAVE_OPENMP
#include <omp.h>
#endif

#if NS_HAVE_OPENBLAS
/* From OpenBLAS (declared here, as in engine/main.c, to avoid depending on its cblas.h). */
void openblas_set_num_threads(int num_threads);
#endif

/* Entries per partial sum of a dot product. Fixed, so sums never depend on the thread count. */
#define CHUNK 1024
/* Vectors shorter than this stay on one thread: an operation on 4k entries takes about as long
 * as waking the other threads. */
#define PARALLEL_MIN (4 * CHUNK)

/* A refactorization scheduled by a slow STALE_PCG solve, run by a worker thread (or by the
 * scheduling solve itself with one thread) and adopted by solve adopt_at. While running is set,
 * the worker owns cm, M and L, and reads `symbolic`; the solver touches none of them. */
typedef struct RefreshJob {
    int pending;      /* scheduled, not yet adopted or dropped */
    int running;      /* a worker thread was started and not yet joined */
    pthread_t thread; /* valid while running */
    atomic_int done;  /* set by the worker when it finishes (only to lend its core back) */
    long made_at;     /* the solve whose matrix is factored */
    long adopt_at;    /* the solve that adopts the factor */
    uint64_t pattern; /* pattern hash and free DOF count of that matrix */
    int nfree;
    cholmod_common cm; /* the worker's own: CHOLMOD is thread-safe with one common per thread */
    int cm_started;
    cholmod_sparse *M;        /* the matrix to factor; the worker frees it */
    cholmod_factor *symbolic; /* the solver's Lsym, read-only while the job exists */
    cholmod_factor *L; /* in: a numeric factor to overwrite, or NULL; out: the factor, or NULL
                          if the factorization failed */
    NsSuperFactor *sf; /* out: L's single-precision copy (NULL: none, CHOLMOD's solve is used) */
    /* ns_solver_factor_async's columns: Z = A^-1 B with the new factor (ncols of n3 each, dof
     * the free numbering of that matrix, the job's own copy); cols_ok is set when they were. */
    int ncols, n3, cols_ok;
    const double *B;
    double *Z;
    int *dof;
    int dof_cap;
    /* out: the tail's blocks of L (tail_extract), when the analysis has a tail */
    double *tail_S, *tail_L0;
    int tail_k, tail_ok;
} RefreshJob;

struct NsSolver {
    NsSolverKind kind;
    int refresh_iterations;
    int refresh_lag;
    int threads;
    long solves; /* solve calls so far; the clock of refreshes */
    cholmod_common cm;
    int cm_started;
    cholmod_factor *Lsym;  /* symbolic analysis (ordering, supernodes) for `pattern` */
    cholmod_factor *L;     /* numeric factor in use (possibly stale), NULL if none */
    NsSuperFactor *sf;     /* L's single-precision copy for preconditioning (supernodal.h), made
                              at L's first preconditioning (a background refactorization makes
                              it on its thread), or NULL: then CHOLMOD's solve preconditions */
    int sf_tried;          /* the copy of this L was attempted */
    cholmod_factor *spare; /* a numeric factor of the same analysis no longer in use: the next
                              factorization overwrites it rather than allocating (~10 ms of page
                              faults for the box's 24 MB factor) */
    long factor_solve;     /* the solve whose matrix L is the factor of */
    long factors;          /* factors made and adopted so far (ns_solver_factor_count) */
    uint64_t pattern;      /* hash of the pattern Lsym was analyzed for */
    int nfree;             /* scalar free DOFs Lsym was built for */
    RefreshJob job;
    /* Dense vectors of cholmod_solve2, kept between solves (allocating them in every PCG
     * iteration cost more than the triangular solves). */
    cholmod_dense *B, *X, *Y, *E;
    int *dof; /* (3n) free index of each scalar DOF, -1 if fixed */
    int n3;   /* 3n of the last numbering */
    int dof_cap;
    /* The same numbering the other way: free DOF f is scalar DOF dof_src[f] (nfree of the
     * last numbering), and the fixed ones, dof_held[0..nheld). */
    int *dof_src, *dof_held;
    int nsrc, nheld, src_cap, held_cap;
    double *work; /* 5 vectors of 3n for CG, then the chunk partial sums */
    int work_cap;
    /* The tail (docs/solvers.md, "The tail"): nodes the caller asked to be ordered last at the
     * next analysis (tail_req), and the free DOFs that Lsym's ordering put last (tail_k, 0 if
     * none). For the factor in use: tail_L0 its trailing block L22 and tail_S = A22 - L22 L22^T
     * (k x k, column-major), the part of the trailing Schur complement that comes from the
     * rest of the matrix. ns_solver_tail_update refactors A22_now - tail_S into the copy. */
    int *tail_req, tail_nreq, tail_req_cap;
    int tail_k, tail_ok;
    double *tail_S, *tail_L0, *tail_D;
    const double *tail_cur; /* the block in the copy now: tail_D or tail_L0 */
    size_t tail_cap;
    int *iperm; /* (nfree) the copy's numbering of each free DOF */
    int iperm_cap;
    const NsSuperFactor *iperm_of;
};

#if NS_HAVE_OPENBLAS
static pthread_once_t blas_once = PTHREAD_ONCE_INIT;
static void blas_one_thread(void)
{
    /* CHOLMOD's BLAS calls run on the thread that makes them; more BLAS threads would compete
     * with a background refactorization and with our own loops for 2 cores. */
    openblas_set_num_threads(1);
}
#endif

/* CHOLMOD from 4.0 has a run-time thread limit (nthreads_max). CHOLMOD 3.0.14 (Debian 12) has
 * none: its supernodal loops say num_threads(CHOLMOD_OMP_NUM_THREADS), 4 at compile time, which
 * OMP_NUM_THREADS cannot lower (a factorization starts 3 more threads with OMP_NUM_THREADS=1),
 * and they made the factorization slower on 2 cores: 44-52 ms against 32 ms (DESIGN.md); on the
 * same 2-core box, here, ~100-180 ms against ~45-65 ms, and the analysis too. Allowing no
 * active parallel level in the calling thread for the length of the call runs them on that
 * thread alone. libgomp (GCC 11 on) keeps this setting per thread, so a background
 * refactorization does not serialize our loops on the main thread. Without OpenMP in our build
 * we cannot reach libgomp; OMP_THREAD_LIMIT=1 in the environment does the same then. */
typedef struct OmpSerial {
    int levels;
} OmpSerial;

static OmpSerial omp_serial_begin(void)
{
    OmpSerial o = {0};
#if NS_HAVE_OPENMP && CHOLMOD_MAIN_VERSION < 4
    o.levels = omp_get_max_active_levels();
    omp_set_max_active_levels(0);
#endif
    return o;
}

static void omp_serial_end(OmpSerial o)
{
#if NS_HAVE_OPENMP && CHOLMOD_MAIN_VERSION < 4
    omp_set_max_active_levels(o.levels);
#else
    (void)o;
#endif
}

static void start_common(cholmod_common *cm)
{
    cholmod_start(cm);
    cm->supernodal = CHOLMOD_SUPERNODAL;
    /* One ordering, METIS nested dissection: the fill-reducing choice for 3D meshes. */
    cm->nmethods = 1;
    cm->method[0].ordering = CHOLMOD_METIS;
    cm->postorder = 1;
    cm->print = 0;
    cm->error_handler = NULL;
#if CHOLMOD_MAIN_VERSION >= 4
    cm->nthreads_max = 1; /* see omp_serial_begin */
#endif
}

/* The solver's own common, and BLAS on one thread (the kinds with a factor). */
static void start_solver_common(NsSolver *s)
{
#if NS_HAVE_OPENBLAS
    pthread_once(&blas_once, blas_one_thread);
#endif
    start_common(&s->cm);
    s->cm_started = 1;
}

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
    s->refresh_lag = 2;
    s->threads = 1;
    atomic_init(&s->job.done, 0);
    if (kind == NS_SOLVER_DIRECT || kind == NS_SOLVER_STALE_PCG)
        start_solver_common(s);
    return s;
}

/* Wait for the worker thread, if there is one. */
static void job_join(NsSolver *s)
{
    if (s->job.running) {
        pthread_join(s->job.thread, NULL);
        s->job.running = 0;
    }
}

/* Drop the pending refactorization, waiting for its thread. */
static void job_cancel(NsSolver *s)
{
    RefreshJob *j = &s->job;
    job_join(s);
    if (j->M)
        cholmod_free_sparse(&j->M, &j->cm);
    if (j->L)
        cholmod_free_factor(&j->L, &j->cm);
    ns_super_free(j->sf);
    j->sf = NULL;
    j->pending = 0;
}

/* Drops the single-precision copy: s->L changed. The next preconditioning makes one (solvers
 * that only solve exactly never pay for it). */
static void drop_super(NsSolver *s)
{
    ns_super_free(s->sf);
    s->sf = NULL;
    s->sf_tried = 0;
    s->iperm_of = NULL;
}

static void free_factors(NsSolver *s)
{
    drop_super(s);
    s->tail_k = 0;
    s->tail_ok = 0;
    s->tail_cur = NULL;
    if (s->L)
        cholmod_free_factor(&s->L, &s->cm);
    if (s->spare)
        cholmod_free_factor(&s->spare, &s->cm);
    if (s->Lsym)
        cholmod_free_factor(&s->Lsym, &s->cm);
}

void ns_solver_destroy(NsSolver *s)
{
    if (!s)
        return;
    job_cancel(s);
    if (s->job.cm_started)
        cholmod_finish(&s->job.cm);
    if (s->cm_started) {
        free_factors(s);
        cholmod_free_dense(&s->B, &s->cm);
        cholmod_free_dense(&s->X, &s->cm);
        cholmod_free_dense(&s->Y, &s->cm);
        cholmod_free_dense(&s->E, &s->cm);
        cholmod_finish(&s->cm);
    }
    ns_super_free(s->sf);
    free(s->dof_src);
    free(s->dof_held);
    free(s->dof);
    free(s->job.dof);
    free(s->job.tail_S);
    free(s->job.tail_L0);
    free(s->work);
    free(s->tail_req);
    free(s->tail_S);
    free(s->tail_L0);
    free(s->tail_D);
    free(s->iperm);
    free(s);
}

NsSolverKind ns_solver_kind(const NsSolver *s)
{
    return s->kind;
}

void ns_solver_set_threads(NsSolver *s, int threads)
{
    s->threads = threads > 1 ? threads : 1;
}

void ns_solver_set_refresh_iterations(NsSolver *s, int iterations)
{
    s->refresh_iterations = iterations > 0 ? iterations : 1;
}

void ns_solver_set_refresh_lag(NsSolver *s, int lag)
{
    s->refresh_lag = lag > 0 ? lag : 0;
}

void ns_solver_refresh(NsSolver *s)
{
    job_cancel(s);
    if (s->L && !s->spare)
        s->spare = s->L; /* its memory is reused by the next factorization */
    else if (s->L)
        cholmod_free_factor(&s->L, &s->cm);
    s->L = NULL;
    drop_super(s);
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
    int m = 3 * n > 0 ? 3 * n : 1;
    if (ensure((void **)&s->dof, &s->dof_cap, m, sizeof(int)) ||
        ensure((void **)&s->dof_src, &s->src_cap, m, sizeof(int)) ||
        ensure((void **)&s->dof_held, &s->held_cap, m, sizeof(int)))
        return -1;
    int f = 0, h = 0;
    s->n3 = 3 * n;
    for (int i = 0; i < 3 * n; i++) {
        int held = fixed && fixed[i];
        s->dof[i] = held ? -1 : f;
        if (held)
            s->dof_held[h++] = i;
        else
            s->dof_src[f++] = i;
    }
    s->nsrc = f;
    s->nheld = h;
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
static cholmod_sparse *to_cholmod(const NsBlockMatrix *A, const int *dof, int nfree,
                                  cholmod_common *cm)
{
    size_t nnz = 0;
    for (int J = 0; J < A->n; J++)
        nnz += (size_t)A->rows[J].count * 9;
    cholmod_sparse *M =
        cholmod_allocate_sparse((size_t)nfree, (size_t)nfree, nnz, 1, 1, 1, CHOLMOD_REAL, cm);
    if (!M)
        return NULL;
    int *Ap = M->p, *Ai = M->i;
    double *Ax = M->x;
    size_t k = 0;
    for (int J = 0; J < A->n; J++)
        for (int c = 0; c < 3; c++) {
            int q = dof[3 * J + c];
            if (q < 0)
                continue;
            Ap[q] = (int)k;
            const NsBlockRow *r = &A->rows[J];
            for (int e = 0; e < r->count; e++) {
                int I = r->col[e];
                for (int c2 = 0; c2 < 3; c2++) {
                    int p = dof[3 * I + c2];
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

/* ---- The tail (docs/solvers.md, "The tail") ---- */

/* The analysis of M: METIS's ordering, with the free DOFs of the requested tail nodes moved
 * to its end when there are any (then *tail_k is their count). */
static cholmod_factor *analyze(NsSolver *s, cholmod_sparse *M, int *tail_k)
{
    *tail_k = 0;
    int n = (int)M->nrow, k = 0;
    int *perm = NULL;
    unsigned char *mark = NULL;
    cholmod_factor *L = NULL;
    if (s->tail_nreq > 0 && n > 0) {
        perm = malloc(2 * (size_t)n * sizeof *perm);
        mark = calloc((size_t)n, 1);
    }
    if (perm && mark) {
        int *tail = perm + n;
        for (int i = 0; i < s->tail_nreq; i++)
            for (int c = 0; c < 3; c++) {
                int d = 3 * s->tail_req[i] + c;
                int f = d < s->n3 ? s->dof[d] : -1;
                if (f >= 0 && !mark[f]) {
                    mark[f] = 1;
                    tail[k++] = f;
                }
            }
        if (k > 0 && 2 * k < n && cholmod_metis(M, NULL, 0, 1, perm, &s->cm)) {
            int m = 0;
            for (int i = 0; i < n; i++)
                if (!mark[perm[i]])
                    perm[m++] = perm[i];
            memmove(perm + m, tail, (size_t)k * sizeof *perm); /* m = n - k */
            /* The elimination tree's postorder, which the supernodal analysis needs, with each
             * node's tail child visited last (the heaviest child goes last), so the tail stays
             * at the end: CHOLMOD's own postorder moved other subtrees behind it. */
            int *parent = malloc(3 * (size_t)n * sizeof *parent), *post = parent + n,
                *wt = post + n;
            cholmod_sparse *C1 = parent ? cholmod_ptranspose(M, 1, perm, NULL, 0, &s->cm) : NULL;
            cholmod_sparse *C2 = C1 ? cholmod_transpose(C1, 1, &s->cm) : NULL;
            int post_ok = C2 && cholmod_etree(C2, parent, &s->cm);
            for (int i = 0; post_ok && i < n; i++)
                wt[i] = i >= m;
            post_ok = post_ok && cholmod_postorder(parent, (size_t)n, wt, post, &s->cm) == n;
            for (int i = 0; post_ok && i < n; i++)
                wt[i] = perm[post[i]];
            if (post_ok)
                memcpy(perm, wt, (size_t)n * sizeof *perm);
            cholmod_free_sparse(&C1, &s->cm);
            cholmod_free_sparse(&C2, &s->cm);
            free(parent);
            int saved = s->cm.method[0].ordering, saved_post = s->cm.postorder;
            s->cm.method[0].ordering = CHOLMOD_GIVEN;
            s->cm.postorder = 0;
            L = post_ok ? cholmod_analyze_p(M, perm, NULL, 0, &s->cm) : NULL;
            s->cm.method[0].ordering = saved;
            s->cm.postorder = saved_post;
            int ok = L && s->cm.status >= CHOLMOD_OK && L->Perm;
            for (int i = n - k; ok && i < n; i++)
                ok = mark[((const int *)L->Perm)[i]]; /* still last after the postorder */
            if (!ok && L)
                cholmod_free_factor(&L, &s->cm);
            if (ok)
                *tail_k = k;
        }
    }
    free(perm);
    free(mark);
    return L ? L : cholmod_analyze(M, &s->cm);
}

/* From a numeric factor L of M whose ordering ends with k tail DOFs: L0 = L's trailing k x k
 * block and S = A22 - L0 L0^T (k x k, column-major; A22 = M's trailing block in L's order).
 * pos: n ints of scratch. */
static void tail_extract(const cholmod_factor *L, const cholmod_sparse *M, int k, double *S,
                         double *L0, int *pos)
{
    int n = (int)L->n, t0 = n - k;
    const int *perm = L->Perm, *Ls = L->super, *Lpi = L->pi, *Lpx = L->px, *Lrows = L->s;
    const double *lx = L->x;
    memset(S, 0, (size_t)k * (size_t)k * sizeof *S);
    memset(L0, 0, (size_t)k * (size_t)k * sizeof *L0);
    for (int i = 0; i < n; i++)
        pos[i] = -1;
    for (int i = 0; i < k; i++)
        pos[perm[t0 + i]] = i;
    const int *Mp = M->p, *Mi = M->i;
    const double *Mx = M->x;
    for (int i = 0; i < k; i++) { /* A22 into S: M holds the upper triangle */
        int q = perm[t0 + i];
        for (int p = Mp[q]; p < Mp[q + 1]; p++) {
            int j = pos[Mi[p]];
            if (j >= 0) {
                S[i + (size_t)k * j] = Mx[p];
                S[j + (size_t)k * i] = Mx[p];
            }
        }
    }
    int sn = (int)L->nsuper - 1;
    for (int c = n - 1; c >= t0; c--) {
        while (sn > 0 && Ls[sn] > c)
            sn--;
        int nr = Lpi[sn + 1] - Lpi[sn];
        const double *xc = lx + Lpx[sn] + (size_t)(c - Ls[sn]) * (size_t)nr;
        for (int r = 0; r < nr; r++) {
            int row = Lrows[Lpi[sn] + r];
            if (row >= c)
                L0[(row - t0) + (size_t)k * (c - t0)] = xc[r];
        }
    }
    for (int j = 0; j < k; j++)
        for (int i = j; i < k; i++) {
            double v = S[i + (size_t)k * j];
            for (int m = 0; m <= j; m++)
                v -= L0[i + (size_t)k * m] * L0[j + (size_t)k * m];
            S[i + (size_t)k * j] = v;
            S[j + (size_t)k * i] = v;
        }
}

/* Room for the tail's k x k blocks in the solver and its job. */
static int tail_alloc(NsSolver *s, int k)
{
    size_t need = (size_t)k * (size_t)k + 1;
    if (need <= s->tail_cap)
        return 0;
    double *a = realloc(s->tail_S, need * sizeof *a), *b = NULL, *c = NULL, *d = NULL, *e = NULL;
    if (a)
        s->tail_S = a;
    b = realloc(s->tail_L0, need * sizeof *b);
    if (b)
        s->tail_L0 = b;
    c = realloc(s->tail_D, need * sizeof *c);
    if (c)
        s->tail_D = c;
    d = realloc(s->job.tail_S, need * sizeof *d);
    if (d)
        s->job.tail_S = d;
    e = realloc(s->job.tail_L0, need * sizeof *e);
    if (e)
        s->job.tail_L0 = e;
    if (!a || !b || !c || !d || !e)
        return -1;
    s->tail_cap = need;
    return 0;
}

/* L = numeric Cholesky factor of M (L has M's analysis). Returns 0, or -1 if M is not
 * positive definite or CHOLMOD failed. Safe on any thread that owns cm. */
static int factor_numeric(cholmod_sparse *M, cholmod_factor *L, cholmod_common *cm)
{
    OmpSerial o = omp_serial_begin();
    int ok = cholmod_factorize(M, L, cm);
    omp_serial_end(o);
    return ok && cm->status == CHOLMOD_OK && L->minor >= M->nrow ? 0 : -1;
}

/* Factor A's free block into s->L, now, in this solve (analysis only if the pattern changed).
 * A pending refactorization is dropped: this factor is newer. */
static int factor_sync(NsSolver *s, const NsBlockMatrix *A, int nfree, uint64_t h, NsSolveStats *st)
{
    job_cancel(s);
    cholmod_sparse *M = to_cholmod(A, s->dof, nfree, &s->cm);
    if (!M)
        return -1;
    if (!s->Lsym || h != s->pattern || nfree != s->nfree) {
        free_factors(s);
        OmpSerial o = omp_serial_begin();
        int k = 0;
        s->Lsym = analyze(s, M, &k);
        omp_serial_end(o);
        s->tail_k = k > 0 && tail_alloc(s, k) == 0 ? k : 0;
        if (!s->Lsym || s->cm.status < CHOLMOD_OK) {
            if (s->Lsym)
                cholmod_free_factor(&s->Lsym, &s->cm);
            cholmod_free_sparse(&M, &s->cm);
            return -1;
        }
        s->pattern = h;
        s->nfree = nfree;
        st->analyzed = 1;
    }
    if (!s->L) {
        s->L = s->spare ? s->spare : cholmod_copy_factor(s->Lsym, &s->cm);
        s->spare = NULL;
    }
    int rc = s->L ? factor_numeric(M, s->L, &s->cm) : -1;
    s->tail_ok = 0;
    s->tail_cur = NULL;
    if (rc == 0 && s->tail_k > 0) {
        int *pos = malloc((size_t)nfree * sizeof *pos);
        if (pos) {
            tail_extract(s->L, M, s->tail_k, s->tail_S, s->tail_L0, pos);
            s->tail_ok = 1;
        }
        free(pos);
    }
    cholmod_free_sparse(&M, &s->cm);
    st->factorized = 1;
    if (rc) {
        if (s->L)
            cholmod_free_factor(&s->L, &s->cm);
        drop_super(s);
        return -1;
    }
    drop_super(s);
    s->factor_solve = s->solves;
    s->factors++;
    return 0;
}

/* Z = A^-1 B for ncols columns of n3 entries with the factor L (free numbering dof, nfree
 * free DOFs): fixed entries of B ignored, of Z set to 0. Returns 0 or -1. */
static int solve_columns(cholmod_factor *L, cholmod_common *cm, const int *dof, int n3, int nfree,
                         int ncols, const double *B, double *Z)
{
    cholmod_dense *Bd =
        cholmod_allocate_dense((size_t)nfree, (size_t)ncols, (size_t)nfree, CHOLMOD_REAL, cm);
    if (!Bd)
        return -1;
    double *bx = Bd->x;
    for (int j = 0; j < ncols; j++)
        for (int i = 0; i < n3; i++)
            if (dof[i] >= 0)
                bx[(size_t)j * (size_t)nfree + (size_t)dof[i]] = B[(size_t)j * (size_t)n3 + i];
    OmpSerial o = omp_serial_begin();
    cholmod_dense *X = cholmod_solve(CHOLMOD_A, L, Bd, cm);
    omp_serial_end(o);
    cholmod_free_dense(&Bd, cm);
    if (!X)
        return -1;
    const double *xx = X->x;
    for (int j = 0; j < ncols; j++)
        for (int i = 0; i < n3; i++)
            Z[(size_t)j * (size_t)n3 + i] =
                dof[i] >= 0 ? xx[(size_t)j * (size_t)nfree + (size_t)dof[i]] : 0.0;
    cholmod_free_dense(&X, cm);
    return 0;
}

static void *job_main(void *arg)
{
    RefreshJob *j = arg;
    cholmod_factor *L = j->L ? j->L : cholmod_copy_factor(j->symbolic, &j->cm);
    if (L && factor_numeric(j->M, L, &j->cm))
        cholmod_free_factor(&L, &j->cm);
    j->tail_ok = 0;
    if (L && j->tail_k > 0) {
        int *pos = malloc(L->n * sizeof *pos);
        if (pos) {
            tail_extract(L, j->M, j->tail_k, j->tail_S, j->tail_L0, pos);
            j->tail_ok = 1;
        }
        free(pos);
    }
    cholmod_free_sparse(&j->M, &j->cm);
    j->L = L;
    j->sf = L ? ns_super_from_cholmod(L) : NULL;
    j->cols_ok = 0;
    if (L && j->ncols > 0)
        j->cols_ok = solve_columns(L, &j->cm, j->dof, j->n3, (int)L->n, j->ncols, j->B, j->Z) == 0;
    atomic_store_explicit(&j->done, 1, memory_order_release);
    return NULL;
}

/* Schedule the refactorization of A (this solve's matrix, whose pattern s->Lsym has): on a
 * worker thread with 2 or more threads, else right here; adopted refresh_lag solves later. */
/* Starts the refactorization of A (free numbering dof, nfree free DOFs; the pattern of
 * s->Lsym): on a worker thread with 2 or more threads, else right here. The caller has set the
 * job's columns (ncols). Returns 0, or -1 (memory: nothing scheduled). */
static int job_launch(NsSolver *s, const NsBlockMatrix *A, const int *dof, int nfree, long adopt_at)
{
    RefreshJob *j = &s->job;
    if (!j->cm_started) {
        start_common(&j->cm);
        j->cm_started = 1;
    }
    j->M = to_cholmod(A, dof, nfree, &j->cm);
    if (!j->M)
        return -1;
    j->symbolic = s->Lsym;
    j->tail_k = s->tail_k;
    j->L = s->spare;
    s->spare = NULL;
    j->pattern = s->pattern;
    j->nfree = s->nfree;
    j->made_at = s->solves;
    j->adopt_at = adopt_at;
    j->cols_ok = 0;
    atomic_store_explicit(&j->done, 0, memory_order_relaxed);
    j->pending = 1;
    if (s->threads > 1 && pthread_create(&j->thread, NULL, job_main, j) == 0)
        j->running = 1;
    else
        job_main(j); /* the same factor, made now: results do not change */
    return 0;
}

static void job_start(NsSolver *s, const NsBlockMatrix *A, int nfree, NsSolveStats *st)
{
    s->job.ncols = 0;
    if (job_launch(s, A, s->dof, nfree, s->solves + s->refresh_lag) == 0)
        st->refresh_started = 1; /* else out of memory: keep the stale factor */
}

/* Switch to the factor of the pending job (waiting for it), if it is for the current analysis
 * and pattern h / nfree. A failed factorization leaves the stale factor in use. */
static void job_adopt(NsSolver *s, uint64_t h, int nfree, NsSolveStats *st)
{
    RefreshJob *j = &s->job;
    job_join(s);
    if (j->L && j->pattern == h && j->nfree == nfree && s->Lsym && s->pattern == h &&
        s->nfree == nfree) {
        if (s->spare)
            cholmod_free_factor(&s->spare, &s->cm);
        s->spare = s->L;
        s->L = j->L;
        j->L = NULL;
        drop_super(s);
        s->sf = j->sf;
        s->sf_tried = s->sf != NULL;
        j->sf = NULL;
        s->factor_solve = j->made_at;
        s->factors++;
        st->refresh_adopted = 1;
        double *t = s->tail_S;
        s->tail_S = j->tail_S;
        j->tail_S = t;
        t = s->tail_L0;
        s->tail_L0 = j->tail_L0;
        j->tail_L0 = t;
        s->tail_ok = j->tail_ok && j->tail_k == s->tail_k;
        s->tail_cur = NULL;
    }
    job_cancel(s); /* frees whatever was not adopted */
}

/* Threads for our loops now: a refactorization running in the background has a core of its
 * own, so leave it that one. The results do not depend on this. */
static int loop_threads(const NsSolver *s)
{
    int nt = s->threads;
    if (nt > 1 && s->job.running && !atomic_load_explicit(&s->job.done, memory_order_relaxed))
        nt--;
    return nt;
}

/* z = L^-1 r on the free DOFs of full-length vectors. */
static int apply_factor(NsSolver *s, int n3, const double *r, double *z)
{
    if (s->nsrc != s->nfree)
        return -1; /* numbered since the factor's analysis for another count of free DOFs */
    if (s->B && s->B->nrow != (size_t)s->nfree)
        cholmod_free_dense(&s->B, &s->cm);
    if (!s->B) {
        s->B = cholmod_allocate_dense((size_t)s->nfree, 1, (size_t)s->nfree, CHOLMOD_REAL, &s->cm);
        if (!s->B)
            return -1;
    }
    double *bx = s->B->x;
    for (int i = 0; i < n3; i++)
        if (s->dof[i] >= 0)
            bx[s->dof[i]] = r[i];
    /* X, Y and E are (re)allocated by CHOLMOD only when their shape must change. */
    if (!cholmod_solve2(CHOLMOD_A, s->L, s->B, NULL, &s->X, NULL, &s->Y, &s->E, &s->cm))
        return -1;
    const double *xx = s->X->x;
    for (int i = 0; i < n3; i++)
        z[i] = s->dof[i] >= 0 ? xx[s->dof[i]] : 0.0;
    return 0;
}

/* z ~ A^-1 r on the free DOFs for preconditioning: with the factor's single-precision copy
 * (supernodal.h) on this solve's loop threads, else with CHOLMOD's solve. */
/* The single-precision copy of the factor in use, made if it was not yet; NULL if it cannot be
 * (or does not fit the numbering). */
static NsSuperFactor *copy_in_use(NsSolver *s, int n3)
{
    if (!s || !s->L || n3 != s->n3 || s->nsrc != s->nfree)
        return NULL;
    if (!s->sf && !s->sf_tried) {
        s->sf = ns_super_from_cholmod(s->L);
        s->sf_tried = 1;
    }
    return s->sf && ns_super_n(s->sf) == s->nfree ? s->sf : NULL;
}

/* The copy's substitutions between full-length vectors and the factor's numbering (dof_src),
 * with mid between them (NULL: none); the held entries zeroed after (r and z may be the same
 * array). */
static void solve_copy(NsSolver *s, NsSuperFactor *sf, const double *r, double *z, NsSolverMid mid,
                       void *ctx)
{
    ns_super_solve_mid(sf, s->dof_src, r, z, loop_threads(s), mid, ctx);
    for (int k = 0; k < s->nheld; k++)
        z[s->dof_held[k]] = 0.0;
}

static int precondition(NsSolver *s, int n3, const double *r, double *z)
{
    NsSuperFactor *sf = copy_in_use(s, n3);
    if (!sf)
        return apply_factor(s, n3, r, z); /* no copy (or a numbering it does not fit) */
    solve_copy(s, sf, r, z, NULL, NULL);
    return 0;
}

/* Vector operations of CG over full-length vectors, free DOFs only (fixed entries are 0 in the
 * outputs, except x's, which are kept). Each returns a sum of its chunk partials (0 if none). */
typedef enum VecOp {
    VEC_DOT,       /* sum a.b */
    VEC_RESIDUAL,  /* out = a - b; sum out.out */
    VEC_FIXED,     /* out = a on fixed DOFs, 0 on free ones */
    VEC_SCALE,     /* out = a * b (Jacobi: z = D^-1 r); sum b.out */
    VEC_COPY,      /* out = a; sum a.a */
    VEC_DIRECTION, /* out = a + alpha out (p = z + beta p) */
    VEC_STEP,      /* out += alpha a, out2 -= alpha b (x += alpha p, r -= alpha q); sum out2^2 */
    VEC_ADD,       /* out += a */
} VecOp;

typedef struct VecTask {
    VecOp op;
    int n;          /* vector length (3 x nodes) */
    const int *dof; /* (n) free index, -1 if fixed */
    double *out, *out2;
    const double *a, *b;
    double alpha;
    double *part; /* (chunks) partial sums */
} VecTask;

static void vec_chunk(const VecTask *t, int c)
{
    int lo = c * CHUNK, hi = lo + CHUNK < t->n ? lo + CHUNK : t->n;
    const int *dof = t->dof;
    const double *a = t->a, *b = t->b;
    double *out = t->out, *out2 = t->out2, alpha = t->alpha, sum = 0.0;
    switch (t->op) {
    case VEC_DOT:
        for (int i = lo; i < hi; i++)
            if (dof[i] >= 0)
                sum += a[i] * b[i];
        break;
    case VEC_RESIDUAL:
        for (int i = lo; i < hi; i++) {
            out[i] = dof[i] >= 0 ? a[i] - b[i] : 0.0;
            if (dof[i] >= 0)
                sum += out[i] * out[i];
        }
        break;
    case VEC_FIXED:
        for (int i = lo; i < hi; i++)
            out[i] = dof[i] >= 0 ? 0.0 : a[i];
        break;
    case VEC_SCALE:
        for (int i = lo; i < hi; i++) {
            out[i] = dof[i] >= 0 ? a[i] * b[i] : 0.0;
            if (dof[i] >= 0)
                sum += b[i] * out[i];
        }
        break;
    case VEC_COPY:
        for (int i = lo; i < hi; i++) {
            out[i] = dof[i] >= 0 ? a[i] : 0.0;
            if (dof[i] >= 0)
                sum += a[i] * a[i];
        }
        break;
    case VEC_DIRECTION:
        for (int i = lo; i < hi; i++)
            out[i] = a[i] + alpha * out[i];
        break;
    case VEC_STEP:
        for (int i = lo; i < hi; i++)
            if (dof[i] >= 0) {
                out[i] += alpha * a[i];
                out2[i] -= alpha * b[i];
                sum += out2[i] * out2[i];
            }
        break;
    case VEC_ADD:
        for (int i = lo; i < hi; i++)
            if (dof[i] >= 0)
                out[i] += a[i];
        break;
    }
    t->part[c] = sum;
}

static double vec_run(const VecTask *t, int threads)
{
    int chunks = (t->n + CHUNK - 1) / CHUNK;
#if NS_HAVE_OPENMP
    if (threads > 1 && t->n >= PARALLEL_MIN) {
#pragma omp parallel for num_threads(threads) schedule(static)
        for (int c = 0; c < chunks; c++)
            vec_chunk(t, c);
    } else
#else
    (void)threads;
#endif
    {
        for (int c = 0; c < chunks; c++)
            vec_chunk(t, c);
    }
    double sum = 0.0;
    for (int c = 0; c < chunks; c++)
        sum += t->part[c];
    return sum;
}

/* One vector operation with up to s's loop threads (see VecOp for what a, b, out mean). */
static double vec(NsSolver *s, VecOp op, int n3, double *out, double *out2, const double *a,
                  const double *b, double alpha)
{
    VecTask t = {op, n3, s->dof, out, out2, a, b, alpha, s->work + 5 * (size_t)n3};
    return vec_run(&t, loop_threads(s));
}

int ns_solver_solve(NsSolver *s, const NsBlockMatrix *A, const uint8_t *node_fixed, const double *b,
                    double *x, double tol, int max_iter, NsSolveStats *stats)
{
    NsSolveStats st = {0};
    st.factor_age = -1;
    if (!s) { /* ns_solver_create ran out of memory: fail the solve, not the process */
        if (stats)
            *stats = st;
        return -1;
    }
    s->solves++;
    int n3 = 3 * A->n;
    int nfree = number_dofs(s, A->n, node_fixed);
    if (nfree < 0)
        return -1;
    int chunks = (n3 + CHUNK - 1) / CHUNK;
    if (ensure((void **)&s->work, &s->work_cap, 5 * n3 + (chunks > 0 ? chunks : 1), sizeof(double)))
        return -1;
    double *r = s->work, *z = r + n3, *p = z + n3, *q = p + n3, *diag = q + n3;
    const int *dof = s->dof;
    uint64_t h = 0;
    if (s->kind == NS_SOLVER_DIRECT || s->kind == NS_SOLVER_STALE_PCG)
        h = pattern_hash(A, dof);
    /* A scheduled refactorization is adopted at its solve whatever happens in it. */
    if (s->job.pending && s->solves >= s->job.adopt_at)
        job_adopt(s, h, nfree, &st);

    /* r = b - A x over free DOFs (fixed entries of x act through A_fc). */
    ns_bsm_mul_threads(A, x, q, loop_threads(s));
    vec(s, VEC_RESIDUAL, n3, r, NULL, b, q, 0.0);
    /* The reference norm: b_f - A_fc x_c, i.e. the residual at x_f = 0. */
    vec(s, VEC_FIXED, n3, p, NULL, x, NULL, 0.0);
    ns_bsm_mul_threads(A, p, q, loop_threads(s));
    double bnorm = sqrt(vec(s, VEC_RESIDUAL, n3, z, NULL, b, q, 0.0));
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
        if (factor_sync(s, A, nfree, h, &st) || apply_factor(s, n3, r, z)) {
            if (stats)
                *stats = st;
            return -1;
        }
        st.factor_age = 0;
        vec(s, VEC_ADD, n3, x, NULL, z, NULL, 0.0);
        ns_bsm_mul_threads(A, x, q, loop_threads(s));
        st.residual = sqrt(vec(s, VEC_RESIDUAL, n3, z, NULL, b, q, 0.0)) / bnorm;
        st.converged = st.residual <= tol || tol <= 0.0;
        if (stats)
            *stats = st;
        return 0;
    }

    if (s->kind == NS_SOLVER_STALE_PCG) {
        if (!s->L || h != s->pattern || nfree != s->nfree)
            if (factor_sync(s, A, nfree, h, &st)) {
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
    double rnorm = sqrt(vec(s, VEC_DOT, n3, NULL, NULL, r, r, 0.0));
    int it = 0;
    double rz = 0.0;
    while (rnorm > tol * bnorm && it < max_iter) {
        double rz_new;
        if (s->kind == NS_SOLVER_STALE_PCG) {
            if (precondition(s, n3, r, z)) {
                if (stats)
                    *stats = st;
                return -1;
            }
            rz_new = vec(s, VEC_DOT, n3, NULL, NULL, r, z, 0.0);
        } else if (s->kind == NS_SOLVER_JACOBI_PCG) {
            rz_new = vec(s, VEC_SCALE, n3, z, NULL, diag, r, 0.0);
        } else {
            rz_new = vec(s, VEC_COPY, n3, z, NULL, r, NULL, 0.0);
        }
        if (it == 0)
            memcpy(p, z, (size_t)n3 * sizeof(double));
        else
            vec(s, VEC_DIRECTION, n3, p, NULL, z, NULL, rz_new / rz);
        rz = rz_new;
        ns_bsm_mul_threads(A, p, q, loop_threads(s));
        double pq = vec(s, VEC_DOT, n3, NULL, NULL, p, q, 0.0);
        if (!(pq > 0.0))
            break; /* not positive definite along p: stop, report unconverged */
        double alpha = rz / pq;
        rnorm = sqrt(vec(s, VEC_STEP, n3, x, r, p, q, alpha));
        it++;
    }
    st.iterations += it;
    if (s->kind == NS_SOLVER_STALE_PCG) {
        int converged = rnorm <= tol * bnorm;
        int slow = it > s->refresh_iterations;
        if (!retried && !st.factorized && (!converged || (slow && s->refresh_lag == 0))) {
            /* The stale factor failed (or a synchronous refresh was asked for): factor this
             * matrix now and finish the solve with it. */
            retried = 1;
            if (factor_sync(s, A, nfree, h, &st) == 0) {
                ns_bsm_mul_threads(A, x, q, loop_threads(s));
                vec(s, VEC_RESIDUAL, n3, r, NULL, b, q, 0.0);
                goto restart;
            }
        } else if (converged && slow && !st.factorized && !s->job.pending) {
            job_start(s, A, nfree, &st);
        }
        if (s->L)
            st.factor_age = (int)(s->solves - s->factor_solve);
    }
    st.residual = rnorm / bnorm;
    st.converged = rnorm <= tol * bnorm;
    if (stats)
        *stats = st;
    return 0;
}

int ns_solver_factor(NsSolver *s, const NsBlockMatrix *A, const uint8_t *dof_fixed)
{
    if (!s || (s->kind != NS_SOLVER_DIRECT && s->kind != NS_SOLVER_STALE_PCG))
        return -1;
    int nfree = number_dofs(s, A->n, dof_fixed);
    if (nfree < 0)
        return -1;
    NsSolveStats st = {0};
    return factor_sync(s, A, nfree, pattern_hash(A, s->dof), &st);
}

int ns_solver_apply(NsSolver *s, int n3, int ncols, const double *B, double *Z)
{
    if (!s || !s->L || n3 != s->n3 || ncols < 0)
        return -1;
    if (ncols == 0)
        return 0;
    if (ncols == 1) /* one column: the solve's kept buffers */
        return apply_factor(s, n3, B, Z);
    return solve_columns(s->L, &s->cm, s->dof, n3, s->nfree, ncols, B, Z);
}

int ns_solver_precondition(NsSolver *s, int n3, const double *r, double *z)
{
    if (!s || !s->L || n3 != s->n3)
        return -1;
    return precondition(s, n3, r, z);
}

int ns_solver_precondition_cut(const NsSolver *s, size_t entries[3])
{
    if (!s || !s->sf)
        return -1;
    ns_super_cut(s->sf, entries);
    return 0;
}

long ns_solver_factor_count(const NsSolver *s)
{
    return s ? s->factors : 0;
}

int ns_solver_factor_async(NsSolver *s, const NsBlockMatrix *A, const uint8_t *dof_fixed, int ncols,
                           const double *B, double *Z)
{
    if (!s || (s->kind != NS_SOLVER_DIRECT && s->kind != NS_SOLVER_STALE_PCG) || !s->Lsym ||
        ncols < 0)
        return -1;
    int n3 = 3 * A->n;
    /* The same pattern and free DOFs as the analysis, or nothing to do in the background. */
    int *dof = s->job.dof;
    if (n3 > s->job.dof_cap) {
        dof = realloc(s->job.dof, (size_t)n3 * sizeof *dof);
        if (!dof)
            return -1;
        s->job.dof = dof;
        s->job.dof_cap = n3;
    }
    job_cancel(s);
    int nfree = 0;
    for (int i = 0; i < n3; i++)
        dof[i] = (dof_fixed && dof_fixed[i]) ? -1 : nfree++;
    if (nfree != s->nfree || pattern_hash(A, dof) != s->pattern)
        return -1;
    RefreshJob *j = &s->job;
    j->ncols = ncols;
    j->n3 = n3;
    j->B = B;
    j->Z = Z;
    return job_launch(s, A, dof, nfree, -1); /* -1: only ns_solver_factor_adopt adopts it */
}

int ns_solver_factor_adopt(NsSolver *s, int *cols_ok)
{
    *cols_ok = 0;
    if (!s || !s->job.pending || s->job.adopt_at != -1)
        return 0;
    NsSolveStats st = {0};
    job_join(s);
    *cols_ok = s->job.L && s->job.ncols > 0 && s->job.cols_ok;
    s->job.ncols = 0;
    job_adopt(s, s->pattern, s->nfree, &st);
    if (!st.refresh_adopted)
        *cols_ok = 0;
    return st.refresh_adopted;
}

int ns_solver_set_tail(NsSolver *s, const int *nodes, int count)
{
    if (!s || count < 0)
        return -1;
    if (count > s->tail_req_cap) {
        int *p = realloc(s->tail_req, (size_t)count * sizeof *p);
        if (!p)
            return -1;
        s->tail_req = p;
        s->tail_req_cap = count;
    }
    if (count > 0)
        memcpy(s->tail_req, nodes, (size_t)count * sizeof *nodes);
    s->tail_nreq = count;
    return 0;
}

int ns_solver_tail_update(NsSolver *s, const NsBlockMatrix *A)
{
    if (!s || !s->tail_ok || s->tail_k == 0 || !copy_in_use(s, 3 * A->n))
        return 0;
    int k = s->tail_k, t0 = s->nfree - k;
    const int *perm = s->L->Perm;
    double *D = s->tail_D;
    for (int j = 0; j < k; j++) {
        int dj = s->dof_src[perm[t0 + j]];
        for (int i = j; i < k; i++) {
            int di = s->dof_src[perm[t0 + i]];
            const double *b = ns_bsm_find(A, di / 3, dj / 3);
            double a = b ? b[3 * (di % 3) + dj % 3] : 0.0;
            D[i + (size_t)k * j] = a - s->tail_S[i + (size_t)k * j];
        }
    }
    int ok = 1; /* Cholesky of D in place, lower triangle */
    for (int j = 0; j < k && ok; j++) {
        double d = D[j + (size_t)k * j];
        for (int m = 0; m < j; m++)
            d -= D[j + (size_t)k * m] * D[j + (size_t)k * m];
        if (!(d > 0.0) || !isfinite(d)) {
            ok = 0;
            break;
        }
        d = sqrt(d);
        D[j + (size_t)k * j] = d;
        for (int i = j + 1; i < k; i++) {
            double v = D[i + (size_t)k * j];
            for (int m = 0; m < j; m++)
                v -= D[i + (size_t)k * m] * D[j + (size_t)k * m];
            D[i + (size_t)k * j] = v / d;
        }
    }
    s->tail_cur = ok ? D : s->tail_L0;
    ns_super_set_tail(s->sf, k, s->tail_cur);
    return ok ? k : 0;
}

int ns_solver_precondition_mid(NsSolver *s, int n3, const double *r, double *z, NsSolverMid mid,
                               void *ctx)
{
    NsSuperFactor *sf = copy_in_use(s, n3);
    if (!sf)
        return 1;
    solve_copy(s, sf, r, z, mid, ctx);
    return 0;
}

int ns_solver_forward_dof(NsSolver *s, int n3, int dof, float *y)
{
    NsSuperFactor *sf = copy_in_use(s, n3);
    if (!sf || dof < 0 || dof >= n3)
        return -1;
    int n = s->nfree;
    if (!y)
        return n;
    if (s->iperm_of != sf) {
        if (ensure((void **)&s->iperm, &s->iperm_cap, n > 0 ? n : 1, sizeof(int)))
            return -1;
        const int *perm = ns_super_perm(sf);
        for (int k = 0; k < n; k++)
            s->iperm[perm[k]] = k;
        s->iperm_of = sf;
    }
    if (s->dof[dof] < 0)
        return 0;
    ns_super_forward_unit(sf, s->iperm[s->dof[dof]], y);
    return n;
}

int ns_solver_tail_block(NsSolver *s, int n3, const double **L22)
{
    *L22 = NULL;
    if (!copy_in_use(s, n3) || !s->tail_ok || s->tail_k == 0)
        return 0;
    *L22 = s->tail_cur ? s->tail_cur : s->tail_L0;
    return s->tail_k;
}

/* ---- snapshots (sim/snapshot.h) ----
 *
 * Held: the solver's scalars and arrays, its CHOLMOD factors field by field (CHOLMOD has no
 * serialization of its own) read back into CHOLMOD's allocator, its dense vectors. Made again
 * on reading: the commons, started as ns_solver_create starts them (they hold settings, which
 * analyze restores after each change, and workspace, which CHOLMOD leaves clean between calls);
 * the single-precision copies, ns_super_from_cholmod of the factor read back (a rounding of its
 * values, its cut a function of its structure), the one in use given its tail block again
 * (ns_super_set_tail of the block tail_cur points to, the last one put there). A
 * refactorization still running is waited for and held as finished, not adopted. Not held,
 * zeroed on reading, because every use writes them before it reads them: work, job.dof (read by
 * the finished job only), and the values of `spare`, which the next factorization overwrites
 * (CHOLMOD's supernodal factorization clears each supernode before it assembles into it). */

/* What a solver's pointers pointed to, held beside its bytes. */
typedef struct SolverLinks {
    uint8_t cm, job_cm; /* the commons were started */
    uint8_t sf, job_sf; /* copies of L and of job.L were made */
    uint8_t tail_cur;   /* 0: NULL, 1: tail_D, 2: tail_L0 */
    uint8_t iperm_of;   /* iperm is the copy's (sf) */
    uint8_t symbolic;   /* the job reads Lsym */
    uint8_t pad;
} SolverLinks;

/* Every pointer of s NULL, its commons and thread zeroed: the copy a writer writes, and a read
 * solver before its arrays are read (its bytes carried stale addresses). */
static void solver_forget(void *obj)
{
    NsSolver *s = obj;
    RefreshJob *j = &s->job;
    memset(&s->cm, 0, sizeof s->cm);
    memset(&j->cm, 0, sizeof j->cm);
    memset(&j->thread, 0, sizeof j->thread);
    s->cm_started = j->cm_started = 0;
    j->running = 0;
    atomic_store_explicit(&j->done, 0, memory_order_relaxed);
    s->Lsym = s->L = s->spare = NULL;
    s->sf = NULL;
    j->M = NULL;
    j->symbolic = j->L = NULL;
    j->sf = NULL;
    j->B = NULL;
    j->Z = NULL;
    j->dof = NULL;
    j->tail_S = j->tail_L0 = NULL;
    s->B = s->X = s->Y = s->E = NULL;
    s->dof = s->dof_src = s->dof_held = NULL;
    s->work = NULL;
    s->tail_req = NULL;
    s->tail_S = s->tail_L0 = s->tail_D = NULL;
    s->tail_cur = NULL;
    s->iperm = NULL;
    s->iperm_of = NULL;
}

/* An array of count elements of elem bytes in CHOLMOD's allocator (so that CHOLMOD frees it),
 * or NULL; with data 0 its contents are not held (read back zeroed). */
static void pack_cm_array(NsPack *p, void **a, size_t count, size_t elem, int data,
                          cholmod_common *cm)
{
    uint8_t present = *a != NULL;
    NS_PACK(p, present);
    if (!p->writing) {
        *a = NULL;
        if (p->failed || !present)
            return;
        if (present != 1 || count > NS_PACK_MAX_BYTES / elem ||
            count * elem > NS_PACK_MAX_BYTES - p->allocated ||
            (data && count * elem > p->size - p->pos)) {
            ns_pack_fail(p, "solver: bad CHOLMOD array at byte %zu (%zu x %zu bytes)", p->pos,
                         count, elem);
            return;
        }
        *a = data ? cholmod_malloc(count, elem, cm) : cholmod_calloc(count, elem, cm);
        if (!*a) {
            ns_pack_fail(p, "solver: out of memory (%zu bytes)", count * elem);
            return;
        }
        p->allocated += count * elem;
    }
    if (present && data)
        ns_pack_bytes(p, *a, count * elem);
}

/* A CHOLMOD object at *obj (NULL allowed), its header h (size bytes) first: written with its
 * pointers cleared (forget), read into an object of CHOLMOD's allocator (cm; NULL: none may be
 * read) whose pointers are NULL until the caller reads its arrays. Returns the object, or NULL
 * (none, or a failure). */
static void *pack_cm_object(NsPack *p, void **obj, void *h, size_t size, void (*forget)(void *),
                            cholmod_common *cm)
{
    uint8_t present = *obj != NULL;
    NS_PACK(p, present);
    if (!p->writing)
        *obj = NULL;
    if (!present || p->failed)
        return NULL;
    if (p->writing)
        memcpy(h, *obj, size);
    ns_pack_scalars(p, h, size, forget);
    if (p->writing)
        return *obj;
    if (!p->failed && (present != 1 || !cm))
        ns_pack_fail(p, "solver: bad CHOLMOD object before byte %zu", p->pos);
    void *o = p->failed ? NULL : cholmod_malloc(1, size, cm);
    if (o)
        *obj = memcpy(o, h, size);
    else
        ns_pack_fail(p, "solver: out of memory");
    return o;
}

static void factor_forget(void *h)
{
    cholmod_factor *L = h;
    L->Perm = L->ColCount = L->IPerm = NULL;
    L->p = L->i = L->x = L->z = L->nz = L->next = L->prev = NULL;
    L->super = L->pi = L->px = L->s = NULL;
}

static void dense_forget(void *h)
{
    cholmod_dense *D = h;
    D->x = D->z = NULL;
}

/* The kinds of factor solver.c makes: int indices, real or symbolic, double. */
static int factor_kind_held(const cholmod_factor *L)
{
    return L->itype == CHOLMOD_INT && L->dtype == CHOLMOD_DOUBLE &&
           (L->xtype == CHOLMOD_PATTERN || L->xtype == CHOLMOD_REAL) && L->n <= INT_MAX &&
           L->nsuper <= L->n && (L->is_super == 0 || L->is_super == 1);
}

/* What reading needs of a factor before it makes the copy (ns_super_from_cholmod) and puts a
 * tail block into it: a supernodal structure within its arrays. NULL if it holds. */
static const char *factor_check(const cholmod_factor *L)
{
    if (!L->is_super)
        return NULL;
    const int *sup = L->super, *pi = L->pi, *px = L->px, *rows = L->s, *perm = L->Perm;
    int n = (int)L->n, ns = (int)L->nsuper;
    if (!sup || !pi || !px || !rows || !perm)
        return "arrays missing";
    if (sup[0] != 0 || pi[0] != 0 || px[0] != 0 || sup[ns] != n || (size_t)pi[ns] > L->ssize ||
        (size_t)px[ns] > L->xsize)
        return "supernode bounds";
    for (int s = 0; s < ns; s++) {
        long nc = sup[s + 1] - sup[s], nr = pi[s + 1] - pi[s];
        if (nc < 1 || nr < nc || (long)px[s + 1] - px[s] < nr * nc)
            return "supernode sizes";
    }
    for (int i = 0; i < pi[ns]; i++)
        if (rows[i] < 0 || rows[i] >= n)
            return "row index";
    for (int k = 0; k < n; k++)
        if (perm[k] < 0 || perm[k] >= n)
            return "permutation";
    return NULL;
}

/* A CHOLMOD factor (NULL allowed), its arrays sized as cholmod_free_factor sizes them; values
 * 0: L->x's contents not held. A reader allocates with cm (NULL: none may be read). */
static void pack_factor(NsPack *p, cholmod_factor **Lp, int values, cholmod_common *cm)
{
    cholmod_factor h, *L = pack_cm_object(p, (void **)Lp, &h, sizeof h, factor_forget, cm);
    if (!L)
        return;
    if (!factor_kind_held(&h) || (p->writing && (L->x != NULL) != (L->xtype == CHOLMOD_REAL)))
        ns_pack_fail(p, "solver: a CHOLMOD factor of a kind snapshots do not hold, at byte %zu",
                     p->pos);
    size_t n = L->n, ns = L->nsuper + 1;
    void **arr[12] = {&L->Perm, &L->ColCount, &L->IPerm, &L->p,  &L->i,  &L->nz,
                      &L->next, &L->prev,     &L->super, &L->pi, &L->px, &L->s};
    size_t count[12] = {n, n, n, n + 1, L->nzmax, n, n + 2, n + 2, ns, ns, ns, L->ssize};
    for (int k = 0; k < 12; k++)
        pack_cm_array(p, arr[k], count[k], sizeof(int), 1, cm);
    if (L->xtype == CHOLMOD_REAL)
        pack_cm_array(p, &L->x, L->is_super ? L->xsize : L->nzmax, sizeof(double), values, cm);
    const char *bad = p->writing || p->failed ? NULL : factor_check(L);
    if (bad)
        ns_pack_fail(p, "solver: a CHOLMOD factor read back is not one (%s)", bad);
}

/* A dense matrix of doubles (NULL allowed), read back into CHOLMOD's allocator. */
static void pack_dense(NsPack *p, cholmod_dense **Dp, cholmod_common *cm)
{
    cholmod_dense h, *D = pack_cm_object(p, (void **)Dp, &h, sizeof h, dense_forget, cm);
    if (!D)
        return;
    if (h.xtype != CHOLMOD_REAL || h.dtype != CHOLMOD_DOUBLE || h.d < h.nrow ||
        (h.ncol > 0 && h.d > h.nzmax / h.ncol) || (p->writing && !D->x))
        ns_pack_fail(p, "solver: a dense matrix of a kind snapshots do not hold, at byte %zu",
                     p->pos);
    pack_cm_array(p, &D->x, D->nzmax, sizeof(double), 1, cm);
}

/* The links of s, as a writer finds them. */
static SolverLinks links_of(NsPack *p, const NsSolver *s)
{
    SolverLinks ln = {0};
    ln.cm = (uint8_t)s->cm_started;
    ln.job_cm = (uint8_t)s->job.cm_started;
    ln.sf = s->sf != NULL;
    ln.job_sf = s->job.sf != NULL;
    ln.tail_cur = !s->tail_cur ? 0 : s->tail_cur == s->tail_D ? 1 : 2;
    ln.iperm_of = s->iperm_of != NULL;
    ln.symbolic = s->job.pending && s->job.symbolic == s->Lsym && s->Lsym;
    if ((s->tail_cur && s->tail_cur != s->tail_D && s->tail_cur != s->tail_L0) ||
        (s->iperm_of && s->iperm_of != s->sf) || s->job.M || s->job.running)
        ns_pack_fail(p, "solver: links that snapshots do not hold");
    return ln;
}

/* A read solver's links made again: its copies, the tail block in use, the job's analysis. */
static void solver_relink(NsPack *p, NsSolver *s, const SolverLinks *ln)
{
    RefreshJob *j = &s->job;
    j->symbolic = ln->symbolic ? s->Lsym : NULL;
    atomic_store_explicit(&j->done, j->pending, memory_order_relaxed);
    if (ln->tail_cur)
        s->tail_cur = ln->tail_cur == 1 ? s->tail_D : s->tail_L0;
    if (p->failed)
        return;
    size_t k = s->tail_k > 0 ? (size_t)s->tail_k : 0;
    if (s->tail_k < 0 || (k > 0 && (k * k >= s->tail_cap || !s->Lsym || k > s->Lsym->n)))
        ns_pack_fail(p, "solver: bad tail (%d DOFs)", s->tail_k);
    else if (ln->sf && !(s->L && (s->sf = ns_super_from_cholmod(s->L))))
        ns_pack_fail(p, "solver: the factor's single-precision copy could not be made again");
    else if (ln->job_sf && !(j->L && (j->sf = ns_super_from_cholmod(j->L))))
        ns_pack_fail(p, "solver: the new factor's single-precision copy could not be made again");
    else if (ln->iperm_of && (!s->sf || !s->iperm || s->iperm_cap < s->nfree))
        ns_pack_fail(p, "solver: bad inverse permutation");
    if (p->failed)
        return;
    if (s->sf && s->tail_cur && k > (size_t)ns_super_n(s->sf))
        ns_pack_fail(p, "solver: bad tail (%d DOFs)", s->tail_k);
    else if (s->sf && s->tail_cur && k > 0)
        ns_super_set_tail(s->sf, (int)k, s->tail_cur);
    s->iperm_of = ln->iperm_of ? s->sf : NULL;
}

/* The solver's own arrays (malloc'd). */
static void pack_arrays(NsPack *p, NsSolver *s)
{
    RefreshJob *j = &s->job;
    /* Arrays present or not by their pointer (a reader's are NULL yet): the flag first. */
    uint8_t has_dof = s->dof != NULL, has_iperm = s->iperm_of != NULL;
    NS_PACK(p, has_dof);
    NS_PACK(p, has_iperm);
    NS_PACK_ARRAY(p, s->dof, has_dof ? s->n3 : 0, s->dof_cap);
    NS_PACK_ARRAY(p, s->dof_src, s->nsrc, s->src_cap);
    NS_PACK_ARRAY(p, s->dof_held, s->nheld, s->held_cap);
    NS_PACK_ARRAY(p, s->work, 0, s->work_cap);
    NS_PACK_ARRAY(p, s->tail_req, s->tail_nreq, s->tail_req_cap);
    NS_PACK_ARRAY(p, s->tail_S, s->tail_cap, s->tail_cap);
    NS_PACK_ARRAY(p, s->tail_L0, s->tail_cap, s->tail_cap);
    NS_PACK_ARRAY(p, s->tail_D, s->tail_cap, s->tail_cap);
    NS_PACK_ARRAY(p, s->iperm, has_iperm ? s->nfree : 0, s->iperm_cap);
    NS_PACK_ARRAY(p, j->dof, 0, j->dof_cap);
    NS_PACK_ARRAY(p, j->tail_S, s->tail_cap, s->tail_cap);
    NS_PACK_ARRAY(p, j->tail_L0, s->tail_cap, s->tail_cap);
}

static void solver_pack(NsPack *p, NsSolver *s)
{
    /* The layouts held whole: a snapshot of another build is refused. */
    uint32_t size[3] = {sizeof *s, sizeof(cholmod_factor), sizeof(cholmod_dense)};
    uint32_t here[3] = {sizeof *s, sizeof(cholmod_factor), sizeof(cholmod_dense)};
    NS_PACK(p, size);
    if (!p->writing && !p->failed && memcmp(size, here, sizeof size) != 0)
        ns_pack_fail(p, "solver: written by another build (its layouts %u, %u, %u bytes)", size[0],
                     size[1], size[2]);
    SolverLinks ln = {0};
    if (p->writing) {
        job_join(s); /* its factor is held as made, adopted later as it would have been */
        ln = links_of(p, s);
    }
    ns_pack_scalars(p, s, sizeof *s, solver_forget);
    NS_PACK(p, ln);
    RefreshJob *j = &s->job;
    if (!p->writing && !p->failed) {
        if (ln.cm > 1 || ln.job_cm > 1 || ln.sf > 1 || ln.job_sf > 1 || ln.tail_cur > 2 ||
            ln.iperm_of > 1 || ln.symbolic > 1)
            ns_pack_fail(p, "solver: bad links at byte %zu", p->pos);
        if (ln.cm == 1)
            start_solver_common(s);
        if (ln.job_cm == 1) {
            start_common(&j->cm);
            j->cm_started = 1;
        }
    }
    cholmod_common *cm = s->cm_started ? &s->cm : NULL;
    pack_factor(p, &s->Lsym, 1, cm);
    pack_factor(p, &s->L, 1, cm);
    pack_factor(p, &s->spare, 0, cm);
    pack_factor(p, &j->L, 1, j->cm_started ? &j->cm : NULL);
    pack_dense(p, &s->B, cm);
    pack_dense(p, &s->X, cm);
    pack_dense(p, &s->Y, cm);
    pack_dense(p, &s->E, cm);
    pack_arrays(p, s);
    if (!p->writing)
        solver_relink(p, s, &ln);
}

int ns_solver_pack(NsPack *p, NsSolver **sp)
{
    NsSolver *s = ns_pack_object(p, (void **)sp, sizeof **sp, "solver");
    if (s)
        solver_pack(p, s);
    return p->failed ? -1 : 0;
}

void ns_solver_factor_async_moved(NsSolver *s, const double *B, double *Z)
{
    if (s && s->job.pending && s->job.adopt_at == -1) {
        s->job.B = B;
        s->job.Z = Z;
    }
}
