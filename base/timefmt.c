/* timefmt.c: see timefmt.h. */
#include "timefmt.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "num.h"

/* Reads from `least` to `most` decimal digits at *p into *value, advancing
 * *p; -1 if there are fewer. */
static int digits_at(const char **p, int least, int most, int *value)
{
    int v = 0, n = 0;
    while (n < most && **p >= '0' && **p <= '9') {
        v = v * 10 + (**p - '0');
        (*p)++, n++;
    }
    *value = v;
    return n >= least ? 0 : -1;
}

int timefmt_parse(const char *text, double *t)
{
    if (num_parse_real(text, -INFINITY, INFINITY, t) == 0)
        return 0;
    int y, mo, d, h = 0, mi = 0, s = 0, zh = 0, zm = 0, sign = 0;
    double frac = 0;
    const char *p = text;
    if (digits_at(&p, 4, 4, &y) || *p++ != '-' || digits_at(&p, 1, 2, &mo) || *p++ != '-' ||
        digits_at(&p, 1, 2, &d))
        return -EINVAL;
    if (*p == 'T' || *p == 't' || *p == ' ') {
        p++;
        if (digits_at(&p, 1, 2, &h) || *p++ != ':' || digits_at(&p, 1, 2, &mi))
            return -EINVAL;
        if (*p == ':') {
            p++;
            if (digits_at(&p, 1, 2, &s))
                return -EINVAL;
            if (*p == '.') {
                /* "0.ddd" read by strtod: the fraction to the last digit. */
                char buf[32] = "0.";
                size_t n = 2;
                p++;
                if (*p < '0' || *p > '9')
                    return -EINVAL;
                for (; *p >= '0' && *p <= '9'; p++)
                    if (n < sizeof buf - 1)
                        buf[n++] = *p;
                buf[n] = 0;
                frac = strtod(buf, NULL);
            }
        }
        if (*p == 'Z' || *p == 'z') {
            p++;
        } else if (*p == '+' || *p == '-') {
            sign = *p++ == '+' ? 1 : -1;
            if (digits_at(&p, 2, 2, &zh))
                return -EINVAL;
            if (*p == ':' ? (p++, digits_at(&p, 2, 2, &zm)) : *p && digits_at(&p, 2, 2, &zm))
                return -EINVAL;
            if (zh > 23 || zm > 59)
                return -EINVAL;
        }
    }
    if (*p || mo < 1 || mo > 12 || d < 1 || d > 31 || h > 23 || mi > 59 || s > 60)
        return -EINVAL;
    struct tm tm = {.tm_year = y - 1900, .tm_mon = mo - 1, .tm_mday = d, .tm_hour = h, .tm_min = mi, .tm_sec = s};
    time_t secs = timegm(&tm);
    if (tm.tm_mday != d) /* 2026-02-30 came back as March */
        return -EINVAL;
    *t = (double)secs + frac - sign * (zh * 3600.0 + zm * 60.0);
    return 0;
}

void timefmt_iso(char buf[TIMEFMT_ISO_MAX], double t, int digits)
{
    if (digits < 0)
        digits = 0;
    if (digits > 6)
        digits = 6; /* t * 10^digits stays within a long long up to 1e11 s */
    if (!isfinite(t) || fabs(t) > 1e11) {
        snprintf(buf, TIMEFMT_ISO_MAX, "%.17g", t);
        return;
    }
    long long per = 1;
    for (int i = 0; i < digits; i++)
        per *= 10;
    long long units = llround(t * (double)per);
    long long secs = units / per, frac = units % per;
    if (frac < 0) {
        frac += per;
        secs--;
    }
    time_t tt = (time_t)secs;
    struct tm tm;
    gmtime_r(&tt, &tm);
    size_t n = strftime(buf, TIMEFMT_ISO_MAX, "%Y-%m-%dT%H:%M:%S", &tm);
    if (digits)
        snprintf(buf + n, TIMEFMT_ISO_MAX - n, ".%0*lldZ", digits, frac);
    else
        snprintf(buf + n, TIMEFMT_ISO_MAX - n, "Z");
}
