/*
 * refine.h: one refinement round of an object's collision map (the paper's
 * "divide bounding box into smaller bounding boxes"). Pure module: no I/O.
 *
 * Input: the object's triangles and boxes (local coordinates) and the
 * clusters of unexpected collisions. A cluster presses on the box it names
 * and on every box its points lie on or an avatar touching there may reach
 * (their bounding box, grown by a hundredth of the avatar's width for
 * rounding and upwards by the avatar's height and a step, meets it): users
 * stopped along a wall that earlier rounds cut into several boxes press on
 * all of them, and on the box above a step they would climb. The boxes a
 * cluster presses on (problem boxes) are re-divided together, as one
 * object; every other box is kept as it is.
 *
 * Groups: clusters that press on a common box are one group, and each
 * group is refined on its own (steps 1 to 7), heaviest first (the sum of
 * its clusters' weights), the other groups' boxes kept meanwhile: one grid
 * over boxes far apart (both sides of a well) spends the budget cutting
 * the space between them out, at coarser cells. Each group may add a share
 * of the boxes left under max_boxes, by its weight among the groups still
 * to come (what one leaves goes to the next). A problem box that no
 * cluster's region (step 3) can reach, say a roof pressed because a user
 * at the well might step up under it, is only tightened (step 6), and the
 * grid spans the others.
 *
 *   1. Digitize (voxel.h): one grid over the hull of the problem boxes
 *      divided, a cell occupied when a triangle touches it. The grid has
 *      2^d cells per axis, d the least from ECM_DEPTH_MIN up to depth whose
 *      cells are no larger than the object's cell (its bounding box over
 *      2^depth) on any axis: the map's resolution is the object's cell (the
 *      phantom tolerance), and a grid over a few small boxes at full depth
 *      cuts a curve into steps nobody can tell apart, and spends the whole
 *      budget on them.
 *   2. Classes: a cell must be covered when it is occupied and meets a
 *      problem box; it is outside when it meets no problem box (space the
 *      map leaves free, or only a kept box's): no new box may hold an
 *      outside cell, so openings of earlier rounds stay open.
 *   3. Pressure: each cluster stands for a region: its points' bounding box,
 *      grown by half the avatar's size, stretched along the axis of the face of
 *      its box nearest its centroid through the problem boxes it presses on
 *      (users walk in across that face: a tunnel under an arch, a room behind a
 *      door), across them too along that face's horizontal axis (users who came
 *      in roam sideways: the far wall of a tunnel, the column pair past the
 *      last one pressed), and upwards by one cell (a user stands on a box of
 *      the map, whose top may be a cell above the geometry) and then by the
 *      step height. Only space an avatar fits in counts (a morphological
 *      opening of the cells no triangle touches and no kept box meets, space
 *      outside the grid counting as empty, and nothing under the world's
 *      floor): the hollow inside a thick wall, or the space under a table or a
 *      spiral stair's treads, is never wanted. Users outside the box they name
 *      want only places they can walk to: placements reached from those within
 *      a cell of the cluster's points that overlap no box of the map (where
 *      users stood), through placements that fit and stand on something within
 *      a step and a cell under their footprint (or the floor under the grid),
 *      6-connected. The well inside a ring wall nobody steps over, or the
 *      inside of a closed drawer pedestal, is no place to open (a gazebo's ring
 *      spent 45 boxes around its well and kept corners a hand's width proud).
 *      Not for clusters on a floor or a ceiling face, and not when no placement
 *      starts a walk. A placement of the avatar that reaches into the step band
 *      must stand on something (a blocked cell right under its footprint, or
 *      the floor under the grid): users step up onto a base, not into the air.
 *      Each wanted cell of a problem box gets the cluster's pressure, by its
 *      weight: from 4 for the lightest to 255 for the heaviest near its points,
 *      a quarter of that where the region is only stretched, a sixteenth beside
 *      the points' own reach; pressures of several clusters add, up to 255.
 *      Users who stood inside the box they name (a building they start in)
 *      cross no face: their region is their points' reach, and they walk on to
 *      every place they can reach in the grid, so the cells covered by every
 *      avatar placement reachable on foot from their points (placements that
 *      fit and stand on something within a step and a cell below, 6-connected:
 *      steps and stairs climbed, never the air) get a sixteenth too. Only where
 *      this round's users went, the rest of the building stayed one box of
 *      arcades and aisles for later users (Sponza: up to 271 phantom blocks per
 *      1,000 moves at round 3); stretched up through the floor, the region
 *      spent 40 boxes on galleries nobody reaches.
 *   4. Divide, best first: shrink the grid to its cells to cover; cut the
 *      node first in line in two and shrink the parts (empty parts go).
 *      Nodes holding outside cells come first and are always cut (the cut
 *      cuts off outside cells); then the node with the most pressure (the
 *      pressure of its wanted cells: wanted volume weighted by how hard
 *      users press), until no node holds pressure. The cut lies on a face
 *      of the bounding box of the cells to cut off, the one that cuts off
 *      the largest slab without them (a doorway in a wall: the wall on one
 *      side, then on the other, and the rest shrinks to the lintel: three
 *      boxes); when they reach every face of the node, outside cells
 *      halve it across its longest side, and pressed cells choose the
 *      plane (any cell border) whose two parts, shrunk, keep the least
 *      pressure, then the least volume (the treads of a spiral stair:
 *      halves freed little of the air over them, and 53 of its 64 boxes
 *      were nodes kept whole at the cap); halved when no plane frees
 *      any. Nodes without pressure are kept whole: fine near the
 *      clusters, coarse elsewhere; one cut adds at most one box.
 *   5. Merge and cap: the budget is max_boxes less the kept boxes, for the
 *      whole object. When the next pressed cut would pass the budget by
 *      more than a slack even after merging, division stops and the
 *      nodes still waiting stay whole. When users stood inside a box
 *      they press on (their feet in it, below its top by more than a
 *      step), they show only the part they stand in, and later rounds need
 *      boxes for the rest: the slack is smaller, and the budget holds the
 *      problem boxes and three quarters of the boxes the object may still
 *      add. When merging then leaves boxes of the budget unused (the
 *      parts of nodes kept whole join back), the division runs again with
 *      as much more slack (twice at most; not for users inside). Two
 *      boxes (of any problem boxes: merges cross the old boxes' borders)
 *      whose hull holds no outside cell, adds no pressure and adds at most
 *      max_empty of its volume as new empty space become one, cheapest
 *      first: slivers that free no wanted cell go back. Then, while
 *      there are more boxes than the budget, the pair whose hull adds the
 *      least pressure, then the fewest empty cells, and holds no outside
 *      cell, merges. If that cannot meet
 *      the budget (or keeping outside cells out would take more than
 *      4 x ECM_MAX_BOXES_LIMIT boxes and nodes), the problem boxes are only
 *      tightened (step 6): never more boxes than the object had.
 *   6. Tighten: each box shrinks to the bounding box of the parts of the
 *      triangles that lie in it and in a problem box (worked out exactly,
 *      each triangle clipped to the box, in double, with a margin against
 *      rounding), rounded outwards to float; a box with no such part goes.
 *      A box never grows: boxes stop at the geometry, not at the cells around
 *      it, so an opening never narrows by a cell per round. A box over several
 *      problem boxes whose parts' bounds reach out of the old map (a cell that
 *      met one problem box let it cover the corner of another's free space) by
 *      more than two cells of the grid, or more than a quarter of the avatar's
 *      narrower width, on an axis (every part of it), or at all where it meets
 *      an avatar where users stood when they collided (stood: pushed out of
 *      the box when the map comes in force, such an avatar may find no room
 *      among the boxes around it, and is left inside, free to walk on into the
 *      geometry: on a spiral stair's treads, the judge counted 800 to 900
 *      moves into them on later rounds' maps), is taken apart into its parts
 *      in each problem box, each tightened, and then two parts whose hull
 *      stays in the old map by the same rule join again, the smallest hull
 *      first; if they pass max_boxes, the division runs again with as many
 *      boxes fewer (twice at most), and then the problem boxes are only
 *      tightened. Whether a box stays in the old map is worked out exactly,
 *      however many old boxes it meets (a staircase's later-round boxes
 *      meet 20 to 40). Less than the tolerance is kept: boxes an earlier
 *      grid tightened are offset from this grid's by up to a cell or two,
 *      and taking apart every box that joins them passes the cap on curved
 *      geometry (a gazebo's ring by 69 boxes). An avatar that such a box
 *      encloses when the map comes in force is pushed out of it (move.h,
 *      move_push_out, no further than half its narrower width), so it never
 *      stands inside a new box, which would let it walk on into the geometry
 *      (move.h's inside policy).
 *   7. Split under the cell: a new box with wanted cells in it or next to
 *      it may still hold empty space along the geometry that no cell
 *      border separates (a desk's side panel in one box with the last
 *      centimetres of the back board that meets it: users stop short of
 *      the panel all along it). While the object has fewer than
 *      max_boxes less a quarter (left for later rounds), the box whose
 *      best plane frees the most is split across it, both parts tightened
 *      as in step 6, if that frees more than one of the object's cells,
 *      and more than a quarter of it and than max_empty, or a slab half a
 *      cell deep across its whole face (a drawer pedestal's box that also
 *      holds the end of the back board, a cell further out). The plane is
 *      chosen among the starts and ends of the triangles' bounding boxes
 *      in it, on each axis (boxes meeting more than SPLIT_PARTS_MAX
 *      triangles are left as they are: their surface already follows the
 *      cells). When no one plane frees enough, two that peel both ends off
 *      along an axis may (a wall's box that also holds the first cell of
 *      the two walls meeting it: users stop a cell short of the wall).
 *   8. Move boxes to where users were stopped: when the object already has
 *      max_boxes boxes and steps 1 to 7 only tightened the problem boxes or
 *      gave back the map in force (a spiral stair's later round: its one
 *      cluster presses on 55 of its 64 boxes, and a division that stays in
 *      the old map takes 40 boxes and more before any is taken apart), the
 *      places where users stood (stood) tell which boxes stopped them where
 *      nothing real was. A box is hot when HOT_MIN (3) collisions or more
 *      (each place counts by its weight) named it while the avatar's box,
 *      grown by a cell of the object sideways and upwards, touched no
 *      triangle (a phantom, as the judge counts it); the HOT_MAX (8) with
 *      the most count. For each hot box, up to FREED_PER_HOT (3) pairs of
 *      boxes that no collision named join into their hull, the pair adding the
 *      least volume first, if the hull, grown by a quarter of the avatar's
 *      narrower width, meets no avatar where users stood; then steps 1 to
 *      7 divide the hot boxes alone, with the boxes freed. Joins close
 *      space where no user was seen, the one place a refinement closes
 *      space: the judge decides, as for any candidate (the scenario's
 *      staircase at seeds 1 to 5: 4 of its 10 later jobs write a map, where
 *      none did). ecm_move_boxes runs step 8 alone on a candidate at the
 *      cap, by the places where the judge's trials were held back on it
 *      (algo/refine/second.c), each weighted by its ticks, the job's
 *      own places unnamed (no box of the candidate) so that no join covers
 *      them: held clusters, whose region is their points' reach, stretched
 *      through the boxes along the face alone, and no walk (step 3): the
 *      trials stood there.
 *
 * `capped` counts the new boxes left holding pressure (wanted cells), or
 * every problem box when they were only tightened: the opening may stay
 * partly closed until a later round, whose collisions name it again.
 *
 * Invariant: every point of a triangle in a problem box lies in a cell to
 * cover (cells are closed and conservative, cell ranges widened against
 * rounding), every cell to cover lies in a new box (its coordinates rounded
 * outwards), and tightening keeps every triangle part in the box and in a
 * problem box; the rest of every triangle lies in the kept boxes. So the
 * union of the object's boxes still contains every triangle. Refinement
 * only ever removes space in which no triangle lies: no amount of
 * deliberate bumping opens a real wall. And every new box lies in the old
 * map's union, give or take the tolerance of step 6 (none where users
 * stood): it never closes space but by that, and by step 8's joins.
 */
#ifndef CVRE_ECM_REFINE_H
#define CVRE_ECM_REFINE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "trimesh.h"
#include "voxel.h"

/* Grid depths a refinement accepts: the division keeps three counts per
 * cell (32-bit summed-volume tables), 3 x 64 MiB at 2^8, and the walk of
 * users inside (step 3) a queue of 4 bytes a placement, at most as much;
 * deeper grids would need a sparse structure. */
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
    float step;         /* the highest step the avatar climbs, object-local units (>= 0) */
    float floor;        /* the world's floor, object-local height: no avatar stands
                         * below it (step 3); -INFINITY (the default): none */
    const struct ecm_stood *stood; /* nstood places where users stood when they collided
                                    * (steps 6 and 8; the default: none) */
    uint32_t nstood;
    unsigned threads; /* most threads a refinement runs on: the digitizing in slabs
                       * (voxel_mark_boxed), two tables and the triangles' index
                       * built beside other steps (task.h); 1: this thread
                       * alone; the default 0: one per CPU it may run on */
} ecm_params;

/* Where a user stood when it collided: its avatar's box, local, the box
 * its collision named (an index among the object's boxes; past them: none)
 * and how many collisions it stands for (a trial held there tick after
 * tick: judge.h's places; 0 counts as 1). */
typedef struct ecm_stood {
    float box[6];
    uint32_t hit;
    uint32_t weight;
} ecm_stood;

/* Fills p with the defaults above and the default avatar's size and step
 * (avatar.h; for an object of scale 1: divide by the object's scale), and
 * no floor (server/pipeline/apply.c sets the world's). */
void ecm_params_default(ecm_params *p);

/* A cluster of unexpected collisions, in object-local coordinates. */
typedef struct ecm_cluster {
    uint32_t box;          /* the problem box: index among the object's boxes */
    float min[3], max[3];  /* bounding box of its points */
    float centroid[3];
    uint32_t weight;       /* how hard it presses: its collisions (0 counts as 1) */
    bool held;             /* its points are where trials were held back, not users
                            * stopped at a face they would cross (second.h): its
                            * region is stretched along the face alone, and no
                            * walk (step 3) */
} ecm_cluster;

/* What one refinement produced. */
typedef struct ecm_result {
    float (*boxes)[6];      /* count boxes, local min x y z, max x y z; ecm_result_free */
    uint32_t count;
    uint32_t problem_boxes; /* boxes replaced */
    uint32_t capped;        /* new boxes left holding wanted cells by the cap, or every
                             * problem box when they were only tightened (step 5) */
    uint32_t apart_over;    /* when they were only tightened because the new boxes,
                             * taken apart in step 6, passed the cap: by how many
                             * boxes, at the first try (else 0) */
    uint64_t cells;         /* cells examined: 2^(3 depth) a grid, one grid a group of
                             * clusters (0: no problem box) */
    uint64_t occupied;      /* of which occupied */
    uint64_t wanted;        /* of which wanted (step 3) */
    double voxel_ms;        /* ms in digitization, and */
    double divide_ms;       /* in steps 2 to 6: CPU time, the calling thread's
                             * (CLOCK_THREAD_CPUTIME_ID, page faults included) and
                             * that of the threads it started (threads), what the
                             * work costs on a loaded machine too */
} ecm_result;

/*
 * Refines an object (see above). tris: ntris triangles, 9 floats each;
 * boxes: nboxes boxes; clusters: nclusters, each naming a box below nboxes.
 * Boxes without clusters are copied unchanged, in their order (but for
 * those step 8 joins), followed by the boxes replacing the problem boxes,
 * all inside their hull; the same
 * input always gives the same output. The count is at most max_boxes, or
 * the object's own count when its kept boxes leave no room.
 *
 * Returns 0 and fills *out (the caller calls ecm_result_free), or, with
 * *out empty and a one-line reason in err (room for errlen bytes):
 * -EINVAL for bad parameters (depth, max_boxes, max_empty, avatar, step), no
 * triangles, no boxes or more than ECM_MAX_BOXES_LIMIT, a cluster naming no
 * box, or a coordinate that is not finite; -ENOMEM when out of memory.
 */
int ecm_refine(const ecm_params *p, const float *tris, uint32_t ntris, const float (*boxes)[6], uint32_t nboxes,
               const ecm_cluster *clusters, uint32_t nclusters, ecm_result *out, char *err, size_t errlen);
/* The same over a mesh its caller has (trimesh_init: the triangles were
 * checked there), so that the judge can use it too. */
int ecm_refine_mesh(const ecm_params *p, const trimesh *m, const float (*boxes)[6], uint32_t nboxes,
                    const ecm_cluster *clusters, uint32_t nclusters, ecm_result *out, char *err, size_t errlen);
/* Step 8 alone (see above) on a map at the cap, by the places in p->stood
 * and the clusters: a second candidate where a first left users stopped
 * (second.h: the judge's own trials). Returns 1 with *out
 * filled, 0 with *out empty but for the times spent when it has nothing
 * to offer (fewer than max_boxes boxes, no place, no hot box, no pair to
 * join or no division that fits), or an error as ecm_refine_mesh's. */
int ecm_move_boxes(const ecm_params *p, const trimesh *m, const float (*boxes)[6], uint32_t nboxes,
                   const ecm_cluster *clusters, uint32_t nclusters, ecm_result *out, char *err, size_t errlen);
void ecm_result_free(ecm_result *r);

/* Whether the na boxes a are the nb boxes b in some order (each as many
 * times): a refinement that only lists the boxes in force in another
 * order changes nothing. */
int ecm_same_boxes(const float (*a)[6], uint32_t na, const float (*b)[6], uint32_t nb);

#endif
