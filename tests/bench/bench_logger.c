/*
 * bench_logger: sustained throughput of the collision log writer (db/dblog.c)
 * on the real schema (collisions in sorted segments, with their groups,
 * rtree cells, user entries and segments: db/README.md), side by side in one
 * run with a bare loop of batched prepared inserts of the same rows into a
 * table without indexes. Not a test: it prints figures.
 *
 *   bench_logger [--rows N] [--repeat K] [--batch N] [--queue N] [--batch-ms MS] [--dir DIR]
 *                [--tick-rate R] [--seconds S] [--busy-ms MS] [--breakdown] [--quick]
 *
 * Workload: 10,000 avatars, each pressing against one of 1,000 objects (boxes
 * of 4-20 m spread over 1 km x 1 km), sliding along the face a little every
 * tick; every avatar collides on every tick, so a tick is 10,000 rows in
 * avatar order, as the server would log them.
 *
 * Phases, each repeated K times, interleaved so that load from other
 * processes hits them alike; the median is reported:
 *   bare    the baseline: one thread, batches of --batch rows, no indexes;
 *   dblog   a tick thread pushes the same rows through dblog_push as fast as
 *           the writer absorbs them (it waits while two batches are queued,
 *           so nothing is dropped) and does --busy-ms of work per 10,000
 *           rows; rate = rows / (first push .. dblog_stop returned);
 *   paced   the tick thread runs at 20 Hz for --seconds, each tick --busy-ms
 *           of work then --tick-rate/20 rows pushed: drops, queue high-water
 *           mark and the cost of dblog_push are what count here;
 *   push    the cost of one push: dblog_push beside a running writer, versus
 *           a queue under a mutex held for one memcpy, with a consumer
 *           taking the same lock to copy rows out.
 * --breakdown adds bare-loop runs with each part of the first, naive schema
 * (an index on time; indexes by object, user and time; an rtree row per
 * collision; all of them), to show what the real schema's design avoids;
 * --quick stops after bare and dblog.
 * Rates are wall-clock; "cpu" rates divide by the CPU time of the inserting
 * thread(s), which other load on the machine disturbs less.
 */
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <sqlite3.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "../testdb.h"
#include "dblog.h"
#include "log.h"

#define AVATARS 10000u
#define OBJECTS 1000u
#define TICK_HZ 20u
#define MAX_REPEAT 15

static const char collisions_ddl[] =
    "CREATE TABLE collisions (id INTEGER PRIMARY KEY, at REAL NOT NULL, session_id INTEGER NOT NULL, "
    "user_id INTEGER, avatar_id INTEGER NOT NULL, object_id INTEGER NOT NULL, ecm_version INTEGER NOT NULL, "
    "box_index INTEGER NOT NULL, inside INTEGER NOT NULL, avatar_x REAL NOT NULL, avatar_y REAL NOT NULL, "
    "avatar_z REAL NOT NULL, world_x REAL NOT NULL, world_y REAL NOT NULL, world_z REAL NOT NULL, "
    "local_x REAL NOT NULL, local_y REAL NOT NULL, local_z REAL NOT NULL, normal_x REAL NOT NULL, "
    "normal_y REAL NOT NULL, normal_z REAL NOT NULL, vel_x REAL NOT NULL, vel_y REAL NOT NULL, "
    "vel_z REAL NOT NULL)";
static const char time_index_ddl[] = "CREATE INDEX collisions_by_time ON collisions(at)";
static const char indexes_ddl[] = "CREATE INDEX collisions_by_object ON collisions(object_id, ecm_version, at);"
                                  "CREATE INDEX collisions_by_user ON collisions(user_id, at);"
                                  "CREATE INDEX collisions_by_time ON collisions(at)";
static const char rtree_ddl[] =
    "CREATE VIRTUAL TABLE collisions_rtree USING rtree(id, min_x, max_x, min_y, max_y, min_z, max_z)";

static struct {
    uint32_t rows, repeat, batch, queue, batch_ms, busy_ms, tick_rate, seconds;
    int breakdown, quick;
    const char *dir;
} opt = {500000, 3, 0, 0, 0, 10, 200000, 10, 0, 0, "/tmp"};

static dblog_row *rows;

static double mono(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

static double cpu(clockid_t id)
{
    struct timespec ts;
    clock_gettime(id, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

/* xorshift64*: the same rows on every run. */
static uint64_t rng = 0x9e3779b97f4a7c15u;
static double uniform(double lo, double hi)
{
    rng ^= rng >> 12;
    rng ^= rng << 25;
    rng ^= rng >> 27;
    return lo + (hi - lo) * (double)((rng * 0x2545f4914f6cdd1du) >> 11) / 9007199254740992.0;
}

static void generate(void)
{
    struct { float pos[3], half[3]; } obj[OBJECTS];
    struct { uint32_t obj; int axis; float side, at[3]; } av[AVATARS];
    for (uint32_t o = 0; o < OBJECTS; o++) {
        obj[o].pos[0] = (float)uniform(-490, 490);
        obj[o].pos[1] = 0;
        obj[o].pos[2] = (float)uniform(-490, 490);
        obj[o].half[0] = (float)uniform(2, 10);
        obj[o].half[1] = (float)uniform(1.5, 5);
        obj[o].half[2] = (float)uniform(2, 10);
    }
    for (uint32_t a = 0; a < AVATARS; a++) {
        av[a].obj = (uint32_t)uniform(0, OBJECTS);
        av[a].axis = uniform(0, 1) < 0.5 ? 0 : 2;
        av[a].side = uniform(0, 1) < 0.5 ? -1.0f : 1.0f;
        for (int k = 0; k < 3; k++)
            av[a].at[k] = (float)uniform(-1, 1);
    }
    rows = malloc((size_t)opt.rows * sizeof *rows);
    if (!rows) {
        fprintf(stderr, "bench_logger: out of memory for %u rows\n", opt.rows);
        exit(1);
    }
    for (uint32_t i = 0; i < opt.rows; i++) {
        uint32_t a = i % AVATARS, tick = i / AVATARS;
        dblog_row *r = &rows[i];
        const float *p = obj[av[a].obj].pos, *h = obj[av[a].obj].half;
        memset(r, 0, sizeof *r);
        r->at = 1795000000.0 + tick / (double)TICK_HZ + a * 1e-6;
        r->session_id = a + 1;
        r->user_id = a % 10 == 9 ? 0 : a + 1;
        r->avatar_id = 0x10000u | a;
        r->object_id = av[a].obj + 1;
        r->ecm_version = 1;
        for (int k = 0; k < 3; k++) { /* slide along the face, stay on it */
            av[a].at[k] += (float)uniform(-0.05, 0.05);
            if (av[a].at[k] < -1 || av[a].at[k] > 1)
                av[a].at[k] = (float)uniform(-1, 1);
        }
        float local[3] = {av[a].at[0] * h[0], h[1] + av[a].at[1] * h[1], av[a].at[2] * h[2]};
        local[av[a].axis] = av[a].side * h[av[a].axis];
        for (int k = 0; k < 3; k++) {
            r->local[k] = local[k];
            r->world[k] = p[k] + local[k];
            r->normal[k] = k == av[a].axis ? av[a].side : 0.0f;
            r->avatar[k] = r->world[k] + 0.3f * r->normal[k];
            r->vel[k] = -1.5f * r->normal[k] + (float)uniform(-0.2, 0.2);
        }
        r->avatar[1] = 0;
    }
}

static void fail_sql(sqlite3 *s, const char *what)
{
    fprintf(stderr, "bench_logger: %s: %s\n", what, sqlite3_errmsg(s));
    exit(1);
}

static void exec(sqlite3 *s, const char *sql)
{
    if (sqlite3_exec(s, sql, NULL, NULL, NULL) != SQLITE_OK)
        fail_sql(s, sql);
}

static void db_path(char *out, size_t len, const char *name)
{
    snprintf(out, len, "%s/bench-logger-%d-%s.db", opt.dir, (int)getpid(), name);
}

struct rate {
    double wall, cpu; /* rows per second */
};

/* Before each timed phase: write back what earlier phases left dirty in
 * the kernel's page cache (hundreds of MiB for the slow phases), so that
 * their writeback, and the throttling of writers it brings, is not billed
 * to whichever phase runs next. */
static void settle(void)
{
    sync();
}

/* The baseline, and the breakdown: batched prepared inserts in one thread,
 * pragmas as dblog's connection has them, extra DDL after the table. */
static struct rate bare(const char *name, const char *extra_ddl, int rtree)
{
    char path[512];
    db_path(path, sizeof path, name);
    testdb_remove(path);
    sqlite3 *s;
    if (sqlite3_open(path, &s) != SQLITE_OK)
        fail_sql(s, path);
    exec(s, "PRAGMA journal_mode = WAL; PRAGMA synchronous = NORMAL; PRAGMA cache_size = -65536; "
            "PRAGMA wal_autocheckpoint = 10000");
    exec(s, collisions_ddl);
    if (extra_ddl)
        exec(s, extra_ddl);
    if (rtree)
        exec(s, rtree_ddl);
    sqlite3_stmt *ins, *rt = NULL;
    if (sqlite3_prepare_v2(s,
                           "INSERT INTO collisions(at, session_id, user_id, avatar_id, object_id, ecm_version, "
                           "box_index, inside, avatar_x, avatar_y, avatar_z, world_x, world_y, world_z, local_x, "
                           "local_y, local_z, normal_x, normal_y, normal_z, vel_x, vel_y, vel_z) VALUES (?1, ?2, "
                           "?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16, ?17, ?18, ?19, ?20, "
                           "?21, ?22, ?23)",
                           -1, &ins, NULL) != SQLITE_OK)
        fail_sql(s, "prepare");
    if (rtree && sqlite3_prepare_v2(s, "INSERT INTO collisions_rtree VALUES (?1, ?2, ?2, ?3, ?3, ?4, ?4)", -1, &rt,
                                    NULL) != SQLITE_OK)
        fail_sql(s, "prepare");
    uint32_t batch = opt.batch ? opt.batch : DBLOG_BATCH_ROWS_DEFAULT;
    settle();
    double t0 = mono(), c0 = cpu(CLOCK_PROCESS_CPUTIME_ID);
    for (uint32_t i = 0; i < opt.rows; i += batch) {
        exec(s, "BEGIN IMMEDIATE");
        for (uint32_t j = i; j < i + batch && j < opt.rows; j++) {
            const dblog_row *r = &rows[j];
            sqlite3_bind_double(ins, 1, r->at);
            sqlite3_bind_int64(ins, 2, r->session_id);
            if (r->user_id)
                sqlite3_bind_int64(ins, 3, r->user_id);
            else
                sqlite3_bind_null(ins, 3);
            sqlite3_bind_int64(ins, 4, r->avatar_id);
            sqlite3_bind_int64(ins, 5, r->object_id);
            sqlite3_bind_int64(ins, 6, r->ecm_version);
            sqlite3_bind_int64(ins, 7, r->box_index);
            sqlite3_bind_int(ins, 8, r->inside != 0);
            const float *v[5] = {r->avatar, r->world, r->local, r->normal, r->vel};
            for (int k = 0; k < 5; k++)
                for (int c = 0; c < 3; c++)
                    sqlite3_bind_double(ins, 9 + 3 * k + c, v[k][c]);
            if (sqlite3_step(ins) != SQLITE_DONE)
                fail_sql(s, "insert");
            sqlite3_reset(ins);
            if (rt) {
                sqlite3_bind_int64(rt, 1, sqlite3_last_insert_rowid(s));
                for (int c = 0; c < 3; c++)
                    sqlite3_bind_double(rt, 2 + c, r->world[c]);
                if (sqlite3_step(rt) != SQLITE_DONE)
                    fail_sql(s, "rtree insert");
                sqlite3_reset(rt);
            }
        }
        exec(s, "COMMIT");
    }
    struct rate out = {opt.rows / (mono() - t0), opt.rows / (cpu(CLOCK_PROCESS_CPUTIME_ID) - c0)};
    sqlite3_finalize(ins);
    sqlite3_finalize(rt);
    sqlite3_close(s);
    testdb_remove(path);
    return out;
}

/* Simulated tick work: arithmetic the compiler cannot drop, for ms. */
static volatile double sink;
static void busy(double ms)
{
    double end = mono() + ms * 1e-3, x = 1.0;
    while (mono() < end)
        for (int i = 0; i < 1000; i++)
            x = x * 1.0000001 + 1e-9;
    sink = x;
}

static dblog *open_log(const char *name, uint32_t queue, char *path, size_t len)
{
    char err[256];
    db_path(path, len, name);
    testdb_remove(path);
    dblog_config cfg = {.queue_rows = queue, .batch_rows = opt.batch, .batch_ms = opt.batch_ms};
    dblog *l = dblog_open(path, &cfg, err, sizeof err);
    if (!l) {
        fprintf(stderr, "bench_logger: %s\n", err);
        exit(1);
    }
    return l;
}

/* The writer's sustained rate with the tick thread running: push as fast as
 * the queue takes rows without dropping any. */
static struct rate through_dblog(dblog_stats *st)
{
    char path[512];
    dblog *l = open_log("dblog", opt.queue, path, sizeof path);
    /* Keep no more than two batches queued: the last ones are written in
     * one uncapped transaction at stop, which must not flatter the rate. */
    uint32_t batch = opt.batch ? opt.batch : DBLOG_BATCH_ROWS_DEFAULT;
    uint32_t cap = opt.queue ? opt.queue : DBLOG_QUEUE_ROWS_DEFAULT;
    uint32_t high = 2 * batch < cap / 4 * 3 ? 2 * batch : cap / 4 * 3;
    settle();
    double t0 = mono(), c0 = cpu(CLOCK_PROCESS_CPUTIME_ID), p0 = cpu(CLOCK_THREAD_CPUTIME_ID);
    for (uint32_t i = 0; i < opt.rows; i++) {
        if (i % AVATARS == 0) {
            busy(opt.busy_ms);
            dblog_stats q;
            for (dblog_stats_get(l, &q); q.queued > high; dblog_stats_get(l, &q))
                usleep(1000);
        }
        dblog_push(l, &rows[i]);
    }
    double producer = cpu(CLOCK_THREAD_CPUTIME_ID) - p0;
    dblog_stop(l, st);
    double wall = mono() - t0, writer = cpu(CLOCK_PROCESS_CPUTIME_ID) - c0 - producer;
    testdb_remove(path);
    return (struct rate){(double)st->written / wall, (double)st->written / writer};
}

struct paced {
    dblog_stats st;
    double push_ns_avg, push_ns_max, tick_push_ms_max, late_ticks, seconds, rate;
};

/* The tick thread at 20 Hz: work, then one tick's rows. */
static struct paced paced(void)
{
    char path[512];
    struct paced out = {0};
    dblog *l = open_log("paced", opt.queue, path, sizeof path);
    uint32_t per_tick = opt.tick_rate / TICK_HZ, ticks = opt.seconds * TICK_HZ, i = 0;
    double period = 1.0 / TICK_HZ, next = mono(), t0 = next, total = 0;
    for (uint32_t t = 0; t < ticks; t++) {
        busy(opt.busy_ms);
        double a = mono();
        for (uint32_t k = 0; k < per_tick; k++, i = (i + 1) % opt.rows) {
            double b = (k & 1023) == 0 ? mono() : 0;
            dblog_push(l, &rows[i]);
            if (b != 0 && mono() - b > out.push_ns_max * 1e-9)
                out.push_ns_max = (mono() - b) * 1e9;
        }
        double d = mono() - a;
        total += d;
        if (d * 1e3 > out.tick_push_ms_max)
            out.tick_push_ms_max = d * 1e3;
        next += period;
        double now = mono();
        if (now > next)
            out.late_ticks++;
        else
            usleep((useconds_t)((next - now) * 1e6));
    }
    out.seconds = mono() - t0;
    out.push_ns_avg = total / ((double)ticks * per_tick) * 1e9;
    dblog_stop(l, &out.st);
    out.rate = (double)out.st.written / (mono() - t0);
    testdb_remove(path);
    return out;
}

/* The alternative to the lock-free ring: a ring under a mutex held for one
 * memcpy by the producer and for a bulk copy by the consumer. */
static struct {
    pthread_mutex_t mu;
    dblog_row ring[4096], out[4096];
    uint32_t head, tail;
    atomic_int stop;
} mq = {.mu = PTHREAD_MUTEX_INITIALIZER};

static void *mutex_consumer(void *arg)
{
    (void)arg;
    while (!atomic_load(&mq.stop)) {
        pthread_mutex_lock(&mq.mu);
        uint32_t n = 0;
        for (; mq.tail != mq.head; mq.tail++)
            memcpy(&mq.out[n++], &mq.ring[mq.tail % 4096], sizeof mq.out[0]);
        pthread_mutex_unlock(&mq.mu);
        busy(0.05 * n / 100.0); /* as if inserting, outside the lock */
    }
    return NULL;
}

static void push_cost(double *ring_avg, double *ring_max, double *mutex_avg, double *mutex_max)
{
    enum { N = 400000 };
    char path[512];
    dblog *l = open_log("push", 1u << 20, path, sizeof path); /* room for every row: no drops */
    double t0 = mono(), worst = 0;
    for (uint32_t i = 0; i < N; i++) {
        double a = mono();
        dblog_push(l, &rows[i % opt.rows]);
        double d = mono() - a;
        if (d > worst)
            worst = d;
    }
    *ring_avg = (mono() - t0) / N * 1e9;
    *ring_max = worst * 1e9;
    dblog_stop(l, NULL);
    testdb_remove(path);

    pthread_t t;
    pthread_create(&t, NULL, mutex_consumer, NULL);
    t0 = mono();
    worst = 0;
    for (uint32_t i = 0; i < N; i++) {
        double a = mono();
        pthread_mutex_lock(&mq.mu);
        if (mq.head - mq.tail < 4096)
            memcpy(&mq.ring[mq.head++ % 4096], &rows[i % opt.rows], sizeof mq.ring[0]);
        pthread_mutex_unlock(&mq.mu);
        double d = mono() - a;
        if (d > worst)
            worst = d;
    }
    *mutex_avg = (mono() - t0) / N * 1e9;
    *mutex_max = worst * 1e9;
    atomic_store(&mq.stop, 1);
    pthread_join(t, NULL);
}

static int by_value(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

static double median(double *v, uint32_t n)
{
    qsort(v, n, sizeof *v, by_value);
    return n % 2 ? v[n / 2] : (v[n / 2 - 1] + v[n / 2]) / 2;
}

static uint32_t number(const char *flag, const char *text, uint32_t lo, uint32_t hi)
{
    char *end;
    errno = 0;
    unsigned long v = strtoul(text, &end, 10);
    if (errno || end == text || *end || v < lo || v > hi) {
        fprintf(stderr, "bench_logger: %s wants a whole number from %u to %u\n", flag, lo, hi);
        exit(2);
    }
    return (uint32_t)v;
}

int main(int argc, char **argv)
{
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : "";
        if (!strcmp(a, "--rows"))
            opt.rows = number(a, v, AVATARS, 100000000), i++;
        else if (!strcmp(a, "--repeat"))
            opt.repeat = number(a, v, 1, MAX_REPEAT), i++;
        else if (!strcmp(a, "--batch"))
            opt.batch = number(a, v, 1, DBLOG_QUEUE_ROWS_MAX / 2), i++;
        else if (!strcmp(a, "--queue"))
            opt.queue = number(a, v, 2, DBLOG_QUEUE_ROWS_MAX), i++;
        else if (!strcmp(a, "--batch-ms"))
            opt.batch_ms = number(a, v, 1, DBLOG_BATCH_MS_MAX), i++;
        else if (!strcmp(a, "--busy-ms"))
            opt.busy_ms = number(a, v, 0, 40), i++;
        else if (!strcmp(a, "--tick-rate"))
            opt.tick_rate = number(a, v, TICK_HZ, 10000000), i++;
        else if (!strcmp(a, "--seconds"))
            opt.seconds = number(a, v, 1, 3600), i++;
        else if (!strcmp(a, "--dir"))
            opt.dir = v, i++;
        else if (!strcmp(a, "--breakdown"))
            opt.breakdown = 1;
        else if (!strcmp(a, "--quick"))
            opt.quick = 1;
        else {
            fprintf(stderr, "usage: bench_logger [--rows N] [--repeat K] [--batch N] [--queue N] [--batch-ms MS] [--dir DIR]\n"
                            "                    [--tick-rate R] [--seconds S] [--busy-ms MS] [--breakdown] [--quick]\n");
            return 2;
        }
    }
    log_set_level(LOG_WARN);
    generate();
    printf("bench_logger: %u rows (%u avatars x %u ticks), batch %u rows / %u ms, queue %u, SQLite %s, dir %s\n",
           opt.rows, AVATARS, opt.rows / AVATARS, opt.batch ? opt.batch : DBLOG_BATCH_ROWS_DEFAULT,
           opt.batch_ms ? opt.batch_ms : DBLOG_BATCH_MS_DEFAULT, opt.queue ? opt.queue : DBLOG_QUEUE_ROWS_DEFAULT,
           sqlite3_libversion(), opt.dir);

    enum { BARE, TIME, IDX, RTREE, ALL, DBLOG, NPHASE };
    static const char *const names[NPHASE] = {
        "bare loop, no indexes", "naive: + index on at", "naive: + 3 indexes",
        "naive: + rtree row per row", "naive: + 3 indexes + rtree", "dblog (real schema, tick running)"};
    double wall[NPHASE][MAX_REPEAT], cpus[NPHASE][MAX_REPEAT];
    uint64_t dropped = 0, batches = 0, rows_done = 0;
    for (uint32_t k = 0; k < opt.repeat; k++) {
        struct rate r[NPHASE] = {{0, 0}};
        r[BARE] = bare("bare", NULL, 0);
        dblog_stats st;
        r[DBLOG] = through_dblog(&st);
        dropped += st.dropped;
        batches += st.batches;
        rows_done += st.written;
        if (opt.breakdown) {
            r[TIME] = bare("time", time_index_ddl, 0);
            r[IDX] = bare("idx", indexes_ddl, 0);
            r[RTREE] = bare("rtree", NULL, 1);
            r[ALL] = bare("all", indexes_ddl, 1);
        }
        for (int p = 0; p < NPHASE; p++) {
            wall[p][k] = r[p].wall;
            cpus[p][k] = r[p].cpu;
        }
        printf("  run %u: bare %.0f rows/s, dblog %.0f rows/s (ratio %.2f)\n", k + 1, r[BARE].wall, r[DBLOG].wall,
               r[DBLOG].wall / r[BARE].wall);
        fflush(stdout);
    }
    printf("\nmedian of %u runs               rows/s (wall)   rows/s per CPU-second   vs bare\n", opt.repeat);
    double base_w = median(wall[BARE], opt.repeat), base_c = median(cpus[BARE], opt.repeat);
    for (int p = 0; p < NPHASE; p++) {
        if (!opt.breakdown && p != BARE && p != DBLOG)
            continue;
        double w = median(wall[p], opt.repeat), c = median(cpus[p], opt.repeat);
        printf("  %-34s %9.0f   %9.0f              %.2f (cpu %.2f)\n", names[p], w, c, w / base_w, c / base_c);
    }
    printf("  dblog: %llu dropped, %.0f rows per transaction on average\n", (unsigned long long)dropped,
           (double)rows_done / (double)(batches ? batches : 1));

    if (opt.quick) {
        free(rows);
        return 0;
    }
    struct paced pc = paced();
    printf("\npaced: %u rows/s offered (%u per tick at %u Hz, %u ms busy work per tick) for %.1f s\n",
           opt.tick_rate, opt.tick_rate / TICK_HZ, TICK_HZ, opt.busy_ms, pc.seconds);
    printf("  written %llu, dropped %llu, lost %llu, queue high-water %llu of %u, %.0f rows/s committed\n",
           (unsigned long long)pc.st.written, (unsigned long long)pc.st.dropped, (unsigned long long)pc.st.lost,
           (unsigned long long)pc.st.high_water, opt.queue ? opt.queue : DBLOG_QUEUE_ROWS_DEFAULT, pc.rate);
    printf("  dblog_push %.0f ns average, %.1f us worst sampled; one tick's pushes take %.2f ms at most; %.0f late "
           "ticks\n",
           pc.push_ns_avg, pc.push_ns_max / 1e3, pc.tick_push_ms_max, pc.late_ticks);

    double ra, rm, ma, mm;
    push_cost(&ra, &rm, &ma, &mm);
    printf("\npush cost with a consumer running: lock-free ring %.0f ns avg, %.1f us worst; "
           "mutex + memcpy %.0f ns avg, %.1f us worst\n",
           ra, rm / 1e3, ma, mm / 1e3);
    free(rows);
    return 0;
}
