/* DBSCAN on tiny hand-made cases, bad parameters and allocation failures. */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>
#include <errno.h>
#include <malloc.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "alloc.h"
#include "dbscan.h"

#define MAXP 4096

static float pts[3 * MAXP];
static uint32_t users[MAXP];
static int32_t labels[MAXP];
static size_t npts;

static void add(float x, float y, float z, uint32_t user)
{
    pts[3 * npts] = x;
    pts[3 * npts + 1] = y;
    pts[3 * npts + 2] = z;
    users[npts++] = user;
}

static int setup(void **state)
{
    (void)state;
    npts = 0;
    cvre_alloc_fail_after(-1);
    return 0;
}

/* Runs on the points added so far; asserts success and returns the result. */
static dbscan_result *run(double eps, uint32_t min_points, uint32_t min_users, const uint32_t *u)
{
    dbscan_params p = {.eps = eps, .min_points = min_points, .min_users = min_users, .threads = 1};
    dbscan_result *r = NULL;
    assert_int_equal(dbscan_run(pts, u, npts, &p, labels, &r), 0);
    assert_non_null(r);
    return r;
}

static void test_chain_at_exactly_eps(void **state)
{
    (void)state;
    for (int i = 0; i < 10; i++)
        add((float)i, 0, 0, (uint32_t)i);
    dbscan_result *r = run(1.0, 3, 1, users);
    assert_int_equal(dbscan_result_count(r), 1);
    for (size_t i = 0; i < npts; i++) {
        assert_int_equal(labels[i], 0);
        /* The ends have one neighbour at exactly eps: border points. */
        assert_int_equal(dbscan_result_is_core(r, i), i != 0 && i != npts - 1);
    }
    const dbscan_cluster *c = dbscan_result_cluster(r, 0);
    assert_int_equal(c->points, 10);
    assert_int_equal(c->users, 10);
    assert_float_equal(c->centroid[0], 4.5f, 1e-6f);
    assert_float_equal(c->min[0], 0.0f, 0.0f);
    assert_float_equal(c->max[0], 9.0f, 0.0f);
    assert_null(dbscan_result_cluster(r, 1));
    dbscan_result_free(r);

    /* Just below the spacing, nobody has a neighbour. */
    r = run(0.999, 2, 1, users);
    assert_int_equal(dbscan_result_count(r), 0);
    for (size_t i = 0; i < npts; i++)
        assert_int_equal(labels[i], -1);
    dbscan_result_free(r);
}

/* Two 1D clusters, B listed first, and a border point b between them; eps 1.2,
 * min_points 4: the innermost core points are at -1 (A) and +1 (B). */
static void border_case(float b)
{
    const float B[] = {1.0f, 1.4f, 1.7f, 2.0f}, A[] = {-1.0f, -1.4f, -1.7f, -2.0f};
    for (int i = 0; i < 4; i++)
        add(B[i], 0, 0, 1);
    for (int i = 0; i < 4; i++)
        add(A[i], 0, 0, 2);
    add(b, 0, 0, 3);
}

static void test_border_between_two_clusters(void **state)
{
    (void)state;
    /* Nearer to B's core point (0.95 against 1.05): B, which is cluster 0
     * because its core points come first. */
    border_case(0.05f);
    dbscan_result *r = run(1.2, 4, 1, users);
    assert_int_equal(dbscan_result_count(r), 2);
    assert_int_equal(labels[0], 0);
    assert_int_equal(labels[4], 1);
    assert_int_equal(dbscan_result_is_core(r, 8), 0);
    assert_int_equal(labels[8], 0);
    assert_int_equal(dbscan_result_cluster(r, 0)->points, 5);
    /* b counts as a user of both clusters: it is reached by both. */
    assert_int_equal(dbscan_result_cluster(r, 0)->users, 2);
    assert_int_equal(dbscan_result_cluster(r, 1)->users, 2);
    dbscan_result_free(r);

    /* Nearer to A. */
    npts = 0;
    border_case(-0.05f);
    r = run(1.2, 4, 1, users);
    assert_int_equal(labels[8], 1);
    dbscan_result_free(r);

    /* A tie goes to the core point with the lower index: B's, index 0. */
    npts = 0;
    border_case(0.0f);
    r = run(1.2, 4, 1, users);
    assert_int_equal(labels[8], 0);
    dbscan_result_free(r);
}

static void test_min_points_one_makes_every_point_core(void **state)
{
    (void)state;
    add(0, 0, 0, 0);
    add(0.5f, 0, 0, 0);
    add(10, 0, 0, 0);
    add(20, 20, 20, 0);
    dbscan_result *r = run(0.5, 1, 1, users);
    assert_int_equal(dbscan_result_count(r), 3);
    const int32_t want[] = {0, 0, 1, 2};
    for (size_t i = 0; i < npts; i++) {
        assert_int_equal(dbscan_result_is_core(r, i), 1);
        assert_int_equal(labels[i], want[i]);
    }
    assert_int_equal(dbscan_result_is_core(r, npts), 0);
    dbscan_result_free(r);
}

static void test_min_users(void **state)
{
    (void)state;
    /* Cluster X: 12 points from user 7 alone. Cluster Y: 12 points from 3 users. */
    for (int i = 0; i < 12; i++)
        add(0.1f * (float)i, 0, 0, 7);
    for (int i = 0; i < 12; i++)
        add(50 + 0.1f * (float)i, 0, 0, (uint32_t)(i % 3));
    dbscan_result *r = run(0.5, 5, 1, users);
    assert_int_equal(dbscan_result_count(r), 2);
    assert_int_equal(dbscan_result_cluster(r, 0)->users, 1);
    assert_int_equal(dbscan_result_cluster(r, 1)->users, 3);
    dbscan_result_free(r);

    r = run(0.5, 5, 2, users);
    assert_int_equal(dbscan_result_count(r), 1);
    for (size_t i = 0; i < 12; i++) {
        assert_int_equal(labels[i], -1);
        assert_int_equal(dbscan_result_is_core(r, i), 1); /* core, but dropped */
        assert_int_equal(labels[12 + i], 0);
    }
    assert_int_equal(dbscan_result_cluster(r, 0)->users, 3);
    assert_float_equal(dbscan_result_cluster(r, 0)->centroid[0], 50.55f, 1e-4f);
    dbscan_result_free(r);

    r = run(0.5, 5, 4, users);
    assert_int_equal(dbscan_result_count(r), 0);
    dbscan_result_free(r);

    /* No user ids: every point is its own user. */
    r = run(0.5, 5, 12, NULL);
    assert_int_equal(dbscan_result_count(r), 2);
    assert_int_equal(dbscan_result_cluster(r, 0)->users, 12);
    dbscan_result_free(r);
    r = run(0.5, 5, 13, NULL);
    assert_int_equal(dbscan_result_count(r), 0);
    dbscan_result_free(r);
}

static void test_duplicates(void **state)
{
    (void)state;
    for (int i = 0; i < 5; i++)
        add(3, 4, 5, (uint32_t)i);
    add(3, 4, 5.25f, 9);
    dbscan_result *r = run(0.1, 5, 1, users);
    assert_int_equal(dbscan_result_count(r), 1);
    for (size_t i = 0; i < 5; i++)
        assert_int_equal(labels[i], 0);
    assert_int_equal(labels[5], -1);
    dbscan_result_free(r);
    r = run(0.25, 6, 1, users); /* the sixth point at exactly eps joins */
    assert_int_equal(dbscan_result_count(r), 1);
    for (size_t i = 0; i < 6; i++)
        assert_int_equal(labels[i], 0);
    dbscan_result_free(r);
    r = run(0.1, 6, 1, users);
    assert_int_equal(dbscan_result_count(r), 0);
    dbscan_result_free(r);
}

static void test_no_points(void **state)
{
    (void)state;
    dbscan_params p = {.eps = 1, .min_points = 3, .min_users = 1, .threads = 0};
    dbscan_result *r = NULL;
    assert_int_equal(dbscan_run(NULL, NULL, 0, &p, NULL, &r), 0);
    assert_non_null(r);
    assert_int_equal(dbscan_result_count(r), 0);
    assert_int_equal(dbscan_result_searches(r), 0);
    dbscan_result_free(r);
    assert_int_equal(dbscan_run(NULL, NULL, 0, &p, NULL, NULL), 0);
    dbscan_result_free(NULL);
}

static void expect_einval(const dbscan_params *p, const float *xyz, int32_t *lab, size_t n)
{
    dbscan_result *r = (dbscan_result *)&r; /* must be reset to NULL */
    assert_int_equal(dbscan_run(xyz, NULL, n, p, lab, &r), -EINVAL);
    assert_null(r);
}

static void test_bad_params(void **state)
{
    (void)state;
    add(0, 0, 0, 0);
    add(1, 0, 0, 0);
    const double bad_eps[] = {0.0, -1.0, NAN, INFINITY, -INFINITY, 1e-300, 1e300};
    for (size_t i = 0; i < sizeof bad_eps / sizeof *bad_eps; i++) {
        dbscan_params p = {.eps = bad_eps[i], .min_points = 2, .min_users = 1};
        expect_einval(&p, pts, labels, npts);
    }
    dbscan_params p = {.eps = 1, .min_points = 0, .min_users = 1};
    expect_einval(&p, pts, labels, npts);
    p.min_points = 2;
    expect_einval(NULL, pts, labels, npts);
    expect_einval(&p, NULL, labels, npts);
    expect_einval(&p, pts, NULL, npts);
    expect_einval(&p, pts, labels, (size_t)DBSCAN_MAX_POINTS + 1);
    const float bad_coord[] = {NAN, INFINITY, -INFINITY, 2e9f};
    for (size_t i = 0; i < sizeof bad_coord / sizeof *bad_coord; i++) {
        for (int a = 0; a < 3; a++) {
            float saved = pts[3 + a];
            pts[3 + a] = bad_coord[i];
            expect_einval(&p, pts, labels, npts);
            pts[3 + a] = saved;
        }
    }
}

/* Blobs on a 100-unit lattice of centres plus scattered points: dense grid
 * cells, searched points, border points, several clusters. */
static void make_mixed(unsigned seed, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        seed = seed * 1103515245u + 12345u;
        float f[4];
        for (int a = 0; a < 4; a++) {
            seed = seed * 1103515245u + 12345u;
            f[a] = (float)((seed >> 8) & 0xffffu) / 65535.0f;
        }
        if (i % 3 == 0)
            add(10 * f[0], 10 * f[1], 10 * f[2], seed % 17);
        else
            add(2.0f * (float)(i % 4) + f[0] * 0.6f, f[1] * 0.6f, f[2] * 0.6f, seed % 17);
    }
}

static void test_threads_agree(void **state)
{
    (void)state;
    make_mixed(7, MAXP);
    static int32_t one[MAXP];
    dbscan_params p = {.eps = 0.3, .min_points = 6, .min_users = 3, .threads = 1};
    dbscan_result *r1 = NULL, *r4 = NULL;
    assert_int_equal(dbscan_run(pts, users, npts, &p, one, &r1), 0);
    p.threads = 4;
    assert_int_equal(dbscan_run(pts, users, npts, &p, labels, &r4), 0);
    assert_memory_equal(one, labels, npts * sizeof *labels);
    assert_true(dbscan_result_count(r1) >= 4);
    assert_int_equal(dbscan_result_count(r1), dbscan_result_count(r4));
    assert_true(dbscan_result_searches(r1) < npts); /* the grid spared some searches */
    dbscan_result_free(r1);
    dbscan_result_free(r4);
}

/* A tiny eps over a huge extent cannot use the grid: every point is searched. */
static void test_without_grid(void **state)
{
    (void)state;
    for (int i = 0; i < 4; i++) {
        add(-5e8f, 0, 0, (uint32_t)i);
        add(5e8f, 1e-6f * (float)i, 0, (uint32_t)i);
    }
    dbscan_result *r = run(1e-3, 4, 1, users);
    assert_int_equal(dbscan_result_count(r), 2);
    assert_true(dbscan_result_searches(r) >= npts);
    for (size_t i = 0; i < npts; i++)
        assert_int_equal(labels[i], (int32_t)(i % 2));
    dbscan_result_free(r);
}

/* Bytes in use in the heap (glibc), to see that a failed run leaks nothing.
 * glibc's per-thread cache keeps freed chunks counted as in use, so main()
 * turns it off; if it could not, this returns 0 and LeakSanitizer (ASan
 * builds) and valgrind remain the leak checks, as under ASan where mallinfo2
 * reads 0 anyway. */
static int heap_exact;

static size_t heap_in_use(void)
{
    if (!heap_exact)
        return 0;
    struct mallinfo2 mi = mallinfo2();
    return mi.uordblks + mi.hblkhd;
}

static void test_allocation_failure(void **state)
{
    (void)state;
    make_mixed(11, 1500);
    dbscan_params p = {.eps = 0.3, .min_points = 6, .min_users = 3, .threads = 1};
    static int32_t want[MAXP];
    dbscan_result *r = NULL;
    assert_int_equal(dbscan_run(pts, users, npts, &p, want, &r), 0);
    size_t want_count = dbscan_result_count(r);
    dbscan_result_free(r);
    long k;
    for (k = 0; k < 10000; k++) {
        /* Twice per k: the first run may leave one-time library state behind
         * (glibc, FLANN); a leak of ours shows on the second run as well. */
        size_t before = 0;
        int rc = 0;
        for (int pass = 0; pass < 2; pass++) {
            before = heap_in_use();
            cvre_alloc_fail_after(k);
            r = (dbscan_result *)&r;
            rc = dbscan_run(pts, users, npts, &p, labels, &r);
            cvre_alloc_fail_after(-1);
            if (rc == 0)
                break;
            assert_int_equal(rc, -ENOMEM);
            assert_null(r);
        }
        if (rc == 0) {
            assert_int_equal(dbscan_result_count(r), want_count);
            assert_memory_equal(labels, want, npts * sizeof *labels);
            dbscan_result_free(r);
            break;
        }
        assert_int_equal(heap_in_use(), before);
    }
    assert_true(k > 20); /* every allocation of the run was failed once */
    assert_true(k < 10000);
}

#define NO_TCACHE "glibc.malloc.tcache_count=0"

int main(int argc, char **argv)
{
    (void)argc;
    const char *tun = getenv("GLIBC_TUNABLES");
    if (!tun) {
        setenv("GLIBC_TUNABLES", NO_TCACHE, 1);
        execv("/proc/self/exe", argv); /* returns only on failure */
    }
    heap_exact = tun && strstr(tun, NO_TCACHE) != NULL;
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup(test_chain_at_exactly_eps, setup),
        cmocka_unit_test_setup(test_border_between_two_clusters, setup),
        cmocka_unit_test_setup(test_min_points_one_makes_every_point_core, setup),
        cmocka_unit_test_setup(test_min_users, setup),
        cmocka_unit_test_setup(test_duplicates, setup),
        cmocka_unit_test_setup(test_no_points, setup),
        cmocka_unit_test_setup(test_bad_params, setup),
        cmocka_unit_test_setup(test_threads_agree, setup),
        cmocka_unit_test_setup(test_without_grid, setup),
        cmocka_unit_test_setup(test_allocation_failure, setup),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
