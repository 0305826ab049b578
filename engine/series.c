/* Per-step series (series.h). */
#include "series.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

double ns_wall_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

double ns_thread_cpu_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* ---- per-step series (medians, percentiles) ---- */

int ns_series_push(NsSeries *s, double x)
{
    if (s->n == s->cap) {
        int cap = s->cap ? 2 * s->cap : 256;
        double *v = realloc(s->v, (size_t)cap * sizeof *v);
        if (!v)
            return -1;
        s->v = v;
        s->cap = cap;
    }
    s->v[s->n++] = x;
    return 0;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* The q-quantile (nearest rank) of the series; 0 when empty. Sorts a copy. */
double ns_series_quantile(const NsSeries *s, double q)
{
    if (s->n == 0)
        return 0.0;
    double *c = malloc((size_t)s->n * sizeof *c);
    if (!c)
        return NAN;
    memcpy(c, s->v, (size_t)s->n * sizeof *c);
    qsort(c, (size_t)s->n, sizeof *c, cmp_double);
    int k = (int)ceil(q * s->n) - 1;
    double v = c[k < 0 ? 0 : k >= s->n ? s->n - 1 : k];
    free(c);
    return v;
}

void ns_series_range(const NsSeries *s, double *lo, double *mean, double *hi)
{
    *lo = *mean = *hi = 0.0;
    for (int i = 0; i < s->n; i++) {
        *lo = i ? fmin(*lo, s->v[i]) : s->v[i];
        *hi = i ? fmax(*hi, s->v[i]) : s->v[i];
        *mean += s->v[i] / s->n;
    }
}

double ns_series_mean(const NsSeries *s)
{
    double lo, mean, hi;
    ns_series_range(s, &lo, &mean, &hi);
    return mean;
}
