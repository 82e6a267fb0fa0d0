#include "judge.h"

#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "err.h"
#include "refine.h"
#include "task.h"
#include "tribins.h"
#include "voxel.h"

/* The table's counts: a whole grid's cells fit uint32_t. */
#define JUDGE_DEPTH_MAX 8u
_Static_assert(3 * JUDGE_DEPTH_MAX < 32, "cell counts fit uint32_t");
_Static_assert(JUDGE_DEPTH_MAX <= VOXEL_DEPTH_MAX, "depths the voxelizer takes");
/* Bins per axis of the triangle index the exact test looks in: a triangle
 * of a detailed mesh falls in one or two, a room's wall in a row of them;
 * 16^3 offsets are 16 KiB. With 32^3 (128 KiB) building and walking the
 * bins cost more than the candidates they spared (see JUDGE_DEPTH_DEFAULT). */
#define JUDGE_BINS 16u
/* The occupancy grid only says where no triangle is (maybe_touches), so a
 * triangle whose bounding box spans at most this many cells marks them all
 * (voxel_mark_boxed's loose marking) without a test of its own: bench-
 * refine's bunny statue, 30.2 -> 21.1 M instructions. */
#define JUDGE_LOOSE_CELLS 8u

/* The geometry, asked "does this box touch a triangle?". Local
 * coordinates: boxes in the metric frame are divided by the scale. Only the
 * triangles whose bounding box meets the region the trials can reach (near:
 * see trial_region) are indexed, copied into tris; a box outside that
 * region, which no trial asks by move.h's contract, is still answered
 * exactly, from all the triangles. */
typedef struct geometry {
    voxel_grid g;        /* over the indexed triangles (none: no grid) */
    voxel_svt svt;       /* occupied cells */
    tribins bins;        /* JUDGE_BINS^3 over the grid's box */
    float (*tbox)[6];    /* each indexed triangle's bounding box: most exact tests end there */
    float *tris;         /* the indexed triangles, 9 floats each */
    uint32_t ntris;
    double near[6];      /* local min x y z, max x y z: the region indexed */
    const judge_input *in;
    double scale;
    double beside_ms;    /* CPU time of the index's build on a thread of its own */
    int bins_rc;         /* tribins_build's return */
} geometry;

/* One map in the metric frame, with room for the boxes near one move. */
typedef struct map {
    move_box *boxes;
    uint32_t n;
    move_box *near;
} map;

void judge_params_default(judge_params *p)
{
    *p = (judge_params){.dt = JUDGE_DT_DEFAULT,
                        .reach = JUDGE_REACH_DEFAULT,
                        .speed = JUDGE_SPEED_DEFAULT,
                        .deflect = JUDGE_DEFLECT_DEFAULT,
                        .depth = JUDGE_DEPTH_DEFAULT,
                        .cell_depth = ECM_DEPTH_DEFAULT,
                        .max_samples = JUDGE_SAMPLES_DEFAULT};
    move_params_default(&p->move);
}

static void geometry_free(geometry *g)
{
    voxel_grid_free(&g->g);
    free(g->svt.t);
    tribins_free(&g->bins);
    free(g->tbox);
    free(g->tris);
}

/* Inline: fminf and fmaxf are library calls on baseline x86-64, and every
 * value here is finite. */
static inline float fmin2(float a, float b) { return a < b ? a : b; }
static inline float fmax2(float a, float b) { return a > b ? a : b; }

/* The table of occupied cells, from the grid's bits made bytes. */
static int build_svt(geometry *g)
{
    uint32_t n = g->g.n, m = n + 1;
    uint8_t *cells = cvre_malloc((size_t)n * n * n);
    g->svt.t = cvre_malloc((size_t)m * m * m * sizeof *g->svt.t);
    if (!cells || !g->svt.t) {
        free(cells);
        return -ENOMEM;
    }
    for (uint32_t z = 0, i = 0; z < n; z++)
        for (uint32_t y = 0; y < n; y++)
            for (uint32_t x = 0; x < n; x++)
                cells[i++] = (uint8_t)voxel_get(&g->g, x, y, z);
    voxel_svt_build(&g->svt, g->svt.t, n, cells, 0);
    free(cells);
    return 0;
}

static int meets(const float b[6], const double r[6])
{
    for (int a = 0; a < 3; a++)
        if ((double)b[a] > r[3 + a] || (double)b[3 + a] < r[a])
            return 0;
    return 1;
}

/* The bins of the indexed triangles over their grid's box (a task). */
static void build_bins(void *arg)
{
    geometry *g = arg;
    const double region[6] = {g->g.min[0], g->g.min[1], g->g.min[2], g->g.max[0], g->g.max[1], g->g.max[2]};
    g->bins_rc = tribins_build(&g->bins, region, JUDGE_BINS, (const float(*)[6])g->tbox, g->ntris, 0,
                               JUDGE_BIN_SPREAD_MAX);
}

/* Indexes the triangles whose bounding box meets near (local): copies them,
 * digitizes them over their bounding box and bins them. */
static int geometry_init(geometry *g, const judge_params *p, const judge_input *in, const double near[6])
{
    memcpy(g->near, near, sizeof g->near);
    g->in = in;
    g->scale = in->scale;
    /* Room for every triangle, of which only what the indexed ones fill
     * is touched (a large block's pages are mapped as they are written):
     * growing the arrays instead copied them again and again. */
    const trimesh *m = in->mesh;
    g->tbox = cvre_malloc(m->ntris * sizeof *g->tbox);
    g->tris = cvre_malloc((size_t)m->ntris * 9 * sizeof *g->tris);
    if (!g->tbox || !g->tris)
        return -ENOMEM;
    float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (uint32_t i = 0; i < m->ntris; i++) {
        const float *t = m->tris + 9 * (size_t)i, *b = m->box[i];
        if (!meets(b, near))
            continue;
        memcpy(g->tbox[g->ntris], b, sizeof g->tbox[0]);
        memcpy(g->tris + 9 * (size_t)g->ntris, t, 9 * sizeof *t);
        g->ntris++;
        for (int a = 0; a < 3; a++) {
            lo[a] = fmin2(lo[a], b[a]);
            hi[a] = fmax2(hi[a], b[3 + a]);
        }
    }
    if (g->ntris == 0)
        return 0;
    int rc = voxel_grid_init(&g->g, p->depth, lo, hi);
    if (rc < 0)
        return rc;
    /* The index beside the coarse grid (its loose marking, a few cells a
     * triangle, is too little work to share out in slabs). */
    task bins;
    task_start(&bins, build_bins, g, task_spare(p->threads));
    /* Copies of the mesh's triangles, checked by trimesh_init, and their boxes. */
    if ((rc = voxel_mark_boxed(&g->g, g->tris, (const float(*)[6])g->tbox, g->ntris, JUDGE_LOOSE_CELLS, 1)) >= 0)
        rc = build_svt(g);
    g->beside_ms = task_wait(&bins);
    return rc < 0 ? rc : g->bins_rc;
}

/* The cells of a local interval on axis a: [lo, hi], closed cells, so a box
 * touching a cell's face gets that cell too; 0 if it misses the grid. */
static int cell_range(const geometry *g, int a, double lo, double hi, uint32_t *clo, uint32_t *chi)
{
    if (hi < g->g.min[a] || lo > g->g.max[a])
        return 0;
    uint32_t n = g->g.n;
    if (g->g.cell[a] <= 0) {
        *clo = 0;
        *chi = n - 1;
        return 1;
    }
    double l = floor((lo - g->g.min[a]) / g->g.cell[a]), h = floor((hi - g->g.min[a]) / g->g.cell[a]);
    *clo = l < 0 ? 0 : l > n - 1 ? n - 1 : (uint32_t)l;
    *chi = h < 0 ? 0 : h > n - 1 ? n - 1 : (uint32_t)h;
    return 1;
}

/* Whether the metric box [lo, hi] may touch a triangle: occupied cells in
 * the cells it meets. */
static int maybe_touches(const geometry *g, const double lo[3], const double hi[3])
{
    uint32_t a[3], b[3];
    for (int k = 0; k < 3; k++)
        if (!cell_range(g, k, lo[k] / g->scale, hi[k] / g->scale, &a[k], &b[k]))
            return 0;
    b[0]++, b[1]++, b[2]++;
    return voxel_svt_sum(&g->svt, a, b) > 0;
}

/* Whether the metric box [lo, hi] overlaps a triangle, exactly. */
static int touches_exactly(geometry *g, const double lo[3], const double hi[3])
{
    double l[3], h[3];
    int inside = 1;
    for (int k = 0; k < 3; k++) {
        l[k] = lo[k] / g->scale;
        h[k] = hi[k] / g->scale;
        inside &= l[k] >= g->near[k] && h[k] <= g->near[3 + k];
    }
    if (!inside) { /* beyond the triangles indexed: all of them, one by one */
        const trimesh *m = g->in->mesh;
        for (uint32_t i = 0; i < m->ntris; i++)
            if (trimesh_tri_overlaps(m->tris + 9 * (size_t)i, m->box[i], l, h))
                return 1;
        return 0;
    }
    if (g->ntris == 0 || !maybe_touches(g, lo, hi))
        return 0;
    tribins_iter it;
    tribins_query(&g->bins, l, h, &it);
    for (uint32_t t; (t = tribins_next(&it)) != TRIBINS_END;)
        if (trimesh_tri_overlaps(g->tris + 9 * (size_t)t, g->tbox[t], l, h))
            return 1;
    return 0;
}

static int map_init(map *m, const float (*boxes)[6], uint32_t n, double scale)
{
    m->boxes = cvre_malloc(n * sizeof *m->boxes);
    m->near = cvre_malloc(n * sizeof *m->near);
    if (!m->boxes || !m->near)
        return -ENOMEM;
    m->n = n;
    for (uint32_t i = 0; i < n; i++) {
        m->boxes[i] = (move_box){.box_index = i};
        for (int a = 0; a < 3; a++) {
            m->boxes[i].min[a] = (float)(boxes[i][a] * scale);
            m->boxes[i].max[a] = (float)(boxes[i][3 + a] * scale);
        }
    }
    return 0;
}

static void map_free(map *m)
{
    free(m->boxes);
    free(m->near);
}

/* The avatar's box at feet f, grown by lo below and hi above on each axis
 * (negative: shrunk). */
static void avatar_box(const move_params *mp, const float f[3], const double grow_lo[3], const double grow_hi[3],
                       double lo[3], double hi[3])
{
    const double base[3] = {-mp->size[0] / 2.0, 0, -mp->size[2] / 2.0};
    const double top[3] = {mp->size[0] / 2.0, mp->size[1], mp->size[2] / 2.0};
    for (int a = 0; a < 3; a++) {
        lo[a] = f[a] + base[a] - grow_lo[a];
        hi[a] = f[a] + top[a] + grow_hi[a];
    }
}

/* The contact of the move r (from st, asked for disp) that held it back,
 * or NULL: an inside contact, or a blocking one that left the avatar less
 * than JUDGE_HELD_BACK of its horizontal motion, the one whose face most
 * opposes the motion (a trial sliding along one box is stopped by the
 * next). Sliding along a face it meets at a glance is not held back: a map
 * that opens a corridor is not charged for its walls as if they stopped
 * users. */
static const move_contact *held_back(const move_result *r, const move_state *st, const float disp[3])
{
    for (uint32_t i = 0; i < r->ncontacts; i++)
        if (r->contacts[i].inside)
            return &r->contacts[i];
    if (r->ncontacts == 0)
        return NULL;
    double moved = hypot((double)r->state.pos[0] - st->pos[0], (double)r->state.pos[2] - st->pos[2]);
    if (!(moved < JUDGE_HELD_BACK * hypot(disp[0], disp[2])))
        return NULL;
    const move_contact *most = &r->contacts[0];
    for (uint32_t i = 1; i < r->ncontacts; i++) {
        const float *a = r->contacts[i].normal, *b = most->normal;
        if (a[0] * disp[0] + a[2] * disp[2] < b[0] * disp[0] + b[2] * disp[2])
            most = &r->contacts[i];
    }
    return most;
}

/* Where a new map's phantom blocks were (judge_places). */
typedef struct place_list {
    judge_place *p;
    uint32_t n, cap;
} place_list;

/* What the trials of one map counted (trial: phantom, opened; walk_map:
 * the ticks walked and the samples not walked), and where its phantom
 * blocks were (at: NULL for the old map). */
typedef struct tally {
    uint64_t phantom, opened, moves, still;
    place_list *at;
} tally;

/* Adds ticks phantom blocks of the avatar with its feet at f, held back by
 * contact c, to *at (metric -> local by scale); a stuck avatar adds to its
 * last place. Out of memory, the place is left out: places only guide. */
static void add_place(place_list *at, const move_params *mp, const float f[3], const move_contact *c, double scale,
                      uint64_t ticks)
{
    static const double none[3] = {0, 0, 0};
    double lo[3], hi[3];
    avatar_box(mp, f, none, none, lo, hi);
    judge_place q = {.hit = c->box_index, .ticks = ticks > UINT32_MAX ? UINT32_MAX : (uint32_t)ticks};
    for (int a = 0; a < 3; a++) {
        q.box[a] = (float)(lo[a] / scale);
        q.box[3 + a] = (float)(hi[a] / scale);
        q.point[a] = (float)(c->point[a] / scale);
    }
    if (at->n && memcmp(at->p[at->n - 1].box, q.box, sizeof q.box) == 0 && at->p[at->n - 1].hit == q.hit) {
        uint64_t sum = (uint64_t)at->p[at->n - 1].ticks + q.ticks;
        at->p[at->n - 1].ticks = sum > UINT32_MAX ? UINT32_MAX : (uint32_t)sum;
        return;
    }
    if (at->n == at->cap) {
        uint32_t cap = at->cap ? 2 * at->cap : 64;
        judge_place *np = cvre_realloc(at->p, cap * sizeof *np);
        if (!np)
            return;
        at->p = np;
        at->cap = cap;
    }
    at->p[at->n++] = q;
}

/* Whether the avatar with its feet at f overlaps a box of m (interiors). */
static int encloses(const move_params *mp, const map *m, const float f[3])
{
    static const double none[3] = {0, 0, 0};
    double lo[3], hi[3];
    avatar_box(mp, f, none, none, lo, hi);
    for (uint32_t i = 0; i < m->n; i++) {
        const move_box *b = &m->boxes[i];
        if (b->min[0] < hi[0] && lo[0] < b->max[0] && b->min[1] < hi[1] && lo[1] < b->max[1] && b->min[2] < hi[2] &&
            lo[2] < b->max[2])
            return 1;
    }
    return 0;
}

/* Where sample s starts against the new map: where the server leaves an
 * avatar when it puts that map in force (server/world.h, world_push_out):
 * pushed out of the new boxes if one encloses it and no old box did. */
static move_state start_new(const judge_params *p, const map *old, const map *cur, const judge_sample *s)
{
    move_state st = {.pos = {s->pos[0], s->pos[1], s->pos[2]}, .vy = 0, .grounded = true};
    if (!encloses(&p->move, old, st.pos) && encloses(&p->move, cur, st.pos))
        (void)move_push_out(&p->move, &st, cur->boxes, cur->n); /* none frees it: the inside policy */
    return st;
}

/* Walks the avatar from st along (dx, dz) (a unit vector) at speed for
 * ticks ticks against m; adds what it finds to *t. */
static void trial(const judge_params *p, geometry *g, const double cell[3], map *m, move_state st, float dx,
                  float dz, float speed, uint32_t ticks, tally *t)
{
    /* Its bottom raised: what it stands on is support, not what stopped it. */
    const double grow_lo[3] = {cell[0], -JUDGE_FLOOR_TOLERANCE, cell[2]};
    const double shrink[3] = {-JUDGE_LEAK_TOLERANCE, -JUDGE_LEAK_TOLERANCE, -JUDGE_LEAK_TOLERANCE};
    const float disp[3] = {dx * speed * p->dt, 0, dz * speed * p->dt};
    uint64_t run = 0;        /* phantom ticks in a row so far */
    move_contact last = {0}; /* what held the last of them back, */
    float at[3] = {0, 0, 0}; /* and where */
    for (uint32_t k = 0; k < ticks; k++) {
        float lo[3], hi[3];
        move_bounds(&p->move, &st, disp, p->dt, lo, hi);
        uint32_t n = 0;
        for (uint32_t i = 0; i < m->n; i++) {
            const move_box *b = &m->boxes[i];
            if (b->min[0] <= hi[0] && b->max[0] >= lo[0] && b->min[1] <= hi[1] && b->max[1] >= lo[1] &&
                b->min[2] <= hi[2] && b->max[2] >= lo[2])
                m->near[n++] = *b;
        }
        move_result r;
        if (move_step(&p->move, &st, disp, p->dt, m->near, n, &r) < 0)
            return; /* out of the controller's range: the trial ends there */
        double blo[3], bhi[3];
        int phantom = 0, opened;
        const move_contact *held = held_back(&r, &st, disp);
        if (held) {
            avatar_box(&p->move, r.state.pos, grow_lo, cell, blo, bhi);
            phantom = !touches_exactly(g, blo, bhi);
        }
        avatar_box(&p->move, r.state.pos, shrink, shrink, blo, bhi);
        opened = touches_exactly(g, blo, bhi);
        bool stuck = memcmp(&r.state.pos, &st.pos, sizeof st.pos) == 0 && r.state.vy == st.vy &&
                     r.state.grounded == st.grounded;
        /* Stuck: every tick left would be this one again. */
        uint64_t times = stuck ? ticks - k : 1;
        if (phantom) {
            /* A run counts once it is JUDGE_HELD_TICKS long, from its first tick. */
            run += times;
            uint64_t counted = run < JUDGE_HELD_TICKS ? 0 : run - times >= JUDGE_HELD_TICKS ? times : run;
            t->phantom += counted;
            last = *held;
            memcpy(at, r.state.pos, sizeof at);
            if (counted && t->at)
                add_place(t->at, &p->move, at, &last, g->scale, counted);
        } else {
            run = 0;
        }
        t->opened += (uint64_t)opened * times;
        if (stuck)
            return;
        st = r.state;
    }
    /* A run the reach cut short: the next tick would have held it too. */
    if (run > 0 && run < JUDGE_HELD_TICKS) {
        t->phantom += run;
        if (t->at)
            add_place(t->at, &p->move, at, &last, g->scale, run);
    }
}

/* The pace of a sample walking at horizontal speed h (> 0): its speed
 * (JUDGE_SPEED_MIN and up, raised so that JUDGE_TICKS_MAX ticks cover the
 * reach) and the ticks that cover the reach. */
static void pace(const judge_params *p, float h, float *speed, uint32_t *ticks)
{
    float v = h < JUDGE_SPEED_MIN ? p->speed : h;
    if (v * p->dt * JUDGE_TICKS_MAX < p->reach)
        v = p->reach / (p->dt * JUDGE_TICKS_MAX);
    *speed = v;
    *ticks = (uint32_t)ceilf(p->reach / (v * p->dt));
}

/*
 * The local region every box the trials of the n samples chosen from the m
 * of distinct test can lie in (geometry's near), at any height: a move
 * takes the avatar at most its displacement sideways (move.h: falls, lifts
 * and steps are vertical, slides shorten it), to which rounding adds less
 * than twice the spacing of floats at MOVE_MAX_COORD a tick; a test box
 * reaches half the avatar and a cell (the metric cell) further.
 */
static void trial_region(const judge_params *p, const judge_sample *distinct, uint32_t m, uint32_t n,
                         const double cell[3], double scale, double near[6])
{
    near[0] = near[2] = INFINITY;
    near[3] = near[5] = -INFINITY;
    near[1] = -INFINITY;
    near[4] = INFINITY;
    for (uint32_t i = 0; i < n; i++) {
        const judge_sample *s = &distinct[(uint64_t)i * m / n];
        float h = hypotf(s->vel[0], s->vel[2]), speed;
        uint32_t ticks;
        if (!(h > 0))
            continue; /* not walked */
        pace(p, h, &speed, &ticks);
        double walk = 1.001 * speed * p->dt * ticks + 2.0 * ticks * MOVE_MAX_COORD * FLT_EPSILON;
        for (int a = 0; a <= 2; a += 2) {
            double r = walk + p->move.size[a] / 2.0 + cell[a];
            near[a] = fmin(near[a], (s->pos[a] - r) / scale);
            near[3 + a] = fmax(near[3 + a], (s->pos[a] + r) / scale);
        }
    }
}

/* Samples in a fixed order: their bytes (judge_sample is six floats, no
 * padding). */
static int cmp_sample(const void *a, const void *b) { return memcmp(a, b, sizeof(judge_sample)); }
_Static_assert(sizeof(judge_sample) == 6 * sizeof(float), "no padding in a sample");

static int finite_box(const float b[6])
{
    for (int a = 0; a < 3; a++)
        if (!isfinite(b[a]) || !isfinite(b[3 + a]) || b[a] > b[3 + a])
            return 0;
    return 1;
}

/* A map the judge walks: 1 to ECM_MAX_BOXES_LIMIT finite boxes. */
static int check_map(const char *which, const float (*boxes)[6], uint32_t n, char *err, size_t errlen)
{
    if (!boxes || n == 0 || n > ECM_MAX_BOXES_LIMIT)
        return cvre_fail(err, errlen, -EINVAL, "%s map: %u boxes, 1 to %u wanted", which, n, ECM_MAX_BOXES_LIMIT);
    for (uint32_t i = 0; i < n; i++)
        if (!finite_box(boxes[i]))
            return cvre_fail(err, errlen, -EINVAL, "%s map: box %u is not a finite box", which, i);
    return 0;
}

/* The parameters, the mesh, the old map and the samples (the new map:
 * judge_new). */
static int check(const judge_params *p, const judge_input *in, char *err, size_t errlen)
{
    int rc;
    if (!(p->dt > 0 && p->dt <= MOVE_MAX_DT) || !(p->reach > 0 && p->reach <= 100) ||
        !(p->speed >= JUDGE_SPEED_MIN && p->speed <= 100) || !(p->deflect >= 0 && p->deflect <= 1.5707964f) ||
        p->depth < VOXEL_DEPTH_MIN || p->depth > JUDGE_DEPTH_MAX || p->cell_depth < VOXEL_DEPTH_MIN ||
        p->cell_depth > VOXEL_DEPTH_MAX || p->max_samples < 1 ||
        p->max_samples > JUDGE_SAMPLES_LIMIT)
        return cvre_fail(err, errlen, -EINVAL, "judge parameters out of range");
    if (!in->mesh || in->mesh->ntris == 0)
        return cvre_fail(err, errlen, -EINVAL, "no triangles to judge against");
    if (!(in->scale > 0) || !isfinite(in->scale) || !isfinite(in->pose_y))
        return cvre_fail(err, errlen, -EINVAL, "scale %g or height %g unusable", in->scale, in->pose_y);
    if ((rc = check_map("old", in->old_boxes, in->nold, err, errlen)) < 0)
        return rc;
    if (!in->samples || in->nsamples == 0)
        return cvre_fail(err, errlen, -EINVAL, "no samples: nothing to judge by");
    for (uint32_t i = 0; i < in->nsamples; i++)
        for (int a = 0; a < 3; a++) {
            float v = in->samples[i].pos[a], w = in->samples[i].vel[a];
            if (!isfinite(v) || !isfinite(w) || fabsf(v) > MOVE_MAX_COORD || fabsf(w) > MOVE_MAX_COORD)
                return cvre_fail(err, errlen, -EINVAL, "sample %u: coordinate out of range", i);
        }
    return 0;
}

int judge_gain(uint64_t before, uint64_t after, uint32_t num, uint32_t den)
{
    return after + JUDGE_GAIN_MIN <= before && (before - after) * den >= before * num;
}

int judge_better(const judge_result *r)
{
    return judge_gain(r->phantom_old, r->phantom_new, JUDGE_GAIN_NUM, JUDGE_GAIN_DEN) &&
           r->opened_new <= r->opened_old;
}

/* An open judgement (judge.h): the geometry, the samples chosen, the old
 * map and its figures. */
struct judge {
    judge_params p;
    const judge_input *in;
    geometry g;
    map maps[2]; /* old, new */
    judge_sample *distinct;
    uint32_t m, n; /* distinct samples, and those judged */
    double cell[3];
    judge_result old; /* the old map's figures */
    place_list at;    /* the last new map's phantom blocks */
};

/* Walks every sample's trials against map k (0: from where it was logged;
 * 1: as start_new puts it on the new map), counting into *t. */
static void walk_map(judge *j, int k, tally *t)
{
    const judge_params *p = &j->p;
    const float turns[3] = {0, p->deflect, -p->deflect};
    int nturns = p->deflect > 0 ? 3 : 1;
    for (uint32_t i = 0; i < j->n; i++) {
        const judge_sample *s = &j->distinct[(uint64_t)i * j->m / j->n];
        float h = hypotf(s->vel[0], s->vel[2]), speed;
        uint32_t ticks;
        if (!(h > 0)) {
            t->still++;
            continue;
        }
        pace(p, h, &speed, &ticks);
        const move_state from = k ? start_new(p, &j->maps[0], &j->maps[1], s)
                                  : (move_state){.pos = {s->pos[0], s->pos[1], s->pos[2]}, .vy = 0, .grounded = true};
        for (int d = 0; d < nturns; d++) {
            float c = cosf(turns[d]), sn = sinf(turns[d]);
            float dx = (s->vel[0] * c - s->vel[2] * sn) / h, dz = (s->vel[0] * sn + s->vel[2] * c) / h;
            trial(p, &j->g, j->cell, &j->maps[k], from, dx, dz, speed, ticks, t);
            t->moves += ticks;
        }
    }
}

void judge_close(judge *j)
{
    if (!j)
        return;
    free(j->distinct);
    free(j->at.p);
    geometry_free(&j->g);
    map_free(&j->maps[0]);
    map_free(&j->maps[1]);
    free(j);
}

int judge_open(judge **out, const judge_params *p, const judge_input *in, judge_result *old, char *err,
               size_t errlen)
{
    double t0 = task_cpu_ms(); /* this thread's CPU time: see judge_result */
    *out = NULL;
    memset(old, 0, sizeof *old);
    int rc = check(p, in, err, errlen);
    if (rc < 0)
        return rc;
    judge *j = cvre_calloc(1, sizeof *j);
    if (!j)
        return cvre_fail(err, errlen, -ENOMEM, "judging: %s", strerror(ENOMEM));
    j->p = *p;
    j->p.move.floor_y = (float)-in->pose_y;
    j->in = in;
    /* A user pressing on a box logs the same collision tick after tick:
     * each distinct sample once, in an order of their own. */
    j->distinct = cvre_malloc(in->nsamples * sizeof *j->distinct);
    if (!j->distinct) {
        rc = -ENOMEM;
        goto fail;
    }
    memcpy(j->distinct, in->samples, in->nsamples * sizeof *j->distinct);
    qsort(j->distinct, in->nsamples, sizeof *j->distinct, cmp_sample);
    uint32_t m = 0;
    for (uint32_t i = 0; i < in->nsamples; i++)
        if (m == 0 || cmp_sample(&j->distinct[m - 1], &j->distinct[i]) != 0)
            j->distinct[m++] = j->distinct[i];
    j->m = m;
    j->n = m < j->p.max_samples ? m : j->p.max_samples;
    const float *lo = in->mesh->min, *hi = in->mesh->max;
    const double cells = (double)(1u << j->p.cell_depth);
    for (int a = 0; a < 3; a++)
        j->cell[a] = ((double)hi[a] - lo[a]) / cells * in->scale;
    double near[6];
    trial_region(&j->p, j->distinct, m, j->n, j->cell, in->scale, near);
    if ((rc = geometry_init(&j->g, &j->p, in, near)) < 0 ||
        (rc = map_init(&j->maps[0], in->old_boxes, in->nold, in->scale)) < 0)
        goto fail; /* the input was checked: what is left is memory */
    tally t = {0};
    walk_map(j, 0, &t);
    j->old.samples = j->n;
    j->old.still = (uint32_t)t.still;
    j->old.moves = t.moves;
    j->old.phantom_old = t.phantom;
    j->old.opened_old = t.opened;
    j->old.ms = task_cpu_ms() - t0 + j->g.beside_ms;
    *old = j->old;
    *out = j;
    return 0;
fail:
    judge_close(j);
    return cvre_fail(err, errlen, rc, "judging: %s", strerror(-rc));
}

int judge_can_gain(const judge_result *old) { return old->phantom_old >= JUDGE_GAIN_MIN; }

int judge_new(judge *j, const float (*boxes)[6], uint32_t n, judge_result *out, char *err, size_t errlen)
{
    double t0 = task_cpu_ms();
    memset(out, 0, sizeof *out);
    j->at.n = 0;
    int rc = check_map("new", boxes, n, err, errlen);
    if (rc < 0)
        return rc;
    map_free(&j->maps[1]);
    if ((rc = map_init(&j->maps[1], boxes, n, j->in->scale)) < 0)
        return cvre_fail(err, errlen, rc, "judging: %s", strerror(-rc));
    tally t = {.at = &j->at}; /* its moves and still are the old map's */
    walk_map(j, 1, &t);
    *out = j->old;
    out->phantom_new = t.phantom;
    out->opened_new = t.opened;
    out->better = judge_better(out);
    out->ms = j->old.ms + task_cpu_ms() - t0;
    return 0;
}

void judge_places(const judge *j, const judge_place **places, uint32_t *n)
{
    *places = j->at.p;
    *n = j->at.n;
}

int judge_maps(const judge_params *p, const judge_input *in, judge_result *out, char *err, size_t errlen)
{
    judge *j;
    judge_result old;
    memset(out, 0, sizeof *out);
    int rc = judge_open(&j, p, in, &old, err, errlen);
    if (rc == 0)
        rc = judge_new(j, in->new_boxes, in->nnew, out, err, errlen);
    judge_close(j);
    return rc;
}
