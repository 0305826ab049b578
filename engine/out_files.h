/* Output files, written safely (issue: untrusted paths). A command's outputs are written to a
 * temporary `.part` name beside their final name and renamed into place only when everything
 * succeeded. Here:
 *   - a final name may be replaced only when it is absent or a regular file (never a device,
 *     a FIFO, a folder or a symbolic link: `--record /dev/full` must not replace the device);
 *   - a `.part` file is created fresh (O_EXCL, no symbolic link followed) after removing an
 *     old regular one, and registered with cleanup.h so that every way out removes it;
 *   - nothing else is removed.
 * Messages: one line naming the path. */
#ifndef NS_OUT_FILES_H
#define NS_OUT_FILES_H

#include <stdio.h>

/* 0 when `path` is absent or a regular file; else -1 with "WHAT 'PATH' exists and is not a
 * regular file ..." in err. */
int ns_out_replaceable(const char *path, const char *what, char *err, int err_sz);
/* Removes `path` if it is a regular file (an earlier run's output this run replaces). */
void ns_out_remove_old(const char *path);
/* Creates the temporary file `path` for writing (see above). Returns the stream, or NULL with
 * a message naming what/path. */
FILE *ns_out_create_part(const char *path, const char *what, char *err, int err_sz);
/* Removes a temporary file made by ns_out_create_part (a regular file only) and forgets it. */
void ns_out_remove_part(const char *path);
/* Renames a temporary file into place (final name checked again) and forgets it. Returns 0, or
 * -1 with errno set. */
int ns_out_commit(const char *part, const char *final);

#endif
