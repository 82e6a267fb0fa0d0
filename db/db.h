/*
 * db.h: the SQLite store (embedded default). One db handle per thread.
 *
 * Opening a writable store sets WAL mode, a busy timeout and foreign keys,
 * and brings the schema up to date with the embedded migrations; a read-only
 * open (admin tools) only checks that the schema version is one this build
 * knows.
 *
 * Results (CONTRIBUTING.md): every function of the store (db.h, ecm.h,
 * account.h, moderation.h, maint.h, dblog.h) returns 0, or a count, an id or
 * 1 for "found" where it says so, on success, and a negative errno on
 * failure, with the reason in db_error(). SQLite's own failures are mapped
 * by db_errno; the store's refusals use the errno that names them (-ENOENT
 * no such thing, -EEXIST taken, -EACCES wrong credentials, -EPERM not
 * allowed for this one, -EINVAL bad argument, -ESTALE changed meanwhile).
 */
#ifndef CVRE_DB_H
#define CVRE_DB_H

#include <sqlite3.h>
#include <stddef.h>
#include <stdint.h>

typedef struct db db;

enum { DB_READWRITE = 0, DB_READONLY = 1 };

/* Opens path. On failure returns NULL and writes "PATH: what went wrong"
 * to err. */
db *db_open(const char *path, int mode, char *err, size_t errlen);
/* Finalizes statements and closes; a WAL database is checkpointed. */
void db_close(db *d);
/* The last error message; valid until the next call on d. */
const char *db_error(const db *d);
sqlite3 *db_sqlite(db *d);
/* The negative errno for an SQLite result code (primary or extended):
 * BUSY and LOCKED -EBUSY, FULL -ENOSPC, NOMEM -ENOMEM, READONLY -EROFS,
 * CONSTRAINT -EEXIST (unique, primary key) or -EINVAL (the others),
 * CANTOPEN -ENOENT or -EACCES after sys_errno (sqlite3_system_errno; else
 * -EIO), INTERRUPT -EINTR, MISUSE and RANGE -EINVAL, TOOBIG -E2BIG, every
 * other code (IOERR, CORRUPT, NOTADB, ...) -EIO. The one place where the
 * store's callers and modules turn SQLite's codes into errnos. */
int db_errno(int code, int sys_errno);
/* db_errno of the last failed call on connection s (db_sqlite(d) for a
 * store's handle). */
int db_sqlite_errno(sqlite3 *s);
/* Schema version this build migrates to. */
int db_schema_version(void);

/* Wall-clock time as the store keeps it: Unix seconds. */
double db_now(void);

int db_begin(db *d);
int db_commit(db *d);
/* Rolls back the transaction in progress, if any. */
void db_rollback(db *d);
/* How long a write waits for another connection's lock (default 5 s). */
void db_set_busy_timeout(db *d, int ms);
/* True when the last failure was another connection holding the lock. */
int db_busy(db *d);

/* Sessions. A new session id is max(id) + 1 at start-up, counted up in
 * memory, so that ids can be handed out before their row is written.
 * Returns the highest id in the store (0 if none), or a negative errno. */
int64_t db_session_last_id(db *d);
/* Closes sessions a crashed run left open. Returns how many, or a negative
 * errno. */
int db_sessions_close_stale(db *d, double now);
int db_session_open(db *d, int64_t id, const char *token_hex, const char *peer, double at);
/* Creates the user (a users row: who appears in the logs) if new, stamps
 * last_seen_at and sets *user_id to its id. */
int db_user_upsert(db *d, const char *name, double at, int64_t *user_id);
/* Creates the user if new, stamps last_seen_at, ties it to the session and
 * sets *user_id to the user's id. */
int db_session_join(db *d, int64_t id, const char *name, uint32_t avatar_id, double at, int64_t *user_id);
int db_session_close(db *d, int64_t id, const char *reason, double at);

/* An object's mesh is named by the BLAKE2b hash (libsodium's
 * crypto_generichash, 32 bytes) of its triangles as stored: 9 little-endian
 * float32 a triangle, in object-local coordinates. Clients cache meshes by
 * it (PROTOCOL.md, "Meshes"). It is computed, not stored: at import and
 * when the store is read, so every row has one and no row can hold a
 * stale one. */
#define DB_MESH_HASH_SIZE 32u
void db_mesh_hash(const float *tris, uint32_t tri_count, uint8_t out[DB_MESH_HASH_SIZE]);

/* An object as stored: its mesh and the boxes of one ECM version, all in
 * object-local coordinates; world = R_y(yaw) * (scale * local) + pos. */
typedef struct db_object {
    int64_t id;
    const char *owner;  /* user name */
    const char *name;
    const char *format;
    float pos[3], yaw, scale;
    uint32_t ecm_version;
    uint32_t tri_count;
    const float *tris;  /* 9 floats a triangle */
    uint8_t mesh_hash[DB_MESH_HASH_SIZE]; /* set by db_object_create and db_objects_load */
    float min[3], max[3]; /* MBR */
    uint32_t box_count;
    const float (*boxes)[6]; /* min x y z, max x y z */
} db_object;

/* Stores a new object with its mesh and ECM version 1 (its boxes, reason
 * "import"), creating the owner's user row if needed, in one transaction.
 * Sets o->id. */
int db_object_create(db *d, db_object *o, double at);
/* What the objects in the world (not removed) of the user named owner hold:
 * *count objects of *triangles triangles in all (what upload quotas count). */
int db_owner_usage(db *d, const char *owner, uint32_t *count, uint64_t *triangles);
int db_object_place(db *d, int64_t id, const float pos[3], float yaw, float scale);
int db_object_remove(db *d, int64_t id, double at);
/* Calls fn for every object in the world (not removed) with its current
 * ECM version, in id order; the pointers in o are valid during the call
 * only. Stops early and returns fn's value if it is not 0. */
typedef int db_object_fn(void *ctx, const db_object *o);
int db_objects_load(db *d, db_object_fn *fn, void *ctx);

#endif
