/*
 * world.h: the authoritative simulation state: avatars, their movement, and
 * who is near whom. Single-threaded (the tick thread). No I/O.
 *
 * Avatars are boxes whose position is the centre of the bottom face; y is up
 * and the floor is y = min[1]. A client's move is recorded as a request and
 * applied at the next world_step, limited to max_speed x elapsed time and
 * clamped into the world.
 */
#ifndef CVRE_WORLD_H
#define CVRE_WORLD_H

#include <stdint.h>

#include "proto.h"
#include "move.h"
#include "scene.h"

typedef struct world world;

/* How far from its random spawn point an avatar's free spot is looked for,
 * in metres: a large object at the spawn point (a building users start
 * outside of) is tens of metres across. */
#ifndef WORLD_SPAWN_SEARCH
#define WORLD_SPAWN_SEARCH 64.0f
#endif

/* A pose is passed on to the avatar's viewers only when it moved this far
 * from the one they were last given: the facing by 0.01 rad (half a
 * degree, the least a viewer can notice at a few metres), the head or a
 * hand by 5 mm or 0.02 rad of turn. Below that a tracked headset's jitter
 * alone would send a pose every tick. */
#define WORLD_POSE_ANGLE_MIN 0.01f
#define WORLD_POSE_MOVE_MIN_MM 5
#define WORLD_POSE_TURN_MIN 0.02f

/* An avatar id is its slot (below the world's capacity) plus a generation
 * in the upper bits, so per-avatar tables can be indexed by slot. */
#define WORLD_SLOT_BITS 16u
static inline uint32_t world_slot(uint32_t id) { return id & ((1u << WORLD_SLOT_BITS) - 1u); }

typedef struct world_config {
    float min[3], max[3]; /* world bounds */
    float max_speed;      /* m/s */
    float aoi_radius;     /* m, horizontal */
    float spawn_radius;   /* m around the centre of the floor */
    float tick_dt;        /* s per step */
    uint32_t capacity;    /* most avatars at once (<= 65535) */
    uint64_t seed;        /* spawn positions */
} world_config;

/* A read-only view of one avatar. */
typedef struct world_avatar {
    uint32_t id;
    float pos[3];
    float box[3];
    char name[PROTO_NAME_MAX + 1];
    uint32_t changed_tick; /* last step that moved it */
    uint32_t ack_seq;      /* seq of the last move request applied */
    float vy;              /* vertical velocity, m/s */
    int grounded;          /* standing on the floor or a box */
    int has_pose;          /* it has sent a facing */
    proto_pose pose;       /* the pose its viewers were last given */
    uint32_t pose_tick;    /* the step from which viewers are to get it */
} world_avatar;

/* NULL if out of memory or the config is unusable. */
world *world_create(const world_config *cfg);
void world_destroy(world *w);

/* Adds an avatar at a spawn point: a random point within spawn_radius of
 * the centre, stood on any floor of sc its feet are a little into there (as
 * move.h stands it), or if the avatar's box would still overlap a box of sc,
 * the nearest free point found searching outward from it (up to
 * WORLD_SPAWN_SEARCH metres). *crowded is set to 1 when none was free and
 * the avatar stands inside an object, else 0. name is name_len bytes
 * (<= PROTO_NAME_MAX). Returns the new avatar, or NULL when the world is
 * full or out of memory. Ids are never 0 and are not reused soon (the
 * slot's generation changes). */
const world_avatar *world_add(world *w, const scene *sc, const char *name, uint32_t name_len, const float box[3],
                              int *crowded);
void world_remove(world *w, uint32_t id);
/* The avatar with this id, or NULL if it is gone. */
const world_avatar *world_get(const world *w, uint32_t id);

/* Records a move request; a later request in the same step replaces it.
 * pos must be finite (the codec guarantees it). */
void world_request_move(world *w, uint32_t id, uint32_t seq, const float pos[3]);

/* Takes avatar id's pose if it is its first or differs from the last one
 * taken by more than the WORLD_POSE_* thresholds; viewers get it at the
 * next step's update. Returns 1 when taken, 0 when not (or no avatar). */
int world_set_pose(world *w, uint32_t id, const proto_pose *p);

/* Called for each contact that blocked an avatar (or that it made from
 * inside a box) during world_step; vel is the avatar's requested velocity. */
typedef void world_contact_fn(void *ctx, const world_avatar *a, const move_contact *c, const float vel[3]);

/* Advances the step counter and moves every avatar that asked to move or is
 * falling: toward its request (horizontally; the height is the world's to
 * decide) at most max_speed x elapsed time, under gravity, against the
 * scene's boxes (move.h: sliding, stepping, support, the inside policy),
 * reporting each contact to fn. */
void world_step(world *w, const scene *sc, world_contact_fn *fn, void *ctx);
uint32_t world_tick(const world *w);

/* After object object_id's collision map changed in sc (its boxes before,
 * as world AABBs: old, nold of them): pushes every avatar that a new box
 * of it overlaps, and that overlapped none of the old ones, out of the
 * scene's boxes (move_push_out; boxes of other objects it was already
 * inside stay out of the trial), never out of the world; viewers hear of
 * it with the next step. Returns how many were pushed; *stuck counts those
 * no push-out frees (or with more boxes around than one move is checked
 * against), left to move.h's inside policy. */
uint32_t world_push_out(world *w, const scene *sc, uint32_t object_id, const scene_box *old, uint32_t nold,
                        uint32_t *stuck);

/* The other avatars within the area-of-interest radius of avatar id,
 * written to out (room for max) in no particular order. Returns how many
 * were written. */
uint32_t world_neighbours(world *w, uint32_t id, const world_avatar **out, uint32_t max);

uint32_t world_count(const world *w);

#endif
