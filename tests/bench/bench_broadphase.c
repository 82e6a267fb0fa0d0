/*
 * bench_broadphase: 10,000 moving avatars query 100,000 static ECM boxes once
 * per tick, in a sparse 1 km world and a dense 250 m world (the issue's
 * target: at most 1 ms and 5 ms per tick). Times, side by side in the same
 * run and on the same queries, the broadphase (algo/scene/broadphase.c)
 * queried one avatar at a time and in one batch, and the peer: a plain hashed
 * uniform grid (below). Checks that all three return the same set for every
 * query, without duplicates, and brute force for a sample.
 *
 *   bench_broadphase [--ticks 200] [--avatars 10000] [--boxes 100000]
 *                    [--cell 0] [--base-cell 3] [--seed 1] [--world sparse|dense|both]
 *
 * --cell is the broadphase's finest cell (0: its default), --base-cell the
 * peer's (3 m, its best on this data among 2, 3, 4, 6 and 8 m). Prints ms
 * per tick (p50, p99, mean) and the peer's p50 over each of the others'.
 * Times are CPU time of the querying thread, so that other processes on a
 * shared machine do not count. Exits 1 if any result set differs.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "alloc.h"
#include "broadphase.h"

#define AVATAR_W 0.6f
#define AVATAR_H 1.8f
#define STEP_UP 0.35f
#define PROBE 0.01f
#define MAX_MOVE 0.25f /* m per tick */
#define OUT_CAP (1u << 22) /* result handles per tick, per structure */

/* ---- deterministic random numbers (xorshift64*) ---- */

static uint64_t rng_state = 1;

static double rnd(void)
{
    rng_state ^= rng_state >> 12;
    rng_state ^= rng_state << 25;
    rng_state ^= rng_state >> 27;
    return (double)((rng_state * 2685821657736338717ull) >> 11) * (1.0 / 9007199254740992.0);
}

static float urand(float lo, float hi) { return lo + (hi - lo) * (float)rnd(); }
/* Log-uniform: as many 0.2-0.4 m boxes as 5-10 m ones per factor of two. */
static float lrand(float lo, float hi) { return lo * powf(hi / lo, (float)rnd()); }

/* ---- the peer: a plain hashed uniform grid ----
 * Cubic cells keyed by (ix, iy, iz) in an open-addressing hash table; each
 * cell holds a growable array of box ids; the boxes' AABBs live in one array
 * indexed by id; a per-box stamp removes the duplicates of boxes spanning
 * several cells. */

typedef struct hcell {
    int32_t key[3];
    uint32_t used; /* slot taken */
    uint32_t n, cap;
    uint32_t *ids;
} hcell;

typedef struct hgrid {
    float inv;
    hcell *slots;
    uint32_t mask; /* slots - 1 */
    uint32_t ncells;
    float (*box)[6];
    uint32_t *stamp;
    uint32_t qstamp;
} hgrid;

static uint32_t hhash(int32_t x, int32_t y, int32_t z)
{
    return ((uint32_t)x * 73856093u) ^ ((uint32_t)y * 19349663u) ^ ((uint32_t)z * 83492791u);
}

static hcell *hfind(const hgrid *g, int32_t x, int32_t y, int32_t z)
{
    for (uint32_t i = hhash(x, y, z) & g->mask;; i = (i + 1) & g->mask) {
        hcell *c = &g->slots[i];
        if (!c->used)
            return NULL;
        if (c->key[0] == x && c->key[1] == y && c->key[2] == z)
            return c;
    }
}

static hcell *hget(hgrid *g, int32_t x, int32_t y, int32_t z)
{
    for (uint32_t i = hhash(x, y, z) & g->mask;; i = (i + 1) & g->mask) {
        hcell *c = &g->slots[i];
        if (!c->used) {
            c->used = 1;
            c->key[0] = x, c->key[1] = y, c->key[2] = z;
            g->ncells++;
            return c;
        }
        if (c->key[0] == x && c->key[1] == y && c->key[2] == z)
            return c;
    }
}

static int32_t hcoord(const hgrid *g, float v) { return (int32_t)floorf(v * g->inv); }

/* Builds the grid over n boxes (box i has id i). Aborts when out of memory. */
static hgrid *hgrid_build(float cell, float (*box)[6], uint32_t n)
{
    hgrid *g = cvre_xcalloc(1, sizeof *g);
    g->inv = 1.0f / cell;
    g->box = box;
    g->stamp = cvre_xcalloc(n, sizeof *g->stamp);
    uint64_t refs = 0;
    for (uint32_t i = 0; i < n; i++) {
        uint64_t c = 1;
        for (int a = 0; a < 3; a++)
            c *= (uint64_t)(hcoord(g, box[i][3 + a]) - hcoord(g, box[i][a]) + 1);
        refs += c;
    }
    uint32_t slots = 1024;
    while (slots < 2 * refs)
        slots *= 2;
    g->slots = cvre_xcalloc(slots, sizeof *g->slots);
    g->mask = slots - 1;
    for (uint32_t i = 0; i < n; i++) {
        for (int32_t z = hcoord(g, box[i][2]); z <= hcoord(g, box[i][5]); z++)
            for (int32_t y = hcoord(g, box[i][1]); y <= hcoord(g, box[i][4]); y++)
                for (int32_t x = hcoord(g, box[i][0]); x <= hcoord(g, box[i][3]); x++) {
                    hcell *c = hget(g, x, y, z);
                    if (c->n == c->cap) {
                        c->cap = c->cap ? 2 * c->cap : 4;
                        c->ids = cvre_xrealloc(c->ids, c->cap * sizeof *c->ids);
                    }
                    c->ids[c->n++] = i;
                }
    }
    return g;
}

static void hgrid_free(hgrid *g)
{
    for (uint32_t i = 0; i <= g->mask; i++)
        free(g->slots[i].ids);
    free(g->slots);
    free(g->stamp);
    free(g);
}

static uint32_t hgrid_query(hgrid *g, const bp_box *qb, uint32_t *out, uint32_t max)
{
    const float q[6] = {qb->min[0], qb->min[1], qb->min[2], qb->max[0], qb->max[1], qb->max[2]};
    uint32_t n = 0, s = ++g->qstamp;
    int32_t x0 = hcoord(g, q[0]), x1 = hcoord(g, q[3]);
    int32_t y0 = hcoord(g, q[1]), y1 = hcoord(g, q[4]);
    int32_t z0 = hcoord(g, q[2]), z1 = hcoord(g, q[5]);
    for (int32_t z = z0; z <= z1; z++)
        for (int32_t y = y0; y <= y1; y++)
            for (int32_t x = x0; x <= x1; x++) {
                const hcell *c = hfind(g, x, y, z);
                if (!c)
                    continue;
                for (uint32_t k = 0; k < c->n; k++) {
                    uint32_t id = c->ids[k];
                    if (g->stamp[id] == s)
                        continue;
                    g->stamp[id] = s;
                    const float *b = g->box[id];
                    if (b[0] <= q[3] && b[3] >= q[0] && b[1] <= q[4] && b[4] >= q[1] && b[2] <= q[5] && b[5] >= q[2]) {
                        if (n < max)
                            out[n] = id;
                        n++;
                    }
                }
            }
    return n;
}

/* ---- scene ---- */

/* Boxes shaped like ECM boxes: mostly props and furniture (0.2-2 m), rooms
 * and building parts (2-10 m), long thin walls (3-30 m) and floor slabs on
 * upper storeys, at random places in a world of side w. */
static void gen_boxes(float (*box)[6], uint32_t n, float w)
{
    for (uint32_t i = 0; i < n; i++) {
        float s[3], y;
        double kind = rnd();
        if (kind < 0.55) {
            s[0] = lrand(0.2f, 2.0f), s[1] = lrand(0.2f, 2.0f), s[2] = lrand(0.2f, 2.0f);
            y = rnd() < 0.7 ? 0.0f : urand(0.0f, 9.0f);
        } else if (kind < 0.80) {
            s[0] = lrand(2.0f, 10.0f), s[1] = lrand(2.0f, 10.0f), s[2] = lrand(2.0f, 10.0f);
            y = 0.0f;
        } else if (kind < 0.92) {
            float len = urand(3.0f, 30.0f), thick = urand(0.1f, 0.4f);
            int along_x = rnd() < 0.5;
            s[0] = along_x ? len : thick, s[2] = along_x ? thick : len;
            s[1] = urand(2.5f, 4.0f);
            y = 3.0f * (float)(int)(rnd() * 3);
        } else {
            s[0] = urand(4.0f, 10.0f), s[2] = urand(4.0f, 10.0f), s[1] = urand(0.2f, 0.3f);
            y = 3.0f * (float)(1 + (int)(rnd() * 3));
        }
        float x = urand(0.0f, w - s[0]), z = urand(0.0f, w - s[2]);
        box[i][0] = x, box[i][1] = y, box[i][2] = z;
        box[i][3] = x + s[0], box[i][4] = y + s[1], box[i][5] = z + s[2];
    }
}

typedef struct avatar {
    float x, y, z, heading;
} avatar;

static void gen_avatars(avatar *av, uint32_t n, float w)
{
    for (uint32_t i = 0; i < n; i++) {
        av[i].x = urand(1.0f, w - 1.0f);
        av[i].z = urand(1.0f, w - 1.0f);
        av[i].y = rnd() < 0.85 ? 0.0f : 3.0f * (float)(1 + (int)(rnd() * 2));
        av[i].heading = urand(0.0f, 6.2831853f);
    }
}

/* One tick of wandering: up to MAX_MOVE in a slowly turning direction,
 * turned back at the world's edge. Writes the swept box of the move. */
static void step_avatar(avatar *a, float w, bp_box *q)
{
    a->heading += urand(-0.5f, 0.5f);
    float d = urand(0.0f, MAX_MOVE);
    float nx = a->x + d * cosf(a->heading), nz = a->z + d * sinf(a->heading);
    if (nx < 1.0f || nx > w - 1.0f || nz < 1.0f || nz > w - 1.0f) {
        a->heading += 3.14159265f;
        nx = a->x, nz = a->z;
    }
    float h = AVATAR_W * 0.5f;
    q->min[0] = fminf(a->x, nx) - h, q->max[0] = fmaxf(a->x, nx) + h;
    q->min[2] = fminf(a->z, nz) - h, q->max[2] = fmaxf(a->z, nz) + h;
    q->min[1] = a->y - PROBE, q->max[1] = a->y + AVATAR_H + STEP_UP;
    a->x = nx, a->z = nz;
}

/* ---- measurement ---- */

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

/* CPU time of this thread: the machine may be shared, and time spent
 * descheduled says nothing about the structures. */
static double cpu_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

static int cmp_u32(const void *a, const void *b)
{
    uint32_t x = *(const uint32_t *)a, y = *(const uint32_t *)b;
    return (x > y) - (x < y);
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

typedef struct results {
    uint32_t *h;   /* OUT_CAP handles */
    uint32_t *off; /* avatars + 1 */
} results;

/* Sorts each query's list; returns the number of lists with a duplicate. */
static uint32_t sort_lists(results *r, uint32_t nav)
{
    uint32_t dups = 0;
    for (uint32_t i = 0; i < nav; i++) {
        uint32_t *l = r->h + r->off[i], n = r->off[i + 1] - r->off[i];
        qsort(l, n, sizeof *l, cmp_u32);
        for (uint32_t k = 1; k < n; k++)
            if (l[k] == l[k - 1]) {
                dups++;
                break;
            }
    }
    return dups;
}

typedef struct stats {
    double p50, p99, mean;
} stats;

static stats summarize(double *ms, uint32_t n)
{
    stats s = {0, 0, 0};
    for (uint32_t i = 0; i < n; i++)
        s.mean += ms[i] / n;
    qsort(ms, n, sizeof *ms, cmp_double);
    s.p50 = ms[n / 2];
    s.p99 = ms[(uint32_t)ceil(0.99 * n) - 1];
    return s;
}

typedef struct options {
    uint32_t ticks, avatars, boxes;
    float cell, base_cell;
    uint64_t seed;
    int sparse, dense;
} options;

/* Runs one world; returns 0 if every result set matched. */
static int run_world(const options *o, const char *name, float w)
{
    rng_state = o->seed;
    float(*box)[6] = cvre_xmalloc(o->boxes * sizeof *box);
    avatar *av = cvre_xmalloc(o->avatars * sizeof *av);
    bp_box *q = cvre_xmalloc(o->avatars * sizeof *q);
    gen_boxes(box, o->boxes, w);
    gen_avatars(av, o->avatars, w);

    float wmin[3] = {0, 0, 0}, wmax[3] = {w, 256.0f, w};
    double t0 = now_ms();
    bp *b = bp_create(wmin, wmax, o->cell);
    if (!b) {
        fprintf(stderr, "bp_create failed\n");
        exit(2);
    }
    for (uint32_t i = 0; i < o->boxes; i++)
        if (bp_insert(b, box[i], box[i] + 3, i) != 0) {
            fprintf(stderr, "bp_insert failed\n");
            exit(2);
        }
    double t1 = now_ms();
    if (bp_optimize(b) != 0)
        exit(2);
    double t2 = now_ms();
    hgrid *g = hgrid_build(o->base_cell, box, o->boxes);
    double t3 = now_ms();

    enum { SINGLE, BATCH, PEER, NRUNS };
    static const char *const label[NRUNS] = {"broadphase, bp_query per avatar", "broadphase, bp_query_batch",
                                             "peer: hashed uniform grid"};
    results r[NRUNS];
    double *ms[NRUNS];
    for (int k = 0; k < NRUNS; k++) {
        r[k].h = cvre_xmalloc(OUT_CAP * sizeof(uint32_t));
        r[k].off = cvre_xmalloc((o->avatars + 1) * sizeof(uint32_t));
        ms[k] = cvre_xmalloc(o->ticks * sizeof(double));
    }
    uint64_t hits = 0;
    uint32_t bad = 0;

    for (uint32_t t = 0; t < o->ticks; t++) {
        for (uint32_t i = 0; i < o->avatars; i++)
            step_avatar(&av[i], w, &q[i]);
        for (int pass = 0; pass < NRUNS; pass++) {
            /* Rotate which one goes first, so that none always finds the
             * caches warmed (or flushed) by another. */
            int k = (int)((t + (uint32_t)pass) % NRUNS);
            uint32_t n = 0, *out = r[k].h, *off = r[k].off;
            double s = cpu_ms();
            if (k == SINGLE) {
                for (uint32_t i = 0; i < o->avatars; i++) {
                    off[i] = n;
                    n += bp_query(b, q[i].min, q[i].max, out + n, OUT_CAP - n);
                }
                off[o->avatars] = n;
            } else if (k == BATCH) {
                n = bp_query_batch(b, q, o->avatars, out, OUT_CAP, off);
            } else {
                for (uint32_t i = 0; i < o->avatars; i++) {
                    off[i] = n;
                    n += hgrid_query(g, &q[i], out + n, OUT_CAP - n);
                }
                off[o->avatars] = n;
            }
            ms[k][t] = cpu_ms() - s;
            if (n > OUT_CAP) {
                fprintf(stderr, "result buffer too small\n");
                exit(2);
            }
        }
        hits += r[PEER].off[o->avatars];
        for (int k = 0; k < NRUNS; k++)
            bad += sort_lists(&r[k], o->avatars);
        for (int k = 0; k < PEER; k++)
            if (memcmp(r[k].off, r[PEER].off, (o->avatars + 1) * sizeof(uint32_t)) != 0 ||
                memcmp(r[k].h, r[PEER].h, r[PEER].off[o->avatars] * sizeof(uint32_t)) != 0)
                bad++;
        if (t == 0) {
            /* Brute force for a sample of the first tick's queries. */
            const results *rp = &r[PEER];
            for (uint32_t i = 0; i < o->avatars; i += 97) {
                uint32_t m = 0, len = rp->off[i + 1] - rp->off[i];
                for (uint32_t k = 0; k < o->boxes; k++)
                    if (box[k][0] <= q[i].max[0] && box[k][3] >= q[i].min[0] && box[k][1] <= q[i].max[1] &&
                        box[k][4] >= q[i].min[1] && box[k][2] <= q[i].max[2] && box[k][5] >= q[i].min[2]) {
                        if (m >= len || rp->h[rp->off[i] + m] != k)
                            bad++;
                        m++;
                    }
                if (m != len)
                    bad++;
            }
        }
    }

    printf("%s world %.0f m: %u boxes, %u avatars, %u ticks, %.2f hits/query\n", name, (double)w, o->boxes,
           o->avatars, o->ticks, (double)hits / ((double)o->ticks * o->avatars));
    printf("  build: broadphase %.1f ms (+ optimize %.1f ms), hashed grid %.1f ms (%u cells)\n", t1 - t0, t2 - t1,
           t3 - t2, g->ncells);
    stats st[NRUNS];
    for (int k = 0; k < NRUNS; k++) {
        st[k] = summarize(ms[k], o->ticks);
        printf("  %-34s p50 %7.3f  p99 %7.3f  mean %7.3f ms/tick\n", label[k], st[k].p50, st[k].p99, st[k].mean);
    }
    printf("  peer / broadphase p50: %.2fx per avatar, %.2fx batch   result sets: %s\n", st[PEER].p50 / st[SINGLE].p50,
           st[PEER].p50 / st[BATCH].p50, bad ? "MISMATCH" : "identical");

    for (int k = 0; k < NRUNS; k++) {
        free(r[k].h);
        free(r[k].off);
        free(ms[k]);
    }
    bp_destroy(b);
    hgrid_free(g);
    free(box), free(av), free(q);
    return bad ? 1 : 0;
}

int main(int argc, char **argv)
{
    options o = {200, 10000, 100000, 0.0f, 3.0f, 1, 1, 1};
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!v)
            goto usage;
        i++;
        if (!strcmp(a, "--ticks"))
            o.ticks = (uint32_t)strtoul(v, NULL, 10);
        else if (!strcmp(a, "--avatars"))
            o.avatars = (uint32_t)strtoul(v, NULL, 10);
        else if (!strcmp(a, "--boxes"))
            o.boxes = (uint32_t)strtoul(v, NULL, 10);
        else if (!strcmp(a, "--cell"))
            o.cell = strtof(v, NULL);
        else if (!strcmp(a, "--base-cell"))
            o.base_cell = strtof(v, NULL);
        else if (!strcmp(a, "--seed"))
            o.seed = strtoull(v, NULL, 10);
        else if (!strcmp(a, "--world")) {
            o.sparse = !strcmp(v, "sparse") || !strcmp(v, "both");
            o.dense = !strcmp(v, "dense") || !strcmp(v, "both");
        } else
            goto usage;
    }
    if (!o.ticks || !o.avatars || !o.boxes || !(o.base_cell > 0) || !(o.cell >= 0) || !o.seed ||
        (!o.sparse && !o.dense))
        goto usage;
    int rc = 0;
    if (o.sparse)
        rc |= run_world(&o, "sparse", 1000.0f);
    if (o.dense)
        rc |= run_world(&o, "dense", 250.0f);
    return rc;
usage:
    fprintf(stderr, "usage: %s [--ticks N] [--avatars N] [--boxes N] [--cell M] [--base-cell M] [--seed N] "
                    "[--world sparse|dense|both]\n", argv[0]);
    return 2;
}
