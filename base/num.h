/*
 * num.h: numbers typed by people (flags, script words, times), read the
 * one strict way: the whole text, nothing after it, finite, in range.
 * strtod alone would take "nan", "inf", "5abc" and " 5".
 */
#ifndef CVRE_NUM_H
#define CVRE_NUM_H

/* text as a finite number in [lo, hi]. Returns 0, or -EINVAL when it is
 * empty, has anything after the number, is not finite, overflows or is
 * out of range. */
int num_parse_real(const char *text, double lo, double hi, double *out);

/* text as a decimal integer in [lo, hi]: digits, with a leading '-' only
 * when lo < 0 (no blanks, no '+'). Returns 0 or -EINVAL. */
int num_parse_int(const char *text, long long lo, long long hi, long long *out);

#endif
