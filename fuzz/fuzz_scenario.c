/* libFuzzer harness for the scenario loader: the Lua file run in its sandbox and the tissue
 * built from what it returns (engine/scenario.c, engine/lua_runtime.c), then the run fields
 * read from it (engine/run_spec.c), as `needlesim run` does before its first step. A scenario
 * that fails is an error message; a crash, a sanitizer report, a leak, a load past the time
 * limit or a runaway allocation is a finding.
 *
 * `require "needlesim"` finds this tree's scripts/ (NEEDLESIM_SCRIPTS, else the folder the
 * build was configured with); a plain `require` finds only the input itself, in its private
 * folder.
 *
 *     build-fuzz/fuzz/fuzz_scenario fuzz/corpus/scenario -dict=fuzz/scenario.dict   (tools/fuzz.sh)
 */
#include "fuzz_file.h"
#include "lua_runtime.h"
#include "run_spec.h"
#include "scenario.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    /* Legitimate tissues up to NS_LIMIT_MESHER_BYTES take seconds to mesh, longer than the
     * run's time limit per input under the sanitizers: 2 MiB (about 4,000 lattice vertices)
     * keeps every input's meshing fast, and the limit's own path is exercised all the more. */
    ns_scenario_set_mesher_budget(2.0 * 1048576.0);
    /* Likewise the script's own budgets: an endless loop runs the full 5e8 instructions in
     * about 7 s under the sanitizers and a heap-filling one 5 s, and mutations find both often
     * enough to hold the campaign to ~50 executions/s. 5e6 instructions (about 0.07 s; the
     * corpus's largest scenario loads in under a tenth of it) and 32 MiB keep each input short;
     * the same checks stop it, only sooner. */
    ns_lua_set_limits(5000000, (size_t)32 << 20);
    const char *path = fuzz_write_file("input.lua", data, size);
    NsScenario sc;
    char err[1024] = "";
    if (ns_scenario_load_set(path, NULL, 0, &sc, err, (int)sizeof err) == 0) {
        NsRunSpec spec;
        if (ns_run_spec_read(&sc, &spec, err, (int)sizeof err) == 0)
            ns_run_spec_free(&spec);
        ns_scenario_free(&sc);
    }
    if (memchr(err, '\0', sizeof err) == NULL)
        abort();
    fuzz_report(err);
    unlink(path);
    return 0;
}
