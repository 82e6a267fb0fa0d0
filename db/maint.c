#include "maint.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "dbInt.h"
#include "dblog.h"
#include "task.h"

static void sleep_ms(double ms)
{
    if (ms <= 0)
        return;
    long long ns = (long long)(ms * 1e6);
    struct timespec t = {.tv_sec = (time_t)(ns / 1000000000), .tv_nsec = (long)(ns % 1000000000)};
    while (nanosleep(&t, &t) != 0 && errno == EINTR)
        ;
}

/* ---- backup ------------------------------------------------------------- */

/* Removes a temporary copy and the side files SQLite may have left by it. */
static void remove_partial(const char *tmp)
{
    static const char *const side[] = {"", "-journal", "-wal", "-shm"};
    char p[PATH_MAX + 16];
    for (size_t i = 0; i < sizeof side / sizeof side[0]; i++) {
        snprintf(p, sizeof p, "%s%s", tmp, side[i]);
        unlink(p);
    }
}

/* fsync()s path (a file or a directory): 0 or a negative errno. */
static int sync_path(const char *path)
{
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0)
        return -errno;
    int rc = fsync(fd) < 0 ? -errno : 0;
    close(fd);
    return rc;
}

/* The first row of a one-column pragma on s, as text, into buf: 0, or a
 * negative errno with the message in sqlite3_errmsg(s). */
static int pragma_text(sqlite3 *s, const char *sql, char *buf, size_t len)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(s, sql, -1, &st, NULL) != SQLITE_OK)
        return db_sqlite_errno(s);
    int rc = sqlite3_step(st);
    if (rc == SQLITE_ROW)
        snprintf(buf, len, "%s", sqlite3_column_text(st, 0) ? (const char *)sqlite3_column_text(st, 0) : "");
    rc = rc == SQLITE_ROW ? 0 : db_sqlite_errno(s);
    sqlite3_finalize(st);
    return rc;
}

/* Writes the snapshot of src into the empty file tmp. */
static int copy_into(db *d, sqlite3 *src, const char *tmp, int vacuum)
{
    if (vacuum) {
        /* PRAGMA query_only refuses VACUUM INTO although it writes only
         * the new file: lift it for this statement (a handle opened
         * read-only stays so). */
        char was[8] = "0";
        pragma_text(src, "PRAGMA query_only", was, sizeof was);
        sqlite3_exec(src, "PRAGMA query_only = 0", NULL, NULL, NULL);
        sqlite3_stmt *st;
        int rc = sqlite3_prepare_v2(src, "VACUUM INTO ?1", -1, &st, NULL);
        if (rc == SQLITE_OK) {
            sqlite3_bind_text(st, 1, tmp, -1, SQLITE_STATIC);
            rc = sqlite3_step(st);
        }
        sqlite3_finalize(st);
        rc = rc == SQLITE_DONE ? 0 : db__fail(d, db_sqlite_errno(src), "VACUUM INTO: %s", sqlite3_errmsg(src));
        if (strcmp(was, "0") != 0)
            sqlite3_exec(src, "PRAGMA query_only = 1", NULL, NULL, NULL);
        return rc;
    }
    sqlite3 *dst;
    if (sqlite3_open_v2(tmp, &dst, SQLITE_OPEN_READWRITE, NULL) != SQLITE_OK) {
        int rc = dst ? db__fail(d, db_sqlite_errno(dst), "%s: %s", tmp, sqlite3_errmsg(dst))
                     : db__fail(d, -ENOMEM, "%s: out of memory", tmp);
        sqlite3_close(dst);
        return rc;
    }
    /* One step over every page: one read transaction, so one snapshot (a
     * stepwise copy would start again whenever the server commits). */
    sqlite3_backup *b = sqlite3_backup_init(dst, "main", src, "main");
    int rc = b ? sqlite3_backup_step(b, -1) : sqlite3_errcode(dst);
    if (b)
        sqlite3_backup_finish(b);
    rc = rc == SQLITE_DONE ? 0 : db__fail(d, db_errno(rc, 0), "copy: %s", b ? sqlite3_errstr(rc) : sqlite3_errmsg(dst));
    sqlite3_close(dst);
    return rc;
}

/* Makes the copy at tmp one self-contained file in the rollback journal
 * mode, checks it, and reads its figures. */
static int check_copy(db *d, const char *tmp, db_backup_stats *st)
{
    sqlite3 *c;
    char text[256] = "";
    int rc;
    if (sqlite3_open_v2(tmp, &c, SQLITE_OPEN_READWRITE, NULL) != SQLITE_OK) {
        rc = c ? db__fail(d, db_sqlite_errno(c), "%s: %s", tmp, sqlite3_errmsg(c))
               : db__fail(d, -ENOMEM, "%s: out of memory", tmp);
        goto done;
    }
    if ((rc = pragma_text(c, "PRAGMA journal_mode = DELETE", text, sizeof text)) < 0 || strcmp(text, "delete") != 0) {
        rc = db__fail(d, rc < 0 ? rc : -EIO, "the copy stays in journal mode %s: %s", text, sqlite3_errmsg(c));
        goto done;
    }
    if ((rc = pragma_text(c, "PRAGMA integrity_check", text, sizeof text)) < 0) {
        rc = db__fail(d, rc, "integrity_check of the copy: %s", sqlite3_errmsg(c));
        goto done;
    }
    if (strcmp(text, "ok") != 0) {
        rc = db__fail(d, -EIO, "the copy fails integrity_check: %s", text);
        goto done;
    }
    char n[3][32];
    if ((rc = pragma_text(c, "PRAGMA user_version", n[0], sizeof n[0])) < 0 ||
        (rc = pragma_text(c, "PRAGMA page_count", n[1], sizeof n[1])) < 0 ||
        (rc = pragma_text(c, "PRAGMA page_size", n[2], sizeof n[2])) < 0) {
        rc = db__fail(d, rc, "reading the copy: %s", sqlite3_errmsg(c));
        goto done;
    }
    st->schema = atoi(n[0]);
    st->pages = atoll(n[1]);
    st->bytes = st->pages * atoll(n[2]);
    rc = 0;
done:
    sqlite3_close(c);
    return rc;
}

int db_backup(db *d, const char *dest, int vacuum, db_backup_stats *out)
{
    double t0 = task_wall_ms();
    db_backup_stats st = {0};
    char tmp[PATH_MAX], dir[PATH_MAX];
    struct stat sb;
    if (!*dest || strlen(dest) + sizeof ".partial-XXXXXX" > sizeof tmp)
        return db__fail(d, -EINVAL, "not a usable file name for the copy: \"%s\"", dest);
    if (lstat(dest, &sb) == 0)
        return db__fail(d, -EEXIST, "%s exists: the copy goes to a new file", dest);
    snprintf(tmp, sizeof tmp, "%s.partial-XXXXXX", dest);
    int fd = mkstemp(tmp);
    if (fd < 0)
        return db__fail(d, -errno, "cannot write beside %s: %s", dest, strerror(errno));
    close(fd);
    int rc;
    if ((rc = copy_into(d, db_sqlite(d), tmp, vacuum)) < 0 || (rc = check_copy(d, tmp, &st)) < 0)
        goto fail;
    if ((rc = sync_path(tmp)) < 0) {
        db__fail(d, rc, "cannot sync %s: %s", tmp, strerror(-rc));
        goto fail;
    }
    /* link(), not rename(): a dest made meanwhile is never replaced (-EEXIST). */
    if (link(tmp, dest) < 0) {
        rc = db__fail(d, -errno, "cannot name the copy %s: %s", dest, strerror(errno));
        goto fail;
    }
    unlink(tmp);
    /* The directory's entry for dest, made durable too. */
    snprintf(dir, sizeof dir, "%s", dest);
    char *slash = strrchr(dir, '/');
    if (slash == dir)
        snprintf(dir, sizeof dir, "/");
    else if (slash)
        *slash = 0;
    if ((rc = sync_path(slash ? dir : ".")) < 0)
        return db__fail(d, rc, "the copy is %s, but its directory could not be synced: %s", dest, strerror(-rc));
    st.seconds = (task_wall_ms() - t0) / 1e3;
    if (out)
        *out = st;
    return 0;
fail:
    remove_partial(tmp);
    return rc;
}

/* ---- retention ---------------------------------------------------------- */

/* SQLite's default autocheckpoint threshold, in WAL pages; what the server's
 * connections use too. */
#define DB_RETENTION_CHECKPOINT_PAGES 1000

enum {
    RS_SEGMENT,  /* the oldest segment of a bucket before the cutoff */
    RS_ROWS,     /* a segment's rows, or its first ones */
    RS_SEG_DEL,
    RS_SEG_MOVE, /* a segment whose first rows went starts later */
    RS_GROUP,    /* a group of a bucket before the cutoff */
    RS_USERS,
    RS_CELL,
    RS_GROUP_DEL,
    RS_COUNT
};

static const char *const retention_sql[RS_COUNT] = {
    [RS_SEGMENT] = "SELECT first_id, last_id FROM collision_segments WHERE bucket < ?1 ORDER BY bucket, first_id LIMIT 1",
    [RS_ROWS] = "DELETE FROM collisions WHERE id BETWEEN ?1 AND ?2",
    [RS_SEG_DEL] = "DELETE FROM collision_segments WHERE first_id = ?1",
    [RS_SEG_MOVE] = "UPDATE collision_segments SET first_id = ?2 WHERE first_id = ?1",
    [RS_GROUP] = "SELECT g FROM collision_groups WHERE bucket < ?1 ORDER BY bucket, g LIMIT 1",
    [RS_USERS] = "DELETE FROM collision_users WHERE g = ?1",
    [RS_CELL] = "DELETE FROM collision_cells WHERE g = ?1",
    [RS_GROUP_DEL] = "DELETE FROM collision_groups WHERE g = ?1",
};

struct retention {
    db *d;
    sqlite3 *sql;
    sqlite3_stmt *st[RS_COUNT];
    int64_t cut; /* buckets below it go */
    const db_retention_config *cfg;
    db_retention_stats *out;
    db_retention_stats txn; /* this transaction's share, added to out at commit */
    double released_ms;     /* when the last commit let the write lock go */
};

/* Steps st once with up to two integer arguments and resets it. Returns
 * SQLITE_ROW (with *col0, *col1 the row's first columns, if asked),
 * SQLITE_DONE (*changes set, if asked) or the error. */
static int step(struct retention *r, int which, int64_t a, int64_t b, int64_t *col0, int64_t *col1, uint64_t *changes)
{
    sqlite3_stmt *st = r->st[which];
    sqlite3_bind_int64(st, 1, a);
    if (sqlite3_bind_parameter_count(st) > 1)
        sqlite3_bind_int64(st, 2, b);
    int rc = sqlite3_step(st);
    if (rc == SQLITE_ROW) {
        if (col0)
            *col0 = sqlite3_column_int64(st, 0);
        if (col1)
            *col1 = sqlite3_column_int64(st, 1);
    } else if (rc == SQLITE_DONE && changes) {
        *changes = (uint64_t)sqlite3_changes64(r->sql);
    }
    sqlite3_reset(st);
    return rc;
}

/* Removes rows and entries inside the open transaction, in steps of at
 * most DB_RETENTION_STEP_ROWS rows or one group, until cfg->units_max
 * rows and entries are gone or the transaction has worked cfg->txn_ms
 * since t0 (looked at between steps): the rows of the oldest segments
 * first, then, once no segment before the cutoff is left, the groups.
 * Sets *more when work remains. Returns SQLITE_OK or the error. */
static int remove_some(struct retention *r, double t0, int *more)
{
    int64_t left = r->cfg->units_max;
    double deadline = t0 + r->cfg->txn_ms;
    *more = 1;
    while (left > 0 && task_wall_ms() < deadline) {
        int64_t first, last;
        uint64_t n;
        int rc = step(r, RS_SEGMENT, r->cut, 0, &first, &last, NULL);
        if (rc == SQLITE_DONE)
            goto groups;
        if (rc != SQLITE_ROW)
            return rc;
        int64_t take = left < DB_RETENTION_STEP_ROWS ? left : DB_RETENTION_STEP_ROWS;
        int whole = last - first + 1 <= take;
        int64_t upto = whole ? last : first + take - 1;
        if ((rc = step(r, RS_ROWS, first, upto, NULL, NULL, &n)) != SQLITE_DONE)
            return rc;
        r->txn.collisions += n;
        rc = whole ? step(r, RS_SEG_DEL, first, 0, NULL, NULL, NULL)
                   : step(r, RS_SEG_MOVE, first, upto + 1, NULL, NULL, NULL);
        if (rc != SQLITE_DONE)
            return rc;
        r->txn.segments += (uint64_t)whole;
        left -= upto - first + 1;
    }
    return SQLITE_OK;
groups:
    while (left > 0 && task_wall_ms() < deadline) {
        int64_t g;
        uint64_t users, cells, groups;
        int rc = step(r, RS_GROUP, r->cut, 0, &g, NULL, NULL);
        if (rc == SQLITE_DONE) {
            *more = 0;
            return SQLITE_OK;
        }
        if (rc != SQLITE_ROW)
            return rc;
        if ((rc = step(r, RS_USERS, g, 0, NULL, NULL, &users)) != SQLITE_DONE ||
            (rc = step(r, RS_CELL, g, 0, NULL, NULL, &cells)) != SQLITE_DONE ||
            (rc = step(r, RS_GROUP_DEL, g, 0, NULL, NULL, &groups)) != SQLITE_DONE)
            return rc;
        r->txn.user_entries += users;
        r->txn.cells += cells;
        r->txn.groups += groups;
        left -= (int64_t)(1 + users + cells);
    }
    return SQLITE_OK;
}

/* Called by SQLite after each commit of ours, once the write lock is
 * released: notes the time, and checkpoints as the default hook would
 * (SQLite's autocheckpoint threshold), outside the lock, so that the WAL
 * stays short and no other connection has to checkpoint it (the server's
 * tick thread would, inline, past that threshold: db/README.md). */
static int on_commit(void *arg, sqlite3 *conn, const char *name, int pages)
{
    struct retention *r = arg;
    r->released_ms = task_wall_ms();
    if (pages >= DB_RETENTION_CHECKPOINT_PAGES)
        sqlite3_wal_checkpoint_v2(conn, name, SQLITE_CHECKPOINT_PASSIVE, NULL, NULL);
    return SQLITE_OK;
}

/* One transaction. Returns 0 (*more set, r->out updated, *held the time
 * the write lock was held) or a negative errno. */
static int retention_txn(struct retention *r, int *more, double *held)
{
    memset(&r->txn, 0, sizeof r->txn);
    int rc = db_begin(r->d);
    if (rc < 0)
        return rc;
    double t0 = task_wall_ms(); /* the write lock is ours from here */
    if (remove_some(r, t0, more) != SQLITE_OK) {
        rc = db__sql_fail(r->d, NULL);
        db_rollback(r->d);
        return rc;
    }
    r->released_ms = 0;
    if ((rc = db_commit(r->d)) < 0) {
        db_rollback(r->d);
        return rc;
    }
    if (r->released_ms == 0) /* the hook is not called when nothing was written */
        r->released_ms = task_wall_ms();
    *held = r->released_ms - t0;
    db_retention_stats *o = r->out;
    o->collisions += r->txn.collisions;
    o->segments += r->txn.segments;
    o->groups += r->txn.groups;
    o->cells += r->txn.cells;
    o->user_entries += r->txn.user_entries;
    o->transactions++;
    if (*held > o->longest_ms)
        o->longest_ms = *held;
    return 0;
}

int db_retention(db *d, double before, const db_retention_config *cfg, db_retention_stats *out)
{
    static const db_retention_config defaults = {
        .txn_ms = DB_RETENTION_TXN_MS, .pause_ms = DB_RETENTION_PAUSE_MS, .units_max = DB_RETENTION_UNITS_MAX};
    const db_retention_config *c = cfg ? cfg : &defaults;
    memset(out, 0, sizeof *out);
    if (c->units_max < 1 || c->txn_ms < 1)
        return db__fail(d, -EINVAL, "retention wants txn_ms >= 1 and units_max >= 1");
    double latest = db_now() - DB_RETENTION_MIN_AGE_S;
    if (!isfinite(before) || before > latest)
        return db__fail(d, -ERANGE,
                        "the cutoff must be at least %.0f s in the past: the collision log may still write there",
                        DB_RETENTION_MIN_AGE_S);
    struct retention r = {.d = d, .sql = db_sqlite(d), .cut = dblog_bucket(before), .cfg = c, .out = out};
    out->cutoff = (double)r.cut * DBLOG_BUCKET_S;
    int rc = 0;
    for (int i = 0; i < RS_COUNT; i++)
        if (sqlite3_prepare_v2(r.sql, retention_sql[i], -1, &r.st[i], NULL) != SQLITE_OK) {
            rc = db__sql_fail(d, "prepare");
            goto done;
        }
    sqlite3_wal_hook(r.sql, on_commit, &r);
    for (int more = 1; more;) {
        double held = 0;
        if ((rc = retention_txn(&r, &more, &held)) < 0)
            break;
        if (more) /* the checkpoint after the commit counts towards the pause */
            sleep_ms((held > c->pause_ms ? held : c->pause_ms) - (task_wall_ms() - r.released_ms));
    }
    sqlite3_wal_autocheckpoint(r.sql, DB_RETENTION_CHECKPOINT_PAGES); /* the default hook again */
done:
    for (int i = 0; i < RS_COUNT; i++)
        sqlite3_finalize(r.st[i]);
    return rc;
}
