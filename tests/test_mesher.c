/* Isosurface stuffing: the dihedral-angle guarantee (Labelle & Shewchuk 2007), conformity,
 * volumes, multi-region interfaces and junctions, fixed flags, determinism and errors.
 *
 * Every random choice comes from a seeded generator, so each run meshes the same shapes. The
 * figures printed with "#" are the ones quoted in docs/mesher.md. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "mesher.h"
#include "ns_test.h"
#include "quality.h"

#define PI           3.14159265358979323846
#define MIN_DIHEDRAL 10.7 /* L&S's bound for alpha = (0.24999, 0.41189) */
#define MAX_DIHEDRAL 164.8

static double rnd(uint32_t *state)
{
    *state = *state * 1664525u + 1013904223u;
    return (double)(*state >> 8) / 16777216.0;
}

static double box_sdf(const double c[3], const double size[3], const double p[3])
{
    double out2 = 0, in = -INFINITY;
    for (int a = 0; a < 3; a++) {
        double e = fabs(p[a] - c[a]) - 0.5 * size[a];
        if (e > 0)
            out2 += e * e;
        in = fmax(in, e);
    }
    return sqrt(out2) + fmin(in, 0.0);
}

typedef struct Report {
    int tets, nodes;
    double min_dih, max_dih;
    int bad_volume; /* tets with signed volume <= 0 */
    double volume[4];
    double total_volume;
    NsBoundaryStats boundary;
    int valid; /* ns_mesh_validate */
    int unreferenced;
} Report;

static const double *node(const NsMesh *m, int t, int k)
{
    return m->u + 3 * m->tet_node[4 * t + k];
}

static void inspect(NsMesh *m, Report *r)
{
    memset(r, 0, sizeof *r);
    r->min_dih = 180;
    r->tets = m->tet_alive;
    r->nodes = m->node_alive;
    for (int t = 0; t < m->tet_slots; t++) {
        if (!ns_mesh_tet_alive(m, t))
            continue;
        double d[6];
        ns_tet_dihedrals(node(m, t, 0), node(m, t, 1), node(m, t, 2), node(m, t, 3), d);
        for (int i = 0; i < 6; i++) {
            r->min_dih = fmin(r->min_dih, d[i]);
            r->max_dih = fmax(r->max_dih, d[i]);
        }
        double v = ns_tet_volume(node(m, t, 0), node(m, t, 1), node(m, t, 2), node(m, t, 3));
        r->bad_volume += !(v > 0);
        if (m->tet_region[t] < 4)
            r->volume[m->tet_region[t]] += v;
        r->total_volume += v;
    }
    char err[256];
    r->valid = ns_mesh_validate(m, err, sizeof err);
    if (r->valid)
        fprintf(stderr, "validate: %s\n", err);
    ns_mesh_boundary(m, &r->boundary);
    r->unreferenced = ns_mesh_first_unreferenced_node(m);
}

/* The conformity checks every mesh must pass. */
static int ensure_sound(const Report *r)
{
    ENSURE(r->tets > 0);
    ENSURE(r->valid == 0);
    ENSURE(r->bad_volume == 0);
    ENSURE(r->boundary.closed);
    ENSURE(r->boundary.manifold);
    ENSURE(r->unreferenced == -1);
    return 0;
}

/* ---- single surface: the guarantee ---------------------------------------------------------- */

typedef NsShape *(*MakeShape)(uint32_t *seed, double *volume);

static NsShape *make_sphere(uint32_t *seed, double *volume)
{
    double c[3] = {0.01 * rnd(seed), 0.01 * rnd(seed), 0.01 * rnd(seed)};
    double r = 0.012 + 0.01 * rnd(seed);
    *volume = 4.0 / 3.0 * PI * r * r * r;
    return ns_shape_sphere(c, r);
}

static NsShape *make_ellipsoid(uint32_t *seed, double *volume)
{
    double c[3] = {0.01 * rnd(seed), 0.01 * rnd(seed), 0.01 * rnd(seed)};
    double r0 = 0.015 + 0.01 * rnd(seed);
    double r[3] = {r0, r0 * (0.4 + 0.4 * rnd(seed)), r0 * (0.6 + 0.6 * rnd(seed))};
    *volume = 4.0 / 3.0 * PI * r[0] * r[1] * r[2];
    return ns_shape_ellipsoid(c, r);
}

/* Two overlapping spheres: the union has a concave crease where the spheres meet. */
static NsShape *make_union(uint32_t *seed, double *volume)
{
    double r1 = 0.012 + 0.006 * rnd(seed), r2 = r1 * (0.6 + 0.3 * rnd(seed));
    double c1[3] = {0.01 * rnd(seed), 0.01 * rnd(seed), 0.01 * rnd(seed)};
    double d = 0.9 * r1 + 0.5 * r2 * rnd(seed);
    double c2[3] = {c1[0] + d, c1[1], c1[2]};
    NsShape *k[2] = {ns_shape_sphere(c1, r1), ns_shape_sphere(c2, r2)};
    NsShape *s = ns_shape_union(k, 2);
    ns_shape_release(k[0]);
    ns_shape_release(k[1]);
    /* the lens where they overlap is counted once */
    double lens = PI * pow(r1 + r2 - d, 2) *
                  (d * d + 2 * d * r2 - 3 * r2 * r2 + 2 * d * r1 + 6 * r1 * r2 - 3 * r1 * r1) /
                  (12 * d);
    *volume = 4.0 / 3.0 * PI * (r1 * r1 * r1 + r2 * r2 * r2) - lens;
    return s;
}

/* A sphere with a bite taken out of it: a concave spherical dent with a sharp rim. */
static NsShape *make_bitten(uint32_t *seed, double *volume)
{
    double r1 = 0.014 + 0.006 * rnd(seed), r2 = r1 * (0.5 + 0.3 * rnd(seed));
    double c1[3] = {0.01 * rnd(seed), 0.01 * rnd(seed), 0.01 * rnd(seed)};
    double d = 0.8 * r1;
    double c2[3] = {c1[0] + d, c1[1] + 0.2 * r1 * rnd(seed), c1[2]};
    d = sqrt((c2[0] - c1[0]) * (c2[0] - c1[0]) + (c2[1] - c1[1]) * (c2[1] - c1[1]));
    NsShape *a = ns_shape_sphere(c1, r1), *b = ns_shape_sphere(c2, r2);
    NsShape *s = ns_shape_difference(a, b);
    ns_shape_release(a);
    ns_shape_release(b);
    double lens = PI * pow(r1 + r2 - d, 2) *
                  (d * d + 2 * d * r2 - 3 * r2 * r2 + 2 * d * r1 + 6 * r1 * r2 - 3 * r1 * r1) /
                  (12 * d);
    *volume = 4.0 / 3.0 * PI * r1 * r1 * r1 - lens;
    return s;
}

/* A box turned by a random rotation, so its edges and corners cut across the lattice. */
static NsShape *make_box(uint32_t *seed, double *volume)
{
    double c[3] = {0, 0, 0};
    double size[3] = {0.02 + 0.01 * rnd(seed), 0.015 + 0.01 * rnd(seed), 0.01 + 0.01 * rnd(seed)};
    NsShape *box = ns_shape_box(c, size);
    double ax[3] = {rnd(seed) - 0.5, rnd(seed) - 0.5, rnd(seed) - 0.5};
    double n = sqrt(ax[0] * ax[0] + ax[1] * ax[1] + ax[2] * ax[2]);
    for (int i = 0; i < 3; i++)
        ax[i] /= n;
    double th = PI * rnd(seed), cs = cos(th), sn = sin(th), R[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            R[3 * i + j] = (i == j ? cs : 0.0) + (1 - cs) * ax[i] * ax[j];
    R[1] -= sn * ax[2], R[2] += sn * ax[1], R[3] += sn * ax[2];
    R[5] -= sn * ax[0], R[6] -= sn * ax[1], R[7] += sn * ax[0];
    double t[3] = {0.01 * rnd(seed), 0.01 * rnd(seed), 0.01 * rnd(seed)};
    NsShape *s = ns_shape_transform(box, R, t, 1.0);
    ns_shape_release(box);
    *volume = size[0] * size[1] * size[2];
    return s;
}

/* Meshes `variants` shapes from make(), each at a random spacing and lattice offset, and checks
 * L&S's bound and conformity on every one. Returns the worst volume error through vol_err. */
static int guarantee(const char *name, MakeShape make, uint32_t seed, int variants, double *vol_err)
{
    double lo_dih = 180, hi_dih = 0, worst = 0;
    long tets = 0;
    for (int v = 0; v < variants; v++) {
        double volume;
        NsShape *s = make(&seed, &volume);
        ENSURE(s);
        NsMesherRegion region = {s, false};
        NsMesherDef def = ns_default_mesher_def();
        def.spacing = 0.0015 + 0.0035 * rnd(&seed);
        def.regions = &region;
        def.region_count = 1;
        /* shift the lattice by a random fraction of a cell along each axis */
        ENSURE(ns_shape_bounds(s, def.lo, def.hi));
        for (int a = 0; a < 3; a++)
            def.lo[a] -= def.spacing * rnd(&seed);
        NsMesh m;
        ns_mesh_init(&m);
        NsMesherStats st;
        char err[256];
        ENSURE(ns_mesher_stuff(&def, &m, &st, err, sizeof err) == 0);
        Report r;
        inspect(&m, &r);
        if (r.min_dih < MIN_DIHEDRAL || r.max_dih > MAX_DIHEDRAL)
            fprintf(stderr, "%s variant %d (h = %g): dihedrals [%.3f, %.3f]\n", name, v,
                    def.spacing, r.min_dih, r.max_dih);
        ENSURE(r.min_dih >= MIN_DIHEDRAL && r.max_dih <= MAX_DIHEDRAL);
        if (ensure_sound(&r))
            return 1;
        ENSURE(st.junction_tets == 0);
        ENSURE(r.volume[0] == r.total_volume);
        lo_dih = fmin(lo_dih, r.min_dih);
        hi_dih = fmax(hi_dih, r.max_dih);
        worst = fmax(worst, fabs(r.total_volume / volume - 1));
        tets += r.tets;
        ns_mesh_free(&m);
        ns_shape_release(s);
    }
    printf("# %-10s %2d meshes, %7ld tets: dihedrals [%.2f, %.2f] deg, worst volume error "
           "%.1f%%\n",
           name, variants, tets, lo_dih, hi_dih, 100 * worst);
    if (vol_err)
        *vol_err = worst;
    return 0;
}

static int test_guarantee_sphere(void)
{
    return guarantee("sphere", make_sphere, 101, 16, NULL);
}

static int test_guarantee_ellipsoid(void)
{
    return guarantee("ellipsoid", make_ellipsoid, 202, 16, NULL);
}

static int test_guarantee_union(void)
{
    return guarantee("union", make_union, 303, 16, NULL);
}

static int test_guarantee_bitten(void)
{
    return guarantee("difference", make_bitten, 404, 16, NULL);
}

/* Sharp features. The angle bound is a property of the stencils and of warping, not of the
 * surface, so it holds for a box turned across the lattice too (asserted). What suffers is
 * fidelity: the box's edges and corners are not lattice features, so they come out bevelled
 * (cut points and warped vertices lie on the faces, not on the edges) and the volume comes out
 * short: up to about 13% for boxes 2 to 5 cells across (measured over 300 boxes). */
static int test_guarantee_box(void)
{
    double err;
    if (guarantee("box", make_box, 505, 16, &err))
        return 1;
    ENSURE(err < 0.15);
    return 0;
}

/* Volume at a fine resolution (radius / spacing about 10): the lattice error is small. */
static int test_volume(void)
{
    double c[3] = {0.001, -0.002, 0.0005}, r[3] = {0.02, 0.014, 0.01};
    NsShape *shapes[2] = {ns_shape_sphere(c, 0.02), ns_shape_ellipsoid(c, r)};
    double volumes[2] = {4.0 / 3.0 * PI * 0.02 * 0.02 * 0.02, 4.0 / 3.0 * PI * r[0] * r[1] * r[2]};
    for (int i = 0; i < 2; i++) {
        NsMesherRegion region = {shapes[i], false};
        NsMesherDef def = ns_default_mesher_def();
        def.spacing = 0.002;
        def.regions = &region;
        def.region_count = 1;
        NsMesh m;
        ns_mesh_init(&m);
        char err[256];
        ENSURE(ns_mesher_stuff(&def, &m, NULL, err, sizeof err) == 0);
        Report rep;
        inspect(&m, &rep);
        if (ensure_sound(&rep))
            return 1;
        double e = rep.total_volume / volumes[i] - 1;
        printf("# volume %s: %d tets, error %+.2f%%\n", i ? "ellipsoid" : "sphere", rep.tets,
               100 * e);
        ENSURE(fabs(e) < 0.02);
        ns_mesh_free(&m);
        ns_shape_release(shapes[i]);
    }
    return 0;
}

/* A box whose faces lie on lattice planes is meshed exactly: flat faces, exact volume. */
static int test_aligned_box(void)
{
    double h = 0.004, c[3] = {0.02, 0.014, 0.01}, size[3] = {0.04, 0.028, 0.02};
    NsShape *s = ns_shape_box(c, size);
    NsMesherRegion region = {s, false};
    NsMesherDef def = ns_default_mesher_def();
    def.spacing = h;
    def.regions = &region;
    def.region_count = 1;
    NsMesh m;
    ns_mesh_init(&m);
    char err[256];
    ENSURE(ns_mesher_stuff(&def, &m, NULL, err, sizeof err) == 0);
    Report r;
    inspect(&m, &r);
    if (ensure_sound(&r))
        return 1;
    ENSURE_SMALL(r.total_volume / (size[0] * size[1] * size[2]) - 1, 1e-12);
    for (int i = 0; i < m.node_slots; i++)
        if (m.flags[i] & NS_NODE_BOUNDARY)
            ENSURE_SMALL(box_sdf(c, size, m.u + 3 * i), 1e-15);
    /* Every pair of neighbouring cube centres with at least one inside the box gives 4 tets
     * (whole, or halved by the face between the centres): 4 sum_a (n_a + 1) n_b n_c. */
    ENSURE(r.tets == 4 * (11 * 7 * 5 + 8 * 10 * 5 + 6 * 10 * 7));
    printf("# aligned box: %d tets, dihedrals [%.2f, %.2f] deg\n", r.tets, r.min_dih, r.max_dih);
    ns_mesh_free(&m);
    ns_shape_release(s);
    return 0;
}

/* ---- several regions ------------------------------------------------------------------------ */

typedef struct Multi {
    NsShape *shape[3];
    NsMesherRegion region[3];
    int count;
    double box_c[3], box_size[3];
    double h;
} Multi;

static int label_at(const Multi *mu, const double p[3])
{
    for (int r = mu->count - 1; r >= 0; r--)
        if (ns_shape_eval(mu->shape[r], p) <= 0)
            return r;
    return -1;
}

/* The checks for a multi-region mesh inside a lattice-aligned box (region 0):
 * - the outer boundary is the box and nothing else, so every face inside it is shared by two
 *   tets: interfaces between regions are conforming, with no cracks;
 * - the regions tile the box exactly (total volume = box volume);
 * - most tets' centroids lie in their own region (cut tets straddle by at most a sliver);
 * - NS_NODE_FIXED is set exactly on the nodes of fixed regions' tets. */
static int check_multi(const Multi *mu, NsMesh *m, Report *r, double *agree)
{
    inspect(m, r);
    if (ensure_sound(r))
        return 1;
    for (int t = 0; t < m->tet_slots; t++)
        for (int k = 0; k < 4; k++) {
            if (m->tet_adj[4 * t + k] >= 0)
                continue;
            for (int j = 0; j < 3; j++)
                ENSURE_SMALL(box_sdf(mu->box_c, mu->box_size, node(m, t, ns_tet_face[k][j])),
                             1e-12);
        }
    double box_volume = mu->box_size[0] * mu->box_size[1] * mu->box_size[2];
    ENSURE_SMALL(r->total_volume / box_volume - 1, 1e-12);
    int good = 0;
    for (int t = 0; t < m->tet_slots; t++) {
        double g[3] = {0, 0, 0};
        for (int k = 0; k < 4; k++)
            for (int a = 0; a < 3; a++)
                g[a] += 0.25 * node(m, t, k)[a];
        good += label_at(mu, g) == m->tet_region[t];
    }
    *agree = (double)good / m->tet_alive;
    ENSURE(*agree >= 0.95);
    uint8_t *want = calloc((size_t)m->node_slots, 1);
    ENSURE(want);
    for (int t = 0; t < m->tet_slots; t++)
        if (mu->region[m->tet_region[t]].fixed)
            for (int k = 0; k < 4; k++)
                want[m->tet_node[4 * t + k]] = 1;
    int mismatched = 0;
    for (int i = 0; i < m->node_slots; i++)
        mismatched += want[i] != ((m->flags[i] & NS_NODE_FIXED) != 0);
    free(want);
    ENSURE(mismatched == 0);
    return 0;
}

/* A box (region 0) anchored on the lattice with one or two spheres inside it; the second
 * sphere's gap to the first is in units of the spacing (at most 0). */
static void make_multi(Multi *mu, uint32_t *seed, int spheres, double gap, double vol[3])
{
    memset(mu, 0, sizeof *mu);
    mu->h = 0.002 + 0.002 * rnd(seed);
    /* The spheres stay at least 1.5 h inside the box: where two interfaces come within a
     * lattice cell of each other a vertex warped onto one is also a vertex of the other, and
     * the box's faces would no longer be exactly flat there (docs/mesher.md). */
    double n[3] = {16, 12, 12};
    for (int a = 0; a < 3; a++) {
        mu->box_size[a] = n[a] * mu->h;
        mu->box_c[a] = 0.5 * mu->box_size[a];
    }
    mu->shape[0] = ns_shape_box(mu->box_c, mu->box_size);
    double r1 = (2.2 + 1.3 * rnd(seed)) * mu->h;
    double c1[3] = {(5.0 + rnd(seed)) * mu->h, (5.5 + rnd(seed)) * mu->h,
                    (5.5 + rnd(seed)) * mu->h};
    mu->shape[1] = ns_shape_sphere(c1, r1);
    double v1 = 4.0 / 3.0 * PI * r1 * r1 * r1;
    mu->count = 2;
    vol[1] = v1;
    vol[2] = 0;
    if (spheres == 2) {
        /* a second sphere beside the first: overlapping (gap < 0: it paints over the first)
         * or just touching (gap = 0) */
        double r2 = (1.8 + 0.6 * rnd(seed)) * mu->h, d = r1 + r2 + gap * mu->h;
        double c2[3] = {c1[0] + d, c1[1], c1[2]};
        mu->shape[2] = ns_shape_sphere(c2, r2);
        mu->count = 3;
        double lens = 0;
        if (d < r1 + r2)
            lens = PI * pow(r1 + r2 - d, 2) *
                   (d * d + 2 * d * r2 - 3 * r2 * r2 + 2 * d * r1 + 6 * r1 * r2 - 3 * r1 * r1) /
                   (12 * d);
        vol[2] = 4.0 / 3.0 * PI * r2 * r2 * r2;
        vol[1] = v1 - lens;
    }
    vol[0] = mu->box_size[0] * mu->box_size[1] * mu->box_size[2] - vol[1] - vol[2];
    for (int i = 0; i < mu->count; i++) {
        mu->region[i].shape = mu->shape[i];
        mu->region[i].fixed = i == 1; /* the first sphere is bone */
    }
}

static void free_multi(Multi *mu)
{
    for (int i = 0; i < mu->count; i++)
        ns_shape_release(mu->shape[i]);
}

static int stuff_multi(const Multi *mu, NsMesh *m, NsMesherStats *st)
{
    NsMesherDef def = ns_default_mesher_def();
    def.spacing = mu->h;
    def.regions = mu->region;
    def.region_count = mu->count;
    char err[256];
    ns_mesh_init(m);
    int rc = ns_mesher_stuff(&def, m, st, err, sizeof err);
    if (rc)
        fprintf(stderr, "mesher: %s\n", err);
    return rc;
}

/* One sphere in a box: two-sided stuffing only (no junctions), so L&S's bound must hold. */
static int test_multi_sphere_in_box(void)
{
    uint32_t seed = 606;
    double lo_dih = 180, hi_dih = 0, worst_agree = 1, worst_vol = 0;
    long tets = 0;
    for (int v = 0; v < 12; v++) {
        Multi mu;
        double vol[3];
        make_multi(&mu, &seed, 1, 0, vol);
        NsMesh m;
        NsMesherStats st;
        ENSURE(stuff_multi(&mu, &m, &st) == 0);
        Report r;
        double agree;
        if (check_multi(&mu, &m, &r, &agree))
            return 1;
        ENSURE(st.junction_tets == 0);
        if (r.min_dih < MIN_DIHEDRAL || r.max_dih > MAX_DIHEDRAL)
            fprintf(stderr, "variant %d: dihedrals [%.3f, %.3f]\n", v, r.min_dih, r.max_dih);
        ENSURE(r.min_dih >= MIN_DIHEDRAL && r.max_dih <= MAX_DIHEDRAL);
        for (int i = 0; i < 2; i++) {
            double e = r.volume[i] / vol[i] - 1;
            worst_vol = fmax(worst_vol, fabs(e));
            ENSURE(fabs(e) < 0.10);
        }
        lo_dih = fmin(lo_dih, r.min_dih);
        hi_dih = fmax(hi_dih, r.max_dih);
        worst_agree = fmin(worst_agree, agree);
        tets += r.tets;
        ns_mesh_free(&m);
        free_multi(&mu);
    }
    printf("# sphere in box: 12 meshes, %ld tets: dihedrals [%.2f, %.2f] deg, worst region "
           "volume error %.1f%%, centroid in own region >= %.1f%%\n",
           tets, lo_dih, hi_dih, 100 * worst_vol, 100 * worst_agree);
    return 0;
}

/* Two spheres in a box, overlapping or touching: lattice tets with three labels take the
 * junction fallback, which has no proven bound; we measured >= 10 degrees and assert 5. */
static int test_multi_junctions(void)
{
    uint32_t seed = 707;
    double lo_dih = 180, hi_dih = 0, worst_agree = 1, worst_vol = 0;
    long tets = 0, junctions = 0;
    for (int v = 0; v < 12; v++) {
        Multi mu;
        double vol[3];
        make_multi(&mu, &seed, 2, v % 2 ? 0.0 : -0.5, vol);
        NsMesh m;
        NsMesherStats st;
        ENSURE(stuff_multi(&mu, &m, &st) == 0);
        Report r;
        double agree;
        if (check_multi(&mu, &m, &r, &agree))
            return 1;
        ENSURE(r.min_dih >= 5.0 && r.max_dih <= 175.0);
        for (int i = 0; i < 3; i++) {
            double e = r.volume[i] / vol[i] - 1;
            worst_vol = fmax(worst_vol, fabs(e));
            ENSURE(fabs(e) < 0.12);
        }
        lo_dih = fmin(lo_dih, r.min_dih);
        hi_dih = fmax(hi_dih, r.max_dih);
        worst_agree = fmin(worst_agree, agree);
        tets += r.tets;
        junctions += st.junction_tets;
        ns_mesh_free(&m);
        free_multi(&mu);
    }
    ENSURE(junctions > 0);
    printf("# two spheres in box: 12 meshes, %ld tets, %ld junction lattice tets: dihedrals "
           "[%.2f, %.2f] deg, worst region volume error %.1f%%, centroid in own region >= "
           "%.1f%%\n",
           tets, junctions, lo_dih, hi_dih, 100 * worst_vol, 100 * worst_agree);
    return 0;
}

/* Many random two-region configurations (sphere in box at random offsets): the two sides of
 * every ++-- wedge must split the interface quad with the same diagonal, or the interface
 * would show up as boundary faces inside the box (check_multi). */
static int test_interface_conformity(void)
{
    uint32_t seed = 808;
    for (int v = 0; v < 40; v++) {
        Multi mu;
        double vol[3];
        make_multi(&mu, &seed, v % 4 == 3 ? 2 : 1, -0.3, vol);
        NsMesh m;
        NsMesherStats st;
        ENSURE(stuff_multi(&mu, &m, &st) == 0);
        Report r;
        double agree;
        if (check_multi(&mu, &m, &r, &agree))
            return 1;
        ns_mesh_free(&m);
        free_multi(&mu);
    }
    return 0;
}

static int test_determinism(void)
{
    uint32_t s1 = 909, s2 = 909;
    Multi a, b;
    double vol[3];
    make_multi(&a, &s1, 2, -0.4, vol);
    make_multi(&b, &s2, 2, -0.4, vol);
    NsMesh ma, mb;
    ENSURE(stuff_multi(&a, &ma, NULL) == 0);
    ENSURE(stuff_multi(&b, &mb, NULL) == 0);
    ENSURE(ma.node_slots == mb.node_slots && ma.tet_slots == mb.tet_slots);
    ENSURE(memcmp(ma.u, mb.u, 3 * sizeof(double) * (size_t)ma.node_slots) == 0);
    ENSURE(memcmp(ma.flags, mb.flags, (size_t)ma.node_slots) == 0);
    ENSURE(memcmp(ma.tet_node, mb.tet_node, 4 * sizeof(int) * (size_t)ma.tet_slots) == 0);
    ENSURE(memcmp(ma.tet_region, mb.tet_region, sizeof(int) * (size_t)ma.tet_slots) == 0);
    ENSURE(ns_mesh_topology_hash(&ma) == ns_mesh_topology_hash(&mb));
    ns_mesh_free(&ma);
    ns_mesh_free(&mb);
    free_multi(&a);
    free_multi(&b);
    return 0;
}

static int test_stats(void)
{
    double c[3] = {0, 0, 0};
    NsShape *s = ns_shape_sphere(c, 0.02);
    NsMesherRegion region = {s, false};
    NsMesherDef def = ns_default_mesher_def();
    ENSURE(def.spacing == 0 && def.alpha_long == 0.24999 && def.alpha_short == 0.41189);
    def.spacing = 0.004;
    def.regions = &region;
    def.region_count = 1;
    NsMesh m;
    ns_mesh_init(&m);
    NsMesherStats st;
    char err[256];
    ENSURE(ns_mesher_stuff(&def, &m, &st, err, sizeof err) == 0);
    ENSURE(st.lattice_vertices > 0 && st.warped_vertices > 0 && st.cut_points > 0);
    ENSURE(st.junction_tets == 0);
    /* compact: nodes and tets numbered densely */
    ENSURE(m.node_slots == m.node_alive && m.tet_slots == m.tet_alive);
    for (int i = 0; i < m.node_slots; i++)
        ENSURE(!(m.flags[i] & NS_NODE_FIXED));
    ns_mesh_free(&m);
    ns_shape_release(s);
    return 0;
}

/* ---- errors --------------------------------------------------------------------------------- */

static double nan_shape(void *user, const double p[3])
{
    (void)user;
    return p[0] > 0.01 ? NAN : p[0] - 0.02;
}

static int expect_error(const NsMesherDef *def, const char *needle)
{
    NsMesh m;
    ns_mesh_init(&m);
    char err[256] = "";
    ENSURE(ns_mesher_stuff(def, &m, NULL, err, sizeof err) == -1);
    if (!strstr(err, needle))
        fprintf(stderr, "error \"%s\" lacks \"%s\"\n", err, needle);
    ENSURE(strstr(err, needle) != NULL);
    ENSURE(m.tet_alive == 0 && m.node_alive == 0);
    ns_mesh_free(&m);
    return 0;
}

static int test_errors(void)
{
    double c[3] = {0, 0, 0}, lo[3] = {-0.03, -0.03, -0.03}, hi[3] = {0.03, 0.03, 0.03};
    NsShape *nan = ns_shape_callback(nan_shape, NULL, lo, hi);
    NsShape *sphere = ns_shape_sphere(c, 0.02);
    NsMesherRegion region = {nan, false};
    NsMesherDef def = ns_default_mesher_def();
    def.spacing = 0.004;
    def.regions = &region;
    def.region_count = 1;
    if (expect_error(&def, "shape evaluated to NaN at ("))
        return 1;

    region.shape = sphere;
    def.spacing = 0;
    if (expect_error(&def, "spacing"))
        return 1;
    def.spacing = -1;
    if (expect_error(&def, "spacing"))
        return 1;
    def.spacing = 0.004;
    def.region_count = 0;
    if (expect_error(&def, "no regions"))
        return 1;
    def.region_count = 1;
    def.spacing = 1e-5; /* 4000^3 cells */
    if (expect_error(&def, "lattice vertices"))
        return 1;
    def.spacing = 0.004;
    region.shape = NULL;
    if (expect_error(&def, "region 0"))
        return 1;
    /* a sphere far smaller than the spacing, between lattice vertices: nothing to mesh */
    double off[3] = {0.0021, 0.0019, 0.0023};
    NsShape *small = ns_shape_sphere(off, 1e-4);
    region.shape = small;
    if (expect_error(&def, "the regions produced no tets (resolution too coarse?)"))
        return 1;
    ns_shape_release(nan);
    ns_shape_release(sphere);
    ns_shape_release(small);
    return 0;
}

NS_TEST_MAIN({"guarantee_sphere", test_guarantee_sphere},
             {"guarantee_ellipsoid", test_guarantee_ellipsoid},
             {"guarantee_union", test_guarantee_union},
             {"guarantee_difference", test_guarantee_bitten}, {"guarantee_box", test_guarantee_box},
             {"volume", test_volume}, {"aligned_box", test_aligned_box},
             {"multi_sphere_in_box", test_multi_sphere_in_box},
             {"multi_junctions", test_multi_junctions},
             {"interface_conformity", test_interface_conformity}, {"determinism", test_determinism},
             {"stats", test_stats}, {"errors", test_errors})
