/* Contour lines of a scalar field sampled on a regular 2D grid (marching squares), for the
 * isodose lines on the cut face (render/scene.c). Pure geometry: no GL, no sim. */
#ifndef NS_RENDER_CONTOUR_H
#define NS_RENDER_CONTOUR_H

/* Calls emit(ctx, a, b) for each segment of the level line f = level through the nu x nv grid f
 * (f[j * nu + i] at grid point (i, j)); a and b are points {i, j} in grid units, interpolated
 * linearly along the cells' edges. A cell whose corners alternate above and below (a saddle) is
 * split by its centre's mean. Returns 0, or the first non-zero value emit returned. */
int ns_contour(const double *f, int nu, int nv, double level,
               int (*emit)(void *ctx, const double a[2], const double b[2]), void *ctx);

#endif
