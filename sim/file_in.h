/* Opening files that come from other people (meshes, trainee logs, scenarios) for reading:
 * regular files only, and no larger than a named limit (ns_limits.h), both checked before a
 * byte is read. A FIFO, a device (/dev/zero, /dev/stdin) or a directory is refused at once:
 * it could block the open or the reads forever, or never end. */
#ifndef NS_FILE_IN_H
#define NS_FILE_IN_H

/* Opens path read-only after stat() says it is a regular file of at most max_bytes bytes;
 * the open is O_NONBLOCK (a FIFO swapped in after the stat cannot block it) and fstat() on the
 * descriptor checks the file again (the stat and the open are two calls: the file may have
 * been replaced between them). Returns the descriptor (blocking again: reads of a regular
 * file never wait) and its size in *size (may be NULL), or -1 with "path: message" in err;
 * `what` names the file's kind in messages ("mesh file"). */
int ns_file_open_regular(const char *path, long long max_bytes, const char *what, long long *size,
                         char *err, int err_sz);

#endif
