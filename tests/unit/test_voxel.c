/*
 * The voxelizer against an independent reference, hand-made boundary cases
 * and a real model.
 *
 * The reference clips the triangle, as a polygon, against the cell's six
 * closed half-spaces (Sutherland-Hodgman, in double): the cell overlaps iff
 * something is left. It shares no code or method with voxel.c's separating
 * axis test. A grid is right when every cell the reference says overlaps is
 * marked and every marked cell overlaps the triangle once grown by a small
 * tolerance (TOL_REL of the grid's extent, far above voxel.c's eps, far
 * below a cell).
 *
 * Usage: test_voxel [MODELS_DIR] [--only PATTERN]... [--skip PATTERN]...
 * (MODELS_DIR defaults to the shared models folder next to the repository,
 * set at build time). The real model's case is named after its file, so
 * that ctest runs it as an entry of its own (tests/models.h).
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
#include "import.h"
#include "trimesh.h"
#include "voxel.h"

#ifndef CVRE_MODELS_DIR
#define CVRE_MODELS_DIR "../shared/models"
#endif

/* Marked cells may be this far (relative to the grid's largest extent) from
 * the triangle: 100 times voxel.c's eps. */
#define TOL_REL 1e-7

static const char *models_dir = CVRE_MODELS_DIR;

/* ---- helpers ------------------------------------------------------------ */

static uint64_t rng_state;

static uint64_t rnd(void)
{
    /* splitmix64 */
    uint64_t z = (rng_state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

/* Uniform in [0, 1). */
static double rndu(void) { return (double)(rnd() >> 11) * 0x1p-53; }

static double rndr(double lo, double hi) { return lo + (hi - lo) * rndu(); }

static int rndi(int n) { return (int)(rnd() % (uint64_t)n); }

static void grid_init(voxel_grid *g, uint32_t depth, double x0, double y0, double z0, double x1, double y1,
                      double z1)
{
    float lo[3] = {(float)x0, (float)y0, (float)z0}, hi[3] = {(float)x1, (float)y1, (float)z1};
    assert_int_equal(voxel_grid_init(g, depth, lo, hi), 0);
}

static void mark1(voxel_grid *g, double ax, double ay, double az, double bx, double by, double bz, double cx,
                  double cy, double cz)
{
    float t[9] = {(float)ax, (float)ay, (float)az, (float)bx, (float)by, (float)bz,
                  (float)cx, (float)cy, (float)cz};
    assert_int_equal(voxel_mark(g, t, 1), 0);
}

static uint64_t popcount_grid(const voxel_grid *g)
{
    uint64_t cells = (uint64_t)g->n * g->n * g->n, c = 0;
    for (uint64_t w = 0; w < (cells + 63) / 64; w++)
        c += (uint64_t)__builtin_popcountll(g->bits[w]);
    return c;
}

static double grid_tol(const voxel_grid *g)
{
    double ext = 0.0, far = 1.0;
    for (int a = 0; a < 3; a++) {
        ext = fmax(ext, g->max[a] - g->min[a]);
        far = fmax(far, fmax(fabs(g->min[a]), fabs(g->max[a])));
    }
    return TOL_REL * (ext > 0.0 ? ext : far);
}

/* Cell (i, j, k) as a box grown by `grow` on every side. */
static void cell_box(const voxel_grid *g, const int idx[3], double grow, double lo[3], double hi[3])
{
    for (int a = 0; a < 3; a++) {
        lo[a] = g->min[a] + idx[a] * g->cell[a] - grow;
        hi[a] = g->min[a] + (idx[a] + 1) * g->cell[a] + grow;
    }
}

/* ---- the reference: polygon clipping ------------------------------------ */

#define MAXPOLY 16

/* Keeps the part of polygon p (n points) with sign * (x[a] - bound) <= 0,
 * the plane closed. Returns the new point count. */
static int clip(double p[MAXPOLY][3], int n, int a, double bound, double sign)
{
    double out[MAXPOLY][3];
    int m = 0;
    for (int i = 0; i < n; i++) {
        const double *cur = p[i], *prev = p[(i + n - 1) % n];
        double dc = sign * (cur[a] - bound), dp = sign * (prev[a] - bound);
        if ((dc <= 0.0) != (dp <= 0.0)) {
            double t = dp / (dp - dc), *q = out[m++];
            for (int c = 0; c < 3; c++)
                q[c] = prev[c] + t * (cur[c] - prev[c]);
            q[a] = bound;
        }
        if (dc <= 0.0)
            memcpy(out[m++], cur, sizeof out[0]);
    }
    memcpy(p, out, (size_t)m * sizeof out[0]);
    return m;
}

/* 1 if the closed triangle t and the closed box [lo, hi] share a point. */
static int ref_overlap(const double t[9], const double lo[3], const double hi[3])
{
    double p[MAXPOLY][3];
    int n = 3;
    for (int a = 0; a < 3; a++) {
        double tlo = fmin(t[a], fmin(t[3 + a], t[6 + a])), thi = fmax(t[a], fmax(t[3 + a], t[6 + a]));
        if (tlo > hi[a] || thi < lo[a])
            return 0;
    }
    for (int i = 0; i < 3; i++)
        for (int a = 0; a < 3; a++)
            p[i][a] = t[3 * i + a];
    for (int a = 0; a < 3 && n > 0; a++) {
        n = clip(p, n, a, lo[a], -1.0);
        if (n > 0)
            n = clip(p, n, a, hi[a], 1.0);
    }
    return n > 0;
}

static void set_bit(uint8_t *b, size_t i) { b[i >> 3] |= (uint8_t)(1u << (i & 7)); }
static int get_bit(const uint8_t *b, size_t i) { return (b[i >> 3] >> (i & 7)) & 1; }

/* Index range of cells that could be within `grow` of [lo, hi] on axis a,
 * one cell wider on each side than needed. */
static void cand_range(const voxel_grid *g, int a, double lo, double hi, double grow, int r[2])
{
    int n = (int)g->n;
    if (g->cell[a] == 0.0) {
        r[0] = 0, r[1] = n - 1;
        return;
    }
    double f = floor((lo - grow - g->min[a]) / g->cell[a]) - 1, l = floor((hi + grow - g->min[a]) / g->cell[a]) + 1;
    r[0] = f < 0 ? 0 : f > n - 1 ? n : (int)f;
    r[1] = l > n - 1 ? n - 1 : l < 0 ? -1 : (int)l;
}

/*
 * Checks g (marked with exactly these triangles) against the reference:
 * required (overlapping exactly) <= marked <= allowed (overlapping once
 * grown by the tolerance), and that `occupied` counts the bits. Also
 * checks voxel_tri_box_overlap against the reference on every cell looked
 * at, with the same tolerance. Returns the number of required cells.
 */
static uint64_t check_grid(const voxel_grid *g, const float *tris, size_t ntris)
{
    size_t n = g->n, cells = n * n * n;
    uint8_t *req = calloc(cells / 8 + 1, 1), *allow = calloc(cells / 8 + 1, 1);
    double tol = grid_tol(g);
    assert_non_null(req);
    assert_non_null(allow);
    for (size_t t = 0; t < ntris; t++) {
        double tri[9];
        int r[3][2];
        for (int c = 0; c < 9; c++)
            tri[c] = tris[9 * t + (size_t)c];
        for (int a = 0; a < 3; a++)
            cand_range(g, a, fmin(tri[a], fmin(tri[3 + a], tri[6 + a])),
                       fmax(tri[a], fmax(tri[3 + a], tri[6 + a])), tol, r[a]);
        int idx[3];
        for (idx[2] = r[2][0]; idx[2] <= r[2][1]; idx[2]++)
            for (idx[1] = r[1][0]; idx[1] <= r[1][1]; idx[1]++)
                for (idx[0] = r[0][0]; idx[0] <= r[0][1]; idx[0]++) {
                    size_t i = (size_t)idx[0] + n * ((size_t)idx[1] + n * (size_t)idx[2]);
                    double lo[3], hi[3], glo[3], ghi[3];
                    cell_box(g, idx, 0.0, lo, hi);
                    cell_box(g, idx, tol, glo, ghi);
                    int exact = ref_overlap(tri, lo, hi), grown = ref_overlap(tri, glo, ghi);
                    int sat = voxel_tri_box_overlap(tri, lo, hi), sat_grown = voxel_tri_box_overlap(tri, glo, ghi);
                    if ((exact && !sat_grown) || (sat && !grown))
                        fail_msg("voxel_tri_box_overlap %d, reference %d on cell %d %d %d", sat, exact,
                                 idx[0], idx[1], idx[2]);
                    if (exact)
                        set_bit(req, i);
                    if (grown)
                        set_bit(allow, i);
                }
    }
    uint64_t nreq = 0;
    for (size_t i = 0; i < cells; i++) {
        int m = voxel_get(g, (uint32_t)(i % n), (uint32_t)(i / n % n), (uint32_t)(i / n / n));
        nreq += (uint64_t)get_bit(req, i);
        if (get_bit(req, i) && !m)
            fail_msg("cell %zu %zu %zu touches a triangle but is not marked", i % n, i / n % n, i / n / n);
        if (m && !get_bit(allow, i))
            fail_msg("cell %zu %zu %zu is marked but no triangle comes within %g of it", i % n, i / n % n,
                     i / n / n, tol);
    }
    assert_int_equal(g->occupied, popcount_grid(g));
    free(req);
    free(allow);
    return nreq;
}

/* ---- random triangles --------------------------------------------------- */

/* A random box: dyadic (exact cell planes) or arbitrary, sometimes flat on
 * an axis or on all of them. */
static void random_box(double lo[3], double hi[3], int n)
{
    int dyadic = rndi(2), flat = rndi(8);
    for (int a = 0; a < 3; a++) {
        if (dyadic) {
            lo[a] = rndi(64) / 4.0 - 8.0;
            hi[a] = lo[a] + n * ldexp(1.0, rndi(5) - 3);
        } else {
            lo[a] = (double)(float)rndr(-100.0, 100.0);
            hi[a] = (double)(float)(lo[a] + rndr(0.01, 50.0));
        }
    }
    if (flat <= 1) {
        int a = rndi(3);
        hi[a] = lo[a];
        if (flat == 0 && rndi(4) == 0)
            for (int b = 0; b < 3; b++)
                hi[b] = lo[b];
    }
}

/* A point of the lattice of cell planes, a few cells beyond the grid. */
static double lattice(const double lo[3], const double hi[3], int n, int a)
{
    return lo[a] + (hi[a] - lo[a]) / n * (rndi(n + 5) - 2);
}

static double near_box(const double lo[3], const double hi[3], int a, double margin)
{
    double e = fmax(hi[a] - lo[a], 1e-3);
    return rndr(lo[a] - margin * e, hi[a] + margin * e);
}

/* One random triangle of one of several kinds, as floats. */
static void random_tri(float out[9], const double lo[3], const double hi[3], int n)
{
    double t[9], ext = 0.0;
    for (int a = 0; a < 3; a++)
        ext = fmax(ext, hi[a] - lo[a]);
    if (ext == 0.0)
        ext = 1.0;
    int kind = rndi(10);
    for (int i = 0; i < 3; i++)
        for (int a = 0; a < 3; a++)
            t[3 * i + a] = near_box(lo, hi, a, 0.2);
    switch (kind) {
    case 0: /* tiny, around a random point */
        for (int i = 1; i < 3; i++)
            for (int a = 0; a < 3; a++)
                t[3 * i + a] = t[a] + rndr(-1, 1) * ext / n * 0.3;
        break;
    case 1: { /* axis-aligned, on a cell plane */
        int a = rndi(3);
        double v = lattice(lo, hi, n, a);
        for (int i = 0; i < 3; i++)
            t[3 * i + a] = v;
        break;
    }
    case 2: /* every vertex on the lattice: edges along cell edges, vertices on corners */
        for (int i = 0; i < 9; i++)
            t[i] = lattice(lo, hi, n, i % 3);
        if (rndi(2)) { /* an edge along a cell edge: two vertices share two coordinates */
            int b = rndi(3);
            for (int a = 0; a < 3; a++)
                if (a != b)
                    t[3 + a] = t[a];
        }
        break;
    case 3: /* collinear: the third vertex on the line of the first two */
        for (int a = 0; a < 3; a++)
            t[6 + a] = t[a] + (rndi(5) - 1) * 0.5 * (t[3 + a] - t[a]);
        break;
    case 4: /* a point, or a segment (two vertices equal) */
        for (int a = 0; a < 3; a++) {
            t[3 + a] = rndi(2) ? t[a] : t[3 + a];
            t[6 + a] = t[a];
        }
        break;
    case 5: { /* sliver: the third vertex barely off the opposite edge */
        double s = rndu(), off = ext * pow(10.0, -3 - rndi(5));
        for (int a = 0; a < 3; a++)
            t[6 + a] = t[a] + s * (t[3 + a] - t[a]) + rndr(-off, off);
        break;
    }
    case 6: /* large: far beyond the box */
        for (int i = 0; i < 9; i++)
            t[i] = near_box(lo, hi, i % 3, 3.0);
        break;
    case 7: { /* outside, just beyond one face */
        int a = rndi(3), up = rndi(2);
        double gap = ext * pow(10.0, -1 - rndi(6));
        for (int i = 0; i < 3; i++)
            t[3 * i + a] = up ? hi[a] + gap + rndu() * ext : lo[a] - gap - rndu() * ext;
        break;
    }
    default:
        break;
    }
    for (int i = 0; i < 9; i++)
        out[i] = (float)t[i];
}

static void test_random_triangles_against_reference(void **state)
{
    (void)state;
    rng_state = 12345;
    for (int round = 0; round < 3000; round++) {
        uint32_t depth = 1u + (uint32_t)rndi(round % 10 == 0 ? 5 : 4);
        int n = 1 << depth;
        double lo[3], hi[3];
        float t[9];
        voxel_grid g;
        random_box(lo, hi, n);
        random_tri(t, lo, hi, n);
        grid_init(&g, depth, lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]);
        assert_int_equal(voxel_mark(&g, t, 1), 0);
        check_grid(&g, t, 1);
        voxel_grid_free(&g);
    }
}

/* Big triangles at depth 6: the hierarchical descent, checked cell by cell. */
static void test_large_triangles_against_reference(void **state)
{
    (void)state;
    rng_state = 777;
    for (int round = 0; round < 6; round++) {
        double lo[3] = {-1, -2, -3}, hi[3] = {3, 1, 2};
        float t[9];
        voxel_grid g;
        /* Through a point p inside the box: p is the centroid. */
        double p[3], v[9];
        for (int a = 0; a < 3; a++)
            p[a] = rndr(lo[a], hi[a]);
        for (int i = 0; i < 6; i++)
            v[i] = near_box(lo, hi, i % 3, round < 3 ? 0.5 : 2.0);
        for (int a = 0; a < 3; a++)
            v[6 + a] = 3 * p[a] - v[a] - v[3 + a];
        for (int i = 0; i < 9; i++)
            t[i] = (float)v[i];
        grid_init(&g, 6, lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]);
        assert_int_equal(voxel_mark(&g, t, 1), 0);
        uint64_t req = check_grid(&g, t, 1);
        assert_true(req > 64); /* it crossed many cells */
        voxel_grid_free(&g);
    }
}

/* Many triangles in one call mark the union of what each marks alone: a
 * cell marked by one triangle and skipped for the next changes nothing. */
static void test_one_call_equals_union(void **state)
{
    (void)state;
    rng_state = 99;
    enum { N = 300 };
    static float t[9 * N];
    double lo[3] = {0, 0, 0}, hi[3] = {8, 4, 2};
    voxel_grid all, one, uni;
    for (int i = 0; i < N; i++)
        random_tri(t + 9 * i, lo, hi, 16);
    grid_init(&all, 4, 0, 0, 0, 8, 4, 2);
    grid_init(&uni, 4, 0, 0, 0, 8, 4, 2);
    assert_int_equal(voxel_mark(&all, t, N), 0);
    for (int i = 0; i < N; i++) {
        grid_init(&one, 4, 0, 0, 0, 8, 4, 2);
        assert_int_equal(voxel_mark(&one, t + 9 * i, 1), 0);
        for (size_t w = 0; w < 16 * 16 * 16 / 64; w++)
            uni.bits[w] |= one.bits[w];
        voxel_grid_free(&one);
    }
    assert_memory_equal(all.bits, uni.bits, 16 * 16 * 16 / 8);
    check_grid(&all, t, N);
    voxel_grid_free(&all);
    voxel_grid_free(&uni);
}

/* Marking a checked mesh sets exactly the cells marking its triangles
 * does: triangles in the grid, grazing it, near it and far from it (passed
 * over from their boxes), on flat grids too, on one thread or several
 * (whose slabs count only the triangles meeting the grid). */
static void test_mesh_equals_triangles(void **state)
{
    (void)state;
    rng_state = 777;
    enum { N = 3 * VOXEL_MIN_TRIS_PER_THREAD };
    float *t = malloc(9 * sizeof *t * N);
    assert_non_null(t);
    struct {
        uint32_t depth;
        double lo[3], hi[3];
    } cases[] = {{6, {-1, -2, -3}, {3, 1, 2}}, {5, {0, 0, 0}, {4, 4, 0}}, {4, {0, 0, 0}, {1, 1, 1}}};
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
        const double *lo = cases[c].lo, *hi = cases[c].hi;
        for (int i = 0; i < N; i++) {
            random_tri(t + 9 * i, lo, hi, 1 << cases[c].depth);
            if (i % 3 == 0) /* a third far off on x: passed over from the box */
                for (int k = 0; k < 3; k++)
                    t[9 * i + 3 * k] += (float)(3 * (hi[0] - lo[0]) + 1);
        }
        char err[128] = "";
        trimesh m;
        assert_int_equal(trimesh_init(&m, t, N, err, sizeof err), 0);
        voxel_grid tri, mesh;
        grid_init(&tri, cases[c].depth, lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]);
        assert_int_equal(voxel_mark(&tri, t, N), 0);
        assert_true(tri.occupied > 0);
        static const unsigned thread_counts[] = {1, 2, 3};
        for (size_t tc = 0; tc < sizeof thread_counts / sizeof thread_counts[0]; tc++) {
            grid_init(&mesh, cases[c].depth, lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]);
            assert_int_equal(
                voxel_mark_boxed(&mesh, m.tris, (const float(*)[6])m.box, m.ntris, 0, thread_counts[tc]), 0);
            assert_int_equal(mesh.occupied, tri.occupied);
            assert_memory_equal(mesh.bits, tri.bits, ((size_t)tri.n * tri.n * tri.n + 7) / 8);
            /* Helper threads ran, and their CPU time is counted, only where
             * there are slabs (not on the grid flat in z). */
            assert_int_equal(mesh.helper_ms > 0.0, thread_counts[tc] > 1 && tri.cell[2] > 0.0);
            voxel_grid_free(&mesh);
        }
        grid_init(&mesh, cases[c].depth, lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]);
        assert_int_equal(voxel_mark_boxed(NULL, m.tris, (const float(*)[6])m.box, m.ntris, 0, 1), -EINVAL);
        assert_int_equal(voxel_mark_boxed(&mesh, m.tris, NULL, m.ntris, 0, 1), -EINVAL);
        /* Loose: every exact cell (test_loose_marks_the_box: and more). */
        voxel_grid loose;
        grid_init(&loose, cases[c].depth, lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]);
        assert_int_equal(voxel_mark_boxed(&loose, m.tris, (const float(*)[6])m.box, m.ntris, 8, 1), 0);
        for (size_t i = 0; i < ((size_t)tri.n * tri.n * tri.n + 63) / 64; i++)
            assert_int_equal(loose.bits[i] & tri.bits[i], tri.bits[i]);
        assert_true(loose.occupied >= tri.occupied);
        voxel_grid loose3; /* the same cells on three threads */
        grid_init(&loose3, cases[c].depth, lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]);
        assert_int_equal(voxel_mark_boxed(&loose3, m.tris, (const float(*)[6])m.box, m.ntris, 8, 3), 0);
        assert_int_equal(loose3.occupied, loose.occupied);
        assert_memory_equal(loose3.bits, loose.bits, ((size_t)tri.n * tri.n * tri.n + 7) / 8);
        voxel_grid_free(&loose3);
        voxel_grid_free(&loose);
        voxel_grid_free(&tri);
        voxel_grid_free(&mesh);
        trimesh_free(&m);
    }
    free(t);
}

/* A grid nearly flat in z (its cells far thinner than eps): a triangle a
 * few cells under it is within eps and marks cells, and slabs, whose
 * filter passes triangles over only beyond a cell and twice eps, mark what
 * one thread marks. */
static void test_nearly_flat_slabs(void **state)
{
    (void)state;
    rng_state = 99;
    enum { N = 3 * VOXEL_MIN_TRIS_PER_THREAD };
    const double zext = 1e-8, c = zext / 128;
    float *t = malloc(9 * sizeof *t * (N + 1));
    assert_non_null(t);
    for (int i = 0; i < N; i++) {
        float x = (float)(0.9 * rndu()), y = (float)(0.9 * rndu()), z = (float)(zext * rndu());
        const float tri[9] = {x, y, z, x + 0.01f, y, z, x, y + 0.01f, z};
        memcpy(t + 9 * i, tri, sizeof tri);
    }
    const float below = (float)(-5 * c), under[9] = {0.95f, 0.95f, below, 0.96f, 0.95f, below, 0.95f, 0.96f, below};
    memcpy(t + 9 * N, under, sizeof under);
    voxel_grid one;
    grid_init(&one, 7, 0, 0, 0, 1, 1, zext);
    assert_int_equal(voxel_mark(&one, t + 9 * N, 1), 0);
    assert_true(one.occupied > 0);
    voxel_grid_free(&one);
    char err[128] = "";
    trimesh m;
    assert_int_equal(trimesh_init(&m, t, N + 1, err, sizeof err), 0);
    grid_init(&one, 7, 0, 0, 0, 1, 1, zext);
    assert_int_equal(voxel_mark_boxed(&one, m.tris, (const float(*)[6])m.box, m.ntris, 0, 1), 0);
    static const unsigned thread_counts[] = {2, 3};
    for (size_t tc = 0; tc < sizeof thread_counts / sizeof thread_counts[0]; tc++) {
        voxel_grid many;
        grid_init(&many, 7, 0, 0, 0, 1, 1, zext);
        assert_int_equal(voxel_mark_boxed(&many, m.tris, (const float(*)[6])m.box, m.ntris, 0, thread_counts[tc]), 0);
        assert_int_equal(many.occupied, one.occupied);
        assert_memory_equal(many.bits, one.bits, (size_t)128 * 128 * 128 / 8);
        voxel_grid_free(&many);
    }
    voxel_grid_free(&one);
    trimesh_free(&m);
    free(t);
}

/* Threads mark exactly what one thread marks, whatever the split, on
 * grids where triangles cross slab boundaries; and fall back to one thread
 * where slabs would share words or copies (n < 8, flat z). */
static void test_threads_equal_one_thread(void **state)
{
    (void)state;
    rng_state = 4242;
    enum { N = 3 * VOXEL_MIN_TRIS_PER_THREAD };
    float *t = malloc(9 * sizeof *t * N);
    assert_non_null(t);
    struct {
        uint32_t depth;
        double lo[3], hi[3];
    } cases[] = {
        {6, {-1, -2, -3}, {3, 1, 2}}, {3, {0, 0, 0}, {1, 1, 1}}, {2, {0, 0, 0}, {1, 1, 1}}, {5, {0, 0, 0}, {4, 4, 0}},
    };
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
        const double *lo = cases[c].lo, *hi = cases[c].hi;
        for (int i = 0; i < N; i++) {
            random_tri(t + 9 * i, lo, hi, 1 << cases[c].depth);
            if (i % 2) /* half of them small and clustered in z, so slabs are uneven */
                for (int k = 0; k < 3; k++)
                    t[9 * i + 3 * k + 2] = (float)(lo[2] + 0.1 * (hi[2] - lo[2]) * rndu());
        }
        voxel_grid one, many;
        grid_init(&one, cases[c].depth, lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]);
        assert_int_equal(voxel_mark(&one, t, N), 0);
        static const unsigned thread_counts[] = {0, 2, 3}; /* 0: one per CPU */
        for (size_t tc = 0; tc < sizeof thread_counts / sizeof thread_counts[0]; tc++) {
            unsigned threads = thread_counts[tc];
            grid_init(&many, cases[c].depth, lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]);
            assert_int_equal(voxel_mark_threads(&many, t, N, threads), 0);
            assert_int_equal(many.occupied, one.occupied);
            assert_int_equal(many.occupied, popcount_grid(&many));
            assert_memory_equal(many.bits, one.bits, ((size_t)one.n * one.n * one.n + 7) / 8);
            voxel_grid_free(&many);
        }
        if (c == 0) { /* a grid already holding cells, and bad input */
            grid_init(&many, cases[c].depth, lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]);
            assert_int_equal(voxel_mark_threads(&many, t, N / 2, 2), 0);
            assert_int_equal(voxel_mark_threads(&many, t + 9 * (N / 2), N - N / 2, 2), 0);
            assert_int_equal(many.occupied, one.occupied);
            assert_memory_equal(many.bits, one.bits, (size_t)one.n * one.n * one.n / 8);
            t[9 * N - 1] = NAN;
            assert_int_equal(voxel_mark_threads(&many, t, N, 2), -EINVAL);
            assert_int_equal(many.occupied, one.occupied);
            assert_int_equal(voxel_mark_threads(NULL, t, N, 2), -EINVAL);
            voxel_grid_free(&many);
        }
        voxel_grid_free(&one);
    }
    free(t);
}

/* ---- hand-made cases ---------------------------------------------------- */

/* Grid [0,4]^3 at depth 2: cells of 1. */
static void unit_grid(voxel_grid *g) { grid_init(g, 2, 0, 0, 0, 4, 4, 4); }

static void test_triangle_on_cell_face(void **state)
{
    (void)state;
    voxel_grid g;
    unit_grid(&g);
    mark1(&g, 0.25, 0.25, 1, 0.75, 0.25, 1, 0.25, 0.75, 1); /* on the face z = 1 */
    assert_int_equal(g.occupied, 2);
    assert_true(voxel_get(&g, 0, 0, 0) && voxel_get(&g, 0, 0, 1));
    /* On face z = 1 and touching x = 1 and y = 1 at a vertex: 8 cells. */
    mark1(&g, 1, 1, 1, 1.5, 1, 1, 1, 1.5, 1);
    assert_int_equal(g.occupied, 2 + 6);
    for (uint32_t k = 0; k < 2; k++)
        for (uint32_t j = 0; j < 2; j++)
            for (uint32_t i = 0; i < 2; i++)
                assert_true(voxel_get(&g, i, j, k));
    voxel_grid_free(&g);
}

static void test_triangle_on_outer_faces(void **state)
{
    (void)state;
    voxel_grid g;
    unit_grid(&g);
    mark1(&g, 0, 0, 0, 8, 0, 0, 0, 8, 0); /* covers the whole face z = 0 */
    assert_int_equal(g.occupied, 16);
    for (uint32_t j = 0; j < 4; j++)
        for (uint32_t i = 0; i < 4; i++)
            assert_true(voxel_get(&g, i, j, 0));
    /* On the face z = 4, where x + y <= 4 and x, y >= 0.5: in the top
     * layer, the cells with max(i, 0.5) + max(j, 0.5) <= 4, 13 of them. */
    mark1(&g, 0.5, 0.5, 4, 3.5, 0.5, 4, 0.5, 3.5, 4);
    assert_int_equal(g.occupied, 16 + 13);
    for (uint32_t j = 0; j < 4; j++)
        for (uint32_t i = 0; i < 4; i++)
            assert_int_equal(voxel_get(&g, i, j, 3), fmax(i, 0.5) + fmax(j, 0.5) <= 4.0);
    mark1(&g, 4, 4, 4, 5, 4, 4, 4, 5, 5); /* touches the grid at its far corner only */
    assert_int_equal(g.occupied, 16 + 14);
    assert_true(voxel_get(&g, 3, 3, 3));
    mark1(&g, 0, 0, 4.001, 4, 0, 4.001, 0, 4, 4.001); /* just outside */
    mark1(&g, -1, -1, -1e-3, 5, -1, -1e-3, -1, 5, -1e-3);
    assert_int_equal(g.occupied, 16 + 14);
    voxel_grid_free(&g);
}

static void test_triangle_along_cell_edges(void **state)
{
    (void)state;
    voxel_grid g;
    unit_grid(&g);
    /* In the plane x = 1, one edge along the cell edge x = 1, y = 1, from
     * z = 0.5 to 2.5: two cells in x, two in y (it touches y = 1), three in z. */
    mark1(&g, 1, 1, 0.5, 1, 1, 2.5, 1, 1.5, 1.5);
    assert_int_equal(g.occupied, 12);
    for (uint32_t k = 0; k < 3; k++)
        for (uint32_t j = 0; j < 2; j++)
            for (uint32_t i = 0; i < 2; i++)
                assert_true(voxel_get(&g, i, j, k));
    voxel_grid_free(&g);
    /* A segment (degenerate triangle) along the cell edge x = 2, y = 2. */
    unit_grid(&g);
    mark1(&g, 2, 2, 0.5, 2, 2, 3.5, 2, 2, 0.5);
    assert_int_equal(g.occupied, 16);
    voxel_grid_free(&g);
}

static void test_sliver(void **state)
{
    (void)state;
    voxel_grid g;
    float t[9] = {0.1f, 0.1f, 0.1f, 3.9f, 3.9f, 3.9f, 2.0f, 2.0f, 2.000001f};
    grid_init(&g, 3, 0, 0, 0, 4, 4, 4);
    assert_int_equal(voxel_mark(&g, t, 1), 0);
    /* The diagonal passes through the corners (k, k, k): every cell around
     * each of them is touched. */
    for (uint32_t k = 0; k < 8; k++)
        assert_true(voxel_get(&g, k, k, k));
    assert_true(voxel_get(&g, 4, 3, 3) && voxel_get(&g, 3, 4, 4) && voxel_get(&g, 3, 3, 4));
    check_grid(&g, t, 1);
    voxel_grid_free(&g);
    /* A thin triangle crossing cells at a slant, nearly a segment. */
    float u[9] = {0.3f, 0.2f, 0.1f, 3.7f, 2.9f, 1.3f, 3.7f, 2.9f + 1e-6f, 1.3f};
    grid_init(&g, 4, 0, 0, 0, 4, 4, 4);
    assert_int_equal(voxel_mark(&g, u, 1), 0);
    check_grid(&g, u, 1);
    voxel_grid_free(&g);
}

/* Number of (i, j, k) in [0, n)^3 with lo <= i + j + k <= hi. */
static uint64_t count_diagonal(int64_t n, int64_t lo, int64_t hi)
{
    uint64_t c = 0;
    for (int64_t i = 0; i < n; i++)
        for (int64_t j = 0; j < n; j++) {
            int64_t a = lo - i - j, b = hi - i - j;
            if (a < 0)
                a = 0;
            if (b > n - 1)
                b = n - 1;
            if (b >= a)
                c += (uint64_t)(b - a + 1);
        }
    return c;
}

/* The plane x + y + z = 6 over the whole grid [0,4]^3: cell (i,j,k) touches
 * it iff (i+j+k) c <= 6 <= (i+j+k+3) c, corners counting. */
static void test_huge_diagonal_triangle(void **state)
{
    (void)state;
    float t[9] = {-20, 13, 13, 13, -20, 13, 13, 13, -20};
    for (uint32_t depth = 1; depth <= VOXEL_DEPTH_MAX; depth++) {
        voxel_grid g;
        int64_t n = 1 << depth, s = 6 * n / 4; /* 6 / c */
        grid_init(&g, depth, 0, 0, 0, 4, 4, 4);
        assert_int_equal(voxel_mark(&g, t, 1), 0);
        assert_int_equal(g.occupied, count_diagonal(n, s - 3, s));
        assert_int_equal(g.occupied, popcount_grid(&g));
        if (depth <= 7) { /* every cell (deeper: a sample of columns) */
            for (int64_t k = 0; k < n; k++)
                for (int64_t j = 0; j < n; j++)
                    for (int64_t i = 0; i < n; i++)
                        assert_int_equal(voxel_get(&g, (uint32_t)i, (uint32_t)j, (uint32_t)k),
                                         i + j + k >= s - 3 && i + j + k <= s);
        } else {
            for (int64_t j = 0; j < n; j += 37)
                for (int64_t i = 0; i < n; i += 41)
                    for (int64_t k = 0; k < n; k++)
                        assert_int_equal(voxel_get(&g, (uint32_t)i, (uint32_t)j, (uint32_t)k),
                                         i + j + k >= s - 3 && i + j + k <= s);
        }
        if (depth == 6)
            check_grid(&g, t, 1);
        voxel_grid_free(&g);
    }
}

static void test_tiny_and_degenerate(void **state)
{
    (void)state;
    voxel_grid g;
    unit_grid(&g);
    mark1(&g, 2.4, 1.4, 3.4, 2.41, 1.4, 3.4, 2.4, 1.41, 3.41); /* tiny, inside one cell */
    assert_int_equal(g.occupied, 1);
    assert_true(voxel_get(&g, 2, 1, 3));
    voxel_grid_free(&g);

    unit_grid(&g);
    mark1(&g, 1, 1, 1, 1, 1, 1, 1, 1, 1); /* a point on a corner: 8 cells */
    assert_int_equal(g.occupied, 8);
    mark1(&g, 3.5, 3.5, 3.5, 3.5, 3.5, 3.5, 3.5, 3.5, 3.5); /* a point inside a cell */
    assert_int_equal(g.occupied, 9);
    voxel_grid_free(&g);

    unit_grid(&g);
    mark1(&g, 0.5, 0.5, 0.5, 3.5, 0.5, 0.5, 2, 0.5, 0.5); /* collinear, along x */
    assert_int_equal(g.occupied, 4);
    float seg[9] = {0.5f, 1.5f, 0.5f, 3.5f, 3.5f, 3.5f, 2, 2.5f, 2}; /* collinear, slanted */
    voxel_grid s;
    unit_grid(&s);
    assert_int_equal(voxel_mark(&s, seg, 1), 0);
    check_grid(&s, seg, 1);
    /* x = z crosses the cell edges x = z = 1, 2, 3 (four cells each) and y
     * crosses 2 and 3 between them: 12 cells. */
    assert_int_equal(s.occupied, 12);
    voxel_grid_free(&s);
    voxel_grid_free(&g);
}

static void test_outside_and_empty(void **state)
{
    (void)state;
    voxel_grid g;
    unit_grid(&g);
    mark1(&g, 5, 5, 5, 6, 5, 5, 5, 6, 5);
    mark1(&g, -3, 0, 0, -1, 4, 0, -2, 2, 4);
    mark1(&g, 1e30, 0, 0, 0, 1e30, 0, 1e30, 1e30, 0); /* huge, in the plane z = 0 but x + y >= 1e30 */
    assert_int_equal(g.occupied, 0);
    /* A plane cutting only past the far corner: x + y + z = 12.001. */
    mark1(&g, 12.001, 0, 0, 0, 12.001, 0, 0, 0, 12.001);
    assert_int_equal(g.occupied, 0);
    assert_int_equal(voxel_mark(&g, NULL, 0), 0);
    assert_int_equal(popcount_grid(&g), 0);
    voxel_grid_free(&g);
}

static void test_flat_boxes(void **state)
{
    (void)state;
    voxel_grid g;
    /* A floor: the box is flat in y. Its cells along y are copies. */
    grid_init(&g, 2, 0, 2, 0, 4, 2, 4);
    assert_true(g.cell[1] == 0.0);
    mark1(&g, 0.5, 2, 0.5, 1.5, 2, 0.5, 0.5, 2, 1.5); /* on the floor: 2 x 2 columns */
    assert_int_equal(g.occupied, 4 * 4);
    for (uint32_t j = 0; j < 4; j++)
        assert_true(voxel_get(&g, 0, j, 0) && voxel_get(&g, 1, j, 0) && voxel_get(&g, 0, j, 1));
    mark1(&g, 0.5, 2.5, 0.5, 3.5, 2.5, 0.5, 0.5, 2.5, 3.5); /* above the floor */
    assert_int_equal(g.occupied, 16);
    mark1(&g, 3.5, 1, 3.5, 3.5, 3, 3.5, 3.5, 3, 3.6); /* a wall crossing it in one cell */
    assert_int_equal(g.occupied, 20);
    assert_true(voxel_get(&g, 3, 2, 3));
    voxel_grid_free(&g);
    grid_init(&g, 4, 0, 2, 0, 4, 2, 4);
    float big[9] = {-1, 1, -1, 9, 3, -1, -1, 3, 9};
    assert_int_equal(voxel_mark(&g, big, 1), 0);
    check_grid(&g, big, 1);
    voxel_grid_free(&g);

    /* Flat on x and z: a vertical line of cells. */
    grid_init(&g, 3, 1, 0, 1, 1, 8, 1);
    mark1(&g, 0, 2.5, 0, 2, 2.5, 2, 2, 2.5, 0); /* crosses the line at y = 2.5 */
    assert_int_equal(g.occupied, 64);
    voxel_grid_free(&g);

    /* A point box: every cell is that point. */
    grid_init(&g, 2, 1, 1, 1, 1, 1, 1);
    mark1(&g, 0, 1, 1, 2, 1, 1, 1, 2, 1); /* through it */
    assert_int_equal(g.occupied, 64);
    assert_int_equal(popcount_grid(&g), 64);
    voxel_grid_free(&g);
    grid_init(&g, 2, 1, 1, 1, 1, 1, 1);
    mark1(&g, 0, 0, 0, 2, 0, 0, 0, 2, 0); /* the plane z = 0 */
    assert_int_equal(g.occupied, 0);
    voxel_grid_free(&g);
}

static void test_bad_arguments(void **state)
{
    (void)state;
    voxel_grid g;
    float lo[3] = {0, 0, 0}, hi[3] = {1, 1, 1};
    assert_int_equal(voxel_grid_init(&g, VOXEL_DEPTH_MIN - 1, lo, hi), -EINVAL);
    assert_null(g.bits);
    assert_int_equal(voxel_grid_init(&g, VOXEL_DEPTH_MAX + 1, lo, hi), -EINVAL);
    assert_int_equal(voxel_grid_init(NULL, 3, lo, hi), -EINVAL);
    assert_int_equal(voxel_grid_init(&g, 3, NULL, hi), -EINVAL);
    float bad[3] = {0, 2, 0};
    assert_int_equal(voxel_grid_init(&g, 3, bad, hi), -EINVAL); /* min > max */
    bad[1] = NAN;
    assert_int_equal(voxel_grid_init(&g, 3, bad, hi), -EINVAL);
    bad[1] = INFINITY;
    assert_int_equal(voxel_grid_init(&g, 3, lo, bad), -EINVAL);
    voxel_grid_free(&g);
    voxel_grid_free(NULL);

    assert_int_equal(voxel_grid_init(&g, VOXEL_DEPTH_MIN, lo, hi), 0);
    assert_int_equal(g.n, 2);
    voxel_grid_free(&g);
    assert_int_equal(voxel_grid_init(&g, VOXEL_DEPTH_MAX, lo, hi), 0);
    assert_int_equal(g.n, 1024);
    voxel_grid_free(&g);

    /* A non-finite coordinate anywhere: nothing marked, even before it. */
    assert_int_equal(voxel_grid_init(&g, 3, lo, hi), 0);
    float t[18] = {0.1f, 0.1f, 0.1f, 0.9f, 0.1f, 0.1f, 0.1f, 0.9f, 0.1f,
                   0.1f, 0.1f, 0.5f, 0.9f, 0.1f, 0.5f, 0.1f, 0.9f, 0.5f};
    for (int i = 0; i < 18; i += 5) {
        float saved = t[i];
        t[i] = i % 2 ? NAN : -INFINITY;
        assert_int_equal(voxel_mark(&g, t, 2), -EINVAL);
        assert_int_equal(g.occupied, 0);
        assert_int_equal(popcount_grid(&g), 0);
        t[i] = saved;
    }
    assert_int_equal(voxel_mark(&g, t, 2), 0);
    assert_true(g.occupied > 0);
    assert_int_equal(voxel_mark(&g, NULL, 1), -EINVAL);
    assert_int_equal(voxel_mark(NULL, t, 1), -EINVAL);
    voxel_grid_free(&g);
    assert_int_equal(voxel_mark(&g, t, 1), -EINVAL); /* freed: no bits */
}

static void test_allocation_failure(void **state)
{
    (void)state;
    voxel_grid g;
    float lo[3] = {0, 0, 0}, hi[3] = {1, 1, 1};
    cvre_alloc_fail_after(0);
    assert_int_equal(voxel_grid_init(&g, 5, lo, hi), -ENOMEM);
    cvre_alloc_fail_after(-1);
    assert_null(g.bits);
    assert_int_equal(g.occupied, 0);
    voxel_grid_free(&g);
    /* Marking allocates nothing, so it cannot fail for memory. */
    assert_int_equal(voxel_grid_init(&g, 5, lo, hi), 0);
    cvre_alloc_fail_after(0);
    float t[9] = {0, 0, 0, 1, 0, 0, 0, 1, 1};
    assert_int_equal(voxel_mark(&g, t, 1), 0);
    cvre_alloc_fail_after(-1);
    assert_true(g.occupied > 32);
    voxel_grid_free(&g);
}

/* ---- voxel_tri_box_overlap's truth table -------------------------------- */

static int overlap(double ax, double ay, double az, double bx, double by, double bz, double cx, double cy,
                   double cz)
{
    static const double lo[3] = {0, 0, 0}, hi[3] = {1, 1, 1};
    double t[9] = {ax, ay, az, bx, by, bz, cx, cy, cz};
    int r = voxel_tri_box_overlap(t, lo, hi);
    /* The vertex order never matters. */
    double u[9] = {cx, cy, cz, ax, ay, az, bx, by, bz}, w[9] = {bx, by, bz, ax, ay, az, cx, cy, cz};
    assert_int_equal(voxel_tri_box_overlap(u, lo, hi), r);
    assert_int_equal(voxel_tri_box_overlap(w, lo, hi), r);
    return r;
}

static void test_overlap_truth_table(void **state)
{
    (void)state;
    /* Inside, crossing, containing a face. */
    assert_true(overlap(0.2, 0.2, 0.2, 0.8, 0.2, 0.2, 0.2, 0.8, 0.8));
    assert_true(overlap(-5, -5, 0.5, 5, -5, 0.5, 0, 5, 0.5));
    /* Touching: at the far corner, by a vertex; along an edge; on a face. */
    assert_true(overlap(1, 1, 1, 2, 1, 1, 1, 2, 1));
    assert_true(overlap(1, 1, 1, 2, 2, 2, 3, 1, 2));
    assert_true(overlap(0.5, 1, 1, 0.5, 2, 1, 0.5, 1, 2));
    assert_true(overlap(-1, 1, 1, 2, 1, 1, 0.5, 2, 2)); /* an edge along the box's edge */
    assert_true(overlap(0.2, 0.2, 1, 0.8, 0.2, 1, 0.2, 0.8, 1));
    assert_true(overlap(-1, -1, 0, 3, -1, 0, -1, 3, 0));
    /* Just off a face, or beyond a corner on the box axes. */
    assert_false(overlap(0.2, 0.2, 1 + 1e-9, 0.8, 0.2, 1 + 1e-9, 0.2, 0.8, 1 + 1e-9));
    assert_false(overlap(1.5, 1.5, 1.5, 2, 1.5, 1.5, 1.5, 2, 1.5));
    /* Separated by the normal only: the plane x + y + z = 3.001 passes the
     * corner (1,1,1); at exactly 3 it touches it. */
    assert_false(overlap(3.001, 0, 0, 0, 3.001, 0, 0, 0, 3.001));
    assert_true(overlap(3, 0, 0, 0, 3, 0, 0, 0, 3));
    assert_false(overlap(-0.001, 0, 0, 0, -0.001, 0, 0, 0, -0.001));
    /* Separated by an edge cross product only: in the plane x + y = 1.5,
     * which crosses the box, but beside it; moving one vertex down makes it
     * touch the box's edge x = 1, z = 1 at (1, 0.5, 1). */
    assert_false(overlap(1.5, 0, 2, 0, 1.5, 2, 1.5, 0, 0.6));
    assert_true(overlap(1.5, 0, 2, 0, 1.5, 2, 1.5, 0, 0.5));
    /* Degenerate: points and segments, where only edge axes can separate. */
    assert_true(overlap(0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5));
    assert_true(overlap(1, 0, 1, 1, 0, 1, 1, 0, 1));
    assert_false(overlap(1, 0, 1.5, 1, 0, 1.5, 1, 0, 1.5));
    assert_true(overlap(2, -0.5, 0.5, -0.5, 2, 0.5, 2, -0.5, 0.5));    /* x + y = 1.5 */
    assert_true(overlap(2.5, -0.5, 0.5, -0.5, 2.5, 0.5, 2.5, -0.5, 0.5)); /* x + y = 2: the edge */
    assert_false(overlap(2.6, -0.5, 0.5, -0.5, 2.6, 0.5, 2.6, -0.5, 0.5));
    assert_false(overlap(-1, 0.5, -0.001, 2, 0.5, -0.001, 0.5, 0.5, -0.001));
    /* A flat box (z from 0.5 to 0.5). */
    double lo[3] = {0, 0, 0.5}, hi[3] = {1, 1, 0.5};
    double cross[9] = {0.5, 0.5, 0, 0.5, 0.5, 1, 0.6, 0.5, 1}, above[9] = {0, 0, 0.6, 1, 0, 0.6, 0, 1, 0.7};
    assert_true(voxel_tri_box_overlap(cross, lo, hi));
    assert_false(voxel_tri_box_overlap(above, lo, hi));
}

/* ---- a real model ------------------------------------------------------- */

static float *load_model(const char *rel, import_mesh *m)
{
    char path[4096], err[256];
    snprintf(path, sizeof path, "%s/%s", models_dir, rel);
    FILE *f = fopen(path, "rb");
    if (!f)
        fail_msg("cannot open %s (pass the models folder as the first argument)", path);
    assert_int_equal(fseek(f, 0, SEEK_END), 0);
    long size = ftell(f);
    assert_true(size > 0);
    rewind(f);
    char *data = malloc((size_t)size);
    assert_non_null(data);
    assert_int_equal(fread(data, 1, (size_t)size, f), (size_t)size);
    fclose(f);
    import_options opt = IMPORT_OPTIONS_DEFAULT;
    int rc = import_model(data, (size_t)size, "obj", &opt, m, err, sizeof err);
    free(data);
    if (rc != 0)
        fail_msg("import %s: %s", path, err);
    return m->tris;
}

/* The summed-volume table against sums cell by cell, for every box of a
 * small grid of random bytes, taken whole and through a mask. */
/* voxel_mark_boxed's loose marking: a triangle over 2 x 2 x 2 cells that
 * misses one of them sets all eight loosely, seven exactly; over more cells
 * than `loose`, its exact cells. */
static void test_loose_marks_the_box(void **state)
{
    (void)state;
    const float t[9] = {0.5f, 0.5f, 0.5f, 1.5f, 0.6f, 0.5f, 0.5f, 1.5f, 1.5f};
    char err[128] = "";
    trimesh m;
    assert_int_equal(trimesh_init(&m, t, 1, err, sizeof err), 0);
    voxel_grid exact, loose, wide;
    grid_init(&exact, 2, 0, 0, 0, 4, 4, 4);
    grid_init(&loose, 2, 0, 0, 0, 4, 4, 4);
    grid_init(&wide, 2, 0, 0, 0, 4, 4, 4);
    assert_int_equal(voxel_mark_boxed(&exact, m.tris, (const float(*)[6])m.box, 1, 0, 1), 0);
    assert_int_equal(voxel_mark_boxed(&loose, m.tris, (const float(*)[6])m.box, 1, 8, 1), 0);
    assert_int_equal(voxel_mark_boxed(&wide, m.tris, (const float(*)[6])m.box, 1, 7, 1), 0);
    assert_int_equal(exact.occupied, 7);
    assert_false(voxel_get(&exact, 1, 0, 1));
    assert_int_equal(loose.occupied, 8);
    assert_true(voxel_get(&loose, 1, 0, 1));
    assert_int_equal(wide.occupied, 7);
    assert_memory_equal(wide.bits, exact.bits, 8);
    voxel_grid_free(&exact);
    voxel_grid_free(&loose);
    voxel_grid_free(&wide);
    trimesh_free(&m);
}

static void test_svt_against_sums(void **state)
{
    (void)state;
    enum { N = 5 };
    uint8_t bytes[N * N * N];
    uint32_t t[(N + 1) * (N + 1) * (N + 1)], seed = 7;
    for (size_t i = 0; i < sizeof bytes; i++) {
        seed = seed * 1664525u + 1013904223u;
        bytes[i] = (uint8_t)(seed >> 24);
    }
    const uint8_t masks[] = {0, 0x12};
    for (int k = 0; k < 2; k++) {
        voxel_svt s;
        voxel_svt_build(&s, t, N, bytes, masks[k]);
        uint32_t lo[3], hi[3];
        for (lo[0] = 0; lo[0] <= N; lo[0]++)
            for (hi[0] = lo[0]; hi[0] <= N; hi[0]++)
                for (lo[1] = 0; lo[1] <= N; lo[1]++)
                    for (hi[1] = lo[1]; hi[1] <= N; hi[1]++)
                        for (lo[2] = 0; lo[2] <= N; lo[2]++)
                            for (hi[2] = lo[2]; hi[2] <= N; hi[2]++) {
                                uint32_t want = 0;
                                for (uint32_t z = lo[2]; z < hi[2]; z++)
                                    for (uint32_t y = lo[1]; y < hi[1]; y++)
                                        for (uint32_t x = lo[0]; x < hi[0]; x++) {
                                            uint8_t b = bytes[x + N * (y + N * z)];
                                            want += masks[k] ? (b & masks[k]) != 0 : b;
                                        }
                                assert_int_equal(voxel_svt_sum(&s, lo, hi), want);
                            }
    }
}

/* The real model's test, named after its file (tests/models.h). */
#define BUNNY "classic/stanford-bunny.obj"

static void test_bunny(void **state)
{
    (void)state;
    import_mesh m;
    voxel_grid g, h;
    load_model(BUNNY, &m);
    assert_int_equal(m.ntris, 69451);
    assert_int_equal(voxel_grid_init(&g, 6, m.min, m.max), 0);
    assert_int_equal(voxel_mark(&g, m.tris, m.ntris), 0);
    /* Every vertex's cell is marked. */
    for (size_t i = 0; i < 3 * (size_t)m.ntris; i++) {
        uint32_t c[3];
        for (int a = 0; a < 3; a++) {
            double f = floor(((double)m.tris[3 * i + (size_t)a] - g.min[a]) / g.cell[a]);
            c[a] = f >= g.n ? g.n - 1 : (uint32_t)f;
        }
        assert_true(voxel_get(&g, c[0], c[1], c[2]));
    }
    /* A surface, not a solid nor a sprinkle: the bunny's skin at 64^3. */
    printf("bunny at 64^3: %llu cells\n", (unsigned long long)g.occupied);
    assert_true(g.occupied > 5000 && g.occupied < 20000);
    /* Exactly what the reference says, triangle by triangle. */
    check_grid(&g, m.tris, m.ntris);

    /* Deterministic, and independent of triangle order and of splitting
     * the mesh across calls. */
    float *rev = malloc(36 * (size_t)m.ntris);
    assert_non_null(rev);
    for (size_t t = 0; t < m.ntris; t++)
        memcpy(rev + 9 * t, m.tris + 9 * (m.ntris - 1 - t), 36);
    assert_int_equal(voxel_grid_init(&h, 6, m.min, m.max), 0);
    assert_int_equal(voxel_mark(&h, rev, 1000), 0);
    assert_int_equal(voxel_mark(&h, rev + 9000, m.ntris - 1000), 0);
    assert_int_equal(h.occupied, g.occupied);
    assert_memory_equal(h.bits, g.bits, 64 * 64 * 64 / 8);
    free(rev);
    voxel_grid_free(&h);
    /* On threads, at a depth where slabs are many layers thick. */
    for (uint32_t depth = 6; depth <= 8; depth += 2) {
        voxel_grid one;
        assert_int_equal(voxel_grid_init(&one, depth, m.min, m.max), 0);
        assert_int_equal(voxel_mark(&one, m.tris, m.ntris), 0);
        for (unsigned threads = 0; threads <= 3; threads++) {
            assert_int_equal(voxel_grid_init(&h, depth, m.min, m.max), 0);
            assert_int_equal(voxel_mark_threads(&h, m.tris, m.ntris, threads), 0);
            assert_int_equal(h.occupied, one.occupied);
            assert_memory_equal(h.bits, one.bits, (size_t)one.n * one.n * one.n / 8);
            voxel_grid_free(&h);
        }
        voxel_grid_free(&one);
    }
    voxel_grid_free(&g);
    import_mesh_free(&m);
}

int main(int argc, char **argv)
{
    models_select sel;
    models_args(argc, argv, "The voxelizer against an independent reference, and on a real model.", &models_dir,
                &sel);
    struct CMUnitTest tests[] = {
        cmocka_unit_test(test_overlap_truth_table),
        cmocka_unit_test(test_triangle_on_cell_face),
        cmocka_unit_test(test_triangle_on_outer_faces),
        cmocka_unit_test(test_triangle_along_cell_edges),
        cmocka_unit_test(test_sliver),
        cmocka_unit_test(test_huge_diagonal_triangle),
        cmocka_unit_test(test_tiny_and_degenerate),
        cmocka_unit_test(test_outside_and_empty),
        cmocka_unit_test(test_flat_boxes),
        cmocka_unit_test(test_bad_arguments),
        cmocka_unit_test(test_allocation_failure),
        cmocka_unit_test(test_random_triangles_against_reference),
        cmocka_unit_test(test_large_triangles_against_reference),
        cmocka_unit_test(test_one_call_equals_union),
        cmocka_unit_test(test_threads_equal_one_thread),
        cmocka_unit_test(test_nearly_flat_slabs),
        cmocka_unit_test(test_mesh_equals_triangles),
        cmocka_unit_test(test_loose_marks_the_box),
        cmocka_unit_test(test_svt_against_sums),
        {BUNNY, test_bunny, NULL, NULL, NULL},
    };
    return models_run("test_voxel", tests, sizeof tests / sizeof tests[0], &sel);
}
