/* The validation suite behind `needlesim validate` (DESIGN.md "Command line"): each case runs
 * the simulator on a problem whose answer is known independently (closed form, beam theory,
 * a published figure, or a run with every approximation switched off) and reports one metric
 * against that reference. docs/validation.md explains every case and its source.
 *
 * A case fills an NsValidateResult; the command prints them as a table or as JSON. Later
 * layers (needle, coupling, remeshing) add their own case tables next to the FEM ones. */
#ifndef NS_VALIDATE_H
#define NS_VALIDATE_H

#include <stdbool.h>

typedef struct NsValidateResult {
    char metric[64];  /* what value measures, with its unit */
    double value;     /* what the simulator gave */
    double reference; /* the independent answer */
    double error;     /* the compared quantity (usually |value - reference| / |reference|) */
    double tolerance; /* pass when error <= tolerance (and every side condition holds) */
    bool pass;
    char detail[2560]; /* one line: resolutions, counts, side conditions (may be empty) */
} NsValidateResult;

typedef struct NsValidateCase {
    const char *name;
    const char *summary;
    /* Returns 0 with r filled, or -1 when the case could not run (r->detail says why; the
     * case then counts as failed). */
    int (*run)(NsValidateResult *r);
} NsValidateCase;

/* The FEM tissue cases (engine/validate_fem.c). */
extern const NsValidateCase ns_validate_fem_cases[];
extern const int ns_validate_fem_case_count;

/* The needle rod cases (engine/validate_rod.c). */
extern const NsValidateCase ns_validate_rod_cases[];
extern const int ns_validate_rod_case_count;

/* The needle-tissue coupling cases (engine/validate_coupling.c). */
extern const NsValidateCase ns_validate_coupling_cases[];
extern const int ns_validate_coupling_case_count;

/* The tip remeshing cases (engine/validate_remesh.c). */
extern const NsValidateCase ns_validate_remesh_cases[];
extern const int ns_validate_remesh_case_count;

/* The bevel steering cases (engine/validate_steering.c). */
extern const NsValidateCase ns_validate_steering_cases[];
extern const int ns_validate_steering_case_count;

/* The TG-43U1 dose cases (engine/validate_dose.c). */
extern const NsValidateCase ns_validate_dose_cases[];
extern const int ns_validate_dose_case_count;

/* Appends printf-style text to r->detail. */
void ns_validate_detail(NsValidateResult *r, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));

#endif
