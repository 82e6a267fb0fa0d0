#include "grid.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>

#include "alloc.h"

typedef struct cell {
    uint32_t *items; /* handles */
    uint32_t n, cap;
} cell;

typedef struct entry {
    float x, z;
    uint32_t cell; /* index in cells */
    uint32_t at;   /* index in that cell's items */
} entry;

struct grid {
    float min_x, min_z, inv_cell;
    uint32_t nx, nz;
    cell *cells;
    entry *entries; /* by handle */
    uint32_t capacity;
};

grid *grid_create(float min_x, float min_z, float max_x, float max_z, float cell_size, uint32_t capacity)
{
    if (!(cell_size > 0) || !(max_x > min_x) || !(max_z > min_z))
        return NULL;
    grid *g = cvre_calloc(1, sizeof *g);
    if (!g)
        return NULL;
    g->min_x = min_x;
    g->min_z = min_z;
    g->inv_cell = 1.0f / cell_size;
    g->nx = (uint32_t)ceilf((max_x - min_x) / cell_size);
    g->nz = (uint32_t)ceilf((max_z - min_z) / cell_size);
    g->nx = g->nx ? g->nx : 1;
    g->nz = g->nz ? g->nz : 1;
    g->capacity = capacity;
    g->cells = cvre_calloc((size_t)g->nx * g->nz, sizeof *g->cells);
    g->entries = cvre_calloc(capacity, sizeof *g->entries);
    if (!g->cells || !g->entries) {
        grid_destroy(g);
        return NULL;
    }
    return g;
}

void grid_destroy(grid *g)
{
    if (!g)
        return;
    if (g->cells)
        for (size_t i = 0; i < (size_t)g->nx * g->nz; i++)
            free(g->cells[i].items);
    free(g->cells);
    free(g->entries);
    free(g);
}

/* Column or row of a coordinate, clamped into the grid. */
static uint32_t coord(float v, float min, float inv, uint32_t n)
{
    float f = (v - min) * inv;
    if (!(f > 0))
        return 0;
    return f >= (float)n ? n - 1 : (uint32_t)f;
}

static uint32_t cell_of(const grid *g, float x, float z)
{
    return coord(z, g->min_z, g->inv_cell, g->nz) * g->nx + coord(x, g->min_x, g->inv_cell, g->nx);
}

static int cell_add(grid *g, uint32_t ci, uint32_t h)
{
    cell *c = &g->cells[ci];
    if (c->n == c->cap) {
        uint32_t cap = c->cap ? c->cap * 2 : 8;
        uint32_t *items = cvre_realloc(c->items, cap * sizeof *items);
        if (!items)
            return -ENOMEM;
        c->items = items;
        c->cap = cap;
    }
    g->entries[h].cell = ci;
    g->entries[h].at = c->n;
    c->items[c->n++] = h;
    return 0;
}

/* Removes the item at position at of cell ci (swap with the last). */
static void cell_del(grid *g, uint32_t ci, uint32_t at)
{
    cell *c = &g->cells[ci];
    if (at == --c->n)
        return; /* it was the last: nothing moves (its entry may already
                   describe its new cell, see grid_move) */
    uint32_t last = c->items[c->n];
    c->items[at] = last;
    g->entries[last].at = at;
}

int grid_insert(grid *g, uint32_t h, float x, float z)
{
    g->entries[h].x = x;
    g->entries[h].z = z;
    return cell_add(g, cell_of(g, x, z), h);
}

int grid_move(grid *g, uint32_t h, float x, float z)
{
    uint32_t ci = cell_of(g, x, z);
    g->entries[h].x = x;
    g->entries[h].z = z;
    uint32_t old = g->entries[h].cell, at = g->entries[h].at;
    if (ci == old)
        return 0;
    /* Add before removing: if the add fails the handle stays in its old
     * cell, still consistent, merely filed under a neighbouring cell. */
    int rc = cell_add(g, ci, h);
    if (rc < 0)
        return rc;
    cell_del(g, old, at);
    return 0;
}

void grid_remove(grid *g, uint32_t h) { cell_del(g, g->entries[h].cell, g->entries[h].at); }

uint32_t grid_query(const grid *g, float x, float z, float r, uint32_t *out, uint32_t max)
{
    uint32_t x0 = coord(x - r, g->min_x, g->inv_cell, g->nx), x1 = coord(x + r, g->min_x, g->inv_cell, g->nx);
    uint32_t z0 = coord(z - r, g->min_z, g->inv_cell, g->nz), z1 = coord(z + r, g->min_z, g->inv_cell, g->nz);
    float r2 = r * r;
    uint32_t n = 0;
    for (uint32_t cz = z0; cz <= z1; cz++) {
        for (uint32_t cx = x0; cx <= x1; cx++) {
            const cell *c = &g->cells[cz * g->nx + cx];
            for (uint32_t i = 0; i < c->n; i++) {
                const entry *e = &g->entries[c->items[i]];
                float dx = e->x - x, dz = e->z - z;
                if (dx * dx + dz * dz <= r2) {
                    if (n < max)
                        out[n] = c->items[i];
                    n++;
                }
            }
        }
    }
    return n;
}
