/* Store maintenance (db/maint.h): retention removes exactly the whole
 * buckets before its cutoff with every index entry of theirs, in bounded
 * transactions, leaves a consistent log when interrupted, refuses a recent
 * cutoff, and runs beside the collision log's writer without costing it a
 * failure; a backup is one checked, self-contained snapshot in a new file,
 * never replaces one, and leaves nothing behind when it fails. */
#include <errno.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>
#include <dirent.h>
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "db.h"
#include "dblog.h"
#include "maint.h"
#define TESTDB_NAME "maint"
#include "../testdb.h"

/* Rows are logged from BASE on (2020: far past DB_RETENTION_MIN_AGE_S, and
 * a bucket's start), ROW_GAP s apart (exact in binary): 160 rows a bucket. */
#define BASE 1600000000.0
#define ROW_GAP 0.0625
#define ROWS_PER_BUCKET 160

static sqlite3 *raw(void)
{
    sqlite3 *s;
    assert_int_equal(sqlite3_open_v2(testdb_path, &s, SQLITE_OPEN_READWRITE, NULL), SQLITE_OK);
    sqlite3_busy_timeout(s, 5000);
    return s;
}

static void make_row(dblog_row *r, uint32_t i, double at)
{
    memset(r, 0, sizeof *r);
    r->at = at;
    r->session_id = 1 + i % 9;
    r->user_id = i % 5 == 0 ? 0 : 1 + i % 11; /* 0: unknown, no user entry */
    r->object_id = 1 + i % 4;
    r->avatar_id = i % 9;
    r->ecm_version = 1 + i % 2;
    for (int k = 0; k < 3; k++)
        r->world[k] = r->local[k] = r->avatar[k] = (float)((i * 7 + (uint32_t)k * 13) % 40) - 20.0f;
    r->normal[1] = 1.0f;
}

/* Logs n rows through the real writer, from at0 on, ROW_GAP apart, in
 * batches of batch_rows (so that segments are that long). */
static void log_rows(uint32_t n, double at0, uint32_t batch_rows)
{
    char err[256];
    dblog_config cfg = {.queue_rows = 1u << 16, .batch_rows = batch_rows, .batch_ms = 1000};
    dblog *l = dblog_open(testdb_path, &cfg, err, sizeof err);
    assert_non_null(l);
    dblog_row r;
    for (uint32_t i = 0; i < n; i++) {
        make_row(&r, i, at0 + i * ROW_GAP);
        while (dblog_push(l, &r) != 0)
            usleep(100);
    }
    dblog_stats st;
    assert_int_equal(dblog_stop(l, &st), 0);
    assert_int_equal(st.written, n);
}

static int64_t count(sqlite3 *s, const char *sql, int64_t bucket)
{
    sqlite3_stmt *st;
    assert_int_equal(sqlite3_prepare_v2(s, sql, -1, &st, NULL), SQLITE_OK);
    if (sqlite3_bind_parameter_count(st))
        sqlite3_bind_int64(st, 1, bucket);
    assert_int_equal(sqlite3_step(st), SQLITE_ROW);
    int64_t v = sqlite3_column_int64(st, 0);
    sqlite3_finalize(st);
    return v;
}

/* What queries rely on (db/README.md, "Collision log storage"), as far as
 * retention can break it: every row has its group, cell, user entry and a
 * segment of its bucket; segments hold exactly the rows; no cell or user
 * entry outlives its group. A group without rows is allowed (an interrupted
 * run leaves some). */
static void check_consistent(sqlite3 *s)
{
    assert_int_equal(testdb_scalar(s, "SELECT count(*) FROM collisions c WHERE NOT EXISTS "
                                      "(SELECT 1 FROM collision_groups g WHERE g.g = c.g)"), 0);
    assert_int_equal(testdb_scalar(s, "SELECT count(*) FROM collisions c WHERE NOT EXISTS "
                                      "(SELECT 1 FROM collision_cells r WHERE r.g = c.g)"), 0);
    assert_int_equal(testdb_scalar(s, "SELECT count(*) FROM collisions c WHERE c.user_id IS NOT NULL AND NOT EXISTS "
                                      "(SELECT 1 FROM collision_users u WHERE u.user_id = c.user_id AND u.g = c.g)"), 0);
    assert_int_equal(testdb_scalar(s, "SELECT count(*) FROM collisions c JOIN collision_groups g ON g.g = c.g "
                                      "WHERE NOT EXISTS (SELECT 1 FROM collision_segments s WHERE s.first_id = "
                                      "(SELECT max(first_id) FROM collision_segments WHERE first_id <= c.id) "
                                      "AND c.id <= s.last_id AND s.bucket = g.bucket)"), 0);
    assert_int_equal(testdb_scalar(s, "SELECT coalesce(sum(last_id - first_id + 1), 0) FROM collision_segments"),
                     testdb_scalar(s, "SELECT count(*) FROM collisions"));
    assert_int_equal(testdb_scalar(s, "SELECT count(*) FROM collision_cells r WHERE NOT EXISTS "
                                      "(SELECT 1 FROM collision_groups g WHERE g.g = r.g)"), 0);
    assert_int_equal(testdb_scalar(s, "SELECT count(*) FROM collision_groups g WHERE NOT EXISTS "
                                      "(SELECT 1 FROM collision_cells r WHERE r.g = g.g)"), 0);
    assert_int_equal(testdb_scalar(s, "SELECT count(*) FROM collision_users u WHERE NOT EXISTS "
                                      "(SELECT 1 FROM collision_groups g WHERE g.g = u.g)"), 0);
    assert_int_equal(testdb_scalar(s, "SELECT count(*) FROM pragma_integrity_check WHERE integrity_check != 'ok'"),
                     0);
    assert_int_equal(testdb_scalar(s, "SELECT rtreecheck('collision_cells') = 'ok'"), 1);
}

/* The log's figures of the buckets below cut (or, with keep, of the rest). */
typedef struct figures {
    int64_t rows, groups, users;
} figures;

static figures measure(sqlite3 *s, int64_t cut, int keep)
{
    figures f;
    f.rows = count(s, keep ? "SELECT count(*) FROM collisions c JOIN collision_groups g ON g.g = c.g WHERE g.bucket >= ?1"
                           : "SELECT count(*) FROM collisions c JOIN collision_groups g ON g.g = c.g WHERE g.bucket < ?1",
                   cut);
    f.groups = count(s, keep ? "SELECT count(*) FROM collision_groups WHERE bucket >= ?1"
                             : "SELECT count(*) FROM collision_groups WHERE bucket < ?1",
                     cut);
    f.users = count(s, keep ? "SELECT count(*) FROM collision_users u JOIN collision_groups g ON g.g = u.g WHERE g.bucket >= ?1"
                            : "SELECT count(*) FROM collision_users u JOIN collision_groups g ON g.g = u.g WHERE g.bucket < ?1",
                    cut);
    return f;
}

static const db_retention_config quick = {.txn_ms = 50, .pause_ms = 0, .units_max = 100};

static void test_retention_removes_whole_old_buckets(void **state)
{
    (void)state;
    enum { N = 8000 };
    log_rows(N, BASE, 1000); /* 50 buckets; batches end part way through a bucket */
    sqlite3 *s = raw();
    double before = BASE + 250.3; /* inside a bucket: only the 25 wholly before it go */
    int64_t cut = dblog_bucket(before);
    figures old = measure(s, cut, 0), kept = measure(s, cut, 1);
    int64_t max_id = testdb_scalar(s, "SELECT max(id) FROM collisions");
    int64_t segments = count(s, "SELECT count(*) FROM collision_segments WHERE bucket < ?1", cut);
    assert_int_equal(old.rows, 25 * ROWS_PER_BUCKET);
    assert_int_equal(kept.rows, N - 25 * ROWS_PER_BUCKET);
    assert_true(old.users > 0 && segments >= 25);

    db *d = testdb_open();
    db_retention_stats st;
    assert_int_equal(db_retention(d, before, &quick, &st), 0);
    assert_true(st.cutoff == (double)cut * DBLOG_BUCKET_S && st.cutoff <= before && st.cutoff > before - 10);
    assert_int_equal(st.collisions, old.rows);
    assert_int_equal(st.groups, old.groups);
    assert_int_equal(st.cells, old.groups);
    assert_int_equal(st.user_entries, old.users);
    assert_int_equal(st.segments, segments);
    /* 100 rows at most per transaction (a group's entries may overshoot by one group). */
    assert_true(st.transactions >= old.rows / 100);
    assert_true(st.longest_ms > 0);

    assert_int_equal(testdb_scalar(s, "SELECT count(*) FROM collisions WHERE at < 1600000250"), 0);
    assert_int_equal(testdb_scalar(s, "SELECT min(at) FROM collisions"), 1600000250);
    figures after = measure(s, cut, 1);
    assert_int_equal(after.rows, kept.rows);
    assert_int_equal(after.groups, kept.groups);
    assert_int_equal(after.users, kept.users);
    assert_int_equal(testdb_scalar(s, "SELECT count(*) FROM collisions"), kept.rows);
    assert_int_equal(testdb_scalar(s, "SELECT max(id) FROM collisions"), max_id);
    check_consistent(s);

    /* Again: nothing left to do, one empty transaction. */
    assert_int_equal(db_retention(d, before, &quick, &st), 0);
    assert_int_equal(st.collisions + st.groups + st.user_entries + st.segments, 0);
    assert_int_equal(st.transactions, 1);
    db_close(d);
    sqlite3_close(s);
}

/* A segment longer than the budget is removed in parts; between two parts
 * it starts at its first remaining row. */
static void test_retention_splits_long_segments(void **state)
{
    (void)state;
    log_rows(400, BASE, 4000); /* one batch: segments of 160, 160 and 80 rows */
    sqlite3 *s = raw();
    int64_t first = testdb_scalar(s, "SELECT min(first_id) FROM collision_segments");
    assert_int_equal(testdb_scalar(s, "SELECT count(*) FROM collision_segments"), 3);
    /* The run stops (its transaction rolls back) when it reaches the 150th
     * row: the first transaction, 96 rows, stays committed. */
    char sql[256];
    snprintf(sql, sizeof sql,
             "CREATE TRIGGER stop BEFORE DELETE ON collisions WHEN old.id = %lld "
             "BEGIN SELECT RAISE(ABORT, 'interrupted'); END",
             (long long)first + 149);
    assert_int_equal(sqlite3_exec(s, sql, NULL, NULL, NULL), SQLITE_OK);
    db *d = testdb_open();
    db_retention_stats st;
    db_retention_config one = {.txn_ms = 1000, .pause_ms = 0, .units_max = 96};
    double before = BASE + 25; /* the first two buckets */
    assert_int_equal(db_retention(d, before, &one, &st), -EINVAL); /* RAISE(ABORT): a constraint */
    assert_non_null(strstr(db_error(d), "interrupted"));
    assert_int_equal(st.transactions, 1);
    assert_int_equal(st.collisions, 96);
    assert_int_equal(st.segments, 0);
    assert_int_equal(testdb_scalar(s, "SELECT min(first_id) FROM collision_segments"), first + 96);
    check_consistent(s);
    assert_int_equal(sqlite3_exec(s, "DROP TRIGGER stop", NULL, NULL, NULL), SQLITE_OK);
    assert_int_equal(db_retention(d, before, &one, &st), 0);
    assert_int_equal(st.collisions, 2 * ROWS_PER_BUCKET - 96);
    assert_int_equal(st.segments, 2);
    assert_int_equal(measure(s, dblog_bucket(before), 0).groups, 0);
    assert_int_equal(testdb_scalar(s, "SELECT count(*) FROM collisions"), 400 - 2 * ROWS_PER_BUCKET);
    check_consistent(s);
    db_close(d);
    sqlite3_close(s);
}

/* Interrupted while removing groups: what was committed is consistent, and
 * the next run finishes the job. */
static void test_retention_interrupted_among_groups(void **state)
{
    (void)state;
    log_rows(4000, BASE, 500);
    sqlite3 *s = raw();
    double before = BASE + 100;
    int64_t cut = dblog_bucket(before);
    figures old = measure(s, cut, 0), kept = measure(s, cut, 1);
    /* The 61st group stops the run: the 60 before it cost at least 120 of
     * the 100 units a transaction has, so no row is removed in the same
     * transaction as it, and every row went before. */
    assert_true(old.groups > 61);
    sqlite3_stmt *q;
    assert_int_equal(sqlite3_prepare_v2(s, "SELECT g FROM collision_groups WHERE bucket < ?1 ORDER BY bucket, g LIMIT 1 "
                                           "OFFSET 60", -1, &q, NULL), SQLITE_OK);
    sqlite3_bind_int64(q, 1, cut);
    assert_int_equal(sqlite3_step(q), SQLITE_ROW);
    char sql[256];
    snprintf(sql, sizeof sql,
             "CREATE TRIGGER stop BEFORE DELETE ON collision_groups WHEN old.g = %lld "
             "BEGIN SELECT RAISE(ABORT, 'interrupted'); END",
             (long long)sqlite3_column_int64(q, 0));
    sqlite3_finalize(q);
    assert_int_equal(sqlite3_exec(s, sql, NULL, NULL, NULL), SQLITE_OK);
    db *d = testdb_open();
    db_retention_stats st, st2;
    assert_int_equal(db_retention(d, before, &quick, &st), -EINVAL);
    assert_int_equal(st.collisions, old.rows);
    assert_true(st.groups <= 60); /* those before the 61st, at most */
    check_consistent(s);
    assert_int_equal(sqlite3_exec(s, "DROP TRIGGER stop", NULL, NULL, NULL), SQLITE_OK);
    assert_int_equal(db_retention(d, before, &quick, &st2), 0);
    assert_int_equal(st2.collisions, 0);
    assert_int_equal(st.groups + st2.groups, old.groups);
    assert_int_equal(st.user_entries + st2.user_entries, old.users);
    figures after = measure(s, cut, 1);
    assert_memory_equal(&after, &kept, sizeof kept);
    assert_int_equal(measure(s, cut, 0).groups, 0);
    check_consistent(s);
    db_close(d);
    sqlite3_close(s);
}

static void test_retention_refusals(void **state)
{
    (void)state;
    log_rows(10, BASE, 10);
    db *d = testdb_open();
    db_retention_stats st;
    assert_int_equal(db_retention(d, db_now(), NULL, &st), -ERANGE);
    assert_non_null(strstr(db_error(d), "in the past"));
    assert_int_equal(db_retention(d, db_now() - DB_RETENTION_MIN_AGE_S + 60, NULL, &st), -ERANGE);
    assert_int_equal(db_retention(d, NAN, NULL, &st), -ERANGE);
    assert_int_equal(db_retention(d, INFINITY, NULL, &st), -ERANGE);
    db_retention_config bad = {.txn_ms = 50, .pause_ms = 0, .units_max = 0};
    assert_int_equal(db_retention(d, BASE + 100, &bad, &st), -EINVAL);
    bad = (db_retention_config){.txn_ms = 0, .pause_ms = 0, .units_max = 100};
    assert_int_equal(db_retention(d, BASE + 100, &bad, &st), -EINVAL);
    assert_int_equal(testdb_scalar(db_sqlite(d), "SELECT count(*) FROM collisions"), 10);
    /* Another connection holding the write lock past the busy timeout:
     * an error that says so, nothing removed. */
    sqlite3 *w = raw();
    assert_int_equal(sqlite3_exec(w, "BEGIN IMMEDIATE", NULL, NULL, NULL), SQLITE_OK);
    db_set_busy_timeout(d, 20);
    assert_int_equal(db_retention(d, BASE + 100, NULL, &st), -EBUSY);
    assert_true(db_busy(d));
    assert_int_equal(st.transactions, 0);
    assert_int_equal(sqlite3_exec(w, "ROLLBACK", NULL, NULL, NULL), SQLITE_OK);
    sqlite3_close(w);
    /* Before any bucket: nothing to remove. */
    assert_int_equal(db_retention(d, BASE - 3600, NULL, &st), 0);
    assert_int_equal(st.collisions, 0);
    db_close(d);
}

/* ---- beside the log's writer -------------------------------------------- */

struct side_run {
    db_retention_stats st;
    int rc;
    atomic_int done;
    char err[256];
};

static void *retention_thread(void *arg)
{
    struct side_run *r = arg;
    char err[256];
    db *d = db_open(testdb_path, DB_READWRITE, err, sizeof err);
    if (!d) {
        snprintf(r->err, sizeof r->err, "%s", err);
        r->rc = -1;
    } else {
        r->rc = db_retention(d, BASE + 1e5, NULL, &r->st); /* the defaults: 50 ms transactions, pauses */
        snprintf(r->err, sizeof r->err, "%s", db_error(d));
        db_close(d);
    }
    atomic_store(&r->done, 1);
    return NULL;
}

static void test_retention_beside_the_writer(void **state)
{
    (void)state;
    enum { OLD = 30000 };
    log_rows(OLD, BASE, 16384);
    char err[256];
    dblog_config cfg = {.queue_rows = 1u << 16, .batch_ms = 20};
    dblog *l = dblog_open(testdb_path, &cfg, err, sizeof err);
    assert_non_null(l);
    struct side_run run = {0};
    pthread_t t;
    assert_int_equal(pthread_create(&t, NULL, retention_thread, &run), 0);
    /* New rows, about 20,000 a second (a thousand avatars pressing on
     * walls at 20 Hz), while retention runs (30 s at most). */
    dblog_row r;
    for (uint32_t n = 0; n < 600000 && !atomic_load(&run.done); n++) {
        make_row(&r, n, db_now());
        dblog_push(l, &r);
        if (n % 200 == 199)
            usleep(10000);
    }
    pthread_join(t, NULL);
    dblog_stats st;
    assert_int_equal(dblog_stop(l, &st), 0);
    if (run.rc != 0)
        fail_msg("retention: %s", run.err);
    assert_int_equal(run.st.collisions, OLD);
    assert_true(run.st.transactions > 1);
    assert_int_equal(st.failures, 0); /* the writer never gave up waiting for the lock */
    assert_int_equal(st.written, st.pushed - st.dropped);
    assert_true(st.written > 0);
    sqlite3 *s = raw();
    assert_int_equal(testdb_scalar(s, "SELECT count(*) FROM collisions"), (int64_t)st.written);
    check_consistent(s);
    sqlite3_close(s);
}

/* ---- backup ------------------------------------------------------------- */

static char dir[64];

static int backup_setup(void **state)
{
    testdb_setup(state);
    snprintf(dir, sizeof dir, "/tmp/cvre-test-maint-%d.d", (int)getpid());
    mkdir(dir, 0700);
    return 0;
}

/* Removes dir and what is in it; fails the test if a partial copy is left. */
static int backup_teardown(void **state)
{
    DIR *dd = opendir(dir);
    struct dirent *e;
    char p[400];
    int partial = 0;
    while (dd && (e = readdir(dd)) != NULL) {
        if (e->d_name[0] == '.')
            continue;
        partial |= strstr(e->d_name, ".partial-") != NULL;
        snprintf(p, sizeof p, "%s/%s", dir, e->d_name);
        unlink(p);
    }
    if (dd)
        closedir(dd);
    rmdir(dir);
    testdb_teardown(state);
    return partial ? -1 : 0;
}

static sqlite3 *open_copy(const char *path)
{
    sqlite3 *c;
    assert_int_equal(sqlite3_open_v2(path, &c, SQLITE_OPEN_READONLY, NULL), SQLITE_OK);
    return c;
}

static db *open_readonly(void)
{
    char err[256];
    db *d = db_open(testdb_path, DB_READONLY, err, sizeof err);
    assert_non_null(d);
    return d;
}

static void check_copy(const char *path, int64_t rows, int64_t sessions)
{
    sqlite3 *c = open_copy(path);
    assert_int_equal(testdb_scalar(c, "SELECT count(*) FROM collisions"), rows);
    assert_int_equal(testdb_scalar(c, "SELECT count(*) FROM sessions"), sessions);
    assert_int_equal(testdb_scalar(c, "PRAGMA user_version"), db_schema_version());
    sqlite3_stmt *st;
    assert_int_equal(sqlite3_prepare_v2(c, "PRAGMA journal_mode", -1, &st, NULL), SQLITE_OK);
    assert_int_equal(sqlite3_step(st), SQLITE_ROW);
    assert_string_equal((const char *)sqlite3_column_text(st, 0), "delete"); /* one file, no -wal */
    sqlite3_finalize(st);
    assert_int_equal(testdb_scalar(c, "SELECT count(*) FROM pragma_integrity_check WHERE integrity_check != 'ok'"),
                     0);
    sqlite3_close(c);
    struct stat sb;
    assert_int_equal(stat(path, &sb), 0);
    assert_int_equal(sb.st_mode & 077, 0); /* the owner's only: it holds password hashes */
}

static void test_backup_copies_and_checks(void **state)
{
    (void)state;
    log_rows(3000, BASE, 500);
    db *rw = testdb_open();
    assert_int_equal(db_session_open(rw, 1, "00", "127.0.0.1:1", BASE), 0);
    db_close(rw);
    db *d = open_readonly();
    assert_int_equal(sqlite3_exec(db_sqlite(d), "PRAGMA query_only = 1", NULL, NULL, NULL), SQLITE_OK);
    char a[128], b[128];
    snprintf(a, sizeof a, "%s/pages.db", dir);
    snprintf(b, sizeof b, "%s/vacuum.db", dir);
    db_backup_stats st;
    assert_int_equal(db_backup(d, a, 0, &st), 0);
    assert_int_equal(st.schema, db_schema_version());
    assert_true(st.pages > 0 && st.bytes > 0 && st.seconds >= 0);
    struct stat sb;
    assert_int_equal(stat(a, &sb), 0);
    assert_int_equal(sb.st_size, st.bytes);
    check_copy(a, 3000, 1);
    db_backup_stats v;
    if (db_backup(d, b, 1, &v) != 0)
        fail_msg("%s", db_error(d));
    check_copy(b, 3000, 1);

    /* Never over an existing file: it stays as it was. */
    FILE *f = fopen(a, "w");
    fputs("precious", f);
    fclose(f);
    assert_int_equal(db_backup(d, a, 0, &st), -EEXIST);
    assert_non_null(strstr(db_error(d), "exists"));
    assert_int_equal(db_backup(d, b, 1, &st), -EEXIST);
    char text[16] = "";
    f = fopen(a, "r");
    assert_non_null(fgets(text, sizeof text, f));
    fclose(f);
    assert_string_equal(text, "precious");

    /* A directory that does not exist; an empty name. */
    char c[160];
    snprintf(c, sizeof c, "%s/missing/copy.db", dir);
    assert_int_equal(db_backup(d, c, 0, &st), -ENOENT);
    assert_non_null(strstr(db_error(d), "cannot write beside"));
    assert_int_equal(db_backup(d, "", 0, &st), -EINVAL);
    db_close(d);
}

/* The copy is the snapshot of when it began: a transaction another
 * connection has not committed is not in it. */
static void test_backup_is_one_snapshot(void **state)
{
    (void)state;
    db *rw = testdb_open();
    assert_int_equal(db_session_open(rw, 1, "00", "127.0.0.1:1", BASE), 0);
    db_close(rw);
    sqlite3 *w = raw();
    assert_int_equal(sqlite3_exec(w,
                                  "BEGIN IMMEDIATE; INSERT INTO sessions(id, token, peer, started_at) "
                                  "VALUES (2, '00', 'x', 1)",
                                  NULL, NULL, NULL),
                     SQLITE_OK);
    db *d = open_readonly();
    char a[128];
    snprintf(a, sizeof a, "%s/snap.db", dir);
    db_backup_stats st;
    assert_int_equal(db_backup(d, a, 0, &st), 0);
    assert_int_equal(sqlite3_exec(w, "COMMIT", NULL, NULL, NULL), SQLITE_OK);
    check_copy(a, 0, 1);
    db_close(d);
    sqlite3_close(w);
}

/* A damaged database: the page copy succeeds but fails its check, the
 * compacting copy fails while reading; neither leaves a file behind. */
static void test_backup_of_a_damaged_database(void **state)
{
    (void)state;
    log_rows(3000, BASE, 500);
    sqlite3 *s = raw();
    assert_int_equal(sqlite3_exec(s, "PRAGMA wal_checkpoint(TRUNCATE)", NULL, NULL, NULL), SQLITE_OK);
    int64_t page = testdb_scalar(s, "PRAGMA page_size"), pages = testdb_scalar(s, "PRAGMA page_count");
    sqlite3_close(s);
    /* Scribble over the middle of the file: the collisions' b-tree pages. */
    FILE *f = fopen(testdb_path, "r+b");
    assert_non_null(f);
    char junk[512];
    memset(junk, 0x5a, sizeof junk);
    for (int64_t p = pages / 3; p < pages / 3 + 8; p++) {
        assert_int_equal(fseek(f, (long)(p * page), SEEK_SET), 0);
        assert_int_equal(fwrite(junk, 1, sizeof junk, f), sizeof junk);
    }
    fclose(f);
    db *d = open_readonly();
    char a[128], b[128];
    snprintf(a, sizeof a, "%s/pages.db", dir);
    snprintf(b, sizeof b, "%s/vacuum.db", dir);
    db_backup_stats st;
    assert_int_equal(db_backup(d, a, 0, &st), -EIO);
    assert_non_null(strstr(db_error(d), "integrity_check"));
    assert_int_equal(db_backup(d, b, 1, &st), -EIO);
    assert_non_null(strstr(db_error(d), "VACUUM INTO"));
    assert_int_equal(access(a, F_OK), -1);
    assert_int_equal(access(b, F_OK), -1);
    db_close(d);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_retention_removes_whole_old_buckets, testdb_setup, testdb_teardown),
        cmocka_unit_test_setup_teardown(test_retention_splits_long_segments, testdb_setup, testdb_teardown),
        cmocka_unit_test_setup_teardown(test_retention_interrupted_among_groups, testdb_setup, testdb_teardown),
        cmocka_unit_test_setup_teardown(test_retention_refusals, testdb_setup, testdb_teardown),
        cmocka_unit_test_setup_teardown(test_retention_beside_the_writer, testdb_setup, testdb_teardown),
        cmocka_unit_test_setup_teardown(test_backup_copies_and_checks, backup_setup, backup_teardown),
        cmocka_unit_test_setup_teardown(test_backup_is_one_snapshot, backup_setup, backup_teardown),
        cmocka_unit_test_setup_teardown(test_backup_of_a_damaged_database, backup_setup, backup_teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
