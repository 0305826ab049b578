/* Signed-distance shapes for the mesher: primitives, CSG and transforms.
 * Convention: negative inside, positive outside, zero on the surface, in metres. The value is
 * an exact distance for sphere, box, cylinder and capsule, an approximate distance with an
 * exact sign for the others; the mesher needs only a correct sign and a continuous function. */
#ifndef NS_SHAPE_H
#define NS_SHAPE_H

#include <stdbool.h>

typedef enum NsShapeKind {
    NS_SHAPE_SPHERE,
    NS_SHAPE_ELLIPSOID,
    NS_SHAPE_BOX,
    NS_SHAPE_CYLINDER,
    NS_SHAPE_CAPSULE,
    NS_SHAPE_UNION,
    NS_SHAPE_INTERSECTION,
    NS_SHAPE_DIFFERENCE,
    NS_SHAPE_TRANSFORM,
    NS_SHAPE_CALLBACK,
} NsShapeKind;

/* A user function: signed distance at p. Must return a finite value; a NaN aborts meshing
 * with the error set by the callback's owner. */
typedef double (*NsShapeFn)(void *user, const double p[3]);

typedef struct NsShape NsShape;

/* Constructors return a new shape with one reference, or NULL when out of memory.
 * CSG constructors take their own reference on the children. */
NsShape *ns_shape_sphere(const double center[3], double radius);
NsShape *ns_shape_ellipsoid(const double center[3], const double radii[3]);
NsShape *ns_shape_box(const double center[3], const double size[3]);
/* Finite cylinder with flat caps between the centres of its end discs a and b. */
NsShape *ns_shape_cylinder(const double a[3], const double b[3], double radius);
NsShape *ns_shape_capsule(const double a[3], const double b[3], double radius);
NsShape *ns_shape_union(NsShape *const *children, int count);
NsShape *ns_shape_intersection(NsShape *const *children, int count);
NsShape *ns_shape_difference(NsShape *a, NsShape *b);
/* eval(p) = scale * child(R^T (p - translate) / scale); R is a rotation (row-major 3x3). */
NsShape *ns_shape_transform(NsShape *child, const double rotation[9], const double translate[3],
                            double scale);
/* A function with explicit bounds (lo, hi) that contain its interior. */
NsShape *ns_shape_callback(NsShapeFn fn, void *user, const double lo[3], const double hi[3]);

void ns_shape_retain(NsShape *s);
void ns_shape_release(NsShape *s);

double ns_shape_eval(const NsShape *s, const double p[3]);
/* An axis-aligned box containing the interior {eval <= 0}. Returns false if unbounded
 * (e.g. the difference of something unbounded), leaving lo/hi untouched. */
bool ns_shape_bounds(const NsShape *s, double lo[3], double hi[3]);
NsShapeKind ns_shape_kind(const NsShape *s);

#endif
