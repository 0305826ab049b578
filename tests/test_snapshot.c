/* Tests of world snapshots (sim/snapshot.h): a world restored from a snapshot, in memory or from
 * a file, steps on bit for bit as the original (the same ns_tissue_state_hash and
 * ns_rod_state_hash after more steps), restores as often as wanted, and writes the same bytes
 * again; a damaged or truncated file is refused with a message and nothing leaks. Two scenes, both
 * with the paper's solver (ours keeps a factor the snapshots do not hold yet): a needle cutting
 * by remeshing (Algorithm 2, a gel block as engine/validate_remesh.c's) and one cutting along a
 * pre-laid path (tests/test_coupling.c's). */
#include <stdlib.h>
#include <time.h>

#include "coupling.h"
#include "mesh_grid.h"
#include "ns_test.h"
#include "snapshot.h"
#include "step.h"

typedef struct World {
    NsTissue tissue;
    NsRod rod;
    NsCoupled cpl;
} World;

typedef struct Hashes {
    uint64_t tissue, rod;
} Hashes;

static void world_free(World *w)
{
    ns_coupled_free(&w->cpl);
    ns_rod_free(&w->rod);
    ns_tissue_free(&w->tissue);
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void fix_sides(NsTissue *t, double width)
{
    const NsMesh *M = &t->mesh;
    for (int i = 0; i < M->node_slots; i++) {
        const double *u = M->u + 3 * i;
        if (fabs(fabs(u[1]) - 0.5 * width) < 1e-9 || fabs(fabs(u[2]) - 0.5 * width) < 1e-9)
            for (int c = 0; c < 3; c++)
                ns_tissue_fix_dof(t, i, c, 1);
    }
}

static NsTissueParams tissue_params(int threads)
{
    NsTissueParams tp = ns_default_tissue_params();
    tp.gamma = 0.55;
    tp.beta = 0.25 * 1.05 * 1.05;
    tp.threads = threads;
    return tp;
}

static int make_tissue(NsTissue *t, double len, double width, int nx, int nyz, int threads)
{
    char err[256];
    NsMesh mesh;
    double lo[3] = {0.0, -0.5 * width, -0.5 * width}, hi[3] = {len, 0.5 * width, 0.5 * width};
    ENSURE(ns_mesh_grid_box(&mesh, lo, hi, nx, nyz, nyz, 0, err, sizeof err) == 0);
    NsTissueMaterial mat = {ns_fem_material(NS_MODEL_COROTATIONAL, 30e3, 0.45, 3.0, 3.0), 1000.0};
    NsTissueParams tp = tissue_params(threads);
    int rc = ns_tissue_init(t, &mesh, &mat, 1, &tp, err, sizeof err);
    ns_mesh_free(&mesh);
    ENSURE(rc == 0);
    return 0;
}

/* The remeshing scene (engine/validate_remesh.c's insertion): a block of len x width x width
 * with clamped sides in cells of h, the needle entering off the centre line by skin entry. */
static int remesh_world(World *w, double len, double width, double h, int threads)
{
    memset(w, 0, sizeof *w);
    char err[256];
    ENSURE(make_tissue(&w->tissue, len, width, (int)lround(len / h), (int)lround(width / h),
                       threads) == 0);
    NsMesh *M = &w->tissue.mesh;
    double a[3] = {0.0, 0.37 * h, -0.23 * h}, dir[3] = {1.0, 0.0, 0.0};
    int nodes[2];
    NsRemeshStack entry;
    ns_remesh_stack_init(&entry);
    ENSURE(ns_remesh_skin_entry(M, &entry, a, dir, 0.1 * h, nodes, err, sizeof err) == 0);
    ENSURE(ns_tissue_sync_topology(&w->tissue, err, sizeof err) == 0);
    fix_sides(&w->tissue, width);
    double x[3 * 6];
    const double *e0 = M->x + 3 * nodes[0];
    for (int i = 0; i < 4; i++) {
        x[3 * i] = e0[0] - 0.005 * (4 - i);
        x[3 * i + 1] = e0[1];
        x[3 * i + 2] = e0[2];
    }
    for (int i = 0; i < 2; i++)
        memcpy(x + 3 * (4 + i), M->x + 3 * nodes[i], 3 * sizeof *x);
    NsRodParams rp = ns_default_rod_params();
    rp.gamma = w->tissue.params.gamma;
    rp.beta = w->tissue.params.beta;
    double d1[3] = {0.0, 1.0, 0.0};
    ENSURE(ns_rod_init(&w->rod, x, 6, d1, 2, &rp, err, sizeof err) == 0);
    const double *u0 = M->u + 3 * nodes[0], *u1 = M->u + 3 * nodes[1];
    double s = sqrt((u1[0] - u0[0]) * (u1[0] - u0[0]) + (u1[1] - u0[1]) * (u1[1] - u0[1]) +
                    (u1[2] - u0[2]) * (u1[2] - u0[2]));
    NsNeedlePath path;
    ENSURE(ns_needle_path_init(&path, M, nodes, 2, s, err, sizeof err) == 0);
    NsCouplingParams cp = ns_default_coupling_params();
    cp.f_perlen = 10.0;
    cp.cut_force[0] = 0.05;
    cp.remesh = 1;
    cp.solver = NS_COUPLED_PAPER;
    cp.threads = threads;
    ENSURE(ns_coupled_init(&w->cpl, &w->tissue, &w->rod, &path, &cp, err, sizeof err) == 0);
    ns_remesh_stack_free(&w->cpl.remesh);
    w->cpl.remesh = entry;
    return 0;
}

/* tests/test_coupling.c's scene (nx 8, nyz 4): a block of nx x nyz x nyz cells of 2 mm, the
 * needle's tip half way in along a laid path. */
static int path_world(World *w, int nx, int nyz)
{
    const double h = 0.002, width = nyz * h;
    memset(w, 0, sizeof *w);
    char err[256];
    ENSURE(make_tissue(&w->tissue, nx * h, width, nx, nyz, 1) == 0);
    fix_sides(&w->tissue, width);
    int path[64], tip = nx / 2, out = 4, n = out + 1 + tip + 1;
    double x[3 * 64] = {0};
    ENSURE(nx < 64 && n < 64);
    for (int i = 0; i <= nx; i++)
        path[i] = i + (nx + 1) * (nyz / 2 + (nyz + 1) * (nyz / 2));
    for (int i = 0; i < n; i++)
        x[3 * i] = (i - out - 1) * h;
    double d1[3] = {0.0, 1.0, 0.0};
    NsRodParams rp = ns_default_rod_params();
    rp.gamma = 0.55;
    rp.beta = 0.25 * 1.05 * 1.05;
    ENSURE(ns_rod_init(&w->rod, x, n, d1, 2, &rp, err, sizeof err) == 0);
    NsNeedlePath p;
    ENSURE(ns_needle_path_init(&p, &w->tissue.mesh, path, nx + 1, tip * h, err, sizeof err) == 0);
    NsCouplingParams cp = ns_default_coupling_params();
    cp.f_perlen = 20.0;
    cp.cut_force[0] = 0.05;
    cp.solver = NS_COUPLED_PAPER;
    ENSURE(ns_coupled_init(&w->cpl, &w->tissue, &w->rod, &p, &cp, err, sizeof err) == 0);
    return 0;
}

/* n steps of dt at insertion speed v; 0, or 1 if a step failed. */
static int steps(World *w, int n, double v, double dt)
{
    const double vb[3] = {0, 0, 0};
    NsStepControls ctl = ns_step_controls(v, vb, 0.0);
    for (int k = 0; k < n; k++) {
        NsCouplingStats st;
        if (ns_step(&w->cpl, &ctl, dt, &st) != 0) {
            fprintf(stderr, "step %d: %s\n", k, w->cpl.error);
            return 1;
        }
    }
    return 0;
}

static Hashes hashes(const World *w)
{
    Hashes h = {ns_tissue_state_hash(&w->tissue), ns_rod_state_hash(&w->rod)};
    return h;
}

/* FNV-1a of a snapshot's bytes: two snapshots are compared by length and this. */
static uint64_t bytes_hash(const NsWorldSnapshot *s)
{
    uint64_t h = 14695981039346656037ULL;
    for (size_t i = 0; i < s->len; i++) {
        h ^= s->bytes[i];
        h *= 1099511628211ULL;
    }
    return h;
}

static int restore(const NsWorldSnapshot *s, World *w)
{
    char err[256] = "";
    int rc = ns_world_restore(s, &w->tissue, &w->rod, &w->cpl, err, sizeof err);
    if (rc != 0)
        fprintf(stderr, "restore: %s\n", err);
    return rc;
}

static int same_snapshot(World *w, const NsWorldSnapshot *s)
{
    NsWorldSnapshot again;
    char err[256];
    ENSURE(ns_world_snapshot(&w->tissue, &w->rod, &w->cpl, &again, err, sizeof err) == 0);
    int same = again.len == s->len && bytes_hash(&again) == bytes_hash(s);
    ns_world_snapshot_free(&again);
    ENSURE(same);
    return 0;
}

/* Restored from s (fresh structures), the world writes s's bytes again, then steps m steps to
 * the hashes want. */
static int restored_steps_to(const NsWorldSnapshot *s, int m, double v, double dt, Hashes want)
{
    World w;
    ENSURE(restore(s, &w) == 0);
    int rc = same_snapshot(&w, s) || steps(&w, m, v, dt);
    Hashes h = hashes(&w);
    world_free(&w);
    ENSURE(rc == 0);
    ENSURE(h.tissue == want.tissue && h.rod == want.rod);
    return 0;
}

/* In 32 steps of 0.2 mm the tip has split the tissue (the split on the stack; the skin entry's
 * tip node starts about half an element in and snaps its way on before it needs one); the next 30
 * undo it, split again and snap. */
enum { N_IN = 32, M_MORE = 30 };
#define SPEED 0.02
#define DT    0.01

/* The remeshing scene N_IN steps in (the entry's and the cut's splits on the stack, the shaft
 * sliding), snapshot in memory. */
static int remesh_snapshot(World *w, NsWorldSnapshot *s)
{
    ENSURE(remesh_world(w, 0.036, 0.012, 0.003, 2) == 0);
    ENSURE(steps(w, N_IN, SPEED, DT) == 0);
    int sliding = 0;
    for (int i = 0; i < w->rod.nodes; i++)
        sliding += w->cpl.state[i] == NS_FRICTION_DYN_POS;
    printf("  after %d steps: %d needle nodes, %d sliding, %d splits on the stack, %d tets\n", N_IN,
           w->rod.nodes, sliding, w->cpl.remesh.count, w->tissue.mesh.tet_alive);
    ENSURE(w->cpl.remesh.count > 0 && w->cpl.remesh.snaps > 0 && sliding > 0);
    ENSURE(w->cpl.schur == NULL); /* the paper's solver: nothing that does not pack yet */
    char err[256];
    ENSURE(ns_world_snapshot(&w->tissue, &w->rod, &w->cpl, s, err, sizeof err) == 0);
    return 0;
}

static int remesh_memory(void)
{
    World w;
    NsWorldSnapshot s;
    ENSURE(remesh_snapshot(&w, &s) == 0);
    ENSURE(same_snapshot(&w, &s) == 0);
    ENSURE(steps(&w, M_MORE, SPEED, DT) == 0);
    Hashes want = hashes(&w);
    world_free(&w);
    ENSURE(restored_steps_to(&s, M_MORE, SPEED, DT, want) == 0);
    ENSURE(restored_steps_to(&s, M_MORE, SPEED, DT, want) == 0); /* the same snapshot again */
    /* The check can fail: a restored world without the lazy Jacobians' reference (every tet
     * rebuilt, §3.6.3) steps elsewhere. */
    World c;
    ENSURE(restore(&s, &c) == 0);
    memset(c.tissue.jvalid, 0, (size_t)c.tissue.mesh.tet_slots);
    int rc = steps(&c, M_MORE, SPEED, DT);
    Hashes other = hashes(&c);
    world_free(&c);
    ns_world_snapshot_free(&s);
    ENSURE(rc == 0);
    ENSURE(other.tissue != want.tissue);
    return 0;
}

/* The world written to f; *len its bytes. */
static int write_file(World *w, FILE *f, size_t *len)
{
    NsPack p;
    ns_pack_writer(&p, f);
    ENSURE(ns_world_pack(&p, &w->tissue, &w->rod, &w->cpl) == 0);
    ENSURE(fflush(f) == 0);
    *len = p.pos;
    ns_pack_free(&p);
    return 0;
}

/* Reads a world from the first len bytes of f into w; returns ns_world_pack's result, the
 * message in err. */
static int read_file(FILE *f, size_t len, World *w, char *err, size_t err_sz)
{
    rewind(f);
    NsPack p;
    ns_pack_reader(&p, f, NULL, len);
    int rc = ns_world_pack(&p, &w->tissue, &w->rod, &w->cpl);
    snprintf(err, err_sz, "%s", p.err);
    ns_pack_free(&p);
    return rc;
}

/* bytes[0 .. len) into a new temporary file, which it returns (NULL on failure). */
static FILE *file_of(const unsigned char *bytes, size_t len)
{
    FILE *f = tmpfile();
    if (f && (fwrite(bytes, 1, len, f) != len || fflush(f) != 0)) {
        fclose(f);
        f = NULL;
    }
    return f;
}

/* The damaged copy of s (byte at flipped by mask; or the first len bytes) refused, with a
 * message, the structures freeable. */
static int refused(const NsWorldSnapshot *s, size_t at, unsigned char mask, size_t len)
{
    unsigned char *b = malloc(s->len);
    ENSURE(b != NULL);
    memcpy(b, s->bytes, s->len);
    if (at < s->len)
        b[at] ^= mask;
    FILE *f = file_of(b, len);
    free(b);
    ENSURE(f != NULL);
    World w;
    char err[256];
    int rc = read_file(f, len, &w, err, sizeof err);
    fclose(f);
    world_free(&w);
    if (rc != -1 || err[0] == '\0')
        fprintf(stderr, "  byte %zu ^ %#x, %zu bytes: accepted\n", at, mask, len);
    ENSURE(rc == -1 && err[0] != '\0');
    return 0;
}

static int remesh_file(void)
{
    World w;
    NsWorldSnapshot s;
    ENSURE(remesh_snapshot(&w, &s) == 0);
    FILE *f = tmpfile();
    ENSURE(f != NULL);
    size_t len = 0;
    ENSURE(write_file(&w, f, &len) == 0);
    ENSURE(len == s.len);
    ENSURE(steps(&w, M_MORE, SPEED, DT) == 0);
    Hashes want = hashes(&w);
    world_free(&w);
    World r;
    char err[256];
    int rc = read_file(f, len, &r, err, sizeof err);
    fclose(f);
    if (rc != 0)
        fprintf(stderr, "read: %s\n", err);
    rc = rc || same_snapshot(&r, &s) || steps(&r, M_MORE, SPEED, DT);
    Hashes h = hashes(&r);
    world_free(&r);
    ENSURE(rc == 0);
    ENSURE(h.tissue == want.tissue && h.rod == want.rod);
    /* Damaged: one byte flipped (the header, the first structures' sizes, spread over the
     * arrays, the checksum), or cut short. */
    size_t at[] = {0,    5,         12,        40,        100,       300,
                   1000, s.len / 7, s.len / 3, s.len / 2, s.len - 9, s.len - 1};
    for (size_t k = 0; k < sizeof at / sizeof at[0]; k++)
        ENSURE(refused(&s, at[k], 0x10, s.len) == 0);
    for (int k = 1; k <= 16; k++)
        ENSURE(refused(&s, (size_t)k * s.len / 17, 0x01, s.len) == 0);
    ENSURE(refused(&s, s.len, 0, s.len / 2) == 0);
    ENSURE(refused(&s, s.len, 0, s.len - 1) == 0);
    ENSURE(refused(&s, s.len, 0, 3) == 0);
    ns_world_snapshot_free(&s);
    return 0;
}

static int path_cut(void)
{
    World w;
    ENSURE(path_world(&w, 8, 4) == 0);
    ENSURE(steps(&w, 20, 0.01, 5e-3) == 0);
    int sliding = 0;
    for (int i = 0; i < w.rod.nodes; i++)
        sliding += w.cpl.state[i] == NS_FRICTION_DYN_POS;
    ENSURE(sliding > 0 && w.cpl.params.remesh == 0);
    NsWorldSnapshot s;
    char err[256];
    ENSURE(ns_world_snapshot(&w.tissue, &w.rod, &w.cpl, &s, err, sizeof err) == 0);
    /* in 10 steps more, then out 10 */
    int rc = steps(&w, 10, 0.01, 5e-3) || steps(&w, 10, -0.01, 5e-3);
    Hashes want = hashes(&w);
    world_free(&w);
    ENSURE(rc == 0);
    for (int k = 0; k < 2; k++) {
        World r;
        ENSURE(restore(&s, &r) == 0);
        rc = same_snapshot(&r, &s) || steps(&r, 10, 0.01, 5e-3) || steps(&r, 10, -0.01, 5e-3);
        Hashes h = hashes(&r);
        world_free(&r);
        ENSURE(rc == 0);
        ENSURE(h.tissue == want.tissue && h.rod == want.rod);
    }
    ns_world_snapshot_free(&s);
    return 0;
}

/* Every byte of each structure's own bytes flipped in turn (sizes, counts, the blanked pointers)
 * in a small world's snapshot: each refused with a message, nothing leaked or read out of
 * bounds (the sanitizer build). */
static int damaged_headers(void)
{
    World w;
    ENSURE(path_world(&w, 4, 2) == 0);
    ENSURE(steps(&w, 3, 0.01, 5e-3) == 0);
    NsWorldSnapshot s;
    char err[256];
    ENSURE(ns_world_snapshot(&w.tissue, &w.rod, &w.cpl, &s, err, sizeof err) == 0);
    world_free(&w);
    const char *tags[] = {"TISS", "MESH", "BSMX", "ROD ", "BAND", "CPLD", "PATH", "RSTK"};
    const size_t sizes[] = {sizeof(NsTissue),     sizeof(NsMesh),       sizeof(NsBlockMatrix),
                            sizeof(NsRod),        sizeof(NsBanded),     sizeof(NsCoupled),
                            sizeof(NsNeedlePath), sizeof(NsRemeshStack)};
    int flips = 0;
    for (int k = 0; k < 8; k++) {
        size_t at = 0;
        while (at + 4 <= s.len && memcmp(s.bytes + at, tags[k], 4) != 0)
            at++;
        ENSURE(at + 4 + sizes[k] <= s.len);
        for (size_t i = at + 4; i < at + 4 + sizes[k]; i++) {
            s.bytes[i] ^= 0x81;
            World r;
            err[0] = '\0';
            int rc = ns_world_restore(&s, &r.tissue, &r.rod, &r.cpl, err, sizeof err);
            world_free(&r);
            s.bytes[i] ^= 0x81;
            if (rc != -1 || err[0] == '\0')
                fprintf(stderr, "  %.4s + %zu: accepted\n", tags[k], i - at - 4);
            ENSURE(rc == -1 && err[0] != '\0');
            flips++;
        }
    }
    printf("  %d flips in %zu bytes refused\n", flips, s.len);
    ns_world_snapshot_free(&s);
    return 0;
}

/* What a snapshot costs on the largest scene here (printed, not checked). */
static int cost(void)
{
    World w;
    ENSURE(remesh_world(&w, 0.1, 0.032, 0.004, 1) == 0);
    ENSURE(steps(&w, 5, SPEED, DT) == 0);
    NsWorldSnapshot s;
    char err[256];
    const int reps = 5;
    double t0 = now_s();
    for (int k = 0; k < reps; k++) {
        if (k > 0)
            ns_world_snapshot_free(&s);
        ENSURE(ns_world_snapshot(&w.tissue, &w.rod, &w.cpl, &s, err, sizeof err) == 0);
    }
    double t1 = now_s();
    for (int k = 0; k < reps; k++) {
        World r;
        ENSURE(restore(&s, &r) == 0);
        world_free(&r);
    }
    double t2 = now_s();
    printf("  %d tets, %d nodes: snapshot %.1f MB, %.2f ms to write, %.2f ms to restore (and "
           "free)\n",
           w.tissue.mesh.tet_alive, w.tissue.mesh.node_alive, 1e-6 * (double)s.len,
           1e3 * (t1 - t0) / reps, 1e3 * (t2 - t1) / reps);
    ns_world_snapshot_free(&s);
    world_free(&w);
    return 0;
}

NS_TEST_MAIN({"remesh_memory", remesh_memory}, {"remesh_file", remesh_file}, {"path_cut", path_cut},
             {"damaged_headers", damaged_headers}, {"cost", cost})
