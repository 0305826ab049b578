/* render/: the cutaway scene and the GL renderer, checked on pixels (issue 8). A known scene
 * (a two-region block cut through its middle, a straight needle along x, one target hit and
 * one missed) is drawn through EGL (llvmpipe here) and the frame is read back: the needle's
 * colour lies along its projected line, each region's colour fills its part of the cut face,
 * the hit target is green and the missed one red, and two renders are byte-identical. No
 * stored image is compared (Mesa versions differ). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "coupling.h"
#include "frame.h"
#include "mesh_grid.h"
#include "ns_test.h"
#include "scene.h"
#include "trus.h"

typedef struct Block {
    NsMesh mesh;
    double rod[12 * 3];
    uint8_t state[12];
    double target_x[6], target_r[2];
    bool hit[2];
    NsSceneInput in;
} Block;

/* A 40 x 20 x 20 mm block, region 1 where x > 20 mm; the needle along x through its centre
 * line from -10 mm to 25 mm, sticking; a hit target ahead of the tip, a missed one below. */
static int block_init(Block *b)
{
    memset(b, 0, sizeof *b);
    double lo[3] = {0.0, -0.01, -0.01}, hi[3] = {0.04, 0.01, 0.01};
    char err[256];
    if (ns_mesh_grid_box(&b->mesh, lo, hi, 8, 4, 4, 0, err, sizeof err)) {
        fprintf(stderr, "%s\n", err);
        return -1;
    }
    for (int e = 0; e < b->mesh.tet_slots; e++) {
        double cx = 0.0;
        for (int k = 0; k < 4; k++)
            cx += 0.25 * b->mesh.x[3 * b->mesh.tet_node[4 * e + k]];
        b->mesh.tet_region[e] = cx > 0.02 ? 1 : 0;
    }
    for (int k = 0; k < 12; k++) {
        b->rod[3 * k] = -0.01 + 0.035 * k / 11.0;
        b->state[k] = NS_FRICTION_STATIC;
    }
    double t[6] = {0.032, 0.0, 0.0, 0.012, 0.0, -0.006};
    memcpy(b->target_x, t, sizeof t);
    b->target_r[0] = b->target_r[1] = 0.003;
    b->hit[0] = true;
    NsSceneInput *in = &b->in;
    in->mesh = &b->mesh;
    in->regions = 2;
    in->rod_x = b->rod;
    in->rod_nodes = 12;
    in->rod_radius = 0.4e-3;
    in->state = b->state;
    in->held = 2;
    in->target_x = b->target_x;
    in->target_r = b->target_r;
    in->target_hit = b->hit;
    in->targets = 2;
    in->axis[0] = 1.0;
    memcpy(in->bounds, lo, sizeof lo);
    memcpy(in->bounds + 3, hi, sizeof hi);
    return 0;
}

static const uint8_t *pixel(const NsImage *im, const NsCamera *cam, int w, int h, int x0,
                            const double p[3])
{
    double px[2];
    if (!ns_camera_project(cam, w, h, p, px))
        return NULL;
    int x = x0 + (int)floor(px[0]), y = (int)floor(px[1]);
    if (x < 0 || y < 0 || x >= im->w || y >= im->h)
        return NULL;
    return im->rgb + 3 * ((size_t)y * im->w + x);
}

static int near_rgb(const uint8_t *p, const uint8_t *c, int tol)
{
    return p && abs(p[0] - c[0]) <= tol && abs(p[1] - c[1]) <= tol && abs(p[2] - c[2]) <= tol;
}

/* The scene alone: the side view's plane holds the axis and faces the camera; the cap has a
 * piece for every tet the plane crosses and lies in the plane. */
static int scene_cut_in_plane(void)
{
    Block b;
    ENSURE(block_init(&b) == 0);
    NsScene s;
    memset(&s, 0, sizeof s);
    ENSURE(ns_scene_build(&b.in, NS_VIEW_SIDE, 16.0 / 9.0, &s) == 0);
    double f[3];
    for (int i = 0; i < 3; i++)
        f[i] = s.camera.target[i] - s.camera.eye[i];
    ENSURE_SMALL(s.plane[0], 1e-12);                                         /* holds the x axis */
    ENSURE(s.plane[0] * f[0] + s.plane[1] * f[1] + s.plane[2] * f[2] < 0.0); /* faces the eye */
    ENSURE(s.cap.n > 0 && s.cap.n % 3 == 0);
    for (int k = 0; k < s.cap.n; k++) {
        const float *p = s.cap.v[k].p;
        ENSURE_SMALL(s.plane[0] * p[0] + s.plane[1] * p[1] + s.plane[2] * p[2] + s.plane[3], 1e-7);
    }
    ENSURE(s.glass.n > 0 && s.solid.n > 0 && s.edges.n == 0); /* tet_edges off */
    b.in.tet_edges = true;
    ENSURE(ns_scene_build(&b.in, NS_VIEW_SIDE, 16.0 / 9.0, &s) == 0);
    ENSURE(s.edges.n > 0 && s.edges.n % 2 == 0);
    ns_scene_free(&s);
    ns_mesh_free(&b.mesh);
    return 0;
}

/* An isotropic made-up dose from the one seed, K / |p - seed|^2: its level line K / R^2 on the
 * cut face is the circle of radius R round the seed's trace on the plane. */
static int inverse_square(void *ctx, const double *seed_x, int seeds, const double *pts, long n,
                          double *out)
{
    (void)ctx;
    for (long i = 0; i < n; i++) {
        double d2 = 0.0;
        for (int c = 0; c < 3; c++)
            d2 += (pts[3 * i + c] - seed_x[c]) * (pts[3 * i + c] - seed_x[c]);
        out[i] = seeds > 0 ? 1.0 / fmax(d2, 1e-12) : 0.0;
    }
    return 0;
}

/* The isodose lines lie in the cut plane, in their level's colour, on the level's circle
 * within a grid cell (the grid: 120 cells across the 40 mm box, 0.33 mm), all round it. */
static int isodose_lines_on_their_level(void)
{
    Block b;
    ENSURE(block_init(&b) == 0);
    double seed[3] = {0.015, 0.0, 0.0};
    b.in.seed_x = seed;
    b.in.seeds = 1;
    b.in.dose_points = inverse_square;
    b.in.iso_levels[0] = 1.0 / (0.006 * 0.006); /* R = 6 mm */
    b.in.iso_levels[1] = 1.0 / (0.003 * 0.003); /* R = 3 mm */
    b.in.iso_count = 2;
    b.in.px_size = 1e-5;
    NsScene s;
    memset(&s, 0, sizeof s);
    ENSURE(ns_scene_build(&b.in, NS_VIEW_SIDE, 16.0 / 9.0, &s) == 0);
    int count[2] = {0, 0}, quadrant[2][4] = {{0}};
    for (int k = 0; k < s.edges.n; k++) {
        const NsVertex *v = &s.edges.v[k];
        int lvl = -1;
        for (int q = 0; q < 2; q++)
            if (memcmp(v->rgba, ns_scene_iso_rgb[q], 3) == 0)
                lvl = q;
        ENSURE(lvl >= 0); /* tet edges are off: every line is an isodose */
        double d[3] = {v->p[0] - seed[0], v->p[1] - seed[1], v->p[2] - seed[2]};
        ENSURE_SMALL(
            s.plane[0] * v->p[0] + s.plane[1] * v->p[1] + s.plane[2] * v->p[2] + s.plane[3], 1e-6);
        double R = lvl == 0 ? 0.006 : 0.003, r = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        ENSURE_SMALL(r - R, 0.34e-3);
        count[lvl]++;
        quadrant[lvl][(d[0] > 0) + 2 * (d[1] + d[2] > 0)]++;
    }
    for (int q = 0; q < 2; q++) {
        ENSURE(count[q] > 20);
        for (int k = 0; k < 4; k++)
            ENSURE(quadrant[q][k] > 0); /* the whole circle, not an arc */
    }
    b.in.seeds = 0; /* no seed: no lines */
    ENSURE(ns_scene_build(&b.in, NS_VIEW_SIDE, 16.0 / 9.0, &s) == 0);
    ENSURE(s.edges.n == 0);
    ns_scene_free(&s);
    ns_mesh_free(&b.mesh);
    return 0;
}

static int render_view(Block *b, NsFrame *f, NsImage *im, bool hud, NsView view)
{
    char err[256];
    int views[1] = {view};
    const char *lines[2] = {"test scene", "t 0.00 s"};
    if (ns_frame_render(f, &b->in, views, 1, lines, hud ? 2 : 0, false, im, err, sizeof err)) {
        fprintf(stderr, "%s\n", err);
        return -1;
    }
    return 0;
}

static int render_block(Block *b, NsFrame *f, NsImage *im, bool hud)
{
    return render_view(b, f, im, hud, NS_VIEW_SIDE);
}

static bool needle_blue(const uint8_t *c)
{
    return c && c[2] > c[0] + 60 && c[2] > c[1] + 20;
}

/* Geometry, not just pixels (issue 39): in the side view and in cutaway3d (perspective, from
 * above and ahead at an angle) the needle's drawn tip lies within 3 pixels of the simulated tip
 * projected by the view's camera, and the hit target is drawn green where it is. Walking out
 * along the needle's projected line from 10 pixels behind the tip, the last needle-coloured
 * pixel (of the line or a pixel either side) is the drawn tip. */
/* The block and a w x h renderer (samples a pixel: 1 is the runs' default, edges smoothed);
 * 0, or -1 with a message. */
static int open_block_samples(Block *b, NsFrame *f, int w, int h, int samples)
{
    char err[256];
    if (block_init(b) != 0)
        return -1;
    if (ns_frame_open_samples(f, w, h, samples, err, sizeof err)) {
        fprintf(stderr, "%s\n", err);
        ns_mesh_free(&b->mesh);
        return -1;
    }
    return 0;
}

static int open_block(Block *b, NsFrame *f, int w, int h)
{
    return open_block_samples(b, f, w, h, 4);
}

/* With 4 samples a pixel, and with 1 and the edges smoothed (needlesim run's default). */
static int tip_where_simulated(void)
{
    for (int samples = 4; samples >= 1; samples -= 3) {
        printf("  %d sample(s) a pixel\n", samples);
        Block b;
        NsFrame f;
        int w = 640, h = 360;
        ENSURE(open_block_samples(&b, &f, w, h, samples) == 0);
        NsImage im = {0};
        const NsView views[2] = {NS_VIEW_SIDE, NS_VIEW_CUTAWAY3D};
        for (int v = 0; v < 2; v++) {
            ENSURE(render_view(&b, &f, &im, false, views[v]) == 0);
            NsCamera cam;
            ns_scene_camera(&b.in, views[v], (double)w / h, &cam);
            const double *tip = b.rod + 3 * 11;
            double back[3] = {tip[0] - 0.005, tip[1], tip[2]}, pt[2], pb[2];
            ENSURE(ns_camera_project(&cam, w, h, tip, pt) &&
                   ns_camera_project(&cam, w, h, back, pb));
            double d[2] = {pt[0] - pb[0], pt[1] - pb[1]}, len = hypot(d[0], d[1]);
            ENSURE(len > 5.0);
            d[0] /= len;
            d[1] /= len;
            double last = -100.0;
            for (double s = -10.0; s <= 15.0; s += 0.25)
                for (int side = -1; side <= 1; side++) {
                    int x = (int)floor(pt[0] + s * d[0] - side * d[1]);
                    int y = (int)floor(pt[1] + s * d[1] + side * d[0]);
                    if (x >= 0 && y >= 0 && x < w && y < h &&
                        needle_blue(im.rgb + 3 * ((size_t)y * w + x)))
                        last = s;
                }
            printf("  %s: the drawn tip %.2f px from the simulated one along the needle\n",
                   ns_view_name(views[v]), last);
            ENSURE(fabs(last) <= 3.0);
            const uint8_t *g = pixel(&im, &cam, w, h, 0, b.target_x);
            ENSURE(g && g[1] > g[0] + 40 && g[1] > g[2] + 40);
        }
        ns_image_free(&im);
        ns_frame_close(&f);
        ns_mesh_free(&b.mesh);
    }
    return 0;
}

/* The smoothing of 1-sample frames: a hard edge's pixels take half their neighbours' across
 * it, a flat area and the columns outside are untouched. */
static int smooth_edges_blend_across(void)
{
    char err[128];
    NsImage im = {0};
    ENSURE(ns_image_alloc(&im, 8, 6, err, sizeof err) == 0);
    for (int y = 0; y < 6; y++)
        for (int x = 0; x < 8; x++)
            memset(im.rgb + 3 * (y * 8 + x), x >= 4 ? 200 : 40, 3);
    uint8_t scratch[8 * 6 * 3];
    ns_image_smooth_edges(&im, 1, 6, scratch);
    /* x = 3 (40, its east neighbour 200): (2 * 40 + 200 + 40) / 4 = 80; x = 4: (400 + 240) / 4 */
    for (int y = 1; y < 5; y++) {
        ENSURE(im.rgb[3 * (y * 8 + 3)] == 80 && im.rgb[3 * (y * 8 + 4)] == 160);
        ENSURE(im.rgb[3 * (y * 8 + 2)] == 40 && im.rgb[3 * (y * 8 + 5)] == 200);
    }
    ENSURE(im.rgb[3 * (0 * 8 + 3)] == 40 && im.rgb[3 * (5 * 8 + 4)] == 200); /* edge rows */
    ns_image_smooth_edges(&im, 5, 3, scratch); /* the columns 5..7: flat, unchanged */
    ENSURE(im.rgb[3 * (2 * 8 + 5)] == 200 && im.rgb[3 * (2 * 8 + 6)] == 200);
    ns_image_free(&im);
    return 0;
}

/* The trus view: the needle crossing the image plane (at the tip's depth) is a white dot whose
 * centre lies within 3 pixels of the simulated tip projected by the probe's pose; speckle is
 * fixed in the tissue, so two renders are the same bytes. */
static int trus_tip_where_simulated(void)
{
    Block b;
    NsFrame f;
    int w = 640, h = 360;
    ENSURE(open_block(&b, &f, w, h) == 0);
    NsImage im = {0}, again = {0};
    ENSURE(render_view(&b, &f, &im, false, NS_VIEW_TRUS) == 0);
    ENSURE(render_view(&b, &f, &again, false, NS_VIEW_TRUS) == 0);
    ENSURE(memcmp(im.rgb, again.rgb, (size_t)w * h * 3) == 0);
    NsTrusPose p;
    ns_trus_pose(&b.in, &p);
    double px[2];
    ENSURE(ns_trus_project(&p, w, h, b.rod + 3 * 11, px));
    double sx = 0.0, sy = 0.0;
    int n = 0;
    for (int y = (int)px[1] - 12; y <= (int)px[1] + 12; y++)
        for (int x = (int)px[0] - 12; x <= (int)px[0] + 12; x++)
            if (x >= 0 && y >= 0 && x < w && y < h && im.rgb[3 * ((size_t)y * w + x)] == 255) {
                sx += x + 0.5;
                sy += y + 0.5;
                n++;
            }
    ENSURE(n > 0);
    double off = hypot(sx / n - px[0], sy / n - px[1]);
    printf("  trus: the needle's dot %.2f px from the simulated tip (%d white pixels)\n", off, n);
    ENSURE(off <= 3.0);
    ns_image_free(&im);
    ns_image_free(&again);
    ns_frame_close(&f);
    ns_mesh_free(&b.mesh);
    return 0;
}

static bool plan_blue(const uint8_t *c)
{
    return c && c[1] > c[0] + 30 && c[2] > c[0] + 40 && 10 * c[1] > 7 * c[2];
}

/* The planned path (act.steer's predicted arc) is drawn light blue where it lies, ahead of the
 * tip, and only when given: the pixel of its midpoint in the side view and in cutaway3d, and
 * not the mirror image of that point about the needle's axis. */
static int plan_drawn_where_it_lies(void)
{
    Block b;
    NsFrame f;
    int w = 640, h = 360;
    ENSURE(open_block_samples(&b, &f, w, h, 1) == 0);
    double plan[9 * 3];
    for (int k = 0; k < 9; k++) { /* from the tip (25 mm) 5 mm on, 3 mm aside in y and z */
        double s = k / 8.0;
        plan[3 * k] = 0.025 + 0.005 * s;
        plan[3 * k + 1] = plan[3 * k + 2] = -0.003 * s * s;
    }
    const double mid[3] = {0.0275, -0.00075, -0.00075}, mirror[3] = {0.0275, 0.00075, 0.00075};
    const NsView views[2] = {NS_VIEW_SIDE, NS_VIEW_CUTAWAY3D};
    NsImage im = {0};
    for (int v = 0; v < 2; v++)
        for (int with = 0; with < 2; with++) {
            b.in.plan_x = with ? plan : NULL;
            b.in.plan_n = with ? 9 : 0;
            ENSURE(render_view(&b, &f, &im, false, views[v]) == 0);
            NsCamera cam;
            ns_scene_camera(&b.in, views[v], (double)w / h, &cam);
            const uint8_t *c = pixel(&im, &cam, w, h, 0, mid),
                          *m = pixel(&im, &cam, w, h, 0, mirror);
            printf("  %s, %s the plan: (%d, %d, %d) at its midpoint\n", ns_view_name(views[v]),
                   with ? "with" : "without", c ? c[0] : -1, c ? c[1] : -1, c ? c[2] : -1);
            ENSURE(plan_blue(c) == (with == 1) && !plan_blue(m));
        }
    ns_image_free(&im);
    ns_frame_close(&f);
    ns_mesh_free(&b.mesh);
    return 0;
}

/* A CPU view keeps its column wherever it is: between OpenGL views (drawn after the read-back)
 * and at either end (drawn while OpenGL rasterizes, into the image already sized). The column is
 * trus drawn alone at that size (above the views' names), in a first frame and the next ones,
 * the image reused from layout to layout. */
static int trus_between_gl_views(void)
{
    Block b, b1;
    NsFrame f, f1;
    int vw = 200, h = 240;
    ENSURE(open_block_samples(&b, &f, 3 * vw, h, 1) == 0);
    ENSURE(open_block_samples(&b1, &f1, vw, h, 1) == 0);
    char err[256];
    int layouts[3][3] = {{NS_VIEW_SIDE, NS_VIEW_TRUS, NS_VIEW_SIDE},
                         {NS_VIEW_TRUS, NS_VIEW_SIDE, NS_VIEW_SIDE},
                         {NS_VIEW_SIDE, NS_VIEW_SIDE, NS_VIEW_TRUS}},
        one[1] = {NS_VIEW_TRUS};
    NsImage alone = {0}, im = {0};
    ENSURE(ns_frame_render(&f1, &b1.in, one, 1, NULL, 0, false, &alone, err, sizeof err) == 0);
    for (int l = 0; l < 3; l++)
        for (int pass = 0; pass < 2; pass++) {
            ENSURE(ns_frame_render(&f, &b.in, layouts[l], 3, NULL, 0, false, &im, err,
                                   sizeof err) == 0);
            int k = l == 0 ? 1 : l == 1 ? 0 : 2, differ = 0;
            for (int y = 0; y < h * 3 / 4; y++)
                differ += memcmp(im.rgb + 3 * ((size_t)y * 3 * vw + (size_t)k * vw),
                                 alone.rgb + 3 * (size_t)y * vw, 3 * (size_t)vw) != 0;
            printf("  trus as view %d of 3, frame %d: %d rows differ from trus alone\n", k + 1,
                   pass + 1, differ);
            ENSURE(differ == 0);
        }
    ns_image_free(&im);
    ns_image_free(&alone);
    ns_frame_close(&f);
    ns_frame_close(&f1);
    ns_mesh_free(&b.mesh);
    ns_mesh_free(&b1.mesh);
    return 0;
}

static int pixels_show_the_scene(void)
{
    Block b;
    NsFrame f;
    char err[256];
    int w = 640, h = 360;
    ENSURE(open_block(&b, &f, w, h) == 0);
    printf("  %s\n", ns_renderer_info(f.gl));
    NsImage im = {0}, again = {0};
    ENSURE(render_block(&b, &f, &im, false) == 0);
    if (getenv("NS_TEST_PNG")) /* a look at the frame */
        ns_image_write_png(&im, getenv("NS_TEST_PNG"), err, sizeof err);
    NsCamera cam;
    ns_scene_camera(&b.in, NS_VIEW_SIDE, (double)w / h, &cam);
    /* the needle: its sticking colour (blue) along its line, in and out of the tissue */
    for (int k = 0; k < 7; k++) {
        double p[3] = {-0.002 + 0.0035 * k, 0.0, 0.0};
        const uint8_t *c = pixel(&im, &cam, w, h, 0, p);
        ENSURE(c != NULL);
        if (!(c[2] > c[0] + 60 && c[2] > c[1] + 20)) {
            fprintf(stderr, "needle at x = %.3f: pixel (%d, %d, %d)\n", p[0], c[0], c[1], c[2]);
            return 1;
        }
    }
    /* the cut face: each region's colour inside its part (away from the needle and targets) */
    uint8_t r0[3], r1[3];
    ns_scene_region_rgb(0, false, r0);
    ns_scene_region_rgb(1, false, r1);
    const double in0[4][3] = {
        {0.004, 0.0, 0.006}, {0.016, 0.0, 0.007}, {0.006, 0.0, -0.003}, {0.018, 0.0, 0.004}};
    const double in1[4][3] = {
        {0.024, 0.0, 0.006}, {0.036, 0.0, 0.007}, {0.026, 0.0, -0.007}, {0.037, 0.0, -0.002}};
    for (int k = 0; k < 4; k++) {
        const uint8_t *c0 = pixel(&im, &cam, w, h, 0, in0[k]);
        const uint8_t *c1 = pixel(&im, &cam, w, h, 0, in1[k]);
        if (!near_rgb(c0, r0, 3) || !near_rgb(c1, r1, 3)) {
            fprintf(stderr,
                    "region colours: (%d %d %d) want (%d %d %d); (%d %d %d) want (%d %d %d)\n",
                    c0 ? c0[0] : -1, c0 ? c0[1] : -1, c0 ? c0[2] : -1, r0[0], r0[1], r0[2],
                    c1 ? c1[0] : -1, c1 ? c1[1] : -1, c1 ? c1[2] : -1, r1[0], r1[1], r1[2]);
            return 1;
        }
    }
    /* outside the block: the background, not a region's colour */
    double out[3] = {0.02, 0.0, 0.0115};
    const uint8_t *bg = pixel(&im, &cam, w, h, 0, out);
    ENSURE(bg && !near_rgb(bg, r0, 30) && !near_rgb(bg, r1, 30));
    /* targets: the hit one green, the missed one red */
    const uint8_t *g = pixel(&im, &cam, w, h, 0, b.target_x);
    const uint8_t *rd = pixel(&im, &cam, w, h, 0, b.target_x + 3);
    ENSURE(g && g[1] > g[0] + 60 && g[1] > g[2] + 60);
    ENSURE(rd && rd[0] > rd[1] + 80 && rd[0] > rd[2] + 80);
    /* a target's starting place (the missed one, started 5 mm above where it is): a grey
     * ghost there; the first target did not move, and has none */
    double x0[6] = {b.target_x[0], b.target_x[1], b.target_x[2],
                    b.target_x[3], b.target_x[4], b.target_x[5] + 0.005};
    b.in.target_x0 = x0;
    NsImage ghost = {0};
    ENSURE(render_block(&b, &f, &ghost, false) == 0);
    const uint8_t *gh = pixel(&ghost, &cam, w, h, 0, x0 + 3);
    ENSURE(gh && abs(gh[0] - gh[2]) < 30 && abs(gh[0] - gh[1]) < 30 && gh[0] > 100);
    const uint8_t *still = pixel(&ghost, &cam, w, h, 0, b.target_x);
    ENSURE(still && still[1] > still[0] + 60); /* the first target, green as before */
    b.in.target_x0 = NULL;
    ns_image_free(&ghost);
    /* deterministic: the same scene twice gives the same bytes */
    ENSURE(render_block(&b, &f, &again, false) == 0);
    ENSURE(memcmp(im.rgb, again.rgb, (size_t)w * h * 3) == 0);
    /* tets the latest remeshing made are highlighted (yellower), the others not */
    uint8_t *changed = calloc((size_t)b.mesh.tet_slots, 1);
    ENSURE(changed != NULL);
    for (int e = 0; e < b.mesh.tet_slots; e++)
        changed[e] = b.mesh.tet_region[e] == 1;
    b.in.changed = changed;
    ENSURE(render_block(&b, &f, &again, false) == 0);
    const uint8_t *hl = pixel(&again, &cam, w, h, 0, in1[0]);
    const uint8_t *plain = pixel(&again, &cam, w, h, 0, in0[0]);
    ENSURE(hl && !near_rgb(hl, r1, 20) && hl[1] > r1[1] + 40);
    ENSURE(near_rgb(plain, r0, 3));
    free(changed);
    b.in.changed = NULL;
    /* the HUD draws text (light pixels) in the top left corner, over the background */
    ENSURE(render_block(&b, &f, &again, true) == 0);
    int light = 0;
    for (int y = 0; y < h / 8; y++)
        for (int x = 0; x < w / 4; x++) {
            const uint8_t *c = again.rgb + 3 * ((size_t)y * w + x);
            light += c[0] > 200 && c[1] > 200 && c[2] > 200;
        }
    ENSURE(light > 50);
    ns_image_free(&im);
    ns_image_free(&again);
    ns_frame_close(&f);
    ns_mesh_free(&b.mesh);
    return 0;
}

NS_TEST_MAIN({"scene_cut_in_plane", scene_cut_in_plane},
             {"tip_where_simulated", tip_where_simulated},
             {"trus_tip_where_simulated", trus_tip_where_simulated},
             {"smooth_edges_blend_across", smooth_edges_blend_across},
             {"trus_between_gl_views", trus_between_gl_views},
             {"plan_drawn_where_it_lies", plan_drawn_where_it_lies},
             {"isodose_lines_on_their_level", isodose_lines_on_their_level},
             {"pixels_show_the_scene", pixels_show_the_scene})
