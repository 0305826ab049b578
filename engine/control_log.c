/* Trainee control logs (control_log.h). */
#include "control_log.h"

#include <errno.h>
#include <inttypes.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "err.h"
#include "file_in.h"
#include "ns_limits.h"

void ns_control_log_free(NsControlLog *log)
{
    free(log->rows);
    log->rows = NULL;
    log->n = 0;
}

bool ns_control_log_id_ok(const char *id)
{
    size_t n = strlen(id);
    return n >= 1 && n <= NS_CONTROL_LOG_ID_MAX &&
           strspn(id, "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789._-") == n;
}

/* A name as one line of a log: control characters and DEL as '?', at most 200 bytes (a
 * reader takes lines of up to 1023). */
static void put_name(FILE *f, const char *s)
{
    for (int n = 0; *s && n < 200; s++, n++)
        fputc((unsigned char)*s < 0x20 || *s == 0x7f ? '?' : *s, f);
}

void ns_control_log_write_header(FILE *f, const NsLogProvenance *prov, const char *const *sets,
                                 int nsets)
{
    if (prov) {
        fprintf(f, "#needlesim %s\n#scenario ", prov->version);
        put_name(f, prov->scenario);
        fprintf(f, "\n#scenario_hash %016" PRIx64 "\n", prov->scenario_hash);
        if (prov->trainee)
            fprintf(f, "#trainee %s\n", prov->trainee);
        if (prov->session)
            fprintf(f, "#session %s\n", prov->session);
        if (prov->live)
            fputs("#source live\n", f);
        if (prov->model)
            fprintf(f,
                    "#model dt=%.17g tolerance=%.17g check_tolerance=%.17g lazy_threshold=%.17g\n",
                    prov->model->dt, prov->model->tolerance, prov->model->check_tolerance,
                    prov->model->lazy_threshold);
    }
    for (int i = 0; i < nsets; i++)
        fprintf(f, "#set %s\n", sets[i]);
    fputs(NS_CONTROL_LOG_HEADER "\n", f);
}

int ns_file_hash(const char *path, long long max_bytes, const char *what, uint64_t *hash, char *err,
                 int err_sz)
{
    int fd = ns_file_open_regular(path, max_bytes, what, NULL, err, err_sz);
    if (fd < 0)
        return -1;
    uint64_t h = 0xcbf29ce484222325ull; /* FNV-1a 64: offset basis, then prime per byte */
    unsigned char buf[65536];
    long long total = 0;
    for (;;) {
        ssize_t got = read(fd, buf, sizeof buf);
        if (got < 0 && errno == EINTR)
            continue;
        if (got < 0) {
            ns_set_err(err, err_sz, "%s: cannot read: %s", path, strerror(errno));
            close(fd);
            return -1;
        }
        if (got == 0)
            break;
        total += got;
        if (total > max_bytes) {
            ns_set_err(err, err_sz, "%s: the file grew past the limit of %lld bytes", path,
                       max_bytes);
            close(fd);
            return -1;
        }
        for (ssize_t i = 0; i < got; i++) {
            h ^= buf[i];
            h *= 0x100000001b3ull;
        }
    }
    close(fd);
    *hash = h;
    return 0;
}

/* A name for a message: at most 80 bytes, control characters as '?'. */
static const char *show_name(const char *s, char out[88])
{
    size_t n = 0;
    for (; s[n] && n < 80; n++)
        out[n] = (unsigned char)s[n] < 0x20 || s[n] == 0x7f ? '?' : s[n];
    if (s[n])
        memcpy(out + n, "...", 4);
    else
        out[n] = '\0';
    return out;
}

int ns_control_log_check_scenario(const NsControlLog *log, const char *path, const char *name,
                                  uint64_t hash, const char *version, bool rescore, char *note,
                                  int note_sz, char *err, int err_sz)
{
    char a[88], b[88], va[88], vb[88];
    if (note_sz > 0)
        note[0] = '\0';
    if (!log->has_hash) {
        snprintf(note, (size_t)note_sz,
                 "needlesim: warning: %s has no #scenario_hash line (an older or hand-written "
                 "log): it was replayed against '%s' unchecked",
                 path, show_name(name, a));
        return 0;
    }
    const char *recorded = log->scenario[0] ? log->scenario : "?";
    bool other_version = log->version[0] && strcmp(log->version, version) != 0;
    if (log->scenario_hash == hash && !other_version)
        return 0;
    if (rescore) {
        snprintf(note, (size_t)note_sz,
                 "needlesim: %s: recorded %s%s%sagainst scenario '%s' (hash %016" PRIx64
                 "), re-scored against '%s' (hash %016" PRIx64 ") by needlesim %s as --rescore "
                 "asks",
                 path, other_version ? "by needlesim " : "",
                 other_version ? show_name(log->version, va) : "", other_version ? " " : "",
                 show_name(recorded, a), log->scenario_hash, show_name(name, b), hash,
                 show_name(version, vb));
        return 0;
    }
    if (log->scenario_hash != hash)
        ns_set_err(err, err_sz,
                   "%s:%ld: recorded against scenario '%s' (hash %016" PRIx64 "), not '%s' (hash "
                   "%016" PRIx64 "); --rescore replays it anyway",
                   path, log->hash_line, show_name(recorded, a), log->scenario_hash,
                   show_name(name, b), hash);
    else
        ns_set_err(err, err_sz,
                   "%s:%ld: recorded by needlesim %s against scenario '%s' (hash %016" PRIx64
                   "), this is needlesim %s with '%s' (hash %016" PRIx64 "); --rescore replays "
                   "it anyway",
                   path, log->version_line, show_name(log->version, va), show_name(recorded, a),
                   log->scenario_hash, show_name(version, vb), show_name(name, b), hash);
    return -1;
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

/* "#model dt=D tolerance=T check_tolerance=C lazy_threshold=L": 0, or -1 with a message. */
static int read_model(const char *v, const char *path, long lineno, NsControlLog *log, char *err,
                      int err_sz)
{
    NsLogModel *m = &log->model;
    int used = 0;
    bool ok = !log->has_model &&
              sscanf(v, "dt=%lf tolerance=%lf check_tolerance=%lf lazy_threshold=%lf%n", &m->dt,
                     &m->tolerance, &m->check_tolerance, &m->lazy_threshold, &used) == 4 &&
              v[used] == '\0' && isfinite(m->dt) && m->dt > 0.0 && m->dt <= 1.0 &&
              m->tolerance > 0.0 && m->tolerance < 1.0 && m->check_tolerance >= m->tolerance &&
              m->check_tolerance < 1.0 && m->lazy_threshold >= 0.0 && m->lazy_threshold < 1.0;
    if (!ok) {
        ns_set_err(err, err_sz,
                   "%s:%ld: #model must be 'dt=D tolerance=T check_tolerance=C lazy_threshold=L' "
                   "(0 < D <= 1, 0 < T <= C < 1, 0 <= L < 1), once",
                   path, lineno);
        return -1;
    }
    log->has_model = true;
    return 0;
}

/* One '#' line before the header: provenance, a --set, or a comment. 0, or -1 with a
 * message. */
static int read_comment(const char *p, const char *path, long lineno, NsControlLog *log, char *err,
                        int err_sz)
{
    const char *v;
    if (strncmp(p, "#set ", 5) == 0) {
        v = p + 5;
        if (log->nsets == NS_CONTROL_LOG_MAX_SETS || strlen(v) >= sizeof log->sets[0]) {
            ns_set_err(err, err_sz, "%s:%ld: more than %d #set lines, or one longer than %zu bytes",
                       path, lineno, NS_CONTROL_LOG_MAX_SETS, sizeof log->sets[0] - 1);
            return -1;
        }
        memcpy(log->sets[log->nsets++], v, strlen(v) + 1);
    } else if (strncmp(p, "#scenario_hash ", 15) == 0) {
        v = p + 15;
        char *end;
        if (log->has_hash) {
            ns_set_err(err, err_sz, "%s:%ld: a second #scenario_hash line", path, lineno);
            return -1;
        }
        errno = 0;
        unsigned long long h = strtoull(v, &end, 16);
        if (strlen(v) != 16 || strspn(v, "0123456789abcdefABCDEF") != 16 || *end || errno) {
            ns_set_err(err, err_sz, "%s:%ld: #scenario_hash must be 16 hex digits (got '%.40s')",
                       path, lineno, v);
            return -1;
        }
        log->scenario_hash = (uint64_t)h;
        log->has_hash = true;
        log->hash_line = lineno;
    } else if (strncmp(p, "#scenario ", 10) == 0) {
        snprintf(log->scenario, sizeof log->scenario, "%s", p + 10);
    } else if (strcmp(p, "#source live") == 0) {
        log->live = true;
    } else if (strncmp(p, "#model ", 7) == 0) {
        return read_model(p + 7, path, lineno, log, err, err_sz);
    } else if (strncmp(p, "#needlesim ", 11) == 0) {
        snprintf(log->version, sizeof log->version, "%s", p + 11);
        log->version_line = lineno;
    } else if (strncmp(p, "#trainee ", 9) == 0 || strncmp(p, "#session ", 9) == 0) {
        v = p + 9;
        if (!ns_control_log_id_ok(v)) {
            ns_set_err(err, err_sz,
                       "%s:%ld: %.8s must be 1 to %d characters of A-Z a-z 0-9 . _ - (got "
                       "'%.40s')",
                       path, lineno, p, NS_CONTROL_LOG_ID_MAX, v);
            return -1;
        }
        snprintf(p[1] == 't' ? log->trainee : log->session, sizeof log->trainee, "%s", v);
    }
    return 0; /* any other '#' line is a comment */
}

/* |value| within its limit (ns_limits.h), or -1 with "path:line: ..." */
static int within(double v, double limit, const char *column, const char *unit, const char *path,
                  long lineno, char *err, int err_sz)
{
    if (fabs(v) <= limit)
        return 0;
    ns_set_err(err, err_sz, "%s:%ld: %s %g %s is beyond the limit of %g %s", path, lineno, column,
               v, unit, limit, unit);
    return -1;
}

/* One row of a log (line, split in place), the controls of step `step`; 0, or -1 with
 * "path:line: ..." in err. */
static int parse_row(char *line, const char *path, long lineno, long step, double dt, NsControl *c,
                     char *err, int err_sz)
{
    int rc = 0;
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
        return -1;
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
            ns_set_err(err, err_sz, "%s:%ld: %s must be a finite number (got '%s')", path, lineno,
                       columns[k], field[k]);
            rc = -1;
        }
    }
    if (rc)
        return -1;
    if (fabs(v[0] - (double)step * dt) > 1e-3 * dt) {
        ns_set_err(err, err_sz,
                   "%s:%ld: t_s is %.9g but row %ld of a run stepping by dt = %g s is at "
                   "t = %.9g s",
                   path, lineno, v[0], step + 1, dt, (double)step * dt);
        return -1;
    }
    /* Physical bounds (ns_limits.h): a row is one step's work, and that is bounded. */
    rc = within(v[1], NS_LIMIT_INSERT_SPEED, columns[1], "m/s", path, lineno, err, err_sz);
    for (int k = 2; k < 5 && rc == 0; k++)
        rc = within(v[k], NS_LIMIT_BASE_SPEED, columns[k], "m/s", path, lineno, err, err_sz);
    if (rc == 0)
        rc = within(v[5], NS_LIMIT_TWIST_RATE, columns[5], "rad/s", path, lineno, err, err_sz);
    if (rc)
        return -1;
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
            return -1;
        }
    } else if (field[6][0] != '\0') {
        ns_set_err(err, err_sz,
                   "%s:%ld: unknown event '%s' (known: drop_seed, next_needle:..., or empty)", path,
                   lineno, field[6]);
        return -1;
    }
    c->v_insert = v[1];
    memcpy(c->v_base, v + 2, sizeof c->v_base);
    c->twist_rate = v[5];
    c->drop_seed = drop;
    c->next_needle = next;
    c->entry = entry;
    return 0;
}

/* The '#' lines before the header (what the log was recorded with: control_log.h), then the
 * header line itself, from f into log; line (1024 bytes) is the reader's buffer, lineno and
 * bytes count what was read. 0, or -1 with "path:line: ..." in err. */
static int read_head(FILE *f, const char *path, NsControlLog *log, char *line, long *lineno,
                     long long *bytes, char *err, int err_sz)
{
    int rc = 0, got = 0;
    while (rc == 0 && (got = fgets(line, 1024, f) != NULL)) {
        (*lineno)++;
        *bytes += (long long)strlen(line);
        char *p = line;
        if (*lineno == 1 && (unsigned char)p[0] == 0xEF && (unsigned char)p[1] == 0xBB &&
            (unsigned char)p[2] == 0xBF)
            p += 3; /* a UTF-8 byte-order mark */
        if (!strchr(p, '\n') && !feof(f)) {
            ns_set_err(err, err_sz, "%s:%ld: line too long", path, *lineno);
            return -1;
        }
        chomp(p);
        if (p[0] != '#') {
            memmove(line, p, strlen(p) + 1);
            break;
        }
        rc = read_comment(p, path, *lineno, log, err, err_sz);
    }
    if (rc)
        return -1;
    if (!got) {
        ns_set_err(err, err_sz, "%s:%ld: no header (want %s)", path, *lineno + 1,
                   NS_CONTROL_LOG_HEADER);
        return -1;
    }
    if (strcmp(line, NS_CONTROL_LOG_HEADER) != 0) {
        ns_set_err(err, err_sz, "%s:%ld: the header must be %s", path, *lineno,
                   NS_CONTROL_LOG_HEADER);
        return -1;
    }
    return 0;
}

/* Opens a log for reading: a regular file within the size limit, checked before it is opened
 * (a FIFO or /dev/zero would block or never end). NULL with a message in err. */
static FILE *open_log(const char *path, char *err, int err_sz)
{
    int fd = ns_file_open_regular(path, NS_LIMIT_LOG_FILE_BYTES, "control log", NULL, err, err_sz);
    FILE *f = fd >= 0 ? fdopen(fd, "r") : NULL;
    if (!f && fd >= 0) {
        ns_set_err(err, err_sz, "%s: cannot open: %s", path, strerror(errno));
        close(fd);
    }
    return f;
}

int ns_control_log_read_provenance(const char *path, NsControlLog *log, char *err, int err_sz)
{
    memset(log, 0, sizeof *log);
    FILE *f = open_log(path, err, err_sz);
    if (!f)
        return -1;
    char line[1024];
    long lineno = 0;
    long long bytes = 0;
    int rc = read_head(f, path, log, line, &lineno, &bytes, err, err_sz);
    fclose(f);
    return rc;
}

int ns_control_log_read(const char *path, double dt, NsControlLog *log, char *err, int err_sz)
{
    memset(log, 0, sizeof *log);
    FILE *f = open_log(path, err, err_sz); /* the rows are bounded below */
    if (!f)
        return -1;
    char line[1024];
    long lineno = 0, cap = 0, blank = 0;
    long long bytes = 0;
    int rc = read_head(f, path, log, line, &lineno, &bytes, err, err_sz);
    long header_line = lineno;
    while (rc == 0 && fgets(line, sizeof line, f)) {
        lineno++;
        bytes += (long long)strlen(line);
        if (bytes > NS_LIMIT_LOG_FILE_BYTES) { /* it grew since it was opened */
            ns_set_err(err, err_sz,
                       "%s:%ld: the control log is longer than the limit of %lld bytes", path,
                       lineno, NS_LIMIT_LOG_FILE_BYTES);
            rc = -1;
            break;
        }
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
        if (log->n >= NS_LIMIT_STEPS) {
            ns_set_err(err, err_sz,
                       "%s:%ld: more than %ld rows (NS_LIMIT_STEPS, the most steps a run takes)",
                       path, lineno, (long)NS_LIMIT_STEPS);
            rc = -1;
            break;
        }
        NsControl row;
        if (parse_row(line, path, lineno, lineno - header_line - 1,
                      log->has_model ? log->model.dt : dt, &row, err, err_sz)) {
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
        log->rows[log->n++] = row;
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
