/* A run's warnings explained (engine/run_warnings.c): which counts were in a state read for the
 * result, counted by hand. */
#include "ns_test.h"
#include "run_warnings.h"

/* Three steps: inverted 2 (with friction unresolved), then 0 (friction unresolved), then 3. A
 * result read after the first, twice, both times with both inverted elements beside it (two
 * counted, not four; the friction once); none read after the second; after the third, one
 * inverted element beside what was read. */
static int read_states_only(void)
{
    NsRunWarnings w = {0};
    ns_run_warnings_step(&w, (int[NS_WARN_KINDS]){[NS_WARN_INVERTED] = 2, [NS_WARN_LCP] = 1});
    ns_run_warnings_read(&w, 2);
    ns_run_warnings_read(&w, 2);
    ns_run_warnings_step(&w, (int[NS_WARN_KINDS]){[NS_WARN_LCP] = 1});
    ns_run_warnings_step(&w, (int[NS_WARN_KINDS]){[NS_WARN_INVERTED] = 3});
    ns_run_warnings_read(&w, 1);
    ENSURE(w.total[NS_WARN_INVERTED] == 5 && w.steps[NS_WARN_INVERTED] == 2);
    ENSURE(w.most[NS_WARN_INVERTED] == 3);
    ENSURE(ns_run_warnings_affected(&w, NS_WARN_INVERTED) == 3);
    ENSURE(w.total[NS_WARN_LCP] == 2 && ns_run_warnings_affected(&w, NS_WARN_LCP) == 1);
    char line[256];
    ns_run_warnings_line(&w, line, sizeof line);
    ENSURE(strcmp(line, "warnings: NaN 0, inverted 5 (3 bore on the result), unconverged 0, "
                        "friction unresolved 2 (1 bore on the result)") == 0);
    NsRunWarnings q = {0};
    ns_run_warnings_step(&q, (int[NS_WARN_KINDS]){[NS_WARN_INVERTED] = 1, [NS_WARN_LCP] = 1});
    ns_run_warnings_step(&q, (int[NS_WARN_KINDS]){0});
    ns_run_warnings_read(&q, 0);
    ns_run_warnings_line(&q, line, sizeof line);
    ENSURE(strcmp(line, "warnings: NaN 0, inverted 1 (none bore on the result), unconverged 0, "
                        "friction unresolved 1 (none bore on the result)") == 0);
    return 0;
}

/* A read before any step counts nothing; a NaN bears on the result unread. */
static int nan_always_counts(void)
{
    NsRunWarnings w = {0};
    ns_run_warnings_read(&w, 0);
    ns_run_warnings_step(&w, (int[NS_WARN_KINDS]){[NS_WARN_NAN] = 1, [NS_WARN_UNCONVERGED] = 1});
    ENSURE(ns_run_warnings_affected(&w, NS_WARN_NAN) == 1);
    ENSURE(ns_run_warnings_affected(&w, NS_WARN_UNCONVERGED) == 0);
    ns_run_warnings_read(&w, 0);
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
