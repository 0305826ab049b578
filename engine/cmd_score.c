/* needlesim score LOG.csv... -o OUT [--jobs N] [--scenario-dir DIR] [--rescore]
 *                  [--slurm [--partition P] [--array-chunk K]]
 *
 * Scores a training programme's logs (docs/scoring.md, score.h): each log's scenario is found
 * in DIR by the hash its #scenario_hash line records, its replay runs as a child of this
 * program, and one row per log, in the order given, goes into OUT/scores.csv (score_csv.h),
 * with the cohort report beside it. A log that cannot be scored is a row with its error. A
 * session whose folder holds a result for the same inputs (its key: the log's bytes, the
 * scenario file's, the version, --rescore) is not run again, so a stopped batch resumes. */
#include <dirent.h>
#include <errno.h>
#include <inttypes.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "cleanup.h"
#include "commands.h"
#include "control_log.h"
#include "data_dir.h"
#include "err.h"
#include "file_in.h"
#include "names.h"
#include "ns_config.h"
#include "ns_limits.h"
#include "score.h"
#include "score_csv.h"

static const char score_usage[] =
    "usage: needlesim score LOG.csv... -o OUT [--jobs N] [--scenario-dir DIR] [--rescore]\n"
    "                       [--quiet] [--slurm [--partition P] [--array-chunk K]]\n";

static int usage_error(const char *fmt, const char *arg)
{
    char line[600];
    snprintf(line, sizeof line, fmt, arg);
    ns_one_line(line);
    fprintf(stderr, "needlesim score: %s (needlesim score --help)\n", line);
    return 2;
}

/* A positive integer argument in 1..max, or -1. */
static int count_arg(const char *v, int max)
{
    char *end;
    long n = v ? strtol(v, &end, 10) : 0;
    return v && *v && !*end && n >= 1 && n <= max ? (int)n : -1;
}

static int parse_args(int argc, char **argv, NsScoreOpts *o)
{
    o->jobs = 1;
    o->chunk = 4;
    o->logs = calloc((size_t)argc, sizeof *o->logs);
    if (!o->logs)
        return usage_error("%s", "out of memory");
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        bool valued = strcmp(a, "-o") == 0 || strcmp(a, "--jobs") == 0 ||
                      strcmp(a, "--scenario-dir") == 0 || strcmp(a, "--partition") == 0 ||
                      strcmp(a, "--array-chunk") == 0 || strcmp(a, "--chunk-file") == 0 ||
                      strcmp(a, "--rows") == 0;
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            fputs(score_usage, stdout);
            return 1;
        } else if (valued && (!v || !v[0])) {
            return usage_error("%s needs a value", a);
        } else if (strcmp(a, "-o") == 0) {
            o->out = v;
        } else if (strcmp(a, "--scenario-dir") == 0) {
            o->scenario_dir = v;
        } else if (strcmp(a, "--partition") == 0) {
            for (const char *c = v; *c; c++)
                if (!strchr("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789._-",
                            *c))
                    return usage_error("--partition '%s': A-Z a-z 0-9 . _ - only", v);
            o->partition = v;
        } else if (strcmp(a, "--chunk-file") == 0) {
            o->chunk_file = v;
        } else if (strcmp(a, "--rows") == 0) {
            o->rows_out = v;
        } else if (strcmp(a, "--jobs") == 0 || strcmp(a, "--array-chunk") == 0) {
            bool jobs = a[2] == 'j';
            int n = count_arg(v, jobs ? NS_SCORE_MAX_JOBS : NS_SCORE_MAX_LOGS);
            if (n < 0)
                return usage_error(jobs ? "--jobs '%s': expected 1 to 64"
                                        : "--array-chunk '%s': expected a positive integer",
                                   v);
            *(jobs ? &o->jobs : &o->chunk) = n;
        } else if (strcmp(a, "--rescore") == 0) {
            o->rescore = true;
        } else if (strcmp(a, "--slurm") == 0) {
            o->slurm = true;
        } else if (strcmp(a, "--quiet") == 0) {
            o->quiet = true;
        } else if (a[0] == '-' && a[1] != '\0') {
            return usage_error("unknown option '%s'", a);
        } else {
            if (o->nlogs == NS_SCORE_MAX_LOGS)
                return usage_error("more than %s logs (run several batches into the same OUT)",
                                   "10000");
            o->logs[o->nlogs++] = a;
        }
        i += valued;
    }
    if (!o->out)
        return usage_error("%s", "-o OUT is required (the folder the scores go to)");
    if (!o->nlogs && !o->chunk_file)
        return usage_error("%s", "no LOG.csv given");
    if ((o->chunk_file != NULL) != (o->rows_out != NULL) || (o->chunk_file && o->nlogs))
        return usage_error("%s", "--chunk-file and --rows go together, without logs");
    if (!o->slurm && (o->partition || o->chunk != 4))
        return usage_error("%s", "--partition and --array-chunk need --slurm");
    if (!o->scenario_dir)
        o->scenario_dir = ns_data_dir("scenarios");
    return 0;
}

/* A folder of the output that must be a real folder (not a link out of OUT): made if missing.
 * 0, or -1 with a message. */
static int real_dir(const char *path, char *err, int err_sz)
{
    struct stat st;
    if (lstat(path, &st) != 0) {
        if (errno == ENOENT && mkdir(path, 0777) == 0)
            return 0;
        /* made meanwhile by another process (Slurm tasks start together): looked at again */
        if (errno != EEXIST || lstat(path, &st) != 0) {
            ns_set_err(err, err_sz, "cannot create output folder '%s': %s", path, strerror(errno));
            return -1;
        }
    }
    if (!S_ISDIR(st.st_mode)) {
        ns_set_err(err, err_sz, "'%s' is not a folder (a link or a file): outputs stay in OUT",
                   path);
        return -1;
    }
    return 0;
}

/* OUT (made with its parents), OUT/sessions. */
static int prepare_out(const NsScoreOpts *o, char *err, int err_sz)
{
    char path[PATH_MAX];
    snprintf(path, sizeof path, "%s", o->out);
    for (char *p = path + 1; *p; p++) /* mkdir -p */
        if (*p == '/') {
            *p = '\0';
            mkdir(path, 0777);
            *p = '/';
        }
    struct stat st;
    if (stat(o->out, &st) != 0 && mkdir(o->out, 0777) != 0) {
        ns_set_err(err, err_sz, "cannot create output folder '%s': %s", o->out, strerror(errno));
        return -1;
    }
    if (stat(o->out, &st) != 0 || !S_ISDIR(st.st_mode)) {
        ns_set_err(err, err_sz, "-o '%s' is not a folder", o->out);
        return -1;
    }
    snprintf(path, sizeof path, "%s/sessions", o->out);
    return real_dir(path, err, err_sz);
}

typedef struct Scenario {
    char path[4096];
    uint64_t hash;
} Scenario;

static int by_path(const void *a, const void *b)
{
    return strcmp(((const Scenario *)a)->path, ((const Scenario *)b)->path);
}

/* The regular *.lua files of dir and their hashes, sorted by name. */
static Scenario *scan_scenarios(const char *dir, int *n)
{
    *n = 0;
    DIR *d = opendir(dir);
    Scenario *sc = calloc(NS_SCORE_MAX_SCENARIOS, sizeof *sc);
    struct dirent *e;
    while (d && sc && *n < NS_SCORE_MAX_SCENARIOS && (e = readdir(d)) != NULL) {
        size_t len = strlen(e->d_name);
        if (len < 5 || strcmp(e->d_name + len - 4, ".lua") != 0 || e->d_name[0] == '.')
            continue;
        Scenario *s = &sc[*n];
        char msg[256];
        if (snprintf(s->path, sizeof s->path, "%s/%s", dir, e->d_name) < (int)sizeof s->path &&
            ns_file_hash(s->path, NS_LIMIT_SCRIPT_FILE_BYTES, "scenario file", &s->hash, msg,
                         (int)sizeof msg) == 0)
            (*n)++;
    }
    if (d)
        closedir(d);
    if (sc)
        qsort(sc, (size_t)*n, sizeof *sc, by_path);
    return sc;
}

static uint64_t fnv(uint64_t h, const char *s)
{
    for (; *s; s++) {
        h ^= (unsigned char)*s;
        h *= 0x100000001b3ull;
    }
    return h;
}

/* A session's provenance, scenario file and key, or its error. */
static void setup_session(const NsScoreOpts *o, NsScoreSession *s, const Scenario *sc, int nsc)
{
    s->dup_of = -1;
    if (ns_control_log_read_provenance(s->log, &s->prov, s->error, (int)sizeof s->error)) {
        s->done = true;
        return;
    }
    const NsControlLog *p = &s->prov;
    for (int k = 0; k < nsc && p->has_hash && !s->resolved; k++)
        if (sc[k].hash == p->scenario_hash) {
            snprintf(s->scenario_file, sizeof s->scenario_file, "%s", sc[k].path);
            s->file_hash = sc[k].hash;
            s->resolved = true;
        }
    /* No file with its hash: the file of its name, which its replay refuses (naming both
     * hashes) unless --rescore, or warns about when the log has no hash. */
    char want[4400];
    snprintf(want, sizeof want, "%s/%s.lua", o->scenario_dir, p->scenario);
    for (int k = 0; k < nsc && p->scenario[0] && !s->resolved; k++)
        if (ns_control_log_id_ok(p->scenario) && strcmp(sc[k].path, want) == 0) {
            snprintf(s->scenario_file, sizeof s->scenario_file, "%s", sc[k].path);
            s->file_hash = sc[k].hash;
            s->resolved = true;
        }
    if (!s->resolved) {
        if (p->has_hash)
            snprintf(s->error, sizeof s->error,
                     "%s: recorded against scenario '%.80s' (hash %016" PRIx64
                     "): no scenario file in %s has that hash or name",
                     s->log, p->scenario[0] ? p->scenario : "?", p->scenario_hash, o->scenario_dir);
        else
            snprintf(s->error, sizeof s->error,
                     "%s: no #scenario_hash line and no scenario file in %s named '%.80s.lua'",
                     s->log, o->scenario_dir, p->scenario);
        ns_one_line(s->error);
        s->done = true;
        return;
    }
    uint64_t log_hash;
    if (ns_file_hash(s->log, NS_LIMIT_LOG_FILE_BYTES, "control log", &log_hash, s->error,
                     (int)sizeof s->error)) {
        s->done = true;
        return;
    }
    char in[256];
    snprintf(in, sizeof in,
             "needlesim-score 1\nlog %016" PRIx64 "\nscenario %016" PRIx64
             "\nversion %s\nrescore %d\n",
             log_hash, s->file_hash, NS_VERSION, (int)o->rescore);
    s->key = fnv(0xcbf29ce484222325ull, in);
    if (p->trainee[0] && p->session[0])
        snprintf(s->name, sizeof s->name, "%s.%s.%016" PRIx64, p->trainee, p->session, s->key);
    else
        snprintf(s->name, sizeof s->name, "%016" PRIx64, s->key);
}

/* The session's row of scores.csv (score_csv.h), without its newline. */
static void format_row(const NsScoreSession *s, FILE *f)
{
    const NsControlLog *p = &s->prov;
    char *rf[NS_SCORE_RUN_COLUMNS + 1], copy[NS_SCORE_ROW_MAX + 1], hash[20] = "";
    int nf = 0;
    if (s->ok && s->row) {
        snprintf(copy, sizeof copy, "%s", s->row);
        nf = ns_csv_split(copy, rf, NS_SCORE_RUN_COLUMNS + 1);
    }
    bool ok = nf == NS_SCORE_RUN_COLUMNS;
    if (s->resolved)
        snprintf(hash, sizeof hash, "%016" PRIx64, s->file_hash);
    else if (p->has_hash)
        snprintf(hash, sizeof hash, "%016" PRIx64, p->scenario_hash);
    const char *head[7] = {s->log,
                           p->trainee,
                           p->session,
                           ok ? rf[0] : p->scenario,
                           hash,
                           ok ? "ok" : "error",
                           ok ? "" : (s->error[0] ? s->error : "no result")};
    for (int k = 0; k < 7; k++) {
        if (k)
            fputc(',', f);
        ns_csv_field(f, head[k]);
    }
    for (int k = 1; k < NS_SCORE_RUN_COLUMNS; k++) {
        fputc(',', f);
        ns_csv_field(f, ok ? rf[k] : "");
    }
}

/* Each session's row, malloc'd. */
static char **format_rows(const NsScoreSession *s, int n)
{
    char **rows = calloc((size_t)n, sizeof *rows);
    for (int i = 0; rows && i < n; i++) {
        size_t len = 0;
        FILE *m = open_memstream(&rows[i], &len);
        if (m) {
            format_row(&s[i], m);
            fclose(m);
        }
    }
    return rows;
}

/* scores.csv (or, for a Slurm task, its rows file "INDEX,ROW"), then the cohort report. */
static int write_outputs(const NsScoreOpts *o, char **rows, int n, char *err, int err_sz)
{
    char *text = NULL;
    size_t len = 0;
    FILE *m = open_memstream(&text, &len);
    if (!m) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    if (!o->rows_out)
        fputs(NS_SCORE_CSV_HEADER "\n", m);
    for (int i = 0; i < n; i++) {
        if (o->rows_out)
            fprintf(m, "%d,", o->index[i]);
        fprintf(m, "%s\n", rows[i] ? rows[i] : "");
    }
    fclose(m);
    int rc;
    if (o->rows_out) {
        char dir[PATH_MAX];
        const char *slash = strrchr(o->rows_out, '/');
        snprintf(dir, sizeof dir, "%.*s", slash ? (int)(slash - o->rows_out) : 1,
                 slash ? o->rows_out : ".");
        rc = ns_score_write_file(dir, slash ? slash + 1 : o->rows_out, text, len, err, err_sz);
    } else {
        rc = ns_score_write_file(o->out, "scores.csv", text, len, err, err_sz);
        if (rc == 0)
            rc = ns_score_write_cohort(o->out, rows, n, err, err_sz);
    }
    free(text);
    return rc;
}

/* --chunk-file: "INDEX<TAB>LOG" lines (written by the Slurm client) into o->logs, o->index. */
static int read_chunk(NsScoreOpts *o, char *err, int err_sz)
{
    FILE *f = fopen(o->chunk_file, "r");
    if (!f) {
        ns_set_err(err, err_sz, "%s: %s", o->chunk_file, strerror(errno));
        return -1;
    }
    char line[PATH_MAX + 32];
    int cap = 0;
    while (fgets(line, sizeof line, f)) {
        char *tab = strchr(line, '\t'), *nl = strchr(line, '\n'), *end;
        long idx = strtol(line, &end, 10);
        if (!tab || !nl || end != tab || idx < 0 || idx >= NS_SCORE_MAX_LOGS ||
            o->nlogs == NS_SCORE_MAX_LOGS) {
            ns_set_err(err, err_sz, "%s: a line is not INDEX<TAB>LOG", o->chunk_file);
            fclose(f);
            return -1;
        }
        *nl = '\0';
        if (o->nlogs == cap) {
            cap = cap ? 2 * cap : 64;
            const char **l = realloc(o->logs, (size_t)cap * sizeof *l);
            int *x = realloc(o->index, (size_t)cap * sizeof *x);
            if (l)
                o->logs = l;
            if (x)
                o->index = x;
            if (!l || !x) {
                fclose(f);
                ns_set_err(err, err_sz, "out of memory");
                return -1;
            }
        }
        o->index[o->nlogs] = (int)idx;
        o->logs[o->nlogs++] = strdup(tab + 1);
    }
    fclose(f);
    return 0;
}

int ns_cmd_score(int argc, char **argv)
{
    NsScoreOpts o;
    memset(&o, 0, sizeof o);
    int pa = parse_args(argc, argv, &o);
    if (pa) {
        free(o.logs);
        return pa == 1 ? 0 : pa;
    }
    ns_cleanup_install();
    char err[1024] = "";
    int rc = o.chunk_file ? read_chunk(&o, err, sizeof err) : 0;
    rc = rc ? rc : prepare_out(&o, err, sizeof err);
    int nsc = 0;
    Scenario *sc = rc ? NULL : scan_scenarios(o.scenario_dir, &nsc);
    NsScoreSession *s = calloc((size_t)(o.nlogs ? o.nlogs : 1), sizeof *s);
    if (rc == 0 && (!sc || !s)) {
        ns_set_err(err, sizeof err, "out of memory");
        rc = -1;
    }
    int cached = 0, errors = 0, failed = 0, dups = 0;
    for (int i = 0; rc == 0 && i < o.nlogs; i++) {
        s[i].log = o.logs[i];
        setup_session(&o, &s[i], sc, nsc);
        if (!s[i].done && ns_score_read_cached(&o, &s[i]))
            cached++;
        else if (s[i].done)
            failed++; /* its log or scenario could not be read: an error row, no replay */
        for (int k = 0; k < i && !s[i].done && s[i].dup_of < 0; k++)
            if (!s[k].done && s[k].dup_of < 0 && s[k].key == s[i].key) {
                s[i].dup_of = k; /* the same inputs: replayed once */
                dups++;
            }
    }
    if (rc == 0 && !o.quiet)
        fprintf(stderr,
                "needlesim score: %d logs, %d already scored, %d to replay (%d at a time)\n",
                o.nlogs, cached, o.nlogs - cached - failed - dups, o.jobs);
    char **rows = NULL;
    if (rc == 0 && o.slurm) {
        rows = calloc((size_t)o.nlogs, sizeof *rows);
        for (int i = 0; i < o.nlogs; i++) /* what a row no task wrote says */
            if (!s[i].done)
                snprintf(s[i].error, sizeof s[i].error,
                         "its Slurm task wrote no row (OUT/slurm/task-%d.out)", i / o.chunk);
        char **mine = rows ? format_rows(s, o.nlogs) : NULL;
        rc = mine ? ns_score_slurm(&o, s, o.nlogs, mine, rows, err, sizeof err) : -1;
        for (int i = 0; mine && i < o.nlogs; i++)
            free(mine[i]);
        free(mine);
    } else if (rc == 0) {
        rc = ns_score_run_sessions(&o, s, o.nlogs, err, sizeof err);
        rows = rc ? NULL : format_rows(s, o.nlogs);
    }
    int replayed = 0;
    for (int i = 0; rc == 0 && i < o.nlogs; i++) {
        char copy[NS_SCORE_ROW_MAX + 1], *f[NS_SCORE_COLUMNS + 1];
        snprintf(copy, sizeof copy, "%s", rows[i] ? rows[i] : "");
        errors += ns_csv_split(copy, f, NS_SCORE_COLUMNS + 1) != NS_SCORE_COLUMNS ||
                  strcmp(f[NS_SC_STATUS], "ok") != 0;
        replayed += s[i].resolved && !s[i].cached && s[i].dup_of < 0;
    }
    if (rc == 0)
        rc = write_outputs(&o, rows, o.nlogs, err, sizeof err);
    if (rc == 0 && !o.quiet)
        fprintf(stderr,
                "needlesim score: %d sessions: %d replayed, %d already scored, %d errors; wrote "
                "%s/%s\n",
                o.nlogs, replayed, cached, errors, o.rows_out ? "" : o.out,
                o.rows_out ? o.rows_out : "scores.csv, cohort.json, cohort.html, cohort.png");
    if (rc) {
        ns_one_line(err);
        fprintf(stderr, "needlesim score: %s\n", err);
    }
    for (int i = 0; i < o.nlogs; i++) {
        free(s[i].row);
        if (rows)
            free(rows[i]);
        if (o.chunk_file)
            free((char *)o.logs[i]);
    }
    free(rows);
    free(s);
    free(sc);
    free(o.logs);
    free(o.index);
    return rc ? 1 : 0;
}
