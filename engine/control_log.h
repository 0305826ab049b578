/* Trainee control logs: the controls applied at every step of a run, as CSV, written by
 * `needlesim run --record LOG.csv` and read back by `--replay LOG.csv` (docs/scenarios.md).
 * A session captured on any device can be converted to this format and scored later.
 *
 *     t_s,v_insert_m_s,base_vx_m_s,base_vy_m_s,base_vz_m_s,twist_rate_rad_s,event
 *     0,0.02,0,0,0,0,
 *     0.01,0.02,0,0,0,0,drop_seed
 *     0.02,0,0,0,0,0,next_needle:0.008;-0.004;0;0;0;1
 *
 * Row k holds the controls applied for the step from t = k dt; numbers are written with 17
 * significant digits, so a replay applies exactly the recorded values. Lines starting with '#'
 * may come before the header; "#set KEY=VALUE" lines name the --set values of the recorded run,
 * which its replay must repeat. */
#ifndef NS_CONTROL_LOG_H
#define NS_CONTROL_LOG_H

#include <stdio.h>

#define NS_CONTROL_LOG_HEADER                                                                      \
    "t_s,v_insert_m_s,base_vx_m_s,base_vy_m_s,base_vz_m_s,twist_rate_rad_s,event"

/* A needle's entry: a point on the skin, the direction it goes in (unit), and optionally where
 * a bevel tip steers first (unit, normal to the direction). */
typedef struct NsEntry {
    double point[3], direction[3], bevel_toward[3];
    int has_bevel_toward;
} NsEntry;

typedef struct NsControl {
    double v_insert;   /* [m/s], negative retracts */
    double v_base[3];  /* sleeve velocity [m/s] */
    double twist_rate; /* [rad/s] */
    int drop_seed;     /* event: release a seed at the tip before the step */
    int next_needle;   /* event: a new needle at `entry` (the last one is out) */
    NsEntry entry;
} NsControl;

#define NS_CONTROL_LOG_MAX_SETS 32

typedef struct NsControlLog {
    NsControl *rows;
    long n;
    char sets[NS_CONTROL_LOG_MAX_SETS][256]; /* the --set KEY=VALUE it was recorded with */
    int nsets;
} NsControlLog;

/* Reads a log for a scenario stepping by dt: '#' lines, the header above, then one row per step
 * whose t is k dt (within dt / 1000), finite decimal numbers, the event empty, "drop_seed" or
 * "next_needle:px;py;pz;dx;dy;dz[;bx;by;bz]" (the new entry: point, direction, bevel_toward).
 * Returns 0, or -1 with "path:line: ..." in err. */
int ns_control_log_read(const char *path, double dt, NsControlLog *log, char *err, int err_sz);
void ns_control_log_free(NsControlLog *log);

/* Writes "#set KEY=VALUE" for each --set the run has (a replay must be given the same ones),
 * then the header line. */
void ns_control_log_write_header(FILE *f, const char *const *sets, int nsets);
void ns_control_log_write_row(FILE *f, double t, const NsControl *c);

#endif
