/* Tet mesh files, writing: Gmsh MSH 4.1 ASCII and VTK .vtu. Both write "path.tmp", flush and
 * fsync it, then rename() it over path, so a failure never leaves a partial file at path. */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE 1
#endif

#include "mesh_io.h"
#include "err.h"
#include "quality.h"

#include <errno.h>
#include <sys/stat.h>
#include <fcntl.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* ---------------------------------------------------------------------------------------------
 * Writing
 * ------------------------------------------------------------------------------------------- */

/* The mesh must be dense, regions non-negative, coordinates finite. */
static int check_writable(const char *path, const NsMesh *m, char *err, int err_sz)
{
    if (m->node_slots != m->node_alive || m->tet_slots != m->tet_alive) {
        ns_set_err(err, err_sz,
                   "%s: the mesh is not compact (%d of %d node slots and %d of %d tet slots in "
                   "use); call ns_mesh_compact first",
                   path, m->node_alive, m->node_slots, m->tet_alive, m->tet_slots);
        return -1;
    }
    for (int i = 0; i < m->node_slots; i++) {
        const double *u = &m->u[3 * i];
        if (!isfinite(u[0]) || !isfinite(u[1]) || !isfinite(u[2])) {
            ns_set_err(err, err_sz, "%s: node %d has a non-finite material coordinate", path, i);
            return -1;
        }
    }
    for (int t = 0; t < m->tet_slots; t++) {
        if (m->tet_region[t] < 0 || m->tet_region[t] == INT_MAX) {
            ns_set_err(err, err_sz, "%s: tet %d has an invalid region %d", path, t,
                       m->tet_region[t]);
            return -1;
        }
    }
    return 0;
}

typedef struct AtomicFile {
    FILE *f;
    char *tmp;
} AtomicFile;

static int atomic_open(AtomicFile *af, const char *path, char *err, int err_sz)
{
    size_t n = strlen(path);
    af->f = NULL;
    af->tmp = malloc(n + 5);
    if (!af->tmp) {
        ns_set_err(err, err_sz, "%s: out of memory", path);
        return -1;
    }
    memcpy(af->tmp, path, n);
    memcpy(af->tmp + n, ".tmp", 5);
    /* Created fresh: an old regular "path.tmp" is removed first, and nothing else is followed
     * or written through (a symbolic or hard link there must not redirect the write). */
    struct stat st;
    if (lstat(af->tmp, &st) == 0 && S_ISREG(st.st_mode))
        unlink(af->tmp);
    int fd = open(af->tmp, O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0644);
    af->f = fd >= 0 ? fdopen(fd, "w") : NULL;
    if (!af->f && fd >= 0)
        close(fd);
    if (!af->f) {
        ns_set_err(err, err_sz, "%s: cannot create %s: %s", path, af->tmp, strerror(errno));
        free(af->tmp);
        af->tmp = NULL;
        return -1;
    }
    return 0;
}

/* Finishes the file: flush, sync, close, rename over path. On any failure the temporary file is
 * removed instead and path is untouched. */
static int atomic_close(AtomicFile *af, const char *path, char *err, int err_sz)
{
    int rc = 0;
    if ((fflush(af->f) != 0 || ferror(af->f))) {
        ns_set_err(err, err_sz, "%s: write error: %s", path, strerror(errno));
        rc = -1;
    }
    if (rc == 0 && fsync(fileno(af->f)) != 0) {
        ns_set_err(err, err_sz, "%s: cannot sync: %s", path, strerror(errno));
        rc = -1;
    }
    if (fclose(af->f) != 0 && rc == 0) {
        ns_set_err(err, err_sz, "%s: write error: %s", path, strerror(errno));
        rc = -1;
    }
    struct stat st;
    if (rc == 0 && lstat(path, &st) == 0 && !S_ISREG(st.st_mode)) {
        ns_set_err(err, err_sz, "%s exists and is not a regular file: refusing to replace it",
                   path);
        rc = -1;
    }
    if (rc == 0 && rename(af->tmp, path) != 0) {
        ns_set_err(err, err_sz, "%s: cannot rename %s over it: %s", path, af->tmp, strerror(errno));
        rc = -1;
    }
    if (rc != 0)
        remove(af->tmp);
    free(af->tmp);
    af->tmp = NULL;
    af->f = NULL;
    return rc;
}

static int cmp_region_tet(const void *a, const void *b)
{
    const int *p = a, *q = b;
    if (p[0] != q[0])
        return p[0] < q[0] ? -1 : 1;
    return (p[1] > q[1]) - (p[1] < q[1]);
}

int ns_mesh_write_msh(const char *path, const NsMesh *m, const char *const *names, int name_count,
                      char *err, int err_sz)
{
    if (check_writable(path, m, err, err_sz))
        return -1;
    int nn = m->node_slots, nt = m->tet_slots;
    if (nt == 0) {
        ns_set_err(err, err_sz, "%s: the mesh has no tetrahedra to write", path);
        return -1;
    }
    int named = 0;
    for (int i = 0; names && i < name_count; i++) {
        if (!names[i])
            continue;
        if (strpbrk(names[i], "\"\n\r")) {
            ns_set_err(err, err_sz, "%s: region %d's name contains a quote or a line break", path,
                       i);
            return -1;
        }
        named++;
    }

    /* (region, tet) pairs sorted: one element block per region, tets in index order */
    int *rt = malloc((size_t)nt * 2 * sizeof *rt);
    if (!rt) {
        ns_set_err(err, err_sz, "%s: out of memory", path);
        return -1;
    }
    for (int t = 0; t < nt; t++) {
        rt[2 * t] = m->tet_region[t];
        rt[2 * t + 1] = t;
    }
    qsort(rt, (size_t)nt, 2 * sizeof *rt, cmp_region_tet);
    int regions = 0;
    for (int t = 0; t < nt; t++)
        regions += t == 0 || rt[2 * t] != rt[2 * t - 2];

    AtomicFile af;
    if (atomic_open(&af, path, err, err_sz)) {
        free(rt);
        return -1;
    }
    FILE *f = af.f;
    fprintf(f, "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n");
    if (named > 0) {
        fprintf(f, "$PhysicalNames\n%d\n", named);
        for (int i = 0; i < name_count; i++)
            if (names[i])
                fprintf(f, "3 %d \"%s\"\n", i + 1, names[i]);
        fprintf(f, "$EndPhysicalNames\n");
    }

    /* one volume entity per region: entity tag = physical tag = region + 1 */
    fprintf(f, "$Entities\n0 0 0 %d\n", regions);
    for (int s = 0; s < nt;) {
        int e = s, reg = rt[2 * s];
        double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
        for (; e < nt && rt[2 * e] == reg; e++) {
            const int *tv = &m->tet_node[4 * rt[2 * e + 1]];
            for (int k = 0; k < 4; k++)
                for (int c = 0; c < 3; c++) {
                    double x = m->u[3 * tv[k] + c];
                    lo[c] = x < lo[c] ? x : lo[c];
                    hi[c] = x > hi[c] ? x : hi[c];
                }
        }
        fprintf(f, "%d %.17g %.17g %.17g %.17g %.17g %.17g 1 %d 0\n", reg + 1, lo[0], lo[1], lo[2],
                hi[0], hi[1], hi[2], reg + 1);
        s = e;
    }
    fprintf(f, "$EndEntities\n");

    /* all nodes in one block, classified on the first volume (Gmsh resolves elements' nodes by
     * tag, whatever entity holds them) */
    fprintf(f, "$Nodes\n1 %d 1 %d\n3 %d 0 %d\n", nn, nn, rt[0] + 1, nn);
    for (int i = 0; i < nn; i++)
        fprintf(f, "%d\n", i + 1);
    for (int i = 0; i < nn; i++)
        fprintf(f, "%.17g %.17g %.17g\n", m->u[3 * i], m->u[3 * i + 1], m->u[3 * i + 2]);
    fprintf(f, "$EndNodes\n");

    /* element tag = tet index + 1, so reading back (which orders tets by tag) keeps indices */
    fprintf(f, "$Elements\n%d %d 1 %d\n", regions, nt, nt);
    for (int s = 0; s < nt;) {
        int e = s, reg = rt[2 * s];
        while (e < nt && rt[2 * e] == reg)
            e++;
        fprintf(f, "3 %d 4 %d\n", reg + 1, e - s);
        for (int j = s; j < e; j++) {
            int t = rt[2 * j + 1];
            const int *tv = &m->tet_node[4 * t];
            fprintf(f, "%d %d %d %d %d\n", t + 1, tv[0] + 1, tv[1] + 1, tv[2] + 1, tv[3] + 1);
        }
        s = e;
    }
    fprintf(f, "$EndElements\n");
    free(rt);
    return atomic_close(&af, path, err, err_sz);
}

int ns_mesh_write_vtu(const char *path, const NsMesh *m, char *err, int err_sz)
{
    if (check_writable(path, m, err, err_sz))
        return -1;
    int nn = m->node_slots, nt = m->tet_slots;
    AtomicFile af;
    if (atomic_open(&af, path, err, err_sz))
        return -1;
    FILE *f = af.f;
    fprintf(f, "<?xml version=\"1.0\"?>\n"
               "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\">\n"
               "  <UnstructuredGrid>\n");
    fprintf(f, "    <Piece NumberOfPoints=\"%d\" NumberOfCells=\"%d\">\n", nn, nt);

    fprintf(f, "      <PointData Scalars=\"fixed\">\n"
               "        <DataArray type=\"UInt8\" Name=\"fixed\" format=\"ascii\">\n");
    for (int i = 0; i < nn; i++)
        fprintf(f, "%d\n", (m->flags[i] & NS_NODE_FIXED) ? 1 : 0);
    fprintf(f, "        </DataArray>\n      </PointData>\n");

    fprintf(f, "      <CellData Scalars=\"region\">\n"
               "        <DataArray type=\"Int32\" Name=\"region\" format=\"ascii\">\n");
    for (int t = 0; t < nt; t++)
        fprintf(f, "%d\n", m->tet_region[t]);
    fprintf(f, "        </DataArray>\n"
               "        <DataArray type=\"Float64\" Name=\"quality\" format=\"ascii\">\n");
    for (int t = 0; t < nt; t++) {
        const int *tv = &m->tet_node[4 * t];
        double q =
            ns_tet_quality(&m->u[3 * tv[0]], &m->u[3 * tv[1]], &m->u[3 * tv[2]], &m->u[3 * tv[3]]);
        fprintf(f, "%.17g\n", isfinite(q) ? q : 0.0);
    }
    fprintf(f, "        </DataArray>\n      </CellData>\n");

    fprintf(f, "      <Points>\n"
               "        <DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n");
    for (int i = 0; i < nn; i++)
        fprintf(f, "%.17g %.17g %.17g\n", m->u[3 * i], m->u[3 * i + 1], m->u[3 * i + 2]);
    fprintf(f, "        </DataArray>\n      </Points>\n");

    fprintf(f, "      <Cells>\n"
               "        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n");
    for (int t = 0; t < nt; t++) {
        const int *tv = &m->tet_node[4 * t];
        fprintf(f, "%d %d %d %d\n", tv[0], tv[1], tv[2], tv[3]);
    }
    fprintf(f, "        </DataArray>\n"
               "        <DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n");
    for (int t = 0; t < nt; t++)
        fprintf(f, "%lld\n", 4LL * (t + 1));
    fprintf(f, "        </DataArray>\n"
               "        <DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
    for (int t = 0; t < nt; t++)
        fprintf(f, "10\n"); /* VTK_TETRA */
    fprintf(f, "        </DataArray>\n      </Cells>\n");
    fprintf(f, "    </Piece>\n  </UnstructuredGrid>\n</VTKFile>\n");
    return atomic_close(&af, path, err, err_sz);
}
