/* The Lua sandbox a scenario runs in: one lua_State per scenario (STYLE.md: the Lua model;
 * Redis and mpv embed Lua this way).
 *
 * Only the base, table, string, math, utf8 and coroutine libraries are open: no io, os,
 * package or debug. dofile, loadfile and string.dump are gone; `load` takes text only; print
 * writes to stderr (stdout belongs to --json). `require` loads `needlesim` and
 * `needlesim.<x>` from the scripts folder (NEEDLESIM_SCRIPTS, else NS_SCRIPTS_DIR) and plain
 * names from the scenario's own folder, nothing else (the engine finds the same function in
 * the registry as "ns.require", whatever a script does to its globals). math.random is seeded with
 * a constant, so a scenario is deterministic unless it reseeds.
 *
 * Every entry from C into Lua goes through ns_lua_call: a protected call with a fresh
 * instruction budget (an endless loop fails instead of hanging) whose error, if any, is one
 * line "file:line: message". */
#ifndef NS_LUA_RUNTIME_H
#define NS_LUA_RUNTIME_H

#include <lua.h>

/* Instructions one protected entry from C may run before it fails. */
#define NS_LUA_DEFAULT_BUDGET 500000000LL

typedef struct NsLua NsLua;

/* A sandbox for the scenario at scenario_path (which sets the folder plain `require` names
 * are looked up in). Returns NULL with a message when out of memory. */
NsLua *ns_lua_open(const char *scenario_path, char *err, int err_sz);
void ns_lua_close(NsLua *rt);

lua_State *ns_lua_state(NsLua *rt);
const char *ns_lua_scripts_dir(const NsLua *rt);
/* The scenario's folder ("." when the path has none). */
const char *ns_lua_scenario_dir(const NsLua *rt);

/* Instructions each later ns_lua_call may run (default NS_LUA_DEFAULT_BUDGET). */
void ns_lua_set_budget(NsLua *rt, long long instructions);

/* lua_pcall of the function below nargs arguments on the stack, with the message handler and
 * a fresh budget. Returns 0 with nresults values pushed, or -1 with the stack back where it
 * was minus the function and arguments, and a one-line message in err. */
int ns_lua_call(NsLua *rt, int nargs, int nresults, char *err, int err_sz);

/* Loads the scenario file (text only, chunkname "@path") and runs it; pushes its first
 * result. Returns 0, or -1 with a one-line message ("path:line: ..." or
 * "needlesim: cannot open ..."). */
int ns_lua_run_scenario(NsLua *rt, const char *path, char *err, int err_sz);

#endif
