/*
 * moderation.h: kicks and bans in the store, and the feed of them that a
 * running server follows (schema: db/migrations/0006_moderation.sql).
 *
 * cvre-admin writes an action (db_kick, db_ban, db_unban; db/account.c
 * adds "logout" when an account's password changes and "deleted" when it
 * goes); every running server reads the feed (db_admin_events) about
 * every 100 ms and applies it: a kicked session gets bye and is closed, a
 * banned, logged-out or deleted name's sessions too (a deleted account's
 * objects pass to the world account), and the auth worker refuses a
 * banned name's joins (db_banned).
 *
 * Functions return 0, or a negative errno with the message in db_error()
 * (db.h); those that write use one transaction of their own and must not be
 * called inside one.
 */
#ifndef CVRE_MODERATION_H
#define CVRE_MODERATION_H

#include <stdint.h>

#include "db.h"

/* Asks running servers to disconnect session id. -ENOENT, nothing
 * written, if no session of that id is open. */
int db_kick(db *d, int64_t session_id, double at);
/* Bars name (1..32 bytes; else -EINVAL) from joining until `until` (0:
 * until unbanned) and asks running servers to disconnect its sessions.
 * Banning a banned name sets its new end. An account's resume tokens are
 * revoked too. */
int db_ban(db *d, const char *name, double until, double at);
/* Lifts a ban; -ENOENT, nothing written, if the name is not banned. */
int db_unban(db *d, const char *name, double at);
/* 1 and *until (0: no end) if name is banned at `now`, 0 if not, or a
 * negative errno. */
int db_banned(db *d, const char *name, double now, double *until);

/* The feed: calls fn for each action with id > after, in id order (kind
 * "kick" with session_id, or "ban", "unban", "logout", "deleted" with
 * name), and sets *last to the last id seen. Actions are read in one
 * batch before fn is called. */
typedef void db_admin_event_fn(void *ctx, const char *kind, int64_t session_id, const char *name);
int db_admin_events(db *d, int64_t after, db_admin_event_fn *fn, void *ctx, int64_t *last);
/* The newest action's id, 0 if none (where a starting server begins). */
int db_admin_events_head(db *d, int64_t *last);

#endif
