/*
 * dblog.h: the collision log writer. The tick thread hands over one row per
 * blocked move; a writer thread of its own, with its own SQLite connection,
 * commits them in batched transactions to `collisions` and `collisions_rtree`
 * (db/migrations/0002_objects_collisions.sql).
 *
 * Data flow: tick thread --dblog_push--> bounded ring --writer thread-->
 * BEGIN IMMEDIATE; INSERT x N (+ one rtree row each); COMMIT.
 *
 * The producer never waits on the disk or on the writer. dblog_push copies
 * the row into a single-producer / single-consumer lock-free ring (no lock,
 * no allocation, no system call except an occasional eventfd write to wake a
 * sleeping writer). Exactly one thread may push, and the same thread (or one
 * that joined it) calls dblog_stop.
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
 * transaction that has been inserting for batch_ms commits early with what
 * it has, so the write lock is never held much longer than that. Rows stay in
 * the ring until their transaction commits, so a failed batch is retried
 * as is: a database error (disk full, locked beyond the busy timeout) is
 * logged and the same batch retried up to DBLOG_ATTEMPTS times, then its rows
 * are counted as lost. Every batch is one transaction: an error can lose a
 * batch, never leave half of one or a collision without its rtree row.
 *
 * Error convention (as db.h): functions return 0 or -1, or NULL with the
 * message in the caller's buffer.
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
 * 10,000 avatars colliding on every tick at 20 Hz would log, and 5 s at the
 * 50,000 rows/s this writer sustains on the benchmark; the benchmark's
 * high-water mark at a sustainable rate is a small fraction of it. */
#ifndef DBLOG_QUEUE_ROWS_DEFAULT
#define DBLOG_QUEUE_ROWS_DEFAULT (1u << 18)
#endif
/* Largest ring accepted: 2^24 rows = 2 GiB, more than any server should pin. */
#define DBLOG_QUEUE_ROWS_MAX (1u << 24)

/* Default rows per transaction. A commit writes every page it dirtied to the
 * WAL, and the by-object and by-user indexes dirty one leaf per distinct
 * object and user in the batch, so small batches multiply page writes: on
 * the benchmark, 4096 rows a batch run at 3/4 of the rate of 16384. 65536
 * gain another sixth but would hold the write lock for about a second, past
 * the time cap (DBLOG_BATCH_MS_DEFAULT) anyway. */
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

_Static_assert((DBLOG_QUEUE_ROWS_DEFAULT & (DBLOG_QUEUE_ROWS_DEFAULT - 1)) == 0, "queue must be a power of two");
_Static_assert(DBLOG_QUEUE_ROWS_DEFAULT <= DBLOG_QUEUE_ROWS_MAX, "queue too large");
_Static_assert(DBLOG_BATCH_ROWS_DEFAULT >= 1 && DBLOG_BATCH_ROWS_DEFAULT <= DBLOG_QUEUE_ROWS_DEFAULT / 2,
               "a batch may fill at most half the queue, so the producer keeps room while it commits");
_Static_assert(DBLOG_BATCH_MS_DEFAULT >= 1 && DBLOG_BATCH_MS_DEFAULT <= DBLOG_BATCH_MS_MAX, "batch time out of range");
_Static_assert(DBLOG_ATTEMPTS >= 1 && DBLOG_ATTEMPTS <= 10, "attempts out of range");
_Static_assert(DBLOG_RETRY_MS <= 10000, "retry delay out of range");

typedef struct dblog dblog;

/* One collision, as the collisions table stores it. Coordinates are float,
 * as the simulation computes them: the rtree keeps 32-bit floats, so a float
 * contact point is stored there exactly, as a box of zero size. */
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
    uint32_t batch_ms;   /* 1..DBLOG_BATCH_MS_MAX: gathering a batch, and inserting it
                            (the last transaction, at stop, is not cut short) */
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
    int last_error;      /* SQLite extended result code of the last failure, 0 if none;
                            sqlite3_errstr() names it */
} dblog_stats;

/* Opens a connection to the database at path (creating and migrating it like
 * db_open(DB_READWRITE)), prepares the statements and starts the writer
 * thread with every signal blocked. cfg may be NULL for the defaults. On
 * failure returns NULL and writes "what went wrong" to err. */
dblog *dblog_open(const char *path, const dblog_config *cfg, char *err, size_t errlen);

/* Queues a copy of *row for the writer. Never blocks and never allocates.
 * Returns 0, or -1 if the row was refused and counted: the queue was full
 * (dropped), or a number in it is NaN or infinite (invalid; the NOT NULL
 * columns cannot hold it). Only one thread may push. */
int dblog_push(dblog *log, const dblog_row *row);

/* A consistent-enough snapshot of the counters (each one is exact, they are
 * read one after the other). Safe from any thread while the log runs. */
void dblog_stats_get(const dblog *log, dblog_stats *out);

/* Stops the writer after it has written (or, on persistent errors, given up
 * on) every queued row, in one last transaction, and frees log. Call it from
 * the pushing thread, or after that thread stopped pushing. If final is not
 * NULL it receives the last counters. Returns 0 if every row pushed and not
 * dropped was committed, -1 if some were lost. */
int dblog_stop(dblog *log, dblog_stats *final);

#endif
