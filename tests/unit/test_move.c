/* The character controller: walls, sliding, corners, tunnelling, steps,
 * support and falling, ceilings, the inside policy, push-out, bad input, and
 * a random walk that must never end inside a box it was not already in. */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>
#include <errno.h>
#include <math.h>
#include <string.h>

#include "move.h"

#define DT 0.05f /* 20 Hz */
#define SKIN ((float)MOVE_SKIN)
#define EPS 1e-5

static move_params prm;

static int setup(void **state)
{
    (void)state;
    move_params_default(&prm);
    return 0;
}

static move_box box(float x0, float y0, float z0, float x1, float y1, float z1, uint32_t handle)
{
    move_box b = {{x0, y0, z0}, {x1, y1, z1}, 1000 + handle, handle % 7, handle};
    return b;
}

static move_state at(float x, float y, float z)
{
    move_state s = {{x, y, z}, 0, true};
    return s;
}

static move_result step(const move_state *s, float dx, float dy, float dz, const move_box *b, uint32_t n)
{
    move_result r;
    const float d[3] = {dx, dy, dz};
    assert_int_equal(move_step(&prm, s, d, DT, b, n, &r), 0);
    return r;
}

/* A deterministic pseudo-random float in [0, 1]. */
static float rnd(unsigned *seed)
{
    *seed = *seed * 1103515245u + 12345u;
    return (float)((*seed >> 8) & 0xffffu) / 65535.0f;
}

/* Compares states field by field (the struct has padding). */
static bool same_state(const move_state *a, const move_state *b)
{
    return memcmp(a->pos, b->pos, sizeof a->pos) == 0 && memcmp(&a->vy, &b->vy, sizeof a->vy) == 0 &&
           a->grounded == b->grounded;
}

static void assert_normal(const move_contact *c, float x, float y, float z)
{
    assert_true(c->normal[0] == x && c->normal[1] == y && c->normal[2] == z);
}

static void test_wall_stops(void **state)
{
    (void)state;
    const move_box wall = box(1, 0, -5, 1.2f, 3, 5, 7);
    move_state s = at(0, 0, 0.5f);
    move_result r = step(&s, 2, 0, 0, &wall, 1);
    assert_float_equal(r.state.pos[0], 1 - 0.3f - SKIN, EPS);
    assert_true(r.state.pos[1] == 0 && r.state.pos[2] == 0.5f);
    assert_true(r.state.grounded);
    assert_int_equal(r.ncontacts, 1);
    const move_contact *c = &r.contacts[0];
    assert_int_equal(c->handle, 7);
    assert_int_equal(c->object_id, 1007);
    assert_int_equal(c->box_index, 0);
    assert_int_equal(c->index, 0);
    assert_false(c->inside);
    assert_normal(c, -1, 0, 0);
    assert_float_equal(c->point[0], 1, EPS);   /* on the wall's face */
    assert_float_equal(c->point[1], 0.9f, EPS); /* middle of the avatar's height */
    assert_float_equal(c->point[2], 0.5f, EPS);
    /* Pushing on from there: no motion, the same contact. */
    move_result again = step(&r.state, 0.25f, 0, 0, &wall, 1);
    assert_true(memcmp(again.state.pos, r.state.pos, sizeof r.state.pos) == 0);
    assert_int_equal(again.ncontacts, 1);
    assert_normal(&again.contacts[0], -1, 0, 0);
    /* Walking away is free. */
    move_result away = step(&r.state, -0.25f, 0, 0, &wall, 1);
    assert_int_equal(away.ncontacts, 0);
    assert_float_equal(away.state.pos[0], r.state.pos[0] - 0.25f, EPS);
}

static void test_slide_keeps_tangential_motion(void **state)
{
    (void)state;
    const move_box wall = box(1, 0, -5, 1.2f, 3, 5, 1);
    move_state s = at(0.6f, 0, 0);
    move_result r = step(&s, 0.2f, 0, 0.2f, &wall, 1); /* 45 degrees into the wall */
    assert_float_equal(r.state.pos[0], 0.7f - SKIN, EPS);
    assert_float_equal(r.state.pos[2], 0.2f, EPS); /* all of it, not cos 45 */
    assert_int_equal(r.ncontacts, 1);
    /* Sliding along it for many ticks reports it once per move, never more. */
    for (int k = 0; k < 20; k++) {
        r = step(&r.state, 0.1f, 0, 0.2f, &wall, 1);
        assert_int_equal(r.ncontacts, 1);
        assert_int_equal(r.contacts[0].handle, 1);
    }
    assert_float_equal(r.state.pos[2], 4.2f, 1e-4);
    assert_float_equal(r.state.pos[0], 0.7f - SKIN, EPS);
}

/* A wall made of two boxes: sliding over the seam meets no edge. */
static void test_slide_over_seam(void **state)
{
    (void)state;
    const move_box walls[2] = {box(1, 0, -5, 1.2f, 3, 0, 1), box(1, 0, 0, 1.2f, 3, 5, 2)};
    move_state s = at(0.699f, 0, -1);
    for (int k = 0; k < 8; k++) {
        move_result r = step(&s, 0, 0, 0.25f, walls, 2);
        assert_int_equal(r.ncontacts, 0);
        s = r.state;
    }
    assert_float_equal(s.pos[2], 1, EPS);
}

static void test_corner_stops_both(void **state)
{
    (void)state;
    const move_box walls[2] = {box(1, 0, -5, 1.2f, 3, 5, 1), box(-5, 0, 1, 5, 3, 1.2f, 2)};
    move_state s = at(0.6f, 0, 0.6f);
    move_result r = step(&s, 0.5f, 0, 0.5f, walls, 2);
    assert_float_equal(r.state.pos[0], 0.7f - SKIN, EPS);
    assert_float_equal(r.state.pos[2], 0.7f - SKIN, EPS);
    assert_int_equal(r.ncontacts, 2);
    /* Both at the same instant: the earlier candidate first, then the other. */
    assert_normal(&r.contacts[0], -1, 0, 0);
    assert_normal(&r.contacts[1], 0, 0, -1);
}

/* Walking into a box that clips the footprint's edge by at most an eighth of
 * the width: the avatar slips past the corner, unreported, the slip taken
 * from the walk. By more, or when something stands where it would slip to,
 * or when it walks sideways the other way, or when the walk left is shorter
 * than the slip, or when a wall on the same plane stands where the slip
 * leads (unless it is a step), the box stops it as any wall. */
static void test_clipped_corner_slips(void **state)
{
    (void)state;
    /* Footprint x in [-0.3, 0.3]: the post clips 5 cm of it. */
    const move_box post = box(0.25f, 0, 1, 1.25f, 3, 1.5f, 1);
    move_state s = at(0, 0, 0.6f);
    move_result r = step(&s, 0, 0, 0.2f, &post, 1);
    assert_int_equal(r.ncontacts, 0);
    const float slid = 0.05f + SKIN;
    assert_float_equal(r.state.pos[0], -slid, EPS);
    assert_float_equal(r.state.pos[2], 0.8f - slid, EPS);
    assert_true(r.state.grounded && r.state.pos[1] == 0);
    /* The other side of the post, mirrored: it slips towards +x. */
    const move_box mirrored = box(-1.25f, 0, 1, -0.25f, 3, 1.5f, 1);
    r = step(&s, 0, 0, 0.2f, &mirrored, 1);
    assert_int_equal(r.ncontacts, 0);
    assert_float_equal(r.state.pos[0], slid, EPS);
    /* 10 cm is more than an eighth of 0.6 m: a wall. */
    const move_box wide = box(0.2f, 0, 1, 1.2f, 3, 1.5f, 2);
    r = step(&s, 0, 0, 0.2f, &wide, 1);
    assert_int_equal(r.ncontacts, 1);
    assert_int_equal(r.contacts[0].handle, 2);
    assert_normal(&r.contacts[0], 0, 0, -1);
    assert_true(r.state.pos[0] == 0);
    assert_float_equal(r.state.pos[2], 0.7f - SKIN, EPS);
    /* A box where the slip would go: stopped. */
    const move_box both[2] = {post, box(-1, 0, 0.9f, -0.32f, 3, 1.5f, 3)};
    r = step(&s, 0, 0, 0.2f, both, 2);
    assert_int_equal(r.ncontacts, 1);
    assert_int_equal(r.contacts[0].handle, 1);
    assert_true(r.state.pos[0] == 0);
    /* Walking on towards +x: no slip against it (it slides along instead). */
    r = step(&s, 0.05f, 0, 0.2f, &post, 1);
    assert_int_equal(r.ncontacts, 1);
    assert_float_equal(r.state.pos[0], 0.05f, EPS);
    /* Pressing at the face with less walk left than the slip: stopped,
     * and the next full step slips. */
    s = at(0, 0, 0.7f - SKIN);
    r = step(&s, 0, 0, 0.03f, &post, 1);
    assert_int_equal(r.ncontacts, 1);
    assert_true(r.state.pos[0] == 0);
    r = step(&s, 0, 0, 0.2f, &post, 1);
    assert_int_equal(r.ncontacts, 0);
    assert_float_equal(r.state.pos[0], -slid, EPS);
    assert_float_equal(r.state.pos[2], 0.9f - SKIN - slid, EPS);
    /* A wall on the same plane where the slip would go: the slip gains
     * nothing, so the post stops it where it is. */
    const move_box wall[2] = {post, box(-1, 0, 1, 0.25f, 3, 1.5f, 6)};
    s = at(0, 0, 0.6f);
    r = step(&s, 0, 0, 0.2f, wall, 2);
    assert_int_equal(r.ncontacts, 1);
    assert_int_equal(r.contacts[0].handle, 1);
    assert_true(r.state.pos[0] == 0);
    /* A step there instead: it slips and steps up onto it. */
    const move_box step_there[2] = {post, box(-1, 0, 1, 0.25f, 0.2f, 1.5f, 7)};
    r = step(&s, 0, 0, 0.2f, step_there, 2);
    assert_int_equal(r.ncontacts, 0);
    assert_float_equal(r.state.pos[0], -slid, EPS);
    assert_float_equal(r.state.pos[1], 0.2f, EPS);
    assert_float_equal(r.state.pos[2], 0.8f - slid, EPS);
    /* In a corner: stopped by a wall across z, it slides along x into a
     * post that clips its footprint by 5 cm along z. Slipping would take it
     * back along z, the way the first wall stopped: it stays in the corner. */
    const move_box corner[2] = {box(-5, 0, 1, 5, 3, 1.2f, 4), box(1, 0, 0.95f, 1.5f, 3, 1, 5)};
    s = at(0, 0, 0.6f);
    r = step(&s, 1, 0, 0.3f, corner, 2);
    assert_int_equal(r.ncontacts, 2);
    assert_int_equal(r.contacts[0].handle, 4);
    assert_int_equal(r.contacts[1].handle, 5);
    assert_float_equal(r.state.pos[0], 0.7f - SKIN, EPS);
    assert_float_equal(r.state.pos[2], 0.7f - SKIN, EPS);
}

static void test_no_tunnelling(void **state)
{
    (void)state;
    const move_box thin = box(5, 0, -5, 5.05f, 3, 5, 3); /* 5 cm */
    move_state s = at(0, 0, 0);
    move_result r = step(&s, 10, 0, 0, &thin, 1);
    assert_float_equal(r.state.pos[0], 5 - 0.3f - SKIN, EPS);
    assert_int_equal(r.ncontacts, 1);
    /* Diagonal and from the other side. */
    s = at(10, 0, 0);
    r = step(&s, -10, 0, 2, &thin, 1);
    assert_true(r.state.pos[0] > 5.05f + 0.3f);
    assert_int_equal(r.ncontacts, 1);
    assert_normal(&r.contacts[0], 1, 0, 0);
    /* A zero-thickness wall blocks too. */
    const move_box sheet = box(5, 0, -5, 5, 3, 5, 4);
    s = at(0, 0, 0);
    r = step(&s, 100, 0, 0, &sheet, 1);
    assert_true(r.state.pos[0] < 5 - 0.3f);
    assert_int_equal(r.ncontacts, 1);
    /* A fall at top speed onto a 5 cm slab lands on it. */
    const move_box slab = box(-5, 50, -5, 5, 50.05f, 5, 5);
    s = (move_state){{0, 100, 0}, -MOVE_MAX_FALL_SPEED, false};
    move_result f;
    const float none[3] = {0, 0, 0};
    assert_int_equal(move_step(&prm, &s, none, 1.0f, &slab, 1, &f), 0);
    assert_true(f.state.pos[1] == 50.05f);
    assert_true(f.state.grounded);
    assert_true(f.state.vy == 0);
    assert_int_equal(f.ncontacts, 0);
}

static void test_step_up(void **state)
{
    (void)state;
    const move_box stepbox = box(1, 0, -5, 3, 0.3f, 5, 1);
    move_state s = at(0.5f, 0, 0);
    move_result r = step(&s, 0.25f, 0, 0, &stepbox, 1);
    assert_int_equal(r.ncontacts, 0);
    assert_true(r.state.pos[1] == 0.3f);
    assert_float_equal(r.state.pos[0], 0.75f, 1e-4);
    assert_true(r.state.grounded);
    /* Walk across it and down the far side. */
    s = r.state;
    for (int k = 0; k < 20; k++) {
        r = step(&s, 0.25f, 0, 0, &stepbox, 1);
        assert_int_equal(r.ncontacts, 0);
        s = r.state;
    }
    assert_true(s.pos[1] == 0 && s.grounded);
    assert_float_equal(s.pos[0], 5.75f, 1e-3);
}

static void test_step_too_high_blocks(void **state)
{
    (void)state;
    const move_box stepbox = box(1, 0, -5, 3, 0.4f, 5, 1);
    move_state s = at(0.5f, 0, 0);
    move_result r = step(&s, 0.25f, 0, 0, &stepbox, 1);
    assert_int_equal(r.ncontacts, 1);
    assert_normal(&r.contacts[0], -1, 0, 0);
    assert_float_equal(r.contacts[0].point[1], 0.2f, EPS);
    assert_true(r.state.pos[1] == 0);
    assert_float_equal(r.state.pos[0], 0.7f - SKIN, EPS);
}

static void test_step_needs_headroom_and_room(void **state)
{
    (void)state;
    /* A low ceiling over the step: lifted, the head would hit it. */
    const move_box low[2] = {box(1, 0, -5, 3, 0.3f, 5, 1), box(0, 1.9f, -5, 3, 3, 5, 2)};
    move_state s = at(0.5f, 0, 0);
    move_result r = step(&s, 0.25f, 0, 0, low, 2);
    assert_int_equal(r.ncontacts, 1);
    assert_int_equal(r.contacts[0].handle, 1);
    assert_true(r.state.pos[1] == 0);
    /* A wall flush with the step's face: no stepping, the wall is reported. */
    const move_box flush[2] = {box(1, 0, -5, 3, 0.3f, 5, 1), box(1, 0, -5, 1.2f, 3, 5, 2)};
    r = step(&s, 0.25f, 0, 0, flush, 2);
    assert_int_equal(r.ncontacts, 1);
    assert_int_equal(r.contacts[0].handle, 2);
    assert_true(r.state.pos[1] == 0);
    /* A falling avatar does not step. */
    s.grounded = false;
    s.pos[1] = 0.5f;
    const move_box ledge = box(1, 0, -5, 3, 0.6f, 5, 3);
    r = step(&s, 0.25f, 0, 0, &ledge, 1);
    assert_int_equal(r.ncontacts, 1);
    assert_true(r.state.pos[1] < 0.5f);
}

/* A stair of 0.2 m risers and 0.3 m treads, climbed at 0.25 m a tick. */
static void test_stairs(void **state)
{
    (void)state;
    move_box stair[6];
    for (uint32_t k = 0; k < 6; k++)
        stair[k] = box(1 + 0.3f * (float)k, 0, -2, 10, 0.2f * (float)(k + 1), 2, k);
    move_state s = at(0, 0, 0);
    for (int k = 0; k < 40; k++) {
        move_result r = step(&s, 0.25f, 0, 0, stair, 6);
        assert_int_equal(r.ncontacts, 0);
        s = r.state;
    }
    assert_true(s.pos[1] == 1.2f);
    assert_true(s.grounded);
}

static void test_standing_on_a_box_is_support(void **state)
{
    (void)state;
    const move_box crate = box(-1, 0, -1, 1, 1, 1, 1);
    move_state s = at(0, 1, 0);
    for (int k = 0; k < 100; k++) {
        move_result r = step(&s, 0, 0, 0, &crate, 1);
        assert_int_equal(r.ncontacts, 0);
        assert_true(r.state.pos[1] == 1);
        assert_true(r.state.grounded);
        assert_true(r.state.vy == 0);
        s = r.state;
    }
    /* Walking over a floor made of two boxes at the same height. */
    const move_box deck[2] = {box(-5, 0, -5, 0, 1, 5, 1), box(0, 0, -5, 5, 1, 5, 2)};
    s = at(-2, 1, 0);
    for (int k = 0; k < 16; k++) {
        move_result r = step(&s, 0.25f, 0, 0, deck, 2);
        assert_int_equal(r.ncontacts, 0);
        assert_true(r.state.pos[1] == 1 && r.state.grounded);
        s = r.state;
    }
    assert_float_equal(s.pos[0], 2, 1e-4);
}

static void test_walk_off_edge_falls_and_lands(void **state)
{
    (void)state;
    const move_box crate = box(-1, 0, -1, 1, 1, 1, 1);
    move_state s = at(1.2f, 1, 0); /* 0.1 m of footprint still on the crate */
    move_result r = step(&s, 0.25f, 0, 0, &crate, 1);
    assert_int_equal(r.ncontacts, 0);
    assert_false(r.state.grounded);
    s = r.state;
    int ticks = 0;
    float last = s.pos[1];
    while (!s.grounded && ticks < 100) {
        r = step(&s, 0, 0, 0, &crate, 1);
        assert_int_equal(r.ncontacts, 0);
        assert_true(r.state.pos[1] <= last);
        last = r.state.pos[1];
        s = r.state;
        ticks++;
    }
    assert_true(s.pos[1] == 0 && s.grounded && s.vy == 0);
    /* 1 m under gravity takes sqrt(2 / 9.81) = 0.45 s: 9 or 10 ticks. */
    assert_true(ticks >= 8 && ticks <= 10);
    /* The tick that leaves the edge ends at rest in the air; the next one
     * falls from rest: v = -g dt, y = 1 - g dt^2 / 2, and the one after
     * that keeps accelerating. */
    s = at(1.2f, 1, 0);
    s = step(&s, 0.25f, 0, 0, &crate, 1).state;
    assert_true(s.pos[1] == 1 && s.vy == 0 && !s.grounded);
    r = step(&s, 0, 0, 0, &crate, 1);
    assert_float_equal(r.state.vy, -9.81f * DT, 1e-5);
    assert_float_equal(r.state.pos[1], 1 - 9.81f * DT * DT / 2, 1e-5);
    r = step(&r.state, 0, 0, 0, &crate, 1);
    assert_float_equal(r.state.vy, -2 * 9.81f * DT, 1e-5);
    assert_float_equal(r.state.pos[1], 1 - 9.81f * (2 * DT) * (2 * DT) / 2, 1e-5);
}

static void test_landing_on_a_box(void **state)
{
    (void)state;
    const move_box crate = box(-1, 0, -1, 1, 2, 1, 1);
    move_state s = {{0, 5, 0}, 0, false};
    for (int k = 0; k < 30 && !s.grounded; k++) {
        move_result r = step(&s, 0.05f, 0, 0, &crate, 1);
        assert_int_equal(r.ncontacts, 0);
        s = r.state;
    }
    assert_true(s.grounded && s.pos[1] == 2 && s.vy == 0);
}

static void test_head_hits_ceiling(void **state)
{
    (void)state;
    const move_box ceiling = box(-5, 2, -5, 5, 3, 5, 9);
    move_state s = at(0, 0, 0);
    move_result r = step(&s, 0, 0.5f, 0, &ceiling, 1);
    assert_float_equal(r.state.pos[1], 0.2f - SKIN, EPS);
    assert_int_equal(r.ncontacts, 1);
    assert_normal(&r.contacts[0], 0, -1, 0);
    assert_float_equal(r.contacts[0].point[1], 2, EPS);
    assert_false(r.state.grounded);
    assert_true(r.state.vy <= 0);
    /* Moving up at speed: the ceiling stops the rise too. */
    s.vy = 20;
    s.grounded = false;
    r = step(&s, 0, 0, 0, &ceiling, 1);
    assert_int_equal(r.ncontacts, 1);
    assert_true(r.state.vy == 0);
    assert_true(r.state.pos[1] < 0.2f);
}

static void test_inside_can_walk_out(void **state)
{
    (void)state;
    const move_box crate = box(-1, 0, -1, 1, 2, 1, 4);
    move_state s = at(0, 0, 0);
    /* Standing still inside reports nothing. */
    move_result r = step(&s, 0, 0, 0, &crate, 1);
    assert_int_equal(r.ncontacts, 0);
    int inside = 0;
    for (int k = 0; k < 10; k++) {
        r = step(&s, 0.25f, 0, 0, &crate, 1);
        s = r.state;
        if (r.ncontacts == 0)
            break;
        inside++;
        const move_contact *c = &r.contacts[0];
        assert_int_equal(r.ncontacts, 1);
        assert_true(c->inside);
        assert_int_equal(c->handle, 4);
        assert_normal(c, 1, 0, 0); /* nearest way out: +x */
        assert_float_equal(c->point[0], fminf(s.pos[0], 1), EPS);
        assert_float_equal(c->point[1], 0.9f, EPS);
        assert_float_equal(c->point[2], 0, EPS);
    }
    /* Out once x - 0.3 >= 1: after 6 moves of 0.25 m (at 1.5), 5 inside. */
    assert_int_equal(inside, 5);
    assert_float_equal(s.pos[0], 1.5f, EPS);
    /* Now outside, the box blocks like any other. */
    r = step(&s, -0.5f, 0, 0, &crate, 1);
    assert_int_equal(r.ncontacts, 1);
    assert_false(r.contacts[0].inside);
    assert_normal(&r.contacts[0], 1, 0, 0);
    assert_float_equal(r.state.pos[0], 1.3f + SKIN, EPS);
}

static void test_inside_policy_details(void **state)
{
    (void)state;
    /* Walking deeper in is allowed, and reported. */
    const move_box crate = box(-1, 0, -1, 1, 2, 1, 4);
    move_state s = at(0.9f, 0, 0);
    move_result r = step(&s, -0.5f, 0, 0, &crate, 1);
    assert_float_equal(r.state.pos[0], 0.4f, EPS);
    assert_int_equal(r.ncontacts, 1);
    assert_true(r.contacts[0].inside);
    /* Other boxes still block an avatar that is inside one. */
    const move_box two[2] = {crate, box(0.5f, 0, -1, 0.6f, 2, 1, 5)};
    s = at(0, 0, 0);
    r = step(&s, 1, 0, 0, two, 2);
    assert_float_equal(r.state.pos[0], 0.2f - SKIN, EPS);
    assert_int_equal(r.ncontacts, 2);
    assert_int_equal(r.contacts[0].handle, 5); /* blocking first */
    assert_false(r.contacts[0].inside);
    assert_int_equal(r.contacts[1].handle, 4);
    assert_true(r.contacts[1].inside);
    /* Sunk into a platform deeper than a step: it does not hold the avatar
     * up, which falls through to the floor; the normal points up (the bottom
     * face reaches the floor, so down is no way out). */
    const move_box platform = box(-3, 0, -3, 3, 1, 3, 6);
    s = (move_state){{0, 0.6f, 0}, 0, true};
    r = step(&s, 0.1f, 0, 0, &platform, 1);
    assert_true(r.state.pos[1] < 0.6f);
    assert_false(r.state.grounded);
    assert_int_equal(r.ncontacts, 1);
    assert_normal(&r.contacts[0], 0, 1, 0);
    for (int k = 0; k < 20; k++)
        s = r.state, r = step(&s, 0, 0, 0, &platform, 1);
    assert_true(r.state.pos[1] == 0 && r.state.grounded);
    /* Head inside a floating slab: the nearest way out is down. */
    const move_box slab = box(-3, 1.5f, -3, 3, 2.5f, 3, 7);
    s = at(0, 0, 0);
    r = step(&s, 0.1f, 0, 0, &slab, 1);
    assert_int_equal(r.ncontacts, 1);
    assert_normal(&r.contacts[0], 0, -1, 0);
    assert_float_equal(r.contacts[0].point[1], 1.5f, EPS);
}

/* A model's floor 4 mm above the avatar's feet: it is stood on the floor,
 * not left inside it, and walks on it with nothing to report. */
static void test_sunk_in_floor_stands_on_it(void **state)
{
    (void)state;
    const move_box slab = box(-10, -0.5f, -10, 10, 0.004f, 10, 3);
    move_state s = at(0, 0, 0);
    /* Even a move with no displacement stands it up. */
    move_result r = step(&s, 0, 0, 0, &slab, 1);
    assert_int_equal(r.ncontacts, 0);
    assert_true(r.state.pos[1] == 0.004f && r.state.grounded && r.state.vy == 0);
    for (int k = 0; k < 20; k++) {
        r = step(&s, 0.2f, 0, 0.1f, &slab, 1);
        assert_int_equal(r.ncontacts, 0);
        assert_true(r.state.pos[1] == 0.004f && r.state.grounded && r.state.vy == 0);
        s = r.state;
    }
    assert_float_equal(s.pos[0], 4, EPS);
    /* Spawned falling (not grounded): stood on it too. */
    s = (move_state){{0, 0, 0}, -1, false};
    r = step(&s, 0.1f, 0, 0, &slab, 1);
    assert_int_equal(r.ncontacts, 0);
    assert_true(r.state.pos[1] == 0.004f && r.state.grounded && r.state.vy == 0);
    /* Stood on it, it is on the ground even with nothing pulling it down:
     * the step in front of it is climbed, not a wall. */
    move_params weightless = prm;
    weightless.gravity = 0;
    const move_box slab_step[2] = {slab, box(0.5f, 0, -1, 1, 0.3f, 1, 4)};
    const float d[3] = {0.5f, 0, 0};
    s = (move_state){{0, 0, 0}, 0, false};
    assert_int_equal(move_step(&weightless, &s, d, DT, slab_step, 2, &r), 0);
    assert_int_equal(r.ncontacts, 0);
    assert_true(r.state.pos[1] == 0.3f && r.state.grounded);
    /* Walking off its edge: falls to the floor, nothing reported. */
    s = at(9.6f, 0.004f, 0);
    for (int k = 0; k < 5; k++)
        s = step(&s, 0.2f, 0, 0, &slab, 1).state;
    assert_true(s.pos[1] == 0 && s.grounded);
}

/* Overlapping low boxes (a step-sized block, a lower one beside it): lifted
 * onto the highest top, up to the step height, with no contact; one more
 * millimetre makes a tall box, and the inside contact stays. */
static void test_sunk_in_step_lifted(void **state)
{
    (void)state;
    const move_box low[2] = {box(-1, 0, -1, 0.1f, 0.2f, 1, 1), box(0, 0, -1, 1, 0.35f, 1, 2)};
    move_state s = at(0, 0, 0);
    move_result r = step(&s, 0.1f, 0, 0, low, 2);
    assert_int_equal(r.ncontacts, 0);
    assert_true(r.state.pos[1] == 0.35f && r.state.grounded);
    assert_float_equal(r.state.pos[0], 0.1f, EPS);
    /* From a floor slab the feet are in, onto a step it also overlaps. */
    const move_box slab_and_step[2] = {box(-10, -1, -10, 10, 0.01f, 10, 1), box(0.2f, 0, -1, 1, 0.3f, 1, 2)};
    r = step(&s, 0, 0, 0, slab_and_step, 2);
    assert_true(r.state.pos[1] == 0.3f && r.state.grounded && r.ncontacts == 0);
    /* Higher than a step: an object placed around the avatar. */
    const move_box tall = box(-1, 0, -1, 1, 0.351f, 1, 4);
    r = step(&s, 0.1f, 0, 0, &tall, 1);
    assert_int_equal(r.ncontacts, 1);
    assert_true(r.contacts[0].inside && r.contacts[0].handle == 4);
    assert_true(r.state.pos[1] == 0);
    /* A low box the avatar only touches (their faces meet) is not
     * overlapped: nothing to lift it out of. */
    const move_box beside = box(0.3f, 0, -1, 1, 0.3f, 1, 5);
    r = step(&s, 0, 0, 0, &beside, 1);
    assert_true(r.state.pos[1] == 0 && r.ncontacts == 0);
}

/* Lifting must not push the avatar's head into a box it was not in: then it
 * is not lifted (or only onto a lower top that has room), and the inside
 * contact stays. A box it was already in does not stop the lift. */
static void test_sunk_needs_headroom(void **state)
{
    (void)state;
    const move_box blocked[2] = {box(-1, 0, -1, 1, 0.2f, 1, 1), box(-1, 1.9f, -1, 1, 3, 1, 2)};
    move_state s = at(0, 0, 0);
    move_result r = step(&s, 0.1f, 0, 0, blocked, 2);
    assert_true(r.state.pos[1] == 0);
    assert_int_equal(r.ncontacts, 1);
    assert_true(r.contacts[0].inside && r.contacts[0].handle == 1);
    /* A lower top with room: lifted onto it; the higher box, still
     * overlapped, is reported inside. */
    const move_box two[3] = {box(-1, 0, -1, 1, 0.3f, 1, 1), box(-1, 0, -1, 1, 0.1f, 1, 2),
                             box(-1, 2, -1, 1, 3, 1, 3)};
    r = step(&s, 0.1f, 0, 0, two, 3);
    assert_true(r.state.pos[1] == 0.1f && r.state.grounded);
    assert_int_equal(r.ncontacts, 1);
    assert_true(r.contacts[0].inside && r.contacts[0].handle == 1);
    /* A ceiling the head is already in does not hold it down. */
    const move_box in_ceiling[2] = {box(-1, 0, -1, 1, 0.2f, 1, 1), box(-1, 1.7f, -1, 1, 3, 1, 2)};
    r = step(&s, 0.1f, 0, 0, in_ceiling, 2);
    assert_true(r.state.pos[1] == 0.2f);
    assert_int_equal(r.ncontacts, 1);
    assert_true(r.contacts[0].inside && r.contacts[0].handle == 2);
}

static void test_zero_move_reports_nothing(void **state)
{
    (void)state;
    const move_box wall = box(0.3f, 0, -5, 1, 3, 5, 1); /* touching the avatar */
    move_state s = at(0, 0, 0);
    move_result r = step(&s, 0, 0, 0, &wall, 1);
    assert_int_equal(r.ncontacts, 0);
    assert_int_equal(r.dropped, 0);
    assert_true(memcmp(r.state.pos, s.pos, sizeof s.pos) == 0);
    assert_true(r.state.grounded && r.state.vy == 0);
    /* No boxes at all. */
    r = step(&s, 0, 0, 0, NULL, 0);
    assert_int_equal(r.ncontacts, 0);
    assert_true(memcmp(r.state.pos, s.pos, sizeof s.pos) == 0);
    /* dt = 0: nothing falls. */
    move_state air = {{0, 3, 0}, 0, false};
    const float none[3] = {0, 0, 0};
    assert_int_equal(move_step(&prm, &air, none, 0, NULL, 0, &r), 0);
    assert_true(r.state.pos[1] == 3 && !r.state.grounded);
    /* Below the floor: lifted onto it. */
    move_state under = at(0, -1, 0);
    r = step(&under, 0, 0, 0, NULL, 0);
    assert_true(r.state.pos[1] == 0 && r.state.grounded);
}

/* Expects -EINVAL with out holding s and no contacts, and (when the bad
 * input is not a box) an empty move_bounds. */
static void expect_einval(const move_params *p, const move_state *s, const float d[3], float dt,
                          const move_box *b, uint32_t n)
{
    move_result r;
    memset(&r, 0xab, sizeof r);
    assert_int_equal(move_step(p, s, d, dt, b, n, &r), -EINVAL);
    assert_int_equal(r.ncontacts, 0);
    assert_int_equal(r.dropped, 0);
    if (s)
        assert_true(same_state(&r.state, s));
    float min[3], max[3];
    move_bounds(p, s, d, dt, min, max);
    if (!n)
        for (int a = 0; a < 3; a++)
            assert_true(min[a] > max[a]);
}

static void test_bad_input_rejected(void **state)
{
    (void)state;
    const move_state ok = at(0, 0, 0);
    const float d[3] = {0.1f, 0, 0}, dn[3] = {NAN, 0, 0}, dinf[3] = {0, INFINITY, 0}, dbig[3] = {5000, 0, 0};
    const move_box good = box(1, 0, 0, 2, 1, 1, 1);
    expect_einval(&prm, &ok, dn, DT, NULL, 0);
    expect_einval(&prm, &ok, dinf, DT, NULL, 0);
    expect_einval(&prm, &ok, dbig, DT, NULL, 0);
    move_state s = ok;
    s.pos[2] = NAN;
    expect_einval(&prm, &s, d, DT, NULL, 0);
    s = ok;
    s.vy = NAN;
    expect_einval(&prm, &s, d, DT, NULL, 0);
    s = ok;
    s.pos[0] = 1e5f;
    expect_einval(&prm, &s, d, DT, NULL, 0);
    expect_einval(&prm, &ok, d, NAN, NULL, 0);
    expect_einval(&prm, &ok, d, -DT, NULL, 0);
    expect_einval(&prm, &ok, d, 2 * MOVE_MAX_DT, NULL, 0);
    move_box bad = good;
    bad.min[1] = NAN;
    expect_einval(&prm, &ok, d, DT, &bad, 1);
    bad = good;
    bad.max[0] = -INFINITY;
    expect_einval(&prm, &ok, d, DT, &bad, 1);
    bad = good;
    bad.min[2] = 3; /* min > max */
    expect_einval(&prm, &ok, d, DT, &bad, 1);
    expect_einval(&prm, &ok, d, DT, NULL, 1);
    move_params p = prm;
    p.size[1] = 0;
    expect_einval(&p, &ok, d, DT, NULL, 0);
    p = prm;
    p.gravity = -1;
    expect_einval(&p, &ok, d, DT, NULL, 0);
    p = prm;
    p.step_height = 2; /* above the avatar */
    expect_einval(&p, &ok, d, DT, NULL, 0);
    p = prm;
    p.floor_y = NAN;
    expect_einval(&p, &ok, d, DT, NULL, 0);
    expect_einval(NULL, &ok, d, DT, NULL, 0);
    expect_einval(&prm, NULL, d, DT, NULL, 0);
    expect_einval(&prm, &ok, NULL, DT, NULL, 0);
    assert_int_equal(move_step(&prm, &ok, d, DT, NULL, 0, NULL), -EINVAL);
}

static void test_contact_cap(void **state)
{
    (void)state;
    move_box many[MOVE_MAX_CONTACTS + 4];
    for (uint32_t k = 0; k < MOVE_MAX_CONTACTS + 4; k++)
        many[k] = box(-1 - 0.01f * (float)k, 0, -1, 1, 3, 1, k);
    move_state s = at(0, 0, 0);
    move_result r = step(&s, 0.1f, 0, 0, many, MOVE_MAX_CONTACTS + 4);
    assert_int_equal(r.ncontacts, MOVE_MAX_CONTACTS);
    assert_int_equal(r.dropped, 4);
    for (uint32_t k = 0; k < MOVE_MAX_CONTACTS; k++)
        assert_int_equal(r.contacts[k].handle, k);
}

/* Whether the avatar at s overlaps box b, computed independently. */
static int overlapping(const move_state *s, const move_box *b)
{
    double h = prm.size[0] / 2.0;
    return (double)s->pos[0] - h < b->max[0] && (double)s->pos[0] + h > b->min[0] && s->pos[1] < b->max[1] &&
           (double)s->pos[1] + prm.size[1] > b->min[1] && (double)s->pos[2] - h < b->max[2] &&
           (double)s->pos[2] + h > b->min[2];
}

/*
 * A random walk among random boxes far from the origin (where floats are
 * coarse), now and then sunk 4 mm into what it stands on: the avatar never
 * ends a move overlapping a box it did not overlap when the move began,
 * never goes below the floor, and the candidates inside
 * move_bounds give exactly the move that all boxes give. Deterministic.
 */
static void test_random_walk_never_enters(void **state)
{
    (void)state;
    enum { NB = 60, MOVES = 20000 };
    static move_box all[NB], cand[NB];
    unsigned seed = 12345;
    const float ox = 1000.3f, oz = -777.7f;
    for (uint32_t k = 0; k < NB; k++) {
        float x = ox + rnd(&seed) * 12 - 6, z = oz + rnd(&seed) * 12 - 6, y = rnd(&seed) < 0.6f ? 0 : rnd(&seed) * 2;
        float scale = rnd(&seed) < 0.2f ? 6 : 1.5f; /* some long walls */
        float sx = 0.05f + rnd(&seed) * scale, sz = 0.05f + rnd(&seed) * 1.5f, sy = 0.1f + rnd(&seed) * 2;
        all[k] = box(x, y, z, x + sx, y + sy, z + sz, k);
    }
    move_state s = at(ox, 0, oz);
    int contacts = 0, steps_up = 0, falls = 0, stood = 0;
    for (int m = 0; m < MOVES; m++) {
        float ang = rnd(&seed) * 6.2831853f, len = rnd(&seed) * 0.3f;
        if (rnd(&seed) < 0.05f)
            len = rnd(&seed) * 8; /* now and then a teleport-sized request */
        float d[3] = {len * cosf(ang), 0, len * sinf(ang)};
        if (fabsf(s.pos[0] + d[0] - ox) > 7)
            d[0] = -d[0];
        if (fabsf(s.pos[2] + d[2] - oz) > 7)
            d[2] = -d[2];
        if (rnd(&seed) < (s.pos[1] > 0 ? 0.2f : 0.05f)) /* now and then sunk a few mm into what it stands on */
            s.pos[1] -= 0.004f;
        float min[3], max[3];
        move_bounds(&prm, &s, d, DT, min, max);
        uint32_t nc = 0;
        for (uint32_t k = 0; k < NB; k++)
            if (all[k].min[0] <= max[0] && all[k].max[0] >= min[0] && all[k].min[1] <= max[1] &&
                all[k].max[1] >= min[1] && all[k].min[2] <= max[2] && all[k].max[2] >= min[2])
                cand[nc++] = all[k];
        move_result r, rall;
        assert_int_equal(move_step(&prm, &s, d, DT, cand, nc, &r), 0);
        assert_int_equal(move_step(&prm, &s, d, DT, all, NB, &rall), 0);
        assert_true(same_state(&r.state, &rall.state));
        assert_int_equal(r.ncontacts, rall.ncontacts);
        for (uint32_t k = 0; k < r.ncontacts; k++) {
            assert_int_equal(r.contacts[k].handle, rall.contacts[k].handle);
            assert_true(memcmp(r.contacts[k].point, rall.contacts[k].point, sizeof r.contacts[k].point) == 0);
        }
        for (uint32_t k = 0; k < NB; k++)
            assert_false(!overlapping(&s, &all[k]) && overlapping(&r.state, &all[k]));
        assert_true(r.state.pos[1] >= 0);
        contacts += r.ncontacts > 0;
        steps_up += r.state.pos[1] > s.pos[1] + 0.01f && r.ncontacts == 0;
        stood += s.pos[1] > 0 && r.state.pos[1] > s.pos[1] && r.state.pos[1] < s.pos[1] + 0.005f && r.state.grounded;
        falls += !r.state.grounded;
        s = r.state;
    }
    /* The walk did meet walls, climb, fall and stand up out of a floor. */
    assert_true(contacts > 1000 && steps_up > 50 && falls > 50 && stood > 50);
}

/* At the same instant a top face wins over a wall's side, whatever the
 * candidates' order: the avatar lands, then the wall blocks what is left.
 * Sizes and motion are binary fractions so that the two times are equal. */
static void test_tie_landing_before_wall(void **state)
{
    (void)state;
    move_params p = prm;
    p.size[0] = p.size[2] = 0.5f;
    p.size[1] = 2;
    p.gravity = 0;
    const move_box boxes[2] = {box(0.75f, 0, -5, 1, 5, 5, 1), box(-1, 0, -5, 0.5f, 0.5f, 5, 2)};
    const move_box reversed[2] = {boxes[1], boxes[0]};
    const move_state s = {{0, 1, 0}, 0, false};
    const float d[3] = {1, -1, 0};
    move_result r, q;
    assert_int_equal(move_step(&p, &s, d, DT, boxes, 2, &r), 0);
    assert_int_equal(move_step(&p, &s, d, DT, reversed, 2, &q), 0);
    assert_true(same_state(&r.state, &q.state));
    assert_true(r.state.pos[1] == 0.5f && r.state.grounded);
    assert_float_equal(r.state.pos[0], 0.5f, EPS);
    assert_int_equal(r.ncontacts, 1);
    assert_int_equal(q.ncontacts, 1);
    assert_int_equal(r.contacts[0].handle, 1);
    assert_normal(&r.contacts[0], -1, 0, 0);
}

/* The caller says grounded, but the feet are 5 mm up: the step's face comes
 * before the floor, and the step still lifts it (dropping the fall). */
static void test_step_from_hover(void **state)
{
    (void)state;
    const move_box stepbox = box(1, 0, -5, 3, 0.3f, 5, 1);
    move_state s = at(0.69f, 0.005f, 0);
    move_result r = step(&s, 0.25f, 0, 0, &stepbox, 1);
    assert_int_equal(r.ncontacts, 0);
    assert_true(r.state.pos[1] == 0.3f && r.state.grounded);
}

/*
 * A corridor one float step too narrow for any float position of the avatar:
 * walking in, the move ends inside it in double, and rounding cannot put the
 * avatar anywhere that overlaps neither wall, so it stays where it started.
 */
static void test_rounding_never_overlaps(void **state)
{
    (void)state;
    const double width = 2.0 * (double)(prm.size[0] / 2);
    float right = (float)(1000.0 + width);
    if ((double)right < 1000.0 + width)
        right = nextafterf(right, INFINITY);
    /* The floats around the only x where the avatar fits both miss it. */
    float below = (float)(1000.0 + width / 2);
    if ((double)below - width / 2 >= 1000.0)
        below = nextafterf(below, -INFINITY);
    float above = nextafterf(below, INFINITY);
    assert_true((double)below - width / 2 < 1000.0 && (double)above + width / 2 > (double)right);
    const move_box walls[2] = {box(990, 0, 0, 1000, 3, 10, 1), box(right, 0, 0, 1010, 3, 10, 2)};
    move_state s = at(below, 0, -2);
    float dx = (float)(((double)right - width / 2 + (double)below) / 2 - below); /* ends between them */
    move_result r = step(&s, dx, 0, 2.5f, walls, 2);
    assert_true(same_state(&r.state, &s));
    assert_int_equal(r.ncontacts, 0);
}

static void test_deterministic(void **state)
{
    (void)state;
    const move_box boxes[3] = {box(1, 0, -5, 1.2f, 3, 5, 1), box(-5, 0, 1, 5, 3, 1.2f, 2),
                               box(0, 0, 0, 0.5f, 0.2f, 0.5f, 3)};
    move_state s = at(0.3f, 0, 0.4f);
    move_result a, b;
    const float d[3] = {0.9f, 0, 0.7f};
    memset(&a, 0, sizeof a);
    memset(&b, 0xff, sizeof b);
    assert_int_equal(move_step(&prm, &s, d, DT, boxes, 3, &a), 0);
    assert_int_equal(move_step(&prm, &s, d, DT, boxes, 3, &b), 0);
    assert_true(same_state(&a.state, &b.state));
    assert_int_equal(a.ncontacts, b.ncontacts);
    for (uint32_t k = 0; k < a.ncontacts; k++)
        assert_true(memcmp(&a.contacts[k].point, &b.contacts[k].point, sizeof a.contacts[k].point) == 0 &&
                    a.contacts[k].handle == b.contacts[k].handle);
    /* Sunk into two low boxes, candidates in either order: the same lift. */
    const move_box sunk[2] = {box(-1, -1, -1, 1, 0.004f, 1, 1), box(0, 0, -1, 1, 0.25f, 1, 2)};
    const move_box reversed[2] = {sunk[1], sunk[0]};
    s = at(0.1f, 0, 0);
    assert_int_equal(move_step(&prm, &s, d, DT, sunk, 2, &a), 0);
    assert_int_equal(move_step(&prm, &s, d, DT, reversed, 2, &b), 0);
    assert_true(same_state(&a.state, &b.state) && a.state.pos[1] == 0.25f);
    assert_int_equal(a.ncontacts, 0);
    assert_int_equal(b.ncontacts, 0);
}

/* Push-out (a new map that encloses the avatar): the nearest free place
 * past one face, or two at a corner, or on a top; no further than half the
 * avatar's width; nothing moves an avatar that overlaps nothing. */
static void test_push_out(void **state)
{
    (void)state;
    move_result r;
    static const float still[3] = {0, 0, 0};
    /* 2 cm into a wall's box: back out of it, a skin from its face. */
    const move_box wall = box(0.28f, 0, -1, 1, 3, 1, 1);
    move_state s = at(0, 0, 0);
    assert_int_equal(move_push_out(&prm, &s, &wall, 1), 1);
    assert_float_equal(s.pos[0], 0.28f - 0.3f - SKIN, EPS);
    assert_true(s.pos[1] == 0 && s.pos[2] == 0 && s.grounded && s.vy == 0);
    assert_int_equal(move_step(&prm, &s, still, DT, &wall, 1, &r), 0);
    assert_true(same_state(&r.state, &s));
    /* Overlapping nothing: left as it is. */
    move_state free_s = s;
    assert_int_equal(move_push_out(&prm, &s, &wall, 1), 0);
    assert_true(same_state(&free_s, &s));
    /* A corner of two boxes: out of both, past a face of each. */
    const move_box corner[2] = {wall, box(-1, 0, 0.25f, 1, 3, 1, 2)};
    s = at(0, 0, 0);
    assert_int_equal(move_push_out(&prm, &s, corner, 2), 1);
    assert_float_equal(s.pos[0], 0.28f - 0.3f - SKIN, EPS);
    assert_float_equal(s.pos[2], 0.25f - 0.3f - SKIN, EPS);
    /* A low box under most of it: onto its top, standing. */
    const move_box low = box(-1, 0, -1, 0.2f, 0.1f, 1, 3);
    s = at(0, 0.02f, 0);
    s.vy = -1;
    s.grounded = false;
    assert_int_equal(move_push_out(&prm, &s, &low, 1), 1);
    assert_true(s.pos[0] == 0 && s.pos[1] == 0.1f && s.pos[2] == 0 && s.grounded && s.vy == 0);
    /* Deeper than half its width on every side, or a box above the top it
     * would be pushed onto: left inside (the inside policy). */
    const move_box deep = box(-0.25f, 0, -0.25f, 0.25f, 3, 0.25f, 4);
    s = at(0, 0, 0);
    free_s = s;
    assert_int_equal(move_push_out(&prm, &s, &deep, 1), -ENOSPC);
    assert_true(same_state(&free_s, &s));
    const move_box capped[2] = {box(-1, 0, -1, 1, 0.1f, 1, 5), box(-1, 1.85f, -1, 1, 3, 1, 6)};
    assert_int_equal(move_push_out(&prm, &s, capped, 2), -ENOSPC);
    assert_true(same_state(&free_s, &s));
    /* The nearest face leads into another box: the next nearest place,
     * onto the low box's top. */
    const move_box behind[2] = {box(0.28f, 0, -1, 1, 0.25f, 1, 7), box(-1, 0, -1, -0.31f, 3, 1, 8)};
    assert_int_equal(move_push_out(&prm, &s, behind, 2), 1);
    assert_true(s.pos[0] == 0 && s.pos[1] == 0.25f && s.pos[2] == 0 && s.grounded);
    /* Bad input. */
    s = at(NAN, 0, 0);
    assert_int_equal(move_push_out(&prm, &s, &wall, 1), -EINVAL);
    s = at(0, 0, 0);
    const move_box bad = box(1, 0, 0, 0, 1, 1, 9);
    assert_int_equal(move_push_out(&prm, &s, &bad, 1), -EINVAL);
    assert_int_equal(move_push_out(&prm, &s, NULL, 1), -EINVAL);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup(test_wall_stops, setup),
        cmocka_unit_test_setup(test_slide_keeps_tangential_motion, setup),
        cmocka_unit_test_setup(test_slide_over_seam, setup),
        cmocka_unit_test_setup(test_corner_stops_both, setup),
        cmocka_unit_test_setup(test_clipped_corner_slips, setup),
        cmocka_unit_test_setup(test_no_tunnelling, setup),
        cmocka_unit_test_setup(test_step_up, setup),
        cmocka_unit_test_setup(test_step_too_high_blocks, setup),
        cmocka_unit_test_setup(test_step_needs_headroom_and_room, setup),
        cmocka_unit_test_setup(test_stairs, setup),
        cmocka_unit_test_setup(test_standing_on_a_box_is_support, setup),
        cmocka_unit_test_setup(test_walk_off_edge_falls_and_lands, setup),
        cmocka_unit_test_setup(test_landing_on_a_box, setup),
        cmocka_unit_test_setup(test_head_hits_ceiling, setup),
        cmocka_unit_test_setup(test_inside_can_walk_out, setup),
        cmocka_unit_test_setup(test_inside_policy_details, setup),
        cmocka_unit_test_setup(test_sunk_in_floor_stands_on_it, setup),
        cmocka_unit_test_setup(test_sunk_in_step_lifted, setup),
        cmocka_unit_test_setup(test_sunk_needs_headroom, setup),
        cmocka_unit_test_setup(test_zero_move_reports_nothing, setup),
        cmocka_unit_test_setup(test_bad_input_rejected, setup),
        cmocka_unit_test_setup(test_contact_cap, setup),
        cmocka_unit_test_setup(test_random_walk_never_enters, setup),
        cmocka_unit_test_setup(test_tie_landing_before_wall, setup),
        cmocka_unit_test_setup(test_step_from_hover, setup),
        cmocka_unit_test_setup(test_rounding_never_overlaps, setup),
        cmocka_unit_test_setup(test_deterministic, setup),
        cmocka_unit_test_setup(test_push_out, setup),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
