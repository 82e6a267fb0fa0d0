/*
 * timefmt.h: the one way a program reads a time a person typed and prints
 * one back, so that what cvre-admin prints every other program accepts
 * (cvre-admin's --since/--until, cvre-cluster's --since/--until).
 *
 * Accepted (timefmt_parse):
 *   - Unix seconds: 1795000000, 1795000000.25 (any finite strtod number);
 *   - ISO 8601 / RFC 3339: a date YYYY-MM-DD, optionally followed by 'T',
 *     't' or a space and HH:MM, HH:MM:SS or HH:MM:SS.fraction (any number of
 *     digits), then optionally a zone: Z (or z), +HH, +HH:MM, +HHMM (or -).
 *     Without a zone the time is UTC. Month, day, hour, minute and second
 *     may have one digit (2026-1-5T3:04:05, as cvre-cluster took them).
 * A date that does not exist (2026-02-30, 2026-13-01, 24:00) is refused.
 */
#ifndef CVRE_TIMEFMT_H
#define CVRE_TIMEFMT_H

#include <stddef.h>

/* Room for timefmt_iso's text and its NUL: a %.17g number (at most 24
 * characters), or "-YYYY-MM-DDTHH:MM:SS." with 6 decimals and "Z" (28). */
#define TIMEFMT_ISO_MAX 48

/* Reads text (see above) into *t as Unix seconds. Returns 0, or -EINVAL
 * (and leaves *t alone) when text is none of the accepted forms. */
int timefmt_parse(const char *text, double *t);

/* Writes Unix seconds t into buf (TIMEFMT_ISO_MAX bytes) as ISO 8601 UTC
 * with `digits` decimals (0 to 6) and a Z, e.g. 2026-12-01T17:40:00.000Z,
 * rounded to the last decimal: timefmt_parse reads it back (years 0 to
 * 9999). A value no calendar shows (not finite, beyond 1e11 s from 1970)
 * is written as a %.17g number, which timefmt_parse reads back too (but
 * for NaN and infinities). */
void timefmt_iso(char buf[TIMEFMT_ISO_MAX], double t, int digits);

#endif
