/*
 * dbInt.h: what the store's own modules (db.c, ecm.c) share beyond db.h.
 * Not for callers of the store.
 */
#ifndef CVRE_DB_INT_H
#define CVRE_DB_INT_H

#include "db.h"

/* Sets the message db_error() returns and returns rc, a negative errno, so
 * that a module can `return db__fail(d, -EINVAL, ...)`. */
int db__fail(db *d, int rc, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
/* db__fail for the last failed SQLite call on d's connection: its message
 * (after "context: " when context is not NULL) and its db_sqlite_errno. */
int db__sql_fail(db *d, const char *context);

/* Appends an action to the admin feed (moderation.c), inside the caller's
 * write transaction: kind as the admin_events table allows, session_id 0
 * or name NULL when the kind takes none. */
int db__admin_event(db *d, const char *kind, int64_t session_id, const char *name, double at);

#endif
