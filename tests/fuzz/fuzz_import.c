/*
 * fuzz_import.c: fuzz target for the model importer (server/scene/import.c
 * and the Assimp readers behind it).
 *
 * Each input is imported with no hint and with each of obj, stl, ply and
 * glb. The importer must return one of its codes with a message, or a mesh
 * whose vertices are finite and inside its box; a failed check aborts.
 *
 * Built with -DCVRE_LIBFUZZER (clang -fsanitize=fuzzer) it is a plain
 * libFuzzer target. Otherwise main() below drives it:
 *   fuzz_import --runs N [--seed S] MODELS_DIR   N mutations of the sample
 *                                                models under MODELS_DIR
 *   fuzz_import FILE...                          replay inputs
 */
#include <dirent.h>
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "scene/import.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

#define CHECK(cond)                                                                                \
    do {                                                                                           \
        if (!(cond)) {                                                                             \
            fprintf(stderr, "fuzz_import: check failed: %s (%s:%d)\n", #cond, __FILE__, __LINE__); \
            abort();                                                                               \
        }                                                                                          \
    } while (0)

/* What the target saw, so that a generator that stops reaching Assimp shows. */
static unsigned long n_imports, n_ok;

/* ---- the target --------------------------------------------------------- */

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static const char *const hints[] = {NULL, "obj", "stl", "ply", "glb"};
    /* small enough that huge inputs fail fast, large enough for the samples */
    import_options o = {0, 1.0f, 1000000};

    for (size_t h = 0; h < sizeof hints / sizeof hints[0]; h++) {
        import_mesh m;
        char err[256];
        int rc;

        memset(err, 'x', sizeof err);
        rc = import_model(data, size, hints[h], &o, &m, err, sizeof err);
        n_imports++;
        CHECK(memchr(err, 0, sizeof err) != NULL);
        if (rc != 0) {
            CHECK(rc == -EINVAL || rc == -EFBIG || rc == -ENOMEM);
            CHECK(err[0] != 0 && m.tris == NULL && m.ntris == 0);
            continue;
        }
        n_ok++;
        CHECK(err[0] == 0 && m.tris != NULL && m.ntris >= 1 && m.ntris <= o.max_triangles);
        for (size_t i = 0; i < (size_t)m.ntris * 9; i++) {
            float v = m.tris[i];
            CHECK(isfinite(v) && v >= m.min[i % 3] && v <= m.max[i % 3]);
        }
        import_mesh_free(&m);
    }
    return 0;
}

#ifndef CVRE_LIBFUZZER

/* ---- standalone driver -------------------------------------------------- */

/* Sample models larger than this are skipped: every run re-parses its
 * seed five times. */
#define SEED_MAX (1u << 20)
#define SEEDS_MAX 32
/* Room for a seed plus inserted bytes. */
#define INPUT_MAX (SEED_MAX + 4096u)

static uint64_t rng;

/* splitmix64: the same sequence on every platform for a seed. */
static uint64_t rnd(void)
{
    uint64_t z = (rng += 0x9e3779b97f4a7c15u);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9u;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebu;
    return z ^ (z >> 31);
}

static uint32_t below(uint32_t n) { return (uint32_t)(rnd() % n); }

typedef struct seed {
    uint8_t *data;
    size_t len;
} seed;

static seed seeds[SEEDS_MAX];
static size_t nseeds;

static uint8_t *read_all(const char *path, size_t *len)
{
    FILE *fp = fopen(path, "rb");
    uint8_t *data = NULL;
    long size;

    if (!fp || fseek(fp, 0, SEEK_END) != 0 || (size = ftell(fp)) < 0 ||
        fseek(fp, 0, SEEK_SET) != 0 || !(data = malloc((size_t)size + 1)) ||
        fread(data, 1, (size_t)size, fp) != (size_t)size) {
        perror(path);
        free(data);
        data = NULL;
    }
    if (fp)
        fclose(fp);
    *len = data ? (size_t)size : 0;
    return data;
}

/* Loads the sample models of MODELS_DIR's folders up to SEED_MAX bytes. */
static int load_seeds(const char *dir)
{
    static const char *const folders[] = {"openings", "formats", "classic"};

    for (size_t f = 0; f < sizeof folders / sizeof folders[0]; f++) {
        char path[4096];
        DIR *d;
        struct dirent *e;
        snprintf(path, sizeof path, "%s/%s", dir, folders[f]);
        if (!(d = opendir(path))) {
            perror(path);
            return 0;
        }
        while ((e = readdir(d)) != NULL && nseeds < SEEDS_MAX) {
            seed *s = &seeds[nseeds];
            if (e->d_name[0] == '.')
                continue;
            snprintf(path, sizeof path, "%s/%s/%s", dir, folders[f], e->d_name);
            if (!(s->data = read_all(path, &s->len))) {
                closedir(d);
                return 0;
            }
            if (s->len > SEED_MAX)
                free(s->data);
            else
                nseeds++;
        }
        closedir(d);
    }
    return nseeds > 0;
}

static void put_u32(uint8_t *p, uint32_t v)
{
    for (int i = 0; i < 4; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}

/* Writes a number that tends to break parsers over a decimal run in text
 * formats: huge, negative, zero, NaN, index-like. */
static size_t bad_number(char *out)
{
    static const char *const nums[] = {"4294967295", "4000000000",  "-1",    "0", "nan",
                                       "1e39",       "-2147483648", "99999", "2", "1e-45"};
    return (size_t)sprintf(out, "%s", nums[below(sizeof nums / sizeof nums[0])]);
}

/* Applies one random mutation to in[0..*len), keeping *len <= INPUT_MAX. */
static void mutate(uint8_t *in, size_t *len)
{
    size_t n = *len;

    switch (below(10)) {
    case 0: /* flip a bit */
        if (n)
            in[below((uint32_t)n)] ^= (uint8_t)(1u << below(8));
        break;
    case 1: /* truncate */ *len = below((uint32_t)n + 1); break;
    case 2: /* a boundary u32 somewhere (counts and lengths in binary formats) */
        if (n >= 4) {
            const uint32_t vals[] = {
                0, 1, 2, 3, 0x7fffffffu, 0xffffffffu, 0x80000000u, (uint32_t)n, (uint32_t)rnd()};
            put_u32(in + below((uint32_t)n - 3), vals[below(sizeof vals / sizeof vals[0])]);
        }
        break;
    case 3: /* the same near the start, where headers are */
        if (n >= 88) {
            const uint32_t vals[] = {0, 1, 0x7fffffffu, 0xffffffffu, (uint32_t)rnd()};
            put_u32(in + 4 * below(22), vals[below(5)]);
        }
        break;
    case 4: /* replace a run of digits by a hostile number */
        if (n) {
            size_t at = below((uint32_t)n), end;
            char num[32];
            size_t k;
            while (at < n && (in[at] < '0' || in[at] > '9'))
                at++;
            for (end = at; end < n && in[end] >= '0' && in[end] <= '9'; end++)
                ;
            k = bad_number(num);
            if (at < n && n - (end - at) + k <= INPUT_MAX) {
                memmove(in + at + k, in + end, n - end);
                memcpy(in + at, num, k);
                *len = n - (end - at) + k;
            }
        }
        break;
    case 5: /* overwrite a span with noise */
        if (n) {
            size_t at = below((uint32_t)n), k = 1 + below(16);
            for (size_t i = at; i < n && i < at + k; i++)
                in[i] = (uint8_t)rnd();
        }
        break;
    case 6: /* insert noise */
        if (n + 16 <= INPUT_MAX) {
            size_t at = below((uint32_t)n + 1), k = 1 + below(16);
            memmove(in + at + k, in + at, n - at);
            for (size_t i = at; i < at + k; i++)
                in[i] = (uint8_t)rnd();
            *len = n + k;
        }
        break;
    case 7: /* delete a span */
        if (n) {
            size_t at = below((uint32_t)n), k = 1 + below(256);
            if (k > n - at)
                k = n - at;
            memmove(in + at, in + at + k, n - at - k);
            *len = n - k;
        }
        break;
    case 8: /* duplicate a span (repeated structure: faces, nodes, elements) */
        if (n) {
            size_t at = below((uint32_t)n), k = 1 + below(512);
            if (k > n - at)
                k = n - at;
            if (n + k <= INPUT_MAX) {
                size_t to = below((uint32_t)n + 1);
                memmove(in + to + k, in + to, n - to);
                memmove(in + to, in + (at >= to ? at + k : at), k);
                *len = n + k;
            }
        }
        break;
    default: /* swap two bytes far apart */
        if (n >= 2) {
            size_t a = below((uint32_t)n), b = below((uint32_t)n);
            uint8_t t = in[a];
            in[a] = in[b];
            in[b] = t;
        }
        break;
    }
}

static int run_random(unsigned long long runs, uint64_t seed_value, const char *dir)
{
    static uint8_t in[INPUT_MAX];

    if (!load_seeds(dir))
        return 1;
    rng = seed_value;
    for (unsigned long long r = 0; r < runs; r++) {
        const seed *s = &seeds[below((uint32_t)nseeds)];
        size_t len = s->len;
        uint32_t muts = 1 + below(4);

        memcpy(in, s->data, len);
        for (uint32_t i = 0; i < muts; i++)
            mutate(in, &len);
        LLVMFuzzerTestOneInput(in, len);
    }
    for (size_t i = 0; i < nseeds; i++)
        free(seeds[i].data);
    printf("fuzz_import: %llu inputs, 0 crashes\n", runs);
    fflush(stdout);
    fprintf(stderr, "fuzz_import: %lu imports, %lu succeeded\n", n_imports, n_ok);
    return 0;
}

static int replay(int nfiles, char **files)
{
    for (int i = 0; i < nfiles; i++) {
        size_t len;
        uint8_t *data = read_all(files[i], &len);
        if (!data)
            return 1;
        LLVMFuzzerTestOneInput(data, len);
        free(data);
    }
    printf("fuzz_import: %d inputs, 0 crashes\n", nfiles);
    return 0;
}

static int usage(void)
{
    fprintf(stderr, "usage: fuzz_import --runs N [--seed S] MODELS_DIR\n"
                    "       fuzz_import FILE...\n");
    return 2;
}

/* Parses a whole decimal number; 0 on anything else. */
static int parse_count(const char *s, unsigned long long *out)
{
    char *end;

    if (s[0] < '0' || s[0] > '9')
        return 0;
    *out = strtoull(s, &end, 10);
    return *end == 0;
}

int main(int argc, char **argv)
{
    unsigned long long runs, seed_value = 1;

    if (argc >= 4 && strcmp(argv[1], "--runs") == 0) {
        if (!parse_count(argv[2], &runs))
            return usage();
        if (argc == 6 && strcmp(argv[3], "--seed") == 0 && parse_count(argv[4], &seed_value))
            return run_random(runs, seed_value, argv[5]);
        return argc == 4 ? run_random(runs, seed_value, argv[3]) : usage();
    }
    if (argc >= 2 && argv[1][0] != '-')
        return replay(argc - 1, argv + 1);
    return usage();
}

#endif
