/* test_num.c: base/num.c, the one strict reader of typed numbers. */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "num.h"

static void test_real(void **state)
{
    (void)state;
    double v = 0;
    assert_int_equal(num_parse_real("2.5", 0, 10, &v), 0);
    assert_true(v == 2.5);
    assert_int_equal(num_parse_real("-1e3", -INFINITY, INFINITY, &v), 0);
    assert_true(v == -1000);
    v = 7;
    const char *bad[] = {"", "abc", "5abc", "5 ", "nan", "inf", "-inf", "1e999", "11", "-0.5"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++)
        assert_int_equal(num_parse_real(bad[i], 0, 10, &v), -EINVAL);
    assert_true(v == 7); /* untouched on refusal */
    assert_int_equal(num_parse_real("0", 0, 10, &v), 0);
    assert_int_equal(num_parse_real("10", 0, 10, &v), 0);
}

static void test_int(void **state)
{
    (void)state;
    long long v = 0;
    assert_int_equal(num_parse_int("42", 1, 100, &v), 0);
    assert_int_equal(v, 42);
    assert_int_equal(num_parse_int("-3", -5, 5, &v), 0);
    assert_int_equal(v, -3);
    assert_int_equal(num_parse_int("4294967295", 1, UINT32_MAX, &v), 0);
    assert_int_equal(v, 4294967295LL);
    v = 9;
    const char *bad[] = {"", "-3", "+3", " 3", "3 ", "3.0", "0x10", "101", "0", "99999999999999999999"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++)
        assert_int_equal(num_parse_int(bad[i], 1, 100, &v), -EINVAL);
    assert_int_equal(v, 9);
}

int main(void)
{
    const struct CMUnitTest tests[] = {cmocka_unit_test(test_real), cmocka_unit_test(test_int)};
    return cmocka_run_group_tests(tests, NULL, NULL);
}
