#include "dblog.h"

#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "alloc.h"
#include "db.h"
#include "err.h"
#include "log.h"
#include "task.h"
#include "worker.h"

/* Page cache of the writer's connection. The hot set is one leaf per object
 * and per user (where their index entries are appended), the rtree's inner
 * nodes and the tail of every b-tree; 64 MiB keeps them all for a world of
 * 10,000 users and objects, so a batch reads nothing back from disk. */
#ifndef DBLOG_CACHE_KIB
#define DBLOG_CACHE_KIB 65536
#endif
/* WAL pages after a commit of the writer's at which its checkpointer thread
 * runs a checkpoint (PASSIVE: readers are never blocked). The checkpoint
 * runs beside the writer, on a connection of its own, so that the writer
 * goes on inserting while the pages are copied and synced (on the
 * benchmark's disk that wait was a fifth of the writer's time). Kept at
 * SQLite's default on purpose: the trigger is per connection but the WAL is
 * shared, so if the WAL stayed past the 1000 pages at which the server's own
 * connection checkpoints, that connection's next commit would run the
 * checkpoint on the tick thread (while ours runs, its attempt returns at
 * once: a PASSIVE checkpoint does not wait for another). */
#ifndef DBLOG_WAL_AUTOCHECKPOINT
#define DBLOG_WAL_AUTOCHECKPOINT 1000
#endif
/* The smallest batch the time cap (batch_ms) shrinks transactions to: a
 * millisecond or so of inserts, so that a slow moment cannot make the
 * writer commit row by row. */
#define DBLOG_CLOCK_ROWS 256u
/* A cache line's worth of padding keeps the producer's counters, the
 * writer's and the shared wake-up flag on separate lines, so that each side's
 * writes do not evict what the other reads on every row. Padding, not
 * _Alignas: the struct comes from malloc, which promises only 16 bytes. */
#define DBLOG_CACHE_LINE 64

/* The writer remembers the groups (and the users in each) it created for
 * the current time bucket, so that it adds a group only once per object,
 * version, bucket and cell. Open addressing, cleared (by a generation bump)
 * when the bucket moves on, when half full, and after a failed batch (whose
 * groups were rolled back). Forgetting is always safe: a second group with
 * the same key is as exact as one, only a little more to read. 2^16 groups
 * are 3.5 MiB; a world with more active cells per 10 s makes a few more
 * groups, nothing worse. */
#define DBLOG_GROUP_SLOTS (1u << 16)
#define DBLOG_USER_SLOTS (1u << 17)
_Static_assert((DBLOG_GROUP_SLOTS & (DBLOG_GROUP_SLOTS - 1)) == 0, "group slots: a power of two");
/* Rows ahead whose map slots (and, once sorted, ring slots) are fetched
 * into the cache while the current one is handled: far enough to hide a
 * memory access behind the work of a few rows. */
#define DBLOG_PREFETCH 8u
_Static_assert((DBLOG_USER_SLOTS & (DBLOG_USER_SLOTS - 1)) == 0, "user slots: a power of two");

enum { ST_COLLISION, ST_GROUP, ST_CELL, ST_USER, ST_SEGMENT, ST_COUNT };

static const char *const stmt_sql[ST_COUNT] = {
    [ST_COLLISION] = "INSERT INTO collisions(id, g, at, session_id, user_id, avatar_id, object_id, ecm_version, "
                     "box_index, inside, avatar_x, avatar_y, avatar_z, world_x, world_y, world_z, local_x, local_y, "
                     "local_z, normal_x, normal_y, normal_z, vel_x, vel_y, vel_z) "
                     "VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16, ?17, ?18, "
                     "?19, ?20, ?21, ?22, ?23, ?24, ?25)",
    [ST_GROUP] = "INSERT INTO collision_groups(object_id, ecm_version, bucket, cell_x, cell_y, cell_z) "
                 "VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
    /* OR REPLACE: an rtree row left behind by a deleted group whose id is
     * handed out again must not fail every batch from then on. */
    [ST_CELL] = "INSERT OR REPLACE INTO collision_cells(g, min_x, max_x, min_y, max_y, min_z, max_z, min_t, max_t) "
                "VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)",
    [ST_USER] = "INSERT OR IGNORE INTO collision_users(user_id, g) VALUES (?1, ?2)",
    [ST_SEGMENT] = "INSERT INTO collision_segments(first_id, last_id, bucket) VALUES (?1, ?2, ?3)",
};

/* A group met in the batch being written: its sort key, and where its rows
 * go. */
struct batch_group {
    int64_t bucket, object, g;
    uint32_t version, index; /* index: in the unsorted array, for the rows to find it */
};

struct group_slot {
    int64_t object, bucket, cell[3], g;
    uint32_t version, gen;
    uint64_t batch; /* the batch that last met it (l->batch_no), and its index there */
    uint32_t in_batch, unused;
};

struct user_slot {
    int64_t user, g;
    uint32_t gen, unused;
};

struct dblog {
    /* Written by the producer only. */
    _Atomic uint64_t head; /* rows ever accepted */
    _Atomic uint64_t dropped, invalid;
    _Atomic uint64_t high_water;
    char pad1[DBLOG_CACHE_LINE];
    /* Written by the writer only. */
    _Atomic uint64_t tail; /* rows ever retired (committed or lost) */
    _Atomic uint64_t written, lost, batches, failures;
    _Atomic int64_t committed_id;
    _Atomic int last_error;
    char pad2[DBLOG_CACHE_LINE];
    /* The writer's wake-up request: 0 while it runs, otherwise the queue
     * length at which the producer must wake it (worker_wake). */
    _Atomic uint64_t wake_at;
    char pad3[DBLOG_CACHE_LINE];
    /* Set at open, read-only afterwards. */
    dblog_row *ring;
    uint64_t mask;
    uint32_t batch_rows, batch_ms;
    db *store;
    sqlite3 *sql;
    sqlite3_stmt *st[ST_COUNT];
    worker *writer;
    /* The checkpointer: its connection and worker (a job is a request). */
    sqlite3 *ckpt_sql;
    worker *ckpt;
    /* The writer's own. */
    uint64_t first_ms; /* when the oldest uncommitted row was seen; 0: none */
    uint64_t reported_dropped, reported_lost;
    uint64_t report_due_ms;
    int failing; /* a batch was lost and none has succeeded since */
    uint64_t lost_before_failing; /* l->lost when failing began */
    int moved;   /* the path no longer names the file opened (check_file) */
    uint64_t checked_ms; /* when check_file last ran */
    int64_t next_id; /* the id of the next row, as committed */
    struct group_slot *groups;
    struct user_slot *users;
    uint32_t gen, ngroups, nusers; /* slots of generation gen are in use */
    int64_t map_bucket;            /* the newest bucket seen */
    uint64_t batch_no;             /* transactions begun */
    uint32_t cap_rows;             /* rows per capped transaction, adapted to batch_ms */
    /* Per batch, batch_rows entries each: each row's group (index into bg),
     * the groups met, then sorted, and each group's next place in the
     * sorted batch. */
    uint32_t *row_group, *order, *place;
    struct batch_group *bg, *sorted;
    char errmsg[256];
};

/* Whole ms of the monotonic clock: the writer's sums and shares are in
 * integers. */
static uint64_t now_ms(void) { return (uint64_t)task_wall_ms(); }

static void sleep_ms(uint32_t ms)
{
    struct timespec ts = {.tv_sec = ms / 1000u, .tv_nsec = (long)(ms % 1000u) * 1000000L};
    while (nanosleep(&ts, &ts) != 0 && errno == EINTR)
        ;
}

/* ---- producer side ------------------------------------------------------ */

/* SQLite stores NaN as NULL, which the NOT NULL columns refuse: one such row
 * would fail its whole batch. */
static int row_is_finite(const dblog_row *r)
{
    const float *v[5] = {r->avatar, r->world, r->local, r->normal, r->vel};
    int ok = isfinite(r->at) != 0;
    for (int k = 0; k < 5; k++)
        ok &= isfinite(v[k][0]) && isfinite(v[k][1]) && isfinite(v[k][2]);
    return ok;
}

static void count(_Atomic uint64_t *counter)
{
    /* Single writer: a plain load and store, no locked instruction. */
    atomic_store_explicit(counter, atomic_load_explicit(counter, memory_order_relaxed) + 1, memory_order_relaxed);
}

int dblog_push(dblog *log, const dblog_row *row)
{
    if (!row_is_finite(row)) {
        count(&log->invalid);
        return -EINVAL;
    }
    uint64_t head = atomic_load_explicit(&log->head, memory_order_relaxed);
    uint64_t tail = atomic_load_explicit(&log->tail, memory_order_acquire);
    if (head - tail > log->mask) {
        count(&log->dropped);
        return -ENOBUFS;
    }
    memcpy(&log->ring[head & log->mask], row, sizeof *row);
    /* Sequentially consistent, with the load of wake_at below: the writer
     * stores wake_at and then loads head, so one of the two sides always
     * sees the other and a wake-up is never lost. */
    atomic_store(&log->head, head + 1);
    uint64_t used = head + 1 - tail;
    if (used > atomic_load_explicit(&log->high_water, memory_order_relaxed))
        atomic_store_explicit(&log->high_water, used, memory_order_relaxed);
    uint64_t want = atomic_load(&log->wake_at);
    if (want && used >= want && atomic_exchange(&log->wake_at, 0) != 0)
        worker_wake(log->writer);
    return 0;
}

void dblog_stats_get(const dblog *log, dblog_stats *out)
{
    uint64_t head = atomic_load_explicit(&log->head, memory_order_relaxed);
    uint64_t tail = atomic_load_explicit(&log->tail, memory_order_relaxed);
    out->dropped = atomic_load_explicit(&log->dropped, memory_order_relaxed);
    out->invalid = atomic_load_explicit(&log->invalid, memory_order_relaxed);
    out->pushed = head + out->dropped + out->invalid;
    /* The id before the count (acquire): the rows up to the id are counted
     * in written by then, so a snapshot never has the id ahead of them. */
    out->committed_id = atomic_load_explicit(&log->committed_id, memory_order_acquire);
    out->written = atomic_load_explicit(&log->written, memory_order_relaxed);
    out->lost = atomic_load_explicit(&log->lost, memory_order_relaxed);
    out->batches = atomic_load_explicit(&log->batches, memory_order_relaxed);
    out->failures = atomic_load_explicit(&log->failures, memory_order_relaxed);
    out->queued = head > tail ? head - tail : 0;
    out->high_water = atomic_load_explicit(&log->high_water, memory_order_relaxed);
    out->last_error = atomic_load_explicit(&log->last_error, memory_order_relaxed);
}

/* ---- writer side -------------------------------------------------------- */

/* Asks the producer to wake the writer once the queue holds `rows` rows.
 * Returns 1, or 0 with the request taken back when it holds them already. */
static int wake_when(dblog *l, uint64_t rows)
{
    atomic_store(&l->wake_at, rows);
    uint64_t queued = atomic_load(&l->head) - atomic_load_explicit(&l->tail, memory_order_relaxed);
    if (queued < rows)
        return 1;
    atomic_store(&l->wake_at, 0);
    return 0;
}

int64_t dblog_bucket(double at)
{
    double b = floor(at / DBLOG_BUCKET_S);
    if (!(b > (double)-DBLOG_BUCKET_MAX)) /* also NaN, which rows never hold */
        return -DBLOG_BUCKET_MAX;
    return b < (double)DBLOG_BUCKET_MAX ? (int64_t)b : DBLOG_BUCKET_MAX;
}

int64_t dblog_cell(double v)
{
    double c = floor(v / DBLOG_CELL_M);
    if (!(c > (double)-DBLOG_CELL_MAX))
        return -DBLOG_CELL_MAX;
    return c < (double)DBLOG_CELL_MAX ? (int64_t)c : DBLOG_CELL_MAX;
}

/* Forgets every remembered group and user entry. */
static void forget_groups(dblog *l)
{
    if (++l->gen == 0) { /* wrapped: slots of an old generation 0 would look current */
        memset(l->groups, 0, DBLOG_GROUP_SLOTS * sizeof *l->groups);
        memset(l->users, 0, DBLOG_USER_SLOTS * sizeof *l->users);
        l->gen = 1;
    }
    l->ngroups = l->nusers = 0;
}

static uint64_t mix(uint64_t h, uint64_t v)
{
    h ^= v + 0x9e3779b97f4a7c15u + (h << 6) + (h >> 2);
    return h * 0xff51afd7ed558ccdu;
}

static int step_done(sqlite3_stmt *st)
{
    int rc = sqlite3_step(st);
    sqlite3_reset(st);
    return rc == SQLITE_DONE ? SQLITE_OK : rc;
}

/* The key of row r's group: its bucket *b, cells c, and their hash. */
static uint64_t group_key(const dblog_row *r, int64_t *b, int64_t c[3])
{
    *b = dblog_bucket(r->at);
    for (int k = 0; k < 3; k++)
        c[k] = dblog_cell(r->world[k]);
    return mix(mix(mix(mix(mix(mix(0, (uint64_t)r->object_id), r->ecm_version), (uint64_t)*b), (uint64_t)c[0]),
                   (uint64_t)c[1]),
               (uint64_t)c[2]);
}

/* The group of row r (bucket b, cell c): the remembered one, or a new one
 * inserted with its rtree cell; and its index among the groups of this
 * batch (l->bg, *nbg of them). Returns SQLITE_OK with *bi set, or the
 * error. */
static int find_group(dblog *l, const dblog_row *r, int64_t b, const int64_t c[3], uint64_t h, uint32_t *nbg,
                      uint32_t *bi)
{
    uint32_t mask = DBLOG_GROUP_SLOTS - 1u, i = (uint32_t)(h >> 32) & mask;
    struct group_slot *sl;
    for (;; i = (i + 1u) & mask) {
        sl = &l->groups[i];
        if (sl->gen != l->gen)
            break;
        if (sl->object == r->object_id && sl->version == r->ecm_version && sl->bucket == b && sl->cell[0] == c[0] &&
            sl->cell[1] == c[1] && sl->cell[2] == c[2]) {
            if (sl->batch != l->batch_no) {
                sl->batch = l->batch_no;
                sl->in_batch = (*nbg)++;
                l->bg[sl->in_batch] = (struct batch_group){.bucket = b, .object = r->object_id, .g = sl->g,
                                                           .version = r->ecm_version, .index = sl->in_batch};
            }
            *bi = sl->in_batch;
            return SQLITE_OK;
        }
    }
    sqlite3_stmt *st = l->st[ST_GROUP];
    sqlite3_bind_int64(st, 1, r->object_id);
    sqlite3_bind_int64(st, 2, r->ecm_version);
    sqlite3_bind_int64(st, 3, b);
    for (int k = 0; k < 3; k++)
        sqlite3_bind_int64(st, 4 + k, c[k]);
    int rc = step_done(st);
    if (rc != SQLITE_OK)
        return rc;
    int64_t g = sqlite3_last_insert_rowid(l->sql);
    st = l->st[ST_CELL];
    sqlite3_bind_int64(st, 1, g);
    for (int k = 0; k < 3; k++) {
        /* The outermost cells reach to infinity (the rtree stores floats). */
        sqlite3_bind_double(st, 2 + 2 * k, c[k] == -DBLOG_CELL_MAX ? -3.0e38 : (double)c[k] * DBLOG_CELL_M);
        sqlite3_bind_double(st, 3 + 2 * k, c[k] == DBLOG_CELL_MAX ? 3.0e38 : (double)(c[k] + 1) * DBLOG_CELL_M);
    }
    sqlite3_bind_double(st, 8, b == -DBLOG_BUCKET_MAX ? -3.0e38 : (double)b * DBLOG_BUCKET_S);
    sqlite3_bind_double(st, 9, b == DBLOG_BUCKET_MAX ? 3.0e38 : (double)(b + 1) * DBLOG_BUCKET_S);
    rc = step_done(st);
    if (rc != SQLITE_OK)
        return rc;
    *bi = (*nbg)++;
    l->bg[*bi] = (struct batch_group){.bucket = b, .object = r->object_id, .g = g, .version = r->ecm_version,
                                      .index = *bi};
    if (l->ngroups >= DBLOG_GROUP_SLOTS / 2) {
        forget_groups(l);
        return SQLITE_OK;
    }
    l->ngroups++;
    *sl = (struct group_slot){.object = r->object_id, .bucket = b, .cell = {c[0], c[1], c[2]}, .g = g,
                              .version = r->ecm_version, .gen = l->gen, .batch = l->batch_no, .in_batch = *bi};
    return SQLITE_OK;
}

/* Records that group g holds a row of user u, once per group. h is
 * mix(group key hash, u): the same for the same user and group. */
static int note_user(dblog *l, int64_t u, int64_t g, uint64_t h)
{
    uint32_t mask = DBLOG_USER_SLOTS - 1u, i = (uint32_t)(h >> 32) & mask;
    for (;; i = (i + 1u) & mask) {
        struct user_slot *sl = &l->users[i];
        if (sl->gen != l->gen)
            break;
        if (sl->user == u && sl->g == g)
            return SQLITE_OK;
    }
    sqlite3_stmt *st = l->st[ST_USER];
    sqlite3_bind_int64(st, 1, u);
    sqlite3_bind_int64(st, 2, g);
    int rc = step_done(st);
    if (rc != SQLITE_OK)
        return rc;
    if (l->nusers >= DBLOG_USER_SLOTS / 2) {
        forget_groups(l);
        return SQLITE_OK;
    }
    l->nusers++;
    l->users[i] = (struct user_slot){.user = u, .g = g, .gen = l->gen};
    return SQLITE_OK;
}

/* Inserts one queued row under the given id and group. Returns SQLITE_OK
 * or the error code. */
static int insert_row(dblog *l, const dblog_row *r, int64_t id, int64_t g)
{
    sqlite3_stmt *st = l->st[ST_COLLISION];
    sqlite3_bind_int64(st, 1, id);
    sqlite3_bind_int64(st, 2, g);
    sqlite3_bind_double(st, 3, r->at);
    sqlite3_bind_int64(st, 4, r->session_id);
    if (r->user_id)
        sqlite3_bind_int64(st, 5, r->user_id);
    else
        sqlite3_bind_null(st, 5);
    sqlite3_bind_int64(st, 6, r->avatar_id);
    sqlite3_bind_int64(st, 7, r->object_id);
    sqlite3_bind_int64(st, 8, r->ecm_version);
    sqlite3_bind_int64(st, 9, r->box_index);
    sqlite3_bind_int(st, 10, r->inside != 0);
    const float *v[5] = {r->avatar, r->world, r->local, r->normal, r->vel};
    for (int k = 0; k < 5; k++)
        for (int i = 0; i < 3; i++)
            sqlite3_bind_double(st, 11 + 3 * k + i, v[k][i]);
    return step_done(st);
}

/* The order of a segment: bucket, object, version, group. */
static int by_key(const void *pa, const void *pb)
{
    const struct batch_group *a = pa, *b = pb;
    if (a->bucket != b->bucket)
        return a->bucket < b->bucket ? -1 : 1;
    if (a->object != b->object)
        return a->object < b->object ? -1 : 1;
    if (a->version != b->version)
        return a->version < b->version ? -1 : 1;
    return a->g < b->g ? -1 : a->g > b->g;
}

/* Writes rows [from, from + n) of the ring inside the open transaction:
 * finds (or makes) each row's group and user entry, sorts the batch by
 * (bucket, object, version, group), and inserts it as one id range from
 * l->next_id with one segment per bucket. Returns SQLITE_OK or the error. */
static int write_rows(dblog *l, uint64_t from, uint32_t n)
{
    uint32_t nbg = 0;
    int rc = SQLITE_OK;
    l->batch_no++;
    for (uint32_t i = 0; rc == SQLITE_OK && i < n; i++) {
        int64_t b, c[3];
        if (i + DBLOG_PREFETCH < n) { /* the slots a later row will probe: cache misses otherwise */
            const dblog_row *q = &l->ring[(from + i + DBLOG_PREFETCH) & l->mask];
            uint64_t hq = group_key(q, &b, c);
            __builtin_prefetch(&l->groups[(uint32_t)(hq >> 32) & (DBLOG_GROUP_SLOTS - 1u)]);
            __builtin_prefetch(&l->users[(uint32_t)(mix(hq, (uint64_t)q->user_id) >> 32) & (DBLOG_USER_SLOTS - 1u)]);
        }
        const dblog_row *r = &l->ring[(from + i) & l->mask];
        uint64_t h = group_key(r, &b, c);
        if (b > l->map_bucket) { /* the groups of older buckets are closed */
            forget_groups(l);
            l->map_bucket = b;
        }
        rc = find_group(l, r, b, c, h, &nbg, &l->row_group[i]);
        if (rc == SQLITE_OK && r->user_id)
            rc = note_user(l, r->user_id, l->bg[l->row_group[i]].g, mix(h, (uint64_t)r->user_id));
    }
    if (rc != SQLITE_OK)
        return rc;
    /* Counting sort of the rows by their group's rank. */
    memcpy(l->sorted, l->bg, nbg * sizeof *l->bg);
    qsort(l->sorted, nbg, sizeof *l->sorted, by_key);
    memset(l->place, 0, nbg * sizeof *l->place);
    for (uint32_t i = 0; i < n; i++)
        l->place[l->row_group[i]]++;
    uint32_t at = 0;
    for (uint32_t k = 0; k < nbg; k++) {
        uint32_t idx = l->sorted[k].index, cnt = l->place[idx];
        l->place[idx] = at;
        at += cnt;
    }
    for (uint32_t i = 0; i < n; i++)
        l->order[l->place[l->row_group[i]]++] = i;
    int64_t id0 = l->next_id, seg_first = id0;
    for (uint32_t i = 0; rc == SQLITE_OK && i < n; i++) {
        if (i + DBLOG_PREFETCH < n)
            __builtin_prefetch(&l->ring[(from + l->order[i + DBLOG_PREFETCH]) & l->mask]);
        uint32_t ri = l->order[i];
        const struct batch_group *grp = &l->bg[l->row_group[ri]];
        rc = insert_row(l, &l->ring[(from + ri) & l->mask], id0 + i, grp->g);
        uint32_t next = i + 1 < n ? l->row_group[l->order[i + 1]] : UINT32_MAX;
        if (rc == SQLITE_OK && (next == UINT32_MAX || l->bg[next].bucket != grp->bucket)) {
            sqlite3_stmt *st = l->st[ST_SEGMENT];
            sqlite3_bind_int64(st, 1, seg_first);
            sqlite3_bind_int64(st, 2, id0 + i);
            sqlite3_bind_int64(st, 3, grp->bucket);
            rc = step_done(st);
            seg_first = id0 + i + 1;
        }
    }
    return rc;
}

/* The system's reason for an I/O error, 0 if unknown: an I/O error says
 * little without it (EPERM: the file was made immutable; EROFS: its file
 * system went read-only). SQLite's copy of errno (sqlite3_system_errno) is
 * often overwritten by the time the error reaches us, so the WAL's and the
 * database file's handles are asked for the last one they met. */
static int io_errno(sqlite3 *sql)
{
    int e = sqlite3_system_errno(sql);
    sqlite3_file *wal = NULL;
    if (!e && sqlite3_file_control(sql, "main", SQLITE_FCNTL_JOURNAL_POINTER, &wal) == SQLITE_OK && wal &&
        wal->pMethods)
        wal->pMethods->xFileControl(wal, SQLITE_FCNTL_LAST_ERRNO, &e);
    if (!e)
        sqlite3_file_control(sql, "main", SQLITE_FCNTL_LAST_ERRNO, &e);
    return e;
}

/* One attempt at committing rows [from, from + *n) of the ring in one
 * transaction. With a time cap (cap_ms > 0) the transaction takes at most
 * l->cap_rows rows, setting *n to that count, and cap_rows follows the time
 * the last capped transaction took: a sorted batch cannot be cut short part
 * way, so the cap is kept by sizing batches. Committed, the rows are
 * counted in written and their last id is published in committed_id. On
 * failure the transaction is rolled back, so the database holds all of the
 * batch or none of it, and the message is kept in l->errmsg. Returns
 * SQLITE_OK or the extended error code. */
static int write_batch(dblog *l, uint64_t from, uint64_t *n, uint32_t cap_ms)
{
    uint64_t start = now_ms();
    if (cap_ms && *n > l->cap_rows)
        *n = l->cap_rows;
    int rc = sqlite3_exec(l->sql, "BEGIN IMMEDIATE", NULL, NULL, NULL);
    if (rc == SQLITE_OK)
        rc = write_rows(l, from, (uint32_t)*n);
    if (rc == SQLITE_OK)
        rc = sqlite3_exec(l->sql, "COMMIT", NULL, NULL, NULL);
    if (rc == SQLITE_OK) {
        l->next_id += (int64_t)*n;
        /* Counted before the id is published. Release: whoever reads this
         * id may count on the rows up to it, in the table and in written. */
        atomic_fetch_add_explicit(&l->written, *n, memory_order_relaxed);
        atomic_store_explicit(&l->committed_id, l->next_id - 1, memory_order_release);
        uint64_t took = now_ms() - start;
        if (cap_ms && took > cap_ms) {
            uint64_t rows = (uint64_t)l->cap_rows * cap_ms / took;
            l->cap_rows = rows < DBLOG_CLOCK_ROWS ? DBLOG_CLOCK_ROWS : (uint32_t)rows;
        } else if (cap_ms && took < cap_ms / 2 && *n == l->cap_rows) {
            l->cap_rows = l->cap_rows > l->batch_rows / 2 ? l->batch_rows : l->cap_rows * 2;
        }
        return SQLITE_OK;
    }
    forget_groups(l); /* the groups this transaction made are rolled back */
    rc = sqlite3_extended_errcode(l->sql);
    int sys = (rc & 0xff) == SQLITE_IOERR || (rc & 0xff) == SQLITE_CANTOPEN ? io_errno(l->sql) : 0;
    if (sys)
        snprintf(l->errmsg, sizeof l->errmsg, "%s (%s)", sqlite3_errmsg(l->sql), strerror(sys));
    else
        snprintf(l->errmsg, sizeof l->errmsg, "%s", sqlite3_errmsg(l->sql));
    if (!sqlite3_get_autocommit(l->sql))
        sqlite3_exec(l->sql, "ROLLBACK", NULL, NULL, NULL);
    return rc;
}

/* Whether the database's path no longer names the file the writer opened
 * (deleted, or renamed and maybe replaced): SQLite's SQLITE_FCNTL_HAS_MOVED,
 * one stat(). Logs each change, so the error is said once, when it happens. */
static int check_file(dblog *l)
{
    int moved = 0;
    l->checked_ms = now_ms();
    if (sqlite3_file_control(l->sql, "main", SQLITE_FCNTL_HAS_MOVED, &moved) != SQLITE_OK)
        moved = 0; /* a VFS that cannot tell */
    const char *path = sqlite3_db_filename(l->sql, "main");
    if (moved && !l->moved)
        log_error("collision log: database file %s was deleted or replaced while the server runs: collisions are "
                  "counted as lost, not stored, until that file is back (restart the server to log to a new one)",
                  path);
    else if (!moved && l->moved)
        log_info("collision log: database file %s is back", path);
    l->moved = moved;
    return moved;
}

/* Counts n rows as lost to the failure rc, and says so: one by one until a
 * batch is lost, then summed up by report() until a batch succeeds again. */
static void lose_rows(dblog *l, uint64_t n, int rc)
{
    atomic_store_explicit(&l->last_error, rc, memory_order_relaxed);
    atomic_fetch_add_explicit(&l->lost, n, memory_order_relaxed);
    if (!l->failing) {
        log_error("collision log: %llu rows lost; further failures are reported every %u s",
                  (unsigned long long)n, DBLOG_REPORT_MS / 1000u);
        l->lost_before_failing = atomic_load_explicit(&l->lost, memory_order_relaxed) - n;
        l->reported_lost += n; /* said just now: report() starts after these */
        l->report_due_ms = now_ms() + DBLOG_REPORT_MS;
    }
    l->failing = 1;
}

/* Commits up to n of the oldest queued rows (fewer if batch_ms has shrunk
 * transactions; the last one, at stop, takes all), retrying a failed batch,
 * and retires them from the ring, written or lost. Failures are logged one
 * by one until a batch is lost; from then on, until a batch succeeds again,
 * report() sums them up, so a full disk does not flood the log. While the
 * database file is gone (check_file) nothing is tried. */
static void commit_rows(dblog *l, uint64_t n, int stopping)
{
    uint64_t tail = atomic_load_explicit(&l->tail, memory_order_relaxed);
    uint32_t delay = DBLOG_RETRY_MS;
    for (uint32_t attempt = 1;; attempt++) {
        if (check_file(l)) {
            atomic_fetch_add_explicit(&l->failures, 1, memory_order_relaxed);
            snprintf(l->errmsg, sizeof l->errmsg, "the database file was deleted or replaced");
            lose_rows(l, n, SQLITE_READONLY_DBMOVED);
            break;
        }
        int rc = write_batch(l, tail, &n, stopping ? 0 : l->batch_ms);
        if (rc == SQLITE_OK) {
            atomic_fetch_add_explicit(&l->batches, 1, memory_order_relaxed);
            if (l->failing)
                log_info("collision log: writing again; %llu rows were lost while it failed",
                         (unsigned long long)(atomic_load_explicit(&l->lost, memory_order_relaxed) -
                                              l->lost_before_failing));
            l->failing = 0;
            break;
        }
        atomic_fetch_add_explicit(&l->failures, 1, memory_order_relaxed);
        atomic_store_explicit(&l->last_error, rc, memory_order_relaxed);
        if (!l->failing)
            log_error("collision log: batch of %llu rows to %s failed (attempt %u of %u): %s",
                      (unsigned long long)n, sqlite3_db_filename(l->sql, "main"), attempt, DBLOG_ATTEMPTS,
                      l->errmsg);
        if (attempt == DBLOG_ATTEMPTS) {
            lose_rows(l, n, rc);
            break;
        }
        sleep_ms(delay);
        delay *= 2;
    }
    /* Release: the producer may reuse these slots only after we read them. */
    atomic_store_explicit(&l->tail, tail + n, memory_order_release);
}

/* Logs drops and losses since the last report, at most once per
 * DBLOG_REPORT_MS unless forced (at stop). */
static void report(dblog *l, int force)
{
    uint64_t now = now_ms();
    if (!force && now < l->report_due_ms)
        return;
    uint64_t dropped = atomic_load_explicit(&l->dropped, memory_order_relaxed) - l->reported_dropped;
    uint64_t lost = atomic_load_explicit(&l->lost, memory_order_relaxed) - l->reported_lost;
    if (dropped)
        log_warn("collision log: %llu rows dropped since the last report: the queue (%llu rows) was full",
                 (unsigned long long)dropped, (unsigned long long)l->mask + 1u);
    if (lost)
        log_error("collision log: %llu rows lost to database errors since the last report (last: %s)",
                  (unsigned long long)lost, l->errmsg);
    if (!dropped && !lost)
        return;
    l->reported_dropped += dropped;
    l->reported_lost += lost;
    l->report_due_ms = now + DBLOG_REPORT_MS;
}

/* The writer, called on its worker's thread when the producer wakes it
 * (wake_when), when a batch's time is up (worker_due) and every
 * DBLOG_CHECK_MS while idle. It commits until it must wait for rows: for a
 * first one, or until the batch is full or its time is up. The last
 * transaction, at stop, is dblog_stop's. */
static void writer_every(void *ctx, worker *w)
{
    dblog *l = ctx;
    atomic_store(&l->wake_at, 0);
    for (;;) {
        uint64_t queued = atomic_load_explicit(&l->head, memory_order_acquire) -
                          atomic_load_explicit(&l->tail, memory_order_relaxed);
        uint64_t now = now_ms();
        if (queued == 0) {
            l->first_ms = 0;
            if (now - l->checked_ms >= DBLOG_CHECK_MS)
                check_file(l);
            if (wake_when(l, 1))
                return; /* and again DBLOG_CHECK_MS from now: the period */
            continue;
        }
        if (!l->first_ms)
            l->first_ms = now;
        uint64_t due = l->first_ms + l->batch_ms;
        if (queued >= l->batch_rows) {
            commit_rows(l, l->batch_rows, 0);
        } else if (now >= due) {
            commit_rows(l, queued, 0);
        } else {
            if (wake_when(l, l->batch_rows)) {
                worker_due(w, (unsigned)(due - now));
                return;
            }
            continue;
        }
        /* Rows still queued arrived after `now`, at the earliest. */
        l->first_ms = now;
        report(l, 0);
    }
}

/* ---- checkpointer ------------------------------------------------------- */

/* SQLite calls this after each commit of the writer's connection, with the
 * WAL's size in pages; it replaces the connection's own autocheckpoint. */
static int on_wal_commit(void *arg, sqlite3 *conn, const char *name, int pages)
{
    (void)conn, (void)name;
    dblog *l = arg;
    static const char request = 1;
    if (pages >= DBLOG_WAL_AUTOCHECKPOINT)
        (void)worker_submit(l->ckpt, &request); /* -EBUSY: one is waiting already */
    return SQLITE_OK;
}

/* The checkpointer's job: one PASSIVE checkpoint. Its failures (SQLITE_BUSY
 * while another checkpoint runs) are harmless: the next commit asks again. */
static void *checkpoint(void *ctx, void *job)
{
    (void)job;
    dblog *l = ctx;
    sqlite3_wal_checkpoint_v2(l->ckpt_sql, NULL, SQLITE_CHECKPOINT_PASSIVE, NULL, NULL);
    return NULL;
}

/* ---- life cycle --------------------------------------------------------- */

static int check_config(const dblog_config *cfg, char *err, size_t errlen)
{
    if (cfg->queue_rows < 2 || cfg->queue_rows > DBLOG_QUEUE_ROWS_MAX || (cfg->queue_rows & (cfg->queue_rows - 1)))
        return cvre_fail(err, errlen, -EINVAL, "queue_rows %u is not a power of two from 2 to %u", cfg->queue_rows,
                         DBLOG_QUEUE_ROWS_MAX);
    if (cfg->batch_rows < 1 || cfg->batch_rows > cfg->queue_rows / 2)
        return cvre_fail(err, errlen, -EINVAL, "batch_rows %u is not from 1 to half the queue (%u)", cfg->batch_rows,
                         cfg->queue_rows / 2);
    if (cfg->batch_ms < 1 || cfg->batch_ms > DBLOG_BATCH_MS_MAX)
        return cvre_fail(err, errlen, -EINVAL, "batch_ms %u is not from 1 to %u", cfg->batch_ms, DBLOG_BATCH_MS_MAX);
    return 0;
}

/* Stops the workers (the writer must be idle: stopped already, or never
 * woken) and frees what dblog_open took. */
static void destroy(dblog *l)
{
    worker_stop(l->writer);
    worker_stop(l->ckpt);
    sqlite3_close(l->ckpt_sql);
    for (int i = 0; i < ST_COUNT; i++)
        sqlite3_finalize(l->st[i]);
    db_close(l->store);
    free(l->groups);
    free(l->users);
    free(l->row_group);
    free(l->order);
    free(l->place);
    free(l->bg);
    free(l->sorted);
    free(l->ring);
    free(l);
}

dblog *dblog_open(const char *path, const dblog_config *cfg, char *err, size_t errlen)
{
    dblog_config c = cfg ? *cfg : (dblog_config){0};
    if (!c.queue_rows)
        c.queue_rows = DBLOG_QUEUE_ROWS_DEFAULT;
    if (!c.batch_rows)
        c.batch_rows = c.queue_rows / 2 < DBLOG_BATCH_ROWS_DEFAULT ? c.queue_rows / 2 : DBLOG_BATCH_ROWS_DEFAULT;
    if (!c.batch_ms)
        c.batch_ms = DBLOG_BATCH_MS_DEFAULT;
    if (check_config(&c, err, errlen) < 0)
        return NULL;

    dblog *l = cvre_calloc(1, sizeof *l);
    if (!l) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    l->mask = c.queue_rows - 1u;
    l->batch_rows = c.batch_rows;
    l->batch_ms = c.batch_ms;
    l->ring = cvre_malloc((size_t)c.queue_rows * sizeof *l->ring);
    if (!l->ring) {
        snprintf(err, errlen, "out of memory for a queue of %u rows", c.queue_rows);
        goto fail;
    }
    /* Touch every page now, so that the tick thread never takes a page
     * fault the first time it goes round the ring. */
    memset(l->ring, 0, (size_t)c.queue_rows * sizeof *l->ring);
    l->groups = cvre_calloc(DBLOG_GROUP_SLOTS, sizeof *l->groups);
    l->users = cvre_calloc(DBLOG_USER_SLOTS, sizeof *l->users);
    /* The last transaction, at stop, takes every queued row. */
    l->row_group = cvre_malloc((size_t)c.queue_rows * sizeof *l->row_group);
    l->order = cvre_malloc((size_t)c.queue_rows * sizeof *l->order);
    l->place = cvre_malloc((size_t)c.queue_rows * sizeof *l->place);
    l->bg = cvre_malloc((size_t)c.queue_rows * sizeof *l->bg);
    l->sorted = cvre_malloc((size_t)c.queue_rows * sizeof *l->sorted);
    if (!l->groups || !l->users || !l->row_group || !l->order || !l->place || !l->bg || !l->sorted) {
        snprintf(err, errlen, "out of memory for the group map");
        goto fail;
    }
    l->cap_rows = c.batch_rows;
    l->gen = 1;
    l->map_bucket = -DBLOG_BUCKET_MAX;
    l->store = db_open(path, DB_READWRITE, err, errlen);
    if (!l->store)
        goto fail;
    l->sql = db_sqlite(l->store);
    char pragmas[128];
    snprintf(pragmas, sizeof pragmas, "PRAGMA cache_size = -%d", DBLOG_CACHE_KIB);
    if (sqlite3_exec(l->sql, pragmas, NULL, NULL, NULL) != SQLITE_OK) {
        snprintf(err, errlen, "%s: %s", path, sqlite3_errmsg(l->sql));
        goto fail;
    }
    if (sqlite3_open_v2(path, &l->ckpt_sql, SQLITE_OPEN_READWRITE, NULL) != SQLITE_OK ||
        sqlite3_exec(l->ckpt_sql, "PRAGMA synchronous = NORMAL", NULL, NULL, NULL) != SQLITE_OK) {
        snprintf(err, errlen, "%s: checkpointer: %s", path, l->ckpt_sql ? sqlite3_errmsg(l->ckpt_sql) : "out of memory");
        goto fail;
    }
    for (int i = 0; i < ST_COUNT; i++)
        if (sqlite3_prepare_v3(l->sql, stmt_sql[i], -1, SQLITE_PREPARE_PERSISTENT, &l->st[i], NULL) != SQLITE_OK) {
            snprintf(err, errlen, "%s: prepare: %s", path, sqlite3_errmsg(l->sql));
            goto fail;
        }

    sqlite3_stmt *q;
    if (sqlite3_prepare_v2(l->sql, "SELECT coalesce(max(id), 0) + 1 FROM collisions", -1, &q, NULL) != SQLITE_OK ||
        sqlite3_step(q) != SQLITE_ROW) {
        snprintf(err, errlen, "%s: cannot read the last collision id: %s", path, sqlite3_errmsg(l->sql));
        sqlite3_finalize(q);
        goto fail;
    }
    l->next_id = sqlite3_column_int64(q, 0);
    sqlite3_finalize(q);
    atomic_store_explicit(&l->committed_id, l->next_id - 1, memory_order_relaxed);

    /* The workers take no signals: a server that reads them from a
     * signalfd must find them pending, not delivered to these threads. The
     * first row wakes the writer. */
    sigset_t all, old;
    sigfillset(&all);
    pthread_sigmask(SIG_SETMASK, &all, &old);
    const worker_ops ckpt_ops = {.job_size = 1, .queue_max = 1, .run = checkpoint, .ctx = l};
    const worker_ops writer_ops = {.every = writer_every, .period_ms = DBLOG_CHECK_MS, .ctx = l};
    char why[160] = "";
    l->ckpt = worker_start(&ckpt_ops, why, sizeof why);
    if (l->ckpt) {
        sqlite3_wal_hook(l->sql, on_wal_commit, l);
        atomic_store(&l->wake_at, 1);
        l->writer = worker_start(&writer_ops, why, sizeof why);
    }
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    if (!l->writer) {
        snprintf(err, errlen, "cannot start the collision log's workers: %s", why);
        goto fail;
    }
    return l;
fail:
    destroy(l);
    return NULL;
}

int dblog_stop(dblog *log, dblog_stats *final)
{
    /* The writer finishes what it is doing; the rows still queued go into
     * one last transaction, on this thread (the pushing one, or after it). */
    worker_stop(log->writer);
    log->writer = NULL;
    uint64_t queued = atomic_load_explicit(&log->head, memory_order_acquire) -
                      atomic_load_explicit(&log->tail, memory_order_relaxed);
    if (queued)
        commit_rows(log, queued, 1);
    report(log, 1);
    worker_stop(log->ckpt);
    log->ckpt = NULL;
    dblog_stats s;
    dblog_stats_get(log, &s);
    if (final)
        *final = s;
    destroy(log);
    return s.lost ? -EIO : 0;
}
