/* Tests for sim/vec.h, the vector kernels both coupled solvers' CG loops share: the dot
 * product's fixed order, the fixed-DOF mask, where a vector is cut for two threads, and that a
 * pass gives the same bits on one thread and on two. The solvers' use of them on meshes past
 * the cut's 512 nodes is checked end to end by solver-agreement (docs/validation.md: ours
 * against the paper's on a 1,225-node block) and by test_run.sh (the tutorial's 1,979 nodes:
 * --compare paper, and each solver's state hash on one thread and two). */
#include "ns_test.h"
#include "vec.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

static double rnd(uint64_t *st)
{
    *st = *st * 6364136223846793005ull + 1442695040888963407ull;
    return (double)(*st >> 11) / 9007199254740992.0 * 2.0 - 1.0;
}

/* The documented order, written out: lanes i mod 4 over the whole blocks of four, (s0 + s1) +
 * (s2 + s3), then the tail one by one. Magnitudes from 1e-8 to 1e8, so another order would
 * round differently. */
static int dot_in_its_order(void)
{
    uint64_t st = 7;
    double a[23], b[23];
    for (int i = 0; i < 23; i++) {
        a[i] = rnd(&st) * pow(10.0, (i * 7) % 17 - 8);
        b[i] = rnd(&st);
    }
    int differs = 0;
    for (int n = 0; n <= 23; n++) {
        double s[4] = {0.0, 0.0, 0.0, 0.0}, plain = 0.0;
        int whole = n / 4 * 4;
        for (int i = 0; i < whole; i++)
            s[i % 4] += a[i] * b[i];
        double want = (s[0] + s[1]) + (s[2] + s[3]);
        for (int i = whole; i < n; i++)
            want += a[i] * b[i];
        for (int i = 0; i < n; i++)
            plain += a[i] * b[i];
        double got = ns_vec_dot(a, b, n);
        ENSURE(ns_same_bits(&got, &want, 1));
        ENSURE_SMALL(got - plain, 1e-6 * (fabs(plain) + 1e-8));
        differs |= got != plain;
    }
    ENSURE(differs); /* the data tell the orders apart */
    return 0;
}

static int keep_masks_fixed_dofs(void)
{
    unsigned char tf[6] = {0, 1, 0, 0, 0, 1}, rf[3] = {1, 0, 0};
    double keep[11];
    ns_vec_keep(tf, 6, rf, 3, 11, keep);
    double want[11] = {1, 0, 1, 1, 1, 0, 0, 1, 1, 1, 1}; /* the last two: constraint rows */
    ENSURE(memcmp(keep, want, sizeof keep) == 0);
    return 0;
}

static int cut_at_the_middle_node(void)
{
    ENSURE(ns_vec_cut(3 * (NS_BSM_PARALLEL_MIN_ROWS - 1), 3 * NS_BSM_PARALLEL_MIN_ROWS) == 0);
    ENSURE(ns_vec_cut(3 * 1001, 3 * 1001 + 30) == 3 * 501); /* OpenMP's static split: 501, 500 */
    ENSURE(ns_vec_cut(3 * 1000, 3 * 1000) == 3 * 500);
    return 0;
}

typedef struct Work {
    const double *a, *b;
    double *out;
    int *visits;
} Work;

static void part(void *ctx, int i0, int i1, double sums[2])
{
    const Work *w = ctx;
    sums[0] = ns_vec_dot(w->a + i0, w->b + i0, i1 - i0);
    sums[1] = 0.0;
    for (int i = i0; i < i1; i++) {
        w->out[i] = w->a[i] * w->b[i];
        sums[1] += w->out[i];
        w->visits[i]++;
    }
}

/* Each entry is visited once, by one part or the other; the sums are part 0's plus part 1's
 * on one thread and on two, bit for bit. */
static int pass_same_bits_any_threads(void)
{
    enum { N = 3 * 1500 + 37 };
    static double a[N], b[N], out1[N], out2[N];
    static int v1[N], v2[N];
    uint64_t st = 11;
    for (int i = 0; i < N; i++) {
        a[i] = rnd(&st) * pow(10.0, i % 13 - 6);
        b[i] = rnd(&st);
    }
    int cut = ns_vec_cut(3 * 1500, N);
    ENSURE(cut == 3 * 750);
    double s1[2], s2[2];
    Work w1 = {a, b, out1, v1}, w2 = {a, b, out2, v2};
    ns_vec_pass(part, &w1, N, cut, 1, s1);
    ns_vec_pass(part, &w2, N, cut, 2, s2);
    ENSURE(ns_same_bits(s1, s2, 2));
    ENSURE(ns_same_bits(out1, out2, N));
    for (int i = 0; i < N; i++)
        ENSURE(v1[i] == 1 && v2[i] == 1);
    double want = ns_vec_dot(a, b, cut) + ns_vec_dot(a + cut, b + cut, N - cut);
    ENSURE(ns_same_bits(&s1[0], &want, 1));
    /* No cut: one part holds everything. */
    ns_vec_pass(part, &w1, N, 0, 2, s1);
    want = ns_vec_dot(a, b, N);
    ENSURE(ns_same_bits(&s1[0], &want, 1));
    return 0;
}

NS_TEST_MAIN({"dot_in_its_order", dot_in_its_order},
             {"keep_masks_fixed_dofs", keep_masks_fixed_dofs},
             {"cut_at_the_middle_node", cut_at_the_middle_node},
             {"pass_same_bits_any_threads", pass_same_bits_any_threads})
