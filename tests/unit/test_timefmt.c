/*
 * base/timefmt: every form a program takes a time in (cvre-admin's and
 * cvre-cluster's --since/--until), what each accepted before the one
 * parser, what it refuses, and that what timefmt_iso prints reads back.
 */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <cmocka.h>

#include "timefmt.h"

/* 2026-12-01T17:40:00Z */
#define T_DEC1 1796146800.0

static double parsed(const char *text)
{
    double t = -1;
    int rc = timefmt_parse(text, &t);
    if (rc != 0)
        fail_msg("\"%s\" was refused (%d)", text, rc);
    return t;
}

static void test_accepted(void **state)
{
    (void)state;
    static const struct {
        const char *text;
        double t;
    } cases[] = {
        /* What cvre-admin prints: to the millisecond (tables), the
         * microsecond (CSV, JSON), and whole seconds. */
        {"2026-12-01T17:40:00Z", T_DEC1},
        {"2026-12-01T17:40:00.000Z", T_DEC1},
        {"2026-12-01T17:40:00.250000Z", T_DEC1 + 0.25},
        /* What cvre-cluster took: seconds, no zone (UTC), fields of one digit. */
        {"2026-12-01T17:40:00", T_DEC1},
        {"2026-12-1T17:40:0", T_DEC1},
        {"1796146800", T_DEC1},
        {"1796146800.5", T_DEC1 + 0.5},
        {"1.7961468e9", T_DEC1},
        /* What cvre-admin took: a date, minutes, a space, zones. */
        {"2026-12-01", T_DEC1 - (17 * 3600 + 40 * 60)},
        {"2026-12-01T17:40", T_DEC1},
        {"2026-12-01 17:40:00", T_DEC1},
        {"2026-12-01 18:40:00+01:00", T_DEC1},
        {"2026-12-01T12:40:00-0500", T_DEC1},
        {"2026-12-01T19:40+02", T_DEC1},
        {"2026-12-01t17:40:00z", T_DEC1},
        {"2026-12-01T17:40:00.125+00:00", T_DEC1 + 0.125},
        {"2026-12-01T17:40:60Z", T_DEC1 + 60}, /* a leap second counts on */
        {"1969-12-31T23:59:59Z", -1},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        double t = parsed(cases[i].text);
        if (fabs(t - cases[i].t) > 1e-6)
            fail_msg("\"%s\" read as %.6f, not %.6f", cases[i].text, t, cases[i].t);
    }
}

static void test_refused(void **state)
{
    (void)state;
    static const char *const cases[] = {
        "", "yesterday", "inf", "-inf", "nan", "1e400", "2026-12", "26-12-01", "2026-12-01T", "2026-12-01T17",
        "2026-12-01T17:", "2026-12-01T17:40:", "2026-12-01T17:40:00.", "2026-12-01T17:40:00.5x",
        "2026-12-01T17:40:00ZZ", "2026-12-01T17:40:00+1", "2026-12-01T17:40:00+01:", "2026-12-01T17:40:00+0100x",
        "2026-12-01T17:40:00+24:00", "2026-12-01T17:40:00+01:60", "2026-13-01", "2026-00-10", "2026-02-30T00:00",
        "2026-12-32", "2026-12-01T24:00", "2026-12-01T17:60", "2026-12-01T17:40:61", "2026-12-001", "2026-12-01x",
        " 2026-12-01", "2026-12-01T17:40:00 Z", "12026-12-01",
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        double t = 42;
        int rc = timefmt_parse(cases[i], &t);
        if (rc != -EINVAL || t != 42)
            fail_msg("\"%s\" was not refused: %d, %.6f", cases[i], rc, t);
    }
}

static void test_printed_reads_back(void **state)
{
    (void)state;
    char buf[TIMEFMT_ISO_MAX];
    timefmt_iso(buf, T_DEC1, 0);
    assert_string_equal(buf, "2026-12-01T17:40:00Z");
    timefmt_iso(buf, T_DEC1 + 0.25, 3);
    assert_string_equal(buf, "2026-12-01T17:40:00.250Z");
    timefmt_iso(buf, T_DEC1 - 0.0000004, 6);
    assert_string_equal(buf, "2026-12-01T17:40:00.000000Z");
    timefmt_iso(buf, -0.5, 3); /* before 1970: the fraction counts forward */
    assert_string_equal(buf, "1969-12-31T23:59:59.500Z");
    timefmt_iso(buf, 1e12, 6); /* beyond any calendar shown: a number */
    assert_string_equal(buf, "1000000000000");
    timefmt_iso(buf, -1e11, 6); /* the widest calendar text */
    assert_true(strlen(buf) < TIMEFMT_ISO_MAX);
    assert_int_equal(buf[strlen(buf) - 1], 'Z');
    /* Every printed form reads back, to its last decimal. */
    for (double t = -86400.0 * 400; t < 5e9; t += 86400.0 * 97 + 3600.0 * 7 + 61.123456) {
        for (int digits = 0; digits <= 6; digits++) {
            timefmt_iso(buf, t, digits);
            double back = parsed(buf);
            if (fabs(back - t) > 0.5 * pow(10, -digits) + 1e-6)
                fail_msg("%.6f printed as %s read back as %.6f", t, buf, back);
        }
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_accepted),
        cmocka_unit_test(test_refused),
        cmocka_unit_test(test_printed_reads_back),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
