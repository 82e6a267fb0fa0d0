/*
 * The importer's guards that ordinary models never reach: the in-memory
 * file Assimp is given, the limits of the PLY and GLB pre-checks, and the
 * checks on the scene Assimp hands back (a NULL mesh, a mesh without
 * positions, a missing child, an index past the meshes, a hierarchy too
 * deep), each with the refusal it must give rather than a crash.
 *
 * import.c is included, not linked, so that its static functions can be
 * called on inputs only a broken or hostile Assimp could produce; the
 * file's public entry points are exercised through import_model as usual,
 * and the formats' pre-checks (cvre_import_formats) through importInt.h.
 */
#include "import.c"

#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>

#include <cmocka.h>

#include "le.h"

/* ---- the upload as Assimp's only file ---------------------------------- */

static void test_memfs(void **state)
{
    static const char data[] = "0123456789";
    memfs fs;
    struct aiFile *f[OPEN_MAX], *g;
    char buf[16];

    (void)state;
    memset(&fs, 0, sizeof fs);
    fs.io.OpenProc = mem_open;
    fs.io.CloseProc = mem_close;
    fs.name = "upload.obj";
    fs.data = data;
    fs.len = 10;

    /* only the upload opens, and only for reading */
    assert_null(mem_open(&fs.io, "upload.mtl", "rb"));
    assert_null(mem_open(&fs.io, "upload.obj", "wb"));
    assert_null(mem_open(&fs.io, "upload.obj", "r+"));
    assert_null(mem_open(&fs.io, "upload.obj", "ab"));
    for (int i = 0; i < OPEN_MAX; i++)
        assert_non_null(f[i] = mem_open(&fs.io, "upload.obj", "rb"));
    assert_null(mem_open(&fs.io, "upload.obj", "rb")); /* every slot taken */
    mem_close(&fs.io, f[1]);
    assert_ptr_equal(mem_open(&fs.io, "upload.obj", "rb"), f[1]); /* a closed slot is reused */
    g = f[0];

    /* reads: whole items only, nothing past the end, nothing for size 0 */
    assert_int_equal(g->FileSizeProc(g), 10);
    assert_int_equal(g->ReadProc(g, buf, 0, 5), 0);
    assert_int_equal(g->ReadProc(g, buf, 4, 0), 0);
    assert_int_equal(g->ReadProc(g, buf, 4, 5), 2); /* 8 of the 10 bytes */
    assert_memory_equal(buf, "01234567", 8);
    assert_int_equal(g->TellProc(g), 8);
    assert_int_equal(g->ReadProc(g, buf, 4, 1), 0); /* 2 bytes left: no whole item */
    assert_int_equal(g->ReadProc(g, buf, 1, 4), 2);
    assert_memory_equal(buf, "89", 2);

    /* seeks: from the start, the current position and (backwards) the end */
    assert_int_equal(g->SeekProc(g, 3, aiOrigin_SET), aiReturn_SUCCESS);
    assert_int_equal(g->TellProc(g), 3);
    assert_int_equal(g->SeekProc(g, 7, aiOrigin_CUR), aiReturn_SUCCESS);
    assert_int_equal(g->TellProc(g), 10);
    assert_int_equal(g->SeekProc(g, 1, aiOrigin_CUR), aiReturn_FAILURE); /* past the end */
    assert_int_equal(g->SeekProc(g, 11, aiOrigin_SET), aiReturn_FAILURE);
    assert_int_equal(g->TellProc(g), 10); /* a failed seek moves nothing */
    assert_int_equal(g->SeekProc(g, 4, aiOrigin_END), aiReturn_SUCCESS);
    assert_int_equal(g->TellProc(g), 6);
    assert_int_equal(g->SeekProc(g, 11, aiOrigin_END), aiReturn_FAILURE);
    assert_int_equal(g->TellProc(g), 6);

    /* writes write nothing; a flush does nothing */
    assert_int_equal(g->WriteProc(g, "xx", 1, 2), 0);
    g->FlushProc(g);
    assert_int_equal(g->ReadProc(g, buf, 1, 4), 4);
    assert_memory_equal(buf, "6789", 4);
    assert_string_equal(data, "0123456789");
    for (int i = 0; i < OPEN_MAX; i++)
        mem_close(&fs.io, f[i]);
}

/* ---- the pre-checks' limits -------------------------------------------- */

static int import_text(const char *text, const char *hint, char *err, size_t errlen)
{
    import_mesh m;
    int rc = import_model(text, strlen(text), hint, NULL, &m, err, errlen);

    if (rc == 0)
        import_mesh_free(&m);
    assert_null(m.tris);
    return rc;
}

static void test_ply_too_many_elements(void **state)
{
    size_t cap = 64 + (IMPORT_MAX_PLY_PROPERTIES + 1) * 32u, at;
    char *ply = malloc(cap), err[256];

    (void)state;
    assert_non_null(ply);
    at = (size_t)snprintf(ply, cap, "ply\nformat ascii 1.0\n");
    for (int e = 0; e <= IMPORT_MAX_PLY_PROPERTIES; e++)
        at += (size_t)snprintf(ply + at, cap - at, "element e%d 0\n", e);
    snprintf(ply + at, cap - at, "end_header\n");
    assert_int_equal(import_text(ply, "ply", err, sizeof err), -EINVAL);
    assert_string_equal(err, "PLY header declares too many elements");
    free(ply);
}

/* A GLB of the JSON chunk json (padded with spaces to 4 bytes) followed by
 * a BIN chunk of bin zero bytes (none if 0); *n its length. */
static unsigned char *glb(const char *json, size_t bin, size_t *n)
{
    size_t jl = (strlen(json) + 3) & ~(size_t)3, len = 20 + jl + (bin ? 8 + bin : 0);
    unsigned char *p = calloc(1, len);

    assert_non_null(p);
    memcpy(p, "glTF", 4);
    le_put_u32(p + 4, 2);
    le_put_u32(p + 8, (uint32_t)len);
    le_put_u32(p + 12, (uint32_t)jl);
    le_put_u32(p + 16, 0x4E4F534Au); /* "JSON" */
    memset(p + 20, ' ', jl);
    memcpy(p + 20, json, strlen(json));
    if (bin) {
        le_put_u32(p + 20 + jl, (uint32_t)bin);
        le_put_u32(p + 24 + jl, 0x004E4942u); /* "BIN\0" */
    }
    *n = len;
    return p;
}

/* Imports a GLB of json and bin zero bytes; returns its status. */
static int import_glb(const char *json, size_t bin, char *err, size_t errlen)
{
    import_mesh m;
    size_t n;
    unsigned char *p = glb(json, bin, &n);
    int rc = import_model(p, n, "glb", NULL, &m, err, errlen);

    if (rc == 0)
        import_mesh_free(&m);
    free(p);
    return rc;
}

static void test_glb_document_not_object(void **state)
{
    char err[256];

    (void)state;
    assert_int_equal(import_glb("[{\"asset\":{\"version\":\"2.0\"}}]", 0, err, sizeof err), -EINVAL);
    assert_string_equal(err, "GLB JSON: JSON document is not an object");
}

static void test_glb_morph_target_not_object(void **state)
{
    char err[256];

    (void)state;
    assert_int_equal(import_glb("{\"asset\":{\"version\":\"2.0\"},\"accessors\":[{\"count\":3}],"
                                "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0},"
                                "\"targets\":[{\"POSITION\":0},7]}]}]}",
                                0, err, sizeof err),
                     -EINVAL);
    assert_string_equal(err, "GLB: morph target is not an object");
}

/* A GLB whose scene lists, `listings` times over, a root node with
 * `children` children: every listing is a copy of the whole tree in
 * Assimp's scene. */
static unsigned char *glb_tree(unsigned children, unsigned listings, size_t *n)
{
    size_t cap = 200 + 12u * (children + listings), at;
    char *json = malloc(cap);
    unsigned char *p;

    assert_non_null(json);
    at = (size_t)snprintf(json, cap, "{\"asset\":{\"version\":\"2.0\"},\"nodes\":[{\"children\":[");
    for (unsigned c = 1; c <= children; c++)
        at += (size_t)snprintf(json + at, cap - at, "%s%u", c > 1 ? "," : "", c);
    at += (size_t)snprintf(json + at, cap - at, "]}");
    for (unsigned c = 1; c <= children; c++)
        at += (size_t)snprintf(json + at, cap - at, ",{}");
    at += (size_t)snprintf(json + at, cap - at, "],\"scenes\":[{\"nodes\":[");
    for (unsigned r = 0; r < listings; r++)
        at += (size_t)snprintf(json + at, cap - at, "%s0", r ? "," : "");
    snprintf(json + at, cap - at, "]}]}");
    p = glb(json, 0, n);
    free(json);
    return p;
}

static void test_glb_node_expansion(void **state)
{
    const unsigned children = 300, fit = IMPORT_MAX_GLB_NODES / (children + 1);
    char err[256];
    import_mesh m;
    size_t n;
    unsigned char *p;

    (void)state;
    p = glb_tree(children, fit + 1, &n);
    assert_int_equal(import_model(p, n, "glb", NULL, &m, err, sizeof err), -EINVAL);
    snprintf(err + 128, 128, "GLB node hierarchy expands to over %u nodes", (unsigned)IMPORT_MAX_GLB_NODES);
    assert_string_equal(err, err + 128);
    free(p);

    /* as many copies as fit pass the pre-check (Assimp is not asked here:
     * it would build them all) */
    p = glb_tree(children, fit, &n);
    assert_int_equal(import__glb.check(p, n, err, sizeof err), 0);
    free(p);
}

/* JSON that is small in bytes but large once parsed: jansson's share of
 * the budget runs out before its lexer does. */
static void test_glb_json_over_budget(void **state)
{
    static const char head[] = "{\"asset\":{\"version\":\"2.0\"},\"x\":[";
    size_t arrays = 8u << 20, cap = sizeof head + 3 * arrays + 8, at;
    char *json = malloc(cap), err[256];

    (void)state;
    assert_non_null(json);
    memcpy(json, head, sizeof head - 1);
    at = sizeof head - 1;
    for (size_t i = 0; i < arrays; i++, at += 3)
        memcpy(json + at, i ? ",[]" : " []", 3);
    memcpy(json + at, "]}", 3);
    assert_int_equal(import_glb(json, 0, err, sizeof err), -EINVAL);
    assert_string_equal(err, "GLB JSON: JSON takes too much memory to parse");
    free(json);
}

/* Past IMPORT_MAX_GLB_ELEMENTS / IMPORT_GLB_ELEMENTS_PER_BYTE bytes the
 * absolute cap on copied accessor elements applies, not the per-byte one. */
static void test_glb_elements_absolute_cap(void **state)
{
    char json[400], err[256];
    size_t bin = (size_t)(IMPORT_MAX_GLB_ELEMENTS / IMPORT_GLB_ELEMENTS_PER_BYTE) + 4096;

    (void)state;
    snprintf(json, sizeof json,
             "{\"asset\":{\"version\":\"2.0\"},\"accessors\":[{\"count\":%llu}],"
             "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0}}]}]}",
             (unsigned long long)IMPORT_MAX_GLB_ELEMENTS + 1);
    assert_int_equal(import_glb(json, bin, err, sizeof err), -EINVAL);
    snprintf(json, sizeof json, "over the limit of %llu for its size",
             (unsigned long long)IMPORT_MAX_GLB_ELEMENTS);
    assert_non_null(strstr(err, json));
}

/* ---- the scene Assimp hands back ---------------------------------------- */

/* A scene of one triangle in one mesh under a root node, built by hand. */
typedef struct hand_scene {
    struct aiScene sc;
    struct aiNode root, child;
    struct aiNode *children[1];
    struct aiMesh mesh;
    struct aiMesh *meshes[1];
    unsigned mesh_index[1];
    struct aiFace face;
    unsigned idx[3];
    struct aiVector3D v[3];
} hand_scene;

static void hand_scene_init(hand_scene *h)
{
    memset(h, 0, sizeof *h);
    h->v[1].x = 1;
    h->v[2].y = 1;
    h->idx[0] = 0, h->idx[1] = 1, h->idx[2] = 2;
    h->face.mNumIndices = 3;
    h->face.mIndices = h->idx;
    h->mesh.mNumVertices = 3;
    h->mesh.mVertices = h->v;
    h->mesh.mNumFaces = 1;
    h->mesh.mFaces = &h->face;
    h->meshes[0] = &h->mesh;
    h->root.mTransformation.a1 = h->root.mTransformation.b2 = 1;
    h->root.mTransformation.c3 = h->root.mTransformation.d4 = 1;
    h->root.mNumMeshes = 1;
    h->root.mMeshes = h->mesh_index;
    h->sc.mRootNode = &h->root;
    h->sc.mNumMeshes = 1;
    h->sc.mMeshes = h->meshes;
}

static int collect_hand(hand_scene *h, char *err, size_t errlen)
{
    static const import_options opt = IMPORT_OPTIONS_DEFAULT;
    import_mesh m = {0};
    int rc = collect(&h->sc, &opt, &m, err, errlen);

    if (rc == 0) {
        assert_int_equal(m.ntris, 1);
        import_mesh_free(&m);
    }
    assert_null(m.tris);
    return rc;
}

static void test_scene_checks(void **state)
{
    hand_scene h;
    char err[256];

    (void)state;
    hand_scene_init(&h);
    assert_int_equal(collect_hand(&h, err, sizeof err), 0); /* the scene as built is good */

    h.sc.mRootNode = NULL;
    assert_int_equal(collect_hand(&h, err, sizeof err), -EINVAL);
    assert_string_equal(err, "no scene graph");

    hand_scene_init(&h);
    h.meshes[0] = NULL;
    assert_int_equal(check_polygons(&h.sc, err, sizeof err), 0); /* skipped there */
    assert_int_equal(collect_hand(&h, err, sizeof err), -EINVAL);
    assert_string_equal(err, "mesh 0 missing");

    hand_scene_init(&h);
    h.mesh.mVertices = NULL;
    assert_int_equal(collect_hand(&h, err, sizeof err), -EINVAL);
    assert_string_equal(err, "mesh 0 has faces but no positions");

    hand_scene_init(&h);
    h.mesh_index[0] = 1;
    assert_int_equal(collect_hand(&h, err, sizeof err), -EINVAL);
    assert_string_equal(err, "node refers to missing mesh 1");

    hand_scene_init(&h);
    h.root.mNumChildren = 1;
    h.root.mChildren = h.children; /* holding NULL */
    assert_int_equal(collect_hand(&h, err, sizeof err), -EINVAL);
    assert_string_equal(err, "node child missing");

    hand_scene_init(&h);
    h.children[0] = &h.child; /* a child without meshes is fine */
    h.root.mNumChildren = 1;
    h.root.mChildren = h.children;
    assert_int_equal(collect_hand(&h, err, sizeof err), 0);
}

static void test_scene_too_deep(void **state)
{
    enum { LEVELS = IMPORT_MAX_NODE_DEPTH + 2 };
    struct aiNode *chain = calloc(LEVELS, sizeof *chain), **links = calloc(LEVELS, sizeof *links);
    hand_scene h;
    char err[256];

    (void)state;
    assert_non_null(chain);
    assert_non_null(links);
    hand_scene_init(&h);
    for (int i = 0; i < LEVELS; i++) {
        chain[i].mTransformation = h.root.mTransformation;
        if (i + 1 < LEVELS) {
            links[i] = &chain[i + 1];
            chain[i].mNumChildren = 1;
            chain[i].mChildren = &links[i];
        }
    }
    chain[LEVELS - 1].mNumMeshes = 1;
    chain[LEVELS - 1].mMeshes = h.mesh_index;
    h.sc.mRootNode = &chain[0];
    assert_int_equal(collect_hand(&h, err, sizeof err), -EINVAL);
    snprintf(err + 128, 128, "node hierarchy deeper than %d", IMPORT_MAX_NODE_DEPTH);
    assert_string_equal(err, err + 128);

    /* at the deepest level allowed, the triangle is found */
    h.sc.mRootNode = &chain[1];
    assert_int_equal(collect_hand(&h, err, sizeof err), 0);
    free(chain);
    free(links);
}

static void test_scene_out_of_memory(void **state)
{
    hand_scene h;
    char err[256];

    (void)state;
    hand_scene_init(&h);
    for (long n = 0; n < 2; n++) { /* the triangle counts, then the triangles */
        cvre_alloc_fail_after(n);
        assert_int_equal(collect_hand(&h, err, sizeof err), -ENOMEM);
        cvre_alloc_fail_after(-1);
        assert_non_null(strstr(err, "out of memory"));
    }
    assert_int_equal(collect_hand(&h, err, sizeof err), 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_memfs),
        cmocka_unit_test(test_ply_too_many_elements),
        cmocka_unit_test(test_glb_document_not_object),
        cmocka_unit_test(test_glb_morph_target_not_object),
        cmocka_unit_test(test_glb_node_expansion),
        cmocka_unit_test(test_glb_json_over_budget),
        cmocka_unit_test(test_glb_elements_absolute_cap),
        cmocka_unit_test(test_scene_checks),
        cmocka_unit_test(test_scene_too_deep),
        cmocka_unit_test(test_scene_out_of_memory),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
