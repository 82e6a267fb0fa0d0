/*
 * test_world_place.c: where the world puts an avatar (server/world.c). A
 * new one (world_add): on a model's floor that lies a few millimetres above
 * the world's, stood on it where it spawns, and it walks there with no
 * inside collision; out of the way of a tall object; inside only when
 * nothing around is free. One that a new collision map encloses
 * (world_push_out): out of the new boxes, unless the old map held it
 * already or no place near is free.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "world.h"

static const world_config CFG = {.min = {-50, 0, -50}, .max = {50, 20, 50}, .max_speed = 5, .aoi_radius = 10,
                                 .spawn_radius = 1, .tick_dt = 0.05f, .capacity = 4, .seed = 1};
static const float AV[3] = {0.6f, 1.8f, 0.6f};

/* A scene with one object of one box, [lo, hi] in world coordinates. */
static scene *one_box(const float lo[3], const float hi[3])
{
    scene *sc = scene_create(CFG.min, CFG.max);
    assert_non_null(sc);
    scene_box b = {{lo[0], lo[1], lo[2]}, {hi[0], hi[1], hi[2]}};
    float tri[9] = {lo[0], lo[1], lo[2], hi[0], hi[1], hi[2], hi[0], lo[1], hi[2]};
    scene_object_def d = {.id = 1, .owner = "ann", .name = "o", .at = {.scale = 1}, .ecm_version = 1,
                          .tri_count = 1, .tris = tri, .box_count = 1, .boxes = &b};
    assert_int_equal(scene_add(sc, &d), 0);
    return sc;
}

static void count(void *ctx, const world_avatar *a, const move_contact *c, const float vel[3])
{
    (void)a;
    (void)vel;
    int *n = ctx;
    n[0]++;
    n[1] += c->inside;
}

/* A world and its scene of one box [lo, hi], and an avatar added to them,
 * which must have been crowded (or not) as said. */
static const world_avatar *spawn(const float lo[3], const float hi[3], int crowded_expected, world **w, scene **sc)
{
    *sc = one_box(lo, hi);
    *w = world_create(&CFG);
    assert_non_null(*w);
    int crowded = -1;
    const world_avatar *a = world_add(*w, *sc, "ann", 3, AV, &crowded);
    assert_non_null(a);
    assert_int_equal(crowded, crowded_expected);
    return a;
}

/* One step of the world with a walking 0.2 m along x; counts its contacts
 * (all, inside) into contacts. */
static void walk(world *w, scene *sc, const world_avatar *a, uint32_t seq, int contacts[2])
{
    const float to[3] = {a->pos[0] + 0.2f, 0, a->pos[2]};
    world_request_move(w, a->id, seq, to);
    world_step(w, sc, count, contacts);
}

static void test_stood_on_a_thin_floor(void **state)
{
    (void)state;
    const float lo[3] = {-40, -0.5f, -40}, hi[3] = {40, 0.004f, 40};
    world *w;
    scene *sc;
    const world_avatar *a = spawn(lo, hi, 0, &w, &sc);
    /* Where it spawned, not searched away from the floor. */
    assert_true(a->pos[0] * a->pos[0] + a->pos[2] * a->pos[2] <= 1.0f);
    assert_true(a->pos[1] == 0.004f && a->grounded);
    int contacts[2] = {0, 0};
    for (uint32_t k = 1; k <= 40; k++) {
        walk(w, sc, a, k, contacts);
        assert_true(a->pos[1] == 0.004f && a->grounded);
    }
    assert_int_equal(contacts[0], 0);
    world_destroy(w);
    scene_destroy(sc);
}

static void test_tall_object_searched_around(void **state)
{
    (void)state;
    const float lo[3] = {-3, 0, -3}, hi[3] = {3, 0.5f, 3};
    world *w;
    scene *sc;
    const world_avatar *a = spawn(lo, hi, 0, &w, &sc);
    /* Higher than a step: not stood on, but beside it, on the floor. */
    assert_true(a->pos[1] == 0);
    assert_true(a->pos[0] - 0.3f >= 3 || a->pos[0] + 0.3f <= -3 || a->pos[2] - 0.3f >= 3 || a->pos[2] + 0.3f <= -3);
    world_destroy(w);
    scene_destroy(sc);
}

static void test_crowded_when_nothing_free(void **state)
{
    (void)state;
    /* Covers the whole world: nowhere to stand, the avatar starts inside,
     * and its moves are inside collisions. */
    const float lo[3] = {-50, 0, -50}, hi[3] = {50, 3, 50};
    world *w;
    scene *sc;
    const world_avatar *a = spawn(lo, hi, 1, &w, &sc);
    int contacts[2] = {0, 0};
    walk(w, sc, a, 1, contacts);
    assert_int_equal(contacts[0], 1);
    assert_int_equal(contacts[1], 1);
    world_destroy(w);
    scene_destroy(sc);
}

/* The box an avatar of size AV at p fills overlaps box b. */
static int overlaps(const float p[3], const scene_box *b)
{
    const float lo[3] = {p[0] - AV[0] / 2, p[1], p[2] - AV[2] / 2}, hi[3] = {p[0] + AV[0] / 2, p[1] + AV[1], p[2] + AV[2] / 2};
    return b->min[0] < hi[0] && lo[0] < b->max[0] && b->min[1] < hi[1] && lo[1] < b->max[1] && b->min[2] < hi[2] &&
           lo[2] < b->max[2];
}

/* An avatar spawned beside the box [lo, hi] that walked `steps` steps
 * along x (contacts counted into contacts). */
static const world_avatar *walked(const float lo[3], const float hi[3], uint32_t steps, world **w, scene **sc,
                                  int contacts[2])
{
    const world_avatar *a = spawn(lo, hi, 0, w, sc);
    for (uint32_t k = 1; k <= steps; k++)
        walk(*w, *sc, a, k, contacts);
    return a;
}

/* Puts object 1's map version v of one box [x0, 3] x [0, 3] x [-2, 2] in
 * force and pushes avatars out of it; old: the map before. */
static uint32_t new_map(world *w, scene *sc, uint32_t v, float x0, const scene_box *old, uint32_t *stuck)
{
    const scene_box b = {{x0, 0, -2}, {3, 3, 2}};
    assert_int_equal(scene_set_ecm(sc, 1, v, &b, 1), 0);
    return world_push_out(w, sc, 1, old, 1, stuck);
}

static void test_pushed_out_of_a_new_map(void **state)
{
    (void)state;
    const float lo[3] = {1, 0, -2}, hi[3] = {3, 3, 2};
    world *w;
    scene *sc;
    int contacts[2] = {0, 0};
    /* Walks into the wall's face and stops there. */
    const world_avatar *a = walked(lo, hi, 60, &w, &sc, contacts);
    assert_true(contacts[0] > 0 && contacts[1] == 0);
    assert_float_equal(a->pos[0], 1 - 0.3f - (float)MOVE_SKIN, 1e-5);
    /* v2 reaches 2 cm past the old face: pushed back out of it. */
    const scene_box v1 = {{1, 0, -2}, {3, 3, 2}};
    uint32_t stuck = 9;
    assert_int_equal(new_map(w, sc, 2, 0.98f, &v1, &stuck), 1);
    assert_int_equal(stuck, 0);
    assert_float_equal(a->pos[0], 0.98f - 0.3f - (float)MOVE_SKIN, 1e-5);
    /* Its viewers hear of it with the next step (this one's update went
     * out before the map came in force). */
    assert_int_equal(a->changed_tick, world_tick(w) + 1);
    const scene_box v2 = scene_get(sc, 1)->world[0];
    assert_false(overlaps(a->pos, &v2));
    walk(w, sc, a, 61, contacts);
    assert_int_equal(contacts[1], 0);
    /* v3 encloses it whole: no place near is free, left inside. */
    const float at[3] = {a->pos[0], a->pos[1], a->pos[2]};
    assert_int_equal(new_map(w, sc, 3, -2, &v2, &stuck), 0);
    assert_int_equal(stuck, 1);
    assert_true(a->pos[0] == at[0] && a->pos[1] == at[1] && a->pos[2] == at[2]);
    /* v4 still overlaps it, but v3 held it already (an object placed
     * around it): not moved. */
    const scene_box v3 = scene_get(sc, 1)->world[0];
    assert_int_equal(new_map(w, sc, 4, 0.6f, &v3, &stuck), 0);
    assert_int_equal(stuck, 0);
    assert_true(a->pos[0] == at[0] && a->pos[1] == at[1] && a->pos[2] == at[2]);
    world_destroy(w);
    scene_destroy(sc);
}

/* At the world's edge: the only place near is outside the world, so the
 * avatar is left inside the new box, not pushed out of the world. */
static void test_never_pushed_out_of_the_world(void **state)
{
    (void)state;
    const float lo[3] = {-40, 0, 30}, hi[3] = {-39, 1, 31};
    world *w;
    scene *sc;
    int contacts[2] = {0, 0};
    const world_avatar *a = walked(lo, hi, 300, &w, &sc, contacts);
    assert_float_equal(a->pos[0], CFG.max[0] - 0.3f, 1e-5);
    /* A thin wall 2 cm into its box on the inner side. */
    const scene_box old = {{-40, 0, 30}, {-39, 1, 31}};
    const scene_box b = {{CFG.max[0] - 0.62f, 0, -50}, {CFG.max[0] - 0.58f, 3, 50}};
    assert_int_equal(scene_set_ecm(sc, 1, 2, &b, 1), 0);
    const float at[3] = {a->pos[0], a->pos[1], a->pos[2]};
    uint32_t stuck = 0;
    assert_int_equal(world_push_out(w, sc, 1, &old, 1, &stuck), 0);
    assert_int_equal(stuck, 1);
    assert_true(a->pos[0] == at[0] && a->pos[1] == at[1] && a->pos[2] == at[2]);
    world_destroy(w);
    scene_destroy(sc);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_stood_on_a_thin_floor),
        cmocka_unit_test(test_tall_object_searched_around),
        cmocka_unit_test(test_crowded_when_nothing_free),
        cmocka_unit_test(test_pushed_out_of_a_new_map),
        cmocka_unit_test(test_never_pushed_out_of_the_world),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
