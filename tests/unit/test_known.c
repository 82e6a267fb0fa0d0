/* client/known.c: the objects a client knows, their bounds, and the
 * surface a dropped box lands on. */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>
#include <errno.h>
#include <string.h>

#include "known.h"
#include "le.h"

/* An OBJECT_INFO as decoded: its boxes in wire form (PROTOCOL.md 6.17). */
typedef struct info {
    proto_object_info o;
    uint8_t boxes[4 * 24];
} info;

static void make(info *in, uint32_t id, const float (*boxes)[6], uint16_t n)
{
    in->o = (proto_object_info){.object_id = id, .at = {.yaw = 0.5f, .scale = 2.0f}, .ecm_version = 1,
                                .box_count = n, .boxes = in->boxes};
    for (uint16_t b = 0; b < n; b++)
        for (int k = 0; k < 6; k++)
            le_put_f32(in->boxes + 24 * b + 4 * k, boxes[b][k]);
}

static void bounds_and_table(void **state)
{
    (void)state;
    known *k = known_create();
    static const float two[2][6] = {{0, 0, 0, 1, 1, 1}, {-2, 0.5f, 3, -1, 4, 5}};
    info in;
    make(&in, 7, two, 2);
    float lo[3], hi[3];
    assert_int_equal(known_bounds(&in.o, lo, hi), 0);
    assert_true(lo[0] == -2 && lo[1] == 0 && lo[2] == 0 && hi[0] == 1 && hi[1] == 4 && hi[2] == 5);
    make(&in, 8, two, 0);
    assert_int_equal(known_bounds(&in.o, lo, hi), -ENOENT);

    make(&in, 7, two, 2);
    in.o.tri_count = 12;
    memset(in.o.mesh_hash, 0xa7, sizeof in.o.mesh_hash);
    known_put(k, &in.o);
    make(&in, 3, two, 1);
    known_put(k, &in.o);
    const known_object *e = known_get(k, 7);
    assert_non_null(e);
    assert_int_equal(e->n_boxes, 2);
    assert_true(e->yaw == 0.5f && e->scale == 2.0f && e->boxes[1][4] == 4.0f);
    /* what a fetch asks for */
    assert_int_equal(e->tri_count, 12);
    for (unsigned i = 0; i < PROTO_MESH_HASH_SIZE; i++)
        assert_int_equal(e->mesh_hash[i], 0xa7);
    /* A second OBJECT_INFO replaces the first, with fewer boxes too. */
    make(&in, 7, two + 1, 1);
    known_put(k, &in.o);
    e = known_get(k, 7);
    assert_int_equal(e->n_boxes, 1);
    assert_true(e->boxes[0][0] == -2.0f);
    known_del(k, 7);
    assert_null(known_get(k, 7));
    assert_non_null(known_get(k, 3));
    known_del(k, 99); /* unknown: nothing */
    known_free(k);
}

static void surface_below(void **state)
{
    (void)state;
    known *k = known_create();
    /* A table top (0.8 m) on a leg, a shelf above it (2 m), and beside
     * them a crate (0.5 m) whose footprint only touches x = 1. */
    static const float table[3][6] = {{0, 0.7f, 0, 1, 0.8f, 1}, {0.4f, 0, 0.4f, 0.6f, 0.7f, 0.6f}, {0, 2, 0, 1, 2.1f, 1}};
    static const float crate[1][6] = {{1, 0, 0, 2, 0.5f, 1}};
    info in;
    make(&in, 1, table, 3);
    known_put(k, &in.o);
    make(&in, 2, crate, 1);
    known_put(k, &in.o);
    float lo[3] = {0.2f, 1.5f, 0.2f}, hi[3] = {0.8f, 1.9f, 0.8f};
    /* From 1.5 m: the table top, not the shelf above nor the leg under it. */
    assert_true(known_surface_below(k, 0, lo, hi, 0.0f) == 0.8f);
    /* Its own boxes do not hold it up. */
    assert_true(known_surface_below(k, 1, lo, hi, 0.0f) == 0.0f);
    /* From 3 m: the shelf. */
    lo[1] = 3.0f;
    assert_true(known_surface_below(k, 0, lo, hi, 0.0f) == 2.1f);
    /* Put a centimetre too low on the table top: still the table. */
    lo[1] = 0.79f;
    assert_true(known_surface_below(k, 0, lo, hi, 0.0f) == 0.8f);
    /* Under the table top (0.5 m), beside the leg: the floor. */
    lo[1] = 0.5f;
    assert_true(known_surface_below(k, 0, lo, hi, -1.0f) == -1.0f);
    /* A footprint that only touches the crate's edge at x = 1. */
    float lo2[3] = {2.0f, 1.0f, 0.0f}, hi2[3] = {3.0f, 2.0f, 1.0f};
    assert_true(known_surface_below(k, 0, lo2, hi2, 0.0f) == 0.0f);
    lo2[0] = 1.9f;
    assert_true(known_surface_below(k, 0, lo2, hi2, 0.0f) == 0.5f);
    /* A floor above every top wins. */
    assert_true(known_surface_below(k, 0, lo2, hi2, 3.0f) == 3.0f);
    known_free(k);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(bounds_and_table),
        cmocka_unit_test(surface_below),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
