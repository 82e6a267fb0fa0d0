/* sbuf.c: see sbuf.h. */
#include "sbuf.h"

#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"

static void grow(sbuf *b, size_t more)
{
    if (b->len + more + 1 <= b->cap)
        return;
    size_t cap = b->cap ? b->cap : 256;
    while (cap < b->len + more + 1)
        cap *= 2;
    b->p = cvre_xrealloc(b->p, cap);
    b->cap = cap;
}

void sb_put(sbuf *b, const char *s, size_t n)
{
    grow(b, n);
    memcpy(b->p + b->len, s, n);
    b->len += n;
    b->p[b->len] = 0;
}

void sb_puts(sbuf *b, const char *s) { sb_put(b, s, strlen(s)); }

void sb_printf(sbuf *b, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(NULL, 0, fmt, ap);
    va_end(ap);
    if (n <= 0)
        return;
    grow(b, (size_t)n);
    va_start(ap, fmt);
    vsnprintf(b->p + b->len, (size_t)n + 1, fmt, ap);
    va_end(ap);
    b->len += (size_t)n;
}

void sb_real(sbuf *b, double v)
{
    char t[64];
    if (!isfinite(v)) {
        sb_puts(b, "null");
        return;
    }
    for (int prec = 15; prec <= 17; prec++) {
        snprintf(t, sizeof t, "%.*g", prec, v);
        if (strtod(t, NULL) == v)
            break;
    }
    sb_puts(b, t);
}

void sb_real32(sbuf *b, double v)
{
    char t[64];
    if (!(fabs(v) <= FLT_MAX) || (double)(float)v != v) { /* not finite, beyond a float, or finer */
        sb_real(b, v);
        return;
    }
    float f = (float)v;
    for (int prec = 6; prec <= 9; prec++) { /* FLT_DECIMAL_DIG is 9 */
        snprintf(t, sizeof t, "%.*g", prec, v);
        if (strtof(t, NULL) == f)
            break;
    }
    sb_puts(b, t);
}

void sb_clear(sbuf *b)
{
    b->len = 0;
    if (b->p)
        b->p[0] = 0;
}

void sb_free(sbuf *b)
{
    free(b->p);
    *b = (sbuf){0};
}
