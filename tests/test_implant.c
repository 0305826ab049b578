/* plan/implant.c: a spherical gland, a 9 x 9 template, a point-like source whose dose is
 * S_K Lambda tau r0^2 / r^2 (g = F = 1, L = 0). The plan's V100 is recomputed here from that
 * closed form at the planning grid's voxels (not by the planner's code); every seed lies in the
 * gland, 1 cm from its neighbours on its needle; no needle of the plan can be dropped without
 * losing the coverage; an avoided region keeps its clearance; the budgets hold; the same inputs
 * give the same plan; bad input is refused. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "implant.h"
#include "ns_test.h"

#define R_GLAND 0.015
#define GRID    2e-3
static const double CENTRE[3] = {0, 0, 0.05};

static NsTg43Source point_source(void)
{
    NsTg43Source s;
    memset(&s, 0, sizeof s);
    s.lambda = 1e4; /* 1 cGy h^-1 U^-1 */
    s.length = 0.0;
    s.half_life = 59.4 * 86400.0;
    s.n_g = 2;
    s.g_r[0] = 0.001;
    s.g_r[1] = 0.1;
    s.g[0] = s.g[1] = 1.0;
    s.n_fr = 2;
    s.f_r[0] = 0.001;
    s.f_r[1] = 0.1;
    s.n_ft = 2;
    s.f_theta[0] = 0.0;
    s.f_theta[1] = M_PI / 2;
    for (int k = 0; k < 4; k++)
        s.f[k] = 1.0;
    return s;
}

typedef struct Fixture {
    NsShape *block, *gland, *tube;
    const NsShape *regions[3];
    double holes[81 * 3];
    NsTg43Source src;
    NsImplantParams p;
} Fixture;

static void fixture(Fixture *f, bool tube)
{
    memset(f, 0, sizeof *f);
    double bc[3] = {0, 0, 0.05}, bs[3] = {0.08, 0.08, 0.1}, a[3] = {0, 0, 0.0}, b[3] = {0, 0, 0.1};
    f->block = ns_shape_box(bc, bs);
    f->gland = ns_shape_sphere(CENTRE, R_GLAND);
    f->tube = ns_shape_cylinder(a, b, 0.003);
    f->regions[0] = f->block;
    f->regions[1] = f->gland;
    f->regions[2] = f->tube;
    for (int i = 0; i < 81; i++) {
        f->holes[3 * i] = -0.02 + 0.005 * (i / 9);
        f->holes[3 * i + 1] = -0.02 + 0.005 * (i % 9);
        f->holes[3 * i + 2] = 0.0;
    }
    f->src = point_source();
    static const int avoid[1] = {2};
    f->p = (NsImplantParams){
        .regions = f->regions,
        .region_count = tube ? 3 : 2,
        .target = 1,
        .avoid = avoid,
        .avoid_count = tube ? 1 : 0,
        .clearance = 2.5e-3,
        .holes = f->holes,
        .hole_count = 81,
        .direction = {0, 0, 1},
        .spacing = 0.01,
        .seeds_per_needle = 20,
        .tip_offset = 2.25e-3,
        .margin = 2e-3,
        .seeds_max = 200,
        .needles_max = 81,
        .prescription = 150.0,
        .coverage = 0.95,
        .v150_max = 100.0,
        .grid = GRID,
        .source = &f->src,
        .sk = NS_TG43_UNIT_U,
    };
}

static void fixture_free(Fixture *f)
{
    ns_shape_release(f->block);
    ns_shape_release(f->gland);
    ns_shape_release(f->tube);
}

/* The closed-form dose at x from the seeds (a point source; the capsule clamp of dose.h: a point
 * within 0.4 mm of a seed's axis beside its 4.55 mm capsule is taken on the capsule's side). */
static double dose_at(const NsTg43Source *s, const double *seeds, int n, double sk,
                      const double x[3])
{
    double tau = s->half_life / log(2.0), d = 0.0;
    for (int i = 0; i < n; i++) {
        double dx = x[0] - seeds[3 * i], dy = x[1] - seeds[3 * i + 1], dz = x[2] - seeds[3 * i + 2];
        double rho = sqrt(dx * dx + dy * dy);
        if (rho < NS_TG43_RHO_MIN && fabs(dz) < NS_TG43_Z_CAP)
            rho = NS_TG43_RHO_MIN;
        double r2 = rho * rho + dz * dz;
        d += sk * s->lambda * NS_TG43_R0 * NS_TG43_R0 / r2 * tau;
    }
    return d;
}

/* V100 [%] of the gland (less the tube, when there is one) on the planning grid, from the seeds
 * of the plan's needles except needle `skip` (-1: none). */
static double v100(const Fixture *f, const NsImplantPlan *pl, int skip, long *voxels)
{
    double *seeds = malloc((size_t)pl->seed_count * 3 * sizeof *seeds);
    int n = 0;
    for (int j = 0, k = 0; j < pl->needle_count; j++)
        for (int i = 0; i < pl->seeds[j]; i++, k++)
            if (j != skip)
                memcpy(seeds + 3 * n++, pl->seed_pos + 3 * k, 3 * sizeof *seeds);
    long in = 0, hit = 0;
    int m = (int)ceil(2 * R_GLAND / GRID);
    for (int k = 0; k < m; k++)
        for (int j = 0; j < m; j++)
            for (int i = 0; i < m; i++) {
                double x[3] = {CENTRE[0] - R_GLAND + (i + 0.5) * GRID,
                               CENTRE[1] - R_GLAND + (j + 0.5) * GRID,
                               CENTRE[2] - R_GLAND + (k + 0.5) * GRID};
                double dx = x[0] - CENTRE[0], dy = x[1] - CENTRE[1], dz = x[2] - CENTRE[2];
                if (dx * dx + dy * dy + dz * dz > R_GLAND * R_GLAND)
                    continue;
                if (f->p.region_count == 3 && x[0] * x[0] + x[1] * x[1] <= 0.003 * 0.003)
                    continue;
                in++;
                hit += dose_at(&f->src, seeds, n, f->p.sk, x) >= f->p.prescription;
            }
    free(seeds);
    *voxels = in;
    return 100.0 * (double)hit / (double)in;
}

static int covers(void)
{
    Fixture f;
    fixture(&f, false);
    NsImplantPlan pl;
    char err[256];
    ENSURE(ns_plan_implant(&f.p, &pl, err, sizeof err) == 0);
    printf("    %d needles, %d seeds, V100 %.2f %%, V150 %.2f %%, D90 %.2f Gy, %ld voxels\n",
           pl.needle_count, pl.seed_count, pl.v100, pl.v150, pl.d90, pl.voxels);
    ENSURE(pl.reached && pl.v100 >= 95.0);
    ENSURE(pl.needle_count > 1 && pl.needle_count < 81);
    long voxels;
    double v = v100(&f, &pl, -1, &voxels);
    ENSURE(voxels == pl.voxels);
    ENSURE_SMALL(v - pl.v100, 1e-9);
    /* every seed in the gland, its needle's seeds 1 cm apart along z at the hole's x, y */
    for (int j = 0, k = 0; j < pl.needle_count; j++)
        for (int i = 0; i < pl.seeds[j]; i++, k++) {
            const double *s = pl.seed_pos + 3 * k, *h = f.holes + 3 * pl.hole[j];
            double dx = s[0] - CENTRE[0], dy = s[1] - CENTRE[1], dz = s[2] - CENTRE[2];
            ENSURE(dx * dx + dy * dy + dz * dz < R_GLAND * R_GLAND);
            ENSURE(s[0] == h[0] && s[1] == h[1]);
            ENSURE_SMALL(s[2] - (h[2] + pl.deepest[j] - 0.01 * i), 1e-15);
        }
    /* fewest insertions: without any one of its needles the plan misses the coverage */
    for (int j = 0; j < pl.needle_count; j++)
        ENSURE(v100(&f, &pl, j, &voxels) < 95.0);
    ns_implant_plan_free(&pl);
    fixture_free(&f);
    return 0;
}

static int avoids(void)
{
    Fixture f;
    fixture(&f, true);
    NsImplantPlan pl;
    char err[256];
    ENSURE(ns_plan_implant(&f.p, &pl, err, sizeof err) == 0);
    /* the four holes 5 mm from the tube's axis are within 3 + 2.5 mm of it (the one on the axis
     * crosses no gland: the tube overrides it there) */
    ENSURE(pl.blocked == 4);
    for (int j = 0; j < pl.needle_count; j++) {
        const double *h = f.holes + 3 * pl.hole[j];
        ENSURE(hypot(h[0], h[1]) >= 0.0055);
    }
    long voxels;
    ENSURE_SMALL(v100(&f, &pl, -1, &voxels) - pl.v100, 1e-9);
    ENSURE(voxels == pl.voxels);
    ns_implant_plan_free(&pl);
    /* a clearance no track keeps: refused, saying so */
    f.p.clearance = 0.05;
    ENSURE(ns_plan_implant(&f.p, &pl, err, sizeof err) == -1);
    ENSURE(strstr(err, "within 50 mm of an avoided region") != NULL);
    fixture_free(&f);
    return 0;
}

static int budgets(void)
{
    Fixture f;
    fixture(&f, false);
    NsImplantPlan pl;
    char err[256];
    f.p.needles_max = 2;
    ENSURE(ns_plan_implant(&f.p, &pl, err, sizeof err) == 0);
    ENSURE(pl.needle_count == 2 && !pl.reached && pl.v100 < 95.0);
    ns_implant_plan_free(&pl);
    f.p.needles_max = 81;
    f.p.seeds_max = 7;
    ENSURE(ns_plan_implant(&f.p, &pl, err, sizeof err) == 0);
    ENSURE(pl.seed_count <= 7 && !pl.reached);
    ns_implant_plan_free(&pl);
    fixture_free(&f);
    return 0;
}

static int same_plan(void)
{
    Fixture f;
    fixture(&f, true);
    f.p.v150_max = 60.0;
    NsImplantPlan a, b;
    char err[256];
    ENSURE(ns_plan_implant(&f.p, &a, err, sizeof err) == 0);
    ENSURE(ns_plan_implant(&f.p, &b, err, sizeof err) == 0);
    ENSURE(a.needle_count == b.needle_count && a.seed_count == b.seed_count);
    ENSURE(memcmp(a.hole, b.hole, (size_t)a.needle_count * sizeof *a.hole) == 0);
    ENSURE(ns_same_bits(a.seed_pos, b.seed_pos, 3 * a.seed_count));
    ENSURE(ns_same_bits(&a.d90, &b.d90, 1));
    ns_implant_plan_free(&a);
    ns_implant_plan_free(&b);
    fixture_free(&f);
    return 0;
}

static int bad_input(void)
{
    Fixture f;
    fixture(&f, false);
    NsImplantPlan pl;
    char err[256];
    NsImplantParams keep = f.p;
    f.p.grid = 0.0;
    ENSURE(ns_plan_implant(&f.p, &pl, err, sizeof err) == -1 && strstr(err, "planning grid"));
    f.p = keep;
    f.p.target = 5;
    ENSURE(ns_plan_implant(&f.p, &pl, err, sizeof err) == -1 && strstr(err, "target region"));
    f.p = keep;
    f.p.coverage = 1.5;
    ENSURE(ns_plan_implant(&f.p, &pl, err, sizeof err) == -1 && strstr(err, "coverage"));
    f.p = keep;
    f.p.direction[2] = NAN;
    ENSURE(ns_plan_implant(&f.p, &pl, err, sizeof err) == -1 && strstr(err, "direction"));
    f.p = keep;
    f.p.direction[2] = -1.0; /* the needles go away from the gland */
    ENSURE(ns_plan_implant(&f.p, &pl, err, sizeof err) == -1 &&
           strstr(err, "no hole's track crosses"));
    fixture_free(&f);
    return 0;
}

NS_TEST_MAIN({"covers", covers}, {"avoids", avoids}, {"budgets", budgets}, {"same_plan", same_plan},
             {"bad_input", bad_input})
