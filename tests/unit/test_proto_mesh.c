/*
 * test_proto_mesh.c: unit tests for meshes on the wire: the MESH_REQUEST
 * and MESH_CHUNK frames (protocol/proto.c) and the encoded mesh they carry
 * (protocol/proto_mesh.c): round trips, the quantization's error bound,
 * and every refusal of the decoders.
 */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "le.h"
#include "proto.h"
#include "proto_mesh.h"

static uint8_t big[PROTO_MAX_LEN + 64];

/* Decodes payload[0..n) as a frame of type t. */
static int decode_raw(uint16_t t, const uint8_t *payload, size_t n, proto_msg *m)
{
    static uint8_t b[PROTO_MAX_LEN + 64];
    proto_frame f;

    le_put_u32(b, (uint32_t)(n + 2));
    le_put_u16(b + 4, t);
    if (n)
        memcpy(b + PROTO_HEADER_SIZE, payload, n);
    assert_int_equal(proto_frame_parse(b, n + PROTO_HEADER_SIZE, PROTO_MAX_LEN, &f), PROTO_OK);
    return proto_decode(&f, m);
}

/* ---- frames ------------------------------------------------------------- */

static void test_mesh_request_roundtrip(void **state)
{
    proto_mesh_request in = {.object_id = 0xfffffffeu};
    proto_writer w;
    proto_msg m;
    proto_frame f;

    (void)state;
    for (unsigned i = 0; i < PROTO_MESH_HASH_SIZE; i++)
        in.mesh_hash[i] = (uint8_t)(i * 7 + 1);
    proto_writer_init(&w, big, sizeof big);
    proto_put_mesh_request(&w, &in);
    assert_int_equal(w.err, PROTO_OK);
    assert_int_equal(w.len, PROTO_SIZE_MESH_REQUEST);
    assert_int_equal(w.len, 6 + 36);
    assert_int_equal(proto_frame_parse(big, w.len, PROTO_MAX_LEN, &f), PROTO_OK);
    assert_int_equal(proto_decode(&f, &m), PROTO_OK);
    assert_int_equal(m.type, PROTO_MESH_REQUEST);
    assert_int_equal(m.u.mesh_request.object_id, in.object_id);
    assert_memory_equal(m.u.mesh_request.mesh_hash, in.mesh_hash, PROTO_MESH_HASH_SIZE);
    assert_string_equal(proto_type_name(PROTO_MESH_REQUEST), "mesh_request");
}

/* Id 0 is BAD_VALUE; every cut is SHORT; a byte more TRAILING. */
static void test_mesh_request_refusals(void **state)
{
    uint8_t p[40] = {5};
    proto_msg m;

    (void)state;
    assert_int_equal(decode_raw(PROTO_MESH_REQUEST, p, 36, &m), PROTO_OK);
    for (size_t k = 0; k < 36; k++)
        assert_int_equal(decode_raw(PROTO_MESH_REQUEST, p, k, &m), PROTO_ERR_SHORT);
    assert_int_equal(decode_raw(PROTO_MESH_REQUEST, p, 37, &m), PROTO_ERR_TRAILING);
    p[0] = 0;
    assert_int_equal(decode_raw(PROTO_MESH_REQUEST, p, 36, &m), PROTO_ERR_BAD_VALUE);
    /* the id comes first: id 0 and a cut hash is BAD_VALUE */
    assert_int_equal(decode_raw(PROTO_MESH_REQUEST, p, 10, &m), PROTO_ERR_BAD_VALUE);
}

static void test_mesh_chunk_roundtrip(void **state)
{
    static uint8_t data[PROTO_MESH_CHUNK_MAX];
    const uint32_t lens[] = {1, 2, 1000, PROTO_MESH_CHUNK_MAX};

    (void)state;
    for (size_t i = 0; i < sizeof data; i++)
        data[i] = (uint8_t)(i * 31);
    for (size_t i = 0; i < sizeof lens / sizeof lens[0]; i++) {
        proto_mesh_chunk in = {.object_id = 9, .total = 3u * PROTO_MESH_CHUNK_MAX, .offset = 2u * PROTO_MESH_CHUNK_MAX,
                               .data = data, .len = lens[i]};
        proto_writer w;
        proto_frame f;
        proto_msg m;

        proto_writer_init(&w, big, sizeof big);
        proto_put_mesh_chunk(&w, &in);
        assert_int_equal(w.err, PROTO_OK);
        assert_int_equal(w.len, PROTO_SIZE_MESH_CHUNK(lens[i]));
        assert_int_equal(proto_frame_parse(big, w.len, PROTO_MAX_LEN, &f), PROTO_OK);
        assert_int_equal(proto_decode(&f, &m), PROTO_OK);
        assert_int_equal(m.u.mesh_chunk.object_id, 9);
        assert_int_equal(m.u.mesh_chunk.total, in.total);
        assert_int_equal(m.u.mesh_chunk.offset, in.offset);
        assert_int_equal(m.u.mesh_chunk.len, lens[i]);
        assert_ptr_equal(m.u.mesh_chunk.data, big + PROTO_HEADER_SIZE + 12);
        assert_memory_equal(m.u.mesh_chunk.data, data, lens[i]);
    }
    /* The writer refuses a chunk over the cap, and the error sticks. */
    proto_mesh_chunk over = {.object_id = 9, .total = UINT32_MAX, .offset = 0, .data = data,
                             .len = PROTO_MESH_CHUNK_MAX + 1};
    proto_writer w;
    proto_writer_init(&w, big, sizeof big);
    proto_put_mesh_chunk(&w, &over);
    assert_int_equal(w.err, PROTO_ERR_FRAME_TOO_LONG);
    assert_int_equal(w.len, 0);
    proto_put_mesh_request(&w, &(proto_mesh_request){.object_id = 1});
    assert_int_equal(w.len, 0);
}

/* Writes a chunk head (id, total, offset) and n data bytes into p. */
static size_t chunk_payload(uint8_t *p, uint32_t id, uint32_t total, uint32_t offset, size_t n)
{
    le_put_u32(p, id);
    le_put_u32(p + 4, total);
    le_put_u32(p + 8, offset);
    memset(p + 12, 0xab, n);
    return 12 + n;
}

static void test_mesh_chunk_refusals(void **state)
{
    static uint8_t p[PROTO_MESH_CHUNK_MAX + 64];
    proto_msg m;

    (void)state;
    /* the head cut short */
    chunk_payload(p, 1, 10, 0, 1);
    for (size_t k = 0; k < 12; k++)
        assert_int_equal(decode_raw(PROTO_MESH_CHUNK, p, k, &m), PROTO_ERR_SHORT);
    /* no data */
    assert_int_equal(decode_raw(PROTO_MESH_CHUNK, p, chunk_payload(p, 1, 10, 0, 0), &m), PROTO_ERR_SHORT);
    /* id 0, total 0, offset at or past the total */
    assert_int_equal(decode_raw(PROTO_MESH_CHUNK, p, chunk_payload(p, 0, 10, 0, 1), &m), PROTO_ERR_BAD_VALUE);
    assert_int_equal(decode_raw(PROTO_MESH_CHUNK, p, chunk_payload(p, 1, 0, 0, 1), &m), PROTO_ERR_BAD_VALUE);
    assert_int_equal(decode_raw(PROTO_MESH_CHUNK, p, chunk_payload(p, 1, 10, 10, 1), &m), PROTO_ERR_BAD_VALUE);
    /* data past the total, and the last byte exactly at it */
    assert_int_equal(decode_raw(PROTO_MESH_CHUNK, p, chunk_payload(p, 1, 10, 5, 6), &m), PROTO_ERR_BAD_VALUE);
    assert_int_equal(decode_raw(PROTO_MESH_CHUNK, p, chunk_payload(p, 1, 10, 5, 5), &m), PROTO_OK);
    assert_int_equal(m.u.mesh_chunk.len, 5);
    /* the data cap */
    assert_int_equal(decode_raw(PROTO_MESH_CHUNK, p, chunk_payload(p, 1, UINT32_MAX, 0, PROTO_MESH_CHUNK_MAX), &m),
                     PROTO_OK);
    assert_int_equal(
        decode_raw(PROTO_MESH_CHUNK, p, chunk_payload(p, 1, UINT32_MAX, 0, PROTO_MESH_CHUNK_MAX + 1), &m),
        PROTO_ERR_BAD_VALUE);
    /* a client may not send one; the server's handler says so, the codec
     * only names it */
    assert_string_equal(proto_type_name(PROTO_MESH_CHUNK), "mesh_chunk");
    assert_string_equal(proto_strerror(PROTO_ERR_STALE_MESH), "mesh hash does not match");
}

/* ---- the encoded mesh ----------------------------------------------------- */

/* A grid of n x n squares (2 n^2 triangles) on a bumpy surface, spanning
 * [lo, lo + size] in x and z: neighbouring triangles share corners. */
static float *grid(uint32_t n, float lo, float size, uint32_t *ntris)
{
    float *t = malloc((size_t)n * n * 2 * 9 * sizeof *t);
    size_t k = 0;

    assert_non_null(t);
    for (uint32_t i = 0; i < n; i++)
        for (uint32_t j = 0; j < n; j++) {
            const uint32_t c[6][2] = {{i, j}, {i + 1, j}, {i + 1, j + 1}, {i, j}, {i + 1, j + 1}, {i, j + 1}};
            for (int v = 0; v < 6; v++) {
                float x = lo + size * (float)c[v][0] / (float)n, z = lo + size * (float)c[v][1] / (float)n;
                t[k++] = x;
                t[k++] = 0.3f * sinf(x) * cosf(z);
                t[k++] = z;
            }
        }
    *ntris = 2 * n * n;
    return t;
}

/* Encodes tris, decodes the result and checks every corner of every
 * triangle against the original within half a step of the box on each
 * axis (plus float rounding); returns the encoded size. */
static size_t roundtrip(const float *tris, uint32_t ntris, uint32_t want_vertices)
{
    uint8_t *buf = NULL;
    size_t len = 0;
    proto_mesh m;

    assert_int_equal(proto_mesh_encode(tris, ntris, &buf, &len), 0);
    assert_int_equal(proto_mesh_decode(buf, len, &m), PROTO_OK);
    assert_int_equal(m.tri_count, ntris);
    assert_int_equal(m.vertex_count, want_vertices);
    assert_int_equal(m.index_size, want_vertices <= PROTO_MESH_SMALL_VERTS ? 2 : 4);
    assert_int_equal(len, PROTO_MESH_HEAD_SIZE + 6 * (size_t)m.vertex_count + 3 * (size_t)ntris * m.index_size);
    for (uint32_t k = 0; k < 3 * ntris; k++) {
        float v[3];
        proto_mesh_vertex(&m, proto_mesh_index(&m, k), v);
        for (int a = 0; a < 3; a++) {
            double step = ((double)m.max[a] - m.min[a]) / PROTO_MESH_STEPS;
            double err = fabs((double)v[a] - tris[3 * (size_t)k + (size_t)a]);
            assert_true(err <= 0.5 * step + 4e-7 * (fabs(m.min[a]) + fabs(m.max[a])) + 1e-12);
        }
    }
    free(buf);
    return len;
}

static void test_mesh_roundtrip_small(void **state)
{
    const float one[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    const float flat[9] = {2, 5, -1, 3, 5, -1, 2, 5, 4}; /* flat in y: a zero extent */
    const float same[9] = {7, 7, 7, 7, 7, 7, 7, 7, 7};   /* every corner one point */
    uint32_t n;
    float *g;

    (void)state;
    roundtrip(one, 1, 3);
    roundtrip(flat, 1, 3);
    roundtrip(same, 1, 1);
    g = grid(20, -3.0f, 6.0f, &n);
    roundtrip(g, n, 21 * 21); /* shared corners became one vertex each */
    free(g);
}

/* More than 65536 vertices take u32 indices. */
static void test_mesh_roundtrip_large(void **state)
{
    uint32_t n;
    float *g = grid(300, 100.0f, 250.0f, &n);

    (void)state;
    roundtrip(g, n, 301u * 301u);
    free(g);
}

/* Quantizing halves the positions (6 bytes a vertex, not 12). */
static void test_mesh_size(void **state)
{
    uint32_t n;
    float *g = grid(50, 0.0f, 10.0f, &n);
    size_t len = roundtrip(g, n, 51u * 51u);

    (void)state;
    assert_int_equal(len, 32 + 6 * 51 * 51 + 2 * 3 * (size_t)n);
    assert_true(len * 3 < (size_t)n * 36); /* a third of the triangles as stored */
    free(g);
}

static void test_mesh_encode_refusals(void **state)
{
    float t[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    uint8_t *buf = NULL;
    size_t len = 0;

    (void)state;
    assert_int_equal(proto_mesh_encode(t, 0, &buf, &len), -EINVAL);
    assert_int_equal(proto_mesh_encode(t, PROTO_MESH_TRIS_MAX + 1, &buf, &len), -EINVAL);
    t[4] = NAN;
    assert_int_equal(proto_mesh_encode(t, 1, &buf, &len), -EINVAL);
    t[4] = INFINITY;
    assert_int_equal(proto_mesh_encode(t, 1, &buf, &len), -EINVAL);
    assert_null(buf);
    /* every allocation failing in turn is -ENOMEM, and nothing leaks */
    t[4] = 0;
    for (long k = 0; k < 4; k++) {
        cvre_alloc_fail_after(k);
        assert_int_equal(proto_mesh_encode(t, 1, &buf, &len), -ENOMEM);
        cvre_alloc_fail_after(-1);
    }
    assert_int_equal(proto_mesh_encode(t, 1, &buf, &len), 0);
    free(buf);
}

/* A valid mesh of one triangle, with u16 indices, in b; returns its size. */
static size_t one_triangle(uint8_t *b)
{
    const float t[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    uint8_t *buf;
    size_t len;

    assert_int_equal(proto_mesh_encode(t, 1, &buf, &len), 0);
    memcpy(b, buf, len);
    free(buf);
    return len;
}

static void test_mesh_decode_refusals(void **state)
{
    uint8_t b[128];
    proto_mesh m;
    size_t len = one_triangle(b);

    (void)state;
    assert_int_equal(len, 32 + 3 * 6 + 3 * 2);
    assert_int_equal(proto_mesh_decode(b, len, &m), PROTO_OK);
    for (size_t k = 0; k < len; k++)
        assert_int_equal(proto_mesh_decode(b, k, &m), PROTO_ERR_SHORT);
    assert_int_equal(proto_mesh_decode(b, len + 1, &m), PROTO_ERR_TRAILING);
    /* counts: no vertex, no triangle, too many triangles, more vertices
     * than corners */
    const uint32_t counts[][2] = {{0, 1}, {3, 0}, {3, PROTO_MESH_TRIS_MAX + 1}, {4, 1}};
    for (size_t i = 0; i < sizeof counts / sizeof counts[0]; i++) {
        uint8_t c[128];
        memcpy(c, b, len);
        le_put_u32(c, counts[i][0]);
        le_put_u32(c + 4, counts[i][1]);
        assert_int_equal(proto_mesh_decode(c, len, &m), PROTO_ERR_BAD_VALUE);
    }
    /* the box: not finite (min or max), max below min */
    for (size_t at = 8; at < 32; at += 4) {
        uint8_t c[128];
        memcpy(c, b, len);
        le_put_u32(c + at, 0x7fc00000u);
        assert_int_equal(proto_mesh_decode(c, len, &m), PROTO_ERR_NOT_FINITE);
        le_put_u32(c + at, 0x7f800000u);
        assert_int_equal(proto_mesh_decode(c, len, &m), PROTO_ERR_NOT_FINITE);
    }
    uint8_t c[128];
    memcpy(c, b, len);
    le_put_f32(c + 20, -1.0f); /* max.x below min.x 0 */
    assert_int_equal(proto_mesh_decode(c, len, &m), PROTO_ERR_BAD_VALUE);
    /* an index past the vertices, in each corner */
    for (size_t k = 0; k < 3; k++) {
        memcpy(c, b, len);
        le_put_u16(c + 32 + 18 + 2 * k, 3);
        assert_int_equal(proto_mesh_decode(c, len, &m), PROTO_ERR_BAD_VALUE);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_mesh_request_roundtrip),
        cmocka_unit_test(test_mesh_request_refusals),
        cmocka_unit_test(test_mesh_chunk_roundtrip),
        cmocka_unit_test(test_mesh_chunk_refusals),
        cmocka_unit_test(test_mesh_roundtrip_small),
        cmocka_unit_test(test_mesh_roundtrip_large),
        cmocka_unit_test(test_mesh_size),
        cmocka_unit_test(test_mesh_encode_refusals),
        cmocka_unit_test(test_mesh_decode_refusals),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
