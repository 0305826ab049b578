/* Dose-volume figures (dvh.h). */
#include "dvh.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "err.h"

static int hotter_first(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x < y) - (x > y);
}

int ns_dvh_make(NsDvh *d, const double *dose, long n, double voxel_volume, char *err, int err_sz)
{
    memset(d, 0, sizeof *d);
    if (n < 1 || !dose) {
        ns_set_err(err, err_sz, "a dose-volume histogram needs at least one voxel (got %ld)", n);
        return -1;
    }
    if (!(isfinite(voxel_volume) && voxel_volume > 0.0)) {
        ns_set_err(err, err_sz, "voxel volume %g m^3: must be > 0", voxel_volume);
        return -1;
    }
    for (long i = 0; i < n; i++)
        if (!(isfinite(dose[i]) && dose[i] >= 0.0)) {
            ns_set_err(err, err_sz, "voxel %ld: dose %g Gy is not finite and >= 0", i, dose[i]);
            return -1;
        }
    d->dose = malloc((size_t)n * sizeof *d->dose);
    if (!d->dose) {
        ns_set_err(err, err_sz, "out of memory (%ld voxels)", n);
        return -1;
    }
    memcpy(d->dose, dose, (size_t)n * sizeof *d->dose);
    qsort(d->dose, (size_t)n, sizeof *d->dose, hotter_first);
    d->n = n;
    d->voxel_volume = voxel_volume;
    return 0;
}

void ns_dvh_free(NsDvh *d)
{
    free(d->dose);
    memset(d, 0, sizeof *d);
}

/* The dose of the k-th hottest voxel, k counted from 1 and clamped to 1..n. */
static double kth(const NsDvh *d, double k)
{
    long i = k <= 1.0 ? 0 : k >= (double)d->n ? d->n - 1 : (long)k - 1;
    return d->dose[i];
}

double ns_dvh_d_pct(const NsDvh *d, double pct)
{
    /* the 1e-9 keeps an exact product (90% of 10 voxels) from rounding up a voxel */
    return kth(d, ceil(pct / 100.0 * (double)d->n - 1e-9));
}

double ns_dvh_d_vol(const NsDvh *d, double v)
{
    return kth(d, ceil(v / d->voxel_volume - 1e-9));
}

/* The count of voxels with dose >= D: binary search in the decreasing list. */
static long count_at_least(const NsDvh *d, double dose)
{
    long lo = 0, hi = d->n; /* dose[0 .. lo) >= D, dose[hi ..) < D */
    while (lo < hi) {
        long mid = lo + (hi - lo) / 2;
        if (d->dose[mid] >= dose)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

double ns_dvh_v_vol(const NsDvh *d, double dose)
{
    return (double)count_at_least(d, dose) * d->voxel_volume;
}

double ns_dvh_v_pct(const NsDvh *d, double dose)
{
    return 100.0 * (double)count_at_least(d, dose) / (double)d->n;
}
