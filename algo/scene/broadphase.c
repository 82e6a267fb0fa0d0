#include "broadphase.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"

/*
 * A multi-level uniform grid over x and z. A box lives in the finest level
 * where it covers at most BP_MAX_COPIES cells, and a copy of it (its AABB,
 * handle and first cell) sits in every cell it covers, so a query reads each
 * cell as a few sequential runs of memory and never chases a handle to its
 * box. Coarser levels hold the few large boxes, which would otherwise be
 * copied into hundreds of fine cells.
 *
 * Duplicates are removed without a hash set or stamps: a box that overlaps
 * the query is reported only by the first cell, in x and in z, of the cells
 * it shares with the query. That cell is max(box's first cell, query's first
 * cell) on each axis, so each copy records the first cell of its box.
 *
 * A cell's list is stored as planes (structure of arrays): cap values of
 * min x, then cap of max x, and so on, so that a query compares four boxes
 * per instruction. Slots past the list's end hold NaN coordinates, which
 * never overlap anything, so the last group of four needs no mask.
 *
 * All lists live in one array, in units of one box's worth of planes (32
 * bytes). A full list moves to the end of the array with twice the room,
 * leaving a hole. A list's holes add up to less than its room (1/2 + 1/4 +
 * ... of it), so the array is never more than twice the lists' room;
 * bp_optimize squeezes the holes out and puts the lists back in cell order.
 */

/* Most cells a box is copied into before it goes one level up. With 4 m
 * cells, 36 keeps a 10 m box (at most 4 x 4 cells) and a 30 m wall (9 x 2
 * when it straddles a cell edge) in the finest level. Too low a cap sends
 * ordinary boxes up to cells eight times wider, full of boxes that miss the
 * query: measured with 2 m cells in the dense bench world, a cap of 16 scans
 * 155 boxes per query, 36 scans 80. */
#ifndef BP_MAX_COPIES
#define BP_MAX_COPIES 36u
#endif
/* Each level's cells are this many times wider than the one below: with 8,
 * a box goes up only when it is much larger than the cells, and a 1 km world
 * with 4 m cells has three levels (4, 32 and 256 m). */
#ifndef BP_LEVEL_RATIO
#define BP_LEVEL_RATIO 8u
#endif
/* Enough levels for 65,535 cells per axis at ratio 8 (8^6 > 65,535); with a
 * smaller ratio the last level simply takes every box too big for the rest. */
#define BP_MAX_LEVELS 8u
/* Boxes compared per instruction: four floats fill the 16-byte vectors that
 * every x86-64 and AArch64 CPU has. A list's room is a multiple of it. */
#define BP_LANES 4u
/* Room a list gets when its cell receives its first box. */
#define BP_CELL_INITIAL BP_LANES

_Static_assert(BP_MAX_COPIES >= 4, "a small box may straddle a cell corner");
_Static_assert(BP_LEVEL_RATIO >= 2, "levels must grow");
_Static_assert(BP_MAX_HANDLE <= UINT32_MAX, "handles are uint32");
_Static_assert(BP_CELL_INITIAL % BP_LANES == 0, "room in whole groups");

typedef float v4f __attribute__((vector_size(16)));
typedef int32_t v4i __attribute__((vector_size(16)));

/* The planes of a list, in order. */
enum { P_MINX, P_MAXX, P_MINZ, P_MAXZ, P_MINY, P_MAXY, P_HANDLE, P_CELL, NPLANES };
#define SLOT_BYTES (NPLANES * 4u)

typedef struct cell {
    uint32_t off; /* first slot in bp.arena */
    uint32_t n;   /* boxes in the list */
    uint32_t cap; /* room, a multiple of BP_LANES */
} cell;

typedef struct level {
    float inv; /* 1 / cell side */
    uint32_t nx, nz;
    uint32_t boxes; /* boxes living here; empty levels are skipped */
    cell *cells;    /* nx * nz, row-major in z */
} level;

typedef struct entry {
    float min[3], max[3];
    uint8_t level;
    uint8_t present;
} entry;

_Static_assert(sizeof(entry) == 28, "broadphase.h's BP_MAX_HANDLE comment");

struct bp {
    float ox, oz; /* world min x, z */
    uint32_t nlevels;
    level levels[BP_MAX_LEVELS];
    unsigned char *arena;       /* the lists, SLOT_BYTES per slot */
    uint32_t used, room;        /* slots taken (lists and holes), allocated */
    entry *entries;             /* by handle */
    uint32_t nentries;
    uint32_t count;
};

bp *bp_create(const float world_min[3], const float world_max[3], float cell_side)
{
    if (cell_side == 0)
        cell_side = BP_CELL_DEFAULT;
    for (int a = 0; a < 3; a++)
        if (!isfinite(world_min[a]) || !isfinite(world_max[a]) || !(world_max[a] > world_min[a]))
            return NULL;
    if (!(cell_side > 0) || !isfinite(cell_side))
        return NULL;
    double wx = (double)world_max[0] - world_min[0], wz = (double)world_max[2] - world_min[2];
    if (ceil(wx / cell_side) > 65535 || ceil(wz / cell_side) > 65535)
        return NULL;
    bp *b = cvre_calloc(1, sizeof *b);
    if (!b)
        return NULL;
    b->ox = world_min[0];
    b->oz = world_min[2];
    double side = cell_side;
    for (;;) {
        level *lv = &b->levels[b->nlevels++];
        double fx = ceil(wx / side), fz = ceil(wz / side);
        lv->nx = fx < 1 ? 1 : (uint32_t)fx;
        lv->nz = fz < 1 ? 1 : (uint32_t)fz;
        lv->inv = (float)(1.0 / side);
        lv->cells = cvre_calloc((size_t)lv->nx * lv->nz, sizeof *lv->cells);
        if (!lv->cells) {
            bp_destroy(b);
            return NULL;
        }
        /* The top level takes every box that is too big for the others. */
        if ((uint64_t)lv->nx * lv->nz <= BP_MAX_COPIES || b->nlevels == BP_MAX_LEVELS)
            break;
        side *= BP_LEVEL_RATIO;
    }
    return b;
}

void bp_destroy(bp *b)
{
    if (!b)
        return;
    for (uint32_t l = 0; l < b->nlevels; l++)
        free(b->levels[l].cells);
    free(b->arena);
    free(b->entries);
    free(b);
}

uint32_t bp_count(const bp *b) { return b->count; }

/* Column (or row) of a coordinate at a level, clamped into the grid; NaN
 * gives 0. Monotonic, which is all the queries' exactness relies on. */
static inline uint32_t coord(float v, float origin, float inv, uint32_t n)
{
    float f = (v - origin) * inv;
    if (!(f > 0))
        return 0;
    return f >= (float)n ? n - 1 : (uint32_t)f;
}

typedef struct span {
    uint32_t x0, x1, z0, z1;
} span;

static inline span span_at(const bp *b, const level *lv, const float min[3], const float max[3])
{
    span s;
    s.x0 = coord(min[0], b->ox, lv->inv, lv->nx);
    s.x1 = coord(max[0], b->ox, lv->inv, lv->nx);
    s.z0 = coord(min[2], b->oz, lv->inv, lv->nz);
    s.z1 = coord(max[2], b->oz, lv->inv, lv->nz);
    return s;
}

/* The finest level where the box covers at most BP_MAX_COPIES cells. */
static uint32_t level_for(const bp *b, const float min[3], const float max[3])
{
    uint32_t l = 0;
    for (; l + 1 < b->nlevels; l++) {
        span s = span_at(b, &b->levels[l], min, max);
        if ((uint64_t)(s.x1 - s.x0 + 1) * (s.z1 - s.z0 + 1) <= BP_MAX_COPIES)
            break;
    }
    return l;
}

/* Plane p of a list whose slots start at off and which has room cap. */
static inline float *fplane(unsigned char *arena, uint32_t off, uint32_t cap, int p)
{
    return (float *)(void *)(arena + (size_t)off * SLOT_BYTES + (size_t)p * cap * 4u);
}

static inline uint32_t *uplane(unsigned char *arena, uint32_t off, uint32_t cap, int p)
{
    return (uint32_t *)(void *)(arena + (size_t)off * SLOT_BYTES + (size_t)p * cap * 4u);
}

/* Makes slots from..to-1 of a list empty: NaN never overlaps anything. */
static void clear_slots(unsigned char *arena, uint32_t off, uint32_t cap, uint32_t from, uint32_t to)
{
    for (int p = P_MINX; p <= P_MAXY; p++) {
        float *f = fplane(arena, off, cap, p);
        for (uint32_t k = from; k < to; k++)
            f[k] = NAN;
    }
    for (int p = P_HANDLE; p < NPLANES; p++)
        memset(uplane(arena, off, cap, p) + from, 0, (size_t)(to - from) * 4u);
}

/* Copies the n boxes of a list into another list (another room, or another
 * array) and empties the rest of the new room. */
static void copy_list(unsigned char *dst, uint32_t doff, uint32_t dcap, unsigned char *src, uint32_t soff,
                      uint32_t scap, uint32_t n)
{
    for (int p = 0; p < NPLANES; p++)
        memcpy(uplane(dst, doff, dcap, p), uplane(src, soff, scap, p), (size_t)n * 4u);
    clear_slots(dst, doff, dcap, n, dcap);
}

/* Makes room for want more slots at the end of the array. */
static int reserve(bp *b, uint32_t want)
{
    if (want <= b->room - b->used)
        return 0;
    uint64_t need = (uint64_t)b->used + want;
    uint64_t room = b->room ? (uint64_t)b->room * 2 : 1024;
    while (room < need)
        room *= 2;
    if (room > UINT32_MAX / SLOT_BYTES)
        room = UINT32_MAX / SLOT_BYTES;
    if (need > room)
        return -ENOMEM;
    unsigned char *arena = cvre_realloc(b->arena, (size_t)room * SLOT_BYTES);
    if (!arena)
        return -ENOMEM;
    b->arena = arena;
    b->room = (uint32_t)room;
    return 0;
}

typedef struct item {
    float min[3], max[3];
    uint32_t handle;
    uint32_t first; /* first cell of the box at its level: x | z << 16 */
} item;

/* Appends it to the list of cell c, moving the list to the end of the array
 * with twice the room when it is full. */
static int push(bp *b, cell *c, const item *it)
{
    if (c->n == c->cap) {
        uint32_t cap = c->cap ? c->cap * 2 : BP_CELL_INITIAL;
        int rc = reserve(b, cap);
        if (rc < 0)
            return rc;
        copy_list(b->arena, b->used, cap, b->arena, c->off, c->cap, c->n);
        c->off = b->used;
        c->cap = cap;
        b->used += cap;
    }
    uint32_t k = c->n++;
    fplane(b->arena, c->off, c->cap, P_MINX)[k] = it->min[0];
    fplane(b->arena, c->off, c->cap, P_MAXX)[k] = it->max[0];
    fplane(b->arena, c->off, c->cap, P_MINZ)[k] = it->min[2];
    fplane(b->arena, c->off, c->cap, P_MAXZ)[k] = it->max[2];
    fplane(b->arena, c->off, c->cap, P_MINY)[k] = it->min[1];
    fplane(b->arena, c->off, c->cap, P_MAXY)[k] = it->max[1];
    uplane(b->arena, c->off, c->cap, P_HANDLE)[k] = it->handle;
    uplane(b->arena, c->off, c->cap, P_CELL)[k] = it->first;
    return 0;
}

/* Removes the copy at slot k of cell c: the last box of the list takes its place. */
static void drop(bp *b, cell *c, uint32_t k)
{
    uint32_t last = --c->n;
    for (int p = 0; p < NPLANES; p++) {
        uint32_t *u = uplane(b->arena, c->off, c->cap, p);
        u[k] = u[last];
    }
    clear_slots(b->arena, c->off, c->cap, last, last + 1);
}

/* Removes handle's copy from cell c. */
static void pull(bp *b, cell *c, uint32_t handle)
{
    const uint32_t *h = uplane(b->arena, c->off, c->cap, P_HANDLE);
    for (uint32_t k = 0; k < c->n; k++) {
        if (h[k] == handle) {
            drop(b, c, k);
            return;
        }
    }
}

/* Copies the box into every cell it covers at its level. On -ENOMEM the
 * copies already made are taken back (each is the last of its list). */
static int place(bp *b, const entry *e, uint32_t handle)
{
    level *lv = &b->levels[e->level];
    span s = span_at(b, lv, e->min, e->max);
    item it;
    memcpy(it.min, e->min, sizeof it.min);
    memcpy(it.max, e->max, sizeof it.max);
    it.handle = handle;
    it.first = s.x0 | s.z0 << 16;
    for (uint32_t z = s.z0; z <= s.z1; z++) {
        for (uint32_t x = s.x0; x <= s.x1; x++) {
            int rc = push(b, &lv->cells[z * lv->nx + x], &it);
            if (rc < 0) {
                for (uint32_t uz = s.z0; uz <= z; uz++)
                    for (uint32_t ux = s.x0; ux <= s.x1 && (uz < z || ux < x); ux++) {
                        cell *c = &lv->cells[uz * lv->nx + ux];
                        drop(b, c, c->n - 1);
                    }
                return rc;
            }
        }
    }
    lv->boxes++;
    return 0;
}

static void unplace(bp *b, const entry *e, uint32_t handle)
{
    level *lv = &b->levels[e->level];
    span s = span_at(b, lv, e->min, e->max);
    for (uint32_t z = s.z0; z <= s.z1; z++)
        for (uint32_t x = s.x0; x <= s.x1; x++)
            pull(b, &lv->cells[z * lv->nx + x], handle);
    lv->boxes--;
}

static int valid_box(const float min[3], const float max[3])
{
    for (int a = 0; a < 3; a++)
        if (!isfinite(min[a]) || !isfinite(max[a]) || min[a] > max[a])
            return 0;
    return 1;
}

/* Grows the handle table to cover handle. */
static int reserve_entries(bp *b, uint32_t handle)
{
    if (handle < b->nentries)
        return 0;
    uint64_t n = b->nentries ? b->nentries : 1024;
    while (n <= handle)
        n *= 2;
    if (n > BP_MAX_HANDLE)
        n = BP_MAX_HANDLE;
    entry *e = cvre_realloc(b->entries, (size_t)n * sizeof *e);
    if (!e)
        return -ENOMEM;
    memset(e + b->nentries, 0, (size_t)(n - b->nentries) * sizeof *e);
    b->entries = e;
    b->nentries = (uint32_t)n;
    return 0;
}

int bp_insert(bp *b, const float min[3], const float max[3], uint32_t handle)
{
    if (handle >= BP_MAX_HANDLE || !valid_box(min, max))
        return -EINVAL;
    int rc = reserve_entries(b, handle);
    if (rc < 0)
        return rc;
    entry *e = &b->entries[handle];
    if (e->present)
        return -EEXIST;
    entry ne = {0};
    memcpy(ne.min, min, sizeof ne.min);
    memcpy(ne.max, max, sizeof ne.max);
    ne.level = (uint8_t)level_for(b, min, max);
    ne.present = 1;
    rc = place(b, &ne, handle);
    if (rc < 0)
        return rc;
    *e = ne;
    b->count++;
    return 0;
}

int bp_remove(bp *b, uint32_t handle)
{
    if (handle >= b->nentries || !b->entries[handle].present)
        return -ENOENT;
    entry *e = &b->entries[handle];
    unplace(b, e, handle);
    e->present = 0;
    b->count--;
    return 0;
}

int bp_update(bp *b, const float min[3], const float max[3], uint32_t handle)
{
    if (handle >= b->nentries || !b->entries[handle].present)
        return -ENOENT;
    if (!valid_box(min, max))
        return -EINVAL;
    entry old = b->entries[handle];
    (void)bp_remove(b, handle);
    int rc = bp_insert(b, min, max, handle);
    if (rc < 0) {
        /* Cannot fail: the old copies' cells lost one box each, and a
         * failed insert never shrinks a list's room. */
        (void)place(b, &old, handle);
        b->entries[handle] = old;
        b->count++;
    }
    return rc;
}

/* Room for a list of n boxes after compaction: a quarter more, so that a few
 * inserts stay in place, in whole groups of lanes. */
static uint32_t room_for(uint32_t n)
{
    if (!n)
        return 0;
    uint64_t r = (uint64_t)n + n / 4 + 1;
    r = (r + BP_LANES - 1) / BP_LANES * BP_LANES;
    return r > UINT32_MAX ? UINT32_MAX : (uint32_t)r;
}

int bp_optimize(bp *b)
{
    uint64_t total = 0;
    for (uint32_t l = 0; l < b->nlevels; l++) {
        const level *lv = &b->levels[l];
        for (size_t ci = 0; ci < (size_t)lv->nx * lv->nz; ci++)
            total += room_for(lv->cells[ci].n);
    }
    if (total > UINT32_MAX / SLOT_BYTES)
        return -ENOMEM;
    unsigned char *arena = cvre_malloc((size_t)(total ? total : 1) * SLOT_BYTES);
    if (!arena)
        return -ENOMEM;
    uint32_t at = 0;
    for (uint32_t l = 0; l < b->nlevels; l++) {
        level *lv = &b->levels[l];
        for (size_t ci = 0; ci < (size_t)lv->nx * lv->nz; ci++) {
            cell *c = &lv->cells[ci];
            uint32_t cap = room_for(c->n);
            if (cap)
                copy_list(arena, at, cap, b->arena, c->off, c->cap, c->n);
            c->off = at;
            c->cap = cap;
            at += cap;
        }
    }
    free(b->arena);
    b->arena = arena;
    b->used = b->room = at;
    return 0;
}

/* A query, each bound in all four lanes. */
typedef struct qbox {
    v4f min[3], max[3];
} qbox;

static inline v4f load4(const float *p)
{
    v4f v;
    memcpy(&v, p, sizeof v);
    return v;
}

static inline v4i load4i(const uint32_t *p)
{
    v4i v;
    memcpy(&v, p, sizeof v);
    return v;
}

/* Appends to out the handles of the boxes of cell (x, z) of a level that
 * overlap q and that this cell reports (see the top of the file). */
static inline uint32_t scan_cell(const bp *b, const cell *c, const qbox *q, uint32_t x, uint32_t z, const span *s,
                                 uint32_t *out, uint32_t out_max, uint32_t n)
{
    unsigned char *arena = b->arena;
    const float *minx = fplane(arena, c->off, c->cap, P_MINX), *maxx = fplane(arena, c->off, c->cap, P_MAXX);
    const float *minz = fplane(arena, c->off, c->cap, P_MINZ), *maxz = fplane(arena, c->off, c->cap, P_MAXZ);
    const float *miny = fplane(arena, c->off, c->cap, P_MINY), *maxy = fplane(arena, c->off, c->cap, P_MAXY);
    const uint32_t *handle = uplane(arena, c->off, c->cap, P_HANDLE);
    const uint32_t *first = uplane(arena, c->off, c->cap, P_CELL);
    /* Every box here is reported here when this is the query's first cell
     * on both axes, the common case; otherwise compare first cells. */
    int check = x != s->x0 || z != s->z0;
    v4i here = {0, 0, 0, 0};
    here += (int32_t)(x | z << 16);
    v4i mask = {0, 0, 0, 0};
    mask += (int32_t)((x != s->x0 ? 0xffffu : 0u) | (z != s->z0 ? 0xffff0000u : 0u));
    for (uint32_t k = 0; k < c->n; k += BP_LANES) {
        v4i hit = (load4(minx + k) <= q->max[0]) & (load4(maxx + k) >= q->min[0]) & (load4(minz + k) <= q->max[2]) &
                  (load4(maxz + k) >= q->min[2]) & (load4(miny + k) <= q->max[1]) & (load4(maxy + k) >= q->min[1]);
        if (check)
            hit &= ((load4i(first + k) ^ here) & mask) == 0;
        uint64_t any[2];
        memcpy(any, &hit, sizeof any);
        if (!(any[0] | any[1]))
            continue;
        for (uint32_t lane = 0; lane < BP_LANES; lane++) {
            if (n < out_max)
                out[n] = handle[k + lane];
            n += (uint32_t)hit[lane] & 1u;
        }
    }
    return n;
}

static uint32_t query(const bp *b, const float min[3], const float max[3], uint32_t *out, uint32_t out_max,
                      uint32_t n)
{
    qbox q;
    for (int a = 0; a < 3; a++) {
        q.min[a] = (v4f){0, 0, 0, 0} + min[a];
        q.max[a] = (v4f){0, 0, 0, 0} + max[a];
    }
    for (uint32_t l = 0; l < b->nlevels; l++) {
        const level *lv = &b->levels[l];
        if (!lv->boxes)
            continue;
        span s = span_at(b, lv, min, max);
        for (uint32_t z = s.z0; z <= s.z1; z++) {
            const cell *row = lv->cells + (size_t)z * lv->nx;
            for (uint32_t x = s.x0; x <= s.x1; x++)
                n = scan_cell(b, &row[x], &q, x, z, &s, out, out_max, n);
        }
    }
    return n;
}

uint32_t bp_query(const bp *b, const float min[3], const float max[3], uint32_t *out, uint32_t out_max)
{
    return query(b, min, max, out, out_max, 0);
}

/* How many queries ahead bp_query_batch asks for the cell headers, and then
 * for the cells' lists: a cell costs two dependent cache misses (header,
 * then list) that a lone query can only wait for. Measured with the bench:
 * anything from 4/2 to 24/12 does the same, 2/1 is 10-20% slower. */
#ifndef BP_AHEAD_CELLS
#define BP_AHEAD_CELLS 8u
#endif
#ifndef BP_AHEAD_LISTS
#define BP_AHEAD_LISTS 4u
#endif
/* A list up to this size is fetched whole; a larger one by the first line
 * of each plane, and the hardware streams the rest. */
#define BP_AHEAD_BYTES 512u

static void prefetch_cells(const bp *b, const bp_box *q)
{
    for (uint32_t l = 0; l < b->nlevels; l++) {
        const level *lv = &b->levels[l];
        if (!lv->boxes)
            continue;
        span s = span_at(b, lv, q->min, q->max);
        for (uint32_t z = s.z0; z <= s.z1; z++) {
            __builtin_prefetch(lv->cells + (size_t)z * lv->nx + s.x0);
            __builtin_prefetch(lv->cells + (size_t)z * lv->nx + s.x1);
        }
    }
}

static void prefetch_lists(const bp *b, const bp_box *q)
{
    for (uint32_t l = 0; l < b->nlevels; l++) {
        const level *lv = &b->levels[l];
        if (!lv->boxes)
            continue;
        span s = span_at(b, lv, q->min, q->max);
        for (uint32_t z = s.z0; z <= s.z1; z++) {
            const cell *row = lv->cells + (size_t)z * lv->nx;
            for (uint32_t x = s.x0; x <= s.x1; x++) {
                const unsigned char *p = b->arena + (size_t)row[x].off * SLOT_BYTES;
                size_t bytes = (size_t)row[x].cap * SLOT_BYTES, step = 64;
                if (bytes > BP_AHEAD_BYTES)
                    step = bytes / NPLANES;
                for (size_t at = 0; at < bytes && at < (size_t)NPLANES * step; at += step)
                    __builtin_prefetch(p + at);
            }
        }
    }
}

uint32_t bp_query_batch(const bp *b, const bp_box *q, uint32_t nq, uint32_t *out, uint32_t out_max,
                        uint32_t *off)
{
    uint32_t n = 0;
    for (uint32_t i = 0; i < nq; i++) {
        if (i + BP_AHEAD_CELLS < nq)
            prefetch_cells(b, &q[i + BP_AHEAD_CELLS]);
        if (i + BP_AHEAD_LISTS < nq)
            prefetch_lists(b, &q[i + BP_AHEAD_LISTS]);
        off[i] = n < out_max ? n : out_max;
        n = query(b, q[i].min, q[i].max, out, out_max, n);
    }
    off[nq] = n < out_max ? n : out_max;
    return n;
}
