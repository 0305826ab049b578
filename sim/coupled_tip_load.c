/* Our bevel model's load (NS_BEVEL_FORCE, §3.5; issue 35, docs/needle.md, "The bevel force's
 * reaction"): while the needle is pushed in (v_insert > 0) and its tip is not sliding back, the
 * bevel face presses on the tissue whether the tip cuts this step or sticks while the load
 * builds (an on/off force by the last step's state, DYNAMIC+ only, made the mean force depend on
 * dt through the stick-slip's duty cycle: 96 % of steps at dt 10 ms, 78 % at 5 ms). The bevel
 * pushes the tissue it cuts sideways, against the tip frame's m2, with k_b tan(psi), and the tip,
 * pushed along m2 by the same force, passes it on to the tissue around the needle's end. The
 * paper (§3.5) notes that this happens at a scale too small for the mesh; we model it as a pair of
 * body forces of fixed shape in the tissue: the density (1 - r^2/R^2)^2 over a ball of radius
 * R = tip_load_radius centred R ahead of the tip along its tangent (the reaction, -m2) and its
 * mirror centred R behind the tip (the needle's side, +m2), the two balls touching at the tip.
 * Each is integrated against the elements' shape functions at a lattice of points fixed relative
 * to the tip (spacing R/4, 257 points): the nodes' consistent loads, which tend to the continuum's
 * as the mesh is refined once the elements are finer than the ball. A force put at one point of a
 * 3D mesh (the needle's push, when it reached the tissue through the tip's coupled node) strains
 * the elements around it as F / (E h^2), without limit as the element size h shrinks, and the cut
 * follows that strain: the tip path did not converge under mesh refinement (docs/needle.md). The
 * needle itself takes no load here: the tissue's displacement bends it through the coupling. The
 * ball ahead leaves out the tip's own node (the needle's: a share there would push the needle
 * back, not the tissue ahead); the shares of points outside the tissue are dropped and the rest
 * renormalized, each ball on its own, so the pair stays balanced.
 */
#include "coupling_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define LATTICE_N 4 /* lattice points per radius */

static double norm3(const double *a)
{
    return sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
}

/* Adds the force f (3 components) to et, spread over the ball of radius R centred side * R
 * along t from the tip (side 1 ahead, -1 behind; see above), off node skip (-1: none). Returns
 * 1, 0 when no point of the ball is in the tissue (nothing added), -1 out of memory. */
static int spread_ball(NsCoupled *c, const double tip[3], const double t[3], double side, int tipn,
                       int skip, const double f[3], double *et)
{
    const NsMesh *M = &c->tissue->mesh;
    double R = c->params.tip_load_radius, s = R / LATTICE_N, ctr[3], lo[3], hi[3];
    for (int i = 0; i < 3; i++) {
        ctr[i] = tip[i] + side * R * t[i];
        lo[i] = ctr[i] - R - 1e-6; /* (the widening: 1e-6 m, far over 3 tol a tet's size) */
        hi[i] = ctr[i] + R + 1e-6;
    }
    /* The tets that may hold a lattice point: a point the walk from the last one cannot reach
     * (outside the tissue, across a concave boundary) is searched for among them only. */
    int *cand = ns_arena_push(&c->arena, (size_t)(M->tet_slots + 1) * sizeof *cand);
    if (!cand)
        return -1;
    int ncand = -1; /* found at the first point the walk cannot reach */
    /* First pass: the total weight of the points inside the tissue, off the node skipped. */
    int hint = M->node_tets[tipn].count ? M->node_tets[tipn].items[0] : -1;
    double wsum = 0.0;
    for (int pass = 0; pass < 2; pass++) {
        if (pass == 1 && !(wsum > 0.0))
            break;
        int h = hint;
        for (int i = -LATTICE_N; i <= LATTICE_N; i++)
            for (int j = -LATTICE_N; j <= LATTICE_N; j++)
                for (int k = -LATTICE_N; k <= LATTICE_N; k++) {
                    double r2 = (double)(i * i + j * j + k * k) / (LATTICE_N * LATTICE_N);
                    if (!(r2 < 1.0))
                        continue;
                    double rho = (1.0 - r2) * (1.0 - r2),
                           q[3] = {ctr[0] + s * i, ctr[1] + s * j, ctr[2] + s * k};
                    double b[4];
                    int te = ns_mesh_walk(M, M->x, q, h, 1e-9, b);
                    if (te == -2) {
                        if (ncand < 0)
                            ncand = ns_mesh_tets_in_box(M, M->x, lo, hi, cand);
                        te = ns_mesh_search_among(M, M->x, q, 1e-9, b, cand, ncand);
                    }
                    if (te < 0)
                        continue;
                    h = te;
                    const int *tn = M->tet_node + 4 * te;
                    for (int a = 0; a < 4; a++) {
                        if (tn[a] == skip)
                            continue;
                        if (pass == 0) {
                            wsum += rho * b[a];
                            continue;
                        }
                        double w = rho * b[a] / wsum;
                        for (int d = 0; d < 3; d++)
                            et[3 * tn[a] + d] += w * f[d];
                    }
                }
    }
    ns_arena_pop(&c->arena, cand);
    return wsum > 0.0;
}

int coupled_tip_load(NsCoupled *c, const double *ext_tissue, double *f_out, double **et)
{
    NsRod *r = c->rod;
    NsMesh *M = &c->tissue->mesh;
    int n = r->nodes;
    *et = NULL;
    *f_out = 0.0;
    if (!c->params.remesh || c->outside || c->path.through || r->params.tip != NS_TIP_BEVEL ||
        c->params.bevel_model != NS_BEVEL_FORCE || c->ta[n - 1] < 0 || c->path.count < 2 ||
        c->state[n - 1] == NS_FRICTION_DYN_NEG || !(r->v_insert > 0.0))
        return 0;
    int tn = c->path.node[c->path.count - 1];
    if (M->node_tets[tn].count == 0)
        return 0;
    double t[3], m1[3], m2[3];
    ns_rod_tip_frame(r, t, m1, m2);
    double tl = norm3(t);
    if (!(tl > 0.0))
        return 0;
    for (int i = 0; i < 3; i++)
        t[i] /= tl;
    /* k_b by the region the tip is in. */
    int reg = M->tet_region[M->node_tets[tn].items[0]];
    double kb = reg >= 0 && reg < NS_COUPLING_MAX_REGIONS ? c->params.bevel_force[reg] : 0.0;
    double fb = kb * tan(r->params.bevel_angle);
    if (!(fb != 0.0))
        return 0;
    size_t nt = 3 * (size_t)M->node_slots;
    *et = ns_arena_push_zero(&c->arena, nt * sizeof **et);
    if (!*et)
        return -1;
    if (ext_tissue)
        memcpy(*et, ext_tissue, nt * sizeof **et);
    double ahead[3] = {-fb * m2[0], -fb * m2[1], -fb * m2[2]},
           behind[3] = {fb * m2[0], fb * m2[1], fb * m2[2]};
    const double *tip = r->x + 3 * (n - 1);
    int got = spread_ball(c, tip, t, 1.0, tn, tn, ahead, *et);
    if (got <= 0)
        return got; /* 0: nothing ahead in the tissue: the tip is at the surface (left as given) */
    got = spread_ball(c, tip, t, -1.0, tn, -1, behind, *et);
    if (got < 0)
        return -1;
    if (got == 0) {
        /* nothing behind in the tissue (not reached: the tip's tets are): the pair undone */
        if (ext_tissue)
            memcpy(*et, ext_tissue, nt * sizeof **et);
        else
            memset(*et, 0, nt * sizeof **et);
        return 0;
    }
    *f_out = fb;
    return 0;
}
