/* The remesh stack's primitives (sim/remesh.h): the snap and split operations on the tissue
 * mesh, each pushed on the undo stack, undone in reverse order, and the original positions of
 * moved nodes (paper §3.4.1). Algorithm 2, which chooses among them, is remesh.c. */
#include "remesh.h"
#include "quality.h"
#include "remesh_internal.h"
#include "snapshot.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

void ns_remesh_stack_init(NsRemeshStack *s)
{
    memset(s, 0, sizeof *s);
}

void ns_remesh_stack_free(NsRemeshStack *s)
{
    for (int i = 0; i < s->count; i++) {
        free(s->ops[i].removed_tet);
        free(s->ops[i].added_tet);
    }
    free(s->ops);
    free(s->snap_node);
    free(s->snap_u);
    memset(s, 0, sizeof *s);
}

static void op_blank(void *e)
{
    NsRemeshOp *op = e;
    op->removed_tet = NULL;
    op->added_tet = NULL;
}

static void stack_blank(void *e)
{
    NsRemeshStack *h = e;
    h->ops = NULL;
    h->snap_node = NULL;
    h->snap_u = NULL;
}

/* The ops (each with what it removed and added, in the allocations ns_remesh_split made: removed
 * x 6 and removed x kind) and the first-snap records. */
int ns_remesh_stack_pack(NsPack *p, NsRemeshStack *s)
{
    ns_pack_struct(p, "RSTK", s, sizeof *s, stack_blank);
    size_t count = (size_t)s->count;
    NS_PACK_ARRAY_BLANK(p, s->ops, count, (size_t)s->cap, op_blank);
    for (size_t i = 0; s->ops && i < count; i++) {
        NsRemeshOp *op = &s->ops[i];
        size_t removed = (size_t)op->removed;
        NS_PACK_ARRAY(p, op->removed_tet, 6 * removed, 6 * removed);
        NS_PACK_ARRAY(p, op->added_tet, (size_t)op->added, removed * (size_t)op->kind);
    }
    if (!p->writing && !s->ops)
        s->count = s->cap = 0; /* what ns_remesh_stack_free walks */
    size_t snaps = (size_t)s->snaps, snap_cap = (size_t)s->snap_cap;
    NS_PACK_ARRAY(p, s->snap_node, snaps, snap_cap);
    NS_PACK_ARRAY(p, s->snap_u, 3 * snaps, 3 * snap_cap);
    return p->failed ? -1 : 0;
}

/* Tets containing every node of the simplex, into out (cap); returns their count. */
static int simplex_tets(const NsMesh *m, const int *simplex, int k, int *out, int cap)
{
    int n = 0;
    const NsIntList *l = &m->node_tets[simplex[0]];
    for (int i = 0; i < l->count; i++) {
        int t = l->items[i], all = 1;
        for (int j = 1; j < k && all; j++)
            all = remesh_tet_has(m, t, simplex[j]);
        if (all && n < cap)
            out[n++] = t;
    }
    return n;
}

#define MAX_RING 128

int ns_remesh_split(NsMesh *m, NsRemeshStack *s, const int *simplex, int k, const double u[3])
{
    if (k < 2 || k > 4)
        return -1;
    for (int j = 0; j < k; j++)
        if (!ns_mesh_node_alive(m, simplex[j]))
            return -1;
    int tets[MAX_RING];
    int nt = simplex_tets(m, simplex, k, tets, MAX_RING);
    if (nt == 0 || nt == MAX_RING)
        return -1;
    /* Every created tet must be positive in material space. */
    for (int i = 0; i < nt; i++)
        for (int j = 0; j < k; j++) {
            const double *p[4];
            for (int c = 0; c < 4; c++) {
                int n = m->tet_node[4 * tets[i] + c];
                p[c] = n == simplex[j] ? u : m->u + 3 * n;
            }
            if (!(ns_tet_volume(p[0], p[1], p[2], p[3]) > 0.0))
                return -1;
        }
    double b[4], x[3], v[3], a[3];
    int loc = ns_mesh_locate(m, u, tets[0], 1e-9, b);
    if (loc < 0)
        return -1;
    remesh_interp_state(m, loc, b, x, v, a);
    if (s->count == s->cap) {
        int cap = s->cap ? 2 * s->cap : 16;
        NsRemeshOp *o = realloc(s->ops, (size_t)cap * sizeof *o);
        if (!o)
            return -1;
        s->ops = o;
        s->cap = cap;
    }
    NsRemeshOp *op = &s->ops[s->count];
    memset(op, 0, sizeof *op);
    op->removed_tet = malloc((size_t)nt * 6 * sizeof *op->removed_tet);
    op->added_tet = malloc((size_t)nt * (size_t)k * sizeof *op->added_tet);
    int node = op->removed_tet && op->added_tet ? ns_mesh_add_node(m, u) : -1;
    if (node < 0) {
        free(op->removed_tet);
        free(op->added_tet);
        return -1;
    }
    memcpy(m->x + 3 * node, x, sizeof x);
    memcpy(m->v + 3 * node, v, sizeof v);
    memcpy(m->a + 3 * node, a, sizeof a);
    op->kind = (NsRemeshKind)k;
    op->node = node;
    memcpy(op->simplex, simplex, (size_t)k * sizeof *simplex);
    for (int i = 0; i < nt; i++) {
        int *r = op->removed_tet + 6 * i;
        r[0] = tets[i];
        r[1] = m->tet_region[tets[i]];
        memcpy(r + 2, m->tet_node + 4 * tets[i], 4 * sizeof *r);
        ns_mesh_remove_tet(m, tets[i]);
    }
    op->removed = nt;
    for (int i = 0; i < nt; i++)
        for (int j = 0; j < k; j++) {
            const int *r = op->removed_tet + 6 * i;
            int tn[4];
            for (int c = 0; c < 4; c++)
                tn[c] = r[2 + c] == simplex[j] ? node : r[2 + c];
            int t = ns_mesh_add_tet(m, tn, r[1]);
            if (t < 0) { /* memory: put back everything added so far */
                s->count++;
                ns_remesh_undo(m, s);
                return -1;
            }
            op->added_tet[op->added++] = t;
        }
    s->count++;
    return node;
}

static void forget_original(NsRemeshStack *s, int n);

int ns_remesh_undo(NsMesh *m, NsRemeshStack *s)
{
    if (s->count == 0)
        return -1;
    NsRemeshOp *op = &s->ops[s->count - 1];
    if (m->node_tets[op->node].count != op->added)
        return -1; /* the node is used by tets the operation did not make: nothing changed */
    for (int i = op->added - 1; i >= 0; i--)
        ns_mesh_remove_tet(m, op->added_tet[i]);
    for (int i = op->removed - 1; i >= 0; i--) {
        const int *r = op->removed_tet + 6 * i;
        if (ns_mesh_add_tet(m, r + 2, r[1]) < 0)
            return -1;
    }
    ns_mesh_remove_node(m, op->node);
    forget_original(s, op->node);
    free(op->removed_tet);
    free(op->added_tet);
    s->count--;
    return 0;
}

int ns_remesh_original(const NsRemeshStack *s, int n, double u[3])
{
    for (int i = 0; i < s->snaps; i++)
        if (s->snap_node[i] == n) {
            memcpy(u, s->snap_u + 3 * i, 3 * sizeof *u);
            return 1;
        }
    return 0;
}

/* Moves node n's material position to u, with world state (x, v, a) given; no checks. */
void remesh_set_node(NsMesh *m, int n, const double u[3], const double x[3], const double v[3],
                     const double a[3])
{
    memcpy(m->u + 3 * n, u, 3 * sizeof *u);
    memcpy(m->x + 3 * n, x, 3 * sizeof *x);
    memcpy(m->v + 3 * n, v, 3 * sizeof *v);
    memcpy(m->a + 3 * n, a, 3 * sizeof *a);
}

void ns_remesh_forget_original(NsRemeshStack *s, int n)
{
    forget_original(s, n);
}

/* Forgets node n's original position (its slot died with an undone split). */
static void forget_original(NsRemeshStack *s, int n)
{
    for (int i = 0; i < s->snaps; i++)
        if (s->snap_node[i] == n) {
            s->snap_node[i] = s->snap_node[s->snaps - 1];
            memcpy(s->snap_u + 3 * i, s->snap_u + 3 * (s->snaps - 1), 3 * sizeof(double));
            s->snaps--;
            return;
        }
}

int ns_remesh_record_original(NsRemeshStack *s, int n, const double u[3])
{
    double u0[3];
    if (ns_remesh_original(s, n, u0))
        return 0;
    for (int i = 0; i < s->count; i++)
        if (s->ops[i].node == n)
            return 0; /* made by a split: undoing it removes the node, it has no original */
    if (s->snaps == s->snap_cap) {
        int cap = s->snap_cap ? 2 * s->snap_cap : 16;
        int *sn = realloc(s->snap_node, (size_t)cap * sizeof *sn);
        if (sn)
            s->snap_node = sn;
        double *su = realloc(s->snap_u, (size_t)cap * 3 * sizeof *su);
        if (su)
            s->snap_u = su;
        if (!sn || !su)
            return -1;
        s->snap_cap = cap;
    }
    s->snap_node[s->snaps] = n;
    memcpy(s->snap_u + 3 * s->snaps, u, 3 * sizeof(double));
    s->snaps++;
    return 0;
}

void ns_remesh_release_all(NsMesh *m, NsRemeshStack *s)
{
    for (int i = 0; i < s->snaps; i++) {
        int n = s->snap_node[i];
        if (!ns_mesh_node_alive(m, n) || m->node_tets[n].count == 0)
            continue;
        double b[4], x[3], v[3], a[3];
        const double *u0 = s->snap_u + 3 * i;
        int loc = ns_mesh_locate(m, u0, m->node_tets[n].items[0], 1e-9, b);
        if (loc >= 0) {
            remesh_interp_state(m, loc, b, x, v, a);
            remesh_set_node(m, n, u0, x, v, a);
        } else {
            memcpy(m->u + 3 * n, u0, 3 * sizeof *u0);
        }
    }
    s->snaps = 0;
}

int ns_remesh_snap(NsMesh *m, NsRemeshStack *s, int n, const double u[3])
{
    return ns_remesh_snap_all(m, s, &n, u, 1);
}

int ns_remesh_snap_all(NsMesh *m, NsRemeshStack *s, const int *nodes, const double *u, int count)
{
    /* Every world state from the mesh as it is, before any node moves. */
    double *st = malloc((size_t)(9 * count + 1) * sizeof *st);
    if (!st)
        return -1;
    for (int i = 0; i < count; i++) {
        int n = nodes[i];
        double b[4];
        int loc = ns_mesh_node_alive(m, n) && m->node_tets[n].count > 0
                      ? ns_mesh_locate(m, u + 3 * i, m->node_tets[n].items[0], 1e-9, b)
                      : -1;
        if (loc < 0) {
            free(st);
            return -1;
        }
        remesh_interp_state(m, loc, b, st + 9 * i, st + 9 * i + 3, st + 9 * i + 6);
    }
    for (int i = 0; i < count; i++)
        if (ns_remesh_record_original(s, nodes[i], m->u + 3 * nodes[i])) {
            free(st);
            return -1;
        }
    for (int i = 0; i < count; i++)
        remesh_set_node(m, nodes[i], u + 3 * i, st + 9 * i, st + 9 * i + 3, st + 9 * i + 6);
    free(st);
    return 0;
}
