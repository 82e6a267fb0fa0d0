/* The grid's queries against brute force, under insert, move and remove. */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>
#include <stdlib.h>
#include <string.h>

#include "grid.h"

#define N 2000
#define WORLD 500.0f

static float xs[N], zs[N];
static int present[N];

static float frand(unsigned *seed, float lo, float hi)
{
    *seed = *seed * 1103515245u + 12345u;
    return lo + (hi - lo) * (float)((*seed >> 8) & 0xffffu) / 65535.0f;
}

static int cmp(const void *a, const void *b)
{
    uint32_t x = *(const uint32_t *)a, y = *(const uint32_t *)b;
    return (x > y) - (x < y);
}

/* Every query must return exactly the present handles within r. */
static void check_queries(grid *g, unsigned *seed, float r)
{
    static uint32_t got[N], want[N];
    for (int q = 0; q < 50; q++) {
        float x = frand(seed, -WORLD - 20, WORLD + 20), z = frand(seed, -WORLD - 20, WORLD + 20);
        uint32_t n = grid_query(g, x, z, r, got, N), m = 0;
        for (uint32_t h = 0; h < N; h++) {
            float dx = xs[h] - x, dz = zs[h] - z;
            if (present[h] && dx * dx + dz * dz <= r * r)
                want[m++] = h;
        }
        assert_int_equal(n, m);
        qsort(got, n, sizeof *got, cmp);
        assert_memory_equal(got, want, n * sizeof *got);
    }
}

static void test_matches_brute_force(void **state)
{
    (void)state;
    unsigned seed = 42;
    grid *g = grid_create(-WORLD, -WORLD, WORLD, WORLD, 64.0f, N);
    assert_non_null(g);
    for (uint32_t h = 0; h < N; h++) {
        xs[h] = frand(&seed, -WORLD, WORLD);
        zs[h] = frand(&seed, -WORLD, WORLD);
        present[h] = 1;
        assert_int_equal(grid_insert(g, h, xs[h], zs[h]), 0);
    }
    check_queries(g, &seed, 64.0f);
    check_queries(g, &seed, 10.0f);
    check_queries(g, &seed, 150.0f); /* wider than a cell */
    for (int round = 0; round < 5; round++) {
        for (uint32_t h = 0; h < N; h++) {
            if (!present[h])
                continue;
            if (h % 7 == (uint32_t)round) {
                grid_remove(g, h);
                present[h] = 0;
                continue;
            }
            xs[h] += frand(&seed, -40, 40);
            zs[h] += frand(&seed, -40, 40);
            assert_int_equal(grid_move(g, h, xs[h], zs[h]), 0);
        }
        check_queries(g, &seed, 64.0f);
    }
    grid_destroy(g);
}

static void test_out_of_bounds_and_max(void **state)
{
    (void)state;
    grid *g = grid_create(0, 0, 100, 100, 10, 8);
    assert_non_null(g);
    /* Points outside the bounds are filed in border cells and still found. */
    assert_int_equal(grid_insert(g, 0, -50, -50), 0);
    assert_int_equal(grid_insert(g, 1, 150, 50), 0);
    assert_int_equal(grid_insert(g, 2, 50, 50), 0);
    uint32_t out[1];
    assert_int_equal(grid_query(g, -50, -50, 1, out, 1), 1);
    assert_int_equal(out[0], 0);
    /* More matches than room: the count is exact, only max are written. */
    assert_int_equal(grid_query(g, 50, 50, 1000, out, 1), 3);
    assert_null(grid_create(0, 0, 0, 100, 10, 8));
    assert_null(grid_create(0, 0, 100, 100, 0, 8));
    grid_destroy(g);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_matches_brute_force),
        cmocka_unit_test(test_out_of_bounds_and_max),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
