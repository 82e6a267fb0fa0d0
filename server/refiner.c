#include "refiner.h"

#include <errno.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "apply.h"
#include "db.h"
#include "ecm.h"
#include "find.h"
#include "log.h"
#include "record.h"
#include "task.h"
#include "worker.h"

/* How often the change feed is read: a rollback or an offline refinement
 * reaches clients within a quarter of a second, for one indexed query. */
#define REFINER_FEED_MS 250
/* Collision rows read per query, so that one read never holds a snapshot
 * over a huge backlog for long. */
#define REFINER_READ_BATCH 65536
/* Points kept per object and version: DBSCAN over 2^20 points takes under a
 * second (tests/bench/bench_dbscan.py), 16 MiB of memory. Past it, new
 * points of that version are ignored (logged once); a refinement starts
 * the next version afresh. */
#define REFINER_POINTS_MAX (1u << 20)

/* One object whose collisions the online loop follows. */
typedef struct tracked {
    int64_t id;
    uint32_t version; /* the version in force; points are of this one only */
    int gone;         /* removed from the world */
    object_points pts;
    uint32_t fresh;   /* points added since it was last clustered */
    int full_logged;
    /* The clusters (apply.h's evidence) when a refinement last changed
     * nothing or was rejected by the judge: the same clusters again are not
     * worth a run. */
    int64_t settled;
    int has_settled;
} tracked;

struct refiner {
    refiner_config cfg;
    worker *worker; /* the thread: refiner_update * to the loop */
    db *db;
    double next_examine; /* ms, task_wall_ms; the worker's own */
    int64_t feed_after, collisions_after;
    tracked *objs; /* sorted by id */
    uint32_t nobjs, cap;
    _Atomic uint64_t rounds, versions_written; /* refiner_stats, read by the loop's thread */
};

static void tracked_reset(tracked *t, uint32_t version)
{
    t->version = version;
    t->pts.n = t->fresh = 0;
    t->full_logged = 0;
    t->has_settled = 0;
}

/* The tracked entry for id, created (with its version read from the store)
 * if new; NULL if the store cannot say. */
static tracked *track(refiner *r, int64_t id)
{
    uint32_t lo = 0, hi = r->nobjs;
    while (lo < hi) {
        uint32_t mid = lo + (hi - lo) / 2;
        if (r->objs[mid].id < id)
            lo = mid + 1;
        else
            hi = mid;
    }
    if (lo < r->nobjs && r->objs[lo].id == id)
        return &r->objs[lo];
    sqlite3_stmt *st = NULL;
    tracked t = {.id = id, .gone = 1};
    if (sqlite3_prepare_v2(db_sqlite(r->db), "SELECT ecm_version, removed_at IS NOT NULL FROM objects WHERE id = ?1",
                           -1, &st, NULL) != SQLITE_OK) {
        log_error("refiner: %s", sqlite3_errmsg(db_sqlite(r->db)));
        return NULL;
    }
    sqlite3_bind_int64(st, 1, id);
    if (sqlite3_step(st) == SQLITE_ROW) {
        t.version = (uint32_t)sqlite3_column_int64(st, 0);
        t.gone = sqlite3_column_int(st, 1);
    }
    sqlite3_finalize(st);
    if (r->nobjs == r->cap) {
        r->cap = r->cap ? r->cap * 2 : 64;
        r->objs = cvre_xrealloc(r->objs, r->cap * sizeof *r->objs);
    }
    memmove(r->objs + lo + 1, r->objs + lo, (r->nobjs - lo) * sizeof *r->objs);
    r->objs[lo] = t;
    r->nobjs++;
    return &r->objs[lo];
}

/* The change feed being read, on the worker's thread. */
typedef struct feed_read {
    refiner *r;
    worker *w; /* where the new versions go */
} feed_read;

/* One change feed event: queue the version for the tick and start the
 * object's points afresh. */
static int on_event(void *ctx, int64_t event_id, int64_t object_id, uint32_t version)
{
    feed_read *f = ctx;
    refiner *r = f->r;
    refiner_update u = {.object_id = (uint32_t)object_id, .version = version};
    if (db_ecm_boxes(r->db, object_id, version, &u.boxes, &u.count) < 0) {
        log_error("refiner: change %lld: object %lld version %u: %s", (long long)event_id, (long long)object_id,
                  version, db_error(r->db));
        return 0;
    }
    refiner_update *q = cvre_xmalloc(sizeof *q);
    *q = u;
    worker_put(f->w, q);
    tracked *t = track(r, object_id);
    if (t && version > t->version)
        tracked_reset(t, version);
    return 0;
}

static void follow_feed(refiner *r, worker *w)
{
    feed_read f = {r, w};
    if (db_ecm_events(r->db, r->feed_after, on_event, &f, &r->feed_after) < 0)
        log_error("refiner: reading the change feed: %s", db_error(r->db));
}

static void add_point(tracked *t, const float xyz[3], uint32_t user)
{
    if (t->pts.n == REFINER_POINTS_MAX) {
        if (!t->full_logged)
            log_warn("refiner: object %lld version %u: %u collisions kept, later ones ignored until it changes",
                     (long long)t->id, t->version, REFINER_POINTS_MAX);
        t->full_logged = 1;
        return;
    }
    object_points_add(&t->pts, xyz, user);
    t->fresh++;
}

/* Reads the collisions logged since the last look into the tracked objects.
 * Returns 0 or -EIO. */
static int read_collisions(refiner *r)
{
    sqlite3 *sql = db_sqlite(r->db);
    sqlite3_stmt *st = NULL;
    if (sqlite3_prepare_v2(sql,
                           "SELECT id, object_id, ecm_version, local_x, local_y, local_z, "
                           "coalesce(user_id, -session_id) FROM collisions WHERE id > ?1 ORDER BY id LIMIT ?2",
                           -1, &st, NULL) != SQLITE_OK)
        goto fail;
    for (;;) {
        sqlite3_bind_int64(st, 1, r->collisions_after);
        sqlite3_bind_int64(st, 2, REFINER_READ_BATCH);
        int rows = 0, rc;
        while ((rc = sqlite3_step(st)) == SQLITE_ROW) {
            rows++;
            r->collisions_after = sqlite3_column_int64(st, 0);
            tracked *t = track(r, sqlite3_column_int64(st, 1));
            uint32_t version = (uint32_t)sqlite3_column_int64(st, 2);
            if (!t || t->gone || version != t->version)
                continue; /* an older version's (or the object left) */
            float xyz[3] = {(float)sqlite3_column_double(st, 3), (float)sqlite3_column_double(st, 4),
                            (float)sqlite3_column_double(st, 5)};
            add_point(t, xyz, (uint32_t)sqlite3_column_int64(st, 6));
        }
        sqlite3_reset(st);
        if (rc != SQLITE_DONE)
            goto fail;
        if (rows < REFINER_READ_BATCH)
            break;
    }
    sqlite3_finalize(st);
    return 0;
fail:
    log_error("refiner: reading collisions: %s", sqlite3_errmsg(sql));
    sqlite3_finalize(st);
    return -EIO;
}

/* Clusters t's points; appends what it finds to *found. Returns the
 * clusters found, or -errno. */
static int cluster_one(refiner *r, tracked *t, cluster_found **found, size_t *nfound)
{
    float(*boxes)[6] = NULL;
    uint32_t nboxes = 0;
    int rc = db_ecm_boxes(r->db, t->id, t->version, &boxes, &nboxes);
    if (rc < 0) {
        log_error("refiner: object %lld: %s", (long long)t->id, db_error(r->db));
        return rc;
    }
    rc = cluster_find(&t->pts, &r->cfg.cluster, t->id, t->version, (const float(*)[6])boxes, nboxes, found, nfound);
    free(boxes);
    if (rc < 0)
        log_error("refiner: object %lld: clustering failed: %s", (long long)t->id, strerror(-rc));
    return rc;
}

/* Whether t's clusters (found[0..k)) are the ones a refinement last made
 * nothing of. */
static int settled_again(const tracked *t, const cluster_found *f, size_t k)
{
    return t->has_settled && t->settled == ecm_evidence(f, (uint32_t)k);
}

static void settle(tracked *t, const cluster_found *f, size_t k)
{
    t->settled = ecm_evidence(f, (uint32_t)k);
    t->has_settled = 1;
}

/* A round's ecm_apply_round callback context: the refiner, and the run
 * (set before the first object is refined). */
typedef struct round_ctx {
    refiner *r;
    int64_t run_id;
} round_ctx;

/* What became of one object of the round (ecm_round_fn): its k clusters f,
 * ecm_apply's rc and what it filled in a. */
static int refined_one(void *ctx, const cluster_found *f, uint32_t k, int rc, const ecm_applied *a, const char *err)
{
    const round_ctx *c = ctx;
    refiner *r = c->r;
    tracked *t = track(r, f[0].object_id);
    long long run_id = (long long)c->run_id;
    char figures[160];
    ecm_judge_line(&a->judge, figures, sizeof figures);
    if (rc == 0 && a->version) {
        atomic_fetch_add_explicit(&r->versions_written, 1, memory_order_relaxed);
        log_info("object %lld: collision map v%u -> v%u, %u -> %u boxes, from %u clusters of run %lld "
                 "(digitize %.1f ms, divide %.1f ms, in all %.1f ms); %s",
                 (long long)t->id, t->version, a->version, a->boxes_before, a->boxes_after, k, run_id,
                 a->stats.voxel_ms, a->stats.divide_ms, a->total_ms, figures);
    } else if (rc == 0 && a->candidate) {
        /* Not better: the same clusters would make the same candidate. */
        if (a->judged_before)
            log_info("object %lld v%u: %u clusters of run %lld are those of candidate %u, rejected before; "
                     "map unchanged",
                     (long long)t->id, t->version, k, run_id, a->candidate);
        else
            log_info("object %lld v%u: refined map (%u -> %u boxes) from %u clusters of run %lld rejected as "
                     "candidate %u, not published (%s: it must block fewer moves and let none into geometry)",
                     (long long)t->id, t->version, a->boxes_before, a->boxes_after, k, run_id, a->candidate,
                     figures);
        settle(t, f, k);
    } else if (rc == 0 && a->no_gain) {
        char why[160];
        ecm_no_gain_line(a, why, sizeof why);
        log_info("object %lld v%u: %u clusters of run %lld: map kept, not refined: %s", (long long)t->id, t->version,
                 k, run_id, why);
        settle(t, f, k);
    } else if (rc == 0) { /* unchanged */
        char why[160];
        ecm_unchanged_line(a, why, sizeof why);
        log_info("object %lld v%u: %u clusters of run %lld: map unchanged: %s", (long long)t->id, t->version, k,
                 run_id, why);
        settle(t, f, k);
    } else if (rc == -ESTALE)
        log_info("object %lld: changed while it was refined; the next round uses the new version", (long long)t->id);
    else
        log_error("refiner: %s", err);
    return 0; /* the next object's refinement does not depend on this one's */
}

/* One round of the online loop: the collisions since the last, each object
 * with new ones clustered (unless its clusters are those it settled on),
 * then recorded, refined, judged and stored (apply.h). */
static void examine(refiner *r)
{
    if (read_collisions(r) < 0)
        return;
    atomic_fetch_add_explicit(&r->rounds, 1, memory_order_relaxed);
    cluster_run run = {.started = db_now(), .params = r->cfg.cluster};
    cluster_found *found = NULL;
    size_t nfound = 0;
    for (uint32_t i = 0; i < r->nobjs; i++) {
        tracked *t = &r->objs[i];
        if (t->gone || t->fresh == 0 || t->pts.n < r->cfg.cluster.min_points)
            continue;
        t->fresh = 0;
        run.objects++;
        run.points += t->pts.n;
        size_t before = nfound;
        int k = cluster_one(r, t, &found, &nfound);
        if (k > 0 && settled_again(t, found + before, (size_t)k))
            nfound = before;
    }
    if (nfound) {
        run.finished = db_now();
        round_ctx ctx = {.r = r};
        char err[512];
        if (ecm_apply_round(r->db, &r->cfg.ecm, &run, found, nfound, 1, refined_one, &ctx, &ctx.run_id, err,
                            sizeof err) < 0)
            log_error("refiner: %s", err);
    }
    free(found);
}

/* What the worker does every REFINER_FEED_MS: follows the feed, and runs a
 * round of the online loop when one is due. */
static void every(void *ctx, worker *w)
{
    refiner *r = ctx;
    follow_feed(r, w);
    if (r->cfg.interval_s > 0 && task_wall_ms() >= r->next_examine) {
        examine(r);
        follow_feed(r, w); /* publish what this round wrote now */
        r->next_examine = task_wall_ms() + r->cfg.interval_s * 1000.0;
    }
}

static void free_update(void *p)
{
    refiner_update_free(p);
    free(p);
}

refiner *refiner_start(const refiner_config *cfg, char *err, size_t errlen)
{
    refiner *r = cvre_xcalloc(1, sizeof *r);
    r->cfg = *cfg;
    r->feed_after = cfg->feed_after;
    r->next_examine = task_wall_ms() + cfg->interval_s * 1000.0;
    r->db = db_open(cfg->db_path, DB_READWRITE, err, errlen);
    if (!r->db) {
        free(r);
        return NULL;
    }
    worker_ops ops = {.ctx = r, .every = every, .period_ms = REFINER_FEED_MS, .free_result = free_update};
    r->worker = worker_start(&ops, err, errlen);
    if (!r->worker) {
        db_close(r->db);
        free(r);
        return NULL;
    }
    return r;
}

void refiner_stop(refiner *r)
{
    if (!r)
        return;
    worker_stop(r->worker);
    for (uint32_t i = 0; i < r->nobjs; i++)
        object_points_free(&r->objs[i].pts);
    free(r->objs);
    db_close(r->db);
    free(r);
}

int refiner_fd(const refiner *r) { return worker_fd(r->worker); }

int refiner_take(refiner *r, refiner_update *out)
{
    refiner_update *u = worker_take(r->worker);
    if (!u)
        return -EAGAIN;
    *out = *u;
    free(u);
    return 0;
}

void refiner_update_free(refiner_update *u)
{
    free(u->boxes);
    u->boxes = NULL;
}

void refiner_stats_get(refiner *r, refiner_stats *out)
{
    out->rounds = atomic_load_explicit(&r->rounds, memory_order_relaxed);
    out->versions_written = atomic_load_explicit(&r->versions_written, memory_order_relaxed);
}
