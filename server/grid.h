/*
 * grid.h: a uniform grid over the world's horizontal plane (x, z) that
 * answers "which handles lie within r of this point" without looking at all
 * of them. Handles are small integers below the capacity given at creation
 * (the world uses avatar slots). Pure module: no I/O.
 */
#ifndef CVRE_GRID_H
#define CVRE_GRID_H

#include <stdint.h>

typedef struct grid grid;

/* A grid over [min_x, max_x] x [min_z, max_z] with square cells of side
 * cell (> 0) and room for handles 0..capacity-1. Points outside the bounds
 * are clamped into the border cells. NULL if out of memory. */
grid *grid_create(float min_x, float min_z, float max_x, float max_z, float cell, uint32_t capacity);
void grid_destroy(grid *g);

/* Inserts handle h (not present) at (x, z). Returns 0 or -ENOMEM. */
int grid_insert(grid *g, uint32_t h, float x, float z);
/* Moves present handle h to (x, z); cheap when it stays in its cell.
 * Returns 0 or -ENOMEM. */
int grid_move(grid *g, uint32_t h, float x, float z);
/* Removes present handle h. */
void grid_remove(grid *g, uint32_t h);

/* Writes to out (room for max) the handles whose point lies within distance
 * r (inclusive) of (x, z), in no particular order. Returns how many matched,
 * which may exceed max: only the first max are written. */
uint32_t grid_query(const grid *g, float x, float z, float r, uint32_t *out, uint32_t max);

#endif
