/*
 * proto.c: the cvre wire codec (see proto.h for the API, PROTOCOL.md for the
 * bytes).
 *
 * Every field goes through the little-endian load/store helpers below; no
 * struct is ever laid over the buffer, so the code does not depend on the
 * host's byte order, alignment or padding. Decoding uses a reader whose
 * first failure sticks: each field read after a failure yields zero and
 * changes nothing, so a decoder reads its whole layout and checks the status
 * once, and the status always names the first problem in field order.
 */
#include "proto.h"
#include "le.h"
#include "utf8.h"

#include <assert.h>
#include <math.h>
#include <string.h>

_Static_assert(sizeof(float) == sizeof(uint32_t), "floats travel as IEEE-754 binary32");
_Static_assert(PROTO_MAX_LEN_PREJOIN <= PROTO_MAX_LEN, "the pre-join cap is the smaller one");
_Static_assert(PROTO_MESSAGE_MAX <= 0xffu && PROTO_NAME_MAX <= 0xffu && PROTO_OBJECT_NAME_MAX <= 0xffu &&
                   PROTO_FORMAT_MAX <= 0xffu,
               "string lengths are a u8");
_Static_assert(PROTO_SIZE_SNAPSHOT(PROTO_SNAPSHOT_MAX_ENTRIES) - 4u <= PROTO_MAX_LEN,
               "a full snapshot fits the cap");
_Static_assert(PROTO_SIZE_OBJECT_INFO(PROTO_OBJECT_BOXES_MAX) - 4u <= PROTO_MAX_LEN,
               "an object info with every box and the longest strings fits the cap");

/* Offsets inside an encoded snapshot frame, from the start of the frame. */
#define SNAP_COUNT_AT (PROTO_HEADER_SIZE + 8u)
#define SNAP_ENTRIES_AT (PROTO_HEADER_SIZE + PROTO_SNAPSHOT_HEAD_SIZE)

/* ---- stores that advance a cursor, over le.h ---------------------------- */

static inline float bits_to_f32(uint32_t b)
{
    float v;
    memcpy(&v, &b, sizeof v);
    return v;
}

/* True unless the exponent bits are all ones (NaN or infinity). Looking at
 * the bits rather than calling isfinite() keeps the test exact whatever
 * floating-point flags the codec is built with. */
static inline int bits_finite(uint32_t b) { return (b & 0x7f800000u) != 0x7f800000u; }

static inline uint8_t *st_u8(uint8_t *p, uint8_t v)
{
    p[0] = v;
    return p + 1;
}

static inline uint8_t *st_u16(uint8_t *p, uint16_t v)
{
    le_put_u16(p, v);
    return p + 2;
}

static inline uint8_t *st_u32(uint8_t *p, uint32_t v)
{
    le_put_u32(p, v);
    return p + 4;
}

static inline uint8_t *st_u64(uint8_t *p, uint64_t v)
{
    le_put_u64(p, v);
    return p + 8;
}

static inline uint8_t *st_f32(uint8_t *p, float v)
{
    le_put_f32(p, v);
    return p + 4;
}

static inline uint8_t *st_vec3(uint8_t *p, const float v[3])
{
    p = st_f32(p, v[0]);
    p = st_f32(p, v[1]);
    return st_f32(p, v[2]);
}

static inline uint8_t *st_bytes(uint8_t *p, const void *src, size_t n)
{
    if (n > 0)
        memcpy(p, src, n);
    return p + n;
}

/* ---- UTF-8 ------------------------------------------------------------ */

/* Rejecting overlong forms, surrogates and values past U+10FFFF (see
 * proto.h) keeps one byte form per character, so names compare equal
 * exactly when their bytes do. */
/* Control characters would let a peer forge lines in our logs or mangle a
 * terminal; NUL would end the string early for C callers. */
static inline int is_control(uint32_t cp) { return cp < 0x20u || cp == 0x7fu; }

/* True when s[0..n) is well-formed UTF-8 without control characters, the
 * rule for every string on the wire. */
static int text_ok(const uint8_t *s, size_t n)
{
    size_t i = 0;

    while (i < n) {
        uint32_t cp;
        size_t k = utf8_next(s + i, n - i, &cp);

        if (k == 0 || is_control(cp))
            return 0;
        i += k;
    }
    return 1;
}

/* ---- reader ----------------------------------------------------------- */

typedef struct reader {
    const uint8_t *p;
    size_t left;
    int err; /* PROTO_OK or the first failure */
} reader;

/* Records status unless an earlier failure already did: the first wins. */
static void reader_reject(reader *r, int status)
{
    if (r->err == PROTO_OK)
        r->err = status;
}

/* Consumes n bytes and returns where they start, or returns NULL when the
 * reader has failed or fewer than n bytes remain (PROTO_ERR_SHORT). */
static const uint8_t *take(reader *r, size_t n)
{
    const uint8_t *p = r->p;

    if (r->err != PROTO_OK)
        return NULL;
    if (n > r->left) {
        r->err = PROTO_ERR_SHORT;
        return NULL;
    }
    if (n > 0) {
        r->p += n;
        r->left -= n;
    }
    return p;
}

static uint8_t get_u8(reader *r)
{
    const uint8_t *p = take(r, 1);
    return p ? p[0] : 0;
}

static uint16_t get_u16(reader *r)
{
    const uint8_t *p = take(r, 2);
    return p ? le_get_u16(p) : 0;
}

static uint32_t get_u32(reader *r)
{
    const uint8_t *p = take(r, 4);
    return p ? le_get_u32(p) : 0;
}

static uint64_t get_u64(reader *r)
{
    const uint8_t *p = take(r, 8);
    return p ? le_get_u64(p) : 0;
}

/* Every float on the wire must be finite: a NaN compares false with every
 * bound, so it would slip through the clamps and range checks written the
 * usual way in the server, and an infinity would defeat the speed limit. */
static float get_f32(reader *r)
{
    uint32_t b = get_u32(r);

    if (!bits_finite(b)) {
        reader_reject(r, PROTO_ERR_NOT_FINITE);
        return 0.0f;
    }
    return bits_to_f32(b);
}

static void get_vec3(reader *r, float v[3])
{
    for (int i = 0; i < 3; i++)
        v[i] = get_f32(r);
}

/* A box edge out of range fails at the edge that is wrong, so the status
 * still names the first bad field. */
static void get_box(reader *r, float box[3])
{
    for (int i = 0; i < 3; i++) {
        box[i] = get_f32(r);
        if (!(box[i] >= PROTO_BOX_MIN && box[i] <= PROTO_BOX_MAX))
            reader_reject(r, PROTO_ERR_BAD_VALUE);
    }
}

/*
 * Reads a u8 length and that many bytes of text, min..max bytes long. A
 * missing length byte is PROTO_ERR_SHORT; a length past the end of the
 * payload, out of bounds, or bytes that break the text rule are
 * PROTO_ERR_BAD_STRING. The result points into the payload.
 */
static proto_str get_str(reader *r, uint32_t min, uint32_t max)
{
    proto_str s = {NULL, 0};
    uint8_t n = get_u8(r);

    if (r->err != PROTO_OK)
        return s;
    if (n > r->left || n < min || n > max || !text_ok(r->p, n)) {
        reader_reject(r, PROTO_ERR_BAD_STRING);
        return s;
    }
    s.ptr = (const char *)take(r, n);
    s.len = n;
    return s;
}

/* ---- framing and decoding --------------------------------------------- */

int proto_frame_parse(const uint8_t *buf, size_t avail, uint32_t max_len, proto_frame *f)
{
    uint32_t len;

    if (avail < 4)
        return PROTO_INCOMPLETE;
    len = le_get_u32(buf);
    if (len < PROTO_LEN_MIN)
        return PROTO_ERR_FRAME_EMPTY;
    if (len > max_len)
        return PROTO_ERR_FRAME_TOO_LONG;
    /* avail >= 4 here, so the subtraction cannot wrap and nothing is added
     * to a length the peer chose. */
    if (avail - 4 < len)
        return PROTO_INCOMPLETE;
    f->type = le_get_u16(buf + 4);
    f->payload = buf + PROTO_HEADER_SIZE;
    f->payload_len = len - 2;
    f->size = (size_t)len + 4;
    return PROTO_OK;
}

static void decode_hello(reader *r, proto_hello *m)
{
    m->magic = get_u32(r);
    if (m->magic != PROTO_MAGIC)
        reader_reject(r, PROTO_ERR_BAD_MAGIC);
    m->version = get_u16(r);
}

/* Beyond finiteness, a welcome must describe a usable world: a client
 * divides by the tick rate and builds its view from the radius and bounds. */
static void decode_welcome(reader *r, proto_welcome *m)
{
    const uint8_t *token;

    m->version = get_u16(r);
    m->session_id = get_u64(r);
    token = take(r, PROTO_TOKEN_SIZE);
    if (token)
        memcpy(m->token, token, PROTO_TOKEN_SIZE);
    m->tick_hz = get_u16(r);
    if (m->tick_hz == 0)
        reader_reject(r, PROTO_ERR_BAD_VALUE);
    m->aoi_radius = get_f32(r);
    if (!(m->aoi_radius > 0.0f))
        reader_reject(r, PROTO_ERR_BAD_VALUE);
    m->max_speed = get_f32(r);
    if (!(m->max_speed >= 0.0f))
        reader_reject(r, PROTO_ERR_BAD_VALUE);
    get_vec3(r, m->world_min);
    for (int i = 0; i < 3; i++) {
        m->world_max[i] = get_f32(r);
        if (!(m->world_max[i] >= m->world_min[i]))
            reader_reject(r, PROTO_ERR_BAD_VALUE);
    }
    m->idle_timeout_ms = get_u32(r);
    if (m->idle_timeout_ms == 0)
        reader_reject(r, PROTO_ERR_BAD_VALUE);
}

static void decode_snapshot(reader *r, proto_snapshot *m)
{
    m->tick = get_u32(r);
    m->ack_seq = get_u32(r);
    m->count = get_u16(r);
    m->entries = r->p;
    /* Reading each entry, rather than comparing sizes up front, keeps the
     * first-failure-in-field-order rule: a NaN in entry 0 is reported even
     * if the payload also ends before the last entry. */
    for (uint16_t i = 0; i < m->count && r->err == PROTO_OK; i++) {
        float pos[3];

        (void)get_u32(r);
        get_vec3(r, pos);
    }
}

static void get_transform(reader *r, proto_transform *t)
{
    get_vec3(r, t->pos);
    t->yaw = get_f32(r);
    t->scale = get_f32(r);
    if (!(t->scale >= PROTO_SCALE_MIN && t->scale <= PROTO_SCALE_MAX))
        reader_reject(r, PROTO_ERR_BAD_VALUE);
}

/* A non-zero id: zero is kept free to mean "none" (object_info.upload_id). */
static uint32_t get_id(reader *r)
{
    uint32_t id = get_u32(r);
    if (id == 0)
        reader_reject(r, PROTO_ERR_BAD_VALUE);
    return id;
}

static void decode_upload_begin(reader *r, proto_upload_begin *m)
{
    m->upload_id = get_id(r);
    m->total_size = get_u32(r);
    if (m->total_size == 0)
        reader_reject(r, PROTO_ERR_BAD_VALUE);
    m->name = get_str(r, 1, PROTO_OBJECT_NAME_MAX);
    m->format = get_str(r, 0, PROTO_FORMAT_MAX);
    /* A format is a file extension: anything else is no format. */
    for (uint32_t i = 0; r->err == PROTO_OK && i < m->format.len; i++) {
        char ch = m->format.ptr[i];
        if (!((ch >= 'a' && ch <= 'z') || (ch >= '0' && ch <= '9')))
            reader_reject(r, PROTO_ERR_BAD_STRING);
    }
    m->up_axis = get_u8(r);
    if (m->up_axis > PROTO_UP_Z)
        reader_reject(r, PROTO_ERR_BAD_VALUE);
    m->unit_scale = get_f32(r);
    if (!(m->unit_scale >= PROTO_SCALE_MIN && m->unit_scale <= PROTO_SCALE_MAX))
        reader_reject(r, PROTO_ERR_BAD_VALUE);
}

static void decode_upload_chunk(reader *r, proto_upload_chunk *m)
{
    m->upload_id = get_id(r);
    m->offset = get_u32(r);
    m->len = (uint32_t)r->left;
    if (r->err == PROTO_OK && (m->len == 0 || m->len > PROTO_CHUNK_MAX))
        reader_reject(r, m->len ? PROTO_ERR_BAD_VALUE : PROTO_ERR_SHORT);
    m->data = take(r, m->len);
}

static void decode_object_info(reader *r, proto_object_info *m)
{
    m->object_id = get_id(r);
    m->upload_id = get_u32(r);
    m->owner = get_str(r, 1, PROTO_NAME_MAX);
    m->name = get_str(r, 1, PROTO_OBJECT_NAME_MAX);
    get_transform(r, &m->at);
    m->ecm_version = get_id(r);
    m->tri_count = get_u32(r);
    const uint8_t *hash = take(r, PROTO_MESH_HASH_SIZE);
    if (hash)
        memcpy(m->mesh_hash, hash, PROTO_MESH_HASH_SIZE);
    m->box_count = get_u16(r);
    if (m->box_count > PROTO_OBJECT_BOXES_MAX)
        reader_reject(r, PROTO_ERR_BAD_VALUE);
    m->boxes = r->p;
    /* Each max is compared with its min right after it is read, as for
     * WELCOME's world bounds, so the status names the first bad field. */
    for (uint16_t i = 0; i < m->box_count && r->err == PROTO_OK; i++) {
        float lo[3];

        get_vec3(r, lo);
        for (int k = 0; k < 3; k++) {
            float hi = get_f32(r);
            if (!(lo[k] <= hi))
                reader_reject(r, PROTO_ERR_BAD_VALUE);
        }
    }
}

static void decode_mesh_request(reader *r, proto_mesh_request *m)
{
    m->object_id = get_id(r);
    const uint8_t *hash = take(r, PROTO_MESH_HASH_SIZE);
    if (hash)
        memcpy(m->mesh_hash, hash, PROTO_MESH_HASH_SIZE);
}

/* Like an upload chunk, the data runs to the end of the frame; it must lie
 * within the mesh's total, so a receiver can size its buffer from total
 * once and never grow it. */
static void decode_mesh_chunk(reader *r, proto_mesh_chunk *m)
{
    m->object_id = get_id(r);
    m->total = get_u32(r);
    if (m->total == 0)
        reader_reject(r, PROTO_ERR_BAD_VALUE);
    m->offset = get_u32(r);
    if (m->offset >= m->total)
        reader_reject(r, PROTO_ERR_BAD_VALUE);
    m->len = (uint32_t)r->left;
    if (r->err == PROTO_OK && (m->len == 0 || m->len > PROTO_MESH_CHUNK_MAX || m->len > m->total - m->offset))
        reader_reject(r, m->len ? PROTO_ERR_BAD_VALUE : PROTO_ERR_SHORT);
    m->data = take(r, m->len);
}

static void decode_collision(reader *r, proto_collision *m)
{
    m->object_id = get_id(r);
    m->ecm_version = get_id(r);
    m->box_index = get_u16(r);
    m->inside = get_u8(r);
    if (m->inside > 1)
        reader_reject(r, PROTO_ERR_BAD_VALUE);
    get_vec3(r, m->point);
    get_vec3(r, m->normal);
}

static int16_t get_i16(reader *r) { return (int16_t)get_u16(r); }

/* A pose (PROTOCOL.md, section 1): the facing, then the parts the bits
 * name, each checked right after it is read: the head within
 * PROTO_POSE_HEAD_RANGE_MM of the avatar, a hand within PROTO_POSE_REACH_MM
 * of the head, every quaternion of unit length within tolerance. */
static void get_pose(reader *r, proto_pose *p)
{
    p->yaw = get_f32(r);
    p->pitch = get_f32(r);
    if (!(p->pitch >= -PROTO_PITCH_MAX && p->pitch <= PROTO_PITCH_MAX))
        reader_reject(r, PROTO_ERR_BAD_VALUE);
    p->parts = get_u8(r);
    if (p->parts >> PROTO_POSE_PARTS || (p->parts && !PROTO_POSE_HAS(p, PROTO_POSE_HEAD)))
        reader_reject(r, PROTO_ERR_BAD_VALUE);
    memset(p->pos, 0, sizeof p->pos);
    memset(p->rot, 0, sizeof p->rot);
    for (unsigned k = 0; k < PROTO_POSE_PARTS && r->err == PROTO_OK; k++) {
        if (!PROTO_POSE_HAS(p, k))
            continue;
        int64_t d2 = 0, q2 = 0;
        for (int i = 0; i < 3; i++) {
            p->pos[k][i] = get_i16(r);
            int64_t d = p->pos[k][i] - (k == PROTO_POSE_HEAD ? 0 : p->pos[PROTO_POSE_HEAD][i]);
            if (k == PROTO_POSE_HEAD && (d > PROTO_POSE_HEAD_RANGE_MM || d < -PROTO_POSE_HEAD_RANGE_MM))
                reader_reject(r, PROTO_ERR_BAD_VALUE);
            d2 += d * d;
        }
        if (k != PROTO_POSE_HEAD && d2 > (int64_t)PROTO_POSE_REACH_MM * PROTO_POSE_REACH_MM)
            reader_reject(r, PROTO_ERR_BAD_VALUE);
        for (int i = 0; i < 4; i++) {
            p->rot[k][i] = get_i16(r);
            q2 += (int64_t)p->rot[k][i] * p->rot[k][i];
        }
        double n2 = (double)q2 / ((double)PROTO_QUAT_ONE * PROTO_QUAT_ONE);
        if (!(fabs(n2 - 1.0) <= PROTO_QUAT_NORM2_TOLERANCE))
            reader_reject(r, PROTO_ERR_BAD_VALUE);
    }
}

/* A join and its optional credential: a kind, then 1..PROTO_PASSWORD_MAX
 * password bytes (any bytes: the store hashes them) or a token of exactly
 * PROTO_RESUME_TOKEN_SIZE. */
static void decode_join(reader *r, proto_join *m)
{
    m->name = get_str(r, 1, PROTO_NAME_MAX);
    get_box(r, m->box);
    m->credential = PROTO_CRED_NONE;
    m->secret = NULL;
    m->secret_len = 0;
    if (r->err != PROTO_OK || r->left == 0)
        return;
    m->credential = get_u8(r);
    m->secret_len = get_u8(r);
    if (r->err == PROTO_OK &&
        (m->credential == PROTO_CRED_PASSWORD ? m->secret_len < 1 || m->secret_len > PROTO_PASSWORD_MAX
         : m->credential == PROTO_CRED_TOKEN  ? m->secret_len != PROTO_RESUME_TOKEN_SIZE
                                              : 1))
        reader_reject(r, PROTO_ERR_BAD_VALUE);
    m->secret = take(r, m->secret_len);
}

int proto_decode(const proto_frame *f, proto_msg *m)
{
    reader rd = {f->payload, f->payload_len, PROTO_OK};
    reader *r = &rd;

    m->type = f->type;
    switch (f->type) {
    case PROTO_HELLO:
        decode_hello(r, &m->u.hello);
        break;
    case PROTO_WELCOME:
        decode_welcome(r, &m->u.welcome);
        break;
    case PROTO_JOIN:
        decode_join(r, &m->u.join);
        break;
    case PROTO_JOIN_OK:
        m->u.join_ok.avatar_id = get_u32(r);
        get_vec3(r, m->u.join_ok.pos);
        get_box(r, m->u.join_ok.box);
        m->u.join_ok.has_token = r->err == PROTO_OK && r->left > 0;
        if (m->u.join_ok.has_token) {
            const uint8_t *t = take(r, PROTO_RESUME_TOKEN_SIZE);
            if (t)
                memcpy(m->u.join_ok.token, t, PROTO_RESUME_TOKEN_SIZE);
        }
        break;
    case PROTO_MOVE:
        m->u.move.seq = get_u32(r);
        get_vec3(r, m->u.move.pos);
        m->u.move.has_pose = r->err == PROTO_OK && r->left > 0;
        if (m->u.move.has_pose)
            get_pose(r, &m->u.move.pose);
        break;
    case PROTO_AVATAR_POSE:
        m->u.avatar_pose.id = get_u32(r);
        get_pose(r, &m->u.avatar_pose.pose);
        break;
    case PROTO_SNAPSHOT:
        decode_snapshot(r, &m->u.snapshot);
        break;
    case PROTO_AVATAR_JOINED:
        m->u.avatar_joined.id = get_u32(r);
        m->u.avatar_joined.name = get_str(r, 1, PROTO_NAME_MAX);
        get_vec3(r, m->u.avatar_joined.pos);
        get_box(r, m->u.avatar_joined.box);
        break;
    case PROTO_AVATAR_LEFT:
        m->u.avatar_left.id = get_u32(r);
        m->u.avatar_left.reason = get_u8(r);
        if (m->u.avatar_left.reason > PROTO_LEFT_DISCONNECTED)
            reader_reject(r, PROTO_ERR_BAD_VALUE);
        break;
    case PROTO_ERROR:
        m->u.error.code = get_u16(r);
        if (m->u.error.code < PROTO_ERR_FRAME_EMPTY)
            reader_reject(r, PROTO_ERR_BAD_VALUE);
        m->u.error.message = get_str(r, 0, PROTO_MESSAGE_MAX);
        break;
    case PROTO_PING:
    case PROTO_PONG:
        m->u.ping.stamp = get_u64(r);
        break;
    case PROTO_BYE:
        m->u.bye.reason = get_u8(r);
        if (m->u.bye.reason > PROTO_BYE_KICKED)
            reader_reject(r, PROTO_ERR_BAD_VALUE);
        break;
    case PROTO_OBJECT_UPLOAD_BEGIN:
        decode_upload_begin(r, &m->u.upload_begin);
        break;
    case PROTO_OBJECT_UPLOAD_CHUNK:
        decode_upload_chunk(r, &m->u.upload_chunk);
        break;
    case PROTO_OBJECT_UPLOAD_END:
        m->u.upload_end.upload_id = get_id(r);
        get_transform(r, &m->u.upload_end.at);
        break;
    case PROTO_OBJECT_PLACE:
        m->u.object_place.object_id = get_id(r);
        get_transform(r, &m->u.object_place.at);
        break;
    case PROTO_OBJECT_REMOVE:
    case PROTO_OBJECT_REMOVED:
        m->u.object_id = get_id(r);
        break;
    case PROTO_OBJECT_INFO:
        decode_object_info(r, &m->u.object_info);
        break;
    case PROTO_OBJECT_REJECTED:
        m->u.object_rejected.request_id = get_u32(r);
        m->u.object_rejected.code = get_u16(r);
        if (m->u.object_rejected.code < PROTO_ERR_FRAME_EMPTY)
            reader_reject(r, PROTO_ERR_BAD_VALUE);
        m->u.object_rejected.message = get_str(r, 0, PROTO_MESSAGE_MAX);
        break;
    case PROTO_COLLISION:
        decode_collision(r, &m->u.collision);
        break;
    case PROTO_MESH_REQUEST:
        decode_mesh_request(r, &m->u.mesh_request);
        break;
    case PROTO_MESH_CHUNK:
        decode_mesh_chunk(r, &m->u.mesh_chunk);
        break;
    default:
        return PROTO_ERR_UNKNOWN_TYPE;
    }
    if (rd.err == PROTO_OK && rd.left > 0)
        return PROTO_ERR_TRAILING;
    return rd.err;
}

void proto_snapshot_entry(const proto_snapshot *s, uint16_t i, proto_avatar *out)
{
    const uint8_t *p = s->entries + (size_t)i * PROTO_SNAPSHOT_ENTRY_SIZE;

    assert(i < s->count);
    out->id = le_get_u32(p);
    for (int k = 0; k < 3; k++)
        out->pos[k] = bits_to_f32(le_get_u32(p + 4 + 4 * k));
}

void proto_object_box(const proto_object_info *o, uint16_t i, float min[3], float max[3])
{
    const uint8_t *p = o->boxes + (size_t)i * PROTO_BOX_ENTRY_SIZE;

    assert(i < o->box_count);
    for (int k = 0; k < 3; k++) {
        min[k] = bits_to_f32(le_get_u32(p + 4 * k));
        max[k] = bits_to_f32(le_get_u32(p + 12 + 4 * k));
    }
}

const char *proto_strerror(int status)
{
    switch (status) {
    case PROTO_OK: return "ok";
    case PROTO_INCOMPLETE: return "incomplete frame";
    case PROTO_ERR_FRAME_EMPTY: return "frame length below 2";
    case PROTO_ERR_FRAME_TOO_LONG: return "frame too long";
    case PROTO_ERR_UNKNOWN_TYPE: return "unknown message type";
    case PROTO_ERR_SHORT: return "payload too short";
    case PROTO_ERR_TRAILING: return "trailing bytes after payload";
    case PROTO_ERR_BAD_STRING: return "bad string";
    case PROTO_ERR_NOT_FINITE: return "number not finite";
    case PROTO_ERR_BAD_VALUE: return "value out of range";
    case PROTO_ERR_BAD_MAGIC: return "bad magic";
    case PROTO_ERR_VERSION: return "protocol version not supported";
    case PROTO_ERR_UNEXPECTED: return "unexpected message";
    case PROTO_ERR_ALREADY_JOINED: return "already joined";
    case PROTO_ERR_TRUNCATED: return "connection closed mid-frame";
    case PROTO_ERR_TIMEOUT: return "timeout";
    case PROTO_ERR_SERVER_FULL: return "server full";
    case PROTO_ERR_BAD_SEQ: return "move sequence did not increase";
    case PROTO_ERR_INTERNAL: return "internal server error";
    case PROTO_ERR_UPLOAD: return "upload refused";
    case PROTO_ERR_IMPORT: return "model could not be imported";
    case PROTO_ERR_NO_OBJECT: return "no such object";
    case PROTO_ERR_NOT_OWNER: return "not the owner";
    case PROTO_ERR_GUEST: return "not allowed for guests";
    case PROTO_ERR_AUTH: return "login failed";
    case PROTO_ERR_AUTH_REQUIRED: return "login required";
    case PROTO_ERR_RATE_LIMITED: return "rate limited";
    case PROTO_ERR_PLACEMENT: return "placement refused";
    case PROTO_ERR_STALE_MESH: return "mesh hash does not match";
    default: return "unknown status";
    }
}

const char *proto_bye_name(unsigned reason)
{
    return reason == PROTO_BYE_SHUTDOWN ? "shutdown" : reason == PROTO_BYE_KICKED ? "kicked" : "quit";
}

const char *proto_type_name(uint16_t type)
{
    switch (type) {
    case PROTO_HELLO: return "hello";
    case PROTO_WELCOME: return "welcome";
    case PROTO_JOIN: return "join";
    case PROTO_JOIN_OK: return "join_ok";
    case PROTO_MOVE: return "move";
    case PROTO_SNAPSHOT: return "snapshot";
    case PROTO_AVATAR_JOINED: return "avatar_joined";
    case PROTO_AVATAR_LEFT: return "avatar_left";
    case PROTO_ERROR: return "error";
    case PROTO_PING: return "ping";
    case PROTO_PONG: return "pong";
    case PROTO_BYE: return "bye";
    case PROTO_AVATAR_POSE: return "avatar_pose";
    case PROTO_OBJECT_UPLOAD_BEGIN: return "object_upload_begin";
    case PROTO_OBJECT_UPLOAD_CHUNK: return "object_upload_chunk";
    case PROTO_OBJECT_UPLOAD_END: return "object_upload_end";
    case PROTO_OBJECT_PLACE: return "object_place";
    /* The reserved ids among these (object_move, ecm_update, admin_*) get
     * their future names so a log line says what an older server was sent,
     * although they do not decode yet. */
    case PROTO_OBJECT_MOVE: return "object_move";
    case PROTO_OBJECT_REMOVE: return "object_remove";
    case PROTO_OBJECT_INFO: return "object_info";
    case PROTO_OBJECT_REMOVED: return "object_removed";
    case PROTO_OBJECT_REJECTED: return "object_rejected";
    case PROTO_MESH_REQUEST: return "mesh_request";
    case PROTO_MESH_CHUNK: return "mesh_chunk";
    case PROTO_COLLISION: return "collision";
    case PROTO_ECM_UPDATE: return "ecm_update";
    case PROTO_ADMIN_REQUEST: return "admin_request";
    case PROTO_ADMIN_REPLY: return "admin_reply";
    default: return "unknown";
    }
}

/* ---- writer ----------------------------------------------------------- */

void proto_writer_init(proto_writer *w, uint8_t *buf, size_t cap)
{
    w->buf = buf;
    w->cap = cap;
    w->len = 0;
    w->err = PROTO_OK;
}

/*
 * Reserves one whole frame with payload_len bytes of payload, writes its
 * header and returns where the payload goes; the caller must fill all of
 * it. Returns NULL, writing nothing, when the writer has already failed or
 * the frame does not fit (which makes the failure sticky). Reserving the
 * full size first is what keeps partial frames out of the buffer.
 */
static uint8_t *frame_open(proto_writer *w, uint16_t type, size_t payload_len)
{
    size_t need = PROTO_HEADER_SIZE + payload_len;
    uint8_t *p;

    if (w->err != PROTO_OK)
        return NULL;
    if (need > w->cap - w->len) {
        w->err = PROTO_ERR_FRAME_TOO_LONG;
        return NULL;
    }
    p = w->buf + w->len;
    w->len += need;
    p = st_u32(p, (uint32_t)(need - 4));
    return st_u16(p, type);
}

/* Bytes of s to send as a string of at most max bytes, backing off so the
 * cut does not split a UTF-8 character (the receiver would refuse the half). */
static uint8_t str_len(proto_str s, uint32_t max)
{
    uint32_t n = s.len;

    if (n > max) {
        n = max;
        while (n > 0 && ((uint8_t)s.ptr[n] & 0xc0u) == 0x80u)
            n--;
    }
    return (uint8_t)n;
}

/*
 * Copies the C string src into dst (PROTO_MESSAGE_MAX bytes) so that the
 * result always passes the decoder's text rule: each byte that is not part
 * of a well-formed, non-control character becomes '?', and the copy stops at
 * the limit without splitting a character. Error texts often quote what a
 * peer sent, and a message the receiver rejects would hide the real error.
 * Returns the number of bytes written.
 */
static size_t clean_message(uint8_t *dst, const char *src)
{
    const uint8_t *s = (const uint8_t *)src;
    size_t n = 0, i = 0;

    /* A character starting before the limit ends at most 3 bytes after it. */
    while (n < PROTO_MESSAGE_MAX + 3 && s[n] != 0)
        n++;
    while (i < n && i < PROTO_MESSAGE_MAX) {
        uint32_t cp;
        size_t k = utf8_next(s + i, n - i, &cp);

        if (k == 0 || is_control(cp)) {
            dst[i++] = '?';
            continue;
        }
        if (i + k > PROTO_MESSAGE_MAX)
            break;
        memcpy(dst + i, s + i, k);
        i += k;
    }
    return i;
}

void proto_put_hello(proto_writer *w, const proto_hello *m)
{
    uint8_t *p = frame_open(w, PROTO_HELLO, PROTO_SIZE_HELLO - PROTO_HEADER_SIZE);

    if (!p)
        return;
    p = st_u32(p, m->magic);
    st_u16(p, m->version);
}

void proto_put_welcome(proto_writer *w, const proto_welcome *m)
{
    uint8_t *p = frame_open(w, PROTO_WELCOME, PROTO_SIZE_WELCOME - PROTO_HEADER_SIZE);

    if (!p)
        return;
    p = st_u16(p, m->version);
    p = st_u64(p, m->session_id);
    p = st_bytes(p, m->token, PROTO_TOKEN_SIZE);
    p = st_u16(p, m->tick_hz);
    p = st_f32(p, m->aoi_radius);
    p = st_f32(p, m->max_speed);
    p = st_vec3(p, m->world_min);
    p = st_vec3(p, m->world_max);
    st_u32(p, m->idle_timeout_ms);
}

void proto_put_join(proto_writer *w, const proto_join *m)
{
    uint8_t n = str_len(m->name, PROTO_NAME_MAX);
    uint32_t secret = m->credential == PROTO_CRED_NONE ? 0
                      : m->secret_len > PROTO_PASSWORD_MAX ? PROTO_PASSWORD_MAX
                                                           : m->secret_len;
    uint8_t *p = frame_open(w, PROTO_JOIN, 1u + n + 12u + (m->credential ? 2u + secret : 0u));

    if (!p)
        return;
    p = st_u8(p, n);
    p = st_bytes(p, m->name.ptr, n);
    p = st_vec3(p, m->box);
    if (m->credential == PROTO_CRED_NONE)
        return;
    p = st_u8(p, m->credential);
    p = st_u8(p, (uint8_t)secret);
    st_bytes(p, m->secret, secret);
}

void proto_put_join_ok(proto_writer *w, const proto_join_ok *m)
{
    uint8_t *p = frame_open(w, PROTO_JOIN_OK, PROTO_SIZE_JOIN_OK - PROTO_HEADER_SIZE +
                                                  (m->has_token ? PROTO_RESUME_TOKEN_SIZE : 0u));

    if (!p)
        return;
    p = st_u32(p, m->avatar_id);
    p = st_vec3(p, m->pos);
    p = st_vec3(p, m->box);
    if (m->has_token)
        st_bytes(p, m->token, PROTO_RESUME_TOKEN_SIZE);
}

/* Bytes of a pose on the wire: the facing and its parts. */
static size_t pose_size(const proto_pose *p)
{
    size_t n = PROTO_POSE_HEAD_SIZE;
    for (unsigned k = 0; k < PROTO_POSE_PARTS; k++)
        n += PROTO_POSE_HAS(p, k) ? PROTO_POSE_PART_SIZE : 0u;
    return n;
}

static uint8_t *st_pose(uint8_t *p, const proto_pose *m)
{
    p = st_f32(p, m->yaw);
    p = st_f32(p, m->pitch);
    p = st_u8(p, m->parts);
    for (unsigned k = 0; k < PROTO_POSE_PARTS; k++) {
        if (!PROTO_POSE_HAS(m, k))
            continue;
        for (int i = 0; i < 3; i++)
            p = st_u16(p, (uint16_t)m->pos[k][i]);
        for (int i = 0; i < 4; i++)
            p = st_u16(p, (uint16_t)m->rot[k][i]);
    }
    return p;
}

void proto_put_move(proto_writer *w, const proto_move *m)
{
    uint8_t *p = frame_open(w, PROTO_MOVE,
                            PROTO_SIZE_MOVE - PROTO_HEADER_SIZE + (m->has_pose ? pose_size(&m->pose) : 0u));

    if (!p)
        return;
    p = st_u32(p, m->seq);
    p = st_vec3(p, m->pos);
    if (m->has_pose)
        st_pose(p, &m->pose);
}

void proto_put_avatar_pose(proto_writer *w, const proto_avatar_pose *m)
{
    uint8_t *p = frame_open(w, PROTO_AVATAR_POSE, 4u + pose_size(&m->pose));

    if (!p)
        return;
    p = st_u32(p, m->id);
    st_pose(p, &m->pose);
}

/* Rounds v x scale to the nearest int16, saturating. */
static int16_t quantize(float v, float scale)
{
    float x = roundf(v * scale);
    if (x != x) /* NaN: the caller's bug; nothing undefined comes of it */
        return 0;
    return (int16_t)(x > 32767.0f ? 32767.0f : x < -32768.0f ? -32768.0f : x);
}

void proto_pose_set_part(proto_pose *p, unsigned part, const float pos[3], const float q[4])
{
    float n = sqrtf(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);

    for (int i = 0; i < 3; i++)
        p->pos[part][i] = quantize(pos[i], 1000.0f);
    for (int i = 0; i < 4; i++)
        p->rot[part][i] = quantize(n > 0.0f ? q[i] / n : (i == 3), (float)PROTO_QUAT_ONE);
    p->parts |= (uint8_t)(1u << part);
}

void proto_put_avatar_joined(proto_writer *w, const proto_avatar_joined *m)
{
    uint8_t n = str_len(m->name, PROTO_NAME_MAX);
    uint8_t *p = frame_open(w, PROTO_AVATAR_JOINED, 4u + 1u + n + 24u);

    if (!p)
        return;
    p = st_u32(p, m->id);
    p = st_u8(p, n);
    p = st_bytes(p, m->name.ptr, n);
    p = st_vec3(p, m->pos);
    st_vec3(p, m->box);
}

void proto_put_avatar_left(proto_writer *w, const proto_avatar_left *m)
{
    uint8_t *p = frame_open(w, PROTO_AVATAR_LEFT, PROTO_SIZE_AVATAR_LEFT - PROTO_HEADER_SIZE);

    if (!p)
        return;
    p = st_u32(p, m->id);
    st_u8(p, m->reason);
}

void proto_put_error(proto_writer *w, uint16_t code, const char *message)
{
    uint8_t text[PROTO_MESSAGE_MAX];
    size_t n = clean_message(text, message);
    uint8_t *p = frame_open(w, PROTO_ERROR, 2u + 1u + n);

    if (!p)
        return;
    p = st_u16(p, code);
    p = st_u8(p, (uint8_t)n);
    st_bytes(p, text, n);
}

static void put_stamp(proto_writer *w, uint16_t type, uint64_t stamp)
{
    uint8_t *p = frame_open(w, type, PROTO_SIZE_PING - PROTO_HEADER_SIZE);

    if (p)
        st_u64(p, stamp);
}

void proto_put_ping(proto_writer *w, uint64_t stamp) { put_stamp(w, PROTO_PING, stamp); }

void proto_put_pong(proto_writer *w, uint64_t stamp) { put_stamp(w, PROTO_PONG, stamp); }

void proto_put_bye(proto_writer *w, uint8_t reason)
{
    uint8_t *p = frame_open(w, PROTO_BYE, PROTO_SIZE_BYE - PROTO_HEADER_SIZE);

    if (p)
        st_u8(p, reason);
}

/*
 * The snapshot frame is open from begin to end: its header says count 0
 * until end patches it, so the writer must not be used for other frames in
 * between. If begin fails it returns w->len and writes nothing; add and end
 * then do nothing because the error is sticky.
 */
size_t proto_put_snapshot_begin(proto_writer *w, uint32_t tick, uint32_t ack_seq)
{
    uint8_t *p = frame_open(w, PROTO_SNAPSHOT, PROTO_SNAPSHOT_HEAD_SIZE);

    if (!p)
        return w->len;
    p = st_u32(p, tick);
    p = st_u32(p, ack_seq);
    st_u16(p, 0);
    return w->len - SNAP_ENTRIES_AT;
}

/* On overflow (no room, or a PROTO_SNAPSHOT_MAX_ENTRIES + 1st entry) the
 * whole snapshot is dropped, len going back to frame_at, so a half-built
 * snapshot is never sent; the caller retries next tick with a fresh buffer. */
void proto_put_snapshot_add(proto_writer *w, size_t frame_at, const proto_avatar *a)
{
    size_t entries;
    uint8_t *p;

    if (w->err != PROTO_OK)
        return;
    entries = (w->len - frame_at - SNAP_ENTRIES_AT) / PROTO_SNAPSHOT_ENTRY_SIZE;
    if (entries >= PROTO_SNAPSHOT_MAX_ENTRIES || PROTO_SNAPSHOT_ENTRY_SIZE > w->cap - w->len) {
        w->err = PROTO_ERR_FRAME_TOO_LONG;
        w->len = frame_at;
        return;
    }
    p = st_u32(w->buf + w->len, a->id);
    st_vec3(p, a->pos);
    w->len += PROTO_SNAPSHOT_ENTRY_SIZE;
}

void proto_put_snapshot_end(proto_writer *w, size_t frame_at)
{
    size_t entries;

    if (w->err != PROTO_OK)
        return;
    entries = (w->len - frame_at - SNAP_ENTRIES_AT) / PROTO_SNAPSHOT_ENTRY_SIZE;
    st_u32(w->buf + frame_at, (uint32_t)(w->len - frame_at - 4));
    st_u16(w->buf + frame_at + SNAP_COUNT_AT, (uint16_t)entries);
}

static uint8_t *st_str(uint8_t *p, proto_str s, uint8_t n)
{
    p = st_u8(p, n);
    return st_bytes(p, s.ptr, n);
}

static uint8_t *st_transform(uint8_t *p, const proto_transform *t)
{
    p = st_vec3(p, t->pos);
    p = st_f32(p, t->yaw);
    return st_f32(p, t->scale);
}

void proto_put_upload_begin(proto_writer *w, const proto_upload_begin *m)
{
    uint8_t nn = str_len(m->name, PROTO_OBJECT_NAME_MAX), nf = str_len(m->format, PROTO_FORMAT_MAX);
    uint8_t *p = frame_open(w, PROTO_OBJECT_UPLOAD_BEGIN, 8u + 1u + nn + 1u + nf + 1u + 4u);

    if (!p)
        return;
    p = st_u32(p, m->upload_id);
    p = st_u32(p, m->total_size);
    p = st_str(p, m->name, nn);
    p = st_str(p, m->format, nf);
    p = st_u8(p, m->up_axis);
    st_f32(p, m->unit_scale);
}

/* True, failing the writer as a frame too long would, when n is over max:
 * what the caller would write past a codec limit is not written at all. */
static int over_limit(proto_writer *w, size_t n, size_t max)
{
    if (n <= max)
        return 0;
    if (w->err == PROTO_OK)
        w->err = PROTO_ERR_FRAME_TOO_LONG;
    return 1;
}

void proto_put_upload_chunk(proto_writer *w, const proto_upload_chunk *m)
{
    uint8_t *p;

    if (over_limit(w, m->len, PROTO_CHUNK_MAX))
        return;
    p = frame_open(w, PROTO_OBJECT_UPLOAD_CHUNK, 8u + m->len);
    if (!p)
        return;
    p = st_u32(p, m->upload_id);
    p = st_u32(p, m->offset);
    st_bytes(p, m->data, m->len);
}

void proto_put_upload_end(proto_writer *w, const proto_upload_end *m)
{
    uint8_t *p = frame_open(w, PROTO_OBJECT_UPLOAD_END, 4u + PROTO_SIZE_TRANSFORM);

    if (!p)
        return;
    p = st_u32(p, m->upload_id);
    st_transform(p, &m->at);
}

void proto_put_object_place(proto_writer *w, const proto_object_place *m)
{
    uint8_t *p = frame_open(w, PROTO_OBJECT_PLACE, 4u + PROTO_SIZE_TRANSFORM);

    if (!p)
        return;
    p = st_u32(p, m->object_id);
    st_transform(p, &m->at);
}

static void put_id(proto_writer *w, uint16_t type, uint32_t id)
{
    uint8_t *p = frame_open(w, type, 4u);

    if (p)
        st_u32(p, id);
}

void proto_put_object_remove(proto_writer *w, uint32_t object_id) { put_id(w, PROTO_OBJECT_REMOVE, object_id); }

void proto_put_object_removed(proto_writer *w, uint32_t object_id) { put_id(w, PROTO_OBJECT_REMOVED, object_id); }

void proto_put_object_rejected(proto_writer *w, uint32_t request_id, uint16_t code, const char *message)
{
    uint8_t text[PROTO_MESSAGE_MAX];
    size_t n = clean_message(text, message);
    uint8_t *p = frame_open(w, PROTO_OBJECT_REJECTED, 4u + 2u + 1u + n);

    if (!p)
        return;
    p = st_u32(p, request_id);
    p = st_u16(p, code);
    p = st_u8(p, (uint8_t)n);
    st_bytes(p, text, n);
}

void proto_put_mesh_request(proto_writer *w, const proto_mesh_request *m)
{
    uint8_t *p = frame_open(w, PROTO_MESH_REQUEST, PROTO_SIZE_MESH_REQUEST - PROTO_HEADER_SIZE);

    if (!p)
        return;
    p = st_u32(p, m->object_id);
    st_bytes(p, m->mesh_hash, PROTO_MESH_HASH_SIZE);
}

void proto_put_mesh_chunk(proto_writer *w, const proto_mesh_chunk *m)
{
    uint8_t *p;

    if (over_limit(w, m->len, PROTO_MESH_CHUNK_MAX))
        return;
    p = frame_open(w, PROTO_MESH_CHUNK, PROTO_SIZE_MESH_CHUNK(m->len) - PROTO_HEADER_SIZE);
    if (!p)
        return;
    p = st_u32(p, m->object_id);
    p = st_u32(p, m->total);
    p = st_u32(p, m->offset);
    st_bytes(p, m->data, m->len);
}

void proto_put_collision(proto_writer *w, const proto_collision *m)
{
    uint8_t *p = frame_open(w, PROTO_COLLISION, PROTO_SIZE_COLLISION - PROTO_HEADER_SIZE);

    if (!p)
        return;
    p = st_u32(p, m->object_id);
    p = st_u32(p, m->ecm_version);
    p = st_u16(p, m->box_index);
    p = st_u8(p, m->inside);
    p = st_vec3(p, m->point);
    st_vec3(p, m->normal);
}

void proto_put_object_info(proto_writer *w, const proto_object_info *m, const float (*min)[3], const float (*max)[3])
{
    uint8_t no = str_len(m->owner, PROTO_NAME_MAX), nn = str_len(m->name, PROTO_OBJECT_NAME_MAX);
    uint8_t *p;

    if (over_limit(w, m->box_count, PROTO_OBJECT_BOXES_MAX))
        return;
    p = frame_open(w, PROTO_OBJECT_INFO,
                   8u + 1u + no + 1u + nn + PROTO_SIZE_TRANSFORM + 10u + PROTO_MESH_HASH_SIZE +
                       (size_t)m->box_count * PROTO_BOX_ENTRY_SIZE);
    if (!p)
        return;
    p = st_u32(p, m->object_id);
    p = st_u32(p, m->upload_id);
    p = st_str(p, m->owner, no);
    p = st_str(p, m->name, nn);
    p = st_transform(p, &m->at);
    p = st_u32(p, m->ecm_version);
    p = st_u32(p, m->tri_count);
    p = st_bytes(p, m->mesh_hash, PROTO_MESH_HASH_SIZE);
    p = st_u16(p, m->box_count);
    for (uint16_t i = 0; i < m->box_count; i++) {
        p = st_vec3(p, min[i]);
        p = st_vec3(p, max[i]);
    }
}
