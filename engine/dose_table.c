/* TG-43 consensus tables from the assets/tg43 CSV files (dose_table.h). */
#include "dose_table.h"

#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "data_dir.h"
#include "err.h"
#include "file_in.h"
#include "ns_limits.h"

#define MAX_FIELDS (NS_TG43_MAX_FR + 2)
#define DEG        (M_PI / 180.0)

typedef struct Parse {
    const char *path;
    int line;
    char *err;
    int err_sz;
    NsTg43Source *s;
    bool have_lambda, have_length, have_half_life, have_radii;
} Parse;

static int bad(Parse *p, int field, const char *what)
{
    if (field > 0)
        ns_set_err(p->err, p->err_sz, "%s:%d: field %d: %s", p->path, p->line, field, what);
    else
        ns_set_err(p->err, p->err_sz, "%s:%d: %s", p->path, p->line, what);
    return -1;
}

/* Field f (1-based) of fields as a finite number into *v. */
static int number(Parse *p, char **fields, int f, double *v)
{
    const char *t = fields[f - 1];
    char *end;
    errno = 0;
    double x = strtod(t, &end);
    if (end == t || *end != '\0' || errno == ERANGE || !isfinite(x))
        return bad(p, f, "not a finite number");
    *v = x;
    return 0;
}

static int expect_fields(Parse *p, int n, int want, const char *record)
{
    if (n == want)
        return 0;
    char msg[128];
    snprintf(msg, sizeof msg, "'%s' takes %d fields, found %d", record, want, n);
    return bad(p, 0, msg);
}

static int record_param(Parse *p, char **fl, int n)
{
    double v;
    if (expect_fields(p, n, 3, "param") || number(p, fl, 3, &v))
        return -1;
    if (!(v > 0.0))
        return bad(p, 3, "must be > 0");
    if (strcmp(fl[1], "lambda_cGy_per_h_per_U") == 0) {
        p->s->lambda = v * 1e4; /* cGy h^-1 U^-1 = cm^-2 -> m^-2 */
        p->have_lambda = true;
    } else if (strcmp(fl[1], "active_length_cm") == 0) {
        p->s->length = v * 1e-2;
        p->have_length = true;
    } else if (strcmp(fl[1], "half_life_d") == 0) {
        p->s->half_life = v * 86400.0;
        p->have_half_life = true;
    } else {
        return bad(p, 2,
                   "unknown parameter (lambda_cGy_per_h_per_U, active_length_cm, "
                   "half_life_d)");
    }
    return 0;
}

/* A (radius, value) pair appended to r[], v[] (count *n, at most cap): r > 0 increasing. */
static int record_pair(Parse *p, char **fl, int n, const char *record, double *r, double *v,
                       int *count, int cap)
{
    double rc, x;
    if (expect_fields(p, n, 3, record) || number(p, fl, 2, &rc) || number(p, fl, 3, &x))
        return -1;
    if (*count >= cap)
        return bad(p, 0, "too many rows");
    if (!(rc > 0.0) || (*count > 0 && !(rc * 1e-2 > r[*count - 1])))
        return bad(p, 2, "radius must be > 0 and greater than the previous row's");
    if (!(x > 0.0))
        return bad(p, 3, "must be > 0");
    r[*count] = rc * 1e-2;
    v[*count] = x;
    (*count)++;
    return 0;
}

static int record_radii(Parse *p, char **fl, int n)
{
    if (p->have_radii)
        return bad(p, 0, "a second 'F_radii' record");
    if (n < 2 || n - 1 > NS_TG43_MAX_FR)
        return bad(p, 0, "'F_radii' takes 1 to 32 radii");
    for (int f = 2; f <= n; f++) {
        double rc;
        if (number(p, fl, f, &rc))
            return -1;
        if (!(rc > 0.0) || (f > 2 && !(rc * 1e-2 > p->s->f_r[f - 3])))
            return bad(p, f, "radius must be > 0 and increasing");
        p->s->f_r[f - 2] = rc * 1e-2;
    }
    p->s->n_fr = n - 1;
    p->have_radii = true;
    return 0;
}

static int record_f(Parse *p, char **fl, int n)
{
    NsTg43Source *s = p->s;
    if (!p->have_radii)
        return bad(p, 0, "an 'F' row before the 'F_radii' record");
    if (expect_fields(p, n, 2 + s->n_fr, "F"))
        return -1;
    if (s->n_ft >= NS_TG43_MAX_FT)
        return bad(p, 0, "too many 'F' rows");
    double deg;
    if (number(p, fl, 2, &deg))
        return -1;
    if (!(deg >= 0.0 && deg <= 90.0) || (s->n_ft > 0 && !(deg * DEG > s->f_theta[s->n_ft - 1])))
        return bad(p, 2, "angle must be in 0..90 deg and greater than the previous row's");
    s->f_theta[s->n_ft] = deg == 90.0 ? M_PI / 2 : deg * DEG;
    for (int i = 0; i < s->n_fr; i++) {
        double v;
        if (number(p, fl, 3 + i, &v))
            return -1;
        if (!(v > 0.0 && v < 2.0))
            return bad(p, 3 + i, "anisotropy function must be in (0, 2)");
        s->f[s->n_ft * s->n_fr + i] = v;
    }
    s->n_ft++;
    return 0;
}

/* One line (NUL-terminated, may be modified): comment stripped, fields split on commas. */
static int parse_line(Parse *p, char *line)
{
    char *hash = strchr(line, '#');
    if (hash)
        *hash = '\0';
    char *fl[MAX_FIELDS];
    int n = 0;
    for (char *tok = line;;) {
        char *comma = strchr(tok, ',');
        if (comma)
            *comma = '\0';
        while (*tok == ' ' || *tok == '\t' || *tok == '\r')
            tok++;
        char *e = tok + strlen(tok);
        while (e > tok && (e[-1] == ' ' || e[-1] == '\t' || e[-1] == '\r'))
            *--e = '\0';
        if (n >= MAX_FIELDS)
            return bad(p, 0, "too many fields");
        fl[n++] = tok;
        if (!comma)
            break;
        tok = comma + 1;
    }
    if (n == 1 && fl[0][0] == '\0')
        return 0; /* blank or comment */
    NsTg43Source *s = p->s;
    if (strcmp(fl[0], "param") == 0)
        return record_param(p, fl, n);
    if (strcmp(fl[0], "g") == 0)
        return record_pair(p, fl, n, "g", s->g_r, s->g, &s->n_g, NS_TG43_MAX_G);
    if (strcmp(fl[0], "F_radii") == 0)
        return record_radii(p, fl, n);
    if (strcmp(fl[0], "F") == 0)
        return record_f(p, fl, n);
    if (strcmp(fl[0], "phi_an") == 0)
        return record_pair(p, fl, n, "phi_an", s->phi_r, s->phi, &s->n_phi, NS_TG43_MAX_FR);
    return bad(p, 1, "unknown record (param, g, F_radii, F, phi_an)");
}

static char *read_all(const char *path, char *err, int err_sz)
{
    long long size;
    int fd = ns_file_open_regular(path, NS_LIMIT_DOSE_TABLE_BYTES, "dosimetry table", &size, err,
                                  err_sz);
    if (fd < 0)
        return NULL;
    char *buf = malloc((size_t)size + 1);
    if (!buf) {
        close(fd);
        ns_set_err(err, err_sz, "%s: out of memory", path);
        return NULL;
    }
    long long got = 0;
    while (got < size) {
        ssize_t k = read(fd, buf + got, (size_t)(size - got));
        if (k < 0 && errno == EINTR)
            continue;
        if (k <= 0) {
            ns_set_err(err, err_sz, "%s: cannot read: %s", path, k < 0 ? strerror(errno) : "short");
            free(buf);
            close(fd);
            return NULL;
        }
        got += k;
    }
    close(fd);
    buf[size] = '\0';
    if (strlen(buf) != (size_t)size) {
        ns_set_err(err, err_sz, "%s: a NUL byte: not a text table", path);
        free(buf);
        return NULL;
    }
    return buf;
}

int ns_tg43_load(const char *path, NsTg43Source *s, char *err, int err_sz)
{
    memset(s, 0, sizeof *s);
    char *buf = read_all(path, err, err_sz);
    if (!buf)
        return -1;
    Parse p = {.path = path, .err = err, .err_sz = err_sz, .s = s};
    int rc = 0;
    char *line = buf;
    while (line && rc == 0) {
        char *nl = strchr(line, '\n');
        if (nl)
            *nl = '\0';
        p.line++;
        rc = parse_line(&p, line);
        line = nl ? nl + 1 : NULL;
    }
    free(buf);
    if (rc)
        return -1;
    const char *missing = !p.have_lambda      ? "param lambda_cGy_per_h_per_U"
                          : !p.have_length    ? "param active_length_cm"
                          : !p.have_half_life ? "param half_life_d"
                          : s->n_g < 2        ? "'g' rows (at least 2)"
                          : !p.have_radii     ? "the 'F_radii' record"
                                              : NULL;
    if (missing) {
        ns_set_err(err, err_sz, "%s: missing %s", path, missing);
        return -1;
    }
    char why[256];
    if (ns_tg43_check(s, why, sizeof why)) {
        ns_set_err(err, err_sz, "%s: %s", path, why);
        return -1;
    }
    return 0;
}

int ns_tg43_load_6711(NsTg43Source *s, char *err, int err_sz)
{
    char path[4096];
    int k = snprintf(path, sizeof path, "%s/%s", ns_data_dir("assets"), NS_TG43_6711_ASSET);
    if (k < 0 || k >= (int)sizeof path) {
        ns_set_err(err, err_sz, "the assets folder's path is too long");
        return -1;
    }
    return ns_tg43_load(path, s, err, err_sz);
}
