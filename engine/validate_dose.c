/* Validation cases for the TG-43U1 dose model (sim/dose.c; docs/brachytherapy.md) against the
 * I-125 model 6711 consensus data (assets/tg43/i125_6711.csv) and closed forms computed here,
 * apart from the code under test: the dose-rate constant at the reference point, the radial dose
 * function and the anisotropy function at every tabulated point (read back through the dose of
 * a seed), and the line-source geometry function against the law of cosines. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "dose.h"
#include "dose_table.h"
#include "validate.h"

/* The published consensus dose-rate constant for model 6711 [cGy h^-1 U^-1] (TG-43U1), as a
 * literal: the table's value is checked against it too. */
#define LAMBDA_6711 0.965
#define CGY_PER_H   (0.01 / 3600.0) /* 1 cGy/h in Gy/s */

/* Loads the shipped table and names the case's metric. */
static int load(NsTg43Source *s, NsValidateResult *r, const char *metric)
{
    snprintf(r->metric, sizeof r->metric, "%s", metric);
    char err[512];
    if (ns_tg43_load_6711(s, err, sizeof err) == 0)
        return 0;
    ns_validate_detail(r, "%s", err);
    r->pass = false;
    return -1;
}

/* A relative error against a bar (the reference is 0: the error is the value). */
static void judge(NsValidateResult *r, double worst, double tolerance)
{
    r->value = worst;
    r->reference = 0.0;
    r->error = worst;
    r->tolerance = tolerance;
    r->pass = r->error <= r->tolerance;
}

/* The geometry function by the law of cosines: beta from the distances to the two ends,
 * written apart from sim/dose.c's atan2 form; on the axis 1 / (r^2 - L^2/4). */
static double geometry_closed(double L, double r, double theta)
{
    double z = r * cos(theta), y = r * sin(theta);
    if (fabs(y) < 1e-15)
        return 1.0 / (r * r - L * L / 4.0);
    double d1 = sqrt(y * y + (z - L / 2) * (z - L / 2)),
           d2 = sqrt(y * y + (z + L / 2) * (z + L / 2));
    double c = (d1 * d1 + d2 * d2 - L * L) / (2.0 * d1 * d2);
    double beta = acos(c > 1.0 ? 1.0 : c);
    return beta / (L * y);
}

/* A seed at the origin along +z of 1 U; the point at (r, theta) in the x-z plane. */
static double seed_rate(const NsTg43Source *s, double r, double theta)
{
    NsDoseSeed seed = {{0, 0, 0}, {0, 0, 1}, NS_TG43_UNIT_U};
    double p[3] = {r * sin(theta), 0.0, r * cos(theta)};
    return ns_dose_at(s, &seed, 1, p) / ns_tg43_mean_life(s);
}

static int tg43_dose_rate(NsValidateResult *r)
{
    NsTg43Source s;
    if (load(&s, r, "Ddot(1 cm, 90 deg) / S_K [cGy/(h U)]"))
        return -1;
    /* The formula, a seed's dose over its mean life, and a tilted, stronger seed. */
    double formula = ns_tg43_dose_rate(&s, NS_TG43_UNIT_U, NS_TG43_R0, M_PI / 2) / CGY_PER_H;
    double via_seed = seed_rate(&s, NS_TG43_R0, M_PI / 2) / CGY_PER_H;
    double sk = 0.5; /* U */
    NsDoseSeed tilted = {{0.01, -0.02, 0.005}, {1, 2, 2}, sk * NS_TG43_UNIT_U};
    double perp[3] = {2.0 / 3, -1.0 / 3, 0.0}; /* unit, normal to (1, 2, 2) / 3 */
    double p[3];
    for (int c = 0; c < 3; c++)
        p[c] = tilted.pos[c] + NS_TG43_R0 * perp[c] / sqrt(5.0 / 9);
    double via_tilted = ns_dose_at(&s, &tilted, 1, p) / ns_tg43_mean_life(&s) / CGY_PER_H / sk;
    double table = s.lambda * 1e-4;
    r->value = formula;
    r->reference = LAMBDA_6711;
    double e[4] = {fabs(formula / LAMBDA_6711 - 1), fabs(via_seed / LAMBDA_6711 - 1),
                   fabs(via_tilted / LAMBDA_6711 - 1), fabs(table / LAMBDA_6711 - 1)};
    r->error = fmax(fmax(e[0], e[1]), fmax(e[2], e[3]));
    r->tolerance = 0.005;
    r->pass = r->error <= r->tolerance;
    ns_validate_detail(r,
                       "formula %.6f, seed dose to full decay / tau %.6f, 0.5 U seed along "
                       "(1,2,2) %.6f cGy/(h U); table Lambda %.4f; reference 0.965 (TG-43U1 "
                       "consensus, model 6711); tau %.3f d (T1/2 %.2f d)",
                       formula, via_seed, via_tilted, table, ns_tg43_mean_life(&s) / 86400.0,
                       s.half_life / 86400.0);
    return 0;
}

static int tg43_radial(NsValidateResult *r)
{
    NsTg43Source s;
    if (load(&s, r, "g_L at tabulated radii: max rel error"))
        return -1;
    double L = s.length, worst = 0.0, worst_dose = 0.0, at = 0.0;
    double ref_rate = seed_rate(&s, NS_TG43_R0, M_PI / 2);
    double g_ref0 = geometry_closed(L, NS_TG43_R0, M_PI / 2);
    for (int i = 0; i < s.n_g; i++) {
        double ri = s.g_r[i], want = s.g[i];
        double e1 = fabs(ns_tg43_radial(&s, ri) / want - 1);
        /* The transverse axis's dose, stripped of the closed-form geometry: g_L itself. */
        double rate = seed_rate(&s, ri, M_PI / 2);
        double from_dose = rate / ref_rate * g_ref0 / geometry_closed(L, ri, M_PI / 2);
        double e2 = fabs(from_dose / want - 1);
        if (fmax(e1, e2) > worst) {
            worst = fmax(e1, e2);
            at = ri;
        }
        worst_dose = fmax(worst_dose, e2);
    }
    judge(r, worst, 0.01);
    ns_validate_detail(r,
                       "%d radii 0.1-10 cm (TG-43U1, model 6711): interpolated g_L and "
                       "Ddot(r,90)/Ddot(1cm,90) * G_L(1cm)/G_L(r) (closed-form G_L) against the "
                       "table; worst %.2e at r = %.2f cm (through the dose: %.2e)",
                       s.n_g, worst, at * 100, worst_dose);
    return 0;
}

static int tg43_anisotropy(NsValidateResult *r)
{
    NsTg43Source s;
    if (load(&s, r, "F(r,theta) at tabulated points: max rel"))
        return -1;
    double L = s.length, g0 = geometry_closed(L, NS_TG43_R0, M_PI / 2), worst = 0.0;
    double lam = s.lambda * NS_TG43_UNIT_U; /* S_K = 1 U */
    int points = 0, wr = 0, wt = 0;
    for (int t = 0; t < s.n_ft; t++)
        for (int i = 0; i < s.n_fr; i++) {
            double rr = s.f_r[i], th = s.f_theta[t], want = s.f[t * s.n_fr + i];
            double direct = ns_tg43_anisotropy(&s, rr, th);
            double mirror = ns_tg43_anisotropy(&s, rr, M_PI - th);
            /* Through a seed's dose: F = Ddot / (S_K Lambda G_L/G_L0 g_L), G_L closed-form and
             * g_L the tabulated value at this radius (every F radius is a g_L radius). */
            double gl = ns_tg43_radial(&s, rr);
            double e = fmax(fabs(direct / want - 1), fabs(mirror / want - 1));
            for (int side = 0; side < 2; side++) {
                double a = side ? M_PI - th : th;
                double rate = seed_rate(&s, rr, a);
                double f = rate / (lam * geometry_closed(L, rr, a) / g0 * gl);
                e = fmax(e, fabs(f / want - 1));
            }
            for (int k = 0; k < s.n_g; k++)
                if (fabs(s.g_r[k] - rr) < 1e-12)
                    e = fmax(e, fabs(gl / s.g[k] - 1));
            if (e > worst) {
                worst = e;
                wr = i;
                wt = t;
            }
            points++;
        }
    judge(r, worst, 0.01);
    ns_validate_detail(r,
                       "%d points (r 0.5-5 cm, theta 0-90 deg and mirrored to 180-theta; "
                       "TG-43U1, model 6711): interpolated F and F recovered from a seed's dose "
                       "with closed-form G_L; worst %.2e at r = %.1f cm, theta = %.0f deg",
                       points, worst, s.f_r[wr] * 100, s.f_theta[wt] * 180 / M_PI);
    return 0;
}

static int tg43_geometry(NsValidateResult *r)
{
    snprintf(r->metric, sizeof r->metric, "G_L vs closed form: max rel error");
    const double L = 0.003; /* model 6711's active length [m] */
    double worst = 0.0, worst_axis = 0.0;
    static const double radii[] = {0.002, 0.0025, 0.005, 0.01, 0.02, 0.05, 0.1};
    for (size_t i = 0; i < sizeof radii / sizeof radii[0]; i++)
        for (int deg = 1; deg < 180; deg++) {
            double th = deg * M_PI / 180;
            double e =
                fabs(ns_tg43_geometry(L, radii[i], th) / geometry_closed(L, radii[i], th) - 1);
            worst = fmax(worst, e);
        }
    for (size_t i = 0; i < sizeof radii / sizeof radii[0]; i++) /* on the axis, both ends */
        for (int end = 0; end < 2; end++) {
            double want = 1.0 / (radii[i] * radii[i] - L * L / 4);
            worst_axis =
                fmax(worst_axis, fabs(ns_tg43_geometry(L, radii[i], end ? M_PI : 0.0) / want - 1));
        }
    /* Point-source limit: r^2 G_L -> 1 as L / r -> 0 (r = 10 cm: (L/r)^2 ~ 1e-3), and L = 0
     * gives 1/r^2 exactly. */
    double limit = 0.0;
    for (int deg = 0; deg <= 90; deg += 10) {
        double th = deg * M_PI / 180;
        limit = fmax(limit, fabs(ns_tg43_geometry(L, 0.1, th) * 0.01 - 1));
        limit = fmax(limit, fabs(ns_tg43_geometry(0.0, 0.02, th) * 0.0004 - 1));
    }
    judge(r, fmax(worst, worst_axis), 1e-9);
    r->pass = r->pass && limit <= 1e-3;
    ns_validate_detail(r,
                       "L = 3 mm, r 2-100 mm, theta 1-179 deg: %.1e (law of cosines); on the "
                       "axis (0 and 180 deg) against 1/(r^2 - L^2/4): %.1e; point-source limit "
                       "|r^2 G_L - 1| at r = 10 cm and L = 0: %.1e (bar 1e-3)",
                       worst, worst_axis, limit);
    return 0;
}

const NsValidateCase ns_validate_dose_cases[] = {
    {"tg43-dose-rate", "I-125 6711: dose rate at 1 cm on the transverse axis = Lambda S_K (0.5%)",
     tg43_dose_rate},
    {"tg43-radial", "I-125 6711: g_L at the tabulated radii, also through a seed's dose (1%)",
     tg43_radial},
    {"tg43-anisotropy", "I-125 6711: F(r,theta) at the tabulated points, also through the dose",
     tg43_anisotropy},
    {"tg43-geometry", "line-source G_L against its closed form, on the axis, point-source limit",
     tg43_geometry},
};
const int ns_validate_dose_case_count =
    (int)(sizeof ns_validate_dose_cases / sizeof ns_validate_dose_cases[0]);
