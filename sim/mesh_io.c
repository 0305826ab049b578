/* Tet mesh files, reading: Gmsh MSH 4.1 / 2.2 ASCII (writing is in mesh_write.c).
 *
 * Reading is two passes over an in-memory copy of the file. The parser collects raw nodes
 * (file tag, coordinates, line) and raw tets (element tag, node tags, physical or entity tag,
 * line) without touching the mesh; the builder then sorts both by tag, resolves node tags to
 * dense indices (a node's index is the rank of its tag), validates, and only then fills the
 * NsMesh. Ranking by tag, rather than by position in the file, makes a write/read round trip
 * reproduce node and tet indices exactly, since the writer uses tag = index + 1.
 *
 * Every reading error is "path:line: message", naming the file's own node or element tags so a
 * user can find the culprit in the file or in Gmsh. */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE 1
#endif

#include "mesh_io.h"
#include "err.h"
#include "ns_limits.h"
#include "quality.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

/* |quality| at or below this is a flat tet. Quality is 6*sqrt(2)*volume / rms_edge^3, so this is
 * volume relative to edge length cubed: far below any sliver a mesher would keep. */
#define NS_MSH_DEGENERATE_QUALITY 1e-8

/* Grows *items (element size elem) so that it holds at least need elements. */
static int grow(void **items, size_t *cap, size_t need, size_t elem)
{
    if (need <= *cap)
        return 0;
    size_t c = *cap ? *cap : 64;
    while (c < need)
        c *= 2;
    if (c > SIZE_MAX / elem)
        return -1;
    void *p = realloc(*items, c * elem);
    if (!p)
        return -1;
    *items = p;
    *cap = c;
    return 0;
}

/* ---------------------------------------------------------------------------------------------
 * Reading: tokenizer
 * ------------------------------------------------------------------------------------------- */

typedef struct MshReader {
    const char *path;
    const char *buf; /* whole file, NUL-terminated */
    size_t len;
    size_t pos;
    int line;            /* 1-based line of the cursor */
    const char *section; /* section being read, for messages ("$Nodes") */
    const char *item;    /* item being read ("node"), or NULL */
    int64_t item_tag;    /* its tag, for messages */
    char *err;
    int err_sz;
} MshReader;

typedef struct MshTok {
    const char *s;
    size_t n;
    int line;
} MshTok;

/* "path:line: message" into the caller's buffer; the macro's value is -1, visibly so to
 * static analysers that do not follow a variadic call. */
static void reader_error(const MshReader *r, int line, const char *fmt, ...)
{
    if (!r->err || r->err_sz <= 0)
        return;
    int k = snprintf(r->err, (size_t)r->err_sz, "%s:%d: ", r->path, line);
    if (k >= 0 && k < r->err_sz) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(r->err + k, (size_t)(r->err_sz - k), fmt, ap);
        va_end(ap);
    }
}
#define READ_FAIL(...) (reader_error(__VA_ARGS__), -1)

static bool is_space(char c)
{
    return c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == '\v' || c == '\f';
}

static bool next_tok(MshReader *r, MshTok *t)
{
    while (r->pos < r->len && is_space(r->buf[r->pos])) {
        if (r->buf[r->pos] == '\n')
            r->line++;
        r->pos++;
    }
    if (r->pos >= r->len)
        return false;
    size_t start = r->pos;
    while (r->pos < r->len && !is_space(r->buf[r->pos]))
        r->pos++;
    t->s = r->buf + start;
    t->n = r->pos - start;
    t->line = r->line;
    return true;
}

/* The last line of the file (the cursor's line once it has passed a final newline). */
static int eof_line(const MshReader *r)
{
    if (r->len > 0 && r->buf[r->len - 1] == '\n' && r->line > 1)
        return r->line - 1;
    return r->line;
}

static bool tok_is(const MshTok *t, const char *s)
{
    size_t n = strlen(s);
    return t->n == n && memcmp(t->s, s, n) == 0;
}

/* A token as it may be shown in a message: at most 40 printable characters. */
static const char *tok_show(const MshTok *t, char out[48])
{
    size_t n = t->n < 40 ? t->n : 40;
    for (size_t i = 0; i < n; i++) {
        unsigned char c = (unsigned char)t->s[i];
        out[i] = c >= 0x20 && c < 0x7f ? (char)c : '?';
    }
    if (t->n > n) {
        memcpy(out + n, "...", 4);
    } else {
        out[n] = '\0';
    }
    return out;
}

/* " of node 12" for the item being read, or "". */
static const char *item_ctx(const MshReader *r, char out[64])
{
    if (!r->item)
        out[0] = '\0';
    else
        snprintf(out, 64, " of %s %lld", r->item, (long long)r->item_tag);
    return out;
}

static int need_tok(MshReader *r, MshTok *t, const char *what)
{
    if (next_tok(r, t))
        return 0;
    char ctx[64];
    return READ_FAIL(r, eof_line(r), "truncated file: it ends inside %s (expected %s%s)",
                     r->section, what, item_ctx(r, ctx));
}

static void bad_number(const MshReader *r, const MshTok *t, const char *what)
{
    char shown[48], ctx[64];
    if (t->n > 0 && t->s[0] == '$')
        reader_error(r, t->line,
                     "%s ends early: found '%s' where %s%s was expected (fewer entries than "
                     "its header declares)",
                     r->section, tok_show(t, shown), what, item_ctx(r, ctx));
    else
        reader_error(r, t->line, "malformed number '%s' in %s (expected %s%s)", tok_show(t, shown),
                     r->section, what, item_ctx(r, ctx));
}

static int read_i64(MshReader *r, const char *what, int64_t lo, int64_t hi, int64_t *out)
{
    MshTok t;
    if (need_tok(r, &t, what))
        return -1;
    char tmp[32];
    if (t.n >= sizeof tmp) {
        bad_number(r, &t, what);
        return -1;
    }
    memcpy(tmp, t.s, t.n);
    tmp[t.n] = '\0';
    errno = 0;
    char *end;
    long long v = strtoll(tmp, &end, 10);
    if (end != tmp + t.n || errno == ERANGE) {
        bad_number(r, &t, what);
        return -1;
    }
    if (v < lo || v > hi) {
        char ctx[64];
        return READ_FAIL(r, t.line, "%s %lld%s in %s is out of range (%lld to %lld)", what, v,
                         item_ctx(r, ctx), r->section, (long long)lo, (long long)hi);
    }
    *out = (int64_t)v;
    return 0;
}

static int read_int(MshReader *r, const char *what, int lo, int hi, int *out)
{
    int64_t v;
    if (read_i64(r, what, lo, hi, &v))
        return -1;
    *out = (int)v;
    return 0;
}

static int read_double(MshReader *r, const char *what, double *out)
{
    MshTok t;
    if (need_tok(r, &t, what))
        return -1;
    char tmp[128];
    if (t.n >= sizeof tmp) {
        bad_number(r, &t, what);
        return -1;
    }
    memcpy(tmp, t.s, t.n);
    tmp[t.n] = '\0';
    char *end;
    double v = strtod(tmp, &end);
    if (end != tmp + t.n || t.n == 0) {
        bad_number(r, &t, what);
        return -1;
    }
    if (!isfinite(v)) {
        char shown[48], ctx[64];
        return READ_FAIL(r, t.line, "%s '%s'%s in %s is not finite", what, tok_show(&t, shown),
                         item_ctx(r, ctx), r->section);
    }
    *out = v;
    return 0;
}

static int expect_end(MshReader *r, const char *end)
{
    MshTok t;
    if (!next_tok(r, &t))
        return READ_FAIL(r, eof_line(r), "truncated file: %s is missing", end);
    if (!tok_is(&t, end)) {
        char shown[48];
        return READ_FAIL(r, t.line,
                         "expected %s, found '%s' (more entries than the header of %s "
                         "declares?)",
                         end, tok_show(&t, shown), r->section);
    }
    return 0;
}

/* Skips a section we do not use ($Comments, $PhysicalNames, $NodeData, ...). */
static int skip_section(MshReader *r, const char *name)
{
    char end[80];
    snprintf(end, sizeof end, "$End%s", name);
    MshTok t;
    while (next_tok(r, &t))
        if (tok_is(&t, end))
            return 0;
    return READ_FAIL(r, eof_line(r), "truncated file: %s is missing", end);
}

/* ---------------------------------------------------------------------------------------------
 * Reading: sections
 * ------------------------------------------------------------------------------------------- */

typedef struct RawNode {
    int64_t tag;
    double x[3];
    int line;
} RawNode;

enum { GROUP_NONE, GROUP_PHYSICAL, GROUP_ENTITY };

typedef struct RawTet {
    int64_t tag;
    int64_t node[4];
    int64_t group; /* physical tag (2.2) or volume entity tag (4.1), per group_kind */
    int group_kind;
    int line;
} RawTet;

typedef struct VolumeEntity {
    int64_t tag;
    int64_t physical; /* first physical tag, 0 if none */
} VolumeEntity;

typedef struct MshData {
    int version; /* 41 or 22; 0 until $MeshFormat is read */
    RawNode *nodes;
    size_t node_count, node_cap;
    RawTet *tets;
    size_t tet_count, tet_cap;
    VolumeEntity *volumes;
    size_t volume_count, volume_cap;
    bool have_nodes, have_elements;
    int elements_line;          /* line of $Elements, for "no tetrahedra" */
    int64_t high_order_tets;    /* type 11, 29, 30, 31: kept out, but worth a hint */
    int64_t other_volume_elems; /* hexahedra, prisms, pyramids */
} MshData;

/* Nodes per Gmsh element type (Gmsh reference manual, "MSH file format"), 0 if unknown. */
static int gmsh_nodes_per_element(int64_t type)
{
    static const int n[] = {0, 2,  3,  4,  4, 8,  6,  5,  3,  6,  9, 10, 27, 18, 14, 1,
                            8, 20, 15, 13, 9, 10, 12, 15, 15, 21, 4, 5,  6,  20, 35, 56};
    if (type >= 0 && type < (int64_t)(sizeof n / sizeof n[0]))
        return n[type];
    if (type == 92)
        return 64;
    if (type == 93)
        return 125;
    return 0;
}

static void note_skipped_type(MshData *d, int64_t type)
{
    if (type == 11 || type == 29 || type == 30 || type == 31)
        d->high_order_tets++;
    else if ((type >= 5 && type <= 7) || (type >= 12 && type <= 14) || (type >= 17 && type <= 19) ||
             type == 92 || type == 93)
        d->other_volume_elems++;
}

/* Initial capacity for a declared count: trust it only as far as the file is long (each entry
 * takes at least min_bytes characters), so a corrupt header cannot ask for terabytes. */
static size_t plausible(const MshReader *r, int64_t declared, size_t min_bytes)
{
    size_t most = r->len / min_bytes + 1;
    return (uint64_t)declared < most ? (size_t)declared : most;
}

static int push_node(MshReader *r, MshData *d, int64_t tag, int line)
{
    if (d->node_count >= (size_t)INT_MAX - 1)
        return READ_FAIL(r, line, "too many nodes (more than %d)", INT_MAX - 1);
    if (grow((void **)&d->nodes, &d->node_cap, d->node_count + 1, sizeof(RawNode)))
        return READ_FAIL(r, line, "out of memory");
    RawNode *n = &d->nodes[d->node_count++];
    n->tag = tag;
    n->line = line;
    n->x[0] = n->x[1] = n->x[2] = 0.0;
    return 0;
}

static int push_tet(MshReader *r, MshData *d, const RawTet *t)
{
    if (d->tet_count >= (size_t)INT_MAX / 4)
        return READ_FAIL(r, t->line, "too many tetrahedra (more than %d)", INT_MAX / 4);
    if (grow((void **)&d->tets, &d->tet_cap, d->tet_count + 1, sizeof(RawTet)))
        return READ_FAIL(r, t->line, "out of memory");
    d->tets[d->tet_count++] = *t;
    return 0;
}

static int read_format(MshReader *r, MshData *d)
{
    r->section = "$MeshFormat";
    MshTok ver;
    if (need_tok(r, &ver, "version number"))
        return -1;
    int file_type, data_size;
    if (read_int(r, "file type", INT_MIN, INT_MAX, &file_type))
        return -1;
    if (file_type != 0)
        return READ_FAIL(r, ver.line,
                         "binary MSH files are not supported; save the mesh as ASCII (Gmsh: "
                         "Mesh.Binary = 0)");
    char shown[48];
    if (tok_is(&ver, "4.1"))
        d->version = 41;
    else if (tok_is(&ver, "2.2"))
        d->version = 22;
    else
        return READ_FAIL(r, ver.line,
                         "MSH version %s is not supported (only 4.1 and 2.2 ASCII; Gmsh: "
                         "-format msh41 or msh22)",
                         tok_show(&ver, shown));
    if (read_int(r, "data size", INT_MIN, INT_MAX, &data_size))
        return -1;
    return expect_end(r, "$EndMeshFormat");
}

/* $Entities and $PartitionedEntities (4.1): only volumes matter, for their first physical tag.
 * A partitioned file's elements sit on partition entities, which carry their own physical
 * tags after a prefix (parent dimension and tag, partitions) and a list of ghost entities. */
static int read_entities41(MshReader *r, MshData *d, bool partitioned)
{
    r->section = partitioned ? "$PartitionedEntities" : "$Entities";
    static const char *const kind[4] = {"point", "curve", "surface", "volume"};
    int64_t count[4], dummy, n;
    if (partitioned) {
        if (read_i64(r, "number of partitions", 0, INT_MAX, &dummy) ||
            read_i64(r, "number of ghost entities", 0, INT_MAX, &n))
            return -1;
        for (int64_t i = 0; i < 2 * n; i++)
            if (read_i64(r, i % 2 ? "partition" : "ghost entity tag", INT_MIN, INT_MAX, &dummy))
                return -1;
    }
    for (int dim = 0; dim < 4; dim++) {
        char what[32];
        snprintf(what, sizeof what, "number of %s entities", kind[dim]);
        if (read_i64(r, what, 0, INT_MAX, &count[dim]))
            return -1;
    }
    for (int dim = 0; dim < 4; dim++) {
        for (int64_t i = 0; i < count[dim]; i++) {
            int64_t tag, nphys, nbound;
            double box;
            r->item = NULL;
            if (read_i64(r, "entity tag", INT64_MIN + 1, INT64_MAX, &tag))
                return -1;
            r->item = kind[dim];
            r->item_tag = tag;
            if (partitioned) {
                if (read_i64(r, "parent dimension", 0, 3, &dummy) ||
                    read_i64(r, "parent tag", INT64_MIN + 1, INT64_MAX, &dummy) ||
                    read_i64(r, "number of partitions", 0, INT_MAX, &n))
                    return -1;
                for (int64_t k = 0; k < n; k++)
                    if (read_i64(r, "partition tag", INT_MIN, INT_MAX, &dummy))
                        return -1;
            }
            for (int k = 0; k < (dim == 0 ? 3 : 6); k++)
                if (read_double(r, "bounding box coordinate", &box))
                    return -1;
            if (read_i64(r, "number of physical tags", 0, INT_MAX, &nphys))
                return -1;
            int64_t first = 0;
            for (int64_t k = 0; k < nphys; k++) {
                if (read_i64(r, "physical tag", INT_MIN, INT_MAX, &dummy))
                    return -1;
                if (k == 0)
                    first = dummy;
            }
            if (dim > 0) {
                if (read_i64(r, "number of bounding entities", 0, INT_MAX, &nbound))
                    return -1;
                for (int64_t k = 0; k < nbound; k++)
                    if (read_i64(r, "bounding entity tag", INT64_MIN + 1, INT64_MAX, &dummy))
                        return -1;
            }
            if (dim == 3) {
                if (first < 0)
                    return READ_FAIL(r, r->line, "volume %lld has a negative physical tag %lld",
                                     (long long)tag, (long long)first);
                if (grow((void **)&d->volumes, &d->volume_cap, d->volume_count + 1,
                         sizeof(VolumeEntity)))
                    return READ_FAIL(r, r->line, "out of memory");
                d->volumes[d->volume_count++] = (VolumeEntity){tag, first};
            }
        }
    }
    r->item = NULL;
    return expect_end(r, partitioned ? "$EndPartitionedEntities" : "$EndEntities");
}

static int read_nodes41(MshReader *r, MshData *d, int header_line)
{
    int64_t blocks, declared, min_tag, max_tag;
    if (read_i64(r, "number of node blocks", 0, INT_MAX, &blocks) ||
        read_i64(r, "number of nodes", 0, INT_MAX, &declared) ||
        read_i64(r, "minimum node tag", 0, INT64_MAX, &min_tag) ||
        read_i64(r, "maximum node tag", 0, INT64_MAX, &max_tag))
        return -1;
    if (grow((void **)&d->nodes, &d->node_cap, plausible(r, declared, 8), sizeof(RawNode)))
        return READ_FAIL(r, header_line, "out of memory");
    int64_t total = 0;
    for (int64_t b = 0; b < blocks; b++) {
        int64_t dim, entity, parametric, n;
        r->item = "node block";
        r->item_tag = b + 1;
        if (read_i64(r, "entity dimension", 0, 3, &dim) ||
            read_i64(r, "entity tag", INT64_MIN + 1, INT64_MAX, &entity) ||
            read_i64(r, "parametric flag", 0, 1, &parametric) ||
            read_i64(r, "number of nodes in block", 0, INT_MAX, &n))
            return -1;
        if (parametric)
            return READ_FAIL(r, r->line,
                             "node block %lld has parametric coordinates, which are not supported "
                             "(Gmsh: Mesh.SaveParametric = 0)",
                             (long long)(b + 1));
        size_t first = d->node_count;
        for (int64_t i = 0; i < n; i++) {
            int64_t tag;
            if (read_i64(r, "node tag", 1, INT64_MAX, &tag) || push_node(r, d, tag, r->line))
                return -1;
        }
        r->item = "node";
        for (int64_t i = 0; i < n; i++) {
            RawNode *nd = &d->nodes[first + (size_t)i];
            r->item_tag = nd->tag;
            if (read_double(r, "x coordinate", &nd->x[0]) ||
                read_double(r, "y coordinate", &nd->x[1]) ||
                read_double(r, "z coordinate", &nd->x[2]))
                return -1;
        }
        total += n;
    }
    r->item = NULL;
    if (total != declared)
        return READ_FAIL(r, header_line, "$Nodes declares %lld nodes but its blocks hold %lld",
                         (long long)declared, (long long)total);
    return expect_end(r, "$EndNodes");
}

static int read_nodes22(MshReader *r, MshData *d, int header_line)
{
    int64_t n;
    if (read_i64(r, "number of nodes", 0, INT_MAX, &n))
        return -1;
    if (grow((void **)&d->nodes, &d->node_cap, plausible(r, n, 8), sizeof(RawNode)))
        return READ_FAIL(r, header_line, "out of memory");
    for (int64_t i = 0; i < n; i++) {
        int64_t tag;
        r->item = NULL;
        if (read_i64(r, "node tag", 1, INT64_MAX, &tag) || push_node(r, d, tag, r->line))
            return -1;
        RawNode *nd = &d->nodes[d->node_count - 1];
        r->item = "node";
        r->item_tag = tag;
        if (read_double(r, "x coordinate", &nd->x[0]) ||
            read_double(r, "y coordinate", &nd->x[1]) || read_double(r, "z coordinate", &nd->x[2]))
            return -1;
    }
    r->item = NULL;
    return expect_end(r, "$EndNodes");
}

/* Reads the node tags of one element; a tet's go to out, others are checked and dropped. */
static int read_element_nodes(MshReader *r, int count, int64_t *out)
{
    for (int k = 0; k < count; k++) {
        int64_t tag;
        if (read_i64(r, "node tag", 1, INT64_MAX, &tag))
            return -1;
        if (out)
            out[k] = tag;
    }
    return 0;
}

static int read_elements41(MshReader *r, MshData *d, int header_line)
{
    int64_t blocks, declared, min_tag, max_tag;
    if (read_i64(r, "number of element blocks", 0, INT_MAX, &blocks) ||
        read_i64(r, "number of elements", 0, INT64_MAX, &declared) ||
        read_i64(r, "minimum element tag", 0, INT64_MAX, &min_tag) ||
        read_i64(r, "maximum element tag", 0, INT64_MAX, &max_tag))
        return -1;
    int64_t total = 0;
    for (int64_t b = 0; b < blocks; b++) {
        int64_t dim, entity, type, n;
        r->item = "element block";
        r->item_tag = b + 1;
        if (read_i64(r, "entity dimension", 0, 3, &dim) ||
            read_i64(r, "entity tag", INT64_MIN + 1, INT64_MAX, &entity) ||
            read_i64(r, "element type", 1, INT_MAX, &type) ||
            read_i64(r, "number of elements in block", 0, INT64_MAX, &n))
            return -1;
        int nn = gmsh_nodes_per_element(type);
        if (nn == 0)
            return READ_FAIL(r, r->line, "element block %lld has unknown element type %lld",
                             (long long)(b + 1), (long long)type);
        if (type == 4 && grow((void **)&d->tets, &d->tet_cap, d->tet_count + plausible(r, n, 10),
                              sizeof(RawTet)))
            return READ_FAIL(r, r->line, "out of memory");
        for (int64_t i = 0; i < n; i++) {
            RawTet t = {0};
            r->item = NULL;
            if (read_i64(r, "element tag", 1, INT64_MAX, &t.tag))
                return -1;
            t.line = r->line;
            r->item = "element";
            r->item_tag = t.tag;
            if (read_element_nodes(r, nn, type == 4 ? t.node : NULL))
                return -1;
            if (type != 4) {
                note_skipped_type(d, type);
                continue;
            }
            t.group_kind = dim == 3 ? GROUP_ENTITY : GROUP_NONE;
            t.group = entity;
            if (push_tet(r, d, &t))
                return -1;
        }
        total += n;
    }
    r->item = NULL;
    if (total != declared)
        return READ_FAIL(r, header_line,
                         "$Elements declares %lld elements but its blocks hold %lld",
                         (long long)declared, (long long)total);
    return expect_end(r, "$EndElements");
}

static int read_elements22(MshReader *r, MshData *d)
{
    int64_t n;
    if (read_i64(r, "number of elements", 0, INT64_MAX, &n))
        return -1;
    for (int64_t i = 0; i < n; i++) {
        RawTet t = {0};
        int64_t type, ntags;
        r->item = NULL;
        if (read_i64(r, "element tag", 1, INT64_MAX, &t.tag))
            return -1;
        t.line = r->line;
        r->item = "element";
        r->item_tag = t.tag;
        if (read_i64(r, "element type", 1, INT_MAX, &type) ||
            read_i64(r, "number of tags", 0, 1000, &ntags))
            return -1;
        int nn = gmsh_nodes_per_element(type);
        if (nn == 0)
            return READ_FAIL(r, r->line, "element %lld has unknown element type %lld",
                             (long long)t.tag, (long long)type);
        for (int64_t k = 0; k < ntags; k++) {
            int64_t tag;
            if (read_i64(r, k == 0 ? "physical tag" : "element tag list entry", INT_MIN, INT_MAX,
                         &tag))
                return -1;
            if (k == 0) {
                t.group = tag;
                t.group_kind = GROUP_PHYSICAL;
            }
        }
        if (read_element_nodes(r, nn, type == 4 ? t.node : NULL))
            return -1;
        if (type != 4) {
            note_skipped_type(d, type);
            continue;
        }
        if (t.group < 0)
            return READ_FAIL(r, t.line, "element %lld has a negative physical tag %lld",
                             (long long)t.tag, (long long)t.group);
        if (push_tet(r, d, &t))
            return -1;
    }
    r->item = NULL;
    return expect_end(r, "$EndElements");
}

static int parse_msh(MshReader *r, MshData *d)
{
    MshTok t;
    char shown[48];
    while (next_tok(r, &t)) {
        r->section = "the file";
        r->item = NULL;
        if (d->version == 0 && !tok_is(&t, "$MeshFormat"))
            return READ_FAIL(r, t.line,
                             "not a Gmsh MSH file: found '%s' where $MeshFormat should be",
                             tok_show(&t, shown));
        if (t.n < 2 || t.s[0] != '$' || t.n > 60)
            return READ_FAIL(r, t.line, "expected a section header such as $Nodes, found '%s'",
                             tok_show(&t, shown));
        char name[64];
        memcpy(name, t.s + 1, t.n - 1);
        name[t.n - 1] = '\0';
        if (strncmp(name, "End", 3) == 0)
            return READ_FAIL(r, t.line, "'%s' without a matching $%s", tok_show(&t, shown),
                             name + 3);
        int rc;
        if (strcmp(name, "MeshFormat") == 0) {
            if (d->version != 0)
                return READ_FAIL(r, t.line, "second $MeshFormat section");
            rc = read_format(r, d);
        } else if (strcmp(name, "Nodes") == 0) {
            if (d->have_nodes)
                return READ_FAIL(r, t.line, "second $Nodes section");
            d->have_nodes = true;
            r->section = "$Nodes";
            rc = d->version == 41 ? read_nodes41(r, d, t.line) : read_nodes22(r, d, t.line);
        } else if (strcmp(name, "Elements") == 0) {
            if (d->have_elements)
                return READ_FAIL(r, t.line, "second $Elements section");
            d->have_elements = true;
            d->elements_line = t.line;
            r->section = "$Elements";
            rc = d->version == 41 ? read_elements41(r, d, t.line) : read_elements22(r, d);
        } else if (strcmp(name, "Entities") == 0 && d->version == 41) {
            rc = read_entities41(r, d, false);
        } else if (strcmp(name, "PartitionedEntities") == 0 && d->version == 41) {
            rc = read_entities41(r, d, true);
        } else {
            rc = skip_section(r, name);
        }
        if (rc)
            return -1;
    }
    if (d->version == 0)
        return READ_FAIL(r, eof_line(r), "not a Gmsh MSH file (no $MeshFormat section)");
    return 0;
}

/* ---------------------------------------------------------------------------------------------
 * Reading: building and validating the mesh
 * ------------------------------------------------------------------------------------------- */

static int cmp_node(const void *a, const void *b)
{
    const RawNode *p = a, *q = b;
    if (p->tag != q->tag)
        return p->tag < q->tag ? -1 : 1;
    return (p->line > q->line) - (p->line < q->line);
}

static int cmp_tet(const void *a, const void *b)
{
    const RawTet *p = a, *q = b;
    if (p->tag != q->tag)
        return p->tag < q->tag ? -1 : 1;
    return (p->line > q->line) - (p->line < q->line);
}

static int cmp_volume(const void *a, const void *b)
{
    const VolumeEntity *p = a, *q = b;
    return (p->tag > q->tag) - (p->tag < q->tag);
}

/* Dense index of a node tag (its rank among the sorted tags), or -1. */
static int find_node(const MshData *d, int64_t tag)
{
    size_t lo = 0, hi = d->node_count;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (d->nodes[mid].tag < tag)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo < d->node_count && d->nodes[lo].tag == tag ? (int)lo : -1;
}

static int64_t volume_physical(const MshData *d, int64_t entity)
{
    size_t lo = 0, hi = d->volume_count;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (d->volumes[mid].tag < entity)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo < d->volume_count && d->volumes[lo].tag == entity ? d->volumes[lo].physical : 0;
}

static int no_tets_error(const MshReader *r, const MshData *d)
{
    int line = d->have_elements ? d->elements_line : eof_line(r);
    const char *where = d->have_elements ? "" : " (no $Elements section)";
    if (d->high_order_tets > 0)
        return READ_FAIL(r, line,
                         "no tetrahedra (element type 4) in the file, but %lld higher-order "
                         "tetrahedra: mesh with element order 1 (Gmsh: -order 1)",
                         (long long)d->high_order_tets);
    if (d->other_volume_elems > 0)
        return READ_FAIL(r, line,
                         "no tetrahedra (element type 4) in the file; its %lld hexahedra, prisms "
                         "or pyramids are not supported",
                         (long long)d->other_volume_elems);
    return READ_FAIL(r, line, "no tetrahedra (element type 4) in the file%s", where);
}

typedef struct TetKey {
    int v[4]; /* sorted nodes */
    int tet;
} TetKey;

static int cmp_tet_key(const void *a, const void *b)
{
    const TetKey *p = a, *q = b;
    for (int k = 0; k < 4; k++)
        if (p->v[k] != q->v[k])
            return p->v[k] < q->v[k] ? -1 : 1;
    return (p->tet > q->tet) - (p->tet < q->tet);
}

/* Gmsh 2.2 writes an element once for each physical group it is in, each time under a new tag.
 * Copies with different physical tags are dropped, keeping the lowest tag, as 4.1 keeps an
 * entity's first physical tag; any other repeated tet is an error. Compacts tn, region and
 * d->tets, and updates *nt. */
static int drop_copies(const MshReader *r, MshData *d, int *tn, int *region, int *nt)
{
    int n = *nt, rc = 0;
    TetKey *key = malloc((size_t)n * sizeof *key);
    unsigned char *drop = calloc((size_t)n, 1);
    if (!key || !drop) {
        free(key);
        free(drop);
        return READ_FAIL(r, d->elements_line, "out of memory");
    }
    for (int t = 0; t < n; t++) {
        int *v = key[t].v;
        memcpy(v, &tn[4 * t], sizeof key[t].v);
        for (int i = 1; i < 4; i++) /* insertion sort */
            for (int j = i; j > 0 && v[j - 1] > v[j]; j--) {
                int s = v[j];
                v[j] = v[j - 1];
                v[j - 1] = s;
            }
        key[t].tet = t;
    }
    qsort(key, (size_t)n, sizeof *key, cmp_tet_key);
    for (int i = 1; i < n && rc == 0; i++) {
        if (memcmp(key[i].v, key[i - 1].v, sizeof key[i].v) != 0)
            continue;
        const RawTet *a = &d->tets[key[i - 1].tet], *b = &d->tets[key[i].tet];
        if (d->version == 22 && (a->group_kind != b->group_kind || a->group != b->group))
            drop[key[i].tet] = 1;
        else
            rc = READ_FAIL(r, b->line, "elements %lld and %lld are the same tetrahedron",
                           (long long)a->tag, (long long)b->tag);
    }
    int k = 0;
    for (int t = 0; t < n && rc == 0; t++) {
        if (drop[t])
            continue;
        memmove(&tn[4 * k], &tn[4 * t], 4 * sizeof *tn);
        region[k] = region[t];
        d->tets[k++] = d->tets[t];
    }
    if (rc == 0)
        *nt = (int)(d->tet_count = (size_t)k);
    free(key);
    free(drop);
    return rc;
}

/* A face of a tet, its nodes sorted; tet2 = 2 * tet + parity of the sort. */
typedef struct MshFace {
    int v[3];
    int tet2;
} MshFace;

static int cmp_face(const void *a, const void *b)
{
    const MshFace *p = a, *q = b;
    for (int k = 0; k < 3; k++)
        if (p->v[k] != q->v[k])
            return p->v[k] < q->v[k] ? -1 : 1;
    return (p->tet2 > q->tet2) - (p->tet2 < q->tet2);
}

/* Every face is shared by at most two tets, and two tets sharing a face lie on opposite sides
 * of it. The second catches overlapping tets that the boundary test cannot see. Runs after the
 * orientation test, so all tets are positive. */
static int check_faces(const MshReader *r, const MshData *d, const int *tn, int tet_count)
{
    /* outward-oriented faces of a positive tet (0,1,2,3), opposite vertex k */
    static const int out_face[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
    size_t nf = (size_t)tet_count * 4;
    MshFace *f = malloc(nf * sizeof *f);
    if (!f)
        return READ_FAIL(r, d->elements_line, "out of memory");
    for (int t = 0; t < tet_count; t++) {
        for (int k = 0; k < 4; k++) {
            int a = tn[4 * t + out_face[k][0]], b = tn[4 * t + out_face[k][1]],
                c = tn[4 * t + out_face[k][2]], parity = 0, s;
            if (a > b)
                s = a, a = b, b = s, parity ^= 1;
            if (b > c)
                s = b, b = c, c = s, parity ^= 1;
            if (a > b)
                s = a, a = b, b = s, parity ^= 1;
            f[4 * t + k] = (MshFace){{a, b, c}, 2 * t + parity};
        }
    }
    qsort(f, nf, sizeof *f, cmp_face);
    int rc = 0;
    for (size_t i = 0; i < nf && rc == 0;) {
        size_t j = i + 1;
        while (j < nf && memcmp(f[i].v, f[j].v, sizeof f[i].v) == 0)
            j++;
        const RawTet *t0 = &d->tets[f[i].tet2 >> 1];
        long long a = (long long)d->nodes[f[i].v[0]].tag, b = (long long)d->nodes[f[i].v[1]].tag,
                  c = (long long)d->nodes[f[i].v[2]].tag;
        if (j - i > 2) {
            const RawTet *t1 = &d->tets[f[i + 1].tet2 >> 1], *t2 = &d->tets[f[i + 2].tet2 >> 1];
            rc = READ_FAIL(r, t2->line,
                           "the face with nodes %lld %lld %lld is shared by more than two "
                           "tetrahedra (elements %lld, %lld and %lld)",
                           a, b, c, (long long)t0->tag, (long long)t1->tag, (long long)t2->tag);
        } else if (j - i == 2 && (f[i].tet2 & 1) == (f[i + 1].tet2 & 1)) {
            const RawTet *t1 = &d->tets[f[i + 1].tet2 >> 1];
            rc = READ_FAIL(r, t1->line,
                           "elements %lld and %lld overlap: both lie on the same side of their "
                           "shared face with nodes %lld %lld %lld",
                           (long long)t0->tag, (long long)t1->tag, a, b, c);
        }
        i = j;
    }
    free(f);
    return rc;
}

static int boundary_error(const MshReader *r, const MshData *d, NsMesh *m)
{
    NsBoundaryStats st;
    if (ns_mesh_boundary(m, &st) < 0)
        return READ_FAIL(r, d->elements_line, "out of memory");
    if (st.closed && st.manifold)
        return 0;
    if (st.bad_edge[0] >= 0 && st.bad_edge[1] >= 0) {
        const RawNode *a = &d->nodes[st.bad_edge[0]], *b = &d->nodes[st.bad_edge[1]];
        return READ_FAIL(r, a->line,
                         "the boundary is not %s at the edge between nodes %lld and %lld "
                         "(tetrahedra touching only along this edge?)",
                         st.closed ? "manifold" : "closed", (long long)a->tag, (long long)b->tag);
    }
    if (st.bad_vertex >= 0) {
        const RawNode *a = &d->nodes[st.bad_vertex];
        return READ_FAIL(r, a->line,
                         "the boundary is not manifold at node %lld: its boundary faces form more "
                         "than one fan (tetrahedra touching only at this node?)",
                         (long long)a->tag);
    }
    return READ_FAIL(r, d->elements_line, "the boundary is not %s",
                     st.closed ? "manifold" : "closed");
}

static int build_mesh(const MshReader *r, MshData *d, NsMesh *m)
{
    if (d->tet_count == 0)
        return no_tets_error(r, d);

    if (d->node_count > 0) /* qsort(NULL, 0) is undefined */
        qsort(d->nodes, d->node_count, sizeof *d->nodes, cmp_node);
    for (size_t i = 1; i < d->node_count; i++)
        if (d->nodes[i].tag == d->nodes[i - 1].tag)
            return READ_FAIL(r, d->nodes[i].line,
                             "node tag %lld is defined twice (also on line %d)",
                             (long long)d->nodes[i].tag, d->nodes[i - 1].line);
    if (d->tet_count > 0)
        qsort(d->tets, d->tet_count, sizeof *d->tets, cmp_tet);
    for (size_t i = 1; i < d->tet_count; i++)
        if (d->tets[i].tag == d->tets[i - 1].tag)
            return READ_FAIL(r, d->tets[i].line,
                             "element tag %lld is defined twice (also on line %d)",
                             (long long)d->tets[i].tag, d->tets[i - 1].line);
    if (d->volume_count > 0)
        qsort(d->volumes, d->volume_count, sizeof *d->volumes, cmp_volume);

    int nt = (int)d->tet_count, nn = (int)d->node_count;
    int *tn = malloc((size_t)nt * 4 * sizeof *tn);
    int *region = malloc((size_t)nt * sizeof *region);
    unsigned char *used = calloc((size_t)nn + 1, 1);
    int rc = 0;
    if (!tn || !region || !used) {
        rc = READ_FAIL(r, d->elements_line, "out of memory");
        goto done;
    }

    for (int t = 0; t < nt && rc == 0; t++) {
        const RawTet *rt = &d->tets[t];
        const double *p[4];
        for (int k = 0; k < 4; k++) {
            int idx = find_node(d, rt->node[k]);
            if (idx < 0) {
                rc = READ_FAIL(r, rt->line,
                               "element %lld references node %lld, which is not defined in $Nodes",
                               (long long)rt->tag, (long long)rt->node[k]);
                break;
            }
            for (int j = 0; j < k && rc == 0; j++)
                if (tn[4 * t + j] == idx)
                    rc = READ_FAIL(r, rt->line,
                                   "element %lld is degenerate (node %lld appears twice)",
                                   (long long)rt->tag, (long long)rt->node[k]);
            if (rc)
                break;
            tn[4 * t + k] = idx;
            used[idx] = 1;
            p[k] = d->nodes[idx].x;
        }
        if (rc)
            break;
        int64_t phys = 0;
        if (rt->group_kind == GROUP_PHYSICAL)
            phys = rt->group;
        else if (rt->group_kind == GROUP_ENTITY)
            phys = volume_physical(d, rt->group);
        region[t] = phys > 0 ? (int)(phys - 1) : 0;
        double q = ns_tet_quality(p[0], p[1], p[2], p[3]);
        if (!(fabs(q) > NS_MSH_DEGENERATE_QUALITY))
            rc = READ_FAIL(r, rt->line,
                           "element %lld is degenerate (quality %.3g: its nodes are coplanar or "
                           "nearly so)",
                           (long long)rt->tag, q);
        else if (q < 0.0)
            rc = READ_FAIL(r, rt->line,
                           "element %lld is inverted (negative volume; swap two of its nodes)",
                           (long long)rt->tag);
    }
    if (rc == 0)
        rc = drop_copies(r, d, tn, region, &nt);
    for (int i = 0; i < nn && rc == 0; i++)
        if (!used[i])
            rc = READ_FAIL(r, d->nodes[i].line, "node %lld is not used by any tetrahedron",
                           (long long)d->nodes[i].tag);
    if (rc == 0)
        rc = check_faces(r, d, tn, nt);

    for (int i = 0; i < nn && rc == 0; i++)
        if (ns_mesh_add_node(m, d->nodes[i].x) != i)
            rc = READ_FAIL(r, d->nodes[i].line, "out of memory adding node %lld",
                           (long long)d->nodes[i].tag);
    for (int t = 0; t < nt && rc == 0; t++)
        if (ns_mesh_add_tet(m, &tn[4 * t], region[t]) != t)
            rc = READ_FAIL(r, d->tets[t].line,
                           "cannot add element %lld to the mesh (out of memory?)",
                           (long long)d->tets[t].tag);
    if (rc == 0)
        rc = boundary_error(r, d, m);
done:
    free(tn);
    free(region);
    free(used);
    return rc;
}

/* The whole file, NUL-terminated. Only a regular file, and at most NS_LIMIT_MESH_FILE_BYTES:
 * a device or a FIFO (ns.tissue.file{path = "/dev/zero"}) would otherwise be read until memory
 * ran out, or block. Opened non-blocking so that a FIFO is refused, not waited on; a file that
 * grows while it is read still stops at the limit. */
static int read_whole_file(const char *path, char **out, size_t *out_len, char *err, int err_sz)
{
    const size_t limit = (size_t)NS_LIMIT_MESH_FILE_BYTES;
    int fd = open(path, O_RDONLY | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0) {
        ns_set_err(err, err_sz, "%s: cannot open: %s", path, strerror(errno));
        return -1;
    }
    struct stat st;
    if (fstat(fd, &st) != 0) {
        ns_set_err(err, err_sz, "%s: cannot open: %s", path, strerror(errno));
        close(fd);
        return -1;
    }
    if (!S_ISREG(st.st_mode)) {
        ns_set_err(err, err_sz, "%s: cannot open: not a regular file%s", path,
                   S_ISDIR(st.st_mode) ? " (a directory)" : "");
        close(fd);
        return -1;
    }
    if (st.st_size < 0 || (unsigned long long)st.st_size > limit) {
        ns_set_err(err, err_sz, "%s: the file is %lld bytes; a mesh file may have at most %lld",
                   path, (long long)st.st_size, (long long)NS_LIMIT_MESH_FILE_BYTES);
        close(fd);
        return -1;
    }
    FILE *f = fdopen(fd, "rb");
    if (!f) {
        ns_set_err(err, err_sz, "%s: cannot open: %s", path, strerror(errno));
        close(fd);
        return -1;
    }
    /* The size as the first guess; then grow by half, never past one byte over the limit. */
    size_t cap = (size_t)st.st_size + 2, len = 0;
    char *buf = malloc(cap);
    for (;;) {
        if (buf && len + 1 >= cap && cap < limit + 2) {
            size_t c = cap + cap / 2 + 65536;
            if (c > limit + 2)
                c = limit + 2;
            char *p = realloc(buf, c);
            if (!p) {
                free(buf);
                buf = NULL;
            } else {
                buf = p;
                cap = c;
            }
        }
        if (!buf) {
            ns_set_err(err, err_sz, "%s: out of memory reading the file", path);
            fclose(f);
            return -1;
        }
        if (len + 1 >= cap)
            break; /* limit + 1 bytes read: too long */
        size_t got = fread(buf + len, 1, cap - len - 1, f);
        len += got;
        if (got == 0)
            break;
    }
    if (ferror(f)) {
        ns_set_err(err, err_sz, "%s: cannot read: %s", path, strerror(errno));
        free(buf);
        fclose(f);
        return -1;
    }
    fclose(f);
    if (len > limit) {
        ns_set_err(err, err_sz,
                   "%s: the file is longer than %lld bytes, the most a mesh file may have", path,
                   (long long)NS_LIMIT_MESH_FILE_BYTES);
        free(buf);
        return -1;
    }
    buf[len] = '\0';
    *out = buf;
    *out_len = len;
    return 0;
}

int ns_mesh_read_msh(const char *path, NsMesh *m, char *err, int err_sz)
{
    ns_mesh_init(m);
    char *buf;
    size_t len;
    if (read_whole_file(path, &buf, &len, err, err_sz))
        return -1;
    MshReader r = {.path = path,
                   .buf = buf,
                   .len = len,
                   .line = 1,
                   .section = "the file",
                   .err = err,
                   .err_sz = err_sz};
    MshData d = {0};
    int rc = parse_msh(&r, &d);
    if (rc == 0)
        rc = build_mesh(&r, &d, m);
    free(d.nodes);
    free(d.tets);
    free(d.volumes);
    free(buf);
    if (rc != 0) {
        /* no half-built mesh for the caller to misuse */
        ns_mesh_free(m);
        ns_mesh_init(m);
    }
    return rc;
}
