/* The Lua sandbox a scenario runs in: one lua_State per scenario (STYLE.md: the Lua model;
 * Redis and mpv embed Lua this way).
 *
 * Only the base, table, string, math, utf8 and coroutine libraries are open: no io, os,
 * package or debug. dofile, loadfile and string.dump are gone; `load` takes text only; print
 * writes to stderr (stdout belongs to --json). `require` loads `needlesim` and
 * `needlesim.<x>` from the scripts folder (ns_data_dir("scripts"), data_dir.h) and plain
 * names from the scenario's own folder, nothing else (the engine finds the same function in
 * the registry as "ns.require", whatever a script does to its globals). math.random is seeded with
 * a constant, so a scenario is deterministic unless it reseeds.
 *
 * Every entry from C into Lua goes through ns_lua_call: a protected call whose error, if any,
 * is one line "file:line: message". The instruction budget and the wall clock belong to a
 * phase (loading the scenario, then the run), not to one call: all the calls of a phase draw on
 * one budget (sim/limits.h), so a shape function the mesher calls a million times cannot
 * escape it. setmetatable refuses __gc (finalizers run with hooks off) and the string
 * library's pattern functions are bounded before they run (their matcher is C). A Lua error
 * outside every protected call (a bug) ends the program with one line, not an abort. */
#ifndef NS_LUA_RUNTIME_H
#define NS_LUA_RUNTIME_H

#include <lua.h>

typedef struct NsLua NsLua;

/* A sandbox for the scenario at scenario_path (which sets the folder plain `require` names
 * are looked up in). Returns NULL with a message when out of memory. */
NsLua *ns_lua_open(const char *scenario_path, char *err, int err_sz);
void ns_lua_close(NsLua *rt);

/* Lowers, for every sandbox opened after it in this process, the instructions a scenario's
 * loading may run and the memory its Lua state may hold (defaults: NS_LIMIT_LOAD_INSTRUCTIONS,
 * NS_LIMIT_LUA_MEMORY). For the fuzzing harness, whose inputs must each end in milliseconds;
 * needlesim itself never calls it. */
void ns_lua_set_limits(long long instructions, size_t memory_bytes);

lua_State *ns_lua_state(NsLua *rt);
const char *ns_lua_scripts_dir(const NsLua *rt);
/* The scenario's folder ("." when the path has none). */
const char *ns_lua_scenario_dir(const NsLua *rt);

/* Starts a phase ("loading the scenario" is begun by ns_lua_open; the run begins "the run"):
 * every ns_lua_call until the next phase draws on `instructions` Lua instructions in all and
 * must end within `seconds` of wall-clock time from now (0: no limit). phase is a static
 * string used in messages. per_call_seconds > 0: each call must also end within that many
 * seconds (the run's ticks). */
void ns_lua_begin_phase(NsLua *rt, const char *phase, long long instructions, double seconds,
                        double per_call_seconds);

/* lua_pcall of the function below nargs arguments on the stack, with the message handler, on
 * what is left of the phase's budget. Returns 0 with nresults values pushed, or -1 with the stack
 * back where it was minus the function and arguments, and a one-line message in err. */
int ns_lua_call(NsLua *rt, int nargs, int nresults, char *err, int err_sz);

/* Loads the scenario file (text only, chunkname "@path") and runs it; pushes its first
 * result. Returns 0, or -1 with a one-line message ("path:line: ..." or
 * "needlesim: cannot open ..."). */
int ns_lua_run_scenario(NsLua *rt, const char *path, char *err, int err_sz);

#endif
