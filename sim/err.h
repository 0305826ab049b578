/* Errors from sim/: functions that can fail on input fill a caller's buffer (STYLE.md §6). */
#ifndef NS_ERR_H
#define NS_ERR_H

/* printf into err (err_sz bytes, always terminated); does nothing if err is NULL or err_sz <= 0. */
void ns_set_err(char *err, int err_sz, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 3, 4)))
#endif
    ;

#endif
