/* The scenario sandbox (see lua_runtime.h). */
#include "lua_runtime.h"

#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/time.h>
#include <time.h>
#include <unistd.h>

#include <lauxlib.h>
#include <lualib.h>

#include "cleanup.h"
#include "data_dir.h"
#include "ns_limits.h"
#include "ns_config.h"

/* The count hook runs every NS_HOOK_STEP instructions and charges them to the budget. */
#define NS_HOOK_STEP 10000
/* A line event (only while the scenario chunk runs) costs about this many instructions, and
 * is charged so (a tight endless loop fires one per iteration). */
#define NS_LINE_EVENT_COST 8
/* Memory a scenario's Lua state may hold (past it allocations fail, "not enough memory") and
 * the instructions its loading may run: the limits of ns_limits.h unless a harness lowered them
 * (ns_lua_set_limits). */
static size_t lua_memory_limit = NS_LIMIT_LUA_MEMORY;
static long long load_instructions = NS_LIMIT_LOAD_INSTRUCTIONS;

void ns_lua_set_limits(long long instructions, size_t memory_bytes)
{
    load_instructions = instructions;
    lua_memory_limit = memory_bytes;
}

struct NsLua {
    lua_State *L;
    char *scripts_dir;
    char *scenario_dir;
    char *scenario_source;   /* "@path" of the scenario chunk, for the line hook */
    long long budget;        /* instructions of the current phase (loading, the run) */
    long long remaining;     /* left in the current phase, over all its entries together */
    const char *phase;       /* "loading the scenario", "the run": for messages */
    double deadline;         /* CLOCK_MONOTONIC seconds the phase must end by (0: none) */
    double seconds;          /* the phase's wall-clock limit [s], for messages */
    double per_call;         /* > 0: the clock applies to each call, not the phase [s] */
    int last_line;           /* last line run in the scenario chunk (see ns_where) */
    const char *source_seen; /* the chunk's source string as Lua holds it, once seen */
    int hook_mask;           /* LUA_MASKCOUNT, plus LUA_MASKLINE while the chunk runs */
    int modules_ref;         /* registry ref: the private require cache */
    size_t memory;           /* bytes held by the state */
    int memory_hits;         /* allocations refused at the limit so far */
};

/* The cache holds this while a module is loading, to catch require cycles. */
static const char loading_marker = 0;

static NsLua *runtime_of(lua_State *L)
{
    return *(NsLua **)lua_getextraspace(L);
}

static char *dup_string(const char *s)
{
    size_t n = strlen(s) + 1;
    char *d = malloc(n);
    if (d)
        memcpy(d, s, n);
    return d;
}

/* Copies the first line of msg into err (Lua messages are one line, but a __tostring or a
 * message with embedded newlines must not break the one-line contract). */
static void copy_first_line(char *err, int err_sz, const char *msg)
{
    if (err_sz <= 0)
        return;
    size_t n = strcspn(msg, "\n");
    while (n > 0 && (msg[n - 1] == ' ' || msg[n - 1] == '\r' || msg[n - 1] == '\t'))
        n--;
    if (n >= (size_t)err_sz)
        n = (size_t)err_sz - 1;
    memcpy(err, msg, n);
    err[n] = '\0';
}

/* The name errors and `where` strings show for a function's source: the whole path for
 * files (Lua's own short_src cuts long ones), the short form for strings. */
static const char *source_name(const lua_Debug *ar)
{
    return ar->source && ar->source[0] == '@' ? ar->source + 1 : ar->short_src;
}

/* Lua's allocator with the state's memory limit. At the limit Lua runs a full collection and
 * asks again: a script that keeps allocating there would make every allocation a collection of
 * the whole heap (minutes). After NS_LUA_MEMORY_RETRIES refusals the retries are refused too,
 * so the script fails with "not enough memory" after a bounded number of collections. */
#define NS_LUA_MEMORY_RETRIES 8
static void *limited_alloc(void *ud, void *ptr, size_t osize, size_t nsize)
{
    NsLua *rt = ud;
    size_t old = ptr ? osize : 0;
    if (nsize == 0) {
        free(ptr);
        rt->memory -= old;
        return NULL;
    }
    if (nsize > old &&
        (rt->memory - old + nsize > lua_memory_limit || rt->memory_hits > NS_LUA_MEMORY_RETRIES)) {
        rt->memory_hits++;
        return NULL;
    }
    void *p = realloc(ptr, nsize);
    if (p)
        rt->memory = rt->memory - old + nsize;
    return p;
}

static void set_hook(lua_State *L, int mask, int count);

/* The state a protected call is running now, and its hook mask: a timer (every
 * NS_WATCH_SECONDS while Lua runs) and the stop signals (cleanup.h) set its count hook to fire
 * at the next instruction, so the wall clock and a signal are seen within a fraction of a
 * second even when each instruction is long C work (a string.rep, a concatenation of large
 * strings), not only every NS_HOOK_STEP instructions. lua_sethook may be called from a signal
 * handler (Lua's manual). */
#define NS_WATCH_SECONDS 0.2
static void hook(lua_State *L, lua_Debug *ar);
static lua_State *volatile active_L;
static volatile int active_mask;
static volatile sig_atomic_t forced;

static pthread_t active_thread; /* the thread running active_L */

/* Runs in a signal handler. lua_sethook is only safe on the thread the signal interrupted
 * when that thread is the one running Lua (another thread would race with its calls and
 * returns): on any other thread (the solver's workers, the background factorization) the
 * signal is passed on to the Lua thread instead. */
static void force_check(void)
{
    lua_State *L = active_L;
    if (!L)
        return;
    if (!pthread_equal(pthread_self(), active_thread)) {
        pthread_kill(active_thread, SIGALRM);
        return;
    }
    forced = 1;
    lua_sethook(L, hook, active_mask, 1);
}

static void on_alarm(int sig)
{
    (void)sig;
    force_check();
}

/* Arms (on) or disarms the watch timer. */
static void watch(bool on)
{
    static bool installed;
    if (!installed) {
        struct sigaction sa;
        memset(&sa, 0, sizeof sa);
        sa.sa_handler = on_alarm;
        sa.sa_flags = SA_RESTART;
        sigemptyset(&sa.sa_mask);
        sigaction(SIGALRM, &sa, NULL);
        ns_cleanup_on_signal(force_check);
        installed = true;
    }
    struct itimerval it;
    memset(&it, 0, sizeof it);
    if (on) {
        it.it_interval.tv_usec = (long)(NS_WATCH_SECONDS * 1e6);
        it.it_value = it.it_interval;
    }
    setitimer(ITIMER_REAL, &it, NULL);
}

static double monotonic_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* Raises the "budget used up" error at the current line. From then on every instruction fails
 * (the hook fires at each), so a script that catches the error with pcall cannot go on: the
 * error unwinds every pcall up to C. */
static int exhausted(lua_State *L, lua_Debug *ar, const char *what)
{
    NsLua *rt = runtime_of(L);
    rt->remaining = 0;
    set_hook(L, rt->hook_mask, 1);
    if (ar && lua_getinfo(L, "Sl", ar) && ar->currentline > 0)
        lua_pushfstring(L, "%s:%d: %s", source_name(ar), ar->currentline, what);
    else
        lua_pushstring(L, what);
    return lua_error(L);
}

static const char *budget_message(NsLua *rt, char *buf, size_t n)
{
    snprintf(buf, n,
             "instruction limit exceeded: %s may run %.3g Lua instructions in all "
             "(an endless loop?)",
             rt->phase ? rt->phase : "the script", (double)rt->budget);
    return buf;
}

/* Count events charge the budget and check the phase's wall clock; line events (only while
 * the scenario chunk runs) remember where in the scenario file we are. */
static void hook(lua_State *L, lua_Debug *ar)
{
    NsLua *rt = runtime_of(L);
    char buf[200];
    if (ar->event == LUA_HOOKLINE) {
        /* The chunk's functions share one source string: once it has matched, a pointer
         * comparison does (a strcmp on every line was most of a tight loop's cost). */
        if (rt->scenario_source && lua_getinfo(L, "S", ar) &&
            (ar->source == rt->source_seen || strcmp(ar->source, rt->scenario_source) == 0)) {
            rt->source_seen = ar->source;
            rt->last_line = ar->currentline;
        }
        rt->remaining -= NS_LINE_EVENT_COST;
    } else if (ar->event == LUA_HOOKCOUNT) {
        if (forced) { /* a check the watch timer or a signal asked for (see force_check) */
            forced = 0;
            rt->remaining -= 1;
            set_hook(L, rt->hook_mask, NS_HOOK_STEP);
        } else {
            rt->remaining -= NS_HOOK_STEP;
        }
        if (ns_cleanup_signal() != 0)
            exhausted(L, ar, "interrupted by a signal");
        if (rt->deadline > 0.0 && monotonic_s() > rt->deadline) {
            snprintf(buf, sizeof buf, "%s took longer than its limit of %.0f s",
                     rt->phase ? rt->phase : "the script", rt->seconds);
            exhausted(L, ar, buf);
        }
    } else {
        return;
    }
    if (rt->remaining <= 0)
        exhausted(L, ar, budget_message(rt, buf, sizeof buf));
}

static void set_hook(lua_State *L, int mask, int count)
{
    lua_sethook(L, hook, mask, count);
}

/* msg starts with "SOURCE:LINE:" (a position Lua or a script put there). */
static bool has_location(const char *msg)
{
    const char *c = strchr(msg, ':');
    while (c && c - msg < 1024) {
        const char *d = c + 1;
        while (*d >= '0' && *d <= '9')
            d++;
        if (d > c + 1 && *d == ':')
            return true;
        c = strchr(c + 1, ':');
    }
    return false;
}

/* The error's text: strings as they are, anything else (error(nil), error({})) described and
 * given the file and line of the Lua function that raised it, so every message has one. */
static int message_handler(lua_State *L)
{
    NsLua *rt = runtime_of(L);
    /* The text: strings as they are; else a __tostring's string (called protected: it may
     * fail too); else the value described. */
    const char *msg = NULL;
    if (lua_type(L, 1) == LUA_TSTRING || lua_type(L, 1) == LUA_TNUMBER) {
        msg = lua_tostring(L, 1);
    } else if (luaL_getmetafield(L, 1, "__tostring") != LUA_TNIL) {
        lua_pushvalue(L, 1);
        if (lua_pcall(L, 1, 1, 0) == LUA_OK && lua_type(L, -1) == LUA_TSTRING)
            msg = lua_tostring(L, -1);
    }
    if (!msg)
        msg =
            lua_pushfstring(L, "error (the error value is %s, not a message)", luaL_typename(L, 1));
    /* A message with no position (raised from C, error("x", 0), a __tostring) gets the
     * innermost Lua line, else the scenario file. */
    if (has_location(msg) || strncmp(msg, "needlesim", 9) == 0) {
        lua_pushstring(L, msg);
        return 1;
    }
    lua_Debug ar;
    for (int level = 1; lua_getstack(L, level, &ar); level++)
        if (lua_getinfo(L, "Sl", &ar) && ar.currentline > 0) {
            lua_pushfstring(L, "%s:%d: %s", source_name(&ar), ar.currentline, msg);
            return 1;
        }
    if (rt->scenario_source)
        lua_pushfstring(L, "%s: %s", rt->scenario_source + 1, msg);
    else
        lua_pushstring(L, msg);
    return 1;
}

int ns_lua_call(NsLua *rt, int nargs, int nresults, char *err, int err_sz)
{
    lua_State *L = rt->L;
    int base = lua_gettop(L) - nargs; /* the function's slot */
    /* A phase with a clock per call (the run's ticks) starts each call's clock below: the
     * deadline left by the last call says nothing of this one (the steps between two ticks,
     * seconds each on a fine mesh or a loaded machine, ran past it). */
    int late = rt->per_call <= 0.0 && rt->deadline > 0.0 && monotonic_s() > rt->deadline;
    if (rt->remaining <= 0 || late) {
        char buf[200];
        if (rt->remaining <= 0)
            budget_message(rt, buf, sizeof buf);
        else
            snprintf(buf, sizeof buf, "%s took longer than its limit of %.0f s",
                     rt->phase ? rt->phase : "the script", rt->seconds);
        snprintf(err, (size_t)err_sz, "%s: %s",
                 rt->scenario_source ? rt->scenario_source + 1 : "needlesim", buf);
        lua_settop(L, base - 1);
        return -1;
    }
    lua_pushcfunction(L, message_handler);
    lua_insert(L, base);
    if (rt->per_call > 0.0) /* the run: each call (a tick of the script) has its own clock */
        rt->deadline = monotonic_s() + rt->per_call;
    set_hook(L, rt->hook_mask, rt->remaining < NS_HOOK_STEP ? 1 : NS_HOOK_STEP);
    lua_State *outer = active_L;
    int outer_mask = active_mask;
    active_mask = rt->hook_mask;
    active_thread = pthread_self();
    active_L = L;
    if (!outer)
        watch(true);
    int rc = lua_pcall(L, nargs, nresults, base);
    active_L = outer;
    active_mask = outer_mask;
    if (!outer)
        watch(false);
    if (rc == LUA_ERRMEM) {
        /* No message handler runs for memory errors, so no file:line either. */
        snprintf(err, (size_t)err_sz, "%s: not enough memory (a scenario may use %d MiB)",
                 rt->scenario_source ? rt->scenario_source + 1 : "needlesim",
                 (int)(lua_memory_limit >> 20));
        lua_pop(L, 1);
        lua_remove(L, base);
        return -1;
    }
    if (rc != LUA_OK) {
        const char *msg = lua_tostring(L, -1);
        copy_first_line(err, err_sz, msg ? msg : "unknown Lua error");
        lua_pop(L, 1);
        lua_remove(L, base);
        return -1;
    }
    lua_remove(L, base);
    return 0;
}

/* print(...): like Lua's, but to stderr (stdout carries --json). */
static int sandbox_print(lua_State *L)
{
    int n = lua_gettop(L);
    for (int i = 1; i <= n; i++) {
        size_t len;
        const char *s = luaL_tolstring(L, i, &len);
        if (i > 1)
            fputc('\t', stderr);
        fwrite(s, 1, len, stderr);
        lua_pop(L, 1);
    }
    fputc('\n', stderr);
    return 0;
}

/* load(chunk [, chunkname [, mode [, env]]]): the base library's load with mode forced to
 * text, so no precompiled (unverified) bytecode gets in. Without env the chunk sees the
 * sandbox's globals, which are all a scenario ever sees. */
static int sandbox_load(lua_State *L)
{
    int n = lua_gettop(L);
    lua_pushvalue(L, lua_upvalueindex(1));
    lua_pushvalue(L, 1);
    if (n >= 2)
        lua_pushvalue(L, 2);
    else
        lua_pushnil(L);
    lua_pushliteral(L, "t");
    if (n >= 4)
        lua_pushvalue(L, 4);
    lua_call(L, n >= 4 ? 4 : 3, LUA_MULTRET);
    return lua_gettop(L) - n;
}

/* __ns_where(level): "file:line" of the function `level` levels up (1 = the caller of
 * __ns_where, as for error()). When that frame has no line, because the caller made a tail
 * call (`return ns.scenario{...}` does) and so left the stack, the last scenario line run is
 * the best answer there is. */
static int ns_where(lua_State *L)
{
    int level = (int)luaL_optinteger(L, 1, 1);
    lua_Debug ar;
    if (level >= 0 && lua_getstack(L, level, &ar) && lua_getinfo(L, "Sl", &ar) &&
        ar.currentline > 0) {
        lua_pushfstring(L, "%s:%d", source_name(&ar), ar.currentline);
        return 1;
    }
    NsLua *rt = runtime_of(L);
    if (rt->scenario_source && rt->last_line > 0)
        lua_pushfstring(L, "%s:%d", rt->scenario_source + 1, rt->last_line);
    else if (rt->scenario_source)
        lua_pushstring(L, rt->scenario_source + 1);
    else
        lua_pushliteral(L, "?");
    return 1;
}

/* A script file for the sandbox: a regular file of at most NS_LIMIT_SCRIPT_FILE_BYTES (a FIFO
 * would block, /dev/zero never end). Returns 0, or -1 with the reason in why. */
static int check_script_file(const char *path, char *why, size_t n)
{
    struct stat st;
    if (stat(path, &st) != 0) {
        snprintf(why, n, "%s", strerror(errno));
        return -1;
    }
    if (S_ISDIR(st.st_mode)) {
        snprintf(why, n, "Is a directory");
        return -1;
    }
    if (!S_ISREG(st.st_mode)) {
        snprintf(why, n, "not a regular file");
        return -1;
    }
    if ((long long)st.st_size > NS_LIMIT_SCRIPT_FILE_BYTES) {
        snprintf(why, n, "%lld bytes, more than a script may have (%lld)", (long long)st.st_size,
                 (long long)NS_LIMIT_SCRIPT_FILE_BYTES);
        return -1;
    }
    return 0;
}

/* Module names: plain words separated by dots ("helpers", "needlesim.materials"); no path
 * separators, no "..", nothing absolute. */
static bool valid_module_name(const char *name)
{
    size_t n = strlen(name);
    if (n == 0 || name[0] == '.' || name[n - 1] == '.' || strstr(name, "..") != NULL)
        return false;
    for (size_t i = 0; i < n; i++) {
        char c = name[i];
        bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                  c == '_' || c == '-' || c == '.';
        if (!ok)
            return false;
    }
    return true;
}

/* Pushes the file path module `name` resolves to. */
static void push_module_path(lua_State *L, NsLua *rt, const char *name)
{
    static const char prefix[] = "needlesim.";
    luaL_Buffer b;
    luaL_buffinit(L, &b);
    const char *rest;
    if (strcmp(name, "needlesim") == 0) {
        luaL_addstring(&b, rt->scripts_dir);
        luaL_addstring(&b, "/needlesim");
        rest = NULL;
    } else if (strncmp(name, prefix, sizeof prefix - 1) == 0) {
        luaL_addstring(&b, rt->scripts_dir);
        luaL_addstring(&b, "/needlesim/");
        rest = name + sizeof prefix - 1;
    } else {
        if (strcmp(rt->scenario_dir, ".") != 0) {
            luaL_addstring(&b, rt->scenario_dir);
            luaL_addchar(&b, '/');
        }
        rest = name;
    }
    for (const char *p = rest; p && *p; p++)
        luaL_addchar(&b, *p == '.' ? '/' : *p);
    luaL_addstring(&b, ".lua");
    luaL_pushresult(&b);
}

/* require(name): see lua_runtime.h. Modules run once; their result is cached privately (a
 * scenario cannot reach or poison the cache). */
static int sandbox_require(lua_State *L)
{
    NsLua *rt = runtime_of(L);
    const char *name = luaL_checkstring(L, 1);
    static const char *const unavailable[] = {"io", "os", "package", "debug", "ffi", "jit", NULL};
    for (int i = 0; unavailable[i]; i++)
        if (strcmp(name, unavailable[i]) == 0)
            return luaL_error(L,
                              "require '%s': module not available in the needlesim sandbox "
                              "(scenarios cannot use io, os, package or debug)",
                              name);
    if (!valid_module_name(name))
        return luaL_error(L,
                          "require '%s': invalid module name (use 'needlesim.<name>' or a plain "
                          "name for a .lua file beside the scenario; no paths)",
                          name);

    lua_rawgeti(L, LUA_REGISTRYINDEX, rt->modules_ref); /* 2: cache */
    lua_getfield(L, 2, name);
    if (lua_touserdata(L, -1) == &loading_marker)
        return luaL_error(L, "require '%s': circular require (the module requires itself)", name);
    if (!lua_isnil(L, -1))
        return 1;
    lua_pop(L, 1);

    push_module_path(L, rt, name); /* 3: path */
    const char *path = lua_tostring(L, 3);
    struct stat st;
    if (stat(path, &st) != 0 || !S_ISREG(st.st_mode))
        return luaL_error(L, "require '%s': module not found (no file '%s')", name, path);
    char why[160];
    if (check_script_file(path, why, sizeof why) != 0)
        return luaL_error(L, "require '%s': cannot read '%s': %s", name, path, why);
    if (luaL_loadfilex(L, path, "t") != LUA_OK) /* 4: chunk */
        return lua_error(L);
    lua_pushlightuserdata(L, (void *)&loading_marker);
    lua_setfield(L, 2, name);
    lua_pushvalue(L, 1);
    lua_pushvalue(L, 3);
    if (lua_pcall(L, 2, 1, 0) != LUA_OK) {
        lua_pushnil(L);
        lua_setfield(L, 2, name);
        return lua_error(L); /* rethrow, message unchanged */
    }
    if (lua_isnil(L, -1)) {
        lua_pop(L, 1);
        lua_pushboolean(L, 1);
    }
    lua_pushvalue(L, -1);
    lua_setfield(L, 2, name);
    return 1;
}

/* setmetatable(t, mt): the base library's, refusing a metatable with a __gc field. Lua runs
 * finalizers with hooks off, so a __gc that loops would escape the instruction budget and the
 * wall clock; an object is only marked for finalization when its metatable has __gc at the
 * time it is set, so checking here is enough. */
static int sandbox_setmetatable(lua_State *L)
{
    if (lua_type(L, 2) == LUA_TTABLE) {
        lua_pushliteral(L, "__gc");
        if (lua_rawget(L, 2) != LUA_TNIL)
            return luaL_error(L, "setmetatable: __gc finalizers are not allowed in scenarios");
        lua_pop(L, 1);
    }
    lua_pushvalue(L, lua_upvalueindex(1));
    lua_insert(L, 1);
    lua_call(L, lua_gettop(L) - 1, LUA_MULTRET);
    return lua_gettop(L);
}

/* The work a pattern match may do, bounded before it runs: the matcher (lstrlib.c) is C code
 * the instruction hook never sees, and backtracking over k repetition items (*, +, -, ?, %b)
 * can take subject^(k+1) steps. The estimate len(pattern) * n^(k + unanchored) is charged to
 * the budget, and refused past NS_LIMIT_PATTERN_WORK. */
static double pattern_work(const char *p, size_t lp, size_t n, bool anchored)
{
    int k = 0;
    for (size_t i = 0; i < lp; i++) {
        char c = p[i];
        if (c == '%') {
            if (i + 1 < lp && p[i + 1] == 'b') {
                k++;
                i += 3; /* %bxy */
            } else {
                i++;
            }
        } else if (c == '[') { /* a set: skip to its closing ']' */
            i++;
            if (i < lp && p[i] == '^')
                i++;
            if (i < lp && p[i] == ']')
                i++;
            while (i < lp && p[i] != ']') {
                if (p[i] == '%')
                    i++;
                i++;
            }
        } else if (c == '*' || c == '+' || c == '-' || c == '?') {
            k++;
        }
    }
    double nn = (double)n + 1.0;
    return (double)(lp + 1) * pow(nn, (double)k + (anchored ? 0.0 : 1.0));
}

/* string.find / match / gmatch / gsub with their pattern bounded (upvalue 1: the original;
 * upvalue 2: 1 for find, whose 4th argument `plain` makes it a plain search). */
static int sandbox_pattern(lua_State *L)
{
    NsLua *rt = runtime_of(L);
    size_t n, lp;
    const char *s = luaL_checklstring(L, 1, &n);
    const char *p = luaL_checklstring(L, 2, &lp);
    (void)s;
    bool plain = lua_tointeger(L, lua_upvalueindex(2)) == 1 && lua_toboolean(L, 4);
    if (n > NS_LIMIT_PATTERN_SUBJECT || lp > NS_LIMIT_PATTERN_LENGTH)
        return luaL_error(L,
                          "pattern matching is limited to subjects of %d bytes and patterns of %d "
                          "bytes in scenarios (got %d and %d)",
                          NS_LIMIT_PATTERN_SUBJECT, NS_LIMIT_PATTERN_LENGTH, (int)n, (int)lp);
    double work =
        plain ? (double)(n + 1) * (double)(lp + 1) : pattern_work(p, lp, n, lp > 0 && p[0] == '^');
    if (work > NS_LIMIT_PATTERN_WORK) {
        char buf[200]; /* (lua_pushfstring knows no %g) */
        snprintf(buf, sizeof buf,
                 "a pattern of %d bytes on a subject of %d bytes could take %.3g matching steps "
                 "(at most %.3g)",
                 (int)lp, (int)n, work, (double)NS_LIMIT_PATTERN_WORK);
        return luaL_error(L, "%s: use fewer repetitions (*, +, -, ?) or a shorter subject", buf);
    }
    rt->remaining -= (long long)work / 16; /* a matching step is a few machine instructions */
    if (rt->remaining <= 0) {
        char buf[200];
        return exhausted(L, NULL, budget_message(rt, buf, sizeof buf));
    }
    lua_pushvalue(L, lua_upvalueindex(1));
    lua_insert(L, 1);
    lua_call(L, lua_gettop(L) - 1, LUA_MULTRET);
    return lua_gettop(L);
}

/* string.rep(s, n [, sep]): its output's bytes charged to the budget before it runs (a
 * quarter of an instruction a byte): one instruction of Lua must not be unbounded C work. */
static int sandbox_rep(lua_State *L)
{
    NsLua *rt = runtime_of(L);
    size_t l, lsep = 0;
    luaL_checklstring(L, 1, &l);
    lua_Integer n = luaL_checkinteger(L, 2);
    luaL_optlstring(L, 3, "", &lsep);
    double bytes = n > 0 ? (double)n * (double)(l + lsep) : 0.0;
    if (bytes > (double)lua_memory_limit)
        return luaL_error(L, "string.rep: %d MiB is more than a scenario may hold (%d MiB)",
                          (int)(bytes / 1048576.0), (int)(lua_memory_limit >> 20));
    rt->remaining -= (long long)(bytes / 4.0);
    if (rt->remaining <= 0) {
        char buf[200];
        return exhausted(L, NULL, budget_message(rt, buf, sizeof buf));
    }
    lua_pushvalue(L, lua_upvalueindex(1));
    lua_insert(L, 1);
    lua_call(L, lua_gettop(L) - 1, 1);
    return 1;
}

static void wrap_pattern(lua_State *L, int strtab, const char *name, int is_find)
{
    lua_getfield(L, strtab, name);
    lua_pushinteger(L, is_find);
    lua_pushcclosure(L, sandbox_pattern, 2);
    lua_setfield(L, strtab, name);
}

/* Lua's last line of defence: an error outside any protected call (a bug of ours: every entry
 * is meant to be protected). One line, the temporary files removed, exit 2. */
static int panic(lua_State *L)
{
    const char *msg = lua_tostring(L, -1);
    char line[600];
    snprintf(line, sizeof line, "needlesim: internal error: unprotected Lua error: %s",
             msg ? msg : "(no message)");
    ns_cleanup_fatal(line);
    return 0;
}

/* Sets up the libraries and the sandbox's globals (runs protected: it allocates). */
static int open_sandbox(lua_State *L)
{
    static const luaL_Reg libs[] = {
        {LUA_GNAME, luaopen_base},
        {LUA_TABLIBNAME, luaopen_table},
        {LUA_STRLIBNAME, luaopen_string},
        {LUA_MATHLIBNAME, luaopen_math},
        {LUA_UTF8LIBNAME, luaopen_utf8},
        {LUA_COLIBNAME, luaopen_coroutine},
        {NULL, NULL},
    };
    for (const luaL_Reg *lib = libs; lib->func; lib++) {
        luaL_requiref(L, lib->name, lib->func, 1);
        lua_pop(L, 1);
    }
    NsLua *rt = runtime_of(L);

    lua_pushglobaltable(L);
    lua_pushnil(L);
    lua_setfield(L, -2, "dofile");
    lua_pushnil(L);
    lua_setfield(L, -2, "loadfile");
    lua_getfield(L, -1, "load");
    lua_pushcclosure(L, sandbox_load, 1);
    lua_setfield(L, -2, "load");
    lua_pushcfunction(L, sandbox_print);
    lua_setfield(L, -2, "print");
    lua_pushcfunction(L, sandbox_require);
    lua_setfield(L, -2, "require");
    lua_pushcfunction(L, sandbox_require); /* for the engine, whatever a script does to _G */
    lua_setfield(L, LUA_REGISTRYINDEX, "ns.require");
    lua_pushcfunction(L, ns_where);
    lua_setfield(L, -2, "__ns_where");

    lua_getfield(L, -1, "setmetatable");
    lua_pushcclosure(L, sandbox_setmetatable, 1);
    lua_setfield(L, -2, "setmetatable");

    lua_getfield(L, -1, "string");
    lua_pushnil(L);
    lua_setfield(L, -2, "dump");
    int strtab = lua_gettop(L);
    wrap_pattern(L, strtab, "find", 1);
    wrap_pattern(L, strtab, "match", 0);
    wrap_pattern(L, strtab, "gmatch", 0);
    wrap_pattern(L, strtab, "gsub", 0);
    lua_getfield(L, strtab, "rep");
    lua_pushcclosure(L, sandbox_rep, 1);
    lua_setfield(L, strtab, "rep");
    lua_pop(L, 1);

    /* Deterministic random numbers unless the scenario reseeds. */
    lua_getfield(L, -1, "math");
    lua_getfield(L, -1, "randomseed");
    lua_pushinteger(L, 0x6e73);
    lua_call(L, 1, 0);
    lua_pop(L, 2);

    lua_newtable(L);
    rt->modules_ref = luaL_ref(L, LUA_REGISTRYINDEX);
    return 0;
}

NsLua *ns_lua_open(const char *scenario_path, char *err, int err_sz)
{
    NsLua *rt = calloc(1, sizeof *rt);
    if (!rt) {
        snprintf(err, (size_t)err_sz, "needlesim: out of memory");
        return NULL;
    }
    rt->scripts_dir = dup_string(ns_data_dir("scripts"));
    const char *slash = strrchr(scenario_path, '/');
    if (!slash) {
        rt->scenario_dir = dup_string(".");
    } else if (slash == scenario_path) {
        rt->scenario_dir = dup_string("/");
    } else {
        size_t n = (size_t)(slash - scenario_path);
        rt->scenario_dir = malloc(n + 1);
        if (rt->scenario_dir) {
            memcpy(rt->scenario_dir, scenario_path, n);
            rt->scenario_dir[n] = '\0';
        }
    }
    rt->L = lua_newstate(limited_alloc, rt);
    if (!rt->scripts_dir || !rt->scenario_dir || !rt->L) {
        ns_lua_close(rt);
        snprintf(err, (size_t)err_sz, "needlesim: out of memory");
        return NULL;
    }
    *(NsLua **)lua_getextraspace(rt->L) = rt;
    lua_atpanic(rt->L, panic);
    rt->hook_mask = LUA_MASKCOUNT;
    ns_lua_begin_phase(rt, "loading the scenario", load_instructions, NS_LIMIT_LOAD_SECONDS, 0.0);
    lua_pushcfunction(rt->L, open_sandbox);
    if (ns_lua_call(rt, 0, 0, err, err_sz) != 0) {
        ns_lua_close(rt);
        return NULL;
    }
    return rt;
}

void ns_lua_close(NsLua *rt)
{
    if (!rt)
        return;
    if (rt->L)
        lua_close(rt->L);
    free(rt->scripts_dir);
    free(rt->scenario_dir);
    free(rt->scenario_source);
    free(rt);
}

lua_State *ns_lua_state(NsLua *rt)
{
    return rt->L;
}

const char *ns_lua_scripts_dir(const NsLua *rt)
{
    return rt->scripts_dir;
}

const char *ns_lua_scenario_dir(const NsLua *rt)
{
    return rt->scenario_dir;
}

void ns_lua_begin_phase(NsLua *rt, const char *phase, long long instructions, double seconds,
                        double per_call_seconds)
{
    rt->phase = phase;
    rt->budget = rt->remaining = instructions;
    rt->per_call = per_call_seconds;
    rt->seconds = per_call_seconds > 0.0 ? per_call_seconds : seconds;
    rt->deadline = seconds > 0.0 ? monotonic_s() + seconds : 0.0;
}

int ns_lua_run_scenario(NsLua *rt, const char *path, char *err, int err_sz)
{
    lua_State *L = rt->L;
    char why[160];
    if (check_script_file(path, why, sizeof why) != 0) {
        snprintf(err, (size_t)err_sz, "needlesim: cannot open '%s': %s", path, why);
        return -1;
    }
    int rc = luaL_loadfilex(L, path, "t");
    if (rc != LUA_OK) {
        const char *msg = lua_tostring(L, -1);
        if (rc == LUA_ERRFILE)
            snprintf(err, (size_t)err_sz, "needlesim: %s", msg ? msg : "cannot read scenario");
        else
            copy_first_line(err, err_sz, msg ? msg : "cannot load scenario");
        lua_pop(L, 1);
        return -1;
    }
    free(rt->scenario_source);
    size_t n = strlen(path);
    rt->scenario_source = malloc(n + 2);
    if (!rt->scenario_source) {
        lua_pop(L, 1);
        snprintf(err, (size_t)err_sz, "needlesim: out of memory");
        return -1;
    }
    rt->scenario_source[0] = '@';
    memcpy(rt->scenario_source + 1, path, n + 1);
    rt->last_line = 0;
    rt->source_seen = NULL;
    /* Line events only while the chunk itself runs: they cost, and only constructors called
     * by the chunk need them (ns_where). */
    rt->hook_mask = LUA_MASKCOUNT | LUA_MASKLINE;
    rc = ns_lua_call(rt, 0, 1, err, err_sz);
    rt->hook_mask = LUA_MASKCOUNT;
    set_hook(L, rt->hook_mask, NS_HOOK_STEP);
    return rc;
}
