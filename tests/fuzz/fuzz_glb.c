/*
 * fuzz_glb.c: structure-aware fuzz target for GLB uploads: the importer's
 * GLB pre-check (server/import/import_glb.c over import_json.c, jansson) and
 * Assimp's glTF 2 reader.
 *
 * Inputs are GLB files. The mutator takes one apart (header, JSON chunk
 * parsed with jansson, BIN chunk) and changes its structure before putting
 * it back together: a JSON value of the wrong type (an object where glTF
 * has an array, as in "accessors":{"a":{"count":5}}), an index out of
 * range for the array it names, node cycles, a child listed twice, a node
 * with two parents, chains past IMPORT_MAX_NODE_DEPTH, a node listed as a
 * root at every level, accessors and buffer views with hostile counts,
 * offsets, strides and types, huge or non-finite numbers, nesting past
 * IMPORT_MAX_JSON_DEPTH, duplicate keys, NUL in the JSON, NaN and 1e38 in
 * the vertex data, chunk lengths that disagree. The generator writes a
 * small valid scene (positions, indices, a node tree, transforms) and
 * mutates it. Each input is imported with the hint "glb" and with none
 * (fz_import.c).
 */
#include <jansson.h>
#include <string.h>

#include "fz.h"
#include "le.h"

#define GLB_MAGIC 0x46546c67u /* "glTF" */
#define CHUNK_JSON 0x4e4f534au
#define CHUNK_BIN 0x004e4942u

/* A GLB taken apart: the document and the binary chunk's bytes. */
typedef struct glb {
    json_t *doc;
    uint8_t *bin; /* NULL if there is no BIN chunk */
    size_t bin_len;
} glb;

static void glb_free(glb *g)
{
    json_decref(g->doc);
    free(g->bin);
    memset(g, 0, sizeof *g);
}

/* Takes p[0..n) apart; 0 if it is not a GLB whose JSON chunk parses. */
static int glb_read(const uint8_t *p, size_t n, glb *g)
{
    size_t json_len, at;

    memset(g, 0, sizeof *g);
    if (n < 20 || le_get_u32(p) != GLB_MAGIC || (json_len = le_get_u32(p + 12)) > n - 20)
        return 0;
    g->doc = json_loadb((const char *)p + 20, json_len, JSON_ALLOW_NUL, NULL);
    if (!g->doc)
        return 0;
    at = 20 + json_len;
    if (n - at >= 8 && le_get_u32(p + at + 4) == CHUNK_BIN) {
        size_t len = le_get_u32(p + at);
        if (len > n - at - 8)
            len = n - at - 8;
        if ((g->bin = malloc(len + 1)) != NULL) {
            memcpy(g->bin, p + at + 8, len);
            g->bin_len = len;
        }
    }
    return 1;
}

/* Puts a GLB together from JSON text and an optional BIN chunk, padded as
 * the format wants (spaces after JSON, zeros after binary). */
static void glb_pack(fz_buf *b, const uint8_t *json, size_t json_len, const uint8_t *bin,
                     size_t bin_len)
{
    size_t jpad = (4 - json_len % 4) % 4, bpad = (4 - bin_len % 4) % 4;
    size_t total = 12 + 8 + json_len + jpad + (bin ? 8 + bin_len + bpad : 0);

    fz_put_le(b, GLB_MAGIC, 4);
    fz_put_le(b, 2, 4);
    fz_put_le(b, total, 4);
    fz_put_le(b, json_len + jpad, 4);
    fz_put_le(b, CHUNK_JSON, 4);
    fz_put(b, json, json_len);
    fz_put(b, "   ", jpad);
    if (bin) {
        fz_put_le(b, bin_len + bpad, 4);
        fz_put_le(b, CHUNK_BIN, 4);
        fz_put(b, bin, bin_len);
        fz_put(b, "\0\0\0", bpad);
    }
}

/* ---- finding values in the document ---------------------------------------- */

/* One value of the document and where it sits: member key of an object,
 * or element index of an array (key NULL). ref names the top-level array
 * an index value points into, if the value is one. */
typedef struct slot {
    json_t *parent;
    const char *key;
    size_t index;
    json_t *value;
    const char *ref;
} slot;

#define SLOTS_MAX 4096

typedef struct slots {
    slot v[SLOTS_MAX];
    size_t n;
} slots;

/* The top-level array an index member points into, by its key (or the key
 * of the array holding it, or "attributes"/"targets" above it). */
static const char *ref_of(const char *key)
{
    static const char *const refs[][2] = {
        {"bufferView", "bufferViews"}, {"buffer", "buffers"},   {"indices", "accessors"},
        {"material", "materials"},     {"mesh", "meshes"},      {"skin", "skins"},
        {"camera", "cameras"},         {"scene", "scenes"},     {"inverseBindMatrices", "accessors"},
        {"skeleton", "nodes"},         {"input", "accessors"},  {"output", "accessors"},
        {"node", "nodes"},             {"source", "images"},    {"sampler", "samplers"},
        {"index", "textures"},         {"children", "nodes"},   {"nodes", "nodes"},
        {"joints", "nodes"},           {"attributes", "accessors"}, {"targets", "accessors"}};

    for (size_t i = 0; key && i < sizeof refs / sizeof refs[0]; i++)
        if (strcmp(key, refs[i][0]) == 0)
            return refs[i][1];
    return NULL;
}

static void collect(slots *s, json_t *parent, const char *key, size_t index, json_t *v,
                    const char *ref, int depth)
{
    const char *k;
    json_t *x;
    size_t i;

    if (s->n == SLOTS_MAX || depth > 64)
        return;
    s->v[s->n].parent = parent;
    s->v[s->n].key = key;
    s->v[s->n].index = index;
    s->v[s->n].value = v;
    s->v[s->n].ref = json_is_integer(v) ? ref : NULL;
    s->n++;
    if (json_is_object(v)) {
        json_object_foreach(v, k, x) {
            const char *r = ref_of(k);
            /* members of attributes and morph targets are accessor indices */
            if (!r && ref && strcmp(ref, "accessors") == 0)
                r = ref;
            collect(s, v, k, 0, x, r, depth + 1);
        }
    } else if (json_is_array(v)) {
        json_array_foreach(v, i, x)
            collect(s, v, NULL, i, x, ref, depth + 1);
    }
}

/* A random slot below the root whose value has the given type, or any
 * type if kind is -1; NULL if none. */
static slot *pick(slots *s, int kind)
{
    size_t start = s->n > 1 ? 1 + fz_below((uint32_t)s->n - 1) : 0;

    for (size_t i = 0; i + 1 < s->n; i++) {
        slot *x = &s->v[1 + (start - 1 + i) % (s->n - 1)];
        if (kind < 0 || (int)json_typeof(x->value) == kind ||
            (kind == JSON_INTEGER && json_is_real(x->value)))
            return x;
    }
    return NULL;
}

/* Puts v (a new reference) where x was. */
static void replace(slot *x, json_t *v)
{
    if (x->key)
        json_object_set_new(x->parent, x->key, v);
    else
        json_array_set_new(x->parent, x->index, v);
}

/* ---- hostile JSON values ----------------------------------------------------- */

static json_t *hostile_number(void)
{
    static const json_int_t ints[] = {-1, 0, 1, 2147483647, 2147483648ll, 4294967295ll,
                                      4294967296ll, 9007199254740993ll, INT64_MAX, INT64_MIN};
    static const double reals[] = {1e38, -1e38, 3.4028235e38, 3.5e38, 1e308, -0.0, 5e-324, 0.5, 1e-45, 2.5};

    if (fz_one_in(2))
        return json_integer(ints[fz_below(sizeof ints / sizeof ints[0])]);
    return json_real(reals[fz_below(sizeof reals / sizeof reals[0])]);
}

/* The same value's shape as another type: an array as an object keyed
 * "a", "b"... (the shape that overflowed the heap), an object as an array
 * of its values, a number as a string, an array or an object... */
static json_t *retyped(json_t *v)
{
    json_t *r, *x;
    const char *k;
    size_t i;

    switch (json_typeof(v)) {
    case JSON_ARRAY:
        if (fz_one_in(4))
            break;
        r = json_object();
        json_array_foreach(v, i, x) {
            char key[32];
            snprintf(key, sizeof key, "%c%zu", 'a' + (int)(i % 26), i / 26);
            json_object_set(r, key, x);
        }
        return r;
    case JSON_OBJECT:
        if (fz_one_in(4))
            break;
        r = json_array();
        json_object_foreach(v, k, x)
            json_array_append(r, x);
        return r;
    case JSON_INTEGER:
    case JSON_REAL: {
        char text[64];
        snprintf(text, sizeof text, "%g", json_number_value(v));
        switch (fz_below(4)) {
        case 0: return json_string(text);
        case 1: return json_pack("[O]", v);
        case 2: return json_pack("{sO}", "a", v);
        default: {
            double d = json_number_value(v);
            if (json_is_integer(v))
                return json_real(d + 0.5);
            return json_integer(d > -9e18 && d < 9e18 ? (json_int_t)d : INT64_MAX);
        }
        }
    }
    case JSON_STRING:
        if (fz_one_in(2))
            return json_pack("[O]", v);
        break;
    default:
        break;
    }
    switch (fz_below(6)) {
    case 0: return json_null();
    case 1: return json_true();
    case 2: return json_string("");
    case 3: return json_array();
    case 4: return json_object();
    default: return hostile_number();
    }
}

/* An index into n items, or a hostile one (as a real now and then). */
static json_t *index_value(uint32_t n)
{
    long long i = fz_index(n, 0);

    return fz_one_in(16) ? json_real((double)i) : json_integer(i);
}

static uint32_t count_of(json_t *doc, const char *array)
{
    return (uint32_t)json_array_size(json_object_get(doc, array));
}

/* doc's member key as an array, made if missing or of another type. */
static json_t *array_member(json_t *doc, const char *key)
{
    json_t *a = json_object_get(doc, key);

    if (!json_is_array(a)) {
        a = json_array();
        json_object_set_new(doc, key, a);
    }
    return a;
}

/* Element i of array a as an object, made if it is not one. */
static json_t *object_at(json_t *a, size_t i)
{
    json_t *o = json_array_get(a, i);

    if (!json_is_object(o)) {
        o = json_object();
        if (i < json_array_size(a))
            json_array_set_new(a, i, o);
        else
            json_array_append_new(a, o);
    }
    return o;
}

static json_t *children_of(json_t *node) { return array_member(node, "children"); }

/* ---- structural mutations of the document --------------------------------- */

/* The node graph: cycles, shared children, deep chains, roots everywhere. */
static void mutate_nodes(json_t *doc)
{
    static const uint32_t depths[] = {255, 256, 257, 300, 1000, 20};
    json_t *nodes = array_member(doc, "nodes"), *scenes = array_member(doc, "scenes");
    json_t *roots = array_member(object_at(scenes, 0), "nodes");
    uint32_t n = (uint32_t)json_array_size(nodes), a, b;

    if (n == 0) {
        json_array_append_new(nodes, json_pack("{si}", "mesh", 0));
        n = 1;
    }
    a = fz_below(n);
    b = fz_below(n);
    switch (fz_below(8)) {
    case 0: /* a cycle through two nodes, or one */
        json_array_append_new(children_of(object_at(nodes, a)), json_integer(b));
        json_array_append_new(children_of(object_at(nodes, b)), json_integer(a));
        break;
    case 1: /* a child listed twice */
        json_array_append_new(children_of(object_at(nodes, a)), json_integer(b));
        json_array_append_new(children_of(object_at(nodes, a)), json_integer(b));
        break;
    case 2: /* a child of two parents */
        json_array_append_new(children_of(object_at(nodes, a)), json_integer(b));
        json_array_append_new(children_of(object_at(nodes, fz_below(n))), json_integer(b));
        break;
    case 3: /* a node that is a root and a child */
        json_array_append_new(roots, json_integer(b));
        json_array_append_new(children_of(object_at(nodes, a)), json_integer(b));
        break;
    case 4:
    case 5: { /* a chain, each level a root too now and then (paths grow
               * with the square of its length) */
        uint32_t d = depths[fz_below(sizeof depths / sizeof depths[0])];
        int every = fz_one_in(2);
        for (uint32_t i = 0; i < d; i++) {
            json_t *node = json_pack("{si}", "mesh", 0);
            if (i + 1 < d)
                json_object_set_new(node, "children", json_pack("[I]", (json_int_t)n + i + 1));
            json_array_append_new(nodes, node);
            if (i == 0 || every)
                json_array_append_new(roots, json_integer(n + i));
        }
        break;
    }
    case 6: /* a transform: singular, huge, non-finite once multiplied */
        if (fz_one_in(2)) {
            json_t *m = json_array();
            for (int i = 0; i < 16; i++)
                json_array_append_new(m, fz_one_in(4) ? hostile_number()
                                                      : json_real(i % 5 == 0 ? 1.0 : 0.0));
            json_object_set_new(object_at(nodes, a), "matrix", m);
        } else {
            static const char *const keys[] = {"translation", "rotation", "scale"};
            json_t *v = json_array();
            uint32_t k = fz_below(3), len = k == 1 ? 4 : 3;
            for (uint32_t i = 0; i < len + (fz_one_in(8) ? 1 : 0); i++)
                json_array_append_new(v, fz_one_in(3) ? hostile_number() : json_real(1.0));
            json_object_set_new(object_at(nodes, a), keys[k], v);
        }
        break;
    default: { /* a mesh, skin or camera reference */
        const char *key = fz_one_in(2) ? "mesh" : fz_one_in(2) ? "skin" : "camera";
        json_object_set_new(object_at(nodes, a), key, index_value(count_of(doc, "meshes")));
        break;
    }
    }
}

static const json_int_t component_types[] = {5120, 5121, 5122, 5123, 5125, 5126, 5124, 0};
static const char *const accessor_types[] = {"SCALAR", "VEC2", "VEC3", "VEC4", "MAT2",
                                             "MAT3",   "MAT4", "VEC5", "",     "vec3"};

/* Accessors, buffer views and buffers: counts, offsets, strides, types. */
static void mutate_data(json_t *doc)
{
    uint32_t nv = count_of(doc, "bufferViews");

    switch (fz_below(6)) {
    case 0:
    case 1: { /* an accessor */
        json_t *a = object_at(array_member(doc, "accessors"), fz_below(count_of(doc, "accessors") + 1));
        switch (fz_below(7)) {
        case 0: json_object_set_new(a, "count", json_integer(fz_count((uint32_t)json_integer_value(json_object_get(a, "count"))))); break;
        case 1: json_object_set_new(a, "componentType", json_integer(component_types[fz_below(8)])); break;
        case 2: json_object_set_new(a, "type", json_string(accessor_types[fz_below(10)])); break;
        case 3: json_object_set_new(a, "byteOffset", json_integer(fz_count(4))); break;
        case 4: json_object_set_new(a, "bufferView", index_value(nv)); break;
        case 5: {
            json_t *m = json_array();
            for (uint32_t i = fz_below(5); i > 0; i--)
                json_array_append_new(m, hostile_number());
            json_object_set_new(a, fz_one_in(2) ? "min" : "max", m);
            break;
        }
        default: {
            json_int_t count = fz_count(3);
            json_t *iv = index_value(nv), *vv = index_value(nv);
            json_object_set_new(a, "sparse",
                                json_pack("{s:I,s:{s:o,s:i},s:{s:o}}", "count", count, "indices",
                                          "bufferView", iv, "componentType", 5123, "values",
                                          "bufferView", vv));
            break;
        }
        }
        break;
    }
    case 2:
    case 3: { /* a buffer view */
        static const json_int_t strides[] = {0, 1, 2, 3, 4, 12, 252, 255, 256, 2147483647};
        json_t *v = object_at(array_member(doc, "bufferViews"), fz_below(nv + 1));
        switch (fz_below(4)) {
        case 0: json_object_set_new(v, "byteLength", json_integer(fz_count((uint32_t)json_integer_value(json_object_get(v, "byteLength"))))); break;
        case 1: json_object_set_new(v, "byteOffset", json_integer(fz_count(0))); break;
        case 2: json_object_set_new(v, "byteStride", json_integer(strides[fz_below(10)])); break;
        default: json_object_set_new(v, "buffer", index_value(count_of(doc, "buffers"))); break;
        }
        break;
    }
    default: { /* a buffer: its length, or a URI to somewhere else */
        static const char *const uris[] = {
            "data:application/octet-stream;base64,AAAAAAAAAAAAAIA/",
            "data:application/octet-stream;base64,%%%",
            "data:application/gltf-buffer;base64,",
            "data:;base64,AAAA",
            "model.bin", "/etc/passwd", "../../../etc/shadow", "", "file:///dev/zero",
            "/proc/self/mem"};
        json_t *buf = object_at(array_member(doc, "buffers"), fz_below(count_of(doc, "buffers") + 1));
        if (fz_one_in(2))
            json_object_set_new(buf, "byteLength", json_integer(fz_count((uint32_t)json_integer_value(json_object_get(buf, "byteLength")))));
        else
            json_object_set_new(buf, "uri", json_string(uris[fz_below(10)]));
        break;
    }
    }
}

/* Meshes and their primitives: modes, attributes, indices, morph targets,
 * compression extensions; and top-level arrays Assimp reads besides. */
static void mutate_meshes(json_t *doc)
{
    static const char *const attrs[] = {"POSITION",  "NORMAL",   "TANGENT",  "TEXCOORD_0",
                                        "TEXCOORD_1", "COLOR_0", "JOINTS_0", "WEIGHTS_0", "_X"};
    uint32_t na = count_of(doc, "accessors");
    json_t *mesh = object_at(array_member(doc, "meshes"), fz_below(count_of(doc, "meshes") + 1));
    json_t *prims = array_member(mesh, "primitives");
    json_t *prim = object_at(prims, fz_below((uint32_t)json_array_size(prims) + 1));
    json_t *x;

    switch (fz_below(8)) {
    case 0: json_object_set_new(prim, "mode", json_integer(fz_one_in(2) ? fz_below(7) : fz_count(7))); break;
    case 1:
        x = json_object_get(prim, "attributes");
        if (!json_is_object(x))
            json_object_set_new(prim, "attributes", x = json_object());
        json_object_set_new(x, attrs[fz_below(9)], index_value(na));
        break;
    case 2: json_object_set_new(prim, "indices", index_value(na)); break;
    case 3: json_object_set_new(prim, "targets", json_pack("[{s:o}]", "POSITION", index_value(na))); break;
    case 4: json_object_set_new(prim, "material", index_value(count_of(doc, "materials"))); break;
    case 5:
        json_object_set_new(prim, "extensions",
                            json_pack("{s:{s:o,s:{s:i}}}", "KHR_draco_mesh_compression",
                                      "bufferView", index_value(count_of(doc, "bufferViews")),
                                      "attributes", "POSITION", 0));
        json_object_set_new(doc, "extensionsUsed", json_pack("[s]", "KHR_draco_mesh_compression"));
        break;
    case 6: { /* a skin and an animation on the accessors there are */
        uint32_t nn = count_of(doc, "nodes");
        json_t *ibm = index_value(na), *j0 = index_value(nn), *j1 = index_value(nn);
        json_t *in = index_value(na), *out = index_value(na), *node = index_value(nn);
        const char *interp = fz_one_in(2) ? "LINEAR" : "CUBICSPLINE";
        const char *path = fz_one_in(2) ? "translation" : "weights";
        int sampler = (int)fz_below(2);
        json_array_append_new(array_member(doc, "skins"),
                              json_pack("{s:o,s:[o,o]}", "inverseBindMatrices", ibm, "joints", j0, j1));
        json_array_append_new(array_member(doc, "animations"),
                              json_pack("{s:[{s:o,s:o,s:s}],s:[{s:i,s:{s:o,s:s}}]}", "samplers", "input",
                                        in, "output", out, "interpolation", interp, "channels", "sampler",
                                        sampler, "target", "node", node, "path", path));
        break;
    }
    default: /* materials, textures and images pointing anywhere */
        json_array_append_new(array_member(doc, "images"),
                              json_pack("{s:o,s:s}", "bufferView", index_value(count_of(doc, "bufferViews")),
                                        "mimeType", "image/png"));
        json_array_append_new(array_member(doc, "textures"),
                              json_pack("{s:o}", "source", index_value(count_of(doc, "images"))));
        json_array_append_new(array_member(doc, "materials"),
                              json_pack("{s:{s:{s:o}}}", "pbrMetallicRoughness", "baseColorTexture", "index",
                                        index_value(count_of(doc, "textures"))));
        break;
    }
}

/* One change anywhere in the document. */
static void mutate_doc(json_t *doc)
{
    static slots s;
    slot *x;

    s.n = 0;
    collect(&s, NULL, NULL, 0, doc, NULL, 0);
    switch (fz_below(12)) {
    case 0:
    case 1: /* a value of the wrong type */
        if ((x = pick(&s, -1)) != NULL)
            replace(x, retyped(x->value));
        break;
    case 2: /* a number made hostile */
        if ((x = pick(&s, JSON_INTEGER)) != NULL)
            replace(x, hostile_number());
        break;
    case 3:
    case 4: { /* an index out of range for the array it names */
        slot *found = NULL;
        size_t start = fz_below((uint32_t)s.n);
        for (size_t i = 0; i < s.n && !found; i++)
            if (s.v[(start + i) % s.n].ref)
                found = &s.v[(start + i) % s.n];
        if (found)
            replace(found, index_value(count_of(doc, found->ref)));
        break;
    }
    case 5: /* an array changed: emptied, an element dropped or repeated */
        if ((x = pick(&s, JSON_ARRAY)) != NULL) {
            json_t *a = x->value;
            size_t n = json_array_size(a);
            switch (fz_below(4)) {
            case 0: json_array_clear(a); break;
            case 1: json_array_remove(a, fz_below((uint32_t)n)); break;
            default: {
                size_t k = fz_one_in(4) ? 1000 : 1 + fz_below(3);
                json_t *e = json_array_get(a, fz_below((uint32_t)n));
                for (size_t i = 0; e && i < k; i++)
                    json_array_append(a, e);
                break;
            }
            }
        }
        break;
    case 6: /* a member dropped */
        if ((x = pick(&s, -1)) != NULL && x->key)
            json_object_del(x->parent, x->key);
        break;
    case 7:
    case 8: mutate_nodes(doc); break;
    case 9:
    case 10: mutate_data(doc); break;
    default: mutate_meshes(doc); break;
    }
}

/* ---- changes to the JSON text, the binary chunk and the container ---------- */

/* Nesting past IMPORT_MAX_JSON_DEPTH or jansson's own limit, a member
 * repeated (duplicate keys), a NUL, a number out of every range. The text
 * is in a buffer of cap bytes. */
static size_t mutate_text(uint8_t *t, size_t n, size_t cap)
{
    static const uint32_t depths[] = {63, 64, 65, 2048, 2049, 100000};
    uint8_t *open = memchr(t, '{', n);
    size_t at = open ? (size_t)(open - t) + 1 : 0;

    switch (fz_below(4)) {
    case 0: { /* "x":[[[...]]], at the start of the document */
        uint32_t d = depths[fz_below(sizeof depths / sizeof depths[0])];
        uint8_t *deep = malloc(2 * (size_t)d + 8);
        size_t k = 0;
        if (!deep || !open)
            break;
        memcpy(deep, "\"x\":", 4), k = 4;
        for (uint32_t i = 0; i < d; i++)
            deep[k++] = '[';
        for (uint32_t i = 0; i < d; i++)
            deep[k++] = ']';
        if (at < n && t[at] != '}')
            deep[k++] = ',';
        fz_splice(t, &n, cap, at, at, deep, k);
        free(deep);
        break;
    }
    case 1: { /* the first member repeated */
        uint8_t *colon = memchr(t, ':', n), *comma = colon ? memchr(colon, ',', n - (size_t)(colon - t)) : NULL;
        if (open && comma && comma > open) {
            size_t len = (size_t)(comma - t) + 1 - at;
            uint8_t *copy = malloc(len);
            if (copy) {
                memcpy(copy, t + at, len);
                fz_splice(t, &n, cap, at, at, copy, len);
                free(copy);
            }
        }
        break;
    }
    case 2: /* a NUL: rapidjson stops there, jansson would not */
        if (n)
            t[fz_below((uint32_t)n)] = 0;
        break;
    default:
        n = fz_mutate_number(t, n, cap, 4, 0);
        break;
    }
    return n;
}

/* Vertex data: NaN, infinities, 1e38 where positions are; huge indices. */
static void mutate_bin(uint8_t *bin, size_t len)
{
    size_t at;

    if (len < 4)
        return;
    at = 4 * fz_below((uint32_t)(len / 4));
    if (fz_one_in(2)) {
        float f = fz_f32();
        memcpy(bin + at, &f, 4); /* little-endian hosts only, like the format */
    } else {
        fz_set_le(bin + at, fz_count(0), 4);
    }
}

/* The container's numbers: version, total length, chunk lengths and types. */
static void mutate_container(uint8_t *p, size_t n)
{
    static const size_t fields[] = {4, 8, 12, 16};
    size_t at;
    uint32_t v;

    if (n < 20)
        return;
    at = fields[fz_below(4)];
    if (fz_one_in(4) && n >= 28) /* the BIN chunk's header, if there is one */
        at = 20 + le_get_u32(p + 12) <= n - 8 ? 20 + le_get_u32(p + 12) + 4 * fz_below(2) : at;
    v = le_get_u32(p + at);
    switch (fz_below(4)) {
    case 0: v += fz_below(9) - 4; break;
    case 1: v = fz_count(v); break;
    case 2: v = at == 4 ? fz_below(4) : 0; break;
    default: v = (uint32_t)fz_rnd(); break;
    }
    fz_set_le(p + at, v, 4);
}

/* Serialises g into out (at most max bytes): the document, then one
 * change to the text, the binary chunk or the container, depending on
 * what (0 none, 1 text, 2 binary, 3 container). */
static size_t glb_write(glb *g, int what, uint8_t *out, size_t max)
{
    char *json = json_dumps(g->doc, JSON_COMPACT | JSON_ENCODE_ANY);
    size_t len = json ? strlen(json) : 0, cap = len + 256 * 1024;
    uint8_t *text = malloc(cap);
    fz_buf b = {out, 0, max};

    if (!text) {
        free(json);
        return 0;
    }
    memcpy(text, json ? json : "", len);
    free(json);
    if (what == 1)
        len = mutate_text(text, len, cap);
    if (what == 2 && g->bin)
        mutate_bin(g->bin, g->bin_len);
    glb_pack(&b, text, len, g->bin, g->bin_len);
    free(text);
    if (what == 3)
        mutate_container(out, b.len);
    return b.len;
}

/* ---- generator and mutator -------------------------------------------------- */

/* A small valid scene: positions (a few hostile), indices of 8, 16 or 32
 * bits, one to three meshes, a node tree with transforms. */
static size_t glb_generate(uint8_t *out, size_t max)
{
    static const int index_sizes[] = {1, 2, 4}, index_types[] = {5121, 5123, 5125};
    uint32_t nv = 3 + fz_below(30), ni = fz_one_in(3) ? 0 : 3 * (1 + fz_below(20));
    uint32_t isz = fz_below(3), nmesh = 1 + fz_below(3), nnodes = 1 + fz_below(8);
    size_t pos_len = 12 * (size_t)nv, idx_len = (size_t)ni * (size_t)index_sizes[isz];
    size_t idx_at = (pos_len + 3) & ~(size_t)3;
    fz_buf bin;
    glb g;
    json_t *nodes, *roots, *meshes;
    float lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
    size_t n;

    memset(&g, 0, sizeof g);
    g.bin_len = idx_at + idx_len;
    if (!(g.bin = calloc(1, g.bin_len + 4)))
        return 0;
    bin.p = g.bin;
    bin.len = 0;
    bin.cap = g.bin_len;
    for (uint32_t i = 0; i < 3 * nv; i++) {
        float f = fz_one_in(64) ? fz_f32() : (float)((int)fz_below(2001) - 1000) / 100.0f;
        if (i < 3 || f < lo[i % 3])
            lo[i % 3] = f;
        if (i < 3 || f > hi[i % 3])
            hi[i % 3] = f;
        fz_put_f32(&bin, f);
    }
    bin.len = idx_at;
    for (uint32_t i = 0; i < ni; i++)
        fz_put_le(&bin, fz_one_in(64) ? (uint64_t)fz_index(nv, 0) : fz_below(nv),
                  (unsigned)index_sizes[isz]);
    g.doc = json_pack("{s:{s:s,s:s},s:i,s:[{s:I}],s:[{s:i,s:i,s:I}]}", "asset", "version",
                      fz_one_in(32) ? "1.0" : "2.0", "generator", "fuzz_glb", "scene", 0, "buffers",
                      "byteLength", (json_int_t)g.bin_len, "bufferViews", "buffer", 0, "byteOffset", 0,
                      "byteLength", (json_int_t)pos_len);
    json_object_set_new(g.doc, "accessors",
                        json_pack("[{s:i,s:i,s:I,s:s,s:[f,f,f],s:[f,f,f]}]", "bufferView", 0,
                                  "componentType", 5126, "count", (json_int_t)nv, "type", "VEC3", "min",
                                  (double)lo[0], (double)lo[1], (double)lo[2], "max", (double)hi[0],
                                  (double)hi[1], (double)hi[2]));
    if (ni) {
        json_array_append_new(json_object_get(g.doc, "bufferViews"),
                              json_pack("{s:i,s:I,s:I}", "buffer", 0, "byteOffset", (json_int_t)idx_at,
                                        "byteLength", (json_int_t)idx_len));
        json_array_append_new(json_object_get(g.doc, "accessors"),
                              json_pack("{s:i,s:i,s:I,s:s}", "bufferView", 1, "componentType",
                                        index_types[isz], "count", (json_int_t)ni, "type", "SCALAR"));
    }
    meshes = array_member(g.doc, "meshes");
    for (uint32_t m = 0; m < nmesh; m++) {
        json_t *prim = json_pack("{s:{s:i},s:i}", "attributes", "POSITION", 0, "mode",
                                 fz_one_in(8) ? (int)fz_below(7) : 4);
        if (ni && !fz_one_in(4))
            json_object_set_new(prim, "indices", json_integer(1));
        json_array_append_new(meshes, json_pack("{s:[o]}", "primitives", prim));
    }
    nodes = array_member(g.doc, "nodes");
    roots = json_array();
    for (uint32_t i = 0; i < nnodes; i++) {
        json_t *node = json_object();
        if (!fz_one_in(3))
            json_object_set_new(node, "mesh", json_integer(fz_below(nmesh)));
        if (fz_one_in(4)) {
            double x = fz_below(10), z = -(double)fz_below(10);
            json_object_set_new(node, "translation", json_pack("[f,f,f]", x, 0.0, z));
        }
        if (fz_one_in(8))
            json_object_set_new(node, "scale", json_pack("[f,f,f]", 2.0, 0.5, 1.0));
        json_array_append_new(nodes, node);
        if (i == 0 || fz_one_in(3))
            json_array_append_new(roots, json_integer(i));
        else /* a child of an earlier node: a tree */
            json_array_append_new(children_of(object_at(nodes, fz_below(i))), json_integer(i));
    }
    json_object_set_new(g.doc, "scenes", json_pack("[{s:o}]", "nodes", roots));
    for (uint32_t k = fz_below(3); k > 0; k--)
        mutate_doc(g.doc);
    n = glb_write(&g, fz_one_in(8) ? 1 + (int)fz_below(3) : 0, out, max);
    glb_free(&g);
    return n;
}

static size_t glb_mutate(uint8_t *data, size_t size, size_t max)
{
    glb g;
    int what = 0;
    size_t n;

    if (!glb_read(data, size, &g))
        return 0;
    switch (fz_below(8)) {
    case 0: what = 1; break;
    case 1: what = 2; break;
    case 2: what = 3; break;
    default: mutate_doc(g.doc); break;
    }
    n = glb_write(&g, what, data, max);
    glb_free(&g);
    return n;
}

/* The count of accessor index v of doc, 0 if there is no such accessor. */
static json_int_t accessor_count(json_t *doc, json_t *v)
{
    json_t *acc = json_array_get(json_object_get(doc, "accessors"),
                                 json_is_integer(v) ? (size_t)json_integer_value(v) : SIZE_MAX);

    return json_integer_value(json_object_get(acc, "count"));
}

/*
 * Known, reported, unfixed bugs that the GLB pre-check lets through to
 * Assimp's glTF reader (corpus/fuzz_glb/known-*.glb):
 * - a line loop (mode 2) reads NULL with indices and no POSITION, or with
 *   indices read at a one-byte stride (the server dies), and with one
 *   index leaves a mesh that our check_polygons reads past;
 * - line strips, triangle strips and fans (modes 3, 5, 6) of fewer elements
 *   than the mode needs, or without POSITION, allocate 64 GB (count - 2
 *   wraps);
 * - an accessor whose byteOffset takes it past the end of its buffer view
 *   is copied anyway: a heap over-read whose bytes become vertices;
 * - a sparse accessor whose count exceeds its data overflows the heap;
 * - an index accessor overrunning its view by a byteStride or a type other
 *   than SCALAR leaks 72 bytes;
 * - an animation of morph weights (CUBICSPLINE, a node without targets)
 *   allocates 32 GB.
 * Skipped, broadly: every line loop; strips and fans of under three
 * elements or no POSITION; accessors past their view by their offset;
 * sparse accessors;
 * strided or non-scalar indices; weight animations.
 */
/* Bytes of one element of accessor acc, 0 if its types are not glTF's. */
static json_int_t element_size(json_t *acc)
{
    static const char *const types[] = {"SCALAR", "VEC2", "VEC3", "VEC4", "MAT2", "MAT3", "MAT4"};
    static const json_int_t comps[] = {1, 2, 3, 4, 4, 9, 16};
    const char *type = json_string_value(json_object_get(acc, "type"));
    json_int_t ct = json_integer_value(json_object_get(acc, "componentType"));
    json_int_t bytes = ct == 5120 || ct == 5121 ? 1 : ct == 5122 || ct == 5123 ? 2 : ct == 5125 || ct == 5126 ? 4 : 0;

    for (size_t i = 0; type && i < sizeof types / sizeof types[0]; i++)
        if (strcmp(type, types[i]) == 0)
            return bytes * comps[i];
    return 0;
}

/* True if an accessor reaches past the end of its buffer view by its
 * byteOffset, or is sparse. */
static int accessor_overruns(json_t *doc)
{
    json_t *acc;
    size_t i;

    json_array_foreach(json_object_get(doc, "accessors"), i, acc) {
        json_t *view = json_array_get(json_object_get(doc, "bufferViews"),
                                      (size_t)json_integer_value(json_object_get(acc, "bufferView")));
        json_int_t count = json_integer_value(json_object_get(acc, "count"));
        json_int_t elem = element_size(acc);
        json_int_t stride = json_integer_value(json_object_get(view, "byteStride"));
        json_int_t offset = json_integer_value(json_object_get(acc, "byteOffset"));
        if (json_object_get(acc, "sparse"))
            return 1;
        json_int_t need = count > 0 && count < (1 << 30) && elem > 0
                              ? (count - 1) * (stride > 0 && stride < 256 ? stride : elem) + elem
                              : 0;
        json_int_t len = json_integer_value(json_object_get(view, "byteLength"));
        /* Assimp checks the accessor's size against the view, not its offset */
        if (view && need && offset > 0 && offset < (1 << 30) && need <= len && offset + need > len)
            return 1;
    }
    return 0;
}

static const char *glb_known(const uint8_t *data, size_t size)
{
    const char *why = NULL;
    json_t *mesh, *prim;
    size_t i, k;
    glb g;

    if (!glb_read(data, size, &g))
        return NULL;
    if (accessor_overruns(g.doc))
        why = "GLB accessor past the end of its buffer view, or sparse";
    json_array_foreach(json_object_get(g.doc, "animations"), i, mesh) {
        json_array_foreach(json_object_get(mesh, "channels"), k, prim) {
            const char *path = json_string_value(json_object_get(json_object_get(prim, "target"), "path"));
            if (path && strcmp(path, "weights") == 0)
                why = "GLB animation of morph weights";
        }
    }
    json_array_foreach(json_object_get(g.doc, "meshes"), i, mesh) {
        json_array_foreach(json_object_get(mesh, "primitives"), k, prim) {
            json_int_t mode = json_integer_value(json_object_get(prim, "mode"));
            json_t *pos = json_object_get(json_object_get(prim, "attributes"), "POSITION");
            json_t *ix = json_object_get(prim, "indices");
            json_t *acc = ix ? json_array_get(json_object_get(g.doc, "accessors"),
                                              (size_t)json_integer_value(ix))
                             : NULL;
            json_t *view = json_array_get(json_object_get(g.doc, "bufferViews"),
                                          (size_t)json_integer_value(json_object_get(acc, "bufferView")));
            const char *type = json_string_value(json_object_get(acc, "type"));
            if (mode == 2)
                why = "GLB line loop";
            else if (acc && (json_object_get(view, "byteStride") || !type || strcmp(type, "SCALAR")))
                why = "GLB indices strided or not scalars";
            else if ((mode == 3 || mode == 5 || mode == 6) &&
                     (!pos || accessor_count(g.doc, ix ? ix : pos) < 3))
                why = "GLB strip or fan of under three elements";
        }
    }
    glb_free(&g);
    return why;
}

const fz_target fz_self = {"fuzz_glb", "glb",           glb_generate, glb_mutate,
                           NULL,       fz_import_report, glb_known};
