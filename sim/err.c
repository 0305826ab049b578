/* The one error formatter of sim/. */
#include "err.h"

#include <stdarg.h>
#include <stdio.h>

void ns_set_err(char *err, int err_sz, const char *fmt, ...)
{
    if (!err || err_sz <= 0)
        return;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(err, (size_t)err_sz, fmt, ap);
    va_end(ap);
}
