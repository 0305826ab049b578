/* Builds a view's scene from the simulation's state (render/scene.h): the cutaway of paper
 * Fig. 5 (a plane through the insertion axis facing the camera, the cut face capped and
 * coloured by region, the tets the latest remeshing made highlighted), the needle as a tube
 * coloured by friction state (§3.3: sticking, sliding, cutting), and spheres for targets,
 * seeds and markers. No OpenGL here. */
#include "scene.h"

#include "contour.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

const uint8_t ns_scene_needle_rgb[5][3] = {
    {175, 182, 194}, /* free (outside the tissue): steel */
    {60, 120, 235},  /* sticking */
    {150, 80, 225},  /* sliding back (out) */
    {250, 165, 30},  /* sliding forward (in) */
    {235, 40, 40},   /* cutting (the tip) */
};
const uint8_t ns_scene_hit_rgb[3] = {40, 200, 70}, ns_scene_miss_rgb[3] = {225, 35, 45};
const uint8_t ns_scene_iso_rgb[2][3] = {{255, 230, 40}, {255, 110, 20}};
const uint8_t ns_scene_plan_rgb[3] = {140, 225, 250};

void ns_scene_region_rgb(int region, bool obstacle, uint8_t rgb[3])
{
    static const uint8_t tissue[6][3] = {{228, 178, 164}, {196, 112, 124}, {236, 206, 150},
                                         {178, 150, 196}, {160, 200, 170}, {210, 160, 110}};
    static const uint8_t obst[3] = {70, 112, 116};
    const uint8_t *c = obstacle ? obst : tissue[(region < 0 ? 0 : region) % 6];
    memcpy(rgb, c, 3);
}

int ns_view_parse(const char *name)
{
    static const char *names[NS_VIEW_COUNT] = {"side", "top", "axis", "cutaway3d", "trus"};
    for (int i = 0; i < NS_VIEW_COUNT; i++)
        if (strcmp(name, names[i]) == 0)
            return i;
    return -1;
}

const char *ns_view_name(NsView v)
{
    static const char *names[NS_VIEW_COUNT] = {"side", "top", "axis", "cutaway3d", "trus"};
    return (int)v >= 0 && (int)v < (int)NS_VIEW_COUNT ? names[v] : "side";
}

/* ---- small vector helpers ---- */

static double dot(const double *a, const double *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static void cross(const double *a, const double *b, double *c)
{
    double r[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
    memcpy(c, r, sizeof r);
}

static double normalize(double *a)
{
    double l = sqrt(dot(a, a));
    if (l > 0.0)
        for (int i = 0; i < 3; i++)
            a[i] /= l;
    return l;
}

/* A unit vector normal to a (unit). */
static void any_normal(const double *a, double *n)
{
    double e[3] = {fabs(a[0]) < 0.6 ? 1.0 : 0.0, fabs(a[0]) < 0.6 ? 0.0 : 1.0, 0.0};
    cross(a, e, n);
    normalize(n);
}

/* ---- vertex lists ---- */

static int push(NsVertexBuf *b, const double p[3], const double n[3], const uint8_t rgb[3],
                uint8_t alpha)
{
    if (b->n == b->cap) {
        int cap = b->cap ? 2 * b->cap : 1024;
        NsVertex *v = realloc(b->v, (size_t)cap * sizeof *v);
        if (!v)
            return -1;
        b->v = v;
        b->cap = cap;
    }
    NsVertex *v = b->v + b->n++;
    for (int i = 0; i < 3; i++) {
        v->p[i] = (float)p[i];
        v->n[i] = n ? (float)n[i] : 0.0f;
        v->rgba[i] = rgb[i];
    }
    v->rgba[3] = alpha;
    return 0;
}

static int tri(NsVertexBuf *b, const double *p0, const double *p1, const double *p2,
               const uint8_t rgb[3], uint8_t alpha)
{
    double e1[3], e2[3], n[3];
    for (int i = 0; i < 3; i++) {
        e1[i] = p1[i] - p0[i];
        e2[i] = p2[i] - p0[i];
    }
    cross(e1, e2, n);
    normalize(n);
    return push(b, p0, n, rgb, alpha) || push(b, p1, n, rgb, alpha) || push(b, p2, n, rgb, alpha);
}

void ns_scene_free(NsScene *s)
{
    free(s->cap.v);
    free(s->edges.v);
    free(s->solid.v);
    free(s->glass.v);
    memset(s, 0, sizeof *s);
}

/* ---- cameras ---- */

/* The world's up for the views: +z, or +y when the insertion axis is near z. */
static void world_up(const double *axis, double *up)
{
    up[0] = 0.0;
    up[1] = fabs(axis[2]) > 0.9 ? 1.0 : 0.0;
    up[2] = fabs(axis[2]) > 0.9 ? 0.0 : 1.0;
}

void ns_scene_camera(const NsSceneInput *in, NsView v, double aspect, NsCamera *cam)
{
    double a[3] = {in->axis[0], in->axis[1], in->axis[2]}, up[3], f[3], u[3], r[3];
    normalize(a);
    world_up(a, up);
    if (v == NS_VIEW_AXIS) { /* along the needle, from behind its base */
        memcpy(f, a, sizeof f);
        double k = dot(up, f);
        for (int i = 0; i < 3; i++)
            u[i] = up[i] - k * f[i];
        if (normalize(u) < 1e-9)
            any_normal(f, u);
    } else { /* the axis runs to the right; side: looking level, top: looking down */
        if (v == NS_VIEW_TOP) {
            for (int i = 0; i < 3; i++)
                f[i] = -up[i];
        } else {
            cross(up, a, f);
        }
        if (normalize(f) < 1e-9)
            any_normal(a, f);
        if (v == NS_VIEW_CUTAWAY3D) { /* from the side, 35 deg round towards the tip's end and
                                       * 30 deg above (f is normal to a; a turned into it) */
            double c1 = cos(35.0 * M_PI / 180.0), s1 = sin(35.0 * M_PI / 180.0);
            double c2 = cos(30.0 * M_PI / 180.0), s2 = sin(30.0 * M_PI / 180.0);
            for (int i = 0; i < 3; i++)
                f[i] = c2 * (c1 * f[i] - s1 * a[i]) - s2 * up[i];
            normalize(f);
        }
        if (in->orbit_deg != 0.0) { /* f turned about a (f is normal to a) */
            double g[3], c = cos(in->orbit_deg * M_PI / 180.0),
                         sn = sin(in->orbit_deg * M_PI / 180.0);
            cross(a, f, g);
            for (int i = 0; i < 3; i++)
                f[i] = c * f[i] + sn * g[i];
        }
        if (v == NS_VIEW_CUTAWAY3D) { /* the world's up, as seen */
            double k = dot(up, f);
            for (int i = 0; i < 3; i++)
                u[i] = up[i] - k * f[i];
            if (normalize(u) < 1e-9)
                any_normal(f, u);
        } else {
            cross(a, f, u);
            normalize(u);
        }
    }
    cross(f, u, r);
    double c[3], half_w = 0.0, half_h = 0.0, half_d = 0.0;
    for (int i = 0; i < 3; i++)
        c[i] = 0.5 * (in->bounds[i] + in->bounds[3 + i]);
    for (int k = 0; k < 8; k++) { /* the box's corners on the view's right and up axes */
        double p[3];
        for (int i = 0; i < 3; i++)
            p[i] = ((k >> i) & 1 ? in->bounds[3 + i] : in->bounds[i]) - c[i];
        half_w = fmax(half_w, fabs(dot(p, r)));
        half_h = fmax(half_h, fabs(dot(p, u)));
        half_d = fmax(half_d, fabs(dot(p, f)));
    }
    cam->fov_deg = 30.0;
    double t = tan(0.5 * cam->fov_deg * M_PI / 180.0);
    /* the box fills the view at its centre's depth (the cut); the eye stays outside it */
    double dist = fmax(1.12 * fmax(half_h / t, half_w / (t * aspect)), 1.2 * half_d);
    if (!(dist > 0.0))
        dist = 0.1;
    for (int i = 0; i < 3; i++) {
        cam->target[i] = c[i];
        cam->eye[i] = c[i] - dist * f[i];
        cam->up[i] = u[i];
    }
}

void ns_camera_matrix(const NsCamera *cam, double aspect, double m[16])
{
    double f[3], s[3], u[3];
    for (int i = 0; i < 3; i++)
        f[i] = cam->target[i] - cam->eye[i];
    double dist = normalize(f);
    cross(f, cam->up, s);
    normalize(s);
    cross(s, f, u);
    double zn = 0.05 * dist, zf = 4.0 * dist;
    double t = 1.0 / tan(0.5 * cam->fov_deg * M_PI / 180.0);
    double V[16] = {s[0],
                    u[0],
                    -f[0],
                    0,
                    s[1],
                    u[1],
                    -f[1],
                    0,
                    s[2],
                    u[2],
                    -f[2],
                    0,
                    -dot(s, cam->eye),
                    -dot(u, cam->eye),
                    dot(f, cam->eye),
                    1};
    double P[16] = {t / aspect,
                    0,
                    0,
                    0,
                    0,
                    t,
                    0,
                    0,
                    0,
                    0,
                    (zf + zn) / (zn - zf),
                    -1,
                    0,
                    0,
                    2 * zf * zn / (zn - zf),
                    0};
    for (int c = 0; c < 4; c++) /* m = P V, column-major */
        for (int r = 0; r < 4; r++) {
            double x = 0.0;
            for (int k = 0; k < 4; k++)
                x += P[4 * k + r] * V[4 * c + k];
            m[4 * c + r] = x;
        }
}

int ns_camera_project(const NsCamera *cam, int w, int h, const double p[3], double px[2])
{
    double m[16], q[4];
    ns_camera_matrix(cam, (double)w / h, m);
    for (int r = 0; r < 4; r++)
        q[r] = m[r] * p[0] + m[4 + r] * p[1] + m[8 + r] * p[2] + m[12 + r];
    if (!(q[3] > 0.0))
        return 0;
    px[0] = 0.5 * (q[0] / q[3] + 1.0) * w;
    px[1] = 0.5 * (1.0 - q[1] / q[3]) * h;
    return 1;
}

/* ---- the cut (paper Fig. 5) ---- */

static void blend(const uint8_t a[3], const uint8_t b[3], double t, uint8_t out[3])
{
    for (int i = 0; i < 3; i++)
        out[i] = (uint8_t)lround((1.0 - t) * a[i] + t * b[i]);
}

/* The cap: each tet the plane crosses gives a triangle or a quad, in its region's colour. */
static int build_cut(const NsSceneInput *in, NsScene *s)
{
    const NsMesh *m = in->mesh;
    static const uint8_t highlight[3] = {255, 236, 60}, black[3] = {0, 0, 0};
    for (int e = 0; e < m->tet_slots; e++) {
        const int *tn = m->tet_node + 4 * e;
        if (tn[0] < 0)
            continue;
        double g[4];
        int pos = 0;
        for (int k = 0; k < 4; k++) {
            const double *x = m->x + 3 * tn[k];
            g[k] = dot(s->plane, x) + s->plane[3];
            pos += g[k] > 0.0;
        }
        if (pos == 0 || pos == 4)
            continue;
        int reg = m->tet_region[e];
        bool obst = in->obstacle_region && reg < in->regions && in->obstacle_region[reg];
        uint8_t rgb[3], dark[3];
        ns_scene_region_rgb(reg, obst, rgb);
        if (in->changed && in->changed[e])
            blend(rgb, highlight, 0.6, rgb);
        blend(rgb, black, 0.45, dark);
        /* the crossing points on the edges whose ends lie on either side, in polygon order */
        int P[4], N[4], np = 0, nn = 0;
        for (int k = 0; k < 4; k++) {
            if (g[k] > 0.0)
                P[np++] = k;
            else
                N[nn++] = k;
        }
        int pairs[4][2], cnt = 0;
        if (np == 1 || nn == 1) {
            int lone = np == 1 ? P[0] : N[0], *other = np == 1 ? N : P;
            for (int k = 0; k < 3; k++) {
                pairs[cnt][0] = lone;
                pairs[cnt++][1] = other[k];
            }
        } else {
            int order[4][2] = {{N[0], P[0]}, {N[0], P[1]}, {N[1], P[1]}, {N[1], P[0]}};
            memcpy(pairs, order, sizeof order);
            cnt = 4;
        }
        double q[4][3];
        for (int k = 0; k < cnt; k++) {
            int i = pairs[k][0], j = pairs[k][1];
            const double *xi = m->x + 3 * tn[i], *xj = m->x + 3 * tn[j];
            double t = g[i] / (g[i] - g[j]);
            for (int d = 0; d < 3; d++)
                q[k][d] = xi[d] + t * (xj[d] - xi[d]);
        }
        if (tri(&s->cap, q[0], q[1], q[2], rgb, 255) ||
            (cnt == 4 && tri(&s->cap, q[0], q[2], q[3], rgb, 255)))
            return -1;
        for (int k = 0; in->tet_edges && k < cnt; k++)
            if (push(&s->edges, q[k], NULL, dark, 255) ||
                push(&s->edges, q[(k + 1) % cnt], NULL, dark, 255))
                return -1;
    }
    return 0;
}

/* The outer surface: every boundary face, translucent (the shader clips the removed half). */
static int build_glass(const NsSceneInput *in, NsView v, NsScene *s)
{
    const NsMesh *m = in->mesh;
    for (int e = 0; e < m->tet_slots; e++) {
        const int *tn = m->tet_node + 4 * e;
        if (tn[0] < 0)
            continue;
        for (int k = 0; k < 4; k++) {
            int nb = m->tet_adj[4 * e + k];
            /* the outer surface; in cutaway3d also the organs' surfaces: faces between regions,
             * each once, in the colour of the higher region (an organ within the tissue) */
            if (nb >= 0 && (v != NS_VIEW_CUTAWAY3D || m->tet_region[nb] >= m->tet_region[e]))
                continue;
            int reg = m->tet_region[e];
            bool obst = in->obstacle_region && reg < in->regions && in->obstacle_region[reg];
            uint8_t rgb[3];
            ns_scene_region_rgb(reg, obst, rgb);
            const int *f = ns_tet_face[k];
            if (tri(&s->glass, m->x + 3 * tn[f[0]], m->x + 3 * tn[f[1]], m->x + 3 * tn[f[2]], rgb,
                    56))
                return -1;
        }
    }
    return 0;
}

/* ---- solids ---- */

enum { RING = 12 };

/* A tube of radius r along the polyline x (n points), coloured per point; closed at the end
 * by a cone to apex (if apex) . Frames are carried along the line by parallel transport. */
static int tube(NsVertexBuf *b, const double *x, int n, double r, const uint8_t (*rgb)[3],
                const double *apex)
{
    double t[3] = {1, 0, 0}, d1[3] = {0, 1, 0}, prev_ring[RING][3], prev_n[RING][3];
    for (int k = 0; k < n; k++) {
        double tn[3];
        const double *a = x + 3 * (k > 0 ? k - 1 : 0), *c = x + 3 * (k + 1 < n ? k + 1 : k);
        for (int i = 0; i < 3; i++)
            tn[i] = c[i] - a[i];
        if (normalize(tn) < 1e-12)
            memcpy(tn, k ? t : (double[3]){1, 0, 0}, sizeof tn);
        if (k == 0) {
            any_normal(tn, d1);
        } else { /* transport d1 from t to tn: remove its tn component */
            double kk = dot(d1, tn);
            for (int i = 0; i < 3; i++)
                d1[i] -= kk * tn[i];
            if (normalize(d1) < 1e-9)
                any_normal(tn, d1);
        }
        memcpy(t, tn, sizeof t);
        double d2[3], ring[RING][3], nr[RING][3];
        cross(t, d1, d2);
        for (int j = 0; j < RING; j++) {
            double ang = 2.0 * M_PI * j / RING, cs = cos(ang), sn = sin(ang);
            for (int i = 0; i < 3; i++) {
                nr[j][i] = cs * d1[i] + sn * d2[i];
                ring[j][i] = x[3 * k + i] + r * nr[j][i];
            }
        }
        for (int j = 0; k > 0 && j < RING; j++) {
            int j1 = (j + 1) % RING;
            const uint8_t *c0 = rgb[k - 1], *c1 = rgb[k];
            if (push(b, prev_ring[j], prev_n[j], c0, 255) || push(b, ring[j], nr[j], c1, 255) ||
                push(b, ring[j1], nr[j1], c1, 255) || push(b, prev_ring[j], prev_n[j], c0, 255) ||
                push(b, ring[j1], nr[j1], c1, 255) || push(b, prev_ring[j1], prev_n[j1], c0, 255))
                return -1;
        }
        memcpy(prev_ring, ring, sizeof ring);
        memcpy(prev_n, nr, sizeof nr);
    }
    for (int j = 0; apex && j < RING; j++) {
        int j1 = (j + 1) % RING;
        if (tri(b, prev_ring[j], prev_ring[j1], apex, rgb[n - 1], 255))
            return -1;
    }
    return 0;
}

static int sphere(NsVertexBuf *b, const double *c, double r, const uint8_t rgb[3])
{
    enum { SLICES = 16, STACKS = 10 };
    for (int i = 0; i < STACKS; i++)
        for (int j = 0; j < SLICES; j++) {
            double q[4][3];
            for (int k = 0; k < 4; k++) {
                double th = M_PI * (i + (k >> 1)) / STACKS,
                       ph = 2.0 * M_PI * (j + ((k ^ (k >> 1)) & 1)) / SLICES;
                double n[3] = {sin(th) * cos(ph), sin(th) * sin(ph), cos(th)};
                for (int d = 0; d < 3; d++)
                    q[k][d] = n[d];
            }
            double p[4][3];
            for (int k = 0; k < 4; k++)
                for (int d = 0; d < 3; d++)
                    p[k][d] = c[d] + r * q[k][d];
            if (push(b, p[0], q[0], rgb, 255) || push(b, p[1], q[1], rgb, 255) ||
                push(b, p[2], q[2], rgb, 255) || push(b, p[0], q[0], rgb, 255) ||
                push(b, p[2], q[2], rgb, 255) || push(b, p[3], q[3], rgb, 255))
                return -1;
        }
    return 0;
}

static int build_solids(const NsSceneInput *in, NsScene *s)
{
    int n = in->rod_nodes;
    double px = in->px_size > 0.0 ? in->px_size : 0.0;
    if (n >= 2) {
        uint8_t(*rgb)[3] = malloc((size_t)n * sizeof *rgb);
        if (!rgb)
            return -1;
        for (int k = 0; k < n; k++) {
            int c = 0;
            if (in->state) /* NsFriction: 0 free, 1 static, 2 sliding back, 3 sliding in */
                c = in->state[k] <= 3 ? in->state[k] : 0;
            if (k == n - 1 && in->state && in->cutting)
                c = 4;
            memcpy(rgb[k], ns_scene_needle_rgb[c], 3);
        }
        double r = fmax(in->rod_radius, 2.0 * px);
        const double *tip = in->rod_x + 3 * (n - 1), *pre = in->rod_x + 3 * (n - 2);
        double t[3] = {tip[0] - pre[0], tip[1] - pre[1], tip[2] - pre[2]}, apex[3];
        double last = normalize(t);
        /* the point is the simulated tip: the tube's last ring stands back from it by the
         * cone's length (3 r, or the last edge's length less a little when that is shorter),
         * and a bevel's point lies on the side it steers to */
        double cone = fmin(3.0 * r, 0.9 * last);
        double *x = malloc((size_t)n * 3 * sizeof *x);
        if (!x) {
            free(rgb);
            return -1;
        }
        memcpy(x, in->rod_x, (size_t)n * 3 * sizeof *x);
        for (int i = 0; i < 3; i++) {
            x[3 * (n - 1) + i] = tip[i] - cone * t[i];
            apex[i] = tip[i] + (in->bevel ? 0.9 * r * in->m2[i] : 0.0);
        }
        int rc = tube(&s->solid, x, n, r, (const uint8_t(*)[3])rgb, apex);
        free(x);
        free(rgb);
        if (rc)
            return -1;
        if (in->held >= 2) { /* the sleeve round the held edge */
            static const uint8_t sleeve[2][3] = {{84, 90, 102}, {84, 90, 102}};
            if (tube(&s->solid, in->rod_x, 2, 3.0 * r, sleeve, NULL))
                return -1;
        }
    }
    static const uint8_t ghost_rgb[2][3] = {{150, 156, 168}, {150, 156, 168}};
    for (int i = 0; i < in->targets; i++) {
        double r = fmax(0.5 * in->target_r[i], 4.0 * px);
        if (sphere(&s->solid, in->target_x + 3 * i, r,
                   in->target_hit && in->target_hit[i] ? ns_scene_hit_rgb : ns_scene_miss_rgb))
            return -1;
        /* where the target started, a grey ghost joined to it, once the tissue moved it by
         * more than its drawn radius */
        const double *x0 = in->target_x0 ? in->target_x0 + 3 * i : NULL;
        double d[3] = {0, 0, 0}, seg[6];
        for (int k = 0; x0 && k < 3; k++)
            d[k] = in->target_x[3 * i + k] - x0[k];
        if (x0 && sqrt(dot(d, d)) > r) {
            memcpy(seg, x0, 3 * sizeof *seg);
            memcpy(seg + 3, in->target_x + 3 * i, 3 * sizeof *seg);
            if (sphere(&s->solid, x0, 0.6 * r, ghost_rgb[0]) ||
                tube(&s->solid, seg, 2, fmax(0.15 * r, px), ghost_rgb, NULL))
                return -1;
        }
    }
    static const uint8_t seed_rgb[3] = {240, 240, 225}, marker_rgb[3] = {225, 60, 205};
    for (int i = 0; i < in->seeds; i++)
        if (sphere(&s->solid, in->seed_x + 3 * i, fmax(0.6e-3, 2.5 * px), seed_rgb))
            return -1;
    for (int i = 0; i < in->markers; i++)
        if (sphere(&s->solid, in->marker_x + 3 * i, fmax(0.6e-3, 2.5 * px), marker_rgb))
            return -1;
    return 0;
}

/* A planned path: a tube a third of the needle's width (at least 1.5 pixels), light blue
 * like the paper's predicted helices (§5). */
static int build_path(const NsSceneInput *in, const double *x, int n, NsScene *s)
{
    if (!x || n < 2)
        return 0;
    uint8_t(*rgb)[3] = malloc((size_t)n * sizeof *rgb);
    if (!rgb)
        return -1;
    for (int k = 0; k < n; k++)
        memcpy(rgb[k], ns_scene_plan_rgb, 3);
    double px = in->px_size > 0.0 ? in->px_size : 0.0;
    int rc = tube(&s->solid, x, n, fmax(0.35 * in->rod_radius, 1.5 * px), (const uint8_t(*)[3])rgb,
                  NULL);
    free(rgb);
    return rc;
}

/* act.steer's predicted arc and a plan made before the run. */
static int build_plan(const NsSceneInput *in, NsScene *s)
{
    return build_path(in, in->plan_x, in->plan_n, s) || build_path(in, in->prior_x, in->prior_n, s);
}

/* ---- isodose lines on the cut face ---- */

#define ISO_CELLS 120 /* grid cells across the larger side of the framed box */

typedef struct IsoCtx {
    NsScene *s;
    double o[3], u[3], w[3], n2[3], h, px;
    const uint8_t *rgb;
} IsoCtx;

/* One segment in grid units, drawn three times a pixel apart across itself (GL lines are one
 * pixel wide). */
static int iso_emit(void *ctx, const double a[2], const double b[2])
{
    IsoCtx *c = ctx;
    double pa[3], pb[3], d[3], across[3];
    for (int i = 0; i < 3; i++) {
        pa[i] = c->o[i] + a[0] * c->h * c->u[i] + a[1] * c->h * c->w[i];
        pb[i] = c->o[i] + b[0] * c->h * c->u[i] + b[1] * c->h * c->w[i];
        d[i] = pb[i] - pa[i];
    }
    cross(c->n2, d, across);
    if (normalize(across) == 0.0)
        return 0;
    for (int k = -1; k <= 1; k++) {
        double qa[3], qb[3];
        for (int i = 0; i < 3; i++) {
            qa[i] = pa[i] + k * 0.7 * c->px * across[i];
            qb[i] = pb[i] + k * 0.7 * c->px * across[i];
        }
        if (push(&c->s->edges, qa, NULL, c->rgb, 255) || push(&c->s->edges, qb, NULL, c->rgb, 255))
            return -1;
    }
    return 0;
}

/* The dose on a grid over the cut plane (the part of it the framed box covers) and its level
 * lines. A failed dose evaluation draws no lines; only memory is an error. */
static int build_isodose(const NsSceneInput *in, NsScene *s)
{
    if (!in->dose_points || in->seeds <= 0 || in->iso_count <= 0)
        return 0;
    IsoCtx c = {.s = s, .px = in->px_size};
    memcpy(c.n2, s->plane, sizeof c.n2);
    any_normal(c.n2, c.u);
    cross(c.n2, c.u, c.w);
    double lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY}, p0[3];
    for (int i = 0; i < 3; i++)
        p0[i] = -s->plane[3] * c.n2[i];
    for (int k = 0; k < 8; k++) {
        double q[3] = {in->bounds[k & 1 ? 3 : 0], in->bounds[k & 2 ? 4 : 1],
                       in->bounds[k & 4 ? 5 : 2]};
        double r[3] = {q[0] - p0[0], q[1] - p0[1], q[2] - p0[2]};
        double a = dot(r, c.u), b = dot(r, c.w);
        lo[0] = fmin(lo[0], a);
        hi[0] = fmax(hi[0], a);
        lo[1] = fmin(lo[1], b);
        hi[1] = fmax(hi[1], b);
    }
    c.h = fmax(fmax(hi[0] - lo[0], hi[1] - lo[1]) / ISO_CELLS, 0.5e-3);
    int nu = (int)ceil((hi[0] - lo[0]) / c.h) + 1, nv = (int)ceil((hi[1] - lo[1]) / c.h) + 1;
    if (!(nu >= 2 && nv >= 2 && nu <= 4 * ISO_CELLS && nv <= 4 * ISO_CELLS))
        return 0;
    for (int i = 0; i < 3; i++)
        c.o[i] = p0[i] + lo[0] * c.u[i] + lo[1] * c.w[i];
    long n = (long)nu * nv;
    double *pts = malloc((size_t)n * 3 * sizeof *pts), *f = malloc((size_t)n * sizeof *f);
    int rc = pts && f ? 0 : -1;
    for (int j = 0; rc == 0 && j < nv; j++)
        for (int i = 0; i < nu; i++)
            for (int d = 0; d < 3; d++)
                pts[3 * ((long)j * nu + i) + d] = c.o[d] + i * c.h * c.u[d] + j * c.h * c.w[d];
    if (rc == 0 && in->dose_points(in->dose_ctx, in->seed_x, in->seeds, pts, n, f) == 0)
        for (int k = 0; rc == 0 && k < in->iso_count && k < 2; k++) {
            c.rgb = ns_scene_iso_rgb[k];
            rc = ns_contour(f, nu, nv, in->iso_levels[k], iso_emit, &c);
        }
    free(pts);
    free(f);
    return rc;
}

int ns_scene_build(const NsSceneInput *in, NsView v, double aspect, NsScene *s)
{
    s->cap.n = s->edges.n = s->solid.n = s->glass.n = 0;
    snprintf(s->label, sizeof s->label, "%s", ns_view_name(v));
    ns_scene_camera(in, v, aspect, &s->camera);
    double f[3], a[3] = {in->axis[0], in->axis[1], in->axis[2]}, nc[3];
    const double *p0 = in->entry;
    for (int i = 0; i < 3; i++)
        f[i] = s->camera.target[i] - s->camera.eye[i];
    normalize(f);
    normalize(a);
    if (in->has_cut_normal) {
        memcpy(nc, in->cut_normal, sizeof nc);
        normalize(nc);
    } else if (v == NS_VIEW_AXIS) { /* a cross-section at the tip */
        memcpy(nc, a, sizeof nc);
        if (in->rod_nodes > 0)
            p0 = in->rod_x + 3 * (in->rod_nodes - 1);
    } else { /* the plane holding the axis and facing the camera */
        double k = dot(f, a);
        for (int i = 0; i < 3; i++)
            nc[i] = f[i] - k * a[i];
        if (normalize(nc) < 1e-9)
            any_normal(a, nc);
    }
    if (dot(nc, f) > 0.0) /* the normal points at the camera: its side is removed */
        for (int i = 0; i < 3; i++)
            nc[i] = -nc[i];
    memcpy(s->plane, nc, sizeof nc);
    s->plane[3] = -dot(nc, p0);
    if (build_cut(in, s) || build_isodose(in, s) || build_glass(in, v, s) || build_solids(in, s) ||
        build_plan(in, s))
        return -1;
    return 0;
}
