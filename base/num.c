/* num.c: see num.h. */
#include "num.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>

int num_parse_real(const char *text, double lo, double hi, double *out)
{
    char *end;
    errno = 0;
    double v = strtod(text, &end);
    if (errno || end == text || *end || !isfinite(v) || v < lo || v > hi)
        return -EINVAL;
    *out = v;
    return 0;
}

int num_parse_int(const char *text, long long lo, long long hi, long long *out)
{
    const char *digits = text[0] == '-' && lo < 0 ? text + 1 : text;
    if (*digits < '0' || *digits > '9')
        return -EINVAL;
    char *end;
    errno = 0;
    long long v = strtoll(text, &end, 10);
    if (errno || *end || v < lo || v > hi)
        return -EINVAL;
    *out = v;
    return 0;
}
