/*
 * dbscan_cli: runs dbscan_run on points from a file, for the tests and the
 * benchmark (tests/integration/test_dbscan_sklearn.py, tests/bench/bench_dbscan.py).
 *
 *   dbscan_cli [--eps E] [--min-points N] [--min-users U] [--threads T]
 *              [--summary] IN [OUT]
 *
 * IN is either text, one point per line "x y z user" (blank lines and lines
 * starting with '#' skipped), or binary: the 8 bytes "CVREPTS1", a uint64
 * point count n, then n records of float32 x, y, z and uint32 user, all
 * little-endian. OUT (default stdout) receives one line per point,
 * "label core": the cluster id or -1, and 1 for a core point, 0 otherwise.
 * stderr receives one line "dbscan_run_ms=T clusters=K noise=M searches=S",
 * where T is the time of dbscan_run alone (CLOCK_MONOTONIC), and with
 * --summary one line per cluster. Exit status 0, 1 on error, 2 on bad usage.
 */
#include <errno.h>
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "alloc.h"
#include "dbscan.h"
#include "le.h"

#define MAGIC "CVREPTS1"
#define MAGIC_LEN 8
#define HEADER_LEN 16
#define RECORD_LEN 16
/* Longest text line accepted: four numbers with room to spare. */
#define LINE_MAX_LEN 512

typedef struct points {
    float *xyz;
    uint32_t *users;
    size_t n, cap;
} points;

static int grow(points *p)
{
    if (p->n < p->cap)
        return 0;
    size_t cap = p->cap ? 2 * p->cap : 1024;
    if (cap > DBSCAN_MAX_POINTS)
        return -EINVAL;
    float *xyz = cvre_realloc(p->xyz, 3 * cap * sizeof *xyz);
    if (!xyz)
        return -ENOMEM;
    p->xyz = xyz;
    uint32_t *u = cvre_realloc(p->users, cap * sizeof *u);
    if (!u)
        return -ENOMEM;
    p->users = u;
    p->cap = cap;
    return 0;
}

/* Reads the binary format from f (positioned after the magic). Returns 0 or
 * -EINVAL (short, long or oversized file), -ENOMEM. */
static int read_binary(FILE *f, points *p)
{
    unsigned char hdr[HEADER_LEN - MAGIC_LEN], rec[RECORD_LEN];
    if (fread(hdr, 1, sizeof hdr, f) != sizeof hdr)
        return -EINVAL;
    uint64_t n = le_get_u64(hdr);
    if (n > DBSCAN_MAX_POINTS)
        return -EINVAL;
    p->cap = (size_t)n;
    p->xyz = cvre_malloc(3 * (p->cap ? p->cap : 1) * sizeof *p->xyz);
    p->users = cvre_malloc((p->cap ? p->cap : 1) * sizeof *p->users);
    if (!p->xyz || !p->users)
        return -ENOMEM;
    for (p->n = 0; p->n < n; p->n++) {
        if (fread(rec, 1, sizeof rec, f) != sizeof rec)
            return -EINVAL;
        for (int a = 0; a < 3; a++)
            p->xyz[3 * p->n + (size_t)a] = le_get_f32(rec + 4 * a);
        p->users[p->n] = le_get_u32(rec + 12);
    }
    if (fgetc(f) != EOF)
        return -EINVAL;
    return 0;
}

/* Reads "x y z user" lines from the start of f. On a malformed line, returns
 * -EINVAL with its number in *bad_line. */
static int read_text(FILE *f, points *p, size_t *bad_line)
{
    char line[LINE_MAX_LEN];
    for (size_t lineno = 1; fgets(line, sizeof line, f); lineno++) {
        *bad_line = lineno;
        size_t len = strlen(line);
        if (len == sizeof line - 1 && line[len - 1] != '\n')
            return -EINVAL;
        char *s = line;
        while (*s == ' ' || *s == '\t')
            s++;
        if (*s == '#' || *s == '\n' || *s == '\r' || *s == '\0')
            continue;
        float x, y, z;
        unsigned long u;
        char extra;
        if (sscanf(s, "%f %f %f %lu %c", &x, &y, &z, &u, &extra) != 4 || u > UINT32_MAX)
            return -EINVAL;
        int rc = grow(p);
        if (rc < 0)
            return rc;
        p->xyz[3 * p->n] = x;
        p->xyz[3 * p->n + 1] = y;
        p->xyz[3 * p->n + 2] = z;
        p->users[p->n++] = (uint32_t)u;
    }
    *bad_line = 0;
    return 0;
}

/* Reads IN in either format (a regular file: text is read again from the
 * start). Returns 0 or -errno; *bad_line names a malformed text line. */
static int read_points(const char *path, points *p, size_t *bad_line)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return -errno;
    char head[MAGIC_LEN];
    size_t got = fread(head, 1, MAGIC_LEN, f);
    int rc;
    if (got == MAGIC_LEN && memcmp(head, MAGIC, MAGIC_LEN) == 0)
        rc = read_binary(f, p);
    else
        rc = fseek(f, 0, SEEK_SET) == 0 ? read_text(f, p, bad_line) : -errno;
    if (ferror(f))
        rc = -EIO;
    fclose(f);
    return rc;
}

static const char usage_text[] =
    "usage: dbscan_cli [--eps E] [--min-points N] [--min-users U] [--threads T] [--summary] IN [OUT]\n"
    "\n"
    "Clusters the points of IN (text lines \"x y z user\", or the binary form\n"
    "the header of dbscan_cli.c describes) with DBSCAN and writes one line per\n"
    "point, \"label core\", to OUT (stdout by default); one line of figures goes\n"
    "to stderr.\n"
    "\n"
    "  --eps E          neighbourhood radius (default 0.5)\n"
    "  --min-points N   points within eps that make a core point (default 10)\n"
    "  --min-users U    distinct users a cluster needs (default 1)\n"
    "  --threads T      worker threads; 0: one per CPU (default 0)\n"
    "  --summary        also one line per cluster on stderr\n"
    "  --help           show this help\n"
    "\n"
    "Exit status: 0, 1 on an error, 2 on bad usage.\n";

static int usage(void)
{
    fputs(usage_text, stderr);
    return 2;
}

/* Parses an unsigned 32-bit flag value; -1 if malformed. */
static int parse_u32(const char *s, uint32_t *out)
{
    char *end;
    errno = 0;
    unsigned long v = strtoul(s, &end, 10);
    if (errno || end == s || *end || v > UINT32_MAX || s[0] == '-')
        return -1;
    *out = (uint32_t)v;
    return 0;
}

int main(int argc, char **argv)
{
    dbscan_params prm = {.eps = 0.5, .min_points = 10, .min_users = 1, .threads = 0};
    const char *in = NULL, *outpath = NULL;
    int summary = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        int has_value = i + 1 < argc;
        if (strcmp(a, "--help") == 0) {
            fputs(usage_text, stdout);
            return 0;
        } else if (strcmp(a, "--summary") == 0) {
            summary = 1;
        } else if (strcmp(a, "--eps") == 0 && has_value) {
            char *end;
            prm.eps = strtod(argv[++i], &end);
            if (*end)
                return usage();
        } else if (strcmp(a, "--min-points") == 0 && has_value) {
            if (parse_u32(argv[++i], &prm.min_points) < 0)
                return usage();
        } else if (strcmp(a, "--min-users") == 0 && has_value) {
            if (parse_u32(argv[++i], &prm.min_users) < 0)
                return usage();
        } else if (strcmp(a, "--threads") == 0 && has_value) {
            if (parse_u32(argv[++i], &prm.threads) < 0)
                return usage();
        } else if (a[0] == '-' && a[1] != '\0') {
            return usage();
        } else if (!in) {
            in = a;
        } else if (!outpath) {
            outpath = a;
        } else {
            return usage();
        }
    }
    if (!in)
        return usage();

    points p = {0};
    size_t bad_line = 0;
    int32_t *labels = NULL;
    dbscan_result *res = NULL;
    FILE *out = NULL;
    int status = 1;
    int rc = read_points(in, &p, &bad_line);
    if (rc < 0) {
        if (bad_line)
            fprintf(stderr, "dbscan_cli: %s:%zu: bad line\n", in, bad_line);
        else
            fprintf(stderr, "dbscan_cli: %s: %s\n", in, strerror(-rc));
        goto cleanup;
    }
    labels = cvre_malloc((p.n ? p.n : 1) * sizeof *labels);
    if (!labels) {
        fprintf(stderr, "dbscan_cli: out of memory\n");
        goto cleanup;
    }
    struct timespec t0, t1;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    rc = dbscan_run(p.xyz, p.users, p.n, &prm, labels, &res);
    clock_gettime(CLOCK_MONOTONIC, &t1);
    if (rc < 0) {
        fprintf(stderr, "dbscan_cli: dbscan_run: %s\n", strerror(-rc));
        goto cleanup;
    }
    double ms = (double)(t1.tv_sec - t0.tv_sec) * 1e3 + (double)(t1.tv_nsec - t0.tv_nsec) / 1e6;
    size_t noise = 0;
    for (size_t i = 0; i < p.n; i++)
        noise += labels[i] < 0;
    fprintf(stderr, "dbscan_run_ms=%.3f clusters=%zu noise=%zu searches=%zu\n", ms, dbscan_result_count(res),
            noise, dbscan_result_searches(res));
    if (summary) {
        for (size_t k = 0; k < dbscan_result_count(res); k++) {
            const dbscan_cluster *c = dbscan_result_cluster(res, k);
            fprintf(stderr, "cluster %zu points=%" PRIu32 " users=%" PRIu32 " centroid=%g,%g,%g min=%g,%g,%g max=%g,%g,%g\n",
                    k, c->points, c->users, (double)c->centroid[0], (double)c->centroid[1],
                    (double)c->centroid[2], (double)c->min[0], (double)c->min[1], (double)c->min[2],
                    (double)c->max[0], (double)c->max[1], (double)c->max[2]);
        }
    }
    out = outpath ? fopen(outpath, "w") : stdout;
    if (!out) {
        fprintf(stderr, "dbscan_cli: %s: %s\n", outpath, strerror(errno));
        goto cleanup;
    }
    for (size_t i = 0; i < p.n; i++)
        fprintf(out, "%" PRId32 " %d\n", labels[i], dbscan_result_is_core(res, i));
    if (fflush(out) != 0 || ferror(out)) {
        fprintf(stderr, "dbscan_cli: write failed\n");
        goto cleanup;
    }
    status = 0;
cleanup:
    if (out && out != stdout)
        fclose(out);
    dbscan_result_free(res);
    free(labels);
    free(p.xyz);
    free(p.users);
    return status;
}
