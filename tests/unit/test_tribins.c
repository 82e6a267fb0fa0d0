/*
 * The triangle bins against brute force: for random boxes in and around a
 * region, with and without a margin and a spread limit, every query must
 * yield every triangle whose grown box meets both the region and the query
 * box, each once, and nothing that is not a triangle. Then the edge cases:
 * a flat region, no triangles, a bad bin count, allocation failures.
 */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>

#include <errno.h>
#include <string.h>

#include "alloc.h"
#include "tribins.h"

#define NTRIS 500u

static uint32_t rng = 12345;

static double uniform(double lo, double hi)
{
    rng = rng * 1664525u + 1013904223u;
    return lo + (hi - lo) * (double)(rng >> 8) / (double)(1u << 24);
}

static void random_box(float b[6], double lo, double hi, double size)
{
    for (int a = 0; a < 3; a++) {
        b[a] = (float)uniform(lo, hi);
        b[3 + a] = b[a] + (float)uniform(0, size);
    }
}

static int meets(const float t[6], double grow, const double lo[3], const double hi[3])
{
    for (int a = 0; a < 3; a++)
        if ((double)t[a] - grow > hi[a] || (double)t[3 + a] + grow < lo[a])
            return 0;
    return 1;
}

/* Queries b with random boxes, some partly or wholly outside the region. */
static void check_queries(tribins *b, const double region[6], const float (*box)[6], uint32_t n, double grow)
{
    static uint32_t times[NTRIS];
    const double rlo[3] = {region[0], region[1], region[2]}, rhi[3] = {region[3], region[4], region[5]};
    for (int q = 0; q < 300; q++) {
        float qb[6];
        random_box(qb, -2, 12, q % 3 ? 1.5 : 6);
        double lo[3] = {qb[0], qb[1], qb[2]}, hi[3] = {qb[3], qb[4], qb[5]};
        memset(times, 0, sizeof times);
        tribins_iter it;
        tribins_query(b, lo, hi, &it);
        for (uint32_t t; (t = tribins_next(&it)) != TRIBINS_END;) {
            assert_true(t < n);
            times[t]++;
        }
        int in_region = meets((const float[6]){qb[0], qb[1], qb[2], qb[3], qb[4], qb[5]}, 0, rlo, rhi);
        for (uint32_t t = 0; t < n; t++) {
            assert_true(times[t] <= 1);
            if (in_region && meets(box[t], grow, rlo, rhi) && meets(box[t], grow, lo, hi))
                assert_int_equal(times[t], 1);
        }
    }
}

static void test_against_brute_force(void **state)
{
    (void)state;
    static float box[NTRIS][6];
    for (uint32_t i = 0; i < NTRIS; i++)
        random_box(box[i], -1, 11, i % 10 ? 0.8 : 8); /* a tenth are large */
    const double region[6] = {0, 0, 0, 10, 10, 10};
    const uint32_t per_axis[] = {1, 5, 16};
    const double grow[] = {0, 0.25};
    const uint64_t spread[] = {0, 1, 8};
    for (size_t i = 0; i < sizeof per_axis / sizeof *per_axis; i++)
        for (size_t g = 0; g < 2; g++)
            for (size_t s = 0; s < 3; s++) {
                tribins b;
                assert_int_equal(tribins_build(&b, region, per_axis[i], (const float(*)[6])box, NTRIS, grow[g],
                                               spread[s]),
                                 0);
                /* The spread limit bounds the entries; big ones are kept once. */
                uint64_t nb = (uint64_t)per_axis[i] * per_axis[i] * per_axis[i];
                if (spread[s])
                    assert_true(b.start[nb] <= spread[s] * NTRIS);
                else
                    assert_int_equal(b.nbig, 0);
                if (per_axis[i] > 1 && spread[s] == 1)
                    assert_true(b.nbig > 0);
                check_queries(&b, region, (const float(*)[6])box, NTRIS, grow[g]);
                tribins_free(&b);
                tribins_free(&b);
            }
}

static void test_flat_region(void **state)
{
    (void)state;
    const float box[2][6] = {{0, 1, 2, 4, 1, 3}, {5, 1, 0, 6, 1, 1}};
    const double region[6] = {0, 1, 0, 6, 1, 3};
    tribins b;
    assert_int_equal(tribins_build(&b, region, 4, box, 2, 0, 0), 0);
    tribins_iter it;
    /* A query flat on y = 1 meets the first box only. */
    tribins_query(&b, (const double[3]){0, 1, 2.5}, (const double[3]){1, 1, 2.5}, &it);
    assert_int_equal(tribins_next(&it), 0);
    assert_int_equal(tribins_next(&it), TRIBINS_END);
    /* One above the plane misses the region: nothing. */
    tribins_query(&b, (const double[3]){0, 1.5, 0}, (const double[3]){6, 2, 3}, &it);
    assert_int_equal(tribins_next(&it), TRIBINS_END);
    tribins_free(&b);
}

static void test_edges(void **state)
{
    (void)state;
    const double region[6] = {0, 0, 0, 1, 1, 1};
    tribins b;
    assert_int_equal(tribins_build(&b, region, 3, NULL, 0, 0, 0), 0);
    tribins_iter it;
    tribins_query(&b, region, region + 3, &it);
    assert_int_equal(tribins_next(&it), TRIBINS_END);
    tribins_free(&b);
    assert_int_equal(tribins_build(&b, region, 0, NULL, 0, 0, 0), -EINVAL);
    tribins_free(&b);
    assert_int_equal(tribins_build(&b, region, TRIBINS_PER_AXIS_MAX + 1, NULL, 0, 0, 0), -EINVAL);
    tribins_free(&b);
    /* Every allocation failing in turn: -ENOMEM, and b can be freed. */
    const float box[3][6] = {{0, 0, 0, 1, 1, 1}, {0.1f, 0.1f, 0.1f, 0.2f, 0.2f, 0.2f}, {0.5f, 0, 0, 0.6f, 1, 0.1f}};
    int failed = 0;
    for (long k = 0; k < 8; k++) {
        cvre_alloc_fail_after(k);
        int rc = tribins_build(&b, region, 3, box, 3, 0, 4);
        cvre_alloc_fail_after(-1);
        assert_true(rc == 0 || rc == -ENOMEM);
        failed += rc == -ENOMEM;
        tribins_free(&b);
    }
    assert_int_equal(failed, 5);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_against_brute_force),
        cmocka_unit_test(test_flat_region),
        cmocka_unit_test(test_edges),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
