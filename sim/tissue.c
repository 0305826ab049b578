/* The tissue: FEM forces and lazily updated Jacobians (§3.2, §3.6.3) and the Newmark step with
 * one Newton iteration on the accelerations (§3.1, Eq. 1-5). */
#include "tissue.h"

#include "err.h"
#include "ns_config.h"
#include "snapshot.h"
#include "svd3.h"

#include <limits.h>
#include <math.h>
#include <metis.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#if NS_HAVE_OPENMP
#include <omp.h>
#endif

/* Entries of a tet's Jacobian strip for one node: its three rows of dF/dx, then of dF/dv
 * (NsTissue.tet_jac). */
#define JAC_STRIP 72
/* Calls between full gathers of K and D (see ns_tissue_forces). */
#define KD_REGATHER 256

NsTissueParams ns_default_tissue_params(void)
{
    NsTissueParams p;
    p.gravity[0] = p.gravity[1] = p.gravity[2] = 0.0;
    p.beta = 0.25;
    p.gamma = 0.5;
    p.lazy_threshold = 1e-2; /* fem-lazy: ~8% rebuilt, 0.1% error */
    p.solve_tol = 1e-8;
    p.solve_max_iter = 2000;
    p.threads = 1;
    return p;
}

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

void ns_tissue_free(NsTissue *t)
{
    ns_mesh_free(&t->mesh);
    free(t->materials);
    free(t->rest);
    free(t->frame);
    free(t->jframe);
    free(t->jprod);
    free(t->jvalid);
    free(t->jnew);
    free(t->djac_slot);
    free(t->djac);
    free(t->jprod_old);
    free(t->tet_force);
    free(t->tet_jac);
    free(t->part_node_start);
    free(t->part_nodes);
    free(t->part_tet_start);
    free(t->part_next);
    free(t->part_tets);
    free(t->node_part);
    free(t->colpos);
    free(t->mass);
    free(t->force);
    free(t->dof_fixed);
    free(t->was_alive);
    free(t->a_valid);
    free(t->rest_region);
    free(t->work);
    ns_bsm_free(&t->K);
    ns_bsm_free(&t->D);
    ns_bsm_free(&t->A);
    memset(t, 0, sizeof *t);
}

int ns_tissue_init(NsTissue *t, const NsMesh *mesh, const NsTissueMaterial *materials,
                   int material_count, const NsTissueParams *params, char *err, int err_sz)
{
    memset(t, 0, sizeof *t);
    if (ns_mesh_copy(&t->mesh, mesh)) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    t->params = params ? *params : ns_default_tissue_params();
    int nn = t->mesh.node_slots, nt = t->mesh.tet_slots;
    t->material_count = material_count;
    t->materials = malloc((size_t)(material_count > 0 ? material_count : 1) * sizeof *t->materials);
    t->rest = calloc((size_t)(nt > 0 ? nt : 1), sizeof *t->rest);
    t->frame = calloc((size_t)(nt > 0 ? nt : 1), sizeof *t->frame);
    t->jframe = calloc((size_t)(nt > 0 ? nt : 1), sizeof *t->jframe);
    t->jprod = calloc((size_t)(nt > 0 ? nt : 1) * 9, sizeof(double));
    t->jprod_old = calloc((size_t)(nt > 0 ? nt : 1) * 9, sizeof(double));
    t->jvalid = calloc((size_t)(nt > 0 ? nt : 1), 1);
    t->jnew = calloc((size_t)(nt > 0 ? nt : 1), 1);
    t->djac_slot = calloc((size_t)(nt > 0 ? nt : 1), sizeof(int));
    t->tet_force = calloc((size_t)(nt > 0 ? nt : 1) * 12, sizeof(double));
    t->tet_jac = calloc((size_t)(nt > 0 ? nt : 1) * 288, sizeof(double));
    t->mass = calloc((size_t)(nn > 0 ? nn : 1), sizeof(double));
    t->force = calloc((size_t)(3 * nn > 0 ? 3 * nn : 1), sizeof(double));
    t->dof_fixed = calloc((size_t)(3 * nn > 0 ? 3 * nn : 1), 1);
    t->work = calloc((size_t)(12 * nn > 0 ? 12 * nn : 1), sizeof(double));
    ns_bsm_init(&t->K);
    ns_bsm_init(&t->D);
    ns_bsm_init(&t->A);
    if (!t->materials || !t->rest || !t->frame || !t->jframe || !t->jprod || !t->jprod_old ||
        !t->jvalid || !t->jnew || !t->djac_slot || !t->tet_force || !t->tet_jac || !t->mass ||
        !t->force || !t->dof_fixed || !t->work || ns_bsm_resize(&t->K, nn) ||
        ns_bsm_resize(&t->D, nn) || ns_bsm_resize(&t->A, nn)) {
        ns_set_err(err, err_sz, "out of memory");
        ns_tissue_free(t);
        return -1;
    }
    for (int m = 0; m < material_count; m++) {
        const NsTissueMaterial *mt = &materials[m];
        if (!(mt->density > 0.0) || !(mt->fem.mu > 0.0) || !(mt->fem.lambda >= 0.0) ||
            !(mt->fem.damp_mu >= 0.0) || !(mt->fem.damp_lambda >= 0.0)) {
            ns_set_err(err, err_sz,
                       "material %d: density, moduli and damping must be positive "
                       "(density %g)",
                       m, mt->density);
            ns_tissue_free(t);
            return -1;
        }
        t->materials[m] = *mt;
    }
    const NsMesh *M = &t->mesh;
    for (int e = 0; e < nt; e++) {
        if (!ns_mesh_tet_alive(M, e))
            continue;
        const int *tn = M->tet_node + 4 * e;
        if (M->tet_region[e] >= material_count) {
            ns_set_err(err, err_sz, "tet %d has region %d, which has no material", e,
                       M->tet_region[e]);
            ns_tissue_free(t);
            return -1;
        }
        if (ns_fem_rest(M->u + 3 * tn[0], M->u + 3 * tn[1], M->u + 3 * tn[2], M->u + 3 * tn[3],
                        &t->rest[e])) {
            ns_set_err(err, err_sz, "tet %d is flat or inverted in material space (volume %g)", e,
                       t->rest[e].W);
            ns_tissue_free(t);
            return -1;
        }
        double m4 = t->materials[M->tet_region[e]].density * t->rest[e].W / 4.0;
        for (int k = 0; k < 4; k++)
            t->mass[tn[k]] += m4;
    }
    /* Held nodes, and slots with no node or no mass (nothing to solve for), are Dirichlet. */
    for (int i = 0; i < nn; i++)
        if ((M->flags[i] & NS_NODE_FIXED) || !(M->flags[i] & NS_NODE_ALIVE) || t->mass[i] <= 0.0)
            t->dof_fixed[3 * i] = t->dof_fixed[3 * i + 1] = t->dof_fixed[3 * i + 2] = 1;
    t->tet_cap = nt > 0 ? nt : 1;
    t->node_cap = nn > 0 ? nn : 1;
    t->was_alive = calloc((size_t)t->node_cap, 1);
    t->a_valid = calloc((size_t)t->node_cap, 1);
    t->rest_region = calloc((size_t)t->tet_cap, sizeof *t->rest_region);
    if (!t->was_alive || !t->a_valid || !t->rest_region) {
        ns_set_err(err, err_sz, "out of memory");
        ns_tissue_free(t);
        return -1;
    }
    for (int i = 0; i < nn; i++)
        t->was_alive[i] = (M->flags[i] & NS_NODE_ALIVE) != 0;
    for (int e = 0; e < nt; e++)
        t->rest_region[e] = ns_mesh_tet_alive(M, e) ? M->tet_region[e] : -1;
    return 0;
}

/* Grows *p from old to cap elements of size elem, zeroing the new ones. */
static int grow_zero(void **p, int old, int cap, size_t elem)
{
    void *q = realloc(*p, (size_t)cap * elem);
    if (!q)
        return -1;
    memset((char *)q + (size_t)old * elem, 0, (size_t)(cap - old) * elem);
    *p = q;
    return 0;
}

int ns_tissue_sync_topology(NsTissue *t, char *err, int err_sz)
{
    const NsMesh *M = &t->mesh;
    int nt = M->tet_slots, nn = M->node_slots;
    /* A sync that fails part-way leaves every row of K and D to be gathered again. */
    int kd_valid = t->kd_valid;
    t->kd_valid = 0;
    if (nt > t->tet_cap) {
        int cap = nt > 2 * t->tet_cap ? nt : 2 * t->tet_cap, old = t->tet_cap;
        if (grow_zero((void **)&t->rest, old, cap, sizeof *t->rest) ||
            grow_zero((void **)&t->frame, old, cap, sizeof *t->frame) ||
            grow_zero((void **)&t->jframe, old, cap, sizeof *t->jframe) ||
            grow_zero((void **)&t->jprod, old, cap, 9 * sizeof(double)) ||
            grow_zero((void **)&t->jprod_old, old, cap, 9 * sizeof(double)) ||
            grow_zero((void **)&t->jvalid, old, cap, 1) ||
            grow_zero((void **)&t->jnew, old, cap, 1) ||
            grow_zero((void **)&t->djac_slot, old, cap, sizeof(int)) ||
            grow_zero((void **)&t->tet_force, old, cap, 12 * sizeof(double)) ||
            grow_zero((void **)&t->tet_jac, old, cap, 288 * sizeof(double)) ||
            grow_zero((void **)&t->rest_region, old, cap, sizeof(int))) {
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
        t->tet_cap = cap;
    }
    if (nn > t->node_cap) {
        int cap = nn > 2 * t->node_cap ? nn : 2 * t->node_cap, old = t->node_cap;
        if (grow_zero((void **)&t->mass, old, cap, sizeof(double)) ||
            grow_zero((void **)&t->force, old, cap, 3 * sizeof(double)) ||
            grow_zero((void **)&t->dof_fixed, old, cap, 3) ||
            grow_zero((void **)&t->was_alive, old, cap, 1) ||
            grow_zero((void **)&t->a_valid, old, cap, 1) ||
            grow_zero((void **)&t->work, old, cap, 12 * sizeof(double))) {
            ns_set_err(err, err_sz, "out of memory");
            return -1;
        }
        for (int i = old; i < cap; i++) /* empty slots are Dirichlet */
            t->dof_fixed[3 * i] = t->dof_fixed[3 * i + 1] = t->dof_fixed[3 * i + 2] = 1;
        t->node_cap = cap;
    }
    int a_rows = t->A.n;
    if (ns_bsm_resize(&t->K, nn) || ns_bsm_resize(&t->D, nn) || ns_bsm_resize(&t->A, nn)) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    for (int i = a_rows; i < nn; i++) /* rows new to A (or emptied and grown back) */
        t->a_valid[i] = 0;
    /* Rest data: recomputed for every tet, the Jacobians of changed ones marked stale; the
     * masses summed again into work (a row of A whose mass changed is written again). */
    double *mass_new = t->work;
    memset(mass_new, 0, (size_t)nn * sizeof(double));
    /* Each tet writes only its own entries, so the tets are split over the threads; a bad tet
     * (no material, flat or inverted) is reported by its lowest index, as a serial loop would. */
    int threads = t->params.threads > 1 ? t->params.threads : 1, bad = INT_MAX;
    (void)threads;
#if NS_HAVE_OPENMP
#pragma omp parallel for num_threads(threads) schedule(static)                                     \
    reduction(min                                                                                  \
              : bad) if (threads > 1 && nt >= 4096)
#endif
    for (int e = 0; e < nt; e++) {
        if (!ns_mesh_tet_alive(M, e)) {
            t->jvalid[e] = 0;
            continue;
        }
        const int *tn = M->tet_node + 4 * e;
        NsTetRest r;
        if (M->tet_region[e] >= t->material_count ||
            ns_fem_rest(M->u + 3 * tn[0], M->u + 3 * tn[1], M->u + 3 * tn[2], M->u + 3 * tn[3],
                        &r)) {
            bad = e < bad ? e : bad;
            continue;
        }
        /* A changed shape or material (a reused slot) invalidates the tet's Jacobians. */
        if (memcmp(&r, &t->rest[e], sizeof r) != 0 || t->rest_region[e] != M->tet_region[e]) {
            t->rest[e] = r;
            t->rest_region[e] = M->tet_region[e];
            t->jvalid[e] = 0;
        }
    }
    if (bad < nt) {
        const int *tn = M->tet_node + 4 * bad;
        NsTetRest r;
        if (M->tet_region[bad] >= t->material_count)
            ns_set_err(err, err_sz, "tet %d has region %d, which has no material", bad,
                       M->tet_region[bad]);
        else if (ns_fem_rest(M->u + 3 * tn[0], M->u + 3 * tn[1], M->u + 3 * tn[2], M->u + 3 * tn[3],
                             &r))
            ns_set_err(err, err_sz, "tet %d is flat or inverted in material space (volume %g)", bad,
                       r.W);
        return -1;
    }
    for (int e = 0; e < nt; e++) { /* in tet order: the same sums on any thread count */
        if (!ns_mesh_tet_alive(M, e))
            continue;
        const int *tn = M->tet_node + 4 * e;
        double m4 = t->materials[M->tet_region[e]].density * t->rest[e].W / 4.0;
        for (int k = 0; k < 4; k++)
            mass_new[tn[k]] += m4;
    }
    for (int i = 0; i < nn; i++) {
        if (memcmp(&mass_new[i], &t->mass[i], sizeof(double)) != 0)
            t->a_valid[i] = 0;
        t->mass[i] = mass_new[i];
    }
    /* DOFs: new nodes free (unless flagged fixed), removed ones fixed, others as they were. */
    for (int i = 0; i < nn; i++) {
        int alive = (M->flags[i] & NS_NODE_ALIVE) != 0;
        uint8_t *f = t->dof_fixed + 3 * i;
        if (alive && !t->was_alive[i])
            f[0] = f[1] = f[2] = (M->flags[i] & NS_NODE_FIXED) != 0;
        if (!alive || t->mass[i] <= 0.0)
            f[0] = f[1] = f[2] = 1;
        t->was_alive[i] = (uint8_t)alive;
    }
    t->kd_valid = kd_valid; /* only the rows of nodes whose tets changed are gathered again */
    return 0;
}

void ns_tissue_fix_dof(NsTissue *t, int node, int axis, int fixed)
{
    if (node >= 0 && node < t->mesh.node_slots && axis >= 0 && axis < 3)
        t->dof_fixed[3 * node + axis] = (uint8_t)(fixed != 0);
}

static void frame_product(const NsTetFrame *f, int with_s, double out[9])
{
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            double v = 0.0;
            for (int k = 0; k < 3; k++)
                v += f->U[3 * i + k] * (with_s ? f->s[k] : 1.0) * f->V[3 * j + k];
            out[3 * i + j] = v;
        }
}

/* How much the tet's Jacobian may have changed since it was built (§3.6.3): the largest change
 * of an entry of now against then, each R = U V^T (all the corotational Jacobian depends on) or,
 * for neo-Hookean, F = U S V^T (frame_product), now's of the current frame and then's of the
 * frame the Jacobian was built from. Unlike U and V alone, both are well defined when singular
 * values repeat. */
static double jacobian_change(const double now[9], const double then[9])
{
    double e = 0.0;
    for (int i = 0; i < 9; i++) {
        double d = fabs(now[i] - then[i]);
        e = d > e ? d : e;
    }
    return e;
}

/* The neo-Hookean tangent is made definite (Teran 2005) only for clearly compressed or
 * inverted tets: near rest its rotational eigenvalue lambda log J crosses zero, and clamping it
 * there would make the one-Newton-step linearization inexact for no gain in robustness. */
static int needs_projection(const NsTetFrame *f)
{
    return f->s[2] < NS_TISSUE_PROJECT_BELOW;
}

/* ---- Parallel, deterministic assembly (§3.6.3) --------------------------------------------
 *
 * The paper scatters each tet's forces and Jacobian blocks straight into shared storage from
 * several threads, with METIS keeping the threads' entries mostly apart. Floating-point sums
 * taken in a thread-dependent order would make the state depend on the thread count, so we
 * split the work in two phases with no shared accumulation at all:
 *   1. per tet: forces into tet_force, and for a stale tet its element K and D into tet_jac
 *      (kept between steps: the lazy update never has to rebuild an old contribution to
 *      take it out again); a corotational tet keeps only the rotation they are a closed form
 *      of (jprod) and the one before it (jprod_old);
 *   2. per node: its force is the sum of its incident tets' force rows, and a block row of K
 *      and D touched by a rebuilt tet takes that tet's change (new minus old: computed in
 *      phase 1, or for a corotational tet here from its two rotations, ns_fem_corot_row), as
 *      the paper's incremental update does; a row whose tets changed in number or shape
 *      (remeshing), or one whose change was not kept, is zeroed and summed again.
 * Every sum in phase 2 runs over the mesh's node->tet list in list order, so the result does not
 * depend on which thread did what. Adding changes drifts from a fresh sum by one rounding per
 * change (1e-15 relative in tests/test_threads.c), so every row is summed afresh every
 * KD_REGATHER calls. Block row i of K and D is written only by the thread that takes node i
 * (ns_bsm_get(m, i, j) grows row i alone). */

/* The part owning most of the tet's nodes (ties: the one met first in the tet's node order). */
static int tet_part(const int *part, const int *tn)
{
    int best = part[tn[0]], best_n = 0;
    for (int a = 0; a < 4; a++) {
        int n = 0;
        for (int b = 0; b < 4; b++)
            n += part[tn[b]] == part[tn[a]];
        if (n > best_n) {
            best = part[tn[a]];
            best_n = n;
        }
    }
    return best;
}

#define NS_TISSUE_MAX_PARTS 64 /* partitions with more parts are always made by METIS */

/* The part most of node i's neighbours by tet had in the last partition (its first old slots),
 * ties to the lowest; 0 with none. */
static int neighbour_part(const NsTissue *t, int i, int parts, int old)
{
    const NsMesh *M = &t->mesh;
    const NsIntList *l = &M->node_tets[i];
    int count[NS_TISSUE_MAX_PARTS] = {0}, p = 0;
    for (int q = 0; q < l->count; q++)
        for (int b = 0; b < 4; b++) {
            int j = M->tet_node[4 * l->items[q] + b];
            if (j != i && j < old && t->node_part[j] >= 0 && t->node_part[j] < parts)
                count[t->node_part[j]]++;
        }
    for (int k = 1; k < parts; k++)
        if (count[k] > count[p])
            p = k;
    return p;
}

/* The last partition, patched for a changed mesh into part (node slots): nodes keep their
 * part; a node slot with none (new, or beyond the last partition) takes the part most of its
 * neighbours by tet have, else part 0. The caller checks that the last partition had this many
 * parts. Returns -1 (METIS must run again) when there is no last partition to patch, after 64
 * patches in a row, or when the parts' weights (incident tets) drift more than 15 % from an
 * even split. The partition never changes a result, so neither does patching it. */
static int patch_partition(NsTissue *t, int parts, int *part)
{
    const NsMesh *M = &t->mesh;
    int nn = M->node_slots, old = t->part_node_slots;
    if (!t->node_part || t->part_metis_age < 0 || t->part_metis_age >= 64 || old > t->node_part_cap)
        return -1;
    long weight[NS_TISSUE_MAX_PARTS] = {0}, total = 0;
    if (parts > NS_TISSUE_MAX_PARTS)
        return -1;
    for (int i = 0; i < nn; i++) {
        int p = i < old ? t->node_part[i] : -1;
        part[i] = p >= 0 && p < parts ? p : neighbour_part(t, i, parts, old);
        p = part[i];
        if (M->flags[i] & NS_NODE_ALIVE) {
            weight[p] += M->node_tets[i].count;
            total += M->node_tets[i].count;
        }
    }
    for (int k = 0; k < parts; k++)
        if (total > 0 && labs(weight[k] * parts - total) * 100 > 15 * total)
            return -1;
    return 0;
}

/* METIS's k-way partition of the graph of alive nodes (compacted) joined by tet edges, vertex
 * weight = incident tets, which is what phase 1 costs per node once tets go to their nodes'
 * part: written into part (node_slots) where METIS succeeds, left as it was elsewhere. */
static void metis_partition(const NsMesh *M, int parts, int *part)
{
    int nn = M->node_slots;
    idx_t nv = 0, ncon = 1, np = parts, cut = 0;
    size_t adj_max = 0;
    for (int i = 0; i < nn; i++)
        if (M->flags[i] & NS_NODE_ALIVE) {
            nv++;
            adj_max += 3 * (size_t)M->node_tets[i].count;
        }
    idx_t *vid = malloc((size_t)(nn > 0 ? nn : 1) * sizeof *vid);
    idx_t *xadj = malloc((size_t)(nv + 1) * sizeof *xadj);
    idx_t *adj = malloc((adj_max > 0 ? adj_max : 1) * sizeof *adj);
    idx_t *vwgt = malloc((size_t)(nv > 0 ? nv : 1) * sizeof *vwgt);
    idx_t *vpart = malloc((size_t)(nv > 0 ? nv : 1) * sizeof *vpart);
    int *seen = malloc((size_t)(nn > 0 ? nn : 1) * sizeof *seen);
    if (vid && xadj && adj && vwgt && vpart && seen && nv > parts) {
        idx_t v = 0;
        for (int i = 0; i < nn; i++) {
            vid[i] = (M->flags[i] & NS_NODE_ALIVE) ? v++ : -1;
            seen[i] = -1;
        }
        idx_t k = 0;
        v = 0;
        for (int i = 0; i < nn; i++) {
            if (vid[i] < 0)
                continue;
            const NsIntList *l = &M->node_tets[i];
            xadj[v] = k;
            vwgt[v] = l->count > 0 ? l->count : 1;
            for (int q = 0; q < l->count; q++) {
                const int *tn = M->tet_node + 4 * l->items[q];
                for (int b = 0; b < 4; b++)
                    if (tn[b] != i && seen[tn[b]] != i && vid[tn[b]] >= 0) {
                        seen[tn[b]] = i;
                        adj[k++] = vid[tn[b]];
                    }
            }
            v++;
        }
        xadj[nv] = k;
        idx_t opt[METIS_NOPTIONS];
        METIS_SetDefaultOptions(opt);
        opt[METIS_OPTION_SEED] = 1; /* the same partition every run, for stable timings */
        if (METIS_PartGraphKway(&nv, &ncon, xadj, adj, vwgt, NULL, NULL, &np, NULL, NULL, opt, &cut,
                                vpart) == METIS_OK)
            for (int i = 0; i < nn; i++)
                if (vid[i] >= 0 && vpart[vid[i]] >= 0 && vpart[vid[i]] < parts)
                    part[i] = (int)vpart[vid[i]];
    }
    free(vid);
    free(xadj);
    free(adj);
    free(vwgt);
    free(vpart);
    free(seen);
}

/* Work partition: METIS splits the node graph into one part per thread, so that a thread's tets
 * and block rows sit together and few tets straddle parts (§3.6.3). A tet goes to the part that
 * owns most of its nodes. The partition only decides who does what, for speed and locality; it
 * never changes a result. Returns 0, or -1 when out of memory (the caller then runs serially). */
static int partition(NsTissue *t, int parts)
{
    const NsMesh *M = &t->mesh;
    int nn = M->node_slots, nt = M->tet_slots;
    if (t->part_node_start && t->part_count == parts && t->part_version == M->topology_version &&
        t->part_node_slots == nn && t->part_tet_slots == nt)
        return 0;
    int prev_parts = t->part_count;
    t->part_count = 0;
    int *ns = realloc(t->part_node_start, (size_t)(parts + 1) * sizeof(int));
    if (ns)
        t->part_node_start = ns;
    int *ts = realloc(t->part_tet_start, (size_t)(parts + 1) * sizeof(int));
    if (ts)
        t->part_tet_start = ts;
    int *nx = realloc(t->part_next, (size_t)(2 * parts) * sizeof(int));
    if (nx)
        t->part_next = nx;
    int *pn = realloc(t->part_nodes, (size_t)(nn > 0 ? nn : 1) * sizeof(int));
    if (pn)
        t->part_nodes = pn;
    int *pt = realloc(t->part_tets, (size_t)(nt > 0 ? nt : 1) * sizeof(int));
    if (pt)
        t->part_tets = pt;
    size_t ncol = (size_t)(t->K.n > nn ? t->K.n : nn);
    int *cp = realloc(t->colpos, (size_t)parts * (ncol > 0 ? ncol : 1) * sizeof(int));
    if (cp) {
        t->colpos = cp;
        t->colpos_len = (size_t)parts * (ncol > 0 ? ncol : 1);
    }
    int *part = malloc((size_t)(nn > 0 ? nn : 1) * sizeof(int));
    if (!ns || !ts || !nx || !pn || !pt || !cp || !part) {
        free(part);
        return -1;
    }
    for (size_t k = 0; k < (size_t)parts * ncol; k++)
        cp[k] = -1;
    /* After a remeshing step the last partition is patched rather than made again: METIS took
     * ~0.4 ms a call on one thread, in ~70 % of the brachytherapy steps. */
    int patched = parts > 1 && prev_parts == parts && patch_partition(t, parts, part) == 0;
    /* Otherwise contiguous ranges of node indices: the answer for one part, and the fallback
     * (over whatever a rejected patch wrote). */
    if (!patched)
        for (int i = 0; i < nn; i++)
            part[i] = (int)((int64_t)i * parts / nn);
    if (patched) {
        t->part_metis_age++;
    } else if (parts > 1) {
        metis_partition(M, parts, part);
        t->part_metis_age = 0;
    }
    if (parts > 1 && nn > t->node_part_cap) {
        int *np = realloc(t->node_part, (size_t)nn * sizeof *np);
        if (np) {
            t->node_part = np;
            t->node_part_cap = nn;
        }
    }
    if (parts > 1 && t->node_part && nn <= t->node_part_cap) {
        /* Dead slots keep no part: a slot dead now and reused by the next partition votes with
         * its neighbours (one that dies and is reused in between keeps its part: locality
         * only, never a result). */
        for (int i = 0; i < nn; i++)
            t->node_part[i] = (M->flags[i] & NS_NODE_ALIVE) ? part[i] : -1;
    } else
        t->part_metis_age = -1; /* nothing to patch next time */

    /* Nodes and tets grouped by part (counting sort, ascending index within a part). */
    memset(ns, 0, (size_t)(parts + 1) * sizeof(int));
    memset(ts, 0, (size_t)(parts + 1) * sizeof(int));
    for (int i = 0; i < nn; i++)
        ns[part[i] + 1]++;
    /* each tet's part (-1: dead), once (tet_part is most of this), in part's storage: its
     * first nn entries are read above and below, so the tets' go after them */
    int *tp = realloc(part, ((size_t)nn + (size_t)nt + 1) * sizeof(int));
    if (!tp) {
        free(part);
        return -1;
    }
    part = tp;
    tp = part + nn;
    for (int e = 0; e < nt; e++) {
        tp[e] = ns_mesh_tet_alive(M, e) ? tet_part(part, M->tet_node + 4 * e) : -1;
        if (tp[e] >= 0)
            ts[tp[e] + 1]++;
    }
    for (int p = 0; p < parts; p++) {
        ns[p + 1] += ns[p];
        ts[p + 1] += ts[p];
    }
    for (int i = 0; i < nn; i++)
        pn[ns[part[i]]++] = i;
    for (int e = 0; e < nt; e++)
        if (tp[e] >= 0)
            pt[ts[tp[e]]++] = e;
    for (int p = parts; p > 0; p--) {
        ns[p] = ns[p - 1];
        ts[p] = ts[p - 1];
    }
    ns[0] = ts[0] = 0;
    free(part);
    t->part_count = parts;
    t->part_version = M->topology_version;
    t->part_node_slots = nn;
    t->part_tet_slots = nt;
    return 0;
}

typedef struct AssemblyCounts {
    int alive, updated, inverted, nan;
    int rows_gathered, rows_changed; /* block rows of K and D summed again / by changes */
    double jacobian_ms;              /* time spent on Jacobians by one thread */
} AssemblyCounts;

/* A rebuilt tet's element K and D (any model) into tet_jac, and their change into a slot of
 * djac when it had valid ones. */
static void elastic_jacobians(NsTissue *t, int e, const NsTissueMaterial *mat)
{
    double K[144], D[144], *J = t->tet_jac + 288 * (size_t)e;
    ns_fem_tet_jacobians(&t->rest[e], &mat->fem, &t->frame[e], needs_projection(&t->frame[e]), K,
                         D);
    /* The change since the Jacobians its rows hold (a valid tet's last ones), for phase 2 to
     * add instead of gathering the rows again. Which tet gets which slot depends on the
     * threads, but not whether all fit: if more changed than djac holds, phase 2 gathers
     * every touched row (the same on any thread count), and djac grows for the next call. */
    int slot = -1;
    if (t->jvalid[e]) {
#if NS_HAVE_OPENMP
#pragma omp atomic capture
#endif
        slot = t->djac_count++;
    }
    t->djac_slot[e] = slot;
    double *dJ = slot >= 0 && slot < t->djac_cap ? t->djac + 288 * (size_t)slot : NULL;
    for (int a = 0; a < 4; a++) { /* node a's strips side by side: see JAC_STRIP */
        double *Ja = J + JAC_STRIP * a;
        if (dJ)
            for (int k = 0; k < 36; k++) {
                dJ[JAC_STRIP * a + k] = K[36 * a + k] - Ja[k];
                dJ[JAC_STRIP * a + 36 + k] = D[36 * a + k] - Ja[36 + k];
            }
        memcpy(Ja, K + 36 * a, 36 * sizeof(double));
        memcpy(Ja + 36, D + 36 * a, 36 * sizeof(double));
    }
}

/* Phase 1 for tet e after its forces (tet_phase_n): their check, and its Jacobians when due.
 * Writes only tet e's own slots. */
static void tet_phase(NsTissue *t, int e, AssemblyCounts *c)
{
    const NsMesh *M = &t->mesh;
    const NsTissueMaterial *mat = &t->materials[M->tet_region[e]];
    double *f = t->tet_force + 12 * (size_t)e; /* computed by tet_phase_n */
    for (int k = 0; k < 12; k++)
        if (!isfinite(f[k])) {
            c->nan++;
            f[k] = 0.0;
        }
    c->alive++;
    c->inverted += t->frame[e].s[2] <= 0.0;
    double *jprod = t->jprod + 9 * (size_t)e, prod[9];
    frame_product(&t->frame[e], mat->fem.model == NS_MODEL_NEOHOOKEAN, prod);
    t->jnew[e] = 0;
    if (!t->jvalid[e] || jacobian_change(prod, jprod) > t->params.lazy_threshold) {
        double tj0 = now_ms();
        if (mat->fem.model == NS_MODEL_COROTATIONAL) {
            /* The corotational Jacobians are a closed form in R = jprod (ns_fem_corot_row):
             * phase 2 makes the rows, or their change, from it and the old R kept here, with
             * no 288-entry element matrices written and read back (on the brachytherapy
             * bench the rebuilds come in waves of up to half the tets). */
            memcpy(t->jprod_old + 9 * (size_t)e, jprod, 9 * sizeof(double));
            t->djac_slot[e] = t->jvalid[e] ? NS_TISSUE_CLOSED_FORM : -1;
        } else
            elastic_jacobians(t, e, mat);
        t->jframe[e] = t->frame[e];
        memcpy(jprod, prod, sizeof prod);
        t->jvalid[e] = 1;
        t->jnew[e] = 1;
        c->updated++;
        c->jacobian_ms += now_ms() - tj0;
    }
}

/* Phase 1 for the tets es[0..n): in batches of SVD_BATCH, their deformation gradients' SVDs
 * (§3.2) and their forces (ns_svd3_n, ns_fem_tet_forces_svd_n: the same bits as one at a time,
 * several at once on vector lanes), then each tet's Jacobians when due (tet_phase). */
#define SVD_BATCH 8
static void tet_phase_n(NsTissue *t, const int *es, int n, AssemblyCounts *c)
{
    const NsMesh *M = &t->mesh;
    for (int k0 = 0; k0 < n; k0 += SVD_BATCH) {
        int m = n - k0 < SVD_BATCH ? n - k0 : SVD_BATCH;
        double F[SVD_BATCH][9];
        const double *Fp[SVD_BATCH];
        double *U[SVD_BATCH], *s[SVD_BATCH], *V[SVD_BATCH];
        for (int k = 0; k < m; k++) {
            int e = es[k0 + k];
            const int *tn = M->tet_node + 4 * e;
            const double *x[4] = {M->x + 3 * tn[0], M->x + 3 * tn[1], M->x + 3 * tn[2],
                                  M->x + 3 * tn[3]};
            ns_fem_tet_gradient(&t->rest[e], x, F[k]);
            Fp[k] = F[k];
            U[k] = t->frame[e].U;
            s[k] = t->frame[e].s;
            V[k] = t->frame[e].V;
        }
        ns_svd3_n(m, Fp, U, s, V);
        const NsTetRest *rp[SVD_BATCH];
        const NsFemMaterial *mp[SVD_BATCH];
        const double *vn[SVD_BATCH][4];
        const double *const *vp[SVD_BATCH];
        double *fp[SVD_BATCH];
        const NsTetFrame *frp[SVD_BATCH];
        for (int k = 0; k < m; k++) {
            int e = es[k0 + k];
            const int *tn = M->tet_node + 4 * e;
            for (int a = 0; a < 4; a++)
                vn[k][a] = M->v + 3 * tn[a];
            rp[k] = &t->rest[e];
            mp[k] = &t->materials[M->tet_region[e]].fem;
            vp[k] = vn[k];
            fp[k] = t->tet_force + 12 * (size_t)e;
            frp[k] = &t->frame[e];
        }
        ns_fem_tet_forces_svd_n(m, rp, mp, vp, fp, frp);
        for (int k = 0; k < m; k++)
            tet_phase(t, es[k0 + k], c);
    }
}

/* Local index (0-3) of node i in tet tn. */
static int local_index(const int *tn, int i)
{
    return tn[0] == i ? 0 : tn[1] == i ? 1 : tn[2] == i ? 2 : 3;
}

/* Phase 2, force of node i: its incident tets' rows in node->tet list order, then gravity. */
static void node_force(NsTissue *t, int i)
{
    const NsMesh *M = &t->mesh;
    double f[3] = {0.0, 0.0, 0.0};
    if (M->flags[i] & NS_NODE_ALIVE) {
        const NsIntList *l = &M->node_tets[i];
        for (int q = 0; q < l->count; q++) {
            int e = l->items[q];
            const double *fe =
                t->tet_force + 12 * (size_t)e + 3 * local_index(M->tet_node + 4 * e, i);
            for (int c = 0; c < 3; c++)
                f[c] += fe[c];
        }
    }
    for (int c = 0; c < 3; c++)
        t->force[3 * i + c] = f[c] + t->mass[i] * t->params.gravity[c];
}

/* Prefetch the part of tet e's element Jacobians that row i will read (rows 3a..3a+2 of K and
 * D): the tets around a node lie anywhere in memory, and the gather is bound by fetching them. */
static void prefetch_strip(const NsTissue *t, int e, int i)
{
#if defined(__GNUC__)
    if (t->materials[t->mesh.tet_region[e]].fem.model == NS_MODEL_COROTATIONAL) {
        /* its rows come from R and the rest data (ns_fem_corot_row) */
        __builtin_prefetch(t->jprod + 9 * (size_t)e);
        __builtin_prefetch(&t->rest[e]);
        return;
    }
    const char *p = (const char *)(t->tet_jac + 288 * (size_t)e +
                                   JAC_STRIP * local_index(t->mesh.tet_node + 4 * e, i));
    for (int z = 0; z < JAC_STRIP * (int)sizeof(double); z += 64)
        __builtin_prefetch(p + z);
    __builtin_prefetch(p + JAC_STRIP * sizeof(double) - 1); /* the last line, if p is unaligned */
#else
    (void)t, (void)e, (void)i;
#endif
}

/* kb += the 3x3 block at Ke (row stride 12), db likewise from De. */
static void add_block(double *restrict kb, double *restrict db, const double *restrict Ke,
                      const double *restrict De)
{
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) {
            kb[3 * r + c] += Ke[12 * r + c];
            db[3 * r + c] += De[12 * r + c];
        }
}

/* Phase 2, block row i of K and D by differences (§3.6.3: only the rebuilt tets'
 * contributions change): each rebuilt incident tet's change in node-tet list order, its column
 * positions found through colpos. Returns 0, or -1 when the row cannot take them that way (no
 * scratch, K's and D's patterns differ, a column missing): the caller gathers it. */
static int row_add_changes(NsTissue *t, int i, int *colpos)
{
    const NsMesh *M = &t->mesh;
    const NsIntList *l = &M->node_tets[i];
    NsBlockRow *kr = &t->K.rows[i], *dr = &t->D.rows[i];
    if (!colpos || kr->count != dr->count ||
        memcmp(kr->col, dr->col, (size_t)kr->count * sizeof(int)) != 0)
        return -1;
    for (int p = 0; p < kr->count; p++)
        colpos[kr->col[p]] = p;
    int ok = 1;
    for (int q = 0; q < l->count && ok; q++) {
        int e = l->items[q];
        const int *tn = M->tet_node + 4 * e;
        ok = !t->jnew[e] ||
             (colpos[tn[0]] >= 0 && colpos[tn[1]] >= 0 && colpos[tn[2]] >= 0 && colpos[tn[3]] >= 0);
    }
    for (int q = 0; q < l->count && ok; q++) {
        int e = l->items[q];
        if (!t->jnew[e])
            continue;
        const int *tn = M->tet_node + 4 * e;
        if (t->djac_slot[e] == NS_TISSUE_CLOSED_FORM) {
            double *kb[4], *db[4];
            for (int b = 0; b < 4; b++) {
                kb[b] = kr->val + 9 * colpos[tn[b]];
                db[b] = dr->val + 9 * colpos[tn[b]];
            }
            ns_fem_corot_row(&t->rest[e], &t->materials[M->tet_region[e]].fem,
                             t->jprod + 9 * (size_t)e, t->jprod_old + 9 * (size_t)e,
                             local_index(tn, i), kb, db);
            continue;
        }
        const double *Ke = t->djac + 288 * (size_t)t->djac_slot[e] + JAC_STRIP * local_index(tn, i);
        for (int b = 0; b < 4; b++)
            add_block(kr->val + 9 * colpos[tn[b]], dr->val + 9 * colpos[tn[b]], Ke + 3 * b,
                      Ke + 36 + 3 * b);
    }
    for (int p = 0; p < kr->count; p++)
        colpos[kr->col[p]] = -1;
    return ok ? 0 : -1;
}

/* Phase 2, block row i of K and D: if incident tets were rebuilt and all their changes were
 * kept, those changes are added (row_add_changes); gathered again if its list of tets changed
 * since the last gather (remeshing: mesh.node_changed), a rebuilt tet's change was not kept, or
 * all_rows: zeroed, then every incident tet's blocks (i, j) added in node->tet list order. colpos
 * (node slots, all -1, may be NULL) maps a column to its position in the row while the row is
 * gathered, which saves a search per block when K and D already store every block the tets
 * need (always, after the first gather); otherwise blocks are found, or inserted, one by one.
 * Returns -1 if a block could not be stored (memory), else 0. */
static int node_rows(NsTissue *t, int i, int all_rows, int *colpos, AssemblyCounts *c)
{
    const NsMesh *M = &t->mesh;
    const NsIntList *l = (M->flags[i] & NS_NODE_ALIVE) ? &M->node_tets[i] : NULL;
    int n = l ? l->count : 0, dirty = all_rows || M->node_changed[i] > t->kd_version;
    int changed = 0; /* rebuilt tets, all with their change kept */
    for (int q = 0; q < n && !dirty; q++) {
        int e = l->items[q];
        if (t->jnew[e]) {
            changed = 1;
            dirty = t->djac_slot[e] != NS_TISSUE_CLOSED_FORM &&
                    (t->djac_slot[e] < 0 || t->djac_count > t->djac_cap);
        }
    }
    if (!dirty && !changed)
        return 0;
    t->a_valid[i] = 0; /* K's or D's row changes: A's must be written again */
    if (!dirty && changed && row_add_changes(t, i, colpos) == 0) {
        c->rows_changed++;
        return 0;
    }
    c->rows_gathered++;
    NsBlockRow *kr = &t->K.rows[i], *dr = &t->D.rows[i];
    if (kr->count)
        memset(kr->val, 0, (size_t)kr->count * 9 * sizeof(double));
    if (dr->count)
        memset(dr->val, 0, (size_t)dr->count * 9 * sizeof(double));
    int fast = colpos && kr->count == dr->count &&
               (kr->count == 0 || memcmp(kr->col, dr->col, (size_t)kr->count * sizeof(int)) == 0);
    if (fast) {
        for (int p = 0; p < kr->count; p++)
            colpos[kr->col[p]] = p;
        for (int q = 0; q < n && fast; q++) {
            const int *tn = M->tet_node + 4 * l->items[q];
            fast = colpos[tn[0]] >= 0 && colpos[tn[1]] >= 0 && colpos[tn[2]] >= 0 &&
                   colpos[tn[3]] >= 0;
        }
    }
    int rc = 0;
    for (int q = 0; q < n; q++) {
        int e = l->items[q];
        const int *tn = M->tet_node + 4 * e;
        int a = local_index(tn, i);
        if (q + 1 < n)
            prefetch_strip(t, l->items[q + 1], i);
        if (t->materials[M->tet_region[e]].fem.model == NS_MODEL_COROTATIONAL) {
            /* closed form (ns_fem_corot_row): nothing stored in tet_jac */
            double kl[4][9] = {{0}}, dl[4][9] = {{0}}, *kb[4], *db[4];
            for (int b = 0; b < 4; b++) {
                kb[b] = fast ? kr->val + 9 * colpos[tn[b]] : kl[b];
                db[b] = fast ? dr->val + 9 * colpos[tn[b]] : dl[b];
            }
            ns_fem_corot_row(&t->rest[e], &t->materials[M->tet_region[e]].fem,
                             t->jprod + 9 * (size_t)e, NULL, a, kb, db);
            for (int b = 0; b < 4 && !fast; b++) {
                double *kg = ns_bsm_get(&t->K, i, tn[b]), *dg = ns_bsm_get(&t->D, i, tn[b]);
                if (!kg || !dg) {
                    rc = -1;
                    continue;
                }
                for (int k = 0; k < 9; k++) {
                    kg[k] += kl[b][k];
                    dg[k] += dl[b][k];
                }
            }
            continue;
        }
        const double *Ke = t->tet_jac + 288 * (size_t)e + JAC_STRIP * a, *De = Ke + 36;
        if (fast) {
            for (int b = 0; b < 4; b++)
                add_block(kr->val + 9 * colpos[tn[b]], dr->val + 9 * colpos[tn[b]], Ke + 3 * b,
                          De + 3 * b);
            continue;
        }
        for (int b = 0; b < 4; b++) {
            double *kb = ns_bsm_get(&t->K, i, tn[b]), *db = ns_bsm_get(&t->D, i, tn[b]);
            if (kb && db)
                add_block(kb, db, Ke + 3 * b, De + 3 * b);
            else
                rc = -1;
        }
    }
    if (colpos)
        for (int p = 0; p < kr->count; p++)
            colpos[kr->col[p]] = -1;
    return rc;
}

/* Dynamic load balance of the two phases. The tets near the needle rebuild their Jacobians and
 * their block rows are gathered again, so a part's work depends on where the needle is, not only
 * on its size: measured on the brachytherapy bench, the two threads' phase 1 differed by 1.6-2.9
 * ms in many steps, one of them waiting at the barrier. So each part is cut into chunks, taken
 * one at a time through an atomic counter per part: a thread takes its own parts' chunks first
 * (p = tid, tid + nth, ...), then the others'. Every tet's phase-1 work writes only its own
 * slots, and every node's phase-2 sums are made whole by whichever thread takes its chunk, in
 * the order of its tet list: the result is the same bits whoever does which chunk. */
#define TET_CHUNK  512
#define NODE_CHUNK 128

/* The next chunk for thread tid: chunk index c (part c % parts, its c / parts-th chunk of
 * size), or -1 when every part is done. counters: one per part. */
static int next_chunk(int *counters, int parts, int tid, int nth, const int *start, int size)
{
    for (int round = 0; round < 2; round++)
        for (int q = 0; q < parts; q++) {
            int p = (tid + q) % parts;
            if ((round == 0) != (p % nth == tid % nth)) /* own parts first, then the rest */
                continue;
            int n = (start[p + 1] - start[p] + size - 1) / size, k;
#if NS_HAVE_OPENMP
#pragma omp atomic read
#endif
            k = counters[p];
            if (k >= n) /* done: no increment, so the counters stay small */
                continue;
#if NS_HAVE_OPENMP
#pragma omp atomic capture
#endif
            k = counters[p]++;
            if (k < n)
                return k * parts + p;
        }
    return -1;
}

void ns_tissue_forces(NsTissue *t, int force_all, NsTissueStats *stats)
{
    double t0 = now_ms();
    NsMesh *M = &t->mesh;
    int threads = t->params.threads > 1 ? t->params.threads : 1;
    if (force_all)
        memset(t->jvalid, 0, (size_t)M->tet_slots);
    /* After a topology change only the rows of nodes whose tets changed are gathered again
     * (node_rows: their removed tets' blocks go to zero), the rows of rebuilt tets take their
     * changes, the others are left. Which rows do what depends on the mesh and its history,
     * never on the threads. Rows taken by changes drift from a fresh sum by round-off, one
     * rounding per change: every KD_REGATHER calls every row is gathered again. */
    int all_rows = force_all || !t->kd_valid || t->kd_age >= KD_REGATHER;
    t->kd_age = all_rows ? 0 : t->kd_age + 1;
    t->djac_count = 0;
    int nn = M->node_slots < t->K.n ? M->node_slots : t->K.n;
    int parts = partition(t, threads) == 0 ? t->part_count : 0;
    size_t ncol = (size_t)(t->K.n > M->node_slots ? t->K.n : M->node_slots);
    int alive = 0, updated = 0, inverted = 0, nan = 0, failed = 0, gathered = 0, by_change = 0;
    double tj = 0.0;
    if (parts == 0) { /* no memory for the partition: serially by index, every touched row
                         gathered (no column scratch for the changes) */
        AssemblyCounts c = {0};
        int batch[SVD_BATCH], nb = 0;
        for (int e = 0; e < M->tet_slots; e++)
            if (ns_mesh_tet_alive(M, e)) {
                batch[nb++] = e;
                if (nb == SVD_BATCH) {
                    tet_phase_n(t, batch, nb, &c);
                    nb = 0;
                }
            }
        tet_phase_n(t, batch, nb, &c);
        double tr = now_ms();
        for (int i = 0; i < M->node_slots; i++)
            node_force(t, i);
        for (int i = 0; i < nn; i++)
            failed |= node_rows(t, i, all_rows, NULL, &c) != 0;
        alive = c.alive;
        updated = c.updated;
        gathered = c.rows_gathered;
        by_change = c.rows_changed;
        inverted = c.inverted;
        nan = c.nan;
        tj = c.jacobian_ms + now_ms() - tr;
    } else {
        /* Chunks taken so far of each part's tets (next[p]) and nodes (next[parts + p]). */
        int *next = t->part_next;
        for (int p = 0; p < 2 * parts; p++)
            next[p] = 0;
#if NS_HAVE_OPENMP
#pragma omp parallel num_threads(threads)                                                         \
    reduction(+ : alive, updated, inverted, nan, gathered, by_change) reduction(| : failed)        \
    reduction(max : tj)
#endif
        {
            int tid = 0, nth = 1;
#if NS_HAVE_OPENMP
            tid = omp_get_thread_num();
            nth = omp_get_num_threads();
#endif
            /* Each thread works through its own parts' chunks, then takes what is left of
             * the others' (stealing, below). */
            AssemblyCounts c = {0};
            int chunk;
            while ((chunk = next_chunk(next, parts, tid, nth, t->part_tet_start, TET_CHUNK)) >= 0) {
                int p = chunk % parts, lo = t->part_tet_start[p] + chunk / parts * TET_CHUNK;
                int hi = t->part_tet_start[p + 1] < lo + TET_CHUNK ? t->part_tet_start[p + 1]
                                                                   : lo + TET_CHUNK;
                tet_phase_n(t, t->part_tets + lo, hi - lo, &c);
            }
#if NS_HAVE_OPENMP
#pragma omp barrier
#endif
            double gather = 0.0;
            int *colpos = t->colpos + (size_t)tid * ncol;
            while ((chunk = next_chunk(next + parts, parts, tid, nth, t->part_node_start,
                                       NODE_CHUNK)) >= 0) {
                int p = chunk % parts, lo = t->part_node_start[p] + chunk / parts * NODE_CHUNK;
                int hi = t->part_node_start[p + 1] < lo + NODE_CHUNK ? t->part_node_start[p + 1]
                                                                     : lo + NODE_CHUNK;
                for (int k = lo; k < hi; k++)
                    node_force(t, t->part_nodes[k]);
                double g0 = now_ms();
                for (int k = lo; k < hi; k++)
                    if (t->part_nodes[k] < nn)
                        failed |= node_rows(t, t->part_nodes[k], all_rows, colpos, &c) != 0;
                gather += now_ms() - g0;
            }
            alive += c.alive;
            updated += c.updated;
            gathered += c.rows_gathered;
            by_change += c.rows_changed;
            inverted += c.inverted;
            nan += c.nan;
            double mine = c.jacobian_ms + gather;
            tj = mine > tj ? mine : tj;
        }
    }
    /* A row that lost a block to memory is wrong, and nodes beyond K's rows (no sync since the
     * mesh grew) were not gathered: gather every row again next time. */
    t->kd_valid = !failed && nn == M->node_slots;
    t->kd_version = M->topology_version;
    /* Room for this call's changes next time (a tet without a slot had its rows gathered). */
    if (t->djac_count > t->djac_cap) {
        int cap = t->djac_count + t->djac_count / 4;
        double *d = realloc(t->djac, (size_t)cap * 288 * sizeof(double));
        if (d) {
            t->djac = d;
            t->djac_cap = cap;
        }
    }
    if (stats) {
        double total = now_ms() - t0;
        stats->jacobian_ms += tj;
        stats->force_ms += total > tj ? total - tj : 0.0;
        stats->jacobian_fraction = alive ? (double)updated / alive : 0.0;
        stats->rows_gathered = gathered;
        stats->rows_changed = by_change;
        stats->inverted = inverted;
        stats->nan_count += nan;
    }
}

/* sum over a block row of b x_j, three sums, in the order of ns_bsm_mul (the same bits) */
#define NS_ROW_ACC(s, b, xj)                                                                       \
    do {                                                                                           \
        (s)[0] += (b)[0] * (xj)[0] + (b)[1] * (xj)[1] + (b)[2] * (xj)[2];                          \
        (s)[1] += (b)[3] * (xj)[0] + (b)[4] * (xj)[1] + (b)[5] * (xj)[2];                          \
        (s)[2] += (b)[6] * (xj)[0] + (b)[7] * (xj)[1] + (b)[8] * (xj)[2];                          \
    } while (0)

/* Row i of A = M - c1 K - c2 D on K's pattern (D shares it: both are scattered at the same
 * pairs). The three rows are sorted by column, so one walk finds the blocks; a block missing in
 * A is inserted (only row i's arrays change, so rows can be built on any thread). With y given,
 * the same walk also takes row i of the products K y and D z into ky and dz (the right-hand
 * side's, Eq. 5), summed in column order exactly as ns_bsm_mul would: one pass over K and D
 * instead of three. A row marked a_valid (it is what this would write) is only read for the
 * products: three rows in four on the brachytherapy bench. */
static int build_row(NsTissue *t, int i, double c1, double c2, const double *y, const double *z,
                     double *ky, double *dz)
{
    const NsBlockRow *kr = &t->K.rows[i], *dr = &t->D.rows[i];
    NsBlockRow *ar = &t->A.rows[i];
    int pd = 0, pa = 0, matched = 0;
    double sk[3] = {0.0, 0.0, 0.0}, sd[3] = {0.0, 0.0, 0.0};
    int write = !t->a_valid[i]; /* else A's row stands: only the products */
    if (!write && !y)
        return 0;
    for (int p = 0; p < kr->count; p++) {
        int j = kr->col[p];
        const double *kb = kr->val + 9 * p;
        while (pd < dr->count && dr->col[pd] < j)
            pd++;
        const double *db = pd < dr->count && dr->col[pd] == j ? dr->val + 9 * pd : NULL;
        if (write) {
            while (pa < ar->count && ar->col[pa] < j)
                pa++;
            double *ab =
                pa < ar->count && ar->col[pa] == j ? ar->val + 9 * pa : ns_bsm_get(&t->A, i, j);
            if (!ab)
                return -1; /* out of memory */
            for (int q = 0; q < 9; q++)
                ab[q] = -c1 * kb[q] - c2 * (db ? db[q] : 0.0);
        }
        if (y) {
            NS_ROW_ACC(sk, kb, y + 3 * j);
            if (db) {
                NS_ROW_ACC(sd, db, z + 3 * j);
                matched++;
            }
        }
    }
    if (y) {
        if (matched != dr->count) { /* D has blocks K lacks: its own walk */
            sd[0] = sd[1] = sd[2] = 0.0;
            for (int p = 0; p < dr->count; p++)
                NS_ROW_ACC(sd, dr->val + 9 * p, z + 3 * dr->col[p]);
        }
        for (int c = 0; c < 3; c++) {
            ky[3 * i + c] = sk[c];
            dz[3 * i + c] = sd[c];
        }
    }
    if (!write)
        return 0;
    double *d = ns_bsm_get(&t->A, i, i);
    if (!d)
        return -1;
    for (int c = 0; c < 3; c++)
        d[4 * c] += t->mass[i] > 0.0 ? t->mass[i] : 1.0; /* unused slots: identity */
    t->a_valid[i] = 1;
    return 0;
}

/* A, row by row (on the tissue's threads), and with y given (node_slots long) ky = K y and
 * dz = D z on the rows of node slots; the others (no sync since the mesh grew) are zero. K never
 * has more rows than node slots (a mesh loses slots only in ns_mesh_compact, before
 * ns_tissue_init), so every column j of a product is a node slot. Returns 0, or -1 if a row
 * ran out of memory. */
static int build_system(NsTissue *t, double c1, double c2, const double *y, const double *z,
                        double *ky, double *dz)
{
    int threads = t->params.threads > 1 ? t->params.threads : 1, failed = 0;
    int n = t->K.n, nn = t->mesh.node_slots;
    /* Rows of A kept from the last build only if its coefficients were these (bitwise) and A
     * still has K's rows (a row of A that ran out of memory is marked not valid). */
    if (memcmp(&c1, &t->a_c1, sizeof c1) != 0 || memcmp(&c2, &t->a_c2, sizeof c2) != 0 ||
        t->A.n != n)
        memset(t->a_valid, 0, (size_t)n);
    t->a_c1 = c1;
    t->a_c2 = c2;
#define NS_BUILD_ROW(i) build_row(t, i, c1, c2, (i) < nn ? y : NULL, z, ky, dz)
#if NS_HAVE_OPENMP
    if (threads > 1 && n >= NS_BSM_PARALLEL_MIN_ROWS) {
#pragma omp parallel for num_threads(threads) schedule(static) reduction(| : failed)
        for (int i = 0; i < n; i++)
            failed |= NS_BUILD_ROW(i) != 0;
    } else
#else
    (void)threads;
#endif
    {
        for (int i = 0; i < n; i++)
            failed |= NS_BUILD_ROW(i) != 0;
    }
#undef NS_BUILD_ROW
    if (y)
        for (int i = 3 * n; i < 3 * nn; i++)
            ky[i] = dz[i] = 0.0;
    return failed ? -1 : 0;
}

double *ns_tissue_begin_step(NsTissue *t, double dt, const double *ext, NsTissueStats *st)
{
    NsMesh *M = &t->mesh;
    int n3 = 3 * M->node_slots;
    double beta = t->params.beta, gamma = t->params.gamma;
    ns_tissue_forces(t, 0, st);
    if (t->steps == 0) {
        /* Newmark needs a consistent starting acceleration a0 = M^-1 F(x0, v0) (lumped M);
         * starting from a0 = 0 in a loaded state puts a one-off error into the energy. */
        for (int i = 0; i < n3; i++)
            M->a[i] = t->dof_fixed[i] ? 0.0 : (t->force[i] + (ext ? ext[i] : 0.0)) / t->mass[i / 3];
    }
    double *rhs = t->work, *y = rhs + n3, *z = y + n3, *dz = z + n3;
    for (int i = 0; i < n3; i++) {
        y[i] = dt * M->v[i] + dt * dt * (0.5 - beta) * M->a[i];
        z[i] = dt * (1.0 - gamma) * M->a[i];
    }
    /* A and the products K y, D z in one row-parallel pass: each row summed whole by one
     * thread, the same bits for any count. */
    if (build_system(t, beta * dt * dt, gamma * dt, y, z, rhs, dz))
        return NULL;
    for (int i = 0; i < n3; i++)
        rhs[i] += dz[i] + t->force[i] + (ext ? ext[i] : 0.0);
    return rhs;
}

void ns_tissue_end_step(NsTissue *t, double dt, const double *anew)
{
    NsMesh *M = &t->mesh;
    int n3 = 3 * M->node_slots;
    double beta = t->params.beta, gamma = t->params.gamma;
    for (int i = 0; i < n3; i++) {
        M->x[i] += dt * M->v[i] + dt * dt * ((0.5 - beta) * M->a[i] + beta * anew[i]);
        M->v[i] += dt * ((1.0 - gamma) * M->a[i] + gamma * anew[i]);
        M->a[i] = anew[i];
    }
    t->steps++;
}

int ns_tissue_step(NsTissue *t, NsSolver *solver, double dt, const double *ext,
                   NsTissueStats *stats)
{
    NsTissueStats st;
    memset(&st, 0, sizeof st);
    double t0 = now_ms();
    NsMesh *M = &t->mesh;
    int n3 = 3 * M->node_slots;
    double *rhs = ns_tissue_begin_step(t, dt, ext, &st);
    if (!rhs) {
        st.total_ms = now_ms() - t0;
        if (stats)
            *stats = st;
        return -1;
    }
    double ts = now_ms();
    double *anew = rhs + 3 * n3;
    for (int i = 0; i < n3; i++)
        anew[i] = t->dof_fixed[i] ? 0.0 : M->a[i]; /* warm start; fixed DOFs do not accelerate */
    NsSolveStats ss;
    int rc = ns_solver_solve(solver, &t->A, t->dof_fixed, rhs, anew, t->params.solve_tol,
                             t->params.solve_max_iter, &ss);
    st.solve_ms = now_ms() - ts;
    st.cg_iterations = ss.iterations;
    st.factorized = ss.factorized;
    st.refresh_started = ss.refresh_started;
    st.unconverged = rc == 0 && !ss.converged;
    int finite = rc == 0;
    for (int i = 0; i < n3 && finite; i++)
        finite = isfinite(anew[i]);
    if (!finite) {
        st.nan_count += rc == 0;
        st.total_ms = now_ms() - t0;
        if (stats)
            *stats = st;
        return -1;
    }
    ns_tissue_end_step(t, dt, anew);
    st.total_ms = now_ms() - t0;
    if (stats)
        *stats = st;
    return 0;
}

int ns_tissue_static_solve(NsTissue *t, NsSolver *solver, const double *ext, double tol,
                           int max_newton, NsTissueStats *stats)
{
    NsTissueStats st;
    memset(&st, 0, sizeof st);
    NsMesh *M = &t->mesh;
    int n3 = 3 * M->node_slots;
    double *rhs = t->work, *dx = rhs + n3;
    int it;
    for (it = 0; it <= max_newton; it++) {
        ns_tissue_forces(t, 1, &st);
        /* Residual on free DOFs; the reference is the largest applied or reaction force. */
        double res = 0.0, ref = 1e-300;
        for (int i = 0; i < n3; i++) {
            double f = t->force[i] + (ext ? ext[i] : 0.0);
            if (t->dof_fixed[i])
                ref = fabs(f) > ref ? fabs(f) : ref;
            else
                res = fabs(f) > res ? fabs(f) : res;
            if (ext)
                ref = fabs(ext[i]) > ref ? fabs(ext[i]) : ref;
            rhs[i] = f;
            dx[i] = 0.0;
        }
        if (res <= tol * ref)
            break;
        if (it == max_newton) {
            st.unconverged++;
            break;
        }
        if (build_system(t, 1.0, 0.0, NULL, NULL, NULL, NULL)) {
            if (stats)
                *stats = st;
            return -1;
        }
        /* A = M - K: remove the mass again, the static tangent is -K. */
        for (int i = 0; i < t->A.n; i++) {
            double *d = ns_bsm_get(&t->A, i, i);
            for (int c = 0; c < 3; c++)
                d[4 * c] -= t->mass[i] > 0.0 ? t->mass[i] : 1.0;
            t->a_valid[i] = 0;
        }
        NsSolveStats ss;
        if (ns_solver_solve(solver, &t->A, t->dof_fixed, rhs, dx, 1e-12, 20000, &ss)) {
            if (stats)
                *stats = st;
            return -1;
        }
        st.cg_iterations += ss.iterations;
        for (int i = 0; i < n3; i++)
            M->x[i] += dx[i];
    }
    if (stats)
        *stats = st;
    return it;
}

void ns_tissue_a_row_touched(NsTissue *t, int i)
{
    if (i >= 0 && i < t->node_cap)
        t->a_valid[i] = 0;
}

double ns_tissue_energy(const NsTissue *t)
{
    const NsMesh *M = &t->mesh;
    double e = 0.0;
    for (int i = 0; i < M->node_slots; i++) {
        if (!(M->flags[i] & NS_NODE_ALIVE))
            continue;
        const double *v = M->v + 3 * i, *x = M->x + 3 * i;
        e += 0.5 * t->mass[i] * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        e -= t->mass[i] * (t->params.gravity[0] * x[0] + t->params.gravity[1] * x[1] +
                           t->params.gravity[2] * x[2]);
    }
    for (int k = 0; k < M->tet_slots; k++) {
        if (!ns_mesh_tet_alive(M, k))
            continue;
        const int *tn = M->tet_node + 4 * k;
        const double *x[4] = {M->x + 3 * tn[0], M->x + 3 * tn[1], M->x + 3 * tn[2],
                              M->x + 3 * tn[3]};
        e += ns_fem_tet_energy(&t->rest[k], &t->materials[M->tet_region[k]].fem, x);
    }
    return e;
}

uint64_t ns_tissue_state_hash(const NsTissue *t)
{
    const NsMesh *M = &t->mesh;
    uint64_t h = 0xcbf29ce484222325ull; /* FNV-1a 64 */
    uint64_t topo = ns_mesh_topology_hash(M);
    for (int b = 0; b < 8; b++) {
        h ^= (topo >> (8 * b)) & 0xff;
        h *= 0x100000001b3ull;
    }
    for (int i = 0; i < M->node_slots; i++) {
        if (!(M->flags[i] & NS_NODE_ALIVE))
            continue;
        const double *arrays[3] = {M->x, M->v, M->a};
        for (int k = 0; k < 9; k++) {
            uint64_t bits;
            memcpy(&bits, arrays[k / 3] + 3 * i + k % 3, sizeof bits);
            for (int b = 0; b < 8; b++) {
                h ^= (bits >> (8 * b)) & 0xff;
                h *= 0x100000001b3ull;
            }
        }
    }
    return h;
}

/* The work partition's arrays when there is a partition; after a failed one (part_count 0) their
 * sizes are unknown and nothing reads them: packed as absent, the next partition allocates. */
static void partition_pack(NsPack *p, NsTissue *t)
{
    int has = t->part_count > 0;
    size_t pc = has ? (size_t)t->part_count : 0;
    size_t nn = t->part_node_slots > 0 ? (size_t)t->part_node_slots : 1;
    size_t nt = t->part_tet_slots > 0 ? (size_t)t->part_tet_slots : 1;
    int *ns = has ? t->part_node_start : NULL, *ts = has ? t->part_tet_start : NULL;
    int *pn = has ? t->part_nodes : NULL, *pt = has ? t->part_tets : NULL;
    int *nx = has ? t->part_next : NULL;
    NS_PACK_ARRAY(p, ns, pc + 1, pc + 1);
    NS_PACK_ARRAY(p, ts, pc + 1, pc + 1);
    NS_PACK_ARRAY(p, nx, 2 * pc, 2 * pc);
    NS_PACK_ARRAY(p, pn, ns ? (size_t)ns[pc] : 0, nn);
    NS_PACK_ARRAY(p, pt, ts ? (size_t)ts[pc] : 0, nt);
    if (!p->writing) {
        t->part_node_start = ns;
        t->part_tet_start = ts;
        t->part_next = nx;
        t->part_nodes = pn;
        t->part_tets = pt;
    }
    size_t np = (size_t)t->node_part_cap;
    NS_PACK_ARRAY(p, t->node_part, np, np);
    NS_PACK_ARRAY(p, t->colpos, t->colpos_len, t->colpos_len);
}

static void tissue_blank(void *e)
{
    NsTissue *h = e;
    memset(&h->mesh, 0, sizeof h->mesh);
    memset(&h->K, 0, sizeof h->K);
    memset(&h->D, 0, sizeof h->D);
    memset(&h->A, 0, sizeof h->A);
    h->materials = NULL;
    h->rest = NULL;
    h->frame = h->jframe = NULL;
    h->jprod = h->jprod_old = h->djac = h->tet_force = h->tet_jac = NULL;
    h->mass = h->force = h->work = NULL;
    h->jvalid = h->jnew = h->dof_fixed = h->was_alive = h->a_valid = NULL;
    h->djac_slot = h->rest_region = NULL;
    h->part_node_start = h->part_nodes = h->part_tet_start = h->part_tets = NULL;
    h->part_next = h->node_part = h->colpos = NULL;
}

/* Every array of NsTissue in the allocation its code makes (tet_cap, node_cap, djac_cap, the
 * partition's), the mesh, K, D and A. Per-tet arrays are written up to the mesh's tet_slots: the
 * rest is zero from their growth and stays so until the mesh grows into it. Per-node arrays are
 * written whole (dof_fixed's tail is 1), and so are djac and the scratch. */
int ns_tissue_pack(NsPack *p, NsTissue *t)
{
    ns_pack_struct(p, "TISS", t, sizeof *t, tissue_blank);
    ns_mesh_pack(p, &t->mesh);
    size_t tc = t->tet_cap > 0 ? (size_t)t->tet_cap : 0, nc = (size_t)t->node_cap;
    size_t ts = t->mesh.tet_slots > 0 ? (size_t)t->mesh.tet_slots : 0;
    if (ts > tc)
        ts = tc;
    size_t mc = (size_t)t->material_count, dc = (size_t)t->djac_cap;
    NS_PACK_ARRAY(p, t->materials, mc, mc);
    NS_PACK_ARRAY(p, t->rest, ts, tc);
    NS_PACK_ARRAY(p, t->frame, ts, tc);
    NS_PACK_ARRAY(p, t->jframe, ts, tc);
    NS_PACK_ARRAY(p, t->jprod, 9 * ts, 9 * tc);
    NS_PACK_ARRAY(p, t->jvalid, ts, tc);
    NS_PACK_ARRAY(p, t->jnew, ts, tc);
    NS_PACK_ARRAY(p, t->djac, 288 * dc, 288 * dc);
    NS_PACK_ARRAY(p, t->djac_slot, ts, tc);
    NS_PACK_ARRAY(p, t->jprod_old, 9 * ts, 9 * tc);
    NS_PACK_ARRAY(p, t->tet_force, 12 * ts, 12 * tc);
    NS_PACK_ARRAY(p, t->tet_jac, 288 * ts, 288 * tc);
    NS_PACK_ARRAY(p, t->rest_region, ts, tc);
    NS_PACK_ARRAY(p, t->mass, nc, nc);
    NS_PACK_ARRAY(p, t->force, 3 * nc, 3 * nc);
    NS_PACK_ARRAY(p, t->dof_fixed, 3 * nc, 3 * nc);
    NS_PACK_ARRAY(p, t->work, 12 * nc, 12 * nc);
    NS_PACK_ARRAY(p, t->was_alive, nc, nc);
    NS_PACK_ARRAY(p, t->a_valid, nc, nc);
    partition_pack(p, t);
    ns_block_matrix_pack(p, &t->K);
    ns_block_matrix_pack(p, &t->D);
    ns_block_matrix_pack(p, &t->A);
    return p->failed ? -1 : 0;
}
