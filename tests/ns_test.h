/* Tiny test harness in the Box2D style: each test is `static int name(void)` returning 0 on
 * success; ENSURE and ENSURE_SMALL report file:line and return 1. A test program runs every
 * test in its table (or only those named on its command line) and exits non-zero if any fail. */
#ifndef NS_TEST_H
#define NS_TEST_H

#include <math.h>
#include <stdio.h>
#include <string.h>

#define ENSURE(cond)                                                                               \
    do {                                                                                           \
        if (!(cond)) {                                                                             \
            fprintf(stderr, "%s:%d: ENSURE(%s) failed\n", __FILE__, __LINE__, #cond);              \
            return 1;                                                                              \
        }                                                                                          \
    } while (0)

#define ENSURE_SMALL(value, tol)                                                                   \
    do {                                                                                           \
        double ns_v_ = (double)(value), ns_t_ = (double)(tol);                                     \
        if (!(fabs(ns_v_) <= ns_t_)) {                                                             \
            fprintf(stderr, "%s:%d: ENSURE_SMALL(%s = %.17g, %.3g) failed\n", __FILE__, __LINE__,  \
                    #value, ns_v_, ns_t_);                                                         \
            return 1;                                                                              \
        }                                                                                          \
    } while (0)

typedef struct NsTestCase {
    const char *name;
    int (*fn)(void);
} NsTestCase;

/* 1 if a and b hold the same bits, any two NaNs counting as equal (which NaN an operation on
 * two of them gives can depend on operand order). */
static inline int ns_same_bits(const double *a, const double *b, int n)
{
    for (int i = 0; i < n; i++)
        if (!(isnan(a[i]) && isnan(b[i])) && memcmp(a + i, b + i, sizeof *a) != 0)
            return 0;
    return 1;
}

static inline int ns_test_main(int argc, char **argv, const NsTestCase *cases, int count)
{
    int failed = 0, ran = 0;
    for (int i = 0; i < count; i++) {
        int wanted = argc <= 1;
        for (int a = 1; a < argc; a++)
            wanted |= strcmp(argv[a], cases[i].name) == 0;
        if (!wanted)
            continue;
        ran++;
        int r = cases[i].fn();
        printf("%s %s\n", r == 0 ? "PASS" : "FAIL", cases[i].name);
        fflush(stdout);
        failed += r != 0;
    }
    printf("%d passed, %d failed\n", ran - failed, failed);
    return failed != 0 || ran == 0;
}

#define NS_TEST_MAIN(...)                                                                          \
    int main(int argc, char **argv)                                                                \
    {                                                                                              \
        static const NsTestCase cases[] = {__VA_ARGS__};                                           \
        return ns_test_main(argc, argv, cases, (int)(sizeof cases / sizeof cases[0]));             \
    }

#endif
