/*
 * bench_import: what parsing every model in a separate, sandboxed process
 * (cvre-import, server/import/import_proc.h) costs against parsing it in
 * the server's own process (import_model), on the same files, side by side.
 *
 * Usage: bench_import [--repeat N] [--max-ratio R] HELPER MODELS_DIR
 * For each model: the median over N runs of each way, in ms, and their
 * ratio; the last line the totals. Exits 1 if an import fails or if the
 * isolated way of the largest model takes more than R times the in-process
 * way (default 2: a new process, whose every page is touched for the first
 * time, the pipe and the checks must cost less than the parse itself where
 * it matters; small models pay the process's start, some 20-40 ms).
 */
#include <errno.h>
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bench.h"
#include "import.h"
#include "import_proc.h"

static const struct {
    const char *path;
    int z_up;
} models[] = {
    {"openings/openfoam_room_with_doorway.stl", 1},
    {"openings/homedecor_desk.obj", 0},
    {"openings/kenney_building-garage.glb", 0},
    {"formats/assimp_Wuson_ascii.ply", 0},
    {"scenes/dabrovic_sponza.obj", 0},
    {"scenes/openfoam_windAroundBuildings.obj", 0},
};

static unsigned char *slurp(const char *path, size_t *len)
{
    FILE *f = fopen(path, "rb");
    unsigned char *b = NULL;
    long n;

    if (!f || fseek(f, 0, SEEK_END) != 0 || (n = ftell(f)) <= 0 || fseek(f, 0, SEEK_SET) != 0 ||
        !(b = malloc((size_t)n)) || fread(b, 1, (size_t)n, f) != (size_t)n) {
        fprintf(stderr, "bench_import: cannot read %s\n", path);
        free(b);
        b = NULL;
    }
    if (f)
        fclose(f);
    *len = b ? (size_t)n : 0;
    return b;
}

/* The median time of `repeat` imports one way; -1 if one failed. */
static double time_import(const import_proc *p, const unsigned char *data, size_t len, const char *hint,
                          const import_options *o, int repeat, uint32_t *ntris)
{
    double *t = calloc((size_t)repeat, sizeof *t), med;
    char err[512];

    for (int i = 0; i < repeat; i++) {
        import_mesh m;
        double t0 = bench_now_ms();
        int rc = p ? import_isolated(p, data, len, hint, o, &m, err, sizeof err)
                   : import_model(data, len, hint, o, &m, err, sizeof err);
        t[i] = bench_now_ms() - t0;
        if (rc != 0) {
            fprintf(stderr, "bench_import: %s: %s\n", p ? "isolated" : "in process", err);
            free(t);
            return -1;
        }
        *ntris = m.ntris;
        import_mesh_free(&m);
    }
    med = bench_median(t, repeat);
    free(t);
    return med;
}

int main(int argc, char **argv)
{
    static const struct option opts[] = {{"repeat", required_argument, NULL, 'r'},
                                         {"max-ratio", required_argument, NULL, 'm'},
                                         {"help", no_argument, NULL, 'h'},
                                         {NULL, 0, NULL, 0}};
    int repeat = 5, c, failed = 0;
    double max_ratio = 2.0, ratio_last = 0, sum_in = 0, sum_iso = 0;
    import_proc p = {NULL, IMPORT_PROC_MEMORY_MB, IMPORT_PROC_CPU_SECONDS};

    while ((c = getopt_long(argc, argv, "", opts, NULL)) != -1) {
        if (c == 'r')
            repeat = atoi(optarg);
        else if (c == 'm')
            max_ratio = atof(optarg);
        else {
            fprintf(c == 'h' ? stdout : stderr,
                    "usage: bench_import [--repeat N] [--max-ratio R] HELPER MODELS_DIR\n");
            return c == 'h' ? 0 : 2;
        }
    }
    if (argc - optind != 2 || repeat < 1) {
        fprintf(stderr, "usage: bench_import [--repeat N] [--max-ratio R] HELPER MODELS_DIR\n");
        return 2;
    }
    p.helper = argv[optind];
    printf("%-44s %9s %12s %12s %7s\n", "model", "triangles", "in-process", "isolated", "ratio");
    for (size_t i = 0; i < sizeof models / sizeof models[0]; i++) {
        char path[4096];
        size_t len;
        unsigned char *data;
        const char *dot = strrchr(models[i].path, '.');
        import_options o = IMPORT_OPTIONS_DEFAULT;
        uint32_t n = 0;
        double in, iso;

        snprintf(path, sizeof path, "%s/%s", argv[optind + 1], models[i].path);
        data = slurp(path, &len);
        if (!data)
            return 1;
        o.z_up = models[i].z_up;
        in = time_import(NULL, data, len, dot + 1, &o, repeat, &n);
        iso = time_import(&p, data, len, dot + 1, &o, repeat, &n);
        free(data);
        if (in < 0 || iso < 0)
            return 1;
        ratio_last = iso / in;
        sum_in += in;
        sum_iso += iso;
        printf("%-44s %9u %9.2f ms %9.2f ms %6.2fx\n", models[i].path, n, in, iso, ratio_last);
    }
    printf("%-44s %9s %9.2f ms %9.2f ms %6.2fx\n", "all", "", sum_in, sum_iso, sum_iso / sum_in);
    if (ratio_last > max_ratio) {
        printf("NOT met: the largest model isolated takes %.2fx in-process (target <= %.2fx)\n", ratio_last,
               max_ratio);
        failed = 1;
    } else {
        printf("met: the largest model isolated takes %.2fx in-process (target <= %.2fx)\n", ratio_last, max_ratio);
    }
    return failed;
}
