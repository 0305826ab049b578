/* Snapshots of the simulated world (docs/checkpoints.md): every byte of state the step reads,
 * caches included, written to a stream and read back, so that a world restored from a snapshot
 * steps on bit for bit as the original would have.
 *
 * One function per structure serves both ways (ns_tissue_pack, ns_rod_pack, ns_coupled_pack,
 * ns_solver_pack, ...): with a writer it writes the structure, with a reader it fills a
 * structure from nothing. The structure's own bytes go first, whole (its scalars; its pointers
 * written as NULL, so that a world and its restored copy write the same bytes); then every
 * pointer it owns is packed as an array (NS_PACK_ARRAY), which on reading replaces the NULL the
 * bytes carried; pointers it does not own (borrowed, per-step scratch views) are set by the
 * reader. A snapshot is only read by the build that wrote it (ns_pack_fingerprint).
 *
 * The stream is a memory buffer (the planner's in-memory snapshots) or a file (checkpoints).
 * Reading checks what it can without knowing the structures: every array's size against the
 * bytes left and a budget for the whole snapshot, and the stream's checksum at the end; a
 * snapshot is trusted for what it says beyond that (a checkpoint is needlesim's own file). */
#ifndef NS_SNAPSHOT_H
#define NS_SNAPSHOT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

typedef struct NsPack {
    bool writing;
    FILE *f;            /* the file, or NULL: the memory buffer */
    unsigned char *buf; /* memory: the bytes (owned by a writer; a reader's are borrowed) */
    size_t len, cap;    /* memory: bytes in buf, allocated */
    size_t pos;         /* bytes read or written so far */
    size_t size;        /* reading: the stream's length (file or buffer) */
    size_t allocated;   /* reading: bytes allocated for arrays so far */
    uint64_t sum;       /* FNV-1a 64 over the 8-byte words so far (little-endian) */
    uint64_t tail;      /* the bytes after the last whole word (ntail of them) */
    int ntail;
    bool failed;
    char err[256]; /* the first failure */
} NsPack;

/* A writer into f, or into memory (f NULL; the bytes are p->buf[0 .. p->len), freed by
 * ns_pack_free). */
void ns_pack_writer(NsPack *p, FILE *f);
/* A reader of f (size: its length in bytes), or of the memory buf[0 .. size) when f is NULL. */
void ns_pack_reader(NsPack *p, FILE *f, const void *buf, size_t size);
void ns_pack_free(NsPack *p);

/* n bytes at data, written or read. Returns 0, or -1 (p->failed, p->err; later calls do
 * nothing). */
int ns_pack_bytes(NsPack *p, void *data, size_t n);
/* An owned array at *ptr of count elements of elem bytes, in an allocation of cap elements
 * (cap >= count; a reader allocates cap, zeroed, and reads count; *ptr NULL is packed as NULL).
 * A reader passes the count and cap its structure's fields (already read) give, and a stream
 * that says otherwise is refused. Returns 0 or -1. */
int ns_pack_array(NsPack *p, void **ptr, size_t elem, size_t count, size_t cap);
/* The same for an array of structures that hold pointers: a writer writes each element through
 * blank (called on a copy; it sets the element's pointers NULL), so that equal worlds write equal
 * bytes. elem at most NS_PACK_MAX_ELEM. */
#define NS_PACK_MAX_ELEM 256
int ns_pack_array_blank(NsPack *p, void **ptr, size_t elem, size_t count, size_t cap,
                        void (*blank)(void *elem));
/* An owned structure at *obj (NULL allowed): whether there is one, written or read; a reader
 * allocates it (size bytes, zeroed) for its fields to be read into (what: its name in the
 * messages). Returns the structure, or NULL (none, or a failure). */
void *ns_pack_object(NsPack *p, void **obj, size_t size, const char *what);
/* A structure's own bytes (size at obj): a writer writes a copy whose pointers forget cleared
 * (a snapshot holds no addresses); a reader reads them and clears them the same way (its
 * arrays are read next). Returns 0 or -1. */
int ns_pack_scalars(NsPack *p, void *obj, size_t size, void (*forget)(void *));
/* The failure "what: detail" (the first one sticks); returns -1. */
int ns_pack_fail(NsPack *p, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 2, 3)))
#endif
    ;
/* A structure's own bytes (size), after its tag: a writer writes them through blank (called on
 * a copy; it sets the pointers NULL and empties embedded structures that pack themselves); a
 * reader zeroes the structure, then reads them. size at most NS_PACK_MAX_STRUCT. Returns 0 or
 * -1. */
#define NS_PACK_MAX_STRUCT 8192
int ns_pack_struct(NsPack *p, const char tag[4], void *s, size_t size, void (*blank)(void *copy));
/* Writes the checksum of everything so far, or reads it and compares. Returns 0 or -1. */
int ns_pack_checksum(NsPack *p);
/* Writes tag (4 bytes) or reads it and compares: a check that both sides agree on where a
 * structure starts. Returns 0 or -1. */
int ns_pack_tag(NsPack *p, const char tag[4]);

/* The layout of the structures snapshots hold, as a hash of their sizes: a snapshot written by
 * a build whose structures differ is refused. sim/world.c, as the world's functions below. */
uint64_t ns_pack_fingerprint(void);

/* ---- The structures' pack functions, each in its structure's file. Writing reads the
 * structure; reading fills it from nothing, and even after a failure leaves every pointer it
 * owns NULL or allocated, so the structure's free function can be called on it. They never
 * return early: every field is packed (a failed stream does nothing), and they return
 * p->failed ? -1 : 0. */
struct NsMesh;
struct NsBlockMatrix;
struct NsBanded;
struct NsTissue;
struct NsRod;
struct NsNeedlePath;
struct NsRemeshStack;
struct NsSolver;
struct NsCoupled;
struct NsArena;
int ns_mesh_pack(NsPack *p, struct NsMesh *m);                 /* sim/mesh.c */
int ns_block_matrix_pack(NsPack *p, struct NsBlockMatrix *A);  /* sim/sparse.c */
int ns_banded_pack(NsPack *p, struct NsBanded *B);             /* sim/banded.c */
int ns_tissue_pack(NsPack *p, struct NsTissue *t);             /* sim/tissue.c */
int ns_rod_pack(NsPack *p, struct NsRod *r);                   /* sim/rod.c */
int ns_needle_path_pack(NsPack *p, struct NsNeedlePath *path); /* sim/needle_path.c */
/* The path with its arrays in allocations of cap entries (>= count; NsCoupled.path_cap). */
int ns_needle_path_pack_cap(NsPack *p, struct NsNeedlePath *path, int cap);
int ns_remesh_stack_pack(NsPack *p, struct NsRemeshStack *s); /* sim/remesh_stack.c */
/* A solver (NULL allowed both ways): writing waits for a background refactorization to finish
 * (without adopting it: it is packed as pending); reading creates the solver. sim/solver.c */
int ns_solver_pack(NsPack *p, struct NsSolver **s);
/* The coupling: its own arrays, path, remesh stack and solver state (coupled_schur_pack);
 * reading borrows tissue and rod (already read) and starts an empty arena. sim/coupling.c */
int ns_coupled_pack(NsPack *p, struct NsCoupled *c, struct NsTissue *tissue, struct NsRod *rod);

/* ---- The world: tissue, needle and their coupling (sim/step.h's world and model). ---- */

/* Writes or reads the world with a header (tag, fingerprint) and the checksum. Writing: between
 * steps. Reading: t, r and c are filled from nothing; after a failure free them with
 * ns_coupled_free, ns_rod_free and ns_tissue_free. */
int ns_world_pack(NsPack *p, struct NsTissue *t, struct NsRod *r, struct NsCoupled *c);

/* An in-memory copy of a world (the planner's): restore it as often as wanted. */
typedef struct NsWorldSnapshot {
    unsigned char *bytes;
    size_t len;
} NsWorldSnapshot;
int ns_world_snapshot(struct NsTissue *t, struct NsRod *r, struct NsCoupled *c, NsWorldSnapshot *s,
                      char *err, int err_sz);
/* Fills t, r, c from nothing (free the old world first, or pass fresh structures). Returns 0,
 * or -1 with a message (memory); the structures can be freed either way. */
int ns_world_restore(const NsWorldSnapshot *s, struct NsTissue *t, struct NsRod *r,
                     struct NsCoupled *c, char *err, int err_sz);
void ns_world_snapshot_free(NsWorldSnapshot *s);

#define NS_PACK(p, v) ns_pack_bytes((p), &(v), sizeof(v))
#define NS_PACK_ARRAY(p, ptr, count, cap)                                                          \
    ns_pack_array((p), (void **)&(ptr), sizeof *(ptr), (size_t)(count), (size_t)(cap))
#define NS_PACK_ARRAY_BLANK(p, ptr, count, cap, blank)                                             \
    ns_pack_array_blank((p), (void **)&(ptr), sizeof *(ptr), (size_t)(count), (size_t)(cap),       \
                        (blank))

/* Bytes one snapshot may allocate when read (a guard against a damaged file asking for more
 * memory than the machine has; the brachytherapy world is about 73 MB at its second needle). */
#define NS_PACK_MAX_BYTES ((size_t)16 << 30)

#endif
