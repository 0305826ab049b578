/* scores.csv's rows (score_csv.h). */
#include "score_csv.h"

#include <string.h>

void ns_csv_field(FILE *f, const char *s)
{
    size_t n = strlen(s);
    bool quote = strpbrk(s, ",\"") != NULL || (n > 0 && (s[0] == ' ' || s[n - 1] == ' '));
    if (quote)
        fputc('"', f);
    for (const char *c = s; *c; c++) {
        if (*c == '"')
            fputs("\"\"", f);
        else
            fputc((unsigned char)*c < 0x20 || *c == 0x7f ? '?' : *c, f);
    }
    if (quote)
        fputc('"', f);
}

int ns_csv_split(char *line, char **fields, int max)
{
    int n = 0;
    char *p = line;
    for (;;) {
        if (n == max)
            return -1;
        char *out = p;
        fields[n++] = out;
        if (*p == '"') { /* quoted: "" is a quote; the field ends at the closing quote */
            p++;
            for (;;) {
                if (*p == '\0')
                    return -1;
                if (*p == '"' && p[1] == '"') {
                    *out++ = '"';
                    p += 2;
                } else if (*p == '"') {
                    p++;
                    break;
                } else {
                    *out++ = *p++;
                }
            }
            if (*p != ',' && *p != '\0')
                return -1;
        } else {
            while (*p && *p != ',')
                *out++ = *p++;
        }
        char end = *p;
        *out = '\0';
        if (end == '\0')
            return n;
        p++;
    }
}
