/* Tet quality (§3.4.1: signed volume / rms edge length^3, the remesher's measure) and
 * dihedral angles, the measure of the mesher's guarantee. */
#include "quality.h"

#include <float.h>
#include <math.h>

static void sub(const double *a, const double *b, double *o)
{
    o[0] = a[0] - b[0];
    o[1] = a[1] - b[1];
    o[2] = a[2] - b[2];
}

static void cross(const double *a, const double *b, double *o)
{
    o[0] = a[1] * b[2] - a[2] * b[1];
    o[1] = a[2] * b[0] - a[0] * b[2];
    o[2] = a[0] * b[1] - a[1] * b[0];
}

static double dot(const double *a, const double *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

double ns_tet_volume(const double *p0, const double *p1, const double *p2, const double *p3)
{
    double e1[3], e2[3], e3[3], c[3];
    sub(p1, p0, e1);
    sub(p2, p0, e2);
    sub(p3, p0, e3);
    cross(e1, e2, c);
    return dot(c, e3) / 6.0;
}

double ns_tet_quality(const double *p0, const double *p1, const double *p2, const double *p3)
{
    const double *p[4] = {p0, p1, p2, p3};
    double sum = 0.0;
    for (int i = 0; i < 4; i++)
        for (int j = i + 1; j < 4; j++) {
            double e[3];
            sub(p[j], p[i], e);
            sum += dot(e, e);
        }
    double rms = sqrt(sum / 6.0);
    if (rms <= 0.0)
        return 0.0;
    /* regular tet of edge a: V = a^3 / (6 sqrt 2), rms = a  ->  6 sqrt(2) V / rms^3 = 1 */
    return 6.0 * sqrt(2.0) * ns_tet_volume(p0, p1, p2, p3) / (rms * rms * rms);
}

/* Unit normals n_k of the faces opposite vertex k, oriented away from k; 0 for a degenerate
 * tet (a face of no area). */
static int face_normals(const double *const p[4], double n[4][3])
{
    for (int k = 0; k < 4; k++) {
        int a = (k + 1) % 4, b = (k + 2) % 4, c = (k + 3) % 4;
        double e1[3], e2[3], d[3];
        sub(p[b], p[a], e1);
        sub(p[c], p[a], e2);
        cross(e1, e2, n[k]);
        sub(p[k], p[a], d);
        if (dot(n[k], d) > 0.0) {
            n[k][0] = -n[k][0];
            n[k][1] = -n[k][1];
            n[k][2] = -n[k][2];
        }
        double len = sqrt(dot(n[k], n[k]));
        if (len <= DBL_MIN)
            return 0;
        for (int i = 0; i < 3; i++)
            n[k][i] /= len;
    }
    return 1;
}

/* The dihedral angle at edge (i, j) lies between the two faces that contain the edge, the
 * faces opposite the other two vertices k, l: angle = pi - angle(n_k, n_l), whose cosine is
 * -n_k . n_l (clamped to [-1, 1]). */
static const int edge_faces[6][2] = {{2, 3}, {1, 3}, {1, 2}, {0, 3}, {0, 2}, {0, 1}};

static double edge_cos(double n[4][3], int e)
{
    double c = -dot(n[edge_faces[e][0]], n[edge_faces[e][1]]);
    return c > 1.0 ? 1.0 : (c < -1.0 ? -1.0 : c);
}

double ns_tet_dihedrals(const double *p0, const double *p1, const double *p2, const double *p3,
                        double out[6])
{
    const double *p[4] = {p0, p1, p2, p3};
    double n[4][3];
    if (!face_normals(p, n)) {
        if (out)
            for (int i = 0; i < 6; i++)
                out[i] = 0.0;
        return 0.0;
    }
    double mn = 180.0;
    for (int e = 0; e < 6; e++) {
        double ang = acos(edge_cos(n, e)) * (180.0 / M_PI);
        if (out)
            out[e] = ang;
        if (ang < mn)
            mn = ang;
    }
    return mn;
}

double ns_tet_min_dihedral(const double *p0, const double *p1, const double *p2, const double *p3)
{
    const double *p[4] = {p0, p1, p2, p3};
    double n[4][3];
    if (!face_normals(p, n))
        return 0.0;
    /* acos falls as its argument rises: the smallest angle is the largest cosine's (NaNs, as
     * in ns_tet_dihedrals, never count). */
    double cmax = -INFINITY;
    for (int e = 0; e < 6; e++) {
        double c = edge_cos(n, e);
        if (c > cmax)
            cmax = c;
    }
    if (cmax == -INFINITY)
        return 180.0;
    double ang = acos(cmax) * (180.0 / M_PI);
    return ang < 180.0 ? ang : 180.0;
}

double ns_tet_dihedral_range(const double *p0, const double *p1, const double *p2, const double *p3,
                             double *max_deg)
{
    const double *p[4] = {p0, p1, p2, p3};
    double n[4][3];
    if (!face_normals(p, n)) {
        *max_deg = 180.0;
        return 0.0;
    }
    /* The largest cosine gives the smallest angle, the smallest cosine the largest. */
    double cmax = -INFINITY, cmin = INFINITY;
    for (int e = 0; e < 6; e++) {
        double c = edge_cos(n, e);
        cmax = c > cmax ? c : cmax;
        cmin = c < cmin ? c : cmin;
    }
    if (cmax == -INFINITY) { /* every cosine NaN */
        *max_deg = 180.0;
        return 0.0;
    }
    *max_deg = fmin(acos(cmin) * (180.0 / M_PI), 180.0);
    return fmin(acos(cmax) * (180.0 / M_PI), 180.0);
}

void ns_mesh_quality(const NsMesh *m, bool use_world, NsQualityStats *out)
{
    NsQualityStats s = {0, 180.0, 0.0, DBL_MAX, 0, -1};
    const double *X = use_world ? m->x : m->u;
    for (int t = 0; t < m->tet_slots; t++) {
        if (!ns_mesh_tet_alive(m, t))
            continue;
        const int *tn = m->tet_node + 4 * t;
        const double *a = X + 3 * tn[0], *b = X + 3 * tn[1], *c = X + 3 * tn[2], *d = X + 3 * tn[3];
        double ang[6];
        ns_tet_dihedrals(a, b, c, d, ang);
        for (int i = 0; i < 6; i++) {
            if (ang[i] < s.min_dihedral_deg)
                s.min_dihedral_deg = ang[i];
            if (ang[i] > s.max_dihedral_deg)
                s.max_dihedral_deg = ang[i];
        }
        double q = ns_tet_quality(a, b, c, d);
        if (q <= 0.0)
            s.inverted++;
        if (q < s.min_quality) {
            s.min_quality = q;
            s.worst_tet = t;
        }
        s.tets++;
    }
    if (s.tets == 0) {
        s.min_dihedral_deg = 0.0;
        s.min_quality = 0.0;
    }
    *out = s;
}

/* Mean edge length of the mesh's tets (material space) [m]. */
double ns_mesh_mean_edge(const NsMesh *m)
{
    double sum = 0.0;
    long n = 0;
    for (int e = 0; e < m->tet_slots; e++) {
        if (!ns_mesh_tet_alive(m, e))
            continue;
        const int *tn = m->tet_node + 4 * e;
        for (int a = 0; a < 4; a++)
            for (int b = a + 1; b < 4; b++) {
                const double *p = m->u + 3 * tn[a], *q = m->u + 3 * tn[b];
                sum += sqrt((p[0] - q[0]) * (p[0] - q[0]) + (p[1] - q[1]) * (p[1] - q[1]) +
                            (p[2] - q[2]) * (p[2] - q[2]));
                n++;
            }
    }
    return n ? sum / (double)n : 0.0;
}
