/* The live session's control messages: a strict parser for flat JSON objects
 * (live_protocol.h). Recursive descent over a byte range; no allocation. */
#include "live_protocol.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "json.h"
#include "ns_limits.h"
#include "scene.h"

typedef struct Cur {
    const char *p, *end;
    char *err;
    int err_sz;
} Cur;

static int fail(Cur *c, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(c->err, (size_t)c->err_sz, fmt, ap);
    va_end(ap);
    return -1;
}

static void skip_ws(Cur *c)
{
    while (c->p < c->end && (*c->p == ' ' || *c->p == '\t' || *c->p == '\n' || *c->p == '\r'))
        c->p++;
}

static int hex4(const char *p)
{
    int v = 0;
    for (int i = 0; i < 4; i++) {
        char ch = p[i];
        int d = ch >= '0' && ch <= '9'   ? ch - '0'
                : ch >= 'a' && ch <= 'f' ? ch - 'a' + 10
                : ch >= 'A' && ch <= 'F' ? ch - 'A' + 10
                                         : -1;
        if (d < 0)
            return -1;
        v = 16 * v + d;
    }
    return v;
}

/* A JSON string (a key) into out: escapes decoded; anything outside printable ASCII becomes
 * '?' (no key has it, so the key is then unknown). */
static int parse_string(Cur *c, char *out, size_t out_sz)
{
    if (c->p >= c->end || *c->p != '"')
        return fail(c, "expected a quoted key");
    c->p++;
    size_t n = 0;
    for (;;) {
        if (c->p >= c->end)
            return fail(c, "unterminated string");
        unsigned char ch = (unsigned char)*c->p++;
        if (ch == '"')
            break;
        if (ch < 0x20)
            return fail(c, "control character in a string");
        if (ch == '\\') {
            if (c->p >= c->end)
                return fail(c, "unterminated string");
            char e = *c->p++;
            const char *simple = strchr("\"\\/bfnrt", e);
            if (e && simple) {
                ch = (unsigned char)"\"\\/\b\f\n\r\t"[simple - "\"\\/bfnrt"];
            } else if (e == 'u') {
                int v = c->end - c->p >= 4 ? hex4(c->p) : -1;
                if (v < 0)
                    return fail(c, "bad \\u escape in a string");
                c->p += 4;
                ch = v >= 0x20 && v < 0x7f ? (unsigned char)v : '?';
            } else {
                return fail(c, "bad escape in a string");
            }
        }
        if (ch >= 0x7f || ch < 0x20)
            ch = '?';
        if (n + 1 < out_sz)
            out[n++] = (char)ch;
        else
            return fail(c, "string too long");
    }
    out[n] = '\0';
    return 0;
}

/* A JSON number (RFC 8259 grammar exactly), finite. */
static int parse_number(Cur *c, const char *key, double *x)
{
    const char *s = c->p, *p = s;
    if (p < c->end && *p == '-')
        p++;
    if (p >= c->end || !(*p >= '0' && *p <= '9'))
        return fail(c, "%s: expected a number", key);
    if (*p == '0')
        p++;
    else
        while (p < c->end && *p >= '0' && *p <= '9')
            p++;
    if (p < c->end && *p == '.') {
        p++;
        if (p >= c->end || !(*p >= '0' && *p <= '9'))
            return fail(c, "%s: bad number", key);
        while (p < c->end && *p >= '0' && *p <= '9')
            p++;
    }
    if (p < c->end && (*p == 'e' || *p == 'E')) {
        p++;
        if (p < c->end && (*p == '+' || *p == '-'))
            p++;
        if (p >= c->end || !(*p >= '0' && *p <= '9'))
            return fail(c, "%s: bad number", key);
        while (p < c->end && *p >= '0' && *p <= '9')
            p++;
    }
    char buf[64];
    if ((size_t)(p - s) >= sizeof buf)
        return fail(c, "%s: number too long", key);
    memcpy(buf, s, (size_t)(p - s));
    buf[p - s] = '\0';
    *x = strtod(buf, NULL);
    if (!isfinite(*x))
        return fail(c, "%s: number out of range", key);
    c->p = p;
    return 0;
}

static int parse_bool(Cur *c, const char *key, bool *b)
{
    size_t left = (size_t)(c->end - c->p);
    if (left >= 4 && memcmp(c->p, "true", 4) == 0) {
        c->p += 4;
        *b = true;
        return 0;
    }
    if (left >= 5 && memcmp(c->p, "false", 5) == 0) {
        c->p += 5;
        *b = false;
        return 0;
    }
    return fail(c, "%s: expected true or false", key);
}

static int bounded(Cur *c, const char *key, double x, double lim, const char *unit)
{
    if (fabs(x) > lim)
        return fail(c, "%s: %g is beyond the limit of %g %s", key, x, lim, unit);
    return 0;
}

static int parse_vec3(Cur *c, const char *key, double v[3])
{
    if (c->p >= c->end || *c->p != '[')
        return fail(c, "%s: expected [vx, vy, vz]", key);
    c->p++;
    for (int i = 0; i < 3; i++) {
        skip_ws(c);
        if (parse_number(c, key, &v[i]))
            return -1;
        skip_ws(c);
        char want = i < 2 ? ',' : ']';
        if (c->p >= c->end || *c->p != want)
            return fail(c, "%s: expected [vx, vy, vz]: three numbers", key);
        c->p++;
    }
    return 0;
}

/* "A[,B[,C]]": the views side by side, as --layout takes them; "": the scenario's own. */
static int parse_views(Cur *c, const char *key, NsLiveMsg *m)
{
    char names[64];
    if (c->p >= c->end || *c->p != '"')
        return fail(c, "%s: expected a string of view names, \"cutaway3d,trus\"", key);
    if (parse_string(c, names, sizeof names))
        return -1;
    m->nviews = 0;
    if (names[0] == '\0') /* "": the scenario's own views again */
        return 0;
    for (char *save = NULL, *t = strtok_r(names, ",", &save); t; t = strtok_r(NULL, ",", &save)) {
        int v = ns_view_parse(t);
        if (v < 0)
            return fail(c, "%s: '%s' is not a view (side, top, axis, cutaway3d, trus)", key, t);
        if (m->nviews == 3)
            return fail(c, "%s: at most three views", key);
        m->views[m->nviews++] = v;
    }
    if (m->nviews == 0)
        return fail(c, "%s: expected one to three view names", key);
    return 0;
}

enum { KEYS = 9 };
static const char *const keys[KEYS] = {"insert_speed",  "twist_rate", "twist",
                                       "base_velocity", "drop_seed",  "next_needle",
                                       "pause",         "end",        "views"};

/* One member's value for key index k. */
static int parse_value(Cur *c, int k, NsLiveMsg *m)
{
    const char *key = keys[k];
    switch (k) {
    case 0:
        return parse_number(c, key, &m->insert_speed) ||
               bounded(c, key, m->insert_speed, NS_LIMIT_INSERT_SPEED, "m/s");
    case 1:
        return parse_number(c, key, &m->twist_rate) ||
               bounded(c, key, m->twist_rate, NS_LIMIT_TWIST_RATE, "rad/s");
    case 2:
        return parse_number(c, key, &m->twist) ||
               bounded(c, key, m->twist, NS_LIMIT_TWIST_ANGLE, "rad");
    case 3:
        if (parse_vec3(c, key, m->base_velocity))
            return -1;
        for (int i = 0; i < 3; i++)
            if (bounded(c, key, m->base_velocity[i], NS_LIMIT_BASE_SPEED, "m/s"))
                return -1;
        return 0;
    case 4:
        return parse_bool(c, key, &m->drop_seed);
    case 5:
        return parse_bool(c, key, &m->next_needle);
    case 6:
        return parse_bool(c, key, &m->pause);
    case 7:
        return parse_bool(c, key, &m->end);
    default:
        return parse_views(c, key, m);
    }
}

int ns_live_parse(const char *text, size_t n, NsLiveMsg *m, char *err, int err_sz)
{
    memset(m, 0, sizeof *m);
    Cur c = {text, text + n, err, err_sz};
    if (n > NS_LIMIT_LIVE_MESSAGE_BYTES)
        return fail(&c, "message of %zu bytes: at most %d", n, NS_LIMIT_LIVE_MESSAGE_BYTES);
    if (memchr(text, '\0', n))
        return fail(&c, "NUL byte in the message");
    skip_ws(&c);
    if (c.p >= c.end || *c.p != '{')
        return fail(&c, "expected a JSON object");
    c.p++;
    skip_ws(&c);
    if (c.p < c.end && *c.p == '}')
        return fail(&c, "empty object: no control");
    for (;;) {
        char key[32];
        skip_ws(&c);
        if (parse_string(&c, key, sizeof key))
            return -1;
        int k = 0;
        while (k < KEYS && strcmp(key, keys[k]) != 0)
            k++;
        if (k == KEYS)
            return fail(&c, "unknown key '%s'", key);
        if (m->has & (1u << k))
            return fail(&c, "key '%s' given twice", key);
        skip_ws(&c);
        if (c.p >= c.end || *c.p != ':')
            return fail(&c, "expected ':' after '%s'", key);
        c.p++;
        skip_ws(&c);
        if (parse_value(&c, k, m))
            return -1;
        m->has |= 1u << k;
        skip_ws(&c);
        if (c.p < c.end && *c.p == ',') {
            c.p++;
            continue;
        }
        if (c.p < c.end && *c.p == '}') {
            c.p++;
            break;
        }
        return fail(&c, "expected ',' or '}' after '%s'", key);
    }
    skip_ws(&c);
    if (c.p != c.end)
        return fail(&c, "text after the object");
    return 0;
}

int ns_live_error_json(const char *msg, char *out, size_t out_sz)
{
    FILE *f = fmemopen(out, out_sz, "w");
    if (!f)
        return -1;
    fputs("{\"error\": ", f);
    ns_json_write_string(f, msg);
    fputc('}', f);
    long n = ftell(f);
    int bad = ferror(f);
    fclose(f);
    if (bad || n < 0 || (size_t)n >= out_sz)
        return -1;
    out[n] = '\0';
    return (int)n;
}
