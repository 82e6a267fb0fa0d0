/*
 * import_glb.c: GLB, binary glTF 2.0: a 12-byte header, a JSON chunk that
 * describes the scene, a binary chunk of vertex data.
 *
 * What Assimp 5.2.5's glTF reader does with hostile input: it builds one
 * node per path through the node graph (a 1 KB file of nodes listing the
 * next one twice exhausted 24 GB), recurses per node level (a 20,000-deep
 * chain overflowed the stack) and per JSON level (10^6 overflowed it), and
 * copies an accessor once per primitive using it (3.6 MB took 17.6 GB).
 * So the JSON is parsed first (import_json.c) and its scene counted here,
 * every value read checked for the type glTF gives it. Accessors beyond
 * their buffer and node cycles Assimp refuses itself, cleanly.
 */
#include "importInt.h"
#include "import.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "err.h"
#include "le.h"

/*
 * Counts the nodes Assimp will create: one per path from a scene root.
 * Requires trees (each node one parent at most, no cycles, as glTF 2.0
 * does) no deeper than IMPORT_MAX_NODE_DEPTH; a node listed as a root and
 * also as a child, which exporters do, is counted once per path. The
 * arrays have one entry per node. Refuses through c.
 */
static uint64_t glb_node_paths(import__json_check *c, const json_t *nodes, const json_t *scenes,
                               uint32_t *parent, uint32_t *roots, uint64_t *paths,
                               uint32_t *stack, uint32_t *level)
{
    uint32_t n = (uint32_t)json_array_size(nodes);
    uint64_t total = 0;
    json_t *node, *scene, *v;
    size_t i, k;

    for (uint32_t x = 0; x < n; x++)
        parent[x] = UINT32_MAX, paths[x] = UINT64_MAX, roots[x] = 0;
    json_array_foreach(nodes, i, node) {
        json_t *ch;
        if (!json_is_object(node)) {
            import__json_refuse(c, "node is not an object");
            return 0;
        }
        ch = import__json_member(c, node, "children", JSON_ARRAY, "node children is not an array");
        json_array_foreach(ch, k, v) {
            uint32_t x = import__json_index(c, v, n, "node child out of range");
            if (c->why)
                return 0;
            if (parent[x] != UINT32_MAX) {
                import__json_refuse(c, "node with two parents");
                return 0;
            }
            parent[x] = (uint32_t)i;
        }
        if (c->why)
            return 0;
    }
    json_array_foreach(scenes, i, scene) {
        json_t *rl = import__json_member(c, scene, "nodes", JSON_ARRAY, "scene nodes is not an array");
        if (!json_is_object(scene))
            import__json_refuse(c, "scene is not an object");
        json_array_foreach(rl, k, v) {
            uint32_t r = import__json_index(c, v, n, "scene root out of range");
            if (c->why)
                return 0;
            roots[r]++;
        }
        if (c->why)
            return 0;
    }
    /* paths[x] = roots on x's ancestor chain, x included, and level[x] its
     * length, by walking up to a known ancestor; UINT64_MAX - 1 marks a
     * node on the walk, to find cycles. */
    for (uint32_t x = 0; x < n; x++) {
        uint32_t depth = 0, y = x, lv = 0;
        uint64_t above = 0;
        while (y != UINT32_MAX && paths[y] == UINT64_MAX) {
            paths[y] = UINT64_MAX - 1;
            stack[depth++] = y;
            y = parent[y];
        }
        if (y != UINT32_MAX) {
            if (paths[y] == UINT64_MAX - 1) {
                import__json_refuse(c, "node cycle");
                return 0;
            }
            above = paths[y];
            lv = level[y];
        }
        while (depth) {
            y = stack[--depth];
            above += roots[y];
            paths[y] = above;
            level[y] = ++lv;
        }
        if (lv > IMPORT_MAX_NODE_DEPTH) { /* Assimp recurses once per level */
            import__json_refuse(c, "node hierarchy too deep");
            return 0;
        }
        total += paths[x];
        if (total > IMPORT_MAX_GLB_NODES)
            return total;
    }
    return total;
}

/* Adds the count of the accessor that index value v names to *total. */
static void glb_add_ref(import__json_check *c, const json_t *v, const uint32_t *counts, uint32_t na,
                        uint64_t *total)
{
    uint32_t a = import__json_index(c, v, na, "accessor index out of range");

    if (!c->why)
        *total += counts[a];
}

/* Adds the accessors named by the member values of object obj (may be NULL). */
static void glb_add_members(import__json_check *c, json_t *obj, const uint32_t *counts, uint32_t na,
                            uint64_t *total)
{
    const char *key;
    json_t *v;

    json_object_foreach(obj, key, v) {
        glb_add_ref(c, v, counts, na, total);
        if (c->why)
            return;
    }
}

/* Sums, over every primitive of every mesh, the counts of the accessors it
 * uses (attributes, indices, morph targets): Assimp copies an accessor once
 * per primitive that uses it. counts[i] is accessor i's count. */
static uint64_t glb_primitive_elements(import__json_check *c, const json_t *meshes, const uint32_t *counts,
                                       uint32_t na)
{
    uint64_t total = 0;
    json_t *mesh, *prim, *target;
    size_t i, k, t;

    json_array_foreach(meshes, i, mesh) {
        json_t *prims = import__json_member(c, mesh, "primitives", JSON_ARRAY,
                                   "mesh primitives is not an array");
        if (!json_is_object(mesh))
            import__json_refuse(c, "mesh is not an object");
        json_array_foreach(prims, k, prim) {
            json_t *ix = json_object_get(prim, "indices"),
                   *attrs = import__json_member(c, prim, "attributes", JSON_OBJECT,
                                       "primitive attributes is not an object"),
                   *targets = import__json_member(c, prim, "targets", JSON_ARRAY,
                                         "primitive targets is not an array");
            if (!json_is_object(prim))
                import__json_refuse(c, "primitive is not an object");
            glb_add_members(c, attrs, counts, na, &total);
            if (ix && !c->why)
                glb_add_ref(c, ix, counts, na, &total);
            json_array_foreach(targets, t, target) {
                if (!json_is_object(target))
                    import__json_refuse(c, "morph target is not an object");
                glb_add_members(c, target, counts, na, &total);
                if (c->why)
                    return 0;
            }
            if (c->why)
                return 0;
        }
        if (c->why)
            return 0;
    }
    return total;
}

/* Fills counts[i] with accessor i's count (0 if it has none). */
static void glb_accessor_counts(import__json_check *c, const json_t *accessors, uint32_t *counts)
{
    json_t *acc;
    size_t i;

    json_array_foreach(accessors, i, acc) {
        json_t *count = json_object_get(acc, "count");
        if (!json_is_object(acc)) {
            import__json_refuse(c, "accessor is not an object");
            return;
        }
        counts[i] = count ? import__json_index(c, count, UINT32_MAX, "accessor count too large") : 0;
        if (c->why)
            return;
    }
}

/*
 * Checks a GLB's header and JSON chunk before Assimp sees them: version 2,
 * lengths that agree with the file, strict JSON no deeper than
 * IMPORT_MAX_JSON_DEPTH (so that Assimp's glTF reader, not a fallback
 * importer, takes it), asset.version 2.x, the members read here of the
 * types glTF gives them, node trees no deeper than IMPORT_MAX_NODE_DEPTH,
 * at most IMPORT_MAX_GLB_NODES nodes once expanded, and at most
 * IMPORT_MAX_GLB_ELEMENTS accessor elements copied into meshes (and
 * IMPORT_GLB_ELEMENTS_PER_BYTE per byte of the file). Every loop walks an
 * array or object jansson sized. Returns 0, -EINVAL or -ENOMEM.
 */
static int glb_check(const unsigned char *p, size_t n, char *err, size_t errlen)
{
    import__json_check c = {NULL, 0};
    char where[200];
    json_t *doc, *nodes, *scenes, *meshes, *accessors, *version;
    uint32_t json_len, nn, na;
    uint32_t *u32 = NULL;
    uint64_t *paths = NULL, total = 0, elements_max = (uint64_t)IMPORT_GLB_ELEMENTS_PER_BYTE * n;
    int rc;

    if (elements_max > IMPORT_MAX_GLB_ELEMENTS)
        elements_max = IMPORT_MAX_GLB_ELEMENTS;

    if (n < 20)
        return cvre_fail(err, errlen, -EINVAL, "GLB shorter than its header");
    if (le_get_u32(p + 4) != 2)
        return cvre_fail(err, errlen, -EINVAL, "GLB version %u (only glTF 2.0 is supported)",
                    le_get_u32(p + 4));
    if (le_get_u32(p + 8) != n)
        return cvre_fail(err, errlen, -EINVAL, "GLB length field says %u bytes, the file has %zu",
                    le_get_u32(p + 8), n);
    json_len = le_get_u32(p + 12);
    if (le_get_u32(p + 16) != 0x4E4F534Au || json_len > n - 20)
        return cvre_fail(err, errlen, -EINVAL, "GLB does not start with a whole JSON chunk");

    doc = import__json_load(&c, p + 20, json_len, 20, where, sizeof where);
    version = json_object_get(json_object_get(doc, "asset"), "version");
    if (!c.why && (!json_is_string(version) || json_string_value(version)[0] != '2'))
        import__json_refuse(&c, "asset.version is not 2.x");
    if (c.why) {
        rc = c.nomem ? cvre_fail(err, errlen, -ENOMEM, "out of memory")
                     : cvre_fail(err, errlen, -EINVAL, "GLB JSON: %s", c.why);
        import__printable(err, errlen); /* jansson quotes the file */
        goto cleanup;
    }

    nodes = import__json_member(&c, doc, "nodes", JSON_ARRAY, "nodes is not an array");
    scenes = import__json_member(&c, doc, "scenes", JSON_ARRAY, "scenes is not an array");
    meshes = import__json_member(&c, doc, "meshes", JSON_ARRAY, "meshes is not an array");
    accessors = import__json_member(&c, doc, "accessors", JSON_ARRAY, "accessors is not an array");
    if (c.why) {
        rc = cvre_fail(err, errlen, -EINVAL, "GLB: %s", c.why);
        goto cleanup;
    }
    nn = (uint32_t)json_array_size(nodes); /* under the JSON's length: 32 bits */
    na = (uint32_t)json_array_size(accessors);
    /* parent, roots, stack and level for the nodes, then accessor counts */
    u32 = cvre_calloc((size_t)4 * nn + na + 1, sizeof *u32);
    paths = cvre_malloc(((size_t)nn + 1) * sizeof *paths);
    if (!u32 || !paths) {
        rc = cvre_fail(err, errlen, -ENOMEM, "out of memory");
        goto cleanup;
    }
    if (nodes)
        total = glb_node_paths(&c, nodes, scenes, u32, u32 + nn, paths, u32 + 2 * nn,
                               u32 + 3 * nn);
    if (!c.why && total > IMPORT_MAX_GLB_NODES) {
        rc = cvre_fail(err, errlen, -EINVAL, "GLB node hierarchy expands to over %u nodes",
                  (unsigned)IMPORT_MAX_GLB_NODES);
        goto cleanup;
    }
    if (!c.why)
        glb_accessor_counts(&c, accessors, u32 + 4 * nn);
    total = c.why ? 0 : glb_primitive_elements(&c, meshes, u32 + 4 * nn, na);
    if (c.why)
        rc = cvre_fail(err, errlen, -EINVAL, "GLB: %s", c.why);
    else if (total > elements_max)
        rc = cvre_fail(err, errlen, -EINVAL,
                  "GLB meshes copy %llu accessor elements, over the limit of %llu for its size",
                  (unsigned long long)total, (unsigned long long)elements_max);
    else
        rc = 0;
cleanup:
    free(u32);
    free(paths);
    json_decref(doc);
    return rc;
}

/* The magic word every GLB starts with. */
static int glb_sniff(const unsigned char *p, size_t n) { return n >= 4 && memcmp(p, "glTF", 4) == 0; }

const import__format import__glb = {"glb", "GLB", glb_sniff, glb_check};
