/* A run's warnings explained (engine/run_warnings.c): which counts were in a state read for the
 * result, counted by hand. */
#include "ns_test.h"
#include "run_warnings.h"

/* Three steps: inverted 2, then 0, then 3; a result read after the first (twice: counted
 * once) and after the third. Friction unresolved in the second only, never read. */
static int read_states_only(void)
{
    NsRunWarnings w = {0};
    ns_run_warnings_step(&w, (int[NS_WARN_KINDS]){[NS_WARN_INVERTED] = 2});
    ns_run_warnings_read(&w);
    ns_run_warnings_read(&w);
    ns_run_warnings_step(&w, (int[NS_WARN_KINDS]){[NS_WARN_LCP] = 1});
    ns_run_warnings_step(&w, (int[NS_WARN_KINDS]){[NS_WARN_INVERTED] = 3});
    ns_run_warnings_read(&w);
    ENSURE(w.total[NS_WARN_INVERTED] == 5 && w.steps[NS_WARN_INVERTED] == 2);
    ENSURE(w.most[NS_WARN_INVERTED] == 3);
    ENSURE(ns_run_warnings_affected(&w, NS_WARN_INVERTED) == 5);
    ENSURE(w.total[NS_WARN_LCP] == 1 && ns_run_warnings_affected(&w, NS_WARN_LCP) == 0);
    char line[256];
    ns_run_warnings_line(&w, line, sizeof line);
    ENSURE(strcmp(line, "warnings: NaN 0, inverted 5 (5 where a result was read), unconverged 0, "
                        "friction unresolved 1 (all transient)") == 0);
    return 0;
}

/* A read before any step counts nothing; a NaN bears on the result unread. */
static int nan_always_counts(void)
{
    NsRunWarnings w = {0};
    ns_run_warnings_read(&w);
    ns_run_warnings_step(&w, (int[NS_WARN_KINDS]){[NS_WARN_NAN] = 1, [NS_WARN_UNCONVERGED] = 1});
    ENSURE(ns_run_warnings_affected(&w, NS_WARN_NAN) == 1);
    ENSURE(ns_run_warnings_affected(&w, NS_WARN_UNCONVERGED) == 0);
    ns_run_warnings_read(&w);
    ENSURE(ns_run_warnings_affected(&w, NS_WARN_UNCONVERGED) == 1);
    return 0;
}

/* A line too long for its buffer is cut, not overrun. */
static int line_is_bounded(void)
{
    NsRunWarnings w = {0};
    ns_run_warnings_step(&w, (int[NS_WARN_KINDS]){1, 2, 3, 4});
    char line[24];
    memset(line, 'x', sizeof line);
    ns_run_warnings_line(&w, line, 20);
    ENSURE(strlen(line) == 19 && line[20] == 'x');
    return 0;
}

NS_TEST_MAIN({"read_states_only", read_states_only}, {"nan_always_counts", nan_always_counts},
             {"line_is_bounded", line_is_bounded})
