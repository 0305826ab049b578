/* The planned path's CSV (plan_path_csv.h). The file comes from other people: every line is
 * checked (its length, three numbers and nothing else, each finite and bounded) and the count
 * and size are bounded before they are stored. */
#include "plan_path_csv.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "err.h"
#include "file_in.h"

#define HEADER     "x_m,y_m,z_m"
#define LINE_MAX_B 256
/* 100,000 lines of three numbers, generously written */
#define FILE_MAX_BYTES ((long long)NS_PLAN_PATH_MAX_POINTS * 80 + 4096)

int ns_plan_path_csv_write(FILE *f, const double *xyz, int n)
{
    fprintf(f, HEADER "\n");
    for (int i = 0; i < n; i++)
        fprintf(f, "%.17g,%.17g,%.17g\n", xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
    return ferror(f) ? -1 : 0;
}

/* One data line's three numbers into p; NULL, or what is wrong. */
static const char *parse_point(char *s, double p[3])
{
    for (int k = 0; k < 3; k++) {
        while (*s == ' ')
            s++;
        char *end;
        errno = 0;
        p[k] = strtod(s, &end);
        if (end == s)
            return "expected three numbers x_m,y_m,z_m";
        if (!isfinite(p[k]) || fabs(p[k]) > NS_PLAN_PATH_MAX_ABS)
            return "a coordinate is not a finite number within 10 m";
        s = end;
        while (*s == ' ')
            s++;
        if (k < 2 && *s++ != ',')
            return "expected three numbers x_m,y_m,z_m";
    }
    return *s ? "expected three numbers x_m,y_m,z_m (something follows the third)" : NULL;
}

int ns_plan_path_csv_read(const char *path, double **xyz, int *n, char *err, int err_sz)
{
    *xyz = NULL;
    *n = 0;
    long long size = 0;
    int fd = ns_file_open_regular(path, FILE_MAX_BYTES, "plan path", &size, err, err_sz);
    if (fd < 0)
        return -1;
    char *buf = malloc((size_t)size + 1);
    long long got = 0;
    while (buf && got < size) {
        ssize_t k = read(fd, buf + got, (size_t)(size - got));
        if (k < 0 && errno == EINTR)
            continue;
        if (k <= 0)
            break;
        got += k;
    }
    close(fd);
    if (!buf || got != size) {
        ns_set_err(err, err_sz, "%s: %s", path, buf ? "cannot read it whole" : "out of memory");
        free(buf);
        return -1;
    }
    buf[size] = '\0';
    long lineno = 0;
    int count = 0, cap = 0;
    double *pts = NULL;
    const char *why = NULL;
    for (char *line = buf; !why && line < buf + size;) {
        char *end = memchr(line, '\n', (size_t)(buf + size - line));
        size_t len = end ? (size_t)(end - line) : (size_t)(buf + size - line);
        char *next = end ? end + 1 : buf + size;
        lineno++;
        if (memchr(line, '\0', len)) {
            why = "a NUL byte";
            break;
        }
        if (len > LINE_MAX_B) {
            why = "a line longer than 256 bytes";
            break;
        }
        line[len] = '\0';
        if (len > 0 && line[len - 1] == '\r')
            line[--len] = '\0';
        if (lineno == 1) {
            if (strcmp(line, HEADER) != 0)
                why = "expected the header x_m,y_m,z_m";
            line = next;
            continue;
        }
        if (count == NS_PLAN_PATH_MAX_POINTS) {
            why = "more than 100000 points";
            break;
        }
        if (count == cap) {
            cap = cap ? 2 * cap : 256;
            double *q = realloc(pts, (size_t)cap * 3 * sizeof *q);
            if (!q) {
                why = "out of memory";
                break;
            }
            pts = q;
        }
        why = parse_point(line, pts + 3 * count);
        count += why == NULL;
        line = next;
    }
    free(buf);
    if (!why && lineno == 0) {
        lineno = 1;
        why = "empty (expected the header x_m,y_m,z_m)";
    }
    if (!why && count < 2) {
        lineno++;
        why = "a path needs at least 2 points";
    }
    if (why) {
        free(pts);
        ns_set_err(err, err_sz, "%s:%ld: %s", path, lineno, why);
        return -1;
    }
    *xyz = pts;
    *n = count;
    return 0;
}
