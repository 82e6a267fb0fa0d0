#include "record.h"

#include <stdio.h>

#include "err.h"

uint64_t cluster_problem_boxes(const cluster_found *found, size_t n)
{
    uint64_t problem_boxes = 0;
    for (size_t k = 0; k < n; k++) {
        int dup = 0;
        for (size_t j = 0; j < k && !dup; j++)
            dup = found[j].object_id == found[k].object_id && found[j].ecm_version == found[k].ecm_version &&
                  found[j].box == found[k].box;
        problem_boxes += !dup;
    }
    return problem_boxes;
}

int cluster_record(db *d, const cluster_run *run, const cluster_found *found, size_t n, int64_t *run_id, char *err,
                   size_t errlen)
{
    sqlite3 *sql = db_sqlite(d);
    sqlite3_stmt *st = NULL;
    uint64_t problem_boxes = cluster_problem_boxes(found, n);
    int rc = db_begin(d);
    if (rc < 0)
        goto fail;
    if (sqlite3_prepare_v2(sql,
                           "INSERT INTO cluster_runs(started_at, finished_at, eps, min_points, min_users, since, "
                           "until, objects, points, clusters, problem_boxes) "
                           "VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11)",
                           -1, &st, NULL) != SQLITE_OK)
        goto fail;
    sqlite3_bind_double(st, 1, run->started);
    sqlite3_bind_double(st, 2, run->finished);
    sqlite3_bind_double(st, 3, run->params.eps);
    sqlite3_bind_int64(st, 4, run->params.min_points);
    sqlite3_bind_int64(st, 5, run->params.min_users);
    if (run->has_since)
        sqlite3_bind_double(st, 6, run->since);
    if (run->has_until)
        sqlite3_bind_double(st, 7, run->until);
    sqlite3_bind_int64(st, 8, (sqlite3_int64)run->objects);
    sqlite3_bind_int64(st, 9, (sqlite3_int64)run->points);
    sqlite3_bind_int64(st, 10, (sqlite3_int64)n);
    sqlite3_bind_int64(st, 11, (sqlite3_int64)problem_boxes);
    if (sqlite3_step(st) != SQLITE_DONE)
        goto fail;
    *run_id = sqlite3_last_insert_rowid(sql);
    sqlite3_finalize(st);
    st = NULL;
    if (sqlite3_prepare_v2(sql,
                           "INSERT INTO clusters(run_id, object_id, ecm_version, cluster_id, points, users, "
                           "centroid_x, centroid_y, centroid_z, min_x, min_y, min_z, max_x, max_y, max_z, "
                           "box_index) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, "
                           "?16)",
                           -1, &st, NULL) != SQLITE_OK)
        goto fail;
    for (size_t k = 0; k < n; k++) {
        const cluster_found *f = &found[k];
        sqlite3_bind_int64(st, 1, *run_id);
        sqlite3_bind_int64(st, 2, f->object_id);
        sqlite3_bind_int64(st, 3, f->ecm_version);
        sqlite3_bind_int64(st, 4, f->cluster_id);
        sqlite3_bind_int64(st, 5, f->c.points);
        sqlite3_bind_int64(st, 6, f->c.users);
        for (int j = 0; j < 3; j++) {
            sqlite3_bind_double(st, 7 + j, (double)f->c.centroid[j]);
            sqlite3_bind_double(st, 10 + j, (double)f->c.min[j]);
            sqlite3_bind_double(st, 13 + j, (double)f->c.max[j]);
        }
        sqlite3_bind_int64(st, 16, f->box);
        if (sqlite3_step(st) != SQLITE_DONE)
            goto fail;
        sqlite3_reset(st);
    }
    sqlite3_finalize(st);
    st = NULL;
    if ((rc = db_commit(d)) < 0)
        goto fail;
    return 0;
fail:
    if (rc == 0) /* a statement failed (db_begin and db_commit return why) */
        rc = db_sqlite_errno(sql);
    cvre_fail(err, errlen, rc, "recording the clustering run: %s", sqlite3_errmsg(sql));
    sqlite3_finalize(st);
    db_rollback(d);
    return rc;
}
