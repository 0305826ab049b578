/* Dose-volume figures of one region from the doses at its voxels (docs/brachytherapy.md): the
 * cumulative dose-volume histogram's readings that the AAPM and ABS guidelines judge an implant
 * by. Every voxel stands for the same volume; the figures are read off the voxels sorted from
 * the hottest down, without interpolation. Pure computation. */
#ifndef NS_DVH_H
#define NS_DVH_H

/* One region's voxel doses, sorted in decreasing order. */
typedef struct NsDvh {
    double *dose; /* (n) [Gy], hottest first (malloc'd; ns_dvh_free) */
    long n;
    double voxel_volume; /* [m^3] */
} NsDvh;

/* Copies the n doses (finite, >= 0) and sorts them. Returns 0, or -1 with err (n < 1, a voxel
 * volume not > 0, a dose not finite or negative, out of memory). */
int ns_dvh_make(NsDvh *d, const double *dose, long n, double voxel_volume, char *err, int err_sz);

void ns_dvh_free(NsDvh *d);

/* D_x: the least dose received by the hottest pct % of the region [Gy] (the dose of the
 * ceil(pct/100 n)-th hottest voxel); pct in (0, 100]. */
double ns_dvh_d_pct(const NsDvh *d, double pct);

/* D_v: the least dose received by the hottest volume v [m^3] of the region (all of it when the
 * region is smaller than v). */
double ns_dvh_d_vol(const NsDvh *d, double v);

/* V_D: the volume receiving at least dose D [Gy], in m^3 and as a % of the region. */
double ns_dvh_v_vol(const NsDvh *d, double dose);
double ns_dvh_v_pct(const NsDvh *d, double dose);

#endif
