/* `needlesim score` (docs/scoring.md): trainee logs replayed N at a time, as child processes of
 * this program (`run --replay LOG --no-render --quiet --score-row -o OUT/sessions/NAME`), into
 * OUT/scores.csv (score_csv.h), OUT/cohort.json, OUT/cohort.html and OUT/cohort.png; or, with
 * --slurm, as one Slurm job array whose tasks each score a chunk of the logs (the same code, on
 * their own lists) and whose rows the client merges into the same files. */
#ifndef NS_SCORE_H
#define NS_SCORE_H

#include <stdbool.h>
#include <stdint.h>
#include <sys/types.h>

#include "control_log.h"

#define NS_SCORE_MAX_LOGS      10000 /* logs in one batch (a session holds ~15 KiB) */
#define NS_SCORE_MAX_SCENARIOS 1000  /* .lua files looked at in --scenario-dir */
#define NS_SCORE_MAX_JOBS      64

typedef struct NsScoreOpts {
    const char *out, *scenario_dir;
    const char **logs; /* as given (the `log` column) */
    int nlogs;
    int jobs;
    bool rescore;
    /* --slurm: one job array; --partition, --array-chunk K logs per task */
    bool slurm;
    const char *partition;
    int chunk;
    /* a Slurm task: --chunk-file FILE lists "INDEX<TAB>LOG" lines; the rows go to --rows FILE
     * as "INDEX,ROW" lines instead of scores.csv and the cohort report */
    const char *chunk_file, *rows_out;
    int *index; /* the index of each log in the whole batch (chunk tasks), or NULL */
    bool quiet;
} NsScoreOpts;

typedef struct NsScoreSession {
    const char *log;
    NsControlLog prov; /* its '#' lines */
    char scenario_file[4096];
    uint64_t file_hash; /* the scenario file's */
    bool resolved;
    uint64_t key;   /* the inputs' content hash: log bytes, scenario file, version, --rescore */
    char name[200]; /* the folder under OUT/sessions */
    int dup_of;     /* an earlier session with the same key, or -1 */
    bool done, ok, cached;
    char error[1024];
    char *row; /* the replay's fields (score_row.csv's second line), malloc'd */
    pid_t pid;
    double t0;
} NsScoreSession;

/* engine/score_batch.c: runs the sessions not yet done, `jobs` at a time, as children of this
 * program; each ends ok (row set) or with its error. Progress on stderr. Returns 0, or -1 with
 * a message when it could not run at all (or was stopped by a signal). */
int ns_score_run_sessions(const NsScoreOpts *o, NsScoreSession *s, int n, char *err, int err_sz);
/* The session's result folder, OUT/sessions/NAME, into buf. */
void ns_score_session_dir(const NsScoreOpts *o, const NsScoreSession *s, char *buf, size_t n);
/* Reads OUT/sessions/NAME/score_row.csv's row when its `scored` marker holds the session's key;
 * true when it did (the session is already scored). */
bool ns_score_read_cached(const NsScoreOpts *o, NsScoreSession *s);

/* engine/score_slurm.c: --slurm: the logs in chunks of o->chunk, one Slurm job array (`sbatch
 * --wait --array=0-M`) whose task i runs `needlesim score --chunk-file OUT/slurm/chunk-i.txt
 * --rows OUT/slurm/rows-i.csv -o OUT`, then the tasks' rows merged into rows[] in the logs'
 * order; a row no task wrote is the session's own row (pending[]) with an error naming the
 * task's output. 0, or -1 with a message (sbatch could not be run). */
int ns_score_slurm(const NsScoreOpts *o, const NsScoreSession *s, int n, char *const *pending,
                   char **rows, char *err, int err_sz);

/* engine/score_cohort.c: OUT/cohort.json, OUT/cohort.html and OUT/cohort.png from scores.csv's
 * rows (text lines without the header). 0, or -1 with a message. */
int ns_score_write_cohort(const char *out, char *const *rows, int n, char *err, int err_sz);

/* Writes text to DIR/NAME through a .part file renamed into place. 0, or -1 with a message. */
int ns_score_write_file(const char *dir, const char *name, const char *text, size_t len, char *err,
                        int err_sz);

#endif
