/* The needle's pre-laid path through the tissue (sim/needle_path.h): the stand-in for tip
 * remeshing (§3.4.1) while the coupling of §3.3 is tested on its own. */
#include "needle_path.h"
#include "snapshot.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static double dist3(const double *a, const double *b)
{
    double s = 0.0;
    for (int k = 0; k < 3; k++)
        s += (a[k] - b[k]) * (a[k] - b[k]);
    return sqrt(s);
}

/* 1 if nodes i and j are both vertices of some alive tet (they share a tet edge). */
static int share_tet(const NsMesh *m, int i, int j)
{
    const NsIntList *l = &m->node_tets[i];
    for (int k = 0; k < l->count; k++) {
        const int *tn = m->tet_node + 4 * l->items[k];
        for (int c = 0; c < 4; c++)
            if (tn[c] == j)
                return 1;
    }
    return 0;
}

int ns_needle_path_init(NsNeedlePath *p, const NsMesh *m, const int *nodes, int count, double tip_s,
                        char *err, int err_sz)
{
    p->node = NULL;
    p->s = NULL;
    p->count = 0;
    if (count < 2) {
        snprintf(err, (size_t)err_sz, "needle path: %d nodes, need at least 2", count);
        return -1;
    }
    for (int i = 0; i < count; i++) {
        if (nodes[i] < 0 || nodes[i] >= m->node_slots || !ns_mesh_node_alive(m, nodes[i])) {
            snprintf(err, (size_t)err_sz, "needle path: node %d (entry %d) is not a tissue node",
                     nodes[i], i);
            return -1;
        }
        for (int j = 0; j < i; j++)
            if (nodes[j] == nodes[i]) {
                snprintf(err, (size_t)err_sz, "needle path: node %d appears twice", nodes[i]);
                return -1;
            }
        if (i > 0 && !share_tet(m, nodes[i - 1], nodes[i])) {
            snprintf(err, (size_t)err_sz, "needle path: nodes %d and %d share no tissue edge",
                     nodes[i - 1], nodes[i]);
            return -1;
        }
    }
    p->node = malloc((size_t)count * sizeof *p->node);
    p->s = malloc((size_t)count * sizeof *p->s);
    if (!p->node || !p->s) {
        ns_needle_path_free(p);
        snprintf(err, (size_t)err_sz, "needle path: out of memory");
        return -1;
    }
    p->count = count;
    p->s[0] = 0.0;
    for (int i = 0; i < count; i++) {
        p->node[i] = nodes[i];
        if (i > 0)
            p->s[i] = p->s[i - 1] + dist3(m->u + 3 * nodes[i - 1], m->u + 3 * nodes[i]);
    }
    p->through = tip_s > p->s[count - 1];
    p->tip_s = p->through ? p->s[count - 1] : (tip_s > 0.0 ? tip_s : 0.0);
    p->margin = 0.05;
    return 0;
}

void ns_needle_path_free(NsNeedlePath *p)
{
    free(p->node);
    free(p->s);
    p->node = NULL;
    p->s = NULL;
    p->count = 0;
}

int ns_needle_path_tip(const NsNeedlePath *p, double *w)
{
    if (p->through)
        return -1;
    int k = 0;
    while (k + 2 < p->count && p->s[k + 1] < p->tip_s)
        k++;
    double len = p->s[k + 1] - p->s[k];
    double f = (p->tip_s - p->s[k]) / len;
    *w = f < 0.0 ? 0.0 : (f > 1.0 ? 1.0 : f);
    return k;
}

int ns_needle_path_behind(const NsNeedlePath *p)
{
    if (p->through)
        return p->count;
    int n = 0;
    while (n < p->count) {
        double len = n + 1 < p->count ? p->s[n + 1] - p->s[n] : p->s[n] - p->s[n - 1];
        if (p->s[n] > p->tip_s - p->margin * len)
            break;
        n++;
    }
    return n;
}

double ns_needle_path_cut_force(const NsNeedlePath *p, const NsMesh *m, const double *cut_force,
                                int count)
{
    double w;
    int k = ns_needle_path_tip(p, &w);
    if (k < 0)
        return 0.0;
    int a = p->node[k], b = p->node[k + 1];
    double f = 0.0;
    const NsIntList *l = &m->node_tets[a];
    for (int i = 0; i < l->count; i++) {
        int e = l->items[i];
        const int *tn = m->tet_node + 4 * e;
        int has_b = tn[0] == b || tn[1] == b || tn[2] == b || tn[3] == b;
        int r = m->tet_region[e];
        if (has_b && r >= 0 && r < count && cut_force[r] > f)
            f = cut_force[r];
    }
    return f;
}

/* cap < 0: allocations of count entries (a path of its own, ns_needle_path_init's). */
static void path_blank(void *e)
{
    NsNeedlePath *h = e;
    h->node = NULL;
    h->s = NULL;
}

static int path_pack(NsPack *p, NsNeedlePath *path, int cap)
{
    ns_pack_struct(p, "PATH", path, sizeof *path, path_blank);
    size_t n = (size_t)path->count, c = cap < 0 ? n : (size_t)cap;
    NS_PACK_ARRAY(p, path->node, n, c);
    NS_PACK_ARRAY(p, path->s, n, c);
    return p->failed ? -1 : 0;
}

int ns_needle_path_pack_cap(NsPack *p, NsNeedlePath *path, int cap)
{
    return path_pack(p, path, cap > 0 ? cap : 0);
}

int ns_needle_path_pack(NsPack *p, NsNeedlePath *path)
{
    return path_pack(p, path, -1);
}
