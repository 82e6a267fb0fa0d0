/*
 * test_world_pose.c: which poses the world takes to pass on (server/world.c,
 * world_set_pose): the first always; then only one past a WORLD_POSE_*
 * threshold, measured from the last one taken, never from the last sent.
 */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "world.h"

typedef struct fixture {
    world *w;
    scene *sc;
    uint32_t id;
} fixture;

static int setup(void **state)
{
    static fixture f;
    const world_config cfg = {.min = {-50, 0, -50}, .max = {50, 20, 50}, .max_speed = 5, .aoi_radius = 10,
                              .spawn_radius = 1, .tick_dt = 0.05f, .capacity = 4, .seed = 1};
    const float box[3] = {0.6f, 1.8f, 0.6f};
    int crowded;

    f.w = world_create(&cfg);
    f.sc = scene_create(cfg.min, cfg.max);
    assert_non_null(f.w);
    assert_non_null(f.sc);
    const world_avatar *a = world_add(f.w, f.sc, "ann", 3, box, &crowded);
    assert_non_null(a);
    f.id = a->id;
    *state = &f;
    return 0;
}

static int teardown(void **state)
{
    fixture *f = *state;
    world_destroy(f->w);
    scene_destroy(f->sc);
    return 0;
}

/* Facing yaw, and a head 1.7 m up turned by turn radians about y. */
static proto_pose posed(float yaw, float turn, int16_t head_x)
{
    proto_pose p = {.yaw = yaw};
    const float at[3] = {(float)head_x / 1000.0f, 1.7f, 0.0f};
    const float q[4] = {0.0f, sinf(turn * 0.5f), 0.0f, cosf(turn * 0.5f)};
    proto_pose_set_part(&p, PROTO_POSE_HEAD, at, q);
    return p;
}

static void test_first_and_thresholds(void **state)
{
    fixture *f = *state;
    const world_avatar *a = world_get(f->w, f->id);
    proto_pose p = posed(0.0f, 0.0f, 0);

    assert_false(a->has_pose);
    assert_int_equal(world_set_pose(f->w, f->id, &p), 1);
    assert_true(a->has_pose);
    /* Taken now, sent by the next step's updates (this step's may be done). */
    assert_int_equal(a->pose_tick, world_tick(f->w) + 1);
    /* The same again, and changes under each threshold: not taken. */
    assert_int_equal(world_set_pose(f->w, f->id, &p), 0);
    p = posed(WORLD_POSE_ANGLE_MIN * 0.8f, 0.0f, 0);
    assert_int_equal(world_set_pose(f->w, f->id, &p), 0);
    p = posed(0.0f, WORLD_POSE_TURN_MIN * 0.8f, 0);
    assert_int_equal(world_set_pose(f->w, f->id, &p), 0);
    p = posed(0.0f, 0.0f, WORLD_POSE_MOVE_MIN_MM);
    assert_int_equal(world_set_pose(f->w, f->id, &p), 0);
    p = posed(0.0f, 0.0f, 0);
    p.pitch = -WORLD_POSE_ANGLE_MIN * 0.8f;
    assert_int_equal(world_set_pose(f->w, f->id, &p), 0);
    /* Each one past its threshold is taken, and becomes the reference. */
    p = posed(WORLD_POSE_ANGLE_MIN * 1.5f, 0.0f, 0);
    assert_int_equal(world_set_pose(f->w, f->id, &p), 1);
    p = posed(WORLD_POSE_ANGLE_MIN * 1.5f, WORLD_POSE_TURN_MIN * 1.5f, 0);
    assert_int_equal(world_set_pose(f->w, f->id, &p), 1);
    p = posed(WORLD_POSE_ANGLE_MIN * 1.5f, WORLD_POSE_TURN_MIN * 1.5f, WORLD_POSE_MOVE_MIN_MM + 1);
    assert_int_equal(world_set_pose(f->w, f->id, &p), 1);
    p.pitch = WORLD_POSE_ANGLE_MIN * 1.5f;
    assert_int_equal(world_set_pose(f->w, f->id, &p), 1);
    /* Small steps never add up to a send: each is measured from the last
     * pose taken. */
    for (int i = 1; i <= 5; i++) {
        proto_pose q = p;
        q.yaw += (float)i * WORLD_POSE_ANGLE_MIN * 0.15f;
        assert_int_equal(world_set_pose(f->w, f->id, &q), 0);
    }
    /* Another set of parts is a change, however close the rest. */
    proto_pose facing = p;
    facing.parts = 0;
    assert_int_equal(world_set_pose(f->w, f->id, &facing), 1);
    assert_int_equal(a->pose.parts, 0);
}

/* Yaw is an angle: a full turn is no change, -pi and pi are the same. */
static void test_yaw_wraps(void **state)
{
    fixture *f = *state;
    proto_pose p = {.yaw = 3.14f}, q = {.yaw = 3.14f - 2.0f * (float)M_PI};

    assert_int_equal(world_set_pose(f->w, f->id, &p), 1);
    assert_int_equal(world_set_pose(f->w, f->id, &q), 0);
    q.yaw = -3.14f; /* 0.0032 rad from 3.14 across pi: under */
    assert_int_equal(world_set_pose(f->w, f->id, &q), 0);
    q.yaw = -3.12f; /* 0.0232 rad across pi: over */
    assert_int_equal(world_set_pose(f->w, f->id, &q), 1);
}

static void test_gone_avatar(void **state)
{
    fixture *f = *state;
    proto_pose p = {.yaw = 1.0f};

    assert_int_equal(world_set_pose(f->w, f->id + (1u << WORLD_SLOT_BITS), &p), 0);
    assert_int_equal(world_set_pose(f->w, 0, &p), 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_first_and_thresholds, setup, teardown),
        cmocka_unit_test_setup_teardown(test_yaw_wraps, setup, teardown),
        cmocka_unit_test_setup_teardown(test_gone_avatar, setup, teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
