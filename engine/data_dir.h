/* Where needlesim finds the data it ships: its Lua modules (`scripts`), the ready scenarios
 * (`scenarios`) and `assets`.
 *
 * The lookup, in order, for each folder WHAT:
 *   1. the environment: NEEDLESIM_SCRIPTS, NEEDLESIM_SCENARIOS, NEEDLESIM_ASSETS (used as given);
 *   2. beside the running binary: /proc/self/exe's folder + NS_DATA_FROM_BIN (an installed
 *      needlesim, `<prefix>/bin/needlesim` → `<prefix>/share/needlesim/WHAT`), wherever the
 *      installation was moved;
 *   3. the source tree, when the binary lies inside the build folder it was built in (a build
 *      run in place: `build/needlesim`, `build/tests/bench_*`);
 *   4. the configured install prefix (`<prefix>/share/needlesim/WHAT`), whether or not it exists.
 * A candidate of 2 and 3 is taken only if it is a folder. `needlesim --version` prints the
 * result and the rule that gave it. */
#ifndef NS_DATA_DIR_H
#define NS_DATA_DIR_H

/* The folder WHAT ("scripts", "scenarios", "assets") is found in; never NULL. Resolved once per
 * WHAT and kept: call it first from one thread (the program's main thread does, while loading a
 * scenario). */
const char *ns_data_dir(const char *what);

/* How ns_data_dir(WHAT) was found, for `--version`: e.g. "found via NEEDLESIM_SCRIPTS". */
const char *ns_data_dir_via(const char *what);

#endif
