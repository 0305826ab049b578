/* Per-step series (medians, percentiles) and the wall clock, for run statistics and bench. */
#ifndef NS_SERIES_H
#define NS_SERIES_H

typedef struct NsSeries {
    double *v;
    int n, cap;
} NsSeries;

double ns_wall_s(void);
/* The calling thread's CPU time [s]. */
double ns_thread_cpu_s(void);
int ns_series_push(NsSeries *s, double x);
double ns_series_quantile(const NsSeries *s, double q);
void ns_series_range(const NsSeries *s, double *lo, double *mean, double *hi);
double ns_series_mean(const NsSeries *s);

#endif
