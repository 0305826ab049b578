/* The worst dihedral angle of a mesh over every state shown (sim/quality_watch.h): at rest by the
 * tets changed since the last look, in the world by all. The remesher's quality is a rest-mesh
 * property (paper §3.4.1: quality in material coordinates). */
#include "quality_watch.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "quality.h"

static double tet_min(const NsMesh *m, const double *X, int t)
{
    const int *tn = m->tet_node + 4 * t;
    return ns_tet_min_dihedral(X + 3 * tn[0], X + 3 * tn[1], X + 3 * tn[2], X + 3 * tn[3]);
}

double ns_mesh_min_dihedral(const NsMesh *m, bool use_world)
{
    const double *X = use_world ? m->x : m->u;
    double lo = 180.0;
    for (int t = 0; t < m->tet_slots; t++)
        if (ns_mesh_tet_alive(m, t))
            lo = fmin(lo, tet_min(m, X, t));
    return lo;
}

/* Room for m's slots in the copies. */
static int reserve(NsDihedralWatch *w, const NsMesh *m)
{
    if (m->node_slots > w->node_cap) {
        int cap = 2 * m->node_slots;
        double *u = realloc(w->u, (size_t)cap * 3 * sizeof *u);
        if (!u)
            return -1;
        w->u = u;
        unsigned char *mv = realloc(w->moved, (size_t)cap);
        if (!mv)
            return -1;
        w->moved = mv;
        w->node_cap = cap;
    }
    if (m->tet_slots > w->tet_cap) {
        int cap = 2 * m->tet_slots;
        int *tn = realloc(w->tet_node, (size_t)cap * 4 * sizeof *tn);
        if (!tn)
            return -1;
        w->tet_node = tn;
        w->tet_cap = cap;
    }
    return 0;
}

/* The copies := m. */
static void copy_mesh(NsDihedralWatch *w, const NsMesh *m)
{
    memcpy(w->u, m->u, (size_t)m->node_slots * 3 * sizeof *w->u);
    for (int t = 0; t < m->tet_slots; t++) {
        if (ns_mesh_tet_alive(m, t))
            memcpy(w->tet_node + 4 * t, m->tet_node + 4 * t, 4 * sizeof *w->tet_node);
        else
            for (int k = 0; k < 4; k++)
                w->tet_node[4 * t + k] = -1;
    }
    w->node_slots = m->node_slots;
    w->tet_slots = m->tet_slots;
}

int ns_dihedral_watch_init(NsDihedralWatch *w, const NsMesh *m)
{
    memset(w, 0, sizeof *w);
    if (reserve(w, m)) {
        ns_dihedral_watch_free(w);
        return -1;
    }
    copy_mesh(w, m);
    w->min_rest_deg = w->last_rest_deg = ns_mesh_min_dihedral(m, false);
    w->min_world_deg = ns_mesh_min_dihedral(m, true);
    w->looks = 1;
    return 0;
}

int ns_dihedral_watch_look(NsDihedralWatch *w, const NsMesh *m)
{
    if (reserve(w, m))
        return -1;
    /* Nodes whose material position changed (or whose slot is new). */
    for (int n = 0; n < m->node_slots; n++)
        w->moved[n] = n >= w->node_slots || memcmp(w->u + 3 * n, m->u + 3 * n, 3 * sizeof *w->u);
    double lo = 180.0;
    for (int t = 0; t < m->tet_slots; t++) {
        if (!ns_mesh_tet_alive(m, t))
            continue;
        const int *tn = m->tet_node + 4 * t;
        int changed = t >= w->tet_slots || memcmp(w->tet_node + 4 * t, tn, 4 * sizeof *tn) ||
                      w->moved[tn[0]] || w->moved[tn[1]] || w->moved[tn[2]] || w->moved[tn[3]];
        if (changed)
            lo = fmin(lo, tet_min(m, m->u, t));
    }
    w->last_rest_deg = lo;
    w->min_rest_deg = fmin(w->min_rest_deg, lo);
    w->min_world_deg = fmin(w->min_world_deg, ns_mesh_min_dihedral(m, true));
    copy_mesh(w, m);
    w->looks++;
    return 0;
}

void ns_dihedral_watch_free(NsDihedralWatch *w)
{
    free(w->u);
    free(w->tet_node);
    free(w->moved);
    memset(w, 0, sizeof *w);
}
