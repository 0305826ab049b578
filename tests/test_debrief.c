/* The debrief's closest approach (engine/run_debrief.c): the distance from a point to a tet,
 * against distances worked out by hand on the unit corner tet. */
#include "ns_test.h"
#include "run.h"

static int tet_distance(void)
{
    const double x[12] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1};
    const int tn[4] = {0, 1, 2, 3};
    static const struct {
        double p[3], d;
    } cases[] = {
        {{0.1, 0.1, 0.1}, 0.0},                /* inside */
        {{0.25, 0.25, 0.5}, 0.0},              /* on the slanted face */
        {{-1, 0, 0}, 1.0},                     /* beyond vertex 0 along -x */
        {{2, 0, 0}, 1.0},                      /* beyond vertex 1 */
        {{1, 1, 1}, 2.0 / 1.7320508075688772}, /* over the slanted face's middle */
        {{1, 1, 0}, 0.70710678118654757},      /* beside the edge (1,0,0)-(0,1,0) */
        {{0.2, 0.3, -0.5}, 0.5},               /* under the face z = 0 */
        {{-0.3, -0.4, 0.5}, 0.5},              /* beside the edge along z */
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++)
        ENSURE_SMALL(ns_run_tet_distance(x, tn, 0, cases[i].p) - cases[i].d, 1e-12);
    /* the same tet with its nodes in the other order (negative volume): the same distances */
    const int flip[4] = {0, 2, 1, 3};
    ENSURE_SMALL(ns_run_tet_distance(x, flip, 0, cases[4].p) - cases[4].d, 1e-12);
    ENSURE(ns_run_tet_distance(x, flip, 0, cases[0].p) == 0.0);
    return 0;
}

NS_TEST_MAIN({"tet_distance", tet_distance})
