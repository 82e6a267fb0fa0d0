/*
 * test_proto.c: unit tests for the wire codec (protocol/proto.c).
 *
 * Round trips go through the public writer and decoder only. Malformed
 * input is built by hand from a table of valid sample payloads, one per
 * type, that records where each string, float, scale and non-zero id sits,
 * so every class of error is tried against every type it applies to;
 * what only one type has (a chunk's open-ended data, an object's boxes)
 * gets tests of its own.
 */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>
#include <limits.h>

#include <float.h>
#include <string.h>

#include "proto.h"

/* Room for the largest frame plus a little, shared by the tests. */
#define BIG (PROTO_SIZE_SNAPSHOT(PROTO_SNAPSHOT_MAX_ENTRIES) + 64u)
static uint8_t big[BIG];

/* ---- helpers ------------------------------------------------------------ */

static uint32_t f32_bits(float v)
{
    uint32_t b;
    memcpy(&b, &v, sizeof b);
    return b;
}

static float bits_f32(uint32_t b)
{
    float v;
    memcpy(&v, &b, sizeof v);
    return v;
}

static void wr_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
}

static void wr_u32(uint8_t *p, uint32_t v)
{
    for (int i = 0; i < 4; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}

static void wr_f32(uint8_t *p, float v) { wr_u32(p, f32_bits(v)); }

/* Float fields are compared bit for bit: -0.0 must survive as -0.0. */
static void assert_same_floats(const float *a, const float *b, size_t n)
{
    for (size_t i = 0; i < n; i++)
        assert_int_equal(f32_bits(a[i]), f32_bits(b[i]));
}

static void assert_str(proto_str s, const char *want, size_t want_len)
{
    assert_int_equal(s.len, want_len);
    assert_memory_equal(s.ptr, want, want_len);
}

/* Parses b[0..n) as exactly one frame (joined cap) and decodes it; any
 * other outcome fails the test. */
static void decode_all(const uint8_t *b, size_t n, proto_msg *m)
{
    proto_frame f;

    assert_int_equal(proto_frame_parse(b, n, PROTO_MAX_LEN, &f), PROTO_OK);
    assert_int_equal(f.size, n);
    assert_ptr_equal(f.payload, b + PROTO_HEADER_SIZE);
    assert_int_equal(f.payload_len, n - PROTO_HEADER_SIZE);
    assert_int_equal(proto_decode(&f, m), PROTO_OK);
    assert_int_equal(m->type, f.type);
}

/* Decodes a hand-built payload of the given type and returns the status.
 * The frame is built in a static buffer so pointers in m stay valid. */
static int decode_raw_msg(uint16_t type, const uint8_t *payload, size_t n, proto_msg *m)
{
    static uint8_t b[BIG];
    proto_frame f;

    assert_true(n + PROTO_HEADER_SIZE <= sizeof b);
    wr_u32(b, (uint32_t)(n + 2));
    wr_u16(b + 4, type);
    if (n > 0)
        memcpy(b + PROTO_HEADER_SIZE, payload, n);
    assert_int_equal(proto_frame_parse(b, n + PROTO_HEADER_SIZE, PROTO_MAX_LEN, &f), PROTO_OK);
    assert_int_equal(f.type, type);
    return proto_decode(&f, m);
}

static int decode_raw(uint16_t type, const uint8_t *payload, size_t n)
{
    proto_msg m;
    return decode_raw_msg(type, payload, n, &m);
}

/* ---- sample payloads ---------------------------------------------------- */

#define MAX_FLOATS 20
#define SAMPLE_MAX 128 /* bytes of the largest sample payload */
#define NSAMPLES 21    /* one per defined type */

/* A string inside a sample: where its length byte sits, how many bytes of
 * text follow, and the bounds the decoder holds it to. */
typedef struct sample_str {
    size_t at;
    size_t len;
    uint32_t min, max;
} sample_str;

/* One valid payload per type and what sits where in it. */
typedef struct sample {
    uint16_t type;
    uint8_t payload[SAMPLE_MAX];
    size_t len;
    sample_str strs[2];
    size_t nstrs;
    size_t floats[MAX_FLOATS]; /* offsets of every f32 */
    size_t nfloats;
    size_t boxes[3]; /* offsets of the avatar box edges, if any */
    size_t nboxes;
    size_t scale; /* offset of the object scale or unit scale, if any (else 0) */
    size_t ids[2]; /* offsets of the u32 ids that must not be 0 */
    size_t nids;
    size_t data_at; /* upload chunk: the data runs from here to the end (else 0) */
} sample;

static const proto_welcome sample_welcome = {
    PROTO_VERSION, 0x0102030405060708u,
    {1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16},
    20, 50.0f, 5.0f, {-100.0f, 0.0f, -100.0f}, {100.0f, 50.0f, 100.0f}, 30000};

/* The boxes of the object_info sample. */
static const float sample_min[2][3] = {{-1.0f, 0.0f, -1.0f}, {2.0f, 0.0f, 2.0f}};
static const float sample_max[2][3] = {{1.0f, 2.0f, 1.0f}, {3.0f, 0.5f, 3.0f}};

/* Encodes one message of each type with the writer and strips the header,
 * so the samples are exactly what a peer sends. */
static size_t build_samples(sample *s)
{
    size_t n = 0;
    uint8_t b[SAMPLE_MAX + PROTO_HEADER_SIZE];
    proto_writer w;
    const proto_hello hello = {PROTO_MAGIC, PROTO_VERSION};
    const proto_join join = {.name = {"ann", 3}, .box = {0.5f, 1.8f, 0.5f}};
    const proto_join_ok jok = {.avatar_id = 7, .pos = {1.0f, 0.0f, 2.0f}, .box = {0.5f, 1.8f, 0.5f}};
    const proto_move move = {.seq = 1, .pos = {1.0f, 0.0f, -2.5f}};
    const proto_avatar e0 = {7, {1.0f, 2.0f, 3.0f}}, e1 = {8, {-1.0f, -2.0f, -3.0f}};
    const proto_avatar_joined aj = {8, {"bob", 3}, {4.0f, 0.0f, 4.0f}, {1.0f, 1.0f, 1.0f}};
    const proto_avatar_left al = {8, PROTO_LEFT_OUT_OF_RANGE};
    const proto_upload_begin ub = {5, 1000, {"chair", 5}, {"obj", 3}, PROTO_UP_Z, 0.01f};
    const uint8_t bytes[3] = {'a', 0, 0xff};
    const proto_upload_chunk uc = {5, 0, bytes, 3};
    const proto_upload_end ue = {5, {{1.0f, 2.0f, 3.0f}, 0.5f, 2.0f}};
    const proto_object_place op = {9, {{-1.0f, 0.0f, -2.0f}, -3.0f, 0.5f}};
    const proto_object_info oi = {9, 5, {"ann", 3}, {"chair", 5}, {{4.0f, 0.0f, 4.0f}, 1.5f, 1.0f},
                                  1, 12, {0xa5, 0, 0x5a}, 2, NULL};
    const proto_collision co = {9, 1, 0, 0, {1.0f, 0.0f, 2.0f}, {-1.0f, 0.0f, 0.0f}};
    size_t at;

    memset(s, 0, NSAMPLES * sizeof *s);
#define ADD(T, put)                                                      \
    do {                                                                 \
        proto_writer_init(&w, b, sizeof b);                              \
        put;                                                             \
        assert_int_equal(w.err, PROTO_OK);                               \
        s[n].type = (T);                                                 \
        s[n].len = w.len - PROTO_HEADER_SIZE;                            \
        memcpy(s[n].payload, b + PROTO_HEADER_SIZE, s[n].len);           \
    } while (0)
#define FLOATS(...)                                                      \
    do {                                                                 \
        const size_t offs[] = {__VA_ARGS__};                             \
        s[n].nfloats = sizeof offs / sizeof offs[0];                     \
        memcpy(s[n].floats, offs, sizeof offs);                          \
    } while (0)
#define STR(at_, len_, min_, max_)                                       \
    do {                                                                 \
        const sample_str str = {(at_), (len_), (min_), (max_)};          \
        s[n].strs[s[n].nstrs++] = str;                                   \
    } while (0)
#define IDS(...)                                                         \
    do {                                                                 \
        const size_t offs[] = {__VA_ARGS__};                             \
        s[n].nids = sizeof offs / sizeof offs[0];                        \
        memcpy(s[n].ids, offs, sizeof offs);                             \
    } while (0)

    ADD(PROTO_HELLO, proto_put_hello(&w, &hello));
    n++;
    ADD(PROTO_WELCOME, proto_put_welcome(&w, &sample_welcome));
    FLOATS(28, 32, 36, 40, 44, 48, 52, 56);
    n++;
    ADD(PROTO_JOIN, proto_put_join(&w, &join));
    STR(0, 3, 1, PROTO_NAME_MAX);
    FLOATS(4, 8, 12);
    s[n].boxes[0] = 4, s[n].boxes[1] = 8, s[n].boxes[2] = 12, s[n].nboxes = 3;
    n++;
    ADD(PROTO_JOIN_OK, proto_put_join_ok(&w, &jok));
    FLOATS(4, 8, 12, 16, 20, 24);
    s[n].boxes[0] = 16, s[n].boxes[1] = 20, s[n].boxes[2] = 24, s[n].nboxes = 3;
    n++;
    ADD(PROTO_MOVE, proto_put_move(&w, &move));
    FLOATS(4, 8, 12);
    n++;
    ADD(PROTO_SNAPSHOT, (at = proto_put_snapshot_begin(&w, 100, 1),
                         proto_put_snapshot_add(&w, at, &e0), proto_put_snapshot_add(&w, at, &e1),
                         proto_put_snapshot_end(&w, at)));
    FLOATS(14, 18, 22, 30, 34, 38);
    n++;
    ADD(PROTO_AVATAR_JOINED, proto_put_avatar_joined(&w, &aj));
    STR(4, 3, 1, PROTO_NAME_MAX);
    FLOATS(8, 12, 16, 20, 24, 28);
    s[n].boxes[0] = 20, s[n].boxes[1] = 24, s[n].boxes[2] = 28, s[n].nboxes = 3;
    n++;
    ADD(PROTO_AVATAR_LEFT, proto_put_avatar_left(&w, &al));
    n++;
    ADD(PROTO_ERROR, proto_put_error(&w, PROTO_ERR_BAD_SEQ, "oops"));
    STR(2, 4, 0, PROTO_MESSAGE_MAX);
    n++;
    ADD(PROTO_PING, proto_put_ping(&w, 42));
    n++;
    ADD(PROTO_PONG, proto_put_pong(&w, 42));
    n++;
    ADD(PROTO_BYE, proto_put_bye(&w, PROTO_BYE_QUIT));
    n++;
    ADD(PROTO_OBJECT_UPLOAD_BEGIN, proto_put_upload_begin(&w, &ub));
    STR(8, 5, 1, PROTO_OBJECT_NAME_MAX);
    STR(14, 3, 0, PROTO_FORMAT_MAX);
    FLOATS(19);
    s[n].scale = 19;
    IDS(0);
    n++;
    ADD(PROTO_OBJECT_UPLOAD_CHUNK, proto_put_upload_chunk(&w, &uc));
    IDS(0);
    s[n].data_at = 8;
    n++;
    ADD(PROTO_OBJECT_UPLOAD_END, proto_put_upload_end(&w, &ue));
    FLOATS(4, 8, 12, 16, 20);
    s[n].scale = 20;
    IDS(0);
    n++;
    ADD(PROTO_OBJECT_PLACE, proto_put_object_place(&w, &op));
    FLOATS(4, 8, 12, 16, 20);
    s[n].scale = 20;
    IDS(0);
    n++;
    ADD(PROTO_OBJECT_REMOVE, proto_put_object_remove(&w, 9));
    IDS(0);
    n++;
    ADD(PROTO_OBJECT_INFO, proto_put_object_info(&w, &oi, sample_min, sample_max));
    STR(8, 3, 1, PROTO_NAME_MAX);
    STR(12, 5, 1, PROTO_OBJECT_NAME_MAX);
    FLOATS(18, 22, 26, 30, 34, 80, 84, 88, 92, 96, 100, 104, 108, 112, 116, 120, 124);
    s[n].scale = 34;
    IDS(0, 38);
    n++;
    ADD(PROTO_OBJECT_REMOVED, proto_put_object_removed(&w, 9));
    IDS(0);
    n++;
    ADD(PROTO_OBJECT_REJECTED, proto_put_object_rejected(&w, 5, PROTO_ERR_UPLOAD, "too big"));
    STR(6, 7, 0, PROTO_MESSAGE_MAX);
    n++;
    ADD(PROTO_COLLISION, proto_put_collision(&w, &co));
    FLOATS(11, 15, 19, 23, 27, 31);
    IDS(0, 4);
    n++;
#undef ADD
#undef FLOATS
#undef STR
#undef IDS
    /* The offsets above are this file's copy of PROTOCOL.md; check them. */
    assert_int_equal(n, NSAMPLES);
    for (size_t i = 0; i < n; i++) {
        assert_int_equal(decode_raw(s[i].type, s[i].payload, s[i].len), PROTO_OK);
        for (size_t k = 0; k < s[i].nfloats; k++)
            assert_true(s[i].floats[k] + 4 <= s[i].len);
        for (size_t k = 0; k < s[i].nstrs; k++) {
            assert_int_equal(s[i].payload[s[i].strs[k].at], s[i].strs[k].len);
            assert_true(s[i].strs[k].at + 1 + s[i].strs[k].len <= s[i].len);
        }
    }
    return n;
}

/* Decodes sample s with its string k replaced by text[0..n), and returns
 * the status. The fields around the string keep their values. */
static int splice_status(const sample *s, size_t k, const char *text, size_t n)
{
    uint8_t p[SAMPLE_MAX + 256];
    const sample_str *st = &s->strs[k];
    const size_t tail = st->at + 1 + st->len;
    size_t len = st->at;

    assert_true(n <= 255);
    memcpy(p, s->payload, len);
    p[len++] = (uint8_t)n;
    memcpy(p + len, text, n);
    len += n;
    memcpy(p + len, s->payload + tail, s->len - tail);
    len += s->len - tail;
    return decode_raw(s->type, p, len);
}

/* ---- round trips -------------------------------------------------------- */

static void test_hello_roundtrip(void **state)
{
    proto_writer w;
    proto_msg m;
    const proto_hello in = {PROTO_MAGIC, 0xbeef};

    (void)state;
    proto_writer_init(&w, big, BIG);
    proto_put_hello(&w, &in);
    assert_int_equal(w.err, PROTO_OK);
    assert_int_equal(w.len, PROTO_SIZE_HELLO);
    decode_all(big, w.len, &m);
    assert_int_equal(m.type, PROTO_HELLO);
    assert_int_equal(m.u.hello.magic, PROTO_MAGIC);
    assert_int_equal(m.u.hello.version, 0xbeef);
}

static void test_welcome_roundtrip(void **state)
{
    proto_writer w;
    proto_msg m;
    proto_welcome in = sample_welcome;

    (void)state;
    in.session_id = UINT64_MAX - 1;
    in.tick_hz = 0xffff;
    in.max_speed = 0.0f;
    in.world_min[1] = in.world_max[1] = -0.0f; /* a flat world is allowed */
    in.idle_timeout_ms = UINT32_MAX;
    proto_writer_init(&w, big, BIG);
    proto_put_welcome(&w, &in);
    assert_int_equal(w.err, PROTO_OK);
    assert_int_equal(w.len, PROTO_SIZE_WELCOME);
    decode_all(big, w.len, &m);
    assert_int_equal(m.type, PROTO_WELCOME);
    assert_int_equal(m.u.welcome.version, in.version);
    assert_true(m.u.welcome.session_id == in.session_id);
    assert_memory_equal(m.u.welcome.token, in.token, PROTO_TOKEN_SIZE);
    assert_int_equal(m.u.welcome.tick_hz, in.tick_hz);
    assert_same_floats(&m.u.welcome.aoi_radius, &in.aoi_radius, 1);
    assert_same_floats(&m.u.welcome.max_speed, &in.max_speed, 1);
    assert_same_floats(m.u.welcome.world_min, in.world_min, 3);
    assert_same_floats(m.u.welcome.world_max, in.world_max, 3);
    assert_true(m.u.welcome.idle_timeout_ms == in.idle_timeout_ms);
    /* An idle timeout of 0 would make every connection idle at once. */
    in.idle_timeout_ms = 0;
    proto_writer_init(&w, big, BIG);
    proto_put_welcome(&w, &in);
    proto_frame f;
    assert_int_equal(proto_frame_parse(big, w.len, PROTO_MAX_LEN, &f), PROTO_OK);
    assert_int_equal(proto_decode(&f, &m), PROTO_ERR_BAD_VALUE);
}

static void test_join_roundtrip(void **state)
{
    static const char *names[] = {
        "a", "Ann Lee", "Zoë", "€uro", "\xf0\x9f\x98\x80 smile", "\xf4\x8f\xbf\xbf",
        "abcdefghijklmnopqrstuvwxyz012345", /* exactly PROTO_NAME_MAX */
    };
    (void)state;
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++) {
        proto_writer w;
        proto_msg m;
        const proto_join in = {.name = {names[i], (uint32_t)strlen(names[i])},
                               .box = {PROTO_BOX_MIN, 1.8f, PROTO_BOX_MAX}};

        proto_writer_init(&w, big, BIG);
        proto_put_join(&w, &in);
        assert_int_equal(w.err, PROTO_OK);
        assert_int_equal(w.len, PROTO_HEADER_SIZE + 1 + strlen(names[i]) + 12);
        decode_all(big, w.len, &m);
        assert_int_equal(m.type, PROTO_JOIN);
        assert_str(m.u.join.name, names[i], strlen(names[i]));
        /* The name points into the frame, not into a copy. */
        assert_ptr_equal(m.u.join.name.ptr, (const char *)big + PROTO_HEADER_SIZE + 1);
        assert_same_floats(m.u.join.box, in.box, 3);
        assert_int_equal(m.u.join.credential, PROTO_CRED_NONE);
    }
}

/* A join's credential: a password of 1..PROTO_PASSWORD_MAX bytes (any
 * bytes) or a token of exactly PROTO_RESUME_TOKEN_SIZE; anything else is a
 * bad value, and the whole join must fit the pre-join cap. */
static void test_join_credentials(void **state)
{
    static uint8_t secret[PROTO_PASSWORD_MAX + 1];
    static const struct {
        uint8_t kind;
        uint32_t len;
        int status;
    } cases[] = {
        {PROTO_CRED_PASSWORD, 1, PROTO_OK},
        {PROTO_CRED_PASSWORD, PROTO_PASSWORD_MAX, PROTO_OK},
        {PROTO_CRED_TOKEN, PROTO_RESUME_TOKEN_SIZE, PROTO_OK},
        {PROTO_CRED_PASSWORD, 0, PROTO_ERR_BAD_VALUE},
        {PROTO_CRED_TOKEN, PROTO_RESUME_TOKEN_SIZE - 1, PROTO_ERR_BAD_VALUE},
        {PROTO_CRED_NONE, 4, PROTO_ERR_BAD_VALUE},
        {7, 4, PROTO_ERR_BAD_VALUE},
    };
    (void)state;
    for (size_t i = 0; i < sizeof secret; i++)
        secret[i] = (uint8_t)(i * 37u); /* NUL and high bytes included */
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        uint8_t b[512];
        size_t n = 0;
        proto_frame f;
        proto_msg m;
        /* written by hand: the writer only writes valid joins */
        b[n++] = 0, b[n++] = 0, b[n++] = 0, b[n++] = 0; /* length, below */
        b[n++] = PROTO_JOIN, b[n++] = 0;
        b[n++] = 3, memcpy(b + n, "ann", 3), n += 3;
        for (int k = 0; k < 3; k++) {
            float one = 1.0f;
            memcpy(b + n, &one, 4), n += 4;
        }
        b[n++] = cases[i].kind, b[n++] = (uint8_t)cases[i].len;
        memcpy(b + n, secret, cases[i].len), n += cases[i].len;
        b[0] = (uint8_t)(n - 4);
        assert_int_equal(proto_frame_parse(b, n, PROTO_MAX_LEN_PREJOIN, &f), PROTO_OK);
        assert_int_equal(proto_decode(&f, &m), cases[i].status);
        if (cases[i].status != PROTO_OK)
            continue;
        assert_int_equal(m.u.join.credential, cases[i].kind);
        assert_int_equal(m.u.join.secret_len, cases[i].len);
        assert_memory_equal(m.u.join.secret, secret, cases[i].len);
        {   /* and the writer writes the same bytes */
            uint8_t again[512];
            proto_writer w;
            proto_writer_init(&w, again, sizeof again);
            proto_put_join(&w, &m.u.join);
            assert_int_equal(w.len, n);
            assert_memory_equal(again, b, n);
        }
    }
    /* the longest join fits before join */
    assert_true(PROTO_SIZE_JOIN_MAX - 4 <= PROTO_MAX_LEN_PREJOIN);
}

static void test_join_ok_roundtrip(void **state)
{
    proto_writer w;
    proto_msg m;
    proto_join_ok in = {.avatar_id = 0xfffffffe, .pos = {-0.0f, FLT_MAX, -FLT_MIN},
                        .box = {0.1f, 4.0f, 2.0f}};

    (void)state;
    proto_writer_init(&w, big, BIG);
    proto_put_join_ok(&w, &in);
    assert_int_equal(w.len, PROTO_SIZE_JOIN_OK);
    decode_all(big, w.len, &m);
    assert_int_equal(m.type, PROTO_JOIN_OK);
    assert_int_equal(m.u.join_ok.avatar_id, in.avatar_id);
    assert_same_floats(m.u.join_ok.pos, in.pos, 3);
    assert_same_floats(m.u.join_ok.box, in.box, 3);
    assert_int_equal(m.u.join_ok.has_token, 0);
    /* an account's join_ok carries its next resume token */
    in.has_token = 1;
    for (unsigned i = 0; i < PROTO_RESUME_TOKEN_SIZE; i++)
        in.token[i] = (uint8_t)(255 - i);
    proto_writer_init(&w, big, BIG);
    proto_put_join_ok(&w, &in);
    assert_int_equal(w.len, PROTO_SIZE_JOIN_OK_MAX);
    decode_all(big, w.len, &m);
    assert_int_equal(m.u.join_ok.has_token, 1);
    assert_memory_equal(m.u.join_ok.token, in.token, PROTO_RESUME_TOKEN_SIZE);
}

static void test_move_roundtrip(void **state)
{
    const float odd[] = {0.0f, -0.0f, FLT_MAX, -FLT_MAX, FLT_MIN, bits_f32(1) /* denormal */,
                         123.456f, -1e-30f};
    (void)state;
    for (size_t i = 0; i < sizeof odd / sizeof odd[0]; i++) {
        proto_writer w;
        proto_msg m;
        const proto_move in = {.seq = (uint32_t)i * 0x10001u + 0xff000000u, .pos = {odd[i], -odd[i], 1.0f}};

        proto_writer_init(&w, big, BIG);
        proto_put_move(&w, &in);
        assert_int_equal(w.len, PROTO_SIZE_MOVE);
        decode_all(big, w.len, &m);
        assert_int_equal(m.type, PROTO_MOVE);
        assert_int_equal(m.u.move.seq, in.seq);
        assert_same_floats(m.u.move.pos, in.pos, 3);
    }
}

/* A pose with the head and both hands: looking a little down, the hands
 * in front of the chest, the right one turned a quarter about y. */
static proto_pose full_pose(void)
{
    proto_pose p = {.yaw = 1.25f, .pitch = -0.5f};
    const float head[3] = {0.0f, 1.7f, 0.0f}, left[3] = {-0.3f, 1.2f, 0.4f}, right[3] = {0.3f, 1.2f, 0.4f};
    const float id[4] = {0, 0, 0, 1}, quarter[4] = {0, 0.70710678f, 0, 0.70710678f};

    proto_pose_set_part(&p, PROTO_POSE_HEAD, head, id);
    proto_pose_set_part(&p, PROTO_POSE_LEFT, left, id);
    proto_pose_set_part(&p, PROTO_POSE_RIGHT, right, quarter);
    return p;
}

static void assert_same_pose(const proto_pose *a, const proto_pose *b)
{
    assert_same_floats(&a->yaw, &b->yaw, 1);
    assert_same_floats(&a->pitch, &b->pitch, 1);
    assert_int_equal(a->parts, b->parts);
    for (unsigned k = 0; k < PROTO_POSE_PARTS; k++) {
        if (!PROTO_POSE_HAS(a, k))
            continue;
        assert_memory_equal(a->pos[k], b->pos[k], sizeof a->pos[k]);
        assert_memory_equal(a->rot[k], b->rot[k], sizeof a->rot[k]);
    }
}

/* A move with a pose of each shape (facing only, head, head and hands)
 * and an avatar pose decode to what was written, at the sizes
 * PROTOCOL.md gives. */
static void test_pose_roundtrip(void **state)
{
    const proto_pose full = full_pose();
    const uint8_t shapes[] = {0, 1, 3, 5, 7};
    (void)state;

    assert_int_equal(full.pos[PROTO_POSE_HEAD][1], 1700);
    assert_int_equal(full.rot[PROTO_POSE_HEAD][3], PROTO_QUAT_ONE);
    assert_int_equal(full.rot[PROTO_POSE_RIGHT][1], 23170);
    assert_int_equal(full.pos[PROTO_POSE_LEFT][0], -300);
    for (size_t i = 0; i < sizeof shapes; i++) {
        proto_writer w;
        proto_msg m;
        proto_move in = {7, {1.0f, 0.0f, 2.0f}, 1, full};
        proto_avatar_pose ap = {0x10002, full};
        size_t parts = (shapes[i] & 1u) + (shapes[i] >> 1 & 1u) + (shapes[i] >> 2 & 1u);

        in.pose.parts = ap.pose.parts = shapes[i];
        proto_writer_init(&w, big, BIG);
        proto_put_move(&w, &in);
        assert_int_equal(w.len, PROTO_SIZE_MOVE + PROTO_POSE_HEAD_SIZE + parts * PROTO_POSE_PART_SIZE);
        decode_all(big, w.len, &m);
        assert_int_equal(m.u.move.seq, 7);
        assert_true(m.u.move.has_pose);
        assert_same_pose(&m.u.move.pose, &in.pose);

        proto_writer_init(&w, big, BIG);
        proto_put_avatar_pose(&w, &ap);
        assert_int_equal(w.len, PROTO_HEADER_SIZE + 4u + PROTO_POSE_HEAD_SIZE + parts * PROTO_POSE_PART_SIZE);
        decode_all(big, w.len, &m);
        assert_int_equal(m.type, PROTO_AVATAR_POSE);
        assert_int_equal(m.u.avatar_pose.id, 0x10002);
        assert_same_pose(&m.u.avatar_pose.pose, &ap.pose);
    }
    /* Without a pose a move is the 16 bytes of version 1. */
    {
        proto_writer w;
        proto_msg m;
        const proto_move in = {8, {1.0f, 0.0f, 2.0f}, 0, full};

        proto_writer_init(&w, big, BIG);
        proto_put_move(&w, &in);
        assert_int_equal(w.len, PROTO_SIZE_MOVE);
        decode_all(big, w.len, &m);
        assert_false(m.u.move.has_pose);
    }
    assert_int_equal(PROTO_SIZE_MOVE_MAX, PROTO_SIZE_MOVE + 51u);
    assert_int_equal(PROTO_SIZE_AVATAR_POSE_MAX, PROTO_HEADER_SIZE + 55u);
    /* A pose one byte short of room is not written at all. */
    {
        proto_writer w;
        const proto_avatar_pose ap = {3, full};

        proto_writer_init(&w, big, PROTO_SIZE_AVATAR_POSE_MAX - 1);
        proto_put_avatar_pose(&w, &ap);
        assert_int_equal(w.err, PROTO_ERR_FRAME_TOO_LONG);
        assert_int_equal(w.len, 0);
    }
}

/* Quantizing normalises the quaternion, rounds to the millimetre,
 * saturates out-of-range positions and keeps NaN harmless. */
static void test_pose_quantize(void **state)
{
    proto_pose p = {0};
    const float at[3] = {0.0014f, -0.0016f, 100.0f}, q[4] = {0, 0, 0, 2}, zero[4] = {0, 0, 0, 0};
    const float nan_at[3] = {bits_f32(0x7fc00000u), 0, -100.0f};
    (void)state;

    proto_pose_set_part(&p, PROTO_POSE_LEFT, at, q);
    assert_int_equal(p.parts, 2);
    assert_int_equal(p.pos[1][0], 1);
    assert_int_equal(p.pos[1][1], -2);
    assert_int_equal(p.pos[1][2], 32767);
    assert_int_equal(p.rot[1][3], PROTO_QUAT_ONE);
    proto_pose_set_part(&p, PROTO_POSE_HEAD, nan_at, zero);
    assert_int_equal(p.parts, 3);
    assert_int_equal(p.pos[0][0], 0);
    assert_int_equal(p.pos[0][2], -32768);
    assert_int_equal(p.rot[0][3], PROTO_QUAT_ONE); /* no direction: the identity */
}

/* The pose's bytes inside a payload, for the refusals: move tail at 16,
 * avatar pose at 4. */
static size_t pose_payload(uint16_t type, const proto_pose *pose, uint8_t *out)
{
    proto_writer w;
    proto_writer_init(&w, big, BIG);
    if (type == PROTO_MOVE)
        proto_put_move(&w, &(proto_move){1, {0, 0, 0}, 1, *pose});
    else
        proto_put_avatar_pose(&w, &(proto_avatar_pose){9, *pose});
    assert_int_equal(w.err, PROTO_OK);
    memcpy(out, big + PROTO_HEADER_SIZE, w.len - PROTO_HEADER_SIZE);
    return w.len - PROTO_HEADER_SIZE;
}

static void wr_i16(uint8_t *p, int v) { wr_u16(p, (uint16_t)(int16_t)v); }

/* Every refusal of a pose, in a move and in an avatar pose alike: a NaN
 * or infinite facing, a pitch past straight up or down, unknown part
 * bits, hands without the head, the head out of range, a hand out of
 * reach, a quaternion too far from unit length; and every cut is short,
 * every extra byte trailing. */
static void test_pose_refusals(void **state)
{
    const uint16_t types[] = {PROTO_MOVE, PROTO_AVATAR_POSE};
    const proto_pose full = full_pose();
    (void)state;

    for (size_t t = 0; t < 2; t++) {
        uint8_t p[128], q[128];
        size_t n = pose_payload(types[t], &full, p);
        size_t at = types[t] == PROTO_MOVE ? 16 : 4; /* yaw */
        size_t head = at + PROTO_POSE_HEAD_SIZE, left = head + PROTO_POSE_PART_SIZE;
        size_t right = left + PROTO_POSE_PART_SIZE;

        assert_int_equal(decode_raw(types[t], p, n), PROTO_OK);
        for (size_t cut = types[t] == PROTO_MOVE ? 17 : 0; cut < n; cut++)
            assert_int_equal(decode_raw(types[t], p, cut), PROTO_ERR_SHORT);
        memcpy(q, p, n);
        q[n] = 0;
        assert_int_equal(decode_raw(types[t], q, n + 1), PROTO_ERR_TRAILING);
#define TRY(want, edit)                                            \
    do {                                                           \
        memcpy(q, p, n);                                           \
        edit;                                                      \
        assert_int_equal(decode_raw(types[t], q, n), (want));      \
    } while (0)
        TRY(PROTO_ERR_NOT_FINITE, wr_u32(q + at, 0x7fc00000u));
        TRY(PROTO_ERR_NOT_FINITE, wr_u32(q + at + 4, 0xff800000u));
        TRY(PROTO_OK, wr_f32(q + at + 4, PROTO_PITCH_MAX));
        TRY(PROTO_OK, wr_f32(q + at + 4, -PROTO_PITCH_MAX));
        TRY(PROTO_ERR_BAD_VALUE, wr_f32(q + at + 4, 1.5708f));
        TRY(PROTO_ERR_BAD_VALUE, wr_f32(q + at + 4, -1.6f));
        TRY(PROTO_ERR_BAD_VALUE, q[at + 8] = 0x0f);
        TRY(PROTO_ERR_BAD_VALUE, q[at + 8] = 0x87);
        /* Hands without the head: refused at the parts byte. */
        TRY(PROTO_ERR_BAD_VALUE, q[at + 8] = 6);
        TRY(PROTO_ERR_BAD_VALUE, q[at + 8] = 2);
        TRY(PROTO_OK, (wr_i16(q + head, PROTO_POSE_HEAD_RANGE_MM), wr_i16(q + left, PROTO_POSE_HEAD_RANGE_MM - 300),
                       wr_i16(q + right, PROTO_POSE_HEAD_RANGE_MM + 300)));
        TRY(PROTO_ERR_BAD_VALUE, wr_i16(q + head + 2, PROTO_POSE_HEAD_RANGE_MM + 1));
        TRY(PROTO_ERR_BAD_VALUE, wr_i16(q + head + 4, -PROTO_POSE_HEAD_RANGE_MM - 1));
        /* Reach is measured from the head (0, 1700, 0): 1500 mm is in. */
        TRY(PROTO_OK, (wr_i16(q + left, 0), wr_i16(q + left + 2, 200), wr_i16(q + left + 4, 0)));
        TRY(PROTO_ERR_BAD_VALUE, (wr_i16(q + left, 0), wr_i16(q + left + 2, 199), wr_i16(q + left + 4, 0)));
        TRY(PROTO_ERR_BAD_VALUE, (wr_i16(q + right, 1100), wr_i16(q + right + 2, 2800), wr_i16(q + right + 4, 0)));
        /* Quaternions: a little off unit length is rounding, far off is not
         * a rotation; each part's is checked. */
        TRY(PROTO_OK, wr_i16(q + head + 12, 32767 - 300));
        TRY(PROTO_ERR_BAD_VALUE, wr_i16(q + head + 12, 32767 - 400));
        TRY(PROTO_ERR_BAD_VALUE, wr_i16(q + left + 12, 0));
        TRY(PROTO_ERR_BAD_VALUE, (wr_i16(q + right + 6, 32767), wr_i16(q + right + 12, 32767)));
        /* First failure wins: a bad pitch before a bad quaternion. */
        TRY(PROTO_ERR_BAD_VALUE, (wr_f32(q + at + 4, 3.0f), wr_i16(q + head + 12, 0)));
        TRY(PROTO_ERR_NOT_FINITE, (wr_u32(q + at, 0x7f800000u), q[at + 8] = 0xff));
#undef TRY
    }
}

/* Writes a snapshot of n entries (ids and positions derived from the index)
 * and checks every field after decoding. */
static void snapshot_roundtrip(uint32_t n)
{
    proto_writer w;
    proto_msg m;
    size_t at;

    proto_writer_init(&w, big, BIG);
    at = proto_put_snapshot_begin(&w, 0xdeadbeef, 0xfeedface);
    assert_int_equal(at, 0);
    for (uint32_t i = 0; i < n; i++) {
        const proto_avatar a = {i * 3u + 1u, {(float)i, -(float)i, (float)i * 0.5f}};
        proto_put_snapshot_add(&w, at, &a);
    }
    proto_put_snapshot_end(&w, at);
    assert_int_equal(w.err, PROTO_OK);
    assert_int_equal(w.len, PROTO_SIZE_SNAPSHOT(n));
    decode_all(big, w.len, &m);
    assert_int_equal(m.type, PROTO_SNAPSHOT);
    assert_int_equal(m.u.snapshot.tick, 0xdeadbeef);
    assert_int_equal(m.u.snapshot.ack_seq, 0xfeedface);
    assert_int_equal(m.u.snapshot.count, n);
    for (uint16_t i = 0; i < m.u.snapshot.count; i++) {
        proto_avatar got;
        const float want[3] = {(float)i, -(float)i, (float)i * 0.5f};

        proto_snapshot_entry(&m.u.snapshot, i, &got);
        assert_int_equal(got.id, (uint32_t)i * 3u + 1u);
        assert_same_floats(got.pos, want, 3);
    }
}

static void test_snapshot_empty(void **state)
{
    (void)state;
    snapshot_roundtrip(0);
}

static void test_snapshot_one(void **state)
{
    (void)state;
    snapshot_roundtrip(1);
}

static void test_snapshot_many(void **state)
{
    (void)state;
    snapshot_roundtrip(300);
}

/* The writer holds exactly PROTO_SNAPSHOT_MAX_ENTRIES, the frame then fits
 * the joined cap, and one entry more drops the whole snapshot. */
static void test_snapshot_max_entries(void **state)
{
    proto_writer w;
    proto_frame f;
    size_t at;
    const proto_avatar a = {1, {0.0f, 0.0f, 0.0f}};

    (void)state;
    snapshot_roundtrip(PROTO_SNAPSHOT_MAX_ENTRIES);
    assert_int_equal(proto_frame_parse(big, BIG, PROTO_MAX_LEN, &f), PROTO_OK);
    assert_true(f.size - 4 <= PROTO_MAX_LEN);
    assert_true(f.size - 4 + PROTO_SNAPSHOT_ENTRY_SIZE > PROTO_MAX_LEN);

    proto_writer_init(&w, big, BIG);
    proto_put_ping(&w, 9);
    at = proto_put_snapshot_begin(&w, 1, 2);
    assert_int_equal(at, PROTO_SIZE_PING);
    for (uint32_t i = 0; i < PROTO_SNAPSHOT_MAX_ENTRIES; i++)
        proto_put_snapshot_add(&w, at, &a);
    assert_int_equal(w.err, PROTO_OK);
    proto_put_snapshot_add(&w, at, &a);
    assert_int_equal(w.err, PROTO_ERR_FRAME_TOO_LONG);
    assert_int_equal(w.len, at);
    proto_put_snapshot_end(&w, at);
    assert_int_equal(w.len, at);
    assert_int_equal(proto_frame_parse(big, w.len, PROTO_MAX_LEN, &f), PROTO_OK);
    assert_int_equal(f.type, PROTO_PING);
    assert_int_equal(f.size, w.len);
}

static void test_avatar_joined_roundtrip(void **state)
{
    proto_writer w;
    proto_msg m;
    const proto_avatar_joined in = {77, {"Zoë", 4}, {1.5f, -0.0f, 3.25f}, {0.6f, 1.7f, 0.4f}};

    (void)state;
    proto_writer_init(&w, big, BIG);
    proto_put_avatar_joined(&w, &in);
    assert_int_equal(w.len, PROTO_HEADER_SIZE + 4 + 1 + 4 + 24);
    decode_all(big, w.len, &m);
    assert_int_equal(m.type, PROTO_AVATAR_JOINED);
    assert_int_equal(m.u.avatar_joined.id, 77);
    assert_str(m.u.avatar_joined.name, "Zoë", 4);
    assert_same_floats(m.u.avatar_joined.pos, in.pos, 3);
    assert_same_floats(m.u.avatar_joined.box, in.box, 3);
}

static void test_avatar_left_roundtrip(void **state)
{
    (void)state;
    for (uint8_t reason = 0; reason <= PROTO_LEFT_DISCONNECTED; reason++) {
        proto_writer w;
        proto_msg m;
        const proto_avatar_left in = {0xffffffff, reason};

        proto_writer_init(&w, big, BIG);
        proto_put_avatar_left(&w, &in);
        assert_int_equal(w.len, PROTO_SIZE_AVATAR_LEFT);
        decode_all(big, w.len, &m);
        assert_int_equal(m.type, PROTO_AVATAR_LEFT);
        assert_int_equal(m.u.avatar_left.id, 0xffffffff);
        assert_int_equal(m.u.avatar_left.reason, reason);
    }
}

static void test_error_roundtrip(void **state)
{
    static const char *texts[] = {"", "move sequence did not increase", "name “Zoë” taken"};
    (void)state;
    for (size_t i = 0; i < sizeof texts / sizeof texts[0]; i++) {
        proto_writer w;
        proto_msg m;
        const uint16_t code = (uint16_t)(PROTO_ERR_FRAME_EMPTY + i * 1000);

        proto_writer_init(&w, big, BIG);
        proto_put_error(&w, code, texts[i]);
        assert_int_equal(w.len, PROTO_HEADER_SIZE + 3 + strlen(texts[i]));
        decode_all(big, w.len, &m);
        assert_int_equal(m.type, PROTO_ERROR);
        assert_int_equal(m.u.error.code, code);
        assert_str(m.u.error.message, texts[i], strlen(texts[i]));
    }
}

static void test_ping_pong_roundtrip(void **state)
{
    const uint64_t stamps[] = {0, 1, 0x8000000000000000u, UINT64_MAX};

    (void)state;
    for (size_t i = 0; i < 4; i++) {
        proto_writer w;
        proto_msg m;

        proto_writer_init(&w, big, BIG);
        proto_put_ping(&w, stamps[i]);
        proto_put_pong(&w, stamps[i]);
        assert_int_equal(w.len, 2 * PROTO_SIZE_PING);
        decode_all(big, PROTO_SIZE_PING, &m);
        assert_int_equal(m.type, PROTO_PING);
        assert_true(m.u.ping.stamp == stamps[i]);
        decode_all(big + PROTO_SIZE_PING, PROTO_SIZE_PING, &m);
        assert_int_equal(m.type, PROTO_PONG);
        assert_true(m.u.ping.stamp == stamps[i]);
    }
}

static void test_bye_roundtrip(void **state)
{
    (void)state;
    for (uint8_t reason = 0; reason <= PROTO_BYE_KICKED; reason++) {
        proto_writer w;
        proto_msg m;

        proto_writer_init(&w, big, BIG);
        proto_put_bye(&w, reason);
        assert_int_equal(w.len, PROTO_SIZE_BYE);
        decode_all(big, w.len, &m);
        assert_int_equal(m.type, PROTO_BYE);
        assert_int_equal(m.u.bye.reason, reason);
    }
}

static void test_upload_begin_roundtrip(void **state)
{
    static const struct {
        const char *name, *format;
        uint8_t up_axis;
        float unit_scale;
        uint32_t id, size;
    } cases[] = {
        {"a", "", PROTO_UP_Y, PROTO_SCALE_MIN, 1, 1},
        {"chair.obj", "obj", PROTO_UP_Z, 0.01f, 0xffffffffu, 16u * 1024u * 1024u},
        {"Zoë's \xf0\x9f\x98\x80 lamp", "glb", PROTO_UP_Y, PROTO_SCALE_MAX, 0x80000000u, 0xffffffffu},
        {"abcdefghijklmnopqrstuvwxyz0123456789ABCDEFGHIJKLMNOPQRSTUVWXYZ-_", /* 64 bytes */
         "12345678", PROTO_UP_Z, 1.0f, 7, 12345},
    };
    (void)state;
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        proto_writer w;
        proto_msg m;
        const size_t nn = strlen(cases[i].name), nf = strlen(cases[i].format);
        const proto_upload_begin in = {cases[i].id, cases[i].size, {cases[i].name, (uint32_t)nn},
                                       {cases[i].format, (uint32_t)nf}, cases[i].up_axis,
                                       cases[i].unit_scale};

        assert_true(nn <= PROTO_OBJECT_NAME_MAX && nf <= PROTO_FORMAT_MAX);
        proto_writer_init(&w, big, BIG);
        proto_put_upload_begin(&w, &in);
        assert_int_equal(w.err, PROTO_OK);
        assert_int_equal(w.len, PROTO_HEADER_SIZE + 15 + nn + nf);
        decode_all(big, w.len, &m);
        assert_int_equal(m.type, PROTO_OBJECT_UPLOAD_BEGIN);
        assert_int_equal(m.u.upload_begin.upload_id, in.upload_id);
        assert_int_equal(m.u.upload_begin.total_size, in.total_size);
        assert_str(m.u.upload_begin.name, cases[i].name, nn);
        assert_ptr_equal(m.u.upload_begin.name.ptr, (const char *)big + PROTO_HEADER_SIZE + 9);
        assert_str(m.u.upload_begin.format, cases[i].format, nf);
        assert_int_equal(m.u.upload_begin.up_axis, in.up_axis);
        assert_same_floats(&m.u.upload_begin.unit_scale, &in.unit_scale, 1);
    }
}

/* A chunk of 1 byte, of PROTO_CHUNK_MAX bytes and in between; the data is
 * the rest of the frame, not the rest of the buffer, so chunks back to back
 * decode one by one. */
static void test_upload_chunk_roundtrip(void **state)
{
    static uint8_t data[PROTO_CHUNK_MAX];
    const uint32_t lens[] = {1, 2, 1000, PROTO_CHUNK_MAX - 1, PROTO_CHUNK_MAX};
    proto_writer w;
    proto_msg m;
    size_t off = 0;

    (void)state;
    for (size_t i = 0; i < sizeof data; i++)
        data[i] = (uint8_t)(i * 7u + 3u);
    proto_writer_init(&w, big, BIG);
    for (size_t i = 0; i < sizeof lens / sizeof lens[0]; i++) {
        const proto_upload_chunk in = {(uint32_t)i + 1u, (uint32_t)i * 0x01010101u, data, lens[i]};
        proto_put_upload_chunk(&w, &in);
    }
    assert_int_equal(w.err, PROTO_OK);
    for (size_t i = 0; i < sizeof lens / sizeof lens[0]; i++) {
        const size_t size = PROTO_HEADER_SIZE + 8 + lens[i];

        decode_all(big + off, size, &m);
        assert_int_equal(m.type, PROTO_OBJECT_UPLOAD_CHUNK);
        assert_int_equal(m.u.upload_chunk.upload_id, i + 1);
        assert_int_equal(m.u.upload_chunk.offset, (uint32_t)i * 0x01010101u);
        assert_int_equal(m.u.upload_chunk.len, lens[i]);
        assert_ptr_equal(m.u.upload_chunk.data, big + off + PROTO_HEADER_SIZE + 8);
        assert_memory_equal(m.u.upload_chunk.data, data, lens[i]);
        off += size;
    }
    assert_int_equal(off, w.len);
    /* The largest chunk fits the joined cap with room to spare. */
    assert_true(2u + 8u + PROTO_CHUNK_MAX <= PROTO_MAX_LEN);
}

static const proto_transform odd_transforms[] = {
    {{0.0f, 0.0f, 0.0f}, 0.0f, 1.0f},
    {{-0.0f, FLT_MAX, -FLT_MAX}, -0.0f, PROTO_SCALE_MIN},
    {{FLT_MIN, -1e-30f, 12345.678f}, 3.14159265f, PROTO_SCALE_MAX},
    {{1.0f, 2.0f, 3.0f}, -1e30f /* any finite yaw */, 0.5f},
    {{-4096.0f, 0.25f, 8.0f}, FLT_MAX, 999.0f},
};

static void test_upload_end_roundtrip(void **state)
{
    (void)state;
    for (size_t i = 0; i < sizeof odd_transforms / sizeof odd_transforms[0]; i++) {
        proto_writer w;
        proto_msg m;
        const proto_upload_end in = {(uint32_t)(0xfffffff0u + i), odd_transforms[i]};

        proto_writer_init(&w, big, BIG);
        proto_put_upload_end(&w, &in);
        assert_int_equal(w.len, PROTO_HEADER_SIZE + 4 + PROTO_SIZE_TRANSFORM);
        decode_all(big, w.len, &m);
        assert_int_equal(m.type, PROTO_OBJECT_UPLOAD_END);
        assert_int_equal(m.u.upload_end.upload_id, in.upload_id);
        assert_same_floats(m.u.upload_end.at.pos, in.at.pos, 3);
        assert_same_floats(&m.u.upload_end.at.yaw, &in.at.yaw, 1);
        assert_same_floats(&m.u.upload_end.at.scale, &in.at.scale, 1);
    }
}

static void test_object_place_roundtrip(void **state)
{
    (void)state;
    for (size_t i = 0; i < sizeof odd_transforms / sizeof odd_transforms[0]; i++) {
        proto_writer w;
        proto_msg m;
        const proto_object_place in = {(uint32_t)(1u + i * 0x10000u), odd_transforms[i]};

        proto_writer_init(&w, big, BIG);
        proto_put_object_place(&w, &in);
        assert_int_equal(w.len, PROTO_HEADER_SIZE + 4 + PROTO_SIZE_TRANSFORM);
        decode_all(big, w.len, &m);
        assert_int_equal(m.type, PROTO_OBJECT_PLACE);
        assert_int_equal(m.u.object_place.object_id, in.object_id);
        assert_same_floats(m.u.object_place.at.pos, in.at.pos, 3);
        assert_same_floats(&m.u.object_place.at.yaw, &in.at.yaw, 1);
        assert_same_floats(&m.u.object_place.at.scale, &in.at.scale, 1);
    }
}

static void test_object_remove_roundtrip(void **state)
{
    const uint32_t ids[] = {1, 2, 0x80000000u, UINT32_MAX};

    (void)state;
    for (size_t i = 0; i < sizeof ids / sizeof ids[0]; i++) {
        proto_writer w;
        proto_msg m;

        proto_writer_init(&w, big, BIG);
        proto_put_object_remove(&w, ids[i]);
        proto_put_object_removed(&w, ids[i]);
        assert_int_equal(w.err, PROTO_OK);
        assert_int_equal(w.len, 2 * PROTO_SIZE_OBJECT_REMOVED);
        decode_all(big, PROTO_SIZE_OBJECT_REMOVED, &m);
        assert_int_equal(m.type, PROTO_OBJECT_REMOVE);
        assert_int_equal(m.u.object_id, ids[i]);
        decode_all(big + PROTO_SIZE_OBJECT_REMOVED, PROTO_SIZE_OBJECT_REMOVED, &m);
        assert_int_equal(m.type, PROTO_OBJECT_REMOVED);
        assert_int_equal(m.u.object_id, ids[i]);
    }
}

/* Writes an object info with n boxes (derived from the index), the given
 * owner and name, decodes it and checks every field and every box. With
 * n == 0 the box arrays are NULL: the writer must not read them. */
static void object_info_roundtrip(uint16_t n, const char *owner, const char *name, uint32_t upload_id)
{
    static float mn[PROTO_OBJECT_BOXES_MAX][3], mx[PROTO_OBJECT_BOXES_MAX][3];
    const size_t no = strlen(owner), nn = strlen(name);
    const proto_object_info in = {0xfffffffeu, upload_id, {owner, (uint32_t)no}, {name, (uint32_t)nn},
                                  {{1.0f, -0.0f, -2.5f}, -3.0f, PROTO_SCALE_MAX}, 7, UINT32_MAX,
                                  {1, 2, 3, [PROTO_MESH_HASH_SIZE - 1] = 0xff}, n, NULL};
    proto_writer w;
    proto_msg m;

    for (uint16_t i = 0; i < n; i++) {
        mn[i][0] = (float)i;
        mn[i][1] = -(float)i;
        mn[i][2] = (float)i * 0.5f - 3.0f;
        mx[i][0] = mn[i][0] + 1.0f;
        mx[i][1] = mn[i][1]; /* a flat box */
        mx[i][2] = mn[i][2] + 2.5f;
    }
    if (n > 0) {
        mn[0][0] = 0.0f; /* 0.0 <= -0.0: both bit patterns survive */
        mx[0][0] = -0.0f;
    }
    proto_writer_init(&w, big, BIG);
    proto_put_object_info(&w, &in, n ? (const float (*)[3])mn : NULL, n ? (const float (*)[3])mx : NULL);
    assert_int_equal(w.err, PROTO_OK);
    assert_int_equal(w.len, PROTO_HEADER_SIZE + 72 + no + nn + (size_t)n * PROTO_BOX_ENTRY_SIZE);
    decode_all(big, w.len, &m);
    assert_int_equal(m.type, PROTO_OBJECT_INFO);
    assert_int_equal(m.u.object_info.object_id, in.object_id);
    assert_int_equal(m.u.object_info.upload_id, upload_id);
    assert_str(m.u.object_info.owner, owner, no);
    assert_ptr_equal(m.u.object_info.owner.ptr, (const char *)big + PROTO_HEADER_SIZE + 9);
    assert_str(m.u.object_info.name, name, nn);
    assert_same_floats(m.u.object_info.at.pos, in.at.pos, 3);
    assert_same_floats(&m.u.object_info.at.yaw, &in.at.yaw, 1);
    assert_same_floats(&m.u.object_info.at.scale, &in.at.scale, 1);
    assert_int_equal(m.u.object_info.ecm_version, 7);
    assert_int_equal(m.u.object_info.tri_count, UINT32_MAX);
    assert_memory_equal(m.u.object_info.mesh_hash, in.mesh_hash, PROTO_MESH_HASH_SIZE);
    assert_int_equal(m.u.object_info.box_count, n);
    assert_ptr_equal(m.u.object_info.boxes, big + PROTO_HEADER_SIZE + 72 + no + nn);
    for (uint16_t i = 0; i < m.u.object_info.box_count; i++) {
        float lo[3], hi[3];

        proto_object_box(&m.u.object_info, i, lo, hi);
        assert_same_floats(lo, mn[i], 3);
        assert_same_floats(hi, mx[i], 3);
    }
}

static void test_object_info_no_boxes(void **state)
{
    (void)state;
    object_info_roundtrip(0, "a", "b", 0);
}

static void test_object_info_one_box(void **state)
{
    (void)state;
    object_info_roundtrip(1, "Zoë", "chair.obj", 42);
}

/* The most boxes with the longest strings: exactly PROTO_SIZE_OBJECT_INFO,
 * and within the joined cap. */
static void test_object_info_max_boxes(void **state)
{
    char owner[PROTO_NAME_MAX + 1], name[PROTO_OBJECT_NAME_MAX + 1];

    (void)state;
    memset(owner, 'o', PROTO_NAME_MAX);
    owner[PROTO_NAME_MAX] = 0;
    memset(name, 'n', PROTO_OBJECT_NAME_MAX);
    name[PROTO_OBJECT_NAME_MAX] = 0;
    object_info_roundtrip(PROTO_OBJECT_BOXES_MAX, owner, name, UINT32_MAX);
    assert_int_equal(PROTO_SIZE_OBJECT_INFO(PROTO_OBJECT_BOXES_MAX),
                     PROTO_HEADER_SIZE + 72 + PROTO_NAME_MAX + PROTO_OBJECT_NAME_MAX +
                         PROTO_OBJECT_BOXES_MAX * PROTO_BOX_ENTRY_SIZE);
    assert_true(PROTO_SIZE_OBJECT_INFO(PROTO_OBJECT_BOXES_MAX) - 4 <= PROTO_MAX_LEN);
}

static void test_object_rejected_roundtrip(void **state)
{
    static const struct {
        uint32_t request_id;
        uint16_t code;
        const char *text;
    } cases[] = {
        {0, PROTO_ERR_FRAME_EMPTY, ""},
        {5, PROTO_ERR_UPLOAD, "upload 5: 20000000 bytes over the cap of 16777216"},
        {5, PROTO_ERR_IMPORT, "obj: line 3: no vertices"},
        {9, PROTO_ERR_NO_OBJECT, "no object 9"},
        {UINT32_MAX, PROTO_ERR_NOT_OWNER, "object “chair” belongs to Zoë"},
        {1, 0xffff, "a code from a later version"},
    };
    (void)state;
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        proto_writer w;
        proto_msg m;
        const size_t n = strlen(cases[i].text);

        proto_writer_init(&w, big, BIG);
        proto_put_object_rejected(&w, cases[i].request_id, cases[i].code, cases[i].text);
        assert_int_equal(w.len, PROTO_HEADER_SIZE + 7 + n);
        decode_all(big, w.len, &m);
        assert_int_equal(m.type, PROTO_OBJECT_REJECTED);
        assert_int_equal(m.u.object_rejected.request_id, cases[i].request_id);
        assert_int_equal(m.u.object_rejected.code, cases[i].code);
        assert_str(m.u.object_rejected.message, cases[i].text, n);
    }
}

static void test_collision_roundtrip(void **state)
{
    (void)state;
    for (uint8_t inside = 0; inside <= 1; inside++) {
        proto_writer w;
        proto_msg m;
        const proto_collision in = {inside ? UINT32_MAX : 1u, inside ? 1u : UINT32_MAX,
                                    inside ? (uint16_t)0xffff : (uint16_t)0, inside,
                                    {-0.0f, FLT_MAX, bits_f32(1)}, {0.0f, 1.0f, -0.0f}};

        proto_writer_init(&w, big, BIG);
        proto_put_collision(&w, &in);
        assert_int_equal(w.len, PROTO_SIZE_COLLISION);
        decode_all(big, w.len, &m);
        assert_int_equal(m.type, PROTO_COLLISION);
        assert_int_equal(m.u.collision.object_id, in.object_id);
        assert_int_equal(m.u.collision.ecm_version, in.ecm_version);
        assert_int_equal(m.u.collision.box_index, in.box_index);
        assert_int_equal(m.u.collision.inside, inside);
        assert_same_floats(m.u.collision.point, in.point, 3);
        assert_same_floats(m.u.collision.normal, in.normal, 3);
    }
}

/* The *_MAX size macros are what the largest strings produce. */
static void test_max_sizes(void **state)
{
    char name[PROTO_NAME_MAX + 1], text[PROTO_MESSAGE_MAX + 1];
    static const uint8_t password[PROTO_PASSWORD_MAX];
    proto_writer w;
    const proto_join join = {.name = {name, PROTO_NAME_MAX}, .box = {1, 1, 1}, .credential = PROTO_CRED_PASSWORD,
                             .secret = password, .secret_len = PROTO_PASSWORD_MAX};
    const proto_avatar_joined aj = {1, {name, PROTO_NAME_MAX}, {0, 0, 0}, {1, 1, 1}};

    (void)state;
    memset(name, 'n', sizeof name);
    memset(text, 't', PROTO_MESSAGE_MAX);
    text[PROTO_MESSAGE_MAX] = 0;
    proto_writer_init(&w, big, BIG);
    proto_put_join(&w, &join);
    assert_int_equal(w.len, PROTO_SIZE_JOIN_MAX);
    assert_true(w.len - 4 <= PROTO_MAX_LEN_PREJOIN);
    proto_writer_init(&w, big, BIG);
    proto_put_avatar_joined(&w, &aj);
    assert_int_equal(w.len, PROTO_SIZE_AVATAR_JOINED_MAX);
    proto_writer_init(&w, big, BIG);
    proto_put_error(&w, PROTO_ERR_INTERNAL, text);
    assert_int_equal(w.len, PROTO_SIZE_ERROR_MAX);
    proto_writer_init(&w, big, BIG);
    proto_put_object_rejected(&w, 1, PROTO_ERR_IMPORT, text);
    assert_int_equal(w.len, PROTO_SIZE_OBJECT_REJECTED_MAX);
}

/* Object names are cut at PROTO_OBJECT_NAME_MAX bytes, owners at
 * PROTO_NAME_MAX and formats at PROTO_FORMAT_MAX, never inside a character,
 * and object_rejected texts are cleaned like error texts. */
static void test_object_string_truncation(void **state)
{
    static const struct {
        const char *in;
        size_t want;
    } names[] = {
        {"0123456789012345678901234567890123456789012345678901234567890123456789", 64},
        {"012345678901234567890123456789012345678901234567890123456789012\xc3\xa9", 63},
        {"01234567890123456789012345678901234567890123456789012345678901\xf0\x9f\x98\x80", 62},
        {"0123456789012345678901234567890123456789012345678901234567890\xe2\x82\xac", 64}, /* ends at 64 */
    }, formats[] = {
        {"abcdefghij", 8},
        {"abcdefg\xc3\xa9", 7}, /* the cut leaves a format that decodes */
        {"abcdefgh\xc3\xa9", 8},
    }, owners[] = {
        {"abcdefghijklmnopqrstuvwxyz0123456789", 32},
        {"abcdefghijklmnopqrstuvwxyz0123\xf0\x9f\x98\x80", 30},
    };
    char text[300], want[300];
    proto_writer w;
    proto_msg m;

    (void)state;
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++) {
        const proto_upload_begin ub = {1, 1, {names[i].in, (uint32_t)strlen(names[i].in)}, {"obj", 3},
                                       PROTO_UP_Y, 1.0f};
        const proto_object_info oi = {1, 0, {"ann", 3}, {names[i].in, (uint32_t)strlen(names[i].in)},
                                      {{0, 0, 0}, 0, 1}, 1, 0, {0}, 0, NULL};

        proto_writer_init(&w, big, BIG);
        proto_put_upload_begin(&w, &ub);
        decode_all(big, w.len, &m);
        assert_str(m.u.upload_begin.name, names[i].in, names[i].want);
        assert_str(m.u.upload_begin.format, "obj", 3);
        proto_writer_init(&w, big, BIG);
        proto_put_object_info(&w, &oi, NULL, NULL);
        decode_all(big, w.len, &m);
        assert_str(m.u.object_info.name, names[i].in, names[i].want);
    }
    for (size_t i = 0; i < sizeof formats / sizeof formats[0]; i++) {
        const proto_upload_begin ub = {1, 1, {"x", 1}, {formats[i].in, (uint32_t)strlen(formats[i].in)},
                                       PROTO_UP_Y, 1.0f};

        proto_writer_init(&w, big, BIG);
        proto_put_upload_begin(&w, &ub);
        decode_all(big, w.len, &m);
        assert_str(m.u.upload_begin.format, formats[i].in, formats[i].want);
    }
    for (size_t i = 0; i < sizeof owners / sizeof owners[0]; i++) {
        const proto_object_info oi = {1, 0, {owners[i].in, (uint32_t)strlen(owners[i].in)}, {"x", 1},
                                      {{0, 0, 0}, 0, 1}, 1, 0, {0}, 0, NULL};

        proto_writer_init(&w, big, BIG);
        proto_put_object_info(&w, &oi, NULL, NULL);
        decode_all(big, w.len, &m);
        assert_str(m.u.object_info.owner, owners[i].in, owners[i].want);
    }

    memset(text, 'x', 250);
    text[250] = 0;
    proto_writer_init(&w, big, BIG);
    proto_put_object_rejected(&w, 3, PROTO_ERR_IMPORT, text);
    decode_all(big, w.len, &m);
    assert_str(m.u.object_rejected.message, text, PROTO_MESSAGE_MAX);
    proto_writer_init(&w, big, BIG);
    proto_put_object_rejected(&w, 3, PROTO_ERR_IMPORT, "line 1:\n\x7f\xff bad \xc3(");
    decode_all(big, w.len, &m);
    strcpy(want, "line 1:??? bad ?(");
    assert_str(m.u.object_rejected.message, want, strlen(want));
}

/* Names are cut at PROTO_NAME_MAX bytes, never inside a character. */
static void test_name_truncation(void **state)
{
    static const struct {
        const char *in;
        size_t want;
    } cases[] = {
        {"abcdefghijklmnopqrstuvwxyz0123456789", 32},
        {"abcdefghijklmnopqrstuvwxyz01234\xc3\xa9", 31},      /* é straddles 32 */
        {"abcdefghijklmnopqrstuvwxyz0123\xf0\x9f\x98\x80", 30}, /* 4-byte char */
        {"abcdefghijklmnopqrstuvwxyz012\xe2\x82\xac", 32},     /* € ends at 32 */
    };
    (void)state;
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        proto_writer w;
        proto_msg m;
        const proto_join join = {.name = {cases[i].in, (uint32_t)strlen(cases[i].in)}, .box = {1, 1, 1}};
        const proto_avatar_joined aj = {3, {cases[i].in, (uint32_t)strlen(cases[i].in)},
                                        {0, 0, 0}, {1, 1, 1}};

        proto_writer_init(&w, big, BIG);
        proto_put_join(&w, &join);
        decode_all(big, w.len, &m);
        assert_str(m.u.join.name, cases[i].in, cases[i].want);
        proto_writer_init(&w, big, BIG);
        proto_put_avatar_joined(&w, &aj);
        decode_all(big, w.len, &m);
        assert_str(m.u.avatar_joined.name, cases[i].in, cases[i].want);
    }
}

/* Error texts are cut at PROTO_MESSAGE_MAX on a character boundary, and
 * bytes the decoder would refuse become '?', so the frame always decodes. */
static void test_error_message_cleaning(void **state)
{
    char in[400], want[400];
    proto_writer w;
    proto_msg m;

    (void)state;
    memset(in, 'x', 250);
    in[250] = 0;
    proto_writer_init(&w, big, BIG);
    proto_put_error(&w, PROTO_ERR_INTERNAL, in);
    decode_all(big, w.len, &m);
    assert_str(m.u.error.message, in, PROTO_MESSAGE_MAX);

    memset(in, 'x', 199);
    strcpy(in + 199, "\xe2\x82\xac tail"); /* € would end at byte 202 */
    proto_writer_init(&w, big, BIG);
    proto_put_error(&w, PROTO_ERR_INTERNAL, in);
    decode_all(big, w.len, &m);
    assert_str(m.u.error.message, in, 199);

    memset(in, 'x', 199);
    strcpy(in + 199, "\xffyz"); /* a replacement still fits at 199 */
    proto_writer_init(&w, big, BIG);
    proto_put_error(&w, PROTO_ERR_INTERNAL, in);
    decode_all(big, w.len, &m);
    memcpy(want, in, 199);
    want[199] = '?';
    assert_str(m.u.error.message, want, 200);

    memset(in, 'x', 200);
    strcpy(in + 200, "\xff"); /* a replacement past the limit is dropped too */
    proto_writer_init(&w, big, BIG);
    proto_put_error(&w, PROTO_ERR_INTERNAL, in);
    decode_all(big, w.len, &m);
    assert_str(m.u.error.message, in, 200);

    proto_writer_init(&w, big, BIG);
    proto_put_error(&w, PROTO_ERR_BAD_STRING, "bad name \"a\nb\" \x7f\xc3(\xed\xa0\x80 ok é");
    decode_all(big, w.len, &m);
    strcpy(want, "bad name \"a?b\" ?" "?(??" "? ok é"); /* split: no trigraphs */
    assert_str(m.u.error.message, want, strlen(want));
}

/* A name the writer cannot fix (empty) is still encoded, and the decoder
 * refuses it: the server, not the client's codec, rejects bad names. */
static void test_empty_name_encodes(void **state)
{
    proto_writer w;
    proto_frame f;
    proto_msg m;
    const proto_join join = {.name = {NULL, 0}, .box = {1, 1, 1}};

    (void)state;
    proto_writer_init(&w, big, BIG);
    proto_put_join(&w, &join);
    assert_int_equal(w.err, PROTO_OK);
    assert_int_equal(proto_frame_parse(big, w.len, PROTO_MAX_LEN_PREJOIN, &f), PROTO_OK);
    assert_int_equal(proto_decode(&f, &m), PROTO_ERR_BAD_STRING);
}

/* Several frames back to back parse one at a time, and every cut of the
 * stream that is not at a frame boundary reads as incomplete. */
static void test_stream_of_frames(void **state)
{
    const uint16_t want[] = {PROTO_HELLO, PROTO_JOIN, PROTO_MOVE, PROTO_PING, PROTO_BYE};
    size_t ends[5], off = 0, k = 0;
    proto_writer w;
    const proto_hello hello = {PROTO_MAGIC, PROTO_VERSION};
    const proto_join join = {.name = {"ann", 3}, .box = {1, 1, 1}};
    const proto_move move = {.seq = 1};

    (void)state;
    proto_writer_init(&w, big, BIG);
    proto_put_hello(&w, &hello);
    ends[0] = w.len;
    proto_put_join(&w, &join);
    ends[1] = w.len;
    proto_put_move(&w, &move);
    ends[2] = w.len;
    proto_put_ping(&w, 5);
    ends[3] = w.len;
    proto_put_bye(&w, PROTO_BYE_QUIT);
    ends[4] = w.len;
    assert_int_equal(w.err, PROTO_OK);

    while (off < w.len) {
        proto_frame f;
        proto_msg m;

        assert_int_equal(proto_frame_parse(big + off, w.len - off, PROTO_MAX_LEN_PREJOIN, &f), PROTO_OK);
        assert_int_equal(f.type, want[k]);
        assert_int_equal(proto_decode(&f, &m), PROTO_OK);
        off += f.size;
        assert_int_equal(off, ends[k]);
        k++;
    }
    assert_int_equal(k, 5);

    off = 0;
    for (k = 0; k < 5; k++) {
        for (size_t cut = off; cut < ends[k]; cut++) {
            proto_frame f;
            assert_int_equal(proto_frame_parse(big + off, cut - off, PROTO_MAX_LEN, &f),
                             PROTO_INCOMPLETE);
        }
        off = ends[k];
    }
}

/* The worked examples in PROTOCOL.md, byte for byte. */
static void test_worked_examples(void **state)
{
    static const uint8_t hello_bytes[] = {0x08, 0x00, 0x00, 0x00, 0x01, 0x00,
                                          0x43, 0x56, 0x52, 0x45, 0x02, 0x00};
    static const uint8_t move_bytes[] = {0x12, 0x00, 0x00, 0x00, 0x05, 0x00, 0x01, 0x00,
                                         0x00, 0x00, 0x00, 0x00, 0x80, 0x3f, 0x00, 0x00,
                                         0x00, 0x00, 0x00, 0x00, 0x20, 0xc0};
    static const uint8_t place_bytes[] = {0x1a, 0x00, 0x00, 0x00, 0x23, 0x00, 0x03, 0x00,
                                          0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
                                          0x00, 0x00, 0x00, 0x00, 0x20, 0x41, 0xdb, 0x0f,
                                          0xc9, 0x3f, 0x00, 0x00, 0x00, 0x40};
    static const uint8_t posed_bytes[] = {0x29, 0x00, 0x00, 0x00, 0x05, 0x00, 0x02, 0x00, 0x00, 0x00,
                                          0x00, 0x00, 0x80, 0x3f, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
                                          0x20, 0xc0, 0x00, 0x00, 0x00, 0x3f, 0x00, 0x00, 0x80, 0xbe,
                                          0x01, 0x00, 0x00, 0xa4, 0x06, 0x00, 0x00, 0x00, 0x00, 0x00,
                                          0x00, 0x00, 0x00, 0xff, 0x7f};
    proto_writer w;
    proto_move posed = {.seq = 2, .pos = {1.0f, 0.0f, -2.5f}, .has_pose = 1, .pose = {.yaw = 0.5f, .pitch = -0.25f}};
    const proto_hello hello = {PROTO_MAGIC, 2};
    const proto_move move = {.seq = 1, .pos = {1.0f, 0.0f, -2.5f}};
    const proto_object_place place = {3, {{0.0f, 0.0f, 10.0f}, 1.57079632679f, 2.0f}};

    (void)state;
    assert_int_equal(PROTO_VERSION, 2);
    proto_pose_set_part(&posed.pose, PROTO_POSE_HEAD, (const float[3]){0.0f, 1.7f, 0.0f},
                        (const float[4]){0.0f, 0.0f, 0.0f, 1.0f});
    proto_writer_init(&w, big, BIG);
    proto_put_move(&w, &posed);
    assert_int_equal(w.len, sizeof posed_bytes);
    assert_memory_equal(big, posed_bytes, sizeof posed_bytes);
    proto_writer_init(&w, big, BIG);
    proto_put_hello(&w, &hello);
    assert_int_equal(w.len, sizeof hello_bytes);
    assert_memory_equal(big, hello_bytes, sizeof hello_bytes);
    proto_writer_init(&w, big, BIG);
    proto_put_move(&w, &move);
    assert_int_equal(w.len, sizeof move_bytes);
    assert_memory_equal(big, move_bytes, sizeof move_bytes);
    proto_writer_init(&w, big, BIG);
    proto_put_object_place(&w, &place);
    assert_int_equal(w.len, sizeof place_bytes);
    assert_memory_equal(big, place_bytes, sizeof place_bytes);
}

/* ---- writer overflow ---------------------------------------------------- */

static void test_writer_exact_fit(void **state)
{
    uint8_t b[PROTO_SIZE_MOVE];
    proto_writer w;
    const proto_move move = {.seq = 1};

    (void)state;
    proto_writer_init(&w, b, sizeof b);
    proto_put_move(&w, &move);
    assert_int_equal(w.err, PROTO_OK);
    assert_int_equal(w.len, sizeof b);
    proto_put_bye(&w, 0);
    assert_int_equal(w.err, PROTO_ERR_FRAME_TOO_LONG);
    assert_int_equal(w.len, sizeof b);
}

static void test_writer_overflow_first_frame(void **state)
{
    uint8_t b[PROTO_SIZE_MOVE - 1];
    proto_writer w;
    const proto_move move = {.seq = 1};

    (void)state;
    proto_writer_init(&w, b, sizeof b);
    proto_put_move(&w, &move);
    assert_int_equal(w.err, PROTO_ERR_FRAME_TOO_LONG);
    assert_int_equal(w.len, 0);
    /* Sticky: a frame that would fit is not written either. */
    proto_put_bye(&w, 0);
    assert_int_equal(w.err, PROTO_ERR_FRAME_TOO_LONG);
    assert_int_equal(w.len, 0);
}

/* After an overflow len stays at the end of the last whole frame, later
 * puts of every kind do nothing, and what is there parses cleanly. */
static void test_writer_overflow_sticky(void **state)
{
    uint8_t b[2 * PROTO_SIZE_PING + PROTO_SIZE_PING / 2];
    proto_writer w;
    proto_frame f;
    size_t at, off = 0;
    const proto_hello hello = {PROTO_MAGIC, 1};
    const proto_join join = {.name = {"a", 1}, .box = {1, 1, 1}};
    const proto_join_ok jok = {.avatar_id = 1, .box = {1, 1, 1}};
    const proto_move move = {.seq = 1};
    const proto_avatar_joined aj = {1, {"a", 1}, {0, 0, 0}, {1, 1, 1}};
    const proto_avatar_left al = {1, 0};
    const proto_avatar a = {1, {0, 0, 0}};
    const proto_upload_begin ub = {1, 1, {"a", 1}, {"", 0}, PROTO_UP_Y, 1};
    const uint8_t byte = 1;
    const proto_upload_chunk uc = {1, 0, &byte, 1};
    const proto_upload_end ue = {1, {{0, 0, 0}, 0, 1}};
    const proto_object_place op = {1, {{0, 0, 0}, 0, 1}};
    const proto_object_info oi = {1, 0, {"a", 1}, {"b", 1}, {{0, 0, 0}, 0, 1}, 1, 0, {0}, 0, NULL};
    const proto_collision co = {1, 1, 0, 0, {0, 0, 0}, {0, 1, 0}};

    (void)state;
    memset(b, 0xee, sizeof b);
    proto_writer_init(&w, b, sizeof b);
    proto_put_ping(&w, 1);
    proto_put_ping(&w, 2);
    proto_put_ping(&w, 3);
    assert_int_equal(w.err, PROTO_ERR_FRAME_TOO_LONG);
    assert_int_equal(w.len, 2 * PROTO_SIZE_PING);

    proto_put_bye(&w, 0); /* would fit in the 7 bytes left */
    proto_put_hello(&w, &hello);
    proto_put_welcome(&w, &sample_welcome);
    proto_put_join(&w, &join);
    proto_put_join_ok(&w, &jok);
    proto_put_move(&w, &move);
    proto_put_avatar_joined(&w, &aj);
    proto_put_avatar_left(&w, &al);
    proto_put_error(&w, PROTO_ERR_INTERNAL, "x");
    proto_put_pong(&w, 4);
    proto_put_upload_begin(&w, &ub);
    proto_put_upload_chunk(&w, &uc);
    proto_put_upload_end(&w, &ue);
    proto_put_object_place(&w, &op);
    proto_put_object_remove(&w, 1);
    proto_put_object_info(&w, &oi, NULL, NULL);
    proto_put_object_removed(&w, 1);
    proto_put_object_rejected(&w, 1, PROTO_ERR_UPLOAD, "");
    proto_put_collision(&w, &co);
    at = proto_put_snapshot_begin(&w, 1, 1);
    assert_int_equal(at, w.len);
    proto_put_snapshot_add(&w, at, &a);
    proto_put_snapshot_end(&w, at);
    assert_int_equal(w.err, PROTO_ERR_FRAME_TOO_LONG);
    assert_int_equal(w.len, 2 * PROTO_SIZE_PING);
    for (size_t i = w.len; i < sizeof b; i++)
        assert_int_equal(b[i], 0xee);

    for (int i = 0; i < 2; i++) {
        assert_int_equal(proto_frame_parse(b + off, w.len - off, PROTO_MAX_LEN, &f), PROTO_OK);
        off += f.size;
    }
    assert_int_equal(off, w.len);
}

static void test_writer_null_buffer(void **state)
{
    proto_writer w;
    size_t at;
    const proto_avatar a = {1, {0, 0, 0}};

    (void)state;
    proto_writer_init(&w, NULL, 0);
    proto_put_ping(&w, 1);
    assert_int_equal(w.err, PROTO_ERR_FRAME_TOO_LONG);
    at = proto_put_snapshot_begin(&w, 1, 1);
    proto_put_snapshot_add(&w, at, &a);
    proto_put_snapshot_end(&w, at);
    assert_int_equal(at, 0);
    assert_int_equal(w.len, 0);
}

/* A chunk over PROTO_CHUNK_MAX is not written: the writer fails, keeps
 * the frames before it, and stays failed. A chunk of exactly
 * PROTO_CHUNK_MAX fits a buffer of exactly its size. */
static void test_writer_chunk_over_max(void **state)
{
    static uint8_t data[PROTO_CHUNK_MAX + 1];
    static uint8_t b[PROTO_HEADER_SIZE + 8 + PROTO_CHUNK_MAX];
    proto_writer w;
    proto_upload_chunk c = {1, 0, data, PROTO_CHUNK_MAX};

    (void)state;
    proto_writer_init(&w, b, sizeof b);
    proto_put_upload_chunk(&w, &c);
    assert_int_equal(w.err, PROTO_OK);
    assert_int_equal(w.len, sizeof b);

    proto_writer_init(&w, big, BIG);
    proto_put_ping(&w, 1);
    c.len = PROTO_CHUNK_MAX + 1;
    proto_put_upload_chunk(&w, &c);
    assert_int_equal(w.err, PROTO_ERR_FRAME_TOO_LONG);
    assert_int_equal(w.len, PROTO_SIZE_PING);
    c.len = 1;
    proto_put_upload_chunk(&w, &c);
    assert_int_equal(w.err, PROTO_ERR_FRAME_TOO_LONG);
    assert_int_equal(w.len, PROTO_SIZE_PING);

    /* Over the cap on a writer that has already failed: still that error. */
    proto_writer_init(&w, NULL, 0);
    proto_put_ping(&w, 1);
    c.len = UINT32_MAX;
    proto_put_upload_chunk(&w, &c);
    assert_int_equal(w.err, PROTO_ERR_FRAME_TOO_LONG);
    assert_int_equal(w.len, 0);
}

/* More than PROTO_OBJECT_BOXES_MAX boxes are not written either. */
static void test_writer_info_over_max(void **state)
{
    static float mn[PROTO_OBJECT_BOXES_MAX + 1][3], mx[PROTO_OBJECT_BOXES_MAX + 1][3];
    proto_writer w;
    proto_msg m;
    proto_object_info oi = {1, 0, {"a", 1}, {"b", 1}, {{0, 0, 0}, 0, 1}, 1, 0, {0}, PROTO_OBJECT_BOXES_MAX + 1,
                            NULL};

    (void)state;
    proto_writer_init(&w, big, BIG);
    proto_put_bye(&w, 0);
    proto_put_object_info(&w, &oi, (const float (*)[3])mn, (const float (*)[3])mx);
    assert_int_equal(w.err, PROTO_ERR_FRAME_TOO_LONG);
    assert_int_equal(w.len, PROTO_SIZE_BYE);
    oi.box_count = 0xffff;
    proto_put_object_info(&w, &oi, NULL, NULL);
    assert_int_equal(w.len, PROTO_SIZE_BYE);
    decode_all(big, w.len, &m);
    assert_int_equal(m.type, PROTO_BYE);
}

/* What the writer cannot fix is still encoded and the decoder refuses it:
 * an empty chunk, an id 0, a scale out of range. */
static void test_bad_objects_encode(void **state)
{
    proto_writer w;
    proto_frame f;
    proto_msg m;
    const proto_upload_chunk empty = {1, 0, NULL, 0};
    const proto_upload_end zero = {0, {{0, 0, 0}, 0, 1}};
    const proto_object_place tiny = {1, {{0, 0, 0}, 0, 0}};

    (void)state;
    proto_writer_init(&w, big, BIG);
    proto_put_upload_chunk(&w, &empty);
    assert_int_equal(w.err, PROTO_OK);
    assert_int_equal(w.len, PROTO_HEADER_SIZE + 8);
    assert_int_equal(proto_frame_parse(big, w.len, PROTO_MAX_LEN, &f), PROTO_OK);
    assert_int_equal(proto_decode(&f, &m), PROTO_ERR_SHORT);
    proto_writer_init(&w, big, BIG);
    proto_put_upload_end(&w, &zero);
    assert_int_equal(proto_frame_parse(big, w.len, PROTO_MAX_LEN, &f), PROTO_OK);
    assert_int_equal(proto_decode(&f, &m), PROTO_ERR_BAD_VALUE);
    proto_writer_init(&w, big, BIG);
    proto_put_object_place(&w, &tiny);
    assert_int_equal(proto_frame_parse(big, w.len, PROTO_MAX_LEN, &f), PROTO_OK);
    assert_int_equal(proto_decode(&f, &m), PROTO_ERR_BAD_VALUE);
}

static void test_snapshot_begin_no_room(void **state)
{
    uint8_t b[PROTO_SIZE_SNAPSHOT(0) - 1];
    proto_writer w;
    size_t at;
    const proto_avatar a = {1, {0, 0, 0}};

    (void)state;
    proto_writer_init(&w, b, sizeof b);
    at = proto_put_snapshot_begin(&w, 1, 1);
    assert_int_equal(w.err, PROTO_ERR_FRAME_TOO_LONG);
    assert_int_equal(at, 0);
    proto_put_snapshot_add(&w, at, &a);
    proto_put_snapshot_end(&w, at);
    assert_int_equal(w.len, 0);
}

/* Running out of room mid-snapshot drops the snapshot but keeps the frames
 * before it. */
static void test_snapshot_add_no_room(void **state)
{
    uint8_t b[PROTO_SIZE_PING + PROTO_SIZE_SNAPSHOT(2) + PROTO_SNAPSHOT_ENTRY_SIZE - 1];
    proto_writer w;
    proto_frame f;
    proto_msg m;
    size_t at;
    const proto_avatar a = {1, {0, 0, 0}};

    (void)state;
    proto_writer_init(&w, b, sizeof b);
    proto_put_ping(&w, 77);
    at = proto_put_snapshot_begin(&w, 1, 1);
    assert_int_equal(at, PROTO_SIZE_PING);
    proto_put_snapshot_add(&w, at, &a);
    proto_put_snapshot_add(&w, at, &a);
    assert_int_equal(w.err, PROTO_OK);
    proto_put_snapshot_add(&w, at, &a);
    assert_int_equal(w.err, PROTO_ERR_FRAME_TOO_LONG);
    assert_int_equal(w.len, at);
    proto_put_snapshot_end(&w, at);
    assert_int_equal(w.len, at);
    decode_all(b, w.len, &m);
    assert_int_equal(m.type, PROTO_PING);
    assert_true(m.u.ping.stamp == 77);
    assert_int_equal(proto_frame_parse(b, w.len, PROTO_MAX_LEN, &f), PROTO_OK);
}

/* A snapshot after other frames gets the right offset, count and length. */
static void test_snapshot_after_frames(void **state)
{
    proto_writer w;
    proto_msg m;
    size_t at;
    const proto_avatar a = {5, {1, 2, 3}};

    (void)state;
    proto_writer_init(&w, big, BIG);
    proto_put_bye(&w, 0);
    at = proto_put_snapshot_begin(&w, 9, 8);
    assert_int_equal(at, PROTO_SIZE_BYE);
    proto_put_snapshot_add(&w, at, &a);
    proto_put_snapshot_add(&w, at, &a);
    proto_put_snapshot_end(&w, at);
    proto_put_pong(&w, 3);
    assert_int_equal(w.err, PROTO_OK);
    assert_int_equal(w.len, PROTO_SIZE_BYE + PROTO_SIZE_SNAPSHOT(2) + PROTO_SIZE_PING);
    decode_all(big + at, PROTO_SIZE_SNAPSHOT(2), &m);
    assert_int_equal(m.u.snapshot.count, 2);
    decode_all(big + at + PROTO_SIZE_SNAPSHOT(2), PROTO_SIZE_PING, &m);
    assert_int_equal(m.type, PROTO_PONG);
}

/* ---- framing ------------------------------------------------------------ */

static void test_frame_incomplete_length(void **state)
{
    const uint8_t b[4] = {0xff, 0xff, 0xff, 0xff};
    proto_frame f;

    (void)state;
    for (size_t n = 0; n < 4; n++)
        assert_int_equal(proto_frame_parse(b, n, PROTO_MAX_LEN, &f), PROTO_INCOMPLETE);
}

static void test_frame_empty(void **state)
{
    uint8_t b[16] = {0};
    proto_frame f;

    (void)state;
    for (uint32_t len = 0; len < PROTO_LEN_MIN; len++) {
        wr_u32(b, len);
        assert_int_equal(proto_frame_parse(b, 4, PROTO_MAX_LEN, &f), PROTO_ERR_FRAME_EMPTY);
        assert_int_equal(proto_frame_parse(b, sizeof b, PROTO_MAX_LEN_PREJOIN, &f),
                         PROTO_ERR_FRAME_EMPTY);
    }
    /* Length 2 is the smallest frame: a type and no payload. */
    wr_u32(b, 2);
    wr_u16(b + 4, PROTO_BYE);
    assert_int_equal(proto_frame_parse(b, sizeof b, PROTO_MAX_LEN, &f), PROTO_OK);
    assert_int_equal(f.size, 6);
    assert_int_equal(f.payload_len, 0);
    assert_int_equal(f.type, PROTO_BYE);
}

/* An oversized length is refused as soon as its 4 bytes are in, under
 * either cap, before any payload is buffered. */
static void test_frame_too_long(void **state)
{
    static const struct {
        uint32_t cap, len;
    } cases[] = {
        {PROTO_MAX_LEN, PROTO_MAX_LEN + 1},
        {PROTO_MAX_LEN, 0x7fffffff},
        {PROTO_MAX_LEN, 0xfffffffc},
        {PROTO_MAX_LEN, 0xffffffff},
        {PROTO_MAX_LEN_PREJOIN, PROTO_MAX_LEN_PREJOIN + 1},
        {PROTO_MAX_LEN_PREJOIN, PROTO_MAX_LEN},
        {PROTO_MAX_LEN_PREJOIN, 0xffffffff},
    };
    uint8_t b[8] = {0};
    proto_frame f;

    (void)state;
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        wr_u32(b, cases[i].len);
        assert_int_equal(proto_frame_parse(b, 4, cases[i].cap, &f), PROTO_ERR_FRAME_TOO_LONG);
        assert_int_equal(proto_frame_parse(b, sizeof b, cases[i].cap, &f), PROTO_ERR_FRAME_TOO_LONG);
    }
    /* Over the pre-join cap but within the joined one: just incomplete. */
    wr_u32(b, PROTO_MAX_LEN_PREJOIN + 1);
    assert_int_equal(proto_frame_parse(b, sizeof b, PROTO_MAX_LEN, &f), PROTO_INCOMPLETE);
}

/* A length exactly at the cap is accepted under that cap. */
static void test_frame_at_cap(void **state)
{
    proto_frame f;

    (void)state;
    memset(big, 0, PROTO_MAX_LEN + 4);
    wr_u32(big, PROTO_MAX_LEN);
    wr_u16(big + 4, PROTO_SNAPSHOT);
    assert_int_equal(proto_frame_parse(big, PROTO_MAX_LEN + 3, PROTO_MAX_LEN, &f), PROTO_INCOMPLETE);
    assert_int_equal(proto_frame_parse(big, PROTO_MAX_LEN + 4, PROTO_MAX_LEN, &f), PROTO_OK);
    assert_int_equal(f.size, PROTO_MAX_LEN + 4);
    assert_int_equal(f.payload_len, PROTO_MAX_LEN - 2);

    wr_u32(big, PROTO_MAX_LEN_PREJOIN);
    assert_int_equal(proto_frame_parse(big, PROTO_MAX_LEN_PREJOIN + 4, PROTO_MAX_LEN_PREJOIN, &f),
                     PROTO_OK);
    assert_int_equal(f.size, PROTO_MAX_LEN_PREJOIN + 4);
}

static void test_frame_incomplete_header_and_payload(void **state)
{
    uint8_t b[32] = {0};
    proto_frame f;

    (void)state;
    wr_u32(b, 2 + 16);
    wr_u16(b + 4, PROTO_MOVE);
    assert_int_equal(proto_frame_parse(b, 5, PROTO_MAX_LEN, &f), PROTO_INCOMPLETE); /* half a type */
    for (size_t n = 6; n < 22; n++)
        assert_int_equal(proto_frame_parse(b, n, PROTO_MAX_LEN, &f), PROTO_INCOMPLETE);
    assert_int_equal(proto_frame_parse(b, 22, PROTO_MAX_LEN, &f), PROTO_OK);
    /* Bytes after the frame belong to the next one. */
    assert_int_equal(proto_frame_parse(b, sizeof b, PROTO_MAX_LEN, &f), PROTO_OK);
    assert_int_equal(f.size, 22);
    assert_int_equal(f.payload_len, 16);
}

/* ---- decoding: classes that apply to every type ------------------------- */

static void test_unknown_and_reserved_types(void **state)
{
    const uint8_t payload[16] = {0};

    (void)state;
    for (uint32_t t = 0; t <= 0xffff; t++) {
        if ((t >= PROTO_HELLO && t <= PROTO_AVATAR_POSE) || (t >= PROTO_OBJECT_UPLOAD_BEGIN && t <= PROTO_OBJECT_REJECTED &&
                                                     t != PROTO_OBJECT_MOVE) || t == PROTO_COLLISION)
            continue;
        if (t == PROTO_MESH_REQUEST || t == PROTO_MESH_CHUNK)
            continue;
        assert_int_equal(decode_raw((uint16_t)t, payload, sizeof payload), PROTO_ERR_UNKNOWN_TYPE);
        assert_int_equal(decode_raw((uint16_t)t, NULL, 0), PROTO_ERR_UNKNOWN_TYPE);
    }
    assert_int_equal(decode_raw(PROTO_OBJECT_MOVE, payload, sizeof payload), PROTO_ERR_UNKNOWN_TYPE);
    assert_int_equal(decode_raw(PROTO_ECM_UPDATE, payload, sizeof payload), PROTO_ERR_UNKNOWN_TYPE);
    assert_int_equal(decode_raw(PROTO_ADMIN_REQUEST, payload, sizeof payload), PROTO_ERR_UNKNOWN_TYPE);
}

/* Every proper prefix of every sample is short, except a cut inside a
 * string's text, which is a string running past the end of the frame, and
 * a cut inside an upload chunk's data, which is a shorter chunk. */
static void test_short_every_type(void **state)
{
    sample s[NSAMPLES];
    size_t n = build_samples(s);

    (void)state;
    for (size_t i = 0; i < n; i++) {
        for (size_t k = 0; k < s[i].len; k++) {
            int want = PROTO_ERR_SHORT;

            for (size_t j = 0; j < s[i].nstrs; j++) {
                if (k > s[i].strs[j].at && k <= s[i].strs[j].at + s[i].strs[j].len)
                    want = PROTO_ERR_BAD_STRING;
            }
            if (s[i].data_at && k > s[i].data_at)
                want = PROTO_OK;
            if (decode_raw(s[i].type, s[i].payload, k) != want)
                fail_msg("%s cut at %zu: got %d want %d", proto_type_name(s[i].type), k,
                         decode_raw(s[i].type, s[i].payload, k), want);
        }
    }
}

/* Bytes after the layout are trailing, except after an upload chunk's head,
 * where they are more data (the chunk cap is test_upload_chunk_sizes'), and
 * after a join or join_ok, where they start its optional tail (a credential,
 * a token) and these zeros make a broken one. */
static void test_trailing_every_type(void **state)
{
    sample s[NSAMPLES];
    size_t n = build_samples(s);

    (void)state;
    for (size_t i = 0; i < n; i++) {
        uint8_t p[SAMPLE_MAX + 32] = {0};

        memcpy(p, s[i].payload, s[i].len);
        for (size_t extra = 1; extra <= 17; extra++) {
            int got = decode_raw(s[i].type, p, s[i].len + extra);
            if (s[i].type == PROTO_JOIN || s[i].type == PROTO_JOIN_OK)
                assert_true(got == PROTO_ERR_SHORT || got == PROTO_ERR_BAD_VALUE);
            else if (s[i].type == PROTO_MOVE) /* zeros: a pose tail, facing only, once whole */
                assert_int_equal(got, extra < PROTO_POSE_HEAD_SIZE    ? PROTO_ERR_SHORT
                                      : extra == PROTO_POSE_HEAD_SIZE ? PROTO_OK
                                                                      : PROTO_ERR_TRAILING);
            else
                assert_int_equal(got, s[i].data_at ? PROTO_OK : PROTO_ERR_TRAILING);
        }
    }
}

/* NaN (quiet, signalling, negative) and both infinities in every float
 * field of every type. */
static void test_not_finite_every_float(void **state)
{
    static const uint32_t bad[] = {0x7fc00000u, 0x7f800001u, 0xffc00000u, 0x7fffffffu,
                                   0x7f800000u, 0xff800000u};
    sample s[NSAMPLES];
    size_t n = build_samples(s);
    size_t tried = 0;

    (void)state;
    for (size_t i = 0; i < n; i++) {
        for (size_t k = 0; k < s[i].nfloats; k++) {
            for (size_t b = 0; b < sizeof bad / sizeof bad[0]; b++) {
                uint8_t p[SAMPLE_MAX];

                memcpy(p, s[i].payload, s[i].len);
                wr_u32(p + s[i].floats[k], bad[b]);
                if (decode_raw(s[i].type, p, s[i].len) != PROTO_ERR_NOT_FINITE)
                    fail_msg("%s float at %zu = %08x accepted", proto_type_name(s[i].type),
                             s[i].floats[k], (unsigned)bad[b]);
                tried++;
            }
        }
    }
    /* welcome, join, join_ok, move, snapshot, avatar_joined, then
     * upload_begin, upload_end, place, object_info, collision */
    assert_int_equal(tried, (8 + 3 + 6 + 3 + 6 + 6 + 1 + 5 + 5 + 17 + 6) * 6);
}

/* Box edges must lie in [PROTO_BOX_MIN, PROTO_BOX_MAX] in join, join_ok and
 * avatar_joined, with both bounds included. */
static void test_box_range(void **state)
{
    const float bad[] = {0.0f, -0.0f, -1.0f, bits_f32(f32_bits(PROTO_BOX_MIN) - 1),
                         bits_f32(f32_bits(PROTO_BOX_MAX) + 1), 4.5f, 1e30f, -FLT_MAX, FLT_MAX};
    const float good[] = {PROTO_BOX_MIN, PROTO_BOX_MAX, 1.0f, 0.25f};
    sample s[NSAMPLES];
    size_t n = build_samples(s), tried = 0;

    (void)state;
    for (size_t i = 0; i < n; i++) {
        for (size_t k = 0; k < s[i].nboxes; k++) {
            uint8_t p[SAMPLE_MAX];

            memcpy(p, s[i].payload, s[i].len);
            for (size_t b = 0; b < sizeof bad / sizeof bad[0]; b++) {
                wr_f32(p + s[i].boxes[k], bad[b]);
                assert_int_equal(decode_raw(s[i].type, p, s[i].len), PROTO_ERR_BAD_VALUE);
                tried++;
            }
            for (size_t g = 0; g < sizeof good / sizeof good[0]; g++) {
                wr_f32(p + s[i].boxes[k], good[g]);
                assert_int_equal(decode_raw(s[i].type, p, s[i].len), PROTO_OK);
            }
        }
    }
    assert_int_equal(tried, 3 * 3 * (sizeof bad / sizeof bad[0]));
}

/* An object's scale (upload_end, place, object_info) and an upload's unit
 * scale must lie in [PROTO_SCALE_MIN, PROTO_SCALE_MAX], both included. */
static void test_scale_range(void **state)
{
    const float bad[] = {0.0f, -0.0f, -1.0f, -PROTO_SCALE_MIN, bits_f32(1) /* denormal */,
                         bits_f32(f32_bits(PROTO_SCALE_MIN) - 1), bits_f32(f32_bits(PROTO_SCALE_MAX) + 1),
                         1001.0f, 1e30f, -FLT_MAX, FLT_MAX};
    const float good[] = {PROTO_SCALE_MIN, PROTO_SCALE_MAX, 1.0f, 0.01f, 999.5f};
    sample s[NSAMPLES];
    size_t n = build_samples(s), tried = 0;

    (void)state;
    for (size_t i = 0; i < n; i++) {
        uint8_t p[SAMPLE_MAX];

        if (!s[i].scale)
            continue;
        memcpy(p, s[i].payload, s[i].len);
        for (size_t b = 0; b < sizeof bad / sizeof bad[0]; b++) {
            wr_f32(p + s[i].scale, bad[b]);
            if (decode_raw(s[i].type, p, s[i].len) != PROTO_ERR_BAD_VALUE)
                fail_msg("%s scale %g accepted", proto_type_name(s[i].type), (double)bad[b]);
            tried++;
        }
        for (size_t g = 0; g < sizeof good / sizeof good[0]; g++) {
            wr_f32(p + s[i].scale, good[g]);
            assert_int_equal(decode_raw(s[i].type, p, s[i].len), PROTO_OK);
        }
    }
    assert_int_equal(tried, 4 * (sizeof bad / sizeof bad[0]));
}

/* Object ids, upload ids and ECM versions are never 0 on the wire (0 means
 * "none"); every other value decodes. */
static void test_zero_ids(void **state)
{
    const uint32_t good[] = {1, 2, 0x80000000u, UINT32_MAX};
    sample s[NSAMPLES];
    size_t n = build_samples(s), tried = 0;

    (void)state;
    for (size_t i = 0; i < n; i++) {
        for (size_t k = 0; k < s[i].nids; k++) {
            uint8_t p[SAMPLE_MAX];

            memcpy(p, s[i].payload, s[i].len);
            wr_u32(p + s[i].ids[k], 0);
            if (decode_raw(s[i].type, p, s[i].len) != PROTO_ERR_BAD_VALUE)
                fail_msg("%s id 0 at %zu accepted", proto_type_name(s[i].type), s[i].ids[k]);
            tried++;
            for (size_t g = 0; g < sizeof good / sizeof good[0]; g++) {
                wr_u32(p + s[i].ids[k], good[g]);
                assert_int_equal(decode_raw(s[i].type, p, s[i].len), PROTO_OK);
            }
        }
    }
    /* begin, chunk, end, place, remove, info (id, version), removed,
     * collision (id, version) */
    assert_int_equal(tried, 10);
}

/* Where 0 is a value and not "none", it decodes: object_info's upload_id,
 * object_rejected's request_id, a chunk's offset, a collision's box. */
static void test_zero_where_allowed(void **state)
{
    const struct {
        uint16_t type;
        size_t at, size;
    } cases[] = {
        {PROTO_OBJECT_INFO, 4, 4},
        {PROTO_OBJECT_REJECTED, 0, 4},
        {PROTO_OBJECT_UPLOAD_CHUNK, 4, 4},
        {PROTO_COLLISION, 8, 2},
    };
    sample s[NSAMPLES];
    size_t n = build_samples(s);

    (void)state;
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
        for (size_t i = 0; i < n; i++) {
            uint8_t p[SAMPLE_MAX];

            if (s[i].type != cases[c].type)
                continue;
            memcpy(p, s[i].payload, s[i].len);
            memset(p + cases[c].at, 0, cases[c].size);
            assert_int_equal(decode_raw(s[i].type, p, s[i].len), PROTO_OK);
            memset(p + cases[c].at, 0xff, cases[c].size);
            assert_int_equal(decode_raw(s[i].type, p, s[i].len), PROTO_OK);
        }
    }
}

/* ---- decoding: strings -------------------------------------------------- */

static const char *const bad_text[] = {
    "\x00", "a\x01", "\x1f", "\x7f", "a\nb", "tab\there", "a\rb", "\x1b[31m",
    "\x80", "a\xbf", "\xc0\x80", "\xc1\xbf", "\xe0\x80\x80", "\xe0\x9f\xbf",
    "\xf0\x80\x80\x80", "\xf0\x8f\xbf\xbf", "\xed\xa0\x80", "\xed\xbf\xbf",
    "\xf4\x90\x80\x80", "\xf5\x80\x80\x80", "\xf8\x88\x80\x80\x80", "\xfe", "\xff",
    "\xc3", "ab\xe2\x82", "ab\xf0\x9f\x98", "\xc3\x41", "\xe2\x28\xa1",
};
/* Lengths, because several bad texts contain NUL. */
static size_t bad_text_len(size_t i) { return i == 0 ? 1 : strlen(bad_text[i]); }

static const char *const good_text[] = {
    " ", "~", "a b", "Zoë", "\xe2\x82\xac", "\xf0\x9f\x98\x80", "\xf4\x8f\xbf\xbf",
    "\xef\xbf\xbd", "\xed\x9f\xbf", "\xee\x80\x80", "\xc2\xa0",
};

/* Every name field (join, avatar_joined, upload_begin's object name,
 * object_info's owner and name) takes 1..max bytes of text. */
static void test_name_rules(void **state)
{
    char longest[256];
    sample s[NSAMPLES];
    size_t n = build_samples(s), tried = 0;

    (void)state;
    memset(longest, 'x', sizeof longest);
    for (size_t i = 0; i < n; i++) {
        for (size_t k = 0; k < s[i].nstrs; k++) {
            const uint32_t max = s[i].strs[k].max;

            if (max != PROTO_NAME_MAX && max != PROTO_OBJECT_NAME_MAX)
                continue;
            assert_int_equal(s[i].strs[k].min, 1);
            for (size_t b = 0; b < sizeof bad_text / sizeof bad_text[0]; b++) {
                if (splice_status(&s[i], k, bad_text[b], bad_text_len(b)) != PROTO_ERR_BAD_STRING)
                    fail_msg("%s string %zu accepted bad text #%zu", proto_type_name(s[i].type), k, b);
            }
            for (size_t g = 0; g < sizeof good_text / sizeof good_text[0]; g++)
                assert_int_equal(splice_status(&s[i], k, good_text[g], strlen(good_text[g])), PROTO_OK);
            assert_int_equal(splice_status(&s[i], k, "", 0), PROTO_ERR_BAD_STRING);
            assert_int_equal(splice_status(&s[i], k, longest, max), PROTO_OK);
            assert_int_equal(splice_status(&s[i], k, longest, max + 1), PROTO_ERR_BAD_STRING);
            assert_int_equal(splice_status(&s[i], k, longest, 255), PROTO_ERR_BAD_STRING);
            tried++;
        }
    }
    assert_int_equal(tried, 5);
}

/* Error texts (error, object_rejected) may be empty, up to
 * PROTO_MESSAGE_MAX bytes. */
static void test_message_rules(void **state)
{
    char longest[256];
    sample s[NSAMPLES];
    size_t n = build_samples(s), tried = 0;

    (void)state;
    memset(longest, 'x', sizeof longest);
    for (size_t i = 0; i < n; i++) {
        for (size_t k = 0; k < s[i].nstrs; k++) {
            if (s[i].strs[k].max != PROTO_MESSAGE_MAX)
                continue;
            for (size_t b = 0; b < sizeof bad_text / sizeof bad_text[0]; b++)
                assert_int_equal(splice_status(&s[i], k, bad_text[b], bad_text_len(b)), PROTO_ERR_BAD_STRING);
            for (size_t g = 0; g < sizeof good_text / sizeof good_text[0]; g++)
                assert_int_equal(splice_status(&s[i], k, good_text[g], strlen(good_text[g])), PROTO_OK);
            assert_int_equal(splice_status(&s[i], k, "", 0), PROTO_OK);
            assert_int_equal(splice_status(&s[i], k, longest, PROTO_MESSAGE_MAX), PROTO_OK);
            assert_int_equal(splice_status(&s[i], k, longest, PROTO_MESSAGE_MAX + 1), PROTO_ERR_BAD_STRING);
            assert_int_equal(splice_status(&s[i], k, longest, 255), PROTO_ERR_BAD_STRING);
            tried++;
        }
    }
    assert_int_equal(tried, 2);
}

/* A format hint is a file extension: 0..PROTO_FORMAT_MAX bytes of a-z and
 * 0-9, nothing else (no upper case, no dot, no non-ASCII). */
static void test_format_rules(void **state)
{
    static const char *const good[] = {"", "obj", "glb", "gltf", "stl", "ply", "3ds", "x3d",
                                       "0", "z", "12345678", "abcdefgh"};
    static const char *const bad[] = {"OBJ", "Obj", "objZ", ".obj", "o.j", "obj.", "-", "_", " ",
                                      "a b", "/", "@", "[", "`", "{", ":", "\xc3\xa9", "\xef\xbc\xa1",
                                      "\x7f", "a\n", "\xff", "123456789", "abcdefghi"};
    sample s[NSAMPLES];
    const sample *ub = NULL;
    size_t n = build_samples(s);

    (void)state;
    for (size_t i = 0; i < n; i++) {
        if (s[i].type == PROTO_OBJECT_UPLOAD_BEGIN)
            ub = &s[i];
    }
    assert_non_null(ub);
    assert_int_equal(ub->strs[1].max, PROTO_FORMAT_MAX);
    for (size_t g = 0; g < sizeof good / sizeof good[0]; g++)
        assert_int_equal(splice_status(ub, 1, good[g], strlen(good[g])), PROTO_OK);
    for (size_t b = 0; b < sizeof bad / sizeof bad[0]; b++) {
        if (splice_status(ub, 1, bad[b], strlen(bad[b])) != PROTO_ERR_BAD_STRING)
            fail_msg("format \"%s\" accepted", bad[b]);
    }
    assert_int_equal(splice_status(ub, 1, "\0", 1), PROTO_ERR_BAD_STRING);
}

/* A string length that runs past the end of the frame is a bad string, for
 * each type that carries one, whatever the declared length. */
static void test_string_past_end(void **state)
{
    uint8_t p[8];

    (void)state;
    p[0] = 4;
    memcpy(p + 1, "abc", 3);
    assert_int_equal(decode_raw(PROTO_JOIN, p, 4), PROTO_ERR_BAD_STRING);
    p[0] = 255;
    assert_int_equal(decode_raw(PROTO_JOIN, p, 4), PROTO_ERR_BAD_STRING);
    assert_int_equal(decode_raw(PROTO_JOIN, p, 1), PROTO_ERR_BAD_STRING);

    wr_u32(p, 1);
    p[4] = 3;
    memcpy(p + 5, "ab", 2);
    assert_int_equal(decode_raw(PROTO_AVATAR_JOINED, p, 7), PROTO_ERR_BAD_STRING);

    wr_u16(p, PROTO_ERR_INTERNAL);
    p[2] = 1;
    assert_int_equal(decode_raw(PROTO_ERROR, p, 3), PROTO_ERR_BAD_STRING);
    p[2] = 0;
    assert_int_equal(decode_raw(PROTO_ERROR, p, 3), PROTO_OK);
    /* The length byte itself missing is a short payload. */
    assert_int_equal(decode_raw(PROTO_ERROR, p, 2), PROTO_ERR_SHORT);
    assert_int_equal(decode_raw(PROTO_JOIN, p, 0), PROTO_ERR_SHORT);
}

/* ---- decoding: per-type values ------------------------------------------ */

static void test_hello_magic(void **state)
{
    const uint32_t bad[] = {0, 0x43565245u /* "CVRE" read big-endian */, PROTO_MAGIC ^ 1u,
                            PROTO_MAGIC ^ 0x80000000u, 0xffffffffu};
    uint8_t p[6];
    proto_msg m;

    (void)state;
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        wr_u32(p, bad[i]);
        wr_u16(p + 4, PROTO_VERSION);
        assert_int_equal(decode_raw(PROTO_HELLO, p, 6), PROTO_ERR_BAD_MAGIC);
    }
    /* The magic is the ASCII bytes "CVRE" in order. */
    memcpy(p, "CVRE", 4);
    /* The version is the server's business, not the codec's. */
    wr_u16(p + 4, 0);
    assert_int_equal(decode_raw_msg(PROTO_HELLO, p, 6, &m), PROTO_OK);
    assert_int_equal(m.u.hello.version, 0);
    wr_u16(p + 4, 0xffff);
    assert_int_equal(decode_raw_msg(PROTO_HELLO, p, 6, &m), PROTO_OK);
    assert_int_equal(m.u.hello.version, 0xffff);
}

static void test_welcome_values(void **state)
{
    sample s[NSAMPLES];
    uint8_t p[64];

    (void)state;
    build_samples(s);
    assert_int_equal(s[1].type, PROTO_WELCOME);
#define TRY(off, put, want)                                              \
    do {                                                                 \
        memcpy(p, s[1].payload, s[1].len);                               \
        put(p + (off));                                                  \
        assert_int_equal(decode_raw(PROTO_WELCOME, p, s[1].len), want);  \
    } while (0)
#define TICK0(q) wr_u16(q, 0)
#define NEG(q) wr_f32(q, -1.0f)
#define ZERO(q) wr_f32(q, 0.0f)
#define NZERO(q) wr_f32(q, -0.0f)
#define HUGE_MIN(q) wr_f32(q, 1000.0f)
#define SAME_MIN(q) wr_f32(q, 0.0f)
    TRY(26, TICK0, PROTO_ERR_BAD_VALUE);
    TRY(28, ZERO, PROTO_ERR_BAD_VALUE);  /* aoi radius */
    TRY(28, NZERO, PROTO_ERR_BAD_VALUE);
    TRY(28, NEG, PROTO_ERR_BAD_VALUE);
    TRY(32, NEG, PROTO_ERR_BAD_VALUE);   /* max speed */
    TRY(32, ZERO, PROTO_OK);
    TRY(36, HUGE_MIN, PROTO_ERR_BAD_VALUE); /* world_min.x > world_max.x */
    TRY(44, HUGE_MIN, PROTO_ERR_BAD_VALUE);
    TRY(52, NEG, PROTO_ERR_BAD_VALUE);      /* world_max.y < world_min.y (0) */
    TRY(52, SAME_MIN, PROTO_OK);            /* equal bounds: a flat world */
#undef TRY
#undef TICK0
#undef NEG
#undef ZERO
#undef NZERO
#undef HUGE_MIN
#undef SAME_MIN
}

static void test_snapshot_count_mismatch(void **state)
{
    uint8_t p[PROTO_SNAPSHOT_HEAD_SIZE + 3 * PROTO_SNAPSHOT_ENTRY_SIZE] = {0};
    const size_t head = PROTO_SNAPSHOT_HEAD_SIZE, e = PROTO_SNAPSHOT_ENTRY_SIZE;

    (void)state;
    wr_u16(p + 8, 0);
    assert_int_equal(decode_raw(PROTO_SNAPSHOT, p, head), PROTO_OK);
    assert_int_equal(decode_raw(PROTO_SNAPSHOT, p, head + e), PROTO_ERR_TRAILING);
    wr_u16(p + 8, 1);
    assert_int_equal(decode_raw(PROTO_SNAPSHOT, p, head), PROTO_ERR_SHORT);
    assert_int_equal(decode_raw(PROTO_SNAPSHOT, p, head + e - 1), PROTO_ERR_SHORT);
    assert_int_equal(decode_raw(PROTO_SNAPSHOT, p, head + e), PROTO_OK);
    assert_int_equal(decode_raw(PROTO_SNAPSHOT, p, head + 2 * e), PROTO_ERR_TRAILING);
    wr_u16(p + 8, 2);
    assert_int_equal(decode_raw(PROTO_SNAPSHOT, p, head + e), PROTO_ERR_SHORT);
    assert_int_equal(decode_raw(PROTO_SNAPSHOT, p, head + 3 * e), PROTO_ERR_TRAILING);
    wr_u16(p + 8, 0xffff);
    assert_int_equal(decode_raw(PROTO_SNAPSHOT, p, head + 3 * e), PROTO_ERR_SHORT);
}

/* A non-finite coordinate deep in a long snapshot is still found. */
static void test_snapshot_late_nan(void **state)
{
    proto_writer w;
    proto_frame f;
    proto_msg m;
    size_t at;
    const proto_avatar a = {1, {1, 2, 3}};

    (void)state;
    proto_writer_init(&w, big, BIG);
    at = proto_put_snapshot_begin(&w, 1, 1);
    for (int i = 0; i < 1000; i++)
        proto_put_snapshot_add(&w, at, &a);
    proto_put_snapshot_end(&w, at);
    wr_u32(big + at + PROTO_HEADER_SIZE + PROTO_SNAPSHOT_HEAD_SIZE + 999 * PROTO_SNAPSHOT_ENTRY_SIZE + 12,
           0x7f800000u);
    assert_int_equal(proto_frame_parse(big, w.len, PROTO_MAX_LEN, &f), PROTO_OK);
    assert_int_equal(proto_decode(&f, &m), PROTO_ERR_NOT_FINITE);
}

static void test_avatar_left_reason(void **state)
{
    uint8_t p[5] = {1, 0, 0, 0, 0};

    (void)state;
    for (unsigned r = 0; r <= 255; r++) {
        p[4] = (uint8_t)r;
        assert_int_equal(decode_raw(PROTO_AVATAR_LEFT, p, 5),
                         r <= PROTO_LEFT_DISCONNECTED ? PROTO_OK : PROTO_ERR_BAD_VALUE);
    }
}

static void test_bye_reason(void **state)
{
    uint8_t p[1];

    (void)state;
    for (unsigned r = 0; r <= 255; r++) {
        p[0] = (uint8_t)r;
        assert_int_equal(decode_raw(PROTO_BYE, p, 1), r <= PROTO_BYE_KICKED ? PROTO_OK : PROTO_ERR_BAD_VALUE);
    }
}

/* Codes below 16 are local results and never travel; codes the receiver
 * does not know yet (up to 0xffff) are accepted for later versions. */
static void test_error_code(void **state)
{
    uint8_t p[3] = {0, 0, 0};

    (void)state;
    for (unsigned c = 0; c <= 0xffff; c++) {
        wr_u16(p, (uint16_t)c);
        assert_int_equal(decode_raw(PROTO_ERROR, p, 3), c < 16 ? PROTO_ERR_BAD_VALUE : PROTO_OK);
    }
}

/* The sample whose type is t. */
static const sample *sample_of(const sample *s, size_t n, uint16_t t)
{
    for (size_t i = 0; i < n; i++) {
        if (s[i].type == t)
            return &s[i];
    }
    fail_msg("no sample of type %u", t);
    return NULL;
}

/* total_size must be at least 1; up_axis is 0 (y) or 1 (z). */
static void test_upload_begin_values(void **state)
{
    sample s[NSAMPLES];
    size_t n = build_samples(s);
    const sample *ub = sample_of(s, n, PROTO_OBJECT_UPLOAD_BEGIN);
    uint8_t p[SAMPLE_MAX];
    const size_t up_at = 10 + ub->strs[0].len + ub->strs[1].len;

    (void)state;
    memcpy(p, ub->payload, ub->len);
    wr_u32(p + 4, 0);
    assert_int_equal(decode_raw(ub->type, p, ub->len), PROTO_ERR_BAD_VALUE);
    wr_u32(p + 4, 1);
    assert_int_equal(decode_raw(ub->type, p, ub->len), PROTO_OK);
    wr_u32(p + 4, UINT32_MAX); /* the server's cap, not the codec's */
    assert_int_equal(decode_raw(ub->type, p, ub->len), PROTO_OK);

    assert_int_equal(up_at, 18);
    for (unsigned a = 0; a <= 255; a++) {
        p[up_at] = (uint8_t)a;
        assert_int_equal(decode_raw(ub->type, p, ub->len), a <= PROTO_UP_Z ? PROTO_OK : PROTO_ERR_BAD_VALUE);
    }
}

/* A chunk's data is everything after its 8-byte head: none is short, 1 to
 * PROTO_CHUNK_MAX bytes decode, more is a bad value (not trailing bytes). */
static void test_upload_chunk_sizes(void **state)
{
    static uint8_t p[PROTO_MAX_LEN - 2];
    const size_t sizes[] = {9, 10, 100, 8 + PROTO_CHUNK_MAX - 1, 8 + PROTO_CHUNK_MAX};
    const size_t over[] = {8 + PROTO_CHUNK_MAX + 1, 8 + PROTO_CHUNK_MAX + 17, 2 * PROTO_CHUNK_MAX,
                           PROTO_MAX_LEN - 2};
    proto_msg m;

    (void)state;
    memset(p, 0xab, sizeof p);
    wr_u32(p, 77);
    wr_u32(p + 4, 0xffffffffu);
    for (size_t k = 0; k <= 8; k++)
        assert_int_equal(decode_raw(PROTO_OBJECT_UPLOAD_CHUNK, p, k), PROTO_ERR_SHORT);
    for (size_t i = 0; i < sizeof sizes / sizeof sizes[0]; i++) {
        assert_int_equal(decode_raw_msg(PROTO_OBJECT_UPLOAD_CHUNK, p, sizes[i], &m), PROTO_OK);
        assert_int_equal(m.u.upload_chunk.upload_id, 77);
        assert_int_equal(m.u.upload_chunk.offset, 0xffffffffu);
        assert_int_equal(m.u.upload_chunk.len, sizes[i] - 8);
    }
    for (size_t i = 0; i < sizeof over / sizeof over[0]; i++)
        assert_int_equal(decode_raw(PROTO_OBJECT_UPLOAD_CHUNK, p, over[i]), PROTO_ERR_BAD_VALUE);
    /* An id 0 comes first, whatever the size. */
    wr_u32(p, 0);
    for (size_t k = 4; k <= 9; k++)
        assert_int_equal(decode_raw(PROTO_OBJECT_UPLOAD_CHUNK, p, k), PROTO_ERR_BAD_VALUE);
    assert_int_equal(decode_raw(PROTO_OBJECT_UPLOAD_CHUNK, p, 8 + PROTO_CHUNK_MAX + 1), PROTO_ERR_BAD_VALUE);
}

/* Builds an object_info payload at p with count announced, nboxes boxes
 * present (min 0,0,0, max 1,1,1) and returns its length. */
static size_t info_payload(uint8_t *p, uint16_t count, size_t nboxes)
{
    size_t at = 0;

    wr_u32(p, 1);
    wr_u32(p + 4, 0);
    p[8] = 1;
    p[9] = 'a';
    p[10] = 1;
    p[11] = 'b';
    at = 12;
    for (int i = 0; i < 4; i++, at += 4)
        wr_f32(p + at, 0.0f);
    wr_f32(p + at, 1.0f); /* scale */
    at += 4;
    wr_u32(p + at, 1);
    wr_u32(p + at + 4, 12);
    memset(p + at + 8, 0x5a, PROTO_MESH_HASH_SIZE);
    wr_u16(p + at + 8 + PROTO_MESH_HASH_SIZE, count);
    at += 10 + PROTO_MESH_HASH_SIZE;
    assert_int_equal(at, 74);
    for (size_t i = 0; i < nboxes; i++) {
        for (int k = 0; k < 3; k++, at += 4)
            wr_f32(p + at, 0.0f);
        for (int k = 0; k < 3; k++, at += 4)
            wr_f32(p + at, 1.0f);
    }
    return at;
}

/* The payload holds exactly box_count boxes; box_count is at most
 * PROTO_OBJECT_BOXES_MAX; in each box max >= min on every axis. */
static void test_object_info_boxes(void **state)
{
    static uint8_t p[PROTO_MAX_LEN];
    const size_t e = PROTO_BOX_ENTRY_SIZE;
    size_t len;

    (void)state;
    len = info_payload(p, 0, 0);
    assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len), PROTO_OK);
    assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len + e), PROTO_ERR_TRAILING);
    len = info_payload(p, 2, 3);
    assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len - 2 * e), PROTO_ERR_SHORT);
    assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len - e - 1), PROTO_ERR_SHORT);
    assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len - e), PROTO_OK);
    assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len), PROTO_ERR_TRAILING);

    len = info_payload(p, PROTO_OBJECT_BOXES_MAX, PROTO_OBJECT_BOXES_MAX);
    assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len), PROTO_OK);
    /* Over the cap even with every box there, or with none. */
    len = info_payload(p, PROTO_OBJECT_BOXES_MAX + 1, PROTO_OBJECT_BOXES_MAX + 1);
    assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len), PROTO_ERR_BAD_VALUE);
    assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, 74), PROTO_ERR_BAD_VALUE);
    len = info_payload(p, 0xffff, 0);
    assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len), PROTO_ERR_BAD_VALUE);

    /* min > max on each axis of box 1 of 2; equal is a flat box. */
    for (size_t k = 0; k < 3; k++) {
        len = info_payload(p, 2, 2);
        wr_f32(p + 74 + e + 4 * k, 1.5f);
        assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len), PROTO_ERR_BAD_VALUE);
        wr_f32(p + 74 + e + 4 * k, 1.0f);
        assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len), PROTO_OK);
        wr_f32(p + 74 + e + 12 + 4 * k, -1.0f);
        assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len), PROTO_ERR_BAD_VALUE);
        wr_f32(p + 74 + e + 12 + 4 * k, -0.0f); /* min 1.0 */
        assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len), PROTO_ERR_BAD_VALUE);
    }
    /* -0.0 and 0.0 are equal: either may be min or max. */
    len = info_payload(p, 1, 1);
    wr_f32(p + 74, 0.0f);
    wr_f32(p + 74 + 12, -0.0f);
    assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len), PROTO_OK);
    wr_f32(p + 74, -0.0f);
    wr_f32(p + 74 + 12, 0.0f);
    assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len), PROTO_OK);
}

static void test_collision_inside(void **state)
{
    sample s[NSAMPLES];
    size_t n = build_samples(s);
    const sample *co = sample_of(s, n, PROTO_COLLISION);
    uint8_t p[SAMPLE_MAX];

    (void)state;
    memcpy(p, co->payload, co->len);
    for (unsigned v = 0; v <= 255; v++) {
        p[10] = (uint8_t)v;
        assert_int_equal(decode_raw(co->type, p, co->len), v <= 1 ? PROTO_OK : PROTO_ERR_BAD_VALUE);
    }
}

/* As in error: codes below 16 never travel, later codes are accepted. */
static void test_object_rejected_code(void **state)
{
    uint8_t p[7] = {5, 0, 0, 0, 0, 0, 0};

    (void)state;
    for (unsigned c = 0; c <= 0xffff; c++) {
        wr_u16(p + 4, (uint16_t)c);
        assert_int_equal(decode_raw(PROTO_OBJECT_REJECTED, p, 7), c < 16 ? PROTO_ERR_BAD_VALUE : PROTO_OK);
    }
}

/* With several problems the first in field order wins. */
static void test_first_failure_wins(void **state)
{
    uint8_t p[64];

    (void)state;
    /* join: empty name, then a NaN box */
    p[0] = 0;
    wr_u32(p + 1, 0x7fc00000u);
    assert_int_equal(decode_raw(PROTO_JOIN, p, 13), PROTO_ERR_BAD_STRING);
    /* join: box.x out of range, box.y NaN / box.x NaN, box.y out of range */
    p[0] = 1;
    p[1] = 'a';
    wr_f32(p + 2, 0.0f);
    wr_u32(p + 6, 0x7fc00000u);
    wr_f32(p + 10, 1.0f);
    assert_int_equal(decode_raw(PROTO_JOIN, p, 14), PROTO_ERR_BAD_VALUE);
    wr_u32(p + 2, 0x7fc00000u);
    wr_f32(p + 6, 0.0f);
    assert_int_equal(decode_raw(PROTO_JOIN, p, 14), PROTO_ERR_NOT_FINITE);
    /* ...and both before trailing bytes */
    assert_int_equal(decode_raw(PROTO_JOIN, p, 20), PROTO_ERR_NOT_FINITE);
    /* move: NaN x, then the payload ends */
    wr_u32(p, 1);
    wr_u32(p + 4, 0xff800000u);
    assert_int_equal(decode_raw(PROTO_MOVE, p, 10), PROTO_ERR_NOT_FINITE);
    /* hello: bad magic, then short or trailing */
    wr_u32(p, 0);
    assert_int_equal(decode_raw(PROTO_HELLO, p, 5), PROTO_ERR_BAD_MAGIC);
    assert_int_equal(decode_raw(PROTO_HELLO, p, 9), PROTO_ERR_BAD_MAGIC);
    /* avatar_left / bye: bad reason, then trailing */
    memset(p, 9, 8);
    assert_int_equal(decode_raw(PROTO_AVATAR_LEFT, p, 8), PROTO_ERR_BAD_VALUE);
    assert_int_equal(decode_raw(PROTO_BYE, p, 3), PROTO_ERR_BAD_VALUE);
    /* error: bad code, then a string past the end */
    wr_u16(p, 3);
    p[2] = 50;
    assert_int_equal(decode_raw(PROTO_ERROR, p, 5), PROTO_ERR_BAD_VALUE);
    /* snapshot: NaN in entry 0 though the count promises more than is there */
    memset(p, 0, sizeof p);
    wr_u16(p + 8, 3);
    wr_u32(p + 14, 0x7fc00000u);
    assert_int_equal(decode_raw(PROTO_SNAPSHOT, p, 26), PROTO_ERR_NOT_FINITE);
}

/* The same rule for the object messages. */
static void test_first_failure_wins_objects(void **state)
{
    static uint8_t p[PROTO_MAX_LEN];
    sample s[NSAMPLES];
    size_t n = build_samples(s), len;
    const sample *ub = sample_of(s, n, PROTO_OBJECT_UPLOAD_BEGIN);
    const sample *pl = sample_of(s, n, PROTO_OBJECT_PLACE);
    const sample *co = sample_of(s, n, PROTO_COLLISION);

    (void)state;
    /* upload_begin: total_size 0, then an empty name */
    memcpy(p, ub->payload, ub->len);
    wr_u32(p + 4, 0);
    p[8] = 0;
    assert_int_equal(decode_raw(ub->type, p, ub->len), PROTO_ERR_BAD_VALUE);
    /* upload_begin: an upper-case format, then up_axis 7 and a NaN scale */
    memcpy(p, ub->payload, ub->len);
    p[15] = 'O';
    p[18] = 7;
    wr_u32(p + 19, 0x7fc00000u);
    assert_int_equal(decode_raw(ub->type, p, ub->len), PROTO_ERR_BAD_STRING);
    /* ...up_axis 7 then the NaN */
    p[15] = 'o';
    assert_int_equal(decode_raw(ub->type, p, ub->len), PROTO_ERR_BAD_VALUE);
    /* ...the NaN, then the payload ends early or runs on */
    p[18] = 0;
    assert_int_equal(decode_raw(ub->type, p, ub->len + 5), PROTO_ERR_NOT_FINITE);
    /* upload_begin: a format past the end is a bad string, not short */
    p[14] = 8;
    assert_int_equal(decode_raw(ub->type, p, 17), PROTO_ERR_BAD_STRING);

    /* place: NaN yaw, then scale 0; scale 0, then trailing bytes */
    memcpy(p, pl->payload, pl->len);
    wr_u32(p + 16, 0x7f800000u);
    wr_f32(p + 20, 0.0f);
    assert_int_equal(decode_raw(pl->type, p, pl->len), PROTO_ERR_NOT_FINITE);
    wr_f32(p + 16, 1.0f);
    assert_int_equal(decode_raw(pl->type, p, pl->len + 3), PROTO_ERR_BAD_VALUE);
    /* place: id 0, then the payload ends */
    wr_u32(p, 0);
    assert_int_equal(decode_raw(pl->type, p, 6), PROTO_ERR_BAD_VALUE);

    /* object_info: box 0 min.x > max.x, then a NaN at max.y: the x axis is
     * wrong first */
    len = info_payload(p, 2, 2);
    wr_f32(p + 74, 5.0f);
    wr_u32(p + 74 + 16, 0x7fc00000u);
    assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len), PROTO_ERR_BAD_VALUE);
    /* ...but a NaN at max.x itself is found before the comparison */
    wr_u32(p + 74 + 12, 0x7fc00000u);
    assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len), PROTO_ERR_NOT_FINITE);
    /* object_info: min > max in box 0, and box 1 cut short */
    len = info_payload(p, 2, 2);
    wr_f32(p + 74 + 4, 5.0f);
    assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len - 10), PROTO_ERR_BAD_VALUE);
    /* object_info: a count over the cap, and no boxes at all */
    len = info_payload(p, 2000, 0);
    assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len), PROTO_ERR_BAD_VALUE);
    /* object_info: an empty owner, then ecm_version 0 */
    len = info_payload(p, 0, 0);
    p[8] = 0;
    assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len), PROTO_ERR_BAD_STRING);
    /* object_info: scale out of range, then ecm_version 0 */
    len = info_payload(p, 0, 0);
    wr_f32(p + 28, 2000.0f);
    wr_u32(p + 32, 0);
    assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len), PROTO_ERR_BAD_VALUE);
    wr_f32(p + 28, 1.0f);
    assert_int_equal(decode_raw(PROTO_OBJECT_INFO, p, len), PROTO_ERR_BAD_VALUE);

    /* chunk: id 0 and no data */
    wr_u32(p, 0);
    wr_u32(p + 4, 0);
    assert_int_equal(decode_raw(PROTO_OBJECT_UPLOAD_CHUNK, p, 8), PROTO_ERR_BAD_VALUE);

    /* collision: inside 2, then a NaN point; a NaN normal, then trailing */
    memcpy(p, co->payload, co->len);
    p[10] = 2;
    wr_u32(p + 11, 0x7fc00000u);
    assert_int_equal(decode_raw(co->type, p, co->len), PROTO_ERR_BAD_VALUE);
    memcpy(p, co->payload, co->len);
    wr_u32(p + 31, 0xff800000u);
    assert_int_equal(decode_raw(co->type, p, co->len + 1), PROTO_ERR_NOT_FINITE);

    /* object_rejected: a bad code, then a message past the end */
    wr_u32(p, 5);
    wr_u16(p + 4, 15);
    p[6] = 100;
    assert_int_equal(decode_raw(PROTO_OBJECT_REJECTED, p, 9), PROTO_ERR_BAD_VALUE);
}

/* ---- names of things ---------------------------------------------------- */

static void test_strerror_total(void **state)
{
    const char *unknown = proto_strerror(-1);
    const int known[] = {PROTO_OK, PROTO_INCOMPLETE, 16, 17, 18, 19, 20, 21, 22, 23, 24,
                         25, 26, 27, 28, 29, 30, 32, 34, 35, 36, 37, 38, 39, 40, 41, 42, 43, 44};

    (void)state;
    for (int s = -2000; s <= 2000; s++) {
        assert_non_null(proto_strerror(s));
        assert_true(proto_strerror(s)[0] != '\0');
    }
    assert_non_null(proto_strerror(INT_MIN));
    assert_non_null(proto_strerror(INT_MAX));
    assert_ptr_equal(proto_strerror(2), unknown);
    assert_ptr_equal(proto_strerror(15), unknown);
    assert_ptr_equal(proto_strerror(31), unknown); /* reserved */
    assert_ptr_equal(proto_strerror(33), unknown);
    assert_ptr_equal(proto_strerror(45), unknown);
    for (size_t i = 0; i < sizeof known / sizeof known[0]; i++) {
        assert_true(proto_strerror(known[i]) != unknown);
        for (size_t j = 0; j < i; j++)
            assert_string_not_equal(proto_strerror(known[i]), proto_strerror(known[j]));
    }
}

static void test_type_names(void **state)
{
    static const char *want[] = {NULL, "hello", "welcome", "join", "join_ok", "move", "snapshot",
                                 "avatar_joined", "avatar_left", "error", "ping", "pong", "bye",
                                 "avatar_pose"};
    static const struct {
        uint16_t type;
        const char *name;
    } objects[] = {
        {PROTO_OBJECT_UPLOAD_BEGIN, "object_upload_begin"},
        {PROTO_OBJECT_UPLOAD_CHUNK, "object_upload_chunk"},
        {PROTO_OBJECT_UPLOAD_END, "object_upload_end"},
        {PROTO_OBJECT_PLACE, "object_place"},
        {PROTO_OBJECT_MOVE, "object_move"}, /* reserved, but named */
        {PROTO_OBJECT_REMOVE, "object_remove"},
        {PROTO_OBJECT_INFO, "object_info"},
        {PROTO_OBJECT_REMOVED, "object_removed"},
        {PROTO_OBJECT_REJECTED, "object_rejected"},
        {PROTO_MESH_REQUEST, "mesh_request"},
        {PROTO_MESH_CHUNK, "mesh_chunk"},
        {PROTO_COLLISION, "collision"},
        {PROTO_ECM_UPDATE, "ecm_update"},
        {PROTO_ADMIN_REQUEST, "admin_request"},
        {PROTO_ADMIN_REPLY, "admin_reply"},
    };
    const uint16_t unknown[] = {0, 14, 31, 43, 47, 50, 63, 66, 79, 80, 0xffff};

    (void)state;
    for (uint16_t t = PROTO_HELLO; t <= PROTO_AVATAR_POSE; t++)
        assert_string_equal(proto_type_name(t), want[t]);
    for (size_t i = 0; i < sizeof objects / sizeof objects[0]; i++)
        assert_string_equal(proto_type_name(objects[i].type), objects[i].name);
    for (size_t i = 0; i < sizeof unknown / sizeof unknown[0]; i++)
        assert_string_equal(proto_type_name(unknown[i]), "unknown");
    for (uint32_t t = 0; t <= 0xffff; t++)
        assert_non_null(proto_type_name((uint16_t)t));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_hello_roundtrip),
        cmocka_unit_test(test_welcome_roundtrip),
        cmocka_unit_test(test_join_roundtrip),
        cmocka_unit_test(test_join_credentials),
        cmocka_unit_test(test_join_ok_roundtrip),
        cmocka_unit_test(test_pose_roundtrip),
        cmocka_unit_test(test_pose_quantize),
        cmocka_unit_test(test_pose_refusals),
        cmocka_unit_test(test_move_roundtrip),
        cmocka_unit_test(test_snapshot_empty),
        cmocka_unit_test(test_snapshot_one),
        cmocka_unit_test(test_snapshot_many),
        cmocka_unit_test(test_snapshot_max_entries),
        cmocka_unit_test(test_avatar_joined_roundtrip),
        cmocka_unit_test(test_avatar_left_roundtrip),
        cmocka_unit_test(test_error_roundtrip),
        cmocka_unit_test(test_ping_pong_roundtrip),
        cmocka_unit_test(test_bye_roundtrip),
        cmocka_unit_test(test_upload_begin_roundtrip),
        cmocka_unit_test(test_upload_chunk_roundtrip),
        cmocka_unit_test(test_upload_end_roundtrip),
        cmocka_unit_test(test_object_place_roundtrip),
        cmocka_unit_test(test_object_remove_roundtrip),
        cmocka_unit_test(test_object_info_no_boxes),
        cmocka_unit_test(test_object_info_one_box),
        cmocka_unit_test(test_object_info_max_boxes),
        cmocka_unit_test(test_object_rejected_roundtrip),
        cmocka_unit_test(test_collision_roundtrip),
        cmocka_unit_test(test_max_sizes),
        cmocka_unit_test(test_object_string_truncation),
        cmocka_unit_test(test_name_truncation),
        cmocka_unit_test(test_error_message_cleaning),
        cmocka_unit_test(test_empty_name_encodes),
        cmocka_unit_test(test_stream_of_frames),
        cmocka_unit_test(test_worked_examples),
        cmocka_unit_test(test_writer_exact_fit),
        cmocka_unit_test(test_writer_overflow_first_frame),
        cmocka_unit_test(test_writer_overflow_sticky),
        cmocka_unit_test(test_writer_null_buffer),
        cmocka_unit_test(test_writer_chunk_over_max),
        cmocka_unit_test(test_writer_info_over_max),
        cmocka_unit_test(test_bad_objects_encode),
        cmocka_unit_test(test_snapshot_begin_no_room),
        cmocka_unit_test(test_snapshot_add_no_room),
        cmocka_unit_test(test_snapshot_after_frames),
        cmocka_unit_test(test_frame_incomplete_length),
        cmocka_unit_test(test_frame_empty),
        cmocka_unit_test(test_frame_too_long),
        cmocka_unit_test(test_frame_at_cap),
        cmocka_unit_test(test_frame_incomplete_header_and_payload),
        cmocka_unit_test(test_unknown_and_reserved_types),
        cmocka_unit_test(test_short_every_type),
        cmocka_unit_test(test_trailing_every_type),
        cmocka_unit_test(test_not_finite_every_float),
        cmocka_unit_test(test_box_range),
        cmocka_unit_test(test_scale_range),
        cmocka_unit_test(test_zero_ids),
        cmocka_unit_test(test_zero_where_allowed),
        cmocka_unit_test(test_name_rules),
        cmocka_unit_test(test_message_rules),
        cmocka_unit_test(test_format_rules),
        cmocka_unit_test(test_string_past_end),
        cmocka_unit_test(test_hello_magic),
        cmocka_unit_test(test_welcome_values),
        cmocka_unit_test(test_snapshot_count_mismatch),
        cmocka_unit_test(test_snapshot_late_nan),
        cmocka_unit_test(test_avatar_left_reason),
        cmocka_unit_test(test_bye_reason),
        cmocka_unit_test(test_error_code),
        cmocka_unit_test(test_upload_begin_values),
        cmocka_unit_test(test_upload_chunk_sizes),
        cmocka_unit_test(test_object_info_boxes),
        cmocka_unit_test(test_collision_inside),
        cmocka_unit_test(test_object_rejected_code),
        cmocka_unit_test(test_first_failure_wins),
        cmocka_unit_test(test_first_failure_wins_objects),
        cmocka_unit_test(test_strerror_total),
        cmocka_unit_test(test_type_names),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
