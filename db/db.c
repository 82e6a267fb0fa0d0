#include "db.h"

#include <errno.h>
#include <sodium.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "alloc.h"
#include "dbInt.h"
#include "err.h"
#include "migrations.h"

/* A writer waits this long for a lock held by another connection (the admin
 * tool, the clustering job) before giving up. */
#define DB_BUSY_TIMEOUT_MS 5000

/* Meshes are stored as little-endian float32 and copied as they are. */
_Static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "mesh blobs are little-endian float32");

enum {
    ST_SESSION_OPEN,
    ST_USER_UPSERT,
    ST_SESSION_JOIN,
    ST_SESSION_CLOSE,
    ST_OBJECT_INSERT,
    ST_MESH_INSERT,
    ST_ECM_VERSION_INSERT,
    ST_ECM_BOX_INSERT,
    ST_OBJECT_PLACE,
    ST_OBJECT_REMOVE,
    ST_USER_ID,
    ST_COUNT
};

static const char *const stmt_sql[ST_COUNT] = {
    [ST_SESSION_OPEN] = "INSERT INTO sessions(id, token, peer, started_at) VALUES (?1, ?2, ?3, ?4)",
    [ST_USER_UPSERT] = "INSERT INTO users(name, created_at, last_seen_at) VALUES (?1, ?2, ?2) "
                       "ON CONFLICT(name) DO UPDATE SET last_seen_at = excluded.last_seen_at",
    [ST_SESSION_JOIN] = "UPDATE sessions SET user_id = (SELECT id FROM users WHERE name = ?2), "
                        "avatar_id = ?3, joined_at = ?4 WHERE id = ?1",
    [ST_SESSION_CLOSE] = "UPDATE sessions SET ended_at = ?3, end_reason = ?2 "
                         "WHERE id = ?1 AND ended_at IS NULL",
    [ST_OBJECT_INSERT] = "INSERT INTO objects(owner_id, name, format, created_at, pos_x, pos_y, pos_z, yaw, scale, "
                         "ecm_version, tri_count, min_x, min_y, min_z, max_x, max_y, max_z) "
                         "VALUES ((SELECT id FROM users WHERE name = ?1), ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, 1, ?10, "
                         "?11, ?12, ?13, ?14, ?15, ?16)",
    [ST_MESH_INSERT] = "INSERT INTO meshes(object_id, triangles) VALUES (?1, ?2)",
    [ST_ECM_VERSION_INSERT] = "INSERT INTO ecm_versions(object_id, version, created_at, reason, box_count) "
                              "VALUES (?1, ?2, ?3, ?4, ?5)",
    [ST_ECM_BOX_INSERT] = "INSERT INTO ecm_boxes(object_id, version, box_index, min_x, min_y, min_z, max_x, max_y, "
                          "max_z) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)",
    [ST_OBJECT_PLACE] = "UPDATE objects SET pos_x = ?2, pos_y = ?3, pos_z = ?4, yaw = ?5, scale = ?6 WHERE id = ?1",
    [ST_OBJECT_REMOVE] = "UPDATE objects SET removed_at = ?2 WHERE id = ?1 AND removed_at IS NULL",
    [ST_USER_ID] = "SELECT id FROM users WHERE name = ?1",
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

int db__fail(db *d, int rc, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    cvre_vfail(d->err, sizeof d->err, rc, fmt, ap);
    va_end(ap);
    return rc;
}

int db_errno(int code, int sys_errno)
{
    switch (code & 0xff) {
    case SQLITE_BUSY:
    case SQLITE_LOCKED: return -EBUSY;
    case SQLITE_FULL: return -ENOSPC;
    case SQLITE_NOMEM: return -ENOMEM;
    case SQLITE_READONLY: return -EROFS;
    case SQLITE_CONSTRAINT:
        return code == SQLITE_CONSTRAINT_UNIQUE || code == SQLITE_CONSTRAINT_PRIMARYKEY ? -EEXIST : -EINVAL;
    case SQLITE_CANTOPEN:
        return sys_errno == ENOENT ? -ENOENT : sys_errno == EACCES || sys_errno == EPERM ? -EACCES : -EIO;
    case SQLITE_INTERRUPT: return -EINTR;
    case SQLITE_MISUSE:
    case SQLITE_RANGE: return -EINVAL;
    case SQLITE_TOOBIG: return -E2BIG;
    default: return -EIO;
    }
}

int db_sqlite_errno(sqlite3 *s) { return db_errno(sqlite3_extended_errcode(s), sqlite3_system_errno(s)); }

int db__sql_fail(db *d, const char *context)
{
    const char *msg = sqlite3_errmsg(d->sql);
    if (context)
        return db__fail(d, db_sqlite_errno(d->sql), "%s: %s", context, msg);
    return db__fail(d, db_sqlite_errno(d->sql), "%s", msg);
}

const char *db_error(const db *d) { return d->err; }

sqlite3 *db_sqlite(db *d) { return d->sql; }

static int exec(db *d, const char *sql)
{
    char *msg = NULL;
    int code = sqlite3_exec(d->sql, sql, NULL, NULL, &msg);
    if (code == SQLITE_OK)
        return 0;
    int rc = db__fail(d, db_errno(code, sqlite3_system_errno(d->sql)), "%s", msg ? msg : sqlite3_errmsg(d->sql));
    sqlite3_free(msg);
    return rc;
}

/* PRAGMA user_version (>= 0), or a negative errno. */
static int user_version(db *d)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(d->sql, "PRAGMA user_version", -1, &st, NULL) != SQLITE_OK)
        return db__sql_fail(d, NULL);
    int v = sqlite3_step(st) == SQLITE_ROW ? sqlite3_column_int(st, 0) : db__sql_fail(d, NULL);
    sqlite3_finalize(st);
    return v;
}

/* Applies the migrations the file lacks, each in its own transaction with its
 * version bump, so a crash leaves the schema at a whole version. */
static int migrate(db *d)
{
    int v = user_version(d), rc;
    if (v < 0)
        return v;
    if (v > db_migration_count)
        return db__fail(d, -ENOTSUP, "schema version %d is newer than this build knows (%d)", v,
                        db_migration_count);
    for (; v < db_migration_count; v++) {
        char bump[64];
        snprintf(bump, sizeof bump, "PRAGMA user_version = %d", v + 1);
        if ((rc = exec(d, "BEGIN IMMEDIATE")) < 0)
            return rc;
        if ((rc = exec(d, db_migrations[v].sql)) < 0 || (rc = exec(d, bump)) < 0) {
            char why[sizeof d->err];
            memcpy(why, d->err, sizeof why);
            exec(d, "ROLLBACK");
            return db__fail(d, rc, "migration %s failed: %s", db_migrations[v].name, why);
        }
        if ((rc = exec(d, "COMMIT")) < 0)
            return rc;
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
        if (d->sql)
            db__sql_fail(d, "cannot open");
        else
            db__fail(d, -ENOMEM, "cannot open: out of memory");
        goto fail;
    }
    sqlite3_busy_timeout(d->sql, DB_BUSY_TIMEOUT_MS);
    sqlite3_extended_result_codes(d->sql, 1);
    if (mode == DB_READONLY) {
        int v = user_version(d);
        if (v < 0)
            goto fail;
        if (v != db_migration_count) {
            db__fail(d, -ENOTSUP, "schema version %d, this build expects %d%s", v, db_migration_count,
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
            db__sql_fail(d, "prepare");
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

void db_rollback(db *d)
{
    if (!sqlite3_get_autocommit(d->sql))
        sqlite3_exec(d->sql, "ROLLBACK", NULL, NULL, NULL);
}

void db_set_busy_timeout(db *d, int ms) { sqlite3_busy_timeout(d->sql, ms); }

int db_busy(db *d) { return (sqlite3_extended_errcode(d->sql) & 0xff) == SQLITE_BUSY; }

/* Runs a prepared statement to completion and resets it for the next use. */
static int run(db *d, sqlite3_stmt *st)
{
    int rc = sqlite3_step(st);
    sqlite3_reset(st);
    sqlite3_clear_bindings(st);
    if (rc != SQLITE_DONE)
        return db__sql_fail(d, NULL);
    return 0;
}

int64_t db_session_last_id(db *d)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(d->sql, "SELECT coalesce(max(id), 0) FROM sessions", -1, &st, NULL) != SQLITE_OK)
        return db__sql_fail(d, NULL);
    int64_t id = sqlite3_step(st) == SQLITE_ROW ? sqlite3_column_int64(st, 0) : db__sql_fail(d, NULL);
    sqlite3_finalize(st);
    return id;
}

int db_owner_usage(db *d, const char *owner, uint32_t *count, uint64_t *triangles)
{
    sqlite3_stmt *st;
    int rc;
    *count = 0;
    *triangles = 0;
    if (sqlite3_prepare_v2(d->sql,
                           "SELECT count(*), coalesce(sum(o.tri_count), 0) FROM objects o "
                           "JOIN users u ON u.id = o.owner_id WHERE u.name = ?1 AND o.removed_at IS NULL",
                           -1, &st, NULL) != SQLITE_OK)
        return db__sql_fail(d, NULL);
    sqlite3_bind_text(st, 1, owner, -1, SQLITE_STATIC);
    rc = sqlite3_step(st);
    if (rc == SQLITE_ROW) {
        *count = (uint32_t)sqlite3_column_int64(st, 0);
        *triangles = (uint64_t)sqlite3_column_int64(st, 1);
    }
    sqlite3_finalize(st);
    return rc == SQLITE_ROW ? 0 : db__sql_fail(d, NULL);
}

int db_sessions_close_stale(db *d, double now)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(d->sql, "UPDATE sessions SET ended_at = ?1, end_reason = 'crashed' WHERE ended_at IS NULL",
                           -1, &st, NULL) != SQLITE_OK)
        return db__sql_fail(d, NULL);
    sqlite3_bind_double(st, 1, now);
    int rc = sqlite3_step(st) == SQLITE_DONE ? 0 : db__sql_fail(d, NULL);
    sqlite3_finalize(st);
    if (rc < 0)
        return rc;
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

int db_user_upsert(db *d, const char *name, double at, int64_t *user_id)
{
    sqlite3_stmt *st = d->st[ST_USER_UPSERT];
    sqlite3_bind_text(st, 1, name, -1, SQLITE_STATIC);
    sqlite3_bind_double(st, 2, at);
    int rc = run(d, st);
    if (rc < 0)
        return rc;
    st = d->st[ST_USER_ID];
    sqlite3_bind_text(st, 1, name, -1, SQLITE_STATIC);
    int step = sqlite3_step(st);
    *user_id = step == SQLITE_ROW ? sqlite3_column_int64(st, 0) : 0;
    sqlite3_reset(st);
    sqlite3_clear_bindings(st);
    if (step == SQLITE_ROW)
        return 0;
    return step == SQLITE_DONE ? db__fail(d, -EIO, "user %s vanished", name) : db__sql_fail(d, NULL);
}

int db_session_join(db *d, int64_t id, const char *name, uint32_t avatar_id, double at, int64_t *user_id)
{
    int rc = db_user_upsert(d, name, at, user_id);
    if (rc < 0)
        return rc;
    sqlite3_stmt *st = d->st[ST_SESSION_JOIN];
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

void db_mesh_hash(const float *tris, uint32_t tri_count, uint8_t out[DB_MESH_HASH_SIZE])
{
    _Static_assert(DB_MESH_HASH_SIZE >= crypto_generichash_BYTES_MIN && DB_MESH_HASH_SIZE <= crypto_generichash_BYTES_MAX,
                   "a BLAKE2b digest size");
    crypto_generichash(out, DB_MESH_HASH_SIZE, (const unsigned char *)tris, (unsigned long long)tri_count * 9 * sizeof(float),
                       NULL, 0);
}

/* Binds n doubles from v to parameters first..first+n-1. */
static void bind_floats(sqlite3_stmt *st, int first, const float *v, int n)
{
    for (int i = 0; i < n; i++)
        sqlite3_bind_double(st, first + i, (double)v[i]);
}

int db_object_create(db *d, db_object *o, double at)
{
    int rc = db_begin(d);
    if (rc < 0)
        return rc;
    sqlite3_stmt *st = d->st[ST_USER_UPSERT];
    sqlite3_bind_text(st, 1, o->owner, -1, SQLITE_STATIC);
    sqlite3_bind_double(st, 2, at);
    if ((rc = run(d, st)) < 0)
        goto fail;
    st = d->st[ST_OBJECT_INSERT];
    sqlite3_bind_text(st, 1, o->owner, -1, SQLITE_STATIC);
    sqlite3_bind_text(st, 2, o->name, -1, SQLITE_STATIC);
    sqlite3_bind_text(st, 3, o->format, -1, SQLITE_STATIC);
    sqlite3_bind_double(st, 4, at);
    bind_floats(st, 5, o->pos, 3);
    sqlite3_bind_double(st, 8, (double)o->yaw);
    sqlite3_bind_double(st, 9, (double)o->scale);
    sqlite3_bind_int64(st, 10, o->tri_count);
    bind_floats(st, 11, o->min, 3);
    bind_floats(st, 14, o->max, 3);
    if ((rc = run(d, st)) < 0)
        goto fail;
    o->id = sqlite3_last_insert_rowid(d->sql);
    o->ecm_version = 1;
    db_mesh_hash(o->tris, o->tri_count, o->mesh_hash);
    st = d->st[ST_MESH_INSERT];
    sqlite3_bind_int64(st, 1, o->id);
    sqlite3_bind_blob64(st, 2, o->tris, (sqlite3_uint64)o->tri_count * 9 * sizeof(float), SQLITE_STATIC);
    if ((rc = run(d, st)) < 0)
        goto fail;
    st = d->st[ST_ECM_VERSION_INSERT];
    sqlite3_bind_int64(st, 1, o->id);
    sqlite3_bind_int64(st, 2, 1);
    sqlite3_bind_double(st, 3, at);
    sqlite3_bind_text(st, 4, "import", -1, SQLITE_STATIC);
    sqlite3_bind_int64(st, 5, o->box_count);
    if ((rc = run(d, st)) < 0)
        goto fail;
    for (uint32_t i = 0; i < o->box_count; i++) {
        st = d->st[ST_ECM_BOX_INSERT];
        sqlite3_bind_int64(st, 1, o->id);
        sqlite3_bind_int64(st, 2, 1);
        sqlite3_bind_int64(st, 3, i);
        bind_floats(st, 4, o->boxes[i], 6);
        if ((rc = run(d, st)) < 0)
            goto fail;
    }
    if ((rc = db_commit(d)) == 0)
        return 0;
fail:
    sqlite3_exec(d->sql, "ROLLBACK", NULL, NULL, NULL);
    return rc;
}

int db_object_place(db *d, int64_t id, const float pos[3], float yaw, float scale)
{
    sqlite3_stmt *st = d->st[ST_OBJECT_PLACE];
    sqlite3_bind_int64(st, 1, id);
    bind_floats(st, 2, pos, 3);
    sqlite3_bind_double(st, 5, (double)yaw);
    sqlite3_bind_double(st, 6, (double)scale);
    return run(d, st);
}

int db_object_remove(db *d, int64_t id, double at)
{
    sqlite3_stmt *st = d->st[ST_OBJECT_REMOVE];
    sqlite3_bind_int64(st, 1, id);
    sqlite3_bind_double(st, 2, at);
    return run(d, st);
}

/* Reads the current ECM boxes of one object into a growing array. */
static int load_boxes(db *d, sqlite3_stmt *bx, int64_t id, uint32_t version, float (**boxes)[6], uint32_t *n,
                      uint32_t *cap)
{
    *n = 0;
    sqlite3_bind_int64(bx, 1, id);
    sqlite3_bind_int64(bx, 2, version);
    int rc;
    while ((rc = sqlite3_step(bx)) == SQLITE_ROW) {
        if (*n == *cap) {
            uint32_t ncap = *cap ? *cap * 2 : 64;
            float(*nb)[6] = cvre_realloc(*boxes, ncap * sizeof **boxes);
            if (!nb) {
                sqlite3_reset(bx);
                return db__fail(d, -ENOMEM, "out of memory loading boxes");
            }
            *boxes = nb;
            *cap = ncap;
        }
        for (int k = 0; k < 6; k++)
            (*boxes)[*n][k] = (float)sqlite3_column_double(bx, k);
        (*n)++;
    }
    sqlite3_reset(bx);
    return rc == SQLITE_DONE ? 0 : db__sql_fail(d, NULL);
}

int db_objects_load(db *d, db_object_fn *fn, void *ctx)
{
    sqlite3_stmt *ob = NULL, *bx = NULL;
    float(*boxes)[6] = NULL;
    uint32_t cap = 0;
    int rc, step;
    if (sqlite3_prepare_v2(d->sql,
                           "SELECT o.id, u.name, o.name, o.format, o.pos_x, o.pos_y, o.pos_z, o.yaw, o.scale, "
                           "o.ecm_version, o.tri_count, o.min_x, o.min_y, o.min_z, o.max_x, o.max_y, o.max_z, "
                           "m.triangles FROM objects o JOIN users u ON u.id = o.owner_id "
                           "JOIN meshes m ON m.object_id = o.id WHERE o.removed_at IS NULL ORDER BY o.id",
                           -1, &ob, NULL) != SQLITE_OK ||
        sqlite3_prepare_v2(d->sql,
                           "SELECT min_x, min_y, min_z, max_x, max_y, max_z FROM ecm_boxes "
                           "WHERE object_id = ?1 AND version = ?2 ORDER BY box_index",
                           -1, &bx, NULL) != SQLITE_OK) {
        rc = db__sql_fail(d, NULL);
        goto done;
    }
    while ((step = sqlite3_step(ob)) == SQLITE_ROW) {
        db_object o = {.id = sqlite3_column_int64(ob, 0),
                       .owner = (const char *)sqlite3_column_text(ob, 1),
                       .name = (const char *)sqlite3_column_text(ob, 2),
                       .format = (const char *)sqlite3_column_text(ob, 3),
                       .yaw = (float)sqlite3_column_double(ob, 7),
                       .scale = (float)sqlite3_column_double(ob, 8),
                       .ecm_version = (uint32_t)sqlite3_column_int64(ob, 9),
                       .tri_count = (uint32_t)sqlite3_column_int64(ob, 10)};
        for (int k = 0; k < 3; k++) {
            o.pos[k] = (float)sqlite3_column_double(ob, 4 + k);
            o.min[k] = (float)sqlite3_column_double(ob, 11 + k);
            o.max[k] = (float)sqlite3_column_double(ob, 14 + k);
        }
        o.tris = sqlite3_column_blob(ob, 17);
        if ((size_t)sqlite3_column_bytes(ob, 17) != (size_t)o.tri_count * 9 * sizeof(float)) {
            rc = db__fail(d, -EIO, "object %lld: mesh size does not match its triangle count", (long long)o.id);
            goto done;
        }
        db_mesh_hash(o.tris, o.tri_count, o.mesh_hash);
        if ((rc = load_boxes(d, bx, o.id, o.ecm_version, &boxes, &o.box_count, &cap)) < 0)
            goto done;
        o.boxes = (const float(*)[6])boxes;
        if ((rc = fn(ctx, &o)) != 0)
            goto done;
    }
    rc = step == SQLITE_DONE ? 0 : db__sql_fail(d, NULL);
done:
    sqlite3_finalize(ob);
    sqlite3_finalize(bx);
    free(boxes);
    return rc;
}
