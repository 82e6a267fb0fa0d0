/*
 * voxel.h: digitization of an object's geometry inside one of its boxes (the
 * paper's "digitize the object"). A grid of n = 2^depth cells per axis spans
 * the box; voxel_mark sets every cell that any triangle touches. Pure module:
 * no I/O, no global state.
 *
 * Conservative by construction: cells are closed boxes (a triangle lying
 * exactly on a face between two cells touches both), and the exact
 * triangle-box overlap test (separating axes) runs in double on the float
 * input with each cell grown by VOXEL_EPS_REL of the grid's extent, so that
 * rounding can only add cells, never lose one. Thin, axis-aligned, sliver and
 * degenerate triangles (a segment, a point) are handled by the same test.
 * A box may be flat on an axis (min == max): its cells are then flat too
 * (and all n of them along that axis are the same cell, set together). A box
 * that is a single point scales eps by its distance from the origin, or 1.
 * The margin holds for geometry within about 10^6 extents of the box.
 *
 * One grid per thread: calls on distinct grids may run in parallel.
 */
#ifndef CVRE_VOXEL_H
#define CVRE_VOXEL_H

#include <stddef.h>
#include <stdint.h>

/* Grid depths accepted: 2^1 to 2^10 cells per axis. 2^10 = 1024^3 cells is
 * a 128 MiB bit set, the most a refinement should ever hold in memory. */
#define VOXEL_DEPTH_MIN 1u
#define VOXEL_DEPTH_MAX 10u
/* How much each cell grows, relative to the grid's largest extent, in the
 * overlap test: far above double rounding on float input, far below anything
 * a user could see (1e-9 of a 1 km object is a micrometre). */
#define VOXEL_EPS_REL 1e-9

typedef struct voxel_grid {
    uint32_t depth;
    uint32_t n;           /* cells per axis: 1 << depth */
    double min[3], max[3];/* the box the grid spans */
    double cell[3];       /* cell size per axis: (max - min) / n, may be 0 */
    uint64_t *bits;       /* n^3 bits; cell (x, y, z) is bit x + n (y + n z) */
    uint64_t occupied;    /* cells set */
    double helper_ms;     /* CPU time of the threads its marking started (slabs, voxel_mark_threads) */
} voxel_grid;

/* Prepares an empty grid over [min, max] (each min <= max, all finite); the
 * grid owns its bits until voxel_grid_free. Returns 0, -EINVAL for a depth
 * outside VOXEL_DEPTH_MIN..MAX or a bad box (g zeroed), or -ENOMEM (g
 * zeroed). */
int voxel_grid_init(voxel_grid *g, uint32_t depth, const float min[3], const float max[3]);
/* Frees g's bits and zeroes it; a zeroed grid may be freed again. */
void voxel_grid_free(voxel_grid *g);

/* Sets every cell that one of the ntris triangles (9 floats each: three
 * vertices, x y z) touches; triangles outside the box set nothing. Cells
 * already set stay set, so a mesh may be marked in several calls; occupied
 * counts the cells set. Allocates nothing. Returns 0, or -EINVAL if a
 * coordinate is not finite or g has no bits (nothing is marked then). */
int voxel_mark(voxel_grid *g, const float *tris, size_t ntris);
/* voxel_mark over triangles whose coordinates the caller checked
 * (trimesh_init), with box[t] triangle t's bounding box: no second pass
 * over the coordinates, and a triangle whose box misses the grid by more
 * than a cell is passed over from its box (a group's grid over part of an
 * object). With loose 0 it sets the same cells; with loose > 0, every cell
 * of a triangle's bounding box where those are at most loose cells (a
 * superset, for a filter that only needs "no triangle here" to be true;
 * most triangles of a detailed mesh, with no test of their own). Runs on
 * up to `threads` threads as voxel_mark_threads does (1: this thread
 * only). Returns 0, or -EINVAL if g has no bits. */
int voxel_mark_boxed(voxel_grid *g, const float *tris, const float (*box)[6], uint32_t ntris, uint32_t loose,
                     unsigned threads);

static inline int voxel_get(const voxel_grid *g, uint32_t x, uint32_t y, uint32_t z)
{
    uint64_t i = (uint64_t)x + (uint64_t)g->n * ((uint64_t)y + (uint64_t)g->n * z);
    return (int)((g->bits[i >> 6] >> (i & 63)) & 1u);
}

/* A summed-volume table over an n^3 grid of counts: t[x + m (y + m z)],
 * m = n + 1, holds the sum over cells [0, x) x [0, y) x [0, z), so that a
 * box of cells sums in 8 reads. Its (n + 1)^3 entries are the caller's. */
typedef struct voxel_svt {
    uint32_t *t;
    uint32_t m;
} voxel_svt;

/* Room for a large table of bytes bytes (voxel_svt_build's t, a table of
 * each triangle's bounds), aligned for transparent huge pages and advised
 * as such (madvise; a hint the system may ignore): three tables of 2^7
 * cells a side are 6,300 pages of 4 KiB, faulted in one by one in every
 * process that refines, and a fifth of a small object's refinement.
 * Returns NULL when out of memory; freed with voxel_table_free (NULL:
 * nothing). */
void *voxel_table_alloc(size_t bytes);
void voxel_table_free(void *t);

/* Builds s in t from n^3 bytes (cell x + n (y + n z)): the byte itself
 * (mask 0), or 1 where it has a bit of mask. The whole grid's sum must fit
 * uint32_t. */
void voxel_svt_build(voxel_svt *s, uint32_t *t, uint32_t n, const uint8_t *bytes, uint8_t mask);

/* The sum over the cells [lo, hi) on each axis (lo <= hi <= n). Inline:
 * the refinement's division asks it at every split it weighs. */
static inline uint32_t voxel_svt_sum(const voxel_svt *s, const uint32_t lo[3], const uint32_t hi[3])
{
    size_t m = s->m;
#define T(x, y, z) s->t[(size_t)(x) + m * ((size_t)(y) + m * (size_t)(z))]
    int64_t v = (int64_t)T(hi[0], hi[1], hi[2]) - T(lo[0], hi[1], hi[2]) - T(hi[0], lo[1], hi[2]) -
                T(hi[0], hi[1], lo[2]) + T(lo[0], lo[1], hi[2]) + T(lo[0], hi[1], lo[2]) + T(hi[0], lo[1], lo[2]) -
                T(lo[0], lo[1], lo[2]);
#undef T
    return (uint32_t)v;
}

/* Most threads voxel_mark_threads uses: beyond the cores of any machine
 * the server runs on, and a bound on its per-thread state (on the stack). */
#ifndef VOXEL_MAX_THREADS
#define VOXEL_MAX_THREADS 16u
#endif
/* Fewest triangles per extra thread: below that, starting a thread (tens
 * of microseconds) costs more than the triangles (tens of nanoseconds each). */
#ifndef VOXEL_MIN_TRIS_PER_THREAD
#define VOXEL_MIN_TRIS_PER_THREAD 4096u
#endif

/* voxel_mark on up to `threads` threads (0: one per CPU it may run on), each
 * setting the cells of its own slab of z layers; it sets exactly the cells
 * voxel_mark sets. Falls back to voxel_mark (this thread only) for a grid
 * under 8 cells per axis or flat in z, or for few triangles; a thread that
 * cannot be started leaves its slab to the calling thread; the CPU time of
 * the threads it started is added to g->helper_ms. voxel_mark itself never
 * starts threads. Same returns as voxel_mark. */
int voxel_mark_threads(voxel_grid *g, const float *tris, size_t ntris, unsigned threads);

/* 1 if none of the n floats at p is an infinity or a NaN (bit operations:
 * several times faster than isfinite on each). */
int voxel_finite(const float *p, size_t n);

/* The exact overlap test: 1 if the closed triangle t (9 doubles) and the
 * closed box [min, max] share a point, else 0. */
int voxel_tri_box_overlap(const double t[9], const double min[3], const double max[3]);

#endif
