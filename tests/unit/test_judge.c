/* The judge: a doorway opened is better, a garage's base opened under a
 * coarse roof box is not, a map that uncovers a wall is not, the same input
 * gives the same figures, a marginal gain is no gain, the places of its
 * phantom blocks name the boxes that held the trials, and bad input gets a
 * clear refusal. */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>
#include <errno.h>
#include <math.h>
#include <string.h>

#include "judge.h"

#define MAX_TRIS 256

typedef struct mesh {
    float t[MAX_TRIS * 9];
    uint32_t n;
    trimesh tm; /* over t, made by input() */
} mesh;

/* The 12 triangles of the surface of box [x0, x1] x [y0, y1] x [z0, z1]. */
static void cuboid(mesh *m, float x0, float y0, float z0, float x1, float y1, float z1)
{
    const float c[8][3] = {{x0, y0, z0}, {x1, y0, z0}, {x1, y1, z0}, {x0, y1, z0},
                           {x0, y0, z1}, {x1, y0, z1}, {x1, y1, z1}, {x0, y1, z1}};
    const int f[12][3] = {{0, 1, 2}, {0, 2, 3}, {4, 5, 6}, {4, 6, 7}, {0, 1, 5}, {0, 5, 4},
                          {3, 2, 6}, {3, 6, 7}, {0, 3, 7}, {0, 7, 4}, {1, 2, 6}, {1, 6, 5}};
    assert_true(m->n + 12 <= MAX_TRIS);
    for (int i = 0; i < 12; i++, m->n++)
        for (int v = 0; v < 3; v++)
            memcpy(m->t + 9 * m->n + 3 * v, c[f[i][v]], sizeof c[0]);
}

/* A wall 6 m wide, 3 m tall, 0.2 m thick in z in [0, 0.2], with a doorway
 * 1 m wide and 2.2 m tall at x = 0; its parts as boxes. */
static const float wall_parts[3][6] = {
    {-3, 0, 0, -0.5f, 3, 0.2f}, {0.5f, 0, 0, 3, 3, 0.2f}, {-0.5f, 2.2f, 0, 0.5f, 3, 0.2f}};
static const float wall_mbr[1][6] = {{-3, 0, 0, 3, 3, 0.2f}};

static void wall(mesh *m)
{
    m->n = 0;
    for (int i = 0; i < 3; i++)
        cuboid(m, wall_parts[i][0], wall_parts[i][1], wall_parts[i][2], wall_parts[i][3], wall_parts[i][4],
               wall_parts[i][5]);
}

/* Users stopped in front of the wall (their box's front 1 mm before z = 0),
 * walking into it at 1.5 m/s, from x0 to x1. */
static uint32_t in_front(judge_sample *s, uint32_t n, float x0, float x1)
{
    for (uint32_t i = 0; i < n; i++)
        s[i] = (judge_sample){.pos = {x0 + (x1 - x0) * (float)i / (float)(n > 1 ? n - 1 : 1), 0, -0.301f},
                              .vel = {0, 0, 1.5f}};
    return n;
}

/* The judge's input over m's triangles as they are now; the test frees
 * m->tm at its end. */
static judge_input input(mesh *m, const float (*old)[6], uint32_t nold, const float (*cand)[6], uint32_t nnew,
                         const judge_sample *s, uint32_t ns)
{
    char err[128] = "";
    trimesh_free(&m->tm);
    if (trimesh_init(&m->tm, m->t, m->n, err, sizeof err) != 0)
        fail_msg("trimesh_init: %s", err);
    return (judge_input){.mesh = &m->tm, .scale = 1, .pose_y = 0, .old_boxes = old, .nold = nold,
                         .new_boxes = cand, .nnew = nnew, .samples = s, .nsamples = ns};
}

/* Judges with the default parameters; the call must succeed. */
static judge_result judged(const judge_input *in)
{
    judge_params p;
    judge_params_default(&p);
    judge_result r;
    char err[128] = "";
    int rc = judge_maps(&p, in, &r, err, sizeof err);
    if (rc != 0)
        fail_msg("judge_maps: %d %s", rc, err);
    return r;
}

static void test_doorway_opened_is_better(void **state)
{
    (void)state;
    static mesh m;
    wall(&m);
    judge_sample s[16];
    uint32_t ns = in_front(s, 16, -0.15f, 0.15f);
    judge_input in = input(&m, wall_mbr, 1, wall_parts, 3, s, ns);
    judge_result r = judged(&in);
    assert_int_equal(r.samples, 16);
    assert_int_equal(r.still, 0);
    assert_true(r.moves > 0);
    /* The MBR stops every user in the doorway, every tick: phantoms. */
    assert_true(r.phantom_old >= 16 * 3);
    assert_true(r.phantom_new < r.phantom_old / 10);
    assert_int_equal(r.opened_old, 0);
    assert_int_equal(r.opened_new, 0);
    assert_int_equal(r.better, 1);
    /* The same, the other way round: the refined map is not worse than
     * itself, nor the MBR better than it. */
    judge_input back = input(&m, wall_parts, 3, wall_mbr, 1, s, ns);
    r = judged(&back);
    assert_int_equal(r.better, 0);
    assert_true(r.phantom_new > r.phantom_old);
    trimesh_free(&m.tm);
}

/* A room behind the doorway (back wall at z = 4): the candidate opens only
 * a corridor from the door, the rest of the room in two coarse boxes with
 * nothing in them. Users sent 30 degrees off their line slide along the
 * corridor's sides; that is not being stopped, so the map is better. */
static void test_corridor_behind_a_doorway_is_better(void **state)
{
    (void)state;
    static mesh m;
    wall(&m);
    cuboid(&m, -3, 0, 4, 3, 3, 4.2f);
    const float mbr[1][6] = {{-3, 0, 0, 3, 3, 4.2f}};
    const float cand[6][6] = {{-3, 0, 0, -0.5f, 3, 0.2f}, {0.5f, 0, 0, 3, 3, 0.2f}, {-0.5f, 2.2f, 0, 0.5f, 3, 0.2f},
                              {-3, 0, 4, 3, 3, 4.2f},     {-3, 0, 0.2f, -0.5f, 3, 4}, {0.5f, 0, 0.2f, 3, 3, 4}};
    judge_sample s[16];
    uint32_t ns = in_front(s, 16, -0.15f, 0.15f);
    judge_input in = input(&m, mbr, 1, cand, 6, s, ns);
    judge_result r = judged(&in);
    assert_true(r.phantom_old >= 16 * 3);
    assert_true(r.phantom_new < r.phantom_old / 10);
    assert_int_equal(r.opened_new, 0);
    assert_int_equal(r.better, 1);
    trimesh_free(&m.tm);
}

/* Users pressed on the far side of the wall, its solid part (sliding along
 * it, they do not reach the doorway): the face they meet is the bounding
 * box's max face (the last row of every index), and real, so no map stops
 * them by a phantom. */
static void test_wall_on_the_max_face_is_real(void **state)
{
    (void)state;
    static mesh m;
    wall(&m);
    judge_sample s[8];
    for (uint32_t i = 0; i < 8; i++)
        s[i] = (judge_sample){.pos = {2.2f + 0.05f * (float)i, 0, 0.501f}, .vel = {0, 0, -1.5f}};
    judge_input in = input(&m, wall_mbr, 1, wall_parts, 3, s, 8);
    judge_result r = judged(&in);
    assert_int_equal(r.samples, 8);
    assert_int_equal(r.phantom_old, 0);
    assert_int_equal(r.phantom_new, 0);
    assert_int_equal(r.better, 0);
    trimesh_free(&m.tm);
}

/* Users behind the doorway walk 2.8 m on to a back wall, at the end of the
 * judge's reach; a block tower stands 20 m to the side. The judge indexes
 * only the triangles the trials can reach: the back wall is among them
 * (both maps stop users there, and it is real), and the tower is left out
 * without changing a figure. */
static void test_wall_at_the_end_of_the_reach_is_real(void **state)
{
    (void)state;
    static mesh m;
    const float map[4][6] = {{-3, 0, 0, -0.5f, 3, 0.2f}, {0.5f, 0, 0, 3, 3, 0.2f}, {-0.5f, 2.2f, 0, 0.5f, 3, 0.2f},
                             {-3, 0, 3.6f, 3, 3, 3.8f}};
    judge_sample s[8];
    for (uint32_t i = 0; i < 8; i++)
        s[i] = (judge_sample){.pos = {-0.2f + 0.05f * (float)i, 0, 0.8f}, .vel = {0, 0, 1.5f}};
    judge_result r[2];
    for (int tower = 0; tower < 2; tower++) {
        wall(&m);
        cuboid(&m, -3, 0, 3.6f, 3, 3, 3.8f);
        /* The tower, or a plate as wide and high, so that the bounding box
         * (and the phantom test's cell) is the same. */
        for (int k = 0; k < (tower ? 10 : 1); k++)
            cuboid(&m, 20, tower ? 0.3f * (float)k : 0, 1, 21, tower ? 0.3f * (float)(k + 1) : 3, 2);
        judge_input in = input(&m, map, 4, map, 4, s, 8);
        r[tower] = judged(&in);
    }
    assert_true(r[0].moves > 0);
    assert_int_equal(r[0].phantom_old, 0);
    assert_int_equal(r[0].phantom_new, 0);
    assert_int_equal(r[0].opened_old, 0);
    assert_int_equal(r[0].opened_new, 0);
    assert_int_equal(r[1].moves, r[0].moves);
    assert_int_equal(r[1].phantom_old, 0);
    assert_int_equal(r[1].phantom_new, 0);
    assert_int_equal(r[1].opened_old, 0);
    assert_int_equal(r[1].opened_new, 0);
    trimesh_free(&m.tm);
}

/* A garage: a 0.31 m base one steps onto, posts, a roof plate at 2.5 m and
 * a beam at the back reaching down to 1.83 m. The candidate makes the base a
 * box of its own but keeps the roof, beam and posts in one box whose bottom
 * is the beam's, 1.83 m: users step onto the base, walk on, and hit that
 * box with their heads where nothing is near them. The MBR stopped them at
 * the base, which is real. */
static void test_garage_base_opened_under_a_low_box_is_rejected(void **state)
{
    (void)state;
    static mesh m;
    m.n = 0;
    cuboid(&m, -2, 0, 0, 2, 0.31f, 6);       /* base */
    cuboid(&m, -2, 2.5f, 0, 2, 2.6f, 6);     /* roof plate */
    cuboid(&m, -2, 1.83f, 5.8f, 2, 2.5f, 6); /* beam at the back */
    cuboid(&m, -2, 0.31f, 0, -1.9f, 2.5f, 0.1f);
    cuboid(&m, 1.9f, 0.31f, 0, 2, 2.5f, 0.1f);
    const float mbr[1][6] = {{-2, 0, 0, 2, 2.6f, 6}};
    const float cand[4][6] = {{-2, 0, 0, 2, 0.31f, 6},
                              {-2, 1.83f, 1.0f, 2, 2.6f, 6},
                              {-2, 0.31f, 0, -1.9f, 2.6f, 1.0f},
                              {1.9f, 0.31f, 0, 2, 2.6f, 1.0f}};
    judge_sample s[8];
    uint32_t ns = in_front(s, 8, -0.5f, 0.5f);
    judge_input in = input(&m, mbr, 1, cand, 4, s, ns);
    judge_result r = judged(&in);
    assert_int_equal(r.phantom_old, 0);
    assert_true(r.phantom_new > 0);
    assert_int_equal(r.opened_new, 0);
    assert_int_equal(r.better, 0);
    trimesh_free(&m.tm);
}

/* A candidate that forgets the right part of the wall: fewer phantoms at
 * the doorway, but users in front of that part walk into it. */
static void test_uncovered_wall_is_rejected(void **state)
{
    (void)state;
    static mesh m;
    wall(&m);
    judge_sample s[24];
    uint32_t ns = in_front(s, 16, -0.15f, 0.15f);
    ns += in_front(s + ns, 8, 1.2f, 2.4f);
    const float two[2][6] = {{-3, 0, 0, -0.5f, 3, 0.2f}, {-0.5f, 2.2f, 0, 0.5f, 3, 0.2f}};
    judge_input in = input(&m, wall_mbr, 1, two, 2, s, ns);
    judge_result r = judged(&in);
    assert_true(r.phantom_new < r.phantom_old);
    assert_int_equal(r.opened_old, 0);
    assert_true(r.opened_new > 0);
    assert_int_equal(r.better, 0);
    trimesh_free(&m.tm);
}

/* A candidate whose box of the wall's right part reaches 2 cm in front of
 * the old face, where users stood pressed on it: the server pushes such an
 * avatar out when the map comes in force (move_push_out), and so do the
 * trials. Left inside, they would walk on into the wall (move.h's inside
 * policy). Further than half the avatar's width, no push frees them. */
static void test_sample_enclosed_by_a_new_box_pushed_out(void **state)
{
    (void)state;
    static mesh m;
    wall(&m);
    judge_sample s[8];
    uint32_t ns = in_front(s, 8, 1.2f, 2.4f);
    float near[3][6], deep[3][6];
    memcpy(near, wall_parts, sizeof near);
    memcpy(deep, wall_parts, sizeof deep);
    near[1][2] = -0.02f;
    deep[1][2] = -0.5f;
    judge_input in = input(&m, wall_parts, 3, (const float(*)[6])near, 3, s, ns);
    judge_result r = judged(&in);
    assert_int_equal(r.opened_old, 0);
    assert_int_equal(r.opened_new, 0);
    in = input(&m, wall_parts, 3, (const float(*)[6])deep, 3, s, ns);
    r = judged(&in);
    assert_true(r.opened_new > 0);
    assert_int_equal(r.better, 0);
    trimesh_free(&m.tm);
}

/* Users 1.7 m in front of the wall walking away from it, their backs 10
 * cm into a box of the old map with nothing in it (phantom): they leave
 * it within a tick, a lone held-back tick of each trial, which is how a
 * trial grazes a corner, not a place users are stopped at, and counts
 * nothing. 30 cm into it, they are held back for three ticks or four in
 * a row, and every one of those counts. */
static void test_lone_ticks_are_no_phantom(void **state)
{
    (void)state;
    static mesh m;
    wall(&m);
    judge_sample s[8];
    for (uint32_t i = 0; i < 8; i++)
        s[i] = (judge_sample){.pos = {-1.5f + 0.4f * (float)i, 0, -2.0f}, .vel = {0, 0, -1.5f}};
    float old[4][6];
    memcpy(old, wall_parts, sizeof wall_parts);
    const float thin[6] = {-3, 0, -1.8f, 3, 3, -1.6f}, thick[6] = {-3, 0, -2.0f, 3, 3, -1.6f};
    memcpy(old[3], thin, sizeof thin);
    judge_input in = input(&m, (const float(*)[6])old, 4, wall_parts, 3, s, 8);
    judge_result r = judged(&in);
    assert_int_equal(r.phantom_old, 0);
    assert_int_equal(r.phantom_new, 0);
    memcpy(old[3], thick, sizeof thick);
    in = input(&m, (const float(*)[6])old, 4, wall_parts, 3, s, 8);
    r = judged(&in);
    assert_true(r.phantom_old >= 8 * 3 * 3);
    assert_int_equal(r.phantom_new, 0);
    assert_int_equal(r.better, 1);
    trimesh_free(&m.tm);
}

/* The same input twice: the same figures; a cap picks samples evenly; a
 * sample that stood still is not walked; the object's scale and height
 * carry the trial into metres. */
static void test_deterministic_cap_still_scale(void **state)
{
    (void)state;
    static mesh m;
    wall(&m);
    judge_sample s[40];
    uint32_t ns = in_front(s, 39, -0.15f, 0.15f);
    s[ns++] = (judge_sample){.pos = {0, 0, -0.301f}, .vel = {0, -3, 0}};
    judge_input in = input(&m, wall_mbr, 1, wall_parts, 3, s, ns);
    judge_result a = judged(&in), b = judged(&in);
    assert_int_equal(a.samples, 40);
    assert_int_equal(a.still, 1);
    assert_int_equal(a.moves, b.moves);
    assert_int_equal(a.phantom_old, b.phantom_old);
    assert_int_equal(a.phantom_new, b.phantom_new);
    assert_int_equal(a.opened_old, b.opened_old);
    assert_int_equal(a.opened_new, b.opened_new);
    assert_int_equal(a.better, b.better);
    judge_params p;
    judge_params_default(&p);
    p.max_samples = 10;
    char err[128] = "";
    assert_int_equal(judge_maps(&p, &in, &b, err, sizeof err), 0);
    assert_int_equal(b.samples, 10);
    assert_true(b.still <= 1);
    assert_true(b.moves < a.moves);
    /* A user pressing on the wall tick after tick: the same sample many
     * times counts once. */
    judge_sample same[30];
    for (int i = 0; i < 30; i++)
        same[i] = s[i % 3];
    judge_input pressed = input(&m, wall_mbr, 1, wall_parts, 3, same, 30);
    judge_result three = judged(&pressed);
    judge_input once = input(&m, wall_mbr, 1, wall_parts, 3, s, 3);
    judge_result c = judged(&once);
    assert_int_equal(three.samples, 3);
    assert_int_equal(three.moves, c.moves);
    assert_int_equal(three.phantom_old, c.phantom_old);
    assert_int_equal(three.phantom_new, c.phantom_new);
    /* The wall at a tenth of its size, scaled back up: the same trial. */
    static mesh small;
    small = m;
    small.tm = (trimesh){0}; /* input() makes its own */
    for (uint32_t i = 0; i < small.n * 9; i++)
        small.t[i] /= 10;
    float mbr[1][6], parts[3][6];
    for (int k = 0; k < 6; k++) {
        mbr[0][k] = wall_mbr[0][k] / 10;
        for (int i = 0; i < 3; i++)
            parts[i][k] = wall_parts[i][k] / 10;
    }
    judge_input scaled = input(&small, (const float(*)[6])mbr, 1, (const float(*)[6])parts, 3, s, ns);
    scaled.scale = 10;
    b = judged(&scaled);
    assert_int_equal(b.better, 1);
    assert_true(b.phantom_new < b.phantom_old / 10);
    /* Sunk 0.5 m into the floor: users stand 0.5 m higher in the object's
     * frame, and the 2.2 m doorway stops them at its lintel, which is real:
     * the MBR was no worse. */
    scaled.pose_y = -0.5;
    b = judged(&scaled);
    assert_int_equal(b.better, 0);
    assert_true(b.phantom_old < a.phantom_old / 10);
    trimesh_free(&m.tm);
    trimesh_free(&small.tm);
}

/* The verdict: a map must remove a quarter of the old map's phantom
 * blocks (and at least one), and open nothing more. */
static void test_verdict_needs_a_clear_gain(void **state)
{
    (void)state;
    judge_result r = {.phantom_old = 864, .phantom_new = 861};
    assert_int_equal(judge_better(&r), 0); /* the scenario's desk, seed 1 */
    r = (judge_result){.phantom_old = 29, .phantom_new = 25};
    assert_int_equal(judge_better(&r), 0); /* and seed 3 */
    r = (judge_result){.phantom_old = 1829, .phantom_new = 775};
    assert_int_equal(judge_better(&r), 1);
    r = (judge_result){.phantom_old = 16, .phantom_new = 12};
    assert_int_equal(judge_better(&r), 1); /* exactly a quarter, and JUDGE_GAIN_MIN */
    r = (judge_result){.phantom_old = 17, .phantom_new = 13};
    assert_int_equal(judge_better(&r), 0);
    r = (judge_result){.phantom_old = 4, .phantom_new = 0};
    assert_int_equal(judge_better(&r), 1);
    r = (judge_result){.phantom_old = 3, .phantom_new = 0};
    assert_int_equal(judge_better(&r), 0); /* a trial held back a tick or three */
    r = (judge_result){.phantom_old = 0, .phantom_new = 0};
    assert_int_equal(judge_better(&r), 0); /* nothing to gain */
    r = (judge_result){.phantom_old = 100, .phantom_new = 0, .opened_old = 0, .opened_new = 1};
    assert_int_equal(judge_better(&r), 0); /* opens a wall */
    r = (judge_result){.phantom_old = 100, .phantom_new = 10, .opened_old = 3, .opened_new = 3};
    assert_int_equal(judge_better(&r), 1);
}

/* Opens a judgement of 16 users stopped by the wall's bounding box in its
 * doorway (*in, s and m must outlive it), with the default parameters. */
static judge *open_at_doorway(mesh *m, judge_sample s[16], judge_input *in, judge_params *p, judge_result *old)
{
    wall(m);
    uint32_t ns = in_front(s, 16, -0.15f, 0.15f);
    *in = input(m, wall_mbr, 1, NULL, 0, s, ns);
    judge_params_default(p);
    char err[128] = "";
    judge *j;
    if (judge_open(&j, p, in, old, err, sizeof err) != 0)
        fail_msg("judge_open: %s", err);
    return j;
}

/* The judge in steps: the old map's figures alone first, then any number
 * of new maps against it, each exactly as judge_maps judges it; a wall
 * users only meet for real leaves nothing to gain. */
static void test_in_steps(void **state)
{
    (void)state;
    static mesh m;
    judge_sample s[16];
    judge_input in;
    judge_params p;
    judge_result old, a, b;
    judge *j = open_at_doorway(&m, s, &in, &p, &old);
    char err[128] = "";
    uint32_t ns = in.nsamples;
    assert_int_equal(old.samples, 16);
    assert_true(old.moves > 0 && old.phantom_old >= 16 * 3 && old.ms >= 0);
    assert_true(old.phantom_new == 0 && old.opened_new == 0 && !old.better);
    assert_true(judge_can_gain(&old)); /* the MBR stops them in the doorway */
    assert_int_equal(judge_new(j, wall_parts, 3, &a, err, sizeof err), 0);
    assert_int_equal(judge_new(j, wall_mbr, 1, &b, err, sizeof err), 0);
    /* A bad map is refused and leaves the judgement usable. */
    static const float bad[1][6] = {{1, 0, 0, 0, 1, 1}};
    judge_result c;
    assert_int_equal(judge_new(j, bad, 1, &c, err, sizeof err), -EINVAL);
    assert_non_null(strstr(err, "new map"));
    assert_int_equal(judge_new(j, wall_parts, 3, &c, err, sizeof err), 0);
    assert_true(c.phantom_new == a.phantom_new && c.opened_new == a.opened_new && c.better == a.better);
    judge_close(j);
    judge_close(NULL);
    for (int k = 0; k < 2; k++) {
        judge_input both = input(&m, wall_mbr, 1, k ? wall_mbr : wall_parts, k ? 1 : 3, s, ns);
        judge_result r = judged(&both), *got = k ? &b : &a;
        assert_int_equal(got->samples, r.samples);
        assert_true(got->moves == r.moves && got->phantom_old == r.phantom_old && got->phantom_new == r.phantom_new);
        assert_true(got->opened_old == r.opened_old && got->opened_new == r.opened_new && got->better == r.better);
    }
    assert_true(a.better && !b.better);
    /* Users at the solid wall beside the door: no phantom to remove. */
    ns = in_front(s, 16, 1.5f, 2.5f);
    in = input(&m, wall_mbr, 1, NULL, 0, s, ns);
    assert_int_equal(judge_open(&j, &p, &in, &old, err, sizeof err), 0);
    assert_true(old.phantom_old < JUDGE_GAIN_MIN);
    assert_false(judge_can_gain(&old));
    judge_close(j);
    trimesh_free(&m.tm);
}

/* Where the trials met a new map's phantom blocks: every tick at a place
 * that names the box that held it back (a box closing the doorway, second
 * in the map), the ticks summing to the figure, the avatar's box in front
 * of the wall and the contact on the box's face; none once the doorway is
 * open, and the places go with the next map. */
static void test_places_name_the_box_that_held(void **state)
{
    (void)state;
    static mesh m;
    judge_sample s[16];
    judge_input in;
    judge_params p;
    judge_result old, r;
    judge *j = open_at_doorway(&m, s, &in, &p, &old);
    char err[128] = "";
    const judge_place *at;
    uint32_t n = 1;
    judge_places(j, &at, &n);
    assert_int_equal(n, 0); /* none before a new map */
    const float closed[4][6] = {{-3, 0, 0, -0.5f, 3, 0.2f},
                                {-0.5f, 0, 0, 0.5f, 2.2f, 0.2f},
                                {0.5f, 0, 0, 3, 3, 0.2f},
                                {-0.5f, 2.2f, 0, 0.5f, 3, 0.2f}};
    assert_int_equal(judge_new(j, closed, 4, &r, err, sizeof err), 0);
    assert_true(r.phantom_new >= 16 * 3);
    judge_places(j, &at, &n);
    assert_true(n >= 16);
    uint64_t ticks = 0;
    for (uint32_t i = 0; i < n; i++) {
        assert_int_equal(at[i].hit, 1);
        assert_true(at[i].ticks >= 1);
        ticks += at[i].ticks;
        /* The avatar (0.6 x 1.8 x 0.6) on the floor, its front at the door. */
        assert_float_equal(at[i].box[3] - at[i].box[0], p.move.size[0], 1e-4);
        assert_float_equal(at[i].box[4] - at[i].box[1], p.move.size[1], 1e-4);
        assert_float_equal(at[i].box[1], 0, 1e-3);
        assert_true(at[i].box[5] <= 0.001f && at[i].box[5] >= -0.01f);
        assert_true(at[i].box[0] >= -0.5f && at[i].box[3] <= 0.5f);
        assert_float_equal(at[i].point[2], 0, 0.01f);
        assert_true(at[i].point[0] >= -0.5f && at[i].point[0] <= 0.5f);
    }
    assert_int_equal(ticks, r.phantom_new);
    assert_int_equal(judge_new(j, wall_parts, 3, &r, err, sizeof err), 0);
    assert_int_equal(r.phantom_new, 0);
    judge_places(j, &at, &n);
    assert_int_equal(n, 0);
    judge_close(j);
    trimesh_free(&m.tm);
}

static void test_bad_input(void **state)
{
    (void)state;
    static mesh m;
    wall(&m);
    judge_sample s[4];
    uint32_t ns = in_front(s, 4, -0.1f, 0.1f);
    judge_params p;
    judge_params_default(&p);
    judge_result r;
    char err[128];
    judge_input in = input(&m, wall_mbr, 1, wall_parts, 3, s, 0);
    assert_int_equal(judge_maps(&p, &in, &r, err, sizeof err), -EINVAL);
    assert_string_equal(err, "no samples: nothing to judge by");
    assert_int_equal(r.samples, 0);
    assert_int_equal(r.better, 0);

    in.nsamples = ns;
    s[2].vel[0] = NAN;
    assert_int_equal(judge_maps(&p, &in, &r, err, sizeof err), -EINVAL);
    assert_string_equal(err, "sample 2: coordinate out of range");
    s[2].vel[0] = 0;
    s[1].pos[1] = 1e9f;
    assert_int_equal(judge_maps(&p, &in, &r, err, sizeof err), -EINVAL);
    s[1].pos[1] = 0;

    /* The mesh's own check: a triangle that is not finite never gets
     * to the judge. */
    trimesh bad;
    m.t[13] = NAN;
    assert_int_equal(trimesh_init(&bad, m.t, m.n, err, sizeof err), -EINVAL);
    assert_string_equal(err, "triangle 1: a coordinate is not finite");
    assert_null(bad.box);
    assert_int_equal(trimesh_init(&bad, m.t, 0, err, sizeof err), -EINVAL);
    assert_string_equal(err, "the object has no triangles");
    wall(&m);

    const float inverted[1][6] = {{1, 0, 0, 0, 1, 1}};
    in.new_boxes = inverted;
    in.nnew = 1;
    assert_int_equal(judge_maps(&p, &in, &r, err, sizeof err), -EINVAL);
    assert_string_equal(err, "new map: box 0 is not a finite box");
    in.new_boxes = wall_parts;
    in.nnew = 0;
    assert_int_equal(judge_maps(&p, &in, &r, err, sizeof err), -EINVAL);
    in.nnew = 3;

    in.scale = 0;
    assert_int_equal(judge_maps(&p, &in, &r, err, sizeof err), -EINVAL);
    in.scale = 1;
    in.pose_y = INFINITY;
    assert_int_equal(judge_maps(&p, &in, &r, err, sizeof err), -EINVAL);
    in.pose_y = 0;
    in.mesh = NULL;
    assert_int_equal(judge_maps(&p, &in, &r, err, sizeof err), -EINVAL);
    assert_string_equal(err, "no triangles to judge against");
    in.mesh = &m.tm;

    p.dt = 0;
    assert_int_equal(judge_maps(&p, &in, &r, err, sizeof err), -EINVAL);
    assert_string_equal(err, "judge parameters out of range");
    judge_params_default(&p);
    p.max_samples = 0;
    assert_int_equal(judge_maps(&p, &in, &r, err, sizeof err), -EINVAL);
    judge_params_default(&p);
    assert_int_equal(judge_maps(&p, &in, &r, err, sizeof err), 0);
    trimesh_free(&m.tm);
}

/* The mesh both the refinement and the judge read: each triangle's box and
 * the object's, worked out once. */
static void test_mesh_boxes(void **state)
{
    (void)state;
    static mesh m;
    wall(&m);
    char err[128] = "";
    trimesh tm;
    assert_int_equal(trimesh_init(&tm, m.t, m.n, err, sizeof err), 0);
    assert_int_equal(tm.ntris, 36);
    const float lo[3] = {-3, 0, 0}, hi[3] = {3, 3, 0.2f};
    for (int a = 0; a < 3; a++) {
        assert_true(tm.min[a] == lo[a] && tm.max[a] == hi[a]);
        for (uint32_t t = 0; t < tm.ntris; t++) {
            const float *v = m.t + 9 * t;
            assert_true(tm.box[t][a] == fminf(fminf(v[a], v[3 + a]), v[6 + a]));
            assert_true(tm.box[t][3 + a] == fmaxf(fmaxf(v[a], v[3 + a]), v[6 + a]));
        }
    }
    trimesh_free(&tm);
    assert_null(tm.box);
    trimesh_free(&tm); /* a zeroed mesh frees again */
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_doorway_opened_is_better),
        cmocka_unit_test(test_corridor_behind_a_doorway_is_better),
        cmocka_unit_test(test_wall_on_the_max_face_is_real),
        cmocka_unit_test(test_wall_at_the_end_of_the_reach_is_real),
        cmocka_unit_test(test_garage_base_opened_under_a_low_box_is_rejected),
        cmocka_unit_test(test_uncovered_wall_is_rejected),
        cmocka_unit_test(test_sample_enclosed_by_a_new_box_pushed_out),
        cmocka_unit_test(test_lone_ticks_are_no_phantom),
        cmocka_unit_test(test_deterministic_cap_still_scale),
        cmocka_unit_test(test_verdict_needs_a_clear_gain),
        cmocka_unit_test(test_in_steps),
        cmocka_unit_test(test_places_name_the_box_that_held),
        cmocka_unit_test(test_bad_input),
        cmocka_unit_test(test_mesh_boxes),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
