/* Output files written safely (out_files.h). */
#include "out_files.h"

#include <errno.h>
#include <fcntl.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "cleanup.h"
#include "err.h"

int ns_out_replaceable(const char *path, const char *what, char *err, int err_sz)
{
    struct stat st;
    if (lstat(path, &st) != 0)
        return 0; /* absent: created fresh */
    if (S_ISREG(st.st_mode))
        return 0;
    ns_set_err(err, err_sz, "%s '%s' exists and is not a regular file (%s): refusing to replace it",
               what, path,
               S_ISDIR(st.st_mode)                          ? "a folder"
               : S_ISLNK(st.st_mode)                        ? "a symbolic link"
               : S_ISCHR(st.st_mode) || S_ISBLK(st.st_mode) ? "a device"
               : S_ISFIFO(st.st_mode)                       ? "a FIFO"
                                                            : "not a file");
    return -1;
}

void ns_out_remove_old(const char *path)
{
    struct stat st;
    if (lstat(path, &st) == 0 && S_ISREG(st.st_mode))
        unlink(path);
}

FILE *ns_out_create_part(const char *path, const char *what, char *err, int err_sz)
{
    if (ns_out_replaceable(path, what, err, err_sz) != 0)
        return NULL;
    ns_out_remove_old(path);
    int fd = open(path, O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0644);
    if (fd < 0) {
        ns_set_err(err, err_sz, "cannot write %s '%s': %s", what, path, strerror(errno));
        return NULL;
    }
    FILE *f = fdopen(fd, "w");
    if (!f || ns_cleanup_add(path) != 0) {
        ns_set_err(err, err_sz, "cannot write %s '%s': out of memory", what, path);
        if (f)
            fclose(f);
        else
            close(fd);
        unlink(path);
        return NULL;
    }
    return f;
}

void ns_out_remove_part(const char *path)
{
    ns_out_remove_old(path);
    ns_cleanup_forget(path);
}

int ns_out_commit(const char *part, const char *final)
{
    struct stat st;
    if (lstat(final, &st) == 0 && !S_ISREG(st.st_mode)) {
        errno = EEXIST;
        return -1;
    }
    if (rename(part, final) != 0)
        return -1;
    ns_cleanup_forget(part);
    return 0;
}
