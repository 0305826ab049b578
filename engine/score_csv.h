/* The rows of `needlesim score` (docs/scoring.md): scores.csv's columns, the part of a row a
 * replay writes into its folder (`run --score-row`: DIR/score_row.csv), and a reader for the
 * rows (the cohort report and the Slurm merge read them back).
 *
 * scores.csv, one row per log in the order given:
 *
 *     log,trainee,session,scenario,scenario_hash,status,error,score,targets,targets_hit,
 *     target_error_mm_max,target_errors_mm,obstacles_violated,obstacles_entered,sim_time_s,
 *     steps,warnings_nan,warnings_inverted,warnings_unconverged,warnings_lcp_unresolved,
 *     state_hash
 *
 * The fields from `scenario` on, less scenario_hash, status and error, are the replay's own
 * (NS_SCORE_RUN_HEADER): what `run --score-row` writes. */
#ifndef NS_SCORE_CSV_H
#define NS_SCORE_CSV_H

#include <stdbool.h>
#include <stdio.h>

#define NS_SCORE_CSV_HEADER                                                                        \
    "log,trainee,session,scenario,scenario_hash,status,error,score,targets,targets_hit,"           \
    "target_error_mm_max,target_errors_mm,obstacles_violated,obstacles_entered,sim_time_s,"        \
    "steps,warnings_nan,warnings_inverted,warnings_unconverged,warnings_lcp_unresolved,"           \
    "state_hash"
#define NS_SCORE_COLUMNS 21
/* what score_row.csv holds: scenario, then score .. state_hash */
#define NS_SCORE_RUN_HEADER                                                                        \
    "scenario,score,targets,targets_hit,target_error_mm_max,target_errors_mm,"                     \
    "obstacles_violated,obstacles_entered,sim_time_s,steps,warnings_nan,warnings_inverted,"        \
    "warnings_unconverged,warnings_lcp_unresolved,state_hash"
#define NS_SCORE_RUN_COLUMNS 15
/* column indexes in scores.csv */
enum {
    NS_SC_LOG,
    NS_SC_TRAINEE,
    NS_SC_SESSION,
    NS_SC_SCENARIO,
    NS_SC_SCENARIO_HASH,
    NS_SC_STATUS,
    NS_SC_ERROR,
    NS_SC_SCORE,
    NS_SC_TARGETS,
    NS_SC_TARGETS_HIT,
    NS_SC_TARGET_ERROR_MAX,
    NS_SC_TARGET_ERRORS,
    NS_SC_OBSTACLES_VIOLATED,
    NS_SC_OBSTACLES_ENTERED,
    NS_SC_SIM_TIME,
    NS_SC_STEPS,
};

/* The longest row read back (a row's fields are bounded: paths, names, one-line messages). */
#define NS_SCORE_ROW_MAX 8192

/* Writes s as one CSV field: quoted (with "" for ") when it has a comma, a quote or spaces at
 * its ends; control characters as '?', so a row is always one line. */
void ns_csv_field(FILE *f, const char *s);

/* Splits one CSV line (no newline) in place into at most max fields; returns how many, or -1
 * when a quoted field is not closed or there are more than max. */
int ns_csv_split(char *line, char **fields, int max);

#endif
