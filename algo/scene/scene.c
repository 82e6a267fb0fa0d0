#include "scene.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "broadphase.h"

typedef struct object {
    scene_object pub;
    float *tris;
    scene_box *local, *world;
    uint32_t *handles; /* broadphase handle of each box */
} object;

struct scene {
    object **objects; /* sorted by id: collisions look objects up every tick */
    uint32_t n, cap;
    /* Objects by slot (NULL: free), and their bounds in a broadphase of
     * their own under the slot as handle: areas of interest ask for objects,
     * not boxes. Free slots are reused. */
    object **by_slot;
    uint32_t nslots, slots_cap;
    uint32_t *free_slots, nfree_slots;
    bp *objs;
    bp *bp;
    /* Every world box by broadphase handle; free handles are chained
     * through free_next. */
    scene_box_ref *boxes;
    uint32_t *free_next;
    uint32_t nboxes, boxes_cap, free_head;
};

#define NO_HANDLE UINT32_MAX
/* Cell side of the objects' broadphase: objects are larger than their
 * boxes (a room, a desk, a building) and are asked for by areas of
 * interest tens of metres wide. */
#define SCENE_OBJECT_CELL 16.0f

scene *scene_create(const float world_min[3], const float world_max[3])
{
    scene *s = cvre_calloc(1, sizeof(scene));
    if (!s)
        return NULL;
    s->free_head = NO_HANDLE;
    s->bp = bp_create(world_min, world_max, BP_CELL_DEFAULT);
    s->objs = bp_create(world_min, world_max, SCENE_OBJECT_CELL);
    if (!s->bp || !s->objs) {
        scene_destroy(s);
        return NULL;
    }
    return s;
}

/* A free handle for a new box, or NO_HANDLE when out of memory. */
static uint32_t handle_take(scene *s)
{
    if (s->free_head != NO_HANDLE) {
        uint32_t h = s->free_head;
        s->free_head = s->free_next[h];
        return h;
    }
    if (s->nboxes == s->boxes_cap) {
        uint32_t cap = s->boxes_cap ? s->boxes_cap * 2 : 256;
        scene_box_ref *b = cvre_realloc(s->boxes, cap * sizeof *b);
        if (!b)
            return NO_HANDLE;
        s->boxes = b;
        uint32_t *f = cvre_realloc(s->free_next, cap * sizeof *f);
        if (!f)
            return NO_HANDLE;
        s->free_next = f;
        s->boxes_cap = cap;
    }
    return s->nboxes++;
}

static void handle_give(scene *s, uint32_t h)
{
    s->free_next[h] = s->free_head;
    s->free_head = h;
}

/* A free slot for a new object, or NO_HANDLE when out of memory. */
static uint32_t slot_take(scene *s)
{
    if (s->nfree_slots)
        return s->free_slots[--s->nfree_slots];
    if (s->nslots == s->slots_cap) {
        uint32_t cap = s->slots_cap ? s->slots_cap * 2 : 64;
        object **by_slot = cvre_realloc(s->by_slot, cap * sizeof *by_slot);
        if (!by_slot)
            return NO_HANDLE;
        s->by_slot = by_slot;
        uint32_t *free_slots = cvre_realloc(s->free_slots, cap * sizeof *free_slots);
        if (!free_slots)
            return NO_HANDLE;
        s->free_slots = free_slots;
        s->slots_cap = cap;
    }
    s->by_slot[s->nslots] = NULL;
    return s->nslots++;
}

static void slot_give(scene *s, uint32_t slot)
{
    s->by_slot[slot] = NULL;
    s->free_slots[s->nfree_slots++] = slot;
}

static void object_free(object *o)
{
    if (!o)
        return;
    free(o->handles);
    free(o->tris);
    free(o->local);
    free(o->world);
    free(o);
}

void scene_destroy(scene *s)
{
    if (!s)
        return;
    for (uint32_t i = 0; i < s->n; i++)
        object_free(s->objects[i]);
    free(s->objects);
    free(s->by_slot);
    free(s->free_slots);
    bp_destroy(s->objs);
    bp_destroy(s->bp);
    free(s->boxes);
    free(s->free_next);
    free(s);
}

void scene_to_world(const proto_transform *at, const float l[3], float w[3])
{
    float c = cosf(at->yaw), sn = sinf(at->yaw), x = l[0] * at->scale, y = l[1] * at->scale, z = l[2] * at->scale;
    w[0] = c * x + sn * z + at->pos[0];
    w[1] = y + at->pos[1];
    w[2] = -sn * x + c * z + at->pos[2];
}

void scene_to_local(const proto_transform *at, const float w[3], float l[3])
{
    float c = cosf(at->yaw), sn = sinf(at->yaw);
    float x = w[0] - at->pos[0], y = w[1] - at->pos[1], z = w[2] - at->pos[2];
    l[0] = (c * x - sn * z) / at->scale;
    l[1] = y / at->scale;
    l[2] = (sn * x + c * z) / at->scale;
}

void scene_box_to_world(const proto_transform *at, const scene_box *b, scene_box *out)
{
    for (int k = 0; k < 3; k++) {
        out->min[k] = INFINITY;
        out->max[k] = -INFINITY;
    }
    for (int corner = 0; corner < 8; corner++) {
        float l[3] = {corner & 1 ? b->max[0] : b->min[0], corner & 2 ? b->max[1] : b->min[1],
                      corner & 4 ? b->max[2] : b->min[2]},
              w[3];
        scene_to_world(at, l, w);
        for (int k = 0; k < 3; k++) {
            out->min[k] = fminf(out->min[k], w[k]);
            out->max[k] = fmaxf(out->max[k], w[k]);
        }
    }
}

/* Binary search: the object with this id (and its index), or NULL and in
 * *index the position where it would go. */
static object *find(const scene *s, uint32_t id, uint32_t *index)
{
    uint32_t lo = 0, hi = s->n;
    while (lo < hi) {
        uint32_t mid = lo + (hi - lo) / 2;
        if (s->objects[mid]->pub.id < id)
            lo = mid + 1;
        else
            hi = mid;
    }
    if (index)
        *index = lo;
    return lo < s->n && s->objects[lo]->pub.id == id ? s->objects[lo] : NULL;
}

/* The world AABB of n local boxes under at. Returns 0, or -EINVAL if a
 * coordinate of a world box would not be finite (fminf would hide a NaN,
 * so every box is checked). */
static int bounds_at(const scene_box *local, uint32_t n, const proto_transform *at, scene_box *out)
{
    *out = (scene_box){{INFINITY, INFINITY, INFINITY}, {-INFINITY, -INFINITY, -INFINITY}};
    for (uint32_t i = 0; i < n; i++) {
        scene_box w;
        scene_box_to_world(at, &local[i], &w);
        for (int k = 0; k < 3; k++) {
            if (!isfinite(w.min[k]) || !isfinite(w.max[k]))
                return -EINVAL;
            out->min[k] = fminf(out->min[k], w.min[k]);
            out->max[k] = fmaxf(out->max[k], w.max[k]);
        }
    }
    return 0;
}

int scene_check_fit(const scene_box *local, uint32_t n, const proto_transform *at, const scene_limits *lim,
                    char *why, size_t whylen)
{
    scene_box b;
    if (bounds_at(local, n, at, &b) < 0) {
        snprintf(why, whylen, "its boxes would not be finite");
        return -EINVAL;
    }
    static const char axis[] = "xyz";
    for (int k = 0; k < 3; k++) {
        if (b.max[k] - b.min[k] > lim->max_size) {
            snprintf(why, whylen, "it would be %.0f m long along %c; at most %.0f m", (double)(b.max[k] - b.min[k]),
                     axis[k], (double)lim->max_size);
            return -EINVAL;
        }
        if (b.min[k] < lim->min[k] || b.max[k] > lim->max[k]) {
            snprintf(why, whylen, "it would reach %c %.1f..%.1f, past the world's %.0f..%.0f", axis[k],
                     (double)b.min[k], (double)b.max[k], (double)lim->min[k], (double)lim->max[k]);
            return -EINVAL;
        }
    }
    return 0;
}

/* Sets o's transform, its world boxes and bounds, in the box table and the
 * broadphases too once they are filed there. Returns 0, or -EINVAL (a box
 * would not be finite) leaving o as it was. */
static int place(scene *s, object *o, const proto_transform *at)
{
    scene_box bounds;
    if (bounds_at(o->local, o->pub.box_count, at, &bounds) < 0)
        return -EINVAL;
    o->pub.at = *at;
    o->pub.bounds = bounds;
    o->pub.rev++;
    for (uint32_t i = 0; i < o->pub.box_count; i++) {
        scene_box_to_world(at, &o->local[i], &o->world[i]);
        uint32_t h = o->handles[i];
        if (h == NO_HANDLE)
            continue;
        s->boxes[h].world = o->world[i];
        /* Only out of memory fails here, and the loop aborts on that
         * before the next tick could use a stale box. */
        (void)bp_update(s->bp, o->world[i].min, o->world[i].max, h);
    }
    if (s->by_slot && o->pub.slot < s->nslots && s->by_slot[o->pub.slot] == o)
        (void)bp_update(s->objs, bounds.min, bounds.max, o->pub.slot);
    return 0;
}

/* Gives o's boxes handles and files them in the broadphase. */
static int file_boxes(scene *s, object *o)
{
    for (uint32_t i = 0; i < o->pub.box_count; i++) {
        uint32_t h = handle_take(s);
        if (h == NO_HANDLE)
            return -ENOMEM;
        s->boxes[h] = (scene_box_ref){.object_id = o->pub.id, .box_index = i, .world = o->world[i]};
        int rc = bp_insert(s->bp, o->world[i].min, o->world[i].max, h);
        if (rc < 0) {
            handle_give(s, h);
            return rc;
        }
        o->handles[i] = h;
    }
    return 0;
}

static void unfile_boxes(scene *s, object *o)
{
    for (uint32_t i = 0; i < o->pub.box_count; i++)
        if (o->handles[i] != NO_HANDLE) {
            bp_remove(s->bp, o->handles[i]);
            handle_give(s, o->handles[i]);
            o->handles[i] = NO_HANDLE;
        }
}

int scene_add(scene *s, const scene_object_def *d)
{
    if (find(s, d->id, NULL))
        return -EEXIST;
    if (d->box_count == 0 || d->box_count > PROTO_OBJECT_BOXES_MAX)
        return -EINVAL;
    if (s->n == s->cap) {
        uint32_t cap = s->cap ? s->cap * 2 : 16;
        object **objects = cvre_realloc(s->objects, cap * sizeof *objects);
        if (!objects)
            return -ENOMEM;
        s->objects = objects;
        s->cap = cap;
    }
    object *o = cvre_calloc(1, sizeof *o);
    size_t tri_bytes = (size_t)d->tri_count * 9 * sizeof(float);
    if (!o || !(o->tris = cvre_malloc(tri_bytes)) || !(o->local = cvre_calloc(d->box_count, sizeof(scene_box))) ||
        !(o->world = cvre_calloc(d->box_count, sizeof(scene_box))) ||
        !(o->handles = cvre_malloc(d->box_count * sizeof(uint32_t)))) {
        object_free(o);
        return -ENOMEM;
    }
    if (tri_bytes)
        memcpy(o->tris, d->tris, tri_bytes);
    memcpy(o->local, d->boxes, d->box_count * sizeof(scene_box));
    o->pub.id = d->id;
    snprintf(o->pub.owner, sizeof o->pub.owner, "%s", d->owner);
    snprintf(o->pub.name, sizeof o->pub.name, "%s", d->name);
    o->pub.ecm_version = d->ecm_version;
    o->pub.tri_count = d->tri_count;
    o->pub.tris = o->tris;
    if (d->mesh_hash)
        memcpy(o->pub.mesh_hash, d->mesh_hash, sizeof o->pub.mesh_hash);
    o->pub.box_count = d->box_count;
    o->pub.local = o->local;
    o->pub.world = o->world;
    for (uint32_t i = 0; i < d->box_count; i++)
        o->handles[i] = NO_HANDLE;
    int rc = place(s, o, &d->at);
    if (rc == 0)
        rc = file_boxes(s, o);
    uint32_t slot = rc == 0 ? slot_take(s) : NO_HANDLE;
    if (rc == 0 && slot == NO_HANDLE)
        rc = -ENOMEM;
    if (rc == 0 && (rc = bp_insert(s->objs, o->pub.bounds.min, o->pub.bounds.max, slot)) < 0)
        slot_give(s, slot);
    if (rc < 0) {
        unfile_boxes(s, o);
        object_free(o);
        return rc;
    }
    o->pub.slot = slot;
    s->by_slot[slot] = o;
    uint32_t at;
    find(s, o->pub.id, &at);
    memmove(s->objects + at + 1, s->objects + at, (s->n - at) * sizeof *s->objects);
    s->objects[at] = o;
    s->n++;
    return 0;
}

int scene_remove(scene *s, uint32_t id)
{
    uint32_t i;
    object *o = find(s, id, &i);
    if (!o)
        return -ENOENT;
    unfile_boxes(s, o);
    bp_remove(s->objs, o->pub.slot);
    slot_give(s, o->pub.slot);
    object_free(o);
    memmove(s->objects + i, s->objects + i + 1, (--s->n - i) * sizeof *s->objects);
    return 0;
}

int scene_place(scene *s, uint32_t id, const proto_transform *at)
{
    object *o = find(s, id, NULL);
    if (!o)
        return -ENOENT;
    return place(s, o, at);
}

int scene_set_owner(scene *s, uint32_t id, const char *owner)
{
    object *o = find(s, id, NULL);
    if (!o)
        return -ENOENT;
    snprintf(o->pub.owner, sizeof o->pub.owner, "%s", owner);
    o->pub.rev++;
    return 0;
}

int scene_set_ecm(scene *s, uint32_t id, uint32_t version, const scene_box *boxes, uint32_t count)
{
    object *o = find(s, id, NULL);
    if (!o)
        return -ENOENT;
    scene_box bounds;
    if (count == 0 || count > PROTO_OBJECT_BOXES_MAX || bounds_at(boxes, count, &o->pub.at, &bounds) < 0)
        return -EINVAL;
    scene_box *local = cvre_malloc(count * sizeof *local), *world = cvre_malloc(count * sizeof *world);
    uint32_t *handles = cvre_malloc(count * sizeof *handles);
    if (!local || !world || !handles) {
        free(local);
        free(world);
        free(handles);
        return -ENOMEM;
    }
    memcpy(local, boxes, count * sizeof *local);
    for (uint32_t i = 0; i < count; i++)
        handles[i] = NO_HANDLE;
    object old = *o;
    unfile_boxes(s, o);
    o->pub.local = o->local = local;
    o->pub.world = o->world = world;
    o->handles = handles;
    o->pub.box_count = count;
    (void)place(s, o, &o->pub.at); /* finite: checked above */
    int rc = file_boxes(s, o);
    if (rc < 0) {
        /* Back to the old boxes: the handles just given back make room. */
        unfile_boxes(s, o);
        free(local);
        free(world);
        free(handles);
        *o = old;
        (void)file_boxes(s, o);
        (void)bp_update(s->objs, o->pub.bounds.min, o->pub.bounds.max, o->pub.slot);
        return rc;
    }
    o->pub.ecm_version = version;
    free(old.local);
    free(old.world);
    free(old.handles);
    return 0;
}

const scene_object *scene_get(const scene *s, uint32_t id)
{
    const object *o = find(s, id, NULL);
    return o ? &o->pub : NULL;
}

uint32_t scene_count(const scene *s) { return s->n; }

const scene_object *scene_at(const scene *s, uint32_t i) { return &s->objects[i]->pub; }

uint32_t scene_slots(const scene *s) { return s->nslots; }

const scene_object *scene_at_slot(const scene *s, uint32_t slot)
{
    return slot < s->nslots && s->by_slot[slot] ? &s->by_slot[slot]->pub : NULL;
}

uint32_t scene_query_objects(const scene *s, const float min[3], const float max[3], uint32_t *out,
                             uint32_t out_max)
{
    return bp_query(s->objs, min, max, out, out_max);
}

uint32_t scene_query(const scene *s, const float min[3], const float max[3], uint32_t *out, uint32_t out_max)
{
    return bp_query(s->bp, min, max, out, out_max);
}

const scene_box_ref *scene_box_at(const scene *s, uint32_t handle) { return &s->boxes[handle]; }
