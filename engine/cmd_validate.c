/* needlesim validate [CASE...] [--json] [--list]
 *
 * Runs the built-in validation cases (engine/validate.h, docs/validation.md) and prints a table,
 * or with --json one object {"cases": [{"name", "metric", "value", "reference", "error",
 * "tolerance", "pass", "detail", "seconds"}], "passed", "failed"}. Progress goes to stderr.
 * Exit status: 0 when every case passes, 1 when any fails, 2 for a usage error (an unknown
 * case name is one, reported before anything runs). */
#include <math.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "commands.h"
#include "json.h"
#include "validate.h"

static const char validate_usage[] = "usage: needlesim validate [CASE...] [--json] [--list]\n";

typedef struct CaseTable {
    const NsValidateCase *cases;
    const int *count;
} CaseTable;

static const CaseTable tables[] = {
    {ns_validate_fem_cases, &ns_validate_fem_case_count},
    {ns_validate_rod_cases, &ns_validate_rod_case_count},
    {ns_validate_coupling_cases, &ns_validate_coupling_case_count},
    {ns_validate_remesh_cases, &ns_validate_remesh_case_count},
    {ns_validate_steering_cases, &ns_validate_steering_case_count},
    {ns_validate_dose_cases, &ns_validate_dose_case_count},
};
#define TABLE_COUNT ((int)(sizeof tables / sizeof tables[0]))

void ns_validate_detail(NsValidateResult *r, const char *fmt, ...)
{
    size_t used = strlen(r->detail);
    if (used + 1 >= sizeof r->detail)
        return;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(r->detail + used, sizeof r->detail - used, fmt, ap);
    va_end(ap);
}

static const NsValidateCase *find_case(const char *name)
{
    for (int t = 0; t < TABLE_COUNT; t++)
        for (int i = 0; i < *tables[t].count; i++)
            if (strcmp(tables[t].cases[i].name, name) == 0)
                return &tables[t].cases[i];
    return NULL;
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

static void print_table(const NsValidateCase **sel, const NsValidateResult *res, int n)
{
    printf("%-16s %-34s %12s %12s %10s %10s  %s\n", "case", "metric", "value", "reference", "error",
           "tolerance", "pass");
    for (int i = 0; i < n; i++) {
        const NsValidateResult *r = &res[i];
        printf("%-16s %-34s %12.6g %12.6g %10.3g %10.3g  %s\n", sel[i]->name, r->metric, r->value,
               r->reference, r->error, r->tolerance, r->pass ? "pass" : "FAIL");
        if (r->detail[0])
            printf("    %s\n", r->detail);
    }
}

static void print_json(const NsValidateCase **sel, const NsValidateResult *res, const double *secs,
                       int n, int passed)
{
    NsJson j;
    ns_json_init(&j, stdout, 2);
    ns_json_begin_object(&j);
    ns_json_key(&j, "cases");
    ns_json_begin_array(&j);
    for (int i = 0; i < n; i++) {
        const NsValidateResult *r = &res[i];
        ns_json_begin_object(&j);
        ns_json_key(&j, "name");
        ns_json_string(&j, sel[i]->name);
        ns_json_key(&j, "metric");
        ns_json_string(&j, r->metric);
        ns_json_key(&j, "value");
        ns_json_number(&j, r->value);
        ns_json_key(&j, "reference");
        ns_json_number(&j, r->reference);
        ns_json_key(&j, "error");
        ns_json_number(&j, r->error);
        ns_json_key(&j, "tolerance");
        ns_json_number(&j, r->tolerance);
        ns_json_key(&j, "pass");
        ns_json_bool(&j, r->pass);
        ns_json_key(&j, "detail");
        ns_json_string(&j, r->detail);
        ns_json_key(&j, "seconds");
        ns_json_number(&j, secs[i]);
        ns_json_end_object(&j);
    }
    ns_json_end_array(&j);
    ns_json_key(&j, "passed");
    ns_json_int(&j, passed);
    ns_json_key(&j, "failed");
    ns_json_int(&j, n - passed);
    ns_json_end_object(&j);
    fputc('\n', stdout);
}

int ns_cmd_validate(int argc, char **argv)
{
    bool json = false, list = false;
    int total = 0;
    for (int t = 0; t < TABLE_COUNT; t++)
        total += *tables[t].count;
    const NsValidateCase **sel = calloc((size_t)(argc + total), sizeof *sel);
    if (!sel) {
        fputs("needlesim: validate: out of memory\n", stderr);
        return 1;
    }
    int n = 0;
    for (int a = 1; a < argc; a++) {
        if (strcmp(argv[a], "--json") == 0) {
            json = true;
        } else if (strcmp(argv[a], "--list") == 0) {
            list = true;
        } else if (strcmp(argv[a], "--help") == 0 || strcmp(argv[a], "-h") == 0) {
            fputs(validate_usage, stdout);
            free(sel);
            return 0;
        } else if (argv[a][0] == '-') {
            fprintf(stderr, "needlesim: validate: unknown option '%s'\n%s", argv[a],
                    validate_usage);
            free(sel);
            return 2;
        } else {
            const NsValidateCase *c = find_case(argv[a]);
            if (!c) {
                fprintf(stderr, "needlesim: validate: unknown case '%s' (--list shows them)\n",
                        argv[a]);
                free(sel);
                return 2;
            }
            sel[n++] = c;
        }
    }
    if (n == 0)
        for (int t = 0; t < TABLE_COUNT; t++)
            for (int i = 0; i < *tables[t].count; i++)
                sel[n++] = &tables[t].cases[i];
    if (list) {
        for (int i = 0; i < n; i++)
            printf("%-16s %s\n", sel[i]->name, sel[i]->summary);
        free(sel);
        return 0;
    }
    NsValidateResult *res = calloc((size_t)n, sizeof *res);
    double *secs = calloc((size_t)n, sizeof *secs);
    if (!res || !secs) {
        fputs("needlesim: validate: out of memory\n", stderr);
        free(sel);
        free(res);
        free(secs);
        return 1;
    }
    int passed = 0;
    bool tty = isatty(fileno(stderr));
    for (int i = 0; i < n; i++) {
        NsValidateResult *r = &res[i];
        fprintf(stderr, "[%d/%d] %-16s ...%s", i + 1, n, sel[i]->name, tty ? "" : "\n");
        fflush(stderr);
        double t0 = now_s();
        int rc = sel[i]->run(r);
        secs[i] = now_s() - t0;
        /* A case that could not run, or whose numbers are not finite, fails. */
        if (rc != 0 || !isfinite(r->value) || !isfinite(r->error))
            r->pass = false;
        passed += r->pass;
        if (tty)
            fprintf(stderr, "\r[%d/%d] %-16s %s %.1f s\n", i + 1, n, sel[i]->name,
                    r->pass ? "pass" : "FAIL", secs[i]);
    }
    if (json)
        print_json(sel, res, secs, n, passed);
    else {
        print_table(sel, res, n);
        printf("%d passed, %d failed\n", passed, n - passed);
    }
    free(sel);
    free(res);
    free(secs);
    return passed == n ? 0 : 1;
}
