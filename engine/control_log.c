/* Trainee control logs (control_log.h). */
#include "control_log.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "err.h"

void ns_control_log_free(NsControlLog *log)
{
    free(log->rows);
    log->rows = NULL;
    log->n = 0;
}

void ns_control_log_write_header(FILE *f, const char *const *sets, int nsets)
{
    for (int i = 0; i < nsets; i++)
        fprintf(f, "#set %s\n", sets[i]);
    fputs(NS_CONTROL_LOG_HEADER "\n", f);
}

void ns_control_log_write_row(FILE *f, double t, const NsControl *c)
{
    fprintf(f, "%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,", t, c->v_insert, c->v_base[0], c->v_base[1],
            c->v_base[2], c->twist_rate);
    if (c->next_needle) {
        const NsEntry *e = &c->entry;
        fprintf(f, "next_needle:%.17g;%.17g;%.17g;%.17g;%.17g;%.17g", e->point[0], e->point[1],
                e->point[2], e->direction[0], e->direction[1], e->direction[2]);
        if (e->has_bevel_toward)
            fprintf(f, ";%.17g;%.17g;%.17g", e->bevel_toward[0], e->bevel_toward[1],
                    e->bevel_toward[2]);
    } else if (c->drop_seed) {
        fputs("drop_seed", f);
    }
    fputc('\n', f);
}

/* "px;py;pz;dx;dy;dz[;bx;by;bz]" into e; 0 or -1. */
static int parse_entry(char *s, NsEntry *e)
{
    double v[9];
    int n = 0;
    for (char *tok = s; tok && n < 10;) {
        char *semi = strchr(tok, ';');
        if (semi)
            *semi = '\0';
        char *end;
        size_t len = strlen(tok);
        if (n == 9 || len == 0 || strspn(tok, "0123456789+-.eE") != len)
            return -1;
        v[n] = strtod(tok, &end);
        if (*end || !isfinite(v[n]))
            return -1;
        n++;
        tok = semi ? semi + 1 : NULL;
    }
    if (n != 6 && n != 9)
        return -1;
    memset(e, 0, sizeof *e);
    memcpy(e->point, v, sizeof e->point);
    memcpy(e->direction, v + 3, sizeof e->direction);
    if (n == 9) {
        memcpy(e->bevel_toward, v + 6, sizeof e->bevel_toward);
        e->has_bevel_toward = 1;
    }
    double dl = sqrt(e->direction[0] * e->direction[0] + e->direction[1] * e->direction[1] +
                     e->direction[2] * e->direction[2]);
    return dl > 0.0 ? 0 : -1;
}

/* Strips a trailing "\n" and "\r". */
static void chomp(char *s)
{
    size_t n = strlen(s);
    while (n > 0 && (s[n - 1] == '\n' || s[n - 1] == '\r'))
        s[--n] = '\0';
}

static const char *const columns[7] = {"t_s",         "v_insert_m_s", "base_vx_m_s",
                                       "base_vy_m_s", "base_vz_m_s",  "twist_rate_rad_s",
                                       "event"};

int ns_control_log_read(const char *path, double dt, NsControlLog *log, char *err, int err_sz)
{
    memset(log, 0, sizeof *log);
    FILE *f = fopen(path, "r");
    if (!f) {
        ns_set_err(err, err_sz, "cannot open control log '%s': %s", path, strerror(errno));
        return -1;
    }
    char line[1024];
    long lineno = 0, cap = 0, blank = 0;
    int rc = 0;
    /* '#' lines before the header: what the log was recorded with ("#set KEY=VALUE"). */
    int got = 0;
    while ((got = fgets(line, sizeof line, f) != NULL)) {
        lineno++;
        char *p = line;
        if (lineno == 1 && (unsigned char)p[0] == 0xEF && (unsigned char)p[1] == 0xBB &&
            (unsigned char)p[2] == 0xBF)
            p += 3; /* a UTF-8 byte-order mark */
        chomp(p);
        if (p[0] != '#') {
            memmove(line, p, strlen(p) + 1);
            break;
        }
        if (strncmp(p, "#set ", 5) == 0 && log->nsets < NS_CONTROL_LOG_MAX_SETS &&
            strlen(p + 5) < sizeof log->sets[0])
            memcpy(log->sets[log->nsets++], p + 5, strlen(p + 5) + 1);
    }
    if (!got) {
        ns_set_err(err, err_sz, "%s:%ld: no header (want %s)", path, lineno + 1,
                   NS_CONTROL_LOG_HEADER);
        rc = -1;
    } else if (strcmp(line, NS_CONTROL_LOG_HEADER) != 0) {
        ns_set_err(err, err_sz, "%s:%ld: the header must be %s", path, lineno,
                   NS_CONTROL_LOG_HEADER);
        rc = -1;
    }
    long header_line = lineno;
    while (rc == 0 && fgets(line, sizeof line, f)) {
        lineno++;
        if (!strchr(line, '\n') && !feof(f)) {
            ns_set_err(err, err_sz, "%s:%ld: line too long", path, lineno);
            rc = -1;
            break;
        }
        chomp(line);
        if (line[0] == '\0') { /* blank lines may end the file, nothing else */
            if (blank == 0)
                blank = lineno;
            continue;
        }
        if (blank) {
            ns_set_err(err, err_sz, "%s:%ld: blank line inside the log", path, blank);
            rc = -1;
            break;
        }
        /* Split into 7 fields. */
        char *field[7];
        int nf = 0;
        char *p = line;
        field[nf++] = p;
        for (; *p; p++)
            if (*p == ',') {
                *p = '\0';
                if (nf == 7) {
                    nf++;
                    break;
                }
                field[nf++] = p + 1;
            }
        if (nf != 7) {
            ns_set_err(err, err_sz, "%s:%ld: expected 7 comma-separated fields (%s), got %s", path,
                       lineno, NS_CONTROL_LOG_HEADER, nf > 7 ? "more" : "fewer");
            rc = -1;
            break;
        }
        double v[6];
        for (int k = 0; k < 6 && rc == 0; k++) {
            char *end;
            errno = 0;
            v[k] = strtod(field[k], &end);
            /* Decimal numbers only (no hex floats, spaces or "inf"); tiny values that
             * underflow to subnormals are kept (strtod's ERANGE): they round-trip. */
            size_t len = strlen(field[k]);
            if (len == 0 || strspn(field[k], "0123456789+-.eE") != len || *end != '\0' ||
                !isfinite(v[k])) {
                ns_set_err(err, err_sz, "%s:%ld: %s must be a finite number (got '%s')", path,
                           lineno, columns[k], field[k]);
                rc = -1;
            }
        }
        if (rc)
            break;
        long k = lineno - header_line - 1; /* the step */
        if (fabs(v[0] - (double)k * dt) > 1e-3 * dt) {
            ns_set_err(err, err_sz,
                       "%s:%ld: t_s is %.9g but row %ld of a run stepping by dt = %g s is at "
                       "t = %.9g s",
                       path, lineno, v[0], k + 1, dt, (double)k * dt);
            rc = -1;
            break;
        }
        int drop = 0, next = 0;
        NsEntry entry;
        memset(&entry, 0, sizeof entry);
        if (strcmp(field[6], "drop_seed") == 0) {
            drop = 1;
        } else if (strncmp(field[6], "next_needle:", 12) == 0) {
            next = 1;
            if (parse_entry(field[6] + 12, &entry)) {
                ns_set_err(err, err_sz,
                           "%s:%ld: next_needle: expected px;py;pz;dx;dy;dz[;bx;by;bz] (finite "
                           "numbers, the direction not zero)",
                           path, lineno);
                rc = -1;
                break;
            }
        } else if (field[6][0] != '\0') {
            ns_set_err(err, err_sz,
                       "%s:%ld: unknown event '%s' (known: drop_seed, next_needle:..., or empty)",
                       path, lineno, field[6]);
            rc = -1;
            break;
        }
        if (log->n == cap) {
            cap = cap ? 2 * cap : 1024;
            NsControl *rows = realloc(log->rows, (size_t)cap * sizeof *rows);
            if (!rows) {
                ns_set_err(err, err_sz, "out of memory");
                rc = -1;
                break;
            }
            log->rows = rows;
        }
        NsControl *c = &log->rows[log->n++];
        c->v_insert = v[1];
        memcpy(c->v_base, v + 2, sizeof c->v_base);
        c->twist_rate = v[5];
        c->drop_seed = drop;
        c->next_needle = next;
        c->entry = entry;
    }
    if (rc == 0 && ferror(f)) {
        ns_set_err(err, err_sz, "%s: read error", path);
        rc = -1;
    }
    if (rc == 0 && log->n == 0) {
        ns_set_err(err, err_sz, "%s:%ld: the control log has no rows", path, lineno + 1);
        rc = -1;
    }
    fclose(f);
    if (rc)
        ns_control_log_free(log);
    return rc;
}
