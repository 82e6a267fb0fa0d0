#include "maintain.h"

#include <errno.h>
#include <string.h>

#include "err.h"
#include "maint.h"
#include "out.h"
#include "query.h"
#include "task.h"

#define LEN(a) ((int)(sizeof(a) / sizeof((a)[0])))

const char maintain_backup_help[] =
    "usage: cvre-admin backup FILE [--vacuum]\n"
    "\n"
    "Copies the database to FILE, a new file, as one consistent snapshot: every\n"
    "transaction committed before the command started is in the copy, none\n"
    "committed after. Safe while the server runs: it only reads, and in WAL mode\n"
    "a reader never makes the server wait.\n"
    "\n"
    "  --vacuum          a compacted copy (VACUUM INTO): no free pages, so smaller\n"
    "                    after retention, and slower; by default the pages are\n"
    "                    copied as they are (SQLite's backup API)\n"
    "\n"
    "The copy is written beside FILE (FILE.partial-XXXXXX), checked with PRAGMA\n"
    "integrity_check, switched to SQLite's rollback journal (one self-contained\n"
    "file: no -wal or -shm file goes with it), synced, and only then named FILE,\n"
    "readable by its owner only (it holds password hashes). FILE never exists\n"
    "half written, and an existing FILE is never replaced. To restore: stop the\n"
    "server, delete the database's -wal and -shm files, put the copy in the\n"
    "database's place, start the server (it switches the file back to WAL).\n"
    "\n"
    "WAL caveats: while the snapshot is read, the server's WAL cannot be\n"
    "checkpointed past it, so it grows by what the server writes meanwhile; it\n"
    "is checkpointed and reused afterwards. Never copy a live database with cp:\n"
    "its newest transactions are in the -wal file, and the main file alone is\n"
    "stale or corrupt.\n"
    "\n"
    "Prints: file, method (pages or vacuum), bytes, pages, schema (its version),\n"
    "integrity (ok), seconds. Exit 4, nothing written, if FILE exists; 3 if the\n"
    "copy failed or is not intact (nothing is left behind).\n";

const char maintain_retention_help[] =
    "usage: cvre-admin retention --older-than DAYS\n"
    "\n"
    "Removes the collisions logged more than DAYS days ago, with everything that\n"
    "indexes them: their segments, groups, R*Tree cells and user entries. Only\n"
    "whole 10 s time buckets go: the cutoff is the start of the bucket holding\n"
    "now - DAYS days. Sessions, users, objects, collision map versions,\n"
    "clustering runs and clusters stay (the maps' history refers to them);\n"
    "versions and map then count and draw fewer collisions for old versions.\n"
    "\n"
    "  --older-than DAYS   a whole number of days, 1 to 36500\n"
    "\n"
    "It writes, and is safe while the server runs: in short transactions, each\n"
    "holding the write lock about 50 ms, then pausing at least as long, so the\n"
    "server's collision log waits for one of them at most. Rows go before their\n"
    "groups: an interrupted run (Ctrl-C, a crash) leaves a consistent log, and\n"
    "running it again finishes the job.\n"
    "\n"
    "WAL caveats: what it removes passes through the WAL, which it checkpoints\n"
    "after its commits. The file does not shrink: SQLite reuses the freed pages\n"
    "for new collisions. backup --vacuum writes a compacted copy; to shrink the\n"
    "database itself, stop the server and run: sqlite3 FILE VACUUM.\n"
    "\n"
    "Prints: cutoff, collisions (rows removed), segments, groups, cells,\n"
    "user_entries, transactions, longest_ms (the longest one held the write\n"
    "lock), seconds. Exit 3 if the database failed or stayed locked (what was\n"
    "removed until then stays removed; run it again).\n";

static const char *const verbs[] = {[MAINTAIN_BACKUP] = "backup", [MAINTAIN_RETENTION] = "retention"};

int maintain_verb(const char *command)
{
    for (int i = 0; i < LEN(verbs); i++)
        if (strcmp(command, verbs[i]) == 0)
            return i;
    return -ENOENT;
}

static int backup(db *ro, const maintain_request *r, int format, char *err, size_t errlen)
{
    static const out_column cols[] = {{"file", OUT_TEXT, 0},  {"method", OUT_TEXT, 0},    {"bytes", OUT_INT, 0},
                                      {"pages", OUT_INT, 0},  {"schema", OUT_INT, 0},     {"integrity", OUT_TEXT, 0},
                                      {"seconds", OUT_REAL, 0}};
    db_backup_stats st;
    int rc = db_backup(ro, r->file, r->vacuum, &st);
    if (rc == -EEXIST)
        return cvre_fail(err, errlen, -EPERM, "%s; nothing written", db_error(ro));
    if (rc != 0)
        return cvre_fail(err, errlen, -EIO, "backup failed: %s", db_error(ro));
    sqlite3 *s = db_sqlite(ro);
    sqlite3_stmt *q;
    if (sqlite3_prepare_v2(s, "SELECT ?1, ?2, ?3, ?4, ?5, 'ok', ?6", -1, &q, NULL) != SQLITE_OK)
        return cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
    sqlite3_bind_text(q, 1, r->file, -1, SQLITE_STATIC);
    sqlite3_bind_text(q, 2, r->vacuum ? "vacuum" : "pages", -1, SQLITE_STATIC);
    sqlite3_bind_int64(q, 3, st.bytes);
    sqlite3_bind_int64(q, 4, st.pages);
    sqlite3_bind_int(q, 5, st.schema);
    sqlite3_bind_double(q, 6, st.seconds);
    return query_print(s, q, cols, LEN(cols), OUT_RECORD, format, err, errlen);
}

static int retention(const char *path, const maintain_request *r, int format, char *err, size_t errlen)
{
    static const out_column cols[] = {
        {"cutoff", OUT_TIME, 0},     {"collisions", OUT_INT, 0},   {"segments", OUT_INT, 0},
        {"groups", OUT_INT, 0},      {"cells", OUT_INT, 0},        {"user_entries", OUT_INT, 0},
        {"transactions", OUT_INT, 0}, {"longest_ms", OUT_REAL, 0}, {"seconds", OUT_REAL, 0}};
    char why[512];
    db *d = db_open(path, DB_READWRITE, why, sizeof why);
    if (!d)
        return cvre_fail(err, errlen, -EIO, "cannot open for writing: %s", why);
    double t0 = task_wall_ms();
    db_retention_stats st;
    int rc = db_retention(d, db_now() - (double)r->days * 86400.0, NULL, &st);
    if (rc != 0) {
        rc = cvre_fail(err, errlen, -EIO,
                        "retention stopped: %s%s; %llu collisions were removed before (run it again to go on)",
                        db_error(d), db_busy(d) ? " (the server held the write lock without a pause)" : "",
                        (unsigned long long)st.collisions);
        db_close(d);
        return rc;
    }
    sqlite3 *s = db_sqlite(d);
    sqlite3_stmt *q;
    if (sqlite3_prepare_v2(s, "SELECT ?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9", -1, &q, NULL) != SQLITE_OK) {
        rc = cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
    } else {
        const uint64_t n[] = {st.collisions, st.segments, st.groups, st.cells, st.user_entries, st.transactions};
        sqlite3_bind_double(q, 1, st.cutoff);
        for (int i = 0; i < LEN(n); i++)
            sqlite3_bind_int64(q, 2 + i, (sqlite3_int64)n[i]);
        sqlite3_bind_double(q, 8, st.longest_ms);
        sqlite3_bind_double(q, 9, (task_wall_ms() - t0) / 1e3);
        rc = query_print(s, q, cols, LEN(cols), OUT_RECORD, format, err, errlen);
    }
    db_close(d);
    return rc;
}

int maintain_run(db *ro, const char *path, const maintain_request *r, int format, char *err, size_t errlen)
{
    if (r->verb == MAINTAIN_BACKUP) {
        int rc = backup(ro, r, format, err, errlen);
        db_close(ro);
        return rc;
    }
    db_close(ro); /* the read-only open checked the schema version: the next open never migrates */
    return retention(path, r, format, err, errlen);
}
