#include "dblog.h"

#include <errno.h>
#include <math.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <time.h>
#include <unistd.h>

#include "alloc.h"
#include "db.h"
#include "log.h"

/* Page cache of the writer's connection. The hot set is one leaf per object
 * and per user (where their index entries are appended), the rtree's inner
 * nodes and the tail of every b-tree; 64 MiB keeps them all for a world of
 * 10,000 users and objects, so a batch reads nothing back from disk. */
#ifndef DBLOG_CACHE_KIB
#define DBLOG_CACHE_KIB 65536
#endif
/* WAL pages before a commit checkpoints (PASSIVE: readers are never
 * blocked). Kept at SQLite's default on purpose: the trigger is per
 * connection but the WAL is shared, so if this writer let the WAL grow past
 * the 1000 pages at which the server's own connection checkpoints, that
 * connection's next commit would run the checkpoint on the tick thread.
 * Larger values made no measurable difference to the writer (db/README). */
#ifndef DBLOG_WAL_AUTOCHECKPOINT
#define DBLOG_WAL_AUTOCHECKPOINT 1000
#endif
/* The cap on a transaction's inserting time (batch_ms) is checked once per
 * this many rows, a few milliseconds of inserts at most. */
#define DBLOG_CLOCK_ROWS 256u
/* A cache line's worth of padding keeps the producer's counters, the
 * writer's and the shared wake-up flag on separate lines, so that each side's
 * writes do not evict what the other reads on every row. Padding, not
 * _Alignas: the struct comes from malloc, which promises only 16 bytes. */
#define DBLOG_CACHE_LINE 64

enum { ST_COLLISION, ST_RTREE, ST_COUNT };

static const char *const stmt_sql[ST_COUNT] = {
    [ST_COLLISION] = "INSERT INTO collisions(at, session_id, user_id, avatar_id, object_id, ecm_version, box_index, "
                     "inside, avatar_x, avatar_y, avatar_z, world_x, world_y, world_z, local_x, local_y, local_z, "
                     "normal_x, normal_y, normal_z, vel_x, vel_y, vel_z) "
                     "VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16, ?17, ?18, "
                     "?19, ?20, ?21, ?22, ?23)",
    /* OR REPLACE: an rtree row left behind by a deleted collision whose id
     * is handed out again must not fail every batch from then on. */
    [ST_RTREE] = "INSERT OR REPLACE INTO collisions_rtree(id, min_x, max_x, min_y, max_y, min_z, max_z) "
                 "VALUES (?1, ?2, ?2, ?3, ?3, ?4, ?4)",
};

struct dblog {
    /* Written by the producer only. */
    _Atomic uint64_t head; /* rows ever accepted */
    _Atomic uint64_t dropped, invalid;
    _Atomic uint64_t high_water;
    char pad1[DBLOG_CACHE_LINE];
    /* Written by the writer only. */
    _Atomic uint64_t tail; /* rows ever retired (committed or lost) */
    _Atomic uint64_t written, lost, batches, failures;
    _Atomic int last_error;
    char pad2[DBLOG_CACHE_LINE];
    /* The writer's wake-up request: 0 while it runs, otherwise the queue
     * length at which the producer must wake it through efd. */
    _Atomic uint64_t wake_at;
    _Atomic int stopping;
    char pad3[DBLOG_CACHE_LINE];
    /* Set at open, read-only afterwards. */
    dblog_row *ring;
    uint64_t mask;
    uint32_t batch_rows, batch_ms;
    int efd;
    db *store;
    sqlite3 *sql;
    sqlite3_stmt *st[ST_COUNT];
    pthread_t thread;
    /* The writer's own. */
    uint64_t reported_dropped, reported_lost;
    uint64_t report_due_ms;
    int failing; /* a batch was lost and none has succeeded since */
    char errmsg[256];
};

static uint64_t now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000u + (uint64_t)ts.tv_nsec / 1000000u;
}

static void sleep_ms(uint32_t ms)
{
    struct timespec ts = {.tv_sec = ms / 1000u, .tv_nsec = (long)(ms % 1000u) * 1000000L};
    while (nanosleep(&ts, &ts) != 0 && errno == EINTR)
        ;
}

/* ---- producer side ------------------------------------------------------ */

/* SQLite stores NaN as NULL, which the NOT NULL columns refuse: one such row
 * would fail its whole batch. */
static int row_is_finite(const dblog_row *r)
{
    const float *v[5] = {r->avatar, r->world, r->local, r->normal, r->vel};
    int ok = isfinite(r->at) != 0;
    for (int k = 0; k < 5; k++)
        ok &= isfinite(v[k][0]) && isfinite(v[k][1]) && isfinite(v[k][2]);
    return ok;
}

static void count(_Atomic uint64_t *counter)
{
    /* Single writer: a plain load and store, no locked instruction. */
    atomic_store_explicit(counter, atomic_load_explicit(counter, memory_order_relaxed) + 1, memory_order_relaxed);
}

int dblog_push(dblog *log, const dblog_row *row)
{
    if (!row_is_finite(row)) {
        count(&log->invalid);
        return -1;
    }
    uint64_t head = atomic_load_explicit(&log->head, memory_order_relaxed);
    uint64_t tail = atomic_load_explicit(&log->tail, memory_order_acquire);
    if (head - tail > log->mask) {
        count(&log->dropped);
        return -1;
    }
    memcpy(&log->ring[head & log->mask], row, sizeof *row);
    /* Sequentially consistent, with the load of wake_at below: the writer
     * stores wake_at and then loads head, so one of the two sides always
     * sees the other and a wake-up is never lost. */
    atomic_store(&log->head, head + 1);
    uint64_t used = head + 1 - tail;
    if (used > atomic_load_explicit(&log->high_water, memory_order_relaxed))
        atomic_store_explicit(&log->high_water, used, memory_order_relaxed);
    uint64_t want = atomic_load(&log->wake_at);
    if (want && used >= want && atomic_exchange(&log->wake_at, 0) != 0) {
        uint64_t one = 1;
        ssize_t w = write(log->efd, &one, sizeof one);
        (void)w; /* EAGAIN means a wake-up is already pending */
    }
    return 0;
}

void dblog_stats_get(const dblog *log, dblog_stats *out)
{
    uint64_t head = atomic_load_explicit(&log->head, memory_order_relaxed);
    uint64_t tail = atomic_load_explicit(&log->tail, memory_order_relaxed);
    out->dropped = atomic_load_explicit(&log->dropped, memory_order_relaxed);
    out->invalid = atomic_load_explicit(&log->invalid, memory_order_relaxed);
    out->pushed = head + out->dropped + out->invalid;
    out->written = atomic_load_explicit(&log->written, memory_order_relaxed);
    out->lost = atomic_load_explicit(&log->lost, memory_order_relaxed);
    out->batches = atomic_load_explicit(&log->batches, memory_order_relaxed);
    out->failures = atomic_load_explicit(&log->failures, memory_order_relaxed);
    out->queued = head > tail ? head - tail : 0;
    out->high_water = atomic_load_explicit(&log->high_water, memory_order_relaxed);
    out->last_error = atomic_load_explicit(&log->last_error, memory_order_relaxed);
}

/* ---- writer side -------------------------------------------------------- */

/* Sleeps until the queue holds at least `rows` rows, stop is requested, or
 * timeout_ms passes (-1: no limit). Wakes early at times; callers re-check. */
static void wait_for(dblog *l, uint64_t rows, int timeout_ms)
{
    atomic_store(&l->wake_at, rows);
    uint64_t queued = atomic_load(&l->head) - atomic_load_explicit(&l->tail, memory_order_relaxed);
    if (queued < rows && !atomic_load(&l->stopping)) {
        struct pollfd p = {.fd = l->efd, .events = POLLIN};
        poll(&p, 1, timeout_ms);
    }
    atomic_store(&l->wake_at, 0);
    uint64_t drain;
    ssize_t r = read(l->efd, &drain, sizeof drain);
    (void)r; /* EAGAIN: nothing was pending */
}

/* Binds one queued row to the two insert statements and runs them. Returns
 * SQLITE_OK or the error code. */
static int insert_row(dblog *l, const dblog_row *r)
{
    sqlite3_stmt *st = l->st[ST_COLLISION];
    sqlite3_bind_double(st, 1, r->at);
    sqlite3_bind_int64(st, 2, r->session_id);
    if (r->user_id)
        sqlite3_bind_int64(st, 3, r->user_id);
    else
        sqlite3_bind_null(st, 3);
    sqlite3_bind_int64(st, 4, r->avatar_id);
    sqlite3_bind_int64(st, 5, r->object_id);
    sqlite3_bind_int64(st, 6, r->ecm_version);
    sqlite3_bind_int64(st, 7, r->box_index);
    sqlite3_bind_int(st, 8, r->inside != 0);
    const float *v[5] = {r->avatar, r->world, r->local, r->normal, r->vel};
    for (int k = 0; k < 5; k++)
        for (int i = 0; i < 3; i++)
            sqlite3_bind_double(st, 9 + 3 * k + i, v[k][i]);
    int rc = sqlite3_step(st);
    sqlite3_reset(st);
    if (rc != SQLITE_DONE)
        return rc;
    st = l->st[ST_RTREE];
    sqlite3_bind_int64(st, 1, sqlite3_last_insert_rowid(l->sql));
    for (int i = 0; i < 3; i++)
        sqlite3_bind_double(st, 2 + i, r->world[i]);
    rc = sqlite3_step(st);
    sqlite3_reset(st);
    return rc == SQLITE_DONE ? SQLITE_OK : rc;
}

/* One attempt at committing rows [from, from + *n) of the ring in one
 * transaction. With a time cap (cap_ms > 0) it stops inserting once the
 * transaction has been open that long and commits what it has, setting *n to
 * that count. On failure the transaction is rolled back, so the database
 * holds all of the batch or none of it, and the message is kept in
 * l->errmsg. Returns SQLITE_OK or the extended error code. */
static int write_batch(dblog *l, uint64_t from, uint64_t *n, uint32_t cap_ms)
{
    uint64_t start = now_ms();
    int rc = sqlite3_exec(l->sql, "BEGIN IMMEDIATE", NULL, NULL, NULL);
    for (uint64_t i = 0; rc == SQLITE_OK && i < *n; i++) {
        if (cap_ms && i % DBLOG_CLOCK_ROWS == DBLOG_CLOCK_ROWS - 1 && now_ms() - start >= cap_ms)
            *n = i;
        else
            rc = insert_row(l, &l->ring[(from + i) & l->mask]);
    }
    if (rc == SQLITE_OK)
        rc = sqlite3_exec(l->sql, "COMMIT", NULL, NULL, NULL);
    if (rc == SQLITE_OK)
        return SQLITE_OK;
    rc = sqlite3_extended_errcode(l->sql);
    snprintf(l->errmsg, sizeof l->errmsg, "%s", sqlite3_errmsg(l->sql));
    if (!sqlite3_get_autocommit(l->sql))
        sqlite3_exec(l->sql, "ROLLBACK", NULL, NULL, NULL);
    return rc;
}

/* Commits up to n of the oldest queued rows (fewer if batch_ms cuts the
 * transaction short; the last one, at stop, is not cut), retrying a failed batch,
 * and retires them from the ring, written or lost. Failures are logged one
 * by one until a batch is lost; from then on, until a batch succeeds again,
 * report() sums them up, so a full disk does not flood the log. */
static void commit_rows(dblog *l, uint64_t n, int stopping)
{
    uint64_t tail = atomic_load_explicit(&l->tail, memory_order_relaxed);
    uint32_t delay = DBLOG_RETRY_MS;
    for (uint32_t attempt = 1;; attempt++) {
        int rc = write_batch(l, tail, &n, stopping ? 0 : l->batch_ms);
        if (rc == SQLITE_OK) {
            atomic_fetch_add_explicit(&l->written, n, memory_order_relaxed);
            atomic_fetch_add_explicit(&l->batches, 1, memory_order_relaxed);
            if (l->failing)
                log_info("collision log: writing again");
            l->failing = 0;
            break;
        }
        atomic_fetch_add_explicit(&l->failures, 1, memory_order_relaxed);
        atomic_store_explicit(&l->last_error, rc, memory_order_relaxed);
        if (!l->failing)
            log_error("collision log: batch of %llu rows failed (attempt %u of %u): %s", (unsigned long long)n,
                      attempt, DBLOG_ATTEMPTS, l->errmsg);
        if (attempt == DBLOG_ATTEMPTS) {
            atomic_fetch_add_explicit(&l->lost, n, memory_order_relaxed);
            if (!l->failing)
                log_error("collision log: %llu rows lost; further failures are reported every %u s",
                          (unsigned long long)n, DBLOG_REPORT_MS / 1000u);
            l->failing = 1;
            break;
        }
        sleep_ms(delay);
        delay *= 2;
    }
    /* Release: the producer may reuse these slots only after we read them. */
    atomic_store_explicit(&l->tail, tail + n, memory_order_release);
}

/* Logs drops and losses since the last report, at most once per
 * DBLOG_REPORT_MS unless forced (at stop). */
static void report(dblog *l, int force)
{
    uint64_t now = now_ms();
    if (!force && now < l->report_due_ms)
        return;
    uint64_t dropped = atomic_load_explicit(&l->dropped, memory_order_relaxed) - l->reported_dropped;
    uint64_t lost = atomic_load_explicit(&l->lost, memory_order_relaxed) - l->reported_lost;
    if (dropped)
        log_warn("collision log: %llu rows dropped since the last report: the queue (%llu rows) was full",
                 (unsigned long long)dropped, (unsigned long long)l->mask + 1u);
    if (lost)
        log_error("collision log: %llu rows lost to database errors since the last report (last: %s)",
                  (unsigned long long)lost, l->errmsg);
    if (!dropped && !lost)
        return;
    l->reported_dropped += dropped;
    l->reported_lost += lost;
    l->report_due_ms = now + DBLOG_REPORT_MS;
}

/* The writer thread. It sleeps until a first row arrives, then until the
 * batch is full or its time is up; at stop it writes whatever is queued in
 * one last transaction and returns. */
static void *writer_main(void *arg)
{
    dblog *l = arg;
    uint64_t first_ms = 0; /* when the oldest uncommitted row was seen; 0: none */
    for (;;) {
        uint64_t queued = atomic_load_explicit(&l->head, memory_order_acquire) -
                          atomic_load_explicit(&l->tail, memory_order_relaxed);
        int stopping = atomic_load(&l->stopping);
        if (queued == 0) {
            if (stopping)
                break;
            first_ms = 0;
            wait_for(l, 1, -1);
            continue;
        }
        uint64_t now = now_ms();
        if (!first_ms)
            first_ms = now;
        uint64_t due = first_ms + l->batch_ms;
        if (stopping) {
            commit_rows(l, queued, 1);
        } else if (queued >= l->batch_rows) {
            commit_rows(l, l->batch_rows, 0);
        } else if (now >= due) {
            commit_rows(l, queued, 0);
        } else {
            wait_for(l, l->batch_rows, (int)(due - now));
            continue;
        }
        /* Rows still queued arrived after `now`, at the earliest. */
        first_ms = now;
        report(l, 0);
    }
    report(l, 1);
    return NULL;
}

/* ---- life cycle --------------------------------------------------------- */

static int check_config(const dblog_config *cfg, char *err, size_t errlen)
{
    if (cfg->queue_rows < 2 || cfg->queue_rows > DBLOG_QUEUE_ROWS_MAX || (cfg->queue_rows & (cfg->queue_rows - 1))) {
        snprintf(err, errlen, "queue_rows %u is not a power of two from 2 to %u", cfg->queue_rows,
                 DBLOG_QUEUE_ROWS_MAX);
        return -1;
    }
    if (cfg->batch_rows < 1 || cfg->batch_rows > cfg->queue_rows / 2) {
        snprintf(err, errlen, "batch_rows %u is not from 1 to half the queue (%u)", cfg->batch_rows,
                 cfg->queue_rows / 2);
        return -1;
    }
    if (cfg->batch_ms < 1 || cfg->batch_ms > DBLOG_BATCH_MS_MAX) {
        snprintf(err, errlen, "batch_ms %u is not from 1 to %u", cfg->batch_ms, DBLOG_BATCH_MS_MAX);
        return -1;
    }
    return 0;
}

/* Frees what dblog_open took; the thread must not be running. */
static void destroy(dblog *l)
{
    for (int i = 0; i < ST_COUNT; i++)
        sqlite3_finalize(l->st[i]);
    db_close(l->store);
    if (l->efd >= 0)
        close(l->efd);
    free(l->ring);
    free(l);
}

dblog *dblog_open(const char *path, const dblog_config *cfg, char *err, size_t errlen)
{
    dblog_config c = cfg ? *cfg : (dblog_config){0};
    if (!c.queue_rows)
        c.queue_rows = DBLOG_QUEUE_ROWS_DEFAULT;
    if (!c.batch_rows)
        c.batch_rows = c.queue_rows / 2 < DBLOG_BATCH_ROWS_DEFAULT ? c.queue_rows / 2 : DBLOG_BATCH_ROWS_DEFAULT;
    if (!c.batch_ms)
        c.batch_ms = DBLOG_BATCH_MS_DEFAULT;
    if (check_config(&c, err, errlen) < 0)
        return NULL;

    dblog *l = cvre_calloc(1, sizeof *l);
    if (!l) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    l->efd = -1;
    l->mask = c.queue_rows - 1u;
    l->batch_rows = c.batch_rows;
    l->batch_ms = c.batch_ms;
    l->ring = cvre_malloc((size_t)c.queue_rows * sizeof *l->ring);
    if (!l->ring) {
        snprintf(err, errlen, "out of memory for a queue of %u rows", c.queue_rows);
        goto fail;
    }
    /* Touch every page now, so that the tick thread never takes a page
     * fault the first time it goes round the ring. */
    memset(l->ring, 0, (size_t)c.queue_rows * sizeof *l->ring);
    l->efd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    if (l->efd < 0) {
        snprintf(err, errlen, "eventfd: %s", strerror(errno));
        goto fail;
    }
    l->store = db_open(path, DB_READWRITE, err, errlen);
    if (!l->store)
        goto fail;
    l->sql = db_sqlite(l->store);
    char pragmas[128];
    snprintf(pragmas, sizeof pragmas, "PRAGMA cache_size = -%d; PRAGMA wal_autocheckpoint = %d", DBLOG_CACHE_KIB,
             DBLOG_WAL_AUTOCHECKPOINT);
    if (sqlite3_exec(l->sql, pragmas, NULL, NULL, NULL) != SQLITE_OK) {
        snprintf(err, errlen, "%s: %s", path, sqlite3_errmsg(l->sql));
        goto fail;
    }
    for (int i = 0; i < ST_COUNT; i++)
        if (sqlite3_prepare_v3(l->sql, stmt_sql[i], -1, SQLITE_PREPARE_PERSISTENT, &l->st[i], NULL) != SQLITE_OK) {
            snprintf(err, errlen, "%s: prepare: %s", path, sqlite3_errmsg(l->sql));
            goto fail;
        }

    /* The writer takes no signals: a server that reads them from a signalfd
     * must find them pending, not delivered to this thread. */
    sigset_t all, old;
    sigfillset(&all);
    pthread_sigmask(SIG_SETMASK, &all, &old);
    int rc = pthread_create(&l->thread, NULL, writer_main, l);
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    if (rc != 0) {
        snprintf(err, errlen, "cannot start the writer thread: %s", strerror(rc));
        goto fail;
    }
    return l;
fail:
    destroy(l);
    return NULL;
}

int dblog_stop(dblog *log, dblog_stats *final)
{
    atomic_store(&log->stopping, 1);
    uint64_t one = 1;
    ssize_t w = write(log->efd, &one, sizeof one);
    (void)w; /* EAGAIN: a wake-up is already pending */
    pthread_join(log->thread, NULL);
    dblog_stats s;
    dblog_stats_get(log, &s);
    if (final)
        *final = s;
    destroy(log);
    return s.lost ? -1 : 0;
}
