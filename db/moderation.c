#include "moderation.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <sqlite3.h>

#include "account.h"
#include "dbInt.h"

/* Prepares sql into *st; 0, or a negative errno with the message (and
 * *st NULL). */
static int prepare(db *d, const char *sql, sqlite3_stmt **st)
{
    return sqlite3_prepare_v2(db_sqlite(d), sql, -1, st, NULL) == SQLITE_OK ? 0 : db__sql_fail(d, NULL);
}

/* Steps st to its end and finalizes it; 0 or a negative errno. */
static int finish(db *d, sqlite3_stmt *st)
{
    int rc = sqlite3_step(st);

    rc = rc == SQLITE_DONE || rc == SQLITE_ROW ? 0 : db__sql_fail(d, NULL);
    sqlite3_finalize(st);
    return rc;
}

int db__admin_event(db *d, const char *kind, int64_t session_id, const char *name, double at)
{
    sqlite3_stmt *st;
    int rc = prepare(d, "INSERT INTO admin_events(kind, session_id, name, at) VALUES (?1, ?2, ?3, ?4)", &st);

    if (rc < 0)
        return rc;
    sqlite3_bind_text(st, 1, kind, -1, SQLITE_STATIC);
    if (session_id)
        sqlite3_bind_int64(st, 2, session_id);
    if (name)
        sqlite3_bind_text(st, 3, name, -1, SQLITE_STATIC);
    sqlite3_bind_double(st, 4, at);
    return finish(d, st);
}

/* Ends the write transaction: COMMIT if rc is 0, else ROLLBACK; returns rc
 * (or the commit's error). */
static int end_write(db *d, int rc)
{
    if (rc == 0 && (rc = db_commit(d)) == 0)
        return 0;
    db_rollback(d);
    return rc;
}

int db_kick(db *d, int64_t session_id, double at)
{
    sqlite3_stmt *st;
    int rc;

    if ((rc = db_begin(d)) != 0)
        return rc;
    if ((rc = prepare(d, "SELECT 1 FROM sessions WHERE id = ?1 AND ended_at IS NULL", &st)) < 0)
        return end_write(d, rc);
    sqlite3_bind_int64(st, 1, session_id);
    rc = sqlite3_step(st);
    sqlite3_finalize(st);
    if (rc != SQLITE_ROW) {
        if (rc != SQLITE_DONE)
            return end_write(d, db__sql_fail(d, NULL));
        return end_write(d, db__fail(d, -ENOENT, "no session %lld is open", (long long)session_id));
    }
    return end_write(d, db__admin_event(d, "kick", session_id, NULL, at));
}

int db_ban(db *d, const char *name, double until, double at)
{
    sqlite3_stmt *st;
    db_account acc;
    int rc;

    if (!name || !*name || strlen(name) > DB_ACCOUNT_NAME_MAX)
        return db__fail(d, -EINVAL, "ban: a name is 1 to %u bytes", DB_ACCOUNT_NAME_MAX);
    if ((rc = db_begin(d)) != 0)
        return rc;
    /* a ban in force gets its new end; the row of one whose time was up is a new ban */
    rc = prepare(d, "INSERT INTO bans(name, until, created_at) VALUES (?1, ?2, ?3) "
                    "ON CONFLICT(name) DO UPDATE SET until = excluded.until, created_at = CASE WHEN bans.until "
                    "<= excluded.created_at THEN excluded.created_at ELSE bans.created_at END", &st);
    if (rc < 0)
        return end_write(d, rc);
    sqlite3_bind_text(st, 1, name, -1, SQLITE_STATIC);
    if (until > 0)
        sqlite3_bind_double(st, 2, until);
    sqlite3_bind_double(st, 3, at);
    rc = finish(d, st);
    if (rc == 0)
        rc = db__admin_event(d, "ban", 0, name, at);
    /* a banned account's tokens go with the ban, in its transaction: it
     * must not come back by resuming (a name without an account has none;
     * a failed look-up fails the ban, which would otherwise leave them) */
    if (rc == 0) {
        int found = db_account_find(d, name, &acc);
        if (found == 0)
            rc = db_account_tokens_revoke(d, acc.id);
        else if (found != -ENOENT)
            rc = found;
        if (rc > 0)
            rc = 0; /* how many tokens went */
    }
    return end_write(d, rc);
}

int db_unban(db *d, const char *name, double at)
{
    sqlite3_stmt *st;
    int rc;

    if ((rc = db_begin(d)) != 0)
        return rc;
    /* only a ban in force is lifted (an ended one is no ban, as for
     * db_banned); ended rows go as well */
    if ((rc = prepare(d, "DELETE FROM bans WHERE name = ?1 AND (until IS NULL OR until > ?2)", &st)) < 0)
        return end_write(d, rc);
    sqlite3_bind_text(st, 1, name, -1, SQLITE_STATIC);
    sqlite3_bind_double(st, 2, at);
    rc = finish(d, st);
    if (rc == 0) {
        int lifted = sqlite3_changes(db_sqlite(d));
        sqlite3_stmt *old;
        if ((rc = prepare(d, "DELETE FROM bans WHERE name = ?1", &old)) < 0)
            return end_write(d, rc);
        sqlite3_bind_text(old, 1, name, -1, SQLITE_STATIC);
        rc = finish(d, old);
        if (rc == 0 && lifted == 0)
            return end_write(d, db__fail(d, -ENOENT, "%s is not banned", name));
    }
    if (rc == 0)
        rc = db__admin_event(d, "unban", 0, name, at);
    return end_write(d, rc);
}

int db_banned(db *d, const char *name, double now, double *until)
{
    sqlite3_stmt *st;
    int rc = prepare(d, "SELECT coalesce(until, 0) FROM bans WHERE name = ?1 AND (until IS NULL OR until > ?2)", &st);

    *until = 0;
    if (rc < 0)
        return rc;
    sqlite3_bind_text(st, 1, name, -1, SQLITE_STATIC);
    sqlite3_bind_double(st, 2, now);
    rc = sqlite3_step(st);
    if (rc == SQLITE_ROW)
        *until = sqlite3_column_double(st, 0);
    rc = rc == SQLITE_ROW ? 1 : rc == SQLITE_DONE ? 0 : db__sql_fail(d, NULL);
    sqlite3_finalize(st);
    return rc;
}

/* Most actions read per call: a server applies them in one go. */
#define FEED_BATCH 256

int db_admin_events(db *d, int64_t after, db_admin_event_fn *fn, void *ctx, int64_t *last)
{
    struct action {
        char kind[8];
        int64_t session_id;
        char name[DB_ACCOUNT_NAME_MAX + 1];
    } *batch = calloc(FEED_BATCH, sizeof *batch);
    sqlite3_stmt *st;
    int n = 0, rc = batch ? prepare(d, "SELECT id, kind, coalesce(session_id, 0), coalesce(name, '') "
                                       "FROM admin_events WHERE id > ?1 ORDER BY id LIMIT ?2", &st)
                          : db__fail(d, -ENOMEM, "out of memory");

    if (rc < 0) {
        free(batch);
        return rc;
    }
    sqlite3_bind_int64(st, 1, after);
    sqlite3_bind_int(st, 2, FEED_BATCH);
    while ((rc = sqlite3_step(st)) == SQLITE_ROW) {
        const unsigned char *kind = sqlite3_column_text(st, 1), *name = sqlite3_column_text(st, 3);
        *last = sqlite3_column_int64(st, 0);
        snprintf(batch[n].kind, sizeof batch[n].kind, "%s", kind ? (const char *)kind : "");
        batch[n].session_id = sqlite3_column_int64(st, 2);
        snprintf(batch[n].name, sizeof batch[n].name, "%s", name ? (const char *)name : "");
        n++;
    }
    rc = rc == SQLITE_DONE ? 0 : db__sql_fail(d, NULL);
    sqlite3_finalize(st);
    for (int i = 0; i < n; i++)
        fn(ctx, batch[i].kind, batch[i].session_id, batch[i].name);
    free(batch);
    return rc;
}

int db_admin_events_head(db *d, int64_t *last)
{
    sqlite3_stmt *st;
    int rc = prepare(d, "SELECT coalesce(max(id), 0) FROM admin_events", &st);

    if (rc < 0)
        return rc;
    rc = sqlite3_step(st);
    if (rc == SQLITE_ROW)
        *last = sqlite3_column_int64(st, 0);
    rc = rc == SQLITE_ROW ? 0 : db__sql_fail(d, NULL);
    sqlite3_finalize(st);
    return rc;
}
