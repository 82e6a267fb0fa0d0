#include "query.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "db.h"
#include "out.h"

/* Longest SQL text assembled here (the collisions query with every filter
 * is under 1.5 KiB). */
#define QUERY_SQL_MAX 4096

#define LEN(a) ((int)(sizeof(a) / sizeof((a)[0])))

static int fail(char *err, size_t errlen, int code, const char *fmt, ...) __attribute__((format(printf, 4, 5)));
static int fail(char *err, size_t errlen, int code, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(err, errlen, fmt, ap);
    va_end(ap);
    return code;
}

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
 * used, the values never enter it. */
static void bind_filter(sqlite3_stmt *st, const query_filter *f, int64_t user_id)
{
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
    bind_int(st, ":limit", f->limit > 0 ? f->limit : -1); /* SQLite: a negative limit is none */
    bind_double(st, ":now", db_now());
}

/* Runs sql with f's values and prints its rows as cols. */
static int run(sqlite3 *s, const char *sql, const query_filter *f, int64_t user_id, const out_column *cols, int ncols,
               int vertical, int format, char *err, size_t errlen)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(s, sql, -1, &st, NULL) != SQLITE_OK)
        return fail(err, errlen, QUERY_ERROR, "query failed: %s", sqlite3_errmsg(s));
    bind_filter(st, f, user_id);
    out *o = out_begin(format, stdout, cols, ncols, vertical);
    int rc;
    while ((rc = sqlite3_step(st)) == SQLITE_ROW)
        out_row(o, st);
    long rows = out_end(o);
    if (rc != SQLITE_DONE)
        fail(err, errlen, QUERY_ERROR, "query failed: %s", sqlite3_errmsg(s));
    sqlite3_finalize(st);
    if (rc != SQLITE_DONE)
        return QUERY_ERROR;
    if (rows < 0)
        return fail(err, errlen, QUERY_ERROR, "cannot write the output");
    return QUERY_OK;
}

/* One integer from a statement with one parameter; *found tells whether a
 * row came back. */
static int lookup(sqlite3 *s, const char *sql, const char *text, int64_t num, int64_t *out_id, int *found, char *err,
                  size_t errlen)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(s, sql, -1, &st, NULL) != SQLITE_OK)
        return fail(err, errlen, QUERY_ERROR, "query failed: %s", sqlite3_errmsg(s));
    if (text)
        sqlite3_bind_text(st, 1, text, -1, SQLITE_STATIC);
    else
        sqlite3_bind_int64(st, 1, num);
    int rc = sqlite3_step(st);
    *found = rc == SQLITE_ROW;
    if (*found)
        *out_id = sqlite3_column_int64(st, 0);
    else if (rc != SQLITE_DONE)
        fail(err, errlen, QUERY_ERROR, "query failed: %s", sqlite3_errmsg(s));
    sqlite3_finalize(st);
    return rc == SQLITE_ROW || rc == SQLITE_DONE ? QUERY_OK : QUERY_ERROR;
}

/* Resolves the user and object a filter names; QUERY_NOT_FOUND if either
 * does not exist, so that a typo does not read as "no collisions". */
static int resolve(sqlite3 *s, const query_filter *f, int64_t *user_id, char *err, size_t errlen)
{
    int found, rc;
    int64_t id;
    *user_id = 0;
    if (f->user) {
        rc = lookup(s, "SELECT id FROM users WHERE name = ?1", f->user, 0, user_id, &found, err, errlen);
        if (rc != QUERY_OK)
            return rc;
        if (!found)
            return fail(err, errlen, QUERY_NOT_FOUND, "no user named \"%s\"", f->user);
    }
    if (f->has_object) {
        rc = lookup(s, "SELECT id FROM objects WHERE id = ?1", NULL, f->object, &id, &found, err, errlen);
        if (rc != QUERY_OK)
            return rc;
        if (!found)
            return fail(err, errlen, QUERY_NOT_FOUND, "no object with id %lld", (long long)f->object);
    }
    return QUERY_OK;
}

/* Starts the read transaction a query runs in, so that its statements see
 * one snapshot of a database the server keeps writing. */
static int begin_snapshot(sqlite3 *s, char *err, size_t errlen)
{
    if (sqlite3_exec(s, "BEGIN", NULL, NULL, NULL) != SQLITE_OK)
        return fail(err, errlen, QUERY_ERROR, "cannot start a read transaction: %s", sqlite3_errmsg(s));
    return QUERY_OK;
}

/* Ends it and passes rc through. */
static int end_snapshot(sqlite3 *s, int rc)
{
    sqlite3_exec(s, "COMMIT", NULL, NULL, NULL); /* read-only: nothing to lose */
    return rc;
}

int query_collisions(sqlite3 *s, const query_filter *f, int format, char *err, size_t errlen)
{
    static const out_column cols[] = {
        {"id", OUT_INT, 0},          {"time", OUT_TIME, 0},        {"user", OUT_TEXT, 0},
        {"session", OUT_INT, 1},     {"avatar", OUT_INT, 1},       {"object", OUT_INT, 0},
        {"version", OUT_INT, 0},     {"box", OUT_INT, 0},          {"inside", OUT_BOOL, 0},
        {"world_x", OUT_REAL, 0},    {"world_y", OUT_REAL, 0},     {"world_z", OUT_REAL, 0},
        {"local_x", OUT_REAL, 1},    {"local_y", OUT_REAL, 1},     {"local_z", OUT_REAL, 1},
        {"normal_x", OUT_REAL, 1},   {"normal_y", OUT_REAL, 1},    {"normal_z", OUT_REAL, 1},
        {"velocity_x", OUT_REAL, 1}, {"velocity_y", OUT_REAL, 1},  {"velocity_z", OUT_REAL, 1},
    };
    char sql[QUERY_SQL_MAX] = "SELECT c.id, c.at, u.name, c.session_id, c.avatar_id, c.object_id, c.ecm_version, "
                              "c.box_index, c.inside, c.world_x, c.world_y, c.world_z, c.local_x, c.local_y, "
                              "c.local_z, c.normal_x, c.normal_y, c.normal_z, c.vel_x, c.vel_y, c.vel_z ";
    /* A region goes through the rtree (each contact point is a box of zero
     * size there); the exact test on the row keeps the answer exact. */
    cat(sql, f->has_region ? "FROM collisions_rtree r JOIN collisions c ON c.id = r.id " : "FROM collisions c ");
    cat(sql, "LEFT JOIN users u ON u.id = c.user_id WHERE 1 ");
    if (f->has_region)
        cat(sql, "AND r.min_x <= :x1 AND r.max_x >= :x0 AND r.min_y <= :y1 AND r.max_y >= :y0 "
                 "AND r.min_z <= :z1 AND r.max_z >= :z0 AND c.world_x BETWEEN :x0 AND :x1 "
                 "AND c.world_y BETWEEN :y0 AND :y1 AND c.world_z BETWEEN :z0 AND :z1 ");
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
    if (rc != QUERY_OK)
        return rc;
    int64_t user_id;
    rc = resolve(s, f, &user_id, err, errlen);
    if (rc == QUERY_OK)
        rc = run(s, sql, f, user_id, cols, LEN(cols), 0, format, err, errlen);
    return end_snapshot(s, rc);
}

int query_top_objects(sqlite3 *s, const query_filter *f, int format, char *err, size_t errlen)
{
    static const out_column cols[] = {
        {"object", OUT_INT, 0},     {"name", OUT_TEXT, 0},  {"owner", OUT_TEXT, 0},
        {"collisions", OUT_INT, 0}, {"users", OUT_INT, 0},  {"first", OUT_TIME, 0},
        {"last", OUT_TIME, 0},      {"in_world", OUT_BOOL, 1},
    };
    char sql[QUERY_SQL_MAX] = "SELECT t.object_id, o.name, u.name, t.n, t.users, t.first, t.last, "
                              "o.id IS NOT NULL AND o.removed_at IS NULL "
                              "FROM (SELECT object_id, count(*) AS n, count(DISTINCT user_id) AS users, "
                              "min(at) AS first, max(at) AS last FROM collisions WHERE 1 ";
    if (f->has_since)
        cat(sql, "AND at >= :since ");
    if (f->has_until)
        cat(sql, "AND at < :until ");
    cat(sql, "GROUP BY object_id ORDER BY n DESC, object_id LIMIT :limit) t "
             "LEFT JOIN objects o ON o.id = t.object_id LEFT JOIN users u ON u.id = o.owner_id "
             "ORDER BY t.n DESC, t.object_id");
    int rc = begin_snapshot(s, err, errlen);
    if (rc == QUERY_OK)
        rc = run(s, sql, f, 0, cols, LEN(cols), 0, format, err, errlen);
    return end_snapshot(s, rc);
}

int query_object(sqlite3 *s, int64_t id, int format, char *err, size_t errlen)
{
    static const out_column cols[] = {
        {"object", OUT_INT, 0},         {"name", OUT_TEXT, 0},
        {"format", OUT_TEXT, 0},        {"owner", OUT_TEXT, 0},
        {"created", OUT_TIME, 0},       {"removed", OUT_TIME, 0},
        {"pos_x", OUT_REAL, 0},         {"pos_y", OUT_REAL, 0},
        {"pos_z", OUT_REAL, 0},         {"yaw", OUT_REAL, 0},
        {"scale", OUT_REAL, 0},         {"triangles", OUT_INT, 0},
        {"mbr_min_x", OUT_REAL, 0},     {"mbr_min_y", OUT_REAL, 0},
        {"mbr_min_z", OUT_REAL, 0},     {"mbr_max_x", OUT_REAL, 0},
        {"mbr_max_y", OUT_REAL, 0},     {"mbr_max_z", OUT_REAL, 0},
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
        "(SELECT count(*) FROM collisions c WHERE c.object_id = o.id), "
        "(SELECT count(*) FROM collisions c WHERE c.object_id = o.id AND c.ecm_version = o.ecm_version), "
        "(SELECT count(DISTINCT user_id) FROM collisions c WHERE c.object_id = o.id), "
        "(SELECT min(at) FROM collisions c WHERE c.object_id = o.id), "
        "(SELECT max(at) FROM collisions c WHERE c.object_id = o.id) "
        "FROM objects o LEFT JOIN users u ON u.id = o.owner_id WHERE o.id = :object";
    query_filter f = {.has_object = 1, .object = id};
    int rc = begin_snapshot(s, err, errlen);
    if (rc != QUERY_OK)
        return rc;
    int64_t unused;
    rc = resolve(s, &f, &unused, err, errlen);
    if (rc == QUERY_OK)
        rc = run(s, sql, &f, 0, cols, LEN(cols), 1, format, err, errlen);
    return end_snapshot(s, rc);
}

int query_versions(sqlite3 *s, int64_t id, int format, char *err, size_t errlen)
{
    static const out_column cols[] = {
        {"version", OUT_INT, 0}, {"created", OUT_TIME, 0},    {"reason", OUT_TEXT, 0},
        {"boxes", OUT_INT, 0},   {"collisions", OUT_INT, 0},  {"current", OUT_BOOL, 0},
    };
    static const char sql[] =
        "SELECT v.version, v.created_at, v.reason, v.box_count, "
        "(SELECT count(*) FROM collisions c WHERE c.object_id = v.object_id AND c.ecm_version = v.version), "
        "v.version = o.ecm_version "
        "FROM ecm_versions v JOIN objects o ON o.id = v.object_id WHERE v.object_id = :object ORDER BY v.version";
    query_filter f = {.has_object = 1, .object = id};
    int rc = begin_snapshot(s, err, errlen);
    if (rc != QUERY_OK)
        return rc;
    int64_t unused;
    rc = resolve(s, &f, &unused, err, errlen);
    if (rc == QUERY_OK)
        rc = run(s, sql, &f, 0, cols, LEN(cols), 0, format, err, errlen);
    return end_snapshot(s, rc);
}

int query_totals(sqlite3 *s, int format, char *err, size_t errlen)
{
    static const out_column cols[] = {
        {"users", OUT_INT, 0},       {"sessions", OUT_INT, 0},   {"sessions_open", OUT_INT, 0},
        {"objects", OUT_INT, 0},     {"objects_in_world", OUT_INT, 0}, {"collisions", OUT_INT, 0},
        {"first", OUT_TIME, 0},      {"last", OUT_TIME, 0},
    };
    /* The span covers sessions (start to end, or start if still open) and
     * collisions. */
    static const char sql[] =
        "SELECT (SELECT count(*) FROM users), (SELECT count(*) FROM sessions), "
        "(SELECT count(*) FROM sessions WHERE ended_at IS NULL), (SELECT count(*) FROM objects), "
        "(SELECT count(*) FROM objects WHERE removed_at IS NULL), (SELECT count(*) FROM collisions), "
        "(SELECT min(t) FROM (SELECT min(started_at) AS t FROM sessions UNION ALL SELECT min(at) FROM collisions)), "
        "(SELECT max(t) FROM (SELECT max(coalesce(ended_at, started_at)) AS t FROM sessions "
        "UNION ALL SELECT max(at) FROM collisions))";
    query_filter f = {0};
    int rc = begin_snapshot(s, err, errlen);
    if (rc == QUERY_OK)
        rc = run(s, sql, &f, 0, cols, LEN(cols), 1, format, err, errlen);
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
    if (rc != QUERY_OK)
        return rc;
    int64_t user_id;
    rc = resolve(s, f, &user_id, err, errlen);
    if (rc == QUERY_OK)
        rc = run(s, sql, f, user_id, cols, LEN(cols), 0, format, err, errlen);
    return end_snapshot(s, rc);
}
