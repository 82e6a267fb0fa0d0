/* known.c: the objects this client knows of (see known.h). */
#include "known.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"

/* Sorted by id: lookups are binary searches, and a join into a crowded
 * place inserts mostly at the end (the server sends nearest first, but ids
 * grow with time). */
struct known {
    known_object *objs;
    size_t n, cap;
};

known *known_create(void) { return cvre_xcalloc(1, sizeof(known)); }

void known_free(known *k)
{
    if (!k)
        return;
    for (size_t i = 0; i < k->n; i++)
        free(k->objs[i].boxes);
    free(k->objs);
    free(k);
}

/* Index of the first entry whose id is >= id. */
static size_t find(const known *k, uint32_t id)
{
    size_t lo = 0, hi = k->n;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (k->objs[mid].id < id)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

const known_object *known_get(const known *k, uint32_t id)
{
    size_t i = find(k, id);
    return i < k->n && k->objs[i].id == id ? &k->objs[i] : NULL;
}

void known_put(known *k, const proto_object_info *o)
{
    size_t i = find(k, o->object_id);
    if (i == k->n || k->objs[i].id != o->object_id) {
        if (k->n == k->cap) {
            k->cap = k->cap ? k->cap * 2 : 64;
            k->objs = cvre_xrealloc(k->objs, k->cap * sizeof *k->objs);
        }
        memmove(k->objs + i + 1, k->objs + i, (k->n - i) * sizeof *k->objs);
        k->n++;
        k->objs[i] = (known_object){.id = o->object_id};
    }
    known_object *e = &k->objs[i];
    e->yaw = o->at.yaw;
    e->scale = o->at.scale;
    e->tri_count = o->tri_count;
    memcpy(e->mesh_hash, o->mesh_hash, sizeof e->mesh_hash);
    if (o->box_count > e->n_boxes || !e->boxes)
        e->boxes = cvre_xrealloc(e->boxes, (o->box_count ? o->box_count : 1u) * sizeof *e->boxes);
    e->n_boxes = o->box_count;
    for (uint16_t b = 0; b < o->box_count; b++)
        proto_object_box(o, b, e->boxes[b], e->boxes[b] + 3);
}

void known_del(known *k, uint32_t id)
{
    size_t i = find(k, id);
    if (i < k->n && k->objs[i].id == id) {
        free(k->objs[i].boxes);
        memmove(k->objs + i, k->objs + i + 1, (k->n - i - 1) * sizeof *k->objs);
        k->n--;
    }
}

int known_bounds(const proto_object_info *o, float lo[3], float hi[3])
{
    if (o->box_count == 0)
        return -ENOENT;
    proto_object_box(o, 0, lo, hi);
    for (uint16_t b = 1; b < o->box_count; b++) {
        float bl[3], bh[3];
        proto_object_box(o, b, bl, bh);
        for (int a = 0; a < 3; a++) {
            if (bl[a] < lo[a])
                lo[a] = bl[a];
            if (bh[a] > hi[a])
                hi[a] = bh[a];
        }
    }
    return 0;
}

float known_surface_below(const known *k, uint32_t except, const float lo[3], const float hi[3], float floor_y)
{
    float best = floor_y;
    for (size_t i = 0; i < k->n; i++) {
        const known_object *e = &k->objs[i];
        if (e->id == except)
            continue;
        for (uint16_t b = 0; b < e->n_boxes; b++) {
            const float *box = e->boxes[b];
            /* Footprints that only touch at an edge hold nothing up. */
            if (box[0] >= hi[0] || box[3] <= lo[0] || box[2] >= hi[2] || box[5] <= lo[2])
                continue;
            if (box[4] <= lo[1] + KNOWN_SNAP_M && box[4] > best)
                best = box[4];
        }
    }
    return best;
}
