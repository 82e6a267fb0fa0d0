/*
 * refine.h: one refinement round of an object's collision map (the paper's
 * "divide bounding box into smaller bounding boxes"). Pure module: no I/O.
 *
 * Input: the object's triangles and boxes (local coordinates) and the
 * clusters of unexpected collisions. A cluster presses on the box it names
 * and on every box its points lie on (their bounding box, grown by a
 * hundredth of the avatar's width for rounding, meets it): users stopped
 * along a wall that earlier rounds cut into several boxes press on all of
 * them. Each box a cluster presses on (a problem box) is replaced by boxes
 * that hug the geometry where users want to go; every other box is kept as
 * it is. For each problem box:
 *
 *   1. Digitize (voxel.h): a grid of 2^depth cells per axis over the box,
 *      a cell occupied when a triangle touches it.
 *   2. Wanted space: the empty cells where users were stopped. Each cluster
 *      stands for a region: its points' bounding box, grown by half the
 *      avatar's size, and stretched through the whole box along the axis of
 *      the face it presses on (users walk into the box across that face: a
 *      tunnel under an arch, a room behind a door), and upwards by one
 *      cell more (a user stands on a box of the map, whose top may be a
 *      cell above the geometry under it). Only space an avatar fits in counts (a
 *      morphological opening of the empty cells by the avatar's box, space
 *      outside the grid counting as empty): the hollow between the two
 *      faces of a thick wall is never wanted, so it stays covered.
 *   3. Divide, best first: shrink the box to its occupied cells; while a
 *      node holds wanted cells, cut the one holding the most in two, shrink
 *      the parts to their occupied cells and drop the empty ones. The cut
 *      lies on a face of the bounding box of the node's wanted cells, the
 *      one that cuts off the largest part without wanted cells (a doorway
 *      in a wall: the wall on one side, then on the other, and the rest
 *      shrinks to the lintel: three boxes); when the wanted cells reach
 *      every face of the node, it is halved across its longest side. Nodes
 *      without wanted cells are kept whole: fine near the clusters, down to
 *      single cells, coarse elsewhere; one cut adds at most one box.
 *   4. Merge: two boxes of the same problem box whose hull covers no new
 *      wanted cell and adds at most max_empty of the hull's volume as new
 *      empty space become one, cheapest first, until no pair qualifies.
 *   5. Cap: each problem box may become an equal share of what the
 *      object's other boxes leave of max_boxes (at least one). When the next
 *      cut would pass its share by more than a small slack even after
 *      merging, division stops and the nodes still waiting stay whole,
 *      wanted cells and all; then the cheapest pairs (fewest wanted cells
 *      covered, then fewest empty ones) merge until the share is met.
 *      `capped` counts the boxes left holding wanted cells, and each
 *      problem box whose share is one box (it is only shrunk to its
 *      occupied cells, its wanted space never worked out): the
 *      opening may stay partly closed until the next round, whose
 *      collisions name it again. An object already at the cap can still
 *      grow by one box per problem box beyond it, never more.
 *
 * Invariant: every box is a union of whole cells that contains all the
 * occupied cells of its problem box, so the union of the object's boxes
 * still contains every triangle (cells are closed and conservative, and box
 * coordinates are rounded outwards to float, then clamped to the problem
 * box). Refinement only ever removes empty space: no amount of deliberate
 * bumping opens a real wall.
 */
#ifndef CVRE_ECM_REFINE_H
#define CVRE_ECM_REFINE_H

#include <stddef.h>
#include <stdint.h>

#include "voxel.h"

/* Grid depths a refinement accepts: the division keeps two counts per cell
 * (32-bit summed-volume tables), 2 x 64 MiB at 2^8; deeper grids would need
 * a sparse structure. */
#define ECM_DEPTH_MIN 2u
#define ECM_DEPTH_MAX 8u
/* 2^7 = 128 cells per axis: a 10 m room gets 8 cm cells, so a 0.9 m doorway
 * keeps at least 0.74 m of free cells for the 0.6 m default avatar. */
#define ECM_DEPTH_DEFAULT 7u
#define ECM_MAX_BOXES_DEFAULT 64u
/* Most boxes an object may have: what one OBJECT_INFO frame carries
 * (PROTO_OBJECT_BOXES_MAX). */
#define ECM_MAX_BOXES_LIMIT 1024u
#define ECM_MAX_EMPTY_DEFAULT 0.25

typedef struct ecm_params {
    uint32_t depth;     /* grid 2^depth per axis, ECM_DEPTH_MIN..MAX */
    uint32_t max_boxes; /* most boxes for the object, 1..ECM_MAX_BOXES_LIMIT */
    double max_empty;   /* share of a merged box that may be new empty space, 0..1 */
    float avatar[3];    /* the avatar's size in object-local units (> 0) */
} ecm_params;

/* Fills p with the defaults above and the default avatar's size (avatar.h;
 * for an object of scale 1: divide by the object's scale). */
void ecm_params_default(ecm_params *p);

/* A cluster of unexpected collisions, in object-local coordinates. */
typedef struct ecm_cluster {
    uint32_t box;          /* the problem box: index among the object's boxes */
    float min[3], max[3];  /* bounding box of its points */
    float centroid[3];
} ecm_cluster;

/* What one refinement produced. */
typedef struct ecm_result {
    float (*boxes)[6];      /* count boxes, local min x y z, max x y z; ecm_result_free */
    uint32_t count;
    uint32_t problem_boxes; /* boxes replaced */
    uint32_t capped;        /* boxes left holding wanted cells by the cap, and problem
                             * boxes whose share was one box (only shrunk) */
    uint64_t cells;         /* cells examined: problem boxes x 2^(3 depth) */
    uint64_t occupied;      /* of which occupied */
    uint64_t wanted;        /* of which wanted (step 2) */
    double voxel_ms;        /* time in digitization */
    double divide_ms;       /* time in steps 2 to 5 */
} ecm_result;

/*
 * Refines an object (see above). tris: ntris triangles, 9 floats each;
 * boxes: nboxes boxes; clusters: nclusters, each naming a box below nboxes.
 * Boxes without clusters are copied unchanged, in their order, followed by
 * the boxes replacing each problem box, in problem box order; the same
 * input always gives the same output.
 *
 * Returns 0 and fills *out (the caller calls ecm_result_free), or, with
 * *out empty and a one-line reason in err (room for errlen bytes):
 * -EINVAL for bad parameters (depth, max_boxes, max_empty, avatar), no
 * triangles, no boxes or more than ECM_MAX_BOXES_LIMIT, a cluster naming no
 * box, or a coordinate that is not finite; -ENOMEM when out of memory.
 */
int ecm_refine(const ecm_params *p, const float *tris, uint32_t ntris, const float (*boxes)[6], uint32_t nboxes,
               const ecm_cluster *clusters, uint32_t nclusters, ecm_result *out, char *err, size_t errlen);
void ecm_result_free(ecm_result *r);

#endif
