/*
 * refine.c: one refinement round; the steps are described in refine.h.
 *
 * Everything inside a problem box works on cell indices: a box of cells is
 * [lo, hi) per axis. Counts over any such box (occupied cells, wanted cells)
 * come from summed-volume tables in O(1), so shrinking a node, testing a
 * merge or pricing a pair never walks cells.
 */
#include "refine.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "alloc.h"
#include "avatar.h"
#include "err.h"

_Static_assert(ECM_DEPTH_MIN >= VOXEL_DEPTH_MIN && ECM_DEPTH_MAX <= VOXEL_DEPTH_MAX, "depths the voxelizer takes");
/* Cell indices, and one past the last, fit 16 bits. */
_Static_assert(ECM_DEPTH_MAX <= 15, "cell indices are uint16_t");
/* Counts of a whole grid fit a summed-volume table's uint32_t. */
_Static_assert(3 * ECM_DEPTH_MAX < 32, "cell counts fit uint32_t");

/* Boxes a division may hold beyond the budget before merging brings it
 * back (see divide): parts that merging joins again cost nothing in the
 * end. More slack spends the whole budget in the first round and leaves
 * later rounds nothing to divide with, and merging costs grow with the
 * square of the boxes held. */
#define DIVIDE_SLACK 8u
/* Most cells of the padded array one cluster's wanted space is worked out
 * in: 256^3, an avatar as long as half the grid on each axis (2 MiB of
 * bits). */
#define WANTED_CELLS_MAX ((size_t)16 << 20)

/* A box of cells: [lo, hi) on each axis. */
typedef struct ibox {
    uint16_t lo[3], hi[3];
} ibox;

typedef struct ilist {
    ibox *b;
    uint32_t n, cap;
} ilist;

/* Summed-volume table over an n^3 grid: t[x + m (y + m z)], m = n + 1, holds
 * the count over cells [0, x) x [0, y) x [0, z). */
typedef struct svt {
    uint32_t *t;
    uint32_t m;
} svt;

/* One problem box being refined. */
typedef struct work {
    voxel_grid g;
    uint32_t n;
    svt occ, want;   /* their tables: one block, tables */
    uint32_t *tables;
    uint8_t *wanted; /* n^3: 1 for a wanted cell */
    ilist out;       /* its boxes so far: no more division for them */
    double max_empty;
    uint32_t budget; /* most boxes it may become */
    uint32_t capped; /* boxes of out that still hold wanted cells */
} work;

void ecm_params_default(ecm_params *p)
{
    *p = (ecm_params){.depth = ECM_DEPTH_DEFAULT,
                      .max_boxes = ECM_MAX_BOXES_DEFAULT,
                      .max_empty = ECM_MAX_EMPTY_DEFAULT,
                      .avatar = {AVATAR_WIDTH, AVATAR_HEIGHT, AVATAR_WIDTH}};
}

void ecm_result_free(ecm_result *r)
{
    free(r->boxes);
    memset(r, 0, sizeof *r);
}

static double ms_since(const struct timespec *t0)
{
    struct timespec t1;
    clock_gettime(CLOCK_MONOTONIC, &t1);
    return (double)(t1.tv_sec - t0->tv_sec) * 1e3 + (double)(t1.tv_nsec - t0->tv_nsec) / 1e6;
}

static uint64_t volume(const ibox *b)
{
    return (uint64_t)(b->hi[0] - b->lo[0]) * (uint64_t)(b->hi[1] - b->lo[1]) * (uint64_t)(b->hi[2] - b->lo[2]);
}

static ibox hull(const ibox *a, const ibox *b)
{
    ibox h;
    for (int k = 0; k < 3; k++) {
        h.lo[k] = a->lo[k] < b->lo[k] ? a->lo[k] : b->lo[k];
        h.hi[k] = a->hi[k] > b->hi[k] ? a->hi[k] : b->hi[k];
    }
    return h;
}

static int push(ilist *l, const ibox *b)
{
    if (l->n == l->cap) {
        uint32_t cap = l->cap ? l->cap * 2 : 64;
        ibox *nb = cvre_realloc(l->b, cap * sizeof *nb);
        if (!nb)
            return -ENOMEM;
        l->b = nb;
        l->cap = cap;
    }
    l->b[l->n++] = *b;
    return 0;
}

/* Builds in t ((n + 1)^3 entries) the table of a 0/1 function of the
 * cell, given as a byte array (bytes != NULL) or the grid's bits. One pass: each entry is its row's
 * prefix sum plus the entries below it in y and in z, less the one below
 * both (the previous row and plane are still in cache). */
static void svt_build(svt *s, uint32_t *t, const voxel_grid *g, const uint8_t *bytes)
{
    uint32_t n = g->n, m = n + 1;
    size_t plane = (size_t)m * m;
    s->m = m;
    s->t = t;
    memset(s->t, 0, plane * sizeof *s->t);
    for (uint32_t z = 0; z < n; z++) {
        uint32_t *p = s->t + plane * (z + 1);
        memset(p, 0, m * sizeof *p);
        for (uint32_t y = 0; y < n; y++) {
            uint32_t *row = p + (size_t)m * (y + 1), *below_y = row - m, *below_z = row - plane,
                     *below_yz = below_z - m;
            uint32_t acc = 0;
            row[0] = 0;
            for (uint32_t x = 1; x <= n; x++) {
                acc += bytes ? bytes[(x - 1) + (size_t)n * (y + (size_t)n * z)] : (uint32_t)voxel_get(g, x - 1, y, z);
                row[x] = acc + below_y[x] + below_z[x] - below_yz[x];
            }
        }
    }
}

static uint32_t svt_sum(const svt *s, const ibox *b)
{
    size_t m = s->m;
#define T(x, y, z) s->t[(size_t)(x) + m * ((size_t)(y) + m * (size_t)(z))]
    int64_t v = (int64_t)T(b->hi[0], b->hi[1], b->hi[2]) - T(b->lo[0], b->hi[1], b->hi[2]) -
                T(b->hi[0], b->lo[1], b->hi[2]) - T(b->hi[0], b->hi[1], b->lo[2]) + T(b->lo[0], b->lo[1], b->hi[2]) +
                T(b->lo[0], b->hi[1], b->lo[2]) + T(b->hi[0], b->lo[1], b->lo[2]) - T(b->lo[0], b->lo[1], b->lo[2]);
#undef T
    return (uint32_t)v;
}

/* Shrinks b to the bounding box of its occupied cells; 0 if it has none. */
static int shrink(const svt *occ, ibox *b)
{
    if (svt_sum(occ, b) == 0)
        return 0;
    for (int a = 0; a < 3; a++) {
        /* Smallest hi with cells [lo, hi) occupied somewhere, then largest lo. */
        uint16_t lo = b->lo[a], hi = b->hi[a];
        ibox t = *b;
        uint16_t l = (uint16_t)(lo + 1), h = hi;
        while (l < h) {
            uint16_t mid = (uint16_t)((l + h) / 2);
            t.hi[a] = mid;
            if (svt_sum(occ, &t) > 0)
                h = mid;
            else
                l = (uint16_t)(mid + 1);
        }
        uint16_t first = (uint16_t)(l - 1); /* the first occupied layer */
        t = *b;
        l = lo;
        h = (uint16_t)(hi - 1);
        while (l < h) {
            uint16_t mid = (uint16_t)((l + h + 1) / 2);
            t.lo[a] = mid;
            if (svt_sum(occ, &t) > 0)
                l = mid;
            else
                h = (uint16_t)(mid - 1);
        }
        b->lo[a] = first;
        b->hi[a] = (uint16_t)(l + 1);
    }
    return 1;
}

/* The price of merging a and b: wanted cells the hull adds, then empty cells
 * it adds (the boxes are disjoint cell sets, or nearly: see merge_all). */
typedef struct price {
    uint64_t wanted, empty, vol;
} price;

static price price_of(const work *w, const ibox *a, const ibox *b)
{
    ibox h = hull(a, b);
    price p;
    p.vol = volume(&h);
    uint64_t empty_h = p.vol - svt_sum(&w->occ, &h);
    uint64_t empty_ab = (volume(a) - svt_sum(&w->occ, a)) + (volume(b) - svt_sum(&w->occ, b));
    p.empty = empty_h > empty_ab ? empty_h - empty_ab : 0;
    uint64_t want_h = svt_sum(&w->want, &h), want_ab = svt_sum(&w->want, a) + svt_sum(&w->want, b);
    p.wanted = want_h > want_ab ? want_h - want_ab : 0;
    return p;
}

static int cheaper(const price *a, const price *b)
{
    if (a->wanted != b->wanted)
        return a->wanted < b->wanted;
    return a->empty < b->empty;
}

/* A merge step 4 allows: no wanted cell, little new empty space. */
static int allowed(const work *w, const price *p)
{
    return p->wanted == 0 && (double)p->empty <= w->max_empty * (double)p->vol;
}

/* Per box: its cheapest partner (ties: the lowest index) and the price. */
typedef struct partner {
    uint32_t j;
    price p;
    int has;
} partner;

static void find_best(const work *w, const ilist *l, uint32_t i, int any, partner *out)
{
    out->has = 0;
    for (uint32_t j = 0; j < l->n; j++) {
        if (j == i)
            continue;
        price p = price_of(w, &l->b[i], &l->b[j]);
        if ((any || allowed(w, &p)) && (!out->has || cheaper(&p, &out->p))) {
            out->has = 1;
            out->j = j;
            out->p = p;
        }
    }
}

/*
 * Merges the cheapest pair of w->out, again and again: with keep 0, any pair
 * step 4 allows, while there is one; else (the cap) any pair at all, while
 * there are more than keep boxes. Each box remembers its cheapest partner;
 * a merge looks again only for the boxes that pointed at one of the pair.
 * Returns 0 or -ENOMEM.
 */
static int merge_all(work *w, uint32_t keep)
{
    ilist *l = &w->out;
    int any = keep > 0;
    if (l->n < 2 || (any && l->n <= keep))
        return 0;
    partner *bs = cvre_malloc(l->n * sizeof *bs);
    if (!bs)
        return -ENOMEM;
    for (uint32_t i = 0; i < l->n; i++)
        find_best(w, l, i, any, &bs[i]);
    while (!any || l->n > keep) {
        uint32_t bi = UINT32_MAX;
        for (uint32_t k = 0; k < l->n; k++)
            if (bs[k].has && (bi == UINT32_MAX || cheaper(&bs[k].p, &bs[bi].p)))
                bi = k;
        if (bi == UINT32_MAX)
            break;
        uint32_t i = bi < bs[bi].j ? bi : bs[bi].j, j = bi < bs[bi].j ? bs[bi].j : bi, last = l->n - 1;
        l->b[i] = hull(&l->b[i], &l->b[j]);
        /* Who pointed at one of the pair must look again (has = 2); j
         * leaves, and the last box takes its place. */
        for (uint32_t k = 0; k < l->n; k++) {
            int stale = bs[k].has && (bs[k].j == i || bs[k].j == j);
            if (bs[k].has && bs[k].j == last)
                bs[k].j = j;
            if (stale)
                bs[k].has = 2;
        }
        l->b[j] = l->b[last];
        bs[j] = bs[last];
        l->n--;
        for (uint32_t k = 0; k < l->n; k++) {
            if (k == i)
                continue;
            if (bs[k].has == 2) {
                find_best(w, l, k, any, &bs[k]);
                continue;
            }
            price p = price_of(w, &l->b[k], &l->b[i]);
            if ((any || allowed(w, &p)) && (!bs[k].has || cheaper(&p, &bs[k].p)))
                bs[k] = (partner){.j = i, .p = p, .has = 1};
        }
        find_best(w, l, i, any, &bs[i]);
    }
    free(bs);
    return 0;
}

/* A node waiting for division: the most wanted cells first, then the
 * oldest (so the order, and the result, never depend on anything else). */
typedef struct node {
    ibox b;
    uint32_t wanted;
    uint32_t seq;
} node;

static int node_before(const node *a, const node *b)
{
    return a->wanted != b->wanted ? a->wanted > b->wanted : a->seq < b->seq;
}

typedef struct heap {
    node *v;
    uint32_t n, cap, seq;
} heap;

static int heap_push(heap *h, const ibox *b, uint32_t wanted)
{
    if (h->n == h->cap) {
        uint32_t cap = h->cap ? h->cap * 2 : 64;
        node *v = cvre_realloc(h->v, cap * sizeof *v);
        if (!v)
            return -ENOMEM;
        h->v = v;
        h->cap = cap;
    }
    uint32_t i = h->n++;
    h->v[i] = (node){.b = *b, .wanted = wanted, .seq = h->seq++};
    while (i && node_before(&h->v[i], &h->v[(i - 1) / 2])) {
        node t = h->v[i];
        h->v[i] = h->v[(i - 1) / 2];
        h->v[(i - 1) / 2] = t;
        i = (i - 1) / 2;
    }
    return 0;
}

static node heap_pop(heap *h)
{
    node top = h->v[0];
    h->v[0] = h->v[--h->n];
    for (uint32_t i = 0;;) {
        uint32_t l = 2 * i + 1, r = l + 1, m = i;
        if (l < h->n && node_before(&h->v[l], &h->v[m]))
            m = l;
        if (r < h->n && node_before(&h->v[r], &h->v[m]))
            m = r;
        if (m == i)
            break;
        node t = h->v[i];
        h->v[i] = h->v[m];
        h->v[m] = t;
        i = m;
    }
    return top;
}

/* Files a shrunk, non-empty box: done if it holds no wanted cell, else
 * waiting for division. */
static int file_node(work *w, heap *h, const ibox *b)
{
    uint32_t wanted = svt_sum(&w->want, b);
    return wanted ? heap_push(h, b, wanted) : push(&w->out, b);
}

/*
 * Cuts b in two (step 3) and shrinks the parts to their occupied cells;
 * returns how many are not empty (their boxes in ch). The plane: a face of
 * the bounding box of b's wanted cells, the one that cuts off the largest
 * slab without wanted cells (a doorway in a wall: the wall on one side,
 * then on the other, and what is left shrinks to the lintel: three boxes);
 * when the wanted cells reach every face of b (it always holds some), the
 * middle of b's longest side.
 */
static int cut(const work *w, const ibox *b, ibox ch[2])
{
    ibox want = *b;
    shrink(&w->want, &want);
    int axis = -1;
    uint16_t at = 0;
    uint64_t best = 0;
    for (int a = 0; a < 3; a++) {
        uint64_t area = volume(b) / (uint64_t)(b->hi[a] - b->lo[a]);
        uint64_t below = (uint64_t)(want.lo[a] - b->lo[a]) * area, above = (uint64_t)(b->hi[a] - want.hi[a]) * area;
        if (below > best) {
            best = below;
            axis = a;
            at = want.lo[a];
        }
        if (above > best) {
            best = above;
            axis = a;
            at = want.hi[a];
        }
    }
    if (axis < 0) {
        axis = 0;
        for (int a = 1; a < 3; a++)
            if (b->hi[a] - b->lo[a] > b->hi[axis] - b->lo[axis])
                axis = a;
        at = (uint16_t)((b->lo[axis] + b->hi[axis]) / 2);
    }
    int n = 0;
    ch[n] = *b;
    ch[n].hi[axis] = at;
    n += shrink(&w->occ, &ch[n]);
    ch[n] = *b;
    ch[n].lo[axis] = at;
    n += shrink(&w->occ, &ch[n]);
    return n;
}

/*
 * Step 3, best first: the node holding the most wanted cells is cut in two
 * (cut), until no node holds a wanted cell or the next cut would pass the
 * budget plus DIVIDE_SLACK even after merging what is done (step 4); nodes
 * left then are kept whole. Then step 4 on everything, and step 5: while
 * there are more boxes than the budget, the pair whose hull adds the fewest
 * wanted cells, then the fewest empty ones, is merged. w->capped counts the
 * boxes that still hold wanted cells. A node holding a wanted cell is never
 * a single cell (wanted cells are empty and nodes are shrunk to occupied
 * ones), so it always divides, and both parts are smaller.
 */
static int divide(work *w)
{
    heap h = {0};
    int rc = 0;
    uint32_t n = w->n;
    ibox root = {{0, 0, 0}, {(uint16_t)n, (uint16_t)n, (uint16_t)n}};
    if (shrink(&w->occ, &root) && (rc = file_node(w, &h, &root)) < 0)
        goto done;
    while (h.n) {
        node nd = heap_pop(&h);
        ibox ch[2];
        int nch = cut(w, &nd.b, ch);
        if (w->out.n + h.n + (uint32_t)nch > w->budget + DIVIDE_SLACK) {
            if ((rc = merge_all(w, 0)) < 0)
                goto done;
            if (w->out.n + h.n + (uint32_t)nch > w->budget + DIVIDE_SLACK) {
                /* The budget is spent: what waits stays whole. */
                if ((rc = push(&w->out, &nd.b)) < 0)
                    goto done;
                while (h.n) {
                    node rest = heap_pop(&h);
                    if ((rc = push(&w->out, &rest.b)) < 0)
                        goto done;
                }
                break;
            }
        }
        for (int c = 0; c < nch; c++)
            if ((rc = file_node(w, &h, &ch[c])) < 0)
                goto done;
    }
    if ((rc = merge_all(w, 0)) < 0 || (rc = merge_all(w, w->budget)) < 0)
        goto done;
    for (uint32_t i = 0; i < w->out.n; i++)
        w->capped += svt_sum(&w->want, &w->out.b[i]) > 0;
done:
    free(h.v);
    return rc;
}

/*
 * The padded array of mark_wanted: dim[0] x dim[1] x dim[2] bits, each line
 * along x in w words (bit t of a line is bit t % 64 of word t / 64), the
 * bits past dim[0] kept 0 until the dilations.
 */
typedef struct bits3 {
    uint64_t *v;
    uint32_t dim[3];
    size_t w;
} bits3;

/* Line r of b becomes, at each t, r[t] AND r[t + s] (erode: 0 past the
 * line) or r[t] OR r[t - s] (dilate: 0 before it). */
static void line_step(uint64_t *r, size_t w, uint32_t s, int erode)
{
    size_t q = s / 64;
    unsigned sh = s % 64;
    if (erode) {
        for (size_t i = 0; i < w; i++) {
            uint64_t lo = i + q < w ? r[i + q] : 0, hi = i + q + 1 < w ? r[i + q + 1] : 0;
            r[i] &= sh ? (lo >> sh) | (hi << (64 - sh)) : lo;
        }
    } else {
        for (size_t i = w; i-- > 0;) {
            uint64_t hi = i >= q ? r[i - q] : 0, lo = i >= q + 1 ? r[i - q - 1] : 0;
            r[i] |= sh ? (hi << sh) | (lo >> (64 - sh)) : hi;
        }
    }
}

/* Along y or z: block t (len blocks of bsize words, groups of them gstride
 * words apart) becomes block t AND block t + s (0 past the end), or block
 * t OR block t - s (nothing before the start). */
static void block_step(uint64_t *v, size_t groups, size_t gstride, uint32_t len, size_t bsize, uint32_t s, int erode)
{
    for (size_t g = 0; g < groups; g++) {
        uint64_t *base = v + g * gstride;
        if (erode) {
            for (uint32_t t = 0; t < len; t++) {
                uint64_t *d = base + t * bsize;
                if (t + s < len) {
                    const uint64_t *o = base + (size_t)(t + s) * bsize;
                    for (size_t i = 0; i < bsize; i++)
                        d[i] &= o[i];
                } else {
                    memset(d, 0, bsize * sizeof *d);
                }
            }
        } else {
            for (uint32_t t = len; t-- > s;) {
                uint64_t *d = base + t * bsize;
                const uint64_t *o = base + (size_t)(t - s) * bsize;
                for (size_t i = 0; i < bsize; i++)
                    d[i] |= o[i];
            }
        }
    }
}

/*
 * Erodes (a bit stays 1 if the k bits from it on along axis a are all 1,
 * the window inside the array) or dilates (a bit becomes 1 if one of the k
 * bits up to it is 1) b along axis a, by doubling: windows of 1, 2, 4 ...
 * p bits (p the largest power of two up to k), then two windows of p that
 * overlap to span k.
 */
static void morph(bits3 *b, int a, uint32_t k, int erode)
{
    uint32_t steps[40], ns = 0;
    uint32_t p = 1;
    while (2 * p <= k) {
        steps[ns++] = p;
        p *= 2;
    }
    if (k > p)
        steps[ns++] = k - p;
    for (uint32_t i = 0; i < ns; i++) {
        if (a == 0) {
            size_t lines = (size_t)b->dim[1] * b->dim[2];
            for (size_t l = 0; l < lines; l++)
                line_step(b->v + l * b->w, b->w, steps[i], erode);
        } else if (a == 1) {
            block_step(b->v, b->dim[2], b->w * b->dim[1], b->dim[1], b->w, steps[i], erode);
        } else {
            block_step(b->v, 1, 0, b->dim[2], b->w * b->dim[1], steps[i], erode);
        }
    }
}

/* Cell index of local coordinate v on axis a, rounded down or up, in 0..n. */
static uint32_t cell_of(const voxel_grid *g, int a, double v, int up)
{
    if (!(g->cell[a] > 0))
        return up ? g->n : 0;
    double c = (v - g->min[a]) / g->cell[a];
    c = up ? ceil(c) : floor(c);
    return c <= 0 ? 0 : c >= g->n ? g->n : (uint32_t)c;
}

/*
 * Step 2 for one cluster: marks in w->wanted the empty cells of its region
 * that an avatar-sized box of free cells covers. The opening runs on the
 * region grown by the kernel on each side, cells outside the grid free.
 */
static int mark_wanted(work *w, const ecm_cluster *cl, const float named[6], const float avatar[3])
{
    const voxel_grid *g = &w->g;
    uint32_t n = w->n;
    /* The face of the box the cluster names nearest its centroid: the axis
     * users cross, in every box the cluster presses on (a neighbour's
     * nearest face may be the one it shares with the named box). */
    int face = 0;
    double best = INFINITY;
    for (int a = 0; a < 3; a++) {
        double c = cl->centroid[a];
        double d = fmin(fabs(c - (double)named[a]), fabs((double)named[3 + a] - c));
        if (d < best) {
            best = d;
            face = a;
        }
    }
    /* Horizontal size: the smaller of x and z, so that any yaw is covered. */
    double size[3] = {fmin(avatar[0], avatar[2]), avatar[1], fmin(avatar[0], avatar[2])};
    uint32_t lo[3], hi[3], k[3], dim[3];
    size_t total = 1;
    for (int a = 0; a < 3; a++) {
        if (a == face) {
            lo[a] = 0;
            hi[a] = n;
        } else {
            double up = a == 1 ? g->cell[1] : 0;
            lo[a] = cell_of(g, a, (double)cl->min[a] - size[a] / 2, 0);
            hi[a] = cell_of(g, a, (double)cl->max[a] + size[a] / 2 + up, 1);
        }
        if (lo[a] >= hi[a])
            return 0;
        /* The avatar in cells, rounded down (a smaller kernel finds more
         * space, never less), at most n: a window as long as the grid
         * meets it in the same prefixes, suffixes and whole lines as any
         * longer one (space outside the grid is free). */
        double kc = g->cell[a] > 0 ? floor(size[a] / g->cell[a]) : 1;
        k[a] = kc < 1 ? 1 : kc > n ? n : (uint32_t)kc;
    }
    /* Bounded memory: past WANTED_CELLS_MAX the longest kernel is halved
     * (more space counts as wanted, never less; only deep grids with a
     * large avatar get there). */
    for (;;) {
        total = 1;
        for (int a = 0; a < 3; a++) {
            dim[a] = hi[a] - lo[a] + 2 * k[a]; /* index i is cell lo - k + i */
            total *= dim[a];
        }
        int longest = k[0] >= k[1] && k[0] >= k[2] ? 0 : k[1] >= k[2] ? 1 : 2;
        if (total <= WANTED_CELLS_MAX || k[longest] == 1)
            break;
        k[longest] /= 2;
    }
    bits3 b = {.dim = {dim[0], dim[1], dim[2]}, .w = (dim[0] + 63) / 64};
    size_t lines = (size_t)dim[1] * dim[2];
    b.v = cvre_malloc(lines * b.w * sizeof *b.v);
    if (!b.v)
        return -ENOMEM;
    /* 1 = free: empty cells, and every cell outside the grid. */
    for (size_t l = 0; l < lines; l++) {
        uint64_t *r = b.v + l * b.w;
        for (size_t i = 0; i < b.w; i++)
            r[i] = dim[0] - 64 * i >= 64 ? UINT64_MAX : ((uint64_t)1 << (dim[0] - 64 * i)) - 1;
    }
    for (uint32_t z = 0; z < dim[2]; z++) {
        int64_t cz = (int64_t)lo[2] - k[2] + z;
        for (uint32_t y = 0; y < dim[1] && cz >= 0 && cz < n; y++) {
            int64_t cy = (int64_t)lo[1] - k[1] + y;
            if (cy < 0 || cy >= n)
                continue;
            uint64_t *row = b.v + b.w * (y + (size_t)dim[1] * z);
            int64_t x0 = (int64_t)lo[0] - k[0];
            for (int64_t cx = x0 < 0 ? 0 : x0; cx < n && cx - x0 < dim[0]; cx++)
                if (voxel_get(g, (uint32_t)cx, (uint32_t)cy, (uint32_t)cz)) {
                    uint64_t t = (uint64_t)(cx - x0);
                    row[t / 64] &= ~((uint64_t)1 << (t % 64));
                }
        }
    }
    for (int a = 0; a < 3; a++)
        morph(&b, a, k[a], 1);
    for (int a = 0; a < 3; a++)
        morph(&b, a, k[a], 0);
    for (uint32_t z = lo[2]; z < hi[2]; z++)
        for (uint32_t y = lo[1]; y < hi[1]; y++) {
            const uint64_t *row = b.v + b.w * ((y - lo[1] + k[1]) + (size_t)dim[1] * (z - lo[2] + k[2]));
            for (uint32_t x = lo[0]; x < hi[0]; x++) {
                uint32_t t = x - lo[0] + k[0];
                if ((row[t / 64] >> (t % 64)) & 1u)
                    w->wanted[x + (size_t)n * (y + (size_t)n * z)] = 1;
            }
        }
    free(b.v);
    return 0;
}

static void work_free(work *w)
{
    voxel_grid_free(&w->g);
    free(w->tables);
    free(w->wanted);
    free(w->out.b);
    memset(w, 0, sizeof *w);
}

/* Whether cluster c presses on box i of boxes: the box it names, or any
 * box its points lie on (their bounding box, grown by a hundredth of the
 * avatar's width for rounding, meets the box): a cluster along a wall of
 * several boxes presses on all of them. */
static int presses(const ecm_cluster *c, const float (*boxes)[6], uint32_t i, const float avatar[3])
{
    if (c->box == i)
        return 1;
    double tol = 0.01 * fmin(avatar[0], avatar[2]);
    for (int a = 0; a < 3; a++)
        if ((double)c->min[a] - tol > boxes[i][3 + a] || (double)c->max[a] + tol < boxes[i][a])
            return 0;
    return 1;
}

/* Steps 1 to 5 for one problem box, into at most budget boxes (w->out).
 * Adds to the result's counts and times. */
static int refine_box(work *w, const ecm_params *p, const float (*boxes)[6], uint32_t box_index, const float *tris,
                      uint32_t ntris, const ecm_cluster *cl, uint32_t ncl, uint32_t budget, ecm_result *r)
{
    struct timespec t0;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    memset(w, 0, sizeof *w);
    w->max_empty = p->max_empty;
    w->budget = budget;
    const float *box = boxes[box_index];
    int rc = voxel_grid_init(&w->g, p->depth, box, box + 3);
    if (rc < 0)
        return rc;
    if ((rc = voxel_mark(&w->g, tris, ntris)) < 0)
        return rc;
    r->voxel_ms += ms_since(&t0);
    clock_gettime(CLOCK_MONOTONIC, &t0);
    uint32_t n = w->n = w->g.n;
    size_t cells = (size_t)n * n * n;
    ibox all = {{0, 0, 0}, {(uint16_t)n, (uint16_t)n, (uint16_t)n}};
    /* Both tables in one block (the wanted one only when it is used): two
     * blocks of 8.6 MiB each at 2^7 were handed back to the system after
     * each round and faulted in again, page by page, by the next (glibc
     * keeps a freed block for reuse up to twice the largest one it has
     * seen returned to it). */
    size_t table = (size_t)(n + 1) * (n + 1) * (n + 1);
    w->tables = cvre_malloc((budget == 1 ? 1 : 2) * table * sizeof *w->tables);
    if (!w->tables)
        return -ENOMEM;
    svt_build(&w->occ, w->tables, &w->g, NULL);
    if (budget == 1) {
        /* A share of one box: it can only shrink to its occupied cells, so
         * its wanted space is not worked out; kept whole by the cap. */
        ibox b = all;
        if (shrink(&w->occ, &b) && (rc = push(&w->out, &b)) < 0)
            return rc;
        r->capped += w->out.n;
    } else {
        w->wanted = cvre_calloc(cells, 1);
        if (!w->wanted)
            return -ENOMEM;
        for (uint32_t i = 0; i < ncl; i++)
            if (presses(&cl[i], boxes, box_index, p->avatar) &&
                (rc = mark_wanted(w, &cl[i], boxes[cl[i].box], p->avatar)) < 0)
                return rc;
        svt_build(&w->want, w->tables + table, &w->g, w->wanted);
        if ((rc = divide(w)) < 0)
            return rc;
        r->wanted += svt_sum(&w->want, &all);
        r->capped += w->capped;
    }
    r->cells += cells;
    r->occupied += w->g.occupied;
    r->divide_ms += ms_since(&t0);
    return 0;
}

/* Local float coordinates of a box of cells, rounded outwards and clamped
 * to the problem box. */
static void to_local(const voxel_grid *g, const float box[6], const ibox *b, float out[6])
{
    for (int a = 0; a < 3; a++) {
        double lo = g->min[a] + g->cell[a] * b->lo[a], hi = g->min[a] + g->cell[a] * b->hi[a];
        float flo = b->lo[a] == 0 ? box[a] : (float)lo, fhi = b->hi[a] == g->n ? box[3 + a] : (float)hi;
        if ((double)flo > lo)
            flo = nextafterf(flo, -INFINITY);
        if ((double)fhi < hi)
            fhi = nextafterf(fhi, INFINITY);
        out[a] = flo < box[a] ? box[a] : flo;
        out[3 + a] = fhi > box[3 + a] ? box[3 + a] : fhi;
    }
}

/* A problem box's result in local coordinates. */
typedef struct flist {
    float (*b)[6];
    uint32_t n;
} flist;

/* Moves w's boxes, as local coordinates, into *l. */
static int take_boxes(const work *w, const float box[6], flist *l)
{
    l->n = 0;
    l->b = cvre_malloc((w->out.n ? w->out.n : 1) * sizeof *l->b);
    if (!l->b)
        return -ENOMEM;
    for (uint32_t j = 0; j < w->out.n; j++)
        to_local(&w->g, box, &w->out.b[j], l->b[l->n++]);
    return 0;
}

static int finite_all(const float *v, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (!isfinite(v[i]))
            return 0;
    return 1;
}

int ecm_refine(const ecm_params *p, const float *tris, uint32_t ntris, const float (*boxes)[6], uint32_t nboxes,
               const ecm_cluster *clusters, uint32_t nclusters, ecm_result *out, char *err, size_t errlen)
{
    memset(out, 0, sizeof *out);
    if (p->depth < ECM_DEPTH_MIN || p->depth > ECM_DEPTH_MAX)
        return cvre_fail(err, errlen, -EINVAL, "grid depth %u is outside %u..%u", p->depth, ECM_DEPTH_MIN, ECM_DEPTH_MAX);
    if (p->max_boxes < 1 || p->max_boxes > ECM_MAX_BOXES_LIMIT)
        return cvre_fail(err, errlen, -EINVAL, "max boxes %u is outside 1..%u", p->max_boxes, ECM_MAX_BOXES_LIMIT);
    if (!(p->max_empty >= 0 && p->max_empty <= 1))
        return cvre_fail(err, errlen, -EINVAL, "max empty share %g is outside 0..1", p->max_empty);
    for (int a = 0; a < 3; a++)
        if (!(p->avatar[a] > 0) || !isfinite(p->avatar[a]))
            return cvre_fail(err, errlen, -EINVAL, "the avatar's size must be positive and finite");
    if (ntris == 0 || !tris)
        return cvre_fail(err, errlen, -EINVAL, "the object has no triangles");
    if (!finite_all(tris, (size_t)ntris * 9))
        return cvre_fail(err, errlen, -EINVAL, "a triangle has a coordinate that is not finite");
    if (nboxes == 0 || nboxes > ECM_MAX_BOXES_LIMIT || !boxes)
        return cvre_fail(err, errlen, -EINVAL, "the object has %u boxes (1..%u)", nboxes, ECM_MAX_BOXES_LIMIT);
    for (uint32_t i = 0; i < nboxes; i++) {
        if (!finite_all(boxes[i], 6))
            return cvre_fail(err, errlen, -EINVAL, "box %u has a coordinate that is not finite", i);
        for (int a = 0; a < 3; a++)
            if (boxes[i][a] > boxes[i][3 + a])
                return cvre_fail(err, errlen, -EINVAL, "box %u is inside out", i);
    }
    for (uint32_t i = 0; i < nclusters; i++) {
        if (clusters[i].box >= nboxes)
            return cvre_fail(err, errlen, -EINVAL, "cluster %u names box %u of %u", i, clusters[i].box, nboxes);
        if (!finite_all(clusters[i].min, 3) || !finite_all(clusters[i].max, 3) ||
            !finite_all(clusters[i].centroid, 3))
            return cvre_fail(err, errlen, -EINVAL, "cluster %u has a coordinate that is not finite", i);
    }

    int rc = -ENOMEM;
    uint8_t *problem = cvre_calloc(nboxes, 1);
    flist *lists = cvre_calloc(nboxes, sizeof *lists);
    work w = {0};
    if (!problem || !lists)
        goto done;
    uint32_t kept = nboxes, nproblem = 0;
    for (uint32_t i = 0; i < nclusters; i++)
        for (uint32_t b = 0; b < nboxes; b++)
            if (!problem[b] && presses(&clusters[i], boxes, b, p->avatar)) {
                problem[b] = 1;
                kept--;
                nproblem++;
            }
    /* Each problem box may become an equal share of what the kept boxes
     * leave of max_boxes (the first ones get the remainder), at least one. */
    uint32_t room = p->max_boxes > kept ? p->max_boxes - kept : 0, given = 0;
    for (uint32_t i = 0; i < nboxes; i++) {
        if (!problem[i])
            continue;
        uint32_t budget = room / nproblem + (given < room % nproblem);
        given++;
        if ((rc = refine_box(&w, p, boxes, i, tris, ntris, clusters, nclusters, budget ? budget : 1, out)) < 0 ||
            (rc = take_boxes(&w, boxes[i], &lists[i])) < 0)
            goto done;
        work_free(&w);
    }
    uint64_t total = kept;
    for (uint32_t i = 0; i < nboxes; i++)
        total += problem[i] ? lists[i].n : 0;
    out->boxes = cvre_malloc((size_t)total * sizeof *out->boxes);
    if (!out->boxes) {
        rc = -ENOMEM;
        goto done;
    }
    for (uint32_t i = 0; i < nboxes; i++)
        if (!problem[i])
            memcpy(out->boxes[out->count++], boxes[i], sizeof boxes[i]);
    for (uint32_t i = 0; i < nboxes; i++)
        if (problem[i]) {
            memcpy(out->boxes + out->count, lists[i].b, lists[i].n * sizeof *lists[i].b);
            out->count += lists[i].n;
        }
    out->problem_boxes = nproblem;
    rc = 0;
done:
    if (rc == -ENOMEM)
        cvre_fail(err, errlen, rc, "out of memory");
    else if (rc < 0)
        cvre_fail(err, errlen, rc, "digitization failed: %s", strerror(-rc));
    work_free(&w);
    if (lists)
        for (uint32_t i = 0; i < nboxes; i++)
            free(lists[i].b);
    free(lists);
    free(problem);
    if (rc < 0)
        ecm_result_free(out);
    return rc;
}
