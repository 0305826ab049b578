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
 * may come before the header, "#KEY VALUE": what the log was recorded with (its provenance),
 *
 *     #needlesim 0.1.0                  the program's version
 *     #scenario prostate brachytherapy  the scenario's name (control characters as '?', 200 bytes)
 *     #scenario_hash 8c2f0e13a4b5c6d7   FNV-1a 64 of the scenario file's bytes, 16 hex digits
 *     #trainee A-17 / #session 2026-11-27.3   with --trainee / --session ([A-Za-z0-9._-]{1,64})
 *     #set KEY=VALUE                    each --set of the run, which its replay must repeat
 *     #source live                      recorded by `needlesim live`: the session may end before
 *                                       the scenario's duration, and a replay ends with the log
 *     #model dt=D tolerance=T check_tolerance=C lazy_threshold=L
 *                                       the time step and solver settings the session chose
 *                                       instead of the scenario's (live --accuracy); a replay
 *                                       steps with them (%.17g, so bit for bit)
 *
 * Other '#' lines are comments, skipped (later versions add keys). A replay refuses a log whose
 * scenario hash is not its scenario file's, or whose version is not this program's, unless told
 * to re-score it (--rescore); a log without a hash
 * (older logs, hand-written ones) is replayed with a warning. The values of a row are bounded
 * by ns_limits.h (NS_LIMIT_INSERT_SPEED, ..._BASE_SPEED, ..._TWIST_RATE), the rows by
 * NS_LIMIT_STEPS and the file by NS_LIMIT_LOG_FILE_BYTES (a regular file only). */
#ifndef NS_CONTROL_LOG_H
#define NS_CONTROL_LOG_H

#include <stdbool.h>
#include <stdint.h>
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

/* A run's time step and solver settings, when chosen apart from the scenario's (#model). */
typedef struct NsLogModel {
    double dt, tolerance, check_tolerance, lazy_threshold;
} NsLogModel;

/* Trainee and session IDs: 1 to NS_CONTROL_LOG_ID_MAX characters of [A-Za-z0-9._-]. */
#define NS_CONTROL_LOG_ID_MAX 64

typedef struct NsControlLog {
    NsControl *rows;
    long n;
    char sets[NS_CONTROL_LOG_MAX_SETS][256]; /* the --set KEY=VALUE it was recorded with */
    int nsets;
    /* provenance: empty strings, has_hash false, when the log has no such line */
    char version[64];   /* #needlesim */
    char scenario[256]; /* #scenario */
    uint64_t scenario_hash;
    bool has_hash;
    long hash_line;    /* the #scenario_hash line, for messages */
    long version_line; /* the #needlesim line, for messages */
    char trainee[NS_CONTROL_LOG_ID_MAX + 1], session[NS_CONTROL_LOG_ID_MAX + 1];
    bool live; /* #source live */
    bool has_model;
    NsLogModel model; /* #model: the rows step by model.dt */
} NsControlLog;

/* What a recorded log says it was recorded with. trainee and session may be NULL. */
typedef struct NsLogProvenance {
    const char *version, *scenario;
    uint64_t scenario_hash;
    const char *trainee, *session;
    bool live;               /* a live session's log: #source live */
    const NsLogModel *model; /* #model, or NULL */
} NsLogProvenance;

/* Reads a log for a scenario stepping by dt (by its #model's dt when it has one): '#' lines, the
 * header above, then one row per step whose t is k dt (within dt / 1000), finite decimal numbers
 * within the limits, the event empty, "drop_seed" or "next_needle:px;py;pz;dx;dy;dz[;bx;by;bz]"
 * (the new entry: point, direction, bevel_toward). Returns 0, or -1 with "path:line: ..." in err.
 */
int ns_control_log_read(const char *path, double dt, NsControlLog *log, char *err, int err_sz);
void ns_control_log_free(NsControlLog *log);

/* Whether the log may drive a replay of the scenario `name` whose file hashes to `hash` by this
 * program, whose version is `version`: 0 when its #scenario_hash is that hash and its
 * #needlesim that version; when the hash is another, -1 with "path:line: recorded against
 * scenario 'X' (hash ...), not 'Y' (hash ...); --rescore replays it anyway" in err; when the
 * version is another, -1 with "path:line: recorded by needlesim V1 against scenario 'X' (hash
 * ...), this is needlesim V2 with 'Y' (hash ...); --rescore replays it anyway"; with rescore, 0
 * and a note in `note` instead. Without a #scenario_hash line, 0 and a warning in `note` (the
 * caller says it once the run has succeeded, so a failed run's message stays one line); a log
 * without a #needlesim line is not checked for its version. note is "" when there is nothing
 * to say. */
int ns_control_log_check_scenario(const NsControlLog *log, const char *path, const char *name,
                                  uint64_t hash, const char *version, bool rescore, char *note,
                                  int note_sz, char *err, int err_sz);

/* Reads only the '#' lines of a log, up to its header line (what `needlesim score` needs to
 * find the log's scenario): the provenance fields of `log` (no rows). Returns 0, or -1 with
 * "path:line: ..." in err. The same checks as ns_control_log_read for those lines. */
int ns_control_log_read_provenance(const char *path, NsControlLog *log, char *err, int err_sz);

/* 64-bit FNV-1a (the state hashes' function: sim/tissue.c) of a file's bytes: a regular file
 * of at most max_bytes (`what` names it in messages). Returns 0, or -1 with "path: message" in
 * err. */
int ns_file_hash(const char *path, long long max_bytes, const char *what, uint64_t *hash, char *err,
                 int err_sz);

/* A trainee or session ID: 1 to NS_CONTROL_LOG_ID_MAX characters of [A-Za-z0-9._-]. */
bool ns_control_log_id_ok(const char *id);

/* Writes the provenance lines (#needlesim, #scenario, #scenario_hash, #trainee and #session
 * when given), "#set KEY=VALUE" for each --set the run has (a replay must be given the same
 * ones), then the header line. */
void ns_control_log_write_header(FILE *f, const NsLogProvenance *prov, const char *const *sets,
                                 int nsets);
void ns_control_log_write_row(FILE *f, double t, const NsControl *c);

#endif
