/* Inside scenario loading (engine/scenario.c reads the tables, engine/scenario_build.c builds
 * the tissue from them): the builder both share and the table readers. Not for other files. */
#ifndef NS_SCENARIO_INTERNAL_H
#define NS_SCENARIO_INTERNAL_H

#include <stdbool.h>
#include <stddef.h>

#include <lua.h>

#include "scenario.h"
#include "shape.h"

#define WHERE_MAX 512
/* CSG trees deeper than this are refused (a table that contains itself would recurse). */
#define SHAPE_DEPTH_MAX 200

typedef struct Builder Builder;

/* A Lua function used as a shape: called by the mesher through ns_shape_callback. */
typedef struct LuaShapeFn {
    Builder *b;
    int ref; /* registry ref to the function */
} LuaShapeFn;

struct Builder {
    NsScenario *sc;
    lua_State *L;
    char *err;
    int err_sz;
    LuaShapeFn **fns; /* (nfns) every function shape made, freed after meshing */
    int nfns, capfns;
    bool fn_failed; /* a function shape failed; fn_err says how */
    char fn_err[1024];
    bool have_bounds; /* ns.tissue.shapes{bounds = ...} was given */
    double blo[3], bhi[3];
    int shape_nodes; /* shape nodes made so far (NS_LIMIT_SHAPE_NODES) */
};

/* One line in b->err (printf style); returns -1. */
#if defined(__GNUC__)
__attribute__((format(printf, 2, 3)))
#endif
int scn_fail(Builder *b, const char *fmt, ...);
char *scn_dup_string(const char *s);
int scn_cmp_int(const void *a, const void *b);

/* Raw reads (no metamethod runs): t[key], t[i] pushed, their type returned; nil for a
 * non-table. */
int scn_rawfield(lua_State *L, int idx, const char *key);
int scn_rawindex(lua_State *L, int idx, lua_Integer i);
/* The value's kind (its metatable's __ns_kind) is `kind`. */
bool scn_is_kind(lua_State *L, int idx, const char *kind);
/* The table's `where` ("file:line"), or the fallback. */
void scn_get_where(lua_State *L, int idx, const char *fallback, char *out, size_t n);
/* Typed fields, checked; a message naming where, the constructor and the field. */
int scn_get_string(Builder *b, int idx, const char *key, const char *where, const char *ctor,
                   bool required, char **out);
int scn_get_number(Builder *b, int idx, const char *key, const char *where, const char *ctor,
                   double *out);
int scn_get_vector(Builder *b, int idx, const char *key, int n, const char *where, const char *ctor,
                   double *out);
bool scn_get_bool(lua_State *L, int idx, const char *key);

/* The material table at idx; its fields checked again. */
int scn_material_from_lua(Builder *b, int idx, const char *where, const char *ctor, NsMaterial *m);
void scn_material_free(NsMaterial *m);
/* Shapes: the value at idx, the list or the field `key` (NULL with a message on failure). */
NsShape *scn_shape_from_lua(Builder *b, int idx, const char *ctx_where, const char *ctx, int depth);
NsShape **scn_shape_list(Builder *b, int idx, const char *key, const char *where, const char *ctor,
                         int depth, int *count);
NsShape *scn_shape_field(Builder *b, int idx, const char *key, const char *where, const char *ctor,
                         int depth);

/* engine/scenario_build.c: the scenario's tissue (box, shapes or file) from the table at si. */
int scn_build_tissue(Builder *b, int si);

/* __ns_plan_implant(args), the engine's half of ns.plan_implant (scenario_implant.c;
 * docs/planning.md): registered as a global of the scenario's sandbox. */
int scn_l_plan_implant(lua_State *L);

#endif
