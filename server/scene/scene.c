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
    bp *bp;
    /* Every world box by broadphase handle; free handles are chained
     * through free_next. */
    scene_box_ref *boxes;
    uint32_t *free_next;
    uint32_t nboxes, boxes_cap, free_head;
};

#define NO_HANDLE UINT32_MAX

scene *scene_create(const float world_min[3], const float world_max[3])
{
    scene *s = cvre_calloc(1, sizeof(scene));
    if (!s)
        return NULL;
    s->free_head = NO_HANDLE;
    s->bp = bp_create(world_min, world_max, BP_CELL_DEFAULT);
    if (!s->bp) {
        free(s);
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

/* Sets o's transform and its world boxes, in the box table and in the
 * broadphase too once they have handles. */
static void place(scene *s, object *o, const proto_transform *at)
{
    o->pub.at = *at;
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
}

/* Gives o's boxes handles and files them in the broadphase. */
static int file_boxes(scene *s, object *o)
{
    for (uint32_t i = 0; i < o->pub.box_count; i++) {
        uint32_t h = handle_take(s);
        if (h == NO_HANDLE)
            return -ENOMEM;
        s->boxes[h] = (scene_box_ref){.object_id = o->pub.id, .box_index = i, .world = o->world[i]};
        if (bp_insert(s->bp, o->world[i].min, o->world[i].max, h) < 0) {
            handle_give(s, h);
            return -ENOMEM;
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
    o->pub.box_count = d->box_count;
    o->pub.local = o->local;
    o->pub.world = o->world;
    for (uint32_t i = 0; i < d->box_count; i++)
        o->handles[i] = NO_HANDLE;
    place(s, o, &d->at);
    int rc = file_boxes(s, o);
    if (rc < 0) {
        unfile_boxes(s, o);
        object_free(o);
        return rc;
    }
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
    object_free(o);
    memmove(s->objects + i, s->objects + i + 1, (--s->n - i) * sizeof *s->objects);
    return 0;
}

int scene_place(scene *s, uint32_t id, const proto_transform *at)
{
    object *o = find(s, id, NULL);
    if (!o)
        return -ENOENT;
    place(s, o, at);
    return 0;
}

int scene_set_owner(scene *s, uint32_t id, const char *owner)
{
    object *o = find(s, id, NULL);
    if (!o)
        return -ENOENT;
    snprintf(o->pub.owner, sizeof o->pub.owner, "%s", owner);
    return 0;
}

int scene_set_ecm(scene *s, uint32_t id, uint32_t version, const scene_box *boxes, uint32_t count)
{
    object *o = find(s, id, NULL);
    if (!o)
        return -ENOENT;
    if (count == 0 || count > PROTO_OBJECT_BOXES_MAX)
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
    place(s, o, &o->pub.at);
    int rc = file_boxes(s, o);
    if (rc < 0) {
        /* Back to the old boxes: the handles just given back make room. */
        unfile_boxes(s, o);
        free(local);
        free(world);
        free(handles);
        *o = old;
        (void)file_boxes(s, o);
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

uint32_t scene_query(const scene *s, const float min[3], const float max[3], uint32_t *out, uint32_t out_max)
{
    return bp_query(s->bp, min, max, out, out_max);
}

const scene_box_ref *scene_box_at(const scene *s, uint32_t handle) { return &s->boxes[handle]; }
