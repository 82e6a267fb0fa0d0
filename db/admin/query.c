#include "query.h"

#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "db.h"
#include "dblog.h"
#include "ecm.h"
#include "err.h"
#include "out.h"

/* Longest SQL text assembled here (the collisions query with every filter
 * is under 1.5 KiB). */
#define QUERY_SQL_MAX 4096

#define LEN(a) ((int)(sizeof(a) / sizeof((a)[0])))

/* Appends constant fragments to a SQL buffer. Overflow is a programming
 * error (the fragments are fixed), so it aborts. */
static void cat(char *sql, const char *frag)
{
    size_t n = strlen(sql), k = strlen(frag);
    if (n + k >= QUERY_SQL_MAX)
        abort();
    memcpy(sql + n, frag, k + 1);
}

static void bind_double(sqlite3_stmt *st, const char *name, double v)
{
    int i = sqlite3_bind_parameter_index(st, name);
    if (i)
        sqlite3_bind_double(st, i, v);
}

static void bind_int(sqlite3_stmt *st, const char *name, int64_t v)
{
    int i = sqlite3_bind_parameter_index(st, name);
    if (i)
        sqlite3_bind_int64(st, i, v);
}

/* Binds every filter value the statement names: the SQL decides which are
 * used, the values never enter it. ranges (may be NULL) is the JSON array
 * of [first_id, last_id] pairs that :ranges names (see find_ranges). */
static void bind_filter(sqlite3_stmt *st, const query_filter *f, int64_t user_id, const char *ranges)
{
    int at = sqlite3_bind_parameter_index(st, ":ranges");
    if (at)
        sqlite3_bind_text(st, at, ranges ? ranges : "[]", -1, SQLITE_STATIC);
    bind_int(st, ":b0", f->has_since ? dblog_bucket(f->since) : -DBLOG_BUCKET_MAX);
    bind_int(st, ":b1", f->has_until ? dblog_bucket(f->until) : DBLOG_BUCKET_MAX);
    static const char *const corner[6] = {":x0", ":y0", ":z0", ":x1", ":y1", ":z1"};
    if (f->has_object)
        bind_int(st, ":object", f->object);
    bind_int(st, ":user_id", user_id);
    if (f->has_since)
        bind_double(st, ":since", f->since);
    if (f->has_until)
        bind_double(st, ":until", f->until);
    if (f->has_region)
        for (int i = 0; i < 6; i++)
            bind_double(st, corner[i], f->region[i]);
    /* One row more than asked: print_rows tells whether more match. SQLite:
     * a negative limit is none. */
    bind_int(st, ":limit", f->limit > 0 ? f->limit + 1 : -1);
    bind_double(st, ":now", db_now());
}

/* Prints the rows of the prepared statement st as cols, then finalizes it.
 * limit > 0: st was bound to return one row more (bind_filter); at most
 * limit are printed, and if one more came, a line on stderr says that the
 * answer was cut short, so that stdout stays the rows alone in every
 * format. */
static int print_rows(sqlite3 *s, sqlite3_stmt *st, const out_column *cols, int ncols, int vertical, int format,
                      int64_t limit, char *err, size_t errlen)
{
    out *o = out_begin(format, stdout, cols, ncols, vertical);
    int rc, more = 0;
    int64_t shown = 0;
    while ((rc = sqlite3_step(st)) == SQLITE_ROW) {
        if (limit > 0 && shown == limit) {
            more = 1;
            break;
        }
        out_row(o, st);
        shown++;
    }
    long rows = out_end(o);
    int ok = rc == SQLITE_DONE || more;
    if (!ok)
        cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
    sqlite3_finalize(st);
    if (!ok)
        return -EIO;
    if (rows < 0)
        return cvre_fail(err, errlen, -EIO, "cannot write the output");
    if (more)
        fprintf(stderr, "cvre-admin: showing the first %lld rows; more match (--limit N for more, --limit 0 for all)\n",
                (long long)limit);
    return 0;
}

int query_print(sqlite3 *s, sqlite3_stmt *st, const struct out_column *cols, int ncols, int vertical, int format,
                char *err, size_t errlen)
{
    return print_rows(s, st, cols, ncols, vertical, format, 0, err, errlen);
}

/* Runs sql with f's values and prints its rows as cols. */
static int run(sqlite3 *s, const char *sql, const query_filter *f, int64_t user_id, const char *ranges,
               const out_column *cols, int ncols, int vertical, int format, char *err, size_t errlen)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(s, sql, -1, &st, NULL) != SQLITE_OK)
        return cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
    bind_filter(st, f, user_id, ranges);
    return print_rows(s, st, cols, ncols, vertical, format, f->limit, err, errlen);
}

/* One integer from a statement with one parameter; *found tells whether a
 * row came back. */
static int lookup(sqlite3 *s, const char *sql, const char *text, int64_t num, int64_t *out_id, int *found, char *err,
                  size_t errlen)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(s, sql, -1, &st, NULL) != SQLITE_OK)
        return cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
    if (text)
        sqlite3_bind_text(st, 1, text, -1, SQLITE_STATIC);
    else
        sqlite3_bind_int64(st, 1, num);
    int rc = sqlite3_step(st);
    *found = rc == SQLITE_ROW;
    if (*found)
        *out_id = sqlite3_column_int64(st, 0);
    else if (rc != SQLITE_DONE)
        cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
    sqlite3_finalize(st);
    return rc == SQLITE_ROW || rc == SQLITE_DONE ? 0 : -EIO;
}

/* Resolves the user and object a filter names; -ENOENT if either
 * does not exist, so that a typo does not read as "no collisions". */
static int resolve(sqlite3 *s, const query_filter *f, int64_t *user_id, char *err, size_t errlen)
{
    int found = 0, rc;
    int64_t id;
    *user_id = 0;
    if (f->user) {
        rc = lookup(s, "SELECT id FROM users WHERE name = ?1", f->user, 0, user_id, &found, err, errlen);
        if (rc != 0)
            return rc;
        if (!found)
            return cvre_fail(err, errlen, -ENOENT, "no user named \"%s\"", f->user);
    }
    if (f->has_object) {
        rc = lookup(s, "SELECT id FROM objects WHERE id = ?1", NULL, f->object, &id, &found, err, errlen);
        if (rc != 0)
            return rc;
        if (!found)
            return cvre_fail(err, errlen, -ENOENT, "no object with id %lld", (long long)f->object);
    }
    return 0;
}

/* Starts the read transaction a query runs in, so that its statements see
 * one snapshot of a database the server keeps writing. */
static int begin_snapshot(sqlite3 *s, char *err, size_t errlen)
{
    if (sqlite3_exec(s, "BEGIN", NULL, NULL, NULL) != SQLITE_OK)
        return cvre_fail(err, errlen, -EIO, "cannot start a read transaction: %s", sqlite3_errmsg(s));
    return 0;
}

/* Ends it and passes rc through. */
static int end_snapshot(sqlite3 *s, int rc)
{
    sqlite3_exec(s, "COMMIT", NULL, NULL, NULL); /* read-only: nothing to lose */
    return rc;
}

/* ---- finding collision rows (db/README.md, "Collision log storage") ---- */

/* A growing JSON array of [first_id, last_id] pairs, adjacent ranges
 * merged. */
typedef struct ranges {
    char *text;
    size_t len, cap;
    int64_t lo, hi; /* the pending range; lo > hi: none */
    int64_t rows;   /* ids covered so far, pending range included */
    int failed;     /* out of memory */
} ranges;

static void ranges_flush(ranges *r)
{
    if (r->lo > r->hi || r->failed)
        return;
    char item[64];
    int k = snprintf(item, sizeof item, "%s[%lld,%lld]", r->len > 1 ? "," : "", (long long)r->lo, (long long)r->hi);
    if (r->len + (size_t)k + 2 > r->cap) {
        size_t cap = r->cap ? r->cap * 2 : 4096;
        char *t = realloc(r->text, cap);
        if (!t) {
            r->failed = 1;
            return;
        }
        r->text = t;
        r->cap = cap;
    }
    memcpy(r->text + r->len, item, (size_t)k);
    r->len += (size_t)k;
    r->lo = 1, r->hi = 0;
}

static void ranges_init(ranges *r)
{
    *r = (ranges){.lo = 1, .hi = 0};
    r->text = malloc(4096);
    if (!r->text) {
        r->failed = 1;
        return;
    }
    r->cap = 4096;
    r->text[0] = '[';
    r->len = 1;
}

static void ranges_add(ranges *r, int64_t lo, int64_t hi)
{
    if (lo > hi)
        return;
    r->rows += hi - lo + 1;
    if (r->lo <= r->hi && lo == r->hi + 1) {
        r->hi = hi;
        return;
    }
    ranges_flush(r);
    r->lo = lo, r->hi = hi;
}

/* Closes the array; returns its text (owned by r), or NULL if out of
 * memory. */
static const char *ranges_end(ranges *r)
{
    ranges_flush(r);
    if (r->failed)
        return NULL;
    r->text[r->len] = ']';
    r->text[r->len + 1] = 0;
    return r->text;
}

/* The key a segment is sorted by, of the first row with id >= id, or
 * found = 0 past the end. */
struct probe {
    sqlite3_stmt *st; /* SELECT id, object_id, ecm_version, g ... id >= ?1 ORDER BY id LIMIT 1 */
    int rc;           /* the first error */
};

static int key_cmp(const int64_t a[3], const int64_t b[3], int n)
{
    for (int k = 0; k < n; k++)
        if (a[k] != b[k])
            return a[k] < b[k] ? -1 : 1;
    return 0;
}

/* The smallest id in [lo, hi + 1] such that the first row at or after it
 * (within the segment) has a key whose first n parts are >= key (> key if
 * strict); hi + 1 if there is none. Keys are non-decreasing along the
 * segment's ids, so this is a binary search of log2(hi - lo) probes. */
static int64_t seek(struct probe *p, int64_t lo, int64_t hi, const int64_t key[3], int n, int strict)
{
    int64_t end = hi + 1;
    while (lo < end) {
        int64_t mid = lo + (end - lo) / 2, k[3];
        sqlite3_bind_int64(p->st, 1, mid);
        int rc = sqlite3_step(p->st);
        int after; /* the row found is at or past the key */
        if (rc == SQLITE_ROW && sqlite3_column_int64(p->st, 0) <= hi) {
            for (int i = 0; i < 3; i++)
                k[i] = sqlite3_column_int64(p->st, 1 + i);
            int c = key_cmp(k, key, n);
            after = strict ? c > 0 : c >= 0;
        } else {
            if (rc != SQLITE_ROW && rc != SQLITE_DONE && !p->rc)
                p->rc = rc;
            after = 1; /* past the segment's last row */
        }
        sqlite3_reset(p->st);
        if (after)
            end = mid;
        else
            lo = mid + 1;
    }
    return lo;
}

/* Fills r with the id ranges holding the candidate groups that groups_sql
 * selects (columns: bucket, object_id, ecm_version, g; ordered by bucket),
 * bound with f. In each segment of a group's bucket its rows are one id
 * range, found by binary search. n: how many key parts to match (1: the
 * whole object, 3: the group). Returns 0 or -EIO. */
static int find_ranges(sqlite3 *s, const char *groups_sql, const query_filter *f, int64_t user_id, int n, ranges *r,
                       char *err, size_t errlen)
{
    sqlite3_stmt *gq = NULL, *sq = NULL;
    struct probe p = {0};
    int rc = 0, step;
    int64_t (*seg)[2] = NULL;
    size_t nseg = 0, capseg = 0;
    int64_t seg_bucket = 0, last_key[3] = {0, 0, 0};
    int have_bucket = 0, have_key = 0;
    if (sqlite3_prepare_v2(s, groups_sql, -1, &gq, NULL) != SQLITE_OK ||
        sqlite3_prepare_v2(s, "SELECT first_id, last_id FROM collision_segments WHERE bucket = ?1 ORDER BY first_id",
                           -1, &sq, NULL) != SQLITE_OK ||
        sqlite3_prepare_v2(s, "SELECT id, object_id, ecm_version, g FROM collisions WHERE id >= ?1 ORDER BY id LIMIT 1",
                           -1, &p.st, NULL) != SQLITE_OK) {
        rc = cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
        goto cleanup;
    }
    bind_filter(gq, f, user_id, NULL);
    while ((step = sqlite3_step(gq)) == SQLITE_ROW) {
        int64_t bucket = sqlite3_column_int64(gq, 0);
        int64_t key[3] = {sqlite3_column_int64(gq, 1), sqlite3_column_int64(gq, 2), sqlite3_column_int64(gq, 3)};
        if (!have_bucket || bucket != seg_bucket) { /* the segments of a new bucket */
            have_bucket = 1, have_key = 0;
            seg_bucket = bucket;
            nseg = 0;
            sqlite3_bind_int64(sq, 1, bucket);
            while ((step = sqlite3_step(sq)) == SQLITE_ROW) {
                if (nseg == capseg) {
                    size_t cap = capseg ? capseg * 2 : 64;
                    void *t = realloc(seg, cap * sizeof *seg);
                    if (!t) {
                        rc = cvre_fail(err, errlen, -EIO, "out of memory");
                        goto cleanup;
                    }
                    seg = t, capseg = cap;
                }
                seg[nseg][0] = sqlite3_column_int64(sq, 0);
                seg[nseg][1] = sqlite3_column_int64(sq, 1);
                nseg++;
            }
            sqlite3_reset(sq);
            if (step != SQLITE_DONE)
                break;
        }
        if (have_key && key_cmp(key, last_key, n) == 0)
            continue; /* the same object again (n = 1) */
        memcpy(last_key, key, sizeof key);
        have_key = 1;
        for (size_t k = 0; k < nseg; k++) {
            int64_t a = seek(&p, seg[k][0], seg[k][1], key, n, 0);
            int64_t b = seek(&p, a, seg[k][1], key, n, 1);
            ranges_add(r, a, b - 1);
        }
    }
    if (step != SQLITE_DONE || p.rc)
        rc = cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
cleanup:
    free(seg);
    sqlite3_finalize(gq);
    sqlite3_finalize(sq);
    sqlite3_finalize(p.st);
    return rc;
}

/* Fills r with whole segments of the buckets in [:b0, :b1], newest first;
 * with stop_at > 0, stops after the first bucket that brings the rows of
 * buckets strictly inside the range to stop_at (the newest stop_at rows
 * that match a time filter lie in those buckets). */
static int segment_ranges(sqlite3 *s, const query_filter *f, int64_t stop_at, ranges *r, char *err, size_t errlen)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(s, "SELECT first_id, last_id, bucket FROM collision_segments "
                              "WHERE bucket BETWEEN :b0 AND :b1 ORDER BY bucket DESC, first_id DESC",
                           -1, &st, NULL) != SQLITE_OK)
        return cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
    bind_filter(st, f, 0, NULL);
    int64_t b0 = f->has_since ? dblog_bucket(f->since) : -DBLOG_BUCKET_MAX;
    int64_t b1 = f->has_until ? dblog_bucket(f->until) : DBLOG_BUCKET_MAX;
    int64_t inside = 0, bucket = 0;
    int step, have = 0;
    while ((step = sqlite3_step(st)) == SQLITE_ROW) {
        int64_t b = sqlite3_column_int64(st, 2);
        if (have && b != bucket && stop_at > 0 && inside >= stop_at)
            break;
        have = 1, bucket = b;
        int64_t lo = sqlite3_column_int64(st, 0), hi = sqlite3_column_int64(st, 1);
        ranges_add(r, lo, hi);
        if (b > b0 && b < b1)
            inside += hi - lo + 1;
    }
    int ok = step == SQLITE_DONE || step == SQLITE_ROW;
    if (!ok)
        cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
    sqlite3_finalize(st);
    return ok ? 0 : -EIO;
}

/* The rows read through ranges: SQL for "FROM ..." with c the collision. */
#define FROM_RANGES "FROM json_each(:ranges) j JOIN collisions c ON c.id BETWEEN j.value ->> 0 AND j.value ->> 1 "

int query_collisions(sqlite3 *s, const query_filter *f, int format, char *err, size_t errlen)
{
    static const out_column cols[] = {
        {"id", OUT_INT, 0},          {"time", OUT_TIME, 0},        {"user", OUT_TEXT, 0},
        {"session", OUT_INT, 1},     {"avatar", OUT_INT, 1},       {"object", OUT_INT, 0},
        {"version", OUT_INT, 0},     {"box", OUT_INT, 0},          {"inside", OUT_BOOL, 0},
        {"world_x", OUT_FLOAT, 0},    {"world_y", OUT_FLOAT, 0},     {"world_z", OUT_FLOAT, 0},
        {"local_x", OUT_FLOAT, 1},    {"local_y", OUT_FLOAT, 1},     {"local_z", OUT_FLOAT, 1},
        {"normal_x", OUT_FLOAT, 1},   {"normal_y", OUT_FLOAT, 1},    {"normal_z", OUT_FLOAT, 1},
        {"velocity_x", OUT_FLOAT, 1}, {"velocity_y", OUT_FLOAT, 1},  {"velocity_z", OUT_FLOAT, 1},
    };
    /* Candidate groups: through the rtree for a region, collision_users
     * for a user, the by-object index for an object, buckets for time. */
    char groups[QUERY_SQL_MAX] = "SELECT gr.bucket, gr.object_id, gr.ecm_version, gr.g ";
    cat(groups, f->has_region ? "FROM collision_cells r JOIN collision_groups gr ON gr.g = r.g "
                              : "FROM collision_groups gr ");
    if (f->user)
        cat(groups, "JOIN collision_users cu ON cu.g = gr.g AND cu.user_id = :user_id ");
    cat(groups, "WHERE gr.bucket BETWEEN :b0 AND :b1 ");
    if (f->has_region)
        cat(groups, "AND r.min_x <= :x1 AND r.max_x >= :x0 AND r.min_y <= :y1 AND r.max_y >= :y0 "
                    "AND r.min_z <= :z1 AND r.max_z >= :z0 ");
    if (f->has_region && f->has_since)
        cat(groups, "AND r.max_t >= :since ");
    if (f->has_region && f->has_until)
        cat(groups, "AND r.min_t <= :until ");
    if (f->has_object)
        cat(groups, "AND gr.object_id = :object ");
    cat(groups, "ORDER BY gr.bucket, gr.object_id, gr.ecm_version, gr.g");

    char sql[QUERY_SQL_MAX] = "SELECT c.id, c.at, u.name, c.session_id, c.avatar_id, c.object_id, c.ecm_version, "
                              "c.box_index, c.inside, c.world_x, c.world_y, c.world_z, c.local_x, c.local_y, "
                              "c.local_z, c.normal_x, c.normal_y, c.normal_z, c.vel_x, c.vel_y, c.vel_z ";
    int whole = !f->has_region && !f->user && !f->has_object && !f->has_since && !f->has_until && f->limit <= 0;
    cat(sql, whole ? "FROM collisions c " : FROM_RANGES);
    /* The exact filter on every row read keeps the answer exact. */
    cat(sql, "LEFT JOIN users u ON u.id = c.user_id WHERE 1 ");
    if (f->has_region)
        cat(sql, "AND c.world_x BETWEEN :x0 AND :x1 AND c.world_y BETWEEN :y0 AND :y1 "
                 "AND c.world_z BETWEEN :z0 AND :z1 ");
    if (f->has_object)
        cat(sql, "AND c.object_id = :object ");
    if (f->user)
        cat(sql, "AND c.user_id = :user_id ");
    if (f->has_since)
        cat(sql, "AND c.at >= :since ");
    if (f->has_until)
        cat(sql, "AND c.at < :until ");
    cat(sql, "ORDER BY c.at DESC, c.id DESC LIMIT :limit");

    int rc = begin_snapshot(s, err, errlen);
    if (rc != 0)
        return rc;
    int64_t user_id;
    rc = resolve(s, f, &user_id, err, errlen);
    ranges r;
    ranges_init(&r);
    if (rc == 0 && !whole) {
        if (f->has_region || f->user || f->has_object)
            rc = find_ranges(s, groups, f, user_id, 3, &r, err, errlen);
        else
            rc = segment_ranges(s, f, f->limit > 0 ? f->limit + 1 : 0, &r, err, errlen);
    }
    const char *text = ranges_end(&r);
    if (rc == 0 && !text)
        rc = cvre_fail(err, errlen, -EIO, "out of memory");
    if (rc == 0)
        rc = run(s, sql, f, user_id, text, cols, LEN(cols), 0, format, err, errlen);
    free(r.text);
    return end_snapshot(s, rc);
}

int query_top_objects(sqlite3 *s, const query_filter *f, int format, char *err, size_t errlen)
{
    static const out_column cols[] = {
        {"object", OUT_INT, 0},     {"name", OUT_TEXT, 0},  {"owner", OUT_TEXT, 0},
        {"collisions", OUT_INT, 0}, {"users", OUT_INT, 0},  {"first", OUT_TIME, 0},
        {"last", OUT_TIME, 0},      {"in_world", OUT_BOOL, 1},
    };
    /* Counting every collision reads every row in the time range: the
     * whole table without one. */
    int whole = !f->has_since && !f->has_until;
    char sql[QUERY_SQL_MAX] = "SELECT t.object_id, o.name, u.name, t.n, t.users, t.first, t.last, "
                              "o.id IS NOT NULL AND o.removed_at IS NULL "
                              "FROM (SELECT c.object_id, count(*) AS n, count(DISTINCT c.user_id) AS users, "
                              "min(c.at) AS first, max(c.at) AS last ";
    cat(sql, whole ? "FROM collisions c " : FROM_RANGES);
    cat(sql, "WHERE 1 ");
    if (f->has_since)
        cat(sql, "AND c.at >= :since ");
    if (f->has_until)
        cat(sql, "AND c.at < :until ");
    cat(sql, "GROUP BY c.object_id ORDER BY n DESC, c.object_id LIMIT :limit) t "
             "LEFT JOIN objects o ON o.id = t.object_id LEFT JOIN users u ON u.id = o.owner_id "
             "ORDER BY t.n DESC, t.object_id");
    int rc = begin_snapshot(s, err, errlen);
    if (rc != 0)
        return rc;
    ranges r;
    ranges_init(&r);
    if (!whole)
        rc = segment_ranges(s, f, 0, &r, err, errlen);
    const char *text = ranges_end(&r);
    if (rc == 0 && !text)
        rc = cvre_fail(err, errlen, -EIO, "out of memory");
    if (rc == 0)
        rc = run(s, sql, f, 0, text, cols, LEN(cols), 0, format, err, errlen);
    free(r.text);
    return end_snapshot(s, rc);
}

/* The id ranges of every collision of object f->object (all versions). */
static int object_ranges(sqlite3 *s, const query_filter *f, ranges *r, char *err, size_t errlen)
{
    return find_ranges(s,
                       "SELECT bucket, object_id, 0, 0 FROM collision_groups WHERE object_id = :object "
                       "GROUP BY bucket ORDER BY bucket",
                       f, 0, 1, r, err, errlen);
}

/* Runs sql, a query about one object that reads its collisions through the
 * id ranges of its groups, in one read snapshot; -ENOENT if there is
 * no such object. */
static int per_object(sqlite3 *s, int64_t id, const char *sql, const out_column *cols, int ncols, int vertical,
                      int format, char *err, size_t errlen)
{
    query_filter f = {.has_object = 1, .object = id};
    int rc = begin_snapshot(s, err, errlen);
    if (rc != 0)
        return rc;
    int64_t unused;
    rc = resolve(s, &f, &unused, err, errlen);
    ranges r;
    ranges_init(&r);
    if (rc == 0)
        rc = object_ranges(s, &f, &r, err, errlen);
    const char *text = ranges_end(&r);
    if (rc == 0 && !text)
        rc = cvre_fail(err, errlen, -EIO, "out of memory");
    if (rc == 0)
        rc = run(s, sql, &f, 0, text, cols, ncols, vertical, format, err, errlen);
    free(r.text);
    return end_snapshot(s, rc);
}

int query_object(sqlite3 *s, int64_t id, int format, char *err, size_t errlen)
{
    static const out_column cols[] = {
        {"object", OUT_INT, 0},         {"name", OUT_TEXT, 0},
        {"format", OUT_TEXT, 0},        {"owner", OUT_TEXT, 0},
        {"created", OUT_TIME, 0},       {"removed", OUT_TIME, 0},
        {"pos_x", OUT_FLOAT, 0},         {"pos_y", OUT_FLOAT, 0},
        {"pos_z", OUT_FLOAT, 0},         {"yaw", OUT_FLOAT, 0},
        {"scale", OUT_FLOAT, 0},         {"triangles", OUT_INT, 0},
        {"mbr_min_x", OUT_FLOAT, 0},     {"mbr_min_y", OUT_FLOAT, 0},
        {"mbr_min_z", OUT_FLOAT, 0},     {"mbr_max_x", OUT_FLOAT, 0},
        {"mbr_max_y", OUT_FLOAT, 0},     {"mbr_max_z", OUT_FLOAT, 0},
        {"ecm_version", OUT_INT, 0},    {"ecm_versions", OUT_INT, 0},
        {"boxes", OUT_INT, 0},          {"collisions", OUT_INT, 0},
        {"collisions_current", OUT_INT, 0}, {"users", OUT_INT, 0},
        {"first_collision", OUT_TIME, 0},   {"last_collision", OUT_TIME, 0},
    };
    static const char sql[] =
        "SELECT o.id, o.name, o.format, u.name, o.created_at, o.removed_at, o.pos_x, o.pos_y, o.pos_z, o.yaw, "
        "o.scale, o.tri_count, o.min_x, o.min_y, o.min_z, o.max_x, o.max_y, o.max_z, o.ecm_version, "
        "(SELECT count(*) FROM ecm_versions v WHERE v.object_id = o.id), "
        "(SELECT box_count FROM ecm_versions v WHERE v.object_id = o.id AND v.version = o.ecm_version), "
        "k.n, k.current, k.users, k.first, k.last "
        "FROM objects o LEFT JOIN users u ON u.id = o.owner_id, "
        "(SELECT count(*) AS n, coalesce(sum(c.ecm_version = (SELECT ecm_version FROM objects WHERE id = :object)), 0) "
        "AS current, "
        "count(DISTINCT c.user_id) AS users, min(c.at) AS first, max(c.at) AS last " FROM_RANGES
        "WHERE c.object_id = :object) k WHERE o.id = :object";
    return per_object(s, id, sql, cols, LEN(cols), 1, format, err, errlen);
}

int query_versions(sqlite3 *s, int64_t id, int format, char *err, size_t errlen)
{
    static const out_column cols[] = {
        {"version", OUT_INT, 0},  {"created", OUT_TIME, 0},    {"reason", OUT_TEXT, 0},
        {"parent", OUT_INT, 0},   {"run", OUT_INT, 0},         {"clusters", OUT_TEXT, 0},
        {"restores", OUT_INT, 0}, {"boxes", OUT_INT, 0},       {"collisions", OUT_INT, 0},
        {"current", OUT_BOOL, 0}, {"detail", OUT_TEXT, 0},
    };
    /* Rejected candidates (reason "rejected", no version of their own)
     * come right after the version they were judged against (parent). */
    static const char sql[] =
        "SELECT version, created, reason, parent, run, clusters, restores, boxes, collisions, current, detail FROM ("
        "SELECT v.version AS version, v.created_at AS created, v.reason AS reason, v.parent_version AS parent, "
        "v.run_id AS run, "
        "(SELECT group_concat(t.cluster_id, ',') FROM (SELECT cluster_id FROM ecm_version_clusters t "
        "WHERE t.object_id = v.object_id AND t.version = v.version ORDER BY t.run_id, t.cluster_id) t) AS clusters, "
        "v.restores AS restores, v.box_count AS boxes, coalesce(k.n, 0) AS collisions, "
        "v.version = o.ecm_version AS current, v.detail AS detail, v.version AS after, 0 AS candidate "
        "FROM ecm_versions v JOIN objects o ON o.id = v.object_id "
        "LEFT JOIN (SELECT c.ecm_version AS version, count(*) AS n " FROM_RANGES
        "WHERE c.object_id = :object GROUP BY c.ecm_version) k ON k.version = v.version "
        "WHERE v.object_id = :object "
        "UNION ALL "
        "SELECT NULL, c.created_at, 'rejected', c.version, c.run_id, "
        "(SELECT group_concat(t.cluster_id, ',') FROM (SELECT cluster_id FROM ecm_candidate_clusters t "
        "WHERE t.object_id = c.object_id AND t.candidate = c.candidate ORDER BY t.run_id, t.cluster_id) t), "
        "NULL, c.box_count, 0, 0, 'candidate ' || c.candidate || ': ' || coalesce(c.detail, 'no detail'), "
        "c.version, c.candidate FROM ecm_candidates c WHERE c.object_id = :object"
        ") ORDER BY after, candidate";
    return per_object(s, id, sql, cols, LEN(cols), 0, format, err, errlen);
}

/* ---- ECM versions: diff and rollback ---- */

/* Runs sql, binding :object, :a and :b, and prints its rows as cols. */
static int run_ids(sqlite3 *s, const char *sql, int64_t object, int64_t a, int64_t b, const out_column *cols,
                   int ncols, int vertical, int format, char *err, size_t errlen)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(s, sql, -1, &st, NULL) != SQLITE_OK)
        return cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
    bind_int(st, ":object", object);
    bind_int(st, ":a", a);
    bind_int(st, ":b", b);
    return print_rows(s, st, cols, ncols, vertical, format, 0, err, errlen);
}

/* One integer (NULL as 0) from sql, which has parameter ?1 and maybe ?2
 * and always returns a row. */
static int scalar2(sqlite3 *s, const char *sql, int64_t p1, int64_t p2, int64_t *v, char *err, size_t errlen)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(s, sql, -1, &st, NULL) != SQLITE_OK)
        return cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
    sqlite3_bind_int64(st, 1, p1);
    if (sqlite3_bind_parameter_count(st) >= 2)
        sqlite3_bind_int64(st, 2, p2);
    int rc = sqlite3_step(st);
    *v = rc == SQLITE_ROW ? sqlite3_column_int64(st, 0) : 0;
    if (rc != SQLITE_ROW)
        cvre_fail(err, errlen, -EIO, "query failed: %s", rc == SQLITE_DONE ? "no row" : sqlite3_errmsg(s));
    sqlite3_finalize(st);
    return rc == SQLITE_ROW ? 0 : -EIO;
}

/* -ENOENT (with a message listing the versions there are) if the
 * object has no version v. */
static int has_version(sqlite3 *s, int64_t id, uint32_t v, char *err, size_t errlen)
{
    int64_t n, last;
    int rc = scalar2(s, "SELECT count(*) FROM ecm_versions WHERE object_id = ?1 AND version = ?2", id, v, &n, err,
                     errlen);
    if (rc != 0 || n)
        return rc;
    rc = scalar2(s, "SELECT coalesce(max(version), 0) FROM ecm_versions WHERE object_id = ?1", id, 0, &last, err,
                 errlen);
    if (rc != 0)
        return rc;
    return cvre_fail(err, errlen, -ENOENT, "object %lld has no version %u (its versions: 1 to %lld)",
                (long long)id, v, (long long)last);
}

/* The boxes of versions :a and :b numbered within each run of equal boxes
 * (k), and matched on their six coordinates and k: a box that occurs twice
 * in a matches two in b. m: change ('only_a', 'only_b', 'both'), the box's
 * index in a and in b, its coordinates and volume. */
#define DIFF_SIDE(v)                                                                                      \
    "SELECT box_index, min_x, min_y, min_z, max_x, max_y, max_z, "                                        \
    "(max_x - min_x) * (max_y - min_y) * (max_z - min_z) AS volume, "                                     \
    "row_number() OVER (PARTITION BY min_x, min_y, min_z, max_x, max_y, max_z ORDER BY box_index) AS k " \
    "FROM ecm_boxes WHERE object_id = :object AND version = " v
#define DIFF_SAME(x, y)                                                                                      \
    x ".min_x = " y ".min_x AND " x ".min_y = " y ".min_y AND " x ".min_z = " y ".min_z AND " x ".max_x = " y \
    ".max_x AND " x ".max_y = " y ".max_y AND " x ".max_z = " y ".max_z AND " x ".k = " y ".k"
#define DIFF_CTE                                                                                                 \
    "WITH a AS (" DIFF_SIDE(":a") "), b AS (" DIFF_SIDE(":b") "), "                                              \
    "m AS (SELECT 'both' AS change, a.box_index AS box_a, b.box_index AS box_b, a.min_x, a.min_y, a.min_z, "     \
    "a.max_x, a.max_y, a.max_z, a.volume FROM a JOIN b ON " DIFF_SAME("a", "b") " "                              \
    "UNION ALL SELECT 'only_a', a.box_index, NULL, a.min_x, a.min_y, a.min_z, a.max_x, a.max_y, a.max_z, "       \
    "a.volume FROM a WHERE NOT EXISTS (SELECT 1 FROM b WHERE " DIFF_SAME("a", "b") ") "                          \
    "UNION ALL SELECT 'only_b', NULL, b.box_index, b.min_x, b.min_y, b.min_z, b.max_x, b.max_y, b.max_z, "       \
    "b.volume FROM b WHERE NOT EXISTS (SELECT 1 FROM a WHERE " DIFF_SAME("a", "b") ")) "

int query_diff(sqlite3 *s, int64_t id, uint32_t a, uint32_t b, int format, char *err, size_t errlen)
{
    static const out_column summary[] = {
        {"object", OUT_INT, 0},   {"a", OUT_INT, 0},        {"b", OUT_INT, 0},
        {"boxes_a", OUT_INT, 0},  {"boxes_b", OUT_INT, 0},  {"only_a", OUT_INT, 0},
        {"only_b", OUT_INT, 0},   {"both", OUT_INT, 0},     {"volume_a", OUT_REAL, 0},
        {"volume_b", OUT_REAL, 0},
    };
    static const out_column boxes[] = {
        {"change", OUT_TEXT, 0}, {"box_a", OUT_INT, 0}, {"box_b", OUT_INT, 0},
        {"min_x", OUT_FLOAT, 0},  {"min_y", OUT_FLOAT, 0}, {"min_z", OUT_FLOAT, 0},
        {"max_x", OUT_FLOAT, 0},  {"max_y", OUT_FLOAT, 0}, {"max_z", OUT_FLOAT, 0},
        {"volume", OUT_REAL, 0},
    };
    /* Volumes are sums over boxes: where boxes overlap, counted twice. */
    static const char summary_sql[] = DIFF_CTE
        "SELECT :object, :a, :b, (SELECT count(*) FROM a), (SELECT count(*) FROM b), "
        "(SELECT count(*) FROM m WHERE change = 'only_a'), (SELECT count(*) FROM m WHERE change = 'only_b'), "
        "(SELECT count(*) FROM m WHERE change = 'both'), (SELECT total(volume) FROM a), "
        "(SELECT total(volume) FROM b)";
    static const char boxes_sql[] = DIFF_CTE
        "SELECT change, box_a, box_b, min_x, min_y, min_z, max_x, max_y, max_z, volume FROM m "
        "ORDER BY CASE change WHEN 'only_a' THEN 0 WHEN 'only_b' THEN 1 ELSE 2 END, coalesce(box_a, box_b)";
    query_filter f = {.has_object = 1, .object = id};
    int64_t unused;
    int rc = begin_snapshot(s, err, errlen);
    if (rc == 0)
        rc = resolve(s, &f, &unused, err, errlen);
    if (rc == 0)
        rc = has_version(s, id, a, err, errlen);
    if (rc == 0)
        rc = has_version(s, id, b, err, errlen);
    if (rc != 0)
        return end_snapshot(s, rc);
    /* JSON: one document, {"summary": {...}, "boxes": [...]}; CSV: the boxes
     * only (one table; the summary adds them up); table: both, a blank line
     * between. */
    if (format == OUT_JSON)
        fputs("{\"summary\": ", stdout);
    if (format != OUT_CSV)
        rc = run_ids(s, summary_sql, id, a, b, summary, LEN(summary), OUT_RECORD_BARE, format, err, errlen);
    if (rc == 0)
        fputs(format == OUT_JSON ? ",\n\"boxes\": " : format == OUT_TABLE ? "\n" : "", stdout);
    if (rc == 0)
        rc = run_ids(s, boxes_sql, id, a, b, boxes, LEN(boxes), OUT_ROWS, format, err, errlen);
    if (rc == 0 && format == OUT_JSON && (fputs("}\n", stdout) < 0 || fflush(stdout) != 0))
        rc = cvre_fail(err, errlen, -EIO, "cannot write the output");
    return end_snapshot(s, rc);
}

int query_rollback_check(sqlite3 *s, int64_t id, uint32_t k, uint32_t *in_force, char *err, size_t errlen)
{
    long long oid = (long long)id;
    int64_t v, removed, same;
    int rc = begin_snapshot(s, err, errlen);
    if (rc != 0)
        return rc;
    /* -1: no such object; 0: in the world; 1: removed. */
    rc = scalar2(s, "SELECT coalesce((SELECT removed_at IS NOT NULL FROM objects WHERE id = ?1), -1)", id, 0, &removed,
                 err, errlen);
    if (rc == 0 && removed < 0)
        rc = cvre_fail(err, errlen, -ENOENT, "no object with id %lld", oid);
    if (rc == 0 && removed > 0)
        rc = cvre_fail(err, errlen, -EPERM, "object %lld was removed from the world: its collision map is not in use",
                  oid);
    if (rc == 0)
        rc = has_version(s, id, k, err, errlen);
    if (rc == 0)
        rc = scalar2(s, "SELECT ecm_version FROM objects WHERE id = ?1", id, 0, &v, err, errlen);
    if (rc == 0 && (v < 1 || v > UINT32_MAX))
        rc = cvre_fail(err, errlen, -EIO, "object %lld: version in force %lld out of range", oid, (long long)v);
    if (rc == 0 && v == k)
        rc = cvre_fail(err, errlen, -EPERM, "version %u is already in force for object %lld: nothing to do", k, oid);
    /* The same boxes in the same order (a rollback to k is in force, say). */
    if (rc == 0)
        rc = scalar2(s,
                     "SELECT (SELECT box_count FROM ecm_versions WHERE object_id = ?1 AND version = ?2) = "
                     "(SELECT box_count FROM ecm_versions WHERE object_id = ?1 "
                     "AND version = (SELECT ecm_version FROM objects WHERE id = ?1)) "
                     "AND NOT EXISTS (SELECT 1 FROM ecm_boxes x LEFT JOIN ecm_boxes y ON y.object_id = x.object_id "
                     "AND y.version = (SELECT ecm_version FROM objects WHERE id = ?1) AND y.box_index = x.box_index "
                     "WHERE x.object_id = ?1 AND x.version = ?2 AND (y.box_index IS NULL OR y.min_x != x.min_x "
                     "OR y.min_y != x.min_y OR y.min_z != x.min_z OR y.max_x != x.max_x OR y.max_y != x.max_y "
                     "OR y.max_z != x.max_z))",
                     id, k, &same, err, errlen);
    if (rc == 0 && same)
        rc = cvre_fail(err, errlen, -EPERM,
                  "version %lld in force for object %lld already has version %u's boxes: nothing to do", (long long)v,
                  oid, k);
    if (rc == 0)
        *in_force = (uint32_t)v;
    return end_snapshot(s, rc);
}

int query_rollback(db *d, int64_t id, uint32_t k, uint32_t in_force, int format, char *err, size_t errlen)
{
    static const out_column cols[] = {
        {"object", OUT_INT, 0},   {"version", OUT_INT, 0}, {"parent", OUT_INT, 0},  {"restores", OUT_INT, 0},
        {"reason", OUT_TEXT, 0},  {"boxes", OUT_INT, 0},   {"created", OUT_TIME, 0}, {"detail", OUT_TEXT, 0},
    };
    float(*boxes)[6];
    uint32_t n, version;
    if (db_ecm_boxes(d, id, k, &boxes, &n) < 0)
        return cvre_fail(err, errlen, -EIO, "cannot read version %u: %s", k, db_error(d));
    db_ecm_change c = {.object_id = id, .parent_version = in_force, .reason = "rollback", .restores = k,
                       .detail = "cvre-admin rollback", .box_count = n, .boxes = (const float(*)[6])boxes};
    int rc = db_ecm_write(d, &c, db_now(), &version);
    free(boxes);
    if (rc == -ESTALE)
        return cvre_fail(err, errlen, -EPERM, "object %lld changed meanwhile (%s); nothing written: look again",
                    (long long)id, db_error(d));
    if (rc < 0)
        return cvre_fail(err, errlen, -EIO, "rollback failed, nothing written: %s%s", db_error(d),
                    db_busy(d) ? " (another process held the write lock)" : "");
    return run_ids(db_sqlite(d),
                   "SELECT object_id, version, parent_version, restores, reason, box_count, created_at, detail "
                   "FROM ecm_versions WHERE object_id = :object AND version = :a",
                   id, version, 0, cols, LEN(cols), OUT_RECORD, format, err, errlen);
}

int query_totals(sqlite3 *s, int format, char *err, size_t errlen)
{
    static const out_column cols[] = {
        {"users", OUT_INT, 0},       {"sessions", OUT_INT, 0},   {"sessions_open", OUT_INT, 0},
        {"objects", OUT_INT, 0},     {"objects_in_world", OUT_INT, 0}, {"collisions", OUT_INT, 0},
        {"first", OUT_TIME, 0},      {"last", OUT_TIME, 0},
    };
    /* The span covers sessions (start to end, or start if still open) and
     * collisions: the first and last collisions lie in the segments of the
     * first and last buckets. */
    static const char sql[] =
        "SELECT (SELECT count(*) FROM users), (SELECT count(*) FROM sessions), "
        "(SELECT count(*) FROM sessions WHERE ended_at IS NULL), (SELECT count(*) FROM objects), "
        "(SELECT count(*) FROM objects WHERE removed_at IS NULL), (SELECT count(*) FROM collisions), "
        "(SELECT min(t) FROM (SELECT min(started_at) AS t FROM sessions UNION ALL SELECT min(c.at) "
        "FROM collision_segments g JOIN collisions c ON c.id BETWEEN g.first_id AND g.last_id "
        "WHERE g.bucket = (SELECT min(bucket) FROM collision_segments))), "
        "(SELECT max(t) FROM (SELECT max(coalesce(ended_at, started_at)) AS t FROM sessions "
        "UNION ALL SELECT max(c.at) FROM collision_segments g JOIN collisions c "
        "ON c.id BETWEEN g.first_id AND g.last_id WHERE g.bucket = (SELECT max(bucket) FROM collision_segments)))";
    query_filter f = {0};
    int rc = begin_snapshot(s, err, errlen);
    if (rc == 0)
        rc = run(s, sql, &f, 0, NULL, cols, LEN(cols), 1, format, err, errlen);
    return end_snapshot(s, rc);
}

int query_clusters(sqlite3 *s, const query_filter *f, int format, char *err, size_t errlen)
{
    static const out_column cols[] = {
        {"run", OUT_INT, 0},        {"finished", OUT_TIME, 0}, {"object", OUT_INT, 0},
        {"version", OUT_INT, 0},    {"cluster", OUT_INT, 0},   {"points", OUT_INT, 0},
        {"users", OUT_INT, 0},      {"box", OUT_INT, 0},       {"centroid_x", OUT_FLOAT, 0},
        {"centroid_y", OUT_FLOAT, 0}, {"centroid_z", OUT_FLOAT, 0},
    };
    static const char sql[] =
        "SELECT c.run_id, r.finished_at, c.object_id, c.ecm_version, c.cluster_id, c.points, c.users, c.box_index, "
        "c.centroid_x, c.centroid_y, c.centroid_z FROM clusters c JOIN cluster_runs r ON r.id = c.run_id "
        "WHERE c.run_id = (SELECT max(id) FROM cluster_runs) AND (:object IS NULL OR c.object_id = :object) "
        "ORDER BY c.points DESC, c.object_id, c.cluster_id LIMIT :limit";
    int rc = begin_snapshot(s, err, errlen);
    if (rc == 0)
        rc = run(s, sql, f, 0, NULL, cols, LEN(cols), 0, format, err, errlen);
    return end_snapshot(s, rc);
}

int query_sessions(sqlite3 *s, const query_filter *f, int format, char *err, size_t errlen)
{
    static const out_column cols[] = {
        {"session", OUT_INT, 0},  {"user", OUT_TEXT, 0},    {"peer", OUT_TEXT, 0},
        {"avatar", OUT_INT, 1},   {"started", OUT_TIME, 0}, {"joined", OUT_TIME, 1},
        {"ended", OUT_TIME, 0},   {"reason", OUT_TEXT, 0},  {"duration", OUT_SECONDS, 0},
    };
    /* Connected at some moment in [since, until): started before until and
     * not ended before since. Open sessions last until now. */
    char sql[QUERY_SQL_MAX] = "SELECT s.id, u.name, s.peer, s.avatar_id, s.started_at, s.joined_at, s.ended_at, "
                              "s.end_reason, coalesce(s.ended_at, max(:now, s.started_at)) - s.started_at "
                              "FROM sessions s LEFT JOIN users u ON u.id = s.user_id WHERE 1 ";
    if (f->user)
        cat(sql, "AND s.user_id = :user_id ");
    if (f->has_since)
        cat(sql, "AND (s.ended_at IS NULL OR s.ended_at >= :since) ");
    if (f->has_until)
        cat(sql, "AND s.started_at < :until ");
    cat(sql, "ORDER BY s.started_at DESC, s.id DESC LIMIT :limit");
    int rc = begin_snapshot(s, err, errlen);
    if (rc != 0)
        return rc;
    int64_t user_id;
    rc = resolve(s, f, &user_id, err, errlen);
    if (rc == 0)
        rc = run(s, sql, f, user_id, NULL, cols, LEN(cols), 0, format, err, errlen);
    return end_snapshot(s, rc);
}
