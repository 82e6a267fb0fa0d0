/*
 * db.h: the SQLite store (embedded default). One db handle per thread.
 *
 * Opening a writable store sets WAL mode, a busy timeout and foreign keys,
 * and brings the schema up to date with the embedded migrations; a read-only
 * open (admin tools) only checks that the schema version is one this build
 * knows. Functions return 0 or -1; on -1 the message is in db_error().
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
/* Schema version this build migrates to. */
int db_schema_version(void);

/* Wall-clock time as the store keeps it: Unix seconds. */
double db_now(void);

int db_begin(db *d);
int db_commit(db *d);

/* Sessions. A new session id is max(id) + 1 at start-up, counted up in
 * memory, so that ids can be handed out before their row is written. */
int64_t db_session_last_id(db *d);
/* Closes sessions a crashed run left open. Returns how many, or -1. */
int db_sessions_close_stale(db *d, double now);
int db_session_open(db *d, int64_t id, const char *token_hex, const char *peer, double at);
/* Creates the user if new, stamps last_seen_at, and ties it to the session. */
int db_session_join(db *d, int64_t id, const char *name, uint32_t avatar_id, double at);
int db_session_close(db *d, int64_t id, const char *reason, double at);

#endif
