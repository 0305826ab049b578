/* Dynamic tetrahedral mesh: insert and delete nodes and tets with free lists (§3.6.2 keeps
 * free node indices for new nodes), node->tet incidence and face adjacency kept current on
 * every change, an order-independent topology hash, and a whole-mesh invariant checker. */
#include "mesh.h"
#include "snapshot.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Face k is opposite local vertex k; listed so that, for a tet with positive signed volume
 * det[p1-p0, p2-p0, p3-p0] > 0, the right-hand normal of each face points outwards. */
const int ns_tet_face[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};

static int grow(void **p, int *cap, int need, size_t elem)
{
    if (need <= *cap)
        return 0;
    int nc = *cap ? *cap : 16;
    while (nc < need)
        nc *= 2;
    void *q = realloc(*p, (size_t)nc * elem);
    if (!q)
        return -1;
    *p = q;
    *cap = nc;
    return 0;
}

static int list_push(NsIntList *l, int v)
{
    if (grow((void **)&l->items, &l->cap, l->count + 1, sizeof(int)))
        return -1;
    l->items[l->count++] = v;
    return 0;
}

static void list_remove(NsIntList *l, int v)
{
    for (int i = 0; i < l->count; i++) {
        if (l->items[i] == v) {
            l->items[i] = l->items[--l->count];
            return;
        }
    }
}

void ns_mesh_init(NsMesh *m)
{
    memset(m, 0, sizeof *m);
}

void ns_mesh_free(NsMesh *m)
{
    if (m->node_tets) {
        for (int i = 0; i < m->node_cap; i++)
            free(m->node_tets[i].items);
    }
    free(m->u);
    free(m->x);
    free(m->v);
    free(m->a);
    free(m->flags);
    free(m->node_tets);
    free(m->node_changed);
    free(m->tet_node);
    free(m->tet_region);
    free(m->tet_adj);
    free(m->free_nodes);
    free(m->free_tets);
    ns_mesh_init(m);
}

static int reserve_nodes(NsMesh *m, int need)
{
    if (need <= m->node_cap)
        return 0;
    int nc = m->node_cap ? m->node_cap : 64;
    while (nc < need)
        nc *= 2;
    double *u = realloc(m->u, (size_t)nc * 3 * sizeof(double));
    if (u)
        m->u = u;
    double *x = realloc(m->x, (size_t)nc * 3 * sizeof(double));
    if (x)
        m->x = x;
    double *v = realloc(m->v, (size_t)nc * 3 * sizeof(double));
    if (v)
        m->v = v;
    double *a = realloc(m->a, (size_t)nc * 3 * sizeof(double));
    if (a)
        m->a = a;
    uint8_t *f = realloc(m->flags, (size_t)nc);
    if (f)
        m->flags = f;
    NsIntList *nt = realloc(m->node_tets, (size_t)nc * sizeof(NsIntList));
    if (nt)
        m->node_tets = nt;
    uint64_t *nch = realloc(m->node_changed, (size_t)nc * sizeof(uint64_t));
    if (nch)
        m->node_changed = nch;
    if (!u || !x || !v || !a || !f || !nt || !nch)
        return -1;
    memset(m->node_changed + m->node_cap, 0, (size_t)(nc - m->node_cap) * sizeof(uint64_t));
    memset(m->flags + m->node_cap, 0, (size_t)(nc - m->node_cap));
    memset(m->node_tets + m->node_cap, 0, (size_t)(nc - m->node_cap) * sizeof(NsIntList));
    m->node_cap = nc;
    return 0;
}

static int reserve_tets(NsMesh *m, int need)
{
    if (need <= m->tet_cap)
        return 0;
    int nc = m->tet_cap ? m->tet_cap : 64;
    while (nc < need)
        nc *= 2;
    int *tn = realloc(m->tet_node, (size_t)nc * 4 * sizeof(int));
    if (tn)
        m->tet_node = tn;
    int *tr = realloc(m->tet_region, (size_t)nc * sizeof(int));
    if (tr)
        m->tet_region = tr;
    int *ta = realloc(m->tet_adj, (size_t)nc * 4 * sizeof(int));
    if (ta)
        m->tet_adj = ta;
    if (!tn || !tr || !ta)
        return -1;
    m->tet_cap = nc;
    return 0;
}

int ns_mesh_add_node(NsMesh *m, const double u[3])
{
    int i;
    if (m->free_node_count > 0) {
        i = m->free_nodes[--m->free_node_count];
    } else {
        if (reserve_nodes(m, m->node_slots + 1))
            return -1;
        i = m->node_slots++;
    }
    for (int k = 0; k < 3; k++) {
        m->u[3 * i + k] = u[k];
        m->x[3 * i + k] = u[k];
        m->v[3 * i + k] = 0.0;
        m->a[3 * i + k] = 0.0;
    }
    m->flags[i] = NS_NODE_ALIVE;
    m->node_tets[i].count = 0;
    m->node_alive++;
    m->node_changed[i] = ++m->topology_version;
    return i;
}

int ns_mesh_remove_node(NsMesh *m, int node)
{
    if (!ns_mesh_node_alive(m, node) || m->node_tets[node].count != 0)
        return -1;
    if (grow((void **)&m->free_nodes, &m->free_node_cap, m->free_node_count + 1, sizeof(int)))
        return -1;
    m->flags[node] = 0;
    m->free_nodes[m->free_node_count++] = node;
    m->node_alive--;
    m->node_changed[node] = ++m->topology_version;
    return 0;
}

static bool tet_has_node(const NsMesh *m, int t, int n)
{
    const int *tn = m->tet_node + 4 * t;
    return tn[0] == n || tn[1] == n || tn[2] == n || tn[3] == n;
}

/* The local index (0..3) of the face of tet t made of nodes a, b, c, or -1. */
static int tet_face_index(const NsMesh *m, int t, int a, int b, int c)
{
    const int *tn = m->tet_node + 4 * t;
    for (int k = 0; k < 4; k++) {
        if (tn[k] != a && tn[k] != b && tn[k] != c)
            return tet_has_node(m, t, a) && tet_has_node(m, t, b) && tet_has_node(m, t, c) ? k : -1;
    }
    return -1;
}

int ns_mesh_add_tet(NsMesh *m, const int nodes[4], int region)
{
    for (int k = 0; k < 4; k++) {
        if (!ns_mesh_node_alive(m, nodes[k]))
            return -1;
        for (int j = 0; j < k; j++)
            if (nodes[j] == nodes[k])
                return -1;
    }
    if (region < 0)
        return -1;
    /* Reserve everything first so a failure leaves the mesh unchanged. */
    for (int k = 0; k < 4; k++) {
        NsIntList *l = &m->node_tets[nodes[k]];
        if (grow((void **)&l->items, &l->cap, l->count + 1, sizeof(int)))
            return -1;
    }
    int t;
    if (m->free_tet_count > 0) {
        t = m->free_tets[--m->free_tet_count];
    } else {
        if (reserve_tets(m, m->tet_slots + 1))
            return -1;
        t = m->tet_slots++;
    }
    memcpy(m->tet_node + 4 * t, nodes, 4 * sizeof(int));
    m->tet_region[t] = region;
    /* Link face neighbours: a tet sharing face k contains its three nodes, so it is among the
     * incident tets of any one of them. */
    for (int k = 0; k < 4; k++) {
        int a = nodes[ns_tet_face[k][0]], b = nodes[ns_tet_face[k][1]],
            c = nodes[ns_tet_face[k][2]];
        m->tet_adj[4 * t + k] = -1;
        const NsIntList *l = &m->node_tets[a];
        for (int i = 0; i < l->count; i++) {
            int o = l->items[i];
            int f = tet_face_index(m, o, a, b, c);
            if (f >= 0 && m->tet_adj[4 * o + f] < 0) {
                m->tet_adj[4 * t + k] = o;
                m->tet_adj[4 * o + f] = t;
                break;
            }
        }
    }
    for (int k = 0; k < 4; k++)
        list_push(&m->node_tets[nodes[k]], t); /* cannot fail: reserved above */
    m->tet_alive++;
    m->topology_version++;
    for (int k = 0; k < 4; k++)
        m->node_changed[nodes[k]] = m->topology_version;
    return t;
}

void ns_mesh_remove_tet(NsMesh *m, int t)
{
    if (!ns_mesh_tet_alive(m, t))
        return;
    if (grow((void **)&m->free_tets, &m->free_tet_cap, m->free_tet_count + 1, sizeof(int)))
        return; /* out of memory: leave the mesh unchanged rather than lose the slot */
    for (int k = 0; k < 4; k++) {
        int o = m->tet_adj[4 * t + k];
        if (o >= 0) {
            for (int f = 0; f < 4; f++)
                if (m->tet_adj[4 * o + f] == t)
                    m->tet_adj[4 * o + f] = -1;
        }
        list_remove(&m->node_tets[m->tet_node[4 * t + k]], t);
        m->tet_adj[4 * t + k] = -1;
    }
    m->tet_alive--;
    m->topology_version++;
    for (int k = 0; k < 4; k++)
        m->node_changed[m->tet_node[4 * t + k]] = m->topology_version;
    m->tet_node[4 * t] = -1;
    m->free_tets[m->free_tet_count++] = t;
}

int ns_mesh_copy(NsMesh *dst, const NsMesh *src)
{
    ns_mesh_init(dst);
    if (reserve_nodes(dst, src->node_slots > 0 ? src->node_slots : 1) ||
        reserve_tets(dst, src->tet_slots > 0 ? src->tet_slots : 1))
        goto fail;
    size_t n3 = (size_t)src->node_slots * 3 * sizeof(double);
    memcpy(dst->u, src->u, n3);
    memcpy(dst->x, src->x, n3);
    memcpy(dst->v, src->v, n3);
    memcpy(dst->a, src->a, n3);
    memcpy(dst->flags, src->flags, (size_t)src->node_slots);
    memcpy(dst->node_changed, src->node_changed, (size_t)src->node_slots * sizeof(uint64_t));
    for (int i = 0; i < src->node_slots; i++) {
        const NsIntList *s = &src->node_tets[i];
        NsIntList *d = &dst->node_tets[i];
        if (s->count && grow((void **)&d->items, &d->cap, s->count, sizeof(int)))
            goto fail;
        if (s->count)
            memcpy(d->items, s->items, (size_t)s->count * sizeof(int));
        d->count = s->count;
    }
    memcpy(dst->tet_node, src->tet_node, (size_t)src->tet_slots * 4 * sizeof(int));
    memcpy(dst->tet_region, src->tet_region, (size_t)src->tet_slots * sizeof(int));
    memcpy(dst->tet_adj, src->tet_adj, (size_t)src->tet_slots * 4 * sizeof(int));
    if (grow((void **)&dst->free_nodes, &dst->free_node_cap, src->free_node_count, sizeof(int)) ||
        grow((void **)&dst->free_tets, &dst->free_tet_cap, src->free_tet_count, sizeof(int)))
        goto fail;
    if (src->free_node_count)
        memcpy(dst->free_nodes, src->free_nodes, (size_t)src->free_node_count * sizeof(int));
    if (src->free_tet_count)
        memcpy(dst->free_tets, src->free_tets, (size_t)src->free_tet_count * sizeof(int));
    dst->node_slots = src->node_slots;
    dst->node_alive = src->node_alive;
    dst->tet_slots = src->tet_slots;
    dst->tet_alive = src->tet_alive;
    dst->free_node_count = src->free_node_count;
    dst->free_tet_count = src->free_tet_count;
    dst->topology_version = src->topology_version;
    return 0;
fail:
    ns_mesh_free(dst);
    return -1;
}

static void list_blank(void *e)
{
    ((NsIntList *)e)->items = NULL;
}

/* Node arrays up to node_slots (the rest of node_cap is written before it is read), node_tets
 * over all of node_cap with each list's items in its own allocation (the order matters: sums are
 * taken in it), tet arrays up to tet_slots, the free lists. */
static void mesh_blank(void *e)
{
    NsMesh *h = e;
    h->u = h->x = h->v = h->a = NULL;
    h->flags = NULL;
    h->node_tets = NULL;
    h->node_changed = NULL;
    h->tet_node = h->tet_region = h->tet_adj = NULL;
    h->free_nodes = h->free_tets = NULL;
}

int ns_mesh_pack(NsPack *p, NsMesh *m)
{
    ns_pack_struct(p, "MESH", m, sizeof *m, mesh_blank);
    size_t ns = (size_t)m->node_slots, nc = (size_t)m->node_cap;
    size_t ts = (size_t)m->tet_slots, tc = (size_t)m->tet_cap;
    NS_PACK_ARRAY(p, m->u, 3 * ns, 3 * nc);
    NS_PACK_ARRAY(p, m->x, 3 * ns, 3 * nc);
    NS_PACK_ARRAY(p, m->v, 3 * ns, 3 * nc);
    NS_PACK_ARRAY(p, m->a, 3 * ns, 3 * nc);
    NS_PACK_ARRAY(p, m->flags, nc, nc);
    NS_PACK_ARRAY(p, m->node_changed, nc, nc);
    NS_PACK_ARRAY_BLANK(p, m->node_tets, nc, nc, list_blank);
    for (size_t i = 0; m->node_tets && i < nc; i++) {
        NsIntList *l = &m->node_tets[i];
        NS_PACK_ARRAY(p, l->items, (size_t)l->count, (size_t)l->cap);
    }
    NS_PACK_ARRAY(p, m->tet_node, 4 * ts, 4 * tc);
    NS_PACK_ARRAY(p, m->tet_region, ts, tc);
    NS_PACK_ARRAY(p, m->tet_adj, 4 * ts, 4 * tc);
    NS_PACK_ARRAY(p, m->free_nodes, (size_t)m->free_node_count, (size_t)m->free_node_cap);
    NS_PACK_ARRAY(p, m->free_tets, (size_t)m->free_tet_count, (size_t)m->free_tet_cap);
    return p->failed ? -1 : 0;
}

/* splitmix64 finalizer: a well-mixed 64-bit hash of one value. */
static uint64_t mix64(uint64_t z)
{
    z += 0x9e3779b97f4a7c15ull;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

static void sort4(int *a)
{
    for (int i = 1; i < 4; i++)
        for (int j = i; j > 0 && a[j - 1] > a[j]; j--) {
            int t = a[j];
            a[j] = a[j - 1];
            a[j - 1] = t;
        }
}

uint64_t ns_mesh_topology_hash(const NsMesh *m)
{
    /* A sum of per-element hashes is independent of slot order and history; each element's
     * hash covers its sorted nodes and region, so only the set of tets (and alive nodes)
     * matters. */
    uint64_t h = mix64((uint64_t)m->node_alive) ^ mix64(0x100000000ull + (uint64_t)m->tet_alive);
    for (int i = 0; i < m->node_slots; i++)
        if (m->flags[i] & NS_NODE_ALIVE)
            h += mix64(0xA11CE000000000ull ^ (uint64_t)i);
    for (int t = 0; t < m->tet_slots; t++) {
        if (!ns_mesh_tet_alive(m, t))
            continue;
        int s[4];
        memcpy(s, m->tet_node + 4 * t, sizeof s);
        sort4(s);
        uint64_t e = mix64((uint64_t)(uint32_t)m->tet_region[t]);
        for (int k = 0; k < 4; k++)
            e = mix64(e ^ (uint64_t)(uint32_t)s[k]);
        h += e;
    }
    return mix64(h);
}

#define FAIL(...)                                                                                  \
    do {                                                                                           \
        if (err && err_sz > 0)                                                                     \
            snprintf(err, (size_t)err_sz, __VA_ARGS__);                                            \
        ret = -1;                                                                                  \
        goto done;                                                                                 \
    } while (0)

int ns_mesh_validate(const NsMesh *m, char *err, int err_sz)
{
    int ret = 0;
    int *incidence = calloc((size_t)(m->node_slots > 0 ? m->node_slots : 1), sizeof(int));
    char *seen = calloc((size_t)(m->node_slots + m->tet_slots + 1), 1);
    if (!incidence || !seen)
        FAIL("out of memory");
    int alive_nodes = 0, alive_tets = 0;
    for (int i = 0; i < m->node_slots; i++)
        alive_nodes += (m->flags[i] & NS_NODE_ALIVE) != 0;
    if (alive_nodes != m->node_alive)
        FAIL("node_alive is %d but %d slots are alive", m->node_alive, alive_nodes);
    for (int t = 0; t < m->tet_slots; t++) {
        if (!ns_mesh_tet_alive(m, t))
            continue;
        alive_tets++;
        const int *tn = m->tet_node + 4 * t;
        for (int k = 0; k < 4; k++) {
            if (!ns_mesh_node_alive(m, tn[k]))
                FAIL("tet %d references dead or invalid node %d", t, tn[k]);
            for (int j = 0; j < k; j++)
                if (tn[j] == tn[k])
                    FAIL("tet %d repeats node %d", t, tn[k]);
            incidence[tn[k]]++;
            const NsIntList *l = &m->node_tets[tn[k]];
            int found = 0;
            for (int i = 0; i < l->count; i++)
                found += l->items[i] == t;
            if (found != 1)
                FAIL("node %d lists tet %d %d times (expected once)", tn[k], t, found);
        }
        if (m->tet_region[t] < 0)
            FAIL("tet %d has negative region %d", t, m->tet_region[t]);
        for (int k = 0; k < 4; k++) {
            int a = tn[ns_tet_face[k][0]], b = tn[ns_tet_face[k][1]], c = tn[ns_tet_face[k][2]];
            int o = m->tet_adj[4 * t + k];
            /* Count every tet that has this face, through the incidence list of a. */
            int sharing = 0, other = -1;
            const NsIntList *l = &m->node_tets[a];
            for (int i = 0; i < l->count; i++) {
                int q = l->items[i];
                if (q != t && tet_face_index(m, q, a, b, c) >= 0) {
                    sharing++;
                    other = q;
                }
            }
            if (sharing > 1)
                FAIL("face (%d %d %d) of tet %d is shared by %d other tets", a, b, c, t, sharing);
            if (o != other)
                FAIL("tet %d face %d: adjacency says %d but the neighbour is %d", t, k, o, other);
            if (o >= 0) {
                int f = tet_face_index(m, o, a, b, c);
                if (f < 0 || m->tet_adj[4 * o + f] != t)
                    FAIL("adjacency of tets %d and %d is not symmetric", t, o);
            }
        }
    }
    if (alive_tets != m->tet_alive)
        FAIL("tet_alive is %d but %d slots are alive", m->tet_alive, alive_tets);
    for (int i = 0; i < m->node_slots; i++) {
        int cnt = (m->flags[i] & NS_NODE_ALIVE) ? m->node_tets[i].count : 0;
        if (cnt != incidence[i])
            FAIL("node %d lists %d tets but %d tets use it", i, m->node_tets[i].count,
                 incidence[i]);
    }
    /* Free lists hold exactly the dead slots, each once. */
    if (m->free_node_count != m->node_slots - m->node_alive)
        FAIL("%d free node indices for %d dead node slots", m->free_node_count,
             m->node_slots - m->node_alive);
    for (int i = 0; i < m->free_node_count; i++) {
        int n = m->free_nodes[i];
        if (n < 0 || n >= m->node_slots || (m->flags[n] & NS_NODE_ALIVE) || seen[n])
            FAIL("free node list entry %d (node %d) is alive, repeated or out of range", i, n);
        seen[n] = 1;
    }
    if (m->free_tet_count != m->tet_slots - m->tet_alive)
        FAIL("%d free tet indices for %d dead tet slots", m->free_tet_count,
             m->tet_slots - m->tet_alive);
    for (int i = 0; i < m->free_tet_count; i++) {
        int t = m->free_tets[i];
        if (t < 0 || t >= m->tet_slots || ns_mesh_tet_alive(m, t) || seen[m->node_slots + t])
            FAIL("free tet list entry %d (tet %d) is alive, repeated or out of range", i, t);
        seen[m->node_slots + t] = 1;
    }
done:
    free(incidence);
    free(seen);
    return ret;
}

int ns_mesh_first_unreferenced_node(const NsMesh *m)
{
    for (int i = 0; i < m->node_slots; i++)
        if ((m->flags[i] & NS_NODE_ALIVE) && m->node_tets[i].count == 0)
            return i;
    return -1;
}

/* Boundary edges, as (lo, hi, count) entries sorted for counting. */
typedef struct BEdge {
    int a, b;
} BEdge;

static int cmp_bedge(const void *p, const void *q)
{
    const BEdge *x = p, *y = q;
    if (x->a != y->a)
        return x->a < y->a ? -1 : 1;
    return (x->b > y->b) - (x->b < y->b);
}

int ns_mesh_boundary(NsMesh *m, NsBoundaryStats *out)
{
    NsBoundaryStats st = {0, true, true, {-1, -1}, -1};
    for (int i = 0; i < m->node_slots; i++)
        m->flags[i] &= (uint8_t)~NS_NODE_BOUNDARY;
    int nf = 0;
    for (int t = 0; t < m->tet_slots; t++)
        if (ns_mesh_tet_alive(m, t))
            for (int k = 0; k < 4; k++)
                nf += m->tet_adj[4 * t + k] < 0;
    int *tri = malloc((size_t)(nf > 0 ? nf : 1) * 3 * sizeof(int));
    BEdge *edges = malloc((size_t)(nf > 0 ? nf : 1) * 3 * sizeof(BEdge));
    if (!tri || !edges) {
        free(tri);
        free(edges);
        return -1;
    }
    int f = 0;
    for (int t = 0; t < m->tet_slots; t++) {
        if (!ns_mesh_tet_alive(m, t))
            continue;
        for (int k = 0; k < 4; k++) {
            if (m->tet_adj[4 * t + k] >= 0)
                continue;
            for (int j = 0; j < 3; j++) {
                int n = m->tet_node[4 * t + ns_tet_face[k][j]];
                tri[3 * f + j] = n;
                m->flags[n] |= NS_NODE_BOUNDARY;
            }
            f++;
        }
    }
    st.faces = nf;
    for (int i = 0; i < nf; i++)
        for (int j = 0; j < 3; j++) {
            int a = tri[3 * i + j], b = tri[3 * i + (j + 1) % 3];
            edges[3 * i + j] = (BEdge){a < b ? a : b, a < b ? b : a};
        }
    int ne = 3 * nf;
    qsort(edges, (size_t)ne, sizeof(BEdge), cmp_bedge);
    for (int i = 0; i < ne;) {
        int j = i;
        while (j < ne && edges[j].a == edges[i].a && edges[j].b == edges[i].b)
            j++;
        int cnt = j - i;
        if (cnt % 2 != 0 && st.closed) {
            st.closed = false;
            st.bad_edge[0] = edges[i].a;
            st.bad_edge[1] = edges[i].b;
        }
        if (cnt != 2 && st.manifold) {
            st.manifold = false;
            if (st.bad_edge[0] < 0) {
                st.bad_edge[0] = edges[i].a;
                st.bad_edge[1] = edges[i].b;
            }
        }
        i = j;
    }
    /* Vertex manifoldness: the boundary faces around each boundary vertex must form one fan.
     * Walk the fan through shared edges and compare its size with the vertex's face count. */
    if (st.manifold && nf > 0) {
        int *count = calloc((size_t)m->node_slots, sizeof(int));
        int *start = calloc((size_t)m->node_slots + 1, sizeof(int));
        int *vf = malloc((size_t)nf * 3 * sizeof(int));
        char *mark = calloc((size_t)nf, 1);
        if (!count || !start || !vf || !mark) {
            free(count);
            free(start);
            free(vf);
            free(mark);
            free(tri);
            free(edges);
            return -1;
        }
        for (int i = 0; i < 3 * nf; i++)
            count[tri[i]]++;
        for (int i = 0; i < m->node_slots; i++)
            start[i + 1] = start[i] + count[i];
        memset(count, 0, (size_t)m->node_slots * sizeof(int));
        for (int i = 0; i < nf; i++)
            for (int j = 0; j < 3; j++) {
                int n = tri[3 * i + j];
                vf[start[n] + count[n]++] = i;
            }
        for (int n = 0; n < m->node_slots && st.bad_vertex < 0; n++) {
            int deg = count[n];
            if (deg == 0)
                continue;
            const int *fl = vf + start[n];
            /* Start from the first face, repeatedly step to an unmarked face sharing an edge
             * (n, w) with the current one. */
            int cur = fl[0], visited = 0;
            for (int i = 0; i < deg; i++)
                mark[fl[i]] = 0;
            while (cur >= 0) {
                mark[cur] = 1;
                visited++;
                int next = -1;
                for (int i = 0; i < deg && next < 0; i++) {
                    int g = fl[i];
                    if (mark[g])
                        continue;
                    int shared = 0;
                    for (int p = 0; p < 3; p++)
                        for (int q = 0; q < 3; q++)
                            shared += tri[3 * cur + p] == tri[3 * g + q] && tri[3 * g + q] != n;
                    if (shared >= 1)
                        next = g;
                }
                cur = next;
            }
            if (visited != deg) {
                st.manifold = false;
                st.bad_vertex = n;
            }
        }
        free(count);
        free(start);
        free(vf);
        free(mark);
    }
    free(tri);
    free(edges);
    if (out)
        *out = st;
    return 0;
}

int ns_mesh_compact(NsMesh *m)
{
    int *remap = malloc((size_t)(m->node_slots > 0 ? m->node_slots : 1) * sizeof(int));
    int *tremap = malloc((size_t)(m->tet_slots > 0 ? m->tet_slots : 1) * sizeof(int));
    if (!remap || !tremap) {
        free(remap);
        free(tremap);
        return -1;
    }
    int n = 0;
    for (int i = 0; i < m->node_slots; i++) {
        if (!(m->flags[i] & NS_NODE_ALIVE)) {
            remap[i] = -1;
            continue;
        }
        remap[i] = n;
        if (n != i) {
            memcpy(m->u + 3 * n, m->u + 3 * i, 3 * sizeof(double));
            memcpy(m->x + 3 * n, m->x + 3 * i, 3 * sizeof(double));
            memcpy(m->v + 3 * n, m->v + 3 * i, 3 * sizeof(double));
            memcpy(m->a + 3 * n, m->a + 3 * i, 3 * sizeof(double));
            m->flags[n] = m->flags[i];
            NsIntList tmp = m->node_tets[n];
            m->node_tets[n] = m->node_tets[i];
            m->node_tets[i] = tmp; /* keep the dead slot's buffer for reuse/free */
            m->flags[i] = 0;
        }
        n++;
    }
    int t2 = 0;
    for (int t = 0; t < m->tet_slots; t++)
        tremap[t] = ns_mesh_tet_alive(m, t) ? t2++ : -1;
    for (int t = 0; t < m->tet_slots; t++) {
        int d = tremap[t];
        if (d < 0)
            continue;
        for (int k = 0; k < 4; k++) {
            m->tet_node[4 * d + k] = remap[m->tet_node[4 * t + k]];
            int o = m->tet_adj[4 * t + k];
            m->tet_adj[4 * d + k] = o >= 0 ? tremap[o] : -1;
        }
        m->tet_region[d] = m->tet_region[t];
    }
    for (int i = 0; i < n; i++) {
        NsIntList *l = &m->node_tets[i];
        for (int j = 0; j < l->count; j++)
            l->items[j] = tremap[l->items[j]];
    }
    for (int i = n; i < m->node_slots; i++)
        m->node_tets[i].count = 0;
    m->node_slots = n;
    m->tet_slots = t2;
    m->free_node_count = 0;
    m->free_tet_count = 0;
    m->topology_version++;
    for (int i = 0; i < n; i++) /* renumbered: every node's list counts as changed */
        m->node_changed[i] = m->topology_version;
    free(remap);
    free(tremap);
    return 0;
}
