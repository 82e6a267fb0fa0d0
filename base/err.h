/*
 * err.h: the one way a function says why it failed (CONTRIBUTING.md,
 * "Results"). It returns 0 (or a count) on success and a negative errno on
 * failure; where a person will read why, the caller passes a buffer and
 * the function writes one line into it:
 *
 *     if (n > LIMIT)
 *         return cvre_fail(err, errlen, -E2BIG, "%zu boxes, at most %u", n, LIMIT);
 */
#ifndef CVRE_ERR_H
#define CVRE_ERR_H

#include <stdarg.h>
#include <stddef.h>

/* Formats the message into err[0..errlen) (nothing when errlen is 0) and
 * returns rc, a negative errno. */
int cvre_fail(char *err, size_t errlen, int rc, const char *fmt, ...) __attribute__((format(printf, 4, 5)));
int cvre_vfail(char *err, size_t errlen, int rc, const char *fmt, va_list ap) __attribute__((format(printf, 4, 0)));

#endif
