#include "grid.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>

#include "alloc.h"

/* A cell keeps its handles with their coordinates, so a query scans memory
 * in order instead of chasing every handle to its entry. */
typedef struct item {
    uint32_t h;
    float x, z;
} item;

typedef struct cell {
    item *items;
    uint32_t n, cap;
} cell;

typedef struct entry {
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

static int cell_add(grid *g, uint32_t ci, uint32_t h, float x, float z)
{
    cell *c = &g->cells[ci];
    if (c->n == c->cap) {
        uint32_t cap = c->cap ? c->cap * 2 : 8;
        item *items = cvre_realloc(c->items, cap * sizeof *items);
        if (!items)
            return -ENOMEM;
        c->items = items;
        c->cap = cap;
    }
    g->entries[h].cell = ci;
    g->entries[h].at = c->n;
    c->items[c->n++] = (item){h, x, z};
    return 0;
}

/* Removes the item at position at of cell ci (swap with the last). */
static void cell_del(grid *g, uint32_t ci, uint32_t at)
{
    cell *c = &g->cells[ci];
    if (at == --c->n)
        return; /* it was the last: nothing moves (its entry may already
                   describe its new cell, see grid_move) */
    c->items[at] = c->items[c->n];
    g->entries[c->items[at].h].at = at;
}

int grid_insert(grid *g, uint32_t h, float x, float z) { return cell_add(g, cell_of(g, x, z), h, x, z); }

int grid_move(grid *g, uint32_t h, float x, float z)
{
    uint32_t ci = cell_of(g, x, z);
    uint32_t old = g->entries[h].cell, at = g->entries[h].at;
    if (ci == old) {
        g->cells[ci].items[at].x = x;
        g->cells[ci].items[at].z = z;
        return 0;
    }
    /* Add before removing: if the add fails the handle stays in its old
     * cell with its new coordinates, still consistent, merely filed under a
     * neighbouring cell (a query may miss it until its next move). */
    int rc = cell_add(g, ci, h, x, z);
    if (rc < 0) {
        g->cells[old].items[at].x = x;
        g->cells[old].items[at].z = z;
        return rc;
    }
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
                float dx = c->items[i].x - x, dz = c->items[i].z - z;
                if (dx * dx + dz * dz <= r2) {
                    if (n < max)
                        out[n] = c->items[i].h;
                    n++;
                }
            }
        }
    }
    return n;
}
