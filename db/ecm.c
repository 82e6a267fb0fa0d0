#include "ecm.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "dbInt.h"

/* Events read per query by db_ecm_events before fn sees them: enough that a
 * burst of refinements costs a few queries, small enough for the stack. */
#define DB_ECM_EVENTS_BATCH 256

/* Versions are u32 on the wire; the store keeps them as INTEGER. */
#define DB_ECM_VERSION_MAX UINT32_MAX

/* Steps st once: 1 and the row in st, 0 when there is none, a negative
 * errno on error (with the message). The caller resets st. */
static int step_row(db *d, sqlite3_stmt *st)
{
    int rc = sqlite3_step(st);
    if (rc == SQLITE_ROW)
        return 1;
    if (rc == SQLITE_DONE)
        return 0;
    return db__sql_fail(d, NULL);
}

/* Runs a statement that returns no rows, then resets it for the next use. */
static int step_done(db *d, sqlite3_stmt *st)
{
    int rc = sqlite3_step(st) == SQLITE_DONE ? 0 : db__sql_fail(d, NULL);
    sqlite3_reset(st);
    sqlite3_clear_bindings(st);
    return rc;
}

/* Starts the read transaction a multi-statement read runs in, unless the
 * caller has one open (then its snapshot is used). *own says whether to end
 * it with end_read. */
static int begin_read(db *d, int *own)
{
    *own = sqlite3_get_autocommit(db_sqlite(d));
    if (*own && sqlite3_exec(db_sqlite(d), "BEGIN", NULL, NULL, NULL) != SQLITE_OK)
        return db__sql_fail(d, NULL);
    return 0;
}

static void end_read(db *d, int own)
{
    if (own && sqlite3_exec(db_sqlite(d), "COMMIT", NULL, NULL, NULL) != SQLITE_OK)
        db_rollback(d);
}

/* ---- writing a version ---- */

/* Everything about c that can be checked without the database. */
static int check_change(db *d, const db_ecm_change *c, double at, const uint32_t *version)
{
    if (!c || !version)
        return db__fail(d, -EINVAL, "ecm write: no change given");
    if (c->object_id <= 0)
        return db__fail(d, -EINVAL, "ecm write: object id %lld is not an object", (long long)c->object_id);
    if (c->parent_version == 0)
        return db__fail(d, -EINVAL,
                        "ecm write: object %lld: parent version 0 does not exist (versions start at 1)",
                        (long long)c->object_id);
    size_t n = c->reason ? strnlen(c->reason, DB_ECM_REASON_MAX + 1) : 0;
    if (n == 0 || n > DB_ECM_REASON_MAX)
        return db__fail(d, -EINVAL, "ecm write: object %lld: the reason must be 1 to %u bytes",
                        (long long)c->object_id, DB_ECM_REASON_MAX);
    if (c->detail && strnlen(c->detail, DB_ECM_DETAIL_MAX + 1) > DB_ECM_DETAIL_MAX)
        return db__fail(d, -EINVAL, "ecm write: object %lld: the detail is longer than %u bytes",
                        (long long)c->object_id, DB_ECM_DETAIL_MAX);
    if (c->run_id < 0)
        return db__fail(d, -EINVAL, "ecm write: object %lld: run id %lld is not a run", (long long)c->object_id,
                        (long long)c->run_id);
    if (c->ncluster_ids && (c->run_id == 0 || !c->cluster_ids))
        return db__fail(d, -EINVAL, "ecm write: object %lld: %u cluster ids without the run they belong to",
                        (long long)c->object_id, c->ncluster_ids);
    if (c->box_count < 1 || c->box_count > DB_ECM_BOXES_MAX || !c->boxes)
        return db__fail(d, -EINVAL, "ecm write: object %lld: %u boxes; a version has 1 to %u",
                        (long long)c->object_id, c->boxes ? c->box_count : 0, DB_ECM_BOXES_MAX);
    for (uint32_t i = 0; i < c->box_count; i++) {
        const float *b = c->boxes[i];
        for (int k = 0; k < 6; k++)
            if (!isfinite(b[k]))
                return db__fail(d, -EINVAL, "ecm write: object %lld: box %u has a NaN or infinite coordinate",
                                (long long)c->object_id, i);
        for (int k = 0; k < 3; k++)
            if (b[k] > b[k + 3])
                return db__fail(d, -EINVAL, "ecm write: object %lld: box %u has min > max on axis %c",
                                (long long)c->object_id, i, "xyz"[k]);
    }
    if (!isfinite(at))
        return db__fail(d, -EINVAL, "ecm write: object %lld: the time is not finite", (long long)c->object_id);
    return 0;
}

enum {
    W_OBJECT,
    W_NEXT,
    W_HAS_VERSION,
    W_HAS_RUN,
    W_HAS_CLUSTER,
    W_VERSION,
    W_BOX,
    W_TIE,
    W_SET,
    W_EVENT,
    W_COUNT
};

static const char *const write_sql[W_COUNT] = {
    [W_OBJECT] = "SELECT ecm_version, removed_at IS NOT NULL FROM objects WHERE id = ?1",
    [W_NEXT] = "SELECT coalesce(max(version), 0) + 1 FROM ecm_versions WHERE object_id = ?1",
    [W_HAS_VERSION] = "SELECT 1 FROM ecm_versions WHERE object_id = ?1 AND version = ?2",
    [W_HAS_RUN] = "SELECT 1 FROM cluster_runs WHERE id = ?1",
    [W_HAS_CLUSTER] = "SELECT 1 FROM clusters WHERE run_id = ?1 AND object_id = ?2 AND cluster_id = ?3",
    [W_VERSION] = "INSERT INTO ecm_versions(object_id, version, created_at, reason, box_count, parent_version, run_id, "
                  "restores, detail) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)",
    [W_BOX] = "INSERT INTO ecm_boxes(object_id, version, box_index, min_x, min_y, min_z, max_x, max_y, max_z) "
              "VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)",
    [W_TIE] = "INSERT OR IGNORE INTO ecm_version_clusters(object_id, version, run_id, cluster_id) "
              "VALUES (?1, ?2, ?3, ?4)",
    [W_SET] = "UPDATE objects SET ecm_version = ?2 WHERE id = ?1 AND ecm_version = ?3 AND removed_at IS NULL",
    [W_EVENT] = "INSERT INTO ecm_events(object_id, version, at, reason) VALUES (?1, ?2, ?3, ?4)",
};

/* One existence check: 1 if the statement (bound by the caller) returns a
 * row, 0 if not, -1 on error. Resets it. */
static int exists(db *d, sqlite3_stmt *st)
{
    int r = step_row(d, st);
    sqlite3_reset(st);
    sqlite3_clear_bindings(st);
    return r;
}

/* Whether version is in force for object_id (q: W_OBJECT's statement): 0,
 * or -ENOENT (no such object), -ESTALE (removed, or another version in
 * force) or the database's error, with a message that starts with what. */
static int check_in_force(db *d, sqlite3_stmt *q, int64_t object_id, uint32_t version, const char *what)
{
    sqlite3_bind_int64(q, 1, object_id);
    int r = step_row(d, q);
    int64_t in_force = r == 1 ? sqlite3_column_int64(q, 0) : 0;
    int removed = r == 1 && sqlite3_column_int(q, 1);
    sqlite3_reset(q);
    long long id = (long long)object_id;
    if (r < 0)
        return r;
    if (r == 0)
        return db__fail(d, -ENOENT, "%s: no object %lld", what, id);
    if (removed)
        return db__fail(d, -ESTALE, "%s: object %lld was removed", what, id);
    if (in_force != (int64_t)version)
        return db__fail(d, -ESTALE, "%s: object %lld: version %lld is in force, not %u", what, id,
                        (long long)in_force, version);
    return 0;
}

/* The object's next version or candidate (kind) number from q (W_NEXT's or
 * R_NEXT's statement) into *next: 0, -EOVERFLOW when none is left, or the
 * database's error; messages start with what. */
static int next_number(db *d, sqlite3_stmt *q, int64_t object_id, int64_t *next, const char *what,
                       const char *kind)
{
    sqlite3_bind_int64(q, 1, object_id);
    int r = step_row(d, q);
    *next = r == 1 ? sqlite3_column_int64(q, 0) : 0;
    sqlite3_reset(q);
    if (r < 0)
        return r;
    if (*next < 1 || *next > (int64_t)DB_ECM_VERSION_MAX)
        return db__fail(d, -EOVERFLOW, "%s: object %lld: no %s number left after %lld", what, (long long)object_id,
                        kind, (long long)*next - 1);
    return 0;
}

/* Inserts boxes numbered 0.. under (object_id, number) with q, whose
 * parameters are object, number, index and the six coordinates. */
static int insert_boxes(db *d, sqlite3_stmt *q, int64_t object_id, int64_t number, uint32_t n,
                        const float (*boxes)[6])
{
    for (uint32_t i = 0; i < n; i++) {
        sqlite3_bind_int64(q, 1, object_id);
        sqlite3_bind_int64(q, 2, number);
        sqlite3_bind_int64(q, 3, i);
        for (int k = 0; k < 6; k++)
            sqlite3_bind_double(q, 4 + k, (double)boxes[i][k]);
        int r = step_done(d, q);
        if (r < 0)
            return r;
    }
    return 0;
}

/* Inserts the ties of (object_id, number) to clusters ids of run_id with q
 * (parameters: object, number, run, cluster). */
static int insert_ties(db *d, sqlite3_stmt *q, int64_t object_id, int64_t number, int64_t run_id, uint32_t n,
                       const uint32_t *ids)
{
    for (uint32_t i = 0; i < n; i++) {
        sqlite3_bind_int64(q, 1, object_id);
        sqlite3_bind_int64(q, 2, number);
        sqlite3_bind_int64(q, 3, run_id);
        sqlite3_bind_int64(q, 4, ids[i]);
        int r = step_done(d, q);
        if (r < 0)
            return r;
    }
    return 0;
}

/* Prepares the nsql statements, runs fn with them in a BEGIN IMMEDIATE
 * transaction of its own, and commits if it returns 0 (rolls back if not). */
typedef int locked_fn(db *d, sqlite3_stmt **st, const void *arg, double at, uint32_t *number);
static int in_transaction(db *d, const char *const *sql, int nsql, locked_fn *fn, const void *arg, double at,
                          uint32_t *number, const char *what)
{
    sqlite3 *s = db_sqlite(d);
    if (!sqlite3_get_autocommit(s))
        return db__fail(d, -EINVAL, "%s: called inside a transaction (it needs one of its own)", what);
    sqlite3_stmt *st[W_COUNT] = {0};
    int rc = 0;
    for (int i = 0; i < nsql; i++)
        if (sqlite3_prepare_v2(s, sql[i], -1, &st[i], NULL) != SQLITE_OK) {
            rc = db__sql_fail(d, NULL);
            goto cleanup;
        }
    if ((rc = db_begin(d)) < 0) /* the message and db_busy() come from the BEGIN */
        goto cleanup;
    rc = fn(d, st, arg, at, number);
    if (rc == 0)
        rc = db_commit(d);
    if (rc != 0)
        db_rollback(d);
cleanup:
    for (int i = 0; i < nsql; i++)
        sqlite3_finalize(st[i]);
    return rc;
}

/* The part of db_ecm_write inside the transaction; the caller commits on 0
 * and rolls back otherwise. */
static int write_locked(db *d, sqlite3_stmt **st, const void *arg, double at, uint32_t *version)
{
    const db_ecm_change *c = arg;
    long long id = (long long)c->object_id;
    int r = check_in_force(d, st[W_OBJECT], c->object_id, c->parent_version, "ecm write");
    sqlite3_stmt *q;
    if (r < 0)
        return r;

    int64_t next;
    if ((r = next_number(d, st[W_NEXT], c->object_id, &next, "ecm write", "version")) < 0)
        return r;

    if (c->restores) {
        sqlite3_bind_int64(st[W_HAS_VERSION], 1, c->object_id);
        sqlite3_bind_int64(st[W_HAS_VERSION], 2, c->restores);
        r = exists(d, st[W_HAS_VERSION]);
        if (r <= 0)
            return r < 0 ? r : db__fail(d, -ENOENT, "ecm write: object %lld has no version %u to restore", id,
                                        c->restores);
    }
    if (c->run_id) {
        sqlite3_bind_int64(st[W_HAS_RUN], 1, c->run_id);
        r = exists(d, st[W_HAS_RUN]);
        if (r <= 0)
            return r < 0 ? r : db__fail(d, -ENOENT, "ecm write: no cluster run %lld", (long long)c->run_id);
    }
    for (uint32_t i = 0; i < c->ncluster_ids; i++) {
        sqlite3_bind_int64(st[W_HAS_CLUSTER], 1, c->run_id);
        sqlite3_bind_int64(st[W_HAS_CLUSTER], 2, c->object_id);
        sqlite3_bind_int64(st[W_HAS_CLUSTER], 3, c->cluster_ids[i]);
        r = exists(d, st[W_HAS_CLUSTER]);
        if (r <= 0)
            return r < 0 ? r
                         : db__fail(d, -ENOENT, "ecm write: cluster run %lld has no cluster %u of object %lld",
                                    (long long)c->run_id, c->cluster_ids[i], id);
    }

    q = st[W_VERSION];
    sqlite3_bind_int64(q, 1, c->object_id);
    sqlite3_bind_int64(q, 2, next);
    sqlite3_bind_double(q, 3, at);
    sqlite3_bind_text(q, 4, c->reason, -1, SQLITE_STATIC);
    sqlite3_bind_int64(q, 5, c->box_count);
    sqlite3_bind_int64(q, 6, c->parent_version);
    if (c->run_id)
        sqlite3_bind_int64(q, 7, c->run_id);
    if (c->restores)
        sqlite3_bind_int64(q, 8, c->restores);
    if (c->detail)
        sqlite3_bind_text(q, 9, c->detail, -1, SQLITE_STATIC);
    if ((r = step_done(d, q)) < 0)
        return r;
    if ((r = insert_boxes(d, st[W_BOX], c->object_id, next, c->box_count, c->boxes)) < 0 ||
        (r = insert_ties(d, st[W_TIE], c->object_id, next, c->run_id, c->ncluster_ids, c->cluster_ids)) < 0)
        return r;
    q = st[W_SET];
    sqlite3_bind_int64(q, 1, c->object_id);
    sqlite3_bind_int64(q, 2, next);
    sqlite3_bind_int64(q, 3, c->parent_version);
    if ((r = step_done(d, q)) < 0)
        return r;
    if (sqlite3_changes(db_sqlite(d)) != 1) /* checked above under the same lock: cannot happen */
        return db__fail(d, -EIO, "ecm write: object %lld changed under the write lock", id);
    q = st[W_EVENT];
    sqlite3_bind_int64(q, 1, c->object_id);
    sqlite3_bind_int64(q, 2, next);
    sqlite3_bind_double(q, 3, at);
    sqlite3_bind_text(q, 4, c->reason, -1, SQLITE_STATIC);
    if ((r = step_done(d, q)) < 0)
        return r;
    *version = (uint32_t)next;
    return 0;
}

int db_ecm_write(db *d, const db_ecm_change *c, double at, uint32_t *version)
{
    int rc = check_change(d, c, at, version);
    if (rc < 0)
        return rc;
    return in_transaction(d, write_sql, W_COUNT, write_locked, c, at, version, "ecm write");
}

/* ---- rejected candidates ---- */

enum { R_OBJECT, R_NEXT, R_CANDIDATE, R_BOX, R_TIE, R_COUNT };
_Static_assert((int)R_COUNT <= (int)W_COUNT, "in_transaction holds W_COUNT statements");

static const char *const reject_sql[R_COUNT] = {
    [R_OBJECT] = "SELECT ecm_version, removed_at IS NOT NULL FROM objects WHERE id = ?1",
    [R_NEXT] = "SELECT coalesce(max(candidate), 0) + 1 FROM ecm_candidates WHERE object_id = ?1",
    [R_CANDIDATE] = "INSERT INTO ecm_candidates(object_id, candidate, version, created_at, run_id, evidence, box_count, "
                    "samples, moves, phantom_old, phantom_new, opened_old, opened_new, detail) "
                    "VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14)",
    [R_BOX] = "INSERT INTO ecm_candidate_boxes(object_id, candidate, box_index, min_x, min_y, min_z, max_x, max_y, "
              "max_z) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)",
    [R_TIE] = "INSERT OR IGNORE INTO ecm_candidate_clusters(object_id, candidate, run_id, cluster_id) "
              "VALUES (?1, ?2, ?3, ?4)",
};

/* The part of db_ecm_reject inside the transaction. */
static int reject_locked(db *d, sqlite3_stmt **st, const void *arg, double at, uint32_t *candidate)
{
    const db_ecm_candidate *c = arg;
    int r = check_in_force(d, st[R_OBJECT], c->object_id, c->version, "ecm reject");
    sqlite3_stmt *q;
    if (r < 0)
        return r;
    int64_t next;
    if ((r = next_number(d, st[R_NEXT], c->object_id, &next, "ecm reject", "candidate")) < 0)
        return r;
    q = st[R_CANDIDATE];
    const uint64_t figures[6] = {c->samples, c->moves, c->phantom_old, c->phantom_new, c->opened_old, c->opened_new};
    sqlite3_bind_int64(q, 1, c->object_id);
    sqlite3_bind_int64(q, 2, next);
    sqlite3_bind_int64(q, 3, c->version);
    sqlite3_bind_double(q, 4, at);
    if (c->run_id)
        sqlite3_bind_int64(q, 5, c->run_id);
    sqlite3_bind_int64(q, 6, c->evidence);
    sqlite3_bind_int64(q, 7, c->box_count);
    for (int k = 0; k < 6; k++)
        sqlite3_bind_int64(q, 8 + k, (sqlite3_int64)(figures[k] > INT64_MAX ? INT64_MAX : figures[k]));
    if (c->detail)
        sqlite3_bind_text(q, 14, c->detail, -1, SQLITE_STATIC);
    if ((r = step_done(d, q)) < 0)
        return r;
    if ((r = insert_boxes(d, st[R_BOX], c->object_id, next, c->box_count, c->boxes)) < 0 ||
        (r = insert_ties(d, st[R_TIE], c->object_id, next, c->run_id, c->ncluster_ids, c->cluster_ids)) < 0)
        return r;
    *candidate = (uint32_t)next;
    return 0;
}

int db_ecm_reject(db *d, const db_ecm_candidate *c, double at, uint32_t *candidate)
{
    if (!c || !candidate)
        return db__fail(d, -EINVAL, "ecm reject: no candidate given");
    /* The same checks as a version's: it is one, but for the verdict. */
    db_ecm_change as_version = {.object_id = c->object_id, .parent_version = c->version, .reason = "rejected",
                                .run_id = c->run_id, .ncluster_ids = c->ncluster_ids, .cluster_ids = c->cluster_ids,
                                .detail = c->detail, .box_count = c->box_count, .boxes = c->boxes};
    int rc = check_change(d, &as_version, at, candidate);
    if (rc < 0)
        return rc;
    return in_transaction(d, reject_sql, R_COUNT, reject_locked, c, at, candidate, "ecm reject");
}

int db_ecm_rejected(db *d, int64_t object_id, uint32_t version, int64_t evidence, uint32_t *candidate)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(db_sqlite(d),
                           "SELECT candidate FROM ecm_candidates WHERE object_id = ?1 AND version = ?2 "
                           "AND evidence = ?3 ORDER BY candidate LIMIT 1",
                           -1, &st, NULL) != SQLITE_OK)
        return db__sql_fail(d, NULL);
    sqlite3_bind_int64(st, 1, object_id);
    sqlite3_bind_int64(st, 2, version);
    sqlite3_bind_int64(st, 3, evidence);
    int r = step_row(d, st);
    if (r == 1)
        *candidate = (uint32_t)sqlite3_column_int64(st, 0);
    sqlite3_finalize(st);
    return r;
}

/* ---- reading versions ---- */

/* Reads the boxes of one version with one statement (one snapshot), checking
 * that they are the box_count the version says, numbered 0.. in order. */
static int read_boxes(db *d, int64_t object_id, uint32_t version, float (**boxes)[6], uint32_t *count)
{
    *boxes = NULL;
    *count = 0;
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(db_sqlite(d),
                           "SELECT v.box_count, b.box_index, b.min_x, b.min_y, b.min_z, b.max_x, b.max_y, b.max_z "
                           "FROM ecm_versions v LEFT JOIN ecm_boxes b ON b.object_id = v.object_id "
                           "AND b.version = v.version WHERE v.object_id = ?1 AND v.version = ?2 ORDER BY b.box_index",
                           -1, &st, NULL) != SQLITE_OK)
        return db__sql_fail(d, NULL);
    sqlite3_bind_int64(st, 1, object_id);
    sqlite3_bind_int64(st, 2, version);
    float(*out)[6] = NULL;
    int64_t want = -1; /* the version's box_count; -1: no such version */
    uint32_t n = 0;
    int rc, r;
    while ((r = step_row(d, st)) == 1) {
        if (want < 0) {
            want = sqlite3_column_int64(st, 0);
            /* Not trusted for the allocation beyond what a version may hold. */
            if (want < 1 || want > (int64_t)DB_ECM_BOXES_MAX) {
                rc = db__fail(d, -EIO, "object %lld version %u: box count %lld out of range", (long long)object_id,
                              version, (long long)want);
                goto done;
            }
            out = cvre_malloc((size_t)want * sizeof *out);
            if (!out) {
                rc = db__fail(d, -ENOMEM, "out of memory reading %lld boxes", (long long)want);
                goto done;
            }
        }
        if (sqlite3_column_type(st, 1) == SQLITE_NULL || n >= want || sqlite3_column_int64(st, 1) != n)
            break; /* no boxes, more than box_count, or a gap in the indexes */
        for (int k = 0; k < 6; k++)
            out[n][k] = (float)sqlite3_column_double(st, 2 + k);
        n++;
    }
    if ((rc = r) < 0)
        goto done;
    if (want < 0) {
        rc = db__fail(d, -ENOENT, "object %lld has no ECM version %u", (long long)object_id, version);
        goto done;
    }
    if (r == 1 || n != want) {
        rc = db__fail(d, -EIO, "object %lld version %u: its stored boxes do not match its box count %lld",
                      (long long)object_id, version, (long long)want);
        goto done;
    }
    *boxes = out;
    *count = n;
    out = NULL;
    rc = 0;
done:
    sqlite3_finalize(st);
    free(out);
    return rc;
}

int db_ecm_boxes(db *d, int64_t object_id, uint32_t version, float (**boxes)[6], uint32_t *count)
{
    return read_boxes(d, object_id, version, boxes, count);
}

/* ---- the change feed ---- */

int db_ecm_events(db *d, int64_t after, db_ecm_event_fn *fn, void *ctx, int64_t *last)
{
    struct {
        int64_t id, object;
        uint32_t version;
    } batch[DB_ECM_EVENTS_BATCH];
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(db_sqlite(d), "SELECT id, object_id, version FROM ecm_events WHERE id > ?1 ORDER BY id LIMIT ?2",
                           -1, &st, NULL) != SQLITE_OK)
        return db__sql_fail(d, NULL);
    int rc = 0;
    for (;;) {
        int n = 0, r;
        sqlite3_bind_int64(st, 1, after);
        sqlite3_bind_int(st, 2, DB_ECM_EVENTS_BATCH);
        while ((r = step_row(d, st)) == 1) {
            int64_t v = sqlite3_column_int64(st, 2);
            if (v < 1 || v > (int64_t)DB_ECM_VERSION_MAX) {
                r = db__fail(d, -EIO, "ecm event %lld: version %lld out of range",
                             (long long)sqlite3_column_int64(st, 0), (long long)v);
                break;
            }
            batch[n].id = sqlite3_column_int64(st, 0);
            batch[n].object = sqlite3_column_int64(st, 1);
            batch[n].version = (uint32_t)v;
            n++;
        }
        /* Reset before fn runs: no statement of ours is active while fn uses d. */
        sqlite3_reset(st);
        if (r < 0) {
            rc = r;
            break;
        }
        for (int i = 0; i < n; i++) {
            rc = fn(ctx, batch[i].id, batch[i].object, batch[i].version);
            if (rc != 0)
                goto done;
            *last = after = batch[i].id;
        }
        if (n < DB_ECM_EVENTS_BATCH)
            break;
    }
done:
    sqlite3_finalize(st);
    return rc;
}

int db_ecm_events_head(db *d, int64_t *last)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(db_sqlite(d), "SELECT coalesce(max(id), 0) FROM ecm_events", -1, &st, NULL) != SQLITE_OK)
        return db__sql_fail(d, NULL);
    int r = step_row(d, st);
    if (r == 1)
        *last = sqlite3_column_int64(st, 0);
    sqlite3_finalize(st);
    return r == 1 ? 0 : r == 0 ? db__fail(d, -EIO, "ecm events: no maximum") : r; /* an aggregate has its row */
}

/* ---- one object, for the server ---- */

/* The mesh of object id (meshes' rowid), bytes long (its blob's length,
 * which SQLite keeps under INT_MAX), into *tris (cvre_malloc'd): read
 * straight into it with the blob API, where a column's blob is assembled
 * in a buffer of SQLite's first and copied (the city block's 14 MB: a
 * third of the load). 0 or a negative errno. */
static int read_mesh(db *d, int64_t id, size_t bytes, float **tris)
{
    *tris = cvre_malloc(bytes);
    if (!*tris)
        return db__fail(d, -ENOMEM, "object %lld: out of memory for %zu bytes of mesh", (long long)id, bytes);
    sqlite3_blob *b = NULL;
    int rc = 0;
    if (sqlite3_blob_open(db_sqlite(d), "main", "meshes", "triangles", id, 0, &b) != SQLITE_OK ||
        sqlite3_blob_read(b, *tris, (int)bytes, 0) != SQLITE_OK)
        rc = db__sql_fail(d, "reading the mesh");
    sqlite3_blob_close(b);
    return rc;
}

/* The part of db_ecm_object_load inside its read snapshot. */
static int object_load(db *d, int64_t object_id, db_ecm_object *out)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(db_sqlite(d),
                           "SELECT o.ecm_version, o.tri_count, o.removed_at IS NOT NULL, m.object_id IS NULL, "
                           "length(m.triangles) FROM objects o LEFT JOIN meshes m ON m.object_id = o.id "
                           "WHERE o.id = ?1",
                           -1, &st, NULL) != SQLITE_OK)
        return db__sql_fail(d, NULL);
    sqlite3_bind_int64(st, 1, object_id);
    long long id = (long long)object_id;
    int rc, r = step_row(d, st);
    if (r <= 0) {
        rc = r < 0 ? r : db__fail(d, -ENOENT, "no object %lld", id);
        goto done;
    }
    int64_t version = sqlite3_column_int64(st, 0), tris = sqlite3_column_int64(st, 1);
    if (sqlite3_column_int(st, 2)) {
        rc = db__fail(d, -ENOENT, "object %lld was removed", id);
        goto done;
    }
    if (version < 1 || version > (int64_t)DB_ECM_VERSION_MAX || tris < 0 || tris > (int64_t)UINT32_MAX) {
        rc = db__fail(d, -EIO, "object %lld: version %lld or triangle count %lld out of range", id,
                      (long long)version, (long long)tris);
        goto done;
    }
    if (sqlite3_column_int(st, 3)) {
        rc = db__fail(d, -EIO, "object %lld has no mesh", id);
        goto done;
    }
    /* The blob's length (its record's header: length() reads no content)
     * is checked against the count before anything is read: the count
     * sizes the allocation. */
    size_t bytes = (size_t)tris * 9 * sizeof(float);
    if ((size_t)sqlite3_column_int64(st, 4) != bytes) {
        rc = db__fail(d, -EIO, "object %lld: mesh size does not match its triangle count", id);
        goto done;
    }
    if (bytes && (rc = read_mesh(d, object_id, bytes, &out->tris)) < 0)
        goto done;
    out->id = object_id;
    out->version = (uint32_t)version;
    out->tri_count = (uint32_t)tris;
    rc = read_boxes(d, object_id, out->version, &out->boxes, &out->box_count);
done:
    sqlite3_finalize(st);
    return rc;
}

int db_ecm_object_load(db *d, int64_t object_id, db_ecm_object *out)
{
    *out = (db_ecm_object){0};
    int own, rc = begin_read(d, &own);
    if (rc < 0)
        return rc;
    rc = object_load(d, object_id, out);
    end_read(d, own);
    if (rc < 0)
        db_ecm_object_free(out);
    return rc;
}

void db_ecm_object_free(db_ecm_object *o)
{
    if (!o)
        return;
    free(o->tris);
    free(o->boxes);
    *o = (db_ecm_object){0};
}
