/* Snapshot streams (snapshot.h): bytes to and from memory or a file, arrays with their sizes,
 * a running checksum. */
#include "snapshot.h"

#include <stdarg.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

static const uint64_t FNV_OFFSET = 14695981039346656037ULL;
static const uint64_t FNV_PRIME = 1099511628211ULL;

/* The checksum takes a word at a time (a byte at a time was half the cost of a snapshot), the
 * same whatever the pieces the bytes come in. Each word changes the sum by a bijection, so a
 * stream that differs in one word has another sum. */
static uint64_t mix(uint64_t h, uint64_t w)
{
    return (h ^ w) * FNV_PRIME;
}

static void add_sum(NsPack *p, const unsigned char *b, size_t n)
{
    for (; n > 0 && p->ntail > 0; b++, n--) {
        p->tail |= (uint64_t)*b << (8 * p->ntail);
        if (++p->ntail == 8) {
            p->sum = mix(p->sum, p->tail);
            p->tail = 0;
            p->ntail = 0;
        }
    }
    uint64_t h = p->sum;
    for (; n >= 8; b += 8, n -= 8) {
        uint64_t w = 0;
        for (int k = 0; k < 8; k++)
            w |= (uint64_t)b[k] << (8 * k);
        h = mix(h, w);
    }
    p->sum = h;
    for (; n > 0; b++, n--)
        p->tail |= (uint64_t)*b << (8 * p->ntail++);
}

/* The sum of every byte so far, the unfinished word included. */
static uint64_t sum_now(const NsPack *p)
{
    return p->ntail > 0 ? mix(p->sum, p->tail) : p->sum;
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

/* A writer's array header: present, count, cap. Returns 0 or -1. */
static int write_header(NsPack *p, const void *ptr, size_t count, size_t cap)
{
    uint64_t hdr[3] = {ptr != NULL, ptr ? count : 0, ptr ? cap : 0};
    if (hdr[1] > hdr[2])
        return ns_pack_fail(p, "an array of %zu elements in an allocation of %zu", count, cap);
    return ns_pack_bytes(p, hdr, sizeof hdr);
}

int ns_pack_array(NsPack *p, void **ptr, size_t elem, size_t count, size_t cap)
{
    if (p->writing) {
        if (write_header(p, *ptr, count, cap) != 0)
            return -1;
        return *ptr ? ns_pack_bytes(p, *ptr, count * elem) : 0;
    }
    uint64_t hdr[3];
    *ptr = NULL;
    if (ns_pack_bytes(p, hdr, sizeof hdr) != 0)
        return -1;
    if (hdr[0] == 0)
        return hdr[1] == 0 && hdr[2] == 0 ? 0
                                          : ns_pack_fail(p, "bad array header at byte %zu", p->pos);
    if (hdr[0] != 1 || hdr[1] > hdr[2] || elem == 0 || hdr[2] > NS_PACK_MAX_BYTES / elem ||
        hdr[1] * elem > p->size - p->pos)
        return ns_pack_fail(p, "bad array header at byte %zu (%llu of %llu elements)", p->pos,
                            (unsigned long long)hdr[1], (unsigned long long)hdr[2]);
    /* The structure's own fields, read before, must agree: a damaged size is caught here,
     * before anything is indexed by it, not only by the checksum at the end. */
    if (hdr[1] != count || hdr[2] != cap)
        return ns_pack_fail(p,
                            "array at byte %zu: %llu of %llu elements where the structure says "
                            "%zu of %zu",
                            p->pos, (unsigned long long)hdr[1], (unsigned long long)hdr[2], count,
                            cap);
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

int ns_pack_array_blank(NsPack *p, void **ptr, size_t elem, size_t count, size_t cap,
                        void (*blank)(void *elem))
{
    if (!p->writing)
        return ns_pack_array(p, ptr, elem, count, cap);
    _Alignas(max_align_t) unsigned char copy[NS_PACK_MAX_ELEM];
    if (elem > sizeof copy)
        return ns_pack_fail(p, "elements of %zu bytes (at most %zu)", elem, sizeof copy);
    if (write_header(p, *ptr, count, cap) != 0)
        return -1;
    const unsigned char *a = *ptr;
    for (size_t i = 0; a && i < count && !p->failed; i++) {
        memcpy(copy, a + i * elem, elem);
        blank(copy);
        ns_pack_bytes(p, copy, elem);
    }
    return p->failed ? -1 : 0;
}

int ns_pack_struct(NsPack *p, const char tag[4], void *s, size_t size, void (*blank)(void *copy))
{
    if (!p->writing)
        memset(s, 0, size);
    ns_pack_tag(p, tag);
    if (!p->writing)
        return ns_pack_bytes(p, s, size);
    _Alignas(max_align_t) unsigned char copy[NS_PACK_MAX_STRUCT];
    if (size > sizeof copy)
        return ns_pack_fail(p, "a structure of %zu bytes (at most %zu)", size, sizeof copy);
    memcpy(copy, s, size);
    blank(copy);
    return ns_pack_bytes(p, copy, size);
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
    uint64_t sum = sum_now(p);
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
