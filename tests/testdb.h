/*
 * testdb.h: the database files of tests and benchmarks (header only).
 */
#ifndef CVRE_TESTDB_H
#define CVRE_TESTDB_H

#include <stdint.h>
#include <stdio.h>
#include <unistd.h>

/* Removes a database file and its WAL and shared-memory side files. */
static inline void testdb_remove(const char *path)
{
    char side[4200];
    unlink(path);
    snprintf(side, sizeof side, "%s-wal", path);
    unlink(side);
    snprintf(side, sizeof side, "%s-shm", path);
    unlink(side);
}

#ifdef cmocka_unit_test
#include <sqlite3.h>

/* The one integer a query answers (unit tests: asserts it does). */
static inline int64_t testdb_scalar(sqlite3 *s, const char *sql)
{
    sqlite3_stmt *st;
    assert_int_equal(sqlite3_prepare_v2(s, sql, -1, &st, NULL), SQLITE_OK);
    assert_int_equal(sqlite3_step(st), SQLITE_ROW);
    int64_t v = sqlite3_column_int64(st, 0);
    sqlite3_finalize(st);
    return v;
}
#endif

#if defined(cmocka_unit_test) && defined(CVRE_DB_H) && defined(TESTDB_NAME)
/* A unit test's one database file, /tmp/cvre-test-TESTDB_NAME-PID.sqlite,
 * made anew by testdb_setup and removed by testdb_teardown (cmocka's setup
 * and teardown of each test); testdb_open opens it read-write or fails the
 * test. */
static char testdb_path[64];

static inline int testdb_setup(void **state)
{
    (void)state;
    snprintf(testdb_path, sizeof testdb_path, "/tmp/cvre-test-%s-%d.sqlite", TESTDB_NAME, (int)getpid());
    testdb_remove(testdb_path);
    return 0;
}

static inline int testdb_teardown(void **state)
{
    (void)state;
    testdb_remove(testdb_path);
    return 0;
}

static inline db *testdb_open(void)
{
    char err[256];
    db *d = db_open(testdb_path, DB_READWRITE, err, sizeof err);
    if (!d)
        fail_msg("%s", err);
    return d;
}
#endif

#endif
