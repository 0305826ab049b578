/* Tetrahedron quality measures (paper §3.4.1: quality = signed volume / rms edge length^3,
 * the measure the remesher maximizes lexicographically), and dihedral angles. */
#ifndef NS_QUALITY_H
#define NS_QUALITY_H

#include "mesh.h"

/* Signed volume det[p1-p0, p2-p0, p3-p0] / 6 of the tet (p0, p1, p2, p3) [m^3]. */
double ns_tet_volume(const double *p0, const double *p1, const double *p2, const double *p3);

/* 6*sqrt(2) * signed volume / (rms edge length)^3: 1 for the regular tet, 0 for a flat one,
 * negative for an inverted one. */
double ns_tet_quality(const double *p0, const double *p1, const double *p2, const double *p3);

/* The six interior dihedral angles in degrees (at edges 01, 02, 03, 12, 13, 23). Returns the
 * minimum; out may be NULL. A degenerate tet gives 0. */
double ns_tet_dihedrals(const double *p0, const double *p1, const double *p2, const double *p3,
                        double out[6]);

/* ns_tet_dihedrals' minimum from one acos (of the largest cosine) instead of six: the same
 * value, acos being monotone (tests/test_quality.c compares them). */
double ns_tet_min_dihedral(const double *p0, const double *p1, const double *p2, const double *p3);
/* The smallest and (into *max_deg) the largest dihedral angle [deg] from two acos: the same
 * values as ns_tet_dihedrals' minimum and maximum. A degenerate tet gives 0 and 180. */
double ns_tet_dihedral_range(const double *p0, const double *p1, const double *p2, const double *p3,
                             double *max_deg);

typedef struct NsQualityStats {
    int tets;
    double min_dihedral_deg;
    double max_dihedral_deg;
    double min_quality;
    int inverted;  /* tets with signed volume <= 0 */
    int worst_tet; /* tet with min quality */
} NsQualityStats;

/* Over all alive tets, in material coordinates (use_world = false) or world coordinates. */
void ns_mesh_quality(const NsMesh *m, bool use_world, NsQualityStats *out);

/* Mean edge length of the alive tets, counting each tet's six edges (material space) [m]. */
double ns_mesh_mean_edge(const NsMesh *m);

#endif
