/* Structured box meshes: hexahedra split into six tets (Kuhn split). */
#include "mesh_grid.h"

#include "err.h"
#include "quality.h"

int ns_mesh_grid_box(NsMesh *m, const double lo[3], const double hi[3], int nx, int ny, int nz,
                     int region, char *err, int err_sz)
{
    ns_mesh_init(m);
    if (nx < 1 || ny < 1 || nz < 1) {
        ns_set_err(err, err_sz, "grid counts must be at least 1 (got %d x %d x %d)", nx, ny, nz);
        return -1;
    }
    if (!(hi[0] > lo[0] && hi[1] > lo[1] && hi[2] > lo[2])) {
        ns_set_err(err, err_sz, "grid box is empty");
        return -1;
    }
    const int n[3] = {nx, ny, nz};
    for (int k = 0; k <= nz; k++)
        for (int j = 0; j <= ny; j++)
            for (int i = 0; i <= nx; i++) {
                const int ijk[3] = {i, j, k};
                double u[3];
                for (int c = 0; c < 3; c++)
                    u[c] = ijk[c] == n[c] ? hi[c] : lo[c] + (hi[c] - lo[c]) * ijk[c] / n[c];
                if (ns_mesh_add_node(m, u) < 0)
                    goto oom;
            }
    /* The six tets of a hex: walk from a corner to the opposite one along the axes in every
     * order. Cubes with an odd index along an axis are mirrored along it, so the diagonals
     * alternate (a "crisscross" pattern): neighbours still share face diagonals, since a
     * face's diagonal depends only on the parities of the two axes in its plane, and the mesh
     * has no preferred direction, which makes it far less stiff in bending than one diagonal
     * direction everywhere. */
    static const int perm[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2},
                                   {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
    for (int k = 0; k < nz; k++)
        for (int j = 0; j < ny; j++)
            for (int i = 0; i < nx; i++)
                for (int p = 0; p < 6; p++) {
                    const int base[3] = {i, j, k};
                    int o[3] = {0, 0, 0}, tn[4];
                    for (int s = 0; s < 4; s++) {
                        if (s > 0)
                            o[perm[p][s - 1]] = 1;
                        int c[3];
                        for (int q = 0; q < 3; q++)
                            c[q] = base[q] + ((base[q] & 1) ? 1 - o[q] : o[q]);
                        tn[s] = c[0] + (nx + 1) * (c[1] + (ny + 1) * c[2]);
                    }
                    const double *u = m->u;
                    if (ns_tet_volume(u + 3 * tn[0], u + 3 * tn[1], u + 3 * tn[2], u + 3 * tn[3]) <
                        0.0) {
                        int t = tn[2];
                        tn[2] = tn[3];
                        tn[3] = t;
                    }
                    if (ns_mesh_add_tet(m, tn, region) < 0)
                        goto oom;
                }
    return 0;
oom:
    ns_mesh_free(m);
    ns_set_err(err, err_sz, "out of memory");
    return -1;
}
