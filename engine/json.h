/* A small streaming JSON writer for the command line's --json output and, later, report.json.
 *
 * Numbers are printed with %.17g (round-trip exact); a non-finite number becomes null, since
 * JSON has no NaN or infinity. Strings are escaped, and bytes that are not valid UTF-8 are
 * replaced by U+FFFD so the output is always valid JSON whatever a scenario names things.
 *
 * Layout: containers up to `pretty_depth` deep put each item on its own indented line; deeper
 * ones are written inline. With pretty_depth = 2 an object of arrays of small objects prints
 * one small object per line, which keeps the output easy to read and to grep. */
#ifndef NS_JSON_H
#define NS_JSON_H

#include <stdbool.h>
#include <stdio.h>

#define NS_JSON_MAX_DEPTH 32

typedef struct NsJson {
    FILE *f;
    int depth;                         /* open containers */
    int pretty_depth;                  /* containers this deep or shallower are multi-line */
    bool has_items[NS_JSON_MAX_DEPTH]; /* the container at this depth has an item already */
    bool after_key;                    /* a key was written; the value follows inline */
} NsJson;

void ns_json_init(NsJson *j, FILE *f, int pretty_depth);

void ns_json_begin_object(NsJson *j);
void ns_json_end_object(NsJson *j);
void ns_json_begin_array(NsJson *j);
void ns_json_end_array(NsJson *j);

/* Inside an object: the key of the next value. */
void ns_json_key(NsJson *j, const char *key);

void ns_json_string(NsJson *j, const char *s);
void ns_json_number(NsJson *j, double x);
void ns_json_int(NsJson *j, long long x);
void ns_json_bool(NsJson *j, bool b);
void ns_json_null(NsJson *j);

/* Writes s as a quoted, escaped JSON string. */
void ns_json_write_string(FILE *f, const char *s);

#endif
