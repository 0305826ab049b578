/* Temporary outputs removed on every way out (cleanup.h). */
#include "cleanup.h"

#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define CLEANUP_MAX 64

static char *volatile paths[CLEANUP_MAX];
static volatile sig_atomic_t stop_signal;

static void remove_registered(void)
{
    for (int i = CLEANUP_MAX - 1; i >= 0; i--) { /* newest first: files before their folders */
        char *p = paths[i];
        if (p && unlink(p) != 0)
            rmdir(p);
    }
}

static void (*volatile on_stop)(void);

void ns_cleanup_on_signal(void (*fn)(void))
{
    on_stop = fn;
}

static void on_signal(int sig)
{
    if (stop_signal == 0) {
        stop_signal = sig;
        if (on_stop)
            on_stop();
        return;
    }
    /* The second signal: out at once, with the one line every way out says (write(2) is
     * async-signal-safe; the run's own line, had it come, would not). */
    static const char msg[] = "needlesim: interrupted again: stopped at once, nothing written\n";
    ssize_t w = write(STDERR_FILENO, msg, sizeof msg - 1);
    (void)w;
    remove_registered();
    _exit(128 + sig);
}

void ns_cleanup_install(void)
{
    static int installed;
    if (installed)
        return;
    installed = 1;
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGHUP, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
}

int ns_cleanup_add(const char *path)
{
    for (int i = 0; i < CLEANUP_MAX; i++)
        if (!paths[i]) {
            size_t n = strlen(path) + 1;
            char *p = malloc(n);
            if (!p)
                return -1;
            memcpy(p, path, n);
            paths[i] = p;
            return 0;
        }
    return -1;
}

void ns_cleanup_forget(const char *path)
{
    for (int i = 0; i < CLEANUP_MAX; i++)
        if (paths[i] && strcmp(paths[i], path) == 0) {
            char *p = paths[i];
            paths[i] = NULL;
            free(p);
            return;
        }
}

const volatile sig_atomic_t *ns_cleanup_stop_flag(void)
{
    return &stop_signal;
}

int ns_cleanup_signal(void)
{
    return stop_signal;
}

_Noreturn void ns_cleanup_fatal(const char *line)
{
    fprintf(stderr, "%s\n", line);
    fflush(stderr);
    remove_registered();
    _exit(2);
}
