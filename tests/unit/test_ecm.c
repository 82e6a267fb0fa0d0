/* ECM versions in the store (db/ecm.c): the write/read round trip, version
 * numbering (also after a rollback and after a version in force was moved
 * back by hand), stale parents and removed objects, input checks, the change
 * feed, loading one object, the migration from schema 3, and the error
 * paths: out of memory, a lock held elsewhere, a failure in mid-transaction,
 * a read-only handle, corrupted rows. Every refusal must leave the tables as
 * they were and the connection usable. */
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "alloc.h"
#include "../testdb.h"
#include "db.h"
#include "ecm.h"
#include "migrations.h"
#include "proto.h"

/* The store's cap is the wire's: ecm.h cannot see proto.h, this file sees
 * both. */
_Static_assert(DB_ECM_BOXES_MAX == PROTO_OBJECT_BOXES_MAX, "a version must fit one OBJECT_INFO");

static char path[64];

static int64_t scalar(db *d, const char *sql)
{
    return testdb_scalar(db_sqlite(d), sql);
}

static int setup(void **state)
{
    (void)state;
    snprintf(path, sizeof path, "/tmp/cvre-test-ecm-%d.sqlite", (int)getpid());
    unlink(path);
    return 0;
}

static int teardown(void **state)
{
    (void)state;
    cvre_alloc_fail_after(-1);
    testdb_remove(path);
    return 0;
}

static void sql(db *d, const char *text)
{
    char *msg = NULL;
    int rc = sqlite3_exec(db_sqlite(d), text, NULL, NULL, &msg);
    if (rc != SQLITE_OK)
        fail_msg("%s: %s", text, msg ? msg : "?");
}

static db *open_rw(void)
{
    char err[256];
    db *d = db_open(path, DB_READWRITE, err, sizeof err);
    if (!d)
        fail_msg("%s", err);
    return d;
}

/* Two triangles, and version 1's one box (the MBR), as an import makes. */
static const float TRIS[18] = {0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 3, 1, 2, 3, -1, 0.5f, 0};
static const float MBR[1][6] = {{-1, 0, 0, 1, 2, 3}};

static int64_t make_object(db *d, const char *name)
{
    db_object o = {.owner = "ann", .name = name, .format = "obj", .scale = 1, .tri_count = 2, .tris = TRIS,
                   .min = {-1, 0, 0}, .max = {1, 2, 3}, .box_count = 1, .boxes = MBR};
    assert_int_equal(db_object_create(d, &o, 1000.0), 0);
    return o.id;
}

/* A cluster run with clusters 0..n-1 of object `object`. */
static void make_run(db *d, int64_t run, int64_t object, int n)
{
    char text[512];
    snprintf(text, sizeof text,
             "INSERT INTO cluster_runs(id, started_at, finished_at, eps, min_points, min_users, objects, points, "
             "clusters, problem_boxes) VALUES (%lld, 1, 2, 0.5, 5, 3, 1, 100, %d, 1)",
             (long long)run, n);
    sql(d, text);
    for (int i = 0; i < n; i++) {
        snprintf(text, sizeof text,
                 "INSERT INTO clusters VALUES (%lld, %lld, 1, %d, 10, 3, 0, 0, 0, 0, 0, 0, 1, 1, 1, 0)",
                 (long long)run, (long long)object, i);
        sql(d, text);
    }
}

/* Row counts of everything a write touches, to show that a refusal wrote
 * nothing. */
typedef struct counts {
    int64_t versions, boxes, ties, events, in_force;
} counts;

static counts count(db *d, int64_t object)
{
    char text[128];
    snprintf(text, sizeof text, "SELECT ecm_version FROM objects WHERE id = %lld", (long long)object);
    return (counts){scalar(d, "SELECT count(*) FROM ecm_versions"), scalar(d, "SELECT count(*) FROM ecm_boxes"),
                    scalar(d, "SELECT count(*) FROM ecm_version_clusters"), scalar(d, "SELECT count(*) FROM ecm_events"),
                    scalar(d, text)};
}

static void assert_counts(counts a, counts b)
{
    assert_int_equal(a.versions, b.versions);
    assert_int_equal(a.boxes, b.boxes);
    assert_int_equal(a.ties, b.ties);
    assert_int_equal(a.events, b.events);
    assert_int_equal(a.in_force, b.in_force);
}

static const float THREE[3][6] = {{-1, 0, 0, 0, 2, 3}, {0, 0, 0, 1, 1, 3}, {0.125f, 1.0f / 3.0f, 0, 1, 2, 1e-7f}};

static void assert_boxes(db *d, int64_t object, uint32_t version, const float (*want)[6], uint32_t n)
{
    float(*got)[6] = NULL;
    uint32_t k = 99;
    assert_int_equal(db_ecm_boxes(d, object, version, &got, &k), 0);
    assert_int_equal(k, n);
    assert_memory_equal(got, want, n * sizeof *got); /* exact: float -> REAL -> float */
    free(got);
}

static void test_write_read_round_trip(void **state)
{
    (void)state;
    db *d = open_rw();
    assert_true(db_schema_version() >= 4); /* the ECM history's migration and those after it */
    assert_int_equal(scalar(d, "PRAGMA user_version"), db_schema_version());
    int64_t id = make_object(d, "a");
    make_run(d, 7, id, 3);
    uint32_t ties[] = {2, 0, 2}; /* a duplicate counts once */
    db_ecm_change c = {.object_id = id, .parent_version = 1, .reason = "refine", .run_id = 7, .ncluster_ids = 3,
                       .cluster_ids = ties, .detail = "depth 6, 3 boxes", .box_count = 3, .boxes = THREE};
    uint32_t v = 0;
    assert_int_equal(db_ecm_write(d, &c, 2000.5, &v), 0);
    assert_int_equal(v, 2);
    assert_boxes(d, id, 2, THREE, 3);
    assert_boxes(d, id, 1, MBR, 1); /* the old version stays */
    assert_int_equal(scalar(d, "SELECT ecm_version FROM objects WHERE id = 1"), 2);
    assert_int_equal(scalar(d, "SELECT count(*) FROM ecm_versions WHERE object_id = 1 AND version = 2 "
                               "AND created_at = 2000.5 AND reason = 'refine' AND box_count = 3 "
                               "AND parent_version = 1 AND run_id = 7 AND restores IS NULL "
                               "AND detail = 'depth 6, 3 boxes'"),
                     1);
    /* The import's row has no history. */
    assert_int_equal(scalar(d, "SELECT count(*) FROM ecm_versions WHERE version = 1 AND parent_version IS NULL "
                               "AND run_id IS NULL AND restores IS NULL AND detail IS NULL"),
                     1);
    sqlite3_stmt *st;
    assert_int_equal(sqlite3_prepare_v2(db_sqlite(d),
                                        "SELECT group_concat(cluster_id, ',') FROM (SELECT cluster_id FROM "
                                        "ecm_version_clusters WHERE object_id = 1 AND version = 2 ORDER BY cluster_id)",
                                        -1, &st, NULL),
                     SQLITE_OK);
    assert_int_equal(sqlite3_step(st), SQLITE_ROW);
    assert_string_equal((const char *)sqlite3_column_text(st, 0), "0,2");
    sqlite3_finalize(st);
    assert_int_equal(scalar(d, "SELECT count(*) FROM ecm_events WHERE id = 1 AND object_id = 1 AND version = 2 "
                               "AND at = 2000.5 AND reason = 'refine'"),
                     1);

    /* A rollback to 1: version 3 with version 1's boxes; the largest box
     * count and all-NULL optional fields work too. */
    float(*b1)[6];
    uint32_t n1;
    assert_int_equal(db_ecm_boxes(d, id, 1, &b1, &n1), 0);
    c = (db_ecm_change){.object_id = id, .parent_version = 2, .reason = "rollback", .restores = 1,
                        .box_count = n1, .boxes = (const float(*)[6])b1};
    assert_int_equal(db_ecm_write(d, &c, 3000, &v), 0);
    free(b1);
    assert_int_equal(v, 3);
    assert_boxes(d, id, 3, MBR, 1);
    assert_int_equal(scalar(d, "SELECT count(*) FROM ecm_versions WHERE version = 3 AND parent_version = 2 "
                               "AND restores = 1 AND run_id IS NULL AND detail IS NULL AND reason = 'rollback'"),
                     1);
    float(*many)[6] = calloc(DB_ECM_BOXES_MAX, sizeof *many);
    for (uint32_t i = 0; i < DB_ECM_BOXES_MAX; i++)
        for (int k = 0; k < 6; k++)
            many[i][k] = (float)i + (k >= 3 ? 0.5f : 0.0f);
    c = (db_ecm_change){.object_id = id, .parent_version = 3, .reason = "refine", .box_count = DB_ECM_BOXES_MAX,
                        .boxes = (const float(*)[6])many};
    assert_int_equal(db_ecm_write(d, &c, 3001, &v), 0);
    assert_int_equal(v, 4);
    assert_boxes(d, id, 4, (const float(*)[6])many, DB_ECM_BOXES_MAX);
    free(many);

    /* Versions only grow: if the version in force was moved back to 1 by
     * hand (as an old tool might), the next one is 5, not 2. */
    sql(d, "UPDATE objects SET ecm_version = 1 WHERE id = 1");
    c = (db_ecm_change){.object_id = id, .parent_version = 1, .reason = "refine", .box_count = 3, .boxes = THREE};
    assert_int_equal(db_ecm_write(d, &c, 4000, &v), 0);
    assert_int_equal(v, 5);
    assert_boxes(d, id, 5, THREE, 3);
    /* Each object counts on its own. */
    int64_t other = make_object(d, "b");
    c.object_id = other;
    assert_int_equal(db_ecm_write(d, &c, 4001, &v), 0);
    assert_int_equal(v, 2);
    /* Unknown version. */
    float(*none)[6] = (float(*)[6])1;
    uint32_t nn = 5;
    assert_int_equal(db_ecm_boxes(d, id, 6, &none, &nn), -ENOENT);
    assert_null(none);
    assert_int_equal(nn, 0);
    assert_non_null(strstr(db_error(d), "no ECM version 6"));
    db_close(d);
}

static void test_stale_and_removed(void **state)
{
    (void)state;
    db *d = open_rw();
    int64_t id = make_object(d, "a");
    db_ecm_change c = {.object_id = id, .parent_version = 1, .reason = "refine", .box_count = 3, .boxes = THREE};
    uint32_t v = 0;
    assert_int_equal(db_ecm_write(d, &c, 1, &v), 0);
    counts before = count(d, id);
    /* Computed from version 1, but 2 is in force now. */
    v = 77;
    assert_int_equal(db_ecm_write(d, &c, 2, &v), -ESTALE);
    assert_int_equal(v, 77);
    assert_non_null(strstr(db_error(d), "version 2 is in force, not 1"));
    assert_counts(count(d, id), before);
    /* A parent from the future is stale too. */
    c.parent_version = 9;
    assert_int_equal(db_ecm_write(d, &c, 2, &v), -ESTALE);
    assert_counts(count(d, id), before);
    /* Removed: stale, whatever the parent. */
    assert_int_equal(db_object_remove(d, id, 5), 0);
    c.parent_version = 2;
    assert_int_equal(db_ecm_write(d, &c, 6, &v), -ESTALE);
    assert_non_null(strstr(db_error(d), "removed"));
    assert_counts(count(d, id), before);
    /* The connection is fine: no transaction left open, writes go on. */
    assert_true(sqlite3_get_autocommit(db_sqlite(d)));
    int64_t other = make_object(d, "b");
    c.object_id = other;
    c.parent_version = 1;
    assert_int_equal(db_ecm_write(d, &c, 7, &v), 0);
    db_close(d);
}

/* A rejected candidate: stored with its boxes, ties and figures, numbered
 * within the object, found by its evidence; never a version, never in the
 * feed; refused when stale or invalid, with nothing written. */
static void test_rejected_candidates(void **state)
{
    (void)state;
    db *d = open_rw();
    int64_t id = make_object(d, "a");
    make_run(d, 4, id, 2);
    const uint32_t ids[2] = {1, 0};
    db_ecm_candidate c = {.object_id = id, .version = 1, .run_id = 4, .ncluster_ids = 2, .cluster_ids = ids,
                          .evidence = 12345, .detail = "judge: not better", .box_count = 3, .boxes = THREE,
                          .samples = 10, .moves = 600, .phantom_old = 5, .phantom_new = 7};
    counts before = count(d, id);
    uint32_t n = 0;
    assert_int_equal(db_ecm_rejected(d, id, 1, 12345, &n), 0);
    assert_int_equal(db_ecm_reject(d, &c, 10, &n), 0);
    assert_int_equal(n, 1);
    c.evidence = 777;
    assert_int_equal(db_ecm_reject(d, &c, 11, &n), 0);
    assert_int_equal(n, 2);
    assert_counts(count(d, id), before); /* no version, no event */
    assert_int_equal(scalar(d, "SELECT count(*) FROM ecm_candidate_boxes WHERE candidate = 2"), 3);
    assert_int_equal(scalar(d, "SELECT count(*) FROM ecm_candidate_clusters WHERE candidate = 1 AND run_id = 4"), 2);
    assert_int_equal(scalar(d, "SELECT phantom_new * 1000 + moves FROM ecm_candidates WHERE candidate = 1"), 7600);
    uint32_t found = 0;
    assert_int_equal(db_ecm_rejected(d, id, 1, 12345, &found), 1);
    assert_int_equal(found, 1);
    assert_int_equal(db_ecm_rejected(d, id, 1, 777, &found), 1);
    assert_int_equal(found, 2);
    assert_int_equal(db_ecm_rejected(d, id, 2, 777, &found), 0); /* another version */
    /* Refusals write nothing. */
    int64_t stored = scalar(d, "SELECT count(*) FROM ecm_candidates");
    c.box_count = 0;
    assert_int_equal(db_ecm_reject(d, &c, 12, &n), -EINVAL);
    c.box_count = 3;
    c.ncluster_ids = 0;
    c.run_id = 99; /* no such run: the store's foreign key */
    assert_int_equal(db_ecm_reject(d, &c, 12, &n), -EINVAL);
    c.run_id = 4;
    c.version = 2; /* not in force */
    assert_int_equal(db_ecm_reject(d, &c, 12, &n), -ESTALE);
    assert_non_null(strstr(db_error(d), "ecm reject: object"));
    c.object_id = id + 100;
    assert_int_equal(db_ecm_reject(d, &c, 12, &n), -ENOENT);
    assert_int_equal(scalar(d, "SELECT count(*) FROM ecm_candidates"), stored);
    assert_true(sqlite3_get_autocommit(db_sqlite(d)));
    db_close(d);
}

static void test_invalid_input(void **state)
{
    (void)state;
    db *d = open_rw();
    int64_t id = make_object(d, "a");
    make_run(d, 3, id, 2);
    counts before = count(d, id);
    float bad[1][6];
    char longtext[DB_ECM_DETAIL_MAX + 2];
    memset(longtext, 'x', sizeof longtext - 1);
    longtext[sizeof longtext - 1] = 0;
    uint32_t cl[] = {1, 5};
    const struct {
        const char *what, *message;
        int rc;
        db_ecm_change c;
        float box[6];
    } cases[] = {
        {"no boxes", "0 boxes", -EINVAL, {.box_count = 0}, {0, 0, 0, 1, 1, 1}},
        {"too many boxes", "1025 boxes", -EINVAL, {.box_count = DB_ECM_BOXES_MAX + 1}, {0, 0, 0, 1, 1, 1}},
        {"NaN", "NaN or infinite", -EINVAL, {.box_count = 1}, {0, NAN, 0, 1, 1, 1}},
        {"infinite", "NaN or infinite", -EINVAL, {.box_count = 1}, {0, 0, 0, 1, 1, INFINITY}},
        {"min > max", "min > max on axis y", -EINVAL, {.box_count = 1}, {0, 2, 0, 1, 1, 1}},
        {"no reason", "reason", -EINVAL, {.box_count = 1, .reason = ""}, {0, 0, 0, 1, 1, 1}},
        {"long reason", "reason", -EINVAL, {.box_count = 1, .reason = "refinement-by-the-voxel-job-number-one"},
         {0, 0, 0, 1, 1, 1}},
        {"long detail", "detail", -EINVAL, {.box_count = 1, .detail = longtext}, {0, 0, 0, 1, 1, 1}},
        {"clusters without a run", "without the run", -EINVAL, {.box_count = 1, .ncluster_ids = 1, .cluster_ids = cl},
         {0, 0, 0, 1, 1, 1}},
        {"negative run", "not a run", -EINVAL, {.box_count = 1, .run_id = -1}, {0, 0, 0, 1, 1, 1}},
        {"parent 0", "parent version 0", -EINVAL, {.box_count = 1, .parent_version = 0}, {0, 0, 0, 1, 1, 1}},
        {"no object", "no object 42", -ENOENT, {.box_count = 1, .object_id = 42}, {0, 0, 0, 1, 1, 1}},
        {"no run", "no cluster run 4", -ENOENT, {.box_count = 1, .run_id = 4}, {0, 0, 0, 1, 1, 1}},
        {"no cluster", "has no cluster 5 of object 1", -ENOENT,
         {.box_count = 1, .run_id = 3, .ncluster_ids = 2, .cluster_ids = cl}, {0, 0, 0, 1, 1, 1}},
        {"no such version to restore", "no version 8 to restore", -ENOENT, {.box_count = 1, .restores = 8},
         {0, 0, 0, 1, 1, 1}},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        db_ecm_change c = cases[i].c;
        memcpy(bad[0], cases[i].box, sizeof bad[0]);
        float(*big)[6] = NULL;
        if (c.box_count > 1) {
            big = calloc(c.box_count, sizeof *big);
            for (uint32_t k = 0; k < c.box_count; k++)
                memcpy(big[k], bad[0], sizeof bad[0]);
        }
        c.boxes = big ? (const float(*)[6])big : (const float(*)[6])bad;
        if (!c.object_id)
            c.object_id = id;
        if (!c.reason)
            c.reason = "refine";
        if (!c.parent_version && strcmp(cases[i].what, "parent 0") != 0)
            c.parent_version = 1;
        uint32_t v = 77;
        int rc = db_ecm_write(d, &c, 10, &v);
        free(big);
        if (rc != cases[i].rc || !strstr(db_error(d), cases[i].message))
            fail_msg("%s: rc %d, message \"%s\"", cases[i].what, rc, db_error(d));
        assert_int_equal(v, 77);
        assert_counts(count(d, id), before);
        assert_true(sqlite3_get_autocommit(db_sqlite(d)));
    }
    /* NULL boxes, no version out, no change, a time that is not finite. */
    db_ecm_change c = {.object_id = id, .parent_version = 1, .reason = "refine", .box_count = 1};
    uint32_t v;
    assert_int_equal(db_ecm_write(d, &c, 10, &v), -EINVAL);
    c.boxes = MBR;
    assert_int_equal(db_ecm_write(d, &c, 10, NULL), -EINVAL);
    assert_int_equal(db_ecm_write(d, NULL, 10, &v), -EINVAL);
    assert_int_equal(db_ecm_write(d, &c, NAN, &v), -EINVAL);
    assert_counts(count(d, id), before);
    /* Boxes of zero size are allowed (min == max), and the write works. */
    const float flat[1][6] = {{1, 1, 1, 1, 1, 1}};
    c.boxes = flat;
    assert_int_equal(db_ecm_write(d, &c, 10, &v), 0);
    assert_int_equal(v, 2);
    db_close(d);
}

struct seen {
    int64_t ids[400], objects[400];
    uint32_t versions[400];
    int n, stop_at, stop_value;
    db *d;
    int load; /* use d from inside the callback */
};

static int on_event(void *ctx, int64_t event_id, int64_t object_id, uint32_t version)
{
    struct seen *s = ctx;
    if (s->n == s->stop_at)
        return s->stop_value;
    if (s->load) { /* the server's use: load what changed, on the same connection */
        db_ecm_object load;
        assert_int_equal(db_ecm_object_load(s->d, object_id, &load), 0);
        assert_true(load.version >= version);
        db_ecm_object_free(&load);
    }
    s->ids[s->n] = event_id;
    s->objects[s->n] = object_id;
    s->versions[s->n] = version;
    s->n++;
    return 0;
}

static void test_events_feed(void **state)
{
    (void)state;
    db *d = open_rw();
    int64_t head = 99;
    assert_int_equal(db_ecm_events_head(d, &head), 0);
    assert_int_equal(head, 0);
    struct seen s = {.stop_at = -1, .d = d};
    int64_t last = -5;
    assert_int_equal(db_ecm_events(d, 0, on_event, &s, &last), 0);
    assert_int_equal(s.n, 0);
    assert_int_equal(last, -5); /* none: unchanged */

    /* 300 changes over two objects, more than one batch of the feed. */
    int64_t a = make_object(d, "a"), b = make_object(d, "b");
    uint32_t va = 1, vb = 1;
    for (int i = 0; i < 300; i++) {
        int64_t id = i % 3 == 0 ? b : a;
        uint32_t *v = id == a ? &va : &vb;
        db_ecm_change c = {.object_id = id, .parent_version = *v, .reason = "refine", .box_count = 3, .boxes = THREE};
        assert_int_equal(db_ecm_write(d, &c, 100 + i, v), 0);
    }
    assert_int_equal(db_ecm_events_head(d, &head), 0);
    assert_int_equal(head, 300);
    s.load = 1;
    assert_int_equal(db_ecm_events(d, 0, on_event, &s, &last), 0);
    assert_int_equal(s.n, 300);
    assert_int_equal(last, 300);
    uint32_t wa = 1, wb = 1;
    for (int i = 0; i < 300; i++) {
        assert_int_equal(s.ids[i], i + 1); /* in id order, none missed */
        assert_int_equal(s.objects[i], i % 3 == 0 ? b : a);
        assert_int_equal(s.versions[i], i % 3 == 0 ? ++wb : ++wa);
    }
    /* From a point on; nothing new. */
    s = (struct seen){.stop_at = -1, .d = d};
    assert_int_equal(db_ecm_events(d, 297, on_event, &s, &last), 0);
    assert_int_equal(s.n, 3);
    assert_int_equal(s.ids[0], 298);
    assert_int_equal(last, 300);
    s = (struct seen){.stop_at = -1, .d = d};
    last = 300;
    assert_int_equal(db_ecm_events(d, 300, on_event, &s, &last), 0);
    assert_int_equal(s.n, 0);
    assert_int_equal(last, 300);
    /* fn stops the walk: its value comes back, and the event it refused is
     * offered again from *last. */
    s = (struct seen){.stop_at = 2, .stop_value = 7, .d = d};
    last = 0;
    assert_int_equal(db_ecm_events(d, 10, on_event, &s, &last), 7);
    assert_int_equal(s.n, 2);
    assert_int_equal(last, 12);
    s = (struct seen){.stop_at = 1, .stop_value = -3, .d = d};
    assert_int_equal(db_ecm_events(d, last, on_event, &s, &last), -3);
    assert_int_equal(s.ids[0], 13);
    assert_int_equal(last, 13);
    db_close(d);
}

struct writer_ctx {
    db *d;
    int64_t object;
    int wrote, calls;
};

static int write_in_callback(void *ctx, int64_t event_id, int64_t object_id, uint32_t version)
{
    struct writer_ctx *w = ctx;
    (void)event_id;
    w->calls++;
    if (!w->wrote) {
        db_ecm_change c = {.object_id = object_id, .parent_version = version, .reason = "refine", .box_count = 1,
                           .boxes = MBR};
        uint32_t v;
        assert_int_equal(db_ecm_write(w->d, &c, 50, &v), 0);
        assert_int_equal(v, version + 1);
        w->wrote = 1;
    }
    return 0;
}

static void test_events_with_a_write_in_the_callback(void **state)
{
    (void)state;
    db *d = open_rw();
    int64_t id = make_object(d, "a");
    db_ecm_change c = {.object_id = id, .parent_version = 1, .reason = "refine", .box_count = 3, .boxes = THREE};
    uint32_t v;
    assert_int_equal(db_ecm_write(d, &c, 1, &v), 0);
    struct writer_ctx w = {.d = d, .object = id};
    int64_t last = 0;
    assert_int_equal(db_ecm_events(d, 0, write_in_callback, &w, &last), 0);
    assert_int_equal(last, 1); /* the batch read before the write */
    assert_int_equal(db_ecm_events(d, last, write_in_callback, &w, &last), 0);
    assert_int_equal(last, 2);
    assert_int_equal(w.calls, 2);
    db_close(d);
}

static void test_object_load(void **state)
{
    (void)state;
    db *d = open_rw();
    int64_t id = make_object(d, "a");
    db_ecm_object o;
    assert_int_equal(db_ecm_object_load(d, id, &o), 0);
    assert_int_equal(o.id, id);
    assert_int_equal(o.version, 1);
    assert_int_equal(o.tri_count, 2);
    assert_memory_equal(o.tris, TRIS, sizeof TRIS);
    assert_int_equal(o.box_count, 1);
    assert_memory_equal(o.boxes, MBR, sizeof MBR);
    db_ecm_object_free(&o);
    assert_null(o.tris);
    db_ecm_object_free(&o); /* twice, and NULL: harmless */
    db_ecm_object_free(NULL);
    db_ecm_change c = {.object_id = id, .parent_version = 1, .reason = "refine", .box_count = 3, .boxes = THREE};
    uint32_t v;
    assert_int_equal(db_ecm_write(d, &c, 1, &v), 0);
    assert_int_equal(db_ecm_object_load(d, id, &o), 0);
    assert_int_equal(o.version, 2);
    assert_int_equal(o.box_count, 3);
    assert_memory_equal(o.boxes, THREE, sizeof THREE);
    db_ecm_object_free(&o);
    /* Inside a caller's transaction: its snapshot is used and left open. */
    assert_int_equal(db_begin(d), 0);
    assert_int_equal(db_ecm_object_load(d, id, &o), 0);
    assert_false(sqlite3_get_autocommit(db_sqlite(d)));
    assert_int_equal(db_commit(d), 0);
    db_ecm_object_free(&o);

    /* Out of memory on the triangles, then on the boxes: -ENOMEM, nothing kept. */
    for (long k = 0; k < 2; k++) {
        cvre_alloc_fail_after(k);
        assert_int_equal(db_ecm_object_load(d, id, &o), -ENOMEM);
        cvre_alloc_fail_after(-1);
        assert_non_null(strstr(db_error(d), "out of memory"));
        assert_null(o.tris);
        assert_null(o.boxes);
        assert_true(sqlite3_get_autocommit(db_sqlite(d)));
    }
    float(*b)[6];
    uint32_t n;
    cvre_alloc_fail_after(0);
    assert_int_equal(db_ecm_boxes(d, id, 2, &b, &n), -ENOMEM);
    cvre_alloc_fail_after(-1);
    assert_null(b);

    /* Unknown, removed, corrupted. */
    assert_int_equal(db_ecm_object_load(d, 99, &o), -ENOENT);
    assert_non_null(strstr(db_error(d), "no object 99"));
    int64_t gone = make_object(d, "gone");
    assert_int_equal(db_object_remove(d, gone, 5), 0);
    assert_int_equal(db_ecm_object_load(d, gone, &o), -ENOENT);
    assert_non_null(strstr(db_error(d), "removed"));
    assert_null(o.tris);
    sql(d, "UPDATE meshes SET triangles = x'00000000' WHERE object_id = 1");
    assert_int_equal(db_ecm_object_load(d, id, &o), -EIO);
    assert_non_null(strstr(db_error(d), "mesh size does not match"));
    assert_null(o.tris);
    sql(d, "UPDATE objects SET tri_count = 1000000000 WHERE id = 1"); /* a count that would size a huge copy */
    assert_int_equal(db_ecm_object_load(d, id, &o), -EIO);
    assert_non_null(strstr(db_error(d), "mesh size does not match"));
    sql(d, "UPDATE objects SET tri_count = 0 WHERE id = 1");
    sql(d, "UPDATE meshes SET triangles = x'' WHERE object_id = 1");
    assert_int_equal(db_ecm_object_load(d, id, &o), 0); /* no triangles is consistent */
    assert_int_equal(o.tri_count, 0);
    assert_null(o.tris);
    db_ecm_object_free(&o);
    sql(d, "DELETE FROM meshes WHERE object_id = 1");
    assert_int_equal(db_ecm_object_load(d, id, &o), -EIO);
    assert_non_null(strstr(db_error(d), "no mesh"));

    /* Boxes that do not match their version's box_count. */
    int64_t x = make_object(d, "x");
    assert_int_equal(db_ecm_write(d, &(db_ecm_change){.object_id = x, .parent_version = 1, .reason = "refine",
                                                     .box_count = 3, .boxes = THREE},
                                  1, &v),
                     0);
    sql(d, "DELETE FROM ecm_boxes WHERE object_id = 3 AND version = 2 AND box_index = 1");
    assert_int_equal(db_ecm_boxes(d, x, 2, &b, &n), -EIO);
    assert_non_null(strstr(db_error(d), "do not match"));
    assert_int_equal(db_ecm_object_load(d, x, &o), -EIO);
    sql(d, "INSERT INTO ecm_boxes VALUES (3, 2, 1, 0, 0, 0, 1, 1, 1), (3, 2, 3, 0, 0, 0, 1, 1, 1)");
    assert_int_equal(db_ecm_boxes(d, x, 2, &b, &n), -EIO); /* one too many */
    sql(d, "DELETE FROM ecm_boxes WHERE object_id = 3 AND version = 2 AND box_index >= 2");
    assert_int_equal(db_ecm_boxes(d, x, 2, &b, &n), -EIO); /* the last one missing */
    assert_non_null(strstr(db_error(d), "do not match"));
    sql(d, "INSERT INTO ecm_boxes VALUES (3, 2, 2, 0, 0, 0, 1, 1, 1)");
    assert_int_equal(db_ecm_boxes(d, x, 2, &b, &n), 0);
    assert_int_equal(n, 3);
    free(b);
    sql(d, "UPDATE ecm_versions SET box_count = 2000000 WHERE object_id = 3 AND version = 2");
    assert_int_equal(db_ecm_boxes(d, x, 2, &b, &n), -EIO);
    assert_non_null(strstr(db_error(d), "out of range"));
    db_close(d);
}

static void test_database_errors(void **state)
{
    (void)state;
    db *d = open_rw();
    int64_t id = make_object(d, "a");
    db_ecm_change c = {.object_id = id, .parent_version = 1, .reason = "refine", .box_count = 3, .boxes = THREE};
    uint32_t v;
    counts before = count(d, id);

    /* Another connection holds the write lock beyond our busy timeout. */
    sqlite3 *other;
    assert_int_equal(sqlite3_open(path, &other), SQLITE_OK);
    assert_int_equal(sqlite3_exec(other, "BEGIN IMMEDIATE", NULL, NULL, NULL), SQLITE_OK);
    db_set_busy_timeout(d, 50);
    assert_int_equal(db_ecm_write(d, &c, 1, &v), -EBUSY);
    assert_true(db_busy(d));
    assert_int_equal(sqlite3_exec(other, "ROLLBACK", NULL, NULL, NULL), SQLITE_OK);
    sqlite3_close(other);
    assert_counts(count(d, id), before);

    /* A failure after the version and its boxes went in: all rolled back. */
    sql(d, "CREATE TEMP TRIGGER boom BEFORE INSERT ON ecm_events BEGIN SELECT raise(ABORT, 'feed refused'); END");
    assert_int_equal(db_ecm_write(d, &c, 1, &v), -EINVAL); /* RAISE(ABORT): a constraint */
    assert_non_null(strstr(db_error(d), "feed refused"));
    assert_true(sqlite3_get_autocommit(db_sqlite(d)));
    assert_counts(count(d, id), before);
    sql(d, "DROP TRIGGER boom");

    /* Inside the caller's transaction: refused, and that transaction is
     * left alone. */
    assert_int_equal(db_begin(d), 0);
    assert_int_equal(db_ecm_write(d, &c, 1, &v), -EINVAL);
    assert_non_null(strstr(db_error(d), "inside a transaction"));
    assert_false(sqlite3_get_autocommit(db_sqlite(d)));
    assert_int_equal(db_commit(d), 0);

    /* The connection still writes. */
    assert_int_equal(db_ecm_write(d, &c, 1, &v), 0);
    assert_int_equal(v, 2);
    db_close(d);

    /* A read-only handle reads, and refuses to write with SQLite's message. */
    char err[256];
    db *ro = db_open(path, DB_READONLY, err, sizeof err);
    assert_non_null(ro);
    c.parent_version = 2;
    assert_int_equal(db_ecm_write(ro, &c, 1, &v), -EROFS);
    assert_non_null(strstr(db_error(ro), "readonly"));
    assert_true(sqlite3_get_autocommit(db_sqlite(ro)));
    int64_t head;
    assert_int_equal(db_ecm_events_head(ro, &head), 0);
    assert_int_equal(head, 1);
    db_ecm_object o;
    assert_int_equal(db_ecm_object_load(ro, id, &o), 0);
    assert_int_equal(o.version, 2);
    db_ecm_object_free(&o);
    db_close(ro);

    /* A database without the feed (tables gone): errors, not crashes. */
    d = open_rw();
    sql(d, "DROP TABLE ecm_events");
    assert_int_equal(db_ecm_events_head(d, &head), -EIO);
    assert_non_null(strstr(db_error(d), "no such table"));
    struct seen s = {.stop_at = -1};
    int64_t last = 0;
    assert_int_equal(db_ecm_events(d, 0, on_event, &s, &last), -EIO);
    assert_int_equal(db_ecm_write(d, &c, 1, &v), -EIO);
    db_close(d);
}

/* A database at schema 3 with an imported object gains the history columns
 * (NULL for the old rows) and takes new versions. */
static void test_migration_from_3(void **state)
{
    (void)state;
    sqlite3 *raw;
    assert_int_equal(sqlite3_open(path, &raw), SQLITE_OK);
    for (int i = 0; i < 3; i++)
        assert_int_equal(sqlite3_exec(raw, db_migrations[i].sql, NULL, NULL, NULL), SQLITE_OK);
    assert_int_equal(sqlite3_exec(raw,
                                  "PRAGMA user_version = 3;"
                                  "INSERT INTO users VALUES (1, 'ann', 0, 0);"
                                  "INSERT INTO objects(id, owner_id, name, format, created_at, pos_x, pos_y, pos_z, "
                                  "yaw, scale, ecm_version, tri_count, min_x, min_y, min_z, max_x, max_y, max_z) "
                                  "VALUES (1, 1, 'old', 'obj', 0, 0, 0, 0, 0, 1, 1, 0, 0, 0, 0, 1, 1, 1);"
                                  "INSERT INTO meshes VALUES (1, x'');"
                                  "INSERT INTO ecm_versions VALUES (1, 1, 0, 'import', 1);"
                                  "INSERT INTO ecm_boxes VALUES (1, 1, 0, 0, 0, 0, 1, 1, 1);",
                                  NULL, NULL, NULL),
                     SQLITE_OK);
    sqlite3_close(raw);
    db *d = open_rw();
    assert_int_equal(scalar(d, "PRAGMA user_version"), db_schema_version());
    assert_int_equal(scalar(d, "SELECT count(*) FROM ecm_versions WHERE parent_version IS NULL AND run_id IS NULL "
                               "AND restores IS NULL AND detail IS NULL"),
                     1);
    db_ecm_change c = {.object_id = 1, .parent_version = 1, .reason = "refine", .box_count = 3, .boxes = THREE};
    uint32_t v;
    assert_int_equal(db_ecm_write(d, &c, 1, &v), 0);
    assert_int_equal(v, 2);
    db_ecm_object o;
    assert_int_equal(db_ecm_object_load(d, 1, &o), 0);
    assert_int_equal(o.box_count, 3);
    db_ecm_object_free(&o);
    db_close(d);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_write_read_round_trip, setup, teardown),
        cmocka_unit_test_setup_teardown(test_stale_and_removed, setup, teardown),
        cmocka_unit_test_setup_teardown(test_invalid_input, setup, teardown),
        cmocka_unit_test_setup_teardown(test_rejected_candidates, setup, teardown),
        cmocka_unit_test_setup_teardown(test_events_feed, setup, teardown),
        cmocka_unit_test_setup_teardown(test_events_with_a_write_in_the_callback, setup, teardown),
        cmocka_unit_test_setup_teardown(test_object_load, setup, teardown),
        cmocka_unit_test_setup_teardown(test_database_errors, setup, teardown),
        cmocka_unit_test_setup_teardown(test_migration_from_3, setup, teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
