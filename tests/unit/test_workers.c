/*
 * The server's worker modules around their lives: the login checker
 * (auth.c), the importer (importer.c) and the refiner (refiner.c) refuse
 * to start on a database they cannot open or without their thread (a
 * worker without an eventfd: test_core_limits); the first two refuse jobs past their queue; and at stop
 * they drop the jobs still waiting and the results never taken (freeing
 * what they hold: the sanitizer build's leak check is the judge).
 */
#define _GNU_SOURCE /* pthread_setattr_default_np */
#include <errno.h>
#include <limits.h>
#include <poll.h>
#include <pthread.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cmocka.h>

#include "auth.h"
#include "db.h"
#include "ecm.h"
#include "importer.h"
#include "refiner.h"
#define TESTDB_NAME "workers"
#include "../testdb.h"

/* Runs start() with every new thread's stack unmappable: the worker's
 * thread cannot start. */
static void *without_threads(void *(*start)(void *), void *arg)
{
    pthread_attr_t huge, saved;
    void *r;

    assert_int_equal(pthread_getattr_default_np(&saved), 0);
    assert_int_equal(pthread_attr_init(&huge), 0);
    assert_int_equal(pthread_attr_setstacksize(&huge, (size_t)1 << 50), 0);
    assert_int_equal(pthread_setattr_default_np(&huge), 0);
    r = start(arg);
    assert_int_equal(pthread_setattr_default_np(&saved), 0);
    pthread_attr_destroy(&huge);
    pthread_attr_destroy(&saved);
    return r;
}

static char err[512];

static void *start_auth(void *path) { return auth_start(path, err, sizeof err); }

static void test_auth_start_and_stop(void **state)
{
    auth *a;
    auth_job job = {.session = 1, .name = "nobody", .credential = PROTO_CRED_PASSWORD, .secret = "pw",
                    .secret_len = 2};
    unsigned n = 0;

    (void)state;
    assert_null(auth_start("/nonexistent/dir/cvre.db", err, sizeof err));
    assert_non_null(strstr(err, "/nonexistent/dir/cvre.db"));
    assert_null(without_threads(start_auth, testdb_path));
    assert_non_null(strstr(err, "cannot start a worker thread"));

    a = auth_start(testdb_path, err, sizeof err);
    assert_non_null(a);
    /* password checks (an Argon2id hash each) queue up far faster than
     * they are done: the queue fills, and the next is refused */
    while (auth_submit(a, &job) == 0) {
        job.secret_len = 2;
        memcpy(job.secret, "pw", 2);
        n++;
        assert_true(n <= AUTH_QUEUE_MAX + 1);
    }
    assert_true(n >= AUTH_QUEUE_MAX); /* the worker took one or two meanwhile */
    auth_stop(a); /* the rest are dropped, their secrets wiped */
    auth_stop(NULL);
}

/* A helper that takes its time over every model and then refuses it. */
static char helper_path[PATH_MAX];

static void slow_helper(void)
{
    FILE *f;

    snprintf(helper_path, sizeof helper_path, "%s.helper", testdb_path);
    f = fopen(helper_path, "w");
    assert_non_null(f);
    fputs("#!/bin/sh\n/bin/cat > /dev/null\n/bin/sleep 0.1\n"
          "printf 'CVRA\\001\\000\\000\\000\\352\\377\\377\\377\\004\\000slow'\n", f);
    assert_int_equal(fclose(f), 0);
    assert_int_equal(chmod(helper_path, 0700), 0);
}

static import_proc proc = {helper_path, 256, 5};
static const importer_limits limits = {1000, 10, 1 << 20, {{-500, 0, -500}, {500, 256, 500}, 512}};

static void *start_importer(void *path) { return importer_start(path, &proc, &limits, err, sizeof err); }

static import_job job_of(uint32_t upload)
{
    import_job j = {.session = 1, .upload_id = upload, .owner = "ann", .name = "m", .format = "stl",
                    .unit_scale = 1, .at = {.scale = 1}, .len = 8};
    j.data = malloc(j.len);
    assert_non_null(j.data);
    memcpy(j.data, "solid x\n", 8);
    return j;
}

static void test_importer_start_and_stop(void **state)
{
    importer *im;
    import_job j;
    import_result r;
    struct pollfd pf;
    unsigned n = 0;

    (void)state;
    slow_helper();
    assert_null(importer_start("/nonexistent/dir/cvre.db", &proc, &limits, err, sizeof err));
    assert_non_null(strstr(err, "/nonexistent/dir/cvre.db"));
    assert_null(without_threads(start_importer, testdb_path));
    assert_non_null(strstr(err, "cannot start a worker thread"));

    /* a result never taken is freed at stop */
    im = importer_start(testdb_path, &proc, &limits, err, sizeof err);
    assert_non_null(im);
    j = job_of(1);
    assert_int_equal(importer_submit(im, &j), 0);
    assert_null(j.data); /* the importer's now */
    pf = (struct pollfd){.fd = importer_fd(im), .events = POLLIN};
    assert_int_equal(poll(&pf, 1, 60000), 1);
    importer_stop(im);

    /* a full queue refuses (and frees the data); the waiting jobs are
     * dropped at stop */
    im = importer_start(testdb_path, &proc, &limits, err, sizeof err);
    assert_non_null(im);
    for (;;) {
        j = job_of(n + 2);
        int rc = importer_submit(im, &j);
        assert_null(j.data);
        if (rc != 0) {
            assert_int_equal(rc, -EBUSY);
            break;
        }
        n++;
        assert_true(n < 100);
    }
    assert_true(n >= 8); /* IMPORTER_QUEUE_MAX: the worker may hold one more */
    while (importer_take(im, &r) == 0) /* the slow helper: none or one so far */
        importer_result_free(&r);
    importer_stop(im);
    importer_stop(NULL);
    unlink(helper_path);
}

static refiner_config rcfg;

static void *start_refiner(void *cfg) { return refiner_start(cfg, err, sizeof err); }

static void test_refiner_start_and_stop(void **state)
{
    static const float tri[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0}, box[1][6] = {{0, 0, 0, 1, 1, 1}};
    db_object o = {.owner = "ann", .name = "m", .format = "stl", .scale = 1, .tri_count = 1, .tris = tri,
                   .max = {1, 1, 0}, .box_count = 1, .boxes = box};
    db_ecm_change ch = {.parent_version = 1, .reason = "refine", .box_count = 1, .boxes = box};
    struct pollfd pf;
    uint32_t version;
    refiner *r;
    db *d;

    (void)state;
    rcfg.db_path = "/nonexistent/dir/cvre.db";
    ecm_params_default(&rcfg.ecm);
    assert_null(refiner_start(&rcfg, err, sizeof err));
    assert_non_null(strstr(err, "/nonexistent/dir/cvre.db"));
    rcfg.db_path = testdb_path;
    assert_null(without_threads(start_refiner, &rcfg));
    assert_non_null(strstr(err, "cannot start a worker thread"));

    /* a new collision map in the change feed, never taken: freed at stop */
    d = testdb_open();
    assert_int_equal(db_object_create(d, &o, 1), 0);
    ch.object_id = o.id;
    assert_int_equal(db_ecm_write(d, &ch, 2, &version), 0);
    db_close(d);
    r = refiner_start(&rcfg, err, sizeof err);
    assert_non_null(r);
    pf = (struct pollfd){.fd = refiner_fd(r), .events = POLLIN};
    assert_int_equal(poll(&pf, 1, 60000), 1);
    refiner_stop(r);
    refiner_stop(NULL);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_auth_start_and_stop, testdb_setup, testdb_teardown),
        cmocka_unit_test_setup_teardown(test_importer_start_and_stop, testdb_setup, testdb_teardown),
        cmocka_unit_test_setup_teardown(test_refiner_start_and_stop, testdb_setup, testdb_teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
