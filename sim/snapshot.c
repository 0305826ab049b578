/* Snapshot streams (snapshot.h): bytes to and from memory or a file, arrays with their sizes,
 * a running checksum. */
#include "snapshot.h"

#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

#include "coupling.h"
#include "mesh.h"
#include "remesh.h"
#include "rod.h"
#include "tissue.h"

static const uint64_t FNV_OFFSET = 14695981039346656037ULL;
static const uint64_t FNV_PRIME = 1099511628211ULL;

static void add_sum(NsPack *p, const unsigned char *b, size_t n)
{
    uint64_t h = p->sum;
    for (size_t i = 0; i < n; i++) {
        h ^= b[i];
        h *= FNV_PRIME;
    }
    p->sum = h;
}

void ns_pack_writer(NsPack *p, FILE *f)
{
    memset(p, 0, sizeof *p);
    p->writing = true;
    p->f = f;
    p->sum = FNV_OFFSET;
}

void ns_pack_reader(NsPack *p, FILE *f, const void *buf, size_t size)
{
    memset(p, 0, sizeof *p);
    p->f = f;
    p->buf = (unsigned char *)(uintptr_t)buf;
    p->size = size;
    p->sum = FNV_OFFSET;
}

void ns_pack_free(NsPack *p)
{
    if (p->writing && !p->f)
        free(p->buf);
    p->buf = NULL;
    p->len = p->cap = 0;
}

int ns_pack_fail(NsPack *p, const char *fmt, ...)
{
    if (!p->failed) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(p->err, sizeof p->err, fmt, ap);
        va_end(ap);
        p->failed = true;
    }
    return -1;
}

int ns_pack_bytes(NsPack *p, void *data, size_t n)
{
    if (p->failed)
        return -1;
    if (n == 0)
        return 0;
    if (p->writing) {
        if (p->f) {
            if (fwrite(data, 1, n, p->f) != n)
                return ns_pack_fail(p, "write failed");
        } else {
            if (p->len + n > p->cap) {
                size_t cap = p->cap ? p->cap : 1 << 16;
                while (cap < p->len + n)
                    cap *= 2;
                unsigned char *nb = realloc(p->buf, cap);
                if (!nb)
                    return ns_pack_fail(p, "out of memory (%zu bytes)", cap);
                p->buf = nb;
                p->cap = cap;
            }
            memcpy(p->buf + p->len, data, n);
            p->len += n;
        }
        add_sum(p, data, n);
    } else {
        if (n > p->size - p->pos)
            return ns_pack_fail(p, "truncated at byte %zu (%zu more wanted, %zu left)", p->pos, n,
                                p->size - p->pos);
        if (p->f) {
            if (fread(data, 1, n, p->f) != n)
                return ns_pack_fail(p, "read failed at byte %zu", p->pos);
        } else {
            memcpy(data, p->buf + p->pos, n);
        }
        add_sum(p, data, n);
    }
    p->pos += n;
    return 0;
}

int ns_pack_array(NsPack *p, void **ptr, size_t elem, size_t count, size_t cap)
{
    uint64_t hdr[3] = {*ptr != NULL, count, cap}; /* present, count, cap */
    if (p->writing) {
        if (*ptr == NULL)
            hdr[1] = hdr[2] = 0;
        if (hdr[1] > hdr[2])
            return ns_pack_fail(p, "an array of %zu elements in an allocation of %zu", count, cap);
        if (ns_pack_bytes(p, hdr, sizeof hdr) != 0)
            return -1;
        return *ptr ? ns_pack_bytes(p, *ptr, count * elem) : 0;
    }
    *ptr = NULL;
    if (ns_pack_bytes(p, hdr, sizeof hdr) != 0)
        return -1;
    if (hdr[0] == 0)
        return hdr[1] == 0 && hdr[2] == 0 ? 0 : ns_pack_fail(p, "bad array header at byte %zu", p->pos);
    if (hdr[0] != 1 || hdr[1] > hdr[2] || elem == 0 || hdr[2] > NS_PACK_MAX_BYTES / elem ||
        hdr[1] * elem > p->size - p->pos)
        return ns_pack_fail(p, "bad array header at byte %zu (%llu of %llu elements)", p->pos,
                            (unsigned long long)hdr[1], (unsigned long long)hdr[2]);
    size_t bytes = (size_t)hdr[2] * elem;
    if (bytes > NS_PACK_MAX_BYTES - p->allocated)
        return ns_pack_fail(p, "more than %zu GiB in all", NS_PACK_MAX_BYTES >> 30);
    void *a = calloc(hdr[2] ? (size_t)hdr[2] : 1, elem);
    if (!a)
        return ns_pack_fail(p, "out of memory (%zu bytes)", bytes);
    p->allocated += bytes;
    *ptr = a;
    return ns_pack_bytes(p, a, (size_t)hdr[1] * elem);
}

void *ns_pack_object(NsPack *p, void **obj, size_t size, const char *what)
{
    uint8_t present = *obj != NULL;
    if (ns_pack_bytes(p, &present, 1) != 0 || p->writing)
        return p->failed ? NULL : *obj;
    *obj = NULL;
    if (present > 1)
        ns_pack_fail(p, "%s: bad header at byte %zu", what, p->pos - 1);
    else if (present && size > NS_PACK_MAX_BYTES - p->allocated)
        ns_pack_fail(p, "%s: more than %zu GiB in all", what, NS_PACK_MAX_BYTES >> 30);
    else if (present && !(*obj = calloc(1, size)))
        ns_pack_fail(p, "%s: out of memory (%zu bytes)", what, size);
    else
        p->allocated += present ? size : 0;
    return *obj;
}

int ns_pack_scalars(NsPack *p, void *obj, size_t size, void (*forget)(void *))
{
    if (!p->writing) {
        ns_pack_bytes(p, obj, size);
        forget(obj);
        return p->failed ? -1 : 0;
    }
    void *copy = malloc(size ? size : 1);
    if (!copy)
        return ns_pack_fail(p, "out of memory (%zu bytes)", size);
    memcpy(copy, obj, size);
    forget(copy);
    int rc = ns_pack_bytes(p, copy, size);
    free(copy);
    return rc;
}

int ns_pack_checksum(NsPack *p)
{
    uint64_t sum = p->sum;
    uint64_t v = sum;
    if (ns_pack_bytes(p, &v, sizeof v) != 0)
        return -1;
    if (!p->writing && v != sum)
        return ns_pack_fail(p, "checksum mismatch (the file is damaged)");
    return 0;
}

int ns_pack_tag(NsPack *p, const char tag[4])
{
    char t[4];
    memcpy(t, tag, 4);
    if (ns_pack_bytes(p, t, 4) != 0)
        return -1;
    if (!p->writing && memcmp(t, tag, 4) != 0)
        return ns_pack_fail(p, "expected section '%.4s' at byte %zu", tag, p->pos - 4);
    return 0;
}

uint64_t ns_pack_fingerprint(void)
{
    const size_t sizes[] = {sizeof(NsMesh),    sizeof(NsTissue),     sizeof(NsTissueParams),
                            sizeof(NsRod),     sizeof(NsRodParams),  sizeof(NsCoupled),
                            sizeof(NsCouplingParams), sizeof(NsRemeshStack), sizeof(NsRemeshOp),
                            sizeof(NsBlockMatrix), sizeof(NsBanded), sizeof(void *)};
    uint64_t h = FNV_OFFSET;
    const unsigned char *b = (const unsigned char *)sizes;
    for (size_t i = 0; i < sizeof sizes; i++) {
        h ^= b[i];
        h *= FNV_PRIME;
    }
    return h;
}
