/* Where needlesim finds its data (data_dir.h): the environment, beside the binary, the source
 * tree of a build run in place, the configured prefix. */
#include "data_dir.h"

#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "ns_config.h"

enum { NS_DATA_SLOTS = 4, NS_DATA_WHAT_MAX = 32 };

typedef struct {
    char what[NS_DATA_WHAT_MAX];
    char path[PATH_MAX];
    char via[128];
} DataDir;

static DataDir slots[NS_DATA_SLOTS];
static int n_slots;
static DataDir overflow; /* a fifth name: resolved each call (only `--version` asks for three) */

static int is_dir(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0 && S_ISDIR(st.st_mode);
}

/* PATH made canonical into OUT when it names a folder; 0 on success. */
static int existing_dir(const char *path, char *out)
{
    char real[PATH_MAX];
    if (!realpath(path, real) || !is_dir(real))
        return -1;
    snprintf(out, PATH_MAX, "%s", real);
    return 0;
}

/* The running binary's folder, canonical; 0 on success. */
static int exe_dir(char *out)
{
    char exe[PATH_MAX];
    ssize_t n = readlink("/proc/self/exe", exe, sizeof exe - 1);
    if (n <= 0)
        return -1;
    exe[n] = '\0';
    char *slash = strrchr(exe, '/');
    if (!slash)
        return -1;
    *slash = '\0';
    return existing_dir(exe[0] ? exe : "/", out);
}

/* Is folder DIR (canonical) the folder ROOT or inside it? */
static int inside(const char *dir, const char *root)
{
    char real_root[PATH_MAX];
    if (!realpath(root, real_root))
        return 0;
    size_t n = strlen(real_root);
    return strncmp(dir, real_root, n) == 0 && (dir[n] == '\0' || dir[n] == '/');
}

static void resolve(DataDir *d, const char *what)
{
    snprintf(d->what, sizeof d->what, "%s", what);

    /* 1. NEEDLESIM_<WHAT>, as given. */
    char name[64] = "NEEDLESIM_";
    size_t k = strlen(name);
    for (const char *c = what; *c && k + 1 < sizeof name; c++)
        name[k++] = (*c >= 'a' && *c <= 'z') ? (char)(*c - 'a' + 'A') : *c;
    name[k] = '\0';
    const char *env = getenv(name);
    if (env && env[0]) {
        snprintf(d->path, sizeof d->path, "%s", env);
        snprintf(d->via, sizeof d->via, "found via %s", name);
        return;
    }

    char bin[PATH_MAX], cand[2 * PATH_MAX];
    int have_bin = exe_dir(bin) == 0;
    /* 2. Beside the binary: an installed needlesim, wherever its prefix now is. */
    if (have_bin) {
        snprintf(cand, sizeof cand, "%s/%s/%s", bin, NS_DATA_FROM_BIN, what);
        if (existing_dir(cand, d->path) == 0) {
            snprintf(d->via, sizeof d->via, "found via the binary's location, /proc/self/exe");
            return;
        }
    }
    /* 3. The source tree of a build run in place. */
    if (have_bin && inside(bin, NS_BUILD_DIR)) {
        snprintf(cand, sizeof cand, "%s/%s", NS_SOURCE_DIR, what);
        if (existing_dir(cand, d->path) == 0) {
            snprintf(d->via, sizeof d->via, "found via the build folder's source tree");
            return;
        }
    }
    /* 4. The configured prefix. */
    snprintf(d->path, sizeof d->path, "%s/%s", NS_DATA_DIR, what);
    snprintf(d->via, sizeof d->via, "%s",
             is_dir(d->path) ? "found via the configured prefix"
                             : "the configured prefix; not found there either");
}

static const DataDir *lookup(const char *what)
{
    for (int i = 0; i < n_slots; i++)
        if (strcmp(slots[i].what, what) == 0)
            return &slots[i];
    DataDir *d =
        n_slots < NS_DATA_SLOTS && strlen(what) < NS_DATA_WHAT_MAX ? &slots[n_slots++] : &overflow;
    resolve(d, what);
    return d;
}

const char *ns_data_dir(const char *what)
{
    return lookup(what)->path;
}

const char *ns_data_dir_via(const char *what)
{
    return lookup(what)->via;
}
