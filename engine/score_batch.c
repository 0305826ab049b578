/* `needlesim score`'s replays, N at a time, as children of this program (score.h). */
#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "cleanup.h"
#include "err.h"
#include "file_in.h"
#include "names.h"
#include "out_files.h"
#include "score.h"
#include "score_csv.h"

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

void ns_score_session_dir(const NsScoreOpts *o, const NsScoreSession *s, char *buf, size_t n)
{
    snprintf(buf, n, "%s/sessions/%s", o->out, s->name);
}

int ns_score_write_file(const char *dir, const char *name, const char *text, size_t len, char *err,
                        int err_sz)
{
    char part[4400], final[4400];
    snprintf(final, sizeof final, "%s/%s", dir, name);
    snprintf(part, sizeof part, "%s/.%s.part", dir, name);
    if (ns_out_replaceable(final, name, err, err_sz))
        return -1;
    FILE *f = ns_out_create_part(part, name, err, err_sz);
    if (!f)
        return -1;
    size_t put = fwrite(text, 1, len, f);
    int bad = put != len || ferror(f);
    bad |= fclose(f) != 0;
    if (bad || ns_out_commit(part, final)) {
        ns_set_err(err, err_sz, "cannot write '%s': %s", final, strerror(errno));
        ns_out_remove_part(part);
        return -1;
    }
    return 0;
}

/* A small file (at most max bytes) into a malloc'd string, or NULL. */
static char *slurp(const char *path, long long max)
{
    char e[256];
    long long size = 0;
    int fd = ns_file_open_regular(path, max, "file", &size, e, (int)sizeof e);
    if (fd < 0)
        return NULL;
    char *buf = malloc((size_t)max + 1);
    size_t got = 0;
    while (buf && got < (size_t)max) {
        ssize_t k = read(fd, buf + got, (size_t)max - got);
        if (k < 0 && errno == EINTR)
            continue;
        if (k <= 0)
            break;
        got += (size_t)k;
    }
    close(fd);
    if (buf)
        buf[got] = '\0';
    return buf;
}

/* The row of DIR/score_row.csv (its second line, checked: 15 fields), malloc'd, or NULL. */
static char *read_row(const char *dir)
{
    char path[4400];
    snprintf(path, sizeof path, "%s/score_row.csv", dir);
    char *text = slurp(path, NS_SCORE_ROW_MAX);
    if (!text)
        return NULL;
    char *nl = strchr(text, '\n');
    size_t hn = strlen(NS_SCORE_RUN_HEADER);
    char *row = NULL;
    if (nl && (size_t)(nl - text) == hn && strncmp(text, NS_SCORE_RUN_HEADER, hn) == 0) {
        char *end = strchr(nl + 1, '\n');
        if (end && end[1] == '\0') {
            *end = '\0';
            char copy[NS_SCORE_ROW_MAX + 1], *f[NS_SCORE_RUN_COLUMNS + 1];
            snprintf(copy, sizeof copy, "%s", nl + 1);
            if (ns_csv_split(copy, f, NS_SCORE_RUN_COLUMNS + 1) == NS_SCORE_RUN_COLUMNS)
                row = strdup(nl + 1);
        }
    }
    free(text);
    return row;
}

bool ns_score_read_cached(const NsScoreOpts *o, NsScoreSession *s)
{
    char dir[4400], path[4500], want[32];
    ns_score_session_dir(o, s, dir, sizeof dir);
    snprintf(path, sizeof path, "%s/scored", dir);
    char *mark = slurp(path, 64);
    snprintf(want, sizeof want, "%016" PRIx64 "\n", s->key);
    bool same = mark && strcmp(mark, want) == 0;
    free(mark);
    char *row = same ? read_row(dir) : NULL;
    if (!row)
        return false;
    free(s->row);
    s->row = row;
    s->done = s->ok = s->cached = true;
    return true;
}

/* Starts the replay of s; its stderr goes to errfile. Returns the pid, or -1. */
static pid_t spawn(const NsScoreOpts *o, const NsScoreSession *s, const char *dir,
                   const char *errfile)
{
    const char *argv[16 + 2 * NS_CONTROL_LOG_MAX_SETS];
    int n = 0;
    argv[n++] = "needlesim";
    argv[n++] = "run";
    argv[n++] = s->scenario_file;
    argv[n++] = "--replay";
    argv[n++] = s->log;
    argv[n++] = "--no-render";
    argv[n++] = "--quiet";
    argv[n++] = "--score-row";
    argv[n++] = "-o";
    argv[n++] = dir;
    if (o->rescore)
        argv[n++] = "--rescore";
    for (int k = 0; k < s->prov.nsets; k++) { /* the same --set values as the recording */
        argv[n++] = "--set";
        argv[n++] = s->prov.sets[k];
    }
    argv[n] = NULL;
    int fd = open(errfile, O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0644);
    if (fd < 0)
        return -1;
    ns_cleanup_add(errfile);
    pid_t parent = getpid();
    pid_t pid = fork();
    if (pid == 0) {
        /* The replay ends with the batch: a killed `score` leaves no replay running. */
        prctl(PR_SET_PDEATHSIG, SIGTERM);
        if (getppid() != parent)
            _exit(127);
        int null = open("/dev/null", O_WRONLY);
        if (null < 0 || dup2(null, 1) < 0 || dup2(fd, 2) < 0)
            _exit(127);
        execv("/proc/self/exe", (char *const *)argv);
        _exit(127);
    }
    close(fd);
    return pid;
}

/* The error a failed replay gave: its stderr's last line, the output folder shown as OUT (so
 * that rows do not depend on where the batch wrote). */
static void replay_error(const NsScoreOpts *o, const char *errfile, int status, char *out, size_t n)
{
    char *text = slurp(errfile, 1 << 20);
    char line[1024] = "";
    if (text) {
        size_t len = strlen(text);
        while (len > 0 && text[len - 1] == '\n')
            text[--len] = '\0';
        char *last = strrchr(text, '\n');
        snprintf(line, sizeof line, "%s", last ? last + 1 : text);
        free(text);
    }
    if (!line[0] && WIFSIGNALED(status))
        snprintf(line, sizeof line, "the replay was killed by signal %d", WTERMSIG(status));
    else if (!line[0])
        snprintf(line, sizeof line, "the replay failed (exit %d) and said nothing",
                 WIFEXITED(status) ? WEXITSTATUS(status) : -1);
    /* "OUT/..." for the output folder */
    size_t on = strlen(o->out), k = 0;
    for (const char *p = line; *p && k + 1 < n;) {
        if (strncmp(p, o->out, on) == 0 && p[on] == '/') {
            k += (size_t)snprintf(out + k, n - k, "OUT");
            k = k < n ? k : n - 1;
            p += on;
        } else {
            out[k++] = *p++;
        }
    }
    out[k] = '\0';
    ns_one_line(out);
}

/* A replay ended: its row or its error. */
static void finish(const NsScoreOpts *o, NsScoreSession *s, int status, int done, int total)
{
    char dir[4400], errfile[4500];
    ns_score_session_dir(o, s, dir, sizeof dir);
    snprintf(errfile, sizeof errfile, "%s/sessions/.%s.err", o->out, s->name);
    s->done = true;
    if (WIFEXITED(status) && WEXITSTATUS(status) == 0) {
        s->row = read_row(dir);
        char mark[32], e[512];
        int n = snprintf(mark, sizeof mark, "%016" PRIx64 "\n", s->key);
        if (!s->row)
            snprintf(s->error, sizeof s->error, "the replay wrote no valid score_row.csv");
        else if (ns_score_write_file(dir, "scored", mark, (size_t)n, e, (int)sizeof e))
            snprintf(s->error, sizeof s->error, "%s", e);
        s->ok = s->row != NULL;
    } else {
        replay_error(o, errfile, status, s->error, sizeof s->error);
    }
    ns_out_remove_part(errfile);
    if (!o->quiet)
        fprintf(stderr, "needlesim score: [%d/%d] %s: %s%s (%.1f s)\n", done, total, s->log,
                s->ok ? "ok" : "error: ", s->ok ? "" : s->error, now_s() - s->t0);
}

int ns_score_run_sessions(const NsScoreOpts *o, NsScoreSession *s, int n, char *err, int err_sz)
{
    int todo = 0, done = 0, running = 0, next = 0;
    for (int i = 0; i < n; i++)
        todo += !s[i].done && s[i].dup_of < 0;
    while (done < todo) {
        while (running < o->jobs && next < n && !ns_cleanup_signal()) {
            NsScoreSession *x = &s[next++];
            if (x->done || x->dup_of >= 0)
                continue;
            char dir[4400], errfile[4500];
            ns_score_session_dir(o, x, dir, sizeof dir);
            snprintf(errfile, sizeof errfile, "%s/sessions/.%s.err", o->out, x->name);
            ns_out_remove_part(errfile); /* a stopped batch's */
            x->t0 = now_s();
            x->pid = spawn(o, x, dir, errfile);
            if (x->pid < 0) {
                ns_set_err(err, err_sz, "cannot start a replay (%s): %s", errfile, strerror(errno));
                break;
            }
            running++;
        }
        if (running == 0)
            break;
        int status;
        pid_t pid = waitpid(-1, &status, 0);
        if (pid < 0 && errno == EINTR)
            continue;
        if (pid < 0)
            break;
        for (int i = 0; i < n; i++)
            if (s[i].pid == pid && !s[i].done) {
                s[i].pid = 0;
                running--;
                done++;
                finish(o, &s[i], status, done, todo);
                break;
            }
    }
    if (running > 0 || ns_cleanup_signal() || done < todo) {
        for (int i = 0; i < n; i++) /* stopped: the running replays end too */
            if (s[i].pid > 0 && !s[i].done)
                kill(s[i].pid, SIGTERM);
        while (wait(NULL) > 0 || errno == EINTR)
            ;
        if (!err[0])
            ns_set_err(err, err_sz, "stopped (%d of %d replays done)", done, todo);
        return -1;
    }
    for (int i = 0; i < n; i++) /* the same log (same inputs) given twice: one replay */
        if (s[i].dup_of >= 0) {
            const NsScoreSession *d = &s[s[i].dup_of];
            s[i].done = true;
            s[i].ok = d->ok;
            s[i].row = d->row ? strdup(d->row) : NULL;
            snprintf(s[i].error, sizeof s[i].error, "%s", d->error);
        }
    return 0;
}
