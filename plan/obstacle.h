/* Obstacle regions for the planners, as signed distances: negative inside, positive outside,
 * zero on the surface [m]. Exact for the sphere, capsule, cylinder and box; a sim/shape.h shape
 * gives its own value (exact for primitives, a lower bound with the right sign for CSG). */
#ifndef NS_PLAN_OBSTACLE_H
#define NS_PLAN_OBSTACLE_H

#include <stdbool.h>

#include "shape.h"

typedef enum NsPlanObstacleKind {
    NS_PLAN_SPHERE,   /* centre a, radius */
    NS_PLAN_CAPSULE,  /* segment a-b, radius */
    NS_PLAN_CYLINDER, /* flat-capped, between the end discs' centres a and b, radius */
    NS_PLAN_BOX,      /* axis-aligned, corners a (low) and b (high) */
    NS_PLAN_SHAPE,    /* shape (not owned) */
} NsPlanObstacleKind;

typedef struct NsPlanObstacle {
    NsPlanObstacleKind kind;
    double a[3], b[3]; /* [m] */
    double radius;     /* [m] */
    const NsShape *shape;
    const char *name; /* for messages (may be NULL) */
} NsPlanObstacle;

NsPlanObstacle ns_plan_sphere(const double c[3], double radius);
NsPlanObstacle ns_plan_capsule(const double a[3], const double b[3], double radius);
NsPlanObstacle ns_plan_cylinder(const double a[3], const double b[3], double radius);
NsPlanObstacle ns_plan_box(const double lo[3], const double hi[3]);

/* Whether the obstacle's numbers make a shape (finite, radius > 0, a != b for a capsule or a
 * cylinder, lo < hi for a box, a shape given); else false with a message. */
bool ns_plan_obstacle_valid(const NsPlanObstacle *o, char *err, int err_sz);

double ns_plan_obstacle_distance(const NsPlanObstacle *o, const double p[3]);
/* The least distance to any of them (INFINITY for none); *which gets the nearest's index (-1
 * for none) when not NULL. */
double ns_plan_obstacles_distance(const NsPlanObstacle *obs, int count, const double p[3],
                                  int *which);

#endif
