/* The needlesim subcommands: each takes its own argv (argv[0] is the command's name) and
 * returns the process exit status: 0 success, 1 bad input or failure, 2 usage error. */
#ifndef NS_COMMANDS_H
#define NS_COMMANDS_H

int ns_cmd_check(int argc, char **argv);
int ns_cmd_validate(int argc, char **argv);
int ns_cmd_run(int argc, char **argv);
int ns_cmd_bench(int argc, char **argv);
int ns_cmd_live(int argc, char **argv);
int ns_cmd_plan(int argc, char **argv);
int ns_cmd_score(int argc, char **argv);
/* engine/bench_live.c: `needlesim bench --live` (ns_cmd_bench passes it on) */
int ns_bench_live(int argc, char **argv);

#endif
