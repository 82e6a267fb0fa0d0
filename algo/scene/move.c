#include "move.h"

#include <errno.h>
#include <math.h>
#include <string.h>

/*
 * The avatar is swept as its feet point against each box grown by the
 * avatar's extent (the Minkowski sum): x and z by half the avatar's width on
 * each side, y by its height below the box. The avatar's box overlaps a box
 * exactly when its feet are inside the grown box's open interior.
 *
 * All arithmetic is in double, from float inputs, so that positions, faces
 * and times of impact are exact or nearly so; the result is rounded to float
 * once, at the end, and checked again in float (see settle).
 */

/* How far below its feet a top face still supports a standing avatar. A
 * landing puts the feet exactly on the top; this covers avatars placed by
 * hand and moves whose last slide ran out before the fall did. */
#define GROUND_PROBE (2 * MOVE_SKIN)
/* Margin of move_bounds around the reachable space: far more than every
 * rounding, so the broadphase never misses a box the move could touch. */
#define BOUNDS_MARGIN 0.01f
/* Rounds of settle's float nudges before it gives up and stays put. */
#define SETTLE_ROUNDS 4

void move_params_default(move_params *p)
{
    p->size[0] = AVATAR_WIDTH;
    p->size[1] = AVATAR_HEIGHT;
    p->size[2] = AVATAR_WIDTH;
    p->gravity = MOVE_GRAVITY_DEFAULT;
    p->step_height = MOVE_STEP_DEFAULT;
    p->floor_y = 0.0f;
}

typedef struct ctx {
    const move_box *boxes;
    uint32_t nboxes;
    double grow_lo[3]; /* how far a box grows below its min on each axis */
    double grow_hi[3]; /* and above its max */
    double half[3];    /* the avatar's extent from its feet point: hx, sy, hz */
    double floor;
    double step;
    double start[3]; /* position at the start, after stand_on: boxes overlapping it are ignored */
} ctx;

typedef struct hit {
    double t;      /* time of impact, in [0, 1] of the motion */
    int axis;      /* 0, 1, 2 */
    int side;      /* +1 when moving towards +axis, so the box's min face is hit */
    uint32_t box;  /* candidate index, unless floor */
    bool floor;
} hit;

static inline void grown(const ctx *c, const move_box *b, double lo[3], double hi[3])
{
    for (int a = 0; a < 3; a++) {
        lo[a] = (double)b->min[a] - c->grow_lo[a];
        hi[a] = (double)b->max[a] + c->grow_hi[a];
    }
}

/* Whether the avatar with its feet at p overlaps box b (interiors meet). */
static inline bool overlaps(const ctx *c, const move_box *b, const double p[3])
{
    double lo[3], hi[3];
    grown(c, b, lo, hi);
    return lo[0] < p[0] && p[0] < hi[0] && lo[1] < p[1] && p[1] < hi[1] && lo[2] < p[2] && p[2] < hi[2];
}

static inline bool ignored(const ctx *c, const move_box *b) { return overlaps(c, b, c->start); }

/* Whether hit h comes before hit best. At the same instant a vertical face
 * wins (landing beats a wall's edge), then among sides the higher box (the
 * one that cannot be stepped over), then the earlier candidate. */
static bool before(const ctx *c, const hit *h, const hit *best)
{
    if (h->t != best->t)
        return h->t < best->t;
    if ((h->axis == 1) != (best->axis == 1))
        return h->axis == 1;
    if (h->axis != 1 && c->boxes[h->box].max[1] != c->boxes[best->box].max[1]) /* two sides: no floor */
        return c->boxes[h->box].max[1] > c->boxes[best->box].max[1];
    return false;
}

/*
 * Finds the first face the avatar at p crosses when moving by m (t in
 * [0, 1]), among the floor and the candidates it did not overlap at the
 * start. Returns false if it crosses none.
 */
static bool sweep(const ctx *c, const double p[3], const double m[3], hit *best)
{
    bool found = false;
    double inv[3]; /* one division per axis, not per box */
    for (int a = 0; a < 3; a++)
        inv[a] = m[a] != 0 ? 1 / m[a] : 0;
    if (m[1] < 0) {
        double t = (c->floor - p[1]) * inv[1];
        if (t <= 1) {
            *best = (hit){t > 0 ? t : 0, 1, -1, 0, true};
            found = true;
        }
    }
    for (uint32_t i = 0; i < c->nboxes; i++) {
        const move_box *b = &c->boxes[i];
        if (ignored(c, b))
            continue;
        double lo[3], hi[3];
        grown(c, b, lo, hi);
        double enter = -INFINITY, leave = INFINITY;
        int axis = -1;
        bool miss = false;
        for (int a = 0; a < 3 && !miss; a++) {
            if (m[a] == 0) {
                miss = !(lo[a] < p[a] && p[a] < hi[a]);
                continue;
            }
            double t0 = (lo[a] - p[a]) * inv[a], t1 = (hi[a] - p[a]) * inv[a];
            if (t0 > t1) {
                double tmp = t0;
                t0 = t1;
                t1 = tmp;
            }
            /* Equal entry times: y first, so that at the same instant the
             * avatar lands rather than hits the top edge of a side. */
            if (t0 > enter || (t0 == enter && a == 1)) {
                enter = t0;
                axis = a;
            }
            if (t1 < leave)
                leave = t1;
        }
        /* Not overlapping at the start means entering at t >= 0, if ever. */
        if (miss || axis < 0 || !(enter < leave) || enter < 0 || enter > 1)
            continue;
        hit h = {enter, axis, m[axis] > 0 ? 1 : -1, i, false};
        if (!found || before(c, &h, best)) {
            *best = h;
            found = true;
        }
    }
    return found;
}

/* Whether the avatar's footprint at (x, z) and box b's overlap. */
static bool over(const ctx *c, const move_box *b, double x, double z)
{
    return b->min[0] - c->half[0] < x && x < b->max[0] + c->half[0] && b->min[2] - c->half[2] < z &&
           z < b->max[2] + c->half[2];
}

typedef enum step { STEP_BLOCKED, STEP_UP, STEP_SHORT } step;

/*
 * The avatar at p, moving by m, is blocked by the side of box b. Lifts it
 * onto b (STEP_UP: p is on b's top and m no longer goes down) if b's top is
 * within the step height, nothing blocks the lift, and the rest of the
 * horizontal motion then takes its footprint over b. STEP_SHORT: it would,
 * but the motion left (under MOVE_SKIN) ends before b's edge; the avatar
 * waits at the step for the next move, and b is not a collision.
 * STEP_BLOCKED: a real obstacle (too high, no headroom, or a wall right
 * behind the step's face).
 */
static step step_up(const ctx *c, double p[3], double m[3], const move_box *b)
{
    double rise = (double)b->max[1] - p[1];
    if (!(rise > 0) || rise > c->step)
        return STEP_BLOCKED;
    hit h;
    const double lift[3] = {0, rise, 0};
    if (sweep(c, p, lift, &h))
        return STEP_BLOCKED; /* no headroom */
    const double up[3] = {p[0], b->max[1], p[2]}, rest[3] = {m[0], 0, m[2]};
    if (!over(c, b, up[0] + rest[0], up[2] + rest[2]))
        return STEP_SHORT;
    double t = 1;
    if (sweep(c, up, rest, &h))
        t = fmax(0, h.t - MOVE_SKIN / fabs(rest[h.axis]));
    if (!over(c, b, up[0] + rest[0] * t, up[2] + rest[2] * t))
        return STEP_BLOCKED; /* something in the way right behind the face */
    p[1] = b->max[1];
    if (m[1] < 0)
        m[1] = 0;
    return STEP_UP;
}

/*
 * The avatar at p, moving by m, is blocked by the side of box b across axis
 * a (x or z). If its footprint overlaps b along the other horizontal axis t
 * by no more than MOVE_SLIP_FRACTION of its width there (it clips b's
 * corner), it slips sideways past b's edge (MOVE_SKIN beyond it), the way
 * that is not against the move's requested motion along t (asked), nearer
 * edge first, when nothing blocks the slip and the way on along a is open
 * there: no other side within two MOVE_SKIN of it (it stopped one short of
 * the face), unless it could step onto that one (ground: it may step). The
 * slip takes its length from the motion left along a. Returns whether it
 * slipped (p and m updated).
 */
static bool slip(const ctx *c, double p[3], double m[3], const move_box *b, int a, double asked, bool ground)
{
    const int t = 2 - a;
    const double most = c->half[t] * 2 * MOVE_SLIP_FRACTION;
    /* Towards -t past b's min, towards +t past b's max. */
    const double need[2] = {p[t] + c->half[t] - b->min[t] + MOVE_SKIN, b->max[t] - (p[t] - c->half[t]) + MOVE_SKIN};
    const int first = need[1] < need[0];
    for (int k = 0; k < 2; k++) {
        int side = first ^ k; /* 0: -t, 1: +t */
        double dir = side ? 1 : -1, len = need[side];
        if (!(len > MOVE_SKIN) || len > most + MOVE_SKIN || len > fabs(m[a]) || asked * dir < 0)
            continue;
        double s[3] = {0, 0, 0};
        s[t] = dir * len;
        hit h;
        if (sweep(c, p, s, &h))
            continue;
        /* A slip onto another face of the same wall gains nothing. */
        double q[3] = {p[0], p[1], p[2]}, on[3] = {0, 0, 0};
        q[t] += s[t];
        on[a] = m[a] - (m[a] > 0 ? len : -len);
        if (on[a] != 0 && sweep(c, q, on, &h) && h.axis == a && h.t * fabs(on[a]) <= 2 * MOVE_SKIN &&
            !(ground && step_up(c, (double[3]){q[0], q[1], q[2]}, (double[3]){on[0], on[1], on[2]},
                                &c->boxes[h.box]) == STEP_UP))
            continue;
        p[t] = q[t];
        m[a] = on[a];
        return true;
    }
    return false;
}

/*
 * Adds a contact for box i, or counts it if there is no room. A box never
 * gets two: once a box blocks along an axis, the motion left has nothing
 * along that axis, so the avatar can never enter that box again in this
 * move (and ignored boxes, the inside ones, never block).
 */
static void add_contact(move_result *out, const move_box *boxes, uint32_t i, const double point[3], int axis,
                        double sign, bool inside)
{
    if (out->ncontacts == MOVE_MAX_CONTACTS) {
        out->dropped++;
        return;
    }
    move_contact *ct = &out->contacts[out->ncontacts++];
    ct->index = i;
    ct->object_id = boxes[i].object_id;
    ct->box_index = boxes[i].box_index;
    ct->handle = boxes[i].handle;
    for (int a = 0; a < 3; a++) {
        ct->point[a] = (float)point[a];
        ct->normal[a] = a == axis ? (float)sign : 0.0f;
    }
    ct->inside = inside;
}

/* Reports the face of box b that the avatar with its feet at at touched:
 * the point is the middle of where the two faces meet. */
static void add_blocking(const ctx *c, move_result *out, uint32_t i, const double at[3], const hit *h)
{
    const move_box *b = &c->boxes[i];
    double point[3];
    for (int a = 0; a < 3; a++) {
        if (a == h->axis) {
            point[a] = h->side > 0 ? b->min[a] : b->max[a];
            continue;
        }
        double lo = a == 1 ? at[1] : at[a] - c->half[a], hi = a == 1 ? at[1] + c->half[1] : at[a] + c->half[a];
        point[a] = (fmax(lo, b->min[a]) + fmin(hi, b->max[a])) / 2;
    }
    add_contact(out, c->boxes, i, point, h->axis, -h->side, false);
}

/* Reports an inside contact with box b for the avatar at p (see move.h). */
static void add_inside(const ctx *c, move_result *out, uint32_t i, const double p[3])
{
    const move_box *b = &c->boxes[i];
    double centre[3] = {p[0], p[1] + c->half[1] / 2, p[2]};
    for (int a = 0; a < 3; a++)
        centre[a] = fmin(fmax(centre[a], b->min[a]), b->max[a]);
    /* Push-out through each face, in order of preference at equal depth:
     * sideways before up, and down only if the box leaves room below. */
    const double depth[6] = {
        p[0] + c->half[0] - b->min[0], b->max[0] - (p[0] - c->half[0]),
        p[2] + c->half[2] - b->min[2], b->max[2] - (p[2] - c->half[2]),
        b->max[1] - p[1],              b->min[1] > c->floor ? p[1] + c->half[1] - b->min[1] : INFINITY,
    };
    static const int axis[6] = {0, 0, 2, 2, 1, 1};
    static const double sign[6] = {-1, 1, -1, 1, 1, -1};
    int best = 0;
    for (int k = 1; k < 6; k++)
        if (depth[k] < depth[best])
            best = k;
    add_contact(out, c->boxes, i, centre, axis[best], sign[best], true);
}

/* The first candidate (not ignored) that the avatar with its feet at pf
 * overlaps, or nboxes. */
static uint32_t first_overlap(const ctx *c, const float pf[3])
{
    const double p[3] = {pf[0], pf[1], pf[2]};
    for (uint32_t i = 0; i < c->nboxes; i++)
        if (!ignored(c, &c->boxes[i]) && overlaps(c, &c->boxes[i], p))
            return i;
    return c->nboxes;
}

/*
 * Rounds the final position p to float. The move never enters a box in
 * double, but a position within a float step of a face (a corner touched
 * exactly) may round into the box; then the position is nudged out through
 * the nearest side or top to the closest float outside, and if that does not
 * settle it, the avatar stays where it started, which overlaps nothing new.
 * The rounding goes through a volatile: gcc 12.2 at -O2 and -O3 (its SLP
 * vectorizer) turns "f = (float)d; ... e = (double)f" into "e = d", skipping
 * the rounding that this function exists to check.
 */
static void settle(const ctx *c, const double p[3], float pf[3])
{
    for (int a = 0; a < 3; a++) {
        volatile float rounded = (float)p[a]; /* see above */
        pf[a] = rounded;
    }
    for (int round = 0; round < SETTLE_ROUNDS; round++) {
        uint32_t i = first_overlap(c, pf);
        if (i == c->nboxes)
            return;
        double lo[3], hi[3];
        grown(c, &c->boxes[i], lo, hi);
        int axis = 1;
        bool down = false;
        double depth = hi[1] - pf[1];
        for (int a = 0; a < 3; a += 2) {
            if (pf[a] - lo[a] < depth)
                depth = pf[a] - lo[a], axis = a, down = true;
            if (hi[a] - pf[a] < depth)
                depth = hi[a] - pf[a], axis = a, down = false;
        }
        float f = (float)(down ? lo[axis] : hi[axis]);
        while (down ? (double)f > lo[axis] : (double)f < hi[axis])
            f = nextafterf(f, down ? -INFINITY : INFINITY);
        pf[axis] = f;
    }
    if (first_overlap(c, pf) < c->nboxes)
        for (int a = 0; a < 3; a++)
            pf[a] = (float)c->start[a];
}

/*
 * The avatar's feet are a little inside a floor or a low surface when the
 * move starts: lifts the start onto the highest top, at most a step above the
 * feet, of a box it overlaps, if the lift makes it overlap no box it did not
 * already overlap. Returns whether it lifted. c->start is the feet before.
 */
static bool stand_on(ctx *c)
{
    const double from[3] = {c->start[0], c->start[1], c->start[2]};
    double best = from[1];
    for (uint32_t i = 0; i < c->nboxes; i++) {
        double top = c->boxes[i].max[1];
        if (!(top > best) || top - from[1] > c->step || !overlaps(c, &c->boxes[i], from))
            continue;
        const double up[3] = {from[0], top, from[2]};
        bool room = true;
        for (uint32_t k = 0; k < c->nboxes && room; k++)
            room = !overlaps(c, &c->boxes[k], up) || overlaps(c, &c->boxes[k], from);
        if (room)
            best = top;
    }
    c->start[1] = best;
    return best > from[1];
}

/* Whether the avatar with its feet at p stands on the floor or on the top of
 * a box under its footprint. */
static bool supported(const ctx *c, const double p[3])
{
    if (p[1] - c->floor <= GROUND_PROBE)
        return true;
    for (uint32_t i = 0; i < c->nboxes; i++) {
        const move_box *b = &c->boxes[i];
        if (b->max[1] <= p[1] && p[1] - b->max[1] <= GROUND_PROBE && over(c, b, p[0], p[2]) && !ignored(c, b))
            return true;
    }
    return false;
}

static bool finite_within(const float *v, int n, float limit)
{
    for (int k = 0; k < n; k++)
        if (!isfinite(v[k]) || fabsf(v[k]) > limit)
            return false;
    return true;
}

static bool valid(const move_params *p, const move_state *st, const float disp[3], float dt)
{
    if (!p || !st || !disp)
        return false;
    for (int a = 0; a < 3; a++)
        if (!(p->size[a] > 0))
            return false;
    return finite_within(p->size, 3, MOVE_MAX_COORD) && finite_within(&p->gravity, 1, INFINITY) &&
           p->gravity >= 0 && finite_within(&p->step_height, 1, p->size[1]) && p->step_height >= 0 &&
           finite_within(&p->floor_y, 1, MOVE_MAX_COORD) && finite_within(st->pos, 3, MOVE_MAX_COORD) &&
           finite_within(&st->vy, 1, MOVE_MAX_COORD) && finite_within(disp, 3, MOVE_MAX_COORD) && dt >= 0 &&
           dt <= MOVE_MAX_DT;
}

/* Whether every box is finite with min <= max. */
static bool boxes_valid(const move_box *boxes, uint32_t n)
{
    for (uint32_t i = 0; i < n; i++)
        for (int a = 0; a < 3; a++)
            if (!isfinite(boxes[i].min[a]) || !isfinite(boxes[i].max[a]) || boxes[i].min[a] > boxes[i].max[a])
                return false;
    return true;
}

/* Sets up the context and the motion of the tick: the start (lifted onto the
 * floor), the fall speed at the end of the tick and the whole displacement. */
static void begin(ctx *c, const move_params *p, const move_state *st, const float disp[3], float dt, double m[3],
                  double *vy_end)
{
    for (int a = 0; a < 3; a++) {
        c->half[a] = a == 1 ? p->size[1] : p->size[a] / 2.0;
        c->grow_lo[a] = c->half[a];
        c->grow_hi[a] = a == 1 ? 0 : c->half[a];
        c->start[a] = st->pos[a];
    }
    c->floor = p->floor_y;
    c->step = p->step_height;
    if (c->start[1] < c->floor)
        c->start[1] = c->floor;
    double vy0 = st->vy, g = p->gravity, t = dt;
    *vy_end = fmax(vy0 - g * t, -(double)MOVE_MAX_FALL_SPEED);
    m[0] = disp[0];
    m[1] = disp[1] + (vy0 + *vy_end) / 2 * t;
    m[2] = disp[2];
}

void move_bounds(const move_params *p, const move_state *st, const float disp[3], float dt, float min[3],
                 float max[3])
{
    if (!valid(p, st, disp, dt)) {
        for (int a = 0; a < 3; a++)
            min[a] = 1, max[a] = 0;
        return;
    }
    ctx c;
    double m[3], vy_end;
    begin(&c, p, st, disp, dt, m, &vy_end);
    for (int a = 0; a < 3; a++) {
        double from = c.start[a], to = from + m[a];
        /* Slips sideways take at most the width's share each (slip). */
        double side = a == 1 ? 0 : MOVE_MAX_SLIDES * (2 * c.half[a] * MOVE_SLIP_FRACTION + MOVE_SKIN);
        double lo = fmin(from, to) - (a == 1 ? GROUND_PROBE : c.half[a] + side);
        double hi = fmax(from, to) + c.half[a] + (a == 1 ? (MOVE_MAX_STEPS + 1) * c.step : side);
        min[a] = (float)lo - BOUNDS_MARGIN;
        max[a] = (float)hi + BOUNDS_MARGIN;
    }
}

int move_step(const move_params *p, const move_state *st, const float disp[3], float dt, const move_box *boxes,
              uint32_t nboxes, move_result *out)
{
    if (!out)
        return -EINVAL;
    out->ncontacts = out->dropped = 0;
    if (!valid(p, st, disp, dt) || (!boxes && nboxes)) {
        if (st)
            out->state = *st;
        return -EINVAL;
    }
    if (!boxes_valid(boxes, nboxes)) {
        out->state = *st;
        return -EINVAL;
    }

    ctx c;
    c.boxes = boxes;
    c.nboxes = nboxes;
    double m[3], vy;
    begin(&c, p, st, disp, dt, m, &vy);
    bool on_ground = st->grounded, landed = false;
    if (stand_on(&c)) {
        on_ground = true; /* as after a step up: stands on the top, the fall dropped */
        if (m[1] < 0) {
            m[1] = 0;
            landed = true;
        }
    }
    double pos[3] = {c.start[0], c.start[1], c.start[2]};
    int slides = 0, steps = 0;

    while (slides < MOVE_MAX_SLIDES && (m[0] != 0 || m[1] != 0 || m[2] != 0)) {
        hit h;
        if (!sweep(&c, pos, m, &h)) {
            for (int a = 0; a < 3; a++)
                pos[a] += m[a];
            break;
        }
        int a = h.axis;
        bool top = a == 1 && h.side < 0; /* landing on a top face or the floor */
        /* Stop MOVE_SKIN short of the face along its normal, or exactly on a top. */
        double t = top ? h.t : fmax(0, h.t - MOVE_SKIN / fabs(m[a]));
        double at[3];
        for (int k = 0; k < 3; k++) {
            at[k] = pos[k] + m[k] * h.t;
            pos[k] += m[k] * t;
            m[k] *= 1 - t;
        }
        slides++;
        if (top) {
            pos[1] = h.floor ? c.floor : boxes[h.box].max[1];
            m[1] = 0;
            landed = on_ground = true;
            continue;
        }
        step st_up = STEP_BLOCKED;
        if (a != 1 && on_ground && steps < MOVE_MAX_STEPS)
            st_up = step_up(&c, pos, m, &boxes[h.box]);
        if (st_up == STEP_UP) {
            steps++;
            slides--; /* a step is not a slide */
            continue;
        }
        if (st_up == STEP_BLOCKED && a != 1 &&
            slip(&c, pos, m, &boxes[h.box], a, disp[2 - a], on_ground && steps < MOVE_MAX_STEPS))
            continue;
        if (st_up == STEP_BLOCKED)
            add_blocking(&c, out, h.box, at, &h);
        if (a == 1 && vy > 0)
            vy = 0; /* head against a ceiling */
        m[a] = 0;
    }

    float pf[3];
    settle(&c, pos, pf);
    const double fin[3] = {pf[0], pf[1], pf[2]};
    bool grounded = vy <= 0 && supported(&c, fin);
    memcpy(out->state.pos, pf, sizeof pf);
    out->state.vy = grounded || landed ? 0.0f : (float)vy;
    out->state.grounded = grounded;

    if (disp[0] != 0 || disp[1] != 0 || disp[2] != 0)
        for (uint32_t i = 0; i < nboxes; i++)
            if (ignored(&c, &boxes[i]) && overlaps(&c, &boxes[i], fin))
                add_inside(&c, out, i, fin);
    return 0;
}

/* The first box the avatar with its feet at p overlaps, from box `from` on,
 * or nboxes. */
static uint32_t overlapped_from(const ctx *c, const double p[3], uint32_t from)
{
    for (uint32_t i = from; i < c->nboxes; i++)
        if (overlaps(c, &c->boxes[i], p))
            return i;
    return c->nboxes;
}

/* Where the avatar at p goes past face k of box b (0..3: the sides -x, +x,
 * -z, +z, MOVE_SKIN past them; 4: standing on its top), rounded to float. */
static void past_face(const ctx *c, const move_box *b, int k, const double p[3], double q[3])
{
    double lo[3], hi[3];
    grown(c, b, lo, hi);
    memcpy(q, p, 3 * sizeof *q);
    int a = k == 4 ? 1 : k < 2 ? 0 : 2;
    q[a] = k == 4 ? hi[1] : k % 2 ? hi[a] + MOVE_SKIN : lo[a] - MOVE_SKIN;
    volatile float rounded = (float)q[a]; /* see settle */
    q[a] = rounded;
}

/* Takes q as the best place so far if it is nearer to from than *best_d,
 * within max_push, and overlaps no box. */
static void consider(const ctx *c, const double from[3], const double q[3], double max_push, double best[3],
                     double *best_d)
{
    double d = sqrt((q[0] - from[0]) * (q[0] - from[0]) + (q[1] - from[1]) * (q[1] - from[1]) +
                    (q[2] - from[2]) * (q[2] - from[2]));
    if (d < *best_d && d <= max_push && overlapped_from(c, q, 0) == c->nboxes) {
        *best_d = d;
        memcpy(best, q, 3 * sizeof *best);
    }
}

int move_push_out(const move_params *p, move_state *st, const move_box *boxes, uint32_t nboxes)
{
    static const float still[3] = {0, 0, 0};
    if (!valid(p, st, still, 0) || (!boxes && nboxes) || !boxes_valid(boxes, nboxes))
        return -EINVAL;
    const double max_push = fmin(p->size[0], p->size[2]) / 2.0;
    ctx c = {.boxes = boxes, .nboxes = nboxes};
    double m[3], vy;
    begin(&c, p, st, still, 0, m, &vy);
    const double from[3] = {c.start[0], c.start[1], c.start[2]};
    uint32_t inside[MOVE_PUSH_BOXES], k = 0;
    for (uint32_t i = overlapped_from(&c, from, 0); i < nboxes; i = overlapped_from(&c, from, i + 1)) {
        if (k == MOVE_PUSH_BOXES)
            return -ENOSPC;
        inside[k++] = i;
    }
    if (k == 0)
        return 0;
    /* Past one face; when that place overlaps another box, past one of its
     * faces too. */
    double best[3], best_d = INFINITY;
    for (uint32_t i = 0; i < k; i++)
        for (int f = 0; f < 5; f++) {
            double q[3], r[3];
            past_face(&c, &boxes[inside[i]], f, from, q);
            uint32_t j = overlapped_from(&c, q, 0);
            if (j == nboxes) {
                consider(&c, from, q, max_push, best, &best_d);
                continue;
            }
            for (int g = 0; g < 5; g++) {
                past_face(&c, &boxes[j], g, q, r);
                consider(&c, from, r, max_push, best, &best_d);
            }
        }
    if (best_d == INFINITY)
        return -ENOSPC;
    memcpy(c.start, best, sizeof best); /* it overlaps nothing: nothing is ignored */
    for (int a = 0; a < 3; a++)
        st->pos[a] = (float)best[a];
    st->vy = 0;
    st->grounded = supported(&c, best);
    return 1;
}
