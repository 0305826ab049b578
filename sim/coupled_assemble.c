/* The coupled system of one step (Eq. 7-8, §3.3): built from the needle's and the tissue's
 * forces and Jacobians (ns_rod_begin_step, ns_tissue_begin_step), with the coupling nodes' local
 * frames, friction thresholds, constraint right-hand sides and the viscous friction, the
 * solvers' starting guess, and our bevel model's load on the tip (sim/coupling_internal.h). */
#include "coupling_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static double dot3(const double *a, const double *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static double norm3(const double *a)
{
    return sqrt(dot3(a, a));
}

/* Local frame at needle node i (§3.3): t the normalized sum of the unit edge directions around
 * it (the last edge's at the tip), n1 and n2 completing it (n1 from the axis least aligned). */
static void local_frame(const NsRod *r, int i, double *R)
{
    double t[3] = {0, 0, 0};
    for (int side = 0; side < 2; side++) {
        int a = side ? i : i - 1, b = a + 1;
        if (a < 0 || b >= r->nodes)
            continue;
        double e[3];
        for (int k = 0; k < 3; k++)
            e[k] = r->x[3 * b + k] - r->x[3 * a + k];
        double l = norm3(e);
        for (int k = 0; k < 3; k++)
            t[k] += e[k] / l;
    }
    double l = norm3(t);
    for (int k = 0; k < 3; k++)
        t[k] /= l;
    int ax = fabs(t[0]) <= fabs(t[1]) && fabs(t[0]) <= fabs(t[2]) ? 0
             : fabs(t[1]) <= fabs(t[2])                           ? 1
                                                                  : 2;
    double n1[3] = {0, 0, 0}, n2[3];
    n1[ax] = 1.0;
    double d = dot3(n1, t);
    for (int k = 0; k < 3; k++)
        n1[k] -= d * t[k];
    l = norm3(n1);
    for (int k = 0; k < 3; k++)
        n1[k] /= l;
    n2[0] = t[1] * n1[2] - t[2] * n1[1];
    n2[1] = t[2] * n1[0] - t[0] * n1[2];
    n2[2] = t[0] * n1[1] - t[1] * n1[0];
    for (int k = 0; k < 3; k++) {
        R[k] = t[k];
        R[3 + k] = n1[k];
        R[6 + k] = n2[k];
    }
}

/* Adds s * (w_a w_b) * B to the tissue blocks of the tissue point's nodes. */
static void add_tissue_point_block(NsBlockMatrix *A, int a, int b, double w, const double *B,
                                   double s)
{
    int nodes[2] = {a, b};
    double ws[2] = {1.0 - w, w};
    for (int i = 0; i < 2; i++)
        for (int j = 0; j < 2; j++) {
            if (ws[i] == 0.0 || ws[j] == 0.0)
                continue;
            double *blk = ns_bsm_get(A, nodes[i], nodes[j]);
            if (blk)
                for (int k = 0; k < 9; k++)
                    blk[k] += s * ws[i] * ws[j] * B[k];
        }
}

/* Our bevel model (NS_BEVEL_FORCE): while the tip cuts (DYNAMIC+ in the last step), a lateral
 * force k_b tan(psi) along the tip frame's m2 on the needle's tip, and its reaction on the
 * tissue at the point a quarter of the last path edge ahead of the tip's node along the tip
 * tangent (barycentric shares of that tet's nodes other than the tip's own). The paper
 * displaces u_new instead (§3.5, Figure 7); docs/remeshing.md compares them. *f: the lateral
 * force [N] (0: none); *et / *er: the caller's external forces copied and added to, to be
 * freed (NULL when there is no force). Returns 0, or -1 (memory). */
int coupled_bevel_load(NsCoupled *c, const double *ext_tissue, const double *ext_rod, double *f_out,
                       double **et, double **er)
{
    NsRod *r = c->rod;
    NsMesh *M = &c->tissue->mesh;
    int n = r->nodes;
    *et = *er = NULL;
    *f_out = 0.0;
    if (!c->params.remesh || c->outside || r->params.tip != NS_TIP_BEVEL ||
        c->params.bevel_model != NS_BEVEL_FORCE || c->ta[n - 1] < 0 || c->path.count < 2 ||
        c->state[n - 1] != NS_FRICTION_DYN_POS)
        return 0;
    int tn = c->path.node[c->path.count - 1], prev = c->path.node[c->path.count - 2];
    if (M->node_tets[tn].count == 0)
        return 0;
    double t[3], m1[3], m2[3], q[3], b[4], d[3];
    ns_rod_tip_frame(r, t, m1, m2);
    for (int i = 0; i < 3; i++)
        d[i] = M->x[3 * tn + i] - M->x[3 * prev + i];
    double h = 0.25 * norm3(d);
    for (int i = 0; i < 3; i++)
        q[i] = M->x[3 * tn + i] + h * t[i];
    int te = ns_mesh_locate_in(M, M->x, q, M->node_tets[tn].items[0], 1e-9, b);
    if (te < 0)
        return 0; /* nothing ahead: the tip is at the surface */
    int reg = M->tet_region[te];
    double kb = reg >= 0 && reg < NS_COUPLING_MAX_REGIONS ? c->params.bevel_force[reg] : 0.0;
    double f = kb * tan(r->params.bevel_angle), wsum = 0.0;
    for (int a = 0; a < 4; a++) {
        if (M->tet_node[4 * te + a] == tn)
            b[a] = 0.0;
        wsum += b[a];
    }
    if (!(f != 0.0) || !(wsum > 0.0))
        return 0;
    size_t nt = 3 * (size_t)M->node_slots, nr = 3 * (size_t)n;
    *et = ns_arena_push_zero(&c->arena, nt * sizeof **et);
    *er = ns_arena_push_zero(&c->arena, nr * sizeof **er);
    if (!*et || !*er) {
        ns_arena_pop(&c->arena, *er);
        ns_arena_pop(&c->arena, *et);
        *et = *er = NULL;
        return -1;
    }
    if (ext_tissue)
        memcpy(*et, ext_tissue, nt * sizeof **et);
    if (ext_rod)
        memcpy(*er, ext_rod, nr * sizeof **er);
    for (int i = 0; i < 3; i++) {
        (*er)[3 * (n - 1) + i] += f * m2[i];
        for (int a = 0; a < 4; a++)
            (*et)[3 * M->tet_node[4 * te + a] + i] -= f * m2[i] * b[a] / wsum;
    }
    *f_out = f;
    return 0;
}

/* sum over the rows not fixed of x_i y_i */
static double free_dot(const double *x, const double *y, const uint8_t *fixed, int n)
{
    double s = 0.0;
    for (int i = 0; i < n; i++)
        if (!fixed[i])
            s += x[i] * y[i];
    return s;
}

/* The solve's starting accelerations (both solvers'). Last step's accelerations are a poor guess
 * as they stand: where the tissue is stiff for the step (omega dt >> 1, most of its modes here)
 * Newmark's scheme (gamma >= 1/2) makes the acceleration alternate, a_(n+1) ~ -a_n, and a_n is
 * twice as far from the answer as a zero start (docs/coupling.md, "The starting guess"). Each
 * side's free part d is scaled instead by the alpha that minimizes the error in the norm of its
 * own matrix, alpha = d.(b - A x_held) / d.A d (0 if d.A d is not positive): near -1 in the
 * quasi-static regime, near +1 in a free fall, and never worse than a zero start in that norm.
 * Costs one product with the tissue matrix and two with the needle's band. The constraints are
 * met afterwards by the solver's own feasible start. Returns 0, or -1 (out of memory). */
int coupled_scale_start(CoupledSystem *S)
{
    int n = S->nr3;
    double *w = ns_arena_push(S->arena, ((size_t)S->nt3 + 4 * (size_t)n + 1) * sizeof *w);
    if (!w)
        return -1;
    double *Ad = w, *d = w + S->nt3, *h = d + n, *Ah = h + n, *Adn = Ah + n;
    ns_bsm_mul_threads(S->At, S->at, Ad, S->threads);
    double num = free_dot(S->at, S->bt, S->tfixed, S->nt3);
    double den = free_dot(S->at, Ad, S->tfixed, S->nt3);
    double alpha = den > 0.0 && isfinite(num / den) ? num / den : 0.0;
    for (int i = 0; i < S->nt3; i++)
        S->at[i] *= alpha;
    /* The needle: held DOFs keep their prescribed accelerations (x_held), the free ones d. */
    for (int i = 0; i < n; i++) {
        h[i] = S->rfixed[i] ? S->ar[i] : 0.0;
        d[i] = S->rfixed[i] ? 0.0 : S->ar[i];
    }
    ns_banded_mul(S->Ar, h, Ah);
    ns_banded_mul(S->Ar, d, Adn);
    num = 0.0;
    den = 0.0;
    for (int i = 0; i < n; i++)
        if (!S->rfixed[i]) {
            num += d[i] * (S->br[i] - Ah[i]);
            den += d[i] * Adn[i];
        }
    alpha = den > 0.0 && isfinite(num / den) ? num / den : 0.0;
    for (int i = 0; i < n; i++)
        if (!S->rfixed[i])
            S->ar[i] *= alpha;
    ns_arena_pop(S->arena, w);
    return 0;
}

/* Viscous friction along t at coupling node k, needle node i (§3.3), implicit in each side's
 * own velocity: the force on the needle eta_i l (t.(v_t - v_n)) t; both sides' matrices gain
 * gamma dt eta_i l t t^T. vh, ah: the tissue point's velocity and acceleration; len: the
 * length of needle inside the tissue that node i stands for [m]. */
static void add_viscous(NsCoupled *c, CoupledSystem *S, NsRodSystem *sys, int k, int i, double len,
                        double dt, const double *vh, const double *ah)
{
    NsRod *r = c->rod;
    NsTissue *T = c->tissue;
    double gamma = T->params.gamma;
    double eta = c->params.eta * len, B[9], vrel[3];
    const double *t = S->R + 9 * k;
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++)
            B[3 * a + b] = eta * t[a] * t[b];
    for (int d = 0; d < 3; d++)
        vrel[d] = vh[d] - r->v[3 * i + d];
    double fv = dot3(t, vrel) * eta, an_t = dot3(t, r->a + 3 * i), ah_t = dot3(t, ah);
    for (int d = 0; d < 3; d++) {
        sys->rhs[3 * i + d] += t[d] * (fv - eta * dt * (1.0 - gamma) * an_t);
        double ft = -t[d] * (fv + eta * dt * (1.0 - gamma) * ah_t);
        S->bt[3 * S->ta[k] + d] += (1.0 - S->tw[k]) * ft;
        S->bt[3 * S->tb[k] + d] += S->tw[k] * ft;
    }
    double *nb = ns_banded_block((NsBanded *)sys->A, i, i);
    for (int d = 0; d < 9; d++)
        nb[d] += gamma * dt * B[d];
    add_tissue_point_block(&T->A, S->ta[k], S->tb[k], S->tw[k], B, gamma * dt);
    ns_tissue_a_row_touched(T, S->ta[k]);
    ns_tissue_a_row_touched(T, S->tb[k]);
}

void coupled_twist_bounds(NsCoupled *c)
{
    NsRod *r = c->rod;
    int ne = r->nodes - 1;
    double tau_f = c->params.twist_friction
                       ? c->params.f_perlen * 0.5 * r->params.material.outer_diameter
                       : 0.0;
    for (int j = 0; j < ne; j++)
        r->twist_fric[j] =
            tau_f > 0.0 && c->ta[j] >= 0 && c->ta[j + 1] >= 0 ? tau_f * r->rest_len[j] : 0.0;
}

/* Coupling node k at needle node i: its tissue point, state and local frame, its friction
 * threshold (and f_cut at a tip inside the tissue), the known part of the step's relative
 * displacement and the constraint right-hand side of Eq. 8, and the viscous friction. */
static void assemble_node(NsCoupled *c, CoupledSystem *S, NsRodSystem *sys, int k, int i, double dt)
{
    const NsRod *r = c->rod;
    const NsMesh *M = &c->tissue->mesh;
    double beta = c->tissue->params.beta;
    const double *rl = r->rest_len;
    S->idx[k] = i;
    S->ta[k] = c->ta[i];
    S->tb[k] = c->tb[i];
    S->tw[k] = c->tw[i];
    S->st[k] = c->state[i];
    local_frame(r, i, S->R + 9 * k);
    /* f_i = f_perlen (l_{i-1} + l_i) / 2 over the halves of edges inside the tissue. */
    double len = 0.0;
    if (i > 0 && c->ta[i - 1] >= 0)
        len += 0.5 * rl[i - 1];
    if (i + 1 < r->nodes && c->ta[i + 1] >= 0)
        len += 0.5 * rl[i];
    S->f[k] = c->params.f_perlen * len;
    if (i == r->nodes - 1 && !c->path.through) {
        S->tip = k;
        S->f_cut =
            ns_needle_path_cut_force(&c->path, M, c->params.cut_force, NS_COUPLING_MAX_REGIONS);
    }
    /* Known part of the step's displacement, tissue minus needle (Eq. 1 without a'). */
    double yh[3], vh[3], ah[3];
    coupled_point(S, k, M->v, vh);
    coupled_point(S, k, M->a, ah);
    for (int d = 0; d < 3; d++) {
        yh[d] = dt * vh[d] + dt * dt * (0.5 - beta) * ah[d];
        double yn = dt * r->v[3 * i + d] + dt * dt * (0.5 - beta) * r->a[3 * i + d];
        S->yrel[3 * k + d] = yh[d] - yn;
    }
    /* Eq. 8 in the local axes: R^T (dx_tissue - dx_needle) = 0, i.e. beta dt^2 R^T (a_t - a_n)
     * = -R^T yrel. */
    for (int col = 0; col < 3; col++)
        S->e[3 * k + col] = -dot3(S->R + 9 * k + 3 * col, S->yrel + 3 * k) / S->bdt2;
    if (c->params.eta > 0.0)
        add_viscous(c, S, sys, k, i, len, dt, vh, ah);
}

size_t coupled_system_doubles(int q)
{
    return (size_t)q * 24 + 16;
}

size_t coupled_system_ints(int q)
{
    return (size_t)(3 * q + 1);
}

int coupled_count(const NsCoupled *c)
{
    int q = 0;
    for (int i = 0; i < c->rod->nodes; i++)
        q += c->ta[i] >= 0;
    return q;
}

void coupled_assemble(NsCoupled *c, double dt, NsRodSystem *sys, double *bt, double *w, int *iw,
                      uint8_t *sw, CoupledSystem *S)
{
    NsTissue *T = c->tissue;
    NsRod *r = c->rod;
    NsMesh *M = &T->mesh;
    memset(S, 0, sizeof *S);
    S->c = c;
    S->arena = &c->arena;
    S->nt3 = 3 * M->node_slots;
    S->nr3 = sys->n3;
    S->bdt2 = T->params.beta * dt * dt;
    S->At = &T->A;
    S->tfixed = T->dof_fixed;
    S->bt = bt;
    S->Ar = sys->A;
    S->rfixed = sys->dof_fixed;
    S->br = sys->rhs;
    S->ar = sys->anew;
    S->at = bt + S->nt3; /* t->work's second vector */
    S->threads = c->params.threads;
    S->tip = -1;
    int q = coupled_count(c);
    S->q = q;
    S->tw = w;
    S->R = S->tw + q;
    S->f = S->R + 9 * q;
    S->e = S->f + q;
    S->yrel = S->e + 3 * q;
    S->cf = S->yrel + 3 * q;
    S->idx = iw;
    S->ta = iw + q;
    S->tb = iw + 2 * q;
    S->st = sw;
    for (int i = 0, k = 0; i < r->nodes; i++)
        if (c->ta[i] >= 0)
            assemble_node(c, S, sys, k++, i, dt);
    for (int i = 0; i < S->nt3; i++)
        S->at[i] = T->dof_fixed[i] ? 0.0 : M->a[i];
}

void coupled_known_forces(CoupledSystem *S)
{
    for (int k = 0; k < S->q; k++)
        for (int d = 0; d < 3; d++)
            S->cf[3 * k + d] = d == 0 ? coupled_known_force(S, k, S->st[k]) : 0.0;
}
