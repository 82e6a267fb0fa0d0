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

#endif
