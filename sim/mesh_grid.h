/* Structured tet meshes of a box: an nx x ny x nz grid of hexahedra, each split into six tets
 * around a main diagonal (Kuhn / Freudenthal split), with the cubes mirrored by index parity so
 * the diagonals alternate and the mesh is conforming with no preferred direction. Used by the
 * validation cases (docs/validation.md), where a regular mesh makes beam and bar answers easy
 * to compare; scenarios mesh with the isosurface stuffing mesher instead. */
#ifndef NS_MESH_GRID_H
#define NS_MESH_GRID_H

#include "mesh.h"

/* Fills m (initialised by the call) with the grid mesh of the box [lo, hi] [m]; all tets get
 * region. Node (i, j, k) has index i + (nx + 1) (j + (ny + 1) k). Returns 0, or -1 with a
 * message (counts < 1, an empty box, memory). */
int ns_mesh_grid_box(NsMesh *m, const double lo[3], const double hi[3], int nx, int ny, int nz,
                     int region, char *err, int err_sz);

#endif
