/* A stack arena for one step's scratch memory: blocks are pushed and popped in order (last in,
 * first out), and the arena is empty between steps (ns_step asserts it). One buffer serves
 * every step; a push that does not fit is served by malloc for this step only, and the buffer
 * grows to the step's peak once the arena is empty again (ns_arena_grow), so a step whose sizes
 * do not grow allocates nothing. */
#ifndef NS_ARENA_H
#define NS_ARENA_H

#include <stddef.h>

#define NS_ARENA_MAX_DEPTH 64 /* blocks live at once */
#define NS_ARENA_ALIGN     64 /* bytes: a cache line, and enough for any scalar or vector type */

typedef struct NsArena {
    unsigned char *base;
    size_t cap;  /* bytes of base */
    size_t top;  /* bytes of base in use */
    size_t need; /* bytes the blocks live now would take in base (spilled ones included) */
    size_t peak; /* the most need reached */
    int depth;   /* blocks live */
    size_t size[NS_ARENA_MAX_DEPTH]; /* each live block's bytes (aligned) */
    void *spill[NS_ARENA_MAX_DEPTH]; /* each live block's malloc'd memory, NULL if in base */
    long spills;                     /* pushes served by malloc, all told (0 in a steady state) */
} NsArena;

void ns_arena_init(NsArena *a);
void ns_arena_free(NsArena *a);
/* A block of n bytes (aligned to NS_ARENA_ALIGN), or NULL (out of memory, or more than
 * NS_ARENA_MAX_DEPTH live). Uninitialized. */
void *ns_arena_push(NsArena *a, size_t n);
/* The same, zeroed. */
void *ns_arena_push_zero(NsArena *a, size_t n);
/* Pops the last block pushed, p (NULL: nothing, for a push that failed). */
void ns_arena_pop(NsArena *a, void *p);
/* The live blocks now; ns_arena_reset pops back to such a mark. */
int ns_arena_mark(const NsArena *a);
void ns_arena_reset(NsArena *a, int mark);
/* With the arena empty: the buffer grown to the peak of the blocks since the last call, so the
 * next step of the same sizes fits. Returns 0, or -1 (out of memory: the arena still works). */
int ns_arena_grow(NsArena *a);

#endif
