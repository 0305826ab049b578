/* needlesim: the command line (DESIGN.md "Command line"; the contract tests rely on).
 *
 * Exit status: 0 success, 1 bad input or a failed run (one line on stderr), 2 usage error or
 * a command this version does not have yet. */
#include <stdio.h>
#include <string.h>

#include "commands.h"
#include "data_dir.h"
#include "ns_config.h"

#if NS_HAVE_OPENBLAS
/* From OpenBLAS (declared here to avoid depending on where its cblas.h lives). */
void openblas_set_num_threads(int num_threads);
char *openblas_get_config(void);
#endif

static const char usage[] =
    "usage: needlesim COMMAND [ARGS]\n"
    "\n"
    "  needlesim check SCENARIO.lua [--json] [--mesh-out FILE.vtu|FILE.msh]\n"
    "      run the scenario, build its tissue mesh and print mesh and model statistics\n"
    "  needlesim run SCENARIO.lua [-o DIR] [--steps N] [--threads N] [--solver NAME]\n"
    "                [--set KEY=VALUE]... [--record LOG.csv | --replay LOG.csv] [--quiet]\n"
    "                [--no-render | [--frames] [--video FILE.mp4] [--width W] [--height H]\n"
    "                [--frame-every K]] [--checkpoint-at T FILE] [--resume FILE]\n"
    "      run the scenario's script, score its targets, write DIR/report.json,\n"
    "      DIR/trajectory.csv and DIR/summary.png (and frames, a video: docs/rendering.md)\n"
    "  needlesim live SCENARIO.lua [--port N] [--bind ADDR] [--width W --height H] [--fps F]\n"
    "                 [--record LOG.csv] [-o DIR] [--set KEY=VALUE]... [--threads N] [--quiet]\n"
    "      a trainee drives the needle from a browser in real time (docs/live.md); the session\n"
    "      is scored and its controls recorded as `run` does\n"
    "  needlesim plan SCENARIO.lua --target NAME [--json] [-o DIR] [--clearance M]\n"
    "                 [--method rrt|helix] [--seed N]\n"
    "      plan a bevel-tip insertion to a target around the obstacles on the kinematic model\n"
    "      (docs/planning.md): predicted error, clearance, length and planning time\n"
    "  needlesim score LOG.csv... -o OUT [--jobs N] [--scenario-dir DIR] [--rescore]\n"
    "                  [--slurm [--partition P] [--array-chunk K]]\n"
    "      replay and score a training programme's logs into OUT/scores.csv and the cohort\n"
    "      report (docs/scoring.md); a stopped batch resumes\n"
    "  needlesim validate [CASE...] [--json] [--list]\n"
    "      run the built-in validation cases (docs/validation.md); exit 1 if any fails\n"
    "  needlesim bench SCENARIO.lua [--steps N] [--solver NAME] [--threads N] [--set KEY=VALUE]\n"
    "                  [--json]\n"
    "      per-stage step timings of the scenario's script (the paper's Tables 2 and 3)\n"
    "  needlesim bench --dose [--repeat N] [--threads N] [--json]\n"
    "      TG-43 dose grid of a synthetic 80-seed implant (docs/brachytherapy.md)\n"
    "  needlesim --help | --version\n"
    "\n"
    "Scenarios are Lua files; see docs/scenarios.md.\n";

static void print_version(void)
{
    printf("needlesim %s\n", NS_VERSION);
#if NS_HAVE_OPENBLAS
    const char *config = openblas_get_config();
    printf("BLAS: %s\n", config ? config : "OpenBLAS");
#else
    printf("BLAS: system default (OpenBLAS not linked)\n");
#endif
    /* Where the shipped data is looked for (engine/data_dir.h gives the order). */
    static const char *const what[] = {"scripts", "scenarios", "assets"};
    for (size_t i = 0; i < sizeof what / sizeof what[0]; i++)
        printf("%s: %s (%s)\n", what[i], ns_data_dir(what[i]), ns_data_dir_via(what[i]));
}

int main(int argc, char **argv)
{
#if NS_HAVE_OPENBLAS
    /* One BLAS thread unless a command asks for more: the environment must not decide
     * (meson.build, DESIGN.md: more threads slowed CHOLMOD on 2 cores). */
    openblas_set_num_threads(1);
#endif
    if (argc < 2) {
        fputs(usage, stderr);
        return 2;
    }
    const char *cmd = argv[1];
    if (strcmp(cmd, "--help") == 0 || strcmp(cmd, "-h") == 0 || strcmp(cmd, "help") == 0) {
        fputs(usage, stdout);
        return 0;
    }
    if (strcmp(cmd, "--version") == 0 || strcmp(cmd, "-V") == 0) {
        print_version();
        return 0;
    }
    if (strcmp(cmd, "check") == 0)
        return ns_cmd_check(argc - 1, argv + 1);
    if (strcmp(cmd, "validate") == 0)
        return ns_cmd_validate(argc - 1, argv + 1);
    if (strcmp(cmd, "run") == 0)
        return ns_cmd_run(argc - 1, argv + 1);
    if (strcmp(cmd, "bench") == 0)
        return ns_cmd_bench(argc - 1, argv + 1);
    if (strcmp(cmd, "live") == 0)
        return ns_cmd_live(argc - 1, argv + 1);
    if (strcmp(cmd, "plan") == 0)
        return ns_cmd_plan(argc - 1, argv + 1);
    if (strcmp(cmd, "score") == 0)
        return ns_cmd_score(argc - 1, argv + 1);
    if (cmd[0] == '-')
        fprintf(stderr, "needlesim: unknown option '%s' (needlesim --help)\n", cmd);
    else
        fprintf(stderr, "needlesim: unknown command '%s' (needlesim --help)\n", cmd);
    return 2;
}
