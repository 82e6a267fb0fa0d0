/* The scene: objects found by id whatever the order they came and went in,
 * transforms that round-trip, world boxes that follow placement, and the
 * broadphase handles behind them. */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>
#include <math.h>
#include <string.h>

#include "scene.h"

static const float WMIN[3] = {-500, 0, -500}, WMAX[3] = {500, 256, 500};

static void add(scene *s, uint32_t id, float x)
{
    scene_box box = {{-1, 0, -2}, {1, 3, 2}};
    float tri[9] = {-1, 0, -2, 1, 0, 2, 1, 3, 2};
    scene_object_def d = {.id = id, .owner = "ann", .name = "o", .at = {.pos = {x, 0, 0}, .scale = 1},
                          .ecm_version = 1, .tri_count = 1, .tris = tri, .box_count = 1, .boxes = &box};
    assert_int_equal(scene_add(s, &d), 0);
}

static void test_lookup_in_any_order(void **state)
{
    (void)state;
    scene *s = scene_create(WMIN, WMAX);
    const uint32_t ids[] = {40, 7, 99, 12, 3, 58};
    for (int i = 0; i < 6; i++)
        add(s, ids[i], (float)(10 * i));
    add(s, 500, 0);
    assert_int_equal(scene_remove(s, 12), 0);
    assert_int_equal(scene_remove(s, 12), -2); /* ENOENT */
    assert_int_equal(scene_remove(s, 500), 0);
    assert_int_equal(scene_count(s), 5);
    for (int i = 0; i < 6; i++) {
        const scene_object *o = scene_get(s, ids[i]);
        if (ids[i] == 12) {
            assert_null(o);
            continue;
        }
        assert_non_null(o);
        assert_int_equal(o->id, ids[i]);
        assert_true(o->at.pos[0] == (float)(10 * i));
    }
    for (uint32_t i = 1; i < scene_count(s); i++)
        assert_true(scene_at(s, i - 1)->id < scene_at(s, i)->id);
    scene_box box = {{0, 0, 0}, {1, 1, 1}};
    scene_object_def dup = {.id = 7, .owner = "x", .name = "x", .at = {.scale = 1}, .ecm_version = 1,
                            .box_count = 1, .boxes = &box};
    assert_int_equal(scene_add(s, &dup), -17); /* EEXIST */
    dup.id = 8;
    dup.box_count = 0;
    assert_int_equal(scene_add(s, &dup), -22); /* EINVAL: no boxes */
    scene_destroy(s);
}

static void test_transforms_round_trip(void **state)
{
    (void)state;
    proto_transform at = {.pos = {3, 1, -2}, .yaw = 0.7f, .scale = 2.5f};
    float l[3] = {1.5f, -0.25f, 4}, w[3], back[3];
    scene_to_world(&at, l, w);
    scene_to_local(&at, w, back);
    for (int k = 0; k < 3; k++)
        assert_true(fabsf(back[k] - l[k]) < 1e-5f);
    /* A quarter turn about +y takes +x to -z and +z to +x. */
    proto_transform q = {.yaw = (float)M_PI / 2, .scale = 1};
    float x[3] = {1, 0, 0};
    scene_to_world(&q, x, w);
    assert_true(fabsf(w[0]) < 1e-6f && fabsf(w[2] + 1) < 1e-6f);
}

static void test_world_boxes_follow_placement(void **state)
{
    (void)state;
    scene *s = scene_create(WMIN, WMAX);
    add(s, 1, 100);
    uint32_t h[4];
    float lo[3] = {99, 0, -1}, hi[3] = {101, 1, 1};
    assert_int_equal(scene_query(s, lo, hi, h, 4), 1);
    const scene_box_ref *b = scene_box_at(s, h[0]);
    assert_int_equal(b->object_id, 1);
    assert_int_equal(b->box_index, 0);
    /* Turned a quarter and doubled: x in [-2, 2] -> z, z in [-2, 2] -> x, scaled by 2. */
    proto_transform at = {.pos = {-50, 0, 0}, .yaw = (float)M_PI / 2, .scale = 2};
    assert_int_equal(scene_place(s, 1, &at), 0);
    assert_int_equal(scene_query(s, lo, hi, h, 4), 0);
    float lo2[3] = {-51, 0, -1}, hi2[3] = {-49, 1, 1};
    assert_int_equal(scene_query(s, lo2, hi2, h, 4), 1);
    b = scene_box_at(s, h[0]);
    assert_true(fabsf(b->world.min[0] - -54) < 1e-4f && fabsf(b->world.max[0] - -46) < 1e-4f);
    assert_true(fabsf(b->world.min[2] - -2) < 1e-4f && fabsf(b->world.max[2] - 2) < 1e-4f);
    assert_true(fabsf(b->world.max[1] - 6) < 1e-4f);
    assert_int_equal(scene_remove(s, 1), 0);
    assert_int_equal(scene_query(s, lo2, hi2, h, 4), 0);
    scene_destroy(s);
}

/* Objects by slot and by area: slots are dense and reused, the objects'
 * broadphase follows every change, revisions count what a client must be
 * told again. */
static void test_objects_by_slot_and_area(void **state)
{
    (void)state;
    scene *s = scene_create(WMIN, WMAX);
    add(s, 1, 0);
    add(s, 2, 100);
    add(s, 3, 200);
    assert_int_equal(scene_slots(s), 3);
    uint32_t slot2 = scene_get(s, 2)->slot;
    assert_ptr_equal(scene_at_slot(s, slot2), scene_get(s, 2));
    assert_null(scene_at_slot(s, 3));
    float lo[3] = {90, -10, -10}, hi[3] = {110, 10, 10};
    uint32_t out[4];
    assert_int_equal(scene_query_objects(s, lo, hi, out, 4), 1);
    assert_int_equal(out[0], slot2);
    assert_true(scene_get(s, 2)->bounds.min[0] == 99 && scene_get(s, 2)->bounds.max[2] == 2);

    uint32_t rev = scene_get(s, 2)->rev;
    proto_transform far = {.pos = {-300, 0, 0}, .scale = 2};
    assert_int_equal(scene_place(s, 2, &far), 0);
    assert_int_equal(scene_get(s, 2)->rev, rev + 1);
    assert_int_equal(scene_query_objects(s, lo, hi, out, 4), 0);
    float lo2[3] = {-310, -10, -10}, hi2[3] = {-290, 10, 10};
    assert_int_equal(scene_query_objects(s, lo2, hi2, out, 4), 1);
    assert_int_equal(scene_set_owner(s, 2, "world"), 0);
    scene_box two[2] = {{{-1, 0, -2}, {0, 3, 2}}, {{0, 0, -2}, {1, 1, 2}}};
    assert_int_equal(scene_set_ecm(s, 2, 2, two, 2), 0);
    assert_int_equal(scene_get(s, 2)->rev, rev + 3);
    assert_true(scene_get(s, 2)->bounds.max[1] == 6); /* scale 2 */

    assert_int_equal(scene_remove(s, 2), 0);
    assert_null(scene_at_slot(s, slot2));
    assert_int_equal(scene_query_objects(s, lo2, hi2, out, 4), 0);
    add(s, 4, 50);
    assert_int_equal(scene_get(s, 4)->slot, slot2); /* reused */
    assert_int_equal(scene_slots(s), 3);
    scene_destroy(s);
}

/* A transform that overflows a box to infinity is refused and changes
 * nothing; scene_check_fit says why a placement would not fit. */
static void test_boxes_stay_finite_and_fit(void **state)
{
    (void)state;
    scene *s = scene_create(WMIN, WMAX);
    add(s, 1, 0);
    const scene_object *o = scene_get(s, 1);
    scene_box before = o->world[0];
    uint32_t rev = o->rev;
    proto_transform huge = {.pos = {0, 0, 0}, .scale = 2e38f}; /* 3 m tall: 6e38, past FLT_MAX */
    assert_int_equal(scene_place(s, 1, &huge), -22); /* EINVAL */
    assert_int_equal(memcmp(&o->world[0], &before, sizeof before), 0);
    assert_int_equal(o->rev, rev);
    scene_box inf_box = {{0, 0, 0}, {1e38f, 1, 1}};
    scene_object_def d = {.id = 9, .owner = "ann", .name = "far", .at = {.scale = 1000}, .ecm_version = 1,
                          .box_count = 1, .boxes = &inf_box};
    assert_int_equal(scene_add(s, &d), -22);
    assert_null(scene_get(s, 9));
    assert_int_equal(scene_set_ecm(s, 1, 2, &inf_box, 1), 0); /* finite at scale 1 */
    assert_int_equal(scene_place(s, 1, &(proto_transform){.scale = 10}), -22);

    scene_limits lim = {{-50, -10, -50}, {50, 10, 50}, 20};
    scene_box desk = {{-1, 0, -0.5f}, {1, 1, 0.5f}};
    char why[160];
    assert_int_equal(scene_check_fit(&desk, 1, &(proto_transform){.pos = {10, 0, 0}, .scale = 1}, &lim, why,
                                     sizeof why), 0);
    assert_int_equal(scene_check_fit(&desk, 1, &(proto_transform){.scale = 1000}, &lim, why, sizeof why), -22);
    assert_non_null(strstr(why, "long along x"));
    assert_int_equal(scene_check_fit(&desk, 1, &(proto_transform){.pos = {49.5f, 0, 0}, .scale = 1}, &lim, why,
                                     sizeof why), -22);
    assert_non_null(strstr(why, "past the world"));
    assert_int_equal(scene_check_fit(&inf_box, 1, &(proto_transform){.scale = 10}, &lim, why, sizeof why), -22);
    assert_non_null(strstr(why, "would not be finite"));
    scene_destroy(s);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_lookup_in_any_order),
        cmocka_unit_test(test_transforms_round_trip),
        cmocka_unit_test(test_world_boxes_follow_placement),
        cmocka_unit_test(test_objects_by_slot_and_area),
        cmocka_unit_test(test_boxes_stay_finite_and_fit),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
