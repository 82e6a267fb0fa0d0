#include "apply.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "alloc.h"
#include "ecm.h"
#include "err.h"

/* The object's uniform scale (world metres per local unit) into *scale: 0,
 * or a negative errno with the message in err (-EIO: no positive scale). */
static int object_scale(db *d, int64_t id, double *scale, char *err, size_t errlen)
{
    sqlite3 *s = db_sqlite(d);
    sqlite3_stmt *st = NULL;
    int rc = -EIO; /* no row, or no positive scale */
    if (sqlite3_prepare_v2(s, "SELECT scale FROM objects WHERE id = ?1", -1, &st, NULL) != SQLITE_OK) {
        rc = db_sqlite_errno(s);
    } else {
        sqlite3_bind_int64(st, 1, id);
        int step = sqlite3_step(st);
        if (step == SQLITE_ROW && (*scale = sqlite3_column_double(st, 0)) > 0)
            rc = 0;
        else if (step != SQLITE_ROW && step != SQLITE_DONE)
            rc = db_sqlite_errno(s);
    }
    if (rc < 0)
        cvre_fail(err, errlen, rc, "object %lld: no usable scale", (long long)id);
    sqlite3_finalize(st);
    return rc;
}

int ecm_apply(db *d, const ecm_params *p, int64_t run_id, const cluster_found *f, uint32_t n, ecm_applied *out,
              char *err, size_t errlen)
{
    int64_t object_id = f[0].object_id;
    uint32_t version = f[0].ecm_version;
    ecm_cluster *clusters = cvre_xmalloc(n * sizeof *clusters);
    uint32_t *cluster_ids = cvre_xmalloc(n * sizeof *cluster_ids);
    for (uint32_t i = 0; i < n; i++) {
        clusters[i].box = f[i].box;
        memcpy(clusters[i].min, f[i].c.min, sizeof clusters[i].min);
        memcpy(clusters[i].max, f[i].c.max, sizeof clusters[i].max);
        memcpy(clusters[i].centroid, f[i].c.centroid, sizeof clusters[i].centroid);
        cluster_ids[i] = f[i].cluster_id;
    }
    struct timespec t0, t1;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    memset(out, 0, sizeof *out);
    db_ecm_object o = {0};
    ecm_result r = {0};
    double scale = 0;
    int rc = -ESTALE;
    /* Removed or gone: what the clusters were about no longer stands. */
    if (db_ecm_object_load(d, object_id, &o) < 0 || o.version != version)
        goto done;
    if ((rc = object_scale(d, object_id, &scale, err, errlen)) < 0)
        goto done;
    ecm_params lp = *p;
    for (int a = 0; a < 3; a++)
        lp.avatar[a] = (float)(p->avatar[a] / scale);
    out->boxes_before = o.box_count;
    char why[256];
    if (ecm_refine(&lp, o.tris, o.tri_count, (const float(*)[6])o.boxes, o.box_count, clusters, n, &r, why,
                   sizeof why) < 0) {
        /* Out of memory too: the refinement did not run, the store is fine. */
        rc = cvre_fail(err, errlen, -EINVAL, "object %lld: %s", (long long)object_id, why);
        goto done;
    }
    out->stats = r;
    out->stats.boxes = NULL;
    out->boxes_after = r.count;
    if (r.count == o.box_count && memcmp(r.boxes, o.boxes, r.count * sizeof *r.boxes) == 0)
        goto done; /* unchanged: rc is 0, out->version 0 */
    char detail[256];
    snprintf(detail, sizeof detail,
             "depth %u, max boxes %u, max empty %.2f: %u -> %u boxes, %u problem boxes, %u kept whole at "
             "the cap",
             p->depth, p->max_boxes, p->max_empty, o.box_count, r.count, r.problem_boxes, r.capped);
    db_ecm_change c = {.object_id = object_id, .parent_version = version, .reason = "refine", .run_id = run_id,
                       .ncluster_ids = run_id ? n : 0, .cluster_ids = cluster_ids, .detail = detail,
                       .box_count = r.count, .boxes = (const float(*)[6])r.boxes};
    rc = db_ecm_write(d, &c, db_now(), &out->version);
    if (rc < 0 && rc != -ESTALE)
        cvre_fail(err, errlen, rc, "object %lld: writing the new version: %s", (long long)object_id, db_error(d));
done:
    clock_gettime(CLOCK_MONOTONIC, &t1);
    out->total_ms = (double)(t1.tv_sec - t0.tv_sec) * 1e3 + (double)(t1.tv_nsec - t0.tv_nsec) / 1e6;
    ecm_result_free(&r);
    db_ecm_object_free(&o);
    free(clusters);
    free(cluster_ids);
    return rc;
}
