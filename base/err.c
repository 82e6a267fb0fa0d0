/* err.c: see err.h. */
#include "err.h"

#include <stdio.h>

int cvre_vfail(char *err, size_t errlen, int rc, const char *fmt, va_list ap)
{
    if (errlen)
        vsnprintf(err, errlen, fmt, ap);
    return rc;
}

int cvre_fail(char *err, size_t errlen, int rc, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    cvre_vfail(err, errlen, rc, fmt, ap);
    va_end(ap);
    return rc;
}
