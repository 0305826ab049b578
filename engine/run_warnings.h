/* A run's warnings explained (docs/reliability.md "Warnings"): each count beside what it means,
 * and how much of it was in a state that a result was read from. A result is read from the
 * state after a step when the step ends the run (the targets, the seeds' final places, the
 * dose), when a seed is released after it (the seed's material point), when the tip is inside
 * an obstacle after it (the obstacle's depth) and when it records an event (bone contact, an
 * exit, a re-entry). A warning in any other step was transient: the next steps recovered from
 * it before anything was read. */
#ifndef NS_RUN_WARNINGS_H
#define NS_RUN_WARNINGS_H

#include <stddef.h>

#include "json.h"

enum { NS_WARN_NAN, NS_WARN_INVERTED, NS_WARN_UNCONVERGED, NS_WARN_LCP, NS_WARN_KINDS };

typedef struct NsRunWarnings {
    int total[NS_WARN_KINDS]; /* over the run (the report's `warnings`) */
    int last[NS_WARN_KINDS];  /* in the latest step */
    int steps[NS_WARN_KINDS]; /* steps with one or more */
    int most[NS_WARN_KINDS];  /* the most in one step */
    int read[NS_WARN_KINDS];  /* in states that a result was read from */
    long step;                /* steps taken */
    long read_step;           /* the step last counted as read */
} NsRunWarnings;              /* zeroed: no step yet */

/* After a step: its counts, indexed by NS_WARN_*. */
void ns_run_warnings_step(NsRunWarnings *w, const int counts[NS_WARN_KINDS]);

/* A result is read from the state after the latest step (once per step however often). */
void ns_run_warnings_read(NsRunWarnings *w);

/* How many of kind k bear on the result: every NaN (a step with one is rejected and the run
 * stops), of the others those in a state read. */
int ns_run_warnings_affected(const NsRunWarnings *w, int k);

/* report.json's `warnings_explained` (docs/scenarios.md). */
void ns_run_warnings_report(NsJson *j, const NsRunWarnings *w);

/* One line for the contact sheet and stdout: "warnings: NaN 0, inverted 43 (none in a state
 * read for the result), ...". */
void ns_run_warnings_line(const NsRunWarnings *w, char *buf, size_t n);

#endif
