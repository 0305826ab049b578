/* `needlesim score --slurm` (score.h): one job array, then the tasks' rows merged. */
#include <errno.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include "err.h"
#include "out_files.h"
#include "score.h"
#include "score_csv.h"

/* s as one single-quoted shell word into f. */
static void shell_word(FILE *f, const char *s)
{
    fputc('\'', f);
    for (; *s; s++)
        if (*s == '\'')
            fputs("'\\''", f);
        else
            fputc(*s, f);
    fputc('\'', f);
}

/* OUT/slurm/chunk-i.txt for each chunk and OUT/slurm/job.sh. 0, or -1 with a message. */
static int write_inputs(const NsScoreOpts *o, int n, const char *dir, int chunks, char *err,
                        int err_sz)
{
    for (int c = 0; c < chunks; c++) {
        char *text = NULL, name[64], rows[64], path[PATH_MAX + 64];
        size_t len = 0;
        FILE *m = open_memstream(&text, &len);
        if (!m)
            return ns_set_err(err, err_sz, "out of memory"), -1;
        for (int i = c * o->chunk; i < n && i < (c + 1) * o->chunk; i++)
            fprintf(m, "%d\t%s\n", i, o->logs[i]);
        fclose(m);
        snprintf(name, sizeof name, "chunk-%d.txt", c);
        snprintf(rows, sizeof rows, "rows-%d.csv", c);
        snprintf(path, sizeof path, "%s/%s", dir, rows);
        ns_out_remove_old(path); /* an earlier batch's */
        int rc = ns_score_write_file(dir, name, text, len, err, err_sz);
        free(text);
        if (rc)
            return -1;
    }
    char exe[PATH_MAX];
    ssize_t k = readlink("/proc/self/exe", exe, sizeof exe - 1);
    if (k <= 0)
        return ns_set_err(err, err_sz, "cannot find this program: %s", strerror(errno)), -1;
    exe[k] = '\0';
    char *text = NULL;
    size_t len = 0;
    FILE *m = open_memstream(&text, &len);
    if (!m)
        return ns_set_err(err, err_sz, "out of memory"), -1;
    fputs("#!/bin/sh\n# needlesim score --slurm: one task of the job array (docs/scoring.md)\n"
          "i=$SLURM_ARRAY_TASK_ID\nexec ",
          m);
    shell_word(m, exe);
    fputs(" score --quiet --chunk-file ", m);
    shell_word(m, dir);
    fputs("/chunk-\"$i\".txt --rows ", m);
    shell_word(m, dir);
    fputs("/rows-\"$i\".csv -o ", m);
    shell_word(m, o->out);
    fputs(" --scenario-dir ", m);
    shell_word(m, o->scenario_dir);
    fprintf(m, " --jobs %d%s\n", o->jobs, o->rescore ? " --rescore" : "");
    fclose(m);
    int rc = ns_score_write_file(dir, "job.sh", text, len, err, err_sz);
    free(text);
    return rc;
}

/* Runs sbatch --wait; its exit status (a failed task makes it non-zero), or -1. */
static int submit(const NsScoreOpts *o, const char *dir, int chunks)
{
    char array[64], output[PATH_MAX + 64], script[PATH_MAX + 64], part[128], cpus[32];
    snprintf(array, sizeof array, "--array=0-%d", chunks - 1);
    snprintf(output, sizeof output, "--output=%s/task-%%a.out", dir);
    snprintf(script, sizeof script, "%s/job.sh", dir);
    snprintf(part, sizeof part, "--partition=%s", o->partition ? o->partition : "");
    snprintf(cpus, sizeof cpus, "--cpus-per-task=%d", o->jobs);
    const char *argv[16];
    int n = 0;
    argv[n++] = "sbatch";
    argv[n++] = "--wait";
    argv[n++] = "--job-name=needlesim-score";
    argv[n++] = array;
    argv[n++] = output;
    argv[n++] = cpus;
    if (o->partition)
        argv[n++] = part;
    argv[n++] = script;
    argv[n] = NULL;
    if (!o->quiet)
        fprintf(stderr, "needlesim score: sbatch %s %s (%d tasks of up to %d logs); waiting\n",
                array, script, chunks, o->chunk);
    pid_t pid = fork();
    if (pid == 0) {
        dup2(2, 1); /* sbatch's "Submitted batch job N" with the progress, on stderr */
        execvp("sbatch", (char *const *)argv);
        _exit(127);
    }
    int st;
    if (pid < 0)
        return -1;
    while (waitpid(pid, &st, 0) < 0)
        if (errno != EINTR)
            return -1;
    return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

/* The rows of OUT/slurm/rows-c.csv into rows[] (lines "INDEX,ROW", INDEX within the chunk). */
static void merge(const NsScoreOpts *o, const char *dir, int c, int n, char **rows)
{
    char path[PATH_MAX + 64], line[NS_SCORE_ROW_MAX + 32];
    snprintf(path, sizeof path, "%s/rows-%d.csv", dir, c);
    FILE *f = fopen(path, "r");
    while (f && fgets(line, sizeof line, f)) {
        char *end, *nl = strchr(line, '\n');
        long i = strtol(line, &end, 10);
        if (!nl || *end != ',' || end == line || i < (long)c * o->chunk ||
            i >= (long)(c + 1) * o->chunk || i >= n || rows[i])
            continue; /* not a row of this chunk: left for the session's own */
        *nl = '\0';
        char copy[NS_SCORE_ROW_MAX + 32], *fields[NS_SCORE_COLUMNS + 1];
        snprintf(copy, sizeof copy, "%s", end + 1);
        if (ns_csv_split(copy, fields, NS_SCORE_COLUMNS + 1) == NS_SCORE_COLUMNS &&
            strcmp(fields[0], o->logs[i]) == 0)
            rows[i] = strdup(end + 1);
    }
    if (f)
        fclose(f);
}

int ns_score_slurm(const NsScoreOpts *o, const NsScoreSession *s, int n, char *const *pending,
                   char **rows, char *err, int err_sz)
{
    (void)s;
    char dir[PATH_MAX];
    snprintf(dir, sizeof dir, "%s/slurm", o->out);

    int chunks = (n + o->chunk - 1) / o->chunk;
    struct stat st;
    if (mkdir(dir, 0777) != 0 && errno != EEXIST)
        return ns_set_err(err, err_sz, "cannot create '%s': %s", dir, strerror(errno)), -1;
    if (lstat(dir, &st) != 0 || !S_ISDIR(st.st_mode)) /* not a link out of OUT */
        return ns_set_err(err, err_sz,
                          "'%s' is not a folder (a link or a file): outputs stay "
                          "in OUT",
                          dir),
               -1;
    if (write_inputs(o, n, dir, chunks, err, err_sz))
        return -1;
    int rc = submit(o, dir, chunks);
    if (rc < 0 || rc == 127)
        return ns_set_err(err, err_sz,
                          "cannot run sbatch (is Slurm's client installed, "
                          "SLURM_CONF set? tools/slurm-local.sh)"),
               -1;
    if (rc != 0 && !o->quiet)
        fprintf(stderr,
                "needlesim score: sbatch says a task failed (exit %d); merging what "
                "the tasks wrote\n",
                rc);
    for (int c = 0; c < chunks; c++)
        merge(o, dir, c, n, rows);
    for (int i = 0; i < n; i++)
        if (!rows[i] && pending[i])
            rows[i] = strdup(pending[i]);
    return 0;
}
