/*
 * broadphase.h: every static ECM box of the world in one structure that
 * answers "which boxes overlap this AABB" (an avatar's swept volume) without
 * looking at all of them. Pure module: no I/O, no locks (one writer).
 *
 * Boxes are world-space AABBs named by a caller-chosen handle: a small
 * integer below BP_MAX_HANDLE, typically the slot of the box in the scene's
 * own table. Memory is proportional to the largest handle ever inserted, so
 * handles should be dense. Boxes change rarely (an object placed, moved or
 * refined); queries happen for every avatar on every tick.
 *
 * Overlap is closed: boxes that merely touch the query (a shared face, edge
 * or corner) match, and so do zero-thickness boxes. A query reports each
 * overlapping box exactly once, however many cells it spans. Boxes and
 * queries partly or wholly outside the world bounds given at creation are
 * answered exactly too, only more slowly (they share the border cells).
 */
#ifndef CVRE_BROADPHASE_H
#define CVRE_BROADPHASE_H

#include <stdint.h>

/* Handles are indices into a table of 28-byte entries that grows to the
 * largest handle: 2^24 handles (448 MiB of table) is far more boxes than one
 * server holds (a few hundred thousand) and bounds what a bad handle costs. */
#ifndef BP_MAX_HANDLE
#define BP_MAX_HANDLE (1u << 24)
#endif

/* Default side of the finest cells, in metres; see bp_create. Measured with
 * tests/bench/bench_broadphase.c (boxes of 0.2 to 10 m, walls to 30 m,
 * avatar sweeps under 1 m): 3 to 8 m are within 10% of each other in both a
 * sparse and a dense world, 2 m is 30% slower in the dense one. Smaller
 * cells copy boxes into more cells, larger ones scan more boxes that miss. */
#ifndef BP_CELL_DEFAULT
#define BP_CELL_DEFAULT 4.0f
#endif

typedef struct bp bp;

/*
 * Creates an empty broadphase over the world box [world_min, world_max]. Only
 * x and z are gridded (the world is wide and flat); y is tested per box.
 * cell is the side of the finest cells in metres, or 0 for BP_CELL_DEFAULT;
 * the right value is near the median box size. Returns NULL if out of memory
 * or if the bounds or cell size are unusable (not finite, empty, or more than
 * 65,535 cells along an axis).
 */
bp *bp_create(const float world_min[3], const float world_max[3], float cell);
void bp_destroy(bp *b);

/*
 * Adds the box [min, max] under handle. Returns 0; -EINVAL if handle is not
 * below BP_MAX_HANDLE, a coordinate is not finite or min > max on an axis;
 * -EEXIST if handle is present; -ENOMEM, leaving the broadphase unchanged.
 */
int bp_insert(bp *b, const float min[3], const float max[3], uint32_t handle);

/* Removes the box under handle. Returns 0, or -ENOENT if it is not present. */
int bp_remove(bp *b, uint32_t handle);

/*
 * Replaces the box under handle (an object moved or refined) by [min, max].
 * Returns what bp_insert returns, or -ENOENT if the handle is not present;
 * on any error the old box stays in place.
 */
int bp_update(bp *b, const float min[3], const float max[3], uint32_t handle);

/*
 * Writes to out (room for out_max) the handles of the boxes overlapping
 * [min, max], each once, in no particular order but always the same order for
 * the same contents and history. Returns how many overlap, which may exceed
 * out_max: only the first out_max are written. A query with a NaN, or with
 * min > max on an axis, matches nothing. Does not modify b: queries may run
 * from several threads at once if nothing writes meanwhile.
 */
uint32_t bp_query(const bp *b, const float min[3], const float max[3], uint32_t *out, uint32_t out_max);

/* A query box for bp_query_batch: min then max, six floats in a row. */
typedef struct bp_box {
    float min[3], max[3];
} bp_box;

/*
 * Answers nq queries as bp_query would one after the other, only faster: it
 * asks memory for the cells of the queries to come while it scans the current
 * one. The handles overlapping q[i] are out[off[i]] .. out[off[i + 1] - 1]
 * (off has room for nq + 1). Returns the total of all the lists, which may
 * exceed out_max: then the lists are cut where out fills up (every off is at
 * most out_max).
 */
uint32_t bp_query_batch(const bp *b, const bp_box *q, uint32_t nq, uint32_t *out, uint32_t out_max, uint32_t *off);

/*
 * Lays the per-cell lists out again contiguously, in cell order, with a
 * quarter more room in each to grow. Inserts keep the structure exact but
 * move growing lists to the end of one array, leaving holes (at most as much
 * memory again) and scattering neighbouring cells; call this after loading a
 * world or a large batch of changes. Returns 0, or -ENOMEM and changes nothing.
 */
int bp_optimize(bp *b);

/* Boxes present. */
uint32_t bp_count(const bp *b);

#endif
