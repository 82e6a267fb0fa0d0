/* A second candidate from the judge's own trials (second.h): a first map at
 * the cap that opens one doorway and leaves the one behind it shut gets a
 * second that opens both with boxes joined where nobody stood; nothing is
 * tried below the cap or for a map that is not better. */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>
#include <string.h>

#include "boxes.h"
#include "second.h"

/* Wall A (z 0..0.2) with a doorway at x 2.5..3.5, wall B (z 2..2.2) with
 * one right behind it, both 6 m wide, 3 m high, doorways 2.2 m high; three
 * crates of 0.5 m far off (x 20..22.5). Solid parts as boxes. */
#define PARTS 9
static const float part[PARTS][6] = {
    {0, 0, 0, 2.5f, 3, 0.2f},        {3.5f, 0, 0, 6, 3, 0.2f},        {2.5f, 2.2f, 0, 3.5f, 3, 0.2f},
    {0, 0, 2, 2.5f, 3, 2.2f},        {3.5f, 0, 2, 6, 3, 2.2f},        {2.5f, 2.2f, 2, 3.5f, 3, 2.2f},
    {20, 0, 0, 20.5f, 0.5f, 0.5f}, {21, 0, 0, 21.5f, 0.5f, 0.5f}, {22, 0, 0, 22.5f, 0.5f, 0.5f}};
/* The map in force: the walls' bounding box and a box per crate. */
static const float old_map[4][6] = {
    {0, 0, 0, 6, 3, 2.2f}, {20, 0, 0, 20.5f, 0.5f, 0.5f}, {21, 0, 0, 21.5f, 0.5f, 0.5f}, {22, 0, 0, 22.5f, 0.5f, 0.5f}};

/* Whether each solid part lies in the union of the boxes: every point of a
 * 5^3 lattice over it in some box. */
static int covered(const float (*b)[6], uint32_t n)
{
    for (int k = 0; k < PARTS; k++)
        for (int i = 0; i < 125; i++) {
            float q[3];
            for (int a = 0, d = i; a < 3; a++, d /= 5)
                q[a] = part[k][a] + (part[k][3 + a] - part[k][a]) * (float)(d % 5) / 4;
            int in = 0;
            for (uint32_t j = 0; j < n && !in; j++)
                in = q[0] >= b[j][0] && q[0] <= b[j][3] && q[1] >= b[j][1] && q[1] <= b[j][4] && q[2] >= b[j][2] &&
                     q[2] <= b[j][5];
            if (!in)
                return 0;
        }
    return 1;
}

/* An avatar standing in doorway A (z 0.1) or B (z 2.1). */
static const float door_a[2][3] = {{2.7f, 0, -0.2f}, {3.3f, 1.8f, 0.4f}};
static const float door_b[2][3] = {{2.7f, 0, 1.8f}, {3.3f, 1.8f, 2.4f}};

typedef struct scene {
    float tris[PARTS * 12 * 9];
    trimesh mesh;
    judge_sample s[16];
    ecm_stood stood[16];
    ecm_cluster cl;
    ecm_params p;
    judge_input in;
} scene;

/* Users stopped at the bounding box's face in front of doorway A, walking
 * in; their cluster, and the refinement's parameters with max_boxes. */
static void scene_init(scene *sc, uint32_t max_boxes)
{
    char err[128] = "";
    for (int k = 0; k < PARTS; k++)
        box_surface(part[k], part[k] + 3, sc->tris + 12 * 9 * k);
    assert_int_equal(trimesh_init(&sc->mesh, sc->tris, PARTS * 12, err, sizeof err), 0);
    for (int i = 0; i < 16; i++) {
        float x = 2.85f + 0.02f * (float)i;
        sc->s[i] = (judge_sample){.pos = {x, 0, -0.301f}, .vel = {0, 0, 1.5f}};
        sc->stood[i] = (ecm_stood){.box = {x - 0.3f, 0, -0.601f, x + 0.3f, 1.8f, -0.001f}, .hit = 0, .weight = 1};
    }
    sc->cl = (ecm_cluster){.box = 0, .min = {2.85f, 0.9f, 0}, .max = {3.15f, 0.9f, 0}, .centroid = {3, 0.9f, 0},
                           .weight = 16};
    ecm_params_default(&sc->p);
    sc->p.max_boxes = max_boxes;
    sc->p.floor = 0;
    sc->p.stood = sc->stood;
    sc->p.nstood = 16;
    sc->in = (judge_input){.mesh = &sc->mesh, .scale = 1, .pose_y = 0, .old_boxes = old_map, .nold = 4,
                           .samples = sc->s, .nsamples = 16};
}

/* The first candidate, judged: *j open on it (the caller closes it). */
static void first_candidate(scene *sc, ecm_result *r, judge **j, judge_result *jr)
{
    char err[128] = "";
    assert_int_equal(ecm_refine_mesh(&sc->p, &sc->mesh, old_map, 4, &sc->cl, 1, r, err, sizeof err), 0);
    judge_params jp;
    judge_params_default(&jp);
    judge_result old;
    assert_int_equal(judge_open(j, &jp, &sc->in, &old, err, sizeof err), 0);
    assert_int_equal(judge_new(*j, (const float(*)[6])r->boxes, r->count, jr, err, sizeof err), 0);
}

/* At a cap of 7, the first map opens doorway A and leaves wall B one box:
 * the trials, walking on through A, are held at doorway B. The second joins
 * the crates (nobody stood there) and opens B: fewer phantom blocks, no
 * more boxes, every wall still covered, the users' places free. */
static void test_second_opens_what_the_trials_met(void **state)
{
    (void)state;
    static scene sc;
    scene_init(&sc, 7);
    ecm_result r;
    judge *j;
    judge_result jr;
    first_candidate(&sc, &r, &j, &jr);
    const float(*b)[6] = (const float(*)[6])r.boxes;
    assert_int_equal(r.count, 7);
    assert_true(jr.better);
    assert_true(jr.phantom_new >= JUDGE_GAIN_MIN);
    assert_false(blocked(b, r.count, door_a[0], door_a[1]));
    assert_true(blocked(b, r.count, door_b[0], door_b[1]));
    const uint64_t first = jr.phantom_new;
    const double voxel_ms = r.voxel_ms;
    ecm_second out;
    char err[128] = "";
    assert_int_equal(ecm_second_candidate(&sc.p, &sc.mesh, j, 1.0, &r, &jr, &out, err, sizeof err), 0);
    b = (const float(*)[6])r.boxes;
    assert_true(out.kept);
    assert_true(out.places > 0);
    assert_int_equal(out.first_count, 7);
    assert_int_equal(out.first_phantom, first);
    assert_true(jr.phantom_new + JUDGE_GAIN_MIN <= first && jr.better);
    assert_int_equal(jr.opened_new, 0);
    assert_true(r.count <= 7);
    assert_false(blocked(b, r.count, door_a[0], door_a[1]));
    assert_false(blocked(b, r.count, door_b[0], door_b[1]));
    assert_true(covered(b, r.count));
    for (int i = 0; i < 16; i++)
        assert_false(blocked(b, r.count, sc.stood[i].box, sc.stood[i].box + 3));
    assert_true(r.voxel_ms >= voxel_ms && jr.ms >= 1.0); /* both refinements, all walks */
    judge_close(j);
    ecm_result_free(&r);
    trimesh_free(&sc.mesh);
}

/* Room for both doorways (a cap of 8): the first opens them, its trials
 * meet nothing, no second. A first that is not better gets none either,
 * and either way the first stays as it was. */
static void test_nothing_to_try(void **state)
{
    (void)state;
    static scene sc;
    for (int k = 0; k < 2; k++) {
        scene_init(&sc, k ? 7 : 8);
        ecm_result r;
        judge *j;
        judge_result jr;
        first_candidate(&sc, &r, &j, &jr);
        if (k)
            jr.better = 0;
        else
            assert_true(jr.better && jr.phantom_new == 0);
        float keep[8][6];
        uint32_t n = r.count;
        assert_true(n <= 8);
        memcpy(keep, r.boxes, n * sizeof keep[0]);
        ecm_second out;
        char err[128] = "";
        assert_int_equal(ecm_second_candidate(&sc.p, &sc.mesh, j, 0, &r, &jr, &out, err, sizeof err), 0);
        assert_false(out.kept);
        assert_int_equal(r.count, n);
        assert_memory_equal(r.boxes, keep, n * sizeof keep[0]);
        judge_close(j);
        ecm_result_free(&r);
        trimesh_free(&sc.mesh);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_second_opens_what_the_trials_met),
        cmocka_unit_test(test_nothing_to_try),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
