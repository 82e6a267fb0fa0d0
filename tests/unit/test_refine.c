/*
 * One refinement round (algo/refine/refine.h): the invariant (the boxes
 * contain every triangle) on hand-made, random and real geometry, openings
 * that open, walls that stay, the cap, determinism, bad input and running
 * out of memory.
 *
 * Usage: test_refine MODELS_DIR [--only PATTERN]... [--skip PATTERN]...
 * (MODELS_DIR: the shared/models folder). Every model file in its
 * openings/, classic/, formats/ and scenes/ folders becomes a test of its
 * own (test_model_invariant), named after the file; ctest runs each model,
 * and the test_* cases, as entries of their own (tests/models.h).
 */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../models.h"
#include "alloc.h"
#include "boxes.h"
#include "refine.h"
#include "import.h"

static const char *models_dir;

#define NELEM(a) (sizeof(a) / sizeof((a)[0]))
/* A box array as ecm_refine and the helpers below take it. */
#define CBOXES(b) ((const float(*)[6])(b))

/* What check_result and friends name when they fail: the model, the seed. */
static char check_ctx[256];

#define CHECK(cond, ...)                                                                                          \
    do {                                                                                                          \
        if (!(cond)) {                                                                                            \
            print_error("%s: ", check_ctx);                                                                       \
            print_error(__VA_ARGS__);                                                                             \
            print_error("\n");                                                                                    \
            fail();                                                                                               \
        }                                                                                                         \
    } while (0)

/* ---- helpers ----------------------------------------------------------- */

static int in_box(const float b[6], const double p[3], double tol)
{
    for (int a = 0; a < 3; a++)
        if (p[a] < (double)b[a] - tol || p[a] > (double)b[3 + a] + tol)
            return 0;
    return 1;
}

/* Every sample of every triangle (vertices, points along the edges, an
 * interior lattice) lies in some box: the invariant, checked independently
 * of the voxelizer. tol absorbs float rounding of the samples only. Returns
 * the number of samples outside. */
static size_t uncovered(const float *tris, uint32_t ntris, const float (*boxes)[6], uint32_t nboxes, int steps)
{
    size_t bad = 0;
    uint32_t *cand = malloc((nboxes ? nboxes : 1) * sizeof *cand);
    assert_non_null(cand);
    for (uint32_t t = 0; t < ntris; t++) {
        const float *v = tris + 9 * (size_t)t;
        double lo[3], hi[3], ext = 0;
        for (int a = 0; a < 3; a++) {
            lo[a] = fmin(fmin(v[a], v[3 + a]), v[6 + a]);
            hi[a] = fmax(fmax(v[a], v[3 + a]), v[6 + a]);
            ext = fmax(ext, fmax(fabs(lo[a]), fabs(hi[a])));
        }
        double tol = 4e-7 * (ext + 1);
        uint32_t nc = 0;
        for (uint32_t b = 0; b < nboxes; b++) {
            int overlap = 1;
            for (int a = 0; a < 3; a++)
                overlap &= hi[a] >= (double)boxes[b][a] - tol && lo[a] <= (double)boxes[b][3 + a] + tol;
            if (overlap)
                cand[nc++] = b;
        }
        for (int i = 0; i <= steps; i++)
            for (int j = 0; i + j <= steps; j++) {
                double u = (double)i / steps, w = (double)j / steps, p[3];
                for (int a = 0; a < 3; a++)
                    p[a] = (1 - u - w) * v[a] + u * v[3 + a] + w * v[6 + a];
                int in = 0;
                for (uint32_t c = 0; c < nc && !in; c++)
                    in = in_box(boxes[cand[c]], p, tol);
                bad += !in;
            }
    }
    free(cand);
    return bad;
}

/* Whether box b is want, each side at most one float step further out
 * (boxes are tightened to their triangles, then rounded outwards). */
static int box_near(const float b[6], const float want[6])
{
    for (int a = 0; a < 3; a++)
        if (!(b[a] <= want[a] && b[a] >= nextafterf(want[a], -INFINITY) && b[3 + a] >= want[3 + a] &&
              b[3 + a] <= nextafterf(want[3 + a], INFINITY)))
            return 0;
    return 1;
}

static void mbr(const float *tris, uint32_t n, float box[6])
{
    for (int a = 0; a < 3; a++) {
        box[a] = INFINITY;
        box[3 + a] = -INFINITY;
    }
    for (size_t i = 0; i < (size_t)n * 3; i++)
        for (int a = 0; a < 3; a++) {
            box[a] = fminf(box[a], tris[3 * i + (size_t)a]);
            box[3 + a] = fmaxf(box[3 + a], tris[3 * i + (size_t)a]);
        }
}

/* A model under MODELS_DIR, or under tests/data/models (the project's own)
 * for a path starting with "data/". */
static import_mesh load(const char *rel, int z_up)
{
    char path[4096];
    if (strncmp(rel, "data/", 5) == 0)
        snprintf(path, sizeof path, "%s/%s", CVRE_DATA_MODELS_DIR, rel + 5);
    else
        snprintf(path, sizeof path, "%s/%s", models_dir, rel);
    FILE *f = fopen(path, "rb");
    if (!f)
        fail_msg("cannot open %s", path);
    fseek(f, 0, SEEK_END);
    long size = ftell(f);
    rewind(f);
    uint8_t *data = malloc((size_t)size);
    assert_non_null(data);
    assert_int_equal(fread(data, 1, (size_t)size, f), (size_t)size);
    fclose(f);
    import_options opt = IMPORT_OPTIONS_DEFAULT;
    opt.z_up = z_up;
    import_mesh m;
    char err[256];
    const char *ext = strrchr(rel, '.');
    if (import_model(data, (size_t)size, ext, &opt, &m, err, sizeof err) < 0)
        fail_msg("%s: %s", rel, err);
    free(data);
    return m;
}


/* Samples per triangle edge for uncovered(): fine on small models, coarse
 * on the big scenes (the city block has 400,020 triangles), so that the
 * whole file runs in seconds. */
static int sample_steps(uint32_t ntris)
{
    return ntris >= 200000 ? 2 : ntris >= 50000 ? 4 : ntris >= 5000 ? 8 : 16;
}

static int box_within(const float in[6], const float out[6])
{
    for (int a = 0; a < 3; a++)
        if (in[a] < out[a] || in[3 + a] > out[3 + a])
            return 0;
    return 1;
}

static double box_volume(const float b[6])
{
    return ((double)b[3] - b[0]) * ((double)b[4] - b[1]) * ((double)b[5] - b[2]);
}

/* A cluster on box `box`: its centroid c, its points c +- spread. */
static ecm_cluster cluster_at(uint32_t box, const float c[3], const float spread[3])
{
    ecm_cluster cl = {.box = box};
    for (int a = 0; a < 3; a++) {
        cl.centroid[a] = c[a];
        cl.min[a] = c[a] - spread[a];
        cl.max[a] = c[a] + spread[a];
    }
    return cl;
}

/* Seven one-point clusters on box b (index idx): the centre of each of its
 * faces (b[f] is the coordinate of face f: min x y z, max x y z) and its
 * min corner. */
static void face_clusters(const float b[6], uint32_t idx, ecm_cluster cl[7])
{
    static const float point[3] = {0, 0, 0};
    for (int f = 0; f < 6; f++) {
        float c[3];
        for (int a = 0; a < 3; a++)
            c[a] = (float)(((double)b[a] + b[3 + a]) / 2);
        c[f % 3] = b[f];
        cl[f] = cluster_at(idx, c, point);
    }
    cl[6] = cluster_at(idx, b, point);
}

/* *r as ecm_refine leaves it on failure: all zero. */
static void assert_result_empty(const ecm_result *r)
{
    assert_null(r->boxes);
    assert_int_equal(r->count, 0);
    assert_int_equal(r->problem_boxes, 0);
    assert_int_equal(r->capped, 0);
    assert_int_equal(r->cells, 0);
    assert_int_equal(r->occupied, 0);
    assert_int_equal(r->wanted, 0);
    assert_true(r->voxel_ms == 0 && r->divide_ms == 0);
}

static void assert_results_equal(const ecm_result *a, const ecm_result *b)
{
    assert_int_equal(a->count, b->count);
    assert_int_equal(a->problem_boxes, b->problem_boxes);
    assert_int_equal(a->capped, b->capped);
    assert_int_equal(a->cells, b->cells);
    assert_int_equal(a->occupied, b->occupied);
    assert_int_equal(a->wanted, b->wanted);
    assert_non_null(a->boxes);
    assert_non_null(b->boxes);
    assert_memory_equal(a->boxes, b->boxes, a->count * sizeof *a->boxes);
}

/*
 * Everything a successful ecm_refine promises, whatever the geometry:
 * problem_boxes counts the distinct boxes a cluster presses on (the one it
 * names, and every one its points' bounding box, grown by a hundredth of
 * the avatar's width and upwards by its height and a step, meets); the boxes
 * without a cluster come first, unchanged and in order; each box after them
 * is a proper, finite box inside the hull of the problem boxes; the count
 * respects the cap (max_boxes, or the boxes it had for an object whose
 * kept boxes already fill it); one grid, of at most 2^depth cells a side,
 * was examined a group of clusters (at most one a cluster); the statistics
 * add up (capped
 * counts some of the new boxes); and every triangle is still covered
 * (sampled `steps` times per edge).
 */
static void check_result(const ecm_params *p, const float *tris, uint32_t ntris, const float (*boxes)[6],
                         uint32_t nboxes, const ecm_cluster *cl, uint32_t ncl, const ecm_result *r, int steps)
{
    uint8_t *problem = calloc(nboxes, 1);
    assert_non_null(problem);
    uint32_t nproblem = 0;
    double tol = 0.01 * fmin(p->avatar[0], p->avatar[2]);
    for (uint32_t b = 0; b < nboxes; b++)
        for (uint32_t i = 0; i < ncl && !problem[b]; i++) {
            int meets = 1;
            for (int a = 0; a < 3; a++)
                meets &= (double)cl[i].max[a] + tol + (a == 1 ? (double)p->avatar[1] + p->step : 0) >= boxes[b][a] &&
                         (double)cl[i].min[a] - tol <= boxes[b][3 + a];
            if (cl[i].box == b || meets) {
                problem[b] = 1;
                nproblem++;
            }
        }
    uint32_t kept = nboxes - nproblem;
    uint32_t cap = p->max_boxes > kept + nproblem ? p->max_boxes : kept + nproblem;
    CHECK(r->problem_boxes == nproblem, "%u problem boxes, expected %u", r->problem_boxes, nproblem);
    CHECK(r->count >= kept && r->count <= cap, "%u boxes: not in %u..%u", r->count, kept, cap);
    CHECK(r->boxes != NULL, "no box array");
    const uint64_t grid = (uint64_t)1 << (3 * p->depth);
    const uint64_t least = (uint64_t)1 << (3 * ECM_DEPTH_MIN);
    CHECK(nproblem ? r->cells % least == 0 && r->cells >= least && r->cells <= ncl * grid : r->cells == 0,
          "%llu cells examined: not one grid a group of clusters", (unsigned long long)r->cells);
    CHECK(r->occupied <= r->cells && r->wanted <= r->cells - r->occupied, "%llu occupied, %llu wanted",
          (unsigned long long)r->occupied, (unsigned long long)r->wanted);
    CHECK(r->capped <= r->count - kept, "%u boxes capped of the %u new", r->capped, r->count - kept);

    uint32_t o = 0;
    for (uint32_t i = 0; i < nboxes; i++)
        if (!problem[i]) {
            CHECK(memcmp(r->boxes[o], boxes[i], sizeof boxes[i]) == 0, "kept box %u changed or moved", i);
            o++;
        }
    float hb[6] = {INFINITY, INFINITY, INFINITY, -INFINITY, -INFINITY, -INFINITY};
    for (uint32_t i = 0; i < nboxes; i++)
        for (int a = 0; a < 3 && problem[i]; a++) {
            hb[a] = fminf(hb[a], boxes[i][a]);
            hb[3 + a] = fmaxf(hb[3 + a], boxes[i][3 + a]);
        }
    for (uint32_t j = kept; j < r->count; j++) {
        const float *b = r->boxes[j];
        for (int a = 0; a < 3; a++)
            CHECK(isfinite(b[a]) && isfinite(b[3 + a]) && b[a] <= b[3 + a], "box %u is not a box", j);
        CHECK(box_within(b, hb), "box %u (%g %g %g .. %g %g %g) leaves the problem boxes' hull", j, (double)b[0],
              (double)b[1], (double)b[2], (double)b[3], (double)b[4], (double)b[5]);
    }
    size_t bad = uncovered(tris, ntris, CBOXES(r->boxes), r->count, steps);
    CHECK(bad == 0, "%zu triangle samples outside every box", bad);
    free(problem);
}

/* ecm_refine on model m must succeed, and its result hold every
 * invariant (check_result). */
static void refine_model(const ecm_params *p, const import_mesh *m, const float (*boxes)[6], uint32_t nboxes,
                         const ecm_cluster *cl, uint32_t ncl, ecm_result *r)
{
    char err[256];
    assert_int_equal(ecm_refine(p, m->tris, m->ntris, boxes, nboxes, cl, ncl, r, err, sizeof err), 0);
    check_result(p, m->tris, m->ntris, boxes, nboxes, cl, ncl, r, 16);
}

/* ---- the invariant on every model -------------------------------------- */

typedef struct vol_index {
    double v;
    uint32_t i;
} vol_index;

static int by_volume(const void *pa, const void *pb)
{
    const vol_index *a = pa, *b = pb;
    return a->v != b->v ? (a->v < b->v ? -1 : 1) : (a->i < b->i ? -1 : a->i > b->i);
}

/* The box of median volume: not the largest, unless it is the only one. */
static uint32_t median_box(const ecm_result *r)
{
    vol_index *v = malloc(r->count * sizeof *v);
    assert_non_null(v);
    for (uint32_t i = 0; i < r->count; i++)
        v[i] = (vol_index){box_volume(r->boxes[i]), i};
    qsort(v, r->count, sizeof *v, by_volume);
    uint32_t pick = v[(r->count - 1) / 2].i;
    free(v);
    return pick;
}

/*
 * One model (state: its path under MODELS_DIR). Round 1: one box, the MBR,
 * with users stopped at the centre of each of its six faces and at a corner.
 * Round 2: collisions against version 2 press on the face of a box of
 * median volume; its replacement must keep the invariant for the whole
 * object with the other boxes of version 2.
 */
static void test_model_invariant(void **state)
{
    const char *rel = *state, *base = strrchr(rel, '/');
    base = base ? base + 1 : rel;
    snprintf(check_ctx, sizeof check_ctx, "%s", rel);
    import_mesh m = load(rel, strncmp(base, "openfoam_", 9) == 0);
    int steps = sample_steps(m.ntris);
    float box[6];
    mbr(m.tris, m.ntris, box);
    assert_memory_equal(box, m.min, sizeof m.min);
    assert_memory_equal(box + 3, m.max, sizeof m.max);
    ecm_params p;
    ecm_params_default(&p);
    ecm_cluster cl[7];
    face_clusters(box, 0, cl);
    ecm_result r1, r2;
    char err[256];
    int rc = ecm_refine(&p, m.tris, m.ntris, CBOXES(box), 1, cl, 7, &r1, err, sizeof err);
    CHECK(rc == 0, "round 1: %s", err);
    check_result(&p, m.tris, m.ntris, CBOXES(box), 1, cl, 7, &r1, steps);
    assert_true(r1.count >= 1 && r1.count <= ECM_MAX_BOXES_DEFAULT);
    assert_int_equal(r1.problem_boxes, 1);

    uint32_t pick = median_box(&r1);
    const float *b = r1.boxes[pick];
    float c[3], spread[3];
    for (int a = 0; a < 3; a++) {
        c[a] = (float)(((double)b[a] + b[3 + a]) / 2);
        spread[a] = (b[3 + a] - b[a]) / 4;
    }
    c[0] = b[3]; /* on its max x face */
    spread[0] = 0;
    ecm_cluster c2 = cluster_at(pick, c, spread);
    snprintf(check_ctx, sizeof check_ctx, "%s round 2 (box %u of %u)", rel, pick, r1.count);
    rc = ecm_refine(&p, m.tris, m.ntris, CBOXES(r1.boxes), r1.count, &c2, 1, &r2, err, sizeof err);
    CHECK(rc == 0, "round 2: %s", err);
    check_result(&p, m.tris, m.ntris, CBOXES(r1.boxes), r1.count, &c2, 1, &r2, steps);
    assert_true(r2.count <= ECM_MAX_BOXES_DEFAULT);
    print_message("%-48s %6u tris: %2u boxes (capped %2u), box %2u -> %2u boxes\n", rel, m.ntris, r1.count,
                  r1.capped, pick, r2.count);
    ecm_result_free(&r2);
    ecm_result_free(&r1);
    import_mesh_free(&m);
}

/* ---- openings ---------------------------------------------------------- */

/* The room (Z-up file): walls at local x = -5.642 and 0.218, z = -4.435 and
 * 0.416, floor y = 0, ceiling y = 2.8; the door is in the x = 0.218 wall,
 * z from -2.349 to -1.581, y up to 2.1. Users stopped in front of the door
 * on the MBR's face make a cluster there. */
static import_mesh room_model(float box[6], ecm_params *p)
{
    snprintf(check_ctx, sizeof check_ctx, "room");
    import_mesh m = load("openings/openfoam_room_with_doorway.stl", 1);
    mbr(m.tris, m.ntris, box);
    ecm_params_default(p);
    return m;
}

static void test_room_door_opens_walls_stay(void **state)
{
    (void)state;
    float box[6];
    ecm_params p;
    import_mesh m = room_model(box, &p);
    /* As a live run made it: every user walked the same line. */
    ecm_cluster cl = {.box = 0, .min = {0.217568f, 0.9f, -1.965f}, .max = {0.217568f, 0.9f, -1.965f},
                      .centroid = {0.217568f, 0.9f, -1.965f}};
    ecm_result r;
    char err[256];
    assert_int_equal(ecm_refine(&p, m.tris, m.ntris, (const float(*)[6])box, 1, &cl, 1, &r, err, sizeof err), 0);
    assert_true(r.count > 1 && r.count <= p.max_boxes);
    assert_int_equal(r.problem_boxes, 1);
    assert_int_equal(uncovered(m.tris, m.ntris, (const float(*)[6])r.boxes, r.count, 16), 0);
    check_result(&p, m.tris, m.ntris, CBOXES(box), 1, &cl, 1, &r, 16);
    assert_int_equal(r.capped, 0);
    assert_true(r.wanted > 0);
    /* An avatar standing in the doorway, and one step further in, is free. */
    for (float x = -0.6f; x <= 0.6f; x += 0.2f) {
        float lo[3] = {x - 0.3f, 0.03f, -1.965f - 0.3f}, hi[3] = {x + 0.3f, 1.83f, -1.965f + 0.3f};
        assert_false(blocked((const float(*)[6])r.boxes, r.count, lo, hi));
    }
    /* The walls beside the door still block. */
    float wall_lo[3] = {-0.1f, 0.03f, -1.2f}, wall_hi[3] = {0.5f, 1.83f, -0.6f};
    assert_true(blocked((const float(*)[6])r.boxes, r.count, wall_lo, wall_hi));
    float back_lo[3] = {-5.9f, 0.03f, -2.2f}, back_hi[3] = {-5.3f, 1.83f, -1.6f};
    assert_true(blocked((const float(*)[6])r.boxes, r.count, back_lo, back_hi));
    ecm_result_free(&r);
    import_mesh_free(&m);
}

/*
 * Step 7 on the room, round 0's two clusters at seed 8 of the scenario
 * (users stopped on the front face and on the door's wall). The far wall
 * x = -5.642 got a box one cell thick, which also held the first cell of
 * both side walls that meet it: one split frees nothing (either side still
 * holds a side wall's end), so it stayed, 4.5 cm in front of the wall, and
 * a user who walked in and pushed the far wall was stopped there 31 moves
 * in a row. Both ends peeled off, the wall's box is the wall.
 */
static void test_room_far_wall_peeled(void **state)
{
    (void)state;
    float box[6];
    ecm_params p;
    import_mesh m = room_model(box, &p);
    const ecm_cluster cl[2] = {
        {.box = 0, .min = {-2.7173903f, 0.9f, -4.43519592f}, .max = {-2.7173903f, 0.9f, -4.43519592f},
         .centroid = {-2.7173903f, 0.9f, -4.43519592f}, .weight = 867},
        {.box = 0, .min = {0.217567921f, 0.9f, -4.2198534f}, .max = {0.217567921f, 0.9f, -0.939493179f},
         .centroid = {0.217567921f, 0.9f, -2.07959032f}, .weight = 1636}};
    ecm_result r;
    refine_model(&p, &m, CBOXES(box), 1, cl, 2, &r);
    /* An avatar 5 mm from the far wall, where the user was: free. */
    const float lo[3] = {-5.637f, 0.03f, -2.0f}, hi[3] = {-5.037f, 1.83f, -1.4f};
    CHECK(!blocked(CBOXES(r.boxes), r.count, lo, hi), "the far wall's box stands in front of it");
    ecm_result_free(&r);
    import_mesh_free(&m);
}

/*
 * The archway (Y-up): a stone wall, MBR x -0.5..0.5, y -0.05..0.95, z
 * 0.3315..0.5, its back face flat at z = 0.5. The opening goes through z:
 * with no floor, open from y = -0.05 up to about 0.35 over x -0.3..0.3 and
 * up to about 0.45 over x -0.15..0.15; pillars on both sides (|x| > 0.34),
 * a lintel above (solid at x = 0 from y = 0.73). The archway is imagined
 * scaled 4x in the world, so the 0.6 x 1.8 x 0.6 m avatar is 0.15 x 0.45 x
 * 0.15 in local units. Users stopped on the back face, in front of the
 * opening.
 */
/* Model rel (Y up), its bounding box as its one box, and the default
 * parameters for it scaled `scale` times in the world (the avatar and its
 * step in local units). */
static import_mesh scaled_model(const char *rel, float scale, float box[6], ecm_params *p)
{
    snprintf(check_ctx, sizeof check_ctx, "%s", rel);
    import_mesh m = load(rel, 0);
    mbr(m.tris, m.ntris, box);
    ecm_params_default(p);
    for (int a = 0; a < 3; a++)
        p->avatar[a] /= scale;
    p->step /= scale;
    return m;
}

static void test_archway_opens_stone_stays(void **state)
{
    (void)state;
    float box[6];
    ecm_params p;
    import_mesh m = scaled_model("openings/kenney_archway_cliff_cave_stone.glb", 4, box, &p);
    ecm_cluster cl = cluster_at(0, (const float[3]){0, 0.175f, box[5]}, (const float[3]){0.05f, 0.1f, 0});
    ecm_result r;
    char err[256];
    refine_model(&p, &m, CBOXES(box), 1, &cl, 1, &r);
    assert_true(r.wanted > 0);
    assert_true(r.count > 1);

    /* Standing in the opening, at the front, the back, and spanning the
     * whole passage: free. */
    const float zs[3][2] = {{0.3315f, 0.4815f}, {0.35f, 0.5f}, {0.3315f, 0.5f}};
    for (int i = 0; i < 3; i++) {
        float lo[3] = {-0.075f, -0.049f, zs[i][0]}, hi[3] = {0.075f, 0.40f, zs[i][1]};
        CHECK(!blocked(CBOXES(r.boxes), r.count, lo, hi), "the opening is blocked at z %g..%g",
              (double)zs[i][0], (double)zs[i][1]);
    }
    /* Pressed into the left pillar, the right pillar, the lintel: blocked. */
    const float solid[3][6] = {{-0.48f, -0.049f, 0.3315f, -0.33f, 0.40f, 0.5f},
                               {0.33f, -0.049f, 0.3315f, 0.48f, 0.40f, 0.5f},
                               {-0.075f, 0.75f, 0.3315f, 0.075f, 0.94f, 0.5f}};
    for (int i = 0; i < 3; i++)
        CHECK(blocked(CBOXES(r.boxes), r.count, solid[i], solid[i] + 3), "solid stone %d is free", i);
    ecm_result_free(&r);

    /* Not vacuous: held to one box, the opening stays closed. */
    p.max_boxes = 1;
    assert_int_equal(ecm_refine(&p, m.tris, m.ntris, CBOXES(box), 1, &cl, 1, &r, err, sizeof err), 0);
    float lo[3] = {-0.075f, -0.049f, zs[2][0]}, hi[3] = {0.075f, 0.40f, zs[2][1]};
    assert_true(blocked(CBOXES(r.boxes), r.count, lo, hi));
    ecm_result_free(&r);
    import_mesh_free(&m);
}

/*
 * The archway at seeds 3 and 5 of the scenario: round 0's cluster (every
 * user stopped on the MBR's front face), replayed. With the division held
 * to 8 boxes past the budget before merging back, the 64 boxes cut the
 * arch's curve into steps where the division happened to stop, and one
 * step at head height stood 6 mm (2.4 cm in the world, more than a cell)
 * in front of the stone on a path past the arch's right side: a user
 * walking it was stopped 31 moves in a row. Users who press from outside
 * show the whole opening they want, so the division may hold more before
 * merging chooses what to keep, and that step is gone.
 */
static void test_archway_path_past_the_curve(void **state)
{
    (void)state;
    float box[6];
    ecm_params p;
    import_mesh m = scaled_model("openings/kenney_archway_cliff_cave_stone.glb", 4, box, &p);
    const ecm_cluster cl = {.box = 0, .min = {-0.4318f, 0.175f, 0.3315f}, .max = {0.3875f, 0.175f, 0.3315f},
                            .centroid = {0.0436f, 0.175f, 0.3315f}, .weight = 2591};
    ecm_result r;
    refine_model(&p, &m, CBOXES(box), 1, &cl, 1, &r);
    assert_true(r.count <= p.max_boxes);
    /* The avatar where it was stopped (world 1.30 0 3.81; the object at
     * 0 0.2 2.674, scale 4), walked on 3 mm, its head under the curve:
     * free. */
    const float lo[3] = {0.251f, -0.049f, 0.3315f}, hi[3] = {0.399f, 0.399f, 0.363f};
    CHECK(!blocked(CBOXES(r.boxes), r.count, lo, hi), "the path past the arch's right side is blocked");
    ecm_result_free(&r);
    import_mesh_free(&m);
}

/* Sponza, round 0 of the scenario: every user inside its one box, along
 * its -z arcade (contacts at their centres). */
static const ecm_cluster sponza_inside = {.box = 0, .min = {-15.6777592f, 0.993f, -4.92351198f},
                                          .max = {15.6722403f, 0.993f, -0.198510006f},
                                          .centroid = {-0.079234004f, 0.993f, -2.68530369f}, .weight = 2400};

/*
 * How much of the budget a round spends. The colonnade at seed 1 of the
 * scenario, round 0's four clusters, users stopped on its front face: the
 * division stopped at the budget with 21 pressed nodes kept whole, and
 * merging then joined their parts back to 46 boxes; users later stopped
 * by column bases those 18 boxes would have cut (19 per 1,000 moves in
 * round 3). Users outside show the whole opening they want: every box of
 * the budget is spent. (With planes chosen by what they free, step 4,
 * that round fits in 64 boxes; at 48 the budget binds again.) Sponza, round 0's cluster, users standing inside
 * its one box: they show only the part they stand in, and a quarter of the
 * budget at least is left for the rounds that find the rest (spent in
 * round 1, the next round was left 5 boxes, and 153 of the judge's moves
 * stayed blocked where no triangle is).
 */
static void test_budget_spent_outside_kept_inside(void **state)
{
    (void)state;
    float box[6];
    ecm_params p;
    import_mesh m = scaled_model("data/colonnade.obj", 1, box, &p);
    const ecm_cluster front[4] = {
        {.box = 0, .min = {-1.9242233f, 0.9f, -2.2f}, .max = {0.232935444f, 0.9f, -2.2f},
         .centroid = {-1.19113505f, 0.9f, -2.2f}, .weight = 278},
        {.box = 0, .min = {0.377127469f, 0.9f, -2.2f}, .max = {2.19910049f, 0.9f, -2.2f},
         .centroid = {1.36958659f, 0.9f, -2.2f}, .weight = 369},
        {.box = 0, .min = {3.7750001f, 0.9f, -2.2f}, .max = {5.64656591f, 0.9f, -2.2f},
         .centroid = {4.10390377f, 0.9f, -2.2f}, .weight = 318},
        {.box = 0, .min = {-4.68331718f, 0.9f, -2.2f}, .max = {-2.78816915f, 0.9f, -2.2f},
         .centroid = {-3.85715079f, 0.9f, -2.2f}, .weight = 272}};
    p.max_boxes = 48;
    ecm_result r;
    refine_model(&p, &m, CBOXES(box), 1, front, 4, &r);
    CHECK(r.capped > 0 && r.count == p.max_boxes, "outside: %u boxes of %u, %u pressed kept whole", r.count,
          p.max_boxes, r.capped);
    ecm_result_free(&r);
    import_mesh_free(&m);

    m = scaled_model("scenes/dabrovic_sponza.obj", 1, box, &p);
    refine_model(&p, &m, CBOXES(box), 1, &sponza_inside, 1, &r);
    CHECK(r.capped > 0 && r.count <= p.max_boxes - p.max_boxes / 4, "inside: %u boxes of %u, %u pressed kept whole",
          r.count, p.max_boxes, r.capped);
    ecm_result_free(&r);
    import_mesh_free(&m);
}

/*
 * Users inside Sponza walked along its -z arcade in round 0 (the
 * scenario's cluster, contacts at their centres). Later users walk on to
 * wherever they can: through the +z arcade's arches (columns at x -11.3,
 * -6.75 and -2.5, z 2.2..3.2) into the aisle behind it. Stretched along the
 * floor's normal, the region spent 40 boxes on the upper galleries nobody
 * reaches and kept the +z arcade one box, a phantom wall for later users
 * (up to 271 per 1,000 moves); the space reachable on foot is wanted now
 * (mark_reachable), and nothing above it that no stair leads to.
 */
static void test_inside_users_walk_on(void **state)
{
    (void)state;
    float box[6];
    ecm_params p;
    import_mesh m = scaled_model("scenes/dabrovic_sponza.obj", 1, box, &p);
    ecm_result r;
    refine_model(&p, &m, CBOXES(box), 1, &sponza_inside, 1, &r);
    const float arches[2][6] = {{-9.3f, 0.2f, 2.3f, -8.7f, 2.0f, 3.1f}, {4.2f, 0.2f, 2.3f, 4.8f, 2.0f, 3.1f}};
    for (int i = 0; i < 2; i++)
        CHECK(!blocked(CBOXES(r.boxes), r.count, arches[i], arches[i] + 3), "the arch at x %g is blocked",
              (double)arches[i][0]);
    ecm_result_free(&r);
    import_mesh_free(&m);
}

/*
 * Step 7 on the desk (local units, -1.5..0.5 x -0.5..0.5 x -0.5..0.5; the
 * scenario scales it 3x, so the avatar is 0.2 x 0.6 x 0.2). Its right
 * pedestal's inner panel is the plane x = -0.375 (z -0.437..0.5), and the
 * back board, z 0.438..0.5, runs from the left up to that same x. Users
 * stopped on the front face, as in the scenario's first round: the cell
 * border the division puts at x = -0.391 leaves the board's last 16 mm
 * and the whole panel in one box, so users walking in under the desk
 * stopped 16 mm (5 cm in the world) short of the panel all along it.
 * Split across z, the panel's part tightens to the panel.
 */
static void test_split_frees_space_under_the_cell(void **state)
{
    (void)state;
    float box[6];
    ecm_params p;
    import_mesh m = scaled_model("openings/homedecor_desk.obj", 3, box, &p);
    const ecm_cluster cl = {.box = 0, .min = {-1.21f, -0.2f, -0.5f}, .max = {0.164f, -0.2f, -0.5f},
                            .centroid = {-0.73f, -0.2f, -0.5f}, .weight = 2600};
    ecm_result r;
    refine_model(&p, &m, CBOXES(box), 1, &cl, 1, &r);
    assert_true(r.count <= p.max_boxes);
    /* Beside the panel, in the knee space, from the front to 5 cm before
     * the back board: free up to the panel itself. */
    const float lo[3] = {-0.45f, -0.49f, -0.4f}, hi[3] = {-0.3751f, -0.25f, 0.42f};
    CHECK(!blocked(CBOXES(r.boxes), r.count, lo, hi), "stopped short of the panel");
    /* The panel and the back board stay covered (check_result: every
     * triangle is inside the boxes). */
    ecm_result_free(&r);
    import_mesh_free(&m);
}

/* Whether box b lies in the union of the n boxes old, give or take tol on
 * each axis: 9^3 points spread over it, each in one of them. */
static int within_boxes(const float b[6], const float (*old)[6], uint32_t n, const float tol[3])
{
    for (int i = 0; i < 9 * 9 * 9; i++) {
        const int at[3] = {i % 9, i / 9 % 9, i / 81};
        float q[3];
        for (int a = 0; a < 3; a++)
            q[a] = b[a] + (b[3 + a] - b[a]) * (float)at[a] / 8;
        int in = 0;
        for (uint32_t j = 0; j < n && !in; j++) {
            in = 1;
            for (int a = 0; a < 3; a++)
                in &= q[a] >= old[j][a] - tol[a] && q[a] <= old[j][3 + a] + tol[a];
        }
        if (!in)
            return 0;
    }
    return 1;
}

/*
 * The desk's map of round 1 at seed 4 of the scenario (4 boxes) and the
 * cluster of round 2 (users under the desk). The division merged the back
 * board's box with part of the pedestal's, and the new box's bounds, one
 * part from each, reached 2.5 cm below the board's old box and 2 mm in
 * front of it: users standing at that face were then inside it, free to
 * walk on into the board (move.h), 36 leaks in a round. They are pushed
 * out now (move_push_out: test_move, test_world_place, test_judge), no
 * further than half their width; so no new box may reach out of the old
 * map by more than a quarter of it on an axis, nor by more than two cells.
 */
static void test_new_boxes_stay_near_the_old_map(void **state)
{
    (void)state;
    float box[6];
    ecm_params p;
    import_mesh m = scaled_model("openings/homedecor_desk.obj", 3, box, &p);
    static const float old[4][6] = {{-0.50000006f, -0.5f, -0.5f, 0.5f, 0.5f, 0.5f},
                                    {-1.5f, 0.109374978f, -0.437000036f, -0.49999994f, 0.5f, 0.5f},
                                    {-1.5f, -0.5f, -0.437000036f, -1.42187488f, 0.109375022f, 0.5f},
                                    {-1.42187512f, -0.37500003f, 0.437999964f, -0.49999994f, 0.109375022f, 0.5f}};
    const ecm_cluster cl = {.box = 0, .min = {-0.600333393f, -0.200000003f, -0.5f},
                            .max = {0.394075006f, -0.137500048f, 0.438000053f},
                            .centroid = {-0.048434183f, -0.194857597f, -0.311920017f}, .weight = 316};
    ecm_result r;
    refine_model(&p, &m, CBOXES(old), 4, &cl, 1, &r);
    assert_true(r.count > 4);
    float tol[3];
    for (int a = 0; a < 3; a++)
        tol[a] = fminf(fminf(p.avatar[0], p.avatar[2]) / 4, 2 * (box[3 + a] - box[a]) / (float)(1u << p.depth)) + 1e-5f;
    for (uint32_t i = 0; i < r.count; i++)
        CHECK(within_boxes(r.boxes[i], old, 4, tol), "box %u (%g %g %g .. %g %g %g) reaches out of the old map", i,
              (double)r.boxes[i][0], (double)r.boxes[i][1], (double)r.boxes[i][2], (double)r.boxes[i][3],
              (double)r.boxes[i][4], (double)r.boxes[i][5]);
    ecm_result_free(&r);

    /* A user stood at the back board's face (the avatar's box touching it):
     * one new box reached half a millimetre in front of it, within the
     * tolerance; the user would have stood inside it. Where users stood,
     * no new box reaches out of the old map at all. */
    const ecm_stood stood = {.box = {-1.0f, -0.5f, 0.238f, -0.8f, 0.1f, 0.437999964f}, .hit = 3};
    p.stood = &stood;
    p.nstood = 1;
    refine_model(&p, &m, CBOXES(old), 4, &cl, 1, &r);
    assert_true(r.count > 4);
    const float exact[3] = {1e-5f, 1e-5f, 1e-5f};
    for (uint32_t i = 0; i < r.count; i++) {
        int meets = 1;
        for (int a = 0; a < 3; a++)
            meets &= r.boxes[i][a] < stood.box[3 + a] && r.boxes[i][3 + a] > stood.box[a];
        CHECK(!meets || within_boxes(r.boxes[i], old, 4, exact),
              "box %u (%g %g %g .. %g %g %g) meets the user and reaches out of the old map", i,
              (double)r.boxes[i][0], (double)r.boxes[i][1], (double)r.boxes[i][2], (double)r.boxes[i][3],
              (double)r.boxes[i][4], (double)r.boxes[i][5]);
    }
    ecm_result_free(&r);
    import_mesh_free(&m);
}

/*
 * Step 8. An earlier round's box over two pillars 3 m apart, users stopped
 * at its face between them where nothing is, and three crates far off, a
 * box each, nobody near them: the object holds max_boxes (4). A pillar
 * each takes one box more than the cap leaves, so the round changes
 * nothing, and users stay stopped. The places where they stood name the
 * pillars' box, and their avatars touch no triangle: the crates' boxes
 * join, and the pillars get a box each.
 */
static void test_cap_moves_boxes_to_where_users_were_stopped(void **state)
{
    (void)state;
    snprintf(check_ctx, sizeof check_ctx, "pillars and crates at the cap");
    static const float lo[5][3] = {{0, 0, 0}, {3.5f, 0, 0}, {10, 0, 0}, {10.6f, 0, 0}, {11.2f, 0, 0}};
    static const float hi[5][3] = {
        {0.5f, 2, 0.5f}, {4, 2, 0.5f}, {10.5f, 0.5f, 0.5f}, {11.1f, 0.5f, 0.5f}, {11.7f, 0.5f, 0.5f}};
    float tris[5 * 12 * 9];
    for (int i = 0; i < 5; i++)
        box_surface(lo[i], hi[i], tris + 12 * 9 * i);
    static const float old[4][6] = {{0, 0, 0, 4, 2, 0.5f},
                                    {10, 0, 0, 10.5f, 0.5f, 0.5f},
                                    {10.6f, 0, 0, 11.1f, 0.5f, 0.5f},
                                    {11.2f, 0, 0, 11.7f, 0.5f, 0.5f}};
    const ecm_cluster cl = {.box = 0, .min = {1.5f, 0.9f, 0}, .max = {2.5f, 0.9f, 0}, .centroid = {2, 0.9f, 0},
                            .weight = 100};
    ecm_stood stood[3];
    for (int i = 0; i < 3; i++)
        stood[i] = (ecm_stood){.box = {1.4f + 0.3f * (float)i, 0, -0.6f, 2.0f + 0.3f * (float)i, 1.8f, 0}, .hit = 0};
    const float gap_lo[3] = {1, 0.2f, 0.1f}, gap_hi[3] = {3, 1.5f, 0.4f};
    ecm_params p;
    ecm_params_default(&p);
    p.max_boxes = 4;
    ecm_result r;
    char err[256];
    assert_int_equal(ecm_refine(&p, tris, 60, CBOXES(old), 4, &cl, 1, &r, err, sizeof err), 0);
    CHECK(r.count == 4 && blocked(CBOXES(r.boxes), r.count, gap_lo, gap_hi),
          "without where users stood: %u boxes, the gap %s", r.count,
          blocked(CBOXES(r.boxes), r.count, gap_lo, gap_hi) ? "blocked" : "open");
    ecm_result_free(&r);

    p.stood = stood;
    p.nstood = 3;
    assert_int_equal(ecm_refine(&p, tris, 60, CBOXES(old), 4, &cl, 1, &r, err, sizeof err), 0);
    CHECK(r.count <= p.max_boxes, "%u boxes", r.count);
    CHECK(!blocked(CBOXES(r.boxes), r.count, gap_lo, gap_hi), "the space between the pillars is still blocked");
    size_t bad = uncovered(tris, 60, CBOXES(r.boxes), r.count, 16);
    CHECK(bad == 0, "%zu triangle samples outside every box", bad);
    ecm_result_free(&r);

    /* Step 8 alone (a second candidate's), the users held where they
     * stood: the same opening; nothing below the cap or without places. */
    trimesh tm;
    assert_int_equal(trimesh_init(&tm, tris, 60, err, sizeof err), 0);
    ecm_cluster held = cl;
    held.held = 1;
    assert_int_equal(ecm_move_boxes(&p, &tm, CBOXES(old), 4, &held, 1, &r, err, sizeof err), 1);
    CHECK(r.count <= p.max_boxes, "step 8 alone: %u boxes", r.count);
    CHECK(!blocked(CBOXES(r.boxes), r.count, gap_lo, gap_hi), "step 8 alone: the gap is still blocked");
    bad = uncovered(tris, 60, CBOXES(r.boxes), r.count, 16);
    CHECK(bad == 0, "step 8 alone: %zu triangle samples outside every box", bad);
    ecm_result_free(&r);
    p.max_boxes = 5;
    assert_int_equal(ecm_move_boxes(&p, &tm, CBOXES(old), 4, &held, 1, &r, err, sizeof err), 0);
    assert_null(r.boxes);
    p.max_boxes = 4;
    p.nstood = 0;
    assert_int_equal(ecm_move_boxes(&p, &tm, CBOXES(old), 4, &held, 1, &r, err, sizeof err), 0);
    held.box = 4;
    assert_int_equal(ecm_move_boxes(&p, &tm, CBOXES(old), 4, &held, 1, &r, err, sizeof err), -EINVAL);
    assert_non_null(strstr(err, "names box 4"));
    trimesh_free(&tm);
}

/* A round of the gazebo replayed: the map in force (nold boxes) and the
 * round's clusters. The result must hold every invariant and divide (not
 * only tighten) the problem boxes; the caller frees r and the mesh. */
static import_mesh gazebo_round(const float (*old)[6], uint32_t nold, const ecm_cluster *cl, uint32_t ncl,
                                ecm_result *r)
{
    float box[6];
    ecm_params p;
    import_mesh m = scaled_model("data/gazebo.obj", 1, box, &p);
    refine_model(&p, &m, old, nold, cl, ncl, r);
    CHECK(r->count > nold, "the %u problem boxes were only tightened", r->problem_boxes);
    return m;
}

/*
 * The scenario's gazebo (tests/data/models), seed 4, its second round: the
 * map after round 1 (27 boxes; box 0 is the roof over everything) and the
 * round's cluster, users stopped by the well's box 21 where the curved wall
 * is 4 to 12 cm further in. The cluster also presses on the roof (a user
 * at the well might step up under it), and one grid over the roof's hull
 * cost more boxes to cut the space between the posts out than the budget
 * held: the map came back only tightened, and users stayed stopped there.
 * The roof, which no region of the cluster reaches, is now only tightened,
 * and the well's boxes are divided on a grid of their own.
 */
static void test_roof_over_the_well_is_only_tightened(void **state)
{
    (void)state;
    static const float old[27][6] = {
        {-3.0999999f, 1.84062481f, -3.0999999f, 3.0999999f, 3.79999995f, 3.0999999f},
        {-0.120000005f, 0, -2.72000027f, 0.120000005f, 1.84062505f, -2.47999978f},
        {-2.30876613f, 0, 1.40468729f, -2.19463372f, 0.920312583f, 1.42000008f},
        {2.19463372f, 0, 1.40468729f, 2.30876613f, 0.920312583f, 1.42000008f},
        {-2.37170029f, 0, 1.17999995f, -2.1316998f, 0.920312583f, 1.40468764f},
        {-2.37170029f, 0, -1.42000008f, -2.1316998f, 1.84062505f, -1.17999995f},
        {2.1316998f, 0, -1.42000008f, 2.37170029f, 1.84062505f, -1.17999995f},
        {1.16249979f, 0, -0.281629294f, 1.20000017f, 0.900000036f, 0.281629294f},
        {2.1316998f, 0, 1.17999995f, 2.37170029f, 0.920312583f, 1.40468764f},
        {-1.04346955f, 0.682812393f, -1.0693574f, -0.532812357f, 0.900000036f, -0.581249833f},
        {0.532812357f, 0, -1.0693574f, 1.04346955f, 0.900000036f, -0.581249833f},
        {-0.120000005f, 0, 2.47999978f, 0.120000005f, 1.84062505f, 2.72000027f},
        {0.581249833f, 0, 0.532812357f, 1.0693574f, 0.900000036f, 1.04346955f},
        {-1.04346955f, 0.445312411f, -0.869082332f, -0.823437333f, 0.682812572f, -0.581249833f},
        {-0.629687607f, 0, 0.641906679f, 9.68749987e-08f, 0.44531256f, 1.20000017f},
        {-1.04346955f, 0, -1.0693574f, -0.532812357f, 0.44531256f, -0.581249833f},
        {-0.339062601f, 0.445312411f, 0.833118856f, 9.68749987e-08f, 0.900000036f, 1.20000017f},
        {-0.823437631f, 0.445312411f, -1.0693574f, -0.532812357f, 0.682812572f, -0.869081974f},
        {0.681643844f, 0, -0.581250131f, 1.16250014f, 0.900000036f, 0.532812595f},
        {-1.0693574f, 0, 0.532812357f, -0.629687369f, 0.900000036f, 1.01758182f},
        {-0.629687607f, 0.445312411f, 0.641906679f, -0.339062363f, 0.900000036f, 1.14509892f},
        {-1.20000017f, 0, -0.581250131f, -0.681643844f, 0.900000036f, 0.532812595f},
        {-0.532812595f, 0, -1.20000017f, 0.532812595f, 0.900000036f, -0.721381128f},
        {2.1316998f, 0.920312405f, 1.17999995f, 2.37170029f, 1.84062505f, 1.42000008f},
        {-9.68749987e-08f, 0, 0.681643844f, 0.581250131f, 0.900000036f, 1.20000017f},
        {-2.37170029f, 0.920312405f, 1.17999995f, -2.1316998f, 1.84062505f, 1.42000008f},
        {-0.681644201f, 0.445312411f, -0.721381426f, -0.532812357f, 0.682812572f, -0.581249833f}};
    const ecm_cluster cl = {.box = 21, .min = {-1.20000017f, 0.450000018f, -0.323845387f},
                            .max = {-1.0693574f, 0.450000018f, 1.01728964f},
                            .centroid = {-1.18755805f, 0.450000018f, 0.224983066f}, .weight = 168};
    ecm_result r;
    import_mesh m = gazebo_round(CBOXES(old), 27, &cl, 1, &r);
    /* The roof comes back whole, only tightened: one box at its height. */
    uint32_t roofs = 0;
    for (uint32_t i = 0; i < r.count; i++)
        roofs += r.boxes[i][1] > 1.8f;
    CHECK(roofs == 1, "the roof became %u boxes", roofs);
    /* Where the users pressed, outside the well's curved wall (radius
     * 1.2; this corner of the old box is 3 to 5 cm from it): free. */
    const float spot[6] = {-1.199f, 0.3f, 0.35f, -1.16f, 0.6f, 0.45f};
    CHECK(!blocked(CBOXES(r.boxes), r.count, spot, spot + 3), "the place the users were stopped at is still held");
    ecm_result_free(&r);
    import_mesh_free(&m);
}

/*
 * The gazebo at seed 5, round 3 of the scenario: boxes of the round before
 * (all on one grid) end a hair past a cell border (to_local grows them by
 * two RANGE_MARGIN of a cell): the roof starts 2e-7 m under the row its
 * grid begins at. That row's free cells, which the roof only grazes, were
 * outside cells: cutting them out of the roof's node took 57 boxes before
 * any cut for the users (budget 48), and the 12 problem boxes were only
 * tightened, round after round ("unchanged"), while users kept being
 * stopped at the well's ring.
 */
static void test_grazed_row_is_no_opening(void **state)
{
    (void)state;
    static const float old[28][6] = {
        {-3.0999999f, 1.84062481f, -3.0999999f, 3.0999999f, 3.79999995f, 3.0999999f},
        {-2.30876613f, 0, -1.42000008f, -2.19463372f, 0.920312583f, -1.40468729f},
        {2.19463372f, 0, -1.42000008f, 2.30876613f, 0.920312583f, -1.40468729f},
        {-2.37170029f, 0, -1.40468764f, -2.1316998f, 0.920312583f, -1.17999995f},
        {-2.37170029f, 0, 1.17999995f, -2.1316998f, 1.84062505f, 1.42000008f},
        {2.1316998f, 0, -1.40468764f, 2.37170029f, 0.920312583f, -1.17999995f},
        {1.16249979f, 0, -0.281629294f, 1.20000017f, 0.900000036f, 0.281629294f},
        {2.1316998f, 0, 1.17999995f, 2.37170029f, 1.84062505f, 1.42000008f},
        {0.641906679f, 0, -0.629687607f, 1.16250014f, 0.900000036f, 9.68749987e-08f},
        {-0.339062601f, 0, -1.20000017f, 9.68749987e-08f, 0.900000036f, -0.833118856f},
        {-0.120000005f, 0, 2.47999978f, 0.120000005f, 1.84062505f, 2.72000027f},
        {-1.0693574f, 0, -1.01758182f, -0.629687369f, 0.207812563f, -0.532812357f},
        {0.532812357f, 0, -1.0693574f, 1.01758182f, 0.207812563f, -0.629687369f},
        {2.1316998f, 0.920312405f, -1.42000008f, 2.37170029f, 1.84062505f, -1.17999995f},
        {-1.20000017f, 0, -0.532812595f, -0.721381128f, 0.900000036f, 0.532812595f},
        {-2.37170029f, 0.920312405f, -1.42000008f, -2.1316998f, 1.84062505f, -1.17999995f},
        {-9.68749987e-08f, 0, -1.20000017f, 0.532812595f, 0.900000036f, -0.721381128f},
        {0.532812357f, 0.207812428f, -1.0693574f, 0.775000095f, 0.900000036f, -0.629687369f},
        {-0.120000005f, 0, -2.72000027f, 0.120000005f, 1.84062505f, -2.47999978f},
        {-0.869082332f, 0.207812428f, -1.01758182f, -0.629687369f, 0.900000036f, -0.823437333f},
        {-0.629687607f, 0, 0.641906679f, 9.68749987e-08f, 0.900000036f, 1.20000017f},
        {0.532812357f, 0, 0.581249833f, 1.04346955f, 0.900000036f, 1.0693574f},
        {-1.0693574f, 0, 0.532812357f, -0.629687369f, 0.900000036f, 1.01758182f},
        {-0.629687607f, 0, -1.14509892f, -0.339062363f, 0.900000036f, -0.641906679f},
        {0.774999857f, 0.207812428f, -0.908860743f, 1.01758182f, 0.900000036f, -0.629687369f},
        {-1.0693574f, 0.207812428f, -0.823437631f, -0.629687369f, 0.900000036f, -0.532812357f},
        {-9.68749987e-08f, 0, 0.721381128f, 0.532812595f, 0.900000036f, 1.20000017f},
        {0.681643844f, 0, -9.68749987e-08f, 1.16250014f, 0.900000036f, 0.581250131f}};
    const ecm_cluster cl[2] = {
        {.box = 14, .min = {-1.20000017f, 0.103906281f, -1.19795799f}, .max = {-0.339062601f, 0.553906202f, 0.370974541f},
         .centroid = {-1.09906995f, 0.431523085f, -0.345080942f}, .weight = 309},
        {.box = 4, .min = {-2.37170029f, 0.899999976f, 1.17999983f}, .max = {-2.25169992f, 0.899999976f, 1.32841539f},
         .centroid = {-2.32560539f, 0.899999976f, 1.24618125f}, .weight = 94}};
    ecm_result r;
    import_mesh m = gazebo_round(CBOXES(old), 28, cl, 2, &r);
    /* Where the users pressed, just outside the well's ring (radius
     * 1.2), 210 degrees round: held by boxes 11 and 25 before. */
    const float spot[6] = {-1.07f, 0.3f, -0.62f, -1.05f, 0.6f, -0.60f};
    CHECK(!blocked(CBOXES(r.boxes), r.count, spot, spot + 3), "the place the users were stopped at is still held");
    assert_int_equal(r.apart_over, 0);
    ecm_result_free(&r);

    /* At a cap of the 28 boxes it has, the new boxes join boxes of the
     * well's ring whose faces are offset by a cell or two, and so reach out
     * of the old map by as much (5 boxes go over the cap when one cell is
     * all a box may reach out by). Taken apart in each, they
     * passed the cap by 69 boxes and the round was only tightened; kept
     * (avatars there are pushed out, move_push_out), the round opens. */
    float box[6];
    ecm_params p;
    import_mesh_free(&m);
    m = scaled_model("data/gazebo.obj", 1, box, &p);
    p.max_boxes = 28;
    refine_model(&p, &m, CBOXES(old), 28, cl, 2, &r);
    CHECK(r.count <= 28 && r.capped < r.problem_boxes && r.apart_over == 0,
          "at the cap: %u boxes, %u of %u problem boxes kept whole, %u over", r.count, r.capped, r.problem_boxes,
          r.apart_over);
    CHECK(!blocked(CBOXES(r.boxes), r.count, spot, spot + 3), "at the cap, the place is still held");
    ecm_result_free(&r);
    import_mesh_free(&m);
}

/* ---- random triangle soups --------------------------------------------- */

typedef struct rng {
    uint64_t s;
} rng;

/* splitmix64: a fixed seed gives the same soup on every machine. */
static uint64_t rng_next(rng *r)
{
    uint64_t z = (r->s += 0x9e3779b97f4a7c15u);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9u;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebu;
    return z ^ (z >> 31);
}

static double rng_unit(rng *r) { return (double)(rng_next(r) >> 11) * 0x1p-53; }

static uint32_t rng_below(rng *r, uint32_t n) { return (uint32_t)(rng_next(r) % n); }

/* The coordinate u of the way along axis a of box b, kept inside it. */
static float box_coord(const float b[6], int a, double u)
{
    float v = (float)((double)b[a] + ((double)b[3 + a] - b[a]) * u);
    return v < b[a] ? b[a] : v > b[3 + a] ? b[3 + a] : v;
}

/* A random box. A nice one has power-of-two sides (1/8 to 16) at multiples
 * of 1/4 in [-10, 10], so that every face of a grid cell down to 2^-9 of a
 * side is an exact float and triangles can lie exactly on them; any other
 * has sides from 1e-3 to 1e2 anywhere in [-100, 100]. */
static void random_box(rng *r, int nice, float b[6])
{
    for (int a = 0; a < 3; a++) {
        if (nice) {
            b[a] = (float)((int)rng_below(r, 81) - 40) * 0.25f;
            b[3 + a] = b[a] + ldexpf(1.0f, (int)rng_below(r, 8) - 3);
        } else {
            b[a] = (float)(rng_unit(r) * 200 - 100);
            b[3 + a] = b[a] + (float)pow(10, rng_unit(r) * 5 - 3);
        }
    }
}

enum { TRI_BIG, TRI_SMALL, TRI_SLIVER, TRI_ON_FACE, TRI_SEGMENT, TRI_POINT, TRI_KINDS };

/* One random triangle inside box b, of a random kind: any size from the
 * whole box down to 1e-5 of it, slivers, axis-aligned ones lying exactly on
 * a face of the 2^depth grid over b (or of the grid one level finer: the
 * faces of an octant's grid), segments (a repeated vertex, or three nearly
 * collinear) and points. */
static void random_tri(rng *r, const float b[6], uint32_t depth, float t[9])
{
    double u[3][3];
    for (int i = 0; i < 3; i++)
        for (int a = 0; a < 3; a++)
            u[i][a] = rng_unit(r);
    switch (rng_below(r, TRI_KINDS)) {
    case TRI_SMALL: {
        double s = pow(10, -1 - 4 * rng_unit(r));
        for (int i = 1; i < 3; i++)
            for (int a = 0; a < 3; a++)
                u[i][a] = u[0][a] + s * (rng_unit(r) - 0.5);
        break;
    }
    case TRI_SLIVER: {
        double w = rng_unit(r), s = pow(10, -4 - 3 * rng_unit(r));
        for (int a = 0; a < 3; a++)
            u[2][a] = u[0][a] + w * (u[1][a] - u[0][a]) + s * (rng_unit(r) - 0.5);
        break;
    }
    case TRI_ON_FACE: {
        int a = (int)rng_below(r, 3);
        uint32_t n = 2u << depth;
        double f = (double)rng_below(r, n + 1) / n;
        for (int i = 0; i < 3; i++)
            u[i][a] = f;
        break;
    }
    case TRI_SEGMENT: {
        int repeat = (int)rng_below(r, 2);
        for (int a = 0; a < 3; a++)
            u[2][a] = repeat ? u[0][a] : (u[0][a] + u[1][a]) / 2;
        break;
    }
    case TRI_POINT:
        for (int a = 0; a < 3; a++)
            u[1][a] = u[2][a] = u[0][a];
        break;
    default:
        break;
    }
    for (int i = 0; i < 3; i++)
        for (int a = 0; a < 3; a++)
            t[3 * i + a] = box_coord(b, a, u[i][a]);
}

/* A random cluster on box b (index idx): at the middle of a face, or, one
 * time in seven, anywhere inside; a point or spread over up to a fifth of
 * the box on each axis. */
static ecm_cluster random_cluster(rng *r, const float b[6], uint32_t idx)
{
    float c[3], spread[3];
    for (int a = 0; a < 3; a++) {
        c[a] = box_coord(b, a, rng_unit(r));
        spread[a] = rng_below(r, 3) ? (float)(((double)b[3 + a] - b[a]) * 0.2 * rng_unit(r)) : 0.0f;
    }
    uint32_t face = rng_below(r, 7);
    if (face < 6) {
        c[face % 3] = b[face];
        spread[face % 3] = 0;
    }
    return cluster_at(idx, c, spread);
}

/* Random parameters at the given depth: any cap from 1 to the limit, any
 * share of empty space, an avatar from a hundredth of the object to twice
 * its size, and no floor or one from half the box's height under it to
 * half way up (the ground may cut through the object). */
static void random_params(rng *r, const float b[6], uint32_t depth, ecm_params *p)
{
    static const uint32_t caps[] = {1, 2, 3, 8, ECM_MAX_BOXES_DEFAULT, ECM_MAX_BOXES_LIMIT};
    static const double empties[] = {0, ECM_MAX_EMPTY_DEFAULT, 1};
    ecm_params_default(p);
    p->depth = depth;
    p->max_boxes = caps[rng_below(r, NELEM(caps))];
    p->max_empty = empties[rng_below(r, NELEM(empties))];
    double ext = 0;
    for (int a = 0; a < 3; a++)
        ext = fmax(ext, (double)b[3 + a] - b[a]);
    ext = ext > 0 ? ext : 1;
    for (int a = 0; a < 3; a++)
        p->avatar[a] = (float)(ext * pow(10, -2 + 2.3 * rng_unit(r)));
    double h = (double)b[4] - b[1];
    if (rng_below(r, 3))
        p->floor = (float)(b[1] + h * (rng_unit(r) - 0.5));
}

/* One random object: ntris triangles in a random box; the object's one box
 * is that box or the triangles' MBR; one to four clusters on it. */
static void run_soup(uint64_t seed, uint32_t depth, uint32_t ntris)
{
    rng r = {seed};
    snprintf(check_ctx, sizeof check_ctx, "soup seed %llu depth %u", (unsigned long long)seed, depth);
    float b[6];
    random_box(&r, (int)rng_below(&r, 2), b);
    float *tris = malloc((size_t)ntris * 9 * sizeof *tris);
    assert_non_null(tris);
    for (uint32_t t = 0; t < ntris; t++)
        random_tri(&r, b, depth, tris + 9 * (size_t)t);
    if (rng_below(&r, 2))
        mbr(tris, ntris, b);
    ecm_cluster cl[4];
    uint32_t ncl = 1 + rng_below(&r, 4);
    for (uint32_t i = 0; i < ncl; i++)
        cl[i] = random_cluster(&r, b, 0);
    ecm_params p;
    random_params(&r, b, depth, &p);
    /* Hundreds of boxes at 256^3 take seconds (merging is quadratic). */
    if (depth == ECM_DEPTH_MAX && p.max_boxes > ECM_MAX_BOXES_DEFAULT)
        p.max_boxes = ECM_MAX_BOXES_DEFAULT;
    ecm_result res;
    char err[256];
    int rc = ecm_refine(&p, tris, ntris, CBOXES(b), 1, cl, ncl, &res, err, sizeof err);
    CHECK(rc == 0, "%s", err);
    check_result(&p, tris, ntris, CBOXES(b), 1, cl, ncl, &res, 8);
    ecm_result_free(&res);
    free(tris);
}

static void test_soups(void **state)
{
    (void)state;
    /* Depths 2 to 7, many seeds; sizes from one triangle to a few hundred. */
    for (uint64_t seed = 1; seed <= 90; seed++)
        run_soup(seed, ECM_DEPTH_MIN + (uint32_t)(seed % 6), 1 + (uint32_t)(seed * 37 % 300));
    /* 256^3: a few only. */
    for (uint64_t seed = 1001; seed <= 1003; seed++)
        run_soup(seed, ECM_DEPTH_MAX, 200);
}

/* The object's box cut into its eight octants (their union is the box);
 * clusters on a random non-empty subset of them, listed from the last
 * octant to the first (the result still goes in problem box order). */
static void run_soup_octants(uint64_t seed, uint32_t depth, uint32_t ntris)
{
    rng r = {seed};
    snprintf(check_ctx, sizeof check_ctx, "octant soup seed %llu depth %u", (unsigned long long)seed, depth);
    float b[6], oct[8][6];
    random_box(&r, (int)rng_below(&r, 2), b);
    float *tris = malloc((size_t)ntris * 9 * sizeof *tris);
    assert_non_null(tris);
    for (uint32_t t = 0; t < ntris; t++)
        random_tri(&r, b, depth, tris + 9 * (size_t)t);
    for (int o = 0; o < 8; o++)
        for (int a = 0; a < 3; a++) {
            float mid = (float)(((double)b[a] + b[3 + a]) / 2);
            oct[o][a] = (o >> a) & 1 ? mid : b[a];
            oct[o][3 + a] = (o >> a) & 1 ? b[3 + a] : mid;
        }
    uint32_t mask = 1 + rng_below(&r, 255);
    ecm_cluster cl[16];
    uint32_t ncl = 0;
    for (int o = 7; o >= 0; o--)
        if (mask >> o & 1)
            for (uint32_t k = 1 + rng_below(&r, 2); k-- > 0;)
                cl[ncl++] = random_cluster(&r, oct[o], (uint32_t)o);
    ecm_params p;
    random_params(&r, b, depth, &p);
    ecm_result res;
    char err[256];
    int rc = ecm_refine(&p, tris, ntris, CBOXES(oct), 8, cl, ncl, &res, err, sizeof err);
    CHECK(rc == 0, "%s", err);
    check_result(&p, tris, ntris, CBOXES(oct), 8, cl, ncl, &res, 8);
    ecm_result_free(&res);
    free(tris);
}

static void test_soups_several_boxes(void **state)
{
    (void)state;
    for (uint64_t seed = 101; seed <= 130; seed++)
        run_soup_octants(seed, ECM_DEPTH_MIN + (uint32_t)(seed % 5), 50 + (uint32_t)(seed * 13 % 250));

    /* By hand: four boxes along x, clusters on the second and the fourth
     * only; the first and the third come out first, unchanged. */
    snprintf(check_ctx, sizeof check_ctx, "four boxes");
    rng r = {4};
    float boxes[4][6], tris[4 * 40 * 9];
    for (int i = 0; i < 4; i++) {
        const float b[6] = {(float)i, 0, 0, (float)i + 1, 1, 1};
        memcpy(boxes[i], b, sizeof b);
        for (int t = 0; t < 40; t++)
            random_tri(&r, b, 5, tris + 9 * (40 * i + t));
    }
    ecm_cluster cl[2];
    const float c3[3] = {3.5f, 0.5f, 0}, c1[3] = {1.5f, 0.5f, 1}, spread[3] = {0.2f, 0.2f, 0};
    cl[0] = cluster_at(3, c3, spread);
    cl[1] = cluster_at(1, c1, spread);
    ecm_params p;
    ecm_params_default(&p);
    p.depth = 5;
    p.avatar[0] = p.avatar[1] = p.avatar[2] = 0.1f;
    ecm_result res;
    char err[256];
    assert_int_equal(ecm_refine(&p, tris, 160, CBOXES(boxes), 4, cl, 2, &res, err, sizeof err), 0);
    check_result(&p, tris, 160, CBOXES(boxes), 4, cl, 2, &res, 16);
    assert_int_equal(res.problem_boxes, 2);
    assert_memory_equal(res.boxes[0], boxes[0], sizeof boxes[0]);
    assert_memory_equal(res.boxes[1], boxes[2], sizeof boxes[2]);
    assert_true(res.count > 4);
    ecm_result_free(&res);
}

/* ---- degenerate objects ------------------------------------------------ */

/* Refines a degenerate object with clusters on its MBR's faces at depths
 * up to max_depth: no crash, the invariant holds and every box stays
 * inside the (flat) MBR. */
static void refine_degenerate(const char *what, const float *tris, uint32_t ntris, uint32_t max_depth)
{
    float box[6];
    mbr(tris, ntris, box);
    ecm_cluster cl[7];
    face_clusters(box, 0, cl);
    static const uint32_t depths[] = {ECM_DEPTH_MIN, 5, ECM_DEPTH_DEFAULT, ECM_DEPTH_MAX};
    for (size_t d = 0; d < NELEM(depths) && depths[d] <= max_depth; d++) {
        snprintf(check_ctx, sizeof check_ctx, "%s, depth %u", what, depths[d]);
        ecm_params p;
        ecm_params_default(&p);
        p.depth = depths[d];
        p.avatar[0] = p.avatar[1] = p.avatar[2] = 0.2f;
        ecm_result r;
        char err[256];
        int rc = ecm_refine(&p, tris, ntris, CBOXES(box), 1, cl, 7, &r, err, sizeof err);
        CHECK(rc == 0, "%s", err);
        check_result(&p, tris, ntris, CBOXES(box), 1, cl, 7, &r, 16);
        CHECK(r.count >= 1, "no box left");
        ecm_result_free(&r);
    }
}

static void test_flat_objects(void **state)
{
    (void)state;
    rng r = {42};
    enum { N = 300 };
    float *tris = malloc(N * 9 * sizeof *tris);
    assert_non_null(tris);

    /* Flat on y: every vertex at y = 0 (some triangles on cell faces in x
     * or z, some segments and points); the MBR is flat on y. */
    const float plane[6] = {-1, 0, -1, 1, 0, 1};
    for (int t = 0; t < N; t++)
        random_tri(&r, plane, 5, tris + 9 * t);
    float box[6];
    mbr(tris, N, box);
    assert_true(box[1] == 0 && box[4] == 0);
    refine_degenerate("flat on y", tris, N, ECM_DEPTH_MAX);

    /* A line along x (flat on y and z). */
    const float line[6] = {-1, 0.5f, 0.25f, 1, 0.5f, 0.25f};
    for (int t = 0; t < N; t++)
        random_tri(&r, line, 5, tris + 9 * t);
    refine_degenerate("line along x", tris, N, ECM_DEPTH_DEFAULT);

    /* A point: every triangle the same point; its one box is the point. */
    for (int i = 0; i < N * 3; i++) {
        tris[3 * i] = 3;
        tris[3 * i + 1] = -2;
        tris[3 * i + 2] = 0.125f;
    }
    refine_degenerate("point", tris, N, ECM_DEPTH_DEFAULT);
    const float pt[6] = {3, -2, 0.125f, 3, -2, 0.125f};
    ecm_cluster cl = cluster_at(0, pt, (const float[3]){0, 0, 0});
    ecm_params p;
    ecm_params_default(&p);
    ecm_result res;
    char err[256];
    assert_int_equal(ecm_refine(&p, tris, N, CBOXES(pt), 1, &cl, 1, &res, err, sizeof err), 0);
    assert_int_equal(res.count, 1);
    assert_memory_equal(res.boxes[0], pt, sizeof pt);
    ecm_result_free(&res);
    free(tris);
}

/* ---- what is not wanted stays covered ---------------------------------- */

/* Refines the 12 triangles tris (a box's surface) in the nboxes boxes
 * pressed by cl, where nothing is wanted: the result is one box, want
 * (rounded outwards by at most one float step). */
static void one_box_left(const ecm_params *p, const float *tris, const float (*boxes)[6], uint32_t nboxes,
                         const ecm_cluster *cl, const float want[6])
{
    ecm_result r;
    char err[256];
    assert_int_equal(ecm_refine(p, tris, 12, boxes, nboxes, cl, 1, &r, err, sizeof err), 0);
    check_result(p, tris, 12, boxes, nboxes, cl, 1, &r, 1 << p->depth);
    assert_int_equal(r.wanted, 0);
    assert_int_equal(r.capped, 0);
    CHECK(r.count == 1, "%u boxes", r.count);
    assert_true(box_near(r.boxes[0], want));
    ecm_result_free(&r);
}

/* Users stopped beside the object, out of its box on the other axes: no
 * cell is wanted, so the box only shrinks to the geometry. A cube [-1,
 * 1]^3 in a box [-2, 2]^3 at depth 4 (cells of 1/4): its faces lie on cell
 * faces and touch the cells on both sides (cells are closed), but the box
 * is tightened to the triangles, so the one box left is [-1, 1]^3.
 *
 * A slab 5 x 1 x 5 whose map is 25 columns of 1 x 1 (an earlier round's),
 * pressed by users standing all over it: nothing is wanted either, so the
 * division keeps the slab one box, which lies in the old map although it
 * meets all 25 of its boxes. Step 6 took every box meeting more than 16
 * old ones apart, and the map came back as the 25 columns. */
static void test_nothing_wanted_only_shrinks(void **state)
{
    (void)state;
    snprintf(check_ctx, sizeof check_ctx, "cube in a bigger box");
    float tris[12 * 9];
    box_surface((const float[3]){-1, -1, -1}, (const float[3]){1, 1, 1}, tris);
    const float box[6] = {-2, -2, -2, 2, 2, 2};
    ecm_cluster cl = {.box = 0, .min = {-2, 3, 3}, .max = {-2, 3.5f, 3.5f}, .centroid = {-2, 3.2f, 3.2f}};
    ecm_params p;
    ecm_params_default(&p);
    p.depth = 4;
    p.avatar[0] = p.avatar[1] = p.avatar[2] = 0.3f;
    one_box_left(&p, tris, CBOXES(box), 1, &cl, (const float[6]){-1, -1, -1, 1, 1, 1});

    snprintf(check_ctx, sizeof check_ctx, "slab over 25 columns");
    box_surface((const float[3]){0, 0, 0}, (const float[3]){5, 1, 5}, tris);
    float old[25][6];
    for (int i = 0; i < 25; i++) {
        const float x = (float)(i % 5), z = (float)(i / 5);
        memcpy(old[i], (const float[6]){x, 0, z, x + 1, 1, z + 1}, sizeof old[i]);
    }
    cl = (ecm_cluster){.box = 12, .min = {0.4f, 1, 0.4f}, .max = {4.6f, 1, 4.6f}, .centroid = {2.5f, 1, 2.5f},
                       .weight = 500};
    ecm_params_default(&p);
    p.depth = 5;
    one_box_left(&p, tris, CBOXES(old), 25, &cl, (const float[6]){0, 0, 0, 5, 1, 5});
}

/* A closed wall 4 x 3 x 0.3 m (its two faces 0.3 apart, the avatar 0.6
 * deep) standing in a problem box 3 m deep, users stopped on the box's face
 * in front of it: the space in front is wanted, but the hollow between the
 * wall's faces is no space for them, so the wall stays one box, its cells'
 * box (within one cell of its MBR), and its inside still blocks. The box
 * must be at least four avatars deep: refine.c caps the avatar at a quarter
 * of the grid, and a bare wall's own MBR (0.3 deep) would see its hollow
 * wanted. */
static void test_thick_wall_stays_whole(void **state)
{
    (void)state;
    snprintf(check_ctx, sizeof check_ctx, "thick wall");
    float tris[12 * 9];
    const float wlo[3] = {0, 0, 0}, whi[3] = {4, 3, 0.3f};
    box_surface(wlo, whi, tris);
    const float box[6] = {0, 0, -2.7f, 4, 3, 0.3f};
    ecm_cluster cl = {.box = 0, .min = {1.5f, 0.9f, -2.7f}, .max = {2.5f, 0.9f, -2.7f}, .centroid = {2, 0.9f, -2.7f}};
    ecm_params p;
    ecm_params_default(&p);
    ecm_result r;
    char err[256];
    assert_int_equal(ecm_refine(&p, tris, 12, CBOXES(box), 1, &cl, 1, &r, err, sizeof err), 0);
    check_result(&p, tris, 12, CBOXES(box), 1, &cl, 1, &r, 16);
    assert_true(r.wanted > 0);
    assert_int_equal(r.capped, 0);
    assert_int_equal(r.count, 1);
    double cell = 3.0 / (1u << p.depth);
    for (int a = 0; a < 3; a++) {
        assert_true(r.boxes[0][a] <= wlo[a] && r.boxes[0][a] >= wlo[a] - cell);
        assert_true(r.boxes[0][3 + a] >= whi[a] && r.boxes[0][3 + a] <= whi[a] + cell);
    }
    /* Inside the wall, between its faces, is still blocked. */
    float lo[3] = {1.9f, 0.8f, 0.1f}, hi[3] = {2.1f, 1.0f, 0.2f};
    assert_true(blocked(CBOXES(r.boxes), r.count, lo, hi));
    ecm_result_free(&r);
}

/* ---- wanted space and the exact cap ------------------------------------ */

/* Two unit cubes at opposite corners of the box [0, 4]^3 (depth 5: cells of
 * 1/8), everything between them empty. */
static void two_cubes(float tris[24 * 9])
{
    box_surface((const float[3]){0, 0, 0}, (const float[3]){1, 1, 1}, tris);
    box_surface((const float[3]){3, 3, 3}, (const float[3]){4, 4, 4}, tris + 12 * 9);
}

/* A wall 4 m wide, 3 m high, 0.2 m thick (z 1.9..2.1) with a doorway 1 m
 * wide and 2.2 m high in its middle (x 1.5..2.5): three solid blocks, left,
 * right and the lintel, into t[108]. */
static void doorway_wall(float *t)
{
    box_surface((const float[3]){0, 0, 1.9f}, (const float[3]){1.5f, 3, 2.1f}, t);
    box_surface((const float[3]){2.5f, 0, 1.9f}, (const float[3]){4, 3, 2.1f}, t + 12 * 9);
    box_surface((const float[3]){1.5f, 2.2f, 1.9f}, (const float[3]){2.5f, 3, 2.1f}, t + 24 * 9);
}

/* Whether an avatar (0.6 x 1.8 x 0.6) standing in the doorway, at its
 * middle and 0.1 m to either side (where users were stopped), is free. */
static int doorway_free(const ecm_result *r)
{
    for (int k = -1; k <= 1; k++) {
        const float x = 2 + 0.1f * (float)k;
        const float lo[3] = {x - 0.3f, 0, 1.7f}, hi[3] = {x + 0.3f, 1.8f, 2.3f};
        if (blocked(CBOXES(r->boxes), r->count, lo, hi))
            return 0;
    }
    return 1;
}

/* Refines the doorway wall's map (boxes) for cluster cl with the default
 * parameters, and checks what every refinement promises. */
static void refine_doorway(const float (*boxes)[6], uint32_t nboxes, const ecm_cluster *cl, ecm_result *r)
{
    float tris[36 * 9];
    doorway_wall(tris);
    ecm_params p;
    ecm_params_default(&p);
    char err[256];
    int rc = ecm_refine(&p, tris, 36, boxes, nboxes, cl, 1, r, err, sizeof err);
    CHECK(rc == 0, "%s", err);
    check_result(&p, tris, 36, boxes, nboxes, cl, 1, r, 16);
}

/*
 * A held cluster (trials held back there, refine.h) wants its points' reach
 * alone: a wall 8 m wide with two doorways 4 m apart (x 1.5..2.5, 2.2 m
 * high, and 5.5..6.5, 2 m high: no cut made for the first frees the
 * second), users stopped at the bounding box's face in front of the first.
 * Users who cross a face roam sideways, so the second doorway opens too;
 * trials held at the first do not, and it stays shut.
 */
static void test_held_cluster_wants_its_reach(void **state)
{
    (void)state;
    snprintf(check_ctx, sizeof check_ctx, "two doorways, a held cluster");
    float tris[60 * 9];
    const float lo[5][3] = {{0, 0, 1.9f}, {2.5f, 0, 1.9f}, {6.5f, 0, 1.9f}, {1.5f, 2.2f, 1.9f}, {5.5f, 2.0f, 1.9f}};
    const float hi[5][3] = {{1.5f, 3, 2.1f}, {5.5f, 3, 2.1f}, {8, 3, 2.1f}, {2.5f, 3, 2.1f}, {6.5f, 3, 2.1f}};
    for (int i = 0; i < 5; i++)
        box_surface(lo[i], hi[i], tris + 12 * 9 * i);
    const float mbr[1][6] = {{0, 0, 1.9f, 8, 3, 2.1f}};
    ecm_cluster cl = {.box = 0, .min = {1.9f, 0.9f, 1.9f}, .max = {2.1f, 0.9f, 1.9f}, .centroid = {2, 0.9f, 1.9f},
                      .weight = 50};
    ecm_params p;
    ecm_params_default(&p);
    char err[256];
    const float door2_lo[3] = {5.7f, 0, 1.7f}, door2_hi[3] = {6.3f, 1.8f, 2.3f};
    for (int held = 0; held < 2; held++) {
        cl.held = held;
        ecm_result r;
        int rc = ecm_refine(&p, tris, 60, mbr, 1, &cl, 1, &r, err, sizeof err);
        CHECK(rc == 0, "%s", err);
        check_result(&p, tris, 60, mbr, 1, &cl, 1, &r, 16);
        CHECK(doorway_free(&r), "held %d: the first doorway is still blocked", held);
        int shut = blocked(CBOXES(r.boxes), r.count, door2_lo, door2_hi);
        CHECK(shut == held, "held %d: the second doorway is %s", held, shut ? "shut" : "open");
        ecm_result_free(&r);
    }
}

/* Step 3's cuts: users stopped in front of the doorway (on the MBR's face)
 * want the space in it; three cuts along the faces of that space leave the
 * wall on either side and the lintel above: three boxes, nothing capped,
 * the doorway open and the wall beside it still blocking. */
static void test_doorway_three_cuts(void **state)
{
    (void)state;
    snprintf(check_ctx, sizeof check_ctx, "doorway wall");
    const float box[6] = {0, 0, 1.9f, 4, 3, 2.1f};
    ecm_cluster cl = {.box = 0, .min = {1.9f, 0.9f, 1.9f}, .max = {2.1f, 0.9f, 1.9f}, .centroid = {2, 0.9f, 1.9f}};
    ecm_result r;
    refine_doorway(CBOXES(box), 1, &cl, &r);
    assert_int_equal(r.count, 3);
    assert_int_equal(r.capped, 0);
    assert_true(doorway_free(&r));
    const float wall_lo[3] = {0.5f, 0, 1.7f}, wall_hi[3] = {1.1f, 1.8f, 2.3f};
    assert_true(blocked(CBOXES(r.boxes), r.count, wall_lo, wall_hi));
    ecm_result_free(&r);
}

/* A cluster presses on every box its points lie on, not only the one it
 * names: the doorway wall's map already split at x = 2 into two boxes,
 * users stopped across the split. Both boxes are refined and the whole
 * doorway opens; refining only the named box would leave the other half
 * of the doorway shut. */
static void test_cluster_over_two_boxes(void **state)
{
    (void)state;
    snprintf(check_ctx, sizeof check_ctx, "doorway wall in two boxes");
    const float boxes[2][6] = {{0, 0, 1.9f, 2, 3, 2.1f}, {2, 0, 1.9f, 4, 3, 2.1f}};
    ecm_cluster cl = {.box = 0, .min = {1.8f, 0.9f, 1.9f}, .max = {2.2f, 0.9f, 1.9f}, .centroid = {1.99f, 0.9f, 1.9f}};
    ecm_result r;
    refine_doorway(CBOXES(boxes), 2, &cl, &r);
    assert_int_equal(r.problem_boxes, 2);
    assert_true(doorway_free(&r));
    ecm_result_free(&r);
}

/* ---- the whole object -------------------------------------------------- */

/* ecm_refine, which must succeed, and check_result on what it gives. */
static void refine_ok(const ecm_params *p, const float *tris, uint32_t ntris, const float (*boxes)[6],
                      uint32_t nboxes, const ecm_cluster *cl, uint32_t ncl, ecm_result *r)
{
    char err[256];
    int rc = ecm_refine(p, tris, ntris, boxes, nboxes, cl, ncl, r, err, sizeof err);
    CHECK(rc == 0, "%s", err);
    check_result(p, tris, ntris, boxes, nboxes, cl, ncl, r, 16);
}

/* Walls 1 m high round a 2.6 m square yard (x and z 0..3, 0.2 thick),
 * into t (60 triangles: the near wall at z 0 in two parts, x 0..gap_lo
 * and gap_hi..3; no gap when they meet). */
static void yard_walls(float *t, float gap_lo, float gap_hi)
{
    box_surface((const float[3]){0, 0, 0}, (const float[3]){gap_lo, 1, 0.2f}, t);
    box_surface((const float[3]){gap_hi, 0, 0}, (const float[3]){3, 1, 0.2f}, t + 12 * 9);
    box_surface((const float[3]){0, 0, 2.8f}, (const float[3]){3, 1, 3}, t + 24 * 9);
    box_surface((const float[3]){0, 0, 0.2f}, (const float[3]){0.2f, 1, 2.8f}, t + 36 * 9);
    box_surface((const float[3]){2.8f, 0, 0.2f}, (const float[3]){3, 1, 2.8f}, t + 48 * 9);
}

/* Only places users can walk to are wanted. Users stopped on the near face
 * of a walled yard's box: with no way in (walls 1 m high, steps up to
 * 0.35 m), the yard is no place anyone reaches, and its box stays whole
 * (a gazebo's well spent 45 boxes on the hollow inside its ring wall,
 * while the ring's outer face kept corners a hand's width proud). With a
 * gate in the near wall the yard is walked into, and opened. */
static void test_only_places_users_reach(void **state)
{
    (void)state;
    const float box[6] = {0, 0, 0, 3, 1, 3}, yard[3] = {1.5f, 0.5f, 1.5f};
    const ecm_cluster cl = {.box = 0, .min = {0.5f, 0.9f, 0}, .max = {2.5f, 0.9f, 0},
                            .centroid = {1.5f, 0.9f, 0}, .weight = 100};
    ecm_params p;
    ecm_params_default(&p);
    float tris[60 * 9];
    ecm_result r;
    snprintf(check_ctx, sizeof check_ctx, "closed yard");
    yard_walls(tris, 1.5f, 1.5f);
    refine_ok(&p, tris, 60, CBOXES(box), 1, &cl, 1, &r);
    assert_int_equal(r.wanted, 0);
    assert_int_equal(r.count, 1);
    assert_true(blocked(CBOXES(r.boxes), r.count, yard, yard));
    ecm_result_free(&r);

    snprintf(check_ctx, sizeof check_ctx, "yard with a gate");
    yard_walls(tris, 1.1f, 1.9f);
    refine_ok(&p, tris, 60, CBOXES(box), 1, &cl, 1, &r);
    assert_true(r.wanted > 0);
    assert_false(blocked(CBOXES(r.boxes), r.count, yard, yard));
    const float gate_lo[3] = {1.2f, 0, 0}, gate_hi[3] = {1.8f, 1, 0.2f};
    assert_false(blocked(CBOXES(r.boxes), r.count, gate_lo, gate_hi));
    ecm_result_free(&r);
}

/* Whether an avatar standing in a doorway of doorway_wall, moved dx along
 * x, is free (doorway_free, one place). */
static int door_at_free(const ecm_result *r, float dx)
{
    const float lo[3] = {2 + dx - 0.3f, 0, 1.7f}, hi[3] = {2 + dx + 0.3f, 1.8f, 2.3f};
    return !blocked(CBOXES(r->boxes), r->count, lo, hi);
}

/* Two doorway walls side by side (x 0..4 and 6..10) in one box, users
 * stopped in both doorways. Four boxes open both (one lintel box over
 * both walls); with a cap of 3 only one opens (its lintel, the wall to
 * its left, the rest): the one pressed harder (its cluster's weight),
 * whichever it is. */
static void test_pressure_shares_budget(void **state)
{
    (void)state;
    float tris[72 * 9];
    doorway_wall(tris);
    doorway_wall(tris + 36 * 9);
    for (size_t i = 36 * 3; i < 72 * 3; i++)
        tris[3 * i] += 6;
    const float box[6] = {0, 0, 1.9f, 10, 3, 2.1f};
    for (int heavy = 0; heavy < 2; heavy++) {
        ecm_cluster cl[2];
        for (int d = 0; d < 2; d++) {
            float x = 2 + 6 * (float)d;
            cl[d] = (ecm_cluster){.box = 0, .min = {x - 0.1f, 0.9f, 1.9f}, .max = {x + 0.1f, 0.9f, 1.9f},
                                  .centroid = {x, 0.9f, 1.9f}, .weight = d == heavy ? 40 : 4};
        }
        ecm_params p;
        ecm_params_default(&p);
        ecm_result r;
        snprintf(check_ctx, sizeof check_ctx, "two doorway walls, door %d pressed harder, cap 4", heavy);
        p.max_boxes = 4;
        refine_ok(&p, tris, 72, CBOXES(box), 1, cl, 2, &r);
        CHECK(door_at_free(&r, 0) && door_at_free(&r, 6), "a doorway is shut (%u boxes)", r.count);
        ecm_result_free(&r);
        snprintf(check_ctx, sizeof check_ctx, "two doorway walls, door %d pressed harder, cap 3", heavy);
        p.max_boxes = 3;
        refine_ok(&p, tris, 72, CBOXES(box), 1, cl, 2, &r);
        CHECK(door_at_free(&r, 6 * (float)heavy), "the harder pressed doorway is shut (%u boxes)", r.count);
        CHECK(!door_at_free(&r, 6 * (float)!heavy), "the lighter pressed doorway opened too");
        assert_int_equal(r.capped, 1);
        ecm_result_free(&r);
    }
}

/* The index of the first box holding point c. */
static uint32_t box_at(const ecm_result *r, const float c[3])
{
    for (uint32_t i = 0; i < r->count; i++)
        if (box_within((const float[6]){c[0], c[1], c[2], c[0], c[1], c[2]}, r->boxes[i]))
            return i;
    fail_msg("no box at %g %g %g", (double)c[0], (double)c[1], (double)c[2]);
    return 0;
}

/* Space the map leaves free stays free. Round 1 opens the doorway wall's
 * doorway (three boxes). Round 2: users stopped on the left wall's face
 * and under the lintel press on both their boxes, whose hull holds the
 * doorway; round 3 on the right wall and the lintel. No new box grows back
 * into the doorway, not even by a cell, in any round. */
static void test_outside_stays_open(void **state)
{
    (void)state;
    float tris[36 * 9];
    doorway_wall(tris);
    const float box[6] = {0, 0, 1.9f, 4, 3, 2.1f};
    ecm_params p;
    ecm_params_default(&p);
    ecm_cluster door = {.box = 0, .min = {1.9f, 0.9f, 1.9f}, .max = {2.1f, 0.9f, 1.9f}, .centroid = {2, 0.9f, 1.9f}};
    ecm_result r;
    snprintf(check_ctx, sizeof check_ctx, "doorway wall, round 1");
    refine_ok(&p, tris, 36, CBOXES(box), 1, &door, 1, &r);
    assert_true(doorway_free(&r));
    const float sides[2][3] = {{0.75f, 1, 1.9f}, {3.25f, 1, 1.9f}}, lintel[3] = {2, 2.6f, 1.9f};
    const ecm_result first = r;
    for (int round = 0; round < 2; round++) {
        ecm_cluster cl[2] = {
            {.box = box_at(&r, sides[round]), .min = {sides[round][0], 0.5f, 1.9f},
             .max = {sides[round][0], 1.5f, 1.9f}, .centroid = {sides[round][0], 1, 1.9f}, .weight = 5},
            {.box = box_at(&r, lintel), .min = {1.8f, 2.6f, 1.9f}, .max = {2.2f, 2.6f, 1.9f},
             .centroid = {2, 2.6f, 1.9f}, .weight = 5}};
        ecm_result next;
        snprintf(check_ctx, sizeof check_ctx, "doorway wall, round %d", round + 2);
        refine_ok(&p, tris, 36, CBOXES(r.boxes), r.count, cl, 2, &next);
        CHECK(next.problem_boxes >= 2, "%u problem boxes", next.problem_boxes);
        /* Every point of the wall's plane that round 1 left free is free. */
        for (int i = 0; i <= 400; i++)
            for (int j = 0; j <= 300; j++) {
                const float q[6] = {(float)i / 100, (float)j / 100, 2, (float)i / 100, (float)j / 100, 2};
                int was = 0, is = 0;
                for (uint32_t b = 0; b < first.count; b++)
                    was |= box_within(q, first.boxes[b]);
                for (uint32_t b = 0; b < next.count; b++)
                    is |= box_within(q, next.boxes[b]);
                CHECK(was || !is, "a box grew back to %g %g", (double)q[0], (double)q[1]);
            }
        if (round)
            ecm_result_free(&r);
        r = next;
    }
    ecm_result_free(&r);
    ecm_result free_first = first;
    ecm_result_free(&free_first);
}

/* Boxes of different problem boxes merge: a cube [1, 3]^3 that an earlier
 * round's border at x = 2 cut in two boxes, users stopped on both boxes'
 * faces above it. One box covers the cube again, across the border (the
 * old rule kept one per problem box: two). */
static void test_merge_across_borders(void **state)
{
    (void)state;
    snprintf(check_ctx, sizeof check_ctx, "cube across a border");
    float tris[12 * 9];
    box_surface((const float[3]){1, 1, 1}, (const float[3]){3, 3, 3}, tris);
    const float boxes[2][6] = {{0, 0, 0, 2, 4, 4}, {2, 0, 0, 4, 4, 4}};
    ecm_cluster cl = {.box = 0, .min = {1.5f, 3.5f, 0}, .max = {2.5f, 3.5f, 0}, .centroid = {2, 3.5f, 0}};
    ecm_params p;
    ecm_params_default(&p);
    p.avatar[0] = p.avatar[1] = p.avatar[2] = 0.5f;
    ecm_result r;
    refine_ok(&p, tris, 12, CBOXES(boxes), 2, &cl, 1, &r);
    assert_int_equal(r.problem_boxes, 2);
    assert_int_equal(r.count, 1);
    assert_true(box_near(r.boxes[0], (const float[6]){1, 1, 1, 3, 3, 3}));
    ecm_result_free(&r);
}

/* The step (the garage): a base 0.3 m high (x 0..2, z 0..2) under a roof
 * plate at y 2.5 (x -1..2); an earlier round left the base and the space
 * in front of it in one box (y up to 1.9) and a coarse roof box above it,
 * from y 1.9. Users stopped on the front box's face x = -1 could step onto
 * the base (0.3 < the 0.35 m step) and would hit the roof box with their
 * heads; so the roof box is pressed too (an avatar there reaches it), and
 * the wanted region grows up by the step over the base (something to
 * stand on): an avatar standing on the base is free. (The old rule
 * refined the front box alone: the base became a box of its own, and the
 * roof box stayed at 1.9.) */
static void test_step_onto_base(void **state)
{
    (void)state;
    snprintf(check_ctx, sizeof check_ctx, "base under a roof box");
    float tris[14 * 9];
    box_surface((const float[3]){0, 0, 0}, (const float[3]){2, 0.3f, 2}, tris);
    const float plate[2 * 9] = {-1, 2.5f, 0, 2, 2.5f, 0, 2, 2.5f, 2, -1, 2.5f, 0, 2, 2.5f, 2, -1, 2.5f, 2};
    memcpy(tris + 12 * 9, plate, sizeof plate);
    const float boxes[2][6] = {{-1, 0, 0, 2, 1.9f, 2}, {-1, 1.9f, 0, 2, 2.5f, 2}};
    ecm_cluster cl = {.box = 0, .min = {-1, 0.9f, 0.8f}, .max = {-1, 0.9f, 1.2f}, .centroid = {-1, 0.9f, 1}};
    ecm_params p;
    ecm_params_default(&p);
    ecm_result r;
    refine_ok(&p, tris, 14, CBOXES(boxes), 2, &cl, 1, &r);
    assert_int_equal(r.problem_boxes, 2);
    const float on_lo[3] = {0.2f, 0.31f, 0.7f}, on_hi[3] = {0.8f, 2.11f, 1.3f};
    CHECK(!blocked(CBOXES(r.boxes), r.count, on_lo, on_hi), "an avatar on the base hits a box");
    ecm_result_free(&r);

    /* The same with the roof plate at 2.0: an avatar fits in front (1.8)
     * but not on the base (2.1), so nothing over the base is wanted and
     * the roof's box still reaches below 2.1 there. */
    for (int i = 12 * 9; i < 14 * 9; i += 3)
        tris[i + 1] = 2.0f;
    const float low[2][6] = {{-1, 0, 0, 2, 1.9f, 2}, {-1, 1.9f, 0, 2, 2.0f, 2}};
    refine_ok(&p, tris, 14, CBOXES(low), 2, &cl, 1, &r);
    const float front_lo[3] = {-0.95f, 0.01f, 0.7f}, front_hi[3] = {-0.35f, 1.81f, 1.3f};
    CHECK(!blocked(CBOXES(r.boxes), r.count, front_lo, front_hi), "an avatar in front hits a box");
    CHECK(blocked(CBOXES(r.boxes), r.count, on_lo, on_hi), "the roof plate at 2.0 stopped blocking");
    ecm_result_free(&r);
}

/* No avatar stands below the world's floor. A table 0.7 m high (a top
 * x, z 0..2, legs 0.1 m square at its corners) that users stopped at its
 * near face: nobody fits under it, so nothing there is wanted and its box
 * stays whole. Without a floor, avatars sunk to the waist below the grid
 * reached the space between the legs (a spiral stair's treads: 12% of the
 * wanted cells), and the division opened it. */
static void test_no_one_stands_below_the_floor(void **state)
{
    (void)state;
    float tris[60 * 9];
    box_surface((const float[3]){0, 0.7f, 0}, (const float[3]){2, 0.8f, 2}, tris);
    for (int i = 0; i < 4; i++) {
        float x = i & 1 ? 1.9f : 0, z = i & 2 ? 1.9f : 0;
        box_surface((const float[3]){x, 0, z}, (const float[3]){x + 0.1f, 0.7f, z + 0.1f}, tris + (1 + i) * 12 * 9);
    }
    const float box[6] = {0, 0, 0, 2, 0.8f, 2}, under[3] = {1, 0.3f, 1};
    const ecm_cluster cl = {.box = 0, .min = {0.5f, 0.4f, 0}, .max = {1.5f, 0.8f, 0},
                            .centroid = {1, 0.6f, 0}, .weight = 100};
    ecm_params p;
    ecm_params_default(&p);
    ecm_result r;
    snprintf(check_ctx, sizeof check_ctx, "table on the floor");
    p.floor = 0;
    refine_ok(&p, tris, 60, CBOXES(box), 1, &cl, 1, &r);
    CHECK(r.wanted == 0, "%llu cells wanted", (unsigned long long)r.wanted);
    CHECK(r.count == 1, "%u boxes", r.count);
    ecm_result_free(&r);

    snprintf(check_ctx, sizeof check_ctx, "table with no floor");
    p.floor = -INFINITY;
    refine_ok(&p, tris, 60, CBOXES(box), 1, &cl, 1, &r);
    CHECK(r.wanted > 0, "nothing wanted");
    CHECK(!blocked(CBOXES(r.boxes), r.count, under, under), "the space under the table stayed shut");
    ecm_result_free(&r);

    char err[256];
    p.floor = NAN;
    CHECK(ecm_refine(&p, tris, 60, CBOXES(box), 1, &cl, 1, &r, err, sizeof err) == -EINVAL, "a NaN floor passed");
    assert_non_null(strstr(err, "floor"));
}

/* A thick wall (z 1.9..3.1) with a doorway tunnel through it (x 1.5..2.5,
 * y up to 2.2), its right half set back to z = 1.95, in a map of two boxes
 * split at x = 2; users stopped in front of the named left box, close to
 * the split. The face users cross is the named box's (z), in the right box
 * too, although the centroid is nearer that box's x = 2 face than its set
 * back z face: stretched along x instead, the right box's wanted space
 * would end 0.3 m into the tunnel and the far end would stay shut. */
static void test_neighbour_uses_the_named_face(void **state)
{
    (void)state;
    snprintf(check_ctx, sizeof check_ctx, "thick wall, set back");
    float tris[48 * 9];
    box_surface((const float[3]){0, 0, 1.9f}, (const float[3]){1.5f, 3, 3.1f}, tris);
    box_surface((const float[3]){2.5f, 0, 1.95f}, (const float[3]){4, 3, 3.1f}, tris + 12 * 9);
    box_surface((const float[3]){1.5f, 2.2f, 1.9f}, (const float[3]){2, 3, 3.1f}, tris + 24 * 9);
    box_surface((const float[3]){2, 2.2f, 1.95f}, (const float[3]){2.5f, 3, 3.1f}, tris + 36 * 9);
    const float boxes[2][6] = {{0, 0, 1.9f, 2, 3, 3.1f}, {2, 0, 1.95f, 4, 3, 3.1f}};
    ecm_cluster cl = {.box = 0, .min = {1.8f, 0.9f, 1.9f}, .max = {2.2f, 0.9f, 1.95f}, .centroid = {1.98f, 0.9f, 1.9f}};
    ecm_params p;
    ecm_params_default(&p);
    ecm_result r;
    char err[256];
    assert_int_equal(ecm_refine(&p, tris, 48, CBOXES(boxes), 2, &cl, 1, &r, err, sizeof err), 0);
    check_result(&p, tris, 48, CBOXES(boxes), 2, &cl, 1, &r, 16);
    assert_int_equal(r.problem_boxes, 2);
    for (int k = 0; k < 3; k++) { /* the tunnel, front to back */
        const float z = 2.2f + 0.3f * (float)k;
        const float lo[3] = {1.7f, 0, z - 0.3f}, hi[3] = {2.3f, 1.8f, z + 0.3f};
        CHECK(!blocked(CBOXES(r.boxes), r.count, lo, hi), "avatar at z %g blocked", (double)z);
    }
    ecm_result_free(&r);
}

/*
 * Step 2 by numbers. A cluster on the x = 0 face, its points y 1.5..2.5,
 * z 2..2.5, the avatar 2 x 1 x 0.5: grown by half the avatar (horizontally
 * the smaller of x and z, 0.5, whatever the yaw) and upwards by one cell
 * more, to y 1..3.125, stretched through the box along x, and across it
 * along z (the face's horizontal axis, beside the points at a sixteenth of
 * the pressure): 32 x 17 x 32 cells, less the 81 cells of cube a's top
 * (layer 8) and the 2 x 81 of cube b's bottom (layers 23 and 24 both
 * touch y = 3): 17165, all wanted. A point cluster on the y = 0 face at
 * x = z = 2 is stretched along y instead, and not sideways: 4 x 32 x 4 =
 * 512.
 */
static void test_wanted_region(void **state)
{
    (void)state;
    snprintf(check_ctx, sizeof check_ctx, "two cubes");
    float tris[24 * 9];
    two_cubes(tris);
    const float box[6] = {0, 0, 0, 4, 4, 4};
    ecm_params p;
    ecm_params_default(&p);
    p.depth = 5;
    p.avatar[0] = 2;
    p.avatar[1] = 1;
    p.avatar[2] = 0.5f;
    p.step = 0; /* no step band: test_step_band */
    ecm_cluster on_x = {.box = 0, .min = {0, 1.5f, 2}, .max = {0, 2.5f, 2.5f}, .centroid = {0, 2, 2.25f}};
    ecm_cluster on_y = {.box = 0, .min = {2, 0, 2}, .max = {2, 0, 2}, .centroid = {2, 0, 2}};
    ecm_result r;
    char err[256];
    assert_int_equal(ecm_refine(&p, tris, 24, CBOXES(box), 1, &on_x, 1, &r, err, sizeof err), 0);
    check_result(&p, tris, 24, CBOXES(box), 1, &on_x, 1, &r, 16);
    assert_int_equal(r.wanted, 32 * 17 * 32 - 3 * 81);
    /* Each cube is left in a box of its own, tightened to its triangles
     * (its cells reach one layer further on each side). */
    assert_int_equal(r.count, 2);
    assert_int_equal(r.capped, 0);
    const float a[6] = {0, 0, 0, 1, 1, 1}, b[6] = {3, 3, 3, 4, 4, 4};
    assert_true(box_near(r.boxes[0], a) || box_near(r.boxes[1], a));
    assert_true(box_near(r.boxes[0], b) || box_near(r.boxes[1], b));
    ecm_result_free(&r);

    assert_int_equal(ecm_refine(&p, tris, 24, CBOXES(box), 1, &on_y, 1, &r, err, sizeof err), 0);
    check_result(&p, tris, 24, CBOXES(box), 1, &on_y, 1, &r, 16);
    assert_int_equal(r.wanted, 4 * 32 * 4);
    assert_int_equal(r.count, 2);
    ecm_result_free(&r);

    /* Space outside the grid is free. A plate at y = 0.25 over the whole
     * box (its cells: y layers 1 and 2), the avatar 2 x 2 x 2 (its kernel
     * held to a quarter of the grid, 8 cells), a cluster on the x = 0 face
     * at y = 0.1, z = 2: the region is y layers 0..9, all of z. Below the
     * plate layer 0 is wanted, a kernel there reaching down out of the
     * box. Above it layers 3..9 would be too (the kernel reaches up into the
     * free space above the region), but without a step (step 0) no user
     * stopped under the plate gets up there: nobody walks to it. */
    snprintf(check_ctx, sizeof check_ctx, "low plate");
    const float plate[2 * 9] = {0, 0.25f, 0, 4, 0.25f, 0, 4, 0.25f, 4, 0, 0.25f, 0, 4, 0.25f, 4, 0, 0.25f, 4};
    ecm_cluster low = {.box = 0, .min = {0, 0.1f, 2}, .max = {0, 0.1f, 2}, .centroid = {0, 0.1f, 2}};
    p.avatar[0] = p.avatar[1] = p.avatar[2] = 2;
    assert_int_equal(ecm_refine(&p, plate, 2, CBOXES(box), 1, &low, 1, &r, err, sizeof err), 0);
    check_result(&p, plate, 2, CBOXES(box), 1, &low, 1, &r, 16);
    assert_int_equal(r.wanted, 32 * 32);
    ecm_result_free(&r);
}

/* The same two cubes: their box divides into exactly two boxes, so a cap
 * of 2 frees the space between them and a cap of 1 keeps the one box
 * whole, capped. */
static void test_cap_exact(void **state)
{
    (void)state;
    snprintf(check_ctx, sizeof check_ctx, "two cubes, exact cap");
    float tris[24 * 9];
    two_cubes(tris);
    const float box[6] = {0, 0, 0, 4, 4, 4};
    ecm_params p;
    ecm_params_default(&p);
    p.depth = 5;
    p.avatar[0] = p.avatar[1] = p.avatar[2] = 0.5f;
    ecm_cluster cl = {.box = 0, .min = {0, 2, 2}, .max = {0, 2, 2}, .centroid = {0, 2, 2}};
    ecm_result r;
    char err[256];
    p.max_boxes = 2;
    assert_int_equal(ecm_refine(&p, tris, 24, CBOXES(box), 1, &cl, 1, &r, err, sizeof err), 0);
    check_result(&p, tris, 24, CBOXES(box), 1, &cl, 1, &r, 16);
    assert_int_equal(r.count, 2);
    assert_int_equal(r.capped, 0);
    const float mid_lo[3] = {0, 1.75f, 1.75f}, mid_hi[3] = {4, 2.25f, 2.25f};
    assert_false(blocked(CBOXES(r.boxes), r.count, mid_lo, mid_hi));
    ecm_result_free(&r);

    p.max_boxes = 1;
    assert_int_equal(ecm_refine(&p, tris, 24, CBOXES(box), 1, &cl, 1, &r, err, sizeof err), 0);
    check_result(&p, tris, 24, CBOXES(box), 1, &cl, 1, &r, 16);
    assert_int_equal(r.count, 1);
    assert_int_equal(r.capped, 1);
    assert_memory_equal(r.boxes[0], box, sizeof box);
    assert_true(blocked(CBOXES(r.boxes), r.count, mid_lo, mid_hi));
    ecm_result_free(&r);

    /* Two copies of the object side by side, both pressed on, a cap of 2:
     * the two boxes are shared by the whole object, not one per problem
     * box: each pairs a cube of one copy with the same cube of the other,
     * across the border between the copies' boxes, and both openings stay
     * free (the old rule gave each copy one box, both closed). */
    const float boxes2[2][6] = {{0, 0, 0, 4, 4, 4}, {4, 0, 0, 8, 4, 4}};
    float tris2[48 * 9];
    memcpy(tris2, tris, sizeof tris);
    for (int i = 0; i < 24 * 3; i++) {
        memcpy(tris2 + 24 * 9 + 3 * i, tris + 3 * i, 3 * sizeof *tris);
        tris2[24 * 9 + 3 * i] += 4;
    }
    ecm_cluster cl2[2] = {cl, cl};
    cl2[1].box = 1;
    cl2[1].min[0] = cl2[1].max[0] = cl2[1].centroid[0] = 4;
    p.max_boxes = 2;
    assert_int_equal(ecm_refine(&p, tris2, 48, CBOXES(boxes2), 2, cl2, 2, &r, err, sizeof err), 0);
    check_result(&p, tris2, 48, CBOXES(boxes2), 2, cl2, 2, &r, 16);
    assert_int_equal(r.count, 2);
    assert_int_equal(r.capped, 0);
    const float both_lo[3] = {0, 1.75f, 1.75f}, both_hi[3] = {8, 2.25f, 2.25f};
    assert_false(blocked(CBOXES(r.boxes), r.count, both_lo, both_hi));
    assert_true(box_near(r.boxes[0], (const float[6]){0, 0, 0, 5, 1, 1}) ||
                box_near(r.boxes[1], (const float[6]){0, 0, 0, 5, 1, 1}));
    ecm_result_free(&r);
}

/* ---- merging ----------------------------------------------------------- */

/*
 * Step 4 by numbers. Cubes A [0,0.4]^3, B [3.6,4] x [0,0.4]^2 and C [0,0.4]
 * x [3.6,4]^2 in [0,4]^3 (depth 5: each cube lies in 4^3 cells, its 2^3
 * inner ones empty; too small inside for the 0.5 avatar, so never wanted).
 * Two clusters, on the x = 0 face and on the floor (whose regions are not
 * widened sideways), want everything at y >= 1.25, and at z >= 2.25:
 * wanted cells reach every face. The plane that frees the most of them is
 * y = 0.4 (z = 0.4 frees as much): A and B in one box, C in another, and
 * nothing wanted is left. Their box, 90% empty, stays whole at any
 * max_empty: no one wants that space, and merging only decides between
 * boxes the division made. Halving the longest side (x = 2, then y = 2)
 * took three boxes here, and on a spiral stair's treads it spent the
 * budget on halves that freed little.
 */
static void test_cut_frees_the_most(void **state)
{
    (void)state;
    snprintf(check_ctx, sizeof check_ctx, "three cubes");
    float tris[36 * 9];
    box_surface((const float[3]){0, 0, 0}, (const float[3]){0.4f, 0.4f, 0.4f}, tris);
    box_surface((const float[3]){3.6f, 0, 0}, (const float[3]){4, 0.4f, 0.4f}, tris + 12 * 9);
    box_surface((const float[3]){0, 3.6f, 3.6f}, (const float[3]){0.4f, 4, 4}, tris + 24 * 9);
    const float box[6] = {0, 0, 0, 4, 4, 4}, ab[6] = {0, 0, 0, 4, 0.4f, 0.4f}, c[6] = {0, 3.6f, 3.6f, 0.4f, 4, 4};
    const ecm_cluster cl[2] = {
        {.box = 0, .min = {0, 1.5f, 0}, .max = {0, 4, 4}, .centroid = {0, 2.75f, 2}},
        {.box = 0, .min = {0, 0, 2.5f}, .max = {4, 0, 4}, .centroid = {2, 0, 3.25f}}};
    const double max_empty[] = {0, 1};
    for (size_t i = 0; i < NELEM(max_empty); i++) {
        ecm_params p;
        ecm_params_default(&p);
        p.depth = 5;
        p.avatar[0] = p.avatar[1] = p.avatar[2] = 0.5f;
        p.step = 4; /* the users on the x = 0 face stand in the air: let them walk anywhere */
        p.max_empty = max_empty[i];
        ecm_result r;
        char err[256];
        assert_int_equal(ecm_refine(&p, tris, 36, CBOXES(box), 1, cl, 2, &r, err, sizeof err), 0);
        check_result(&p, tris, 36, CBOXES(box), 1, cl, 2, &r, 16);
        CHECK(r.count == 2 && r.capped == 0, "max_empty %g: %u boxes, %u capped", max_empty[i], r.count, r.capped);
        assert_true(box_near(r.boxes[0], ab) || box_near(r.boxes[1], ab));
        assert_true(box_near(r.boxes[0], c) || box_near(r.boxes[1], c));
        const float lo[3] = {0, 1.5f, 0.5f}, hi[3] = {4, 3.5f, 3.5f}, lo2[3] = {0.5f, 0, 2.5f},
                    hi2[3] = {3.5f, 1, 3.5f};
        assert_false(blocked(CBOXES(r.boxes), r.count, lo, hi));
        assert_false(blocked(CBOXES(r.boxes), r.count, lo2, hi2));
        ecm_result_free(&r);
    }
}

/*
 * Step 5's merges of slivers. Cubes A [0,0.4]^2 x [1.2,1.6], B [0.8,1.2] x
 * [2,2.4] x [0.8,1.2] and C [0.4,0.8] x [1.6,2] x [1.2,1.6], B and C
 * meeting at a corner (B's bottom face and C's top face on the plane
 * y = 2); users stopped on the x = 0 face (depth 5, 0.075 cells along y).
 * The division leaves a flat box holding both faces, x 0.4..1.2, z
 * 0.8..1.6, and beside it B's bottom slab, a third of a cell high: their
 * hull is 0.8 x 0.025 x 0.8, of which the slab fills a quarter, so they
 * merge (six boxes become five) only when max_empty allows three
 * quarters of new empty space.
 */
static void test_merge_max_empty(void **state)
{
    (void)state;
    snprintf(check_ctx, sizeof check_ctx, "slivers");
    float tris[36 * 9];
    box_surface((const float[3]){0, 0, 1.2f}, (const float[3]){0.4f, 0.4f, 1.6f}, tris);
    box_surface((const float[3]){0.8f, 2, 0.8f}, (const float[3]){1.2f, 2.4f, 1.2f}, tris + 12 * 9);
    box_surface((const float[3]){0.4f, 1.6f, 1.2f}, (const float[3]){0.8f, 2, 1.6f}, tris + 24 * 9);
    const float box[6] = {0, 0, 0.8f, 1.2f, 2.4f, 1.6f}, merged[6] = {0.4f, 2, 0.8f, 1.2f, 2.025f, 1.6f};
    const ecm_cluster cl = {.box = 0, .min = {0, 0.6f, 1.38f}, .max = {0, 1.32f, 1.39f}, .centroid = {0, 0.96f, 1.385f}};
    static const struct {
        double max_empty;
        uint32_t count;
    } cases[] = {{0, 6}, {0.74, 6}, {0.76, 5}, {1, 5}};
    for (size_t i = 0; i < NELEM(cases); i++) {
        ecm_params p;
        ecm_params_default(&p);
        p.depth = 5;
        p.avatar[0] = p.avatar[1] = p.avatar[2] = 0.5f;
        p.step = 4;
        p.max_empty = cases[i].max_empty;
        ecm_result r;
        char err[256];
        assert_int_equal(ecm_refine(&p, tris, 36, CBOXES(box), 1, &cl, 1, &r, err, sizeof err), 0);
        check_result(&p, tris, 36, CBOXES(box), 1, &cl, 1, &r, 16);
        CHECK(r.count == cases[i].count && r.capped == 0, "max_empty %g: %u boxes (%u capped), expected %u",
              cases[i].max_empty, r.count, r.capped, cases[i].count);
        int found = 0; /* the box, to tightening's margins */
        for (uint32_t j = 0; j < r.count; j++) {
            int near = 1;
            for (int a = 0; a < 6; a++)
                near &= fabsf(r.boxes[j][a] - merged[a]) < 1e-5f;
            found |= near;
        }
        CHECK(found == (cases[i].count == 5), "max_empty %g: the merged sliver %s", cases[i].max_empty,
              found ? "is there" : "is not there");
        ecm_result_free(&r);
    }
}

/* ---- the cap ----------------------------------------------------------- */

/* Avatar-sized boxes in the room's doorway (see test_room_door_opens_...). */
static int room_door_free(const ecm_result *r)
{
    for (float x = -0.6f; x <= 0.6f; x += 0.2f) {
        float lo[3] = {x - 0.3f, 0.03f, -1.965f - 0.3f}, hi[3] = {x + 0.3f, 1.83f, -1.965f + 0.3f};
        if (blocked(CBOXES(r->boxes), r->count, lo, hi))
            return 0;
    }
    return 1;
}

static const ecm_cluster room_door = {.box = 0,
                                      .min = {0.217568f, 0.9f, -1.965f},
                                      .max = {0.217568f, 0.9f, -1.965f},
                                      .centroid = {0.217568f, 0.9f, -1.965f}};

/* Caps of 1 and 2 boxes, half and one less than the model wants: the
 * count stays under the cap, capped says the cap bit, the invariant holds. */
static void cap_model(const char *rel, int z_up, const ecm_cluster *cl, uint32_t ncl)
{
    import_mesh m = load(rel, z_up);
    float box[6];
    mbr(m.tris, m.ntris, box);
    ecm_cluster *c = malloc(ncl * sizeof *c);
    assert_non_null(c);
    memcpy(c, cl, ncl * sizeof *c);
    ecm_params p;
    ecm_params_default(&p);
    ecm_result r;
    /* At the default cap first: it wants at least 3 boxes. */
    snprintf(check_ctx, sizeof check_ctx, "%s at the default cap", rel);
    refine_model(&p, &m, CBOXES(box), 1, c, ncl, &r);
    uint32_t free_count = r.count;
    assert_true(r.wanted > 0);
    assert_true(free_count >= 3);
    ecm_result_free(&r);

    const uint32_t caps[] = {1, 2, free_count / 2, free_count - 1};
    for (size_t i = 0; i < NELEM(caps); i++) {
        p.max_boxes = caps[i];
        snprintf(check_ctx, sizeof check_ctx, "%s capped at %u", rel, caps[i]);
        refine_model(&p, &m, CBOXES(box), 1, c, ncl, &r);
        assert_in_range(r.count, 1, caps[i]);
        /* The cap bit: the boxes left hold wanted cells, unless so few
         * boxes can still steer clear of them (then capped is 0). */
        CHECK(r.capped <= r.count, "capped %u of %u boxes (%u at the default cap)", r.capped, r.count,
              free_count);
        if (caps[i] == 1) {
            /* The tight MBR shrinks to itself: one box, the MBR, kept
             * whole by the cap, its wanted space still in it. */
            assert_memory_equal(r.boxes[0], box, sizeof box);
            assert_int_equal(r.capped, 1);
            assert_true(r.wanted > 0);
        }
        ecm_result_free(&r);
    }
    free(c);
    import_mesh_free(&m);
}

static void test_cap(void **state)
{
    (void)state;
    cap_model("openings/openfoam_room_with_doorway.stl", 1, &room_door, 1);
    import_mesh m = load("openings/kenney_building-garage.glb", 0);
    float box[6];
    mbr(m.tris, m.ntris, box);
    ecm_cluster cl[7];
    face_clusters(box, 0, cl);
    import_mesh_free(&m);
    cap_model("openings/kenney_building-garage.glb", 0, cl, 7);

    /* At one box the room's door stays closed; at the limit it opens,
     * and nothing is capped. */
    m = load("openings/openfoam_room_with_doorway.stl", 1);
    mbr(m.tris, m.ntris, box);
    ecm_params p;
    ecm_params_default(&p);
    ecm_result r;
    char err[256];
    p.max_boxes = 1;
    assert_int_equal(ecm_refine(&p, m.tris, m.ntris, CBOXES(box), 1, &room_door, 1, &r, err, sizeof err), 0);
    assert_false(room_door_free(&r));
    ecm_result_free(&r);
    p.max_boxes = ECM_MAX_BOXES_LIMIT;
    assert_int_equal(ecm_refine(&p, m.tris, m.ntris, CBOXES(box), 1, &room_door, 1, &r, err, sizeof err), 0);
    assert_int_equal(r.capped, 0);
    assert_true(room_door_free(&r));
    ecm_result_free(&r);
    import_mesh_free(&m);
}

/* An object whose kept boxes already fill the cap: the room's MBR cut into
 * eight octants, clusters on three (the door's octant, the one above it
 * and the opposite one). With max_boxes up to 6 (five kept boxes) the
 * problem boxes are only tightened: never more boxes than the object had;
 * with 7 the two left are not enough to free everything wanted; with 10
 * more is free; with 64 everything. */
static void test_cap_kept_boxes_over_cap(void **state)
{
    (void)state;
    import_mesh m = load("openings/openfoam_room_with_doorway.stl", 1);
    float box[6], oct[8][6];
    mbr(m.tris, m.ntris, box);
    for (int o = 0; o < 8; o++)
        for (int a = 0; a < 3; a++) {
            float mid = (float)(((double)box[a] + box[3 + a]) / 2);
            oct[o][a] = (o >> a) & 1 ? mid : box[a];
            oct[o][3 + a] = (o >> a) & 1 ? box[3 + a] : mid;
        }
    /* The door (x max, y low, z max) is in octant 1 + 4 = 5. */
    assert_true(box_within((const float[6]){room_door.centroid[0], room_door.centroid[1], room_door.centroid[2],
                                            room_door.centroid[0], room_door.centroid[1], room_door.centroid[2]},
                           oct[5]));
    /* The octant above the door's is pressed too: with it kept, no avatar
     * fits in the door's octant (1.4 m high), so nothing there is wanted. */
    ecm_cluster cl[3] = {room_door, room_door};
    cl[0].box = 5;
    cl[1].box = 7;
    ecm_cluster far[7];
    face_clusters(oct[2], 2, far);
    cl[2] = far[0];
    static const uint32_t caps[] = {1, 3, 5, 6, 7, 10, 64};
    for (size_t i = 0; i < NELEM(caps); i++) {
        ecm_params p;
        ecm_params_default(&p);
        p.max_boxes = caps[i];
        ecm_result r;
        snprintf(check_ctx, sizeof check_ctx, "room in octants, cap %u", caps[i]);
        refine_model(&p, &m, CBOXES(oct), 8, cl, 3, &r);
        assert_in_range(r.count, 5, caps[i] > 8 ? caps[i] : 8);
        if (caps[i] <= 6) {
            /* Two problem octants touch, the third is apart: at most one
             * box left for them cannot keep the kept octants' space out. */
            assert_int_equal(r.count, 8);
            assert_int_equal(r.capped, 3);
        } else if (caps[i] == 7) {
            /* Only what users walk to from the door is wanted: it fits. */
            assert_int_equal(r.count, 7);
            assert_int_equal(r.capped, 0);
        } else if (caps[i] == 10) {
            assert_true(r.count > 8 && r.capped < 3);
        } else {
            assert_int_equal(r.capped, 0);
        }
        ecm_result_free(&r);
    }
    import_mesh_free(&m);
}

/* ---- determinism ------------------------------------------------------- */

/* The same input, the same boxes: twice, and on one thread or beside a
 * second (the tasks and the digitizing slabs: the bunny has enough
 * triangles for those). */
static void test_deterministic(void **state)
{
    (void)state;
    ecm_params p, one;
    ecm_params_default(&p);
    one = p;
    p.threads = 2;
    one.threads = 1;
    ecm_result a, b;
    char err[256];
    ecm_cluster cl[7];
    float box[6];
    import_mesh bunny = load("classic/stanford-bunny.obj", 0);
    mbr(bunny.tris, bunny.ntris, box);
    face_clusters(box, 0, cl);
    assert_int_equal(ecm_refine(&p, bunny.tris, bunny.ntris, CBOXES(box), 1, cl, 7, &a, err, sizeof err), 0);
    assert_int_equal(ecm_refine(&one, bunny.tris, bunny.ntris, CBOXES(box), 1, cl, 7, &b, err, sizeof err), 0);
    assert_true(a.count > 1);
    assert_results_equal(&a, &b);
    ecm_result_free(&a);
    ecm_result_free(&b);
    import_mesh_free(&bunny);

    import_mesh m = load("openings/kenney_building-garage.glb", 0);
    mbr(m.tris, m.ntris, box);
    face_clusters(box, 0, cl);
    assert_int_equal(ecm_refine(&p, m.tris, m.ntris, CBOXES(box), 1, cl, 7, &a, err, sizeof err), 0);
    assert_int_equal(ecm_refine(&one, m.tris, m.ntris, CBOXES(box), 1, cl, 7, &b, err, sizeof err), 0);
    assert_results_equal(&a, &b);
    ecm_result_free(&b);
    /* Round 2 twice, from the same version 2. */
    ecm_cluster c2 = cl[1];
    c2.box = a.count / 2;
    memcpy(c2.centroid, a.boxes[c2.box], sizeof c2.centroid);
    memcpy(c2.min, c2.centroid, sizeof c2.min);
    memcpy(c2.max, c2.centroid, sizeof c2.max);
    ecm_result a2, b2;
    assert_int_equal(ecm_refine(&p, m.tris, m.ntris, CBOXES(a.boxes), a.count, &c2, 1, &a2, err, sizeof err), 0);
    assert_int_equal(ecm_refine(&p, m.tris, m.ntris, CBOXES(a.boxes), a.count, &c2, 1, &b2, err, sizeof err), 0);
    assert_results_equal(&a2, &b2);
    ecm_result_free(&a2);
    ecm_result_free(&b2);
    ecm_result_free(&a);
    import_mesh_free(&m);

    /* A random soup in eight boxes, clusters on three. */
    rng r = {77};
    float sb[6] = {-1, -1, -1, 1, 1, 1}, oct[8][6], tris[200 * 9];
    for (int t = 0; t < 200; t++)
        random_tri(&r, sb, 6, tris + 9 * t);
    for (int o = 0; o < 8; o++)
        for (int k = 0; k < 3; k++) {
            oct[o][k] = (o >> k) & 1 ? 0 : sb[k];
            oct[o][3 + k] = (o >> k) & 1 ? sb[3 + k] : 0;
        }
    ecm_cluster sc[3] = {random_cluster(&r, oct[6], 6), random_cluster(&r, oct[1], 1), random_cluster(&r, oct[3], 3)};
    p.depth = 6;
    p.avatar[0] = p.avatar[1] = p.avatar[2] = 0.15f;
    assert_int_equal(ecm_refine(&p, tris, 200, CBOXES(oct), 8, sc, 3, &a, err, sizeof err), 0);
    assert_int_equal(ecm_refine(&p, tris, 200, CBOXES(oct), 8, sc, 3, &b, err, sizeof err), 0);
    assert_results_equal(&a, &b);
    ecm_result_free(&a);
    ecm_result_free(&b);
}

/* ---- bad input --------------------------------------------------------- */

/* A valid call on a cube, to be spoiled one argument at a time. */
typedef struct call {
    ecm_params p;
    float tris[12 * 9];
    const float *tp;
    uint32_t ntris;
    float boxes[2][6];
    const float (*bp)[6];
    uint32_t nboxes;
    ecm_cluster cl[7];
    uint32_t ncl;
} call;

static void call_init(call *c)
{
    memset(c, 0, sizeof *c);
    ecm_params_default(&c->p);
    c->p.depth = 4;
    box_surface((const float[3]){0, 0, 0}, (const float[3]){2, 2, 2}, c->tris);
    c->tp = c->tris;
    c->ntris = 12;
    const float b0[6] = {0, 0, 0, 1, 2, 2}, b1[6] = {1, 0, 0, 2, 2, 2};
    memcpy(c->boxes[0], b0, sizeof b0);
    memcpy(c->boxes[1], b1, sizeof b1);
    c->bp = CBOXES(c->boxes);
    c->nboxes = 2;
    face_clusters(c->boxes[1], 1, c->cl); /* the first two of them */
    c->ncl = 2;
}

static int call_run(const call *c, ecm_result *r, char *err, size_t errlen)
{
    memset(r, 0xab, sizeof *r);
    return ecm_refine(&c->p, c->tp, c->ntris, c->bp, c->nboxes, c->cl, c->ncl, r, err, errlen);
}

static void expect_einval(const call *c, const char *what)
{
    ecm_result r;
    char err[256];
    memset(err, 0, sizeof err);
    snprintf(check_ctx, sizeof check_ctx, "bad input: %s", what);
    int rc = call_run(c, &r, err, sizeof err);
    CHECK(rc == -EINVAL, "returned %d", rc);
    CHECK(err[0] != 0, "no message");
    assert_result_empty(&r);
    /* No room for a message: still refused, nothing written. */
    rc = call_run(c, &r, NULL, 0);
    CHECK(rc == -EINVAL, "returned %d without an error buffer", rc);
    assert_result_empty(&r);
}

/* The same boxes in another order are the same map; a box twice is not
 * the same as another box twice. */
static void test_same_boxes(void **state)
{
    (void)state;
    const float x[6] = {0, 0, 0, 1, 1, 1}, y[6] = {1, 0, 0, 2, 1, 1};
    float xy[2][6], yx[2][6], xx[2][6], yy[2][6];
    memcpy(xy[0], x, sizeof x), memcpy(xy[1], y, sizeof y);
    memcpy(yx[0], y, sizeof y), memcpy(yx[1], x, sizeof x);
    memcpy(xx[0], x, sizeof x), memcpy(xx[1], x, sizeof x);
    memcpy(yy[0], y, sizeof y), memcpy(yy[1], y, sizeof y);
    assert_true(ecm_same_boxes(CBOXES(xy), 2, CBOXES(yx), 2));
    assert_true(ecm_same_boxes(CBOXES(xy), 0, CBOXES(yx), 0));
    assert_false(ecm_same_boxes(CBOXES(xy), 2, CBOXES(yx), 1));
    assert_false(ecm_same_boxes(CBOXES(xy), 2, CBOXES(xx), 2));
    assert_false(ecm_same_boxes(CBOXES(xx), 2, CBOXES(yy), 2));
}

static void test_bad_input(void **state)
{
    (void)state;
    call c;
    call_init(&c);
    ecm_result r;
    char err[256];
    assert_int_equal(call_run(&c, &r, err, sizeof err), 0); /* the baseline is fine */
    ecm_result_free(&r);

    call_init(&c), c.p.depth = ECM_DEPTH_MIN - 1, expect_einval(&c, "depth too small");
    call_init(&c), c.p.depth = ECM_DEPTH_MAX + 1, expect_einval(&c, "depth too large");
    call_init(&c), c.p.max_boxes = 0, expect_einval(&c, "max_boxes 0");
    call_init(&c), c.p.max_boxes = ECM_MAX_BOXES_LIMIT + 1, expect_einval(&c, "max_boxes over the limit");
    call_init(&c), c.p.max_empty = -0.1, expect_einval(&c, "max_empty -0.1");
    call_init(&c), c.p.max_empty = 1.1, expect_einval(&c, "max_empty 1.1");
    call_init(&c), c.p.max_empty = NAN, expect_einval(&c, "max_empty NaN");
    static const float bad_sizes[] = {0.0f, -0.0f, -0.6f, INFINITY, -INFINITY, NAN};
    for (int a = 0; a < 3; a++)
        for (size_t i = 0; i < NELEM(bad_sizes); i++) {
            char what[64];
            snprintf(what, sizeof what, "avatar[%d] = %g", a, (double)bad_sizes[i]);
            call_init(&c), c.p.avatar[a] = bad_sizes[i], expect_einval(&c, what);
        }
    call_init(&c), c.ntris = 0, expect_einval(&c, "no triangles");
    call_init(&c), c.tp = NULL, expect_einval(&c, "triangles NULL");
    /* A mesh of none (never made by trimesh_init) is refused too. */
    call_init(&c);
    const trimesh none = {0};
    assert_int_equal(ecm_refine_mesh(&c.p, &none, c.bp, c.nboxes, c.cl, c.ncl, &r, err, sizeof err), -EINVAL);
    assert_string_equal(err, "the object has no triangles");
    assert_result_empty(&r);
    call_init(&c), c.nboxes = 0, expect_einval(&c, "no boxes");
    call_init(&c), c.bp = NULL, expect_einval(&c, "boxes NULL");
    for (int a = 0; a < 3; a++) {
        call_init(&c), c.boxes[1][a] = c.boxes[1][3 + a] + 0.5f, expect_einval(&c, "a box inside out");
        call_init(&c), c.boxes[0][3 + a] = NAN, expect_einval(&c, "a NaN in a box");
        call_init(&c), c.boxes[1][a] = -INFINITY, expect_einval(&c, "an infinity in a box");
    }
    static const int spots[] = {0, 4, 8, 12 * 9 - 1};
    for (size_t i = 0; i < NELEM(spots); i++) {
        call_init(&c), c.tris[spots[i]] = NAN, expect_einval(&c, "a NaN in a triangle");
        call_init(&c), c.tris[spots[i]] = INFINITY, expect_einval(&c, "an infinity in a triangle");
    }
    for (int a = 0; a < 3; a++) {
        call_init(&c), c.cl[1].min[a] = NAN, expect_einval(&c, "a NaN in a cluster's min");
        call_init(&c), c.cl[0].max[a] = NAN, expect_einval(&c, "a NaN in a cluster's max");
        call_init(&c), c.cl[1].centroid[a] = NAN, expect_einval(&c, "a NaN in a cluster's centroid");
        call_init(&c), c.cl[0].centroid[a] = INFINITY, expect_einval(&c, "an infinity in a cluster");
    }
    call_init(&c), c.cl[1].box = 2, expect_einval(&c, "a cluster naming box nboxes");
    call_init(&c), c.cl[0].box = UINT32_MAX, expect_einval(&c, "a cluster naming box UINT32_MAX");

    /* More boxes than the limit. */
    float(*many)[6] = calloc(ECM_MAX_BOXES_LIMIT + 1, sizeof *many);
    assert_non_null(many);
    for (uint32_t i = 0; i <= ECM_MAX_BOXES_LIMIT; i++)
        memcpy(many[i], c.boxes[i % 2], sizeof many[i]);
    call_init(&c), c.bp = CBOXES(many), c.nboxes = ECM_MAX_BOXES_LIMIT + 1, expect_einval(&c, "too many boxes");
    free(many);
}

/* No clusters: nothing to refine, the boxes come back as they were. */
static void test_no_clusters(void **state)
{
    (void)state;
    call c;
    call_init(&c);
    c.ncl = 0;
    ecm_result r;
    char err[256];
    assert_int_equal(call_run(&c, &r, err, sizeof err), 0);
    assert_int_equal(r.count, 2);
    assert_int_equal(r.problem_boxes, 0);
    assert_int_equal(r.capped, 0);
    assert_int_equal(r.cells, 0);
    assert_memory_equal(r.boxes, c.boxes, sizeof c.boxes);
    ecm_result_free(&r);
    /* Also with the cluster array NULL. */
    assert_int_equal(ecm_refine(&c.p, c.tp, c.ntris, c.bp, c.nboxes, NULL, 0, &r, err, sizeof err), 0);
    assert_int_equal(r.count, 2);
    assert_memory_equal(r.boxes, c.boxes, sizeof c.boxes);
    ecm_result_free(&r);
}

/* ---- out of memory ----------------------------------------------------- */

/* Fails the 1st, 2nd, ... allocation of one call until the call gets
 * through: each failing call returns -ENOMEM with *out empty and a message
 * (ASan checks that nothing leaks), and the call that gets through returns
 * exactly what a call without the hook returns. */
static void oom_case(const char *what, const ecm_params *p, const float *tris, uint32_t ntris,
                     const float (*boxes)[6], uint32_t nboxes, const ecm_cluster *cl, uint32_t ncl)
{
    snprintf(check_ctx, sizeof check_ctx, "out of memory, %s", what);
    ecm_result ref, r;
    char err[256];
    assert_int_equal(ecm_refine(p, tris, ntris, boxes, nboxes, cl, ncl, &ref, err, sizeof err), 0);
    long k;
    for (k = 0; k < 100000; k++) {
        memset(&r, 0xab, sizeof r);
        err[0] = 0;
        cvre_alloc_fail_after(k);
        int rc = ecm_refine(p, tris, ntris, boxes, nboxes, cl, ncl, &r, err, sizeof err);
        cvre_alloc_fail_after(-1);
        if (rc == -ENOMEM) {
            CHECK(err[0] != 0, "allocation %ld failed: no message", k);
            assert_result_empty(&r);
            continue;
        }
        CHECK(rc == 0, "allocation %ld failed: returned %d (%s)", k, rc, err);
        /* Either nothing failed this time, or a failure was not reported. */
        CHECK(r.boxes != NULL && r.count == ref.count && memcmp(r.boxes, ref.boxes, ref.count * sizeof *ref.boxes) == 0,
              "allocation %ld failed, yet 0 returned with %u boxes (array %s), not the %u expected", k, r.count,
              r.boxes ? "set" : "NULL", ref.count);
        ecm_result_free(&r);
        break;
    }
    CHECK(k > 2, "only %ld allocations", k);
    ecm_result_free(&ref);
}

static void test_out_of_memory(void **state)
{
    (void)state;
    import_mesh m = load("openings/openfoam_room_with_doorway.stl", 1);
    float box[6];
    mbr(m.tris, m.ntris, box);
    /* Each case redoes the whole refinement once per allocation, so both
     * run on 16^3 grids: they make the same allocations, from every site
     * in refine.c and voxel.c, as at the default depth (checked with gcov:
     * every -ENOMEM return is reached), in a small share of the time. On
     * one thread: the k-th allocation is then the same one every run (and
     * the failure countdown is not shared between threads). */
    ecm_params p;
    ecm_params_default(&p);
    p.depth = 4;
    p.threads = 1;
    oom_case("the room", &p, m.tris, m.ntris, CBOXES(box), 1, &room_door, 1);

    /* Two problem boxes and a kept one (the room cut in three along x),
     * with face clusters: more lists, merges, a cap. */
    float parts[3][6];
    for (int i = 0; i < 3; i++) {
        memcpy(parts[i], box, sizeof box);
        parts[i][0] = i ? parts[i - 1][3] : box[0];
        parts[i][3] = i < 2 ? (float)(box[0] + ((double)box[3] - box[0]) * (i + 1) / 3) : box[3];
    }
    ecm_cluster cl[14];
    face_clusters(parts[2], 2, cl);
    face_clusters(parts[0], 0, cl + 7);
    p.max_boxes = 12;
    oom_case("three boxes", &p, m.tris, m.ntris, CBOXES(parts), 3, cl, 14);
    import_mesh_free(&m);
}

/* ---- main -------------------------------------------------------------- */

int main(int argc, char **argv)
{
    models_select sel;
    models_args(argc, argv, "One refinement round: fixed cases, and the invariant on every model.", &models_dir,
                &sel);
    const struct CMUnitTest fixed[] = {
        cmocka_unit_test(test_room_door_opens_walls_stay),
        cmocka_unit_test(test_room_far_wall_peeled),
        cmocka_unit_test(test_archway_opens_stone_stays),
        cmocka_unit_test(test_archway_path_past_the_curve),
        cmocka_unit_test(test_budget_spent_outside_kept_inside),
        cmocka_unit_test(test_inside_users_walk_on),
        cmocka_unit_test(test_split_frees_space_under_the_cell),
        cmocka_unit_test(test_roof_over_the_well_is_only_tightened),
        cmocka_unit_test(test_cap_moves_boxes_to_where_users_were_stopped),
        cmocka_unit_test(test_grazed_row_is_no_opening),
        cmocka_unit_test(test_new_boxes_stay_near_the_old_map),
        cmocka_unit_test(test_soups),
        cmocka_unit_test(test_soups_several_boxes),
        cmocka_unit_test(test_flat_objects),
        cmocka_unit_test(test_nothing_wanted_only_shrinks),
        cmocka_unit_test(test_thick_wall_stays_whole),
        cmocka_unit_test(test_only_places_users_reach),
        cmocka_unit_test(test_doorway_three_cuts),
        cmocka_unit_test(test_held_cluster_wants_its_reach),
        cmocka_unit_test(test_cluster_over_two_boxes),
        cmocka_unit_test(test_neighbour_uses_the_named_face),
        cmocka_unit_test(test_pressure_shares_budget),
        cmocka_unit_test(test_outside_stays_open),
        cmocka_unit_test(test_merge_across_borders),
        cmocka_unit_test(test_step_onto_base),
        cmocka_unit_test(test_no_one_stands_below_the_floor),
        cmocka_unit_test(test_wanted_region),
        cmocka_unit_test(test_cap_exact),
        cmocka_unit_test(test_cut_frees_the_most), cmocka_unit_test(test_merge_max_empty),
        cmocka_unit_test(test_cap),
        cmocka_unit_test(test_cap_kept_boxes_over_cap),
        cmocka_unit_test(test_deterministic),
        cmocka_unit_test(test_same_boxes),
        cmocka_unit_test(test_bad_input),
        cmocka_unit_test(test_no_clusters),
        cmocka_unit_test(test_out_of_memory),
    };
    size_t nmodels;
    char **models = models_list(models_dir, &nmodels);
    if (!models)
        return 2;
    /* The 15 models of SOURCES.md at the time of writing: an empty or
     * half-copied folder must not pass quietly. */
    if (nmodels < 15) {
        fprintf(stderr, "test_refine: %zu models in %s, expected at least 15\n", nmodels, models_dir);
        return 2;
    }
    size_t ntests = NELEM(fixed) + nmodels;
    struct CMUnitTest *tests = calloc(ntests, sizeof *tests);
    if (!tests)
        return 2;
    memcpy(tests, fixed, sizeof fixed);
    for (size_t i = 0; i < nmodels; i++)
        tests[NELEM(fixed) + i] = (struct CMUnitTest){models[i], test_model_invariant, NULL, NULL, models[i]};
    int failed = models_run("test_refine", tests, ntests, &sel);
    free(tests);
    for (size_t i = 0; i < nmodels; i++)
        free(models[i]);
    free(models);
    return failed;
}




