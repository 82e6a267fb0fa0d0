/*
 * sbuf.h: a growing string, for text built in pieces (JSON lines, SVG,
 * reports). It is always NUL-terminated; running out of memory aborts
 * (cvre_xrealloc), as for the other loop-side allocations.
 */
#ifndef CVRE_SBUF_H
#define CVRE_SBUF_H

#include <stddef.h>

typedef struct sbuf {
    char *p; /* NULL until the first byte */
    size_t len, cap;
} sbuf;

void sb_put(sbuf *b, const char *s, size_t n);
void sb_puts(sbuf *b, const char *s);
void sb_printf(sbuf *b, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* The shortest %g form that reads back as the same double; "null" for a
 * value that is not finite (JSON has no NaN). */
void sb_real(sbuf *b, double v);
/* The same for a value that was a float (32 bits) before it was stored as
 * a double: the shortest %g form that reads back as the same float, 0.9
 * where sb_real would print 0.89999997615814209. A v that is not exactly a
 * float (it was computed in double) goes to sb_real: nothing is lost. */
void sb_real32(sbuf *b, double v);
/* Empties b, keeping its memory. */
void sb_clear(sbuf *b);
void sb_free(sbuf *b);

#endif
