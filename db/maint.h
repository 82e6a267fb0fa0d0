/*
 * maint.h: maintenance of a store that may be in use: an online backup, and
 * the retention of the collision log (cvre-admin backup and retention).
 *
 * Both run beside a server writing to the same file (WAL mode, db.h):
 *
 * - A backup reads one snapshot (one read transaction) and copies it to a
 *   new file, which is checked (PRAGMA integrity_check) and switched to the
 *   rollback journal (one self-contained file) before it takes its name.
 *   Readers never block the writer in WAL mode, but while the snapshot is
 *   held the WAL cannot be checkpointed past it: it grows by what the
 *   server writes meanwhile and is reused afterwards.
 *
 * - Retention removes the collision log's rows older than a cutoff, whole
 *   10 s time buckets at a time (dblog.h), with everything that indexes
 *   them: the segments, then the groups with their R*Tree cells and user
 *   entries (db/README.md, "Collision log storage"). Rows go first, then
 *   the groups that held them, so every state between two transactions (an
 *   interrupted run included) is one a query reads correctly: a row always
 *   has its group, segment, cell and user entry; at worst a group without
 *   rows is left for the next run. Each transaction works for about txn_ms
 *   (at most units_max rows and entries), and the next one waits at least
 *   as long as it held the lock, so the collision log's writer (which waits
 *   for the write lock) and the server's session records (which are retried
 *   on the next tick) are held up by one short transaction at most. Its
 *   connection checkpoints the WAL it wrote after the commit, outside the
 *   lock. Sessions,
 *   users, objects, collision map versions, clustering runs and clusters
 *   stay: they are small, and the collision maps' history refers to them.
 *   Freed pages are reused by later rows; the file does not shrink (a
 *   backup with vacuum = 1 is a compacted copy).
 *
 * Functions return 0, or a negative errno with the message in db_error()
 * (db.h).
 */
#ifndef CVRE_MAINT_H
#define CVRE_MAINT_H

#include <stdint.h>

#include "db.h"

/* Retention refuses a cutoff less than this far before now (seconds). The
 * collision log's writer keeps the groups of the newest bucket it wrote in
 * memory and appends to them; rows can also wait in its queue, and be
 * retried, for seconds. An hour is far beyond both. */
#ifndef DB_RETENTION_MIN_AGE_S
#define DB_RETENTION_MIN_AGE_S 3600.0
#endif
/* Target length of one retention transaction, in ms of holding the write
 * lock: a fifth of the log writer's own batch time cap
 * (DBLOG_BATCH_MS_DEFAULT, 250 ms), so that waiting for one costs the
 * writer less than one of its own batches. A transaction looks at the
 * clock between steps and commits once this is spent. */
#ifndef DB_RETENTION_TXN_MS
#define DB_RETENTION_TXN_MS 50u
#endif
/* Least pause between two retention transactions, in ms (and at least as
 * long as the last one held the lock): longer than SQLite's busy handler
 * sleeps between its tries while a waiter has waited less than a few
 * hundred ms (1 to 50 ms), so that a waiting writer finds the lock free. */
#ifndef DB_RETENTION_PAUSE_MS
#define DB_RETENTION_PAUSE_MS 50u
#endif
/* Rows one statement removes, between two looks at the clock: a few ms of
 * work. A segment longer than that goes in parts (its first id moves up). */
#ifndef DB_RETENTION_STEP_ROWS
#define DB_RETENTION_STEP_ROWS 1024
#endif
/* Most rows and entries one transaction removes, whatever the clock says:
 * what a clock that jumps cannot stretch. */
#ifndef DB_RETENTION_UNITS_MAX
#define DB_RETENTION_UNITS_MAX 65536u
#endif
_Static_assert(DB_RETENTION_TXN_MS >= 1 && DB_RETENTION_TXN_MS <= 1000, "retention transactions must stay short");
_Static_assert(DB_RETENTION_STEP_ROWS >= 1 && DB_RETENTION_STEP_ROWS <= DB_RETENTION_UNITS_MAX,
               "a step is part of a transaction");

typedef struct db_backup_stats {
    int64_t bytes;  /* the copy's size */
    int64_t pages;
    int schema;     /* its schema version (PRAGMA user_version) */
    double seconds; /* copy and check */
} db_backup_stats;

/* Copies the database of d (a read-only handle will do; it must not be in
 * a transaction) to a new file dest, as one snapshot: every transaction
 * committed before the call is in the copy, none committed after it
 * started. vacuum = 0 copies the pages (sqlite3 backup API, fast); 1
 * writes a compacted copy (VACUUM INTO: slower, no free pages). The copy is
 * written to a temporary file beside dest (dest.partial-XXXXXX), checked
 * with PRAGMA integrity_check, synced, and only then linked to dest, so
 * dest either does not exist or is a whole, checked copy; the temporary
 * file is removed on any failure. Returns 0 (*out filled, if not NULL),
 * -EEXIST if dest exists, -EINVAL if dest is empty or too long, or another
 * negative errno (the file system's, or the database's). */
int db_backup(db *d, const char *dest, int vacuum, db_backup_stats *out);

typedef struct db_retention_config {
    uint32_t txn_ms;    /* >= 1: work of one transaction, ms */
    uint32_t pause_ms;  /* least pause between two */
    uint32_t units_max; /* >= 1: most rows and entries one transaction removes */
} db_retention_config;

typedef struct db_retention_stats {
    double cutoff;         /* rows logged before this moment were removed: the start of the cutoff's bucket */
    uint64_t collisions;   /* rows removed */
    uint64_t segments;     /* segments removed whole */
    uint64_t groups;       /* groups removed, each with its R*Tree cell ... */
    uint64_t cells;
    uint64_t user_entries; /* ... and its user entries */
    uint32_t transactions; /* committed */
    double longest_ms;     /* the longest time one held the write lock */
} db_retention_stats;

/* Removes the collision log's rows logged before `before` (Unix seconds)
 * and their index entries, as the top of this file says, on d, a
 * read-write handle outside a transaction. Only whole buckets go: a row at
 * or after the start of before's bucket stays. cfg NULL takes the
 * defaults above. *out (required) counts what was committed, also when an
 * error ends the run part way; running again continues. Returns 0;
 * -ERANGE, nothing removed, if before is later than now -
 * DB_RETENTION_MIN_AGE_S (or not finite); -EINVAL for a cfg with txn_ms or
 * units_max 0; or the database's error. */
int db_retention(db *d, double before, const db_retention_config *cfg, db_retention_stats *out);

#endif
