/*
 * bench_refine: end-to-end refinement of one object, as the server's online
 * loop does it: load the object from the store, digitize, divide, write the
 * next version (server/pipeline/apply.h), then publish it: read it back as the
 * refiner does, swap it into a scene and encode the OBJECT_INFO clients get.
 *
 * Usage: bench_refine [--repeat N] [--depth D] MODELS_DIR
 * For each model, a cluster of users stopped at the middle of the MBR's
 * +z face (the side a visitor walks into), at 0.9 m: the median over N runs
 * of each stage, in ms. The target: a 100k-triangle object at 128^3
 * under 50 ms end to end.
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
#include "apply.h"
#include "db.h"
#include "ecm.h"
#include "proto.h"
#include "import.h"
#include "scene.h"

static int load(const char *dir, const char *rel, int z_up, uint32_t limit, import_mesh *m)
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

typedef struct stage {
    double load_refine_write, voxel, divide, publish, total;
} stage;

/* One model: a fresh database with the object at version 1, refined repeat
 * times (each time from version 1 again: the later versions are rolled back
 * by resetting objects.ecm_version, so every run does the same work). */
static int bench_model(const char *dir, const char *label, const char *rel, int z_up, uint32_t limit, int depth,
                       int repeat)
{
    import_mesh m;
    if (load(dir, rel, z_up, limit, &m) < 0)
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
    cluster_found cl = {.object_id = o.id, .ecm_version = 1, .box = 0,
                        .c = {.min = {cx - 0.3f, cy - 0.2f, m.max[2]}, .max = {cx + 0.3f, cy + 0.2f, m.max[2]},
                              .centroid = {cx, cy, m.max[2]}}};
    ecm_params p;
    ecm_params_default(&p);
    p.depth = (uint32_t)depth;
    scene *sc = scene_create((float[3]){-1e4f, -1e4f, -1e4f}, (float[3]){1e4f, 1e4f, 1e4f});
    scene_object_def def = {.id = (uint32_t)o.id, .owner = "bench", .name = label, .at = {.scale = 1},
                            .ecm_version = 1, .tri_count = m.ntris, .tris = m.tris, .box_count = 1,
                            .boxes = (const scene_box *)box};
    if (!sc || scene_add(sc, &def) < 0)
        return -1;
    double *t[5];
    for (int k = 0; k < 5; k++)
        t[k] = calloc((size_t)repeat, sizeof(double));
    uint32_t boxes_after = 0;
    uint8_t *frame = malloc(PROTO_HEADER_SIZE + PROTO_MAX_LEN);
    for (int r = 0; r < repeat; r++) {
        char reset[128];
        snprintf(reset, sizeof reset, "UPDATE objects SET ecm_version = 1 WHERE id = %lld", (long long)o.id);
        sqlite3_exec(db_sqlite(d), reset, NULL, NULL, NULL);
        double t0 = bench_now_ms();
        ecm_applied a;
        int rc = ecm_apply(d, &p, 0, &cl, 1, &a, err, sizeof err);
        if (rc != 0 || !a.version) { /* an error, or nothing written */
            fprintf(stderr, "%s: refinement: %d %s\n", label, rc, err);
            return -1;
        }
        double t1 = bench_now_ms();
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
        t[0][r] = t1 - t0;
        t[1][r] = a.stats.voxel_ms;
        t[2][r] = a.stats.divide_ms;
        t[3][r] = t2 - t1;
        t[4][r] = t2 - t0;
        boxes_after = a.boxes_after;
    }
    printf("| %-22s | %7u | %4u^3 | %5u | %8.1f | %8.1f | %12.1f | %7.2f | %8.1f |\n", label, m.ntris,
           1u << depth, boxes_after, bench_median(t[1], repeat), bench_median(t[2], repeat), bench_median(t[0], repeat),
           bench_median(t[3], repeat), bench_median(t[4], repeat));
    for (int k = 0; k < 5; k++)
        free(t[k]);
    free(frame);
    scene_destroy(sc);
    db_close(d);
    testdb_remove(path);
    import_mesh_free(&m);
    return 0;
}

int main(int argc, char **argv)
{
    int repeat = 7, depth = 7, o;
    static const struct option opts[] = {{"repeat", required_argument, 0, 'r'},
                                         {"depth", required_argument, 0, 'd'},
                                         {"help", no_argument, 0, 'h'},
                                         {0, 0, 0, 0}};
    while ((o = getopt_long(argc, argv, "", opts, NULL)) != -1) {
        if (o == 'r')
            repeat = atoi(optarg);
        else if (o == 'd')
            depth = atoi(optarg);
        else {
            fputs("usage: bench_refine [--repeat N] [--depth D] MODELS_DIR\n", o == 'h' ? stdout : stderr);
            return o == 'h' ? 0 : 2;
        }
    }
    if (optind + 1 != argc || repeat < 1 || depth < (int)ECM_DEPTH_MIN || depth > (int)ECM_DEPTH_MAX) {
        fputs("usage: bench_refine [--repeat N] [--depth D] MODELS_DIR\n", stderr);
        return 2;
    }
    const char *dir = argv[optind];
    printf("End-to-end refinement of one object (median of %d; ms)\n\n", repeat);
    printf("| %-22s | %7s | %6s | %5s | %8s | %8s | %12s | %7s | %8s |\n", "object", "tris", "grid", "boxes",
           "digitize", "divide", "load+ref+wr", "publish", "total");
    printf("|------------------------|---------|--------|-------|----------|----------|--------------|"
           "---------|----------|\n");
    struct {
        const char *label, *rel;
        int z_up;
        uint32_t limit;
    } models[] = {
        {"doorway room", "openings/openfoam_room_with_doorway.stl", 1, 0},
        {"stanford bunny", "classic/stanford-bunny.obj", 0, 0},
        {"sponza", "scenes/dabrovic_sponza.obj", 0, 0},
        {"city block, 100k part", "scenes/openfoam_windAroundBuildings.obj", 1, 100000},
        {"city block", "scenes/openfoam_windAroundBuildings.obj", 1, 0},
    };
    for (size_t i = 0; i < sizeof models / sizeof models[0]; i++)
        if (bench_model(dir, models[i].label, models[i].rel, models[i].z_up, models[i].limit, depth, repeat) < 0)
            return 1;
    return 0;
}
