/* A run's warnings explained (run_warnings.h, docs/reliability.md "Warnings"). */
#include "run_warnings.h"

#include <stdio.h>

static const struct {
    const char *key, *label, *meaning, *trust;
} kinds[NS_WARN_KINDS] = {
    [NS_WARN_NAN] = {"nan", "NaN",
                     "a non-finite value in a step's forces or solve; the step is rejected and "
                     "the run stops there",
                     "never information: the run failed at that step"},
    [NS_WARN_INVERTED] = {"inverted", "inverted",
                          "tissue elements turned inside out after a step (det F <= 0), counted "
                          "once per element per step; the invertible FEM (paper 3.2) gives them "
                          "restoring forces and they come back",
                          "ones away from what a result reads are information; one beside a "
                          "point read (a seed, a target, the tip) makes that reading doubtful"},
    [NS_WARN_UNCONVERGED] = {"unconverged", "unconverged",
                             "a step whose final coupled solve missed its tolerance "
                             "(tau_sol); the step keeps the last iterate",
                             "transient ones are information; ones in a state a result was "
                             "read from make that result less accurate"},
    [NS_WARN_LCP] = {"lcp_unresolved", "friction unresolved",
                     "a step whose stick-slip friction states were still inconsistent after the "
                     "LCP's trials (paper Algorithm 3); the step keeps the last trial's states",
                     "transient ones are information (the next step resolves them); ones in a "
                     "state a result was read from let the needle slip or stick a step early"},
};

void ns_run_warnings_step(NsRunWarnings *w, const int counts[NS_WARN_KINDS])
{
    w->step++;
    for (int k = 0; k < NS_WARN_KINDS; k++) {
        w->last[k] = counts[k];
        w->total[k] += counts[k];
        w->steps[k] += counts[k] > 0;
        if (counts[k] > w->most[k])
            w->most[k] = counts[k];
    }
}

void ns_run_warnings_read(NsRunWarnings *w, int inverted_beside)
{
    if (w->read_step != w->step) {
        w->read_step = w->step;
        w->read_inverted = 0;
        for (int k = 0; k < NS_WARN_KINDS; k++)
            if (k != NS_WARN_INVERTED)
                w->read[k] += w->last[k];
    }
    int room = w->last[NS_WARN_INVERTED] - w->read_inverted;
    int add = inverted_beside < room ? inverted_beside : room;
    if (add > 0) {
        w->read_inverted += add;
        w->read[NS_WARN_INVERTED] += add;
    }
}

int ns_run_warnings_affected(const NsRunWarnings *w, int k)
{
    return k == NS_WARN_NAN ? w->total[k] : w->read[k];
}

void ns_run_warnings_report(NsJson *j, const NsRunWarnings *w)
{
    int affected = 0;
    for (int k = 0; k < NS_WARN_KINDS; k++)
        affected += ns_run_warnings_affected(w, k);
    ns_json_key(j, "warnings_explained");
    ns_json_begin_object(j);
    ns_json_key(j, "see");
    ns_json_string(j, "docs/reliability.md#warnings");
    ns_json_key(j, "result_affected");
    ns_json_bool(j, affected > 0);
    for (int k = 0; k < NS_WARN_KINDS; k++) {
        int a = ns_run_warnings_affected(w, k);
        ns_json_key(j, kinds[k].key);
        ns_json_begin_object(j);
        ns_json_key(j, "count");
        ns_json_int(j, w->total[k]);
        ns_json_key(j, "affected_result");
        ns_json_int(j, a);
        ns_json_key(j, "did_not_affect_result");
        ns_json_int(j, w->total[k] - a);
        ns_json_key(j, "steps");
        ns_json_int(j, w->steps[k]);
        ns_json_key(j, "most_in_a_step");
        ns_json_int(j, w->most[k]);
        ns_json_key(j, "meaning");
        ns_json_string(j, kinds[k].meaning);
        ns_json_key(j, "trust");
        ns_json_string(j, kinds[k].trust);
        ns_json_end_object(j);
    }
    ns_json_end_object(j);
}

void ns_run_warnings_line(const NsRunWarnings *w, char *buf, size_t n)
{
    size_t at = (size_t)snprintf(buf, n, "warnings:");
    for (int k = 0; k < NS_WARN_KINDS && at < n; k++) {
        int a = ns_run_warnings_affected(w, k);
        if (w->total[k] == 0 || k == NS_WARN_NAN)
            at += (size_t)snprintf(buf + at, n - at, "%s %s %d", k ? "," : "", kinds[k].label,
                                   w->total[k]);
        else if (a == 0)
            at += (size_t)snprintf(buf + at, n - at, "%s %s %d (none bore on the result)",
                                   k ? "," : "", kinds[k].label, w->total[k]);
        else
            at += (size_t)snprintf(buf + at, n - at, "%s %s %d (%d bore on the result)",
                                   k ? "," : "", kinds[k].label, w->total[k], a);
    }
}
