/*
 * known.h: the objects the server has told this client about (OBJECT_INFO,
 * until OBJECT_REMOVED), with their transform and their collision boxes in
 * world coordinates. The scripted client keeps one table: a place that
 * names no yaw or size keeps the object's current ones, and an import with
 * --drop looks here for the surface its model lands on.
 */
#ifndef CVRE_CLIENT_KNOWN_H
#define CVRE_CLIENT_KNOWN_H

#include <stddef.h>
#include <stdint.h>

#include "proto.h"

typedef struct known known;

typedef struct known_object {
    uint32_t id;
    float yaw, scale;
    uint32_t tri_count;
    uint8_t mesh_hash[PROTO_MESH_HASH_SIZE]; /* what a fetch asks for */
    uint16_t n_boxes;
    float (*boxes)[6]; /* min x y z, max x y z; owned by the table */
} known_object;

known *known_create(void);
void known_free(known *k);

/* Takes o's transform and boxes as the object's current ones (a fresh
 * entry, or a replacement). Out of memory aborts, as for the loop's other
 * allocations. */
void known_put(known *k, const proto_object_info *o);
/* The entry of id, or NULL; valid until the table next changes. */
const known_object *known_get(const known *k, uint32_t id);
/* Forgets id (nothing if it is not known). */
void known_del(known *k, uint32_t id);

/*
 * The box around all of o's boxes, into lo and hi. Returns 0, or -ENOENT
 * when o has no boxes (lo and hi are then untouched).
 */
int known_bounds(const proto_object_info *o, float lo[3], float hi[3]);

/*
 * Where a box with the footprint [lo.x, hi.x] x [lo.z, hi.z] and its bottom
 * at lo.y comes to rest when it falls: the highest top among the boxes of
 * the known objects other than except whose footprint overlaps it and
 * which lie under it (their top at most KNOWN_SNAP_M above lo.y), and at
 * least floor_y, the world's floor.
 */
float known_surface_below(const known *k, uint32_t except, const float lo[3], const float hi[3], float floor_y);

/* A surface this little above the falling box's bottom still counts as
 * under it: a model put by hand "on" a table top a centimetre too low
 * lands on the table instead of falling through to the floor. */
#define KNOWN_SNAP_M 0.05f

#endif
