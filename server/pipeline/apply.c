#include "apply.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "ecm.h"
#include "err.h"
#include "scene.h"
#include "second.h"
#include "task.h"

/* Where the object stands: *at gets its position and yaw with scale 1 (the
 * transform from world to its metric frame), *scale its scale. 0, or a
 * negative errno with the message in err (-EIO: no positive scale). */
static int object_pose(db *d, int64_t id, proto_transform *at, double *scale, char *err, size_t errlen)
{
    sqlite3 *s = db_sqlite(d);
    sqlite3_stmt *st = NULL;
    int rc = -EIO; /* no row, or no positive scale */
    if (sqlite3_prepare_v2(s, "SELECT pos_x, pos_y, pos_z, yaw, scale FROM objects WHERE id = ?1", -1, &st, NULL) !=
        SQLITE_OK) {
        rc = db_sqlite_errno(s);
    } else {
        sqlite3_bind_int64(st, 1, id);
        int step = sqlite3_step(st);
        if (step == SQLITE_ROW && (*scale = sqlite3_column_double(st, 4)) > 0) {
            *at = (proto_transform){.pos = {(float)sqlite3_column_double(st, 0), (float)sqlite3_column_double(st, 1),
                                            (float)sqlite3_column_double(st, 2)},
                                    .yaw = (float)sqlite3_column_double(st, 3),
                                    .scale = 1};
            rc = 0;
        } else if (step != SQLITE_ROW && step != SQLITE_DONE) {
            rc = db_sqlite_errno(s);
        }
    }
    if (rc < 0)
        cvre_fail(err, errlen, rc, "object %lld: no usable scale", (long long)id);
    sqlite3_finalize(st);
    return rc;
}

/* One cluster as the evidence hashes it. */
typedef struct evidence_rec {
    uint32_t box;
    float min[3], max[3], centroid[3];
} evidence_rec;

static int cmp_rec(const void *a, const void *b) { return memcmp(a, b, sizeof(evidence_rec)); }

int64_t ecm_evidence(const cluster_found *f, uint32_t n)
{
    evidence_rec *r = cvre_xcalloc(n ? n : 1, sizeof *r); /* zeroed: hashed bytewise */
    for (uint32_t i = 0; i < n; i++) {
        r[i].box = f[i].box;
        memcpy(r[i].min, f[i].c.min, sizeof r[i].min);
        memcpy(r[i].max, f[i].c.max, sizeof r[i].max);
        memcpy(r[i].centroid, f[i].c.centroid, sizeof r[i].centroid);
    }
    qsort(r, n, sizeof *r, cmp_rec);
    uint64_t h = 14695981039346656037u; /* FNV-1a, 64 bits */
    const unsigned char *b = (const unsigned char *)r;
    for (size_t i = 0; i < (size_t)n * sizeof *r; i++)
        h = (h ^ b[i]) * 1099511628211u;
    free(r);
    return (int64_t)(h >> 1); /* an SQLite INTEGER, never negative */
}

void ecm_judge_line(const judge_result *j, char *buf, size_t len)
{
    snprintf(buf, len, "judge: %u samples, %llu moves, phantom %llu -> %llu, opened %llu -> %llu, %.1f ms",
             j->samples, (unsigned long long)j->moves, (unsigned long long)j->phantom_old,
             (unsigned long long)j->phantom_new, (unsigned long long)j->opened_old,
             (unsigned long long)j->opened_new, j->ms);
}

void ecm_unchanged_line(const ecm_applied *a, char *buf, size_t len)
{
    if (a->stats.apart_over)
        snprintf(buf, len,
                 "the new boxes reach out of the old map (by more than two cells, or at all where users "
                 "stood), and taken apart they pass the cap by %u (%u boxes; %u problem boxes, only tightened)",
                 a->stats.apart_over, a->boxes_before, a->stats.problem_boxes);
    else if (a->stats.wanted && a->stats.capped)
        snprintf(buf, len,
                 "opening what its clusters press on takes more boxes than the cap leaves (%u boxes; %u problem "
                 "boxes, only tightened)",
                 a->boxes_before, a->stats.problem_boxes);
    else
        snprintf(buf, len, "its clusters press on real geometry only");
}

void ecm_no_gain_line(const ecm_applied *a, char *buf, size_t len)
{
    snprintf(buf, len, "the judge's trials meet %llu phantom blocks on it, fewer than the %u a new map must remove",
             (unsigned long long)a->judge.phantom_old, JUDGE_GAIN_MIN);
}

/* Whether local point p lies in one of the clusters' extents. */
static int in_a_cluster(const cluster_found *f, uint32_t n, const float p[3])
{
    for (uint32_t i = 0; i < n; i++)
        if (p[0] >= f[i].c.min[0] && p[0] <= f[i].c.max[0] && p[1] >= f[i].c.min[1] && p[1] <= f[i].c.max[1] &&
            p[2] >= f[i].c.min[2] && p[2] <= f[i].c.max[2])
            return 1;
    return 0;
}

/* The judge's samples: the newest APPLY_SAMPLES_READ collisions of the
 * clusters' object and version whose contact lies in a cluster, of the time
 * window the clusters were found in (run; NULL: all), in the object's
 * metric frame (at). Reads from the first collision segment of the
 * version's time on (collision ids grow with the time they were written),
 * so a long log is not scanned. *out and *hit (cvre_xmalloc'd) get *n
 * samples and the box each one's collision named. Returns 0, or the
 * store's negative errno with the message in err. */
static int load_samples(db *d, const cluster_found *f, uint32_t nf, const cluster_run *run,
                        const proto_transform *at, judge_sample **out, uint32_t **hit, uint32_t *n, char *err,
                        size_t errlen)
{
    sqlite3 *s = db_sqlite(d);
    sqlite3_stmt *st = NULL;
    *out = cvre_xmalloc(APPLY_SAMPLES_READ * sizeof **out);
    *hit = cvre_xmalloc(APPLY_SAMPLES_READ * sizeof **hit);
    *n = 0;
    /* The version's bucket less one: a collision is logged after the version it
     * met was made, a bucket of margin for clocks. */
    int rc = sqlite3_prepare_v2(
        s,
        "SELECT c.avatar_x, c.avatar_y, c.avatar_z, c.vel_x, c.vel_y, c.vel_z, c.local_x, c.local_y, c.local_z, "
        "c.box_index FROM collisions c "
        "WHERE c.id >= (SELECT coalesce(min(g.first_id), 1 << 62) FROM collision_segments g "
        "WHERE g.bucket >= (SELECT CAST(v.created_at / 10 AS INTEGER) - 1 FROM ecm_versions v "
        "WHERE v.object_id = ?1 AND v.version = ?2)) AND c.object_id = ?1 AND c.ecm_version = ?2 "
        "AND c.at >= ?4 AND c.at <= ?5 ORDER BY c.id DESC LIMIT ?3",
        -1, &st, NULL);
    if (rc == SQLITE_OK) {
        sqlite3_bind_int64(st, 1, f[0].object_id);
        sqlite3_bind_int64(st, 2, f[0].ecm_version);
        sqlite3_bind_int64(st, 3, APPLY_SAMPLES_READ);
        sqlite3_bind_double(st, 4, run && run->has_since ? run->since : -1e300);
        sqlite3_bind_double(st, 5, run && run->has_until ? run->until : 1e300);
        const proto_transform turn = {.yaw = at->yaw, .scale = 1};
        while ((rc = sqlite3_step(st)) == SQLITE_ROW) {
            float w[3], v[3], local[3];
            for (int k = 0; k < 3; k++) {
                w[k] = (float)sqlite3_column_double(st, k);
                v[k] = (float)sqlite3_column_double(st, 3 + k);
                local[k] = (float)sqlite3_column_double(st, 6 + k);
            }
            if (!in_a_cluster(f, nf, local))
                continue;
            sqlite3_int64 box = sqlite3_column_int64(st, 9);
            (*hit)[*n] = box >= 0 && box < UINT32_MAX ? (uint32_t)box : UINT32_MAX;
            judge_sample *j = &(*out)[(*n)++];
            scene_to_local(at, w, j->pos);
            scene_to_local(&turn, v, j->vel);
        }
    }
    if (rc != SQLITE_DONE) {
        rc = db_sqlite_errno(s);
        cvre_fail(err, errlen, rc, "object %lld: reading its collisions: %s", (long long)f[0].object_id,
                  sqlite3_errmsg(s));
    } else {
        rc = 0;
    }
    sqlite3_finalize(st);
    return rc;
}

int ecm_apply(db *d, const ecm_params *p, const cluster_run *run, int64_t run_id, const cluster_found *f,
              uint32_t n, ecm_applied *out, char *err, size_t errlen)
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
        clusters[i].weight = f[i].c.points;
        clusters[i].held = false;
        cluster_ids[i] = f[i].cluster_id;
    }
    const double t0 = task_wall_ms();
    memset(out, 0, sizeof *out);
    db_ecm_object o = {0};
    trimesh mesh = {0};
    ecm_result r = {0};
    judge_sample *samples = NULL;
    ecm_stood *stood = NULL;
    judge *jg = NULL;
    uint32_t *hit = NULL, nsamples = 0;
    double scale = 0;
    proto_transform at;
    int64_t evidence = ecm_evidence(f, n);
    int rc = -ESTALE;
    /* Removed or gone: what the clusters were about no longer stands. */
    if (db_ecm_object_load(d, object_id, &o) < 0 || o.version != version)
        goto done;
    if ((rc = object_pose(d, object_id, &at, &scale, err, errlen)) < 0)
        goto done;
    out->boxes_before = o.box_count;
    /* The same clusters made a candidate the judge turned down: it would
     * be the same candidate again. */
    if ((rc = db_ecm_rejected(d, object_id, version, evidence, &out->candidate)) != 0) {
        if (rc < 0)
            cvre_fail(err, errlen, rc, "object %lld: reading its candidates: %s", (long long)object_id, db_error(d));
        out->judged_before = rc == 1;
        rc = rc < 0 ? rc : 0;
        goto done;
    }
    ecm_params lp = *p;
    for (int a = 0; a < 3; a++)
        lp.avatar[a] = (float)(p->avatar[a] / scale);
    lp.step = (float)(p->step / scale);
    lp.floor = (float)(-at.pos[1] / scale); /* the world's floor, y = 0 */
    char why[256];
    if ((rc = load_samples(d, f, n, run, &at, &samples, &hit, &nsamples, err, errlen)) < 0)
        goto done;
    out->store_ms = task_wall_ms() - t0;
    /* The avatars at the samples, in local units, and the boxes they met
     * (refine.h, steps 6 and 8). */
    stood = cvre_xmalloc((nsamples ? nsamples : 1) * sizeof *stood);
    for (uint32_t i = 0; i < nsamples; i++) {
        for (int a = 0; a < 3; a++) {
            double half = a == 1 ? 0 : p->avatar[a] / 2;
            stood[i].box[a] = (float)((samples[i].pos[a] - half) / scale);
            stood[i].box[3 + a] = (float)((samples[i].pos[a] + (a == 1 ? p->avatar[1] : half)) / scale);
        }
        stood[i].hit = hit[i];
        stood[i].weight = 1;
    }
    lp.stood = stood;
    lp.nstood = nsamples;
    /* The triangles' boxes, for the refinement and its judge. */
    if (trimesh_init(&mesh, o.tris, o.tri_count, why, sizeof why) < 0) {
        rc = cvre_fail(err, errlen, -EINVAL, "object %lld: %s", (long long)object_id, why);
        goto done;
    }
    /* The judge walks the map in force first: when no candidate could beat
     * it, nothing is refined. Those refinements were thrown away: 38 of the
     * 62 jobs with clusters after the scenario's round 0 (seeds 1-5), and
     * every object users step over or are stopped at real walls of. */
    judge_params jp;
    judge_params_default(&jp);
    memcpy(jp.move.size, p->avatar, sizeof jp.move.size);
    jp.threads = p->threads;
    judge_input in = {.mesh = &mesh, .scale = scale, .pose_y = at.pos[1],
                      .old_boxes = (const float(*)[6])o.boxes, .nold = o.box_count, .samples = samples,
                      .nsamples = nsamples};
    if (judge_open(&jg, &jp, &in, &out->judge, why, sizeof why) < 0) {
        rc = cvre_fail(err, errlen, -EINVAL, "object %lld: %s", (long long)object_id, why);
        goto done;
    }
    /* The map stays as it is: its figures stand for "new" too. */
    out->judge.phantom_new = out->judge.phantom_old;
    out->judge.opened_new = out->judge.opened_old;
    if (!judge_can_gain(&out->judge)) {
        out->no_gain = 1;
        goto done; /* rc is 0, out->version 0 */
    }
    if (ecm_refine_mesh(&lp, &mesh, (const float(*)[6])o.boxes, o.box_count, clusters, n, &r, why, sizeof why) < 0) {
        /* Out of memory too: the refinement did not run, the store is fine. */
        rc = cvre_fail(err, errlen, -EINVAL, "object %lld: %s", (long long)object_id, why);
        goto done;
    }
    out->stats = r;
    out->stats.boxes = NULL;
    out->boxes_after = r.count;
    if (ecm_same_boxes((const float(*)[6])r.boxes, r.count, (const float(*)[6])o.boxes, o.box_count))
        goto done; /* unchanged: rc is 0, out->version 0 */
    const double open_ms = out->judge.ms;
    if (judge_new(jg, (const float(*)[6])r.boxes, r.count, &out->judge, why, sizeof why) < 0) {
        rc = cvre_fail(err, errlen, -EINVAL, "object %lld: %s", (long long)object_id, why);
        goto done;
    }
    char figures[160], detail[640], first[160] = "";
    /* A better map at the cap: a second try where its trials were still
     * held back (second.h). */
    ecm_second sc;
    if ((rc = ecm_second_candidate(&lp, &mesh, jg, out->judge.ms - open_ms, &r, &out->judge, &sc, why,
                                   sizeof why)) < 0) {
        cvre_fail(err, errlen, rc, "object %lld: %s", (long long)object_id, why);
        goto done;
    }
    if (sc.kept)
        snprintf(first, sizeof first, "; the division's %u boxes: phantom %llu -> %llu, then step 8 on the trials' "
                 "%u places", sc.first_count, (unsigned long long)out->judge.phantom_old,
                 (unsigned long long)sc.first_phantom, sc.places);
    out->stats = r;
    out->stats.boxes = NULL;
    out->boxes_after = r.count;
    ecm_judge_line(&out->judge, figures, sizeof figures);
    snprintf(detail, sizeof detail,
             "depth %u, max boxes %u, max empty %.2f: %u -> %u boxes, %u problem boxes, %u kept whole at "
             "the cap%s; %s%s",
             p->depth, p->max_boxes, p->max_empty, o.box_count, r.count, r.problem_boxes, r.capped, first, figures,
             out->judge.better ? "" : ": not better, not published");
    const double ts = task_wall_ms();
    if (out->judge.better) {
        db_ecm_change c = {.object_id = object_id, .parent_version = version, .reason = "refine", .run_id = run_id,
                           .ncluster_ids = run_id ? n : 0, .cluster_ids = cluster_ids, .detail = detail,
                           .box_count = r.count, .boxes = (const float(*)[6])r.boxes};
        rc = db_ecm_write(d, &c, db_now(), &out->version);
    } else {
        const judge_result *j = &out->judge;
        db_ecm_candidate c = {.object_id = object_id, .version = version, .run_id = run_id,
                              .ncluster_ids = run_id ? n : 0, .cluster_ids = cluster_ids, .evidence = evidence,
                              .detail = detail, .box_count = r.count, .boxes = (const float(*)[6])r.boxes,
                              .samples = j->samples, .moves = j->moves, .phantom_old = j->phantom_old,
                              .phantom_new = j->phantom_new, .opened_old = j->opened_old,
                              .opened_new = j->opened_new};
        rc = db_ecm_reject(d, &c, db_now(), &out->candidate);
    }
    out->store_ms += task_wall_ms() - ts;
    if (rc < 0 && rc != -ESTALE)
        cvre_fail(err, errlen, rc, "object %lld: writing the new %s: %s", (long long)object_id,
                  out->judge.better ? "version" : "candidate", db_error(d));
done:
    out->total_ms = task_wall_ms() - t0;
    judge_close(jg);
    ecm_result_free(&r);
    trimesh_free(&mesh);
    db_ecm_object_free(&o);
    free(samples);
    free(hit);
    free(stood);
    free(clusters);
    free(cluster_ids);
    return rc;
}

int ecm_apply_round(db *d, const ecm_params *p, const cluster_run *run, const cluster_found *found, size_t n,
                    int apply, ecm_round_fn *fn, void *ctx, int64_t *run_id, char *err, size_t errlen)
{
    int rc = cluster_record(d, run, found, n, run_id, err, errlen);
    for (size_t k = 0; rc == 0 && apply && k < n;) {
        size_t first = k;
        while (k < n && found[k].object_id == found[first].object_id)
            k++;
        ecm_applied a;
        char why[512] = "";
        int arc = ecm_apply(d, p, run, *run_id, found + first, (uint32_t)(k - first), &a, why, sizeof why);
        rc = fn(ctx, found + first, (uint32_t)(k - first), arc, &a, why);
    }
    return rc;
}
