/*
 * voxel.c: conservative triangle voxelization by the separating axis test.
 *
 * Everything is computed in the grid's own frame (coordinates minus the
 * box's min), where cell (i, j, k) is [i cx, (i+1) cx] x ... grown by eps on
 * every side. For a separating axis L, a cell's projection is an affine
 * function of its integer indices, d = L.x cx i + L.y cy j + L.z cz k plus
 * constants, so each axis reduces to one interval test on d, and a block of
 * cells to the same test with d widened by the block's size. Per triangle:
 *  1. its AABB becomes an index range clipped to the grid (the three box
 *     axes of the separating axis test, exactly: a cell in the range
 *     overlaps the AABB). One cell holding the whole AABB: marked, done.
 *     A triangle inside the grid whose range is one cell thick on two
 *     axes touches every cell of it; one cell thick on one axis, it is
 *     tested in 2D (the three edge axes across that axis) cell by cell.
 *     Another small range with every cell already marked: done.
 *  2. small ranges are tested cell by cell: the normal first, and the nine
 *     edge x box-axis cross products only once a cell passes it (they are
 *     prepared then). Zero axes are left out (a degenerate triangle's
 *     normal, a cross product of parallel vectors: they separate nothing),
 *     and so are axes along a box axis (step 1 did them).
 *  3. large ranges are split in octants, each tested as one block on every
 *     axis before descending into it, so a big triangle costs about its
 *     surface cells, not its AABB's volume.
 * A cell already marked is never tested again.
 *
 * Tried and dropped, each slower on the benchmark meshes: marking the
 * vertices' cells untested first; solving the plane for the run of cells
 * it crosses in each column instead of testing the normal per cell.
 *
 * Why eps covers rounding: every quantity compared is a sum of a few
 * products of local coordinates and axis components, whose rounding error is
 * about 1e-16 |L| times the local coordinates' size (the grid's extent, for
 * geometry near the grid), while growing a cell by eps widens its projection
 * by at least eps |L| = 1e-9 |L| times the extent. So a cell that truly
 * touches the triangle always passes, whatever the axis (even a nearly
 * degenerate one computed with a large relative error: the test is valid for
 * any axis, only the projections must be accurate). Geometry more than about
 * 10^6 extents away from the box would break that margin; a triangle that far
 * and still crossing the box has a vertex at a distance no model reaches.
 *
 * A flat axis (min == max) has cells of size 0: all n cells along it are the
 * same set, so the range is collapsed to index 0 and marking a cell marks
 * its n copies (the invariant: copies are always set together). *
 * voxel_mark_threads and voxel_mark_boxed give each thread a slab of whole
 * z layers (n^2 bits, a multiple of 64 from n = 8 up, so no word is shared)
 * holding about as many triangles as the others; every thread reads every
 * triangle, skips those outside its slab, and clips the others' ranges to
 * it. No locks, no atomics: the threads write disjoint words and only read
 * the input.
 */
#include "voxel.h"

#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

#include "alloc.h"
#include "task.h"

/* Regions of at most this many cells are tested cell by cell; larger ones
 * are split in octants, each tested as one block first. Most cells of a
 * region fail on the normal alone, a multiply-add and two comparisons, so
 * leaves can be large: 216 (6^3) and 512 were the fastest of 27..4096 on
 * the benchmark meshes at 64^3 to 256^3 (27: 35% slower on the bunny at
 * 256^3). */
#ifndef VOXEL_LEAF_CELLS
#define VOXEL_LEAF_CELLS 216
#endif
/* Ranges of at most this many cells are first checked for an unmarked
 * cell: in a fine mesh, a small triangle's cells are often all marked by
 * its neighbours already, and 27 bit reads cost less than its normal. */
#define SMALL_RANGE 27

_Static_assert(VOXEL_DEPTH_MIN >= 1 && VOXEL_DEPTH_MAX <= 10,
               "cell indices must fit int and n^3 bits a size_t on 64-bit");
_Static_assert(VOXEL_LEAF_CELLS >= 8, "a leaf must hold at least one octant split");
_Static_assert(VOXEL_MAX_THREADS >= 1 && VOXEL_MAX_THREADS <= 256, "slab jobs live on the stack");
_Static_assert(VOXEL_MIN_TRIS_PER_THREAD >= 1, "a thread needs triangles");

/* One separating axis in index form: cell (i, j, k) overlaps the triangle
 * on this axis iff lo <= w[0] i + w[1] j + w[2] k <= hi. */
typedef struct axis {
    double w[3];
    double lo, hi;
} axis;

/* A triangle's separating axes beyond the box axes. The edge axes are
 * prepared only once a cell passes the normal, or for a block test. */
typedef struct tri {
    const double (*v)[3]; /* vertices, local coordinates */
    axis nrm;             /* the normal; absent (has_nrm 0) for a segment or a point */
    int has_nrm;
    int nedge;            /* edge axes in edge[], -1 until prepared */
    axis edge[9];
} tri;

/* One voxel_mark call's state. */
typedef struct marker {
    uint64_t *bits;
    uint64_t n;
    int copies[3];   /* n on a flat axis, else 1 */
    int any_flat;
    double c[3];     /* cell size per axis */
    double inv[3];   /* 1 / cell size, 0 on a flat axis */
    double ext[3];   /* the box's extent per axis */
    double eps;      /* how much every cell grows on each side */
    int zlo, zhi;    /* the slab of z layers this marker may set */
    uint64_t added;  /* bits newly set */
} marker;

/* fmin/fmax and floor are library calls on baseline x86-64 (NaN rules,
 * no SSE4.1); every value here is finite. */
static inline double dmin(double a, double b) { return a < b ? a : b; }
static inline double dmax(double a, double b) { return a > b ? a : b; }

/* floor(x) for 0 <= x < 2^31, ceil(x) - 1 likewise. */
static inline int floor_pos(double x) { return (int)x; }
static inline int ceil_minus_one_pos(double x)
{
    int t = (int)x;
    return (double)t == x ? t - 1 : t;
}

static inline uint64_t cell_index(const marker *m, int x, int y, int z)
{
    return (uint64_t)x + m->n * ((uint64_t)y + m->n * (uint64_t)z);
}

static inline int is_set(const marker *m, int x, int y, int z)
{
    uint64_t i = cell_index(m, x, y, z);
    return (int)((m->bits[i >> 6] >> (i & 63)) & 1u);
}

static inline void set_bit(marker *m, uint64_t i)
{
    uint64_t *w = &m->bits[i >> 6], b = (uint64_t)1 << (i & 63);
    m->added += (*w & b) == 0;
    *w |= b;
}

/* Sets cell (x, y, z) and, on flat axes (where the index is 0), its copies. */
static inline void set_cell(marker *m, int x, int y, int z)
{
    if (!m->any_flat) {
        set_bit(m, cell_index(m, x, y, z));
        return;
    }
    if (is_set(m, x, y, z))
        return; /* and so are its copies */
    for (int dz = 0; dz < m->copies[2]; dz++)
        for (int dy = 0; dy < m->copies[1]; dy++)
            for (int dx = 0; dx < m->copies[0]; dx++)
                set_bit(m, cell_index(m, x + dx, y + dy, z + dz));
}

/* The index range [*r0, *r1] of the cells whose grown extent on one axis
 * meets [lo, hi] (local coordinates), clipped to the grid. Returns 0 if it is
 * empty. Cell i meets it iff i c - eps <= hi and (i+1) c + eps >= lo. */
static int axis_range(const marker *m, int a, double lo, double hi, int r[2])
{
    double eps = m->eps;
    if (m->c[a] == 0.0) {
        if (lo > eps || hi < -eps)
            return 0;
        r[0] = r[1] = 0;
        return 1;
    }
    double top = (double)(m->n - 1);
    double first = (lo - eps) * m->inv[a], last = (hi + eps) * m->inv[a];
    if (last < 0.0 || first > top + 1.0)
        return 0;
    r[0] = first <= 0.0 ? 0 : ceil_minus_one_pos(first);
    r[1] = last >= top ? (int)top : floor_pos(last);
    return 1;
}

/* Fills x with axis L for triangle v (local coordinates): cell (0,0,0)'s
 * grown projection on L is [cmin, cmax], cell (i,j,k)'s that shifted by
 * d = w.(i,j,k); the cell overlaps the triangle's projection [tlo, thi] iff
 * tlo - cmax <= d <= thi - cmin. */
static void make_axis(axis *x, const marker *m, const double L[3], double tlo, double thi)
{
    double sum = 0.0, mag = 0.0, grow = 0.0;
    for (int a = 0; a < 3; a++) {
        x->w[a] = L[a] * m->c[a];
        sum += x->w[a];
        mag += fabs(x->w[a]);
        grow += fabs(L[a]);
    }
    grow *= m->eps;
    x->lo = tlo - (0.5 * (sum + mag) + grow); /* cmax = sum of the positive w, plus the growth */
    x->hi = thi - (0.5 * (sum - mag) - grow); /* cmin = sum of the negative w, minus it */
}

/* Prepares t for triangle v: the normal only. */
static void tri_setup(tri *t, const marker *m, const double v[3][3])
{
    double e0[3], e1[3], L[3];
    for (int a = 0; a < 3; a++) {
        e0[a] = v[1][a] - v[0][a];
        e1[a] = v[2][a] - v[1][a];
    }
    L[0] = e0[1] * e1[2] - e0[2] * e1[1];
    L[1] = e0[2] * e1[0] - e0[0] * e1[2];
    L[2] = e0[0] * e1[1] - e0[1] * e1[0];
    t->v = v;
    t->nedge = -1;
    t->has_nrm = L[0] != 0.0 || L[1] != 0.0 || L[2] != 0.0;
    if (t->has_nrm) {
        double p0 = v[0][0] * L[0] + v[0][1] * L[1] + v[0][2] * L[2];
        double p1 = v[1][0] * L[0] + v[1][1] * L[1] + v[1][2] * L[2];
        double p2 = v[2][0] * L[0] + v[2][1] * L[1] + v[2][2] * L[2];
        make_axis(&t->nrm, m, L, dmin(p0, dmin(p1, p2)), dmax(p0, dmax(p1, p2)));
    }
}

/* Prepares the edge axes: unit axis g cross edge i, for every g and i,
 * except the zero ones and those along a box axis (an edge parallel to a
 * box face: the index range already did those). */
static void edges_setup(tri *t, const marker *m)
{
    const double (*v)[3] = t->v;
    int k = 0;
    for (int i = 0; i < 3; i++) {
        const double *a = v[i], *b = v[(i + 1) % 3], *o = v[(i + 2) % 3];
        for (int g = 0; g < 3; g++) {
            int u = (g + 1) % 3, w = (g + 2) % 3;
            double L[3];
            L[g] = 0.0;
            L[u] = a[w] - b[w]; /* -(edge w) */
            L[w] = b[u] - a[u]; /* edge u */
            if (L[u] == 0.0 || L[w] == 0.0)
                continue;
            /* The edge's two vertices project to the same value, up to
             * rounding (which eps covers): two projections suffice. */
            double pa = L[u] * a[u] + L[w] * a[w], po = L[u] * o[u] + L[w] * o[w];
            make_axis(&t->edge[k++], m, L, dmin(pa, po), dmax(pa, po));
        }
    }
    t->nedge = k;
}

static inline int axis_holds(const axis *x, int i, int j, int k)
{
    double d = x->w[0] * i + x->w[1] * j + x->w[2] * k;
    return d >= x->lo && d <= x->hi;
}

/* 1 if cell (i, j, k), known to pass the normal, passes every edge axis. */
static int edges_hold(tri *t, const marker *m, int i, int j, int k)
{
    if (t->nedge < 0)
        edges_setup(t, m);
    for (int a = 0; a < t->nedge; a++)
        if (!axis_holds(&t->edge[a], i, j, k))
            return 0;
    return 1;
}

/* Tests every unmarked cell of region r (inclusive index ranges): the
 * normal first, which rejects most cells near a triangle, then the edges. */
static void leaf(marker *m, tri *t, const int r[3][2])
{
    const axis *n = &t->nrm;
    for (int k = r[2][0]; k <= r[2][1]; k++)
        for (int j = r[1][0]; j <= r[1][1]; j++) {
            double base = n->w[1] * j + n->w[2] * k;
            uint64_t row = cell_index(m, 0, j, k);
            for (int i = r[0][0]; i <= r[0][1]; i++) {
                uint64_t b = row + (uint64_t)i;
                if ((m->bits[b >> 6] >> (b & 63)) & 1u)
                    continue;
                if (t->has_nrm) {
                    double d = base + n->w[0] * i;
                    if (d < n->lo || d > n->hi)
                        continue;
                }
                if (edges_hold(t, m, i, j, k))
                    set_cell(m, i, j, k);
            }
        }
}

/* 1 if the block of cells r (grown by eps, as the union of its grown cells
 * is) overlaps the triangle on axis x. */
static int block_holds(const axis *x, const int r[3][2])
{
    double d = x->w[0] * r[0][0] + x->w[1] * r[1][0] + x->w[2] * r[2][0];
    double lo = d, hi = d;
    for (int c = 0; c < 3; c++) {
        double s = x->w[c] * (r[c][1] - r[c][0]);
        if (s < 0.0)
            lo += s;
        else
            hi += s;
    }
    return lo <= x->hi && hi >= x->lo;
}

static int block_overlaps(const tri *t, const int r[3][2])
{
    if (t->has_nrm && !block_holds(&t->nrm, r))
        return 0;
    for (int a = 0; a < t->nedge; a++)
        if (!block_holds(&t->edge[a], r))
            return 0;
    return 1;
}

/* Marks the cells of region r that the triangle touches, r itself being
 * known (or assumed, at the top) to overlap it. Recursion depth is at most
 * VOXEL_DEPTH_MAX: each level halves every axis longer than one cell. */
static void descend(marker *m, tri *t, const int r[3][2])
{
    long cells = 1;
    for (int a = 0; a < 3; a++)
        cells *= r[a][1] - r[a][0] + 1;
    if (cells <= VOXEL_LEAF_CELLS) {
        leaf(m, t, r);
        return;
    }
    if (t->nedge < 0)
        edges_setup(t, m);
    int half[3][2][2], parts[3];
    for (int a = 0; a < 3; a++) {
        int mid = r[a][0] + (r[a][1] - r[a][0]) / 2;
        parts[a] = r[a][1] > r[a][0] ? 2 : 1;
        half[a][0][0] = r[a][0];
        half[a][0][1] = parts[a] == 2 ? mid : r[a][1];
        half[a][1][0] = mid + 1;
        half[a][1][1] = r[a][1];
    }
    for (int hz = 0; hz < parts[2]; hz++)
        for (int hy = 0; hy < parts[1]; hy++)
            for (int hx = 0; hx < parts[0]; hx++) {
                int c[3][2] = {{half[0][hx][0], half[0][hx][1]},
                               {half[1][hy][0], half[1][hy][1]},
                               {half[2][hz][0], half[2][hz][1]}};
                if (block_overlaps(t, c))
                    descend(m, t, c);
            }
}

/* A triangle inside the grid whose range is one cell thick on axis g (and
 * more on both others): it lies in that layer of cells, so it touches a
 * cell of the range iff its shadow along g meets the cell's: the box axes
 * (the range) and the three edge axes across g decide, as the 2D
 * separating axis test; the normal and the other six edge axes cannot
 * separate a box the triangle's layer holds. */
static void mark_layer(marker *m, const double v[3][3], const int r[3][2], int g)
{
    axis ax[3];
    int k = 0, u = (g + 1) % 3, w = (g + 2) % 3;
    for (int i = 0; i < 3; i++) {
        const double *a = v[i], *b = v[(i + 1) % 3], *o = v[(i + 2) % 3];
        double L[3];
        L[g] = 0.0;
        L[u] = a[w] - b[w];
        L[w] = b[u] - a[u];
        if (L[u] == 0.0 || L[w] == 0.0)
            continue; /* along a box axis: the range did it */
        double pa = L[u] * a[u] + L[w] * a[w], po = L[u] * o[u] + L[w] * o[w];
        make_axis(&ax[k++], m, L, dmin(pa, po), dmax(pa, po));
    }
    for (int z = r[2][0]; z <= r[2][1]; z++)
        for (int y = r[1][0]; y <= r[1][1]; y++)
            for (int x = r[0][0]; x <= r[0][1]; x++) {
                if (is_set(m, x, y, z))
                    continue;
                int in = 1;
                for (int a = 0; a < k && in; a++)
                    in = axis_holds(&ax[a], x, y, z);
                if (in)
                    set_bit(m, cell_index(m, x, y, z));
            }
}

static void mark_triangle(marker *m, const double v[3][3])
{
    int r[3][2], inside = 1;
    for (int a = 0; a < 3; a++) {
        double lo = dmin(v[0][a], dmin(v[1][a], v[2][a]));
        double hi = dmax(v[0][a], dmax(v[1][a], v[2][a]));
        if (!axis_range(m, a, lo, hi, r[a]))
            return;
        inside &= lo >= -m->eps && hi <= m->ext[a] + m->eps;
    }
    if (r[2][0] < m->zlo || r[2][1] > m->zhi) { /* crosses out of this thread's slab */
        if (r[2][1] < m->zlo || r[2][0] > m->zhi)
            return;
        r[2][0] = r[2][0] < m->zlo ? m->zlo : r[2][0];
        r[2][1] = r[2][1] > m->zhi ? m->zhi : r[2][1];
        inside = 0;
    }
    long cells = 1;
    for (int a = 0; a < 3; a++)
        cells *= r[a][1] - r[a][0] + 1;
    /* One cell holding the whole triangle (clipping could have cut the
     * range down to a cell the triangle passes by). */
    if (cells == 1 && inside) {
        set_cell(m, r[0][0], r[1][0], r[2][0]);
        return;
    }
    /* Thin ranges of a triangle inside the grid (no flat axis): one cell
     * thick on two axes, a row the triangle crosses, each cell of which it
     * touches (it is connected, and its box lies in the row's other two
     * extents); on one axis, a layer (mark_layer). Most triangles of a
     * detailed mesh at the refinement's cells: bench-refine's bunny
     * statue digitized in 92.1 -> 84.1 M instructions. */
    if (inside && !m->any_flat) {
        int thin = 0, g = 0;
        for (int a = 0; a < 3; a++)
            if (r[a][0] == r[a][1]) {
                thin++;
                g = a;
            }
        if (thin == 2) {
            for (int k = r[2][0]; k <= r[2][1]; k++)
                for (int j = r[1][0]; j <= r[1][1]; j++)
                    for (int i = r[0][0]; i <= r[0][1]; i++)
                        set_bit(m, cell_index(m, i, j, k));
            return;
        }
        if (thin == 1) {
            mark_layer(m, v, r, g);
            return;
        }
    }
    if (cells <= SMALL_RANGE) { /* often all marked by the triangle's neighbours */
        int left = 0;
        for (int k = r[2][0]; k <= r[2][1] && !left; k++)
            for (int j = r[1][0]; j <= r[1][1] && !left; j++)
                for (int i = r[0][0]; i <= r[0][1] && !left; i++)
                    left = !is_set(m, i, j, k);
        if (!left)
            return;
    }
    tri t;
    tri_setup(&t, m, v);
    descend(m, &t, r);
}

int voxel_grid_init(voxel_grid *g, uint32_t depth, const float min[3], const float max[3])
{
    if (!g)
        return -EINVAL;
    memset(g, 0, sizeof *g);
    if (depth < VOXEL_DEPTH_MIN || depth > VOXEL_DEPTH_MAX || !min || !max)
        return -EINVAL;
    for (int a = 0; a < 3; a++)
        if (!isfinite(min[a]) || !isfinite(max[a]) || !(min[a] <= max[a]))
            return -EINVAL;
    uint32_t n = 1u << depth;
    uint64_t cells = (uint64_t)n * n * n;
    uint64_t *bits = cvre_calloc((size_t)((cells + 63) / 64), sizeof *bits);
    if (!bits)
        return -ENOMEM;
    g->depth = depth;
    g->n = n;
    for (int a = 0; a < 3; a++) {
        g->min[a] = min[a];
        g->max[a] = max[a];
        g->cell[a] = (g->max[a] - g->min[a]) / n;
    }
    g->bits = bits;
    return 0;
}

void voxel_grid_free(voxel_grid *g)
{
    if (!g)
        return;
    free(g->bits);
    memset(g, 0, sizeof *g);
}

/* 1 if no float of p[0..n) is an infinity or a NaN: exponent all ones,
 * which the added 1 carries into bit 31. Bit operations only (twice as fast
 * as isfinite or a comparison per float); checked a chunk at a time. */
static int all_finite(const float *p, size_t n)
{
    for (size_t i = 0; i < n;) {
        size_t end = n - i > 4096 ? i + 4096 : n;
        uint32_t bad = 0;
        for (; i < end; i++) {
            uint32_t u;
            memcpy(&u, &p[i], sizeof u);
            bad |= (u & 0x7f800000u) + 0x00800000u;
        }
        if (bad & 0x80000000u)
            return 0;
    }
    return 1;
}

/* A marker for g's z layers zlo..zhi. */
static void marker_init(marker *m, const voxel_grid *g, int zlo, int zhi)
{
    double largest = 0.0, far = 0.0;
    memset(m, 0, sizeof *m);
    m->bits = g->bits;
    m->n = g->n;
    m->zlo = zlo;
    m->zhi = zhi;
    for (int a = 0; a < 3; a++) {
        m->ext[a] = g->max[a] - g->min[a];
        m->c[a] = g->cell[a];
        m->inv[a] = m->c[a] > 0.0 ? 1.0 / m->c[a] : 0.0;
        m->copies[a] = m->c[a] > 0.0 ? 1 : (int)g->n;
        m->any_flat |= m->c[a] == 0.0;
        largest = fmax(largest, m->ext[a]);
        far = fmax(far, fmax(fabs(g->min[a]), fabs(g->max[a])));
    }
    /* A box that is a single point has no extent to scale eps by: its
     * distance from the origin, or 1, sets the scale of rounding instead. */
    m->eps = VOXEL_EPS_REL * (largest > 0.0 ? largest : fmax(far, 1.0));
}

/* One triangle (9 floats), in the grid's frame. */
static void mark_one(marker *m, const voxel_grid *g, const float *p)
{
    double v[3][3];
    for (int i = 0; i < 3; i++)
        for (int a = 0; a < 3; a++)
            v[i][a] = (double)p[3 * i + a] - g->min[a];
    mark_triangle(m, v);
}

/* What one call marks: the triangles and, for voxel_mark_boxed, their
 * bounding boxes (box NULL for voxel_mark) and its loose bound. */
typedef struct pass {
    const float *tris;
    const float (*box)[6];
    size_t ntris;
    uint32_t loose;
} pass;

/* Marks the cells of triangle t's bounding box b (the cells its grown
 * extent meets, as mark_triangle finds them, in this marker's slab) when
 * there are at most `loose` of them: 1, or 0 when the triangle needs its
 * exact cells. */
static int mark_box_cells(marker *m, const voxel_grid *g, const float *b, uint32_t loose)
{
    int r[3][2];
    long cells = 1;
    for (int a = 0; a < 3; a++) {
        if (!axis_range(m, a, (double)b[a] - g->min[a], (double)b[3 + a] - g->min[a], r[a]))
            return 1; /* misses the grid: no cell to mark */
        cells *= r[a][1] - r[a][0] + 1;
    }
    if (cells > (long)loose)
        return 0;
    for (int k = r[2][0] < m->zlo ? m->zlo : r[2][0]; k <= r[2][1] && k <= m->zhi; k++)
        for (int j = r[1][0]; j <= r[1][1]; j++)
            for (int i = r[0][0]; i <= r[0][1]; i++)
                set_cell(m, i, j, k);
    return 1;
}

static void mark_pass(marker *m, const voxel_grid *g, const pass *p)
{
    /* The grid, or a thread's slab of it, grown by a cell and twice eps
     * (on a nearly flat axis, eps may pass a cell): triangles wholly outside
     * are passed over before any other work, and axis_range decides the
     * others exactly; a flat axis passes none over. */
    double lo[3], hi[3], grow = 2 * m->eps;
    for (int a = 0; a < 3; a++) {
        lo[a] = m->c[a] > 0.0 ? g->min[a] - m->c[a] - grow : -INFINITY;
        hi[a] = m->c[a] > 0.0 ? g->max[a] + m->c[a] + grow : INFINITY;
    }
    if (m->zlo > 0 || m->zhi < (int)m->n - 1) {
        lo[2] = g->min[2] + (m->zlo - 1) * m->c[2] - grow;
        hi[2] = g->min[2] + (m->zhi + 2) * m->c[2] + grow;
    }
    for (size_t t = 0; t < p->ntris; t++) {
        const float *v = p->tris + 9 * t;
        if (!p->box) {
            if ((v[2] < lo[2] && v[5] < lo[2] && v[8] < lo[2]) || (v[2] > hi[2] && v[5] > hi[2] && v[8] > hi[2]))
                continue;
            mark_one(m, g, v);
            continue;
        }
        const float *b = p->box[t];
        if (b[0] > hi[0] || b[3] < lo[0] || b[1] > hi[1] || b[4] < lo[1] || b[2] > hi[2] || b[5] < lo[2])
            continue;
        if (!p->loose || !mark_box_cells(m, g, b, p->loose))
            mark_one(m, g, v);
    }
}

int voxel_finite(const float *p, size_t n) { return all_finite(p, n); }

typedef struct slab_job {
    marker m;
    const voxel_grid *g;
    const pass *p;
    task t;
} slab_job;

static void mark_slab(void *arg)
{
    slab_job *j = arg;
    mark_pass(&j->m, j->g, j->p);
}

/* The z layer of triangle t's middle (of its box, where it has one), or -1
 * for a triangle whose box misses the grid's z range (no slab's work). */
static int layer_of(const voxel_grid *g, const pass *p, size_t t, double inv)
{
    double z;
    if (p->box) {
        const float *b = p->box[t];
        if ((double)b[5] < g->min[2] || (double)b[2] > g->max[2])
            return -1;
        z = ((double)b[2] + b[5]) / 2.0;
    } else {
        const float *v = p->tris + 9 * t;
        z = ((double)v[2] + v[5] + v[8]) / 3.0;
    }
    z = (z - g->min[2]) * inv;
    return z <= 0.0 ? 0 : z >= g->n - 1 ? (int)g->n - 1 : (int)z;
}

/* Splits the z layers into `threads` slabs holding about as many triangles
 * each (by a sample of their middles): first[s] is slab s's first layer,
 * first[threads] = n. Returns the number of non-empty slabs. */
static unsigned split_slabs(const voxel_grid *g, const pass *p, unsigned threads, int first[VOXEL_MAX_THREADS + 1])
{
    uint32_t count[1u << VOXEL_DEPTH_MAX] = {0};
    size_t step = p->ntris / 4096 + 1, total = 0;
    double inv = g->n / (g->max[2] - g->min[2]);
    for (size_t t = 0; t < p->ntris; t += step) {
        int layer = layer_of(g, p, t, inv);
        if (layer >= 0) {
            count[layer]++;
            total++;
        }
    }
    unsigned s = 0;
    size_t seen = 0;
    first[0] = 0;
    for (int layer = 0; layer < (int)g->n && s + 1 < threads; layer++) {
        seen += count[layer];
        if (seen * threads >= total * (s + 1))
            first[++s] = layer + 1;
    }
    if (first[s] < (int)g->n)
        s++;
    first[s] = (int)g->n;
    return s;
}

/* Marks p on up to `threads` threads (0: one per CPU, task_threads), each
 * setting the cells of its own slab of z layers, or on this thread alone. */
static void mark_slabs(voxel_grid *g, const pass *p, unsigned threads)
{
    threads = task_threads(threads);
    if (threads > VOXEL_MAX_THREADS)
        threads = VOXEL_MAX_THREADS;
    if (p->ntris / VOXEL_MIN_TRIS_PER_THREAD < threads)
        threads = (unsigned)(p->ntris / VOXEL_MIN_TRIS_PER_THREAD);
    /* Slabs are whole z layers of n^2 bits, so threads never share a word
     * when n >= 8; a flat z axis has one layer that all cells copy. */
    if (threads < 2 || g->n < 8 || g->cell[2] == 0.0) {
        marker m;
        marker_init(&m, g, 0, (int)g->n - 1);
        mark_pass(&m, g, p);
        g->occupied += m.added;
        return;
    }
    int first[VOXEL_MAX_THREADS + 1];
    slab_job job[VOXEL_MAX_THREADS];
    unsigned slabs = split_slabs(g, p, threads, first);
    for (unsigned s = 0; s < slabs; s++) {
        marker_init(&job[s].m, g, first[s], first[s + 1] - 1);
        job[s].g = g;
        job[s].p = p;
        /* Slab 0 runs here; a thread that cannot start runs here too. */
        task_start(&job[s].t, mark_slab, &job[s], s > 0);
    }
    for (unsigned s = 0; s < slabs; s++) {
        g->helper_ms += task_wait(&job[s].t);
        g->occupied += job[s].m.added;
    }
}

int voxel_mark(voxel_grid *g, const float *tris, size_t ntris)
{
    return voxel_mark_threads(g, tris, ntris, 1);
}

int voxel_mark_threads(voxel_grid *g, const float *tris, size_t ntris, unsigned threads)
{
    if (!g || !g->bits || (ntris && !tris) || ntris > SIZE_MAX / 9 || !all_finite(tris, 9 * ntris))
        return -EINVAL;
    pass p = {.tris = tris, .ntris = ntris};
    mark_slabs(g, &p, threads);
    return 0;
}

int voxel_mark_boxed(voxel_grid *g, const float *tris, const float (*box)[6], uint32_t ntris, uint32_t loose,
                     unsigned threads)
{
    if (!g || !g->bits || (ntris && (!tris || !box)))
        return -EINVAL;
    pass p = {.tris = tris, .box = box, .ntris = ntris, .loose = loose};
    mark_slabs(g, &p, threads);
    return 0;
}

/* 1 if axis L separates triangle v from the box [0, s] (both relative to
 * the box's min). A zero axis separates nothing. */
static int separates(const double L[3], const double v[3][3], const double s[3])
{
    double p[3], blo = 0.0, bhi = 0.0;
    for (int i = 0; i < 3; i++)
        p[i] = v[i][0] * L[0] + v[i][1] * L[1] + v[i][2] * L[2];
    for (int a = 0; a < 3; a++) {
        double q = L[a] * s[a];
        if (q < 0.0)
            blo += q;
        else
            bhi += q;
    }
    return dmin(p[0], dmin(p[1], p[2])) > bhi || dmax(p[0], dmax(p[1], p[2])) < blo;
}

int voxel_tri_box_overlap(const double t[9], const double min[3], const double max[3])
{
    double v[3][3], s[3], e[3][3], L[3];
    for (int a = 0; a < 3; a++) {
        s[a] = max[a] - min[a];
        for (int i = 0; i < 3; i++)
            v[i][a] = t[3 * i + a] - min[a];
        if (dmin(v[0][a], dmin(v[1][a], v[2][a])) > s[a] || dmax(v[0][a], dmax(v[1][a], v[2][a])) < 0.0)
            return 0;
    }
    for (int i = 0; i < 3; i++)
        for (int a = 0; a < 3; a++)
            e[i][a] = v[(i + 1) % 3][a] - v[i][a];
    L[0] = e[0][1] * e[1][2] - e[0][2] * e[1][1];
    L[1] = e[0][2] * e[1][0] - e[0][0] * e[1][2];
    L[2] = e[0][0] * e[1][1] - e[0][1] * e[1][0];
    if (separates(L, v, s))
        return 0;
    for (int i = 0; i < 3; i++) {
        double ax[3][3] = {{0.0, -e[i][2], e[i][1]}, {e[i][2], 0.0, -e[i][0]}, {-e[i][1], e[i][0], 0.0}};
        for (int a = 0; a < 3; a++)
            if (separates(ax[a], v, s))
                return 0;
    }
    return 1;
}

/* A huge page (x86-64, and the usual size elsewhere); the block is
 * allocated this much larger, and the table starts at the first multiple
 * of it past a header that remembers the block. */
#define HUGE_PAGE ((size_t)2 << 20)

void *voxel_table_alloc(size_t bytes)
{
    if (bytes > SIZE_MAX - 2 * HUGE_PAGE)
        return NULL;
    char *block = cvre_malloc(bytes + HUGE_PAGE + sizeof(void *));
    if (!block)
        return NULL;
    uintptr_t at = ((uintptr_t)block + sizeof(void *) + HUGE_PAGE - 1) & ~(uintptr_t)(HUGE_PAGE - 1);
    char *t = block + (at - (uintptr_t)block);
    memcpy(t - sizeof(void *), &block, sizeof block);
    /* Only whole huge pages; glibc keeps the block for the next
     * refinement of a long-lived process, whose pages are then in. */
    size_t whole = bytes & ~(HUGE_PAGE - 1);
    if (whole)
        madvise(t, whole, MADV_HUGEPAGE);
    return t;
}

void voxel_table_free(void *t)
{
    if (!t)
        return;
    char *block;
    memcpy(&block, (char *)t - sizeof(void *), sizeof block);
    free(block);
}

/* Row r of a table: its own prefix sums (the cells counted: bytes & mask
 * non-zero, or with mask 0 the bytes' values) plus the rows below it in y
 * and in z (by, bz), less the one below both (byz). Eight cells at a time:
 * the prefix, then the rest, which vectorizes; a group where no cell
 * counts (most of a row: cells to cover lie on the surface, pressure only
 * near users) has its prefix at once. Bench-refine's bunny statue, the two
 * tables: 51.2 -> 36.5 M instructions. */
static void row_build(uint32_t *restrict r, const uint8_t *restrict src, uint32_t n, uint8_t mask,
                      const uint32_t *restrict by, const uint32_t *restrict bz, const uint32_t *restrict byz)
{
    uint64_t m8 = mask ? mask * 0x0101010101010101ull : ~0ull;
    uint32_t acc = 0, x = 0, pre[8];
    r[0] = 0; /* and so is every row's first entry */
    for (; x + 8 <= n; x += 8) {
        uint64_t u;
        memcpy(&u, src + x, sizeof u);
        if (!(u & m8)) {
            for (uint32_t i = 0; i < 8; i++)
                pre[i] = acc;
        } else if (mask) {
            for (uint32_t i = 0; i < 8; i++)
                pre[i] = acc += (src[x + i] & mask) != 0;
        } else {
            for (uint32_t i = 0; i < 8; i++)
                pre[i] = acc += src[x + i];
        }
        for (uint32_t i = 0; i < 8; i++)
            r[x + i + 1] = pre[i] + by[x + i + 1] + bz[x + i + 1] - byz[x + i + 1];
    }
    for (; x < n; x++) { /* grids under 8 cells a side */
        acc += mask ? (src[x] & mask) != 0 : src[x];
        r[x + 1] = acc + by[x + 1] + bz[x + 1] - byz[x + 1];
    }
}

/* Each entry is its row's prefix sum plus the entries below it in y and
 * in z, less the one below both (the previous row and plane are still in
 * cache). */
void voxel_svt_build(voxel_svt *s, uint32_t *t, uint32_t n, const uint8_t *bytes, uint8_t mask)
{
    uint32_t m = n + 1;
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
            row_build(row, bytes + (size_t)n * (y + (size_t)n * z), n, mask, below_y, below_z, below_yz);
        }
    }
}
