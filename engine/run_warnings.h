/* A run's warnings explained (docs/reliability.md "Warnings"): each count beside what it means,
 * and how much of it bore on a result. A result is read from the state after a step when the
 * step ends the run (the targets, the tip, the seeds' final places, the dose), when a seed is
 * released after it (the seed's material point), when the tip is inside an obstacle after it
 * (the obstacle's depth) and when it records an event (bone contact, an exit, a re-entry). An
 * unconverged solve or unresolved friction in such a step bears on the result (they are of
 * the whole state); an inverted element bears on it when it is beside a point read (it shares
 * a node with the element the point lies in, whose nodes the reading interpolates). Any other
 * warning was transient or elsewhere: the run recovered from it before anything near it was
 * read. */
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
    int read[NS_WARN_KINDS];  /* bearing on a result (above) */
    long step;                /* steps taken */
    long read_step;           /* the step last counted as read */
    int read_inverted;        /* of the latest step's inverted elements, those counted read */
} NsRunWarnings;              /* zeroed: no step yet */

/* After a step: its counts, indexed by NS_WARN_*. */
void ns_run_warnings_step(NsRunWarnings *w, const int counts[NS_WARN_KINDS]);

/* A result is read from the state after the latest step, with inverted_beside inverted
 * elements beside the points read: the other kinds count once per step however often it is
 * read; the inverted ones add up over the readings of a step, to at most the step's count. */
void ns_run_warnings_read(NsRunWarnings *w, int inverted_beside);

/* How many of kind k bear on the result: every NaN (a step with one is rejected and the run
 * stops), of the others those counted read. */
int ns_run_warnings_affected(const NsRunWarnings *w, int k);

/* report.json's `warnings_explained` (docs/scenarios.md). */
void ns_run_warnings_report(NsJson *j, const NsRunWarnings *w);

/* One line for the contact sheet and stdout: "warnings: NaN 0, inverted 43 (none in a state
 * read for the result), ...". */
void ns_run_warnings_line(const NsRunWarnings *w, char *buf, size_t n);

#endif
