/* Temporary files and folders a command is writing (the `.part` names it renames into place
 * when it succeeds): registered here, so that every way out removes them.
 *
 * SIGINT, SIGTERM and SIGHUP only raise a flag (ns_cleanup_signal): the run loop and the Lua
 * hook look at it and end through the ordinary error path, which removes the run's temporary
 * files itself. A second signal, for a program stuck where nobody looks, removes what is
 * registered (unlink and rmdir only: async-signal-safe) and exits at once. A fatal internal
 * error (ns_cleanup_fatal) does the same. Nothing else is ever removed: only paths this
 * process created are registered. SIGPIPE is ignored (a write to a closed pipe is an error). */
#ifndef NS_CLEANUP_H
#define NS_CLEANUP_H

#include <signal.h>

/* Installs the signal handlers (once per process). */
void ns_cleanup_install(void);
/* Registers a file or folder this process created (a folder is removed with rmdir, so only
 * once its files are gone). The string is copied. Returns 0, or -1 when the table is full or
 * out of memory (the caller then treats it as an error). */
int ns_cleanup_add(const char *path);
/* Forgets a path (renamed into place, or removed by the caller). */
void ns_cleanup_forget(const char *path);
/* A function the stop signals' handler calls after raising the flag (async-signal-safe: the
 * Lua runtime sets its hook, so a running script sees the signal at its next instruction). */
void ns_cleanup_on_signal(void (*fn)(void));
/* The flag itself, for long C work that checks it (the mesher). */
const volatile sig_atomic_t *ns_cleanup_stop_flag(void);
/* The signal that asked the program to stop (SIGINT, SIGTERM, SIGHUP), or 0. */
int ns_cleanup_signal(void);
/* Prints `line` to stderr, removes everything registered and exits with status 2. */
_Noreturn void ns_cleanup_fatal(const char *line);

#endif
