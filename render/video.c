/* The ffmpeg child: fork/execv with a pipe on its stdin, /dev/null on its stdout and an unlinked
 * temporary file on its stderr. */
#include "video.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

struct NsVideo {
    pid_t pid;  /* 0 once reaped */
    int status; /* wait status once reaped */
    int fd;     /* write end of the pipe, -1 once closed */
    int log_fd; /* ffmpeg's stderr */
    int w, h;
};

/* Finds an executable regular file `name` on PATH; writes its path to out. Returns 1 if found. */
static int find_on_path(const char *name, char *out, size_t out_sz)
{
    const char *path = getenv("PATH");
    char def[256];
    if (!path) {
        size_t n = confstr(_CS_PATH, def, sizeof def);
        path = n > 0 && n <= sizeof def ? def : "/usr/bin:/bin";
    }
    for (const char *p = path;; p++) {
        const char *end = strchr(p, ':');
        size_t len = end ? (size_t)(end - p) : strlen(p);
        int n = len == 0 ? snprintf(out, out_sz, "%s", name) /* empty entry: the current dir */
                         : snprintf(out, out_sz, "%.*s/%s", (int)len, p, name);
        struct stat st;
        if (n > 0 && (size_t)n < out_sz && stat(out, &st) == 0 && S_ISREG(st.st_mode) &&
            access(out, X_OK) == 0)
            return 1;
        if (!end)
            return 0;
        p = end;
    }
}

int ns_video_have_ffmpeg(void)
{
    char buf[PATH_MAX];
    return find_on_path("ffmpeg", buf, sizeof buf);
}

/* The last non-empty line of ffmpeg's stderr, into buf. */
static const char *last_log_line(const NsVideo *v, char *buf, size_t n)
{
    char tail[1024];
    snprintf(buf, n, "(no message from ffmpeg)");
    off_t size = lseek(v->log_fd, 0, SEEK_END);
    if (size <= 0)
        return buf;
    off_t start = size > (off_t)sizeof tail - 1 ? size - (off_t)sizeof tail + 1 : 0;
    ssize_t got = pread(v->log_fd, tail, (size_t)(size - start), start);
    if (got <= 0)
        return buf;
    tail[got] = '\0';
    for (ssize_t i = 0; i < got; i++) /* NULs and carriage returns end lines too */
        if (tail[i] == '\0' || tail[i] == '\r')
            tail[i] = '\n';
    while (got > 0 && (tail[got - 1] == '\n' || tail[got - 1] == ' ' || tail[got - 1] == '\t'))
        tail[--got] = '\0';
    if (got == 0)
        return buf;
    const char *line = strrchr(tail, '\n');
    line = line ? line + 1 : tail;
    size_t len = strlen(line) < n ? strlen(line) : n - 1; /* truncation is fine here */
    memcpy(buf, line, len);
    buf[len] = '\0';
    return buf;
}

static void reap(NsVideo *v)
{
    if (v->pid <= 0)
        return;
    while (waitpid(v->pid, &v->status, 0) < 0 && errno == EINTR)
        ;
    v->pid = 0;
}

static void video_free(NsVideo *v)
{
    if (v->fd >= 0)
        close(v->fd);
    if (v->log_fd >= 0)
        close(v->log_fd);
    free(v);
}

/* Starts exe with argv: its stdin a pipe (v->fd, the write end), stdout /dev/null, stderr an
 * unlinked temporary file (v->log_fd). Returns 0, or -1 with a message. */
static int spawn(NsVideo *v, const char *exe, char *const argv[], char *err, int err_sz)
{
    const char *tmpdir = getenv("TMPDIR");
    char log_path[PATH_MAX];
    snprintf(log_path, sizeof log_path, "%s/needlesim-ffmpeg-XXXXXX",
             tmpdir && *tmpdir ? tmpdir : "/tmp");
    v->log_fd = mkostemp(log_path, O_CLOEXEC);
    if (v->log_fd < 0) {
        snprintf(err, err_sz, "cannot create a temporary file for ffmpeg's messages in %s: %s",
                 tmpdir && *tmpdir ? tmpdir : "/tmp", strerror(errno));
        return -1;
    }
    unlink(log_path);
    int pfd[2];
    if (pipe2(pfd, O_CLOEXEC) != 0) {
        snprintf(err, err_sz, "cannot create a pipe to ffmpeg: %s", strerror(errno));
        return -1;
    }
    pid_t pid = fork();
    if (pid < 0) {
        snprintf(err, err_sz, "cannot start ffmpeg: fork: %s", strerror(errno));
        close(pfd[0]);
        close(pfd[1]);
        return -1;
    }
    if (pid == 0) { /* child: async-signal-safe calls only */
        int null_fd = open("/dev/null", O_WRONLY);
        if (dup2(pfd[0], 0) < 0 || null_fd < 0 || dup2(null_fd, 1) < 0 || dup2(v->log_fd, 2) < 0)
            _exit(127);
        execv(exe, argv);
        static const char msg[] = "needlesim: cannot execute ffmpeg\n";
        ssize_t ignored = write(2, msg, sizeof msg - 1);
        (void)ignored;
        _exit(127);
    }
    close(pfd[0]);
    v->fd = pfd[1];
    v->pid = pid;
    return 0;
}

NsVideo *ns_video_open(const char *path, int w, int h, double fps, char *err, int err_sz)
{
    if (w < 2 || h < 2 || w > 16384 || h > 16384 || w % 2 || h % 2) {
        snprintf(err, err_sz, "video size %d x %d must be even and in 2..16384", w, h);
        return NULL;
    }
    if (!(fps > 0.0 && fps <= 1000.0)) {
        snprintf(err, err_sz, "video frame rate %g out of range (0, 1000]", fps);
        return NULL;
    }
    char exe[PATH_MAX];
    if (!find_on_path("ffmpeg", exe, sizeof exe)) {
        snprintf(err, err_sz,
                 "--video needs the ffmpeg program (apt install ffmpeg): "
                 "not found on PATH");
        return NULL;
    }
    NsVideo *v = calloc(1, sizeof *v);
    if (!v) {
        snprintf(err, err_sz, "out of memory for a video");
        return NULL;
    }
    v->fd = v->log_fd = -1;
    v->w = w;
    v->h = h;
    char size[32], rate[32];
    snprintf(size, sizeof size, "%dx%d", w, h);
    snprintf(rate, sizeof rate, "%.9g", fps);
    char *argv[] = {"ffmpeg",     "-y",    "-loglevel", "error",      "-f",      "rawvideo",
                    "-pix_fmt",   "rgb24", "-s",        size,         "-r",      rate,
                    "-i",         "-",     "-an",       "-c:v",       "libx264", "-preset",
                    "veryfast",   "-crf",  "23",        "-pix_fmt",   "yuv420p", "-movflags",
                    "+faststart", "-f",    "mp4",       (char *)path, NULL};
    if (spawn(v, exe, argv, err, err_sz)) {
        video_free(v);
        return NULL;
    }
    return v;
}

/* Writes n bytes to fd with SIGPIPE blocked for this thread; a SIGPIPE raised by the write is
 * consumed before unblocking. Returns 0 or an errno value. */
static int write_all_nosigpipe(int fd, const uint8_t *p, size_t n)
{
    sigset_t pipe_set, old, pending;
    sigemptyset(&pipe_set);
    sigaddset(&pipe_set, SIGPIPE);
    sigpending(&pending);
    int was_pending = sigismember(&pending, SIGPIPE);
    pthread_sigmask(SIG_BLOCK, &pipe_set, &old);
    int e = 0;
    while (n > 0) {
        ssize_t k = write(fd, p, n);
        if (k < 0) {
            if (errno == EINTR)
                continue;
            e = errno;
            break;
        }
        p += k;
        n -= (size_t)k;
    }
    if (e == EPIPE && !was_pending) {
        const struct timespec zero = {0, 0};
        while (sigtimedwait(&pipe_set, NULL, &zero) < 0 && errno == EINTR)
            ;
    }
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    return e;
}

int ns_video_frame(NsVideo *v, const NsImage *im, char *err, int err_sz)
{
    if (im->w != v->w || im->h != v->h || !im->rgb) {
        snprintf(err, err_sz, "video frame is %d x %d, expected %d x %d", im->w, im->h, v->w, v->h);
        return -1;
    }
    if (v->fd < 0) {
        snprintf(err, err_sz, "video frame after ffmpeg stopped");
        return -1;
    }
    int e = write_all_nosigpipe(v->fd, im->rgb, (size_t)v->w * (size_t)v->h * 3);
    if (e == 0)
        return 0;
    close(v->fd);
    v->fd = -1;
    char line[512];
    if (e == EPIPE) { /* ffmpeg quit: wait for it so that its message is complete */
        reap(v);
        snprintf(err, err_sz, "ffmpeg stopped reading frames: %s",
                 last_log_line(v, line, sizeof line));
    } else {
        snprintf(err, err_sz, "cannot write a frame to ffmpeg: %s", strerror(e));
    }
    return -1;
}

int ns_video_close(NsVideo *v, char *err, int err_sz)
{
    if (v->fd >= 0) {
        close(v->fd);
        v->fd = -1;
    }
    reap(v);
    int rc = 0;
    char line[512];
    if (WIFEXITED(v->status) && WEXITSTATUS(v->status) != 0) {
        snprintf(err, err_sz, "ffmpeg failed (exit status %d): %s", WEXITSTATUS(v->status),
                 last_log_line(v, line, sizeof line));
        rc = -1;
    } else if (WIFSIGNALED(v->status)) {
        snprintf(err, err_sz, "ffmpeg killed by signal %d: %s", WTERMSIG(v->status),
                 last_log_line(v, line, sizeof line));
        rc = -1;
    }
    video_free(v);
    return rc;
}

void ns_video_abort(NsVideo *v)
{
    if (!v)
        return;
    if (v->pid > 0)
        kill(v->pid, SIGKILL);
    reap(v);
    video_free(v);
}

/* Appends s to the ffmetadata text at *at, escaping what the format gives a meaning to ('=',
 * ';', '#', '\' and newlines, each after a backslash); other control bytes become spaces. */
static void meta_put(char *buf, size_t cap, size_t *at, const char *s)
{
    for (; *s && *at + 3 < cap; s++) {
        char c = *s;
        if (c == '=' || c == ';' || c == '#' || c == '\\' || c == '\n')
            buf[(*at)++] = '\\';
        buf[(*at)++] = (unsigned char)c < 0x20 && c != '\n' ? ' ' : c;
    }
    buf[*at] = '\0';
}

int ns_video_chapters(const char *in, const char *out, const char *const *titles,
                      const double *start_s, int n, double end_s, char *err, int err_sz)
{
    char exe[PATH_MAX];
    if (!find_on_path("ffmpeg", exe, sizeof exe)) {
        snprintf(err, err_sz, "chapters need the ffmpeg program (apt install ffmpeg)");
        return -1;
    }
    size_t cap = 256 + (size_t)n * 1200, at = 0;
    char *meta = malloc(cap);
    NsVideo *v = meta ? calloc(1, sizeof *v) : NULL;
    if (!v) {
        free(meta);
        snprintf(err, err_sz, "out of memory for the video's chapters");
        return -1;
    }
    v->fd = v->log_fd = -1;
    at = (size_t)snprintf(meta, cap, ";FFMETADATA1\n");
    for (int i = 0; i < n; i++) {
        long a = lround(1e3 * start_s[i]), b = lround(1e3 * (i + 1 < n ? start_s[i + 1] : end_s));
        at += (size_t)snprintf(meta + at, cap - at,
                               "[CHAPTER]\nTIMEBASE=1/1000\nSTART=%ld\nEND=%ld\ntitle=", a,
                               b > a ? b : a + 1);
        meta_put(meta, cap, &at, titles[i]);
        at += (size_t)snprintf(meta + at, cap - at, "\n");
    }
    char *argv[] = {"ffmpeg",   "-y",  "-loglevel",     "error",     "-i",
                    (char *)in, "-f",  "ffmetadata",    "-i",        "-",
                    "-map",     "0",   "-map_metadata", "1",         "-map_chapters",
                    "1",        "-c",  "copy",          "-movflags", "+faststart",
                    "-f",       "mp4", (char *)out,     NULL};
    int rc = spawn(v, exe, argv, err, err_sz);
    int e = rc == 0 ? write_all_nosigpipe(v->fd, (const uint8_t *)meta, at) : 0;
    free(meta);
    if (v->fd >= 0) {
        close(v->fd);
        v->fd = -1;
    }
    reap(v);
    char line[512];
    if (rc == 0 && (e || !WIFEXITED(v->status) || WEXITSTATUS(v->status) != 0)) {
        snprintf(err, err_sz, "ffmpeg could not add the chapters: %s",
                 e ? strerror(e) : last_log_line(v, line, sizeof line));
        rc = -1;
    }
    video_free(v);
    return rc;
}
