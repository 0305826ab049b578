/* Opening untrusted files for reading (file_in.h). */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE 1
#endif

#include "file_in.h"

#include <errno.h>
#include <fcntl.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "err.h"

/* "a FIFO", "a directory", ... for a file that is not regular. */
static const char *kind_of(mode_t mode)
{
    if (S_ISDIR(mode))
        return "a directory";
    if (S_ISFIFO(mode))
        return "a FIFO (named pipe)";
    if (S_ISCHR(mode))
        return "a character device";
    if (S_ISBLK(mode))
        return "a block device";
    if (S_ISSOCK(mode))
        return "a socket";
    return "not a regular file";
}

static int check_stat(const char *path, const struct stat *st, long long max_bytes,
                      const char *what, char *err, int err_sz)
{
    if (!S_ISREG(st->st_mode)) {
        ns_set_err(err, err_sz, "%s: is %s, not a %s (regular files only)", path,
                   kind_of(st->st_mode), what);
        return -1;
    }
    if ((long long)st->st_size > max_bytes) {
        ns_set_err(err, err_sz, "%s: the %s is %lld bytes, more than the limit of %lld bytes", path,
                   what, (long long)st->st_size, max_bytes);
        return -1;
    }
    return 0;
}

int ns_file_open_regular(const char *path, long long max_bytes, const char *what, long long *size,
                         char *err, int err_sz)
{
    struct stat st;
    if (stat(path, &st) != 0) {
        ns_set_err(err, err_sz, "%s: cannot open: %s", path, strerror(errno));
        return -1;
    }
    if (check_stat(path, &st, max_bytes, what, err, err_sz))
        return -1;
    int fd = open(path, O_RDONLY | O_NONBLOCK | O_CLOEXEC | O_NOCTTY);
    if (fd < 0) {
        ns_set_err(err, err_sz, "%s: cannot open: %s", path, strerror(errno));
        return -1;
    }
    if (fstat(fd, &st) != 0) {
        ns_set_err(err, err_sz, "%s: cannot open: %s", path, strerror(errno));
        close(fd);
        return -1;
    }
    if (check_stat(path, &st, max_bytes, what, err, err_sz)) {
        close(fd);
        return -1;
    }
    int flags = fcntl(fd, F_GETFL);
    if (flags < 0 || fcntl(fd, F_SETFL, flags & ~O_NONBLOCK) < 0) {
        ns_set_err(err, err_sz, "%s: cannot open: %s", path, strerror(errno));
        close(fd);
        return -1;
    }
    if (size)
        *size = (long long)st.st_size;
    return fd;
}
