#include "world.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "grid.h"
#include "srv_limits.h"

#define SLOT_MASK ((1u << WORLD_SLOT_BITS) - 1u)
/* Boxes one move is checked against. A tick's swept volume is a few metres
 * across; 4,096 boxes there would be a collision map of absurd density, and
 * past it the farthest found are ignored. */
#define WORLD_MAX_CANDIDATES 4096
/* The world's four sides and its ceiling, boxes in a push-out's trial. */
#define WORLD_WALLS 5

typedef struct avatar {
    world_avatar pub;
    int used;
    uint16_t gen;
    int has_request;
    uint32_t request_seq;
    float request[3];
    uint32_t moved_at_step; /* step of the last applied request */
} avatar;

struct world {
    world_config cfg;
    avatar *avatars; /* by slot */
    uint32_t *free_slots;
    uint32_t nfree;
    uint32_t count;
    uint32_t step;
    uint64_t rng;
    grid *grid;
    uint32_t *scratch; /* grid query results */
    uint32_t handles[WORLD_MAX_CANDIDATES]; /* broadphase results, per move */
    move_box boxes[WORLD_MAX_CANDIDATES];
};

/* xorshift64*: deterministic spawn points for a given seed. */
static double rnd(world *w)
{
    w->rng ^= w->rng >> 12;
    w->rng ^= w->rng << 25;
    w->rng ^= w->rng >> 27;
    return (double)((w->rng * 2685821657736338717ull) >> 11) * (1.0 / 9007199254740992.0);
}

world *world_create(const world_config *cfg)
{
    if (cfg->capacity == 0 || cfg->capacity > SLOT_MASK || !(cfg->aoi_radius > 0) || !(cfg->tick_dt > 0))
        return NULL;
    world *w = cvre_calloc(1, sizeof *w);
    if (!w)
        return NULL;
    w->cfg = *cfg;
    w->rng = cfg->seed ? cfg->seed : 0x9e3779b97f4a7c15ull;
    w->avatars = cvre_calloc(cfg->capacity, sizeof *w->avatars);
    w->free_slots = cvre_calloc(cfg->capacity, sizeof *w->free_slots);
    w->scratch = cvre_calloc(cfg->capacity, sizeof *w->scratch);
    /* Cells as wide as the radius: a query touches at most 3 x 3 cells. */
    w->grid = grid_create(cfg->min[0], cfg->min[2], cfg->max[0], cfg->max[2], cfg->aoi_radius, cfg->capacity);
    if (!w->avatars || !w->free_slots || !w->scratch || !w->grid) {
        world_destroy(w);
        return NULL;
    }
    /* Hand out low slots first: ids stay small and readable in logs. */
    for (uint32_t i = 0; i < cfg->capacity; i++)
        w->free_slots[i] = cfg->capacity - 1 - i;
    w->nfree = cfg->capacity;
    w->step = 1;
    return w;
}

void world_destroy(world *w)
{
    if (!w)
        return;
    grid_destroy(w->grid);
    free(w->avatars);
    free(w->free_slots);
    free(w->scratch);
    free(w);
}

static avatar *lookup(const world *w, uint32_t id)
{
    uint32_t slot = world_slot(id);
    if (slot >= w->cfg.capacity)
        return NULL;
    avatar *a = &w->avatars[slot];
    return a->used && a->pub.id == id ? a : NULL;
}

const world_avatar *world_get(const world *w, uint32_t id)
{
    const avatar *a = lookup(w, id);
    return a ? &a->pub : NULL;
}

static float clampf(float v, float lo, float hi) { return v < lo ? lo : v > hi ? hi : v; }

/* Keeps a box of size box standing at p inside the world. */
static void clamp_into_world(const world *w, const float box[3], float p[3])
{
    const float *lo = w->cfg.min, *hi = w->cfg.max;
    p[0] = clampf(p[0], lo[0] + box[0] * 0.5f, hi[0] - box[0] * 0.5f);
    p[1] = clampf(p[1], lo[1], hi[1] - box[1]);
    p[2] = clampf(p[2], lo[2] + box[2] * 0.5f, hi[2] - box[2] * 0.5f);
}

/* The controller's parameters for an avatar of size box in w. */
static void params(const world *w, const float box[3], move_params *mp)
{
    move_params_default(mp);
    memcpy(mp->size, box, sizeof mp->size);
    mp->floor_y = w->cfg.min[1];
}

/* w->boxes[k] becomes the box behind w->handles[i]. */
static void candidate(world *w, const scene *sc, uint32_t i, uint32_t k)
{
    const scene_box_ref *b = scene_box_at(sc, w->handles[i]);
    w->boxes[k] = (move_box){.object_id = b->object_id, .box_index = b->box_index, .handle = w->handles[i]};
    memcpy(w->boxes[k].min, b->world.min, sizeof b->world.min);
    memcpy(w->boxes[k].max, b->world.max, sizeof b->world.max);
}

/* Moves st by disp over dt through move_step against the boxes of sc the
 * move can reach (into w->boxes). Returns move_step's result. */
static int controller(world *w, const scene *sc, const move_params *mp, const move_state *st, const float disp[3],
                      float dt, move_result *res)
{
    float lo[3], hi[3];
    move_bounds(mp, st, disp, dt, lo, hi);
    uint32_t n = scene_query(sc, lo, hi, w->handles, WORLD_MAX_CANDIDATES);
    if (n > WORLD_MAX_CANDIDATES)
        n = WORLD_MAX_CANDIDATES;
    for (uint32_t i = 0; i < n; i++)
        candidate(w, sc, i, i);
    return move_step(mp, st, disp, dt, w->boxes, n, res);
}

/* The box of an avatar of size box standing at p. */
static void avatar_bounds(const float p[3], const float box[3], float lo[3], float hi[3])
{
    lo[0] = p[0] - box[0] * 0.5f, lo[1] = p[1], lo[2] = p[2] - box[2] * 0.5f;
    hi[0] = p[0] + box[0] * 0.5f, hi[1] = p[1] + box[1], hi[2] = p[2] + box[2] * 0.5f;
}

/* Whether the interiors of the box [lo, hi] and box b meet. */
static int meets(const float lo[3], const float hi[3], const scene_box *b)
{
    return b->min[0] < hi[0] && lo[0] < b->max[0] && b->min[1] < hi[1] && lo[1] < b->max[1] && b->min[2] < hi[2] &&
           lo[2] < b->max[2];
}

/* Whether a box of size box standing at p, once stood on any floor its feet
 * are a little into (move.h), overlaps no box of sc (their interiors meet
 * nowhere, as in move.h); if so, p is moved onto that floor. */
static int free_at(world *w, const scene *sc, const float box[3], float p[3])
{
    move_params mp;
    params(w, box, &mp);
    const move_state st = {.pos = {p[0], p[1], p[2]}, .grounded = true};
    static const float still[3] = {0, 0, 0};
    move_result res;
    if (controller(w, sc, &mp, &st, still, 0, &res) < 0)
        return 0;
    const float *q = res.state.pos;
    float lo[3], hi[3];
    avatar_bounds(q, box, lo, hi);
    uint32_t n = scene_query(sc, lo, hi, w->handles, WORLD_MAX_CANDIDATES);
    if (n > WORLD_MAX_CANDIDATES)
        return 0;
    for (uint32_t i = 0; i < n; i++)
        if (meets(lo, hi, &scene_box_at(sc, w->handles[i])->world))
            return 0;
    memcpy(p, q, sizeof res.state.pos);
    return 1;
}

/* Moves p (on the floor, inside the world) to the nearest point free of
 * sc's boxes on rings around it, one avatar width apart, up to
 * WORLD_SPAWN_SEARCH. Returns 0, or -1 leaving p as it was when every
 * point tried is taken. */
static int find_free_spot(world *w, const scene *sc, const float box[3], float p[3])
{
    if (free_at(w, sc, box, p))
        return 0;
    float step = fmaxf(fmaxf(box[0], box[2]), 0.25f);
    for (float r = step; r <= WORLD_SPAWN_SEARCH; r += step) {
        uint32_t n = (uint32_t)ceilf(2.0f * (float)M_PI * r / step);
        for (uint32_t i = 0; i < n; i++) {
            float ang = 2.0f * (float)M_PI * (float)i / (float)n;
            float q[3] = {p[0] + r * cosf(ang), p[1], p[2] + r * sinf(ang)};
            float inside[3] = {q[0], q[1], q[2]};
            clamp_into_world(w, box, inside);
            if (inside[0] != q[0] || inside[2] != q[2] || !free_at(w, sc, box, q))
                continue;
            memcpy(p, q, sizeof q);
            return 0;
        }
    }
    return -ENOSPC;
}

const world_avatar *world_add(world *w, const scene *sc, const char *name, uint32_t name_len, const float box[3],
                              int *crowded)
{
    if (!w->nfree || name_len > PROTO_NAME_MAX)
        return NULL;
    uint32_t slot = w->free_slots[w->nfree - 1];
    avatar *a = &w->avatars[slot];
    uint16_t gen = (uint16_t)(a->gen + 1u);
    if (gen == 0) /* keeps every id non-zero */
        gen = 1;
    memset(a, 0, sizeof *a);
    a->gen = gen;
    a->pub.id = slot | (uint32_t)gen << WORLD_SLOT_BITS;
    memcpy(a->pub.name, name, name_len);
    memcpy(a->pub.box, box, sizeof a->pub.box);
    double ang = rnd(w) * 2.0 * M_PI, r = w->cfg.spawn_radius * sqrt(rnd(w));
    a->pub.pos[0] = (w->cfg.min[0] + w->cfg.max[0]) * 0.5f + (float)(r * cos(ang));
    a->pub.pos[1] = w->cfg.min[1];
    a->pub.pos[2] = (w->cfg.min[2] + w->cfg.max[2]) * 0.5f + (float)(r * sin(ang));
    clamp_into_world(w, box, a->pub.pos);
    *crowded = find_free_spot(w, sc, box, a->pub.pos) < 0;
    a->pub.changed_tick = w->step;
    a->pub.grounded = 1;
    a->moved_at_step = w->step;
    if (grid_insert(w->grid, slot, a->pub.pos[0], a->pub.pos[2]) < 0)
        return NULL;
    a->used = 1;
    w->nfree--;
    w->count++;
    return &a->pub;
}

void world_remove(world *w, uint32_t id)
{
    avatar *a = lookup(w, id);
    if (!a)
        return;
    uint32_t slot = world_slot(id);
    grid_remove(w->grid, slot);
    a->used = 0;
    w->free_slots[w->nfree++] = slot;
    w->count--;
}

void world_request_move(world *w, uint32_t id, uint32_t seq, const float pos[3])
{
    avatar *a = lookup(w, id);
    if (!a)
        return;
    a->has_request = 1;
    a->request_seq = seq;
    memcpy(a->request, pos, sizeof a->request);
}

/* The angle between two quantized unit quaternions: 2 acos |q.r|. */
static float turn(const int16_t q[4], const int16_t r[4])
{
    float dot = 0;
    for (int i = 0; i < 4; i++)
        dot += (float)q[i] * (float)r[i];
    dot = fabsf(dot) / ((float)PROTO_QUAT_ONE * (float)PROTO_QUAT_ONE);
    return 2.0f * acosf(dot > 1.0f ? 1.0f : dot);
}

/* Whether p is far enough from q, the pose last taken, to be sent again. */
static int pose_moved(const proto_pose *p, const proto_pose *q)
{
    if (p->parts != q->parts || fabsf(remainderf(p->yaw - q->yaw, 2.0f * (float)M_PI)) > WORLD_POSE_ANGLE_MIN ||
        fabsf(p->pitch - q->pitch) > WORLD_POSE_ANGLE_MIN)
        return 1;
    for (unsigned k = 0; k < PROTO_POSE_PARTS; k++) {
        if (!PROTO_POSE_HAS(p, k))
            continue;
        for (int i = 0; i < 3; i++)
            if (abs(p->pos[k][i] - q->pos[k][i]) > WORLD_POSE_MOVE_MIN_MM)
                return 1;
        if (turn(p->rot[k], q->rot[k]) > WORLD_POSE_TURN_MIN)
            return 1;
    }
    return 0;
}

int world_set_pose(world *w, uint32_t id, const proto_pose *p)
{
    avatar *a = lookup(w, id);
    if (!a || (a->pub.has_pose && !pose_moved(p, &a->pub.pose)))
        return 0;
    a->pub.has_pose = 1;
    a->pub.pose = *p;
    /* This step's updates may be done already: the next one sends it. */
    a->pub.pose_tick = w->step + 1;
    return 1;
}

/* Moves a for one step: toward its request (if any) by at most max_speed x
 * the time since its last applied move, under gravity, through move_step
 * against the boxes the scene finds along the way; then keeps it inside the
 * world. */
static void apply(world *w, avatar *a, const scene *sc, world_contact_fn *fn, void *ctx)
{
    float disp[3] = {0, 0, 0}, vel[3] = {0, 0, 0};
    float *p = a->pub.pos;
    if (a->has_request) {
        float elapsed = (float)(w->step - a->moved_at_step) * w->cfg.tick_dt;
        if (elapsed > SRV_MOVE_MAX_DT)
            elapsed = SRV_MOVE_MAX_DT;
        float dx = a->request[0] - p[0], dz = a->request[2] - p[2];
        float len = sqrtf(dx * dx + dz * dz), reach = w->cfg.max_speed * elapsed;
        float k = len > reach ? reach / len : 1.0f;
        disp[0] = dx * k;
        disp[2] = dz * k;
        if (elapsed > 0) {
            vel[0] = disp[0] / elapsed;
            vel[2] = disp[2] / elapsed;
        }
        a->has_request = 0;
        a->moved_at_step = w->step;
        a->pub.ack_seq = a->request_seq;
    }
    move_params mp;
    params(w, a->pub.box, &mp);
    move_state st = {.pos = {p[0], p[1], p[2]}, .vy = a->pub.vy, .grounded = a->pub.grounded != 0};
    move_result res;
    if (controller(w, sc, &mp, &st, disp, w->cfg.tick_dt, &res) < 0)
        return; /* out of the controller's range: stay put */
    float q[3] = {res.state.pos[0], res.state.pos[1], res.state.pos[2]};
    clamp_into_world(w, a->pub.box, q);
    a->pub.vy = res.state.vy;
    a->pub.grounded = res.state.grounded;
    for (uint32_t i = 0; i < res.ncontacts; i++)
        fn(ctx, &a->pub, &res.contacts[i], vel);
    if (q[0] == p[0] && q[1] == p[1] && q[2] == p[2])
        return;
    memcpy(p, q, sizeof q);
    a->pub.changed_tick = w->step;
    /* On out-of-memory the grid keeps the avatar in its old cell, which only
     * delays when neighbours see it; the move itself stands. */
    (void)grid_move(w->grid, world_slot(a->pub.id), p[0], p[2]);
}

void world_step(world *w, const scene *sc, world_contact_fn *fn, void *ctx)
{
    w->step++;
    for (uint32_t s = 0; s < w->cfg.capacity; s++) {
        avatar *a = &w->avatars[s];
        if (a->used && (a->has_request || !a->pub.grounded))
            apply(w, a, sc, fn, ctx);
    }
}

uint32_t world_tick(const world *w) { return w->step; }

/* Pushes avatar a out of object o's new boxes (world_push_out): 1 when
 * pushed, 0 when it needs no push, -ENOSPC when none frees it. */
static int push_out(world *w, const scene *sc, avatar *a, const scene_object *o, const scene_box *old, uint32_t nold)
{
    const float *p = a->pub.pos, *box = a->pub.box;
    float lo[3], hi[3];
    avatar_bounds(p, box, lo, hi);
    if (!meets(lo, hi, &o->bounds))
        return 0;
    for (uint32_t i = 0; i < nold; i++)
        if (meets(lo, hi, &old[i]))
            return 0; /* the object stood around it already */
    /* The boxes a push can meet: past the faces of those it overlaps, at
     * most half its width away, or standing on one (and a little below,
     * what it may stand on). Past the candidates' room, no push: it could
     * land in a box it never saw. */
    float reach = fmaxf(box[0], box[2]);
    const float qlo[3] = {lo[0] - reach, lo[1] - reach, lo[2] - reach},
                qhi[3] = {hi[0] + reach, hi[1] + reach, hi[2] + reach};
    uint32_t n = scene_query(sc, qlo, qhi, w->handles, WORLD_MAX_CANDIDATES), k = 0;
    if (n > WORLD_MAX_CANDIDATES - WORLD_WALLS)
        return -ENOSPC;
    int enclosed = 0;
    for (uint32_t i = 0; i < n; i++) {
        const scene_box_ref *b = scene_box_at(sc, w->handles[i]);
        int in = meets(lo, hi, &b->world);
        if (in && b->object_id != o->id)
            continue; /* another object's box it was inside: its inside policy holds */
        enclosed |= in;
        candidate(w, sc, i, k++);
    }
    if (!enclosed)
        return 0;
    /* The world's sides and ceiling, as boxes just outside it around the
     * query: no push takes an avatar out of the world. */
    const float *wl = w->cfg.min, *wh = w->cfg.max;
    const float walls[WORLD_WALLS][6] = {
        {qlo[0] - 1, qlo[1] - 1, qlo[2] - 1, wl[0], qhi[1] + 1, qhi[2] + 1},
        {wh[0], qlo[1] - 1, qlo[2] - 1, qhi[0] + 1, qhi[1] + 1, qhi[2] + 1},
        {qlo[0] - 1, qlo[1] - 1, qlo[2] - 1, qhi[0] + 1, qhi[1] + 1, wl[2]},
        {qlo[0] - 1, qlo[1] - 1, wh[2], qhi[0] + 1, qhi[1] + 1, qhi[2] + 1},
        {qlo[0] - 1, wh[1], qlo[2] - 1, qhi[0] + 1, qhi[1] + 1, qhi[2] + 1}};
    for (int i = 0; i < WORLD_WALLS; i++)
        if (walls[i][0] < walls[i][3] && walls[i][1] < walls[i][4] && walls[i][2] < walls[i][5]) {
            w->boxes[k] = (move_box){.object_id = 0, .box_index = UINT32_MAX, .handle = UINT32_MAX};
            memcpy(w->boxes[k].min, walls[i], 3 * sizeof(float));
            memcpy(w->boxes[k].max, walls[i] + 3, 3 * sizeof(float));
            k++;
        }
    move_params mp;
    params(w, box, &mp);
    move_state st = {.pos = {p[0], p[1], p[2]}, .vy = a->pub.vy, .grounded = a->pub.grounded != 0};
    int rc = move_push_out(&mp, &st, w->boxes, k);
    if (rc <= 0)
        return rc < 0 ? -ENOSPC : 0;
    memcpy(a->pub.pos, st.pos, sizeof st.pos);
    a->pub.vy = st.vy;
    a->pub.grounded = st.grounded;
    /* Between two steps: viewers hear of it with the next one, which this
     * step's update has already gone out before (world_set_pose too). */
    a->pub.changed_tick = w->step + 1;
    (void)grid_move(w->grid, world_slot(a->pub.id), a->pub.pos[0], a->pub.pos[2]); /* as in apply */
    return 1;
}

uint32_t world_push_out(world *w, const scene *sc, uint32_t object_id, const scene_box *old, uint32_t nold,
                        uint32_t *stuck)
{
    const scene_object *o = scene_get(sc, object_id);
    uint32_t pushed = 0;
    *stuck = 0;
    for (uint32_t s = 0; o && s < w->cfg.capacity; s++) {
        if (!w->avatars[s].used)
            continue;
        int rc = push_out(w, sc, &w->avatars[s], o, old, nold);
        pushed += rc > 0 ? 1u : 0u;
        *stuck += rc < 0 ? 1u : 0u;
    }
    return pushed;
}

uint32_t world_count(const world *w) { return w->count; }

uint32_t world_neighbours(world *w, uint32_t id, const world_avatar **out, uint32_t max)
{
    const avatar *me = lookup(w, id);
    if (!me)
        return 0;
    uint32_t n = grid_query(w->grid, me->pub.pos[0], me->pub.pos[2], w->cfg.aoi_radius, w->scratch, w->cfg.capacity);
    uint32_t k = 0;
    for (uint32_t i = 0; i < n && k < max; i++)
        if (w->scratch[i] != world_slot(id))
            out[k++] = &w->avatars[w->scratch[i]].pub;
    return k;
}
