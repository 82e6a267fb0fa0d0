/*
 * map.c: cvre-admin map (map.h), the command. Reading, then figures, then
 * drawing:
 *
 *   objects, versions, boxes, points (one read snapshot)
 *     -> per object: DBSCAN labels (the run's parameters), union volume
 *        of the boxes (map_world.c), digitization of the mesh (voxel.h);
 *        the mesh is read one object at a time and also rasterized into
 *        the outline masks of the two views (map_world.c)
 *     -> the SVG (map_svg.c), built in memory and written whole; the
 *        figures on stdout (map_figures.c).
 *
 * The picture is meant to be compared before and after refinement, so it
 * holds no time and nothing that varies between runs: numbers are printed
 * with fixed precision and everything is drawn in id order.
 */
#include "map.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "ecm.h"
#include "err.h"
#include "mapInt.h"

static void mobj_free(mobj *o)
{
    free(o->name);
    free(o->reason);
    free(o->boxes);
    free(o->orig);
    free(o->xyz);
    free(o->users);
    free(o->labels);
}

/* ---- reading ---- */

typedef struct reader {
    db *d;
    sqlite3 *s;
    char *err;
    size_t errlen;
    sqlite3_stmt *version, *nversions, *run, *points;
} reader;

static int db_fail(reader *rd)
{
    return cvre_fail(rd->err, rd->errlen, -EIO, "query failed: %s", sqlite3_errmsg(rd->s));
}

static char *dup_text(sqlite3_stmt *st, int i)
{
    const unsigned char *t = sqlite3_column_text(st, i);
    size_t n = t ? (size_t)sqlite3_column_bytes(st, i) : 0;
    char *s = cvre_xmalloc(n + 1);
    if (n)
        memcpy(s, t, n);
    s[n] = 0;
    return s;
}

/* The version shown, its boxes, version 1's, the run whose parameters
 * label the points, and the points. */
static int read_object(reader *rd, mobj *o)
{
    long long oid = (long long)o->id;
    sqlite3_stmt *st = rd->version;
    sqlite3_bind_int64(st, 1, o->id);
    sqlite3_bind_int64(st, 2, o->version);
    int step = sqlite3_step(st);
    int64_t parent = 0;
    if (step == SQLITE_ROW) {
        o->reason = dup_text(st, 0);
        parent = sqlite3_column_int64(st, 1);
    }
    sqlite3_reset(st);
    sqlite3_bind_int64(rd->nversions, 1, o->id);
    int nstep = sqlite3_step(rd->nversions);
    int64_t last = nstep == SQLITE_ROW ? sqlite3_column_int64(rd->nversions, 1) : 0;
    o->nversions = nstep == SQLITE_ROW ? (uint32_t)sqlite3_column_int64(rd->nversions, 0) : 0;
    sqlite3_reset(rd->nversions);
    if ((step != SQLITE_ROW && step != SQLITE_DONE) || nstep != SQLITE_ROW)
        return db_fail(rd);
    if (step == SQLITE_DONE)
        return cvre_fail(rd->err, rd->errlen, -ENOENT, "object %lld has no version %u (its versions: 1 to %lld)",
                    oid, o->version, (long long)last);
    /* The store's reader checks the boxes against the version's count. */
    if (db_ecm_boxes(rd->d, o->id, o->version, &o->boxes, &o->nboxes) < 0 ||
        db_ecm_boxes(rd->d, o->id, 1, &o->orig, &o->norig) < 0)
        return cvre_fail(rd->err, rd->errlen, -EIO, "%s", db_error(rd->d));
    /* The collisions the version answered (its parent's) if it has a
     * parent, else its own. */
    o->points_version = parent > 0 && parent <= UINT32_MAX ? (uint32_t)parent : o->version;

    st = rd->run;
    sqlite3_bind_int64(st, 1, o->id);
    sqlite3_bind_int64(st, 2, o->version);
    sqlite3_bind_int64(st, 3, o->points_version);
    step = sqlite3_step(st);
    if (step == SQLITE_ROW) {
        o->has_run = 1;
        o->run_id = sqlite3_column_int64(st, 0);
        o->prm.eps = sqlite3_column_double(st, 1);
        int64_t mp = sqlite3_column_int64(st, 2), mu = sqlite3_column_int64(st, 3);
        o->prm.min_points = mp < 1 ? 1 : mp > UINT32_MAX ? UINT32_MAX : (uint32_t)mp;
        o->prm.min_users = mu < 0 ? 0 : mu > UINT32_MAX ? UINT32_MAX : (uint32_t)mu;
        o->prm.threads = 0;
    }
    sqlite3_reset(st);
    if (step != SQLITE_ROW && step != SQLITE_DONE)
        return db_fail(rd);

    st = rd->points;
    sqlite3_bind_int64(st, 1, o->id);
    sqlite3_bind_int64(st, 2, o->points_version);
    while ((step = sqlite3_step(st)) == SQLITE_ROW) {
        if (o->npts == o->cap) {
            o->cap = o->cap ? o->cap * 2 : 1024;
            o->xyz = cvre_xrealloc(o->xyz, o->cap * 3 * sizeof *o->xyz);
            o->users = cvre_xrealloc(o->users, o->cap * sizeof *o->users);
        }
        for (int k = 0; k < 3; k++)
            o->xyz[3 * o->npts + (size_t)k] = (float)sqlite3_column_double(st, k);
        /* As cvre-cluster: a user id, or minus the session id for an
         * unknown user, taken modulo 2^32. */
        o->users[o->npts++] = (uint32_t)sqlite3_column_int64(st, 3);
    }
    sqlite3_reset(st);
    return step == SQLITE_DONE ? 0 : db_fail(rd);
}

/* Labels every point: DBSCAN with the run's parameters, or all noise
 * without a run. */
static int cluster_object(mobj *o, char *err, size_t errlen)
{
    o->labels = cvre_xmalloc((o->npts ? o->npts : 1) * sizeof *o->labels);
    o->nclusters = 0;
    if (!o->has_run || o->npts == 0) {
        for (size_t i = 0; i < o->npts; i++)
            o->labels[i] = -1;
    } else {
        dbscan_result *res = NULL;
        int rc = dbscan_run(o->xyz, o->users, o->npts, &o->prm, o->labels, &res);
        if (rc < 0)
            return cvre_fail(err, errlen, -EIO, "object %lld: clustering with run %lld's parameters failed: %s",
                        (long long)o->id, (long long)o->run_id, strerror(-rc));
        o->nclusters = dbscan_result_count(res);
        dbscan_result_free(res);
    }
    o->noise = 0;
    for (size_t i = 0; i < o->npts; i++)
        o->noise += o->labels[i] < 0;
    return 0;
}

/* Reads the mesh of o, digitizes it over the MBR (occupied cells and
 * their volume) and marks its outline in the views. */
static int mesh_object(reader *rd, mobj *o, view *views, int nviews)
{
    long long oid = (long long)o->id;
    db_ecm_object mesh; /* the store's reader checks the mesh against tri_count */
    if (db_ecm_object_load(rd->d, o->id, &mesh) < 0)
        return cvre_fail(rd->err, rd->errlen, -EIO, "%s", db_error(rd->d));
    const float *tris = mesh.tris;

    for (size_t t = 0; t < o->tri_count; t++) {
        double w[3][3];
        for (int k = 0; k < 3; k++)
            map__to_world(o, tris + 9 * t + 3 * k, w[k]);
        for (int i = 0; i < nviews; i++)
            map__view_mark(&views[i], (const double(*)[3])w);
    }

    voxel_grid g;
    int rc = voxel_grid_init(&g, MAP_DEPTH, o->mbr, o->mbr + 3);
    if (rc == 0)
        rc = voxel_mark_threads(&g, tris, o->tri_count, 0);
    db_ecm_object_free(&mesh);
    if (rc < 0) {
        voxel_grid_free(&g);
        return cvre_fail(rd->err, rd->errlen, -EIO, "object %lld: cannot digitize its mesh: %s", oid,
                    strerror(-rc));
    }
    double sc3 = o->scale * o->scale * o->scale;
    o->voxels = g.occupied;
    o->occupied_volume = (double)g.occupied * g.cell[0] * g.cell[1] * g.cell[2] * sc3;
    voxel_grid_free(&g);
    return 0;
}

/* ---- the command ---- */

static int write_file(const char *path, const sbuf *b, char *err, size_t errlen)
{
    FILE *f = fopen(path, "wb");
    if (!f)
        return cvre_fail(err, errlen, -EIO, "cannot write the picture %s: %s", path, strerror(errno));
    size_t n = fwrite(b->p, 1, b->len, f);
    int e = n == b->len ? 0 : errno;
    if (fclose(f) != 0 && !e)
        e = errno;
    if (n != b->len || e)
        return cvre_fail(err, errlen, -EIO, "cannot write the picture %s: %s", path, strerror(e ? e : EIO));
    return 0;
}

#define OBJECT_COLUMNS                                                                                     \
    "SELECT id, name, pos_x, pos_y, pos_z, yaw, scale, ecm_version, tri_count, min_x, min_y, min_z, max_x, " \
    "max_y, max_z, removed_at IS NOT NULL FROM objects "

int map_run(db *d, const map_request *r, char *err, size_t errlen)
{
    sqlite3 *s = db_sqlite(d);
    reader rd = {.d = d, .s = s, .err = err, .errlen = errlen};
    world wd = {.object_mode = r->has_object};
    view views[2] = {{0}, {0}};
    sqlite3_stmt *objs = NULL;
    size_t cap = 0;
    int rc = 0, step;

    if (sqlite3_exec(s, "BEGIN", NULL, NULL, NULL) != SQLITE_OK)
        return cvre_fail(err, errlen, -EIO, "cannot start a read transaction: %s", sqlite3_errmsg(s));
    int in_tx = 1;
    /* The run whose parameters label the points: the one that made the
     * version shown; else the latest with clusters over the collisions
     * drawn (?3), else over the version shown (?2). */
    if (sqlite3_prepare_v2(s, r->has_object ? OBJECT_COLUMNS "WHERE id = ?1"
                                            : OBJECT_COLUMNS "WHERE removed_at IS NULL ORDER BY id",
                           -1, &objs, NULL) != SQLITE_OK ||
        sqlite3_prepare_v2(s, "SELECT reason, parent_version FROM ecm_versions "
                              "WHERE object_id = ?1 AND version = ?2", -1, &rd.version, NULL) != SQLITE_OK ||
        sqlite3_prepare_v2(s, "SELECT count(*), coalesce(max(version), 0) FROM ecm_versions WHERE object_id = ?1", -1,
                           &rd.nversions, NULL) != SQLITE_OK ||
        sqlite3_prepare_v2(s, "SELECT id, eps, min_points, min_users FROM cluster_runs WHERE id = coalesce("
                              "(SELECT run_id FROM ecm_versions WHERE object_id = ?1 AND version = ?2), "
                              "(SELECT max(run_id) FROM clusters WHERE object_id = ?1 AND ecm_version = ?3), "
                              "(SELECT max(run_id) FROM clusters WHERE object_id = ?1 AND ecm_version = ?2))",
                           -1, &rd.run, NULL) != SQLITE_OK ||
        /* An object's collisions of one version through its groups (the
         * by-object index), the segments of their buckets and the id
         * ranges those cover: no scan of the whole log. In id order, as
         * cvre-cluster reads them, so that cluster ids match its own. */
        sqlite3_prepare_v2(s, "SELECT c.local_x, c.local_y, c.local_z, coalesce(c.user_id, -c.session_id) "
                              "FROM (SELECT DISTINCT bucket FROM collision_groups WHERE object_id = ?1 "
                              "AND ecm_version = ?2) b JOIN collision_segments g ON g.bucket = b.bucket "
                              "JOIN collisions c ON c.id BETWEEN g.first_id AND g.last_id "
                              "WHERE c.object_id = ?1 AND c.ecm_version = ?2 ORDER BY c.id",
                           -1, &rd.points, NULL) != SQLITE_OK) {
        rc = db_fail(&rd);
        goto cleanup;
    }
    if (r->has_object)
        sqlite3_bind_int64(objs, 1, r->object);
    while ((step = sqlite3_step(objs)) == SQLITE_ROW) {
        if (wd.n == cap) {
            cap = cap ? cap * 2 : 16;
            wd.o = cvre_xrealloc(wd.o, cap * sizeof *wd.o);
        }
        mobj *o = &wd.o[wd.n++];
        *o = (mobj){.id = sqlite3_column_int64(objs, 0), .name = dup_text(objs, 1)};
        for (int k = 0; k < 3; k++)
            o->pos[k] = sqlite3_column_double(objs, 2 + k);
        o->yaw = sqlite3_column_double(objs, 5);
        o->scale = sqlite3_column_double(objs, 6);
        int64_t in_force = sqlite3_column_int64(objs, 7), tris = sqlite3_column_int64(objs, 8);
        for (int k = 0; k < 6; k++)
            o->mbr[k] = (float)sqlite3_column_double(objs, 9 + k);
        if (sqlite3_column_int(objs, 15)) {
            rc = cvre_fail(err, errlen, -ENOENT, "object %lld was removed from the world", (long long)o->id);
            goto cleanup;
        }
        if (in_force < 1 || in_force > UINT32_MAX || tris < 0 || tris > UINT32_MAX / 9 ||
            !(o->scale > 0) || !isfinite(o->yaw)) {
            rc = cvre_fail(err, errlen, -EIO, "object %lld: stored placement or counts out of range",
                      (long long)o->id);
            goto cleanup;
        }
        o->in_force = (uint32_t)in_force;
        o->tri_count = (uint32_t)tris;
        o->version = r->has_object && r->version ? r->version : o->in_force;
    }
    if (step != SQLITE_DONE) {
        rc = db_fail(&rd);
        goto cleanup;
    }
    if (r->has_object && wd.n == 0) {
        rc = cvre_fail(err, errlen, -ENOENT, "no object with id %lld", (long long)r->object);
        goto cleanup;
    }
    for (size_t i = 0; i < wd.n && rc == 0; i++) {
        rc = read_object(&rd, &wd.o[i]);
        wd.points += wd.o[i].npts;
    }
    if (rc != 0)
        goto cleanup;
    wd.drawn = wd.points < MAP_POINTS_MAX ? wd.points : MAP_POINTS_MAX;
    map__layout(&wd, views);
    for (size_t i = 0; i < wd.n && rc == 0; i++) {
        mobj *o = &wd.o[i];
        double sc3 = o->scale * o->scale * o->scale;
        o->box_volume = map__box_volume((const float(*)[6])o->boxes, o->nboxes) * sc3;
        o->union_volume = map__union_volume((const float(*)[6])o->boxes, o->nboxes) * sc3;
        rc = mesh_object(&rd, o, views, 2);
        if (rc == 0)
            rc = cluster_object(o, err, errlen);
    }
    if (rc != 0)
        goto cleanup;
    sqlite3_exec(s, "COMMIT", NULL, NULL, NULL); /* read-only: nothing to lose */
    in_tx = 0;

    if (r->svg) {
        sbuf svg = {0};
        map__svg(&svg, &wd, views);
        rc = write_file(r->svg, &svg, err, errlen);
        sb_free(&svg);
        if (rc != 0)
            goto cleanup;
    }
    sbuf out = {0};
    if (r->json) {
        size_t g = 0;
        if (!r->has_object)
            sb_puts(&out, "[");
        for (size_t i = 0; i < wd.n; i++) {
            size_t drawn = 0;
            for (size_t p = 0; p < wd.o[i].npts; p++)
                drawn += (size_t)map__drawn_point(g + p, wd.points, wd.drawn);
            g += wd.o[i].npts;
            sb_puts(&out, i ? ",\n" : r->has_object ? "" : "\n");
            map__figures_json(&out, &wd.o[i], drawn);
        }
        sb_puts(&out, r->has_object ? "\n" : wd.n ? "\n]\n" : "]\n");
    } else {
        map__figures_table(&out, &wd);
    }
    if (fwrite(out.p, 1, out.len, stdout) != out.len || fflush(stdout) != 0)
        rc = cvre_fail(err, errlen, -EIO, "cannot write the output");
    sb_free(&out);

cleanup:
    if (in_tx)
        sqlite3_exec(s, "COMMIT", NULL, NULL, NULL);
    sqlite3_finalize(objs);
    sqlite3_finalize(rd.version);
    sqlite3_finalize(rd.nversions);
    sqlite3_finalize(rd.run);
    sqlite3_finalize(rd.points);
    for (size_t i = 0; i < wd.n; i++)
        mobj_free(&wd.o[i]);
    free(wd.o);
    free(views[0].mask);
    free(views[1].mask);
    return rc;
}
