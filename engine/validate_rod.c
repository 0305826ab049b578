/* Validation cases for the needle rod (sim/rod.c, sim/reparam.c; docs/validation.md):
 * small- and large-deflection cantilevers against beam theory and the elastica, Euler buckling,
 * twist propagation from the base, an end torque against T L / GJ, length preservation, and
 * reparameterization. Every case but rod-torsion (the flexible nitinol needle) uses the default
 * needle: stainless steel, 18 gauge (1.27 mm outer, 0.84 mm inner diameter). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "rod.h"
#include "validate.h"

#define ROD_L 0.1 /* length beyond the sleeve [m] */

static int fail(NsValidateResult *r, const char *why)
{
    ns_validate_detail(r, "%s", why);
    r->pass = false;
    return -1;
}

/* A needle held by the sleeve at nodes 0 and 1 (node 1 at the origin, the sleeve along +z),
 * with `edges` edges of equal length beyond it, straight along +z, or bent towards +x on an arc
 * of radius R when R > 0. d1 is +x. */
static int make_needle(NsRod *rod, int edges, double R, const NsRodParams *p, NsValidateResult *r)
{
    int n = edges + 2;
    double h = ROD_L / edges;
    double *x = calloc(3 * (size_t)n, sizeof *x);
    if (!x)
        return fail(r, "out of memory");
    x[2] = -h;
    for (int i = 1; i < n; i++) {
        double s = h * (i - 1);
        if (R > 0.0) {
            x[3 * i] = R * (1.0 - cos(s / R));
            x[3 * i + 2] = R * sin(s / R);
        } else {
            x[3 * i + 2] = s;
        }
    }
    double d1[3] = {1.0, 0.0, 0.0};
    char err[256];
    NsRodParams q = p ? *p : ns_default_rod_params();
    int rc = ns_rod_init(rod, x, n, d1, 2, &q, err, sizeof err);
    free(x);
    if (rc != 0)
        return fail(r, err);
    return 0;
}

static NsRodParams static_params(void)
{
    NsRodParams p = ns_default_rod_params();
    p.auto_reparam = 0;
    return p;
}

/* E I of the validation needle [N m^2] (all cases use the default material). */
static double needle_bend_stiff(void)
{
    NsRodParams p = ns_default_rod_params();
    const NsRodMaterial *m = &p.material;
    double ro = 0.5 * m->outer_diameter, ri = 0.5 * m->inner_diameter;
    return m->youngs * 0.25 * M_PI * (ro * ro * ro * ro - ri * ri * ri * ri);
}

/* Builds a needle (make_needle), turns its base by theta0, puts the tip load (3) on its last
 * node and solves it statically to tol. On success (0) rod holds the result, for the caller to
 * read and free, and *iters the Newton steps; on failure (-1) nothing is left to free. */
static int loaded_needle(NsRod *rod, int edges, double R, double theta0, const double *load,
                         double tol, int max_iter, int *iters, NsValidateResult *r)
{
    NsRodParams p = static_params();
    if (make_needle(rod, edges, R, &p, r) != 0)
        return -1;
    int n = rod->nodes;
    double *ext = calloc(3 * (size_t)n, sizeof *ext);
    if (!ext) {
        ns_rod_free(rod);
        return fail(r, "out of memory");
    }
    memcpy(ext + 3 * (n - 1), load, 3 * sizeof *ext);
    rod->theta[0] = theta0;
    int it = ns_rod_static_solve(rod, ext, tol, max_iter, NULL);
    free(ext);
    if (it < 0) {
        ns_rod_free(rod);
        return fail(r, "static solve did not converge");
    }
    if (iters)
        *iters = it;
    return 0;
}

/* Elastica of a cantilever under a dead tip load perpendicular to its unloaded axis: with the
 * tangent angle th(s) from the axis, EI th'' = -P cos th, th(0) = 0, th'(L) = 0. Shooting on
 * th'(0) by bisection with classical RK4 (40,000 steps); returns the tip's transverse
 * deflection and axial shortening over L for alpha = P L^2 / EI. Tabulated by Bisshopp &
 * Drucker (1945), "Large deflection of cantilever beams", Q. Appl. Math. 3(3):272-275: at
 * alpha = 2 deflection 0.4935 L and shortening 0.1606 L, which this reproduces. */
static void elastica_shot(double alpha, double k0, int steps, double *w_end, double *defl,
                          double *shorten)
{
    double h = 1.0 / steps, th = 0.0, w = k0, z = 0.0, x = 0.0;
    for (int i = 0; i < steps; i++) {
        double t1 = th, w1 = w;
        double t2 = th + 0.5 * h * w1, w2 = w - 0.5 * h * alpha * cos(t1);
        double t3 = th + 0.5 * h * w2, w3 = w - 0.5 * h * alpha * cos(t2);
        double t4 = th + h * w3, w4 = w - h * alpha * cos(t3);
        z += h / 6.0 * (cos(t1) + 2.0 * cos(t2) + 2.0 * cos(t3) + cos(t4));
        x += h / 6.0 * (sin(t1) + 2.0 * sin(t2) + 2.0 * sin(t3) + sin(t4));
        th += h / 6.0 * (w1 + 2.0 * w2 + 2.0 * w3 + w4);
        w += -h / 6.0 * alpha * (cos(t1) + 2.0 * cos(t2) + 2.0 * cos(t3) + cos(t4));
    }
    *w_end = w;
    *defl = x;
    *shorten = 1.0 - z;
}

static void elastica(double alpha, double *defl, double *shorten)
{
    double lo = 0.0, hi = alpha, w;
    for (int it = 0; it < 60; it++) {
        double mid = 0.5 * (lo + hi);
        elastica_shot(alpha, mid, 40000, &w, defl, shorten);
        if (w < 0.0)
            lo = mid;
        else
            hi = mid;
    }
    elastica_shot(alpha, 0.5 * (lo + hi), 40000, &w, defl, shorten);
}

/* Static tip-loaded cantilever: returns the tip displacement (x, z) relative to the unloaded tip.
 */
static int cantilever(int edges, double P, double *dx, double *dz, int *iters, NsValidateResult *r)
{
    NsRod rod;
    double load[3] = {P, 0.0, 0.0};
    if (loaded_needle(&rod, edges, 0.0, 0.0, load, 1e-7, 500, iters, r) != 0)
        return -1;
    int n = rod.nodes;
    *dx = rod.x[3 * (n - 1)];
    *dz = rod.x[3 * (n - 1) + 2] - ROD_L;
    ns_rod_free(&rod);
    return 0;
}

static int rod_cantilever(NsValidateResult *r)
{
    snprintf(r->metric, sizeof r->metric, "tip deflection / (P L^3 / 3EI) - 1");
    double EI = needle_bend_stiff();
    /* Small load: deflection 1e-4 L. */
    double Psmall = 1e-4 * ROD_L * 3.0 * EI / (ROD_L * ROD_L * ROD_L);
    double ref = Psmall * ROD_L * ROD_L * ROD_L / (3.0 * EI);
    double dx, dz;
    int it;
    if (cantilever(20, Psmall, &dx, &dz, &it, r) != 0)
        return -1;
    r->value = dx;
    r->reference = ref;
    r->error = fabs(dx - ref) / ref;
    r->tolerance = 0.01;
    ns_validate_detail(r,
                       "EI %.4g N m^2, L %.3g m, 20 edges: small load %.3g N, deflection %.6g m "
                       "(%d Newton steps);",
                       EI, ROD_L, Psmall, dx, it);
    /* Large load: P L^2 / EI = 2 (tip turns about 45 degrees). */
    double alpha = 2.0, Pbig = alpha * EI / (ROD_L * ROD_L), edefl, eshort;
    elastica(alpha, &edefl, &eshort);
    double worst = 0.0;
    int res[3] = {20, 40, 80};
    for (int k = 0; k < 3; k++) {
        if (cantilever(res[k], Pbig, &dx, &dz, &it, r) != 0)
            return -1;
        double e1 = fabs(dx / ROD_L - edefl) / edefl, e2 = fabs(-dz / ROD_L - eshort) / eshort;
        double e = fmax(e1, e2);
        if (k == 0)
            worst = e;
        ns_validate_detail(r,
                           " large load PL^2/EI = %.0f, %d edges: deflection %.5f L (elastica "
                           "%.5f L), shortening %.5f L (elastica %.5f L), error %.2e (%d steps);",
                           alpha, res[k], dx / ROD_L, edefl, -dz / ROD_L, eshort, e, it);
    }
    ns_validate_detail(r, " large-load bar 2%% at 20 edges (Bisshopp & Drucker 1945)");
    r->pass = r->error <= r->tolerance && worst <= 0.02;
    return 0;
}

/* Lateral tip deflection of a fixed-free rod under axial load P (towards the sleeve) with a
 * lateral imperfection load eps P, solved statically from straight. */
static int column(int edges, double P, double eps, double *defl, NsValidateResult *r)
{
    NsRod rod;
    double load[3] = {eps * P, 0.0, -P};
    if (loaded_needle(&rod, edges, 0.0, 0.0, load, 1e-9, 2000, NULL, r) != 0)
        return -1;
    *defl = rod.x[3 * (rod.nodes - 1)];
    ns_rod_free(&rod);
    return 0;
}

/* Is the straight rod under axial load P a stable equilibrium? Solved statically (it stays
 * straight), then the exact stiffness is tested for definiteness (ns_rod_is_stable). */
static int column_stable(int edges, double P, int *stable, NsValidateResult *r)
{
    NsRod rod;
    double load[3] = {0.0, 0.0, -P};
    if (loaded_needle(&rod, edges, 0.0, 0.0, load, 1e-9, 100, NULL, r) != 0)
        return -1;
    double *ext = calloc(3 * (size_t)rod.nodes, sizeof *ext);
    if (!ext) {
        ns_rod_free(&rod);
        return fail(r, "out of memory");
    }
    memcpy(ext + 3 * (rod.nodes - 1), load, sizeof load);
    *stable = ns_rod_is_stable(&rod, ext);
    free(ext);
    ns_rod_free(&rod);
    return 0;
}

static int rod_buckling(NsValidateResult *r)
{
    snprintf(r->metric, sizeof r->metric, "buckling load [N]");
    double EI = needle_bend_stiff();
    double Pcr = M_PI * M_PI * EI / (4.0 * ROD_L * ROD_L), eps = 1e-5;
    int edges = 20, stable;
    /* The buckling load: the smallest axial load under which the straight rod stops being a
     * stable equilibrium, by bisection between half and 1.5 times Euler's load. */
    double lo = 0.5 * Pcr, hi = 1.5 * Pcr;
    if (column_stable(edges, lo, &stable, r) != 0)
        return -1;
    if (!stable)
        return fail(r, "unstable at half the Euler load");
    if (column_stable(edges, hi, &stable, r) != 0)
        return -1;
    if (stable)
        return fail(r, "still stable at 1.5 times the Euler load");
    while (hi - lo > 1e-5 * Pcr) {
        double mid = 0.5 * (lo + hi);
        if (column_stable(edges, mid, &stable, r) != 0)
            return -1;
        if (stable)
            lo = mid;
        else
            hi = mid;
    }
    double Pb = 0.5 * (lo + hi);
    /* And what it does: with a lateral imperfection of 1e-5 P, the tip barely moves at 0.95 Pb
     * and swings far out at 1.05 Pb (the elastica gives about 0.38 L). */
    double d95, d105;
    if (column(edges, 0.95 * Pb, eps, &d95, r) != 0 || column(edges, 1.05 * Pb, eps, &d105, r))
        return -1;
    d95 = fabs(d95) / ROD_L;
    d105 = fabs(d105) / ROD_L;
    r->value = Pb;
    r->reference = Pcr;
    r->error = fabs(Pb - Pcr) / Pcr;
    r->tolerance = 0.05;
    r->pass = r->error <= r->tolerance && d95 < 0.01 && d105 > 0.2;
    ns_validate_detail(r,
                       "fixed-free, L %.3g m, %d edges, EI %.4g N m^2, Euler pi^2 EI/(4L^2); "
                       "buckling = the straight rod's stiffness stops being definite; with a "
                       "lateral imperfection of %.0e P the tip deflection is %.2e L at 0.95 Pb "
                       "(bar < 0.01) and %.3f L at 1.05 Pb (bar > 0.2)",
                       ROD_L, edges, EI, eps, d95, d105);
    return 0;
}

static double angle_between(const double *a, const double *b)
{
    double c[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
    return atan2(sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]),
                 a[0] * b[0] + a[1] * b[1] + a[2] * b[2]);
}

/* Turns the base by pi over 1 s (dt 1 ms), then lets the rod settle for settle_s. */
static int turn_base(NsRod *rod, double settle_s, NsValidateResult *r)
{
    double dt = 1e-3;
    rod->twist_rate = M_PI;
    for (int s = 0; s < 1000; s++)
        if (ns_rod_step(rod, dt, NULL, NULL) != 0)
            return fail(r, "step failed while turning");
    rod->twist_rate = 0.0;
    int settle = (int)lround(settle_s / dt);
    for (int s = 0; s < settle; s++)
        if (ns_rod_step(rod, dt, NULL, NULL) != 0)
            return fail(r, "step failed while settling");
    return 0;
}

static int rod_twist(NsValidateResult *r)
{
    snprintf(r->metric, sizeof r->metric, "tip frame lag behind base [rad]");
    NsRodParams p = ns_default_rod_params();
    p.damping_mass = 20.0;
    p.auto_reparam = 0;
    /* Straight rod: the tip's m1 must end parallel to the base's, which turned by pi. */
    NsRod rod;
    if (make_needle(&rod, 20, 0.0, &p, r) != 0)
        return -1;
    double b0[3], b1[3], tip[3];
    ns_rod_material_frame(&rod, 0, NULL, b0, NULL);
    if (turn_base(&rod, 0.5, r) != 0) {
        ns_rod_free(&rod);
        return -1;
    }
    ns_rod_material_frame(&rod, 0, NULL, b1, NULL);
    ns_rod_tip_frame(&rod, NULL, tip, NULL);
    double base_turn = angle_between(b0, b1), lag = angle_between(b1, tip);
    ns_rod_free(&rod);
    r->value = lag;
    r->reference = 0.0;
    r->error = lag;
    r->tolerance = 1e-3;
    ns_validate_detail(r,
                       "straight rod, 20 edges: base turned %.6f rad (bar pi within 1e-3), tip "
                       "m1 off the base's by %.2e rad;",
                       base_turn, lag);
    /* Rod with rest curvature (radius 0.5 m towards +x): after the half turn it must lie mirrored
     * (tip towards -x). */
    if (make_needle(&rod, 20, 0.5, &p, r) != 0)
        return -1;
    int n = rod.nodes;
    double x0 = rod.x[3 * (n - 1)], y0 = rod.x[3 * (n - 1) + 1], z0 = rod.x[3 * (n - 1) + 2];
    if (turn_base(&rod, 1.0, r) != 0) {
        ns_rod_free(&rod);
        return -1;
    }
    double x1 = rod.x[3 * (n - 1)], y1 = rod.x[3 * (n - 1) + 1], z1 = rod.x[3 * (n - 1) + 2];
    ns_rod_free(&rod);
    double miss = sqrt((x1 + x0) * (x1 + x0) + (y1 - y0) * (y1 - y0) + (z1 - z0) * (z1 - z0));
    double rel = miss / fabs(x0);
    ns_validate_detail(r,
                       " curved rod (R 0.5 m): tip x %.5f -> %.5f m (y %.1e m), off the mirror "
                       "image by %.2e of the offset (bar 1%%)",
                       x0, x1, y1, rel);
    r->pass = r->error <= r->tolerance && fabs(base_turn - M_PI) <= 1e-3 && rel <= 0.01 && x1 < 0.0;
    return 0;
}

/* The twist of edge j about its tangent from edge 0's material frame (the sleeve's), measured
 * on the directors: atan2((b x m) . t, b . m) with b, m the two m1 [rad]. */
static double frame_twist(const NsRod *rod, int j)
{
    double b[3], m[3], t[3];
    ns_rod_material_frame(rod, 0, NULL, b, NULL);
    ns_rod_material_frame(rod, j, t, m, NULL);
    double c[3] = {b[1] * m[2] - b[2] * m[1], b[2] * m[0] - b[0] * m[2], b[0] * m[1] - b[1] * m[0]};
    return atan2(c[0] * t[0] + c[1] * t[1] + c[2] * t[2], b[0] * m[0] + b[1] * m[1] + b[2] * m[2]);
}

/* One resolution of rod-torsion: the nitinol needle with `edges` edges, torque T on its last
 * edge, static solve. Returns the tip twist extrapolated from the last two edges (the twist is
 * linear in arc length) and the worst relative error of every edge's twist against T s / GJ. */
static int torsion_run(int edges, double T, double GJ, double *tip, double *worst, double *lateral,
                       int *iters, NsValidateResult *r)
{
    NsRodParams p = static_params();
    p.material.youngs = 50e9; /* the flexible needle (Webster et al. 2006) */
    p.material.outer_diameter = 0.83e-3;
    p.material.inner_diameter = 0.0;
    p.material.density = 6450.0;
    NsRod rod;
    if (make_needle(&rod, edges, 0.0, &p, r) != 0)
        return -1;
    rod.tip_torque = T;
    NsRodStats st;
    *iters = ns_rod_static_solve(&rod, NULL, 1e-10, 50, &st);
    if (*iters < 0 || st.twist_unconverged) {
        ns_rod_free(&rod);
        return fail(r, "static solve failed");
    }
    double h = ROD_L / edges;
    *worst = 0.0;
    for (int j = 1; j <= edges; j++) { /* edge j's midpoint is (j - 1/2) h past the sleeve */
        double ref = T * (j - 0.5) * h / GJ;
        *worst = fmax(*worst, fabs(frame_twist(&rod, j) - ref) / ref);
    }
    double a = frame_twist(&rod, edges), b = frame_twist(&rod, edges - 1);
    *tip = a + 0.5 * (a - b);
    const double *xt = rod.x + 3 * (rod.nodes - 1);
    *lateral = sqrt(xt[0] * xt[0] + xt[1] * xt[1]);
    ns_rod_free(&rod);
    return 0;
}

/* End torque on a clamped rod: theta(s) = T s / (G J), J = pi (d_o^4 - d_i^4) / 32. */
static int rod_torsion(NsValidateResult *r)
{
    snprintf(r->metric, sizeof r->metric, "tip twist under an end torque [rad]");
    double E = 50e9, nu = 0.3, d = 0.83e-3;
    double GJ = E / (2.0 * (1.0 + nu)) * M_PI * d * d * d * d / 32.0;
    double T = 0.5 * GJ / ROD_L; /* half a radian at the tip, well below any buckling */
    double ref = T * ROD_L / GJ, tip[2], worst[2], lat[2];
    int iters[2], edges[2] = {10, 40};
    for (int k = 0; k < 2; k++)
        if (torsion_run(edges[k], T, GJ, tip + k, worst + k, lat + k, iters + k, r) != 0)
            return -1;
    r->value = tip[0];
    r->reference = ref;
    r->error = fmax(fabs(tip[0] - ref), fabs(tip[1] - ref)) / ref;
    r->tolerance = 1e-3;
    double prof = fmax(worst[0], worst[1]);
    ns_validate_detail(r,
                       "solid nitinol needle (E 50 GPa, nu 0.3, 0.83 mm: GJ %.4e N m^2), L %.0f "
                       "mm, end torque %.4e N m, static solve: tip twist %.6f rad (10 edges, %d "
                       "iterations), %.6f rad (40 edges, %d) against T L / GJ = %.6f rad; every "
                       "edge's twist against T s / GJ within %.1e (bar 1e-3); tip off the axis "
                       "by %.1e m",
                       GJ, 1e3 * ROD_L, T, tip[0], iters[0], tip[1], iters[1], ref, prof,
                       fmax(lat[0], lat[1]));
    r->pass = r->error <= r->tolerance && prof <= 1e-3 && fmax(lat[0], lat[1]) <= 1e-9;
    return 0;
}

static int rod_length(NsValidateResult *r)
{
    snprintf(r->metric, sizeof r->metric, "max edge |length / rest length - 1|");
    NsRodParams p = ns_default_rod_params();
    p.gravity[0] = -9.81;
    p.auto_reparam = 0;
    NsRod rod;
    if (make_needle(&rod, 20, 0.3, &p, r) != 0)
        return -1;
    int n = rod.nodes;
    double *ext = calloc(3 * (size_t)n, sizeof *ext);
    if (!ext) {
        ns_rod_free(&rod);
        return fail(r, "out of memory");
    }
    /* A tip load across the curvature plane ramped up to P L^2 / EI = 2 over 0.2 s, while the
     * base turns at 2 rad/s: bending, twisting and vibration together. (Applied at once, such a
     * load would move the free tip by centimetres in the first 1 ms step, far outside what one
     * linearized Newton step can follow: docs/needle.md.) */
    double P = 2.0 * rod.bend_stiff / (ROD_L * ROD_L);
    rod.twist_rate = 2.0;
    double L0 = ns_rod_rest_length(&rod), worst = 0.0, total = 0.0, tipmax = 0.0;
    int nan = 0, steps = 1000, failed = 0;
    NsRodStats st;
    for (int s = 0; s < steps; s++) {
        ext[3 * (n - 1) + 1] = P * fmin(1.0, (s + 1) * 1e-3 / 0.2);
        if (ns_rod_step(&rod, 1e-3, ext, &st) != 0) {
            failed = 1;
            break;
        }
        nan += st.nan_count;
        double L = ns_rod_edges_length(&rod);
        if (!isfinite(L))
            nan++;
        total = fmax(total, fabs(L / L0 - 1.0));
        for (int j = 0; j + 1 < n; j++) {
            double l = 0.0;
            for (int k = 0; k < 3; k++)
                l += (rod.x[3 * (j + 1) + k] - rod.x[3 * j + k]) *
                     (rod.x[3 * (j + 1) + k] - rod.x[3 * j + k]);
            worst = fmax(worst, fabs(sqrt(l) / rod.rest_len[j] - 1.0));
        }
        double ty = rod.x[3 * (n - 1) + 1];
        tipmax = fmax(tipmax, fabs(ty));
    }
    for (int i = 0; i < 3 * n; i++)
        nan += !isfinite(rod.x[i]);
    free(ext);
    ns_rod_free(&rod);
    r->value = worst;
    r->reference = 0.0;
    r->error = worst;
    r->tolerance = 1e-3;
    r->pass = !failed && nan == 0 && worst <= r->tolerance;
    ns_validate_detail(r,
                       "1000 steps of 1 ms: curved rod (R 0.3 m), gravity, tip load ramped to "
                       "%.3g N, base turning 2 rad/s; largest tip swing %.4f m; total length "
                       "within %.2e of the rest length; NaN %d%s",
                       P, tipmax, total, nan, failed ? "; a step failed" : "");
    return 0;
}

static int rod_reparam(NsValidateResult *r)
{
    snprintf(r->metric, sizeof r->metric, "bending energy change (worst)");
    NsRod rod;
    /* A needle curved at rest (radius 0.3 m towards +x), its base turned by 0.6 rad and its tip
     * loaded across the curvature plane: bending, twist and rest curvature all carried. */
    double load[3] = {0.0, 2.0 * needle_bend_stiff() / (ROD_L * ROD_L), 0.0};
    int it;
    if (loaded_needle(&rod, 20, 0.3, 0.6, load, 1e-9, 500, &it, r) != 0)
        return -1;
    int n = rod.nodes;
    double *x0 = malloc(3 * (size_t)n * sizeof *x0);
    if (!x0) {
        ns_rod_free(&rod);
        return fail(r, "out of memory");
    }
    memcpy(x0, rod.x, 3 * (size_t)n * sizeof *x0);
    double eb0, et0, L0 = ns_rod_rest_length(&rod);
    ns_rod_energy(&rod, NULL, &eb0, &et0, NULL);
    /* Split every edge outside the sleeve in two... */
    rod.params.merge_factor = 0.3;
    rod.params.split_factor = 0.75;
    NsRodStats st;
    memset(&st, 0, sizeof st);
    int rc = ns_rod_reparameterize(&rod, &st);
    int n1 = rod.nodes, splits = st.splits;
    double moved = 0.0, eb1 = 0.0, et1 = 0.0, L1 = ns_rod_rest_length(&rod);
    if (rc == 0) {
        for (int i = 0; i < n; i++) /* old node i is now node 2 i - 1 (nodes 0, 1 unchanged) */
            for (int k = 0; k < 3; k++) {
                int j = i < 2 ? i : 2 * i - 1;
                moved = fmax(moved, fabs(rod.x[3 * j + k] - x0[3 * i + k]));
            }
        ns_rod_energy(&rod, NULL, &eb1, &et1, NULL);
    }
    /* ... then merge them back. */
    rod.params.split_factor = 2.0;
    rod.params.merge_factor = 0.6;
    memset(&st, 0, sizeof st);
    if (rc == 0)
        rc = ns_rod_reparameterize(&rod, &st);
    int n2 = rod.nodes, merges = st.merges;
    double moved2 = 0.0, eb2 = 0.0, et2 = 0.0, L2 = ns_rod_rest_length(&rod);
    if (rc == 0 && n2 == n) {
        for (int i = 0; i < 3 * n; i++)
            moved2 = fmax(moved2, fabs(rod.x[i] - x0[i]));
        ns_rod_energy(&rod, NULL, &eb2, &et2, NULL);
    }
    free(x0);
    ns_rod_free(&rod);
    if (rc != 0)
        return fail(r, "reparameterization failed");
    double e1 = fabs(eb1 / eb0 - 1.0), e2 = fabs(eb2 / eb0 - 1.0);
    double t1 = fabs((eb1 + et1) / (eb0 + et0) - 1.0), t2 = fabs((eb2 + et2) / (eb0 + et0) - 1.0);
    double dl = fmax(fabs(L1 / L0 - 1.0), fabs(L2 / L0 - 1.0));
    r->value = eb1;
    r->reference = eb0;
    r->error = fmax(e1, e2);
    r->tolerance = 0.01;
    r->pass = r->error <= r->tolerance && fmax(t1, t2) <= 0.01 && dl <= 1e-12 && moved == 0.0 &&
              moved2 == 0.0 && n1 == 2 * n - 2 && n2 == n;
    ns_validate_detail(r,
                       "curved needle (R 0.3 m), base turned 0.6 rad, tip load P L^2/EI = 2 "
                       "across (%d Newton steps), 20 edges: split %d edges -> %d nodes, "
                       "bending energy %.6g -> %.6g J (%.2e), bending + twist %.2e, rest "
                       "length %.1e, old nodes moved %.1e m; merged %d -> %d nodes, bending "
                       "%.6g J (%.2e), bending + twist %.2e, nodes moved %.1e m (bars: 1%%, "
                       "1%%, 1e-12, 0)",
                       it, splits, n1, eb0, eb1, e1, t1, dl, moved, merges, n2, eb2, e2, t2,
                       moved2);
    return 0;
}

const NsValidateCase ns_validate_rod_cases[] = {
    {"rod-cantilever", "needle cantilever: beam theory (small load) and elastica (large)",
     rod_cantilever},
    {"rod-buckling", "fixed-free needle under axial load buckles at pi^2 EI / (4 L^2)",
     rod_buckling},
    {"rod-twist", "base turned half a turn: the tip follows; a curved needle swings over",
     rod_twist},
    {"rod-torsion", "end torque on a clamped nitinol needle: tip twist T L / GJ (10 and 40 edges)",
     rod_torsion},
    {"rod-length", "1,000 steps of bending and twisting: length kept within 0.1%", rod_length},
    {"rod-reparam", "split and merge of a bent needle: nodes kept, bending energy kept",
     rod_reparam},
};
const int ns_validate_rod_case_count =
    (int)(sizeof ns_validate_rod_cases / sizeof ns_validate_rod_cases[0]);
