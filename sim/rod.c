/* The needle as a discrete elastic rod: frames, energies, forces, Jacobians, quasi-static twist,
 * the Newmark step and the static solve (paper §3.1, §3.2, §3.5; see rod.h for the sources). */
#include "rod.h"

#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "err.h"
#include "mutate.h"
#include "rod_internal.h"
#include "snapshot.h"
#include "twist_friction.h"

/* ---- small vector helpers ---- */

static double dot3(const double *a, const double *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static void cross3(const double *a, const double *b, double *c)
{
    double r0 = a[1] * b[2] - a[2] * b[1], r1 = a[2] * b[0] - a[0] * b[2];
    double r2 = a[0] * b[1] - a[1] * b[0];
    c[0] = r0;
    c[1] = r1;
    c[2] = r2;
}

static double norm3(const double *a)
{
    return sqrt(dot3(a, a));
}

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

/* Parallel transport of v from unit tangent a to unit tangent b: the rotation about a x b that
 * takes a to b (Rodrigues, written without the angle). For b = -a there is no unique answer;
 * a half turn about an axis normal to a is used. */
static void transport(const double *a, const double *b, const double *v, double *out)
{
    double c = dot3(a, b), k[3], kv[3];
    cross3(a, b, k);
    if (c < -1.0 + 1e-12) {
        double p[3] = {1.0, 0.0, 0.0};
        if (fabs(a[0]) > 0.9)
            p[0] = 0.0, p[1] = 1.0;
        double ax[3];
        cross3(a, p, ax);
        double n = norm3(ax);
        for (int d = 0; d < 3; d++)
            ax[d] /= n;
        double s = dot3(ax, v);
        for (int d = 0; d < 3; d++)
            out[d] = 2.0 * s * ax[d] - v[d];
        return;
    }
    cross3(k, v, kv);
    double kdv = dot3(k, v) / (1.0 + c);
    for (int d = 0; d < 3; d++)
        out[d] = c * v[d] + kv[d] + kdv * k[d];
}

void rod_transport(const double *a, const double *b, const double *v, double *out)
{
    transport(a, b, v, out);
}

/* Makes d normal to unit t and of unit length (Gram-Schmidt); picks any normal if d is parallel
 * to t. */
static void orthonormalize(const double *t, double *d)
{
    double s = dot3(d, t);
    for (int k = 0; k < 3; k++)
        d[k] -= s * t[k];
    double n = norm3(d);
    if (n < 1e-12) {
        double p[3] = {1.0, 0.0, 0.0};
        if (fabs(t[0]) > 0.9)
            p[0] = 0.0, p[1] = 1.0;
        cross3(t, p, d);
        n = norm3(d);
    }
    for (int k = 0; k < 3; k++)
        d[k] /= n;
}

/* ---- parameters ---- */

NsRodParams ns_default_rod_params(void)
{
    NsRodParams p;
    memset(&p, 0, sizeof p);
    p.material.youngs = 200e9;
    p.material.shear = 0.0;
    p.material.poisson = 0.3;
    p.material.outer_diameter = 1.27e-3;
    p.material.inner_diameter = 0.84e-3;
    p.material.density = 8000.0;
    p.tip = NS_TIP_SYMMETRIC;
    p.bevel_angle = 0.0;
    p.beta = 0.25;
    p.gamma = 0.5;
    p.damping_mass = 1.0;
    p.damping_stretch = 1e-4;
    p.stretch_scale = 1.0;
    p.split_factor = 2.0;
    p.merge_factor = 0.5;
    p.auto_reparam = 1;
    p.newton_max = 8;
    p.newton_strain_tol = 1e-4;
    p.twist_max_iter = 20;
    p.twist_tol = 1e-12;
    return p;
}

static int check_params(const NsRodParams *p, char *err, int err_sz)
{
    const NsRodMaterial *m = &p->material;
    if (!(m->youngs > 0.0) || !isfinite(m->youngs)) {
        ns_set_err(err, err_sz, "needle: youngs must be finite and positive (got %g Pa)",
                   m->youngs);
        return -1;
    }
    if (m->shear != 0.0 && (!(m->shear > 0.0) || !isfinite(m->shear))) {
        ns_set_err(err, err_sz,
                   "needle: shear must be finite and positive, or 0 to use poisson (got %g Pa)",
                   m->shear);
        return -1;
    }
    if (m->shear == 0.0 && !(m->poisson > -1.0 && m->poisson < 0.5)) {
        ns_set_err(err, err_sz, "needle: poisson must lie in (-1, 0.5) (got %g)", m->poisson);
        return -1;
    }
    if (!(m->outer_diameter > 0.0) || !isfinite(m->outer_diameter)) {
        ns_set_err(err, err_sz, "needle: outer diameter must be finite and positive (got %g m)",
                   m->outer_diameter);
        return -1;
    }
    if (!(m->inner_diameter >= 0.0 && m->inner_diameter < m->outer_diameter)) {
        ns_set_err(err, err_sz,
                   "needle: inner diameter must be in [0, outer diameter) (got %g m, outer %g m)",
                   m->inner_diameter, m->outer_diameter);
        return -1;
    }
    if (!(m->density > 0.0) || !isfinite(m->density)) {
        ns_set_err(err, err_sz, "needle: density must be finite and positive (got %g kg/m^3)",
                   m->density);
        return -1;
    }
    if (p->tip != NS_TIP_SYMMETRIC && p->tip != NS_TIP_BEVEL) {
        ns_set_err(err, err_sz, "needle: unknown tip kind %d", (int)p->tip);
        return -1;
    }
    if (p->tip == NS_TIP_BEVEL && !(p->bevel_angle > 0.0 && p->bevel_angle < 1.5707963267948966)) {
        ns_set_err(err, err_sz, "needle: bevel angle must lie in (0, 90) degrees (got %g rad)",
                   p->bevel_angle);
        return -1;
    }
    if (!(p->beta >= 0.0 && p->beta <= 0.5) || !(p->gamma > 0.0 && p->gamma <= 1.0)) {
        ns_set_err(err, err_sz, "needle: Newmark beta in [0, 0.5], gamma in (0, 1] (got %g, %g)",
                   p->beta, p->gamma);
        return -1;
    }
    if (!(p->damping_mass >= 0.0) || !isfinite(p->damping_mass) || !(p->damping_stretch >= 0.0) ||
        !isfinite(p->damping_stretch)) {
        ns_set_err(err, err_sz,
                   "needle: damping must be finite and >= 0 (got damping_mass %g 1/s, "
                   "damping_stretch %g s)",
                   p->damping_mass, p->damping_stretch);
        return -1;
    }
    if (!(p->stretch_scale > 0.0) || !isfinite(p->stretch_scale)) {
        ns_set_err(err, err_sz, "needle: stretch_scale must be finite and > 0 (got %g)",
                   p->stretch_scale);
        return -1;
    }
    if (p->twist_max_iter < 1 || !(p->twist_tol > 0.0) || !isfinite(p->twist_tol)) {
        ns_set_err(err, err_sz,
                   "needle: twist_max_iter must be >= 1 and twist_tol finite and > 0 (got %d, %g "
                   "rad)",
                   p->twist_max_iter, p->twist_tol);
        return -1;
    }
    if (p->newton_max < 1 || !(p->newton_strain_tol > 0.0) || !isfinite(p->newton_strain_tol)) {
        ns_set_err(err, err_sz,
                   "needle: newton_max must be >= 1 and newton_strain_tol finite and > 0 (got %d, "
                   "%g)",
                   p->newton_max, p->newton_strain_tol);
        return -1;
    }
    if (!(p->merge_factor >= 0.0) || !(p->split_factor > 2.0 * p->merge_factor) ||
        !isfinite(p->split_factor)) {
        ns_set_err(err, err_sz, "needle: split_factor must exceed twice merge_factor (got %g, %g)",
                   p->split_factor, p->merge_factor);
        return -1;
    }
    for (int d = 0; d < 3; d++)
        if (!isfinite(p->gravity[d])) {
            ns_set_err(err, err_sz, "needle: gravity must be finite");
            return -1;
        }
    return 0;
}

/* ---- storage ---- */

/* Scratch doubles per node slot: the edge frames t, len, m1, m2, d1 (13, used by the energy and
 * force evaluations) and, after them, the step's or static solve's vectors (4 x 3), DOF mask
 * (3 bytes, within 1 double), the step's start x, v, a (3 x 3), and its saved strains, twist
 * angles and accelerations (1 + 1 + 3). */
#define WORK_PER_NODE 40

int rod_reserve(NsRod *r, int cap)
{
    if (cap <= r->cap)
        return 0;
    int c = r->cap > 0 ? r->cap : 8;
    while (c < cap)
        c *= 2;
    size_t n = (size_t)c;
#define GROW(field, count)                                                                         \
    do {                                                                                           \
        void *p_ = realloc(r->field, (count) * sizeof *r->field);                                  \
        if (!p_)                                                                                   \
            return -1;                                                                             \
        r->field = p_;                                                                             \
    } while (0)
    GROW(x, 3 * n);
    GROW(v, 3 * n);
    GROW(a, 3 * n);
    GROW(mass, n);
    GROW(force, 3 * n);
    GROW(rest_len, n);
    GROW(theta, n);
    GROW(ref_t, 3 * n);
    GROW(ref_d1, 3 * n);
    GROW(ref_twist, n);
    GROW(rest_curv, 2 * n);
    GROW(pinned, n);
    GROW(twist_fric, n);
    GROW(twist_anchor, n);
    GROW(work, WORK_PER_NODE * n);
#undef GROW
    size_t old = (size_t)r->cap;
#define ZERO_TAIL(field, per) memset(r->field + (per)*old, 0, (per) * (n - old) * sizeof *r->field)
    ZERO_TAIL(x, 3);
    ZERO_TAIL(v, 3);
    ZERO_TAIL(a, 3);
    ZERO_TAIL(mass, 1);
    ZERO_TAIL(force, 3);
    ZERO_TAIL(rest_len, 1);
    ZERO_TAIL(theta, 1);
    ZERO_TAIL(ref_t, 3);
    ZERO_TAIL(ref_d1, 3);
    ZERO_TAIL(ref_twist, 1);
    ZERO_TAIL(rest_curv, 2);
    ZERO_TAIL(pinned, 1);
    ZERO_TAIL(twist_fric, 1);
    ZERO_TAIL(twist_anchor, 1);
#undef ZERO_TAIL
    NsBanded K, D, A;
    if (ns_banded_init(&K, c, 2) || ns_banded_init(&D, c, 2) || ns_banded_init(&A, c, 2)) {
        ns_banded_free(&K);
        ns_banded_free(&D);
        ns_banded_free(&A);
        return -1; /* the arrays grew, the matrices and cap did not: the rod still works */
    }
    ns_banded_free(&r->K);
    ns_banded_free(&r->D);
    ns_banded_free(&r->A);
    r->K = K;
    r->D = D;
    r->A = A;
    r->cap = c;
    return 0;
}

static void rod_blank(void *e)
{
    NsRod *h = e;
    h->x = h->v = h->a = h->mass = h->force = h->rest_len = h->theta = NULL;
    h->ref_t = h->ref_d1 = h->ref_twist = h->rest_curv = h->work = NULL;
    h->pinned = NULL;
    h->twist_fric = h->twist_anchor = NULL;
    memset(&h->K, 0, sizeof h->K);
    memset(&h->D, 0, sizeof h->D);
    memset(&h->A, 0, sizeof h->A);
}

/* Every per-node array over all of cap (the tails matter when the rod grows), the scratch whole
 * (it keeps the step's saved start between begin_step and end_step), K, D and A. */
int ns_rod_pack(NsPack *p, NsRod *r)
{
    ns_pack_struct(p, "ROD ", r, sizeof *r, rod_blank);
    size_t c = (size_t)r->cap;
    NS_PACK_ARRAY(p, r->x, 3 * c, 3 * c);
    NS_PACK_ARRAY(p, r->v, 3 * c, 3 * c);
    NS_PACK_ARRAY(p, r->a, 3 * c, 3 * c);
    NS_PACK_ARRAY(p, r->mass, c, c);
    NS_PACK_ARRAY(p, r->force, 3 * c, 3 * c);
    NS_PACK_ARRAY(p, r->rest_len, c, c);
    NS_PACK_ARRAY(p, r->theta, c, c);
    NS_PACK_ARRAY(p, r->ref_t, 3 * c, 3 * c);
    NS_PACK_ARRAY(p, r->ref_d1, 3 * c, 3 * c);
    NS_PACK_ARRAY(p, r->ref_twist, c, c);
    NS_PACK_ARRAY(p, r->rest_curv, 2 * c, 2 * c);
    NS_PACK_ARRAY(p, r->pinned, c, c);
    NS_PACK_ARRAY(p, r->twist_fric, c, c);
    NS_PACK_ARRAY(p, r->twist_anchor, c, c);
    NS_PACK_ARRAY(p, r->work, WORK_PER_NODE * c, WORK_PER_NODE * c);
    ns_banded_pack(p, &r->K);
    ns_banded_pack(p, &r->D);
    ns_banded_pack(p, &r->A);
    return p->failed ? -1 : 0;
}

void ns_rod_free(NsRod *r)
{
    free(r->x);
    free(r->v);
    free(r->a);
    free(r->mass);
    free(r->force);
    free(r->rest_len);
    free(r->theta);
    free(r->ref_t);
    free(r->ref_d1);
    free(r->ref_twist);
    free(r->rest_curv);
    free(r->pinned);
    free(r->twist_fric);
    free(r->twist_anchor);
    free(r->work);
    ns_banded_free(&r->K);
    ns_banded_free(&r->D);
    ns_banded_free(&r->A);
    memset(r, 0, sizeof *r);
}

/* Lumped masses: each node gets half of the rest length of each edge it touches (rho A l). */
void rod_masses(NsRod *r)
{
    int n = r->nodes;
    for (int i = 0; i < n; i++) {
        double l = 0.0;
        if (i > 0)
            l += 0.5 * r->rest_len[i - 1];
        if (i < n - 1)
            l += 0.5 * r->rest_len[i];
        r->mass[i] = r->lin_density * l;
    }
}

/* Voronoi rest length of interior node i (Bergou 2008: half the two rest lengths). At the
 * sleeve's exit (node 1 of a held rod) only the half edge outside the sleeve bends or twists:
 * the part inside is rigid, so counting its half edge too would lengthen the free rod by half an
 * edge (a first-order error: 7.5% on a 20-edge cantilever's tip deflection). */
static double voronoi(const NsRod *r, int i)
{
    if (i == 1 && r->held == 2)
        return 0.5 * r->rest_len[1];
    return 0.5 * (r->rest_len[i - 1] + r->rest_len[i]);
}

/* ---- frames ---- */

/* Edge frames at positions x: unit tangents, lengths, and the material directors m1, m2 of the
 * reference frames carried from ref_t to the tangents of x and turned by theta. Buffers are
 * (edges x 3) and (edges). Returns 0, or -1 if an edge has zero length. */
static int edge_frames(const NsRod *r, const double *x, double *t, double *len, double *m1,
                       double *m2, double *d1out)
{
    int ne = r->nodes - 1;
    for (int j = 0; j < ne; j++) {
        double e[3];
        for (int k = 0; k < 3; k++)
            e[k] = x[3 * (j + 1) + k] - x[3 * j + k];
        double l = norm3(e);
        if (!(l > 0.0))
            return -1;
        len[j] = l;
        for (int k = 0; k < 3; k++)
            t[3 * j + k] = e[k] / l;
        double d1[3], d2[3];
        transport(r->ref_t + 3 * j, t + 3 * j, r->ref_d1 + 3 * j, d1);
        orthonormalize(t + 3 * j, d1);
        cross3(t + 3 * j, d1, d2);
        if (d1out)
            memcpy(d1out + 3 * j, d1, sizeof d1);
        double c = cos(r->theta[j]), s = sin(r->theta[j]);
        for (int k = 0; k < 3; k++) {
            m1[3 * j + k] = c * d1[k] + s * d2[k];
            m2[3 * j + k] = -s * d1[k] + c * d2[k];
        }
    }
    return 0;
}

/* Reference twist between edges a and b (Bergou 2010 §4.2): the signed angle about t_b from the
 * reference director of a, parallel transported onto b, to the reference director of b. */
static double reference_twist(const double *ta, const double *d1a, const double *tb,
                              const double *d1b)
{
    double u[3], c[3];
    transport(ta, tb, d1a, u);
    cross3(u, d1b, c);
    return atan2(dot3(c, tb), dot3(u, d1b));
}

/* Curvature binormal (kb) at the node between unit tangents t0, t1 (Bergou 2008 Eq. 1):
 * 2 t0 x t1 / (1 + t0 . t1). Returns chi = 1 + t0 . t1. */
static double curvature_binormal(const double *t0, const double *t1, double *kb)
{
    double chi = 1.0 + dot3(t0, t1);
    if (chi < 1e-12)
        chi = 1e-12;
    cross3(t0, t1, kb);
    for (int k = 0; k < 3; k++)
        kb[k] *= 2.0 / chi;
    return chi;
}

/* One node's bending quantities. kappa1 = kb . (m2a + m2b) / 2, kappa2 = -kb . (m1a + m1b) / 2
 * (the material curvatures of Bergou 2010, averaged over the two edges) and their gradients with
 * respect to the two edge vectors e0 = x_i - x_{i-1}, e1 = x_{i+1} - x_i, with the material
 * frames carried by parallel transport (Bergou 2010 Eq. 11; derivation in Jawed, Novelia and
 * O'Reilly 2018, "A primer on the kinematics of discrete elastic rods", §7). */
typedef struct Hinge {
    double kb[3];
    double k1, k2;
    double dk1_de0[3], dk1_de1[3], dk2_de0[3], dk2_de1[3];
} Hinge;

static void hinge_eval(const double *t0, const double *t1, double l0, double l1, const double *m1a,
                       const double *m2a, const double *m1b, const double *m2b, Hinge *h)
{
    double chi = curvature_binormal(t0, t1, h->kb);
    double tt[3], mm1[3], mm2[3];
    for (int k = 0; k < 3; k++) {
        tt[k] = (t0[k] + t1[k]) / chi;
        mm1[k] = (m1a[k] + m1b[k]) / chi;
        mm2[k] = (m2a[k] + m2b[k]) / chi;
    }
    double s1[3], s2[3];
    for (int k = 0; k < 3; k++) {
        s1[k] = m1a[k] + m1b[k];
        s2[k] = m2a[k] + m2b[k];
    }
    h->k1 = 0.5 * dot3(h->kb, s2);
    h->k2 = -0.5 * dot3(h->kb, s1);
    double c[3];
    cross3(t1, mm2, c);
    for (int k = 0; k < 3; k++)
        h->dk1_de0[k] = (-h->k1 * tt[k] + c[k]) / l0;
    cross3(t0, mm2, c);
    for (int k = 0; k < 3; k++)
        h->dk1_de1[k] = (-h->k1 * tt[k] - c[k]) / l1;
    cross3(t1, mm1, c);
    for (int k = 0; k < 3; k++)
        h->dk2_de0[k] = (-h->k2 * tt[k] - c[k]) / l0;
    cross3(t0, mm1, c);
    for (int k = 0; k < 3; k++)
        h->dk2_de1[k] = (-h->k2 * tt[k] + c[k]) / l1;
}

void ns_rod_material_frame(const NsRod *r, int j, double *t, double *m1, double *m2)
{
    const double *tj = r->ref_t + 3 * j, *d1 = r->ref_d1 + 3 * j;
    double d2[3];
    cross3(tj, d1, d2);
    double c = cos(r->theta[j]), s = sin(r->theta[j]);
    for (int k = 0; k < 3; k++) {
        if (t)
            t[k] = tj[k];
        if (m1)
            m1[k] = c * d1[k] + s * d2[k];
        if (m2)
            m2[k] = -s * d1[k] + c * d2[k];
    }
}

void ns_rod_tip_frame(const NsRod *r, double *t, double *m1, double *m2)
{
    ns_rod_material_frame(r, r->nodes - 2, t, m1, m2);
}

/* ---- energies ---- */

double ns_rod_energy(const NsRod *r, const double *x, double *bend, double *twist, double *stretch)
{
    if (!x)
        x = r->x;
    int n = r->nodes, ne = n - 1;
    double *t = r->work, *len = t + 3 * (size_t)r->cap, *m1 = len + r->cap;
    double *m2 = m1 + 3 * (size_t)r->cap, *d1 = m2 + 3 * (size_t)r->cap;
    double eb = 0.0, et = 0.0, es = 0.0;
    if (edge_frames(r, x, t, len, m1, m2, d1) != 0) {
        eb = et = es = NAN;
    } else {
        for (int j = 0; j < ne; j++) {
            double dl = len[j] - r->rest_len[j];
            es += 0.5 * r->stretch_stiff * dl * dl / r->rest_len[j];
        }
        for (int i = 1; i < ne; i++) {
            Hinge h;
            hinge_eval(t + 3 * (i - 1), t + 3 * i, len[i - 1], len[i], m1 + 3 * (i - 1),
                       m2 + 3 * (i - 1), m1 + 3 * i, m2 + 3 * i, &h);
            double D = voronoi(r, i);
            double r1 = h.k1 - r->rest_curv[2 * i] * D, r2 = h.k2 - r->rest_curv[2 * i + 1] * D;
            eb += 0.5 * r->bend_stiff / D * (r1 * r1 + r2 * r2);
            double mref = reference_twist(t + 3 * (i - 1), d1 + 3 * (i - 1), t + 3 * i, d1 + 3 * i);
            double tw = r->theta[i] - r->theta[i - 1] + mref;
            et += 0.5 * r->twist_stiff / D * tw * tw;
        }
    }
    if (bend)
        *bend = eb;
    if (twist)
        *twist = et;
    if (stretch)
        *stretch = es;
    return eb + et + es;
}

double ns_rod_edges_length(const NsRod *r)
{
    double s = 0.0;
    for (int j = 0; j + 1 < r->nodes; j++) {
        double e[3];
        for (int k = 0; k < 3; k++)
            e[k] = r->x[3 * (j + 1) + k] - r->x[3 * j + k];
        s += norm3(e);
    }
    return s;
}

double ns_rod_rest_length(const NsRod *r)
{
    double s = 0.0;
    for (int j = 0; j + 1 < r->nodes; j++)
        s += r->rest_len[j];
    return s;
}

/* ---- quasi-static twist (Bergou 2008 §5: the twist angles minimise the energy) ---- */

/* The energy terms that depend on theta, with the node data cached by twist_setup. */
typedef struct TwistNode {
    double kb[3];
    double d1a[3], d2a[3], d1b[3], d2b[3];
    double mref, D, kbar1, kbar2;
} TwistNode;

static double twist_energy(const NsRod *r, const TwistNode *tn, const double *theta, double *g,
                           double *hd, double *ho, int gauss_newton)
{
    int ne = r->nodes - 1;
    double E = 0.0;
    if (g) {
        memset(g, 0, (size_t)ne * sizeof *g);
        memset(hd, 0, (size_t)ne * sizeof *hd);
        memset(ho, 0, (size_t)ne * sizeof *ho);
    }
    for (int i = 1; i < ne; i++) {
        const TwistNode *q = &tn[i];
        double ca = cos(theta[i - 1]), sa = sin(theta[i - 1]);
        double cb = cos(theta[i]), sb = sin(theta[i]);
        double m1a[3], m2a[3], m1b[3], m2b[3];
        for (int k = 0; k < 3; k++) {
            m1a[k] = ca * q->d1a[k] + sa * q->d2a[k];
            m2a[k] = -sa * q->d1a[k] + ca * q->d2a[k];
            m1b[k] = cb * q->d1b[k] + sb * q->d2b[k];
            m2b[k] = -sb * q->d1b[k] + cb * q->d2b[k];
        }
        double kbm1a = dot3(q->kb, m1a), kbm2a = dot3(q->kb, m2a);
        double kbm1b = dot3(q->kb, m1b), kbm2b = dot3(q->kb, m2b);
        double k1 = 0.5 * (kbm2a + kbm2b), k2 = -0.5 * (kbm1a + kbm1b);
        double r1 = k1 - q->kbar1, r2 = k2 - q->kbar2;
        double tw = theta[i] - theta[i - 1] + q->mref;
        double cb_ = r->bend_stiff / q->D, ct = r->twist_stiff / q->D;
        E += 0.5 * cb_ * (r1 * r1 + r2 * r2) + 0.5 * ct * tw * tw;
        if (!g)
            continue;
        /* d kappa1 / d theta_j = -kb . m1_j / 2, d kappa2 / d theta_j = -kb . m2_j / 2;
         * second derivatives -kb . m2_j / 2 and +kb . m1_j / 2. */
        double g1a = -0.5 * kbm1a, g1b = -0.5 * kbm1b, g2a = -0.5 * kbm2a, g2b = -0.5 * kbm2b;
        g[i - 1] += cb_ * (r1 * g1a + r2 * g2a) - ct * tw;
        g[i] += cb_ * (r1 * g1b + r2 * g2b) + ct * tw;
        double haa = cb_ * (g1a * g1a + g2a * g2a) + ct;
        double hbb = cb_ * (g1b * g1b + g2b * g2b) + ct;
        if (!gauss_newton) {
            haa += cb_ * (r1 * (-0.5 * kbm2a) + r2 * (0.5 * kbm1a));
            hbb += cb_ * (r1 * (-0.5 * kbm2b) + r2 * (0.5 * kbm1b));
        }
        hd[i - 1] += haa;
        hd[i] += hbb;
        ho[i - 1] += cb_ * (g1a * g1b + g2a * g2b) - ct; /* (i-1, i) */
    }
    return E;
}

/* Solves the tridiagonal system (diagonal hd, off-diagonal ho) for the angles j >= first with
 * right-hand side -g into dx; angles before first are held (dx 0). Returns -1 if a pivot is not
 * clearly positive (indefinite, or singular: a free rod whose energy does not depend on a common
 * turn of all its angles). */
static int twist_tridiag(int ne, int first, const double *hd, const double *ho, const double *g,
                         double *dx, double *cp)
{
    for (int j = 0; j < first && j < ne; j++)
        dx[j] = 0.0;
    if (ne <= first)
        return 0;
    double piv = hd[first];
    if (!(piv > 1e-12 * fabs(hd[first])) || !(piv > 0.0))
        return -1;
    cp[first] = ho[first] / piv;
    dx[first] = -g[first] / piv;
    for (int j = first + 1; j < ne; j++) {
        piv = hd[j] - ho[j - 1] * cp[j - 1];
        if (!(piv > 1e-12 * fabs(hd[j])) || !(piv > 0.0))
            return -1;
        cp[j] = ho[j] / piv;
        dx[j] = (-g[j] - ho[j - 1] * dx[j - 1]) / piv;
    }
    for (int j = ne - 2; j >= first; j--)
        dx[j] -= cp[j] * dx[j + 1];
    return 0;
}

/* Newton direction for the twist: the full Hessian, else its Gauss-Newton part; for a free rod
 * all angles move, else (or if that is singular) theta_0 is held. The tip torque enters the
 * gradient; with friction (fw != NULL) the direction is the friction step's (stick/slip,
 * sim/twist_friction.h). Returns the first free angle, or -1 if no direction was found. */
static int twist_direction(const NsRod *r, const TwistNode *tn, double *g, double *hd, double *ho,
                           double *dx, double *cp, double *fw)
{
    int ne = r->nodes - 1;
    for (int first = r->held ? 1 : 0; first <= 1; first++)
        for (int gn = 0; gn <= 1; gn++) {
            twist_energy(r, tn, r->theta, g, hd, ho, gn);
            if (r->tip_torque != 0.0)
                g[ne - 1] -= r->tip_torque;
            if (fw ? ns_twist_friction_step(ne, first, hd, ho, g, r->theta, r->twist_anchor,
                                            r->twist_fric, dx, fw) > 0
                   : twist_tridiag(ne, first, hd, ho, g, dx, cp) == 0)
                return first;
        }
    return -1;
}

/* The potential the quasi-static twist minimises: the elastic energy's theta-dependent part,
 * minus the tip torque's work, plus the friction's dissipation from the anchors (fric: friction
 * on; sim/twist_friction.h). */
static double twist_potential(const NsRod *r, const TwistNode *tn, const double *theta, int fric)
{
    int ne = r->nodes - 1;
    double E = twist_energy(r, tn, theta, NULL, NULL, NULL, 0);
    if (r->tip_torque != 0.0)
        E -= r->tip_torque * theta[ne - 1];
    if (fric)
        E += ns_twist_friction_energy(ne, theta, r->twist_anchor, r->twist_fric);
    return E;
}

static void solve_twist(NsRod *r, NsRodStats *stats)
{
    int n = r->nodes, ne = n - 1;
    TwistNode *tn = malloc((size_t)n * sizeof *tn);
    int fric = 0;
    for (int j = 0; j < ne && !fric; j++)
        fric = r->twist_fric[j] > 0.0;
    double *buf =
        malloc(((size_t)ne * 7 + (fric ? NS_TWIST_FRICTION_WORK(ne) : 0)) * sizeof(double));
    if (!tn || !buf) {
        free(tn);
        free(buf);
        if (stats)
            stats->twist_unconverged++;
        return;
    }
    double *g = buf, *hd = g + ne, *ho = hd + ne, *dx = ho + ne, *cp = dx + ne, *trial = cp + ne;
    double *fw = fric ? trial + ne : NULL;
    for (int i = 1; i < ne; i++) {
        TwistNode *q = &tn[i];
        const double *ta = r->ref_t + 3 * (i - 1), *tb = r->ref_t + 3 * i;
        curvature_binormal(ta, tb, q->kb);
        memcpy(q->d1a, r->ref_d1 + 3 * (i - 1), sizeof q->d1a);
        memcpy(q->d1b, r->ref_d1 + 3 * i, sizeof q->d1b);
        cross3(ta, q->d1a, q->d2a);
        cross3(tb, q->d1b, q->d2b);
        q->mref = r->ref_twist[i];
        q->D = voronoi(r, i);
        q->kbar1 = r->rest_curv[2 * i] * q->D;
        q->kbar2 = r->rest_curv[2 * i + 1] * q->D;
    }
    int it, converged = ne < 2;
    for (it = 0; it < r->params.twist_max_iter && !converged; it++) {
        double E = twist_potential(r, tn, r->theta, fric);
        int first = twist_direction(r, tn, g, hd, ho, dx, cp, fw);
        if (first < 0)
            break;
        double step = 0.0, slope = 0.0;
        for (int j = first; j < ne; j++) {
            step = fabs(dx[j]) > step ? fabs(dx[j]) : step;
            slope += g[j] * dx[j];
        }
        /* With friction the potential is not smooth: its decrease predicted by the model's
         * linear part, g dx plus the change of the friction term (Tseng and Yun 2009, Math.
         * Program. 117, the Armijo rule for l1 terms). */
        for (int j = first; j < ne && fric; j++)
            slope += r->twist_fric[j] * (fabs(r->theta[j] + dx[j] - r->twist_anchor[j]) -
                                         fabs(r->theta[j] - r->twist_anchor[j]));
        if (!(step > r->params.twist_tol)) {
            converged = 1;
            break;
        }
        double alpha = 1.0;
        for (int ls = 0; ls < 30; ls++) {
            for (int j = 0; j < ne; j++)
                trial[j] = r->theta[j] + alpha * dx[j];
            double Et = twist_potential(r, tn, trial, fric);
            if (Et <= E + 1e-4 * alpha * slope || alpha * step <= r->params.twist_tol)
                break;
            alpha *= 0.5;
        }
        for (int j = first; j < ne; j++)
            r->theta[j] += alpha * dx[j];
        if (alpha * step <= r->params.twist_tol)
            converged = 1;
    }
    if (stats) {
        stats->twist_iterations = it;
        stats->twist_unconverged += !converged;
    }
    free(tn);
    free(buf);
}

void ns_rod_update_frames(NsRod *r, NsRodStats *stats)
{
    double t0 = now_ms();
    int ne = r->nodes - 1;
    for (int j = 0; j < ne; j++) {
        double e[3], t[3], d1[3];
        for (int k = 0; k < 3; k++)
            e[k] = r->x[3 * (j + 1) + k] - r->x[3 * j + k];
        double l = norm3(e);
        if (!(l > 0.0))
            continue; /* a collapsed edge keeps its old frame (its forces come out NaN) */
        for (int k = 0; k < 3; k++)
            t[k] = e[k] / l;
        transport(r->ref_t + 3 * j, t, r->ref_d1 + 3 * j, d1);
        orthonormalize(t, d1);
        memcpy(r->ref_t + 3 * j, t, sizeof t);
        memcpy(r->ref_d1 + 3 * j, d1, sizeof d1);
    }
    for (int i = 1; i < ne; i++)
        r->ref_twist[i] = reference_twist(r->ref_t + 3 * (i - 1), r->ref_d1 + 3 * (i - 1),
                                          r->ref_t + 3 * i, r->ref_d1 + 3 * i);
    solve_twist(r, stats);
    if (stats)
        stats->twist_ms += now_ms() - t0;
}

/* ---- initialisation ---- */

void ns_rod_set_rest_curvature(NsRod *r, int i, double k1, double k2)
{
    if (i < 1 || i > r->nodes - 2)
        return;
    r->rest_curv[2 * i] = k1;
    r->rest_curv[2 * i + 1] = k2;
}

/* The rest curvature that makes the current shape stress-free (per unit rest length). */
static void rest_curvature_from_shape(NsRod *r)
{
    int ne = r->nodes - 1;
    for (int i = 1; i < ne; i++) {
        double m1a[3], m2a[3], m1b[3], m2b[3], ta[3], tb[3];
        ns_rod_material_frame(r, i - 1, ta, m1a, m2a);
        ns_rod_material_frame(r, i, tb, m1b, m2b);
        double l0 = r->rest_len[i - 1], l1 = r->rest_len[i];
        Hinge h;
        hinge_eval(ta, tb, l0, l1, m1a, m2a, m1b, m2b, &h);
        double D = voronoi(r, i);
        r->rest_curv[2 * i] = h.k1 / D;
        r->rest_curv[2 * i + 1] = h.k2 / D;
    }
}

/* Bishop frame along the rod (space-parallel transport from edge 0, Bergou 2008 §4.2): ref_t
 * must hold the tangents and ref_d1[0] the first director. Reference twists become 0. */
void rod_bishop_frames(NsRod *r)
{
    int ne = r->nodes - 1;
    orthonormalize(r->ref_t, r->ref_d1);
    for (int j = 1; j < ne; j++) {
        transport(r->ref_t + 3 * (j - 1), r->ref_t + 3 * j, r->ref_d1 + 3 * (j - 1),
                  r->ref_d1 + 3 * j);
        orthonormalize(r->ref_t + 3 * j, r->ref_d1 + 3 * j);
    }
    for (int i = 0; i < r->nodes; i++)
        r->ref_twist[i] = 0.0;
    for (int i = 1; i < ne; i++)
        r->ref_twist[i] = reference_twist(r->ref_t + 3 * (i - 1), r->ref_d1 + 3 * (i - 1),
                                          r->ref_t + 3 * i, r->ref_d1 + 3 * i);
}

int ns_rod_init(NsRod *r, const double *x, int n, const double *d1, int held,
                const NsRodParams *params, char *err, int err_sz)
{
    memset(r, 0, sizeof *r);
    NsRodParams p = params ? *params : ns_default_rod_params();
    if (check_params(&p, err, err_sz) != 0)
        return -1;
    if (n < 3) {
        ns_set_err(err, err_sz, "needle: needs at least 3 nodes (got %d)", n);
        return -1;
    }
    if (held != 0 && held != 2) {
        ns_set_err(err, err_sz, "needle: held must be 0 or 2 (got %d)", held);
        return -1;
    }
    for (int i = 0; i < 3 * n; i++)
        if (!isfinite(x[i])) {
            ns_set_err(err, err_sz, "needle: node %d has a non-finite coordinate", i / 3);
            return -1;
        }
    r->params = p;
    if (rod_reserve(r, n) != 0) {
        ns_rod_free(r);
        ns_set_err(err, err_sz, "needle: out of memory (%d nodes)", n);
        return -1;
    }
    r->nodes = n;
    r->held = held;
    const NsRodMaterial *m = &p.material;
    double ro = 0.5 * m->outer_diameter, ri = 0.5 * m->inner_diameter;
    double G = m->shear > 0.0 ? m->shear : m->youngs / (2.0 * (1.0 + m->poisson));
    double I = 0.25 * M_PI * (ro * ro * ro * ro - ri * ri * ri * ri);
    r->area = M_PI * (ro * ro - ri * ri);
    r->bend_stiff = NS_MUTATE("ei", m->youngs * I);
    r->twist_stiff = NS_MUTATE("gj", G * 2.0 * I); /* J = 2 I for a circular (hollow) section */
    r->stretch_stiff = p.stretch_scale * m->youngs * r->area;
    r->lin_density = m->density * r->area;
    memcpy(r->x, x, 3 * (size_t)n * sizeof(double));
    memset(r->v, 0, 3 * (size_t)n * sizeof(double));
    memset(r->a, 0, 3 * (size_t)n * sizeof(double));
    memset(r->theta, 0, (size_t)n * sizeof(double));
    r->min_rest_edge = DBL_MAX;
    r->max_rest_edge = 0.0;
    for (int j = 0; j < n - 1; j++) {
        double e[3];
        for (int k = 0; k < 3; k++)
            e[k] = x[3 * (j + 1) + k] - x[3 * j + k];
        double l = norm3(e);
        if (!(l > 0.0)) {
            ns_rod_free(r);
            ns_set_err(err, err_sz, "needle: edge %d (nodes %d-%d) has zero length", j, j, j + 1);
            return -1;
        }
        if (j > 0) {
            double c = dot3(e, r->ref_t + 3 * (j - 1)) / l;
            if (c < -1.0 + 1e-9) {
                ns_rod_free(r);
                ns_set_err(err, err_sz, "needle: the rod folds back on itself at node %d", j);
                return -1;
            }
        }
        r->rest_len[j] = l;
        for (int k = 0; k < 3; k++)
            r->ref_t[3 * j + k] = e[k] / l;
        r->min_rest_edge = l < r->min_rest_edge ? l : r->min_rest_edge;
        r->max_rest_edge = l > r->max_rest_edge ? l : r->max_rest_edge;
    }
    double dd[3] = {0.0, 0.0, 0.0};
    if (d1)
        memcpy(dd, d1, sizeof dd);
    memcpy(r->ref_d1, dd, sizeof dd);
    rod_bishop_frames(r);
    rest_curvature_from_shape(r);
    rod_masses(r);
    return 0;
}

/* ---- forces and Jacobians ---- */

static void add_block(NsBanded *m, int i, int j, const double *b, double s)
{
    double *p = ns_banded_block(m, i, j);
    for (int k = 0; k < 9; k++)
        p[k] += s * b[k];
}

/* Forces and Jacobians; clamp drops the stretching springs' transverse stiffness under
 * compression (the definite K of ns_rod_forces), else it is kept (the exact geometric stiffness
 * of an axially loaded rod, which the static solve uses while it is definite). */
static void forces_impl(NsRod *r, const double *ext, int clamp)
{
    int n = r->nodes, ne = n - 1;
    double *t = r->work, *len = t + 3 * (size_t)r->cap, *m1 = len + r->cap;
    double *m2 = m1 + 3 * (size_t)r->cap, *d1 = m2 + 3 * (size_t)r->cap;
    double *F = r->force;
    ns_banded_zero(&r->K);
    ns_banded_zero(&r->D);
    memset(F, 0, 3 * (size_t)n * sizeof *F);
    if (edge_frames(r, r->x, t, len, m1, m2, d1) != 0) {
        for (int i = 0; i < 3 * n; i++)
            F[i] = NAN;
        return;
    }
    /* Stretching (Spillmann & Teschner 2007): E = k_s (l - L)^2 / (2 L) per edge, and its
     * dashpot. */
    for (int j = 0; j < ne; j++) {
        const double *tj = t + 3 * j;
        double L = r->rest_len[j], k = r->stretch_stiff / L;
        double f = k * (len[j] - L);
        double rate = 0.0;
        for (int c = 0; c < 3; c++)
            rate += (r->v[3 * (j + 1) + c] - r->v[3 * j + c]) * tj[c];
        double cd = r->params.damping_stretch * k;
        f += cd * rate;
        for (int c = 0; c < 3; c++) {
            F[3 * j + c] += f * tj[c];
            F[3 * (j + 1) + c] -= f * tj[c];
        }
        /* dF_{j+1}/dx_{j+1} = -k (t t^T + max(0, 1 - L/l) (I - t t^T)); the transverse part is
         * dropped under compression so that K stays negative semidefinite. */
        double tr = 1.0 - L / len[j];
        if (tr < 0.0 && clamp)
            tr = 0.0;
        double B[9], Bd[9];
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++) {
                double tt = tj[a] * tj[b];
                B[3 * a + b] = -k * (tt + tr * ((a == b) - tt));
                Bd[3 * a + b] = -cd * tt;
            }
        add_block(&r->K, j, j, B, 1.0);
        add_block(&r->K, j + 1, j + 1, B, 1.0);
        add_block(&r->K, j, j + 1, B, -1.0);
        add_block(&r->K, j + 1, j, B, -1.0);
        add_block(&r->D, j, j, Bd, 1.0);
        add_block(&r->D, j + 1, j + 1, Bd, 1.0);
        add_block(&r->D, j, j + 1, Bd, -1.0);
        add_block(&r->D, j + 1, j, Bd, -1.0);
    }
    /* Bending and twisting at every interior node (Bergou 2008, 2010). */
    for (int i = 1; i < ne; i++) {
        Hinge h;
        hinge_eval(t + 3 * (i - 1), t + 3 * i, len[i - 1], len[i], m1 + 3 * (i - 1),
                   m2 + 3 * (i - 1), m1 + 3 * i, m2 + 3 * i, &h);
        double D = voronoi(r, i), cb = r->bend_stiff / D, ct = r->twist_stiff / D;
        double r1 = h.k1 - r->rest_curv[2 * i] * D, r2 = h.k2 - r->rest_curv[2 * i + 1] * D;
        double mref = reference_twist(t + 3 * (i - 1), d1 + 3 * (i - 1), t + 3 * i, d1 + 3 * i);
        double tw = r->theta[i] - r->theta[i - 1] + mref;
        /* dE/de0, dE/de1. The reference twist's gradient is kb / (2 l) on both edges. */
        double g0[3], g1[3];
        for (int c = 0; c < 3; c++) {
            g0[c] = cb * (r1 * h.dk1_de0[c] + r2 * h.dk2_de0[c]) +
                    ct * tw * h.kb[c] / (2.0 * len[i - 1]);
            g1[c] =
                cb * (r1 * h.dk1_de1[c] + r2 * h.dk2_de1[c]) + ct * tw * h.kb[c] / (2.0 * len[i]);
        }
        for (int c = 0; c < 3; c++) {
            F[3 * (i - 1) + c] += g0[c];
            F[3 * i + c] += g1[c] - g0[c];
            F[3 * (i + 1) + c] -= g1[c];
        }
        /* Gauss-Newton bending Hessian: cb (grad k1 grad k1^T + grad k2 grad k2^T) over the
         * nodes i-1, i, i+1; K = -Hessian. */
        double G1[9], G2[9];
        for (int c = 0; c < 3; c++) {
            G1[c] = -h.dk1_de0[c];
            G1[3 + c] = h.dk1_de0[c] - h.dk1_de1[c];
            G1[6 + c] = h.dk1_de1[c];
            G2[c] = -h.dk2_de0[c];
            G2[3 + c] = h.dk2_de0[c] - h.dk2_de1[c];
            G2[6 + c] = h.dk2_de1[c];
        }
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++) {
                double blk[9];
                for (int p = 0; p < 3; p++)
                    for (int q = 0; q < 3; q++)
                        blk[3 * p + q] =
                            -cb * (G1[3 * a + p] * G1[3 * b + q] + G2[3 * a + p] * G2[3 * b + q]);
                add_block(&r->K, i - 1 + a, i - 1 + b, blk, 1.0);
            }
    }
    /* Gravity, mass-proportional damping, external forces. */
    double am = r->params.damping_mass;
    for (int i = 0; i < n; i++) {
        double mi = r->mass[i];
        for (int c = 0; c < 3; c++)
            F[3 * i + c] +=
                mi * (r->params.gravity[c] - am * r->v[3 * i + c]) + (ext ? ext[3 * i + c] : 0.0);
        double *dd = ns_banded_block(&r->D, i, i);
        dd[0] -= am * mi;
        dd[4] -= am * mi;
        dd[8] -= am * mi;
    }
}

void ns_rod_forces(NsRod *r, const double *ext)
{
    forces_impl(r, ext, 1);
}

/* ---- the step ---- */

/* A = mc M - kx K - kv D over the first `nodes` block rows; the unused slots beyond the rod get
 * identity rows so that they solve to zero and do not disturb the band factorisation. */
static void build_system(NsRod *r, double mc, double kx, double kv)
{
    int n = r->nodes, w = 2 * r->A.half + 1;
    for (int i = 0; i < n; i++)
        for (int o = 0; o < w; o++) {
            size_t off = ((size_t)w * (size_t)i + (size_t)o) * 9;
            for (int k = 0; k < 9; k++)
                r->A.val[off + k] = -kx * r->K.val[off + k] - kv * r->D.val[off + k];
        }
    for (int i = 0; i < n; i++) {
        double *b = ns_banded_block(&r->A, i, i);
        b[0] += mc * r->mass[i];
        b[4] += mc * r->mass[i];
        b[8] += mc * r->mass[i];
    }
    for (int i = n; i < r->A.n; i++) {
        for (int o = -2; o <= 2; o++) {
            double *q = ns_banded_block(&r->A, i, i + o);
            if (q)
                memset(q, 0, 9 * sizeof *q);
            q = ns_banded_block(&r->A, i + o, i);
            if (q)
                memset(q, 0, 9 * sizeof *q);
        }
        double *b = ns_banded_block(&r->A, i, i);
        b[0] = b[4] = b[8] = 1.0;
    }
}

/* Largest |l / L - 1| over the edges. */
static void edge_strains(const NsRod *r, double *eps)
{
    for (int j = 0; j + 1 < r->nodes; j++) {
        double e[3];
        for (int k = 0; k < 3; k++)
            e[k] = r->x[3 * (j + 1) + k] - r->x[3 * j + k];
        eps[j] = norm3(e) / r->rest_len[j] - 1.0;
    }
}

/* Largest change of an edge's strain l / L - 1 over the step, from eps0 (taken at its start
 * with the rest lengths of then; steady insertion keeps edge 1's strain, so it does not count). */
static double strain_jump(const NsRod *r, const double *eps0)
{
    double worst = 0.0;
    for (int j = 0; j + 1 < r->nodes; j++) {
        double e[3];
        for (int k = 0; k < 3; k++)
            e[k] = r->x[3 * (j + 1) + k] - r->x[3 * j + k];
        worst = fmax(worst, fabs(norm3(e) / r->rest_len[j] - 1.0 - eps0[j]));
    }
    return worst;
}

/* Applies the controls of §3.5 for one step of size dt: insertion lengthens edge 1 and base
 * rotation turns theta_0. */
static void apply_controls(NsRod *r, double dt, NsRodStats *st)
{
    if (r->held != 2)
        return;
    if (r->v_insert != 0.0 && r->nodes >= 3) {
        double l = r->rest_len[1] + r->v_insert * dt;
        double floor = 1e-3 * r->min_rest_edge;
        r->rest_len[1] = l > floor ? l : floor;
        rod_masses(r);
    }
    if (r->twist_rate != 0.0) {
        r->theta[0] += r->twist_rate * dt;
        solve_twist(r, st);
    }
}

int ns_rod_begin_step(NsRod *r, double dt, const double *ext, NsRodSystem *sys, NsRodStats *st)
{
    int n = r->nodes, n3 = 3 * n, ne = n - 1;
    double beta = r->params.beta, gamma = r->params.gamma;
    if (!(dt > 0.0) || !isfinite(dt) || !isfinite(r->v_insert) || !isfinite(r->twist_rate) ||
        !isfinite(r->v_base[0]) || !isfinite(r->v_base[1]) || !isfinite(r->v_base[2])) {
        st->nan_count++; /* a bad time step or control: refused, nothing changes */
        return -1;
    }
    /* What the step may change before it can fail, kept to undo it: the strains and the rest
     * length of edge 1 (insertion), the twist angles (base rotation), a (the first step). */
    double *eps0 = r->work + 35 * (size_t)r->cap, *theta0 = eps0 + r->cap;
    double *asave = theta0 + r->cap;
    r->undo_len1 = ne > 1 ? r->rest_len[1] : 0.0;
    edge_strains(r, eps0);
    memcpy(theta0, r->theta, (size_t)ne * sizeof *theta0);
    memcpy(r->twist_anchor, r->theta, (size_t)ne * sizeof *r->twist_anchor);
    memcpy(asave, r->a, (size_t)n3 * sizeof *asave);
    double tf = now_ms();
    int nf = 3 * r->held;
    if (r->steps == 0) { /* consistent starting acceleration a0 = M^-1 F(x0, v0), before the
                            controls act */
        ns_rod_forces(r, ext);
        for (int i = nf; i < n3; i++)
            r->a[i] = r->force[i] / r->mass[i / 3];
    }
    apply_controls(r, dt, st);
    ns_rod_forces(r, ext);
    st->force_ms += now_ms() - tf;
    double *rhs = r->work + 13 * (size_t)r->cap, *y = rhs + 3 * (size_t)r->cap;
    double *z = y + 3 * (size_t)r->cap, *anew = z + 3 * (size_t)r->cap;
    build_system(r, 1.0, beta * dt * dt, gamma * dt);
    for (int i = 0; i < n3; i++) {
        y[i] = dt * r->v[i] + dt * dt * (0.5 - beta) * r->a[i];
        z[i] = dt * (1.0 - gamma) * r->a[i];
    }
    for (int i = n3; i < 3 * r->cap; i++)
        y[i] = z[i] = 0.0;
    ns_banded_mul(&r->K, y, rhs);
    ns_banded_mul(&r->D, z, y);
    for (int i = 0; i < n3; i++) {
        rhs[i] += y[i] + r->force[i];
        anew[i] = r->a[i];
    }
    for (int i = n3; i < 3 * r->cap; i++)
        rhs[i] = anew[i] = 0.0;
    /* Held nodes move with the sleeve: their acceleration brings v to v_base this step. */
    for (int i = 0; i < nf; i++)
        anew[i] = (r->v_base[i % 3] - r->v[i] - dt * (1.0 - gamma) * r->a[i]) / (gamma * dt);
    uint8_t *dof_fixed = (uint8_t *)(anew + 3 * (size_t)r->cap);
    memset(dof_fixed, 1, 3 * (size_t)r->cap);
    memset(dof_fixed + nf, 0, (size_t)(n3 - nf));
    sys->A = &r->A;
    sys->rhs = rhs;
    sys->anew = anew;
    sys->dof_fixed = dof_fixed;
    sys->n3 = 3 * r->cap;
    return 0;
}

void ns_rod_abort_step(NsRod *r)
{
    int n = r->nodes, ne = n - 1;
    double *eps0 = r->work + 35 * (size_t)r->cap, *theta0 = eps0 + r->cap;
    double *asave = theta0 + r->cap;
    if (ne > 1)
        r->rest_len[1] = r->undo_len1;
    memcpy(r->theta, theta0, (size_t)ne * sizeof *theta0);
    memcpy(r->a, asave, (size_t)(3 * n) * sizeof *asave);
    rod_masses(r);
}

void ns_rod_end_step(NsRod *r, double dt, const double *anew, NsRodStats *st)
{
    int n3 = 3 * r->nodes;
    double beta = r->params.beta, gamma = r->params.gamma;
    /* x, v from the new accelerations (Eq. 1, 2), keeping the start of the step for further
     * Newton iterations. */
    double *x0 = r->work + 26 * (size_t)r->cap, *v0 = x0 + 3 * (size_t)r->cap;
    double *a0 = v0 + 3 * (size_t)r->cap;
    memcpy(x0, r->x, (size_t)n3 * sizeof *x0);
    memcpy(v0, r->v, (size_t)n3 * sizeof *v0);
    memcpy(a0, r->a, (size_t)n3 * sizeof *a0);
    for (int i = 0; i < n3; i++) {
        r->x[i] = x0[i] + dt * v0[i] + dt * dt * ((0.5 - beta) * a0[i] + beta * anew[i]);
        r->v[i] = v0[i] + dt * ((1.0 - gamma) * a0[i] + gamma * anew[i]);
        r->a[i] = anew[i];
    }
    ns_rod_update_frames(r, st);
    st->newton_iterations = 1;
    r->steps++;
}

int ns_rod_step(NsRod *r, double dt, const double *ext, NsRodStats *stats)
{
    NsRodStats st;
    memset(&st, 0, sizeof st);
    double t0 = now_ms();
    int n3 = 3 * r->nodes, nf = 3 * r->held;
    double beta = r->params.beta, gamma = r->params.gamma;
    NsRodSystem sys;
    if (ns_rod_begin_step(r, dt, ext, &sys, &st)) {
        if (stats)
            *stats = st;
        return -1;
    }
    double ts = now_ms();
    double *rhs = sys.rhs, *anew = sys.anew, *y = rhs + 3 * (size_t)r->cap;
    const uint8_t *dof_fixed = sys.dof_fixed;
    int rc = ns_banded_solve(&r->A, dof_fixed, rhs, anew, NULL);
    st.solve_ms = now_ms() - ts;
    int finite = rc == 0;
    for (int i = 0; i < n3 && finite; i++)
        finite = isfinite(anew[i]);
    if (!finite) {
        st.solve_failed += rc != 0;
        st.nan_count += rc == 0;
        ns_rod_abort_step(r);
        st.total_ms = now_ms() - t0;
        if (stats)
            *stats = st;
        return -1;
    }
    ns_rod_end_step(r, dt, anew, &st);
    double *x0 = r->work + 26 * (size_t)r->cap, *v0 = x0 + 3 * (size_t)r->cap;
    double *a0 = v0 + 3 * (size_t)r->cap, *eps0 = r->work + 35 * (size_t)r->cap;
    /* The paper takes one Newton step (Eq. 4). When that step moved the rod so far that its
     * linearization stretched edges by more than newton_strain_tol (a large load or time step
     * on the free needle), iterate: residual R = F(x, v) - M a at the current iterate, the same
     * system matrix rebuilt there, a += A^-1 R. */
    while (st.newton_iterations < r->params.newton_max &&
           strain_jump(r, eps0) > r->params.newton_strain_tol) {
        ns_rod_forces(r, ext);
        build_system(r, 1.0, beta * dt * dt, gamma * dt);
        for (int i = 0; i < 3 * r->cap; i++) {
            rhs[i] = i < n3 && i >= nf ? r->force[i] - r->mass[i / 3] * r->a[i] : 0.0;
            y[i] = 0.0;
        }
        if (ns_banded_solve(&r->A, dof_fixed, rhs, y, NULL) != 0)
            break;
        int ok = 1;
        for (int i = nf; i < n3 && ok; i++)
            ok = isfinite(y[i]);
        if (!ok)
            break;
        for (int i = 0; i < n3; i++) {
            r->a[i] += y[i];
            r->x[i] = x0[i] + dt * v0[i] + dt * dt * ((0.5 - beta) * a0[i] + beta * r->a[i]);
            r->v[i] = v0[i] + dt * ((1.0 - gamma) * a0[i] + gamma * r->a[i]);
        }
        ns_rod_update_frames(r, &st);
        st.newton_iterations++;
    }
    if (r->params.auto_reparam && ns_rod_reparameterize(r, &st) != 0) {
        st.total_ms = now_ms() - t0;
        if (stats)
            *stats = st;
        return -1;
    }
    st.total_ms = now_ms() - t0;
    if (stats)
        *stats = st;
    return 0;
}

/* Potential energy: elastic minus the work of gravity and ext. */
static double potential(const NsRod *r, const double *x, const double *ext)
{
    double E = ns_rod_energy(r, x, NULL, NULL, NULL);
    for (int i = 0; i < r->nodes; i++)
        for (int c = 0; c < 3; c++)
            E -= (r->mass[i] * r->params.gravity[c] + (ext ? ext[3 * i + c] : 0.0)) * x[3 * i + c];
    return E;
}

int ns_rod_static_solve(NsRod *r, const double *ext, double tol, int max_iter, NsRodStats *stats)
{
    NsRodStats st;
    memset(&st, 0, sizeof st);
    int n = r->nodes, n3 = 3 * n, nf = 3 * r->held;
    double *rhs = r->work + 13 * (size_t)r->cap, *dx = rhs + 3 * (size_t)r->cap;
    double *trial = dx + 3 * (size_t)r->cap;
    uint8_t *dof_fixed = (uint8_t *)(trial + 3 * (size_t)r->cap);
    memset(dof_fixed, 0, 3 * (size_t)r->cap);
    memset(dof_fixed, 1, (size_t)nf);
    memset(r->v, 0, (size_t)n3 * sizeof(double));
    memset(r->a, 0, (size_t)n3 * sizeof(double));
    memcpy(r->twist_anchor, r->theta, (size_t)(n - 1) * sizeof *r->twist_anchor);
    double applied = 0.0;
    for (int i = 0; i < n && ext; i++)
        for (int c = 0; c < 3; c++)
            applied = fmax(applied, fabs(ext[3 * i + c]));
    for (int i = 0; i < n; i++)
        for (int c = 0; c < 3; c++)
            applied = fmax(applied, fabs(r->mass[i] * r->params.gravity[c]));
    int it, result = -1;
    for (it = 0; it <= max_iter; it++) {
        ns_rod_update_frames(r, &st);
        forces_impl(r, ext, 0);
        double res = 0.0, ref = applied > 0.0 ? applied : 1e-300;
        int finite = 1;
        for (int i = 0; i < n3; i++) {
            double f = r->force[i];
            finite &= isfinite(f) != 0;
            if (i < nf)
                ref = fmax(ref, fabs(f));
            else
                res = fmax(res, fabs(f));
        }
        if (!finite) {
            st.nan_count++;
            break;
        }
        if (res <= tol * ref) {
            result = it;
            break;
        }
        if (it == max_iter)
            break;
        /* (-K) dx = F on the free DOFs with the exact geometric stiffness: Newton's step where -K
         * is definite (quadratic convergence up to a buckling load); where it is not (past one),
         * -K + mu I with mu raised tenfold from 1e-8 of the largest diagonal entry until it is
         * (Levenberg-Marquardt), which still descends along the unstable direction. */
        build_system(r, 0.0, 1.0, 0.0);
        for (int i = 0; i < 3 * r->cap; i++) {
            rhs[i] = i < n3 ? r->force[i] : 0.0;
            dx[i] = 0.0;
        }
        int solved = ns_banded_solve(&r->A, dof_fixed, rhs, dx, NULL) == 0;
        double dmax = 0.0, mu = 0.0;
        for (int i = 0; i < n && !solved; i++) {
            const double *b = ns_banded_block(&r->A, i, i);
            dmax = fmax(dmax, fmax(b[0], fmax(b[4], b[8])));
        }
        for (int tries = 0; tries < 24 && !solved; tries++) {
            double add = (mu == 0.0 ? 1e-8 * dmax : 9.0 * mu);
            mu += add;
            for (int i = 0; i < n; i++) {
                double *b = ns_banded_block(&r->A, i, i);
                b[0] += add;
                b[4] += add;
                b[8] += add;
            }
            solved = ns_banded_solve(&r->A, dof_fixed, rhs, dx, NULL) == 0;
        }
        if (!solved) {
            st.solve_failed++;
            break;
        }
        double slope = 0.0;
        for (int i = nf; i < n3; i++)
            slope -= r->force[i] * dx[i];
        double P0 = potential(r, r->x, ext), alpha = 1.0;
        int ok = 0;
        for (int ls = 0; ls < 40; ls++) {
            for (int i = 0; i < n3; i++)
                trial[i] = r->x[i] + alpha * dx[i];
            double P = potential(r, trial, ext);
            if (isfinite(P) && P <= P0 + 1e-4 * alpha * slope) {
                ok = 1;
                break;
            }
            alpha *= 0.5;
        }
        if (!ok) {
            /* No decrease: at the round-off floor of the potential. Accept if the residual is
             * already small relative to the load, else fail. */
            if (res <= 1e3 * tol * ref)
                result = it;
            break;
        }
        memcpy(r->x, trial, (size_t)n3 * sizeof(double));
    }
    if (stats)
        *stats = st;
    return result;
}

int ns_rod_is_stable(NsRod *r, const double *ext)
{
    forces_impl(r, ext, 0);
    build_system(r, 0.0, 1.0, 0.0);
    int n3 = 3 * r->nodes, nf = 3 * r->held;
    double *rhs = r->work + 13 * (size_t)r->cap, *dx = rhs + 3 * (size_t)r->cap;
    uint8_t *dof_fixed = (uint8_t *)(dx + 3 * (size_t)r->cap);
    memset(dof_fixed, 0, 3 * (size_t)r->cap);
    memset(dof_fixed, 1, (size_t)nf);
    for (int i = 0; i < 3 * r->cap; i++)
        rhs[i] = dx[i] = 0.0;
    for (int i = nf; i < n3; i++)
        rhs[i] = 1.0;
    int ok = ns_banded_solve(&r->A, dof_fixed, rhs, dx, NULL) == 0;
    forces_impl(r, ext, 1); /* leave K as ns_rod_forces documents it */
    return ok;
}

uint64_t ns_rod_state_hash(const NsRod *r)
{
    uint64_t h = 1469598103934665603ULL;
#define MIX(ptr, bytes)                                                                            \
    do {                                                                                           \
        const unsigned char *p_ = (const unsigned char *)(ptr);                                    \
        for (size_t k_ = 0; k_ < (size_t)(bytes); k_++) {                                          \
            h ^= p_[k_];                                                                           \
            h *= 1099511628211ULL;                                                                 \
        }                                                                                          \
    } while (0)
    MIX(&r->nodes, sizeof r->nodes);
    MIX(r->x, 3 * (size_t)r->nodes * sizeof(double));
    MIX(r->v, 3 * (size_t)r->nodes * sizeof(double));
    MIX(r->a, 3 * (size_t)r->nodes * sizeof(double));
    MIX(r->theta, (size_t)(r->nodes - 1) * sizeof(double));
    MIX(r->rest_len, (size_t)(r->nodes - 1) * sizeof(double));
#undef MIX
    return h;
}
