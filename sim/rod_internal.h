/* Pieces of the rod shared between sim/rod.c and sim/reparam.c; not part of the public API. */
#ifndef NS_ROD_INTERNAL_H
#define NS_ROD_INTERNAL_H

#include "rod.h"

/* Grows every per-node array (and the banded matrices) to hold at least cap nodes. Returns 0,
 * or -1 on memory (the arrays that did grow stay valid). */
int rod_reserve(NsRod *r, int cap);
/* Lumped masses from the rest lengths. */
void rod_masses(NsRod *r);
/* Space-parallel Bishop frame from edge 0 (ref_t must hold the tangents, ref_d1[0] the first
 * director); reference twists are recomputed (0 up to round-off). */
void rod_bishop_frames(NsRod *r);
/* Parallel transport of v from unit tangent a to unit tangent b. */
void rod_transport(const double *a, const double *b, const double *v, double *out);

#endif
