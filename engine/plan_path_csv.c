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
    int fd = ns_file_open_regular(path, FILE_MAX_BYTES, "plan path", NULL, err, err_sz);
    FILE *f = fd >= 0 ? fdopen(fd, "r") : NULL;
    if (!f) {
        if (fd >= 0) {
            ns_set_err(err, err_sz, "%s: cannot open: %s", path, strerror(errno));
            close(fd);
        }
        return -1;
    }
    char line[LINE_MAX_B + 2];
    long lineno = 0;
    int count = 0, cap = 0;
    double *pts = NULL;
    const char *why = NULL;
    while (!why && fgets(line, sizeof line, f)) {
        lineno++;
        size_t len = strlen(line);
        if (len > 0 && line[len - 1] == '\n')
            line[--len] = '\0';
        else if (!feof(f)) {
            why = "a line longer than 256 bytes";
            break;
        }
        if (len > 0 && line[len - 1] == '\r')
            line[--len] = '\0';
        if (lineno == 1) {
            if (strcmp(line, HEADER) != 0)
                why = "expected the header x_m,y_m,z_m";
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
    }
    if (!why && ferror(f))
        why = "cannot read";
    if (!why && lineno == 0) {
        lineno = 1;
        why = "empty (expected the header x_m,y_m,z_m)";
    }
    if (!why && count < 2) {
        lineno++;
        why = "a path needs at least 2 points";
    }
    fclose(f);
    if (why) {
        free(pts);
        ns_set_err(err, err_sz, "%s:%ld: %s", path, lineno, why);
        return -1;
    }
    *xyz = pts;
    *n = count;
    return 0;
}
