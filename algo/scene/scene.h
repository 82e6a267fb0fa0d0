/*
 * scene.h: the objects in the world and their collision maps (ECM).
 *
 * An object is a mesh in object-local coordinates (Y up, metres), a transform
 * (world = R_y(yaw) * (scale * local) + pos) and the boxes of its current ECM
 * version, also local. The scene keeps every box's world AABB, which is what
 * avatars collide with; for a yaw that is not a multiple of 90 degrees the
 * world AABB of a turned box is larger than the box (conservative: it never
 * lets an avatar into geometry). Single-threaded (the tick thread).
 */
#ifndef CVRE_SCENE_H
#define CVRE_SCENE_H

#include <stdint.h>

#include "proto.h"

typedef struct scene scene;

typedef struct scene_box {
    float min[3], max[3];
} scene_box;

/* A read-only view of one object. */
typedef struct scene_object {
    uint32_t id;
    uint32_t slot;           /* dense, below scene_slots(); reused after a removal */
    uint32_t rev;            /* grows with every change a client sees (place, boxes, owner) */
    char owner[PROTO_NAME_MAX + 1];
    char name[PROTO_OBJECT_NAME_MAX + 1];
    proto_transform at;
    uint32_t ecm_version;
    uint32_t tri_count;
    const float *tris;       /* 9 floats a triangle, local */
    uint8_t mesh_hash[PROTO_MESH_HASH_SIZE]; /* names the mesh to clients (db_mesh_hash) */
    uint32_t box_count;
    const scene_box *local;  /* ECM boxes, local */
    const scene_box *world;  /* the same, as world AABBs */
    scene_box bounds;        /* the world AABB around all of them */
} scene_object;

/* What a new object, or a new ECM version, is made of. The scene copies
 * everything it is given. */
typedef struct scene_object_def {
    uint32_t id;
    const char *owner;
    const char *name;
    proto_transform at;
    uint32_t ecm_version;
    uint32_t tri_count;
    const float *tris;
    const uint8_t *mesh_hash; /* PROTO_MESH_HASH_SIZE bytes; NULL: zeros */
    uint32_t box_count;
    const scene_box *boxes; /* local */
} scene_object_def;

/* One world box, found by its broadphase handle. */
typedef struct scene_box_ref {
    uint32_t object_id, box_index;
    scene_box world;
} scene_box_ref;

/* A scene over a world of these bounds (its broadphase's extent; boxes
 * outside still work, filed at the border). NULL if out of memory. */
scene *scene_create(const float world_min[3], const float world_max[3]);
void scene_destroy(scene *s);

/* Adds an object. Returns 0, -EEXIST if the id is taken, -EINVAL for no
 * boxes, more than PROTO_OBJECT_BOXES_MAX or a world box that is not finite,
 * or -ENOMEM. */
int scene_add(scene *s, const scene_object_def *def);
/* Removes an object; -ENOENT if there is none with that id. */
int scene_remove(scene *s, uint32_t id);
/* Moves, turns or rescales an object (its world boxes follow). Returns 0,
 * -ENOENT, -EINVAL if a world box would not be finite, or -ENOMEM; on an
 * error the object stays where it was. */
int scene_place(scene *s, uint32_t id, const proto_transform *at);
/* Where objects may stand: inside [min, max], and at most max_size long
 * along any axis. */
typedef struct scene_limits {
    float min[3], max[3];
    float max_size;
} scene_limits;
/* Checks what n local boxes would become under transform at (nothing is
 * changed): every world box finite, their bounds inside lim. Returns 0, or
 * -EINVAL with the reason in why (a sentence without a final stop). */
int scene_check_fit(const scene_box *local, uint32_t n, const proto_transform *at, const scene_limits *lim,
                    char *why, size_t whylen);

/* Replaces an object's boxes with those of ECM version `version` (local
 * boxes, copied), between ticks: the next query sees only the new ones.
 * Returns 0, -ENOENT, -EINVAL as scene_add, or -ENOMEM (the object keeps
 * its boxes). */
int scene_set_ecm(scene *s, uint32_t id, uint32_t version, const scene_box *boxes, uint32_t count);
/* Gives object id to owner (a deleted account's objects pass to the world
 * account). 0 or -ENOENT. */
int scene_set_owner(scene *s, uint32_t id, const char *owner);

/* The object, or NULL. Valid until the next change to the scene. */
const scene_object *scene_get(const scene *s, uint32_t id);
uint32_t scene_count(const scene *s);
/* Object i in 0..scene_count()-1, in id order. */
const scene_object *scene_at(const scene *s, uint32_t i);
/* One more than the largest slot in use: the size of a per-slot table. */
uint32_t scene_slots(const scene *s);
/* The object in a slot, or NULL for a free slot. */
const scene_object *scene_at_slot(const scene *s, uint32_t slot);
/* Writes to out (room for out_max) the slots of the objects whose bounds
 * overlap [min, max], each once; returns how many there are, which may
 * exceed out_max. */
uint32_t scene_query_objects(const scene *s, const float min[3], const float max[3], uint32_t *out,
                             uint32_t out_max);

/* Writes to out (room for out_max) the handles of the world boxes that overlap
 * [min, max]; returns how many there are, which may exceed out_max. */
uint32_t scene_query(const scene *s, const float min[3], const float max[3], uint32_t *out, uint32_t out_max);
/* The box behind a handle scene_query returned (valid until the next change). */
const scene_box_ref *scene_box_at(const scene *s, uint32_t handle);

/* Transforms a local point to world coordinates and back. */
void scene_to_world(const proto_transform *at, const float local[3], float world[3]);
void scene_to_local(const proto_transform *at, const float world[3], float local[3]);
/* The world AABB of a local box under a transform. */
void scene_box_to_world(const proto_transform *at, const scene_box *local, scene_box *world);

#endif
