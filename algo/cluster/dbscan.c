/*
 * dbscan.c: DBSCAN over 3D points, exact, with FLANN for radius searches.
 *
 * A FLANN search costs microseconds, so the grid decides whatever it can
 * exactly and FLANN gets the rest:
 *  1. Points are binned in a uniform grid whose cells have edge h slightly
 *     below eps/sqrt(3), so any two points of one cell are within eps. A cell
 *     holding >= min_points points is all core. Otherwise a point is core if
 *     its cell plus the adjacent cells lying entirely within eps of it hold
 *     >= min_points points, and not core if the 27 coarse cells (2x2x2 cells
 *     each) around it hold fewer. Only the points in between get a FLANN
 *     radius search for their core flag.
 *  2. A non-core point near a core point gets a FLANN search for its
 *     neighbours, to pick its cluster.
 *  FLANN compares in float and with a strict '<', so it is asked with eps^2
 *  slightly enlarged and every candidate is re-checked in double.
 *  Searches run on worker threads sharing one read-only KD-tree.
 *  3. Clusters are built on cells (union-find): all core points of a cell are
 *     within eps of each other, and two cells at most 2 apart (3 cells are
 *     more than eps) are joined by their first pair of core points within eps.
 * Points are processed in grid order (sorted by cell), which keeps each
 * cell's points contiguous in memory; indices are mapped back at the end.
 */
#include "dbscan.h"

#include <errno.h>
#include <flann/flann.h>
#include <limits.h>
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "alloc.h"

/* Relative margin taken off the grid cell edge, so that rounding in the cell
 * computation can never put two points more than eps apart in one cell. */
#define CELL_SLACK 1e-6
/* Relative margin added to eps^2 for FLANN's float search: far above float
 * rounding (about 1e-7), so no pair within eps is missed; the exact test
 * then drops the extra candidates. */
#define SEARCH_SLACK 1e-4
/* Most cells per axis; beyond that (a tiny eps over a huge extent) the grid
 * is skipped: every point gets a search and clusters are built on points.
 * 2^20 per axis keeps cell keys in 60 bits. */
#define GRID_MAX_DIM (1u << 20)
/* Points a worker claims at a time: small enough to balance threads, large
 * enough that the shared counter is not contended. */
#define CHUNK 512u
/* Fewest searches per extra thread; below that a thread costs more to start
 * than it saves. */
#define MIN_POINTS_PER_THREAD 4096u
/* FLANN KD-tree leaf size: 32 searched about 10% faster than 16 and 25%
 * faster than 10 (the default) on the benchmark points, same build time. */
#define FLANN_LEAF 32
/* Cells within 2 steps on each axis can hold points within eps; 3 steps are
 * at least 2h > eps apart. */
#define REACH 2

_Static_assert(DBSCAN_MAX_POINTS <= (uint32_t)INT_MAX + 1u, "indices must fit FLANN's int");
_Static_assert(DBSCAN_MAX_THREADS >= 1 && DBSCAN_MAX_THREADS <= 255, "owner ids are uint8_t");
_Static_assert(CHUNK >= 1, "chunks must hold points");

struct dbscan_result {
    size_t count;
    dbscan_cluster *clusters;
    uint8_t *core; /* per input point */
    size_t n;
    size_t searches;
};

/* A worker's output: neighbour lists of the points it searched. */
typedef struct worker_buf {
    uint32_t *v;
    size_t len, cap;
} worker_buf;

/* Neighbour rows of a grid whose cells are sorted by key x + nx*(y + ny*z).
 * For a cell, the neighbours at offsets (dx, dy, dz) with fixed dy, dz are a
 * key range; while cells are visited in key order that range only moves
 * forward, so one cursor per (dy, dz) finds them without lookups. */
typedef struct rows {
    const uint64_t *key;
    uint32_t count;
    uint32_t nx, ny, nz;
    uint32_t pos[(2 * REACH + 1) * (2 * REACH + 1)];
} rows;

/* Everything one run needs; freed in one place. Indices are in grid order
 * unless named orig. */
typedef struct run {
    size_t n;
    double eps2;
    uint32_t min_points;
    double lo[3], h;
    float *pts;           /* 3n, grid order */
    uint32_t *orig;       /* grid index -> input index */
    uint32_t *cell_of;    /* grid index -> cell */
    uint32_t m;           /* cells */
    uint32_t *cell_start; /* m+1 */
    uint64_t *cell_key;   /* m */
    uint32_t nx, ny, nz;  /* cells per axis */
    /* Coarse cells of 2x2x2 cells, edge 2h > eps: a point's eps-ball lies in
     * the 3x3x3 coarse cells around its own. */
    uint32_t mc;
    uint32_t *coarse_of;  /* cell -> coarse cell */
    uint64_t *ckey;       /* mc */
    uint32_t *ccount;     /* points per coarse cell */
    uint8_t *chas_core;   /* coarse cell holds a core point */
    uint32_t cnx, cny, cnz;
    uint8_t *core;        /* n */
    uint8_t *cell_core;   /* m: cell holds a core point */
    uint32_t *ask;        /* points whose core flag FLANN decides */
    size_t nask;
    uint32_t *bord;       /* non-core points near a core point */
    size_t nbord;
    size_t *nb_off;       /* per point: start of its neighbour list in its */
    uint32_t *nb_len;     /* owner's buffer; only for points that got one */
    uint8_t *nb_owner;
    int use_grid;         /* 0: one cell, every point searched, lists for all */
    worker_buf bufs[DBSCAN_MAX_THREADS];
    size_t searches[DBSCAN_MAX_THREADS];
    flann_index_t index;
    struct FLANNParameters fp;
    float radius2;
    int phase;            /* PHASE_CORE or PHASE_BORDER */
    atomic_size_t next_chunk;
    atomic_int error;
} run;

enum { PHASE_CORE, PHASE_BORDER };

static double dist2(const float *a, const float *b)
{
    double dx = (double)a[0] - (double)b[0];
    double dy = (double)a[1] - (double)b[1];
    double dz = (double)a[2] - (double)b[2];
    return dx * dx + dy * dy + dz * dz;
}

static uint64_t hash64(uint64_t k)
{
    k ^= k >> 31;
    k *= 0x9e3779b97f4a7c15ull;
    k ^= k >> 29;
    return k;
}

static void rows_init(rows *w, const uint64_t *key, uint32_t count, uint32_t nx, uint32_t ny, uint32_t nz)
{
    *w = (rows){key, count, nx, ny, nz, {0}};
}

/*
 * Cells of row `cur` (one per (dy, dz), used with the same offsets each
 * time) next to the cell at x, y, z, with x offsets in [dxlo, dxhi]:
 * returns the first index and sets *end past the last. Calls for one cursor
 * must come in increasing key order of the centre cell.
 */
static uint32_t rows_get(rows *w, int cur, const int64_t c[3], int dy, int dz, int dxlo, int dxhi, uint32_t *end)
{
    int64_t y = c[1] + dy, z = c[2] + dz, x0 = c[0] + dxlo, x1 = c[0] + dxhi;
    *end = 0;
    if (y < 0 || z < 0 || y >= w->ny || z >= w->nz)
        return 0;
    if (x0 < 0)
        x0 = 0;
    if (x1 >= w->nx)
        x1 = (int64_t)w->nx - 1;
    uint64_t base = w->nx * ((uint64_t)y + (uint64_t)w->ny * (uint64_t)z);
    uint32_t o = w->pos[cur];
    while (o < w->count && w->key[o] < base + (uint64_t)x0)
        o++;
    w->pos[cur] = o;
    uint32_t e = o;
    while (e < w->count && w->key[e] <= base + (uint64_t)x1)
        e++;
    *end = e;
    return o;
}

static void key_coords(uint64_t key, uint32_t nx, uint32_t ny, int64_t c[3])
{
    c[0] = (int64_t)(key % nx);
    c[1] = (int64_t)(key / nx % ny);
    c[2] = (int64_t)(key / nx / ny);
}

/* Sorts keys (with their values) by LSD radix sort on the low `bits` bits.
 * tk/tv are scratch arrays of the same length. Returns 0 or -ENOMEM. */
static int radix_sort(uint64_t *k, uint32_t *v, uint64_t *tk, uint32_t *tv, size_t n, unsigned bits)
{
    enum { DIGIT = 11, BUCKETS = 1 << DIGIT };
    size_t *count = cvre_calloc(BUCKETS, sizeof *count);
    if (!count)
        return -ENOMEM;
    for (unsigned shift = 0; shift < bits; shift += DIGIT) {
        memset(count, 0, BUCKETS * sizeof *count);
        for (size_t i = 0; i < n; i++)
            count[(k[i] >> shift) & (BUCKETS - 1)]++;
        size_t sum = 0;
        for (size_t b = 0; b < BUCKETS; b++) {
            size_t c = count[b];
            count[b] = sum;
            sum += c;
        }
        for (size_t i = 0; i < n; i++) {
            size_t d = count[(k[i] >> shift) & (BUCKETS - 1)]++;
            tk[d] = k[i];
            tv[d] = v[i];
        }
        memcpy(k, tk, n * sizeof *k);
        memcpy(v, tv, n * sizeof *v);
    }
    free(count);
    return 0;
}

static unsigned bits_for(uint64_t count)
{
    unsigned bits = 0;
    while (bits < 64 && (count - 1) >> bits)
        bits++;
    return bits;
}

static void cell_coords(const run *r, uint32_t c, int64_t xyz[3])
{
    key_coords(r->cell_key[c], r->nx, r->ny, xyz);
}

/*
 * Puts the points in grid order and fills the cell tables. With a grid that
 * would be too fine (tiny eps over a huge extent), uses one cell that can
 * never be dense and whose bounds decide nothing, so that FLANN decides every
 * point. Returns 0 or -ENOMEM.
 */
static int build_grid(run *r, const float *xyz, const double hi[3], double eps)
{
    size_t n = r->n;
    double dim[3];
    r->h = eps / sqrt(3.0) * (1.0 - CELL_SLACK);
    r->use_grid = 1;
    for (int a = 0; a < 3; a++) {
        dim[a] = floor((hi[a] - r->lo[a]) / r->h) + 1.0;
        if (dim[a] > (double)GRID_MAX_DIM)
            r->use_grid = 0;
    }
    r->nx = r->use_grid ? (uint32_t)dim[0] : 1;
    r->ny = r->use_grid ? (uint32_t)dim[1] : 1;
    r->nz = r->use_grid ? (uint32_t)dim[2] : 1;
    unsigned bits = bits_for((uint64_t)r->nx * r->ny * r->nz);
    uint32_t dims[3] = {r->nx, r->ny, r->nz};

    int rc = -ENOMEM;
    uint64_t *key = cvre_malloc(n * sizeof *key), *tk = cvre_malloc(n * sizeof *tk);
    uint32_t *tv = cvre_malloc(n * sizeof *tv);
    r->orig = cvre_malloc(n * sizeof *r->orig);
    if (!key || !tk || !tv || !r->orig)
        goto cleanup;
    for (size_t i = 0; i < n; i++) {
        uint64_t c[3] = {0, 0, 0};
        for (int a = 0; a < 3 && r->use_grid; a++) {
            c[a] = (uint64_t)floor(((double)xyz[3 * i + (size_t)a] - r->lo[a]) / r->h);
            if (c[a] >= dims[a]) /* rounding at the top edge */
                c[a] = dims[a] - 1;
        }
        key[i] = c[0] + r->nx * (c[1] + (uint64_t)r->ny * c[2]);
        r->orig[i] = (uint32_t)i;
    }
    if ((rc = radix_sort(key, r->orig, tk, tv, n, bits)) < 0)
        goto cleanup;
    rc = -ENOMEM;

    uint32_t m = 0;
    for (size_t i = 0; i < n; i++)
        m += (i == 0 || key[i] != key[i - 1]);
    r->m = m;
    r->pts = cvre_malloc(3 * n * sizeof *r->pts);
    r->cell_of = cvre_malloc(n * sizeof *r->cell_of);
    r->cell_start = cvre_malloc(((size_t)m + 1) * sizeof *r->cell_start);
    r->cell_key = cvre_malloc((size_t)m * sizeof *r->cell_key);
    if (!r->pts || !r->cell_of || !r->cell_start || !r->cell_key)
        goto cleanup;
    uint32_t c = 0;
    for (size_t i = 0; i < n; i++) {
        if (i > 0 && key[i] != key[i - 1])
            c++;
        if (i == 0 || key[i] != key[i - 1]) {
            r->cell_start[c] = (uint32_t)i;
            r->cell_key[c] = key[i];
        }
        r->cell_of[i] = c;
        memcpy(r->pts + 3 * i, xyz + 3 * (size_t)r->orig[i], 3 * sizeof *r->pts);
    }
    r->cell_start[m] = (uint32_t)n;
    rc = 0;
cleanup:
    free(key);
    free(tk);
    free(tv);
    return rc;
}

/* Groups cells by 2x2x2 into coarse cells and counts their points. Cells are
 * in key order, so coarse keys come out unsorted: sort them (with their cell
 * as value) to number the coarse cells. Returns 0 or -ENOMEM. */
static int build_coarse(run *r)
{
    uint32_t m = r->m;
    r->cnx = (r->nx + 1) / 2;
    r->cny = (r->ny + 1) / 2;
    r->cnz = (r->nz + 1) / 2;
    int rc = -ENOMEM;
    uint64_t *k = cvre_malloc((size_t)m * sizeof *k), *tk = cvre_malloc((size_t)m * sizeof *tk);
    uint32_t *v = cvre_malloc((size_t)m * sizeof *v), *tv = cvre_malloc((size_t)m * sizeof *tv);
    r->coarse_of = cvre_malloc((size_t)m * sizeof *r->coarse_of);
    if (!k || !tk || !v || !tv || !r->coarse_of)
        goto cleanup;
    for (uint32_t c = 0; c < m; c++) {
        int64_t x[3];
        cell_coords(r, c, x);
        k[c] = (uint64_t)(x[0] / 2) + r->cnx * ((uint64_t)(x[1] / 2) + (uint64_t)r->cny * (uint64_t)(x[2] / 2));
        v[c] = c;
    }
    if ((rc = radix_sort(k, v, tk, tv, m, bits_for((uint64_t)r->cnx * r->cny * r->cnz))) < 0)
        goto cleanup;
    rc = -ENOMEM;
    uint32_t mc = 0;
    for (uint32_t i = 0; i < m; i++)
        mc += (i == 0 || k[i] != k[i - 1]);
    r->mc = mc;
    r->ckey = cvre_malloc((size_t)mc * sizeof *r->ckey);
    r->ccount = cvre_calloc((size_t)mc, sizeof *r->ccount);
    r->chas_core = cvre_calloc((size_t)mc, 1);
    if (!r->ckey || !r->ccount || !r->chas_core)
        goto cleanup;
    uint32_t cc = 0;
    for (uint32_t i = 0; i < m; i++) {
        if (i > 0 && k[i] != k[i - 1])
            cc++;
        r->ckey[cc] = k[i];
        r->coarse_of[v[i]] = cc;
        r->ccount[cc] += r->cell_start[v[i] + 1] - r->cell_start[v[i]];
    }
    rc = 0;
cleanup:
    free(k);
    free(tk);
    free(v);
    free(tv);
    return rc;
}

/* For every coarse cell, over the 27 coarse cells around it: with any_core
 * 0, the number of points they hold; with 1, whether one holds a core point. */
static void coarse_scan(const run *r, int any_core, uint32_t *out)
{
    rows w;
    rows_init(&w, r->ckey, r->mc, r->cnx, r->cny, r->cnz);
    for (uint32_t cc = 0; cc < r->mc; cc++) {
        int64_t c[3];
        key_coords(r->ckey[cc], r->cnx, r->cny, c);
        uint32_t sum = 0;
        for (int d = 0; d < 9; d++) {
            uint32_t end, o = rows_get(&w, d, c, d % 3 - 1, d / 3 - 1, -1, 1, &end);
            for (; o < end; o++)
                sum += any_core ? r->chas_core[o] : r->ccount[o];
        }
        out[cc] = any_core ? sum > 0 : sum;
    }
}

/*
 * Decides core flags from the grid alone where it can: a cell with at least
 * min_points points is all core (its diameter is below eps); a point whose
 * 27 coarse cells hold fewer than min_points points is not core; a point
 * with at least min_points points in its own cell and in the adjacent cells
 * that lie entirely within eps of it is core. The rest goes to r->ask for
 * FLANN. Without the grid, every point goes to FLANN. Returns 0 or -ENOMEM.
 */
static int classify(run *r)
{
    size_t n = r->n;
    uint32_t *ub = NULL;
    r->core = cvre_calloc(n, 1);
    r->ask = cvre_malloc(n * sizeof *r->ask);
    if (!r->core || !r->ask)
        return -ENOMEM;
    if (!r->use_grid) {
        for (uint32_t s = 0; s < n; s++)
            r->ask[r->nask++] = s;
        return 0;
    }
    ub = cvre_malloc(((size_t)r->mc + 1) * sizeof *ub);
    if (!ub)
        return -ENOMEM;
    coarse_scan(r, 0, ub);
    rows w;
    rows_init(&w, r->cell_key, r->m, r->nx, r->ny, r->nz);
    /* Margin on the cell boxes: far above the rounding of the cell index and
     * of the box bounds, both relative to lo and so to the extent (at most
     * 2^20 cells), never to the size of the coordinates. */
    double margin = r->h * 1e-6, lim2 = r->eps2 * (1.0 - 1e-9);
    for (uint32_t c = 0; c < r->m; c++) {
        uint32_t c0 = r->cell_start[c], c1 = r->cell_start[c + 1], cnt = c1 - c0;
        if (cnt >= r->min_points) {
            memset(r->core + c0, 1, cnt);
            continue;
        }
        if (ub[r->coarse_of[c]] < r->min_points)
            continue;
        int64_t x[3];
        cell_coords(r, c, x);
        /* Points in the 27 cells around, by offset index dx+1 + 3(dy+1) + 9(dz+1);
         * the cell itself (13) is counted apart. */
        uint32_t ncount[27];
        for (int d = 0; d < 27; d++)
            ncount[d] = 0;
        for (int row = 0; row < 9; row++) {
            uint32_t end, o = rows_get(&w, row, x, row % 3 - 1, row / 3 - 1, -1, 1, &end);
            for (; o < end; o++)
                if (o != c)
                    ncount[(int64_t)(r->cell_key[o] % r->nx) - x[0] + 1 + 3 * row] =
                        r->cell_start[o + 1] - r->cell_start[o];
        }
        for (uint32_t s = c0; s < c1; s++) {
            const float *p = r->pts + 3 * (size_t)s;
            /* Farthest reach, per axis, into the cell below, this one and
             * the one above (index 0, 1, 2). */
            double far[3][3];
            for (int a = 0; a < 3; a++) {
                double v = (double)p[a] - r->lo[a], b0 = (double)x[a] * r->h - margin;
                double b1 = (double)(x[a] + 1) * r->h + margin;
                far[a][0] = v - (b0 - r->h);
                far[a][1] = fmax(v - b0, b1 - v);
                far[a][2] = b1 + r->h - v;
            }
            uint32_t lb = cnt;
            for (int d = 0; d < 27 && lb < r->min_points; d++) {
                if (!ncount[d])
                    continue;
                double fx = far[0][d % 3], fy = far[1][d / 3 % 3], fz = far[2][d / 9];
                if (fx * fx + fy * fy + fz * fz <= lim2)
                    lb += ncount[d];
            }
            if (lb >= r->min_points)
                r->core[s] = 1;
            else
                r->ask[r->nask++] = s;
        }
    }
    free(ub);
    return 0;
}

static int buf_push(worker_buf *b, uint32_t v)
{
    if (b->len == b->cap) {
        size_t cap = b->cap ? 2 * b->cap : 1024;
        uint32_t *nv = cvre_realloc(b->v, cap * sizeof *nv);
        if (!nv)
            return -ENOMEM;
        b->v = nv;
        b->cap = cap;
    }
    b->v[b->len++] = v;
    return 0;
}

/* A worker's search buffers, grown when a search finds more. */
typedef struct search_buf {
    int *idx;
    float *dst;
    size_t cap;
} search_buf;

static int search_reserve(search_buf *sb, size_t cap)
{
    if (cap <= sb->cap)
        return 0;
    int *idx = cvre_realloc(sb->idx, cap * sizeof *idx);
    if (!idx)
        return -ENOMEM;
    sb->idx = idx;
    float *dst = cvre_realloc(sb->dst, cap * sizeof *dst);
    if (!dst)
        return -ENOMEM;
    sb->dst = dst;
    sb->cap = cap;
    return 0;
}

/*
 * Leaves in sb->idx the points within eps of grid point s (exact test) and
 * returns how many, or -ENOMEM/-EIO. If more than `enough` are within eps,
 * may stop at `enough` (the caller only needs to know that) unless all is set.
 *
 * FLANN's C API copies max_nn results per search, so it is asked for
 * `enough` nearest candidates first, with eps^2 slightly enlarged (it
 * compares in float, strictly). Only if all of them are candidates but some
 * fail the exact test is it asked to count, then list, all candidates.
 */
static int search_point(run *r, uint8_t owner, uint32_t s, uint32_t enough, int all, search_buf *sb)
{
    float *q = r->pts + 3 * (size_t)s;
    int rc = search_reserve(sb, enough);
    if (rc < 0)
        return rc;
    r->searches[owner]++;
    int found = flann_radius_search(r->index, q, sb->idx, sb->dst, (int)enough, r->radius2, &r->fp);
    if (found < 0)
        return -EIO;
    uint32_t within = 0;
    for (int i = 0; i < found; i++)
        if (dist2(q, r->pts + 3 * (size_t)sb->idx[i]) <= r->eps2)
            sb->idx[within++] = sb->idx[i];
    if ((uint32_t)found < enough || (within == enough && !all))
        return (int)within;
    r->searches[owner] += 2;
    found = flann_radius_search(r->index, q, sb->idx, sb->dst, 0, r->radius2, &r->fp);
    if (found < 0)
        return -EIO;
    if ((rc = search_reserve(sb, (size_t)found + 1)) < 0)
        return rc;
    found = flann_radius_search(r->index, q, sb->idx, sb->dst, found + 1, r->radius2, &r->fp);
    if (found < 0)
        return -EIO;
    within = 0;
    for (int i = 0; i < found; i++)
        if (dist2(q, r->pts + 3 * (size_t)sb->idx[i]) <= r->eps2)
            sb->idx[within++] = sb->idx[i];
    return (int)within;
}

/* Appends the neighbours in sb->idx (core ones only if core_only) to the
 * owner's buffer as point s's list. Returns 0 or -ENOMEM. */
static int keep_list(run *r, uint8_t owner, uint32_t s, const search_buf *sb, int count, int core_only)
{
    worker_buf *b = &r->bufs[owner];
    r->nb_off[s] = b->len;
    r->nb_owner[s] = owner;
    for (int i = 0; i < count; i++) {
        uint32_t t = (uint32_t)sb->idx[i];
        if (t != s && (!core_only || r->core[t]) && buf_push(b, t) < 0)
            return -ENOMEM;
    }
    r->nb_len[s] = (uint32_t)(b->len - r->nb_off[s]);
    return 0;
}

/* One point of the current phase. Core phase: its core flag (and without
 * the grid, its whole neighbour list). Border phase: its core neighbours,
 * fewer than min_points since it is not core. Returns 0 or -errno. */
static int work_one(run *r, uint8_t owner, size_t j, search_buf *sb)
{
    if (r->phase == PHASE_CORE) {
        uint32_t s = r->ask[j];
        int w = search_point(r, owner, s, r->min_points, !r->use_grid, sb);
        if (w < 0)
            return w;
        r->core[s] = (uint8_t)((uint32_t)w >= r->min_points);
        return r->use_grid ? 0 : keep_list(r, owner, s, sb, w, 0);
    }
    int w = search_point(r, owner, r->bord[j], r->min_points, 0, sb);
    return w < 0 ? w : keep_list(r, owner, r->bord[j], sb, w, 1);
}

typedef struct worker_arg {
    run *r;
    uint8_t id;
} worker_arg;

/* Claims chunks of the current phase's points until none is left or a
 * worker failed. */
static void *worker(void *arg)
{
    worker_arg *w = arg;
    run *r = w->r;
    size_t total = r->phase == PHASE_CORE ? r->nask : r->nbord;
    search_buf sb = {NULL, NULL, 0};
    int rc = 0;
    while (rc == 0 && atomic_load(&r->error) == 0) {
        size_t start = atomic_fetch_add(&r->next_chunk, 1) * CHUNK;
        if (start >= total)
            break;
        size_t end = start + CHUNK < total ? start + CHUNK : total;
        for (size_t j = start; j < end && rc == 0; j++)
            rc = work_one(r, w->id, j, &sb);
    }
    if (rc < 0) {
        int zero = 0;
        atomic_compare_exchange_strong(&r->error, &zero, rc);
    }
    free(sb.idx);
    free(sb.dst);
    return NULL;
}

/* Runs one phase on `threads` threads, the caller being one of them.
 * Returns 0 or -errno. */
static int run_phase(run *r, int phase, uint32_t threads)
{
    worker_arg args[DBSCAN_MAX_THREADS];
    pthread_t tid[DBSCAN_MAX_THREADS];
    uint32_t started = 0;
    r->phase = phase;
    atomic_store(&r->next_chunk, 0);
    for (uint32_t t = 0; t < threads; t++)
        args[t] = (worker_arg){r, (uint8_t)t};
    for (uint32_t t = 1; t < threads; t++) {
        if (pthread_create(&tid[started], NULL, worker, &args[t]) != 0)
            break;
        started++;
    }
    /* The caller claims chunks until none is left, so threads that could not
     * be started only cost speed. */
    worker(&args[0]);
    for (uint32_t t = 0; t < started; t++)
        pthread_join(tid[t], NULL);
    return atomic_load(&r->error);
}

static uint32_t uf_find(uint32_t *parent, uint32_t x)
{
    while (parent[x] != x) {
        parent[x] = parent[parent[x]];
        x = parent[x];
    }
    return x;
}

static void uf_union(uint32_t *parent, uint32_t a, uint32_t b)
{
    a = uf_find(parent, a);
    b = uf_find(parent, b);
    if (a < b)
        parent[b] = a;
    else if (b < a)
        parent[a] = b;
}

static const uint32_t *neighbours(const run *r, uint32_t s, uint32_t *len)
{
    *len = r->nb_len[s];
    return *len ? r->bufs[r->nb_owner[s]].v + r->nb_off[s] : NULL;
}

/* True if some core point of cell a is within eps of some core point of b. */
static int cells_touch(const run *r, uint32_t a, uint32_t b)
{
    for (uint32_t i = r->cell_start[a]; i < r->cell_start[a + 1]; i++) {
        if (!r->core[i])
            continue;
        for (uint32_t k = r->cell_start[b]; k < r->cell_start[b + 1]; k++)
            if (r->core[k] && dist2(r->pts + 3 * (size_t)i, r->pts + 3 * (size_t)k) <= r->eps2)
                return 1;
    }
    return 0;
}

/* Union-find over cells holding core points: all core points of one cell are
 * within eps of each other, and two cells (at most REACH apart) are joined
 * by their first pair of core points within eps, unless already joined.
 * Without the grid, over points instead, from their neighbour lists. */
static void connect(const run *r, uint32_t *parent)
{
    if (!r->use_grid) {
        for (uint32_t s = 0; s < r->n; s++)
            parent[s] = s;
        for (uint32_t s = 0; s < r->n; s++) {
            uint32_t len;
            const uint32_t *nb = neighbours(r, s, &len);
            for (uint32_t i = 0; i < len && r->core[s]; i++)
                if (r->core[nb[i]])
                    uf_union(parent, s, nb[i]);
        }
        return;
    }
    for (uint32_t c = 0; c < r->m; c++)
        parent[c] = c;
    rows w;
    rows_init(&w, r->cell_key, r->m, r->nx, r->ny, r->nz);
    for (uint32_t c = 0; c < r->m; c++) {
        if (!r->cell_core[c])
            continue;
        int64_t x[3];
        cell_coords(r, c, x);
        /* Each unordered pair of cells once: offsets after (0,0,0) in key
         * order, i.e. dx > 0 in the cell's own row, all dx in later rows. */
        int cur = 0;
        for (int dz = 0; dz <= REACH; dz++)
            for (int dy = dz ? -REACH : 0; dy <= REACH; dy++, cur++) {
                uint32_t end, o = rows_get(&w, cur, x, dy, dz, (dz || dy) ? -REACH : 1, REACH, &end);
                for (; o < end; o++)
                    if (r->cell_core[o] && uf_find(parent, c) != uf_find(parent, o) && cells_touch(r, c, o))
                        uf_union(parent, c, o);
            }
    }
}

/* Distinct clusters (pre-filter ids, via comp[] of core points) reached by a
 * non-core point's list; written to out (room for its list length). */
static uint32_t reached(const run *r, const uint32_t *comp, const uint32_t *nb, uint32_t len, uint32_t *out)
{
    uint32_t k = 0;
    for (uint32_t i = 0; i < len; i++) {
        if (!r->core[nb[i]])
            continue;
        uint32_t c = comp[nb[i]], e = 0;
        while (e < k && out[e] != c)
            e++;
        if (e == k)
            out[k++] = c;
    }
    return k;
}

/*
 * The second half of a run, after core flags and connectivity are known:
 * numbers the components, counts their distinct users, drops those below
 * min_users, labels border points and fills the result. parent is the
 * union-find; scratch arrays are allocated here. Returns 0 or -ENOMEM.
 */
static int label(run *r, uint32_t *parent, const float *xyz, const uint32_t *users, uint32_t min_users,
                 int32_t *labels_out, dbscan_result *res)
{
    size_t n = r->n;
    int rc = -ENOMEM;
    uint32_t *comp = NULL, *cid = NULL;
    uint32_t *first = NULL, *cnt = NULL, *pair_user = NULL, *table = NULL, *stamp = NULL;
    uint32_t *ucount = NULL, *final_id = NULL, *order = NULL, *tmp = NULL;
    uint32_t k0 = 0;

    /* Component numbers (comp[] of core points) in grid order of their first
     * point; first[k] = lowest input index of a core point of component k. */
    comp = cvre_malloc(n * sizeof *comp);
    cid = cvre_malloc((r->use_grid ? (size_t)r->m : n) * sizeof *cid);
    first = cvre_malloc(n * sizeof *first);
    if (!comp || !cid || !first)
        goto cleanup;
    for (uint32_t c = 0; c < (r->use_grid ? r->m : n); c++)
        cid[c] = UINT32_MAX;
    for (uint32_t s = 0; s < n; s++) {
        if (!r->core[s])
            continue;
        uint32_t root = uf_find(parent, r->use_grid ? r->cell_of[s] : s);
        if (cid[root] == UINT32_MAX) {
            cid[root] = k0;
            first[k0++] = r->orig[s];
        }
        comp[s] = cid[root];
        if (r->orig[s] < first[comp[s]])
            first[comp[s]] = r->orig[s];
    }
    /* (component, user) pairs: core points, and each border point once per
     * component it reaches; counted, then bucketed by component. */
    uint32_t maxlist = 0;
    cnt = cvre_calloc((size_t)k0 + 1, sizeof *cnt);
    if (!cnt)
        goto cleanup;
    for (size_t j = 0; j < r->nbord; j++)
        if (r->nb_len[r->bord[j]] > maxlist)
            maxlist = r->nb_len[r->bord[j]];
    tmp = cvre_malloc(((size_t)maxlist + 1) * sizeof *tmp);
    if (!tmp)
        goto cleanup;
    for (uint32_t s = 0; s < n; s++)
        if (r->core[s])
            cnt[comp[s] + 1]++;
    for (size_t j = 0; j < r->nbord; j++) {
        uint32_t len;
        const uint32_t *nb = neighbours(r, r->bord[j], &len);
        uint32_t k = reached(r, comp, nb, len, tmp);
        for (uint32_t e = 0; e < k; e++)
            cnt[tmp[e] + 1]++;
    }
    uint32_t biggest = 0;
    for (uint32_t k = 0; k < k0; k++) {
        if (cnt[k + 1] > biggest)
            biggest = cnt[k + 1];
        cnt[k + 1] += cnt[k];
    }
    pair_user = cvre_malloc(((size_t)cnt[k0] + 1) * sizeof *pair_user);
    if (!pair_user)
        goto cleanup;
    for (uint32_t s = 0; s < n; s++)
        if (r->core[s])
            pair_user[cnt[comp[s]]++] = users ? users[r->orig[s]] : r->orig[s];
    for (size_t j = 0; j < r->nbord; j++) {
        uint32_t s = r->bord[j], len;
        const uint32_t *nb = neighbours(r, s, &len);
        uint32_t k = reached(r, comp, nb, len, tmp);
        for (uint32_t e = 0; e < k; e++)
            pair_user[cnt[tmp[e]]++] = users ? users[r->orig[s]] : r->orig[s];
    }
    /* cnt[k] now holds the end of bucket k, i.e. the start of bucket k+1. */
    size_t tcap = 2;
    while (tcap < 2 * (size_t)biggest)
        tcap <<= 1;
    table = cvre_malloc(tcap * sizeof *table);
    stamp = cvre_calloc(tcap, sizeof *stamp);
    ucount = cvre_malloc(((size_t)k0 + 1) * sizeof *ucount);
    if (!table || !stamp || !ucount)
        goto cleanup;
    for (uint32_t k = 0; k < k0; k++) {
        uint32_t b0 = k ? cnt[k - 1] : 0, distinct = 0;
        for (uint32_t i = b0; i < cnt[k]; i++) {
            uint32_t u = pair_user[i];
            size_t h = (size_t)hash64(u) & (tcap - 1);
            while (stamp[h] == k + 1 && table[h] != u)
                h = (h + 1) & (tcap - 1);
            if (stamp[h] != k + 1) {
                stamp[h] = k + 1;
                table[h] = u;
                distinct++;
            }
        }
        ucount[k] = distinct;
    }
    /* Survivors, numbered by their lowest core input index. */
    order = cvre_malloc(((size_t)k0 + 1) * sizeof *order);
    final_id = cvre_malloc(((size_t)k0 + 1) * sizeof *final_id);
    if (!order || !final_id)
        goto cleanup;
    uint32_t k1 = 0;
    for (uint32_t k = 0; k < k0; k++) {
        final_id[k] = UINT32_MAX;
        if (ucount[k] >= min_users)
            order[k1++] = k;
    }
    /* Insertion into a table indexed by first[] would need n slots; sort the
     * survivors instead (few clusters in practice, but stay n log n). */
    {
        uint64_t *kv = cvre_malloc(((size_t)k1 + 1) * sizeof *kv);
        uint64_t *tkv = cvre_malloc(((size_t)k1 + 1) * sizeof *tkv);
        uint32_t *tv = cvre_malloc(((size_t)k1 + 1) * sizeof *tv);
        int src = kv && tkv && tv ? 0 : -ENOMEM;
        if (src == 0) {
            for (uint32_t i = 0; i < k1; i++)
                kv[i] = first[order[i]];
            src = radix_sort(kv, order, tkv, tv, k1, 32);
        }
        free(kv);
        free(tkv);
        free(tv);
        if (src < 0)
            goto cleanup;
    }
    for (uint32_t i = 0; i < k1; i++)
        final_id[order[i]] = i;

    res->count = k1;
    res->clusters = cvre_calloc((size_t)k1 + 1, sizeof *res->clusters);
    if (!res->clusters)
        goto cleanup;
    for (uint32_t s = 0; s < n; s++) {
        int32_t l = -1;
        if (r->core[s] && final_id[comp[s]] != UINT32_MAX)
            l = (int32_t)final_id[comp[s]];
        labels_out[r->orig[s]] = l;
    }
    /* Border points: nearest core point of a surviving cluster. */
    for (size_t j = 0; j < r->nbord; j++) {
        uint32_t s = r->bord[j], len, best = UINT32_MAX;
        double bestd = INFINITY;
        const uint32_t *nb = neighbours(r, s, &len);
        for (uint32_t i = 0; i < len; i++) {
            uint32_t t = nb[i];
            if (!r->core[t] || final_id[comp[t]] == UINT32_MAX)
                continue;
            double d = dist2(r->pts + 3 * (size_t)s, r->pts + 3 * (size_t)t);
            if (d < bestd || (d == bestd && r->orig[t] < r->orig[best])) {
                bestd = d;
                best = t;
            }
        }
        if (best != UINT32_MAX)
            labels_out[r->orig[s]] = (int32_t)final_id[comp[best]];
    }
    /* Per-cluster figures, over input order so sums are reproducible. */
    {
        double *sum = cvre_calloc(3 * ((size_t)k1 + 1), sizeof *sum);
        if (!sum)
            goto cleanup;
        for (uint32_t i = 0; i < k1; i++) {
            res->clusters[i].users = ucount[order[i]];
            for (int a = 0; a < 3; a++) {
                res->clusters[i].min[a] = INFINITY;
                res->clusters[i].max[a] = -INFINITY;
            }
        }
        for (size_t i = 0; i < n; i++) {
            if (labels_out[i] < 0)
                continue;
            dbscan_cluster *c = &res->clusters[labels_out[i]];
            c->points++;
            for (int a = 0; a < 3; a++) {
                float v = xyz[3 * i + (size_t)a];
                sum[3 * (size_t)labels_out[i] + (size_t)a] += v;
                if (v < c->min[a])
                    c->min[a] = v;
                if (v > c->max[a])
                    c->max[a] = v;
            }
        }
        for (uint32_t i = 0; i < k1; i++)
            for (int a = 0; a < 3; a++)
                res->clusters[i].centroid[a] = (float)(sum[3 * (size_t)i + (size_t)a] / res->clusters[i].points);
        free(sum);
    }
    for (uint32_t s = 0; s < n; s++)
        res->core[r->orig[s]] = r->core[s];
    rc = 0;
cleanup:
    free(comp);
    free(cid);
    free(first);
    free(cnt);
    free(pair_user);
    free(table);
    free(stamp);
    free(ucount);
    free(order);
    free(final_id);
    free(tmp);
    return rc;
}

static void run_free(run *r)
{
    if (r->index)
        flann_free_index(r->index, &r->fp);
    free(r->pts);
    free(r->orig);
    free(r->cell_of);
    free(r->cell_start);
    free(r->cell_key);
    free(r->coarse_of);
    free(r->ckey);
    free(r->ccount);
    free(r->chas_core);
    free(r->core);
    free(r->cell_core);
    free(r->ask);
    free(r->bord);
    free(r->nb_off);
    free(r->nb_len);
    free(r->nb_owner);
    for (uint32_t t = 0; t < DBSCAN_MAX_THREADS; t++)
        free(r->bufs[t].v);
}

/* Checks parameters and points; fills the bounding box. Returns 0 or -EINVAL. */
static int validate(const float *xyz, size_t n, const dbscan_params *p, int32_t *labels_out, double lo[3],
                    double hi[3])
{
    if (!p || (n > 0 && (!xyz || !labels_out)) || n > DBSCAN_MAX_POINTS)
        return -EINVAL;
    if (!(p->eps > 1e-15 && p->eps < 1e15) || p->min_points < 1)
        return -EINVAL;
    for (int a = 0; a < 3; a++) {
        lo[a] = INFINITY;
        hi[a] = -INFINITY;
    }
    for (size_t i = 0; i < n; i++)
        for (int a = 0; a < 3; a++) {
            double v = xyz[3 * i + (size_t)a];
            if (!(fabs(v) <= DBSCAN_MAX_COORD)) /* also false for NaN */
                return -EINVAL;
            if (v < lo[a])
                lo[a] = v;
            if (v > hi[a])
                hi[a] = v;
        }
    return 0;
}

static uint32_t thread_count(const dbscan_params *p, size_t work)
{
    long t = p->threads;
    if (t == 0)
        t = sysconf(_SC_NPROCESSORS_ONLN);
    if (t < 1)
        t = 1;
    if (t > (long)DBSCAN_MAX_THREADS)
        t = DBSCAN_MAX_THREADS;
    size_t useful = work / MIN_POINTS_PER_THREAD + 1;
    if ((size_t)t > useful)
        t = (long)useful;
    return (uint32_t)t;
}

/* Builds the KD-tree over all points (grid order), once. Returns 0 or -EIO. */
static int build_index(run *r)
{
    if (r->index)
        return 0;
    r->fp = DEFAULT_FLANN_PARAMETERS;
    r->fp.algorithm = FLANN_INDEX_KDTREE_SINGLE;
    r->fp.leaf_max_size = FLANN_LEAF;
    r->fp.trees = 1;
    r->fp.checks = FLANN_CHECKS_UNLIMITED;
    r->fp.eps = 0.0f;
    r->fp.log_level = FLANN_LOG_NONE;
    /* Searches are threaded here, one point each: FLANN's default (0, all
     * cores) would start an OpenMP team per search, three times slower. */
    r->fp.cores = 1;
    r->radius2 = (float)(r->eps2 * (1.0 + SEARCH_SLACK));
    float speedup;
    r->index = flann_build_index(r->pts, (int)r->n, 3, &speedup, &r->fp);
    return r->index ? 0 : -EIO;
}

/* After the core flags: marks cells and coarse cells holding core points,
 * and lists the non-core points with a core point in their 27 coarse cells,
 * which are the only ones that can be border points. Returns 0 or -ENOMEM. */
static int find_border_candidates(run *r)
{
    r->cell_core = cvre_calloc(r->m, 1);
    r->bord = cvre_malloc(r->n * sizeof *r->bord);
    if (!r->cell_core || !r->bord)
        return -ENOMEM;
    for (uint32_t s = 0; s < r->n; s++)
        if (r->core[s]) {
            r->cell_core[r->cell_of[s]] = 1;
            r->chas_core[r->coarse_of[r->cell_of[s]]] = 1;
        }
    uint32_t *near = cvre_malloc(((size_t)r->mc + 1) * sizeof *near);
    if (!near)
        return -ENOMEM;
    coarse_scan(r, 1, near);
    for (uint32_t s = 0; s < r->n; s++)
        if (!r->core[s] && near[r->coarse_of[r->cell_of[s]]])
            r->bord[r->nbord++] = s;
    free(near);
    return 0;
}

int dbscan_run(const float *xyz, const uint32_t *users, size_t n, const dbscan_params *p, int32_t *labels_out,
               dbscan_result **out)
{
    double hi[3];
    run r;
    uint32_t *parent = NULL;
    dbscan_result *res = NULL;
    if (out)
        *out = NULL;
    memset(&r, 0, sizeof r);
    int rc = validate(xyz, n, p, labels_out, r.lo, hi);
    if (rc < 0)
        return rc;
    r.n = n;
    r.eps2 = p->eps * p->eps;
    r.min_points = p->min_points;
    atomic_init(&r.next_chunk, 0);
    atomic_init(&r.error, 0);
    rc = -ENOMEM;
    res = cvre_calloc(1, sizeof *res);
    if (!res)
        goto cleanup;
    res->n = n;
    res->core = cvre_calloc(n ? n : 1, 1);
    if (!res->core)
        goto cleanup;
    if (n == 0) {
        rc = 0;
        goto cleanup;
    }
    if ((rc = build_grid(&r, xyz, hi, p->eps)) < 0 || (rc = build_coarse(&r)) < 0 ||
        (rc = classify(&r)) < 0)
        goto cleanup;
    rc = -ENOMEM;
    r.nb_off = cvre_malloc(n * sizeof *r.nb_off);
    r.nb_len = cvre_calloc(n, sizeof *r.nb_len);
    r.nb_owner = cvre_calloc(n, 1);
    if (!r.nb_off || !r.nb_len || !r.nb_owner)
        goto cleanup;
    if (r.nask > 0) {
        if ((rc = build_index(&r)) < 0 || (rc = run_phase(&r, PHASE_CORE, thread_count(p, r.nask))) < 0)
            goto cleanup;
    }
    if ((rc = find_border_candidates(&r)) < 0)
        goto cleanup;
    if (r.nbord > 0 && r.use_grid) { /* without the grid, lists came with the core flags */
        if ((rc = build_index(&r)) < 0 || (rc = run_phase(&r, PHASE_BORDER, thread_count(p, r.nbord))) < 0)
            goto cleanup;
    }
    parent = cvre_malloc((r.use_grid ? (size_t)r.m : n) * sizeof *parent);
    if (!parent) {
        rc = -ENOMEM;
        goto cleanup;
    }
    connect(&r, parent);
    for (uint32_t t = 0; t < DBSCAN_MAX_THREADS; t++)
        res->searches += r.searches[t];
    rc = label(&r, parent, xyz, users, p->min_users, labels_out, res);
cleanup:
    free(parent);
    run_free(&r);
    if (rc < 0 || !out) {
        dbscan_result_free(res);
        res = NULL;
    }
    if (out)
        *out = res;
    return rc;
}

void dbscan_result_free(dbscan_result *r)
{
    if (!r)
        return;
    free(r->clusters);
    free(r->core);
    free(r);
}

size_t dbscan_result_count(const dbscan_result *r) { return r->count; }

const dbscan_cluster *dbscan_result_cluster(const dbscan_result *r, size_t i)
{
    return i < r->count ? &r->clusters[i] : NULL;
}

int dbscan_result_is_core(const dbscan_result *r, size_t i) { return i < r->n ? r->core[i] : 0; }

size_t dbscan_result_searches(const dbscan_result *r) { return r->searches; }
