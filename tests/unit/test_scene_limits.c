/*
 * The scene when memory runs out, at every allocation in turn: creating
 * it, adding an object and swapping in a new collision map each either
 * succeed or fail with -ENOMEM leaving the scene as it was (its objects,
 * their boxes, and what the broadphases find); and the calls that name an
 * object the scene does not have, or boxes it cannot take.
 */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <cmocka.h>

#include "alloc.h"
#include "scene.h"

static const float WMIN[3] = {-500, 0, -500}, WMAX[3] = {500, 256, 500};
static const float tri[9] = {-1, 0, -2, 1, 0, 2, 1, 3, 2};

static scene_object_def def(uint32_t id, float x, const scene_box *boxes, uint32_t n)
{
    return (scene_object_def){.id = id, .owner = "ann", .name = "o", .at = {.pos = {x, 0, 0}, .scale = 1},
                              .ecm_version = 1, .tri_count = 1, .tris = tri, .box_count = n, .boxes = boxes};
}

/* What the scene shows of itself: objects, box handles near each, and
 * objects in a wide area; equal before and after a failed call. */
typedef struct view {
    uint32_t count, boxes_near[8], objects;
} view;

static view look(const scene *s)
{
    view v = {.count = scene_count(s)};
    uint32_t out[64];
    for (uint32_t i = 0; i < 8; i++) {
        float lo[3] = {(float)i * 20 - 5, 0, -5}, hi[3] = {(float)i * 20 + 5, 10, 5};
        v.boxes_near[i] = scene_query(s, lo, hi, out, 64);
    }
    float lo[3] = {-500, 0, -500}, hi[3] = {500, 256, 500};
    v.objects = scene_query_objects(s, lo, hi, out, 64);
    return v;
}

static void test_create_out_of_memory(void **state)
{
    scene *s = NULL;
    long n;

    (void)state;
    for (n = 0; !s; n++) {
        cvre_alloc_fail_after(n);
        s = scene_create(WMIN, WMAX);
        cvre_alloc_fail_after(-1);
        assert_true(n < 100);
    }
    assert_true(n > 1); /* the scene and its broadphases failed in turn */
    scene_destroy(s);
    scene_destroy(NULL);
}

static void test_add_out_of_memory(void **state)
{
    scene_box boxes[3] = {{{-1, 0, -1}, {1, 1, 1}}, {{-1, 1, -1}, {1, 2, 1}}, {{-1, 2, -1}, {1, 3, 1}}};
    scene *s = scene_create(WMIN, WMAX);

    (void)state;
    /* the 65th object grows the object and slot tables, the 86th the box
     * handles (past 256): each of those adds is swept over its allocations */
    for (uint32_t id = 1; id <= 90; id++) {
        scene_object_def d = def(id, (float)((id - 1) % 8) * 20, boxes, 3);
        if (id != 65 && id != 86) {
            assert_int_equal(scene_add(s, &d), 0);
            continue;
        }
        view before = look(s);
        int rc = -ENOMEM;
        for (long n = 0; rc == -ENOMEM; n++) {
            cvre_alloc_fail_after(n);
            rc = scene_add(s, &d);
            cvre_alloc_fail_after(-1);
            if (rc == -ENOMEM) {
                view after = look(s);
                assert_memory_equal(&after, &before, sizeof after);
                assert_null(scene_get(s, id));
            }
        }
        assert_int_equal(rc, 0);
        assert_non_null(scene_get(s, id));
        assert_int_equal(scene_count(s), before.count + 1);
    }
    scene_destroy(s);
}

static void test_set_ecm_out_of_memory(void **state)
{
    scene_box one = {{-1, 0, -1}, {1, 3, 1}};
    scene_box many[PROTO_OBJECT_BOXES_MAX];
    scene *s = scene_create(WMIN, WMAX);

    (void)state;
    for (uint32_t i = 0; i < PROTO_OBJECT_BOXES_MAX; i++)
        many[i] = (scene_box){{-1, (float)i * 0.01f, -1}, {1, (float)i * 0.01f + 0.01f, 1}};
    scene_object_def d = def(1, 0, &one, 1);
    assert_int_equal(scene_add(s, &d), 0);
    view before = look(s);
    int rc = -ENOMEM;
    for (long n = 0; rc == -ENOMEM; n++) {
        cvre_alloc_fail_after(n);
        rc = scene_set_ecm(s, 1, 2, many, PROTO_OBJECT_BOXES_MAX);
        cvre_alloc_fail_after(-1);
        if (rc == -ENOMEM) { /* the old map stands, filed as before */
            view after = look(s);
            assert_memory_equal(&after, &before, sizeof after);
            assert_int_equal(scene_get(s, 1)->ecm_version, 1);
            assert_int_equal(scene_get(s, 1)->box_count, 1);
        }
    }
    assert_int_equal(rc, 0);
    assert_int_equal(scene_get(s, 1)->ecm_version, 2);
    assert_int_equal(scene_get(s, 1)->box_count, PROTO_OBJECT_BOXES_MAX);
    scene_destroy(s);
}

static void test_refusals(void **state)
{
    scene_box one = {{-1, 0, -1}, {1, 3, 1}}, huge = {{-1, 0, -1}, {1, 3e38f, 1}};
    proto_transform at = {.pos = {1, 0, 1}, .scale = 1};
    scene *s = scene_create(WMIN, WMAX);

    (void)state;
    scene_object_def d = def(1, 0, &one, 1);
    assert_int_equal(scene_add(s, &d), 0);
    assert_int_equal(scene_place(s, 9, &at), -ENOENT);
    assert_int_equal(scene_set_owner(s, 9, "bob"), -ENOENT);
    assert_int_equal(scene_set_ecm(s, 9, 2, &one, 1), -ENOENT);
    assert_int_equal(scene_set_ecm(s, 1, 2, &one, 0), -EINVAL);
    assert_int_equal(scene_set_ecm(s, 1, 2, &one, PROTO_OBJECT_BOXES_MAX + 1), -EINVAL);
    assert_int_equal(scene_set_owner(s, 1, "bob"), 0);
    assert_string_equal(scene_get(s, 1)->owner, "bob");
    at.scale = 1000; /* 3e38 m tall at a thousand times: not finite */
    d = def(2, 0, &huge, 1);
    d.at.scale = 1000;
    assert_int_equal(scene_add(s, &d), -EINVAL);
    assert_int_equal(scene_set_ecm(s, 1, 2, &huge, 1), 0); /* finite where it stands */
    assert_int_equal(scene_place(s, 1, &at), -EINVAL);
    assert_true(scene_get(s, 1)->at.scale == 1.0f); /* left where it was */
    assert_null(scene_at_slot(s, 99));
    scene_destroy(s);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_create_out_of_memory),
        cmocka_unit_test(test_add_out_of_memory),
        cmocka_unit_test(test_set_ecm_out_of_memory),
        cmocka_unit_test(test_refusals),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
