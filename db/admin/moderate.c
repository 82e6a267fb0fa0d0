#include "moderate.h"

#include <errno.h>
#include <stdio.h>
#include <string.h>

#include "account.h"
#include "err.h"
#include "moderation.h"
#include "out.h"
#include "query.h"

#define LEN(a) ((int)(sizeof(a) / sizeof((a)[0])))

static const char *const verbs[] = {[MODERATE_KICK] = "kick", [MODERATE_BAN] = "ban", [MODERATE_UNBAN] = "unban",
                                    [MODERATE_BANS] = "bans"};

int moderate_verb(const char *command)
{
    for (int i = 0; i < LEN(verbs); i++)
        if (strcmp(command, verbs[i]) == 0)
            return i;
    return -ENOENT;
}

int moderate_name_check(const char *name, char *why, size_t whylen)
{
    size_t n = strlen(name);
    if (n < 1 || n > DB_ACCOUNT_NAME_MAX)
        return cvre_fail(why, whylen, -EINVAL, "a name is 1 to %u bytes, not %zu", DB_ACCOUNT_NAME_MAX, n);
    for (size_t i = 0; i < n; i++)
        if ((unsigned char)name[i] < 0x20 || name[i] == 0x7f)
            return cvre_fail(why, whylen, -EINVAL, "a control character at byte %zu: no client can join under it", i);
    return 0;
}

/* ---- bans ---- */

/* The bans in force at :now (or the one of the name :name, any letter
 * case), first made first; until is the word never for a ban without an
 * end, which out.c prints as it is. */
static const out_column ban_cols[] = {{"name", OUT_TEXT, 0}, {"until", OUT_TIME, 0}, {"since", OUT_TIME, 0}};
static const char ban_sql[] = "SELECT name, coalesce(until, 'never'), created_at FROM bans "
                              "WHERE (until IS NULL OR until > :now) AND (:name IS NULL OR name = :name) "
                              "ORDER BY created_at, name";

/* A ban as read before it is lifted, to print after. */
typedef struct ban {
    char name[DB_ACCOUNT_NAME_MAX + 1];
    int forever;
    double until, since;
} ban;

static sqlite3_stmt *prepare_bans(sqlite3 *s, const char *name, char *err, size_t errlen)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(s, ban_sql, -1, &st, NULL) != SQLITE_OK) {
        cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
        return NULL;
    }
    sqlite3_bind_double(st, sqlite3_bind_parameter_index(st, ":now"), db_now());
    if (name)
        sqlite3_bind_text(st, sqlite3_bind_parameter_index(st, ":name"), name, -1, SQLITE_STATIC);
    return st;
}

/* Every ban in force (name NULL, as rows), or the name's (as a record). */
static int print_bans(sqlite3 *s, const char *name, int format, char *err, size_t errlen)
{
    sqlite3_stmt *st = prepare_bans(s, name, err, errlen);
    if (!st)
        return -EIO;
    return query_print(s, st, ban_cols, LEN(ban_cols), name ? OUT_RECORD : OUT_ROWS, format, err, errlen);
}

/* The ban in force of name into *b; -ENOENT if there is none. */
static int find_ban(sqlite3 *s, const char *name, ban *b, char *err, size_t errlen)
{
    sqlite3_stmt *st = prepare_bans(s, name, err, errlen);
    if (!st)
        return -EIO;
    int rc = sqlite3_step(st);
    if (rc == SQLITE_ROW) {
        snprintf(b->name, sizeof b->name, "%s", (const char *)sqlite3_column_text(st, 0));
        b->forever = sqlite3_column_type(st, 1) == SQLITE_TEXT;
        b->until = b->forever ? 0 : sqlite3_column_double(st, 1);
        b->since = sqlite3_column_double(st, 2);
    } else if (rc != SQLITE_DONE) {
        cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
    }
    sqlite3_finalize(st);
    return rc == SQLITE_ROW    ? 0
           : rc == SQLITE_DONE ? cvre_fail(err, errlen, -ENOENT, "%s is not banned", name)
                               : -EIO;
}

/* What unban prints: the ban it lifted, as bans showed it. */
static int print_lifted(sqlite3 *s, const ban *b, int format, char *err, size_t errlen)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(s, "SELECT ?1, ?2, ?3", -1, &st, NULL) != SQLITE_OK)
        return cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
    sqlite3_bind_text(st, 1, b->name, -1, SQLITE_STATIC);
    if (b->forever)
        sqlite3_bind_text(st, 2, "never", -1, SQLITE_STATIC);
    else
        sqlite3_bind_double(st, 2, b->until);
    sqlite3_bind_double(st, 3, b->since);
    return query_print(s, st, ban_cols, LEN(ban_cols), OUT_RECORD, format, err, errlen);
}

/* ---- sessions ---- */

/* Whether session id is open, on the read-only snapshot: -ENOENT
 * with what became of it otherwise. */
static int check_session(sqlite3 *s, int64_t id, char *err, size_t errlen)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(s, "SELECT ended_at IS NULL, coalesce(end_reason, '') FROM sessions WHERE id = ?1", -1,
                           &st, NULL) != SQLITE_OK)
        return cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
    sqlite3_bind_int64(st, 1, id);
    int rc = sqlite3_step(st);
    if (rc == SQLITE_ROW && sqlite3_column_int(st, 0))
        rc = 0;
    else if (rc == SQLITE_ROW)
        rc = cvre_fail(err, errlen, -ENOENT, "session %lld is not open (it ended: %s); nothing written",
                        (long long)id, (const char *)sqlite3_column_text(st, 1));
    else if (rc == SQLITE_DONE)
        rc = cvre_fail(err, errlen, -ENOENT, "no session %lld", (long long)id);
    else
        rc = cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
    sqlite3_finalize(st);
    return rc;
}

/* What kick prints: the session it asked running servers to close. */
static int print_session(sqlite3 *s, int64_t id, int format, char *err, size_t errlen)
{
    static const out_column cols[] = {{"session", OUT_INT, 0}, {"user", OUT_TEXT, 0},    {"peer", OUT_TEXT, 0},
                                      {"started", OUT_TIME, 0}, {"joined", OUT_TIME, 0}};
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(s,
                           "SELECT s.id, u.name, s.peer, s.started_at, s.joined_at "
                           "FROM sessions s LEFT JOIN users u ON u.id = s.user_id WHERE s.id = ?1",
                           -1, &st, NULL) != SQLITE_OK)
        return cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
    sqlite3_bind_int64(st, 1, id);
    return query_print(s, st, cols, LEN(cols), OUT_RECORD, format, err, errlen);
}

/* ---- the commands ---- */

/* The write, on a handle opened read-write for it, and what it prints. */
static int write_action(db *d, const moderate_request *r, const ban *lifted, int format, char *err, size_t errlen)
{
    double now = db_now();
    int rc = r->verb == MODERATE_KICK ? db_kick(d, r->session, now)
             : r->verb == MODERATE_BAN ? db_ban(d, r->name, r->minutes ? now + (double)r->minutes * 60.0 : 0, now)
                                       : db_unban(d, lifted->name, now);
    /* Another process may have come between the check and this write. */
    if (rc == -ENOENT && r->verb == MODERATE_KICK)
        return cvre_fail(err, errlen, -ENOENT, "session %lld ended meanwhile; nothing written",
                          (long long)r->session);
    if (rc == -ENOENT && r->verb == MODERATE_UNBAN)
        return cvre_fail(err, errlen, -ENOENT, "%s was unbanned meanwhile; nothing written", r->name);
    if (rc != 0)
        return cvre_fail(err, errlen, -EIO, "%s failed: %s%s", verbs[r->verb], db_error(d),
                          db_busy(d) ? " (another process held the write lock)" : "");
    sqlite3 *s = db_sqlite(d);
    return r->verb == MODERATE_KICK ? print_session(s, r->session, format, err, errlen)
           : r->verb == MODERATE_BAN ? print_bans(s, r->name, format, err, errlen)
                                     : print_lifted(s, lifted, format, err, errlen);
}

int moderate_run(db *ro, const char *path, const moderate_request *r, int format, char *err, size_t errlen)
{
    ban lifted = {0};
    int rc = 0;
    if (r->verb == MODERATE_BANS)
        rc = print_bans(db_sqlite(ro), NULL, format, err, errlen);
    else if (r->verb == MODERATE_KICK)
        rc = check_session(db_sqlite(ro), r->session, err, errlen);
    else if (r->verb == MODERATE_UNBAN)
        rc = find_ban(db_sqlite(ro), r->name, &lifted, err, errlen);
    db_close(ro);
    if (rc != 0 || r->verb == MODERATE_BANS)
        return rc;
    char why[512];
    db *d = db_open(path, DB_READWRITE, why, sizeof why);
    if (!d)
        return cvre_fail(err, errlen, -EIO, "cannot open for writing: %s", why);
    rc = write_action(d, r, &lifted, format, err, errlen);
    db_close(d);
    return rc;
}
