/* The fuzz harnesses' one shared helper: the parsers under test take a path, so each input is
 * written to a file in a directory private to the fuzzing process (mkdtemp, removed at exit),
 * under a fixed name whose extension the parser expects. One file at a time: libFuzzer runs
 * one input at a time per process, and each harness unlinks the file after the call. */
#ifndef NS_FUZZ_FILE_H
#define NS_FUZZ_FILE_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static char fuzz_dir[256];

static void fuzz_dir_remove(void)
{
    if (fuzz_dir[0])
        rmdir(fuzz_dir);
}

/* Writes data to <private dir>/<name> and returns its path (a static buffer), or NULL. The
 * caller unlinks it. */
static const char *fuzz_write_file(const char *name, const uint8_t *data, size_t size)
{
    static char path[512];
    if (!fuzz_dir[0]) {
        const char *tmp = getenv("TMPDIR");
        snprintf(fuzz_dir, sizeof fuzz_dir, "%s/needlesim-fuzz.XXXXXX",
                 tmp && tmp[0] ? tmp : "/tmp");
        if (!mkdtemp(fuzz_dir)) {
            perror("mkdtemp");
            abort();
        }
        atexit(fuzz_dir_remove);
    }
    snprintf(path, sizeof path, "%s/%s", fuzz_dir, name);
    FILE *f = fopen(path, "wb");
    if (!f) {
        perror(path);
        abort(); /* the harness's own failure, not a finding in the parser */
    }
    if (size > 0 && fwrite(data, 1, size, f) != size) {
        perror(path);
        abort();
    }
    if (fclose(f) != 0) {
        perror(path);
        abort();
    }
    return path;
}

/* NS_FUZZ_VERBOSE=1 prints each input's message to stderr: to see what a reproducer gets. */
static void fuzz_report(const char *err)
{
    static int verbose = -1;
    if (verbose < 0) {
        const char *v = getenv("NS_FUZZ_VERBOSE");
        verbose = v && v[0] && strcmp(v, "0") != 0;
    }
    if (verbose)
        fprintf(stderr, "fuzz: %s\n", err[0] ? err : "(no error)");
}

#endif
