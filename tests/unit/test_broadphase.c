/* The broadphase against brute force: random boxes and queries, inserts,
 * removes and updates, boxes spanning many cells or the whole world,
 * zero-thickness boxes, queries outside the world, out-of-memory. */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "broadphase.h"

#define N 3000
#define WORLD 200.0f

/* The model: what the broadphase should hold. */
static float bmin[N][3], bmax[N][3];
static int present[N];
static uint32_t got[N + 16], want[N];

static unsigned seed;

static float frand(float lo, float hi)
{
    seed = seed * 1103515245u + 12345u;
    return lo + (hi - lo) * (float)((seed >> 8) & 0xffffu) / 65535.0f;
}

static int cmp(const void *a, const void *b)
{
    uint32_t x = *(const uint32_t *)a, y = *(const uint32_t *)b;
    return (x > y) - (x < y);
}

/* A box of a random kind: small, large, a long thin wall, zero-thick, or
 * bigger than the world; sometimes partly or wholly outside the world. */
static void random_box(float min[3], float max[3])
{
    float s[3];
    int kind = (int)frand(0, 10);
    for (int a = 0; a < 3; a++)
        s[a] = frand(0.1f, 3.0f);
    if (kind == 5)
        s[0] = s[2] = frand(5, 40);
    else if (kind == 6)
        s[(int)frand(0, 1.99f) * 2] = frand(20, 150); /* a wall */
    else if (kind == 7)
        s[(int)frand(0, 2.99f)] = 0; /* zero thickness */
    else if (kind == 8)
        s[0] = s[2] = frand(WORLD, 3 * WORLD); /* bigger than the world */
    for (int a = 0; a < 3; a++) {
        min[a] = frand(-WORLD * 0.6f, WORLD * 0.6f);
        max[a] = min[a] + s[a];
    }
}

static void random_query(float min[3], float max[3])
{
    for (int a = 0; a < 3; a++) {
        min[a] = frand(-WORLD * 0.7f, WORLD * 0.7f);
        max[a] = min[a] + frand(0, 4.0f);
    }
}

static uint32_t brute(const float min[3], const float max[3])
{
    uint32_t m = 0;
    for (uint32_t h = 0; h < N; h++)
        if (present[h] && bmin[h][0] <= max[0] && bmax[h][0] >= min[0] && bmin[h][1] <= max[1] &&
            bmax[h][1] >= min[1] && bmin[h][2] <= max[2] && bmax[h][2] >= min[2])
            want[m++] = h;
    return m;
}

/* One query must return exactly the brute-force set, each handle once. */
static void check_one(const bp *b, const float min[3], const float max[3])
{
    uint32_t n = bp_query(b, min, max, got, N), m = brute(min, max);
    assert_int_equal(n, m);
    qsort(got, n, sizeof *got, cmp);
    assert_memory_equal(got, want, n * sizeof *got);
}

static void check_queries(const bp *b, int nq)
{
    for (int q = 0; q < nq; q++) {
        float min[3], max[3];
        random_query(min, max);
        check_one(b, min, max);
    }
    uint32_t count = 0;
    for (uint32_t h = 0; h < N; h++)
        count += (uint32_t)present[h];
    assert_int_equal(bp_count(b), count);
}

static bp *make(float cell)
{
    const float lo[3] = {-WORLD / 2, 0, -WORLD / 2}, hi[3] = {WORLD / 2, 50, WORLD / 2};
    bp *b = bp_create(lo, hi, cell);
    assert_non_null(b);
    memset(present, 0, sizeof present);
    return b;
}

static void insert_model(bp *b, uint32_t h)
{
    assert_int_equal(bp_insert(b, bmin[h], bmax[h], h), 0);
    present[h] = 1;
}

static void test_random_against_brute_force(void **state)
{
    (void)state;
    const float cells[] = {0, 1.0f, 7.5f, 64.0f};
    for (size_t c = 0; c < sizeof cells / sizeof *cells; c++) {
        seed = 7 + (unsigned)c;
        bp *b = make(cells[c]);
        for (uint32_t h = 0; h < N; h++) {
            random_box(bmin[h], bmax[h]);
            insert_model(b, h);
        }
        check_queries(b, 300);
        assert_int_equal(bp_optimize(b), 0);
        check_queries(b, 300);
        bp_destroy(b);
    }
}

static void test_insert_remove_reinsert(void **state)
{
    (void)state;
    seed = 99;
    bp *b = make(0);
    for (uint32_t h = 0; h < N; h++)
        random_box(bmin[h], bmax[h]);
    for (int round = 0; round < 20; round++) {
        for (int k = 0; k < 400; k++) {
            uint32_t h = (uint32_t)frand(0, N - 0.01f);
            if (present[h]) {
                assert_int_equal(bp_insert(b, bmin[h], bmax[h], h), -EEXIST);
                if (frand(0, 1) < 0.5f) {
                    assert_int_equal(bp_remove(b, h), 0);
                    present[h] = 0;
                    assert_int_equal(bp_remove(b, h), -ENOENT);
                } else {
                    random_box(bmin[h], bmax[h]);
                    assert_int_equal(bp_update(b, bmin[h], bmax[h], h), 0);
                }
            } else {
                assert_int_equal(bp_update(b, bmin[h], bmax[h], h), -ENOENT);
                insert_model(b, h);
            }
        }
        check_queries(b, 100);
    }
    /* Remove everything, then put it all back. */
    for (uint32_t h = 0; h < N; h++)
        if (present[h]) {
            assert_int_equal(bp_remove(b, h), 0);
            present[h] = 0;
        }
    assert_int_equal(bp_count(b), 0);
    const float all0[3] = {-INFINITY, -INFINITY, -INFINITY}, all1[3] = {INFINITY, INFINITY, INFINITY};
    assert_int_equal(bp_query(b, all0, all1, got, N), 0);
    for (uint32_t h = 0; h < N; h++)
        insert_model(b, h);
    check_queries(b, 200);
    bp_destroy(b);
}

/* One box over many cells (and levels), queried everywhere it reaches:
 * always exactly once. */
static void test_spanning_and_huge_boxes(void **state)
{
    (void)state;
    seed = 5;
    bp *b = make(1.0f);
    const float wall0[3] = {-90, 0, 3}, wall1[3] = {90, 3, 3.2f};      /* 180 cells long */
    const float huge0[3] = {-1e6f, -5, -1e6f}, huge1[3] = {1e6f, 1, 1e6f}; /* far beyond the world */
    const float slab0[3] = {-30, 10, -30}, slab1[3] = {30, 10.5f, 30};  /* 3,600 cells */
    memcpy(bmin[0], wall0, sizeof wall0), memcpy(bmax[0], wall1, sizeof wall1);
    memcpy(bmin[1], huge0, sizeof huge0), memcpy(bmax[1], huge1, sizeof huge1);
    memcpy(bmin[2], slab0, sizeof slab0), memcpy(bmax[2], slab1, sizeof slab1);
    for (uint32_t h = 0; h < 3; h++)
        insert_model(b, h);
    for (float x = -100; x <= 100; x += 0.37f) {
        float q0[3] = {x, 0.5f, 2.5f}, q1[3] = {x + 0.85f, 12, 3.5f};
        check_one(b, q0, q1);
        float w0[3] = {x, -1, -100}, w1[3] = {x + 30, 11, 100}; /* a wide query */
        check_one(b, w0, w1);
    }
    /* Plus many small boxes around them. */
    for (uint32_t h = 3; h < N; h++) {
        random_box(bmin[h], bmax[h]);
        insert_model(b, h);
    }
    check_queries(b, 500);
    bp_destroy(b);
}

/* Overlap is closed: touching counts, and zero-thickness boxes are found. */
static void test_degenerate_and_touching(void **state)
{
    (void)state;
    bp *b = make(2.0f);
    const float p[3] = {1, 1, 1};                       /* a point */
    const float f0[3] = {4, 0, 4}, f1[3] = {4, 3, 8};   /* a face, zero thick in x */
    const float c0[3] = {-2, 0, -2}, c1[3] = {0, 2, 0}; /* a box ending on cell edges */
    memcpy(bmin[0], p, sizeof p), memcpy(bmax[0], p, sizeof p);
    memcpy(bmin[1], f0, sizeof f0), memcpy(bmax[1], f1, sizeof f1);
    memcpy(bmin[2], c0, sizeof c0), memcpy(bmax[2], c1, sizeof c1);
    for (uint32_t h = 0; h < 3; h++)
        insert_model(b, h);
    const float q0[3] = {1, 1, 1};
    assert_int_equal(bp_query(b, q0, q0, got, N), 1); /* a point query on a point box */
    assert_int_equal(got[0], 0);
    const float t0[3] = {0, 2, 0}, t1[3] = {3.9f, 5, 0.5f}; /* touches box 2 at its corner */
    assert_int_equal(bp_query(b, t0, t1, got, N), 1);
    assert_int_equal(got[0], 2);
    const float u0[3] = {4, 3, 8}, u1[3] = {5, 4, 9}; /* touches the face at its corner */
    assert_int_equal(bp_query(b, u0, u1, got, N), 1);
    assert_int_equal(got[0], 1);
    const float v0[3] = {4.001f, 0, 4}, v1[3] = {5, 4, 9}; /* just misses it */
    assert_int_equal(bp_query(b, v0, v1, got, N), 0);
    for (float x = -3; x < 6; x += 0.25f)
        for (float z = -3; z < 9; z += 0.5f) {
            float a[3] = {x, 0, z}, c[3] = {x + 0.5f, 1, z + 0.25f};
            check_one(b, a, c);
        }
    bp_destroy(b);
}

/* Queries partly or wholly outside the world, inverted, infinite or NaN. */
static void test_queries_outside_the_world(void **state)
{
    (void)state;
    seed = 11;
    bp *b = make(0);
    for (uint32_t h = 0; h < N; h++) {
        random_box(bmin[h], bmax[h]);
        insert_model(b, h);
    }
    for (int k = 0; k < 300; k++) {
        float min[3], max[3];
        random_query(min, max);
        for (int a = 0; a < 3; a++) {
            float shift = frand(0, 1) < 0.5f ? 0 : (frand(0, 1) < 0.5f ? -1 : 1) * frand(WORLD * 0.5f, WORLD * 3);
            min[a] += shift, max[a] += shift;
        }
        check_one(b, min, max);
    }
    const float far0[3] = {1e7f, 0, 1e7f}, far1[3] = {1e7f + 1, 2, 1e7f + 1};
    check_one(b, far0, far1);
    const float all0[3] = {-INFINITY, -INFINITY, -INFINITY}, all1[3] = {INFINITY, INFINITY, INFINITY};
    check_one(b, all0, all1);
    assert_int_equal(bp_query(b, all0, all1, got, N), N);
    const float inv0[3] = {5, 0, 5}, inv1[3] = {4, 2, 6}; /* min > max in x */
    assert_int_equal(bp_query(b, inv0, inv1, got, N), 0);
    const float nan0[3] = {NAN, 0, 0}, nan1[3] = {1, 2, 1};
    assert_int_equal(bp_query(b, nan0, nan1, got, N), 0);
    assert_int_equal(bp_query(b, nan1, nan0, got, N), 0);
    bp_destroy(b);
}

/* Only out_max handles are written; the count is still the true one. The
 * batch gives the same lists as one query at a time. */
static void test_limits_and_batch(void **state)
{
    (void)state;
    seed = 3;
    bp *b = make(0);
    for (uint32_t h = 0; h < N; h++) {
        random_box(bmin[h], bmax[h]);
        insert_model(b, h);
    }
    const float all0[3] = {-INFINITY, -INFINITY, -INFINITY}, all1[3] = {INFINITY, INFINITY, INFINITY};
    for (uint32_t k = 0; k < 16; k++)
        got[10 + k] = 0xdeadbeef;
    assert_int_equal(bp_query(b, all0, all1, got, 10), N);
    for (uint32_t k = 0; k < 16; k++)
        assert_int_equal(got[10 + k], 0xdeadbeef);

    enum { NQ = 200 };
    static bp_box q[NQ];
    static uint32_t out[NQ * 256], off[NQ + 1], one[N];
    for (int i = 0; i < NQ; i++)
        random_query(q[i].min, q[i].max);
    uint32_t total = bp_query_batch(b, q, NQ, out, NQ * 256, off);
    assert_int_equal(off[0], 0);
    assert_int_equal(off[NQ], total);
    for (int i = 0; i < NQ; i++) {
        uint32_t n = bp_query(b, q[i].min, q[i].max, one, N);
        assert_int_equal(off[i + 1] - off[i], n);
        assert_memory_equal(out + off[i], one, n * sizeof *one); /* same order, too */
    }
    /* Too little room: the lists are cut, the total is still right. */
    uint32_t room = total / 2;
    assert_int_equal(bp_query_batch(b, q, NQ, out, room, off), total);
    for (int i = 0; i <= NQ; i++)
        assert_true(off[i] <= room);
    assert_int_equal(off[NQ], room);
    assert_int_equal(bp_query_batch(b, q, 0, out, room, off), 0);
    assert_int_equal(off[0], 0);
    bp_destroy(b);
}

static void test_invalid_input(void **state)
{
    (void)state;
    const float lo[3] = {0, 0, 0}, hi[3] = {10, 10, 10}, flat[3] = {10, 0, 10};
    assert_null(bp_create(lo, flat, 1));      /* empty in y */
    assert_null(bp_create(lo, hi, -1));       /* negative cell */
    assert_null(bp_create(lo, hi, NAN));      /* NaN cell */
    assert_null(bp_create(lo, hi, 1e-4f));    /* 100,000 cells along an axis */
    const float inf[3] = {INFINITY, 10, 10};
    assert_null(bp_create(lo, inf, 1));
    bp *b = bp_create(lo, hi, 0);
    assert_non_null(b);
    const float a[3] = {1, 1, 1}, c[3] = {2, 2, 2}, nan[3] = {1, NAN, 1};
    assert_int_equal(bp_optimize(b), 0); /* empty */
    assert_int_equal(bp_query(b, lo, hi, got, N), 0);
    assert_int_equal(bp_insert(b, c, a, 0), -EINVAL); /* min > max */
    assert_int_equal(bp_insert(b, nan, c, 0), -EINVAL);
    assert_int_equal(bp_insert(b, a, inf, 0), -EINVAL);
    assert_int_equal(bp_insert(b, a, c, BP_MAX_HANDLE), -EINVAL);
    assert_int_equal(bp_insert(b, a, c, 0), 0);
    assert_int_equal(bp_update(b, c, a, 0), -EINVAL);
    assert_int_equal(bp_remove(b, 1), -ENOENT);
    assert_int_equal(bp_remove(b, BP_MAX_HANDLE + 5u), -ENOENT);
    assert_int_equal(bp_count(b), 1);
    assert_int_equal(bp_query(b, a, a, got, N), 1);
    bp_destroy(b);
    bp_destroy(NULL);
}

/* Every allocation that can fail does so once: the call reports -ENOMEM (or
 * NULL) and the structure still answers exactly what it held. */
static void test_out_of_memory(void **state)
{
    (void)state;
    const float lo[3] = {-WORLD / 2, 0, -WORLD / 2}, hi[3] = {WORLD / 2, 50, WORLD / 2};
    for (long k = 0; k < 8; k++) {
        cvre_alloc_fail_after(k);
        bp *b = bp_create(lo, hi, 1);
        cvre_alloc_fail_after(-1);
        bp_destroy(b);
    }
    seed = 21;
    bp *b = make(1.0f);
    for (uint32_t h = 0; h < N; h++)
        random_box(bmin[h], bmax[h]);
    int failures = 0;
    for (uint32_t h = 0; h < N; h++) {
        cvre_alloc_fail_after(h % 3 ? -1 : 0);
        int rc = bp_insert(b, bmin[h], bmax[h], h);
        cvre_alloc_fail_after(-1);
        if (rc == -ENOMEM)
            failures++;
        else
            assert_int_equal(rc, 0);
        present[h] = rc == 0;
        if (h % 97 == 0)
            check_queries(b, 20);
    }
    assert_true(failures > 0);
    check_queries(b, 300);
    /* A failed update keeps the old box. */
    for (uint32_t h = 0; h < N; h += 7) {
        if (!present[h])
            continue;
        float min[3], max[3];
        random_box(min, max);
        cvre_alloc_fail_after(0);
        int rc = bp_update(b, min, max, h);
        cvre_alloc_fail_after(-1);
        if (rc == 0)
            memcpy(bmin[h], min, sizeof min), memcpy(bmax[h], max, sizeof max);
        else
            assert_int_equal(rc, -ENOMEM);
    }
    check_queries(b, 300);
    cvre_alloc_fail_after(0);
    assert_int_equal(bp_optimize(b), -ENOMEM);
    cvre_alloc_fail_after(-1);
    check_queries(b, 100);
    bp_destroy(b);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_random_against_brute_force),
        cmocka_unit_test(test_insert_remove_reinsert),
        cmocka_unit_test(test_spanning_and_huge_boxes),
        cmocka_unit_test(test_degenerate_and_touching),
        cmocka_unit_test(test_queries_outside_the_world),
        cmocka_unit_test(test_limits_and_batch),
        cmocka_unit_test(test_invalid_input),
        cmocka_unit_test(test_out_of_memory),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
