/* Tests for sim/mesh_io.c: MSH 4.1 round trips, hand-written MSH 2.2 and 4.1 files, the .vtu
 * writer, and every reading and writing error naming the right place. All files live in one
 * mkdtemp directory under /tmp that is removed at exit, whichever test fails. */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE 1
#endif

#include "mesh_check.h"
#include "mesh_io.h"
#include "ns_limits.h"
#include "quality.h"
#include "ns_test.h"

/* NS_SOURCE_DIR locates tests/data; the fallback serves a build run from the repository root */
#if defined(__has_include)
#if __has_include("ns_config.h")
#include "ns_config.h"
#endif
#endif
#ifndef NS_SOURCE_DIR
#define NS_SOURCE_DIR "."
#endif

#include <dirent.h>
#include <stdbool.h>
#include <stdlib.h>
#include <sys/stat.h>
#include <unistd.h>

/* ---------------------------------------------------------------------------------------------
 * Temporary files
 * ------------------------------------------------------------------------------------------- */

static char g_dir[64];

static void remove_tree(const char *dir)
{
    DIR *d = opendir(dir);
    if (!d)
        return;
    struct dirent *e;
    while ((e = readdir(d)) != NULL) {
        if (strcmp(e->d_name, ".") == 0 || strcmp(e->d_name, "..") == 0)
            continue;
        char p[512];
        snprintf(p, sizeof p, "%s/%s", dir, e->d_name);
        if (unlink(p) != 0)
            remove_tree(p);
    }
    closedir(d);
    rmdir(dir);
}

static void cleanup_dir(void)
{
    if (g_dir[0])
        remove_tree(g_dir);
}

/* Path of name inside the test directory (created on first use). */
static const char *tmp_path(char out[512], const char *name)
{
    if (!g_dir[0]) {
        strcpy(g_dir, "/tmp/ns_mesh_io_XXXXXX");
        if (!mkdtemp(g_dir)) {
            perror("mkdtemp");
            g_dir[0] = '\0';
            snprintf(out, 512, "/nonexistent/%s", name);
            return out;
        }
        atexit(cleanup_dir);
    }
    snprintf(out, 512, "%s/%s", g_dir, name);
    return out;
}

static int write_text(const char *path, const char *text)
{
    FILE *f = fopen(path, "wb");
    if (!f)
        return -1;
    size_t n = strlen(text);
    int rc = fwrite(text, 1, n, f) == n ? 0 : -1;
    return fclose(f) == 0 ? rc : -1;
}

static char *read_text(const char *path)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    size_t cap = 1 << 16, len = 0, got;
    char *buf = malloc(cap);
    while (buf && (got = fread(buf + len, 1, cap - len - 1, f)) > 0) {
        len += got;
        if (cap - len < 2) {
            char *nb = realloc(buf, cap * 2);
            if (!nb) {
                free(buf);
                buf = NULL;
                break;
            }
            buf = nb;
            cap *= 2;
        }
    }
    fclose(f);
    if (buf)
        buf[len] = '\0';
    return buf;
}

static bool exists(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0;
}

/* ---------------------------------------------------------------------------------------------
 * Meshes
 * ------------------------------------------------------------------------------------------- */

/* nx x ny x nz cubes of edge h, each split into the 6 Kuhn tets around its main diagonal
 * (conforming between neighbours). Cube (i, j, k) gets region region_of_i[i]. Coordinates are
 * offset by values with no short decimal form, so a lossy writer would show. */
static int build_grid(NsMesh *m, int nx, int ny, int nz, double h, const int *region_of_i)
{
    static const int perm[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2},
                                   {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
    const double origin[3] = {0.1, -1.0 / 3.0, 2.0 / 7.0};
    ns_mesh_init(m);
    for (int k = 0; k <= nz; k++)
        for (int j = 0; j <= ny; j++)
            for (int i = 0; i <= nx; i++) {
                double u[3] = {origin[0] + h * i, origin[1] + h * j, origin[2] + h * k};
                if (ns_mesh_add_node(m, u) < 0)
                    return -1;
            }
    for (int k = 0; k < nz; k++)
        for (int j = 0; j < ny; j++)
            for (int i = 0; i < nx; i++)
                for (int p = 0; p < 6; p++) {
                    int c[3] = {i, j, k}, v[4];
                    for (int s = 0; s < 4; s++) {
                        v[s] = c[0] + (nx + 1) * (c[1] + (ny + 1) * c[2]);
                        if (s < 3)
                            c[perm[p][s]]++;
                    }
                    if (ns_tet_volume(&m->u[3 * v[0]], &m->u[3 * v[1]], &m->u[3 * v[2]],
                                      &m->u[3 * v[3]]) < 0) {
                        int s = v[2];
                        v[2] = v[3];
                        v[3] = s;
                    }
                    if (ns_mesh_add_tet(m, v, region_of_i ? region_of_i[i] : 0) < 0)
                        return -1;
                }
    return 0;
}

static double total_volume(const NsMesh *m)
{
    double v = 0.0;
    for (int t = 0; t < m->tet_slots; t++) {
        const int *n = &m->tet_node[4 * t];
        v += ns_tet_volume(&m->u[3 * n[0]], &m->u[3 * n[1]], &m->u[3 * n[2]], &m->u[3 * n[3]]);
    }
    return v;
}

/* ---------------------------------------------------------------------------------------------
 * MSH 4.1 round trip
 * ------------------------------------------------------------------------------------------- */

static int msh41_round_trip(void)
{
    /* 2 x 2 x 1 cubes; regions 0 and 2 interleave in tet order, region 1 is absent */
    const int regions[2] = {0, 2};
    NsMesh m, back;
    char path[512], err[512];
    ENSURE(build_grid(&m, 2, 2, 1, 0.1, regions) == 0);
    ENSURE(m.tet_slots == 24 && m.node_slots == 18);
    m.flags[0] |= NS_NODE_FIXED;
    const char *names[3] = {"fat", NULL, "muscle tissue"};
    tmp_path(path, "round.msh");
    ENSURE(ns_mesh_write_msh(path, &m, names, 3, err, sizeof err) == 0);
    /* writing again replaces the file */
    ENSURE(ns_mesh_write_msh(path, &m, names, 3, err, sizeof err) == 0);
    char tmp[600];
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    ENSURE(!exists(tmp));

    char *text = read_text(path);
    ENSURE(text != NULL);
    bool named = strstr(text, "$PhysicalNames\n2\n3 1 \"fat\"\n3 3 \"muscle tissue\"\n") != NULL;
    bool entities = strstr(text, "$Entities\n0 0 0 2\n1 ") != NULL;
    bool blocks = strstr(text, "$Elements\n2 24 1 24\n3 1 4 12\n") != NULL;
    free(text);
    ENSURE(named && entities && blocks);

    ns_mesh_init(&back);
    ENSURE(ns_mesh_read_msh(path, &back, err, sizeof err) == 0);
    ENSURE(ns_mesh_validate(&back, err, sizeof err) == 0);
    ENSURE(back.node_slots == m.node_slots && back.node_alive == m.node_alive);
    ENSURE(back.tet_slots == m.tet_slots && back.tet_alive == m.tet_alive);
    /* bitwise equal coordinates, same tets in the same slots, same regions */
    ENSURE(memcmp(back.u, m.u, (size_t)m.node_slots * 3 * sizeof(double)) == 0);
    ENSURE(memcmp(back.x, m.u, (size_t)m.node_slots * 3 * sizeof(double)) == 0);
    ENSURE(memcmp(back.tet_node, m.tet_node, (size_t)m.tet_slots * 4 * sizeof(int)) == 0);
    ENSURE(memcmp(back.tet_region, m.tet_region, (size_t)m.tet_slots * sizeof(int)) == 0);
    ENSURE(ns_mesh_topology_hash(&back) == ns_mesh_topology_hash(&m));
    /* reading marks the boundary: the grid's centre-bottom node (1, 1, 0) is on it */
    ENSURE(back.flags[4] & NS_NODE_BOUNDARY);

    /* a second round trip gives the same bytes */
    char path2[512];
    tmp_path(path2, "round2.msh");
    ENSURE(ns_mesh_write_msh(path2, &back, names, 3, err, sizeof err) == 0);
    char *a = read_text(path), *b = read_text(path2);
    bool same = a && b && strcmp(a, b) == 0;
    free(a);
    free(b);
    ENSURE(same);
    ns_mesh_free(&back);
    ns_mesh_free(&m);
    return 0;
}

/* ---------------------------------------------------------------------------------------------
 * Hand-written files
 * ------------------------------------------------------------------------------------------- */

/* The unit cube split into 5 tets: corner c = (bit0, bit1, bit2) has the sparse tag below.
 * Sorted tags 3 8 15 21 44 56 70 90 are corners 2 6 1 5 3 7 0 4, so dense node i is corner
 * kRankCorner[i]. */
static const int kRankCorner[8] = {2, 6, 1, 5, 3, 7, 0, 4};

static int check_cube(const NsMesh *m, const int expect_nodes[5][4], const int expect_region[5])
{
    ENSURE(m->node_slots == 8 && m->node_alive == 8);
    ENSURE(m->tet_slots == 5 && m->tet_alive == 5);
    for (int i = 0; i < 8; i++) {
        int c = kRankCorner[i];
        ENSURE(m->u[3 * i] == (double)(c & 1));
        ENSURE(m->u[3 * i + 1] == (double)((c >> 1) & 1));
        ENSURE(m->u[3 * i + 2] == (double)((c >> 2) & 1));
    }
    for (int t = 0; t < 5; t++) {
        for (int k = 0; k < 4; k++)
            ENSURE(m->tet_node[4 * t + k] == expect_nodes[t][k]);
        ENSURE(m->tet_region[t] == expect_region[t]);
    }
    ENSURE_SMALL(total_volume(m) - 1.0, 1e-14);
    char err[256];
    ENSURE(ns_mesh_validate(m, err, sizeof err) == 0);
    return 0;
}

static const char kMsh22[] =
    "$MeshFormat\n"
    "2.2 0 8\n"
    "$EndMeshFormat\n"
    "$Comments\n"
    "anything at all $Nodes 1 2 3\n"
    "$EndComments\n"
    "$PhysicalNames\n"
    "2\n"
    "3 1 \"fat\"\n"
    "3 3 \"two words\"\n"
    "$EndPhysicalNames\n"
    "$Nodes\n"
    "8\n"
    "70 0 0 0\n"
    "15 1 0 0\n"
    "3 0 1 0\n"
    "44 1 1 0\n"
    "90 0 0 1\n"
    "21 1.0 0 1e0\n"
    "8 0 1 1\n"
    "56 1 1 1\n"
    "$EndNodes\n"
    "$Elements\n"
    "10\n"
    "1 15 2 0 1 70\n"            /* point */
    "4 1 2 0 1 70 15\n"          /* line */
    "5 2 2 2 3 70 15 3\n"        /* triangle */
    "300 4 3 3 2 0 15 3 90 56\n" /* tets: physical tag first, 3 -> region 2 */
    "100 4 2 1 1 70 15 3 90\n"
    "101 4 2 1 1 44 3 15 56\n"
    "205 4 2 3 2 21 15 90 56\n"
    "206 4 0 8 56 90 3\n" /* no tags -> region 0 */
    "7 1 2 0 1 3 90\n"
    "8 9 2 0 1 70 15 3 44 90 21\n" /* 6-node triangle */
    "$EndElements\n"
    "$NodeData\n"
    "1\n"
    "\"ignored\"\n"
    "$EndNodeData\n";

static int msh22_fixture(void)
{
    char path[512], err[512];
    tmp_path(path, "mesh_cube22.msh");
    ENSURE(write_text(path, kMsh22) == 0);
    NsMesh m;
    ns_mesh_init(&m);
    int rc = ns_mesh_read_msh(path, &m, err, sizeof err);
    if (rc)
        fprintf(stderr, "%s\n", err);
    ENSURE(rc == 0);
    /* tets ordered by element tag 100 101 205 206 300; node tag -> rank:
     * 3->0 8->1 15->2 21->3 44->4 56->5 70->6 90->7 */
    const int nodes[5][4] = {{6, 2, 0, 7}, {4, 0, 2, 5}, {3, 2, 7, 5}, {1, 5, 7, 0}, {2, 0, 7, 5}};
    const int region[5] = {0, 0, 2, 0, 2};
    ENSURE(check_cube(&m, nodes, region) == 0);
    uint64_t hash = ns_mesh_topology_hash(&m);
    ns_mesh_free(&m);

    /* the same file with Windows line ends reads the same */
    size_t n = strlen(kMsh22);
    char *crlf = malloc(2 * n + 1), *q = crlf;
    ENSURE(crlf != NULL);
    for (size_t i = 0; i < n; i++) {
        if (kMsh22[i] == '\n')
            *q++ = '\r';
        *q++ = kMsh22[i];
    }
    *q = '\0';
    tmp_path(path, "mesh_cube22_crlf.msh");
    rc = write_text(path, crlf);
    free(crlf);
    ENSURE(rc == 0);
    ENSURE(ns_mesh_read_msh(path, &m, err, sizeof err) == 0);
    ENSURE(check_cube(&m, nodes, region) == 0 && ns_mesh_topology_hash(&m) == hash);
    ns_mesh_free(&m);
    return 0;
}

/* Gmsh 2.2 repeats an element for every physical group it is in, under a new tag: the copies
 * collapse to the first, as MSH 4.1 takes an entity's first physical tag. */
static int msh22_physical_copies(void)
{
    char path[512], err[512];
    tmp_path(path, "mesh_copies22.msh");
    ENSURE(write_text(path, "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n"
                            "$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n"
                            "$Elements\n2\n1 4 2 5 1 1 2 3 4\n2 4 2 2 1 1 2 3 4\n"
                            "$EndElements\n") == 0);
    NsMesh m;
    ENSURE(ns_mesh_read_msh(path, &m, err, sizeof err) == 0);
    ENSURE(m.tet_alive == 1 && m.tet_slots == 1 && m.tet_region[0] == 4);
    ENSURE(ns_mesh_validate(&m, err, sizeof err) == 0);
    ns_mesh_free(&m);
    return 0;
}

/* A partitioned 4.1 file: elements sit on partition entities with their own physical tags. */
static int msh41_partitioned(void)
{
    char path[512], err[512];
    tmp_path(path, "mesh_partitioned41.msh");
    ENSURE(write_text(path, "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n"
                            "$Entities\n0 0 0 1\n1 0 0 0 1 1 1 1 2 0\n$EndEntities\n"
                            "$PartitionedEntities\n2\n1\n9 2\n0 0 0 1\n"
                            "5 3 1 2 1 2 0 0 0 1 1 1 1 4 0\n$EndPartitionedEntities\n"
                            "$Nodes\n1 4 1 4\n3 5 0 4\n1\n2\n3\n4\n"
                            "0 0 0\n1 0 0\n0 1 0\n0 0 1\n$EndNodes\n"
                            "$Elements\n1 1 1 1\n3 5 4 1\n1 1 2 3 4\n$EndElements\n") == 0);
    NsMesh m;
    int rc = ns_mesh_read_msh(path, &m, err, sizeof err);
    if (rc)
        fprintf(stderr, "%s\n", err);
    ENSURE(rc == 0);
    ENSURE(m.tet_alive == 1 && m.tet_region[0] == 3);
    ns_mesh_free(&m);
    return 0;
}

static const char kMsh41[] = "$MeshFormat\n"
                             "4.1 0 8\n"
                             "$EndMeshFormat\n"
                             "$PhysicalNames\n"
                             "3\n"
                             "0 5 \"tip\"\n"
                             "3 1 \"fat\"\n"
                             "3 3 \"muscle\"\n"
                             "$EndPhysicalNames\n"
                             "$Entities\n"
                             "2 0 1 2\n"
                             "11 0 0 0 0\n"
                             "12 1 1 1 1 5\n"
                             "5 0 0 0 1 1 0 1 2 0\n"
                             "7 0 0 0 1 1 1 1 1 1 5\n"
                             "9 0 0 0 1 1 1 1 3 0\n"
                             "$EndEntities\n"
                             "$Nodes\n"
                             "4 8 3 90\n"
                             "0 11 0 1\n"
                             "70\n"
                             "0 0 0\n"
                             "0 12 0 1\n"
                             "56\n"
                             "1 1 1\n"
                             "2 5 0 3\n"
                             "15\n"
                             "3\n"
                             "44\n"
                             "1 0 0\n"
                             "0 1 0\n"
                             "1 1 0\n"
                             "3 7 0 3\n"
                             "90\n"
                             "21\n"
                             "8\n"
                             "0 0 1\n"
                             "1 0 1\n"
                             "0 1 1\n"
                             "$EndNodes\n"
                             "$Elements\n"
                             "4 8 10 40\n"
                             "0 11 15 1\n"
                             "40 70\n"
                             "2 5 2 2\n"
                             "31 70 15 3\n"
                             "32 15 44 3\n"
                             "3 7 4 4\n"
                             "10 70 15 3 90\n"
                             "12 44 3 15 56\n"
                             "14 21 15 90 56\n"
                             "16 8 56 90 3\n"
                             "3 9 4 1\n"
                             "11 15 3 90 56\n"
                             "$EndElements\n";

static int msh41_fixture(void)
{
    char path[512], err[512];
    tmp_path(path, "mesh_cube41.msh");
    ENSURE(write_text(path, kMsh41) == 0);
    NsMesh m;
    ns_mesh_init(&m);
    int rc = ns_mesh_read_msh(path, &m, err, sizeof err);
    if (rc)
        fprintf(stderr, "%s\n", err);
    ENSURE(rc == 0);
    /* tets by element tag 10 11 12 14 16; volume 7 is physical 1, volume 9 physical 3 */
    const int nodes[5][4] = {{6, 2, 0, 7}, {2, 0, 7, 5}, {4, 0, 2, 5}, {3, 2, 7, 5}, {1, 5, 7, 0}};
    const int region[5] = {0, 2, 0, 0, 0};
    ENSURE(check_cube(&m, nodes, region) == 0);
    ns_mesh_free(&m);
    return 0;
}

/* Files written by Gmsh itself (tests/data, provenance in their $Comments): the same mesh of two
 * boxes with physical volumes 1 and 3, in 4.1 and in 2.2, with surfaces and points mixed in. */
static int gmsh_files(void)
{
    NsMesh a, b, c;
    char err[512], out[512];
    const char *p41 = NS_SOURCE_DIR "/tests/data/mesh_gmsh_two_boxes41.msh";
    const char *p22 = NS_SOURCE_DIR "/tests/data/mesh_gmsh_two_boxes22.msh";
    int rc = ns_mesh_read_msh(p41, &a, err, sizeof err);
    if (rc)
        fprintf(stderr, "%s\n", err);
    ENSURE(rc == 0);
    ENSURE(ns_mesh_read_msh(p22, &b, err, sizeof err) == 0);
    ENSURE(a.node_slots == 78 && a.tet_slots == 200);
    int per_region[3] = {0, 0, 0};
    for (int t = 0; t < a.tet_slots; t++)
        if (a.tet_region[t] >= 0 && a.tet_region[t] < 3)
            per_region[a.tet_region[t]]++;
    ENSURE(per_region[0] == 100 && per_region[1] == 0 && per_region[2] == 100);
    ENSURE_SMALL(total_volume(&a) - 2.0, 1e-12);
    ENSURE(ns_mesh_validate(&a, err, sizeof err) == 0);
    /* both versions give the same mesh, index for index */
    ENSURE(b.node_slots == a.node_slots && b.tet_slots == a.tet_slots);
    ENSURE(memcmp(a.u, b.u, (size_t)a.node_slots * 3 * sizeof(double)) == 0);
    ENSURE(memcmp(a.tet_node, b.tet_node, (size_t)a.tet_slots * 4 * sizeof(int)) == 0);
    ENSURE(memcmp(a.tet_region, b.tet_region, (size_t)a.tet_slots * sizeof(int)) == 0);
    /* and our own writer round-trips it */
    const char *names[3] = {"fat", NULL, "muscle"};
    tmp_path(out, "gmsh_again.msh");
    ENSURE(ns_mesh_write_msh(out, &a, names, 3, err, sizeof err) == 0);
    ENSURE(ns_mesh_read_msh(out, &c, err, sizeof err) == 0);
    ENSURE(ns_mesh_topology_hash(&c) == ns_mesh_topology_hash(&a));
    ENSURE(memcmp(a.u, c.u, (size_t)a.node_slots * 3 * sizeof(double)) == 0);
    ns_mesh_free(&a);
    ns_mesh_free(&b);
    ns_mesh_free(&c);
    return 0;
}

/* ---------------------------------------------------------------------------------------------
 * VTU
 * ------------------------------------------------------------------------------------------- */

/* The whitespace-separated values of the DataArray named name, or NULL. Returns a pointer to
 * the first value and sets *count. */
static const char *vtu_array(const char *text, const char *name, int *count)
{
    char key[64];
    snprintf(key, sizeof key, "Name=\"%s\"", name);
    const char *p = strstr(text, key);
    if (!p)
        return NULL;
    p = strchr(p, '>');
    const char *end = p ? strstr(p, "</DataArray>") : NULL;
    if (!end)
        return NULL;
    p++;
    int n = 0;
    for (const char *q = p; q < end;) {
        while (q < end && (*q == ' ' || *q == '\n'))
            q++;
        if (q >= end)
            break;
        n++;
        while (q < end && *q != ' ' && *q != '\n')
            q++;
    }
    *count = n;
    return p;
}

static int vtu_write(void)
{
    const int regions[2] = {3, 1};
    NsMesh m;
    char path[512], err[512];
    ENSURE(build_grid(&m, 2, 1, 1, 0.25, regions) == 0);
    m.flags[0] |= NS_NODE_FIXED;
    m.flags[5] |= NS_NODE_FIXED;
    tmp_path(path, "grid.vtu");
    ENSURE(ns_mesh_write_vtu(path, &m, err, sizeof err) == 0);
    char *text = read_text(path);
    ENSURE(text != NULL);
    int ok = strncmp(text, "<?xml", 5) == 0 && strstr(text, "type=\"UnstructuredGrid\"") &&
             strstr(text, "NumberOfPoints=\"12\" NumberOfCells=\"12\"") &&
             strstr(text, "</VTKFile>");
    int n_region = -1, n_quality = -1, n_fixed = -1, n_conn = -1, n_off = -1, n_types = -1;
    const char *region = vtu_array(text, "region", &n_region);
    const char *quality = vtu_array(text, "quality", &n_quality);
    const char *fixed = vtu_array(text, "fixed", &n_fixed);
    const char *conn = vtu_array(text, "connectivity", &n_conn);
    vtu_array(text, "offsets", &n_off);
    const char *types = vtu_array(text, "types", &n_types);
    ok = ok && region && quality && fixed && conn && types;
    ok = ok && n_region == 12 && n_quality == 12 && n_fixed == 12 && n_conn == 48 && n_off == 12 &&
         n_types == 12;
    ok = ok && strstr(text, "<DataArray type=\"Int32\" Name=\"region\"") &&
         strstr(text, "<DataArray type=\"Float64\" Name=\"quality\"") &&
         strstr(text, "<DataArray type=\"UInt8\" Name=\"fixed\"");
    /* values: regions per cube, quality of each tet, fixed flags, VTK_TETRA */
    if (ok) {
        char *q = (char *)quality;
        for (int t = 0; t < 12 && ok; t++) {
            const int *n = &m.tet_node[4 * t];
            double expect =
                ns_tet_quality(&m.u[3 * n[0]], &m.u[3 * n[1]], &m.u[3 * n[2]], &m.u[3 * n[3]]);
            ok = strtod(q, &q) == expect && expect > 0.0;
        }
        char *r = (char *)region;
        for (int t = 0; t < 12 && ok; t++)
            ok = strtol(r, &r, 10) == m.tet_region[t];
        char *f = (char *)fixed;
        for (int i = 0; i < 12 && ok; i++)
            ok = strtol(f, &f, 10) == (i == 0 || i == 5);
        char *c = (char *)conn;
        for (int i = 0; i < 48 && ok; i++)
            ok = strtol(c, &c, 10) == m.tet_node[i];
        char *y = (char *)types;
        for (int i = 0; i < 12 && ok; i++)
            ok = strtol(y, &y, 10) == 10;
    }
    free(text);
    ENSURE(ok);
    char tmp[600];
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    ENSURE(!exists(tmp));
    ns_mesh_free(&m);
    return 0;
}

/* ---------------------------------------------------------------------------------------------
 * Reading errors
 * ------------------------------------------------------------------------------------------- */

#define HDR22 "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n" /* lines 1-3 */

typedef struct BadFile {
    const char *name;
    const char *text;
    int line; /* expected "path:line:" */
    const char *message;
} BadFile;

static const BadFile kBad[] = {
    {"truncated_nodes", HDR22 "$Nodes\n4\n1 0 0 0\n2 1 0 0\n", 7, "truncated file"},
    {"truncated_nodes_no_newline", HDR22 "$Nodes\n4\n1 0 0 0\n2 1 0", 7, "truncated file"},
    {"short_nodes", HDR22 "$Nodes\n4\n1 0 0 0\n2 1 0 0\n$EndNodes\n", 8,
     "$Nodes ends early: found '$EndNodes'"},
    {"bad_coordinate", HDR22 "$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 abc 0\n4 0 0 1\n$EndNodes\n", 8,
     "malformed number 'abc' in $Nodes (expected y coordinate of node 3)"},
    {"missing_node",
     HDR22 "$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n"
           "$Elements\n1\n17 4 2 1 1 1 2 3 9\n$EndElements\n",
     13, "element 17 references node 9, which is not defined"},
    {"inverted",
     HDR22 "$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n"
           "$Elements\n1\n17 4 2 1 1 1 3 2 4\n$EndElements\n",
     13, "element 17 is inverted"},
    {"degenerate",
     HDR22 "$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 1 1 0\n$EndNodes\n"
           "$Elements\n1\n17 4 2 1 1 1 2 3 4\n$EndElements\n",
     13, "element 17 is degenerate"},
    {"nearly_flat",
     HDR22 "$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0.3 0.3 1e-12\n$EndNodes\n"
           "$Elements\n1\n17 4 2 1 1 1 2 3 4\n$EndElements\n",
     13, "element 17 is degenerate"},
    {"repeated_node",
     HDR22 "$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n"
           "$Elements\n1\n17 4 2 1 1 1 2 3 2\n$EndElements\n",
     13, "element 17 is degenerate (node 2 appears twice)"},
    {"unused_node",
     HDR22 "$Nodes\n5\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 5 5 5\n$EndNodes\n"
           "$Elements\n1\n17 4 2 1 1 1 2 3 4\n$EndElements\n",
     10, "node 5 is not used by any tetrahedron"},
    {"edge_only",
     HDR22 "$Nodes\n6\n1 0 0 0\n2 0 0 1\n3 1 0 0\n4 1 1 0\n5 -1 0 0\n6 -1 -1 0\n$EndNodes\n"
           "$Elements\n2\n1 4 2 1 1 1 2 3 4\n2 4 2 1 1 1 2 5 6\n$EndElements\n",
     6, "not manifold at the edge between nodes 1 and 2"},
    {"vertex_only",
     HDR22 "$Nodes\n7\n1 0 0 0\n2 0 0 1\n3 1 0 0\n4 1 1 0\n5 -1 0 0\n6 0 -1 0\n7 0 0 -1\n"
           "$EndNodes\n$Elements\n2\n1 4 2 1 1 1 2 3 4\n2 4 2 1 1 1 6 5 7\n$EndElements\n",
     6, "not manifold at node 1"},
    {"overlap",
     HDR22 "$Nodes\n5\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 0.2 0.2 0.5\n$EndNodes\n"
           "$Elements\n2\n1 4 2 1 1 1 2 3 4\n2 4 2 1 1 1 2 3 5\n$EndElements\n",
     15, "elements 1 and 2 overlap"},
    {"three_on_face",
     HDR22 "$Nodes\n6\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 0 0 -1\n6 0.1 0.1 2\n$EndNodes\n"
           "$Elements\n3\n1 4 2 1 1 1 2 3 4\n2 4 2 1 1 1 3 2 5\n3 4 2 1 1 1 2 3 6\n"
           "$EndElements\n",
     17, "shared by more than two tetrahedra (elements 1, 2 and 3)"},
    {"same_tet",
     HDR22 "$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n"
           "$Elements\n2\n1 4 2 1 1 1 2 3 4\n2 4 2 1 1 2 3 1 4\n$EndElements\n",
     14, "elements 1 and 2 are the same tetrahedron"},
    {"copies_then_overlap",
     HDR22 "$Nodes\n5\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 0.2 0.2 0.5\n$EndNodes\n"
           "$Elements\n3\n1 4 2 1 1 1 2 3 4\n2 4 2 2 1 1 2 3 4\n3 4 2 1 1 1 2 3 5\n"
           "$EndElements\n",
     16, "elements 1 and 3 overlap"},
    {"duplicate_node_tag",
     HDR22 "$Nodes\n5\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n2 5 5 5\n$EndNodes\n"
           "$Elements\n1\n17 4 2 1 1 1 2 3 4\n$EndElements\n",
     10, "node tag 2 is defined twice (also on line 7)"},
    {"only_triangles",
     HDR22 "$Nodes\n3\n1 0 0 0\n2 1 0 0\n3 0 1 0\n$EndNodes\n"
           "$Elements\n1\n1 2 2 1 1 1 2 3\n$EndElements\n",
     10, "no tetrahedra"},
    {"second_order",
     HDR22 "$Nodes\n1\n1 0 0 0\n$EndNodes\n"
           "$Elements\n1\n1 11 0 1 1 1 1 1 1 1 1 1 1\n$EndElements\n",
     8, "1 higher-order tetrahedra"},
    {"unknown_type", HDR22 "$Nodes\n1\n1 0 0 0\n$EndNodes\n$Elements\n1\n1 77 0 1\n$EndElements\n",
     10, "unknown element type 77"},
    {"missing_end", HDR22 "$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$Elements\n", 10,
     "expected $EndNodes, found '$Elements'"},
    {"binary", "$MeshFormat\n4.1 1 8\n\x01\x02\x03\x04\n$EndMeshFormat\n", 2,
     "binary MSH files are not supported"},
    {"version", "$MeshFormat\n3.0 0 8\n$EndMeshFormat\n", 2, "MSH version 3.0 is not supported"},
    {"version_40", "$MeshFormat\n4 0 8\n$EndMeshFormat\n", 2, "MSH version 4 is not supported"},
    {"not_msh", "solid cube\nfacet normal 0 0 1\n", 1, "not a Gmsh MSH file: found 'solid'"},
    {"junk_between", "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n42\n", 4,
     "expected a section header such as $Nodes"},
    {"no_format", "$Nodes\n0\n$EndNodes\n", 1, "not a Gmsh MSH file"},
    {"empty", "", 1, "not a Gmsh MSH file"},
    {"truncated_41",
     "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 4 1 4\n3 1 0 4\n1\n2\n3\n4\n"
     "0 0 0\n1 0 0\n0 1",
     13, "truncated file: it ends inside $Nodes (expected z coordinate of node 3)"},
    {"count_mismatch_41",
     "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 5 1 4\n3 1 0 1\n1\n0 0 0\n$EndNodes\n", 4,
     "$Nodes declares 5 nodes but its blocks hold 1"},
    {"parametric_41",
     "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 1 1 1\n1 1 1 1\n1\n0 0 0 0.5\n"
     "$EndNodes\n",
     6, "parametric coordinates"},
    {"missing_node_41",
     "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 4 1 4\n3 1 0 4\n1\n2\n3\n4\n"
     "0 0 0\n1 0 0\n0 1 0\n0 0 1\n$EndNodes\n$Elements\n1 1 5 5\n3 1 4 1\n5 1 2 3 8\n"
     "$EndElements\n",
     19, "element 5 references node 8"},
    {"negative_tag", HDR22 "$Nodes\n1\n-4 0 0 0\n$EndNodes\n", 6,
     "node tag -4 in $Nodes is out of range"},
    {"infinite", HDR22 "$Nodes\n1\n1 0 inf 0\n$EndNodes\n", 6,
     "'inf' of node 1 in $Nodes is not finite"},
};

static int read_errors(void)
{
    int n = (int)(sizeof kBad / sizeof kBad[0]);
    for (int i = 0; i < n; i++) {
        const BadFile *b = &kBad[i];
        char name[128], path[512], err[512], where[600];
        snprintf(name, sizeof name, "bad_%s.msh", b->name);
        tmp_path(path, name);
        ENSURE(write_text(path, b->text) == 0);
        NsMesh m;
        ns_mesh_init(&m);
        err[0] = '\0';
        int rc = ns_mesh_read_msh(path, &m, err, sizeof err);
        snprintf(where, sizeof where, "%s:%d: ", path, b->line);
        bool ok = rc == -1 && strncmp(err, where, strlen(where)) == 0 && strstr(err, b->message);
        if (!ok)
            fprintf(stderr, "case %s: rc %d, message \"%s\"; expected \"%s%s\"\n", b->name, rc, err,
                    where, b->message);
        ENSURE(ok);
        /* nothing half-built: the mesh is empty and can be freed (twice, even) */
        ENSURE(m.tet_alive == 0 && m.tet_slots == 0 && m.node_alive == 0 && m.node_slots == 0);
        ENSURE(m.u == NULL && m.tet_node == NULL);
        ns_mesh_free(&m);
        ns_mesh_free(&m);
    }
    return 0;
}

static int read_missing_file(void)
{
    char path[512], err[512];
    tmp_path(path, "does_not_exist.msh");
    NsMesh m;
    ns_mesh_init(&m);
    ENSURE(ns_mesh_read_msh(path, &m, err, sizeof err) == -1);
    ENSURE(strstr(err, path) == err && strstr(err, "cannot open") != NULL);
    ENSURE(m.tet_alive == 0 && m.node_alive == 0);
    ns_mesh_free(&m);
    /* a directory is not a mesh file either */
    ENSURE(ns_mesh_read_msh(g_dir, &m, err, sizeof err) == -1);
    ENSURE(strstr(err, g_dir) == err);
    ns_mesh_free(&m);
    /* a device or a FIFO is refused at once, not read until memory runs out or waited on
     * (found by fuzz/fuzz_scenario: ns.tissue.file{path = "/dev/zero"}) */
    ENSURE(ns_mesh_read_msh("/dev/zero", &m, err, sizeof err) == -1);
    ENSURE(strstr(err, "/dev/zero:") == err && strstr(err, "regular files only") != NULL);
    char fifo[512];
    tmp_path(fifo, "fifo.msh");
    ENSURE(mkfifo(fifo, 0600) == 0);
    ENSURE(ns_mesh_read_msh(fifo, &m, err, sizeof err) == -1);
    ENSURE(strstr(err, "regular files only") != NULL);
    unlink(fifo);
    ns_mesh_free(&m);
    /* a tiny buffer truncates the message but stays terminated; a NULL buffer is allowed */
    char tiny[8];
    ENSURE(ns_mesh_read_msh(path, &m, tiny, sizeof tiny) == -1);
    ENSURE(strlen(tiny) == sizeof tiny - 1);
    ENSURE(ns_mesh_read_msh(path, &m, NULL, 0) == -1);
    ns_mesh_free(&m);
    return 0;
}

/* ---------------------------------------------------------------------------------------------
 * Whole-mesh checks: one connected solid, no overlap (sim/mesh_check.h)
 * ------------------------------------------------------------------------------------------- */

/* A 2 x 2 x 2 grid of cubes of side h, plus a copy of it moved by shift (its own nodes). */
static int two_copies(NsMesh *m, double h, const double shift[3])
{
    if (build_grid(m, 2, 2, 2, h, NULL))
        return -1;
    int nn = m->node_slots, nt = m->tet_slots;
    for (int i = 0; i < nn; i++) {
        double u[3] = {m->u[3 * i] + shift[0], m->u[3 * i + 1] + shift[1],
                       m->u[3 * i + 2] + shift[2]};
        if (ns_mesh_add_node(m, u) != nn + i)
            return -1;
    }
    for (int t = 0; t < nt; t++) {
        int v[4];
        for (int k = 0; k < 4; k++)
            v[k] = m->tet_node[4 * t + k] + nn;
        if (ns_mesh_add_tet(m, v, 0) < 0)
            return -1;
    }
    return 0;
}

/* Writes m, reads it back, expects an error containing each of the messages. */
static int expect_read_error(const NsMesh *m, const char *name, const char *msg1, const char *msg2)
{
    char path[512], err[512];
    tmp_path(path, name);
    ENSURE(ns_mesh_write_msh(path, m, NULL, 0, err, sizeof err) == 0);
    NsMesh back;
    err[0] = '\0';
    int rc = ns_mesh_read_msh(path, &back, err, sizeof err);
    bool ok = rc == -1 && strstr(err, path) == err && strstr(err, msg1) && strstr(err, msg2);
    if (!ok)
        fprintf(stderr, "%s: rc %d, message \"%s\"\n", name, rc, err);
    ENSURE(ok);
    ENSURE(back.tet_alive == 0 && back.node_alive == 0);
    ns_mesh_free(&back);
    return 0;
}

static int overlapping_copies(void)
{
    NsMesh m;
    /* two interpenetrating copies of a cube: the nodes of one inside the tets of the other */
    const double half[3] = {0.5, 0.5, 0.5};
    ENSURE(two_copies(&m, 1.0, half) == 0);
    ENSURE(expect_read_error(&m, "interpenetrating.msh", "tets overlap: an inner point of element",
                             "the elements hold 16 m^3 in 2 separate parts, the first two 8 and "
                             "8 m^3: two copies of a part?") == 0);
    ns_mesh_free(&m);
    /* two copies in the same place (no node inside another tet: their centres are) */
    const double none[3] = {0, 0, 0};
    ENSURE(two_copies(&m, 1.0, none) == 0);
    ENSURE(expect_read_error(&m, "coincident.msh", "tets overlap: the centre of element", "") == 0);
    ns_mesh_free(&m);
    /* shifted by less than an element: still found */
    const double small[3] = {0.3, 0.1, 0.2};
    ENSURE(two_copies(&m, 1.0, small) == 0);
    ENSURE(expect_read_error(&m, "shifted.msh", "tets overlap:", "two copies") == 0);
    ns_mesh_free(&m);
    return 0;
}

static int disconnected_parts(void)
{
    NsMesh m;
    /* side by side, apart: two parts of 48 tets each, named by their first elements */
    const double apart[3] = {5.0, 0.0, 0.0};
    ENSURE(two_copies(&m, 1.0, apart) == 0);
    ENSURE(expect_read_error(&m, "apart.msh",
                             "the mesh has 2 separate solid parts (tets that share no face): 48 "
                             "tets from element 1 and 48 tets from element 49",
                             "one connected solid") == 0);
    ns_mesh_free(&m);
    /* face to face but with nodes of their own: not joined either */
    const double touching[3] = {2.0, 0.0, 0.0};
    ENSURE(two_copies(&m, 1.0, touching) == 0);
    ENSURE(expect_read_error(&m, "touching.msh", "2 separate solid parts", "Coherence") == 0);
    ns_mesh_free(&m);
    /* one grid of 2 x 2 x 2 cubes is one part, and a valid mesh passes the overlap test */
    ENSURE(build_grid(&m, 3, 2, 2, 0.01, NULL) == 0);
    int part[72], count[72];
    double volume[72];
    ENSURE(ns_mesh_parts(&m, part, count, volume) == 1 && count[0] == 72);
    ENSURE(fabs(volume[0] - 12e-6) < 1e-15);
    NsTetOverlap o;
    ENSURE(ns_mesh_find_overlap(&m, &o) == 0);
    ns_mesh_free(&m);
    return 0;
}

/* ---------------------------------------------------------------------------------------------
 * Files that are not regular, or too large: refused before a byte is read
 * ------------------------------------------------------------------------------------------- */

static int special_files(void)
{
    NsMesh m;
    char path[512], err[512];
    /* a FIFO with no writer: opening it for reading would block forever */
    tmp_path(path, "fifo.msh");
    ENSURE(mkfifo(path, 0600) == 0);
    ENSURE(ns_mesh_read_msh(path, &m, err, sizeof err) == -1);
    ENSURE(strstr(err, path) == err && strstr(err, "is a FIFO (named pipe), not a mesh file"));
    ns_mesh_free(&m);
    /* /dev/zero never ends */
    ENSURE(ns_mesh_read_msh("/dev/zero", &m, err, sizeof err) == -1);
    ENSURE(strstr(err, "/dev/zero: is a character device, not a mesh file") == err);
    ns_mesh_free(&m);
    /* a sparse file one byte over the limit: refused by its size, not read */
    tmp_path(path, "huge.msh");
    FILE *f = fopen(path, "wb");
    ENSURE(f != NULL);
    ENSURE(ftruncate(fileno(f), (off_t)(NS_LIMIT_MESH_FILE_BYTES + 1)) == 0);
    fclose(f);
    ENSURE(ns_mesh_read_msh(path, &m, err, sizeof err) == -1);
    char want[128];
    snprintf(want, sizeof want, "the mesh file is %lld bytes, more than the limit of %lld bytes",
             NS_LIMIT_MESH_FILE_BYTES + 1, NS_LIMIT_MESH_FILE_BYTES);
    ENSURE(strstr(err, path) == err && strstr(err, want));
    ns_mesh_free(&m);
    unlink(path);
    return 0;
}

/* ---------------------------------------------------------------------------------------------
 * Writing errors
 * ------------------------------------------------------------------------------------------- */

static int write_errors(void)
{
    NsMesh m;
    char path[512], tmp[600], err[512];
    ENSURE(build_grid(&m, 1, 1, 1, 1.0, NULL) == 0);

    /* a directory that does not exist */
    tmp_path(path, "no/such/dir/out.msh");
    err[0] = '\0';
    ENSURE(ns_mesh_write_msh(path, &m, NULL, 0, err, sizeof err) == -1);
    ENSURE(strstr(err, "cannot create") != NULL && strstr(err, path) == err);
    ENSURE(ns_mesh_write_vtu(path, &m, err, sizeof err) == -1);
    ENSURE(strstr(err, "cannot create") != NULL);
    tmp_path(path, "no");
    ENSURE(!exists(path));

    /* the target is a directory: refused, and the temporary file is removed */
    tmp_path(path, "adir");
    ENSURE(mkdir(path, 0700) == 0);
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    ENSURE(ns_mesh_write_msh(path, &m, NULL, 0, err, sizeof err) == -1);
    ENSURE(strstr(err, "not a regular file") != NULL); /* refused before the rename */
    ENSURE(!exists(tmp));
    ENSURE(ns_mesh_write_vtu(path, &m, err, sizeof err) == -1);
    ENSURE(!exists(tmp));
    struct stat st;
    ENSURE(stat(path, &st) == 0 && S_ISDIR(st.st_mode));

    /* a name that MSH cannot quote */
    const char *bad_names[1] = {"say \"hi\""};
    tmp_path(path, "named.msh");
    ENSURE(ns_mesh_write_msh(path, &m, bad_names, 1, err, sizeof err) == -1);
    ENSURE(strstr(err, "quote") != NULL && !exists(path));

    /* a mesh with holes in its slots must be compacted first; an existing file survives */
    tmp_path(path, "keep.msh");
    ENSURE(write_text(path, "old contents\n") == 0);
    ns_mesh_remove_tet(&m, 2);
    ENSURE(ns_mesh_write_msh(path, &m, NULL, 0, err, sizeof err) == -1);
    ENSURE(strstr(err, "not compact") != NULL);
    ENSURE(ns_mesh_write_vtu(path, &m, err, sizeof err) == -1);
    char *text = read_text(path);
    bool kept = text && strcmp(text, "old contents\n") == 0;
    free(text);
    ENSURE(kept);
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    ENSURE(!exists(tmp));

    /* compacted, it writes (and the boundary still closes) */
    ENSURE(ns_mesh_compact(&m) == 0);
    ENSURE(ns_mesh_write_msh(path, &m, NULL, 0, err, sizeof err) == 0);
    NsMesh back;
    ENSURE(ns_mesh_read_msh(path, &back, err, sizeof err) == 0);
    ENSURE(back.tet_alive == 5 && ns_mesh_topology_hash(&back) == ns_mesh_topology_hash(&m));
    ns_mesh_free(&back);

    /* an empty mesh has nothing to write */
    NsMesh empty;
    ns_mesh_init(&empty);
    tmp_path(path, "empty.msh");
    ENSURE(ns_mesh_write_msh(path, &empty, NULL, 0, err, sizeof err) == -1);
    ENSURE(!exists(path));
    ns_mesh_free(&m);
    return 0;
}

NS_TEST_MAIN({"msh41_round_trip", msh41_round_trip}, {"msh22_fixture", msh22_fixture},
             {"msh22_physical_copies", msh22_physical_copies}, {"msh41_fixture", msh41_fixture},
             {"msh41_partitioned", msh41_partitioned}, {"gmsh_files", gmsh_files},
             {"vtu_write", vtu_write}, {"read_errors", read_errors},
             {"read_missing_file", read_missing_file}, {"write_errors", write_errors},
             {"overlapping_copies", overlapping_copies}, {"disconnected_parts", disconnected_parts},
             {"special_files", special_files})
