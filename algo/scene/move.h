/*
 * move.h: the kinematic character controller. One call moves one avatar for
 * one tick against the ECM boxes near it, with swept AABB collision, sliding,
 * gravity, landing and stepping up, and says which boxes blocked it. Pure and
 * deterministic: no I/O, no allocation, no global state; the same input
 * always gives the same output, bit for bit.
 *
 * Conventions: metres, y up, the floor is the plane y = floor_y and nothing
 * goes below it. An avatar is an axis-aligned box of size (sx, sy, sz) whose
 * position is the centre of its bottom face (its feet). Two boxes overlap
 * when their interiors do: touching faces do not overlap.
 *
 * Rules, in the order they apply within a move:
 *
 *   - Standing on a floor it is sunk into: when the move starts with the
 *     avatar overlapping boxes whose tops are above its feet by at most
 *     step_height (a floor slab or a low surface its feet are a few
 *     millimetres into, e.g. a model whose floor lies just above the world's
 *     floor), it is first lifted onto the highest such top that has
 *     headroom: one where it overlaps no box it did not already overlap.
 *     It then stands there (grounded, the fall of the tick dropped, as after
 *     a step up), walks on that top like on any other, and nothing is
 *     reported. This comes after the lift onto the floor (see below) and
 *     also applies to a move with no displacement.
 *   - The motion of the tick is the requested displacement plus the fall
 *     under gravity, v dt - g dt^2 / 2 (the fall speed is capped at
 *     MOVE_MAX_FALL_SPEED). It is swept as a whole: the avatar stops at the
 *     first box face it would cross (time of impact of its box against each
 *     box, slab method), so no speed and no thinness lets it tunnel. It stops
 *     MOVE_SKIN short of a side or ceiling face, and exactly on a top face or
 *     the floor (those are floats, so standing is exact).
 *   - It then slides: the motion left loses its component along the face's
 *     normal and goes on, up to MOVE_MAX_SLIDES times (a corner is two).
 *   - Landing on a top face or the floor is support, not a collision: the
 *     fall ends and nothing is reported. An avatar stands (grounded, vertical
 *     velocity 0) when it ends the move with its feet on (within 2 mm above)
 *     a top face under its footprint or the floor, and falls otherwise (from
 *     rest if it stood at some point of the move, e.g. walking off an edge).
 *   - Stepping up: when an avatar on the ground (grounded when the move
 *     starts, stood on a top as above, or landed during it) is blocked by
 *     the side of a box whose top is at most step_height above its feet, it
 *     is lifted onto it instead, if there is headroom and if the rest of its
 *     motion takes its footprint over the box (not when a wall stands right
 *     behind the step).
 *     Nothing is reported. At most MOVE_MAX_STEPS steps per move. If less
 *     than MOVE_SKIN of motion is left to get onto it, the avatar waits at
 *     the step until the next move, and that is not reported either.
 *   - Slipping past a corner: when the side of a box it cannot step onto
 *     blocks it, and its footprint overlaps that box sideways (along the
 *     other horizontal axis) by at most MOVE_SLIP_FRACTION of its width, it
 *     slips sideways past the box's edge instead (MOVE_SKIN beyond it), the
 *     way that is not against its sideways motion, the nearer edge first,
 *     if nothing blocks the slip, the way on is open there (no other box's
 *     side on the same plane, unless it can step onto it: a slip that only
 *     meets the rest of the wall would shake a user pushing into a pocket
 *     back and forth) and the motion left towards the face is at least as
 *     long as the slip, which takes its length from it. Nothing is
 *     reported. A box-shaped avatar would otherwise stop at a corner it
 *     clips by a centimetre, where a body glides past; and a slanted wall
 *     that a collision map follows with a staircase of boxes would stop it
 *     at the corner of every step, where the wall turns it aside (a spiral
 *     stair's treads: users stopped at box corners one or two cells proud
 *     of the geometry, phantom collisions on a map that was good).
 *   - Every other blocking face (a wall, a step too high, a ceiling hit
 *     while moving up) is a contact. The motion along its normal is then
 *     gone for the rest of the move, so a move reports at most one blocking
 *     contact per axis, never two for one box, however it slides.
 *
 * Inside policy. An avatar that overlaps a box when a move starts (spawned
 * there, or the box was placed, moved or refined around it), once lifted
 * onto any floor it was sunk into (above), is never trapped: such boxes
 * neither block nor support it during the move, so it can walk out in any
 * direction, and may also walk deeper in or fall through (refusing
 * that would need a notion of "deeper" that some box shapes defeat; a box
 * that is ignored cannot trap). Instead, every move that requests a non-zero
 * displacement and still ends overlapping such a box reports an inside
 * contact for it, so that the collision log keeps the evidence: its point is
 * the avatar's centre clamped into the box, its normal points out of the face
 * the avatar is nearest to leaving through (the smallest push-out; the bottom
 * face only if the box does not reach down to the floor). The other boxes
 * still block it. An avatar below the floor is first lifted onto it. So an
 * inside contact means an object placed around the avatar: a box whose top
 * is more than a step above its feet, or a low one with no headroom above.
 */
#ifndef CVRE_MOVE_H
#define CVRE_MOVE_H

#include <stdbool.h>
#include <stdint.h>

#include "avatar.h"

/* Contacts one move reports at most. At most three block it (one per axis)
 * and the rest are inside contacts; 16 leaves room for an avatar spawned
 * inside a dozen overlapping boxes. More are counted, not kept. */
#ifndef MOVE_MAX_CONTACTS
#define MOVE_MAX_CONTACTS 16
#endif
/* Faces one move slides along or slips past: landing, two walls of a corner,
 * and one more for a ceiling or a wall met after stepping or slipping; any
 * motion left is dropped. */
#define MOVE_MAX_SLIDES 4
/* Most an avatar's footprint may overlap a box sideways, as a share of its
 * width, for it to slip past the box's corner rather than stop at it. */
#define MOVE_SLIP_FRACTION 0.125
/* Steps one move climbs: a tick moves at most a few decimetres, so two steps
 * (a stair whose treads are shorter than the move) are plenty. */
#define MOVE_MAX_STEPS 2
/* Gap kept between the avatar and a face it stops at: 1 mm cannot be seen,
 * and is twice the spacing of floats at MOVE_MAX_COORD. */
#define MOVE_SKIN 0.001
/* Largest |coordinate| of a position or displacement, in metres: four times
 * the default 1 km world, and where float spacing is still below 0.5 mm. */
#define MOVE_MAX_COORD_M 4096 /* the same, a whole number for static asserts */
#define MOVE_MAX_COORD ((float)MOVE_MAX_COORD_M)
/* Longest tick, in seconds: the server caps elapsed time at 0.25 s. */
#define MOVE_MAX_DT_MS 1000
#define MOVE_MAX_DT (MOVE_MAX_DT_MS / 1000.0f)
/* Fastest fall, m/s: a human body's terminal velocity in air. It also bounds
 * the swept volume, and so the broadphase query, of a long fall. */
#define MOVE_MAX_FALL_SPEED 55.0f

#define MOVE_GRAVITY_DEFAULT 9.81f
#define MOVE_STEP_DEFAULT AVATAR_STEP

_Static_assert(MOVE_MAX_CONTACTS >= 3, "room for every blocking contact");

typedef struct move_params {
    float size[3];     /* avatar size sx, sy, sz, each > 0 */
    float gravity;     /* m/s^2, >= 0 */
    float step_height; /* m, 0 <= step_height <= sy */
    float floor_y;     /* the world's min y */
} move_params;

/* Fills p with the defaults: a 0.6 x 1.8 x 0.6 m avatar, 9.81 m/s^2, 0.35 m
 * steps, floor at y = 0. */
void move_params_default(move_params *p);

typedef struct move_state {
    float pos[3];  /* centre of the avatar's bottom face */
    float vy;      /* vertical velocity, m/s, up is positive */
    bool grounded; /* standing on the floor or a top face */
} move_state;

/* A candidate box, as the broadphase found it, with the ids a contact
 * reports. */
typedef struct move_box {
    float min[3], max[3];
    uint32_t object_id, box_index, handle;
} move_box;

typedef struct move_contact {
    uint32_t index; /* of the box among the candidates */
    uint32_t object_id, box_index, handle;
    float point[3];  /* world coordinates: the middle of where the avatar's
                      * face met the box's (for inside contacts, see above) */
    float normal[3]; /* axis-aligned unit vector out of the box */
    bool inside;     /* the avatar overlapped the box (see the inside policy) */
} move_contact;

typedef struct move_result {
    move_state state; /* after the move */
    uint32_t ncontacts;
    uint32_t dropped; /* contacts beyond MOVE_MAX_CONTACTS, not kept */
    move_contact contacts[MOVE_MAX_CONTACTS];
} move_result;

/*
 * The box that every place the avatar can reach during move_step(p, st, disp,
 * dt, ...) lies in, with a margin: query the broadphase with it and pass what
 * it finds as the candidates. Boxes outside it cannot change the move. Input
 * as for move_step; with invalid input the box is empty (min > max).
 */
void move_bounds(const move_params *p, const move_state *st, const float disp[3], float dt, float min[3],
                 float max[3]);

/*
 * Moves the avatar in st by the requested displacement disp (x, y, z) over dt
 * seconds, under gravity, against the nboxes candidate boxes (only they and
 * the floor can block it), and writes its new state and the contacts to out
 * (blocking contacts in the order they happened, then inside contacts in
 * candidate order). Returns 0, or -EINVAL, with out holding st unchanged and
 * no contacts, if a pointer is NULL (boxes may be NULL when nboxes is 0), a
 * number is not finite, a position, displacement or vertical speed exceeds
 * MOVE_MAX_COORD (in m, m/s), dt is outside [0, MOVE_MAX_DT], a parameter is
 * out of range (see move_params), or a box has min > max.
 */
int move_step(const move_params *p, const move_state *st, const float disp[3], float dt, const move_box *boxes,
              uint32_t nboxes, move_result *out);

/*
 * Push-out: a new collision map that encloses an avatar the old one did not
 * (a refined box reaches a little past the old faces it replaces) would
 * leave it inside, free to walk on into the geometry (the inside policy).
 * The server pushes such an avatar out when it puts the map in force, and
 * the judge (algo/refine/judge.h) does the same to its samples.
 *
 * Moves the avatar in st to the nearest place that overlaps none of the
 * nboxes boxes, among those just past one face of a box it overlaps, or
 * past a face of one such box and then of another (a corner): a side
 * (MOVE_SKIN past it) or the top (standing on it), never down. None further
 * from the start (the feet, lifted onto the floor) than half the avatar's
 * narrower width: refinement lets a new box reach past the old map by less
 * (algo/refine/refine.h, step 6), and a longer push could carry it through
 * a thin wall. Its vertical speed becomes 0 and it stands if something is
 * under it (as after a move). Returns 1 when it was pushed, 0 when it overlapped no box (st
 * unchanged), -ENOSPC when no such place is free (st unchanged: the inside
 * policy applies), -EINVAL as move_step.
 * At most 30 k n box tests for k boxes overlapped, at most MOVE_PUSH_BOXES
 * of them (more: -ENOSPC).
 */
#define MOVE_PUSH_BOXES 8
int move_push_out(const move_params *p, move_state *st, const move_box *boxes, uint32_t nboxes);

#endif
