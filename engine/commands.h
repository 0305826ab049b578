/* The needlesim subcommands: each takes its own argv (argv[0] is the command's name) and
 * returns the process exit status: 0 success, 1 bad input or failure, 2 usage error. */
#ifndef NS_COMMANDS_H
#define NS_COMMANDS_H

#include <stdbool.h>

int ns_cmd_check(int argc, char **argv);
int ns_cmd_validate(int argc, char **argv);
int ns_cmd_run(int argc, char **argv);
int ns_cmd_bench(int argc, char **argv);
int ns_cmd_live(int argc, char **argv);
int ns_cmd_plan(int argc, char **argv);
int ns_cmd_score(int argc, char **argv);
/* engine/bench_live.c: `needlesim bench --live` (ns_cmd_bench passes it on) */
int ns_bench_live(int argc, char **argv);
/* engine/bench_dose.c: `needlesim bench --dose` (ns_cmd_bench passes it on) */
int ns_bench_dose(int argc, char **argv);
/* engine/bench_planning.c: `needlesim bench --planning` (ns_cmd_bench passes it on) */
int ns_bench_planning(int argc, char **argv);
struct NsRun;
struct NsRunOpts;
/* One bench run of o's scenario (o->sets applied) with the given solver into r (initialised
 * here; free it with ns_run_free even on failure): the run's loop until its script ends or
 * o->steps. */
int ns_bench_run(const struct NsRunOpts *o, int solver, bool log_tips, struct NsRun *r, char *err,
                 int err_sz);

#endif
