/* The collision log writer: every field round-trips exactly, stop drains the
 * queue, a full queue drops and counts, the groups, cells, user entries and
 * segments describe the table exactly (db/README.md), readers
 * run beside the writer, database errors are counted, not fatal, the
 * committed id never runs ahead of the table, and a database file deleted
 * or renamed under the writer is noticed. Build it once with
 * -fsanitize=thread too: the producer and writer share a ring. */
#include <errno.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include "../testdb.h"
#include "db.h"
#include "dblog.h"
#include "log.h"

static char path[64];

static int setup(void **state)
{
    (void)state;
    snprintf(path, sizeof path, "/tmp/cvre-test-dblog-%d.sqlite", (int)getpid());
    testdb_remove(path);
    return 0;
}

static int teardown(void **state)
{
    (void)state;
    testdb_remove(path);
    return 0;
}

/* A row whose every field depends on i, with values that a float or an
 * int64 must carry exactly (thirds, large ids, negative coordinates). */
static void make_row(dblog_row *r, uint32_t i)
{
    memset(r, 0, sizeof *r);
    r->at = 1795000000.0 + i / 3.0;
    r->session_id = INT64_C(1) << 40 | i;
    r->user_id = i % 7 == 0 ? 0 : (int64_t)(i % 1000) + 1; /* 0: unknown -> NULL */
    r->object_id = INT64_MAX - (i % 50);
    r->avatar_id = 0x10000u | (i & 0xffffu);
    r->ecm_version = 1 + i % 5;
    r->box_index = i % 13;
    r->inside = i % 2;
    for (int k = 0; k < 3; k++) {
        float f = (float)i + (float)k / 3.0f;
        r->avatar[k] = -f;
        r->world[k] = f * 0.5f - 250.0f;
        r->local[k] = f / 7.0f;
        r->normal[k] = k == 1 ? 1.0f : -1.0f / 3.0f;
        r->vel[k] = 1e-3f * f;
    }
}

static sqlite3 *open_ro(void)
{
    sqlite3 *s;
    assert_int_equal(sqlite3_open_v2(path, &s, SQLITE_OPEN_READONLY, NULL), SQLITE_OK);
    sqlite3_busy_timeout(s, 5000);
    return s;
}

/* The layout the queries rely on (db/README.md, "Collision log storage"):
 * every collision is in the group of its object, version, bucket and cell,
 * whose rtree box holds its world point; a known user has an entry for that
 * group; the segments cover the ids exactly, each within one bucket and
 * sorted by (object, version, group). */
static void check_layout(sqlite3 *s, int64_t rows)
{
    sqlite3_stmt *q;
    assert_int_equal(
        sqlite3_prepare_v2(
            s,
            "SELECT c.id, c.at, c.object_id, c.ecm_version, c.g, c.world_x, c.world_y, c.world_z, "
            "gr.object_id, gr.ecm_version, gr.bucket, gr.cell_x, gr.cell_y, gr.cell_z, "
            "r.min_x <= c.world_x AND c.world_x <= r.max_x AND r.min_y <= c.world_y AND c.world_y <= r.max_y "
            "AND r.min_z <= c.world_z AND c.world_z <= r.max_z, "
            "c.user_id IS NULL OR EXISTS (SELECT 1 FROM collision_users u WHERE u.user_id = c.user_id AND u.g = c.g), "
            "s.first_id, s.last_id, s.bucket "
            "FROM collisions c JOIN collision_groups gr ON gr.g = c.g JOIN collision_cells r ON r.g = c.g "
            "JOIN collision_segments s ON s.first_id = "
            "(SELECT max(first_id) FROM collision_segments WHERE first_id <= c.id) ORDER BY c.id",
            -1, &q, NULL),
        SQLITE_OK);
    int64_t n = 0, prev_id = 0, prev_key[3] = {0, 0, 0}, prev_seg = -1;
    while (sqlite3_step(q) == SQLITE_ROW) {
        int64_t id = sqlite3_column_int64(q, 0);
        double at = sqlite3_column_double(q, 1);
        int64_t key[3] = {sqlite3_column_int64(q, 2), sqlite3_column_int64(q, 3), sqlite3_column_int64(q, 4)};
        assert_int_equal(sqlite3_column_int64(q, 8), key[0]);
        assert_int_equal(sqlite3_column_int64(q, 9), key[1]);
        assert_int_equal(sqlite3_column_int64(q, 10), dblog_bucket(at));
        for (int k = 0; k < 3; k++)
            assert_int_equal(sqlite3_column_int64(q, 11 + k), dblog_cell(sqlite3_column_double(q, 5 + k)));
        assert_int_equal(sqlite3_column_int(q, 14), 1);
        assert_int_equal(sqlite3_column_int(q, 15), 1);
        int64_t first = sqlite3_column_int64(q, 16);
        assert_true(id <= sqlite3_column_int64(q, 17));
        assert_int_equal(sqlite3_column_int64(q, 18), dblog_bucket(at));
        if (n > 0)
            assert_int_equal(id, prev_id + 1); /* no gaps */
        if (first == prev_seg) /* sorted within a segment */
            assert_true(prev_key[0] < key[0] || (prev_key[0] == key[0] && (prev_key[1] < key[1] ||
                        (prev_key[1] == key[1] && prev_key[2] <= key[2]))));
        else
            assert_int_equal(first, id); /* a segment starts at its first id */
        prev_seg = first, prev_id = id;
        memcpy(prev_key, key, sizeof key);
        n++;
    }
    sqlite3_finalize(q);
    assert_int_equal(n, rows);
    assert_int_equal(testdb_scalar(s, "SELECT count(*) FROM collisions"), rows);
}

static void test_fields_exact(void **state)
{
    (void)state;
    char err[256];
    enum { N = 5000 };
    dblog_config cfg = {.queue_rows = 1024, .batch_rows = 100, .batch_ms = 5};
    dblog *l = dblog_open(path, &cfg, err, sizeof err);
    assert_non_null(l);
    dblog_row r;
    for (uint32_t i = 0; i < N; i++) {
        make_row(&r, i);
        while (dblog_push(l, &r) != 0) /* a small queue: wait for room */
            usleep(100);
    }
    dblog_stats st;
    assert_int_equal(dblog_stop(l, &st), 0);
    assert_int_equal(st.written, N);
    assert_int_equal(st.pushed, N + st.dropped);
    assert_int_equal(st.lost, 0);
    assert_int_equal(st.last_error, 0);
    assert_true(st.batches >= 2);

    sqlite3 *s = open_ro();
    sqlite3_stmt *q;
    assert_int_equal(sqlite3_prepare_v2(s,
                                        "SELECT at, session_id, user_id, avatar_id, object_id, ecm_version, "
                                        "box_index, inside, avatar_x, avatar_y, avatar_z, world_x, world_y, "
                                        "world_z, local_x, local_y, local_z, normal_x, normal_y, normal_z, vel_x, "
                                        "vel_y, vel_z, typeof(user_id) FROM collisions ORDER BY at",
                                        -1, &q, NULL),
                     SQLITE_OK);
    uint32_t i = 0; /* ids are in sorted order within a batch; times are unique */
    while (sqlite3_step(q) == SQLITE_ROW) {
        make_row(&r, i);
        assert_true(sqlite3_column_double(q, 0) == r.at);
        assert_int_equal(sqlite3_column_int64(q, 1), r.session_id);
        if (r.user_id == 0)
            assert_string_equal((const char *)sqlite3_column_text(q, 23), "null");
        else
            assert_int_equal(sqlite3_column_int64(q, 2), r.user_id);
        assert_int_equal(sqlite3_column_int64(q, 3), r.avatar_id);
        assert_int_equal(sqlite3_column_int64(q, 4), r.object_id);
        assert_int_equal(sqlite3_column_int64(q, 5), r.ecm_version);
        assert_int_equal(sqlite3_column_int64(q, 6), r.box_index);
        assert_int_equal(sqlite3_column_int64(q, 7), r.inside);
        const float *v[5] = {r.avatar, r.world, r.local, r.normal, r.vel};
        for (int k = 0; k < 5; k++)
            for (int c = 0; c < 3; c++)
                assert_true(sqlite3_column_double(q, 8 + 3 * k + c) == (double)v[k][c]);
        i++;
    }
    sqlite3_finalize(q);
    assert_int_equal(i, N);
    check_layout(s, N);
    assert_int_equal(testdb_scalar(s, "SELECT max(id) - min(id) + 1 FROM collisions"), N);
    /* A region query through the rtree's cells, with the exact filter on
     * the rows, finds exactly the rows inside. */
    assert_int_equal(testdb_scalar(s, "SELECT count(*) FROM collision_cells r JOIN collisions c ON c.g = r.g "
                               "WHERE r.min_x <= -100 AND r.max_x >= -200 AND c.world_x BETWEEN -200 AND -100"),
                     testdb_scalar(s, "SELECT count(*) FROM collisions WHERE world_x BETWEEN -200 AND -100"));
    sqlite3_close(s);
}

/* Pushes n rows as fast as one thread can, then stops; returns the stats. */
static dblog_stats flood(const dblog_config *cfg, uint32_t n)
{
    char err[256];
    dblog *l = dblog_open(path, cfg, err, sizeof err);
    assert_non_null(l);
    dblog_row r;
    uint64_t refused = 0;
    for (uint32_t i = 0; i < n; i++) {
        make_row(&r, i);
        int rc = dblog_push(l, &r);
        if (rc != 0) {
            assert_int_equal(rc, -ENOBUFS); /* a full queue, the only refusal of a valid row */
            refused++;
        }
    }
    dblog_stats st;
    assert_int_equal(dblog_stop(l, &st), 0);
    assert_int_equal(st.dropped, refused);
    assert_int_equal(st.pushed, n);
    assert_int_equal(st.written + st.dropped, n);
    assert_int_equal(st.lost, 0);
    assert_int_equal(st.queued, 0);
    assert_true(st.high_water <= (cfg->queue_rows ? cfg->queue_rows : DBLOG_QUEUE_ROWS_DEFAULT));
    sqlite3 *s = open_ro();
    assert_int_equal(testdb_scalar(s, "SELECT count(*) FROM collisions"), st.written);
    check_layout(s, (int64_t)st.written);
    sqlite3_close(s);
    return st;
}

static void test_small_queue_drops_and_counts(void **state)
{
    (void)state;
    dblog_config cfg = {.queue_rows = 256, .batch_rows = 64, .batch_ms = 50};
    dblog_stats st = flood(&cfg, 200000);
    /* The writer cannot keep up with a bare loop through 256 slots. */
    assert_true(st.dropped > 0);
    assert_true(st.written >= 64);
    assert_int_equal(st.high_water, 256);
}

static void test_large_queue_loses_nothing(void **state)
{
    (void)state;
    dblog_config cfg = {0}; /* the defaults: 2^18 slots */
    dblog_stats st = flood(&cfg, 200000);
    assert_int_equal(st.dropped, 0);
    assert_int_equal(st.written, 200000);
}

static void test_invalid_rows_refused(void **state)
{
    (void)state;
    char err[256];
    dblog *l = dblog_open(path, NULL, err, sizeof err);
    assert_non_null(l);
    dblog_row r;
    make_row(&r, 1);
    r.world[1] = NAN;
    assert_int_equal(dblog_push(l, &r), -EINVAL);
    make_row(&r, 2);
    r.vel[2] = INFINITY;
    assert_int_equal(dblog_push(l, &r), -EINVAL);
    make_row(&r, 3);
    assert_int_equal(dblog_push(l, &r), 0);
    dblog_stats st;
    assert_int_equal(dblog_stop(l, &st), 0);
    assert_int_equal(st.invalid, 2);
    assert_int_equal(st.written, 1);
    assert_int_equal(st.pushed, 3);
}

/* A transaction that took longer than batch_ms makes the next ones
 * smaller (a sorted batch cannot be cut part way); the rest follows, and
 * nothing is lost. */
static void test_hold_cap_cuts_batches(void **state)
{
    (void)state;
    char err[256];
    enum { N = 20000 };
    dblog_config cfg = {.queue_rows = 1u << 16, .batch_rows = 16384, .batch_ms = 1};
    dblog *l = dblog_open(path, &cfg, err, sizeof err);
    assert_non_null(l);
    dblog_row r;
    for (uint32_t i = 0; i < N; i++) {
        make_row(&r, i);
        assert_int_equal(dblog_push(l, &r), 0);
    }
    dblog_stats st;
    do { /* all of it before stop, whose last transaction is not capped */
        usleep(1000);
        dblog_stats_get(l, &st);
    } while (st.written < N);
    assert_int_equal(dblog_stop(l, &st), 0);
    assert_int_equal(st.written, N);
    /* A 1 ms cap: the first transaction takes 16384 rows and longer than
     * that, so the ones after it shrink. */
    assert_true(st.batches >= 3);
    sqlite3 *s = open_ro();
    assert_int_equal(testdb_scalar(s, "SELECT count(*) FROM collisions"), N);
    assert_int_equal(testdb_scalar(s, "SELECT max(id) - min(id) + 1 FROM collisions"), N);
    check_layout(s, N);
    sqlite3_close(s);
}

struct reader {
    _Atomic int stop;
    int queries;
    int failures;
    int went_backwards;
};

/* A separate read-only connection queries in a loop while the writer
 * commits; WAL must let every query through without SQLITE_BUSY. */
static void *reader_main(void *arg)
{
    struct reader *rd = arg;
    sqlite3 *s;
    if (sqlite3_open_v2(path, &s, SQLITE_OPEN_READONLY, NULL) != SQLITE_OK) {
        rd->failures++;
        return NULL;
    }
    /* No busy timeout: a reader in WAL mode should never need one. */
    sqlite3_stmt *count, *region;
    if (sqlite3_prepare_v2(s, "SELECT count(*) FROM collisions", -1, &count, NULL) != SQLITE_OK ||
        sqlite3_prepare_v2(s, "SELECT count(*) FROM collision_cells WHERE min_x <= 0 AND max_x >= -100", -1,
                           &region, NULL) != SQLITE_OK) {
        rd->failures++;
        sqlite3_close(s);
        return NULL;
    }
    int64_t last = 0;
    while (!atomic_load(&rd->stop)) {
        int rc = sqlite3_step(count);
        if (rc == SQLITE_ROW) {
            int64_t n = sqlite3_column_int64(count, 0);
            rd->went_backwards += n < last;
            last = n;
        } else {
            rd->failures++;
        }
        sqlite3_reset(count);
        rc = sqlite3_step(region);
        rd->failures += rc != SQLITE_ROW;
        sqlite3_reset(region);
        rd->queries++;
    }
    sqlite3_finalize(count);
    sqlite3_finalize(region);
    sqlite3_close(s);
    return NULL;
}

static void test_reader_beside_writer(void **state)
{
    (void)state;
    char err[256];
    dblog_config cfg = {.queue_rows = 1u << 16, .batch_rows = 512, .batch_ms = 5};
    dblog *l = dblog_open(path, &cfg, err, sizeof err);
    assert_non_null(l);
    struct reader rd = {0};
    pthread_t t;
    assert_int_equal(pthread_create(&t, NULL, reader_main, &rd), 0);
    dblog_row r;
    dblog_stats st;
    /* Rounds of 1000 rows, each waited for, so that at least 60 commits
     * interleave with the reads however slow the build. */
    for (uint32_t i = 0; i < 60000; i++) {
        make_row(&r, i);
        assert_int_equal(dblog_push(l, &r), 0);
        if (i % 1000 == 999)
            do {
                usleep(500);
                dblog_stats_get(l, &st);
            } while (st.written < i + 1);
    }
    assert_int_equal(dblog_stop(l, &st), 0);
    atomic_store(&rd.stop, 1);
    pthread_join(t, NULL);
    assert_int_equal(st.written, 60000);
    assert_true(st.batches >= 60);
    assert_int_equal(rd.failures, 0);
    assert_int_equal(rd.went_backwards, 0);
    assert_true(rd.queries > 10);
}

/* Disk full, simulated with a file size limit: writes past it fail with
 * EFBIG, which SQLite reports as a full disk or an I/O error. Batches are
 * retried, then counted as lost; the writer carries on when space returns,
 * and the database stays intact. */
static void test_disk_full(void **state)
{
    (void)state;
    char err[256];
    int level = log_level();
    log_set_level(LOG_OFF); /* the expected errors would clutter the output */
    /* 100 ms: batches stay at 1000 rows, so the failing ones (each tried
     * DBLOG_ATTEMPTS times, 300 ms apart in all) are few. */
    dblog_config cfg = {.queue_rows = 1u << 16, .batch_rows = 1000, .batch_ms = 100};
    dblog *l = dblog_open(path, &cfg, err, sizeof err);
    assert_non_null(l);
    dblog_row r;
    uint32_t i = 0;
    for (; i < 2000; i++) {
        make_row(&r, i);
        assert_int_equal(dblog_push(l, &r), 0);
    }
    dblog_stats st;
    do {
        usleep(1000);
        dblog_stats_get(l, &st);
    } while (st.written < 2000);

    struct rlimit old, lim;
    struct stat sb;
    char wal[80];
    snprintf(wal, sizeof wal, "%s-wal", path);
    assert_int_equal(stat(wal, &sb), 0);
    assert_int_equal(getrlimit(RLIMIT_FSIZE, &old), 0);
    signal(SIGXFSZ, SIG_IGN);
    lim = old;
    lim.rlim_cur = (rlim_t)sb.st_size + 8192; /* room for a page or so, not a batch */
    assert_int_equal(setrlimit(RLIMIT_FSIZE, &lim), 0);
    for (; i < 6000; i++) {
        make_row(&r, i);
        assert_int_equal(dblog_push(l, &r), 0);
    }
    do {
        usleep(1000);
        dblog_stats_get(l, &st);
    } while (st.written + st.lost < 6000);
    assert_int_equal(setrlimit(RLIMIT_FSIZE, &old), 0);
    assert_true(st.lost > 0);
    assert_true(st.failures >= DBLOG_ATTEMPTS);
    assert_int_not_equal(st.last_error, 0);

    for (; i < 7000; i++) {
        make_row(&r, i);
        assert_int_equal(dblog_push(l, &r), 0);
    }
    assert_int_equal(dblog_stop(l, &st), -EIO); /* rows were lost */
    log_set_level(level);
    signal(SIGXFSZ, SIG_DFL);
    assert_int_equal(st.pushed, 7000);
    assert_int_equal(st.written + st.lost, 7000);
    assert_true(st.written >= 3000); /* before the limit, and after it was lifted */
    assert_int_equal(st.committed_id, st.written); /* ids have no gaps: lost batches took none */

    sqlite3 *s = open_ro();
    assert_int_equal(testdb_scalar(s, "SELECT count(*) FROM collisions"), st.written);
    check_layout(s, (int64_t)st.written);
    sqlite3_stmt *q;
    assert_int_equal(sqlite3_prepare_v2(s, "PRAGMA integrity_check", -1, &q, NULL), SQLITE_OK);
    assert_int_equal(sqlite3_step(q), SQLITE_ROW);
    assert_string_equal((const char *)sqlite3_column_text(q, 0), "ok");
    sqlite3_finalize(q);
    sqlite3_close(s);
}

/* Waits (up to 60 s) until the writer has retired every row pushed. */
static dblog_stats settle(dblog *l)
{
    dblog_stats st;
    for (int i = 0; i < 60000; i++) {
        dblog_stats_get(l, &st);
        if (st.queued == 0)
            return st;
        usleep(1000);
    }
    fail_msg("the writer did not retire its rows within 60 s");
    return st;
}

static void push_rows(dblog *l, uint32_t from, uint32_t to)
{
    dblog_row r;
    for (uint32_t i = from; i < to; i++) {
        make_row(&r, i);
        assert_int_equal(dblog_push(l, &r), 0);
    }
}

/* The committed id is published only after COMMIT returned: whenever it is
 * read, every id up to it is in the table, for a reader in another
 * connection too; it starts at the highest id already stored. */
static void test_committed_id(void **state)
{
    (void)state;
    char err[256];
    dblog_config cfg = {.queue_rows = 1u << 14, .batch_rows = 64, .batch_ms = 2};
    dblog *l = dblog_open(path, &cfg, err, sizeof err);
    assert_non_null(l);
    dblog_stats st;
    dblog_stats_get(l, &st);
    assert_int_equal(st.committed_id, 0);
    sqlite3 *s = open_ro();
    int64_t last = 0, reads = 0;
    for (uint32_t round = 0; round < 40; round++) {
        push_rows(l, round * 100, round * 100 + 100);
        for (int k = 0; k < 5; k++) {
            dblog_stats_get(l, &st);
            assert_true(st.committed_id >= last); /* never goes back */
            assert_true(st.committed_id <= (int64_t)st.written);
            last = st.committed_id;
            char sql[96];
            snprintf(sql, sizeof sql, "SELECT count(*) FROM collisions WHERE id <= %lld", (long long)last);
            assert_int_equal(testdb_scalar(s, sql), last);
            reads++;
            usleep(200);
        }
    }
    sqlite3_close(s);
    assert_int_equal(dblog_stop(l, &st), 0);
    assert_int_equal(st.written, 4000);
    assert_int_equal(st.committed_id, 4000);
    assert_true(reads == 200);

    l = dblog_open(path, &cfg, err, sizeof err); /* a restart: the next ids follow */
    assert_non_null(l);
    dblog_stats_get(l, &st);
    assert_int_equal(st.committed_id, 4000);
    push_rows(l, 4000, 4010);
    assert_int_equal(dblog_stop(l, &st), 0);
    assert_int_equal(st.committed_id, 4010);
    s = open_ro();
    check_layout(s, 4010);
    sqlite3_close(s);
}

/* stderr goes to a file while a test reads what the writer logs. */
static int saved_stderr = -1;
static char captured[80];

static void capture_stderr(void)
{
    snprintf(captured, sizeof captured, "%s.log", path);
    int fd = open(captured, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
    assert_true(fd >= 0);
    fflush(stderr);
    saved_stderr = dup(2);
    assert_true(saved_stderr >= 0);
    assert_int_equal(dup2(fd, 2), 2);
    close(fd);
}

static void restore_stderr(void)
{
    fflush(stderr);
    assert_int_equal(dup2(saved_stderr, 2), 2);
    close(saved_stderr);
    saved_stderr = -1;
    unlink(captured);
}

/* Waits (up to 30 s) until the captured log holds text n times. */
static void wait_logged(const char *text, int n)
{
    for (int i = 0; i < 3000; i++) {
        FILE *f = fopen(captured, "r");
        assert_non_null(f);
        char line[1200];
        int seen = 0;
        while (fgets(line, sizeof line, f))
            seen += strstr(line, text) != NULL;
        fclose(f);
        if (seen >= n)
            return;
        usleep(10000);
    }
    restore_stderr();
    fail_msg("the writer did not log \"%s\" %d times within 30 s", text, n);
}

/* The database file renamed away, then back, then deleted under a running
 * writer: the writer says so once, within DBLOG_CHECK_MS even while idle,
 * counts the rows it gets meanwhile as lost instead of writing them into a
 * file nobody will read, and writes again when the file is back. */
static void test_file_moved(void **state)
{
    (void)state;
    char err[256], away[80];
    snprintf(away, sizeof away, "%s.away", path);
    dblog_config cfg = {.queue_rows = 1u << 12, .batch_rows = 100, .batch_ms = 5};
    dblog *l = dblog_open(path, &cfg, err, sizeof err);
    assert_non_null(l);
    push_rows(l, 0, 300);
    dblog_stats st = settle(l);
    assert_int_equal(st.written, 300);

    capture_stderr();
    assert_int_equal(rename(path, away), 0);
    wait_logged("was deleted or replaced while the server runs", 1); /* idle: no row pushed */
    push_rows(l, 300, 500);
    st = settle(l);
    assert_int_equal(st.written, 300);
    assert_int_equal(st.lost, 200);
    assert_int_equal(st.committed_id, 300);
    assert_int_equal(st.last_error, SQLITE_READONLY_DBMOVED);

    assert_int_equal(rename(away, path), 0);
    wait_logged("is back", 1);
    push_rows(l, 500, 600);
    st = settle(l);
    assert_int_equal(st.written, 400);
    assert_int_equal(st.committed_id, 400);
    wait_logged("writing again; 200 rows were lost while it failed", 1);

    /* Deleted, and a new file made at the path: not the file opened. */
    assert_int_equal(unlink(path), 0);
    FILE *other = fopen(path, "w");
    assert_non_null(other);
    fclose(other);
    push_rows(l, 600, 650);
    st = settle(l);
    wait_logged("was deleted or replaced while the server runs", 2);
    assert_int_equal(st.written, 400);
    assert_int_equal(st.lost, 250);
    assert_int_equal(dblog_stop(l, &st), -EIO);
    restore_stderr();
    assert_int_equal(st.pushed, 650);
    assert_int_equal(st.written + st.lost, 650);
}

static void test_bad_config(void **state)
{
    (void)state;
    char err[256];
    dblog_config cfg = {.queue_rows = 1000};
    assert_null(dblog_open(path, &cfg, err, sizeof err));
    assert_non_null(strstr(err, "power of two"));
    cfg = (dblog_config){.queue_rows = 1024, .batch_rows = 513};
    assert_null(dblog_open(path, &cfg, err, sizeof err));
    assert_non_null(strstr(err, "batch_rows"));
    cfg = (dblog_config){.batch_ms = DBLOG_BATCH_MS_MAX + 1};
    assert_null(dblog_open(path, &cfg, err, sizeof err));
    assert_non_null(strstr(err, "batch_ms"));
    assert_null(dblog_open("/nonexistent/dir/x.db", NULL, err, sizeof err));
    assert_non_null(strstr(err, "cannot open"));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_fields_exact, setup, teardown),
        cmocka_unit_test_setup_teardown(test_small_queue_drops_and_counts, setup, teardown),
        cmocka_unit_test_setup_teardown(test_large_queue_loses_nothing, setup, teardown),
        cmocka_unit_test_setup_teardown(test_invalid_rows_refused, setup, teardown),
        cmocka_unit_test_setup_teardown(test_hold_cap_cuts_batches, setup, teardown),
        cmocka_unit_test_setup_teardown(test_reader_beside_writer, setup, teardown),
        cmocka_unit_test_setup_teardown(test_disk_full, setup, teardown),
        cmocka_unit_test_setup_teardown(test_committed_id, setup, teardown),
        cmocka_unit_test_setup_teardown(test_file_moved, setup, teardown),
        cmocka_unit_test_setup_teardown(test_bad_config, setup, teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
