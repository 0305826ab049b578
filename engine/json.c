/* Streaming JSON writer (see json.h). */
#include "json.h"

#include <math.h>
#include <stdint.h>

void ns_json_init(NsJson *j, FILE *f, int pretty_depth)
{
    j->f = f;
    j->depth = 0;
    j->pretty_depth = pretty_depth;
    j->has_items[0] = false;
    j->after_key = false;
}

static void newline_indent(NsJson *j, int depth)
{
    fputc('\n', j->f);
    for (int i = 0; i < depth; i++)
        fputs("  ", j->f);
}

/* Separator and layout before a value (or a key) in the current container. */
static void before_item(NsJson *j)
{
    if (j->after_key) {
        j->after_key = false;
        return;
    }
    if (j->depth == 0)
        return;
    if (j->has_items[j->depth])
        fputc(',', j->f);
    if (j->depth <= j->pretty_depth)
        newline_indent(j, j->depth);
    else if (j->has_items[j->depth])
        fputc(' ', j->f);
    j->has_items[j->depth] = true;
}

static void begin(NsJson *j, char open)
{
    before_item(j);
    fputc(open, j->f);
    if (j->depth + 1 < NS_JSON_MAX_DEPTH)
        j->depth++;
    j->has_items[j->depth] = false;
}

static void end(NsJson *j, char close)
{
    bool had = j->has_items[j->depth];
    int depth = j->depth;
    if (j->depth > 0)
        j->depth--;
    if (had && depth <= j->pretty_depth)
        newline_indent(j, j->depth);
    fputc(close, j->f);
    if (j->depth == 0)
        fputc('\n', j->f);
}

void ns_json_begin_object(NsJson *j)
{
    begin(j, '{');
}

void ns_json_end_object(NsJson *j)
{
    end(j, '}');
}

void ns_json_begin_array(NsJson *j)
{
    begin(j, '[');
}

void ns_json_end_array(NsJson *j)
{
    end(j, ']');
}

void ns_json_key(NsJson *j, const char *key)
{
    before_item(j);
    ns_json_write_string(j->f, key);
    fputs(": ", j->f);
    j->after_key = true;
}

/* Length of the valid UTF-8 sequence at s, or 0 if the bytes there are not one. */
static int utf8_sequence(const unsigned char *s)
{
    unsigned c = s[0];
    int n;
    uint32_t cp;
    if (c < 0x80)
        return 1;
    if (c >= 0xc2 && c <= 0xdf) {
        n = 2;
        cp = c & 0x1f;
    } else if (c >= 0xe0 && c <= 0xef) {
        n = 3;
        cp = c & 0x0f;
    } else if (c >= 0xf0 && c <= 0xf4) {
        n = 4;
        cp = c & 0x07;
    } else {
        return 0;
    }
    for (int i = 1; i < n; i++) {
        if ((s[i] & 0xc0) != 0x80)
            return 0;
        cp = (cp << 6) | (s[i] & 0x3f);
    }
    if ((n == 3 && cp < 0x800) || (n == 4 && (cp < 0x10000 || cp > 0x10ffff)) ||
        (cp >= 0xd800 && cp <= 0xdfff))
        return 0; /* overlong, out of range, or a surrogate */
    return n;
}

void ns_json_write_string(FILE *f, const char *str)
{
    const unsigned char *s = (const unsigned char *)str;
    fputc('"', f);
    while (*s) {
        unsigned c = *s;
        if (c == '"' || c == '\\') {
            fputc('\\', f);
            fputc((int)c, f);
            s++;
        } else if (c < 0x20) {
            switch (c) {
            case '\n':
                fputs("\\n", f);
                break;
            case '\r':
                fputs("\\r", f);
                break;
            case '\t':
                fputs("\\t", f);
                break;
            case '\b':
                fputs("\\b", f);
                break;
            case '\f':
                fputs("\\f", f);
                break;
            default:
                fprintf(f, "\\u%04x", c);
            }
            s++;
        } else if (c < 0x80) {
            fputc((int)c, f);
            s++;
        } else {
            int n = utf8_sequence(s);
            if (n == 0) {
                fputs("\\ufffd", f);
                s++;
            } else {
                fwrite(s, 1, (size_t)n, f);
                s += n;
            }
        }
    }
    fputc('"', f);
}

void ns_json_string(NsJson *j, const char *s)
{
    before_item(j);
    ns_json_write_string(j->f, s ? s : "");
}

void ns_json_number(NsJson *j, double x)
{
    before_item(j);
    if (isfinite(x))
        fprintf(j->f, "%.17g", x);
    else
        fputs("null", j->f);
}

void ns_json_int(NsJson *j, long long x)
{
    before_item(j);
    fprintf(j->f, "%lld", x);
}

void ns_json_bool(NsJson *j, bool b)
{
    before_item(j);
    fputs(b ? "true" : "false", j->f);
}

void ns_json_null(NsJson *j)
{
    before_item(j);
    fputs("null", j->f);
}
