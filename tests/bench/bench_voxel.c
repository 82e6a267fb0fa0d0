/*
 * bench_voxel: voxelizes real models over their MBRs with algo/refine/voxel.c
 * and prints, per model and grid depth, the median time of --repeat runs
 * (voxel_grid_init + voxel_mark + voxel_grid_free: everything a refinement
 * pays) on one thread (voxel_mark) and on one thread per CPU
 * (voxel_mark_threads), the cells marked and the grid's size.
 *
 *   bench_voxel [--models DIR] [--model REL]... [--depths 6,7,8] [--repeat 7]
 *               [--dump DIR] [--json]
 *
 * Models default to the Stanford bunny and the city block of ../shared/models
 * (imported as the server does, through server/import/import.h, default
 * options). --dump DIR writes each model's triangles to DIR/<name>.tri for
 * tests/bench/bench_openvdb.cpp: "CVRETRI1", uint32 ntris, float min[3],
 * float max[3], then 9 floats per triangle, all little-endian. --json prints
 * one JSON object per line instead of the table (tests/bench/bench_voxel.py
 * reads it). Times are wall clock, like bench_openvdb's (whose default
 * runs on several threads). Exits 1 if a run's cell count
 * differs from the first's, 2 on bad arguments or an unreadable model.
 */
#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bench.h"
#include "import.h"
#include "voxel.h"

#define MAX_MODELS 8
#define MAX_REPEAT 101
#define MAX_DEPTHS 10

/* Reads and imports MODELS_DIR/rel into *m. Returns 0 or prints why not. */
static int load(const char *dir, const char *rel, import_mesh *m)
{
    char path[4096], err[256];
    snprintf(path, sizeof path, "%s/%s", dir, rel);
    FILE *f = fopen(path, "rb");
    if (!f) {
        fprintf(stderr, "bench_voxel: cannot open %s: %s\n", path, strerror(errno));
        return -1;
    }
    fseek(f, 0, SEEK_END);
    long size = ftell(f);
    rewind(f);
    char *data = size > 0 ? malloc((size_t)size) : NULL;
    int ok = data && fread(data, 1, (size_t)size, f) == (size_t)size;
    fclose(f);
    const char *dot = strrchr(rel, '.');
    import_options opt = IMPORT_OPTIONS_DEFAULT;
    int rc = ok ? import_model(data, (size_t)size, dot ? dot + 1 : NULL, &opt, m, err, sizeof err) : -EIO;
    free(data);
    if (rc != 0) {
        fprintf(stderr, "bench_voxel: %s: %s\n", path, ok ? err : "read error");
        return -1;
    }
    return 0;
}

/* The file name without folder and extension. */
static void base_name(const char *rel, char *out, size_t cap)
{
    const char *s = strrchr(rel, '/');
    s = s ? s + 1 : rel;
    snprintf(out, cap, "%s", s);
    char *dot = strrchr(out, '.');
    if (dot)
        *dot = '\0';
}

static void put_u32(FILE *f, uint32_t v)
{
    unsigned char b[4] = {(unsigned char)v, (unsigned char)(v >> 8), (unsigned char)(v >> 16),
                          (unsigned char)(v >> 24)};
    fwrite(b, 1, 4, f);
}

static void put_floats(FILE *f, const float *p, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        uint32_t u;
        memcpy(&u, &p[i], 4);
        put_u32(f, u);
    }
}

static int dump(const char *dir, const char *name, const import_mesh *m)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/%s.tri", dir, name);
    FILE *f = fopen(path, "wb");
    if (!f) {
        fprintf(stderr, "bench_voxel: cannot write %s: %s\n", path, strerror(errno));
        return -1;
    }
    fwrite("CVRETRI1", 1, 8, f);
    put_u32(f, m->ntris);
    put_floats(f, m->min, 3);
    put_floats(f, m->max, 3);
    put_floats(f, m->tris, 9 * (size_t)m->ntris);
    return fclose(f) == 0 ? 0 : -1;
}

static void usage(void)
{
    fprintf(stderr, "usage: bench_voxel [--models DIR] [--model REL]... [--depths 6,7,8] [--repeat 7]\n"
                    "                   [--dump DIR] [--json]\n");
}

int main(int argc, char **argv)
{
    const char *dir = "../shared/models", *dumpdir = NULL;
    const char *models[MAX_MODELS];
    unsigned depths[MAX_DEPTHS] = {6, 7, 8};
    int nmodels = 0, ndepths = 3, repeat = 7, json = 0;

    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "--json")) {
            json = 1;
        } else if (v && !strcmp(a, "--models")) {
            dir = v, i++;
        } else if (v && !strcmp(a, "--model") && nmodels < MAX_MODELS) {
            models[nmodels++] = v, i++;
        } else if (v && !strcmp(a, "--dump")) {
            dumpdir = v, i++;
        } else if (v && !strcmp(a, "--repeat")) {
            repeat = atoi(v), i++;
        } else if (v && !strcmp(a, "--depths")) {
            ndepths = 0;
            for (const char *p = v; *p && ndepths < MAX_DEPTHS; p++) {
                char *end;
                unsigned long d = strtoul(p, &end, 10);
                if (end == p || d < VOXEL_DEPTH_MIN || d > VOXEL_DEPTH_MAX) {
                    usage();
                    return 2;
                }
                depths[ndepths++] = (unsigned)d;
                p = end;
                if (!*p)
                    break;
            }
            i++;
        } else {
            usage();
            return 2;
        }
    }
    if (repeat < 1 || repeat > MAX_REPEAT) {
        usage();
        return 2;
    }
    if (nmodels == 0) {
        models[nmodels++] = "classic/stanford-bunny.obj";
        models[nmodels++] = "scenes/openfoam_windAroundBuildings.obj";
    }
    if (!json)
        printf("%-28s %9s %6s %10s %10s %10s %10s %8s\n", "model", "triangles", "grid", "ms (med)", "ms (min)",
               "ms threads", "cells", "MB");
    int status = 0;
    for (int mi = 0; mi < nmodels; mi++) {
        import_mesh m;
        char name[256];
        if (load(dir, models[mi], &m) != 0)
            return 2;
        base_name(models[mi], name, sizeof name);
        if (dumpdir && dump(dumpdir, name, &m) != 0)
            return 2;
        for (int di = 0; di < ndepths; di++) {
            double t[2][MAX_REPEAT];
            uint64_t cells = 0;
            uint32_t n = 1u << depths[di];
            for (int r = 0; r < 2 * repeat; r++) {
                int mt = r % 2; /* alternate, so that a busy spell hits both */
                voxel_grid g;
                double t0 = bench_now_ms();
                int rc = voxel_grid_init(&g, depths[di], m.min, m.max);
                if (rc == 0)
                    rc = mt ? voxel_mark_threads(&g, m.tris, m.ntris, 0) : voxel_mark(&g, m.tris, m.ntris);
                uint64_t occ = g.occupied;
                voxel_grid_free(&g);
                t[mt][r / 2] = bench_now_ms() - t0;
                if (rc != 0) {
                    fprintf(stderr, "bench_voxel: %s: error %d\n", name, rc);
                    return 2;
                }
                if (r == 0)
                    cells = occ;
                else if (occ != cells)
                    status = 1;
            }
            qsort(t[0], (size_t)repeat, sizeof t[0][0], bench_cmp_double);
            qsort(t[1], (size_t)repeat, sizeof t[1][0], bench_cmp_double);
            double mb = (double)n * n * n / 8.0 / (1024.0 * 1024.0);
            if (json)
                printf("{\"model\": \"%s\", \"triangles\": %u, \"depth\": %u, \"n\": %u, \"ms\": %.4f, "
                       "\"ms_min\": %.4f, \"ms_threads\": %.4f, \"cells\": %llu, \"mb\": %.3f}\n",
                       name, m.ntris, depths[di], n, t[0][repeat / 2], t[0][0], t[1][repeat / 2],
                       (unsigned long long)cells, mb);
            else
                printf("%-28s %9u %5u^3 %10.3f %10.3f %10.3f %10llu %8.3f\n", name, m.ntris, n, t[0][repeat / 2],
                       t[0][0], t[1][repeat / 2], (unsigned long long)cells, mb);
            fflush(stdout);
        }
        import_mesh_free(&m);
    }
    if (status)
        fprintf(stderr, "bench_voxel: cell counts differ between runs or thread counts\n");
    return status;
}
