/* Single-precision supernodal triangular solves on two threads (supernodal.h). */
#include "supernodal.h"

#include "ns_config.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#if NS_HAVE_OPENMP
#include <omp.h>
#endif

/* Owners of a supernode: bin 0, bin 1 (whole subtrees, run at once), or the top part. */
#define TOP 2
/* Most expansions of the top part tried when cutting the tree. */
#define MAX_EXPAND 64

/* The substitutions' working precision (their vectors and sums), and its lanes in a 256-bit
 * vector. */
typedef float sreal;
#define LANES 8

struct NsSuperFactor {
    int n, nsuper;
    int *super;   /* (nsuper + 1) first column of each supernode */
    int *pi;      /* (nsuper + 1) start of its row indices in rows */
    size_t *px;   /* (nsuper + 1) start of its values in x (column-major, nr x nc) */
    int *rows;    /* row indices, the supernode's own columns first */
    int *perm;    /* (n) A(perm, perm) = L L^T */
    float *x;     /* values */
    int *list[3]; /* supernodes of each owner, ascending */
    int count[3];
    unsigned char *col_owner; /* (n) owner of the supernode of each column */
    int *top_cols;            /* columns of the top part, ascending */
    int ntop_cols;
    int light; /* the bin with fewer entries: its thread also moves the top part's vector */
    /* Workspace: y (n), one accumulator (n) and one gather buffer (max_below) per bin. */
    sreal *y, *acc[2], *tbuf[2];
};

void ns_super_free(NsSuperFactor *f)
{
    if (!f)
        return;
    free(f->super);
    free(f->pi);
    free(f->px);
    free(f->rows);
    free(f->perm);
    free(f->x);
    for (int b = 0; b < 3; b++)
        free(f->list[b]);
    free(f->col_owner);
    free(f->top_cols);
    free(f->y);
    free(f->acc[0]);
    free(f->acc[1]);
    free(f->tbuf[0]);
    free(f->tbuf[1]);
    free(f);
}

int ns_super_n(const NsSuperFactor *f)
{
    return f ? f->n : 0;
}

void ns_super_cut(const NsSuperFactor *f, size_t entries[3])
{
    for (int o = 0; o < 3; o++) {
        entries[o] = 0;
        for (int q = 0; f && q < f->count[o]; q++) {
            int s = f->list[o][q];
            entries[o] += f->px[s + 1] - f->px[s];
        }
    }
}

/* Puts the subtrees of the frontier nodes (sub: subtree sizes) into two bins, largest first
 * into the lighter one; bin[k] receives the frontier node k's bin. Returns the heavier bin's
 * size. Ties go to bin 0, and equal sizes keep their order, so the cut is deterministic. */
static double lpt(const int *front, int nf, const double *sub, int *order, unsigned char *bin)
{
    for (int k = 0; k < nf; k++)
        order[k] = k;
    for (int i = 1; i < nf; i++) { /* insertion sort by decreasing size; nf is small */
        int v = order[i], j = i;
        while (j > 0 && sub[front[order[j - 1]]] < sub[front[v]]) {
            order[j] = order[j - 1];
            j--;
        }
        order[j] = v;
    }
    double load[2] = {0.0, 0.0};
    for (int i = 0; i < nf; i++) {
        int b = load[1] < load[0];
        bin[order[i]] = (unsigned char)b;
        load[b] += sub[front[order[i]]];
    }
    return load[0] > load[1] ? load[0] : load[1];
}

/* Cuts the supernodal tree (parent, children lists head/next, subtree sizes sub, own sizes
 * own): the top part grows from the roots by the largest frontier subtree at a time, and of
 * the first MAX_EXPAND cuts the one with the smallest (heavier bin + top) is kept (greedy, not
 * an optimum). Fills owner[s]. Returns 0 or -1. */
static int cut_tree(NsSuperFactor *f, const int *head, const int *next, const int *first,
                    const double *sub, const double *own, const int *parent, unsigned char *owner)
{
    int ns = f->nsuper;
    int *front = malloc(((size_t)ns + 1) * sizeof *front);
    int *order = malloc(((size_t)ns + 1) * sizeof *order);
    unsigned char *bin = malloc((size_t)ns + 1);
    if (!front || !order || !bin) {
        free(front);
        free(order);
        free(bin);
        return -1;
    }
    int best_k = 0;
    double best = 0.0;
    for (int pass = 0; pass < 2; pass++) {
        /* Pass 0 finds the best number of expansions; pass 1 makes that cut. */
        int nf = 0, stop = pass ? best_k : MAX_EXPAND;
        double top = 0.0;
        memset(owner, 0, (size_t)ns);
        for (int s = 0; s < ns; s++)
            if (parent[s] < 0)
                front[nf++] = s;
        for (int k = 0;; k++) {
            double cost = lpt(front, nf, sub, order, bin) + top;
            if (pass == 0 && (k == 0 || cost < best)) {
                best = cost;
                best_k = k;
            }
            if (k == stop)
                break;
            int big = 0; /* the largest frontier subtree (first of equals) */
            for (int i = 1; i < nf; i++)
                if (sub[front[i]] > sub[front[big]])
                    big = i;
            int s = nf > 0 ? front[big] : -1;
            if (s < 0 || head[s] < 0)
                break; /* a leaf cannot be split further */
            owner[s] = TOP;
            top += own[s];
            front[big] = front[--nf];
            for (int c = head[s]; c >= 0; c = next[c])
                front[nf++] = c;
        }
        if (pass == 1) {
            for (int i = 0; i < nf; i++)
                for (int s = first[front[i]]; s <= front[i]; s++)
                    owner[s] = bin[i];
        }
    }
    free(front);
    free(order);
    free(bin);
    return 0;
}

NsSuperFactor *ns_super_from_cholmod(const cholmod_factor *L)
{
    if (!L || !L->is_super || !L->is_ll || L->xtype != CHOLMOD_REAL || L->dtype != CHOLMOD_DOUBLE ||
        !L->x || L->itype != CHOLMOD_INT || L->minor < L->n)
        return NULL; /* not a complete numeric supernodal LL^T factor of doubles */
    NsSuperFactor *f = calloc(1, sizeof *f);
    if (!f)
        return NULL;
    int n = (int)L->n, ns = (int)L->nsuper;
    const int *Ls = L->super, *Lpi = L->pi, *Lpx = L->px, *Lrows = L->s, *Lperm = L->Perm;
    f->n = n;
    f->nsuper = ns;
    size_t nrows = (size_t)Lpi[ns], nx = (size_t)Lpx[ns];
    f->super = malloc(((size_t)ns + 1) * sizeof *f->super);
    f->pi = malloc(((size_t)ns + 1) * sizeof *f->pi);
    f->px = malloc(((size_t)ns + 1) * sizeof *f->px);
    f->rows = malloc((nrows + 1) * sizeof *f->rows);
    f->perm = malloc(((size_t)n + 1) * sizeof *f->perm);
    f->x = malloc((nx + 1) * sizeof *f->x);
    f->col_owner = malloc((size_t)n + 1);
    f->top_cols = malloc(((size_t)n + 1) * sizeof *f->top_cols);
    f->y = malloc(((size_t)n + 1) * sizeof *f->y);
    f->acc[0] = calloc((size_t)n + 1, sizeof *f->acc[0]);
    f->acc[1] = calloc((size_t)n + 1, sizeof *f->acc[1]);
    int *parent = malloc(((size_t)ns + 1) * sizeof *parent);
    int *head = malloc(((size_t)ns + 1) * sizeof *head);
    int *next = malloc(((size_t)ns + 1) * sizeof *next);
    int *first = malloc(((size_t)ns + 1) * sizeof *first);
    int *col_super = malloc(((size_t)n + 1) * sizeof *col_super);
    double *sub = malloc(((size_t)ns + 1) * sizeof *sub);
    double *own = malloc(((size_t)ns + 1) * sizeof *own);
    unsigned char *owner = malloc((size_t)ns + 1);
    int ok = f->super && f->pi && f->px && f->rows && f->perm && f->x && f->col_owner &&
             f->top_cols && f->y && f->acc[0] && f->acc[1] && parent && head && next && first &&
             col_super && sub && own && owner;
    int max_below = 1;
    if (ok) {
        memcpy(f->super, Ls, ((size_t)ns + 1) * sizeof *f->super);
        memcpy(f->pi, Lpi, ((size_t)ns + 1) * sizeof *f->pi);
        for (int s = 0; s <= ns; s++)
            f->px[s] = (size_t)Lpx[s];
        memcpy(f->rows, Lrows, nrows * sizeof *f->rows);
        if (Lperm)
            memcpy(f->perm, Lperm, (size_t)n * sizeof *f->perm);
        else
            for (int k = 0; k < n; k++)
                f->perm[k] = k;
        const double *lx = L->x;
        for (size_t i = 0; i < nx; i++)
            f->x[i] = (float)lx[i];
        /* The supernodal elimination tree: a supernode's parent holds its first row below its
         * own columns. CHOLMOD numbers supernodes in postorder, so each subtree is the range
         * [first[s], s] and children come before parents. */
        for (int s = 0; s < ns; s++)
            for (int k = Ls[s]; k < Ls[s + 1]; k++)
                col_super[k] = s;
        for (int s = 0; s < ns; s++) {
            int nc = Ls[s + 1] - Ls[s], nr = Lpi[s + 1] - Lpi[s];
            parent[s] = nr > nc ? col_super[Lrows[Lpi[s] + nc]] : -1;
            if (parent[s] >= 0 && parent[s] <= s)
                ok = 0; /* not postordered: the subtree ranges would be wrong */
            if (nr - nc > max_below)
                max_below = nr - nc;
            own[s] = (double)(Lpx[s + 1] - Lpx[s]);
            sub[s] = own[s];
            first[s] = s;
            head[s] = -1;
        }
    }
    if (ok) {
        for (int s = 0; s < ns; s++) {
            int p = parent[s];
            if (p >= 0) {
                sub[p] += sub[s];
                if (first[s] < first[p])
                    first[p] = first[s];
            }
        }
        for (int s = ns - 1; s >= 0; s--) /* children lists, ascending */
            if (parent[s] >= 0) {
                next[s] = head[parent[s]];
                head[parent[s]] = s;
            }
        ok = cut_tree(f, head, next, first, sub, own, parent, owner) == 0;
    }
    for (int b = 0; ok && b < 3; b++) {
        f->list[b] = malloc(((size_t)ns + 1) * sizeof *f->list[b]);
        ok = f->list[b] != NULL;
    }
    if (ok) {
        for (int s = 0; s < ns; s++) {
            f->list[owner[s]][f->count[owner[s]]++] = s;
            for (int k = Ls[s]; k < Ls[s + 1]; k++)
                f->col_owner[k] = owner[s];
        }
        for (int k = 0; k < n; k++)
            if (f->col_owner[k] == TOP)
                f->top_cols[f->ntop_cols++] = k;
        /* What the solve relies on: a bin's supernodes send their rows below only to their own
         * bin or to the top (true of any postordered tree; checked, not assumed). */
        for (int s = 0; s < ns && ok; s++)
            for (int p = Lpi[s] + (Ls[s + 1] - Ls[s]); p < Lpi[s + 1] && ok; p++) {
                int o = f->col_owner[Lrows[p]];
                ok = owner[s] == TOP ? o == TOP : (o == owner[s] || o == TOP);
            }
        f->tbuf[0] = malloc((size_t)max_below * sizeof *f->tbuf[0]);
        f->tbuf[1] = malloc((size_t)max_below * sizeof *f->tbuf[1]);
        ok = ok && f->tbuf[0] && f->tbuf[1];
    }
    free(parent);
    free(head);
    free(next);
    free(first);
    free(col_super);
    free(sub);
    free(own);
    free(owner);
    if (!ok) {
        ns_super_free(f);
        return NULL;
    }
    size_t e[3];
    ns_super_cut(f, e);
    f->light = e[1] < e[0];
    return f;
}

/* The kernels: with GCC on x86-64 also built for AVX2 and picked at load time. The compiler
 * does not reassociate (no -ffast-math) or contract (ISO C mode) these sums, so every variant
 * gives the same bits. */
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) &&                             \
    !defined(__SANITIZE_ADDRESS__)
#define KERNEL __attribute__((target_clones("avx2", "default")))
#else
#define KERNEL
#endif

/* Supernode s: its first column k1, nc columns, nr rows (its own columns first, then nb rows
 * below them, whose indices are `below`), values X (column-major, nr x nc). */
typedef struct Block {
    int k1, nc, nr, nb;
    const float *X;
    const int *below;
} Block;

static inline Block block_of(const NsSuperFactor *f, int s)
{
    Block b;
    b.k1 = f->super[s];
    b.nc = f->super[s + 1] - b.k1;
    b.nr = f->pi[s + 1] - f->pi[s];
    b.nb = b.nr - b.nc;
    b.X = f->x + f->px[s];
    b.below = f->rows + f->pi[s] + b.nc;
    return b;
}

/* Helpers inlined into each kernel variant. Both give sums in a fixed order. */

/* sum a[i] t[i] over n terms: two 8-lane partial sums over blocks of 16, added lane by lane,
 * the lanes then halved pairwise (0+4, 1+5, ...; 0+2, 1+3; 0+1), then the tail one by one.
 * Written lane by lane, which GCC turns into 8-wide vector code; the order is fixed. */
static inline __attribute__((always_inline)) sreal dot(const float *a, const sreal *t, int n)
{
    sreal s0[LANES] = {0}, s1[LANES] = {0};
    int i = 0;
    for (; i + 2 * LANES <= n; i += 2 * LANES)
        for (int l = 0; l < LANES; l++) {
            s0[l] += a[i + l] * t[i + l];
            s1[l] += a[i + LANES + l] * t[i + LANES + l];
        }
    for (int l = 0; l < LANES; l++)
        s0[l] += s1[l];
    for (int h = LANES / 2; h > 0; h /= 2)
        for (int l = 0; l < h; l++)
            s0[l] += s0[l + h];
    sreal sum = s0[0];
    for (; i < n; i++)
        sum += a[i] * t[i];
    return sum;
}

/* out[i] += sgn (sum over columns j in [c0, c1) of X[j ld + i] v[j]) for i in [i0, i1): four
 * columns at a time, ((x0 v0 + x1 v1) + (x2 v2 + x3 v3)), then one at a time. sgn is 1 or -1
 * (exact), so one loop serves both. */
static inline __attribute__((always_inline)) void cols_acc(const float *X, size_t ld,
                                                           const sreal *v, int c0, int c1, int i0,
                                                           int i1, sreal sgn, sreal *out)
{
    int j = c0;
    for (; j + 4 <= c1; j += 4) {
        const float *x0 = X + (size_t)j * ld, *x1 = x0 + ld, *x2 = x1 + ld, *x3 = x2 + ld;
        sreal v0 = sgn * v[j], v1 = sgn * v[j + 1], v2 = sgn * v[j + 2], v3 = sgn * v[j + 3];
        for (int i = i0; i < i1; i++)
            out[i] += (x0[i] * v0 + x1[i] * v1) + (x2[i] * v2 + x3[i] * v3);
    }
    for (; j < c1; j++) {
        const float *x0 = X + (size_t)j * ld;
        sreal v0 = sgn * v[j];
        for (int i = i0; i < i1; i++)
            out[i] += x0[i] * v0;
    }
}

/* Forward substitution over the supernodes list[0..count) of one owner: their contributions to
 * rows of that owner go into y, to the top part's rows into acc (when acc is given). */
KERNEL static void forward(const NsSuperFactor *f, const int *list, int count, int self, sreal *y,
                           sreal *acc, sreal *t)
{
    for (int q = 0; q < count; q++) {
        Block b = block_of(f, list[q]);
        int nc = b.nc, nr = b.nr, nb = b.nb;
        sreal *ys = y + b.k1;
        for (int j = 0; j < nc; j++) {
            const float *col = b.X + (size_t)j * (size_t)nr;
            sreal yj = ys[j] / col[j];
            ys[j] = yj;
            for (int i = j + 1; i < nc; i++)
                ys[i] -= col[i] * yj;
        }
        for (int i = 0; i < nb; i++)
            t[i] = 0.0;
        cols_acc(b.X + nc, (size_t)nr, ys, 0, nc, 0, nb, 1.0, t);
        for (int i = 0; i < nb; i++) {
            int r = b.below[i];
            if (!acc || f->col_owner[r] == self)
                y[r] -= t[i];
            else
                acc[r] += t[i];
        }
    }
}

/* Backward substitution over list[0..count) in reverse: rows below a supernode are final. */
KERNEL static void backward(const NsSuperFactor *f, const int *list, int count, sreal *y, sreal *t)
{
    for (int q = count - 1; q >= 0; q--) {
        Block b = block_of(f, list[q]);
        int nc = b.nc, nr = b.nr, nb = b.nb;
        sreal *ys = y + b.k1;
        for (int i = 0; i < nb; i++)
            t[i] = y[b.below[i]];
        for (int j = nc - 1; j >= 0; j--) {
            const float *col = b.X + (size_t)j * (size_t)nr;
            sreal v = ys[j] - dot(col + nc, t, nb);
            v -= dot(col + j + 1, ys + j + 1, nc - j - 1);
            ys[j] = v / col[j];
        }
    }
}

/* Bin b's part of the forward (dir 0) or backward (dir 1) substitution. */
static void run_bin(NsSuperFactor *f, int b, int dir)
{
    if (dir == 0)
        forward(f, f->list[b], f->count[b], b, f->y, f->acc[b], f->tbuf[b]);
    else
        backward(f, f->list[b], f->count[b], f->y, f->tbuf[b]);
}

/* ---- The top part: few supernodes, the largest dense blocks (the root separator). Each is
 * done in column blocks of TOP_CB: the small triangle of a block on one thread, then the work
 * of the rest of the supernode against the block split in two fixed halves, run at once with
 * two threads. Which half a row or column falls in depends on the supernode alone. ---- */
#define TOP_CB 64
/* Supernodes with fewer stored entries are done on one thread (the same arithmetic). */
#define TOP_PARALLEL_MIN 32768

/* Forward: rows [r0, r1) of supernode b take the columns [c0, c1)' share (own rows from ys,
 * rows below into t). */
KERNEL static void top_rows(Block b, sreal *ys, sreal *t, int c0, int c1, int r0, int r1)
{
    int own_end = r1 < b.nc ? r1 : b.nc, below0 = r0 > b.nc ? r0 : b.nc;
    if (r0 < own_end)
        cols_acc(b.X, (size_t)b.nr, ys, c0, c1, r0, own_end, -1.0, ys);
    if (below0 < r1)
        cols_acc(b.X + b.nc, (size_t)b.nr, ys, c0, c1, below0 - b.nc, r1 - b.nc, 1.0, t);
}

/* Backward: w[j - c0] = the sum, for columns j in [j0, j1) of the block [c0, c1), of column
 * j's entries times the final values below the block (rows below the supernode, in t, and its
 * own rows from c1 on). */
KERNEL static void top_cols(Block b, const sreal *ys, const sreal *t, int c0, int c1, int j0,
                            int j1, sreal *w)
{
    for (int j = j0; j < j1; j++) {
        const float *col = b.X + (size_t)j * (size_t)b.nr;
        w[j - c0] = dot(col + b.nc, t, b.nb) + dot(col + c1, ys + c1, b.nc - c1);
    }
}

/* Part `half` (0 or 1) of the parallel work of block [c0, c1) in direction dir. */
static void top_half(Block b, sreal *ys, sreal *t, sreal *w, int c0, int c1, int dir, int half)
{
    if (dir == 0) {
        int mid = c1 + (b.nr - c1) / 2;
        top_rows(b, ys, t, c0, c1, half ? mid : c1, half ? b.nr : mid);
    } else {
        int mid = c0 + (c1 - c0) / 2;
        top_cols(b, ys, t, c0, c1, half ? mid : c0, half ? c1 : mid, w);
    }
}

/* The serial part of block [c0, c1): its triangle. */
static void top_triangle(Block b, sreal *ys, const sreal *w, int c0, int c1, int dir)
{
    if (dir == 0) {
        for (int j = c0; j < c1; j++) {
            const float *col = b.X + (size_t)j * (size_t)b.nr;
            sreal yj = ys[j] / col[j];
            ys[j] = yj;
            for (int i = j + 1; i < c1; i++)
                ys[i] -= col[i] * yj;
        }
    } else {
        for (int j = c1 - 1; j >= c0; j--) {
            const float *col = b.X + (size_t)j * (size_t)b.nr;
            sreal v = ys[j] - w[j - c0];
            for (int i = j + 1; i < c1; i++)
                v -= col[i] * ys[i];
            ys[j] = v / col[j];
        }
    }
}

/* One top supernode, forward (dir 0: blocks first to last, then the rows below get t) or
 * backward (dir 1: t gathered from the rows below, blocks last to first). */
static void top_super(NsSuperFactor *f, int s, int dir, int threads)
{
    Block b = block_of(f, s);
    sreal *y = f->y, *ys = y + b.k1, *t = f->tbuf[0], w[TOP_CB];
    for (int i = 0; i < b.nb; i++)
        t[i] = dir == 0 ? 0.0 : y[b.below[i]];
    int nblocks = (b.nc + TOP_CB - 1) / TOP_CB;
    int par = threads > 1 && (size_t)b.nr * (size_t)b.nc >= TOP_PARALLEL_MIN, done = 0;
#if NS_HAVE_OPENMP
    if (par) {
#pragma omp parallel num_threads(2)
        {
            int me = omp_get_thread_num(), nth = omp_get_num_threads();
            for (int k = 0; k < nblocks; k++) {
                int kb = dir == 0 ? k : nblocks - 1 - k;
                int c0 = kb * TOP_CB, c1 = c0 + TOP_CB < b.nc ? c0 + TOP_CB : b.nc;
                /* Forward: the triangle, then the halves; backward: the halves, then the
                 * triangle. Two barriers a block (dir is the same on both threads). */
                if (dir == 0) {
                    if (me == 0)
                        top_triangle(b, ys, w, c0, c1, dir);
#pragma omp barrier
                }
                if (me == 0)
                    top_half(b, ys, t, w, c0, c1, dir, 0);
                if (me == 1 || nth == 1)
                    top_half(b, ys, t, w, c0, c1, dir, 1);
#pragma omp barrier
                if (dir == 1) {
                    if (me == 0)
                        top_triangle(b, ys, w, c0, c1, dir);
#pragma omp barrier
                }
            }
        }
        done = 1;
    }
#else
    (void)par;
#endif
    for (int k = 0; k < nblocks && !done; k++) {
        int kb = dir == 0 ? k : nblocks - 1 - k;
        int c0 = kb * TOP_CB, c1 = c0 + TOP_CB < b.nc ? c0 + TOP_CB : b.nc;
        if (dir == 0)
            top_triangle(b, ys, w, c0, c1, dir);
        top_half(b, ys, t, w, c0, c1, dir, 0);
        top_half(b, ys, t, w, c0, c1, dir, 1);
        if (dir == 1)
            top_triangle(b, ys, w, c0, c1, dir);
    }
    if (dir == 0)
        for (int i = 0; i < b.nb; i++)
            y[b.below[i]] -= t[i];
}

/* b's entries into y for the columns of owner o's supernodes, scaled by sc (b given), or
 * those of y into x, scaled by sc (b NULL): the right-hand side in, the answer out. */
static void move_cols(NsSuperFactor *f, int o, const int *at, const double *b, double *x, double sc)
{
    sreal *y = f->y;
    for (int q = 0; q < f->count[o]; q++) {
        int s = f->list[o][q];
        for (int k = f->super[s]; k < f->super[s + 1]; k++) {
            int j = f->perm[k];
            if (b)
                y[k] = (sreal)(b[at ? at[j] : j] * sc);
            else
                x[at ? at[j] : j] = (double)y[k] * sc;
        }
    }
}

/* The largest |b| over k in [k0, k1) (NaNs ignored). */
static double abs_max(const int *at, const double *b, int k0, int k1)
{
    double big = 0.0;
    for (int k = k0; k < k1; k++) {
        double v = fabs(b[at ? at[k] : k]);
        big = v > big ? v : big;
    }
    return big;
}

/* b scaled by a power of two (exact) to a largest entry in [0.5, 1), so that the float
 * substitutions neither overflow nor lose small right-hand sides (a converging residual) to
 * underflow; the answer is scaled back: the factors for big = the largest |b|. */
static void scales(double big, double *down, double *up)
{
    int e = 0;
    if (big > 0.0 && isfinite(big))
        frexp(big, &e);
    e = e < -1020 ? -1020 : e > 1020 ? 1020 : e; /* both factors finite */
    *down = ldexp(1.0, -e);
    *up = ldexp(1.0, e);
}

/* L y = P b's forward and L^T z = y's backward substitutions on the top part, between the
 * bins' (the bins' sums into the top rows taken in a fixed order first). */
static void solve_top(NsSuperFactor *f, int threads, NsSuperMid mid, void *ctx, double down,
                      double up)
{
    sreal *y = f->y;
    for (int i = 0; i < f->ntop_cols; i++) {
        int r = f->top_cols[i];
        y[r] = (y[r] - f->acc[0][r]) - f->acc[1][r];
    }
    for (int q = 0; q < f->count[TOP]; q++)
        top_super(f, f->list[TOP][q], 0, threads);
    if (mid)
        mid(ctx, y, f->n, down, up);
    for (int q = f->count[TOP] - 1; q >= 0; q--)
        top_super(f, f->list[TOP][q], 1, threads);
}

void ns_super_solve_at(NsSuperFactor *f, const int *at, const double *b, double *x, int threads)
{
    ns_super_solve_mid(f, at, b, x, threads, NULL, NULL);
}

void ns_super_solve_mid(NsSuperFactor *f, const int *at, const double *b, double *x, int threads,
                        NsSuperMid mid, void *ctx)
{
    int n = f->n;
#if NS_HAVE_OPENMP
    if (threads > 1 && f->count[0] > 0 && f->count[1] > 0) {
        /* Each thread scales, gathers and later scatters its own bin's columns (the lighter
         * bin's thread also the top part's) next to its substitutions: the same numbers as the
         * serial path below, with no serial pass over the vectors. */
        double part[2] = {0.0, 0.0}, up = 1.0, dn = 1.0;
#pragma omp parallel num_threads(2)
        {
            int me = omp_get_thread_num(), nth = omp_get_num_threads();
            part[me] = abs_max(at, b, nth == 1 ? 0 : me * (n / 2), me == 0 && nth > 1 ? n / 2 : n);
#pragma omp barrier
            double down, u;
            scales(part[1] > part[0] ? part[1] : part[0], &down, &u);
            for (int o = 0; o < 2; o++)
                if (o == me || nth == 1) {
                    move_cols(f, o, at, b, NULL, down);
                    for (int i = 0; i < f->ntop_cols; i++)
                        f->acc[o][f->top_cols[i]] = 0.0;
                    if (o == f->light) {
                        move_cols(f, TOP, at, b, NULL, down);
                        up = u;
                        dn = down;
                    }
                    run_bin(f, o, 0);
                }
        }
        solve_top(f, threads, mid, ctx, dn, up);
#pragma omp parallel num_threads(2)
        {
            int me = omp_get_thread_num(), nth = omp_get_num_threads();
            for (int o = 0; o < 2; o++)
                if (o == me || nth == 1) {
                    run_bin(f, o, 1);
                    move_cols(f, o, at, NULL, x, up);
                    if (o == f->light)
                        move_cols(f, TOP, at, NULL, x, up);
                }
        }
        return;
    }
#endif
    double down, up;
    scales(abs_max(at, b, 0, n), &down, &up);
    for (int o = 0; o < 3; o++)
        move_cols(f, o, at, b, NULL, down);
    for (int i = 0; i < f->ntop_cols; i++) {
        f->acc[0][f->top_cols[i]] = 0.0;
        f->acc[1][f->top_cols[i]] = 0.0;
    }
    run_bin(f, 0, 0);
    run_bin(f, 1, 0);
    solve_top(f, threads, mid, ctx, down, up);
    run_bin(f, 0, 1);
    run_bin(f, 1, 1);
    for (int o = 0; o < 3; o++)
        move_cols(f, o, at, NULL, x, up);
}

void ns_super_solve(NsSuperFactor *f, const double *b, double *x, int threads)
{
    ns_super_solve_at(f, NULL, b, x, threads);
}

const int *ns_super_perm(const NsSuperFactor *f)
{
    return f->perm;
}

/* The supernode holding column c. */
static int super_of(const NsSuperFactor *f, int c)
{
    int lo = 0, hi = f->nsuper - 1;
    while (lo < hi) {
        int mid = (lo + hi + 1) / 2;
        if (f->super[mid] <= c)
            lo = mid;
        else
            hi = mid - 1;
    }
    return lo;
}

void ns_super_set_tail(NsSuperFactor *f, int k, const double *L22)
{
    int n = f->n, t0 = n - k;
    for (int c = t0; c < n; c++) {
        int s = super_of(f, c), nr = f->pi[s + 1] - f->pi[s];
        float *xc = f->x + f->px[s] + (size_t)(c - f->super[s]) * (size_t)nr;
        const int *rw = f->rows + f->pi[s];
        for (int i = 0; i < nr; i++)
            if (rw[i] >= c)
                xc[i] = (float)L22[(size_t)(rw[i] - t0) + (size_t)k * (size_t)(c - t0)];
    }
}

void ns_super_forward_unit(NsSuperFactor *f, int k, float *y)
{
    /* L e-solve along the elimination tree's path from k's supernode to the root: the only
     * supernodes whose columns L^-1 e_k reaches. */
    y[k] = 1.0f;
    for (int s = super_of(f, k); s >= 0;) {
        forward(f, &s, 1, 0, y, NULL, f->tbuf[0]);
        int nc = f->super[s + 1] - f->super[s], nr = f->pi[s + 1] - f->pi[s];
        s = nr > nc ? super_of(f, f->rows[f->pi[s] + nc]) : -1;
    }
}
