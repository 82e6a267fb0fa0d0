#include "db.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "alloc.h"
#include "migrations.h"

/* A writer waits this long for a lock held by another connection (the admin
 * tool, the clustering job) before giving up. */
#define DB_BUSY_TIMEOUT_MS 5000

enum { ST_SESSION_OPEN, ST_USER_UPSERT, ST_SESSION_JOIN, ST_SESSION_CLOSE, ST_COUNT };

static const char *const stmt_sql[ST_COUNT] = {
    [ST_SESSION_OPEN] = "INSERT INTO sessions(id, token, peer, started_at) VALUES (?1, ?2, ?3, ?4)",
    [ST_USER_UPSERT] = "INSERT INTO users(name, created_at, last_seen_at) VALUES (?1, ?2, ?2) "
                       "ON CONFLICT(name) DO UPDATE SET last_seen_at = excluded.last_seen_at",
    [ST_SESSION_JOIN] = "UPDATE sessions SET user_id = (SELECT id FROM users WHERE name = ?2), "
                        "avatar_id = ?3, joined_at = ?4 WHERE id = ?1",
    [ST_SESSION_CLOSE] = "UPDATE sessions SET ended_at = ?3, end_reason = ?2 "
                         "WHERE id = ?1 AND ended_at IS NULL",
};

struct db {
    sqlite3 *sql;
    sqlite3_stmt *st[ST_COUNT];
    char err[256];
};

int db_schema_version(void) { return db_migration_count; }

double db_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

static int fail(db *d, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static int fail(db *d, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(d->err, sizeof d->err, fmt, ap);
    va_end(ap);
    return -1;
}

const char *db_error(const db *d) { return d->err; }

sqlite3 *db_sqlite(db *d) { return d->sql; }

static int exec(db *d, const char *sql)
{
    char *msg = NULL;
    if (sqlite3_exec(d->sql, sql, NULL, NULL, &msg) != SQLITE_OK) {
        fail(d, "%s", msg ? msg : sqlite3_errmsg(d->sql));
        sqlite3_free(msg);
        return -1;
    }
    return 0;
}

static int user_version(db *d)
{
    sqlite3_stmt *st;
    int v = -1;
    if (sqlite3_prepare_v2(d->sql, "PRAGMA user_version", -1, &st, NULL) != SQLITE_OK)
        return fail(d, "%s", sqlite3_errmsg(d->sql));
    if (sqlite3_step(st) == SQLITE_ROW)
        v = sqlite3_column_int(st, 0);
    else
        fail(d, "%s", sqlite3_errmsg(d->sql));
    sqlite3_finalize(st);
    return v;
}

/* Applies the migrations the file lacks, each in its own transaction with its
 * version bump, so a crash leaves the schema at a whole version. */
static int migrate(db *d)
{
    int v = user_version(d);
    if (v < 0)
        return -1;
    if (v > db_migration_count)
        return fail(d, "schema version %d is newer than this build knows (%d)", v, db_migration_count);
    for (; v < db_migration_count; v++) {
        char bump[64];
        snprintf(bump, sizeof bump, "PRAGMA user_version = %d", v + 1);
        if (exec(d, "BEGIN IMMEDIATE") < 0)
            return -1;
        if (exec(d, db_migrations[v].sql) < 0 || exec(d, bump) < 0) {
            char why[sizeof d->err];
            memcpy(why, d->err, sizeof why);
            exec(d, "ROLLBACK");
            return fail(d, "migration %s failed: %s", db_migrations[v].name, why);
        }
        if (exec(d, "COMMIT") < 0)
            return -1;
    }
    return 0;
}

db *db_open(const char *path, int mode, char *err, size_t errlen)
{
    db *d = cvre_calloc(1, sizeof *d);
    if (!d) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    int flags = mode == DB_READONLY ? SQLITE_OPEN_READONLY : SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE;
    if (sqlite3_open_v2(path, &d->sql, flags | SQLITE_OPEN_NOMUTEX, NULL) != SQLITE_OK) {
        fail(d, "cannot open: %s", d->sql ? sqlite3_errmsg(d->sql) : "out of memory");
        goto fail;
    }
    sqlite3_busy_timeout(d->sql, DB_BUSY_TIMEOUT_MS);
    sqlite3_extended_result_codes(d->sql, 1);
    if (mode == DB_READONLY) {
        int v = user_version(d);
        if (v < 0)
            goto fail;
        if (v != db_migration_count) {
            fail(d, "schema version %d, this build expects %d%s", v, db_migration_count,
                 v == 0 ? " (not a cvre database, or empty)" : "");
            goto fail;
        }
        return d;
    }
    /* WAL lets readers (admin, clustering job) run beside the server; NORMAL
     * sync in WAL mode is durable against process crashes, which is what the
     * log needs, without an fsync per commit. */
    if (exec(d, "PRAGMA journal_mode = WAL") < 0 || exec(d, "PRAGMA synchronous = NORMAL") < 0 ||
        exec(d, "PRAGMA foreign_keys = ON") < 0 || migrate(d) < 0)
        goto fail;
    for (int i = 0; i < ST_COUNT; i++)
        if (sqlite3_prepare_v3(d->sql, stmt_sql[i], -1, SQLITE_PREPARE_PERSISTENT, &d->st[i], NULL) != SQLITE_OK) {
            fail(d, "prepare: %s", sqlite3_errmsg(d->sql));
            goto fail;
        }
    return d;
fail:
    snprintf(err, errlen, "%s: %s", path, d->err);
    db_close(d);
    return NULL;
}

void db_close(db *d)
{
    if (!d)
        return;
    for (int i = 0; i < ST_COUNT; i++)
        sqlite3_finalize(d->st[i]);
    if (d->sql)
        sqlite3_close(d->sql);
    free(d);
}

int db_begin(db *d) { return exec(d, "BEGIN IMMEDIATE"); }

int db_commit(db *d) { return exec(d, "COMMIT"); }

/* Runs a prepared statement to completion and resets it for the next use. */
static int run(db *d, sqlite3_stmt *st)
{
    int rc = sqlite3_step(st);
    sqlite3_reset(st);
    sqlite3_clear_bindings(st);
    if (rc != SQLITE_DONE)
        return fail(d, "%s", sqlite3_errmsg(d->sql));
    return 0;
}

int64_t db_session_last_id(db *d)
{
    sqlite3_stmt *st;
    int64_t id = -1;
    if (sqlite3_prepare_v2(d->sql, "SELECT coalesce(max(id), 0) FROM sessions", -1, &st, NULL) != SQLITE_OK)
        return fail(d, "%s", sqlite3_errmsg(d->sql));
    if (sqlite3_step(st) == SQLITE_ROW)
        id = sqlite3_column_int64(st, 0);
    else
        fail(d, "%s", sqlite3_errmsg(d->sql));
    sqlite3_finalize(st);
    return id;
}

int db_sessions_close_stale(db *d, double now)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(d->sql, "UPDATE sessions SET ended_at = ?1, end_reason = 'crashed' WHERE ended_at IS NULL",
                           -1, &st, NULL) != SQLITE_OK)
        return fail(d, "%s", sqlite3_errmsg(d->sql));
    sqlite3_bind_double(st, 1, now);
    int rc = sqlite3_step(st);
    sqlite3_finalize(st);
    if (rc != SQLITE_DONE)
        return fail(d, "%s", sqlite3_errmsg(d->sql));
    return sqlite3_changes(d->sql);
}

int db_session_open(db *d, int64_t id, const char *token_hex, const char *peer, double at)
{
    sqlite3_stmt *st = d->st[ST_SESSION_OPEN];
    sqlite3_bind_int64(st, 1, id);
    sqlite3_bind_text(st, 2, token_hex, -1, SQLITE_STATIC);
    sqlite3_bind_text(st, 3, peer, -1, SQLITE_STATIC);
    sqlite3_bind_double(st, 4, at);
    return run(d, st);
}

int db_session_join(db *d, int64_t id, const char *name, uint32_t avatar_id, double at)
{
    sqlite3_stmt *st = d->st[ST_USER_UPSERT];
    sqlite3_bind_text(st, 1, name, -1, SQLITE_STATIC);
    sqlite3_bind_double(st, 2, at);
    if (run(d, st) < 0)
        return -1;
    st = d->st[ST_SESSION_JOIN];
    sqlite3_bind_int64(st, 1, id);
    sqlite3_bind_text(st, 2, name, -1, SQLITE_STATIC);
    sqlite3_bind_int64(st, 3, avatar_id);
    sqlite3_bind_double(st, 4, at);
    return run(d, st);
}

int db_session_close(db *d, int64_t id, const char *reason, double at)
{
    sqlite3_stmt *st = d->st[ST_SESSION_CLOSE];
    sqlite3_bind_int64(st, 1, id);
    sqlite3_bind_text(st, 2, reason, -1, SQLITE_STATIC);
    sqlite3_bind_double(st, 3, at);
    return run(d, st);
}
