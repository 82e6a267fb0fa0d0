/*
 * The model importer against the shared test models and hostile input.
 *
 * Usage: test_import MODELS_DIR [--only PATTERN]... [--skip PATTERN]...
 * (MODELS_DIR: the shared/models folder). Triangle counts and bounding
 * boxes are compared with the table in MODELS_DIR/SOURCES.md, read at run
 * time, for every file in openings/, formats/, classic/ and scenes/, each
 * a test named after the file (tests/models.h); the table and the folders
 * must list the same files.
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
#include <time.h>
#include <unistd.h>

#include <assimp/cimport.h>

#include "../models.h"
#include "alloc.h"
#include "import.h"

static const char *models_dir;

/* ---- helpers ------------------------------------------------------------ */

typedef struct buf {
    char *p;
    size_t n;
} buf;

static buf read_file(const char *path)
{
    buf b = {NULL, 0};
    FILE *f = fopen(path, "rb");
    long size;

    if (!f)
        fail_msg("cannot open %s", path);
    assert_int_equal(fseek(f, 0, SEEK_END), 0);
    size = ftell(f);
    assert_true(size >= 0);
    rewind(f);
    b.n = (size_t)size;
    b.p = malloc(b.n + 1);
    assert_non_null(b.p);
    assert_int_equal(fread(b.p, 1, b.n, f), b.n);
    fclose(f);
    return b;
}

static buf read_model(const char *rel)
{
    char path[4096];

    snprintf(path, sizeof path, "%s/%s", models_dir, rel);
    return read_file(path);
}

/* A buffer holding the text s (without its NUL). */
static buf text(const char *s)
{
    buf b;

    b.n = strlen(s);
    b.p = malloc(b.n + 1);
    assert_non_null(b.p);
    memcpy(b.p, s, b.n + 1);
    return b;
}

static void put32(unsigned char *p, uint32_t v)
{
    for (int i = 0; i < 4; i++)
        p[i] = (unsigned char)(v >> (8 * i));
}

/* A GLB of the JSON text and a binary chunk, both padded to four bytes. */
static buf glb(const char *json, const void *bin, size_t binlen)
{
    size_t jl = (strlen(json) + 3) & ~(size_t)3, bl = (binlen + 3) & ~(size_t)3;
    buf b;
    unsigned char *p;

    b.n = 12 + 8 + jl + (binlen ? 8 + bl : 0);
    b.p = calloc(1, b.n);
    assert_non_null(b.p);
    p = (unsigned char *)b.p;
    memcpy(p, "glTF", 4);
    put32(p + 4, 2);
    put32(p + 8, (uint32_t)b.n);
    put32(p + 12, (uint32_t)jl);
    put32(p + 16, 0x4E4F534Au);
    memset(p + 20, ' ', jl);
    memcpy(p + 20, json, strlen(json));
    if (binlen) {
        put32(p + 20 + jl, (uint32_t)bl);
        put32(p + 24 + jl, 0x004E4942u);
        memcpy(p + 28 + jl, bin, binlen);
    }
    return b;
}

/* One triangle (0,0,0) (1,0,0) (0,1,0) as a GLB with the given nodes and
 * scenes JSON, mesh 0 being that triangle. */
static buf glb_triangle(const char *nodes_and_scenes)
{
    static const float tri[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    size_t cap = strlen(nodes_and_scenes) + 1024;
    char *json = malloc(cap);
    buf b;

    assert_non_null(json);
    snprintf(
        json, cap,
        "{\"asset\":{\"version\":\"2.0\"},%s,"
        "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0}}]}],"
        "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":3,"
        "\"type\":\"VEC3\",\"min\":[0,0,0],\"max\":[1,1,0]}],"
        "\"bufferViews\":[{\"buffer\":0,\"byteLength\":36}],\"buffers\":[{\"byteLength\":36}]}",
        nodes_and_scenes);
    b = glb(json, tri, sizeof tri);
    free(json);
    return b;
}

/* The first occurrence of s in b (which may hold NULs), or NULL. */
static char *find(buf b, const char *s)
{
    size_t k = strlen(s);

    for (size_t i = 0; i + k <= b.n; i++)
        if (memcmp(b.p + i, s, k) == 0)
            return b.p + i;
    return NULL;
}

static double now(void)
{
    struct timespec t;

    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + (double)t.tv_nsec * 1e-9;
}

/* Imports b with hint and options; checks the promises of a success (every
 * vertex finite and inside the box, the box tight) or of a failure (a
 * known code, a message, a zeroed mesh). Returns the code. */
static int run(buf b, const char *hint, const import_options *o, import_mesh *m, char *err,
               size_t errlen)
{
    int rc = import_model(b.p, b.n, hint, o, m, err, errlen);

    if (rc != 0) {
        assert_true(rc == -EINVAL || rc == -EFBIG || rc == -ENOMEM);
        assert_true(err[0] != 0);
        assert_null(m->tris);
        assert_int_equal(m->ntris, 0);
        return rc;
    }
    assert_string_equal(err, "");
    assert_non_null(m->tris);
    assert_true(m->ntris >= 1);
    {
        float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
        for (size_t i = 0; i < (size_t)m->ntris * 9; i++) {
            float v = m->tris[i];
            assert_true(isfinite(v));
            lo[i % 3] = fminf(lo[i % 3], v);
            hi[i % 3] = fmaxf(hi[i % 3], v);
        }
        for (int k = 0; k < 3; k++) {
            assert_true(lo[k] == m->min[k]);
            assert_true(hi[k] == m->max[k]);
        }
    }
    return 0;
}

/* Imports and expects failure rc with why in the message. */
static void expect_fail(buf b, const char *hint, int rc, const char *why)
{
    import_mesh m;
    char err[256];
    int got = run(b, hint, NULL, &m, err, sizeof err);

    if (got != rc || !strstr(err, why))
        fail_msg("expected %d \"%s\", got %d \"%s\"", rc, why, got, err);
}

/* Imports with default options and expects success with ntris triangles. */
static import_mesh expect_ok(buf b, const char *hint, uint32_t ntris)
{
    import_mesh m;
    char err[256];
    int rc = run(b, hint, NULL, &m, err, sizeof err);

    if (rc != 0)
        fail_msg("expected success, got %d \"%s\"", rc, err);
    assert_int_equal(m.ntris, ntris);
    return m;
}

static int close_to(float got, double want)
{
    return fabs((double)got - want) <= 1e-4 * fabs(want) + 1e-7;
}

/* ---- the SOURCES.md table ----------------------------------------------- */

typedef struct model_row {
    char file[256];
    uint32_t tris;
    double min[3], max[3];
} model_row;

#define MAX_ROWS 64
static model_row rows[MAX_ROWS];
static int nrows;

static int parse_vec(const char *s, double v[3])
{
    return sscanf(s, " (%lf, %lf, %lf)", &v[0], &v[1], &v[2]) == 3;
}

/* Reads rows like  | `dir/file` | tris | verts | (min) | (max) | size |. */
static void load_table(void)
{
    char path[4096], line[1024];
    FILE *f;

    snprintf(path, sizeof path, "%s/SOURCES.md", models_dir);
    f = fopen(path, "r");
    if (!f)
        fail_msg("cannot open %s", path);
    nrows = 0;
    while (fgets(line, sizeof line, f)) {
        char *col[7];
        int n = 0;
        model_row *r = &rows[nrows];
        if (strncmp(line, "| `", 3) != 0)
            continue;
        for (char *s = strtok(line + 1, "|"); s && n < 7; s = strtok(NULL, "|"))
            col[n++] = s;
        assert_true(n >= 5);
        assert_int_equal(sscanf(col[0], " `%255[^`]`", r->file), 1);
        r->tris = (uint32_t)strtoul(col[1], NULL, 10);
        assert_true(parse_vec(col[3], r->min) && parse_vec(col[4], r->max));
        assert_true(++nrows < MAX_ROWS);
    }
    fclose(f);
    assert_true(nrows >= 15);
}

static const model_row *find_row(const char *file)
{
    for (int i = 0; i < nrows; i++)
        if (strcmp(rows[i].file, file) == 0)
            return &rows[i];
    return NULL;
}

/* ---- tests -------------------------------------------------------------- */

/* One model (state: its path under MODELS_DIR, from the folder listing):
 * its SOURCES.md row's triangle count and box, with its extension as the
 * format hint and with none; then the file cut short. */
static void test_model(void **state)
{
    const char *file = *state, *hints[2];
    const model_row *r;
    buf b;

    load_table();
    r = find_row(file);
    if (!r)
        fail_msg("%s is not in SOURCES.md's table", file);
    b = read_model(file);
    hints[0] = strrchr(file, '.') + 1;
    hints[1] = NULL;
    for (int h = 0; h < 2; h++) {
        import_mesh m;
        char err[256];
        double t0 = now(), t1;
        int rc = run(b, hints[h], NULL, &m, err, sizeof err);
        t1 = now();
        if (rc != 0)
            fail_msg("%s (hint %s): %d %s", file, hints[h] ? hints[h] : "NULL", rc, err);
        if (m.ntris != r->tris)
            fail_msg("%s: %u triangles, SOURCES.md says %u", file, m.ntris, r->tris);
        for (int k = 0; k < 3; k++)
            if (!close_to(m.min[k], r->min[k]) || !close_to(m.max[k], r->max[k]))
                fail_msg("%s: box axis %d [%g, %g], SOURCES.md says [%g, %g]", file, k, (double)m.min[k],
                         (double)m.max[k], r->min[k], r->max[k]);
        if (h == 0)
            print_message("%-45s %7u triangles %8.1f ms\n", file, m.ntris, (t1 - t0) * 1e3);
        import_mesh_free(&m);
    }
    /* Cut short at several lengths, with and without the hint: an error
     * or a mesh. The big scenes are cut at half their length and later only. */
    {
        size_t cuts[] = {1, 2, 10, 20, 83, 84, 100, 134, b.n / 4, b.n / 2, b.n - b.n / 4, b.n - 1};
        int big = strncmp(file, "scenes/", 7) == 0;
        for (size_t c = big ? 9 : 0; c < sizeof cuts / sizeof cuts[0]; c++)
            for (int h = 0; h < 2; h++) {
                import_mesh m;
                char err[256];
                if (cuts[c] == 0 || cuts[c] >= b.n)
                    continue;
                if (run((buf){b.p, cuts[c]}, hints[h], NULL, &m, err, sizeof err) == 0)
                    import_mesh_free(&m);
            }
    }
    free(b.p);
}

/* The table and the folders agree: a model without a row would go
 * untested, a row without its file would test nothing. */
static void test_every_model_is_listed(void **state)
{
    size_t n;
    char **files = models_list(models_dir, &n);

    (void)state;
    assert_non_null(files);
    load_table();
    for (size_t i = 0; i < n; i++)
        if (!find_row(files[i]))
            fail_msg("%s is not in SOURCES.md's table", files[i]);
    for (int i = 0; i < nrows; i++) {
        size_t k = 0;
        while (k < n && strcmp(files[k], rows[i].file) != 0)
            k++;
        if (k == n)
            fail_msg("SOURCES.md lists %s, which is not in %s", rows[i].file, models_dir);
    }
    for (size_t i = 0; i < n; i++)
        free(files[i]);
    free(files);
}

static void test_up_axis_and_scale(void **state)
{
    buf b = read_model("openings/openfoam_room_with_doorway.stl");
    import_options o = IMPORT_OPTIONS_DEFAULT;
    import_mesh plain, m;
    char err[256];

    (void)state;
    assert_int_equal(run(b, "stl", &o, &plain, err, sizeof err), 0);

    o.z_up = 1; /* (x,y,z) -> (x,z,-y) */
    assert_int_equal(run(b, "stl", &o, &m, err, sizeof err), 0);
    assert_int_equal(m.ntris, plain.ntris);
    assert_true(m.min[0] == plain.min[0] && m.max[0] == plain.max[0]);
    assert_true(m.min[1] == plain.min[2] && m.max[1] == plain.max[2]); /* height: old z */
    assert_true(m.min[2] == -plain.max[1] && m.max[2] == -plain.min[1]);
    for (size_t i = 0; i < (size_t)m.ntris * 3; i++) {
        const float *p = plain.tris + 3 * i, *q = m.tris + 3 * i;
        assert_true(q[0] == p[0] && q[1] == p[2] && q[2] == -p[1]);
    }
    import_mesh_free(&m);

    o.unit_scale = 0.01f; /* centimetres */
    assert_int_equal(run(b, "stl", &o, &m, err, sizeof err), 0);
    for (int k = 0; k < 3; k++) {
        int from = k == 1 ? 2 : k;
        float lo = k == 2 ? -plain.max[1] : plain.min[from];
        float hi = k == 2 ? -plain.min[1] : plain.max[from];
        assert_true(close_to(m.min[k], (double)lo * 0.01));
        assert_true(close_to(m.max[k], (double)hi * 0.01));
    }
    import_mesh_free(&m);
    import_mesh_free(&plain);
    free(b.p);
}

/* Node transforms compose parent first; a mesh used by two nodes is two
 * instances. */
static void test_node_transforms(void **state)
{
    buf b = glb_triangle("\"scene\":0,\"scenes\":[{\"nodes\":[0,2]}],"
                         "\"nodes\":[{\"translation\":[10,0,0],\"scale\":[2,2,2],\"children\":[1]},"
                         "{\"translation\":[0,5,0],\"mesh\":0},"
                         "{\"translation\":[0,0,-3],\"mesh\":0}]");
    import_mesh m = expect_ok(b, "glb", 2);
    /* 2 * (v + (0,5,0)) + (10,0,0), then v + (0,0,-3) */
    static const float want[18] = {10, 10, 0, 12, 10, 0, 10, 12, 0, 0, 0, -3, 1, 0, -3, 0, 1, -3};

    (void)state;
    for (int i = 0; i < 18; i++)
        assert_true(close_to(m.tris[i], want[i]));
    assert_true(m.min[0] == 0 && m.min[1] == 0 && m.min[2] == -3);
    assert_true(m.max[0] == 12 && m.max[1] == 12 && m.max[2] == 0);
    import_mesh_free(&m);
    free(b.p);
}

/* The content decides the format; a hint only matters for data without a
 * signature (parsed as OBJ if the hint says obj) and for the message. */
static void test_hint_vs_detection(void **state)
{
    buf stl = read_model("openings/openfoam_desk.stl");
    buf bin = read_model("formats/assimp_Spider_binary.stl");
    buf g = read_model("openings/kenney_building-garage.glb");
    buf obj = read_model("classic/teapot.obj");
    buf readme = text("Hello, this is a README, not a model.\n");
    const char *hints[] = {"stl", "STL", ".stl", "", NULL, "obj", "glb", "ply"};
    import_mesh m;

    (void)state;
    for (size_t i = 0; i < sizeof hints / sizeof hints[0]; i++) {
        m = expect_ok(stl, hints[i], 60);
        import_mesh_free(&m);
        m = expect_ok(bin, hints[i], 1368);
        import_mesh_free(&m);
        m = expect_ok(g, hints[i], 196);
        import_mesh_free(&m);
        m = expect_ok(obj, hints[i], 6320);
        import_mesh_free(&m);
    }
    expect_fail(stl, "fbx", -EINVAL, "unsupported format \"fbx\" (supported: obj stl ply glb)");
    expect_fail(stl, "dae", -EINVAL, "unsupported format");
    expect_fail(stl, "o\nbj\x01", -EINVAL, "unsupported format \"o?bj?\""); /* one line */
    expect_fail(readme, NULL, -EINVAL, "unrecognised format (supported: obj stl ply glb)");
    expect_fail(readme, "stl", -EINVAL, "not a valid STL file");
    expect_fail(readme, "glb", -EINVAL, "not a valid GLB file");
    expect_fail(readme, "obj", -EINVAL, "no triangles");
    free(stl.p);
    free(bin.p);
    free(g.p);
    free(obj.p);
    free(readme.p);
}

static buf ply_ascii(const char *counts_and_props, const char *body)
{
    char s[1024];

    snprintf(s, sizeof s, "ply\nformat ascii 1.0\n%send_header\n%s", counts_and_props, body);
    return text(s);
}

static buf ply_binary(const char *header, const void *body, size_t n)
{
    buf b;
    size_t hl = strlen(header);

    b.n = hl + n;
    b.p = malloc(b.n);
    assert_non_null(b.p);
    memcpy(b.p, header, hl);
    memcpy(b.p + hl, body, n);
    return b;
}

/* Each class of hostile input, refused quickly with a reason. */
static void test_bad_input(void **state)
{
    static const char tri_props[] = "element vertex 3\nproperty float x\nproperty float y\n"
                                    "property float z\nelement face 1\n"
                                    "property list uchar int vertex_indices\n";
    static const char bin_hdr_huge[] =
        "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\n"
        "property float y\nproperty float z\nelement face 1\n"
        "property list uchar int vertex_indices\nend_header\n";
    static const char bin_hdr_list[] =
        "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
        "property float y\nproperty float z\nelement face 1\n"
        "property list uint int vertex_indices\nend_header\n";
    unsigned char body[64] = {0}, rnd[4096];
    char s[2048];
    buf b, b2;
    unsigned seed = 7;

    (void)state;
    /* empty: Assimp's C API asserts (aborts) on a zero length */
    expect_fail((buf){NULL, 0}, NULL, -EINVAL, "empty");
    expect_fail((buf){"", 0}, "obj", -EINVAL, "empty");
    /* too big: refused before the data is read */
    expect_fail((buf){"x", (size_t)IMPORT_MAX_BYTES + 1}, "obj", -EFBIG, "limit");

    for (size_t i = 0; i < sizeof rnd; i++)
        rnd[i] = (unsigned char)((seed = seed * 1103515245u + 12345u) >> 16);
    expect_fail((buf){(char *)rnd, sizeof rnd}, NULL, -EINVAL, "unrecognised format");
    for (size_t i = 0; i < 8; i++)
        expect_fail((buf){(char *)rnd, sizeof rnd}, i % 2 ? "stl" : "ply", -EINVAL, "not a valid");

    /* binary STL claiming 2^31-1 triangles in 134 bytes */
    memset(s, 0, 134);
    put32((unsigned char *)s + 80, 0x7fffffffu);
    expect_fail((buf){s, 134}, "stl", -EINVAL, "not a valid STL");
    memcpy(s, "solid x\n", 8); /* the same, looking like ASCII STL */
    expect_fail((buf){s, 134}, NULL, -EINVAL, "STL: control character at byte 8");
    /* a cut facet: Assimp would throw and leak its mesh */
    b = text("solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nver");
    expect_fail(b, NULL, -EINVAL, "malformed facet");
    free(b.p);
    /* a vertex's numbers on the next line: Assimp throws (found by fuzzing) */
    b = text("solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0\n0\n"
             "vertex 0 1 0\nendloop\nendfacet\nendsolid t\n");
    expect_fail(b, NULL, -EINVAL, "malformed facet");
    free(b.p);
    b = text("solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
             "vertex 0 1 0\nendloop\nendfacet\nendsolid t\n");
    import_mesh m0 = expect_ok(b, NULL, 1);
    import_mesh_free(&m0);
    free(b.p);

    /* PLY element layouts fuzzing found Assimp abort, corrupt its heap or
     * allocate 32 GB on */
    b = ply_ascii(tri_props, "0 0 0\n1 0 0\n0 1 0\n0\n"); /* a face of no vertices */
    expect_fail(b, "ply", -EINVAL, "PLY data line 4 does not match its element 1");
    free(b.p);
    b = ply_ascii("element face 1\nproperty list uchar int vertex_indices\nelement vertex 3\n"
                  "property float x\nproperty float y\nproperty float z\n",
                  "3 0 1 2\n0 0 0\n1 0 0\n0 1 0\n");
    expect_fail(b, "ply", -EINVAL, "the first element must be vertex");
    free(b.p);
    b = ply_ascii("element vertex 1\nproperty float x\nelement vertex 1\nproperty float y\n", "0\n0\n");
    expect_fail(b, "ply", -EINVAL, "two vertex elements");
    free(b.p);
    b = ply_ascii("element vertex 1\nproperty list uchar float x\n", "1 0\n");
    expect_fail(b, "ply", -EINVAL, "a list property in the vertex element");
    free(b.p);
    {
        static const unsigned char empty_face[13] = {0}; /* a vertex at 0, then a face of length 0 */
        b = ply_binary("ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n"
                       "property float y\nproperty float z\nelement face 1\n"
                       "property list uchar int vertex_indices\nend_header\n",
                       empty_face, sizeof empty_face);
        expect_fail(b, "ply", -EINVAL, "a list of length 0");
        free(b.p);
    }

    /* PLY headers declaring far more than the data holds */
    b = ply_ascii("element vertex 4000000000\nproperty float x\nproperty float y\n"
                  "property float z\nelement face 1\nproperty list uchar int vertex_indices\n",
                  "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
    expect_fail(b, "ply", -EINVAL, "more than the file holds");
    free(b.p);
    b = ply_ascii(tri_props, "0 0 0\n1 0 0\n0 1 0\n1000000 0 1 2\n"); /* a hang in Assimp */
    expect_fail(b, "ply", -EINVAL, "PLY data line 4 does not match its element 1");
    free(b.p);
    b = ply_ascii(tri_props, "0 0 0\n1 0 0\n0 1 0\n3 0 1\n");
    expect_fail(b, "ply", -EINVAL, "line 4 does not match");
    free(b.p);
    b = ply_ascii(tri_props, "0 0 0\n1 0 0\r0 1 0\n3 0 1 2\n"); /* two lines to Assimp */
    expect_fail(b, "ply", -EINVAL, "carriage return inside a line");
    free(b.p);
    b = ply_ascii(tri_props, "0 0 0\n1 0 0\n0 1 x\n3 0 1 2\n"); /* Assimp throws and leaks */
    expect_fail(b, "ply", -EINVAL, "line 3 does not match");
    free(b.p);
    b = ply_ascii("element vertex 3\nproperty float x\nelement junk 5000000000\n", "0\n0\n0\n");
    expect_fail(b, "ply", -EINVAL, "without a count");
    free(b.p);
    b = ply_binary(bin_hdr_huge, body, 49);
    expect_fail(b, "ply", -EINVAL, "more than the file holds");
    free(b.p);
    put32(body + 36, 4000000000u); /* the face's list length */
    b = ply_binary(bin_hdr_list, body, 52);
    expect_fail(b, "ply", -EINVAL, "PLY data ends");
    free(b.p);
    {
        /* a signed list length of -128: the data would hold 128 indices,
         * but Assimp reads the length as a huge unsigned number */
        char hdr[sizeof bin_hdr_list];
        unsigned char data[36 + 1 + 128 * 4] = {0};
        memcpy(hdr, bin_hdr_list, sizeof hdr);
        memcpy(strstr(hdr, "list uint int"), "list char int", 13);
        data[36] = 0x80;
        b = ply_binary(hdr, data, sizeof data);
        expect_fail(b, "ply", -EINVAL, "PLY data ends");
        free(b.p);
    }
    b = ply_ascii(tri_props, "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
    import_mesh m = expect_ok(b, NULL, 1);
    import_mesh_free(&m);
    free(b.p);

    /* OBJ: indices out of range, non-finite coordinates, no faces */
    b = text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99\n");
    expect_fail(b, "obj", -EINVAL, "vertex index 99, but the file has 3");
    free(b.p);
    b = text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -99\n");
    expect_fail(b, "obj", -EINVAL, "before the first vertex");
    free(b.p);
    b = text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n");
    expect_fail(b, "obj", -EINVAL, "malformed vertex index");
    /* Assimp would throw on these and leak its mesh */
    b2 = text("v 0 0 0\nv 1 0 0\nv 0 1 0\ng a\nf 1 2 3\ng b\nf 1 2 4\n");
    expect_fail(b2, "obj", -EINVAL, "vertex index 4");
    free(b2.p);
    b2 = text("v 0 0 0\nv 1 0 0x\nv 0 1 0\nf 1 2 3\n");
    expect_fail(b2, "obj", -EINVAL, "line 2: malformed number");
    free(b2.p);
    /* Assimp counts ".5" as no number and "l1 2" as a line element: found
     * by fuzzing, both made it leak */
    b2 = text("v 0 0 0\nv 1 .5 0\nv 0 1 0\nf 1 2 3\n");
    expect_fail(b2, "obj", -EINVAL, "line 2: malformed number");
    free(b2.p);
    b2 = text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nl1 2\n");
    expect_fail(b2, "obj", -EINVAL, "line 5: unknown or indented statement");
    free(b2.p);
    b2 = text("v 0 0 0\nv 1 0 0\n v 0 1 0\nf 1 2 3\n");
    expect_fail(b2, "obj", -EINVAL, "line 3: unknown or indented statement");
    free(b2.p);
    /* Assimp ends lines at NUL, CR and form feed, so "\0p 9" is a point */
    expect_fail((buf){"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n#\0p 9\n", 37}, "obj", -EINVAL,
                "control character at byte 33");
    b2 = text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n#\rp 9\n");
    expect_fail(b2, "obj", -EINVAL, "vertex index 9, but the file has 3");
    free(b2.p);
    free(b.p);
    b = text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n");
    expect_fail(b, "obj", -EINVAL, "not a finite float");
    free(b.p);
    b = text("v 0 0 0\nv 1e39 0 0\nv 0 1 0\nf 1 2 3\n");
    expect_fail(b, "obj", -EINVAL, "not a finite float");
    free(b.p);
    b = text("v 0 0 0\nv 1 0 0\nv 0 1 0\nl 1 2\np 3\n");
    expect_fail(b, "obj", -EINVAL, "no triangles");
    free(b.p);

    /* GLB: an accessor far beyond its buffer */
    b = glb_triangle("\"scenes\":[{\"nodes\":[0]}],\"nodes\":[{\"mesh\":0}]");
    {
        char *count = find(b, "\"count\":3,");
        assert_non_null(count);
        count[8] = '9'; /* 9 vertices, beyond the 36 bytes */
    }
    expect_fail(b, "glb", -EINVAL, "maxSize");
    free(b.p);
    snprintf(
        s, sizeof s,
        "{\"asset\":{\"version\":\"2.0\"},\"scenes\":[{\"nodes\":[0]}],\"nodes\":[{\"mesh\":0}],"
        "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0}}]}],"
        "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":1000000000,"
        "\"type\":\"VEC3\"}],\"bufferViews\":[{\"buffer\":0,\"byteLength\":36}],"
        "\"buffers\":[{\"byteLength\":36}]}");
    b = glb(s, body, 36);
    expect_fail(b, "glb", -EINVAL, "accessor elements");
    free(b.p);
    /* shared children: each node lists the next one twice (2^24 paths) */
    {
        char *p = s + sprintf(s, "\"scenes\":[{\"nodes\":[0]}],\"nodes\":[");
        for (int i = 0; i < 24; i++)
            p += sprintf(p, "{\"children\":[%d,%d]},", i + 1, i + 1);
        sprintf(p, "{\"mesh\":0}]");
        b = glb_triangle(s);
        expect_fail(b, "glb", -EINVAL, "two parents");
        free(b.p);
    }
    b = glb_triangle("\"scenes\":[{\"nodes\":[0]}],\"nodes\":[{\"mesh\":0,\"children\":[1]},"
                     "{\"children\":[0]}]");
    expect_fail(b, "glb", -EINVAL, "cycle");
    free(b.p);
    /* a root that is also a child (exporters do this): one path, accepted */
    b = glb_triangle("\"scenes\":[{\"nodes\":[1]}],\"nodes\":[{\"children\":[1]},{\"mesh\":0}]");
    m = expect_ok(b, "glb", 1);
    import_mesh_free(&m);
    free(b.p);
    /* deep JSON: rapidjson recursion overflowed the stack at 10^6 */
    {
        static char deep[2 * 200000 + 64];
        int k = sprintf(deep, "{\"asset\":{\"version\":\"2.0\"},\"x\":");
        memset(deep + k, '[', 200000);
        memset(deep + k + 200000, ']', 200000);
        strcpy(deep + k + 400000, "}");
        b = glb(deep, NULL, 0);
        expect_fail(b, "glb", -EINVAL, "nested too deep");
        free(b.p);
    }
    b = glb_triangle("\"scenes\":[{\"nodes\":[0]}],\"nodes\":[{\"mesh\":0}]");
    put32((unsigned char *)b.p + 4, 1);
    expect_fail(b, "glb", -EINVAL, "only glTF 2.0");
    put32((unsigned char *)b.p + 4, 2);
    put32((unsigned char *)b.p + 8, (uint32_t)b.n + 4);
    expect_fail(b, "glb", -EINVAL, "length field");
    free(b.p);
    b = glb("{\"asset\":{\"version\":\"2.0\"},\"nodes\":[{\"mesh\":0},]}", NULL, 0);
    expect_fail(b, "glb", -EINVAL, "GLB JSON");
    free(b.p);

    /* other files are never opened: a buffer URI to a local file fails,
     * an OBJ mtllib naming one is ignored */
    b = glb("{\"asset\":{\"version\":\"2.0\"},\"scenes\":[{\"nodes\":[0]}],"
            "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":"
            "{\"POSITION\":0}}]}],\"accessors\":[{\"bufferView\":0,\"componentType\":5126,"
            "\"count\":3,\"type\":\"VEC3\"}],\"bufferViews\":[{\"buffer\":0,\"byteLength\":36}],"
            "\"buffers\":[{\"byteLength\":36,\"uri\":\"/etc/passwd\"}]}",
            NULL, 0);
    expect_fail(b, "glb", -EINVAL, "parse error");
    free(b.p);
    b = text("mtllib /etc/passwd\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    m = expect_ok(b, "obj", 1);
    import_mesh_free(&m);
    free(b.p);
}

/*
 * GLB JSON whose members have the wrong type. The hand-written tokenizer
 * that came before jansson sized its accessor table from the length of
 * "accessors" as an array (0 for an object) and then wrote one entry per
 * member: a heap overflow any client could send.
 */
static void test_glb_json_types(void **state)
{
    static const struct {
        const char *json, *why;
    } cases[] = {
        {"\"accessors\":{\"a\":{\"count\":5},\"b\":{\"count\":7},\"c\":{\"count\":9}}",
         "accessors is not an array"},
        {"\"accessors\":{\"q\":[1,2]}", "accessors is not an array"},
        {"\"accessors\":[7]", "accessor is not an object"},
        {"\"accessors\":[{\"count\":-1}]", "not a non-negative integer"},
        {"\"accessors\":[{\"count\":2.5}]", "not a non-negative integer"},
        {"\"accessors\":[{\"count\":\"3\"}]", "not a non-negative integer"},
        {"\"nodes\":{\"a\":{\"children\":[0]}}", "nodes is not an array"},
        {"\"nodes\":[{\"children\":{\"a\":0}}]", "children is not an array"},
        {"\"nodes\":[[0]]", "node is not an object"},
        {"\"nodes\":[{}],\"scenes\":{\"nodes\":[0]}", "scenes is not an array"},
        {"\"nodes\":[{}],\"scenes\":[{\"nodes\":{\"r\":0}}]", "scene nodes is not an array"},
        {"\"nodes\":[{}],\"scenes\":[{\"nodes\":[1]}]", "scene root out of range"},
        {"\"meshes\":{\"m\":{}}", "meshes is not an array"},
        {"\"meshes\":[{\"primitives\":{\"p\":{}}}]", "primitives is not an array"},
        {"\"meshes\":[{\"primitives\":[{\"attributes\":[0]}]}],\"accessors\":[{\"count\":1}]",
         "attributes is not an object"},
        {"\"meshes\":[{\"primitives\":[{\"attributes\":{\"P\":3}}]}],\"accessors\":[{\"count\":1}]",
         "accessor index out of range"},
        {"\"meshes\":[{\"primitives\":[{\"targets\":{\"t\":{}}}]}]", "targets is not an array"},
        {"\"asset\":{\"version\":\"2.0\"}", "duplicate"},
    };
    char json[512];

    (void)state;
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        buf b;
        snprintf(json, sizeof json, "{\"asset\":{\"version\":\"2.0\"},%s}", cases[i].json);
        b = glb(json, NULL, 0);
        expect_fail(b, "glb", -EINVAL, cases[i].why);
        expect_fail(b, NULL, -EINVAL, cases[i].why);
        free(b.p);
    }
}

/* The guards that bound Assimp's time and memory, at and past the limit. */
static void test_work_limits(void **state)
{
    size_t cap = 1 << 20, n = 0;
    char *s = malloc(cap);
    buf b;
    import_mesh m;

    (void)state;
    assert_non_null(s);
    /* one 10,000-vertex polygon passes, one of 10,001 does not */
    for (int size = 10000; size <= 10001; size++) {
        n = (size_t)sprintf(s, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf");
        for (int i = 0; i < size; i++)
            n += (size_t)sprintf(s + n, " %d", i % 3 + 1);
        s[n++] = '\n';
        b = (buf){s, n};
        if (size == 10000) {
            m = expect_ok(b, "obj", 9998);
            import_mesh_free(&m);
        } else {
            expect_fail(b, "obj", -EINVAL, "too large to triangulate");
        }
    }
    /* named parts */
    for (unsigned parts = IMPORT_MAX_PARTS; parts <= IMPORT_MAX_PARTS + 1; parts++) {
        n = (size_t)sprintf(s, "v 0 0 0\nv 1 0 0\nv 0 1 0\n");
        for (unsigned i = 0; i < parts; i++)
            n += (size_t)sprintf(s + n, "%s m%u\nf 1 2 3\n", i % 2 ? "usemtl" : "o", i);
        b = (buf){s, n};
        if (parts == IMPORT_MAX_PARTS) {
            m = expect_ok(b, "obj", parts);
            import_mesh_free(&m);
        } else {
            expect_fail(b, "obj", -EINVAL, "over the limit");
        }
    }
    /* node chains: Assimp recursed off an 8 MiB stack at 20,000 levels */
    for (int depth = IMPORT_MAX_NODE_DEPTH; depth <= IMPORT_MAX_NODE_DEPTH + 1; depth++) {
        n = (size_t)sprintf(s, "\"scenes\":[{\"nodes\":[0]}],\"nodes\":[");
        for (int i = 0; i < depth - 1; i++)
            n += (size_t)sprintf(s + n, "{\"children\":[%d]},", i + 1);
        sprintf(s + n, "{\"mesh\":0}]");
        b = glb_triangle(s);
        if (depth == IMPORT_MAX_NODE_DEPTH) {
            m = expect_ok(b, "glb", 1);
            import_mesh_free(&m);
        } else {
            expect_fail(b, "glb", -EINVAL, "node hierarchy too deep");
        }
        free(b.p);
    }
    n = 0;
    for (unsigned i = 0; i <= IMPORT_MAX_PARTS; i++)
        n += (size_t)sprintf(s + n, "solid\nendsolid\n");
    expect_fail((buf){s, n}, "stl", -EINVAL, "STL solids");
    free(s);
}

static void test_options_and_triangle_limit(void **state)
{
    buf b = read_model("classic/teapot.obj");
    import_options o = IMPORT_OPTIONS_DEFAULT;
    import_mesh m;
    char err[256];

    (void)state;
    o.max_triangles = 6320;
    assert_int_equal(run(b, "obj", &o, &m, err, sizeof err), 0);
    import_mesh_free(&m);
    o.max_triangles = 6319;
    assert_int_equal(run(b, "obj", &o, &m, err, sizeof err), -EFBIG);
    assert_non_null(strstr(err, "more than 6319 triangles"));
    o = (import_options)IMPORT_OPTIONS_DEFAULT;
    o.unit_scale = 1e38f; /* 3.4 * 1e38 overflows a float; smaller ones are far out */
    assert_int_equal(run(b, "obj", &o, &m, err, sizeof err), -EINVAL);
    assert_true(strstr(err, "not a finite float") || strstr(err, "beyond 1000 km"));
    o.unit_scale = 1e6f; /* finite, but the teapot is then 3,400 km across */
    assert_int_equal(run(b, "obj", &o, &m, err, sizeof err), -EINVAL);
    assert_non_null(strstr(err, "beyond 1000 km"));
    {   /* a vertex at 1e38, finite as a float: refused, not stored */
        buf far = text("v 0 0 0\nv 1e38 0 0\nv 0 1 0\nf 1 2 3\n");
        assert_int_equal(run(far, "obj", NULL, &m, err, sizeof err), -EINVAL);
        assert_non_null(strstr(err, "beyond 1000 km"));
        free(far.p);
    }

    {
        const float bad_scales[] = {0.0f, -1.0f, NAN, INFINITY};
        for (size_t i = 0; i < 4; i++) {
            o = (import_options)IMPORT_OPTIONS_DEFAULT;
            o.unit_scale = bad_scales[i];
            assert_int_equal(run(b, "obj", &o, &m, err, sizeof err), -EINVAL);
            assert_non_null(strstr(err, "unit_scale"));
        }
    }
    o = (import_options)IMPORT_OPTIONS_DEFAULT;
    o.max_triangles = 0;
    assert_int_equal(run(b, "obj", &o, &m, err, sizeof err), -EINVAL);
    assert_int_equal(import_model(b.p, b.n, "obj", NULL, NULL, err, sizeof err), -EINVAL);
    /* no message buffer is fine */
    assert_int_equal(import_model(b.p, b.n, "fbx", NULL, &m, NULL, 0), -EINVAL);
    free(b.p);
}

/* Assimp's logger stays off: nothing on stderr, good input or bad. */
static void test_stderr_quiet(void **state)
{
    FILE *tmp = tmpfile();
    int saved = dup(2);
    buf b = read_model("openings/kenney_building-garage.glb");
    import_mesh m;
    char err[256];

    (void)state;
    assert_non_null(tmp);
    assert_true(saved >= 0);
    fflush(stderr);
    assert_true(dup2(fileno(tmp), 2) >= 0);
    (void)run(b, NULL, NULL, &m, err, sizeof err);
    import_mesh_free(&m);
    (void)run((buf){b.p, b.n / 2}, NULL, NULL, &m, err, sizeof err);
    (void)run((buf){"v 1 2 3\nf 1 2 9\n", 16}, "obj", NULL, &m, err, sizeof err);
    fflush(stderr);
    assert_true(dup2(saved, 2) >= 0);
    close(saved);
    assert_int_equal(ftell(tmp), 0);
    fclose(tmp);
    free(b.p);
}

/* Our own allocations (jansson's included) failing give -ENOMEM and leak
 * nothing. */
static void test_alloc_failure(void **state)
{
    buf inputs[3];

    (void)state;
    inputs[0] = read_model("openings/homedecor_desk.obj");
    inputs[1] = glb_triangle("\"scenes\":[{\"nodes\":[0]}],\"nodes\":[{\"children\":[1,2]},"
                             "{\"mesh\":0},{\"mesh\":0}]");
    inputs[2] = read_model("formats/assimp_Spider_binary.stl");
    for (size_t i = 0; i < 3; i++) {
        long n;
        for (n = 0; n < 1000; n++) {
            import_mesh m;
            char err[256];
            int rc;
            cvre_alloc_fail_after(n);
            rc = import_model(inputs[i].p, inputs[i].n, NULL, NULL, &m, err, sizeof err);
            cvre_alloc_fail_after(-1);
            if (rc == 0) {
                import_mesh_free(&m);
                break;
            }
            if (rc != -ENOMEM)
                fail_msg("input %zu, failing allocation %ld: %d %s", i, n, rc, err);
            assert_null(m.tris);
        }
        assert_true(n >= 1 && n < 1000); /* some allocation was ours, and it then succeeded */
        free(inputs[i].p);
    }
}

static void test_formats_and_free(void **state)
{
    char list[64], *save = NULL;
    import_mesh m;

    (void)state;
    /* every format we accept is in the Assimp we link */
    snprintf(list, sizeof list, "%s", import_formats());
    for (char *w = strtok_r(list, " ", &save); w; w = strtok_r(NULL, " ", &save)) {
        char ext[16];
        snprintf(ext, sizeof ext, ".%s", w);
        assert_true(aiIsExtensionSupported(ext));
    }
    memset(&m, 0, sizeof m);
    import_mesh_free(&m);
    import_mesh_free(&m);
}

int main(int argc, char **argv)
{
    const struct CMUnitTest fixed[] = {
        cmocka_unit_test(test_every_model_is_listed),
        cmocka_unit_test(test_up_axis_and_scale),
        cmocka_unit_test(test_node_transforms),
        cmocka_unit_test(test_hint_vs_detection),
        cmocka_unit_test(test_bad_input),
        cmocka_unit_test(test_glb_json_types),
        cmocka_unit_test(test_work_limits),
        cmocka_unit_test(test_options_and_triangle_limit),
        cmocka_unit_test(test_stderr_quiet),
        cmocka_unit_test(test_alloc_failure),
        cmocka_unit_test(test_formats_and_free),
    };
    models_select sel;
    size_t n, nmodels;
    char **models;
    struct CMUnitTest *tests;
    int failed;

    models_args(argc, argv, "The model importer against the shared models and hostile input.", &models_dir, &sel);
    models = models_list(models_dir, &nmodels);
    if (!models)
        return 2;
    n = sizeof fixed / sizeof fixed[0];
    tests = calloc(n + nmodels, sizeof *tests);
    if (!tests)
        return 2;
    memcpy(tests, fixed, sizeof fixed);
    for (size_t i = 0; i < nmodels; i++)
        tests[n + i] = (struct CMUnitTest){models[i], test_model, NULL, NULL, models[i]};
    failed = models_run("test_import", tests, n + nmodels, &sel);
    free(tests);
    for (size_t i = 0; i < nmodels; i++)
        free(models[i]);
    free(models);
    return failed;
}
