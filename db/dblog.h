/*
 * dblog.h: the collision log writer. The tick thread hands over one row per
 * blocked move; a writer of its own (a base/worker.h worker, whose thread
 * has its own SQLite connection) commits them in batched transactions to
 * `collisions` and its group
 * tables `collision_groups`, `collision_cells` (the R*Tree) and
 * `collision_users` (db/migrations/0002_objects_collisions.sql).
 *
 * Data flow: tick thread --dblog_push--> bounded ring --writer thread-->
 * BEGIN IMMEDIATE; INSERT x N (+ a group for each new object, version,
 * bucket and cell, + a user entry for each new user in a group); COMMIT.
 *
 * The producer never waits on the disk or on the writer. dblog_push copies
 * the row into a single-producer / single-consumer lock-free ring (no lock,
 * no allocation, no system call except an occasional eventfd write to wake a
 * sleeping writer: worker_wake, which takes no lock either). Exactly one
 * thread may push, and the same thread (or one that joined it) calls
 * dblog_stop.
 *
 * Queue full: the row is dropped and counted. Backpressure would mean
 * stalling the tick, that is every avatar in the world, to save a log row;
 * a lost collision only thins a density cluster that thousands of others
 * make. Drops are visible in dblog_stats and logged by the writer at most once
 * per DBLOG_REPORT_MS. At a rate the writer sustains the queue never fills
 * (tests/bench/bench_logger.c); see DBLOG_QUEUE_ROWS_DEFAULT and db/README.md
 * for what it sustains.
 *
 * Commit policy: a batch is committed when it reaches batch_rows, or
 * batch_ms after its first row was seen, whichever comes first; and a
 * transaction that took longer than batch_ms makes the next ones smaller in
 * proportion (a batch is sorted before it is inserted, so it cannot be cut
 * part way), so the write lock is not held much longer than that. A
 * checkpointer (a second worker, with its own connection) checkpoints the
 * WAL beside the writer. Rows stay in
 * the ring until their transaction commits, so a failed batch is retried
 * as is: a database error (disk full, locked beyond the busy timeout, a
 * file made read-only) is logged and the same batch retried up to
 * DBLOG_ATTEMPTS times, then its rows are counted as lost, and the next
 * batch tries again, so logging resumes by itself once the cause is gone.
 * Every batch is one transaction: an error can lose a batch, never leave
 * half of one or a collision without its group.
 *
 * A database file deleted or renamed under a running writer would take
 * every later row with it (SQLite goes on writing to the unlinked file), so
 * the writer checks before each batch, and every DBLOG_CHECK_MS while
 * idle, that the path still names the file it opened; while it does not,
 * rows are counted as lost and not written, and the log says why.
 *
 * What was committed is published only after COMMIT returned
 * (dblog_stats.committed_id): a crash can lose rows still queued or in an
 * open transaction, never one at or below the committed id reported before
 * it (WAL with synchronous=NORMAL: a commit survives the process; only the
 * operating system's crash can undo the last ones).
 *
 * Error convention (as db.h): functions return 0 or a negative errno, or
 * NULL with the message in the caller's buffer.
 */
#ifndef CVRE_DBLOG_H
#define CVRE_DBLOG_H

#include <stddef.h>
#include <stdint.h>

/* Default ring capacity in rows (a power of two), 112 bytes each: 2^18 rows
 * = 28 MiB, allocated and touched at open. A queue cannot make up for a
 * writer slower than the tick on average; it carries the tick over the
 * writer's pauses (a commit, a WAL checkpoint, another process holding the
 * lock) and over bursts. 2^18 rows are 1.3 s of the 200,000 rows/s that
 * 10,000 avatars colliding on every tick at 20 Hz would log, which this
 * writer sustains on the benchmark (db/README.md) with the queue's
 * high-water mark at a sixth of it. */
#ifndef DBLOG_QUEUE_ROWS_DEFAULT
#define DBLOG_QUEUE_ROWS_DEFAULT (1u << 18)
#endif
/* Largest ring accepted: 2^24 rows = 2 GiB, more than any server should pin. */
#define DBLOG_QUEUE_ROWS_MAX (1u << 24)

/* Default rows per transaction. Each commit has fixed costs (the WAL
 * frames of the pages it touched, a segment per bucket, a sort), and the
 * segments the queries binary-search are a batch long, so fewer, larger
 * batches are cheaper to write and to read; 65536 rows would hold the write
 * lock past the time cap (DBLOG_BATCH_MS_DEFAULT) anyway. */
#ifndef DBLOG_BATCH_ROWS_DEFAULT
#define DBLOG_BATCH_ROWS_DEFAULT 16384u
#endif
/* Default time limit on a batch, twice over: a batch is committed at most
 * this long after its first row was seen, and a transaction that has been
 * inserting this long commits early with the rows it has (the rest go into
 * the next one).
 * - Under light load the log is at most this far behind the world, and a
 *   crash (not a stop) loses at most this much. Clustering runs offline on
 *   minutes of data.
 * - A transaction holds the database's write lock, and the server's tick
 *   thread writes session records through another connection: it waits for
 *   that lock. On the benchmark a quiet machine commits full 16384-row
 *   batches within 250 ms; on a loaded one (the writer descheduled half the
 *   time) a 100 ms cap cut batches to ~5000 rows and the writer's rate by a
 *   third, 250 ms by a tenth. */
#ifndef DBLOG_BATCH_MS_DEFAULT
#define DBLOG_BATCH_MS_DEFAULT 250u
#endif
#define DBLOG_BATCH_MS_MAX 60000u

/* A failing batch is tried this many times in all, DBLOG_RETRY_MS apart
 * (doubling), then its rows are lost. Each try already waits out the busy
 * timeout (db.h), so three tries ride over a long checkpoint or a slow
 * admin query holding a lock, and still give up within seconds when the
 * disk is full. */
#ifndef DBLOG_ATTEMPTS
#define DBLOG_ATTEMPTS 3u
#endif
#ifndef DBLOG_RETRY_MS
#define DBLOG_RETRY_MS 100u
#endif

/* Drops and losses are logged at most this often, so a full queue at
 * 200,000 rows/s does not turn into 200,000 log lines. */
#ifndef DBLOG_REPORT_MS
#define DBLOG_REPORT_MS 10000u
#endif
/* How often an idle writer checks that its database file is still there:
 * one stat() a second costs nothing, and an operator who deleted the file
 * learns it from the log within a second even when nobody collides. */
#ifndef DBLOG_CHECK_MS
#define DBLOG_CHECK_MS 1000u
#endif

_Static_assert((DBLOG_QUEUE_ROWS_DEFAULT & (DBLOG_QUEUE_ROWS_DEFAULT - 1)) == 0, "queue must be a power of two");
_Static_assert(DBLOG_QUEUE_ROWS_DEFAULT <= DBLOG_QUEUE_ROWS_MAX, "queue too large");
_Static_assert(DBLOG_BATCH_ROWS_DEFAULT >= 1 && DBLOG_BATCH_ROWS_DEFAULT <= DBLOG_QUEUE_ROWS_DEFAULT / 2,
               "a batch may fill at most half the queue, so the producer keeps room while it commits");
_Static_assert(DBLOG_BATCH_MS_DEFAULT >= 1 && DBLOG_BATCH_MS_DEFAULT <= DBLOG_BATCH_MS_MAX, "batch time out of range");
_Static_assert(DBLOG_ATTEMPTS >= 1 && DBLOG_ATTEMPTS <= 10, "attempts out of range");
_Static_assert(DBLOG_RETRY_MS <= 10000, "retry delay out of range");
_Static_assert(DBLOG_CHECK_MS >= 10 && DBLOG_CHECK_MS <= 60000, "file check interval out of range");

/* The collision log's groups (db/README.md, "Collision log storage"): rows
 * are gathered per object, ECM version, time bucket and cell of the world
 * contact point, and queries find the groups first.
 * - 10 s buckets: a time query reads at most 10 s of rows too many at each
 *   end, and at 200,000 rows/s a group holds many rows, so the writer adds
 *   one group (a row, an rtree entry, an index entry) per thousands of rows.
 * - 4 m cells: about an avatar's reach and a room's width, so a region
 *   query reads little outside its box while an avatar pressing against a
 *   wall stays in one or two groups per bucket.
 * Changing either changes where existing rows are looked for: both are part
 * of the schema, not tunables. */
#define DBLOG_BUCKET_S 10.0
#define DBLOG_CELL_M 4.0
/* Cells and buckets beyond these (67,000 km; 350,000 years) are clamped to
 * the last one, whose rtree box is unbounded on that side. */
#define DBLOG_CELL_MAX (INT64_C(1) << 24)
#define DBLOG_BUCKET_MAX (INT64_C(1) << 40)

typedef struct dblog dblog;

/* The time bucket of a row at Unix time at (finite): floor(at / 10 s),
 * clamped to +-DBLOG_BUCKET_MAX. Monotonic in at, so rows with
 * since <= at < until lie in buckets dblog_bucket(since) ..
 * dblog_bucket(until). */
int64_t dblog_bucket(double at);
/* The cell index of a world coordinate v (finite): floor(v / 4 m), clamped
 * to +-DBLOG_CELL_MAX. */
int64_t dblog_cell(double v);

/* One collision, as the collisions table stores it (the writer adds its id
 * and group). Coordinates are float, as the simulation computes them. */
typedef struct dblog_row {
    double at;            /* Unix seconds (db_now) */
    int64_t session_id;
    int64_t user_id;      /* users.id; 0 = unknown, stored as NULL */
    int64_t object_id;
    uint32_t avatar_id;
    uint32_t ecm_version;
    uint32_t box_index;
    uint32_t inside;      /* 1: the avatar was already inside the box */
    float avatar[3];      /* avatar position, world */
    float world[3];       /* contact point, world */
    float local[3];       /* contact point, object-local */
    float normal[3];      /* contact normal, world */
    float vel[3];         /* avatar velocity, m/s, world */
} dblog_row;

/* Zero fields take the defaults above. */
typedef struct dblog_config {
    uint32_t queue_rows; /* ring capacity: a power of two, 2..DBLOG_QUEUE_ROWS_MAX */
    uint32_t batch_rows; /* rows per transaction: 1..queue_rows/2 */
    uint32_t batch_ms;   /* 1..DBLOG_BATCH_MS_MAX: gathering a batch, and (by sizing the
                            next ones) inserting it; the last transaction, at stop,
                            takes every queued row */
} dblog_config;

/* Counters since dblog_open. After dblog_stop,
 * pushed == written + dropped + invalid + lost. */
typedef struct dblog_stats {
    uint64_t pushed;     /* dblog_push calls */
    uint64_t dropped;    /* refused by dblog_push: queue full */
    uint64_t invalid;    /* refused by dblog_push: a NaN or infinite number */
    uint64_t written;    /* committed */
    uint64_t lost;       /* in batches given up after DBLOG_ATTEMPTS failures */
    uint64_t batches;    /* committed transactions */
    uint64_t failures;   /* failed attempts (each one is logged) */
    uint64_t queued;     /* in the ring now, committed or not yet */
    uint64_t high_water; /* most rows ever in the ring */
    int64_t committed_id; /* every collision id up to this one is in the table: the
                             highest at dblog_open, then the last row of each batch
                             once its COMMIT has returned (ids have no gaps) */
    int last_error;      /* SQLite extended result code of the last failure, 0 if none;
                            sqlite3_errstr() names it (SQLITE_READONLY_DBMOVED: the file
                            was deleted or renamed) */
} dblog_stats;

/* Opens a connection to the database at path (creating and migrating it like
 * db_open(DB_READWRITE)) and one for checkpoints, prepares the statements
 * and starts the writer's and the checkpointer's workers with every signal
 * blocked. cfg may be NULL for the defaults. On
 * failure returns NULL and writes "what went wrong" to err. */
dblog *dblog_open(const char *path, const dblog_config *cfg, char *err, size_t errlen);

/* Queues a copy of *row for the writer. Never blocks and never allocates.
 * Returns 0, or a negative errno if the row was refused and counted:
 * -ENOBUFS, the queue was full (dropped); -EINVAL, a number in it is NaN or
 * infinite (invalid; the NOT NULL columns cannot hold it). Only one thread
 * may push. */
int dblog_push(dblog *log, const dblog_row *row);

/* A consistent-enough snapshot of the counters (each one is exact, they are
 * read one after the other). Safe from any thread while the log runs. */
void dblog_stats_get(const dblog *log, dblog_stats *out);

/* Stops the writer after it has written (or, on persistent errors, given up
 * on) every queued row, in one last transaction (which runs on the calling
 * thread, once the writer's worker has stopped), and frees log. Call it from
 * the pushing thread, or after that thread stopped pushing. If final is not
 * NULL it receives the last counters. Returns 0 if every row pushed and not
 * dropped was committed, -EIO if some were lost. */
int dblog_stop(dblog *log, dblog_stats *final);

#endif
