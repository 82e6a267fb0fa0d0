/* The store: migrations, session records, stale sessions after a crash, and
 * the schema-version checks that guard read-only opens. */
#include <errno.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "../testdb.h"
#include "db.h"

static char path[64];

static int64_t scalar(db *d, const char *sql)
{
    return testdb_scalar(db_sqlite(d), sql);
}

static int setup(void **state)
{
    (void)state;
    snprintf(path, sizeof path, "/tmp/cvre-test-db-%d.sqlite", (int)getpid());
    unlink(path);
    return 0;
}

static int teardown(void **state)
{
    (void)state;
    testdb_remove(path);
    return 0;
}

static void test_sessions_round_trip(void **state)
{
    (void)state;
    char err[256];
    db *d = db_open(path, DB_READWRITE, err, sizeof err);
    assert_non_null(d);
    assert_int_equal(scalar(d, "PRAGMA user_version"), db_schema_version());
    assert_int_equal(db_session_last_id(d), 0);
    assert_int_equal(db_begin(d), 0);
    assert_int_equal(db_session_open(d, 1, "00ff", "127.0.0.1:1", 100.0), 0);
    assert_int_equal(db_session_open(d, 2, "11ee", "127.0.0.1:2", 101.0), 0);
    int64_t uid1, uid2;
    assert_int_equal(db_session_join(d, 1, "alice", 65536, 100.5, &uid1), 0);
    assert_int_equal(db_session_join(d, 2, "alice", 65537, 101.5, &uid2), 0); /* same user again */
    assert_true(uid1 == 1 && uid2 == 1);
    assert_int_equal(db_session_close(d, 1, "quit", 102.0), 0);
    assert_int_equal(db_commit(d), 0);
    assert_int_equal(scalar(d, "SELECT count(*) FROM users"), 1);
    assert_int_equal(scalar(d, "SELECT count(*) FROM sessions WHERE user_id = 1"), 2);
    assert_int_equal(scalar(d, "SELECT last_seen_at FROM users WHERE name = 'alice'"), 101);
    db_close(d); /* session 2 is left open, as by a crash */

    d = db_open(path, DB_READWRITE, err, sizeof err);
    assert_non_null(d);
    assert_int_equal(db_session_last_id(d), 2);
    assert_int_equal(db_sessions_close_stale(d, 200.0), 1);
    assert_int_equal(scalar(d, "SELECT count(*) FROM sessions WHERE end_reason = 'crashed'"), 1);
    assert_int_equal(scalar(d, "SELECT count(*) FROM sessions WHERE end_reason = 'quit'"), 1);
    /* Duplicate ids are refused, with a message. */
    assert_int_equal(db_session_open(d, 2, "x", "y", 1.0), -EEXIST);
    assert_non_null(strstr(db_error(d), "UNIQUE"));
    db_close(d);

    d = db_open(path, DB_READONLY, err, sizeof err);
    assert_non_null(d);
    db_close(d);
}

static void test_version_checks(void **state)
{
    (void)state;
    char err[256];
    /* A file of another program: read-only open refuses it by version. */
    sqlite3 *raw;
    assert_int_equal(sqlite3_open(path, &raw), SQLITE_OK);
    assert_int_equal(sqlite3_exec(raw, "CREATE TABLE t(x)", NULL, NULL, NULL), SQLITE_OK);
    sqlite3_close(raw);
    assert_null(db_open(path, DB_READONLY, err, sizeof err));
    assert_non_null(strstr(err, "schema version 0"));
    /* A newer schema than this build knows is refused, not downgraded. */
    assert_int_equal(sqlite3_open(path, &raw), SQLITE_OK);
    assert_int_equal(sqlite3_exec(raw, "PRAGMA user_version = 999", NULL, NULL, NULL), SQLITE_OK);
    sqlite3_close(raw);
    assert_null(db_open(path, DB_READWRITE, err, sizeof err));
    assert_non_null(strstr(err, "newer"));
    /* A missing file cannot be opened read-only. */
    assert_null(db_open("/nonexistent/dir/x.db", DB_READONLY, err, sizeof err));
    assert_non_null(strstr(err, "cannot open"));
}

/* SQLite's result codes as the store's callers see them (db_errno). */
static void test_errno_mapping(void **state)
{
    (void)state;
    static const struct {
        int code, sys, want;
    } cases[] = {
        {SQLITE_BUSY, 0, -EBUSY},
        {SQLITE_BUSY_SNAPSHOT, 0, -EBUSY},
        {SQLITE_LOCKED, 0, -EBUSY},
        {SQLITE_FULL, 0, -ENOSPC},
        {SQLITE_NOMEM, 0, -ENOMEM},
        {SQLITE_READONLY, 0, -EROFS},
        {SQLITE_READONLY_DBMOVED, 0, -EROFS},
        {SQLITE_CONSTRAINT_UNIQUE, 0, -EEXIST},
        {SQLITE_CONSTRAINT_PRIMARYKEY, 0, -EEXIST},
        {SQLITE_CONSTRAINT_CHECK, 0, -EINVAL},
        {SQLITE_CONSTRAINT_TRIGGER, 0, -EINVAL},
        {SQLITE_CANTOPEN, ENOENT, -ENOENT},
        {SQLITE_CANTOPEN, EACCES, -EACCES},
        {SQLITE_CANTOPEN, EPERM, -EACCES},
        {SQLITE_CANTOPEN, 0, -EIO},
        {SQLITE_INTERRUPT, 0, -EINTR},
        {SQLITE_MISUSE, 0, -EINVAL},
        {SQLITE_TOOBIG, 0, -E2BIG},
        {SQLITE_IOERR_WRITE, ENOSPC, -EIO},
        {SQLITE_CORRUPT, 0, -EIO},
        {SQLITE_NOTADB, 0, -EIO},
        {SQLITE_ERROR, 0, -EIO},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++)
        if (db_errno(cases[i].code, cases[i].sys) != cases[i].want)
            fail_msg("SQLite code %d (errno %d): %d, wanted %d", cases[i].code, cases[i].sys,
                     db_errno(cases[i].code, cases[i].sys), cases[i].want);
    /* A connection's last failure, through the same table. */
    char err[256];
    db *d = db_open(path, DB_READWRITE, err, sizeof err);
    assert_non_null(d);
    assert_int_not_equal(sqlite3_exec(db_sqlite(d), "INSERT INTO sessions(id) VALUES (NULL, 1)", NULL, NULL, NULL),
                         SQLITE_OK);
    assert_int_equal(db_sqlite_errno(db_sqlite(d)), -EIO); /* a plain SQL error */
    assert_int_equal(db_session_open(d, 1, "00", "p", 1.0), 0);
    assert_int_equal(db_session_open(d, 1, "00", "p", 1.0), -EEXIST);
    assert_int_equal(db_sqlite_errno(db_sqlite(d)), -EEXIST);
    db_close(d);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_errno_mapping, setup, teardown),
        cmocka_unit_test_setup_teardown(test_sessions_round_trip, setup, teardown),
        cmocka_unit_test_setup_teardown(test_version_checks, setup, teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
