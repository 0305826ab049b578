/* The step's stack arena (sim/arena.h). */
#include "arena.h"

#include <assert.h>
#include <stdlib.h>
#include <string.h>

void ns_arena_init(NsArena *a)
{
    memset(a, 0, sizeof *a);
}

void ns_arena_free(NsArena *a)
{
    ns_arena_reset(a, 0);
    free(a->base);
    memset(a, 0, sizeof *a);
}

void *ns_arena_push(NsArena *a, size_t n)
{
    if (a->depth >= NS_ARENA_MAX_DEPTH)
        return NULL;
    size_t sz = (n + NS_ARENA_ALIGN - 1) / NS_ARENA_ALIGN * NS_ARENA_ALIGN;
    if (sz == 0)
        sz = NS_ARENA_ALIGN;
    void *p = NULL, *spill = NULL;
    if (a->base && a->top + sz <= a->cap) {
        p = a->base + a->top;
        a->top += sz;
    } else {
        spill = p = aligned_alloc(NS_ARENA_ALIGN, sz);
        if (!p)
            return NULL;
        a->spills++;
    }
    a->size[a->depth] = sz;
    a->spill[a->depth] = spill;
    a->depth++;
    a->need += sz;
    if (a->need > a->peak)
        a->peak = a->need;
    return p;
}

void *ns_arena_push_zero(NsArena *a, size_t n)
{
    void *p = ns_arena_push(a, n);
    if (p)
        memset(p, 0, n);
    return p;
}

void ns_arena_pop(NsArena *a, void *p)
{
    if (!p)
        return;
    assert(a->depth > 0);
    int d = --a->depth;
    a->need -= a->size[d];
    if (a->spill[d]) {
        assert(a->spill[d] == p);
        free(a->spill[d]);
        a->spill[d] = NULL;
    } else {
        a->top -= a->size[d];
        assert(a->base + a->top == (unsigned char *)p);
    }
}

int ns_arena_mark(const NsArena *a)
{
    return a->depth;
}

void ns_arena_reset(NsArena *a, int mark)
{
    while (a->depth > mark) {
        int d = a->depth - 1;
        ns_arena_pop(a, a->spill[d] ? a->spill[d] : a->base + a->top - a->size[d]);
    }
}

int ns_arena_grow(NsArena *a)
{
    assert(a->depth == 0);
    if (a->peak <= a->cap)
        return 0;
    unsigned char *b = aligned_alloc(NS_ARENA_ALIGN, a->peak);
    if (!b)
        return -1;
    free(a->base);
    a->base = b;
    a->cap = a->peak;
    a->top = 0;
    return 0;
}
