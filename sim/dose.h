/* Brachytherapy dose from I-125 seeds: the AAPM TG-43U1 formalism (Rivard et al., Med. Phys.
 * 31(3) 633-674, 2004) with the line-source geometry function, and a dose grid over a box
 * (docs/brachytherapy.md). Pure computation: the consensus tables come in an NsTg43Source that
 * the caller fills (engine/dose_table.c reads assets/tg43/); nothing here reads a file.
 *
 * Units are SI throughout (STYLE.md): lengths in metres, angles in radians, time in seconds,
 * dose in gray. The air-kerma strength S_K, tabulated in U (1 U = 1 uGy m^2 h^-1 =
 * 1 cGy cm^2 h^-1), is held in Gy m^2 s^-1 (1 U = 1e-6 / 3600 Gy m^2 s^-1: NS_TG43_UNIT_U);
 * the dose-rate constant Lambda, tabulated in cGy h^-1 U^-1 = cm^-2, is held in m^-2
 * (x 1e4). Then Ddot [Gy/s] = S_K [Gy m^2 s^-1] * Lambda [m^-2] * (dimensionless factors).
 *
 * The formalism (TG-43U1 Eq. 1, line source), with r0 = 1 cm, theta0 = 90 deg:
 *   Ddot(r, theta) = S_K Lambda [G_L(r, theta) / G_L(r0, theta0)] g_L(r) F(r, theta)
 *   G_L(r, theta) = beta / (L r sin(theta))  off the axis, 1 / (r^2 - L^2/4) on it,
 * beta the angle the active length L subtends at the point. A seed's total dose to full decay
 * is Ddot0 * tau, tau = T_half / ln 2 the mean life. */
#ifndef NS_DOSE_H
#define NS_DOSE_H

/* Table sizes an NsTg43Source holds (the 6711 tables: 16 radii for g_L, 6 x 11 for F). */
#define NS_TG43_MAX_G  64
#define NS_TG43_MAX_FR 32
#define NS_TG43_MAX_FT 64
/* The reference point of the formalism: r0 = 1 cm on the transverse axis. */
#define NS_TG43_R0 0.01
/* 1 U of air-kerma strength in Gy m^2 s^-1. */
#define NS_TG43_UNIT_U (1e-6 / 3600.0)
/* Points inside a seed's capsule have no dose in the formalism (G_L is infinite on the active
 * length). A point closer to the seed's axis than NS_TG43_RHO_MIN while beside the capsule
 * (|z| < NS_TG43_Z_CAP along the axis) is evaluated on the capsule's surface, at
 * rho = NS_TG43_RHO_MIN. Model 6711's capsule: 0.8 mm outer diameter, 4.55 mm long (Dolan et
 * al.'s geometry as given in the TOPAS-nBio seed documentation). [m] */
#define NS_TG43_RHO_MIN 0.4e-3
#define NS_TG43_Z_CAP   2.275e-3
/* Grid bounds (sim/ns_limits.h style: checked before the allocation they bound). */
#define NS_DOSE_MAX_SEEDS   10000
#define NS_DOSE_MAX_VOXELS  20000000L /* 160 MB of doubles: a 27 cm cube at 1 mm */
#define NS_DOSE_MIN_SPACING 1e-5      /* [m] */

/* One source model's consensus data, in SI. */
typedef struct NsTg43Source {
    double lambda;    /* dose-rate constant Lambda [m^-2] */
    double length;    /* active length L of the geometry function [m] */
    double half_life; /* [s] */
    int n_g;
    double g_r[NS_TG43_MAX_G]; /* radii of g_L [m], strictly increasing, > 0 */
    double g[NS_TG43_MAX_G];   /* g_L(g_r[i]) (> 0) */
    int n_fr, n_ft;
    double f_r[NS_TG43_MAX_FR];                /* radii of F's columns [m], strictly increasing */
    double f_theta[NS_TG43_MAX_FT];            /* F's rows [rad], 0 .. pi/2, strictly increasing */
    double f[NS_TG43_MAX_FT * NS_TG43_MAX_FR]; /* F (n_ft x n_fr, row per angle): f[t*n_fr+i] */
    int n_phi;                                 /* the 1D anisotropy function (reported only) */
    double phi_r[NS_TG43_MAX_FR];              /* [m] */
    double phi[NS_TG43_MAX_FR];
} NsTg43Source;

/* A seed: its centre, the direction of its axis (any length > 0) and its air-kerma strength. */
typedef struct NsDoseSeed {
    double pos[3];  /* [m] */
    double axis[3]; /* direction of the seed's long axis */
    double sk;      /* air-kerma strength S_K [Gy m^2 s^-1] (NS_TG43_UNIT_U per U) */
} NsDoseSeed;

/* A dose grid: n[0] x n[1] x n[2] voxels of side spacing, voxel (i, j, k) centred at
 * lo + (i + 1/2, j + 1/2, k + 1/2) * spacing, stored x fastest: dose[(k*n[1] + j)*n[0] + i]. */
typedef struct NsDoseGrid {
    double lo[3];   /* the box's low corner [m] */
    double spacing; /* [m] */
    int n[3];
    double *dose; /* total dose to full decay [Gy] (malloc'd; ns_dose_grid_free) */
} NsDoseGrid;

/* 0 if s is usable (finite, positive constants; tables in range and increasing; F covers
 * 0 .. pi/2), else -1 with what is wrong in err. */
int ns_tg43_check(const NsTg43Source *s, char *err, int err_sz);

/* The line-source geometry function G_L(r, theta) [m^-2] for active length L [m] at distance
 * r [m] (> 0) and polar angle theta [rad] from the seed's axis. On the axis (sin theta = 0) it
 * is 1 / (r^2 - L^2/4), which needs r > L/2; with L = 0 it is the point source's 1/r^2. */
double ns_tg43_geometry(double L, double r, double theta);

/* g_L(r): log-linear interpolation between tabulated radii; below the first radius the first
 * value, beyond the last the log-linear extrapolation of the last two. */
double ns_tg43_radial(const NsTg43Source *s, double r);

/* F(r, theta), theta in [0, pi] (mirrored about pi/2): linear in theta and in r between
 * tabulated points; outside the tabulated radii the nearest radius's column. */
double ns_tg43_anisotropy(const NsTg43Source *s, double r, double theta);

/* The dose rate [Gy/s] at (r, theta) from a seed of strength sk [Gy m^2 s^-1]: the formula
 * above, as written (no capsule clamp). */
double ns_tg43_dose_rate(const NsTg43Source *s, double sk, double r, double theta);

/* The mean life tau = T_half / ln 2 [s]: total dose to full decay = initial rate x tau. */
double ns_tg43_mean_life(const NsTg43Source *s);

/* Total dose to full decay [Gy] at point p [m] from the seeds, each evaluated with the capsule
 * clamp above. The grid's voxels are this at their centres. */
double ns_dose_at(const NsTg43Source *s, const NsDoseSeed *seeds, int n_seeds, const double p[3]);

/* 0 if the seeds are usable (finite position, axis of length > 0, 0 < sk finite), else -1
 * naming the first bad seed. */
int ns_dose_check_seeds(const NsDoseSeed *seeds, int n_seeds, char *err, int err_sz);

/* Fills g with the total dose to full decay at every voxel centre of the box [lo, hi] at the
 * given spacing (the box is covered: n = ceil(size / spacing) voxels a side), summing the seeds
 * in order (so the result does not depend on threads). threads > 1 splits the slices over
 * OpenMP threads when the build has OpenMP. Returns 0, or -1 with err (bad source, seeds, box
 * or spacing; too many voxels; out of memory) and g left empty. */
int ns_dose_grid(const NsTg43Source *s, const NsDoseSeed *seeds, int n_seeds, const double lo[3],
                 const double hi[3], double spacing, int threads, NsDoseGrid *g, char *err,
                 int err_sz);

void ns_dose_grid_free(NsDoseGrid *g);

/* Total dose to full decay [Gy] at each of n points (pts: n x 3 [m]) into out (n), as
 * ns_dose_at, the seeds summed in order (so the result does not depend on threads; threads > 1
 * splits the points over OpenMP threads when the build has OpenMP). Returns 0, or -1 with err
 * (bad source or seeds, n outside 0..NS_DOSE_MAX_VOXELS, out of memory). */
int ns_dose_points(const NsTg43Source *s, const NsDoseSeed *seeds, int n_seeds, const double *pts,
                   long n, int threads, double *out, char *err, int err_sz);

#endif
