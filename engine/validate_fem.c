/* Validation cases for the tissue FEM (§3.1, §3.2, §3.6.3): each compares the simulator with an
 * answer known independently of it. docs/validation.md gives the sources and the reasoning
 * behind every number here. All quantities are SI. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mesh_grid.h"
#include "mesher.h"
#include "tissue.h"
#include "validate.h"

/* ---- helpers ------------------------------------------------------------------------------ */

#define DENSITY 1000.0 /* [kg/m^3] of every case's tissue: water, soft tissue */

static int fail(NsValidateResult *r, const char *why)
{
    ns_validate_detail(r, "%s%s", r->detail[0] ? "; " : "", why);
    r->pass = false;
    return -1;
}

static const char *model_name(NsElasticModel m)
{
    return m == NS_MODEL_NEOHOOKEAN ? "neo-Hookean" : "corotational";
}

/* A one-material tissue on mesh m. */
static int make_tissue(NsTissue *t, const NsMesh *m, NsElasticModel model, double youngs,
                       double poisson, double damp_mu, const NsTissueParams *p, NsValidateResult *r)
{
    NsTissueMaterial mat = {ns_fem_material(model, youngs, poisson, damp_mu, 0.0), 1000.0};
    char err[256];
    if (ns_tissue_init(t, m, &mat, 1, p, err, sizeof err)) {
        fail(r, err);
        return -1;
    }
    return 0;
}

static int make_grid(NsMesh *m, const double size[3], int nx, int ny, int nz, NsValidateResult *r)
{
    const double lo[3] = {0.0, 0.0, 0.0};
    char err[256];
    if (ns_mesh_grid_box(m, lo, size, nx, ny, nz, 0, err, sizeof err)) {
        fail(r, err);
        return -1;
    }
    return 0;
}

static bool on_plane(const NsMesh *m, int node, int axis, double value)
{
    return fabs(m->u[3 * node + axis] - value) <= 1e-9;
}

/* Area weights of the boundary faces lying in the plane u[axis] = value: w[i] gets a third of
 * the area of each such face at node i (the consistent load of a uniform traction on linear
 * triangles). Returns the plane's total area. */
static double plane_weights(const NsMesh *m, int axis, double value, double *w)
{
    memset(w, 0, (size_t)m->node_slots * sizeof *w);
    double total = 0.0;
    for (int e = 0; e < m->tet_slots; e++) {
        if (!ns_mesh_tet_alive(m, e))
            continue;
        for (int k = 0; k < 4; k++) {
            if (m->tet_adj[4 * e + k] >= 0)
                continue;
            int f[3];
            bool in = true;
            for (int q = 0; q < 3; q++) {
                f[q] = m->tet_node[4 * e + ns_tet_face[k][q]];
                in = in && on_plane(m, f[q], axis, value);
            }
            if (!in)
                continue;
            const double *a = m->u + 3 * f[0], *b = m->u + 3 * f[1], *c = m->u + 3 * f[2];
            double e1[3], e2[3];
            for (int q = 0; q < 3; q++) {
                e1[q] = b[q] - a[q];
                e2[q] = c[q] - a[q];
            }
            double n0 = e1[1] * e2[2] - e1[2] * e2[1], n1 = e1[2] * e2[0] - e1[0] * e2[2],
                   n2 = e1[0] * e2[1] - e1[1] * e2[0];
            double area = 0.5 * sqrt(n0 * n0 + n1 * n1 + n2 * n2);
            for (int q = 0; q < 3; q++)
                w[f[q]] += area / 3.0;
            total += area;
        }
    }
    return total;
}

/* Weighted mean displacement along axis c over the nodes with weights w (summing to wsum). */
static double mean_displacement(const NsMesh *m, const double *w, double wsum, int c)
{
    double d = 0.0;
    for (int i = 0; i < m->node_slots; i++)
        if (w[i] != 0.0)
            d += w[i] * (m->x[3 * i + c] - m->u[3 * i + c]);
    return d / wsum;
}

/* ---- fem-patch ---------------------------------------------------------------------------- */

/* A homogeneous deformation x = G u + t has constant F, hence constant stress and zero nodal
 * force at every interior node, for any hyperelastic model: imposing it on the boundary of an
 * irregular mesh, the static solve must reproduce it inside (the patch test). */
static int fem_patch(NsValidateResult *r)
{
    snprintf(r->metric, sizeof r->metric, "interior error / displacement");
    r->reference = 0.0;
    r->tolerance = 1e-8;
    double c[3] = {0.0, 0.0, 0.0};
    NsShape *s = ns_shape_sphere(c, 0.02);
    NsMesherRegion reg = {s, false};
    NsMesherDef d = ns_default_mesher_def();
    d.spacing = 0.005;
    d.regions = &reg;
    d.region_count = 1;
    NsMesh m;
    ns_mesh_init(&m);
    char err[256];
    int rc = ns_mesher_stuff(&d, &m, NULL, err, sizeof err);
    ns_shape_release(s);
    if (rc)
        return fail(r, err);
    NsBoundaryStats b;
    ns_mesh_boundary(&m, &b);
    /* 10% stretches and shears: large enough that the corotational and neo-Hookean forces are
     * well inside their nonlinear range. */
    const double G[9] = {1.08, 0.05, -0.04, 0.03, 0.93, 0.06, -0.05, 0.02, 1.10};
    const double tr[3] = {0.002, -0.003, 0.001};
    double worst = 0.0;
    int interior = 0;
    for (int model = 0; model < 2; model++) {
        NsTissue t;
        if (make_tissue(&t, &m, (NsElasticModel)model, 50e3, 0.45, 0.0, NULL, r)) {
            ns_mesh_free(&m);
            return -1;
        }
        double dmax = 0.0;
        for (int i = 0; i < m.node_slots; i++) {
            const double *u = m.u + 3 * i;
            for (int k = 0; k < 3; k++) {
                double xk = G[3 * k] * u[0] + G[3 * k + 1] * u[1] + G[3 * k + 2] * u[2] + tr[k];
                dmax = fmax(dmax, fabs(xk - u[k]));
                if (m.flags[i] & NS_NODE_BOUNDARY) {
                    t.mesh.x[3 * i + k] = xk;
                    ns_tissue_fix_dof(&t, i, k, 1);
                }
            }
        }
        NsSolver *solver = ns_solver_create(NS_SOLVER_DIRECT);
        NsTissueStats st;
        int it = ns_tissue_static_solve(&t, solver, NULL, 1e-11, 100, &st);
        ns_solver_destroy(solver);
        double emax = 0.0;
        interior = 0;
        for (int i = 0; i < m.node_slots; i++) {
            if (m.flags[i] & NS_NODE_BOUNDARY)
                continue;
            interior++;
            const double *u = m.u + 3 * i;
            for (int k = 0; k < 3; k++) {
                double xk = G[3 * k] * u[0] + G[3 * k + 1] * u[1] + G[3 * k + 2] * u[2] + tr[k];
                emax = fmax(emax, fabs(t.mesh.x[3 * i + k] - xk));
            }
        }
        ns_tissue_free(&t);
        double rel = emax / dmax;
        ns_validate_detail(r, "%s%s: %.2e (%d Newton iterations%s)", model ? "; " : "",
                           model_name((NsElasticModel)model), rel, it,
                           it < 0 || st.unconverged ? ", NOT converged" : "");
        if (it < 0 || st.unconverged)
            rel = INFINITY;
        worst = fmax(worst, rel);
    }
    ns_validate_detail(r, "; %d tets, %d interior nodes", m.tet_alive, interior);
    ns_mesh_free(&m);
    r->value = worst;
    r->error = worst;
    r->pass = worst <= r->tolerance && interior >= 100; /* else there is little to test */
    return 0;
}

/* ---- fem-compression ---------------------------------------------------------------------- */

/* A bar between two frictionless (sliding) ends, shortened by a small strain eps: the stress is
 * uniaxial and uniform, so the reaction is E A eps. The faces x = 0, y = 0, z = 0 are symmetry
 * planes (each holds only its normal DOF); x = L is moved and held in x only. */
static int fem_compression(NsValidateResult *r)
{
    const double L = 0.1, a = 0.02, E = 100e3, nu = 0.45, eps = 1e-4;
    snprintf(r->metric, sizeof r->metric, "reaction force [N]");
    r->reference = E * a * a * eps;
    r->tolerance = 0.01;
    NsMesh m;
    const double size[3] = {L, a, a};
    if (make_grid(&m, size, 10, 3, 3, r))
        return -1;
    double worst = 0.0, value = 0.0;
    bool lateral_ok = true;
    for (int model = 0; model < 2; model++) {
        NsTissue t;
        if (make_tissue(&t, &m, (NsElasticModel)model, E, nu, 0.0, NULL, r)) {
            ns_mesh_free(&m);
            return -1;
        }
        for (int i = 0; i < m.node_slots; i++) {
            for (int c = 0; c < 3; c++)
                if (on_plane(&m, i, c, 0.0))
                    ns_tissue_fix_dof(&t, i, c, 1);
            if (on_plane(&m, i, 0, L)) {
                t.mesh.x[3 * i] = L * (1.0 - eps);
                ns_tissue_fix_dof(&t, i, 0, 1);
            }
        }
        NsSolver *solver = ns_solver_create(NS_SOLVER_DIRECT);
        NsTissueStats st;
        int it = ns_tissue_static_solve(&t, solver, NULL, 1e-8, 30, &st);
        ns_solver_destroy(solver);
        /* The elastic force on the moved face pushes it back out; the support holds it. */
        double reaction = 0.0, lateral = 0.0;
        int corner = -1;
        for (int i = 0; i < m.node_slots; i++) {
            if (on_plane(&m, i, 0, L))
                reaction += t.force[3 * i];
            if (on_plane(&m, i, 0, L) && on_plane(&m, i, 1, a) && on_plane(&m, i, 2, a))
                corner = i;
        }
        if (corner >= 0)
            lateral = (t.mesh.x[3 * corner + 1] - a) / a; /* lateral strain, nu eps expected */
        ns_tissue_free(&t);
        double rel = fabs(reaction - r->reference) / r->reference;
        ns_validate_detail(r, "%s%s: %.6g N (error %.2e), lateral strain %.4g (nu eps = %.4g)%s",
                           model ? "; " : "", model_name((NsElasticModel)model), reaction, rel,
                           lateral, nu * eps, it < 0 || st.unconverged ? ", NOT converged" : "");
        if (it < 0 || st.unconverged)
            rel = INFINITY;
        /* Side condition: the free lateral faces expand by nu eps (uniaxial stress). */
        if (!(fabs(lateral - nu * eps) <= 0.01 * nu * eps)) {
            ns_validate_detail(r, " (lateral strain off by more than 1%%)");
            lateral_ok = false;
        }
        if (rel >= worst) {
            worst = rel;
            value = reaction;
        }
    }
    ns_mesh_free(&m);
    r->value = value;
    r->error = worst;
    r->pass = lateral_ok && worst <= r->tolerance;
    return 0;
}

/* ---- beams: fem-cantilever and fem-vibration ---------------------------------------------- */

/* The beam of both beam cases: L x b x h with L / h = 10, clamped (all DOFs) at x = 0, E and nu
 * of a stiff gel. Linear elasticity in the small-deflection limit. */
#define BEAM_L   0.1
#define BEAM_B   0.01
#define BEAM_H   0.01
#define BEAM_E   100e3
#define BEAM_NU  0.3
#define BEAM_RHO DENSITY /* the masses are lumped from it in ns_tissue_init */

/* Timoshenko's tip deflection of a cantilever under a tip load P: bending P L^3 / (3 E I) plus
 * shear P L / (kappa G A), with Cowper's shear coefficient for a rectangle
 * kappa = 10 (1 + nu) / (12 + 11 nu). */
static double timoshenko_tip_deflection(double P)
{
    double I = BEAM_B * BEAM_H * BEAM_H * BEAM_H / 12.0, A = BEAM_B * BEAM_H;
    double G = BEAM_E / (2.0 * (1.0 + BEAM_NU));
    double kappa = 10.0 * (1.0 + BEAM_NU) / (12.0 + 11.0 * BEAM_NU);
    return P * BEAM_L * BEAM_L * BEAM_L / (3.0 * BEAM_E * I) + P * BEAM_L / (kappa * G * A);
}

/* The beam meshed (sim/mesh_grid.c) with n cells through the depth, ceil(n / 3) across the
 * width and 10 n along (cubic cells in the bending plane); loaded by a
 * uniform downward (-z) traction of total P on the tip face and solved statically. On success
 * t holds the deflected beam, w the tip-face weights (node_slots), *wsum their sum. */
static int beam_static(NsTissue *t, int n, double P, double **w, double *wsum,
                       const NsTissueParams *params, NsValidateResult *r)
{
    NsMesh m;
    const double size[3] = {BEAM_L, BEAM_B, BEAM_H};
    if (make_grid(&m, size, 10 * n, (n + 2) / 3, n, r))
        return -1;
    int rc = make_tissue(t, &m, NS_MODEL_COROTATIONAL, BEAM_E, BEAM_NU, 0.0, params, r);
    double *weights = calloc((size_t)m.node_slots, sizeof *weights);
    double *ext = calloc((size_t)3 * m.node_slots, sizeof *ext);
    if (rc || !weights || !ext) {
        free(weights);
        free(ext);
        ns_mesh_free(&m);
        if (rc == 0)
            ns_tissue_free(t);
        return rc ? -1 : fail(r, "out of memory");
    }
    *wsum = plane_weights(&m, 0, BEAM_L, weights);
    for (int i = 0; i < m.node_slots; i++) {
        ext[3 * i + 2] = -P * weights[i] / *wsum;
        if (on_plane(&m, i, 0, 0.0))
            for (int c = 0; c < 3; c++)
                ns_tissue_fix_dof(t, i, c, 1);
    }
    ns_mesh_free(&m);
    NsSolver *solver = ns_solver_create(NS_SOLVER_DIRECT);
    NsTissueStats st;
    int it = ns_tissue_static_solve(t, solver, ext, 1e-8, 30, &st);
    ns_solver_destroy(solver);
    free(ext);
    if (it < 0 || st.unconverged) {
        free(weights);
        ns_tissue_free(t);
        return fail(r, "static solve did not converge");
    }
    *w = weights;
    return 0;
}

/* The tip deflection converges to Timoshenko's from above in stiffness (linear tets are too
 * stiff in bending), so the error must fall with every refinement. */
static int fem_cantilever(NsValidateResult *r)
{
    /* A load giving a deflection of 1e-4 L: well inside the small-deflection range. */
    const double P = 1e-4 * BEAM_L * 3.0 * BEAM_E * (BEAM_B * BEAM_H * BEAM_H * BEAM_H / 12.0) /
                     (BEAM_L * BEAM_L * BEAM_L);
    const int res[] = {4, 8, 12};
    const int nres = (int)(sizeof res / sizeof res[0]);
    snprintf(r->metric, sizeof r->metric, "tip deflection [m] (n = %d)", res[nres - 1]);
    r->reference = timoshenko_tip_deflection(P);
    r->tolerance = 0.05;
    double prev = INFINITY;
    bool decreasing = true;
    ns_validate_detail(r, "L/h = %.0f; error by elements through the depth:", BEAM_L / BEAM_H);
    for (int k = 0; k < nres; k++) {
        NsTissue t;
        double *w, wsum;
        if (beam_static(&t, res[k], P, &w, &wsum, NULL, r))
            return -1;
        double tip = -mean_displacement(&t.mesh, w, wsum, 2);
        int tets = t.mesh.tet_alive;
        ns_tissue_free(&t);
        free(w);
        double rel = fabs(tip - r->reference) / r->reference;
        ns_validate_detail(r, " n=%d (%d tets) %.2f%%", res[k], tets, 100.0 * rel);
        decreasing = decreasing && rel < prev;
        prev = rel;
        r->value = tip;
        r->error = rel;
    }
    if (!decreasing)
        ns_validate_detail(r, "; the error did NOT decrease with every refinement");
    r->pass = decreasing && r->error <= r->tolerance;
    return 0;
}

/* First bending frequency of the clamped-free beam by Timoshenko's theory (shear deformation
 * and rotary inertia), which has no closed form: a converged 1D finite-element solution with
 * exact-stiffness Timoshenko elements (Friedman & Kosmatka 1993) and consistent mass with
 * rotary inertia, by inverse iteration on K x = omega^2 M x. With 100 elements it agrees with
 * 400 to 1e-7. Euler-Bernoulli's value, (1.87510^2 / (2 pi L^2)) sqrt(E I / (rho A)), is
 * printed beside it: it is ~1% higher at L/h = 10. */
#define TB_ELEMENTS 100
#define TB_DOF      (2 * TB_ELEMENTS)

static double timoshenko_f1(void)
{
    double I = BEAM_B * BEAM_H * BEAM_H * BEAM_H / 12.0, A = BEAM_B * BEAM_H;
    double G = BEAM_E / (2.0 * (1.0 + BEAM_NU));
    double kappa = 10.0 * (1.0 + BEAM_NU) / (12.0 + 11.0 * BEAM_NU);
    double le = BEAM_L / TB_ELEMENTS, phi = 12.0 * BEAM_E * I / (kappa * G * A * le * le);
    double ks = BEAM_E * I / ((1.0 + phi) * le * le * le);
    double mt = BEAM_RHO * A * le / 420.0, mr = BEAM_RHO * I / (30.0 * le);
    const double ke[4][4] = {{12.0, 6.0 * le, -12.0, 6.0 * le},
                             {6.0 * le, (4.0 + phi) * le * le, -6.0 * le, (2.0 - phi) * le * le},
                             {-12.0, -6.0 * le, 12.0, -6.0 * le},
                             {6.0 * le, (2.0 - phi) * le * le, -6.0 * le, (4.0 + phi) * le * le}};
    const double me[4][4] = {{156.0, 22.0 * le, 54.0, -13.0 * le},
                             {22.0 * le, 4.0 * le * le, 13.0 * le, -3.0 * le * le},
                             {54.0, 13.0 * le, 156.0, -22.0 * le},
                             {-13.0 * le, -3.0 * le * le, -22.0 * le, 4.0 * le * le}};
    const double re[4][4] = {{36.0, 3.0 * le, -36.0, 3.0 * le},
                             {3.0 * le, 4.0 * le * le, -3.0 * le, -le * le},
                             {-36.0, -3.0 * le, 36.0, -3.0 * le},
                             {3.0 * le, -le * le, -3.0 * le, 4.0 * le * le}};
    double *K = calloc((size_t)TB_DOF * TB_DOF, sizeof *K);
    double *M = calloc((size_t)TB_DOF * TB_DOF, sizeof *M);
    double *x = malloc(2 * TB_DOF * sizeof *x);
    if (!K || !M || !x) {
        free(K);
        free(M);
        free(x);
        return NAN;
    }
    double *y = x + TB_DOF;
    /* DOFs (w, theta) of nodes 1..N; node 0 is clamped. */
    for (int e = 0; e < TB_ELEMENTS; e++)
        for (int a = 0; a < 4; a++)
            for (int b = 0; b < 4; b++) {
                int i = 2 * e + a - 2, j = 2 * e + b - 2;
                if (i < 0 || j < 0)
                    continue;
                K[i * TB_DOF + j] += ks * ke[a][b];
                M[i * TB_DOF + j] += mt * me[a][b] + mr * re[a][b];
            }
    /* Cholesky of K in place (lower triangle). */
    for (int j = 0; j < TB_DOF; j++) {
        double d = K[j * TB_DOF + j];
        for (int k = 0; k < j; k++)
            d -= K[j * TB_DOF + k] * K[j * TB_DOF + k];
        d = sqrt(d);
        K[j * TB_DOF + j] = d;
        for (int i = j + 1; i < TB_DOF; i++) {
            double v = K[i * TB_DOF + j];
            for (int k = 0; k < j; k++)
                v -= K[i * TB_DOF + k] * K[j * TB_DOF + k];
            K[i * TB_DOF + j] = v / d;
        }
    }
    for (int i = 0; i < TB_DOF; i++)
        x[i] = (i % 2 == 0) ? (double)(i + 2) : 0.0; /* deflection growing along the beam */
    double lambda = 0.0;
    for (int it = 0; it < 60; it++) {
        for (int i = 0; i < TB_DOF; i++) { /* y = M x */
            double v = 0.0;
            for (int j = 0; j < TB_DOF; j++)
                v += M[i * TB_DOF + j] * x[j];
            y[i] = v;
        }
        double xmx = 0.0;
        for (int i = 0; i < TB_DOF; i++)
            xmx += x[i] * y[i];
        for (int i = 0; i < TB_DOF; i++) { /* solve L L^T x' = y */
            double v = y[i];
            for (int k = 0; k < i; k++)
                v -= K[i * TB_DOF + k] * y[k];
            y[i] = v / K[i * TB_DOF + i];
        }
        for (int i = TB_DOF - 1; i >= 0; i--) {
            double v = y[i];
            for (int k = i + 1; k < TB_DOF; k++)
                v -= K[k * TB_DOF + i] * y[k];
            y[i] = v / K[i * TB_DOF + i];
        }
        /* Rayleigh quotient estimate: x^T M x / x^T M x' with x' = K^-1 M x. */
        double xmy = 0.0, norm = 0.0;
        for (int i = 0; i < TB_DOF; i++) {
            double v = 0.0;
            for (int j = 0; j < TB_DOF; j++)
                v += M[i * TB_DOF + j] * y[j];
            xmy += x[i] * v;
            norm = fmax(norm, fabs(y[i]));
        }
        lambda = xmx / xmy;
        for (int i = 0; i < TB_DOF; i++)
            x[i] = y[i] / norm;
    }
    free(K);
    free(M);
    free(x);
    return sqrt(lambda) / (2.0 * M_PI);
}

static double euler_bernoulli_f1(void)
{
    double I = BEAM_B * BEAM_H * BEAM_H * BEAM_H / 12.0, A = BEAM_B * BEAM_H;
    double bl = 1.8751040687;
    return bl * bl / (2.0 * M_PI * BEAM_L * BEAM_L) * sqrt(BEAM_E * I / (BEAM_RHO * A));
}

/* Released from its static deflection under a tip load, the undamped beam swings in (mostly)
 * its first mode. The period comes from the tip's zero crossings; the trapezoidal rule
 * (beta = 1/4, gamma = 1/2) conserves the energy of a linear system, so its drift is small. */
static int fem_vibration(NsValidateResult *r)
{
    const int n = 8, steps = 1000, per_period = 40;
    const double f_ref = timoshenko_f1();
    snprintf(r->metric, sizeof r->metric, "first-mode frequency [Hz]");
    r->reference = f_ref;
    r->tolerance = 0.05;
    const double P = 1e-4 * BEAM_L * 3.0 * BEAM_E * (BEAM_B * BEAM_H * BEAM_H * BEAM_H / 12.0) /
                     (BEAM_L * BEAM_L * BEAM_L);
    NsTissue t;
    double *w, wsum;
    if (beam_static(&t, n, P, &w, &wsum, NULL, r))
        return -1;
    NsMesh *M = &t.mesh;
    memset(M->v, 0, (size_t)3 * M->node_slots * sizeof(double));
    memset(M->a, 0, (size_t)3 * M->node_slots * sizeof(double));
    const double dt = 1.0 / (f_ref * per_period);
    NsSolver *solver = ns_solver_create(NS_SOLVER_STALE_PCG);
    double e0 = ns_tissue_energy(&t), drift = 0.0;
    double prev = -mean_displacement(M, w, wsum, 2), first_cross = -1.0, last_cross = -1.0;
    int crossings = 0, failed = 0, nan = 0, unconverged = 0;
    for (int s = 1; s <= steps; s++) {
        NsTissueStats st;
        if (ns_tissue_step(&t, solver, dt, NULL, &st)) {
            failed = 1;
            break;
        }
        nan += st.nan_count;
        unconverged += st.unconverged;
        drift = fmax(drift, fabs(ns_tissue_energy(&t) - e0) / e0);
        double d = -mean_displacement(M, w, wsum, 2);
        if ((prev > 0.0) != (d > 0.0)) { /* interpolate the crossing time */
            double tc = (s - 1 + prev / (prev - d)) * dt;
            if (crossings == 0)
                first_cross = tc;
            last_cross = tc;
            crossings++;
        }
        prev = d;
    }
    int tets = M->tet_alive;
    ns_solver_destroy(solver);
    ns_tissue_free(&t);
    free(w);
    if (failed)
        return fail(r, "a step failed");
    if (crossings < 3)
        return fail(r, "the beam did not oscillate");
    /* Crossings come every half period. */
    double f = 0.5 * (crossings - 1) / (last_cross - first_cross);
    r->value = f;
    r->error = fabs(f - f_ref) / f_ref;
    const double drift_tol = 0.01;
    ns_validate_detail(r,
                       "Timoshenko f1 %.5g Hz (Euler-Bernoulli %.5g Hz); n=%d (%d tets), %d steps "
                       "of T/%d, %d half periods; energy drift %.2e (tolerance %.0e); NaN %d, "
                       "unconverged %d",
                       f_ref, euler_bernoulli_f1(), n, tets, steps, per_period, crossings - 1,
                       drift, drift_tol, nan, unconverged);
    r->pass = r->error <= r->tolerance && drift < drift_tol && nan == 0 && unconverged == 0;
    return 0;
}

/* ---- fem-inversion ------------------------------------------------------------------------ */

/* A cube held at its base is crushed by a plate moving through the base plane, which inverts
 * elements; the plate is then removed. With the inversion-safe forces (§3.2, Irving 2004) it
 * must come back to its rest shape, with no NaN on the way. Both elastic models. */
static int fem_inversion(NsValidateResult *r)
{
    const double H = 0.02, E = 10e3, nu = 0.4, damp = 15.0, dt = 1e-3;
    const int crush_steps = 100, release_steps = 900;
    snprintf(r->metric, sizeof r->metric, "max node error / size");
    r->reference = 0.0;
    r->tolerance = 0.01;
    NsMesh m;
    const double size[3] = {H, H, H};
    if (make_grid(&m, size, 4, 4, 4, r))
        return -1;
    double worst = 0.0;
    bool ok = true;
    for (int model = 0; model < 2; model++) {
        NsTissue t;
        if (make_tissue(&t, &m, (NsElasticModel)model, E, nu, damp, NULL, r)) {
            ns_mesh_free(&m);
            return -1;
        }
        NsMesh *M = &t.mesh;
        /* The plate travels from z = H to z = -0.5 H. */
        const double speed = 1.5 * H / (crush_steps * dt);
        for (int i = 0; i < M->node_slots; i++)
            for (int c = 0; c < 3; c++)
                if (on_plane(M, i, 2, 0.0) || on_plane(M, i, 2, H))
                    ns_tissue_fix_dof(&t, i, c, 1);
        NsSolver *solver = ns_solver_create(NS_SOLVER_DIRECT);
        int max_inverted = 0, nan = 0, failed = 0;
        for (int s = 0; s < crush_steps + release_steps && !failed; s++) {
            if (s == 0 || s == crush_steps)
                for (int i = 0; i < M->node_slots; i++)
                    if (on_plane(M, i, 2, H)) {
                        M->v[3 * i + 2] = s == 0 ? -speed : 0.0;
                        M->a[3 * i + 2] = 0.0;
                        for (int c = 0; c < 3; c++)
                            ns_tissue_fix_dof(&t, i, c, s == 0);
                    }
            NsTissueStats st;
            failed = ns_tissue_step(&t, solver, dt, NULL, &st) != 0;
            nan += st.nan_count;
            max_inverted = st.inverted > max_inverted ? st.inverted : max_inverted;
        }
        double emax = 0.0;
        for (int i = 0; i < 3 * M->node_slots; i++)
            emax = fmax(emax, fabs(M->x[i] - M->u[i]));
        ns_solver_destroy(solver);
        ns_tissue_free(&t);
        double rel = emax / H;
        ns_validate_detail(r, "%s%s: %.2e, up to %d of %d tets inverted, NaN %d%s",
                           model ? "; " : "", model_name((NsElasticModel)model), rel, max_inverted,
                           m.tet_alive, nan, failed ? ", a step FAILED" : "");
        if (failed || nan > 0 || !isfinite(rel))
            rel = INFINITY;
        if (max_inverted == 0) {
            ns_validate_detail(r, " (no tet inverted: the case tests nothing)");
            ok = false;
        }
        worst = fmax(worst, rel);
    }
    ns_mesh_free(&m);
    r->value = worst;
    r->error = worst;
    r->pass = ok && worst <= r->tolerance;
    return 0;
}

/* ---- fem-lazy ----------------------------------------------------------------------------- */

/* A needle-like load (a tip force spread over the nodes around a point moving down through a
 * block) for 200 steps, with the default lazy threshold and with threshold 0 (every Jacobian
 * rebuilt every step): the probe trajectories must agree, with few Jacobians rebuilt (§3.6.3,
 * paper Table 1). */
typedef struct LazyRun {
    double *probe;   /* (steps x 3) probe position */
    double fraction; /* mean fraction of Jacobians rebuilt per step, after the first */
    double fraction_max;
    int nan, unconverged, failed;
} LazyRun;

#define LAZY_STEPS 200

static int lazy_run(const NsMesh *m, double threshold, int probe, LazyRun *out, NsValidateResult *r)
{
    const double size = 0.06, speed = 0.1, dt = 1e-3, force = 1.0, radius = 0.006;
    NsTissueParams p = ns_default_tissue_params();
    p.lazy_threshold = threshold;
    NsTissue t;
    if (make_tissue(&t, m, NS_MODEL_COROTATIONAL, 30e3, 0.45, 1.0, &p, r))
        return -1;
    NsMesh *M = &t.mesh;
    for (int i = 0; i < M->node_slots; i++)
        if (on_plane(M, i, 2, 0.0))
            for (int c = 0; c < 3; c++)
                ns_tissue_fix_dof(&t, i, c, 1);
    double *ext = calloc((size_t)3 * M->node_slots, sizeof *ext);
    double *wt = calloc((size_t)M->node_slots, sizeof *wt);
    out->probe = calloc((size_t)3 * LAZY_STEPS, sizeof(double));
    if (!ext || !wt || !out->probe) {
        free(ext);
        free(wt);
        ns_tissue_free(&t);
        return fail(r, "out of memory");
    }
    NsSolver *solver = ns_solver_create(NS_SOLVER_STALE_PCG);
    double fsum = 0.0;
    for (int s = 0; s < LAZY_STEPS; s++) {
        /* The tip point, entering at the top centre and moving down; its force pushes down and
         * a little sideways (a bevelled tip), spread with a smooth radial weight. */
        const double tip[3] = {0.5 * size, 0.5 * size, size - speed * s * dt};
        double wsum = 0.0;
        for (int i = 0; i < M->node_slots; i++) {
            double d2 = 0.0;
            for (int c = 0; c < 3; c++)
                d2 += (M->x[3 * i + c] - tip[c]) * (M->x[3 * i + c] - tip[c]);
            double q = 1.0 - d2 / (radius * radius);
            wt[i] = q > 0.0 ? q * q : 0.0;
            wsum += wt[i];
        }
        for (int i = 0; i < M->node_slots; i++) {
            double w = wsum > 0.0 ? wt[i] / wsum : 0.0;
            ext[3 * i] = 0.3 * force * w;
            ext[3 * i + 1] = 0.0;
            ext[3 * i + 2] = -force * w;
        }
        NsTissueStats st;
        if (ns_tissue_step(&t, solver, dt, ext, &st)) {
            out->failed = 1;
            break;
        }
        out->nan += st.nan_count;
        out->unconverged += st.unconverged;
        if (s > 0) {
            fsum += st.jacobian_fraction;
            out->fraction_max = fmax(out->fraction_max, st.jacobian_fraction);
        }
        memcpy(out->probe + 3 * s, M->x + 3 * probe, 3 * sizeof(double));
    }
    out->fraction = fsum / (LAZY_STEPS - 1);
    ns_solver_destroy(solver);
    ns_tissue_free(&t);
    free(ext);
    free(wt);
    return 0;
}

static int fem_lazy(NsValidateResult *r)
{
    const double size = 0.06;
    NsTissueParams defaults = ns_default_tissue_params();
    snprintf(r->metric, sizeof r->metric, "probe trajectory error");
    r->reference = 0.0;
    r->tolerance = 0.005;
    NsMesh m;
    const double box[3] = {size, size, size};
    if (make_grid(&m, box, 12, 12, 12, r))
        return -1;
    /* The probe: the node nearest a point 6 mm beside the path at mid-depth. */
    const double pp[3] = {0.5 * size + 0.006, 0.5 * size, 0.5 * size};
    int probe = -1;
    double best = INFINITY;
    for (int i = 0; i < m.node_slots; i++) {
        double d2 = 0.0;
        for (int c = 0; c < 3; c++)
            d2 += (m.u[3 * i + c] - pp[c]) * (m.u[3 * i + c] - pp[c]);
        if (d2 < best) {
            best = d2;
            probe = i;
        }
    }
    LazyRun lazy = {0}, full = {0};
    int rc = lazy_run(&m, defaults.lazy_threshold, probe, &lazy, r);
    if (rc == 0)
        rc = lazy_run(&m, 0.0, probe, &full, r);
    double emax = 0.0, dmax = 0.0;
    if (rc == 0)
        for (int s = 0; s < LAZY_STEPS; s++) {
            double e2 = 0.0, d2 = 0.0;
            for (int c = 0; c < 3; c++) {
                double ref = full.probe[3 * s + c];
                e2 += (lazy.probe[3 * s + c] - ref) * (lazy.probe[3 * s + c] - ref);
                d2 += (ref - m.u[3 * probe + c]) * (ref - m.u[3 * probe + c]);
            }
            emax = fmax(emax, sqrt(e2));
            dmax = fmax(dmax, sqrt(d2));
        }
    free(lazy.probe);
    free(full.probe);
    int tets = m.tet_alive;
    ns_mesh_free(&m);
    if (rc)
        return -1;
    const double fraction_tol = 0.10;
    r->value = dmax > 0.0 ? emax / dmax : INFINITY;
    r->error = r->value;
    ns_validate_detail(r,
                       "%d tets, %d steps, e_thres %.0e: Jacobians rebuilt per step %.2f%% mean, "
                       "%.2f%% max (tolerance %.0f%%; threshold 0: %.0f%%); probe moved %.3g mm, "
                       "max deviation %.3g mm; NaN %d, unconverged %d",
                       tets, LAZY_STEPS, defaults.lazy_threshold, 100.0 * lazy.fraction,
                       100.0 * lazy.fraction_max, 100.0 * fraction_tol, 100.0 * full.fraction,
                       1e3 * dmax, 1e3 * emax, lazy.nan + full.nan,
                       lazy.unconverged + full.unconverged);
    r->pass = !lazy.failed && !full.failed && lazy.nan + full.nan == 0 &&
              lazy.unconverged + full.unconverged == 0 && lazy.fraction <= fraction_tol &&
              full.fraction >= 0.999 && r->error <= r->tolerance;
    return 0;
}

const NsValidateCase ns_validate_fem_cases[] = {
    {"fem-patch", "homogeneous deformation on an irregular mesh is reproduced inside", fem_patch},
    {"fem-compression", "bar with sliding ends: reaction = E A eps", fem_compression},
    {"fem-cantilever", "tip-loaded cantilever converges to Timoshenko's deflection",
     fem_cantilever},
    {"fem-vibration", "first bending frequency; trapezoidal-rule energy conservation",
     fem_vibration},
    {"fem-inversion", "crushed through itself and released: back to rest, no NaN", fem_inversion},
    {"fem-lazy", "lazy Jacobians: few rebuilt, probe trajectory unchanged", fem_lazy},
};
const int ns_validate_fem_case_count =
    (int)(sizeof ns_validate_fem_cases / sizeof ns_validate_fem_cases[0]);
