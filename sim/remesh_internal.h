/* Shared between Algorithm 2 (remesh.c) and the remesh stack's primitives (remesh_stack.c). */
#ifndef NS_REMESH_INTERNAL_H
#define NS_REMESH_INTERNAL_H

#include "remesh.h"

/* World state (x, v, a) at barycentric b of tet t. */
void remesh_interp_state(const NsMesh *m, int t, const double b[4], double x[3], double v[3],
                         double a[3]);
/* Is n a node of tet t? */
int remesh_tet_has(const NsMesh *m, int t, int n);
/* Moves node n's material position to u, with world state (x, v, a) given; no checks. */
void remesh_set_node(NsMesh *m, int n, const double u[3], const double x[3], const double v[3],
                     const double a[3]);

#endif
