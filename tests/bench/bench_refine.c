/*
 * bench_refine: end-to-end refinement of one object, as the server's online
 * loop does it: load the object from the store, digitize, divide, judge,
 * write the next version (server/pipeline/apply.h), then publish it: read it
 * back as the refiner does, swap it into a scene and encode the OBJECT_INFO
 * clients get. A map the judge turns down is stored as a candidate, not
 * published (the row says so; publish 0).
 *
 * Usage: bench_refine [--repeat N] [--depth D] [--threads T] [--only TEXT] MODELS_DIR
 * (--only: the objects whose label contains TEXT, say to profile one;
 * --threads: ecm_params.threads, the most threads a refinement runs on,
 * the default 0 one per CPU as in the server, 1 to compare with this
 * thread alone.)
 * For each model, a cluster of users stopped at the middle of the MBR's
 * +z face (the side a visitor walks into), at 0.9 m, and 64 logged
 * collisions there for the judge; for Sponza, a building users start in,
 * at the middle of its MBR (its courtyard): from outside they meet its
 * closed outer wall and can walk to nothing inside it, so the judge's
 * trials find nothing a new map could gain and nothing is refined (the row
 * says so). The bunny is a statue 1.5 m tall (its file's 0.15 m times 10):
 * at 0.15 m users step over it, and a map no user is stopped by is not
 * refined. Then the median over N runs of each stage, in
 * ms: digitize and divide (ecm_result), judge (judge_result), in CPU
 * time (the refining thread's, and that of the threads it starts: their
 * sum can pass the total); load+write, the store's read of
 * the object and its samples and the write of the version or candidate
 * (ecm_applied's store_ms); publish and the total, wall clock (run it on an
 * idle machine). The target: every object under 50 ms in total; exits 1,
 * after the whole table, naming each object that misses it.
 */
#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "../testdb.h"
#include "bench.h"
#include "alloc.h"
#include "apply.h"
#include "db.h"
#include "ecm.h"
#include "proto.h"
#include "import.h"
#include "scene.h"

static int load(const char *dir, const char *rel, int z_up, float scale, uint32_t limit, import_mesh *m)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", dir, rel);
    FILE *f = fopen(path, "rb");
    if (!f) {
        perror(path);
        return -1;
    }
    fseek(f, 0, SEEK_END);
    long size = ftell(f);
    rewind(f);
    uint8_t *data = malloc((size_t)size);
    if (!data || fread(data, 1, (size_t)size, f) != (size_t)size) {
        fclose(f);
        free(data);
        return -1;
    }
    fclose(f);
    import_options opt = IMPORT_OPTIONS_DEFAULT;
    opt.z_up = z_up;
    opt.unit_scale = scale;
    char err[256];
    int rc = import_model(data, (size_t)size, strrchr(rel, '.'), &opt, m, err, sizeof err);
    free(data);
    if (rc < 0) {
        fprintf(stderr, "%s: %s\n", rel, err);
        return -1;
    }
    if (limit && m->ntris > limit) {
        /* The first `limit` triangles: a real model's part of that size. */
        m->ntris = limit;
        for (int a = 0; a < 3; a++) {
            m->min[a] = INFINITY;
            m->max[a] = -INFINITY;
        }
        for (size_t i = 0; i < (size_t)limit * 3; i++)
            for (size_t a = 0; a < 3; a++) {
                m->min[a] = fminf(m->min[a], m->tris[3 * i + a]);
                m->max[a] = fmaxf(m->max[a], m->tris[3 * i + a]);
            }
    }
    return 0;
}

/* The judge's evidence (apply.h): users stopped on the cluster's face,
 * walking in (feet at feet_y, 4 m/s along -z), 8 x 8 of them over its
 * extent, logged against version 1 of object id. 0 or -1. */
static int log_evidence(db *d, int64_t id, const cluster_found *cl, float feet_y)
{
    sqlite3 *s = db_sqlite(d);
    enum { N = 64 };
    char sql[160];
    snprintf(sql, sizeof sql, "INSERT INTO collision_segments(first_id, last_id, bucket) VALUES (1, %d, %lld)", N,
             (long long)(db_now() / 10));
    sqlite3_stmt *st = NULL;
    if (sqlite3_exec(s, sql, NULL, NULL, NULL) != SQLITE_OK ||
        sqlite3_prepare_v2(s,
                           "INSERT INTO collisions(id, g, at, session_id, avatar_id, object_id, ecm_version, "
                           "box_index, inside, avatar_x, avatar_y, avatar_z, world_x, world_y, world_z, local_x, "
                           "local_y, local_z, normal_x, normal_y, normal_z, vel_x, vel_y, vel_z) VALUES (?1, 1, ?2, "
                           "1, 1, ?3, 1, 0, 0, ?4, ?5, ?6, ?4, ?7, ?8, ?4, ?7, ?8, 0, 0, 1, 0, 0, -4)",
                           -1, &st, NULL) != SQLITE_OK) {
        fprintf(stderr, "%s\n", sqlite3_errmsg(s));
        return -1;
    }
    int rc = 0;
    for (int i = 0; i < N && rc == 0; i++) {
        double x = (double)cl->c.min[0] + ((double)cl->c.max[0] - cl->c.min[0]) * (i % 8) / 7.0;
        double y = (double)cl->c.min[1] + ((double)cl->c.max[1] - cl->c.min[1]) * (i / 8) / 7.0, z = cl->c.max[2];
        sqlite3_bind_int(st, 1, i + 1);
        sqlite3_bind_double(st, 2, db_now());
        sqlite3_bind_int64(st, 3, id);
        sqlite3_bind_double(st, 4, x);
        sqlite3_bind_double(st, 5, feet_y);
        sqlite3_bind_double(st, 6, z + 0.3);
        sqlite3_bind_double(st, 7, y);
        sqlite3_bind_double(st, 8, z);
        if (sqlite3_step(st) != SQLITE_DONE) {
            fprintf(stderr, "%s\n", sqlite3_errmsg(s));
            rc = -1;
        }
        sqlite3_reset(st);
    }
    sqlite3_finalize(st);
    return rc;
}

/* The target for one object's refinement, end to end, ms. */
#define TARGET_MS 50.0

/* Stages of one run, ms (see the top comment). */
enum { T_VOXEL, T_DIVIDE, T_JUDGE, T_LOAD_WRITE, T_PUBLISH, T_TOTAL, T_STAGES };

/* One model: a fresh database with the object at version 1, refined repeat
 * times (each time from version 1 again: the later versions are rolled back
 * by resetting objects.ecm_version, and rejected candidates deleted, so
 * every run does the same work). *total gets the median total, ms.
 * Returns 0 or -1. */
static int bench_model(const char *dir, const char *label, const char *rel, int z_up, float scale, uint32_t limit,
                       int inside, const ecm_params *base, int repeat, double *total)
{
    import_mesh m;
    if (load(dir, rel, z_up, scale, limit, &m) < 0)
        return -1;
    char path[] = "/tmp/bench_refine_XXXXXX";
    int fd = mkstemp(path);
    if (fd < 0)
        return -1;
    close(fd);
    unlink(path);
    char err[512];
    db *d = db_open(path, DB_READWRITE, err, sizeof err);
    if (!d) {
        fprintf(stderr, "%s\n", err);
        return -1;
    }
    float box[1][6] = {{m.min[0], m.min[1], m.min[2], m.max[0], m.max[1], m.max[2]}};
    db_object o = {.owner = "bench", .name = label, .format = "bench", .scale = 1, .tri_count = m.ntris,
                   .tris = m.tris, .box_count = 1, .boxes = (const float(*)[6])box};
    memcpy(o.min, m.min, sizeof o.min);
    memcpy(o.max, m.max, sizeof o.max);
    if (db_object_create(d, &o, db_now()) < 0) {
        fprintf(stderr, "%s\n", db_error(d));
        return -1;
    }
    float cx = (m.min[0] + m.max[0]) / 2, cy = fminf(m.min[1] + 0.9f, m.max[1]);
    float cz = inside ? (m.min[2] + m.max[2]) / 2 : m.max[2];
    cluster_found cl = {.object_id = o.id, .ecm_version = 1, .box = 0,
                        .c = {.min = {cx - 0.3f, cy - 0.2f, cz}, .max = {cx + 0.3f, cy + 0.2f, cz},
                              .centroid = {cx, cy, cz}}};
    if (log_evidence(d, o.id, &cl, m.min[1]) < 0)
        return -1;
    ecm_params p = *base;
    scene *sc = scene_create((float[3]){-1e4f, -1e4f, -1e4f}, (float[3]){1e4f, 1e4f, 1e4f});
    scene_object_def def = {.id = (uint32_t)o.id, .owner = "bench", .name = label, .at = {.scale = 1},
                            .ecm_version = 1, .tri_count = m.ntris, .tris = m.tris, .box_count = 1,
                            .boxes = (const scene_box *)box};
    if (!sc || scene_add(sc, &def) < 0)
        return -1;
    double *t[T_STAGES];
    for (int k = 0; k < T_STAGES; k++)
        t[k] = calloc((size_t)repeat, sizeof(double));
    uint32_t boxes_after = 0;
    int rejected = 0; /* the judge turned the refined map down: not published */
    int no_gain = 0;  /* nothing refined: no map could be better (apply.h) */
    uint8_t *frame = malloc(PROTO_HEADER_SIZE + PROTO_MAX_LEN);
    for (int r = 0; r < repeat; r++) {
        /* Version 1 in force again, and no candidate the judge turned
         * down (the same clusters are not refined twice). */
        char reset[320];
        snprintf(reset, sizeof reset,
                 "UPDATE objects SET ecm_version = 1 WHERE id = %1$lld; DELETE FROM ecm_candidate_clusters WHERE "
                 "object_id = %1$lld; DELETE FROM ecm_candidate_boxes WHERE object_id = %1$lld; DELETE FROM "
                 "ecm_candidates WHERE object_id = %1$lld",
                 (long long)o.id);
        sqlite3_exec(db_sqlite(d), reset, NULL, NULL, NULL);
        double t0 = bench_now_ms();
        ecm_applied a;
        int rc = ecm_apply(d, &p, NULL, 0, &cl, 1, &a, err, sizeof err);
        if (rc != 0 || (!a.version && !a.candidate && !a.no_gain)) { /* an error, or unchanged */
            fprintf(stderr, "%s: refinement: %d %s\n", label, rc, err);
            return -1;
        }
        double t1 = bench_now_ms();
        rejected = !a.version;
        no_gain = a.no_gain;
        t[T_VOXEL][r] = a.stats.voxel_ms;
        t[T_DIVIDE][r] = a.stats.divide_ms;
        t[T_JUDGE][r] = a.judge.ms;
        t[T_LOAD_WRITE][r] = a.store_ms;
        t[T_PUBLISH][r] = 0;
        t[T_TOTAL][r] = t1 - t0;
        boxes_after = a.boxes_after;
        if (rejected)
            continue; /* nothing to publish */
        /* Publishing, as the server does it: read the version back, swap
         * it in, encode the frame for a client. */
        float(*nb)[6];
        uint32_t n;
        if (db_ecm_boxes(d, o.id, a.version, &nb, &n) < 0 ||
            scene_set_ecm(sc, (uint32_t)o.id, a.version, (const scene_box *)nb, n) < 0)
            return -1;
        const scene_object *so = scene_get(sc, (uint32_t)o.id);
        float(*lo)[3] = malloc(n * sizeof *lo), (*hi)[3] = malloc(n * sizeof *hi);
        for (uint32_t i = 0; i < n; i++) {
            memcpy(lo[i], so->world[i].min, sizeof lo[i]);
            memcpy(hi[i], so->world[i].max, sizeof hi[i]);
        }
        proto_writer w;
        proto_writer_init(&w, frame, PROTO_HEADER_SIZE + PROTO_MAX_LEN);
        proto_object_info info = {.object_id = so->id, .owner = {"bench", 5}, .name = {label, (uint32_t)strlen(label)},
                                  .at = so->at, .ecm_version = so->ecm_version, .tri_count = so->tri_count,
                                  .box_count = (uint16_t)n};
        proto_put_object_info(&w, &info, (const float(*)[3])lo, (const float(*)[3])hi);
        free(lo);
        free(hi);
        free(nb);
        double t2 = bench_now_ms();
        t[T_PUBLISH][r] = t2 - t1;
        t[T_TOTAL][r] = t2 - t0;
    }
    double med[T_STAGES];
    for (int k = 0; k < T_STAGES; k++)
        med[k] = bench_median(t[k], repeat);
    *total = med[T_TOTAL];
    printf("| %-22s | %7u | %4u^3 | %5u | %8.1f | %8.1f | %6.1f | %10.1f | %7.2f | %8.1f |%s\n", label, m.ntris,
           1u << p.depth, boxes_after, med[T_VOXEL], med[T_DIVIDE], med[T_JUDGE], med[T_LOAD_WRITE], med[T_PUBLISH],
           med[T_TOTAL], no_gain ? " nothing to gain, not refined" : rejected ? " rejected by the judge" : "");
    for (int k = 0; k < T_STAGES; k++)
        free(t[k]);
    free(frame);
    scene_destroy(sc);
    db_close(d);
    testdb_remove(path);
    import_mesh_free(&m);
    return 0;
}

#define USAGE "usage: bench_refine [--repeat N] [--depth D] [--threads T] [--only TEXT] MODELS_DIR\n"

int main(int argc, char **argv)
{
    int repeat = 7, depth = 7, threads = 0, o;
    const char *only = NULL;
    static const struct option opts[] = {{"repeat", required_argument, 0, 'r'},
                                         {"depth", required_argument, 0, 'd'},
                                         {"threads", required_argument, 0, 't'},
                                         {"only", required_argument, 0, 'o'},
                                         {"help", no_argument, 0, 'h'},
                                         {0, 0, 0, 0}};
    cvre_alloc_keep_freed(); /* as the server does (alloc.h) */
    while ((o = getopt_long(argc, argv, "", opts, NULL)) != -1) {
        if (o == 'r')
            repeat = atoi(optarg);
        else if (o == 'd')
            depth = atoi(optarg);
        else if (o == 't')
            threads = atoi(optarg);
        else if (o == 'o')
            only = optarg;
        else {
            fputs(USAGE, o == 'h' ? stdout : stderr);
            return o == 'h' ? 0 : 2;
        }
    }
    if (optind + 1 != argc || repeat < 1 || depth < (int)ECM_DEPTH_MIN || depth > (int)ECM_DEPTH_MAX || threads < 0) {
        fputs(USAGE, stderr);
        return 2;
    }
    const char *dir = argv[optind];
    ecm_params base;
    ecm_params_default(&base);
    base.depth = (uint32_t)depth;
    base.threads = (unsigned)threads;
    printf("End-to-end refinement of one object (median of %d; ms)\n\n", repeat);
    printf("| %-22s | %7s | %6s | %5s | %8s | %8s | %6s | %10s | %7s | %8s |\n", "object", "tris", "grid", "boxes",
           "digitize", "divide", "judge", "load+write", "publish", "total");
    printf("|------------------------|---------|--------|-------|----------|----------|--------|------------|"
           "---------|----------|\n");
    struct {
        const char *label, *rel;
        int z_up;
        float scale; /* the import's unit_scale */
        uint32_t limit;
        int inside; /* users start inside: the cluster at the MBR's middle */
    } models[] = {
        {"doorway room", "openings/openfoam_room_with_doorway.stl", 1, 1, 0, 0},
        {"stanford bunny, 1.5 m", "classic/stanford-bunny.obj", 0, 10, 0, 0},
        {"sponza", "scenes/dabrovic_sponza.obj", 0, 1, 0, 1},
        {"city block, 100k part", "scenes/openfoam_windAroundBuildings.obj", 1, 1, 100000, 0},
        {"city block", "scenes/openfoam_windAroundBuildings.obj", 1, 1, 0, 0},
    };
    enum { NMODELS = sizeof models / sizeof models[0] };
    double total[NMODELS] = {0};
    for (size_t i = 0; i < NMODELS; i++)
        if ((!only || strstr(models[i].label, only)) &&
            bench_model(dir, models[i].label, models[i].rel, models[i].z_up, models[i].scale, models[i].limit,
                        models[i].inside, &base,
                        repeat, &total[i]) < 0)
            return 1;
    int missed = 0;
    for (size_t i = 0; i < NMODELS; i++)
        if (total[i] >= TARGET_MS) {
            printf("%s: %.1f ms, target %.0f ms: missed\n", models[i].label, total[i], TARGET_MS);
            missed = 1;
        }
    return missed;
}
