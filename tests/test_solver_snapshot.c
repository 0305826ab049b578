/* Snapshots of a solver (ns_solver_pack, sim/snapshot.h): a solver read back from a snapshot
 * goes on bit for bit as the one written, which itself goes on as if no snapshot had been
 * taken; the factor scheduled before the snapshot (in the background) is adopted by both; a
 * damaged stream is refused. The matrices are a tissue's (a gel block with clamped sides, a
 * growing force pulling its middle sideways), one per step. */
#include <stdlib.h>

#include "mesh_grid.h"
#include "ns_test.h"
#include "snapshot.h"
#include "solver.h"
#include "tissue.h"

enum { STEPS = 8, NX = 12, NYZ = 6, RING = 32, KMAX = 3 * RING };
#define LEN   0.024
#define WIDTH 0.012

/* The tissue's system matrices of STEPS steps (same pattern), the same with the middle node's
 * block stiffened (T: for the tail's updates, a change of the trailing block that a float copy
 * sees), its fixed DOFs and the middle node. */
typedef struct Mats {
    NsBlockMatrix A[STEPS], T[STEPS];
    uint8_t *fixed;
    int n3, mid;
} Mats;

static void bsm_copy(NsBlockMatrix *dst, const NsBlockMatrix *src)
{
    ns_bsm_init(dst);
    ns_bsm_resize(dst, src->n);
    for (int i = 0; i < src->n; i++)
        for (int e = 0; e < src->rows[i].count; e++)
            ns_bsm_add(dst, i, src->rows[i].col[e], src->rows[i].val + 9 * e);
}

static int mats_make(Mats *m)
{
    char err[256];
    NsMesh mesh;
    NsTissue t;
    double lo[3] = {0.0, -0.5 * WIDTH, -0.5 * WIDTH}, hi[3] = {LEN, 0.5 * WIDTH, 0.5 * WIDTH};
    ENSURE(ns_mesh_grid_box(&mesh, lo, hi, NX, NYZ, NYZ, 0, err, sizeof err) == 0);
    NsTissueMaterial mat = {ns_fem_material(NS_MODEL_COROTATIONAL, 30e3, 0.45, 3.0, 3.0), 1000.0};
    NsTissueParams tp = ns_default_tissue_params();
    ENSURE(ns_tissue_init(&t, &mesh, &mat, 1, &tp, err, sizeof err) == 0);
    const NsMesh *M = &t.mesh;
    m->mid = NX / 2 + (NX + 1) * (NYZ / 2 + (NYZ + 1) * (NYZ / 2));
    for (int i = 0; i < M->node_slots; i++) {
        const double *u = M->u + 3 * i;
        if (fabs(fabs(u[1]) - 0.5 * WIDTH) < 1e-9 || fabs(fabs(u[2]) - 0.5 * WIDTH) < 1e-9)
            for (int c = 0; c < 3; c++)
                ns_tissue_fix_dof(&t, i, c, 1);
    }
    m->n3 = 3 * M->node_slots;
    double *ext = calloc((size_t)m->n3, sizeof *ext);
    NsSolver *s = ns_solver_create(NS_SOLVER_DIRECT);
    int ok = ext && s;
    for (int k = 0; k < STEPS && ok; k++) {
        ext[3 * m->mid + 1] = 0.05 * (k + 1);
        NsTissueStats st;
        ok = ns_tissue_step(&t, s, 2e-3, ext, &st) == 0;
        bsm_copy(&m->A[k], &t.A);
        bsm_copy(&m->T[k], &t.A);
        const double *d = ns_bsm_find(&t.A, m->mid, m->mid);
        double w = d ? 0.2 * (k + 1) * d[0] : 0.0, D[9] = {w, 0, 0, 0, w, 0, 0, 0, w};
        ns_bsm_add(&m->T[k], m->mid, m->mid, D);
    }
    m->fixed = malloc((size_t)m->n3);
    if (m->fixed)
        memcpy(m->fixed, t.dof_fixed, (size_t)m->n3);
    ns_solver_destroy(s);
    free(ext);
    ns_tissue_free(&t);
    ns_mesh_free(&mesh);
    ENSURE(ok && m->fixed);
    return 0;
}

static void mats_free(Mats *m)
{
    for (int k = 0; k < STEPS; k++) {
        ns_bsm_free(&m->A[k]);
        ns_bsm_free(&m->T[k]);
    }
    free(m->fixed);
}

static void rhs(double *b, int n3, int k)
{
    for (int i = 0; i < n3; i++)
        b[i] = sin(0.37 * i + 0.05 * k) + 0.1;
}

/* The solver written to memory and read back into *out; 0, or 1 with the reader's message. */
static int round_trip(NsSolver *s, NsSolver **out, NsPack *w)
{
    ns_pack_writer(w, NULL);
    ENSURE(ns_solver_pack(w, &s) == 0 && ns_pack_checksum(w) == 0);
    NsPack r;
    ns_pack_reader(&r, NULL, w->buf, w->len);
    int rc = ns_solver_pack(&r, out);
    if (rc == 0)
        rc = ns_pack_checksum(&r);
    if (rc)
        fprintf(stderr, "read back: %s\n", r.err);
    ENSURE(rc == 0 && r.pos == w->len);
    return 0;
}

/* The copy writes the same bytes again: everything held came back. */
static int same_stream(NsSolver *s, const NsPack *w)
{
    NsPack again;
    ns_pack_writer(&again, NULL);
    ENSURE(ns_solver_pack(&again, &s) == 0 && ns_pack_checksum(&again) == 0);
    int same = again.len == w->len && memcmp(again.buf, w->buf, w->len) == 0;
    ns_pack_free(&again);
    ENSURE(same);
    return 0;
}

static int same_stats(const NsSolveStats *a, const NsSolveStats *b)
{
    return a->iterations == b->iterations && memcmp(&a->residual, &b->residual, 8) == 0 &&
           a->converged == b->converged && a->factorized == b->factorized &&
           a->analyzed == b->analyzed && a->refresh_started == b->refresh_started &&
           a->refresh_adopted == b->refresh_adopted && a->factor_age == b->factor_age;
}

static NsSolver *stale_solver(int refresh)
{
    NsSolver *s = ns_solver_create(NS_SOLVER_STALE_PCG);
    ns_solver_set_threads(s, 2);
    ns_solver_set_refresh_iterations(s, refresh);
    return s;
}

/* STALE_PCG (refactoring after solves of more than `refresh` iterations) through the tissue's
 * matrices, written after solve k0 - 1 and read back, for every k0: the original, the copy and
 * a solver never written solve the rest alike, bit for bit. *pending and *idle count the
 * snapshots taken with a refactorization pending (running in the background) and without. */
static int resume_each(const Mats *m, int refresh, int *pending_at, int *idle_at)
{
    int n3 = m->n3;
    size_t bytes = (size_t)n3 * sizeof(double);
    double *b = malloc(bytes), *xs = calloc((size_t)n3 * STEPS, sizeof *xs);
    double *x = calloc((size_t)n3, sizeof *x), *y = malloc(bytes);
    NsSolveStats ref[STEPS], sx, sy;
    NsSolver *r = stale_solver(refresh);
    for (int k = 0; k < STEPS; k++) {
        rhs(b, n3, k);
        ENSURE(ns_solver_solve(r, &m->A[k], m->fixed, b, x, 1e-10, 2000, &ref[k]) == 0);
        ENSURE(ref[k].converged);
        memcpy(xs + (size_t)k * n3, x, bytes);
    }
    ns_solver_destroy(r);
    for (int k0 = 1; k0 < STEPS; k0++) {
        NsSolver *s = stale_solver(refresh), *c = NULL;
        memset(x, 0, bytes);
        for (int k = 0; k < k0; k++) {
            rhs(b, n3, k);
            ENSURE(ns_solver_solve(s, &m->A[k], m->fixed, b, x, 1e-10, 2000, &sx) == 0);
        }
        /* Pending: scheduled by solve k0 - 2 or k0 - 1 (adopted two solves later). */
        int pending = ref[k0 - 1].refresh_started || (k0 >= 2 && ref[k0 - 2].refresh_started);
        *pending_at += pending;
        *idle_at += !pending;
        NsPack w;
        ENSURE(round_trip(s, &c, &w) == 0);
        ENSURE(same_stream(c, &w) == 0);
        ns_pack_free(&w);
        memcpy(y, x, bytes);
        for (int k = k0; k < STEPS; k++) {
            rhs(b, n3, k);
            ENSURE(ns_solver_solve(s, &m->A[k], m->fixed, b, x, 1e-10, 2000, &sx) == 0);
            ENSURE(ns_solver_solve(c, &m->A[k], m->fixed, b, y, 1e-10, 2000, &sy) == 0);
            ENSURE(memcmp(x, xs + (size_t)k * n3, bytes) == 0);
            ENSURE(memcmp(y, x, bytes) == 0);
            ENSURE(same_stats(&sx, &ref[k]) && same_stats(&sy, &sx));
            ENSURE(ns_solver_factor_count(c) == ns_solver_factor_count(s));
        }
        ns_solver_destroy(s);
        ns_solver_destroy(c);
    }
    free(b);
    free(xs);
    free(x);
    free(y);
    return 0;
}

static int stale_pcg_resumes(void)
{
    Mats m;
    ENSURE(mats_make(&m) == 0);
    int pending_at = 0, idle_at = 0;
    ENSURE(resume_each(&m, 2, &pending_at, &idle_at) == 0);
    ENSURE(resume_each(&m, 9, &pending_at, &idle_at) == 0);
    printf("  written with a refactorization pending at %d solves, none at %d\n", pending_at,
           idle_at);
    ENSURE(pending_at >= 2 && idle_at >= 2);
    mats_free(&m);
    return 0;
}

static void mid_scale(void *ctx, float *y, int n, double down, double up)
{
    (void)ctx;
    (void)down;
    (void)up;
    for (int i = 0; i < n; i += 7)
        y[i] *= 0.5f;
}

/* Everything the coupled solver asks of a DIRECT solver with a tail, with step k's matrix and
 * right-hand side: into out (4 n3 doubles, then the tail block, KMAX^2 at most) and yf. */
static int use_factor(NsSolver *s, const Mats *m, int k, double *out, float *yf)
{
    int n3 = m->n3;
    double *b = malloc((size_t)n3 * sizeof *b);
    rhs(b, n3, k);
    ENSURE(ns_solver_apply(s, n3, 1, b, out) == 0);
    ENSURE(ns_solver_precondition(s, n3, b, out + n3) == 0);
    ENSURE(ns_solver_tail_update(s, &m->T[k]) > 0);
    ENSURE(ns_solver_precondition(s, n3, b, out + 2 * n3) == 0);
    ENSURE(ns_solver_precondition_mid(s, n3, b, out + 3 * n3, mid_scale, NULL) == 0);
    const double *L22;
    int kt = ns_solver_tail_block(s, n3, &L22);
    ENSURE(kt > 0 && kt <= KMAX);
    for (int j = 0; j < kt; j++) /* its lower triangle: the rest is not read */
        for (int i = j; i < kt; i++)
            out[4 * n3 + i + kt * j] = L22[i + kt * j];
    int nf = ns_solver_forward_dof(s, n3, 0, NULL);
    ENSURE(nf > 0);
    memset(yf, 0, (size_t)nf * sizeof *yf);
    ENSURE(ns_solver_forward_dof(s, n3, 3 * m->mid + 1, yf) == nf);
    free(b);
    return 0;
}

static NsSolver *direct_solver(const Mats *m)
{
    NsSolver *s = ns_solver_create(NS_SOLVER_DIRECT);
    int ring[RING], nr = 0;
    const NsBlockRow *row = &m->A[0].rows[m->mid];
    for (int e = 0; e < row->count && nr < RING; e++)
        ring[nr++] = row->col[e];
    ns_solver_set_tail(s, ring, nr);
    ns_solver_set_threads(s, 2);
    return s;
}

/* The coupled solver's use of a DIRECT solver: factor, copy with its tail block made current,
 * columns; a factorization with columns scheduled (running in the background) and then the
 * snapshot. The original, the copy (its columns' arrays moved) and a solver never written adopt
 * it alike and go on alike. Also the damaged streams of that state. */
static int factor_async_adopted_alike(void)
{
    Mats m;
    ENSURE(mats_make(&m) == 0);
    const int n3 = m.n3, cols = 6;
    size_t nout = 4 * (size_t)n3 + KMAX * KMAX;
    double *B = calloc((size_t)n3 * cols, sizeof *B), *Z[3], *out[3];
    float *yf[3];
    for (int j = 0; j < cols; j++)
        B[(size_t)j * n3 + 3 * m.mid + j % 3 + 3 * (j / 3)] = 1.0;
    NsSolver *s[3];
    for (int v = 0; v < 3; v++) { /* 0 never written, 1 written, 2 read back */
        Z[v] = calloc((size_t)n3 * cols, sizeof *Z[v]);
        out[v] = calloc(nout, sizeof *out[v]);
        yf[v] = calloc((size_t)n3, sizeof *yf[v]);
    }
    NsPack w;
    for (int v = 0; v < 2; v++) {
        s[v] = direct_solver(&m);
        ENSURE(ns_solver_factor(s[v], &m.A[0], m.fixed) == 0);
        ENSURE(use_factor(s[v], &m, 1, out[v], yf[v]) == 0);
        ENSURE(ns_solver_factor_async(s[v], &m.A[2], m.fixed, cols, B, Z[v]) == 0);
    }
    ENSURE(round_trip(s[1], &s[2], &w) == 0);
    ENSURE(same_stream(s[2], &w) == 0);
    double *B2 = malloc((size_t)n3 * cols * sizeof *B2);
    memcpy(B2, B, (size_t)n3 * cols * sizeof *B);
    memcpy(Z[2], Z[1], (size_t)n3 * cols * sizeof *Z[1]); /* what the owner's pack does */
    ns_solver_factor_async_moved(s[2], B2, Z[2]);
    for (int phase = 0; phase < 4; phase++) {
        for (int v = 0; v < 3; v++) {
            int ok = -1;
            if (phase == 1)
                ENSURE(ns_solver_factor_adopt(s[v], &ok) == 1 && ok);
            else if (phase > 1)
                ENSURE(ns_solver_factor(s[v], &m.A[phase + 1], m.fixed) == 0);
            /* phase 0: still the old factor, its copy's tail block as written */
            ENSURE(use_factor(s[v], &m, phase + 2, out[v], yf[v]) == 0);
        }
        for (int v = 1; v < 3; v++) {
            /* Z belongs to the pending factorization until it is adopted (solver.h): at phase 0
             * the never-written solver's may still be being written on its thread */
            ENSURE(phase == 0 || memcmp(Z[v], Z[0], (size_t)n3 * cols * sizeof *Z[0]) == 0);
            ENSURE(memcmp(out[v], out[0], nout * sizeof *out[0]) == 0);
            ENSURE(memcmp(yf[v], yf[0], (size_t)n3 * sizeof *yf[0]) == 0);
            ENSURE(ns_solver_factor_count(s[v]) == ns_solver_factor_count(s[0]));
        }
    }
    size_t cut[3][3];
    for (int v = 0; v < 3; v++)
        ENSURE(ns_solver_precondition_cut(s[v], cut[v]) == 0);
    ENSURE(memcmp(cut[1], cut[0], sizeof cut[0]) == 0 &&
           memcmp(cut[2], cut[0], sizeof cut[0]) == 0);
    /* Cut short anywhere, the stream is refused with a message, and what was read is freed. */
    int refused = 0, tries = 0;
    for (int i = 0; i <= 40; i++, tries++) {
        size_t len = i < 40 ? w.len * (size_t)i / 40 : w.len - 1;
        NsPack r;
        NsSolver *d = NULL;
        ns_pack_reader(&r, NULL, w.buf, len);
        int rc = ns_solver_pack(&r, &d);
        if (rc == 0)
            rc = ns_pack_checksum(&r);
        refused += rc == -1 && r.err[0] != '\0';
        ns_solver_destroy(d);
    }
    printf("  %zu bytes; cut short at %d places, refused at %d\n", w.len, tries, refused);
    ENSURE(refused == tries && tries > 20);
    ns_pack_free(&w);
    for (int v = 0; v < 3; v++) {
        ns_solver_destroy(s[v]);
        free(Z[v]);
        free(out[v]);
        free(yf[v]);
    }
    free(B);
    free(B2);
    mats_free(&m);
    return 0;
}

/* No solver, and a solver without a factor (CG), come back as they were. */
static int empty_and_cg(void)
{
    NsSolver *none = NULL, *back = NULL, *cg = ns_solver_create(NS_SOLVER_CG);
    NsPack w;
    ENSURE(round_trip(none, &back, &w) == 0 && back == NULL);
    ns_pack_free(&w);
    ns_solver_set_threads(cg, 3);
    ENSURE(round_trip(cg, &back, &w) == 0 && back != NULL);
    ENSURE(ns_solver_kind(back) == NS_SOLVER_CG && ns_solver_factor_count(back) == 0);
    ENSURE(same_stream(back, &w) == 0);
    ns_pack_free(&w);
    ns_solver_destroy(cg);
    ns_solver_destroy(back);
    return 0;
}

NS_TEST_MAIN({"stale_pcg_resumes", stale_pcg_resumes},
             {"factor_async_adopted_alike", factor_async_adopted_alike},
             {"empty_and_cg", empty_and_cg})
