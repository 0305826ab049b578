/* Signed-distance shapes: values at known points, CSG signs, transforms, bounds. */
#include <math.h>
#include <stdint.h>

#include "ns_test.h"
#include "shape.h"

static double eval3(const NsShape *s, double x, double y, double z)
{
    double p[3] = {x, y, z};
    return ns_shape_eval(s, p);
}

/* A small deterministic generator (tests must not depend on the C library's rand). */
static double rnd(uint32_t *state)
{
    *state = *state * 1664525u + 1013904223u;
    return (double)(*state >> 8) / 16777216.0;
}

static int test_sphere(void)
{
    double c[3] = {1, 2, 3};
    NsShape *s = ns_shape_sphere(c, 0.5);
    ENSURE(s && ns_shape_kind(s) == NS_SHAPE_SPHERE);
    ENSURE_SMALL(eval3(s, 1, 2, 3) + 0.5, 1e-15);
    ENSURE_SMALL(eval3(s, 1.5, 2, 3), 1e-15);
    ENSURE_SMALL(eval3(s, 1, 2, 4) - 0.5, 1e-15);
    ENSURE_SMALL(eval3(s, 1, 2.25, 3) + 0.25, 1e-15);
    double lo[3], hi[3];
    ENSURE(ns_shape_bounds(s, lo, hi));
    ENSURE_SMALL(lo[0] - 0.5, 1e-15);
    ENSURE_SMALL(hi[2] - 3.5, 1e-15);
    ns_shape_release(s);
    return 0;
}

static int test_ellipsoid(void)
{
    double c[3] = {0, 0, 0}, r[3] = {3, 2, 1};
    NsShape *s = ns_shape_ellipsoid(c, r);
    ENSURE(s);
    /* Along an axis the bound k0 (k0 - 1) / k1 is the exact distance. */
    ENSURE_SMALL(eval3(s, 3, 0, 0), 1e-15);
    ENSURE_SMALL(eval3(s, 0, 2, 0), 1e-15);
    ENSURE_SMALL(eval3(s, 0, 0, -1), 1e-15);
    ENSURE_SMALL(eval3(s, 4, 0, 0) - 1, 1e-12);
    ENSURE_SMALL(eval3(s, 0, 0, 0.5) + 0.5, 1e-12);
    ENSURE(eval3(s, 0, 0, 0) < 0); /* the centre */
    /* Off-axis points: the sign is exact. */
    double q = 1.0 / sqrt(3.0);
    ENSURE(eval3(s, 3 * q * 0.999, 2 * q * 0.999, 1 * q * 0.999) < 0);
    ENSURE(eval3(s, 3 * q * 1.001, 2 * q * 1.001, 1 * q * 1.001) > 0);
    ENSURE_SMALL(eval3(s, 3 * q, 2 * q, 1 * q), 1e-12);
    ns_shape_release(s);
    return 0;
}

static int test_box(void)
{
    double c[3] = {1, 1, 1}, size[3] = {2, 4, 6};
    NsShape *s = ns_shape_box(c, size);
    ENSURE(s);
    ENSURE_SMALL(eval3(s, 1, 1, 1) + 1, 1e-15);       /* nearest face is 1 away */
    ENSURE_SMALL(eval3(s, 2, 1, 1), 1e-15);           /* on a face */
    ENSURE_SMALL(eval3(s, 3, 1, 1) - 1, 1e-15);       /* beyond a face */
    ENSURE_SMALL(eval3(s, 3, 4, 1) - sqrt(2), 1e-15); /* beyond an edge */
    ENSURE_SMALL(eval3(s, 3, 4, 5) - sqrt(3), 1e-15); /* beyond a corner */
    ENSURE_SMALL(eval3(s, 1.5, 1, 1) + 0.5, 1e-15);
    double lo[3], hi[3];
    ENSURE(ns_shape_bounds(s, lo, hi));
    ENSURE_SMALL(lo[1] + 1, 1e-15);
    ENSURE_SMALL(hi[2] - 4, 1e-15);
    ns_shape_release(s);
    return 0;
}

static int test_cylinder(void)
{
    /* Axis along (1, 1, 0)/sqrt2, length 2 sqrt2, radius 0.5. */
    double a[3] = {0, 0, 0}, b[3] = {2, 2, 0};
    NsShape *s = ns_shape_cylinder(a, b, 0.5);
    ENSURE(s);
    double r2 = sqrt(2.0);
    ENSURE_SMALL(eval3(s, 1, 1, 0) + 0.5, 1e-15);             /* the middle of the axis */
    ENSURE_SMALL(eval3(s, 1, 1, 0.5), 1e-15);                 /* on the side */
    ENSURE_SMALL(eval3(s, 1, 1, 2) - 1.5, 1e-15);             /* off the side */
    ENSURE_SMALL(eval3(s, 3, 3, 0) - r2, 1e-12);              /* beyond cap b, on the axis */
    ENSURE_SMALL(eval3(s, -0.1, -0.1, 0) - 0.1 * r2, 1e-12);  /* beyond cap a */
    ENSURE_SMALL(eval3(s, 0.05, 0.05, 0) + 0.05 * r2, 1e-12); /* inside near cap a */
    ENSURE_SMALL(eval3(s, -1, -1, 1.5) - sqrt(2 + 1), 1e-12); /* beyond the rim */
    double lo[3], hi[3];
    ENSURE(ns_shape_bounds(s, lo, hi));
    /* The end discs have normal (1,1,0)/sqrt2: they reach 0.5/sqrt2 along x and y, 0.5 in z. */
    ENSURE_SMALL(lo[0] + 0.5 / r2, 1e-12);
    ENSURE_SMALL(hi[1] - 2 - 0.5 / r2, 1e-12);
    ENSURE_SMALL(hi[2] - 0.5, 1e-12);
    ns_shape_release(s);
    return 0;
}

static int test_capsule(void)
{
    double a[3] = {0, 0, 0}, b[3] = {0, 0, 2};
    NsShape *s = ns_shape_capsule(a, b, 0.5);
    ENSURE(s);
    ENSURE_SMALL(eval3(s, 0, 0, 1) + 0.5, 1e-15);
    ENSURE_SMALL(eval3(s, 0.5, 0, 1), 1e-15);
    ENSURE_SMALL(eval3(s, 0, 0, 3) - 0.5, 1e-15); /* beyond end b */
    ENSURE_SMALL(eval3(s, 0, 0, -0.5), 1e-15);    /* the tip of cap a */
    ENSURE_SMALL(eval3(s, 3, 4, -1) - (sqrt(9 + 16 + 1) - 0.5), 1e-12);
    ns_shape_release(s);
    return 0;
}

static int test_csg(void)
{
    double c0[3] = {0, 0, 0}, c1[3] = {1, 0, 0};
    NsShape *a = ns_shape_sphere(c0, 0.75), *b = ns_shape_sphere(c1, 0.75);
    NsShape *pair[2] = {a, b};
    NsShape *u = ns_shape_union(pair, 2), *i = ns_shape_intersection(pair, 2);
    NsShape *d = ns_shape_difference(a, b);
    ENSURE(u && i && d);
    /* The CSG nodes hold their own references: the children may be released now. */
    ns_shape_release(a);
    ns_shape_release(b);
    /* Points: only in a, in both, only in b, in neither. */
    double pa[3] = {-0.5, 0, 0}, pab[3] = {0.5, 0, 0}, pb[3] = {1.5, 0, 0}, pn[3] = {0.5, 2, 0};
    ENSURE(ns_shape_eval(u, pa) < 0 && ns_shape_eval(u, pab) < 0 && ns_shape_eval(u, pb) < 0);
    ENSURE(ns_shape_eval(u, pn) > 0);
    ENSURE(ns_shape_eval(i, pa) > 0 && ns_shape_eval(i, pab) < 0 && ns_shape_eval(i, pb) > 0);
    ENSURE(ns_shape_eval(d, pa) < 0 && ns_shape_eval(d, pab) > 0 && ns_shape_eval(d, pb) > 0);
    ENSURE(ns_shape_eval(d, pn) > 0);
    ENSURE_SMALL(ns_shape_eval(u, pa) + 0.25, 1e-15); /* min of the children */
    double lo[3], hi[3];
    ENSURE(ns_shape_bounds(u, lo, hi));
    ENSURE_SMALL(lo[0] + 0.75, 1e-15);
    ENSURE_SMALL(hi[0] - 1.75, 1e-15);
    ENSURE(ns_shape_bounds(i, lo, hi));
    ENSURE_SMALL(lo[0] - 0.25, 1e-15);
    ENSURE_SMALL(hi[0] - 0.75, 1e-15);
    ENSURE(ns_shape_bounds(d, lo, hi)); /* bounds of a */
    ENSURE_SMALL(lo[0] + 0.75, 1e-15);
    ENSURE_SMALL(hi[0] - 0.75, 1e-15);
    ENSURE(ns_shape_kind(u) == NS_SHAPE_UNION && ns_shape_kind(d) == NS_SHAPE_DIFFERENCE);
    ENSURE(ns_shape_union(pair, 0) == NULL);
    ns_shape_release(u);
    ns_shape_release(i);
    ns_shape_release(d);
    return 0;
}

static int test_transform(void)
{
    /* A box 2 x 1 x 1 at the origin, turned 90 degrees about z (x -> y), scaled by 2 and moved
     * to (10, 0, 0): it becomes 2 x 4 x 2 centred at (10, 0, 0). */
    double c[3] = {0, 0, 0}, size[3] = {2, 1, 1};
    NsShape *box = ns_shape_box(c, size);
    double rot[9] = {0, -1, 0, 1, 0, 0, 0, 0, 1}, t[3] = {10, 0, 0};
    NsShape *s = ns_shape_transform(box, rot, t, 2.0);
    ns_shape_release(box);
    ENSURE(s && ns_shape_kind(s) == NS_SHAPE_TRANSFORM);
    ENSURE_SMALL(eval3(s, 10, 0, 0) + 1, 1e-15); /* half the smallest extent (2) */
    ENSURE_SMALL(eval3(s, 10, 2, 0), 1e-15);     /* on the long face (y = 2) */
    ENSURE_SMALL(eval3(s, 11, 0, 0), 1e-15);     /* on the short face (x = 11) */
    ENSURE_SMALL(eval3(s, 10, 3, 0) - 1, 1e-15); /* distances scale with s */
    ENSURE_SMALL(eval3(s, 13, 0, 0) - 2, 1e-15);
    double lo[3], hi[3];
    ENSURE(ns_shape_bounds(s, lo, hi));
    ENSURE_SMALL(lo[0] - 9, 1e-12);
    ENSURE_SMALL(hi[0] - 11, 1e-12);
    ENSURE_SMALL(lo[1] + 2, 1e-12);
    ENSURE_SMALL(hi[1] - 2, 1e-12);
    ENSURE_SMALL(hi[2] - 1, 1e-12);
    ns_shape_release(s);
    return 0;
}

static double half_space(void *user, const double p[3])
{
    return p[0] - *(const double *)user; /* x <= k */
}

static int test_callback(void)
{
    double k = 0.25, lo[3] = {-1, -1, -1}, hi[3] = {0.25, 1, 1};
    NsShape *s = ns_shape_callback(half_space, &k, lo, hi);
    ENSURE(s && ns_shape_kind(s) == NS_SHAPE_CALLBACK);
    ENSURE_SMALL(eval3(s, 0, 5, 5) + 0.25, 1e-15);
    ENSURE_SMALL(eval3(s, 1, 0, 0) - 0.75, 1e-15);
    double l2[3], h2[3];
    ENSURE(ns_shape_bounds(s, l2, h2));
    ENSURE(l2[0] == -1 && h2[0] == 0.25);
    ns_shape_release(s);
    ENSURE(ns_shape_callback(NULL, NULL, lo, hi) == NULL);
    return 0;
}

/* The bounds must contain every interior point: sample a generous box around a few trees of
 * transformed CSG shapes and check each point with eval <= 0. */
static int test_bounds_contain_interior(void)
{
    uint32_t seed = 12345;
    for (int trial = 0; trial < 20; trial++) {
        double c0[3] = {rnd(&seed), rnd(&seed), rnd(&seed)};
        double c1[3] = {c0[0] + 0.5 * rnd(&seed), c0[1] + 0.5 * rnd(&seed), c0[2]};
        double radii[3] = {0.2 + 0.3 * rnd(&seed), 0.1 + 0.2 * rnd(&seed), 0.3};
        double size[3] = {0.4, 0.2 + 0.3 * rnd(&seed), 0.5};
        NsShape *k[4] = {ns_shape_ellipsoid(c0, radii), ns_shape_cylinder(c0, c1, 0.15),
                         ns_shape_capsule(c1, c0, 0.1), ns_shape_box(c1, size)};
        NsShape *u = ns_shape_union(k, 4);
        NsShape *in = ns_shape_intersection(k + 2, 2);
        NsShape *d = ns_shape_difference(u, k[1]);
        /* A rotation about a random axis (Rodrigues). */
        double ax[3] = {rnd(&seed) - 0.5, rnd(&seed) - 0.5, rnd(&seed) - 0.5};
        double n = sqrt(ax[0] * ax[0] + ax[1] * ax[1] + ax[2] * ax[2]);
        for (int i = 0; i < 3; i++)
            ax[i] /= n;
        double th = 6.0 * rnd(&seed), cs = cos(th), sn = sin(th);
        double R[9];
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                R[3 * i + j] = (i == j ? cs : 0.0) + (1 - cs) * ax[i] * ax[j];
        R[1] -= sn * ax[2], R[2] += sn * ax[1], R[3] += sn * ax[2];
        R[5] -= sn * ax[0], R[6] -= sn * ax[1], R[7] += sn * ax[0];
        double t[3] = {rnd(&seed), -rnd(&seed), 0.5};
        NsShape *tr = ns_shape_transform(d, R, t, 0.5 + rnd(&seed));
        NsShape *shapes[] = {k[0], k[1], k[2], k[3], u, in, d, tr};
        for (size_t si = 0; si < sizeof shapes / sizeof shapes[0]; si++) {
            double lo[3], hi[3];
            ENSURE(ns_shape_bounds(shapes[si], lo, hi));
            int inside = 0;
            for (int s = 0; s < 4000; s++) {
                double p[3];
                for (int a = 0; a < 3; a++)
                    p[a] = -2.0 + 5.0 * rnd(&seed);
                if (ns_shape_eval(shapes[si], p) > 0)
                    continue;
                inside++;
                for (int a = 0; a < 3; a++)
                    ENSURE(p[a] >= lo[a] && p[a] <= hi[a]);
            }
            (void)inside;
        }
        for (int i = 0; i < 4; i++)
            ns_shape_release(k[i]);
        ns_shape_release(u);
        ns_shape_release(in);
        ns_shape_release(d);
        ns_shape_release(tr);
    }
    return 0;
}

/* A shared child survives as long as any parent holds it. */
static int test_refcount(void)
{
    double c[3] = {0, 0, 0};
    NsShape *s = ns_shape_sphere(c, 1);
    NsShape *u = ns_shape_union(&s, 1);
    NsShape *pair[2] = {s, u};
    NsShape *v = ns_shape_union(pair, 2);
    ns_shape_release(s);
    ns_shape_release(u);
    ENSURE_SMALL(eval3(v, 0, 0, 0) + 1, 1e-15);
    ns_shape_retain(v);
    ns_shape_release(v);
    ENSURE_SMALL(eval3(v, 2, 0, 0) - 1, 1e-15);
    ns_shape_release(v);
    return 0;
}

NS_TEST_MAIN({"sphere", test_sphere}, {"ellipsoid", test_ellipsoid}, {"box", test_box},
             {"cylinder", test_cylinder}, {"capsule", test_capsule}, {"csg", test_csg},
             {"transform", test_transform}, {"callback", test_callback},
             {"bounds_contain_interior", test_bounds_contain_interior}, {"refcount", test_refcount})
