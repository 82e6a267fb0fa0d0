/*
 * fuzz_proto.c: fuzz target for the wire codec (protocol/proto.c).
 *
 * The target reads its input as a stream of frames, the way a connection's
 * input buffer is read, under both length caps. Every frame that decodes is
 * checked against the decoder's promises, re-encoded with the writer and
 * must come back byte for byte and decode to the same message: the encoding
 * is canonical, so any difference is a codec bug. A failed check aborts.
 *
 * Inputs are made and changed frame-aware (fz.h): the generator writes one
 * to three valid frames of random types and contents, then corrupts them
 * (lengths at and past both caps, reserved types, NaN and infinity, noise);
 * the mutator finds the frames of an input and replaces, inserts or
 * corrupts one. Built with -DCVRE_LIBFUZZER (clang -fsanitize=fuzzer) the
 * mutator is libFuzzer's custom mutator; otherwise fz.c's main() drives
 * the target (see tests/fuzz/README.md), which also has
 *   fuzz_proto --write-seeds DIR     one valid frame per type, as a corpus
 */
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "fz.h"
#include "le.h"
#include "proto.h"

#define CHECK FZ_CHECK

/* What the target saw, reported by the standalone driver so a change that
 * stops inputs from reaching the decoder shows up. */
static unsigned long n_frames, n_decoded;

/* The largest frame there is. */
static uint8_t reenc[PROTO_MAX_LEN + 4];

/* Every type that decodes, for the checks and the generator. */
static const uint16_t types[] = {
    PROTO_HELLO, PROTO_WELCOME, PROTO_JOIN, PROTO_JOIN_OK, PROTO_MOVE, PROTO_SNAPSHOT,
    PROTO_AVATAR_JOINED, PROTO_AVATAR_LEFT, PROTO_ERROR, PROTO_PING, PROTO_PONG, PROTO_BYE, PROTO_AVATAR_POSE,
    PROTO_OBJECT_UPLOAD_BEGIN, PROTO_OBJECT_UPLOAD_CHUNK, PROTO_OBJECT_UPLOAD_END,
    PROTO_OBJECT_PLACE, PROTO_OBJECT_REMOVE, PROTO_OBJECT_INFO, PROTO_OBJECT_REMOVED,
    PROTO_OBJECT_REJECTED, PROTO_COLLISION, PROTO_MESH_REQUEST, PROTO_MESH_CHUNK,
};
#define NTYPES (sizeof types / sizeof types[0])

static int defined_type(uint16_t t)
{
    for (size_t i = 0; i < NTYPES; i++) {
        if (types[i] == t)
            return 1;
    }
    return 0;
}

/* ---- the target --------------------------------------------------------- */

static int same_floats(const float *a, const float *b, size_t n)
{
    return memcmp(a, b, n * sizeof *a) == 0; /* bitwise: -0.0 is not 0.0 */
}

static int same_str(proto_str a, proto_str b)
{
    return a.len == b.len && memcmp(a.ptr, b.ptr, a.len) == 0;
}

static int same_transform(const proto_transform *a, const proto_transform *b)
{
    return same_floats(a->pos, b->pos, 3) && same_floats(&a->yaw, &b->yaw, 1) &&
           same_floats(&a->scale, &b->scale, 1);
}

/* Only the parts present are compared: the others are not on the wire. */
static int same_pose(const proto_pose *a, const proto_pose *b)
{
    if (!same_floats(&a->yaw, &b->yaw, 1) || !same_floats(&a->pitch, &b->pitch, 1) || a->parts != b->parts)
        return 0;
    for (unsigned k = 0; k < PROTO_POSE_PARTS; k++)
        if (PROTO_POSE_HAS(a, k) && (memcmp(a->pos[k], b->pos[k], sizeof a->pos[k]) != 0 ||
                                     memcmp(a->rot[k], b->rot[k], sizeof a->rot[k]) != 0))
            return 0;
    return 1;
}

static int same_msg(const proto_msg *a, const proto_msg *b)
{
    if (a->type != b->type)
        return 0;
    switch (a->type) {
    case PROTO_HELLO:
        return a->u.hello.magic == b->u.hello.magic && a->u.hello.version == b->u.hello.version;
    case PROTO_WELCOME: {
        const proto_welcome *x = &a->u.welcome, *y = &b->u.welcome;
        return x->version == y->version && x->session_id == y->session_id &&
               memcmp(x->token, y->token, PROTO_TOKEN_SIZE) == 0 && x->tick_hz == y->tick_hz &&
               same_floats(&x->aoi_radius, &y->aoi_radius, 1) &&
               same_floats(&x->max_speed, &y->max_speed, 1) &&
               same_floats(x->world_min, y->world_min, 3) && same_floats(x->world_max, y->world_max, 3) &&
               x->idle_timeout_ms == y->idle_timeout_ms;
    }
    case PROTO_JOIN:
        return same_str(a->u.join.name, b->u.join.name) && same_floats(a->u.join.box, b->u.join.box, 3) &&
               a->u.join.credential == b->u.join.credential && a->u.join.secret_len == b->u.join.secret_len &&
               (a->u.join.secret_len == 0 || memcmp(a->u.join.secret, b->u.join.secret, a->u.join.secret_len) == 0);
    case PROTO_JOIN_OK:
        return a->u.join_ok.avatar_id == b->u.join_ok.avatar_id &&
               same_floats(a->u.join_ok.pos, b->u.join_ok.pos, 3) &&
               same_floats(a->u.join_ok.box, b->u.join_ok.box, 3) && a->u.join_ok.has_token == b->u.join_ok.has_token &&
               (!a->u.join_ok.has_token || memcmp(a->u.join_ok.token, b->u.join_ok.token, PROTO_RESUME_TOKEN_SIZE) == 0);
    case PROTO_MOVE:
        return a->u.move.seq == b->u.move.seq && same_floats(a->u.move.pos, b->u.move.pos, 3) &&
               a->u.move.has_pose == b->u.move.has_pose &&
               (!a->u.move.has_pose || same_pose(&a->u.move.pose, &b->u.move.pose));
    case PROTO_AVATAR_POSE:
        return a->u.avatar_pose.id == b->u.avatar_pose.id && same_pose(&a->u.avatar_pose.pose, &b->u.avatar_pose.pose);
    case PROTO_SNAPSHOT: {
        const proto_snapshot *x = &a->u.snapshot, *y = &b->u.snapshot;
        if (x->tick != y->tick || x->ack_seq != y->ack_seq || x->count != y->count)
            return 0;
        for (uint16_t i = 0; i < x->count; i++) {
            proto_avatar p, q;
            proto_snapshot_entry(x, i, &p);
            proto_snapshot_entry(y, i, &q);
            if (p.id != q.id || !same_floats(p.pos, q.pos, 3))
                return 0;
        }
        return 1;
    }
    case PROTO_AVATAR_JOINED: {
        const proto_avatar_joined *x = &a->u.avatar_joined, *y = &b->u.avatar_joined;
        return x->id == y->id && same_str(x->name, y->name) && same_floats(x->pos, y->pos, 3) &&
               same_floats(x->box, y->box, 3);
    }
    case PROTO_AVATAR_LEFT:
        return a->u.avatar_left.id == b->u.avatar_left.id &&
               a->u.avatar_left.reason == b->u.avatar_left.reason;
    case PROTO_ERROR:
        return a->u.error.code == b->u.error.code && same_str(a->u.error.message, b->u.error.message);
    case PROTO_PING:
    case PROTO_PONG:
        return a->u.ping.stamp == b->u.ping.stamp;
    case PROTO_BYE:
        return a->u.bye.reason == b->u.bye.reason;
    case PROTO_OBJECT_UPLOAD_BEGIN: {
        const proto_upload_begin *x = &a->u.upload_begin, *y = &b->u.upload_begin;
        return x->upload_id == y->upload_id && x->total_size == y->total_size && same_str(x->name, y->name) &&
               same_str(x->format, y->format) && x->up_axis == y->up_axis &&
               same_floats(&x->unit_scale, &y->unit_scale, 1);
    }
    case PROTO_OBJECT_UPLOAD_CHUNK: {
        const proto_upload_chunk *x = &a->u.upload_chunk, *y = &b->u.upload_chunk;
        return x->upload_id == y->upload_id && x->offset == y->offset && x->len == y->len &&
               memcmp(x->data, y->data, x->len) == 0;
    }
    case PROTO_OBJECT_UPLOAD_END:
        return a->u.upload_end.upload_id == b->u.upload_end.upload_id &&
               same_transform(&a->u.upload_end.at, &b->u.upload_end.at);
    case PROTO_OBJECT_PLACE:
        return a->u.object_place.object_id == b->u.object_place.object_id &&
               same_transform(&a->u.object_place.at, &b->u.object_place.at);
    case PROTO_OBJECT_REMOVE:
    case PROTO_OBJECT_REMOVED:
        return a->u.object_id == b->u.object_id;
    case PROTO_OBJECT_INFO: {
        const proto_object_info *x = &a->u.object_info, *y = &b->u.object_info;
        if (x->object_id != y->object_id || x->upload_id != y->upload_id || !same_str(x->owner, y->owner) ||
            !same_str(x->name, y->name) || !same_transform(&x->at, &y->at) ||
            x->ecm_version != y->ecm_version || x->tri_count != y->tri_count || x->box_count != y->box_count ||
            memcmp(x->mesh_hash, y->mesh_hash, PROTO_MESH_HASH_SIZE) != 0)
            return 0;
        for (uint16_t i = 0; i < x->box_count; i++) {
            float p[2][3], q[2][3];
            proto_object_box(x, i, p[0], p[1]);
            proto_object_box(y, i, q[0], q[1]);
            if (!same_floats(p[0], q[0], 3) || !same_floats(p[1], q[1], 3))
                return 0;
        }
        return 1;
    }
    case PROTO_OBJECT_REJECTED: {
        const proto_object_rejected *x = &a->u.object_rejected, *y = &b->u.object_rejected;
        return x->request_id == y->request_id && x->code == y->code && same_str(x->message, y->message);
    }
    case PROTO_COLLISION: {
        const proto_collision *x = &a->u.collision, *y = &b->u.collision;
        return x->object_id == y->object_id && x->ecm_version == y->ecm_version &&
               x->box_index == y->box_index && x->inside == y->inside && same_floats(x->point, y->point, 3) &&
               same_floats(x->normal, y->normal, 3);
    }
    case PROTO_MESH_REQUEST:
        return a->u.mesh_request.object_id == b->u.mesh_request.object_id &&
               memcmp(a->u.mesh_request.mesh_hash, b->u.mesh_request.mesh_hash, PROTO_MESH_HASH_SIZE) == 0;
    case PROTO_MESH_CHUNK: {
        const proto_mesh_chunk *x = &a->u.mesh_chunk, *y = &b->u.mesh_chunk;
        return x->object_id == y->object_id && x->total == y->total && x->offset == y->offset && x->len == y->len &&
               memcmp(x->data, y->data, x->len) == 0;
    }
    default:
        return 0;
    }
}

/* The writer takes error texts as C strings; decoded text never holds a
 * NUL, so a copy with one appended is the same text. */
static const char *c_text(proto_str s, char out[PROTO_MESSAGE_MAX + 1])
{
    memcpy(out, s.ptr, s.len);
    out[s.len] = 0;
    return out;
}

/* Appends m to w with the matching put. m must have decoded cleanly, so
 * its type is one of the defined ones. */
static void encode(proto_writer *w, const proto_msg *m)
{
    static float box_min[PROTO_OBJECT_BOXES_MAX][3], box_max[PROTO_OBJECT_BOXES_MAX][3];
    char text[PROTO_MESSAGE_MAX + 1];

    switch (m->type) {
    case PROTO_HELLO: proto_put_hello(w, &m->u.hello); break;
    case PROTO_WELCOME: proto_put_welcome(w, &m->u.welcome); break;
    case PROTO_JOIN: proto_put_join(w, &m->u.join); break;
    case PROTO_JOIN_OK: proto_put_join_ok(w, &m->u.join_ok); break;
    case PROTO_MOVE: proto_put_move(w, &m->u.move); break;
    case PROTO_SNAPSHOT: {
        size_t at = proto_put_snapshot_begin(w, m->u.snapshot.tick, m->u.snapshot.ack_seq);
        for (uint16_t i = 0; i < m->u.snapshot.count; i++) {
            proto_avatar a;
            proto_snapshot_entry(&m->u.snapshot, i, &a);
            proto_put_snapshot_add(w, at, &a);
        }
        proto_put_snapshot_end(w, at);
        break;
    }
    case PROTO_AVATAR_JOINED: proto_put_avatar_joined(w, &m->u.avatar_joined); break;
    case PROTO_AVATAR_LEFT: proto_put_avatar_left(w, &m->u.avatar_left); break;
    case PROTO_ERROR: proto_put_error(w, m->u.error.code, c_text(m->u.error.message, text)); break;
    case PROTO_PING: proto_put_ping(w, m->u.ping.stamp); break;
    case PROTO_PONG: proto_put_pong(w, m->u.ping.stamp); break;
    case PROTO_BYE: proto_put_bye(w, m->u.bye.reason); break;
    case PROTO_AVATAR_POSE: proto_put_avatar_pose(w, &m->u.avatar_pose); break;
    case PROTO_OBJECT_UPLOAD_BEGIN: proto_put_upload_begin(w, &m->u.upload_begin); break;
    case PROTO_OBJECT_UPLOAD_CHUNK: proto_put_upload_chunk(w, &m->u.upload_chunk); break;
    case PROTO_OBJECT_UPLOAD_END: proto_put_upload_end(w, &m->u.upload_end); break;
    case PROTO_OBJECT_PLACE: proto_put_object_place(w, &m->u.object_place); break;
    case PROTO_OBJECT_REMOVE: proto_put_object_remove(w, m->u.object_id); break;
    case PROTO_OBJECT_REMOVED: proto_put_object_removed(w, m->u.object_id); break;
    case PROTO_OBJECT_INFO:
        /* The writer takes boxes as arrays, as the server holds them. */
        for (uint16_t i = 0; i < m->u.object_info.box_count; i++)
            proto_object_box(&m->u.object_info, i, box_min[i], box_max[i]);
        proto_put_object_info(w, &m->u.object_info, (const float (*)[3])box_min, (const float (*)[3])box_max);
        break;
    case PROTO_OBJECT_REJECTED:
        proto_put_object_rejected(w, m->u.object_rejected.request_id, m->u.object_rejected.code,
                                  c_text(m->u.object_rejected.message, text));
        break;
    case PROTO_COLLISION: proto_put_collision(w, &m->u.collision); break;
    case PROTO_MESH_REQUEST: proto_put_mesh_request(w, &m->u.mesh_request); break;
    case PROTO_MESH_CHUNK: proto_put_mesh_chunk(w, &m->u.mesh_chunk); break;
    }
}

static int inside(const proto_frame *f, const void *p, size_t n)
{
    const uint8_t *b = p;
    return b >= f->payload && n <= f->payload_len && (size_t)(b - f->payload) <= f->payload_len - n;
}

static int finite3(const float v[3])
{
    return isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]);
}

static int transform_ok(const proto_transform *t)
{
    return finite3(t->pos) && isfinite(t->yaw) && t->scale >= PROTO_SCALE_MIN && t->scale <= PROTO_SCALE_MAX;
}

/* The decoder's promises for the object messages. */
static void check_object(const proto_frame *f, const proto_msg *m)
{
    switch (m->type) {
    case PROTO_OBJECT_UPLOAD_BEGIN: {
        const proto_upload_begin *u = &m->u.upload_begin;
        CHECK(u->upload_id != 0 && u->total_size != 0 && u->up_axis <= PROTO_UP_Z);
        CHECK(inside(f, u->name.ptr, u->name.len) && u->name.len >= 1 && u->name.len <= PROTO_OBJECT_NAME_MAX);
        CHECK(inside(f, u->format.ptr, u->format.len) && u->format.len <= PROTO_FORMAT_MAX);
        for (uint32_t i = 0; i < u->format.len; i++)
            CHECK((u->format.ptr[i] >= 'a' && u->format.ptr[i] <= 'z') ||
                  (u->format.ptr[i] >= '0' && u->format.ptr[i] <= '9'));
        CHECK(u->unit_scale >= PROTO_SCALE_MIN && u->unit_scale <= PROTO_SCALE_MAX);
        break;
    }
    case PROTO_OBJECT_UPLOAD_CHUNK: {
        const proto_upload_chunk *c = &m->u.upload_chunk;
        CHECK(c->upload_id != 0 && c->len >= 1 && c->len <= PROTO_CHUNK_MAX);
        CHECK(c->len == f->payload_len - 8 && c->data == f->payload + 8);
        break;
    }
    case PROTO_OBJECT_UPLOAD_END:
        CHECK(m->u.upload_end.upload_id != 0 && transform_ok(&m->u.upload_end.at));
        break;
    case PROTO_OBJECT_PLACE:
        CHECK(m->u.object_place.object_id != 0 && transform_ok(&m->u.object_place.at));
        break;
    case PROTO_OBJECT_REMOVE:
    case PROTO_OBJECT_REMOVED:
        CHECK(m->u.object_id != 0);
        break;
    case PROTO_OBJECT_INFO: {
        const proto_object_info *o = &m->u.object_info;
        const size_t n = (size_t)o->box_count * PROTO_BOX_ENTRY_SIZE;
        CHECK(o->object_id != 0 && o->ecm_version != 0 && transform_ok(&o->at));
        CHECK(inside(f, o->owner.ptr, o->owner.len) && inside(f, o->name.ptr, o->name.len));
        CHECK(o->box_count <= PROTO_OBJECT_BOXES_MAX);
        CHECK(f->payload_len == 72u + o->owner.len + o->name.len + n);
        CHECK(inside(f, o->boxes, n));
        for (uint16_t i = 0; i < o->box_count; i++) {
            float lo[3], hi[3];
            proto_object_box(o, i, lo, hi);
            CHECK(finite3(lo) && finite3(hi));
            for (int k = 0; k < 3; k++)
                CHECK(lo[k] <= hi[k]);
        }
        break;
    }
    case PROTO_OBJECT_REJECTED:
        CHECK(m->u.object_rejected.code >= PROTO_ERR_FRAME_EMPTY);
        CHECK(inside(f, m->u.object_rejected.message.ptr, m->u.object_rejected.message.len));
        break;
    case PROTO_COLLISION:
        CHECK(m->u.collision.object_id != 0 && m->u.collision.ecm_version != 0 && m->u.collision.inside <= 1);
        CHECK(finite3(m->u.collision.point) && finite3(m->u.collision.normal));
        break;
    case PROTO_MESH_REQUEST:
        CHECK(m->u.mesh_request.object_id != 0 && f->payload_len == 4u + PROTO_MESH_HASH_SIZE);
        break;
    case PROTO_MESH_CHUNK: {
        const proto_mesh_chunk *c = &m->u.mesh_chunk;
        CHECK(c->object_id != 0 && c->total != 0 && c->offset < c->total);
        CHECK(c->len >= 1 && c->len <= PROTO_MESH_CHUNK_MAX && c->len <= c->total - c->offset);
        CHECK(c->len == f->payload_len - 12 && c->data == f->payload + 12);
        break;
    }
    default:
        break;
    }
}

/* The decoder's promises for a pose: a finite facing, a pitch in range,
 * known parts, hands only with the head. */
static void check_pose(const proto_pose *p)
{
    CHECK(isfinite(p->yaw) && p->pitch >= -PROTO_PITCH_MAX && p->pitch <= PROTO_PITCH_MAX);
    CHECK(p->parts >> PROTO_POSE_PARTS == 0 && (p->parts == 0 || PROTO_POSE_HAS(p, PROTO_POSE_HEAD)));
}

/* Checks a message the decoder accepted, then its round trip. */
static void check_decoded(const proto_frame *f, const proto_msg *m)
{
    proto_writer w;
    proto_frame g;
    proto_msg again;

    CHECK(m->type == f->type && defined_type(m->type));
    check_object(f, m);
    if (m->type == PROTO_JOIN)
        CHECK(inside(f, m->u.join.name.ptr, m->u.join.name.len));
    if (m->type == PROTO_AVATAR_JOINED)
        CHECK(inside(f, m->u.avatar_joined.name.ptr, m->u.avatar_joined.name.len));
    if (m->type == PROTO_MOVE && m->u.move.has_pose)
        check_pose(&m->u.move.pose);
    if (m->type == PROTO_AVATAR_POSE)
        check_pose(&m->u.avatar_pose.pose);
    if (m->type == PROTO_ERROR)
        CHECK(inside(f, m->u.error.message.ptr, m->u.error.message.len));
    if (m->type == PROTO_SNAPSHOT) {
        size_t n = (size_t)m->u.snapshot.count * PROTO_SNAPSHOT_ENTRY_SIZE;
        CHECK(f->payload_len == PROTO_SNAPSHOT_HEAD_SIZE + n);
        CHECK(inside(f, m->u.snapshot.entries, n));
        for (uint16_t i = 0; i < m->u.snapshot.count; i++) {
            proto_avatar a;
            proto_snapshot_entry(&m->u.snapshot, i, &a);
            for (int k = 0; k < 3; k++)
                CHECK(isfinite(a.pos[k]));
        }
    }

    proto_writer_init(&w, reenc, sizeof reenc);
    encode(&w, m);
    CHECK(w.err == PROTO_OK);
    CHECK(w.len == f->size);
    CHECK(memcmp(reenc, f->payload - PROTO_HEADER_SIZE, f->size) == 0);
    CHECK(proto_frame_parse(reenc, w.len, PROTO_MAX_LEN, &g) == PROTO_OK);
    CHECK(g.size == w.len);
    CHECK(proto_decode(&g, &again) == PROTO_OK);
    CHECK(same_msg(m, &again));
}

/* Reads frames from the front of p like a connection's input buffer does,
 * stopping at the first that is incomplete or refused. */
static void walk(const uint8_t *p, size_t left, uint32_t cap)
{
    for (;;) {
        proto_frame f, g;
        proto_msg m;
        int rc = proto_frame_parse(p, left, cap, &f);

        if (rc == PROTO_INCOMPLETE) {
            CHECK(left < 4 || left - 4 < ((uint32_t)p[0] | (uint32_t)p[1] << 8 |
                                          (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24));
            return;
        }
        if (rc != PROTO_OK) {
            CHECK(rc == PROTO_ERR_FRAME_EMPTY || rc == PROTO_ERR_FRAME_TOO_LONG);
            return;
        }
        n_frames++;
        CHECK(f.size >= PROTO_HEADER_SIZE && f.size <= left && f.size - 4 <= cap);
        CHECK(f.payload == p + PROTO_HEADER_SIZE && f.payload_len == f.size - PROTO_HEADER_SIZE);
        /* What passes the small cap passes the large one unchanged. */
        CHECK(proto_frame_parse(p, left, PROTO_MAX_LEN, &g) == PROTO_OK && g.size == f.size);
        rc = proto_decode(&f, &m);
        if (rc == PROTO_OK) {
            n_decoded++;
            check_decoded(&f, &m);
        } else {
            CHECK(rc >= PROTO_ERR_UNKNOWN_TYPE && rc <= PROTO_ERR_BAD_MAGIC);
        }
        p += f.size;
        left -= f.size;
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    walk(data, size, PROTO_MAX_LEN_PREJOIN);
    walk(data, size, PROTO_MAX_LEN);
    return 0;
}

/* ---- generator and mutator ---------------------------------------------- */

#define MAX_FRAMES 3

/* The shared random stream (fz.h) under the generator's short names. */
static uint64_t rnd(void) { return fz_rnd(); }

static uint32_t below(uint32_t n) { return fz_below(n); }

static float bits_f32(uint32_t b)
{
    float v;
    memcpy(&v, &b, sizeof v);
    return v;
}

/* Mostly ordinary coordinates, with the edge cases a codec can get wrong. */
static float rnd_float(void)
{
    switch (below(8)) {
    case 0: return 0.0f;
    case 1: return -0.0f;
    case 2: return (float)below(2001) - 1000.0f;
    case 3: return bits_f32(0x7f7fffffu); /* largest finite */
    case 4: return bits_f32(below(0x800000u)); /* denormal */
    case 5: return bits_f32((uint32_t)rnd()); /* anything, NaN included */
    default: return (float)below(1u << 24) / 1024.0f - 8192.0f;
    }
}

static float rnd_box(void)
{
    if (below(16) == 0)
        return rnd_float();
    return PROTO_BOX_MIN + (float)below(3901) / 1000.0f;
}

static void rnd_vec3(float v[3])
{
    for (int i = 0; i < 3; i++)
        v[i] = rnd_float();
}

/* A pose: mostly a plausible one, sometimes with a part out of reach, a
 * quaternion off unit length, a pitch past straight up or unknown bits. */
static void rnd_pose(proto_pose *p)
{
    static const float parts[PROTO_POSE_PARTS][3] = {{0, 1.7f, 0}, {-0.3f, 1.2f, 0.4f}, {0.3f, 1.2f, 0.4f}};
    memset(p, 0, sizeof *p);
    p->yaw = rnd_float();
    p->pitch = below(8) ? (float)below(3142) / 1000.0f - 1.571f : rnd_float();
    for (unsigned k = 0; k < PROTO_POSE_PARTS; k++) {
        float at[3], q[4];
        for (int i = 0; i < 3; i++)
            at[i] = parts[k][i] + (below(8) ? (float)below(401) / 1000.0f - 0.2f : rnd_float());
        for (int i = 0; i < 4; i++)
            q[i] = (float)below(2001) / 1000.0f - 1.0f;
        if (below(2))
            proto_pose_set_part(p, k, at, q);
        if (below(16) == 0)
            p->rot[k][below(4)] = (int16_t)rnd();
    }
    if (below(16) == 0)
        p->parts = (uint8_t)rnd();
}

/* Text of about max bytes built from pieces, some of them invalid, and
 * sometimes longer than max to exercise truncation. Returns its length;
 * out gets a NUL after it and must hold max + 16 bytes. */
static size_t rnd_text(char *out, size_t max)
{
    static const char *const good[] = {"a", "Z", " ", "~", "\xc3\xa9", "\xe2\x82\xac",
                                       "\xf0\x9f\x98\x80", "\xf4\x8f\xbf\xbf"};
    static const char *const bad[] = {"\n", "\x7f", "\xff", "\xc3", "\xed\xa0\x80", "\xc0\x80"};
    size_t want = below((uint32_t)max + 9), n = 0;

    while (n < want) {
        const char *piece = below(32) == 0 ? bad[below(6)] : good[below(8)];
        size_t k = strlen(piece);

        if (n + k > max + 8)
            break;
        memcpy(out + n, piece, k);
        n += k;
    }
    out[n] = 0;
    return n;
}

/* A non-zero id, now and then 0 (which only a decoder refuses). */
static uint32_t rnd_id(void)
{
    switch (below(32)) {
    case 0: return 0;
    case 1: return (uint32_t)rnd();
    default: return 1 + below(1000);
    }
}

/* Mostly a scale in range, its bounds, now and then anything. */
static float rnd_scale(void)
{
    switch (below(16)) {
    case 0: return rnd_float();
    case 1: return PROTO_SCALE_MIN;
    case 2: return PROTO_SCALE_MAX;
    case 3: return bits_f32(0x3a83126eu); /* just under the minimum */
    default: return (float)(1 + below(100000)) / 1000.0f;
    }
}

/* A chunk's data length: mostly small; now and then max, one byte more
 * (the writer refuses it) or none (the decoder does). */
static uint32_t rnd_chunk_len(uint32_t max)
{
    switch (below(64)) {
    case 0: return max;
    case 1: return max + 1;
    case 2: return 0;
    case 3: return 1 + below(max);
    default: return 1 + below(64);
    }
}

static void rnd_transform(proto_transform *t)
{
    rnd_vec3(t->pos);
    t->yaw = below(4) ? (float)below(6284) / 1000.0f - 3.142f : rnd_float();
    t->scale = rnd_scale();
}

/* A format hint: mostly a valid extension, sometimes not, sometimes cut. */
static proto_str rnd_format(void)
{
    static const char *const formats[] = {"", "obj", "glb", "gltf", "stl", "ply", "3ds", "12345678",
                                          "OBJ", ".obj", "abcdefghij", "abcdefg\xc3\xa9", "\xc3\xa9"};
    const char *f = formats[below(16) ? below(8) : below(sizeof formats / sizeof formats[0])];
    proto_str s = {f, (uint32_t)strlen(f)};
    return s;
}

/* Appends one message of the given type with random contents. */
static void gen_frame(proto_writer *w, uint16_t type)
{
    static uint8_t data[PROTO_CHUNK_MAX + 1];
    static float box_min[PROTO_OBJECT_BOXES_MAX + 1][3], box_max[PROTO_OBJECT_BOXES_MAX + 1][3];
    char text[PROTO_MESSAGE_MAX + 16], text2[PROTO_MESSAGE_MAX + 16];

    switch (type) {
    case PROTO_HELLO: {
        proto_hello m;
        m.magic = below(8) ? PROTO_MAGIC : (uint32_t)rnd();
        m.version = (uint16_t)below(3);
        proto_put_hello(w, &m);
        break;
    }
    case PROTO_WELCOME: {
        proto_welcome m;
        m.version = PROTO_VERSION;
        m.session_id = rnd();
        for (size_t i = 0; i < PROTO_TOKEN_SIZE; i++)
            m.token[i] = (uint8_t)rnd();
        m.tick_hz = (uint16_t)below(200);
        m.aoi_radius = rnd_float();
        m.max_speed = rnd_float();
        for (int i = 0; i < 3; i++) {
            m.world_min[i] = -(float)below(5000);
            m.world_max[i] = (float)below(5000);
        }
        m.idle_timeout_ms = below(16) ? 1 + below(120000) : (uint32_t)rnd();
        proto_put_welcome(w, &m);
        break;
    }
    case PROTO_JOIN: {
        proto_join m;
        static uint8_t secret[PROTO_PASSWORD_MAX];
        m.name.ptr = text;
        m.name.len = (uint32_t)rnd_text(text, PROTO_NAME_MAX);
        for (int i = 0; i < 3; i++)
            m.box[i] = rnd_box();
        m.credential = (uint8_t)below(3);
        m.secret_len = m.credential == PROTO_CRED_PASSWORD ? 1 + below(PROTO_PASSWORD_MAX)
                       : m.credential == PROTO_CRED_TOKEN  ? PROTO_RESUME_TOKEN_SIZE
                                                           : 0;
        for (uint32_t i = 0; i < m.secret_len; i++)
            secret[i] = (uint8_t)rnd();
        m.secret = secret;
        proto_put_join(w, &m);
        break;
    }
    case PROTO_JOIN_OK: {
        proto_join_ok m;
        m.avatar_id = (uint32_t)rnd();
        rnd_vec3(m.pos);
        for (int i = 0; i < 3; i++)
            m.box[i] = rnd_box();
        m.has_token = (uint8_t)below(2);
        for (unsigned i = 0; i < PROTO_RESUME_TOKEN_SIZE; i++)
            m.token[i] = (uint8_t)rnd();
        proto_put_join_ok(w, &m);
        break;
    }
    case PROTO_MOVE: {
        proto_move m;
        m.seq = (uint32_t)rnd();
        rnd_vec3(m.pos);
        m.has_pose = below(2) == 0;
        rnd_pose(&m.pose);
        proto_put_move(w, &m);
        break;
    }
    case PROTO_SNAPSHOT: {
        /* Now and then the largest snapshot, or one entry too many. */
        uint32_t n = below(4) ? below(8) : below(200), tick, ack;
        size_t at;

        if (below(2048) == 0)
            n = PROTO_SNAPSHOT_MAX_ENTRIES + below(2);
        tick = (uint32_t)rnd();
        ack = (uint32_t)rnd();
        at = proto_put_snapshot_begin(w, tick, ack);
        for (uint32_t i = 0; i < n; i++) {
            proto_avatar a;
            a.id = below(1000);
            rnd_vec3(a.pos);
            proto_put_snapshot_add(w, at, &a);
        }
        proto_put_snapshot_end(w, at);
        break;
    }
    case PROTO_AVATAR_JOINED: {
        proto_avatar_joined m;
        m.id = (uint32_t)rnd();
        m.name.ptr = text;
        m.name.len = (uint32_t)rnd_text(text, PROTO_NAME_MAX);
        rnd_vec3(m.pos);
        for (int i = 0; i < 3; i++)
            m.box[i] = rnd_box();
        proto_put_avatar_joined(w, &m);
        break;
    }
    case PROTO_AVATAR_LEFT: {
        proto_avatar_left m;
        m.id = (uint32_t)rnd();
        m.reason = (uint8_t)below(3);
        proto_put_avatar_left(w, &m);
        break;
    }
    case PROTO_ERROR:
        rnd_text(text, PROTO_MESSAGE_MAX);
        proto_put_error(w, (uint16_t)(below(16) ? 16 + below(20) : rnd()), text);
        break;
    case PROTO_PING: proto_put_ping(w, rnd()); break;
    case PROTO_PONG: proto_put_pong(w, rnd()); break;
    case PROTO_BYE: proto_put_bye(w, (uint8_t)below(4)); break;
    case PROTO_AVATAR_POSE: {
        proto_avatar_pose m = {.id = (uint32_t)rnd()};
        rnd_pose(&m.pose);
        proto_put_avatar_pose(w, &m);
        break;
    }
    case PROTO_OBJECT_UPLOAD_BEGIN: {
        proto_upload_begin m;
        m.upload_id = rnd_id();
        m.total_size = below(32) ? 1 + below(1u << 24) : (uint32_t)rnd();
        m.name.ptr = text;
        m.name.len = (uint32_t)rnd_text(text, PROTO_OBJECT_NAME_MAX);
        m.format = rnd_format();
        m.up_axis = (uint8_t)(below(16) ? below(2) : below(256));
        m.unit_scale = rnd_scale();
        proto_put_upload_begin(w, &m);
        break;
    }
    case PROTO_OBJECT_UPLOAD_CHUNK: {
        proto_upload_chunk m;
        m.upload_id = rnd_id();
        m.offset = below(2) ? below(1u << 24) : (uint32_t)rnd();
        m.len = rnd_chunk_len(PROTO_CHUNK_MAX);
        for (uint32_t i = 0; i < m.len; i++)
            data[i] = (uint8_t)rnd();
        m.data = data;
        proto_put_upload_chunk(w, &m);
        break;
    }
    case PROTO_OBJECT_UPLOAD_END: {
        proto_upload_end m;
        m.upload_id = rnd_id();
        rnd_transform(&m.at);
        proto_put_upload_end(w, &m);
        break;
    }
    case PROTO_OBJECT_PLACE: {
        proto_object_place m;
        m.object_id = rnd_id();
        rnd_transform(&m.at);
        proto_put_object_place(w, &m);
        break;
    }
    case PROTO_OBJECT_REMOVE: proto_put_object_remove(w, rnd_id()); break;
    case PROTO_OBJECT_REMOVED: proto_put_object_removed(w, rnd_id()); break;
    case PROTO_OBJECT_INFO: {
        /* Now and then the most boxes, or one box too many. */
        proto_object_info m;
        m.object_id = rnd_id();
        m.upload_id = below(2) ? 0 : rnd_id();
        /* Two random texts would rarely both be valid: one is often plain. */
        m.owner.ptr = text;
        m.owner.len = (uint32_t)rnd_text(text, PROTO_NAME_MAX);
        m.name.ptr = text2;
        if (below(2))
            m.name.len = (uint32_t)snprintf(text2, sizeof text2, "object %u.obj", (unsigned)below(1000));
        else
            m.name.len = (uint32_t)rnd_text(text2, PROTO_OBJECT_NAME_MAX);
        rnd_transform(&m.at);
        m.ecm_version = rnd_id();
        m.tri_count = (uint32_t)rnd();
        for (unsigned i = 0; i < PROTO_MESH_HASH_SIZE; i++)
            m.mesh_hash[i] = (uint8_t)rnd();
        m.box_count = (uint16_t)(below(4) ? below(8) : below(200));
        if (below(512) == 0)
            m.box_count = (uint16_t)(PROTO_OBJECT_BOXES_MAX + below(2));
        m.boxes = NULL;
        for (uint16_t i = 0; i < m.box_count; i++) {
            rnd_vec3(box_min[i]);
            for (int k = 0; k < 3; k++) {
                /* Mostly a proper box, flat now and then, rarely inside out. */
                switch (below(256)) {
                case 0: box_max[i][k] = box_min[i][k] - 1.0f; break;
                case 1: box_max[i][k] = box_min[i][k]; break;
                default: box_max[i][k] = box_min[i][k] + (float)below(100); break;
                }
            }
        }
        proto_put_object_info(w, &m, (const float (*)[3])box_min, (const float (*)[3])box_max);
        break;
    }
    case PROTO_MESH_REQUEST: {
        proto_mesh_request m = {.object_id = rnd_id()};
        for (unsigned i = 0; i < PROTO_MESH_HASH_SIZE; i++)
            m.mesh_hash[i] = (uint8_t)rnd();
        proto_put_mesh_request(w, &m);
        break;
    }
    case PROTO_MESH_CHUNK: {
        /* Mostly a chunk inside its total; now and then the largest, one
         * byte more (the writer refuses it), none, or one running past the
         * total or starting at it (the decoder refuses those). */
        proto_mesh_chunk m;
        m.object_id = rnd_id();
        m.len = rnd_chunk_len(PROTO_MESH_CHUNK_MAX);
        m.offset = below(2) ? below(1u << 20) : 0;
        m.total = m.offset + m.len + (below(8) ? below(1u << 20) : 0);
        if (below(32) == 0)
            m.total = below(2) ? m.offset : m.offset + m.len - 1;
        for (uint32_t i = 0; i < m.len && i < PROTO_MESH_CHUNK_MAX; i++)
            data[i] = (uint8_t)rnd();
        m.data = data;
        proto_put_mesh_chunk(w, &m);
        break;
    }
    case PROTO_OBJECT_REJECTED: {
        uint32_t id = rnd_id();
        uint16_t code = (uint16_t)(below(16) ? PROTO_ERR_UPLOAD + below(4) : rnd());
        rnd_text(text, PROTO_MESSAGE_MAX);
        proto_put_object_rejected(w, id, code, text);
        break;
    }
    default: {
        proto_collision m;
        m.object_id = rnd_id();
        m.ecm_version = rnd_id();
        m.box_index = (uint16_t)below(1100);
        m.inside = (uint8_t)(below(16) ? below(2) : below(256));
        rnd_vec3(m.point);
        rnd_vec3(m.normal);
        proto_put_collision(w, &m);
        break;
    }
    }
}

/*
 * Applies one random mutation to in[0..*len). starts[] are the offsets
 * where the generated frames began, so that length and type corruption
 * hit real header fields. *len never exceeds max.
 */
static void mutate(uint8_t *in, size_t *len, size_t max, const size_t *starts, size_t nstarts)
{
    static const uint8_t bytes[] = {0x00, 0x01, 0x1f, 0x20, 0x7f, 0x80, 0xbf, 0xc0, 0xff};
    size_t n = *len, s = nstarts ? starts[below((uint32_t)nstarts)] : 0;

    switch (below(10)) {
    case 0: /* flip a bit */
        if (n) {
            size_t at = below((uint32_t)n);
            in[at] ^= (uint8_t)(1u << below(8));
        }
        break;
    case 1: /* set a byte to a boundary value */
        if (n) {
            size_t at = below((uint32_t)n);
            in[at] = bytes[below(sizeof bytes)];
        }
        break;
    case 2: /* truncate */
        *len = below((uint32_t)n + 1);
        break;
    case 3: /* corrupt a frame's length */
        if (s + 4 <= n) {
            const uint32_t cur = (uint32_t)in[s] | (uint32_t)in[s + 1] << 8 |
                                 (uint32_t)in[s + 2] << 16 | (uint32_t)in[s + 3] << 24;
            const uint32_t lens[] = {0, 1, 2, cur - 1, cur + 1, PROTO_MAX_LEN_PREJOIN,
                                     PROTO_MAX_LEN_PREJOIN + 1, PROTO_MAX_LEN, PROTO_MAX_LEN + 1,
                                     0xffffffffu, 0x80000000u, (uint32_t)rnd()};
            fz_set_le(in + s, lens[below(sizeof lens / sizeof lens[0])], 4);
        }
        break;
    case 4: /* corrupt a frame's type */
        if (s + 6 <= n) {
            const uint32_t t = below(4) ? below(96) : (uint32_t)rnd();
            in[s + 4] = (uint8_t)t;
            in[s + 5] = (uint8_t)(t >> 8);
        }
        break;
    case 5: /* a NaN or infinity somewhere */
        if (n >= 4) {
            const uint32_t bad[] = {0x7fc00000u, 0x7f800000u, 0xff800000u, 0x7f800001u};
            size_t at = below((uint32_t)n - 3);
            fz_set_le(in + at, bad[below(4)], 4);
        }
        break;
    case 6: /* overwrite a span with noise */
        if (n) {
            size_t at = below((uint32_t)n), k = 1 + below(16);
            for (size_t i = at; i < n && i < at + k; i++)
                in[i] = (uint8_t)rnd();
        }
        break;
    case 7: /* insert noise */
        if (n + 16 <= max) {
            size_t at = below((uint32_t)n + 1), k = 1 + below(16);
            memmove(in + at + k, in + at, n - at);
            for (size_t i = at; i < at + k; i++)
                in[i] = (uint8_t)rnd();
            *len = n + k;
        }
        break;
    case 8: /* delete a span */
        if (n) {
            size_t at = below((uint32_t)n), k = 1 + below(16);
            if (k > n - at)
                k = n - at;
            memmove(in + at, in + at + k, n - at - k);
            *len = n - k;
        }
        break;
    default: /* replace everything with noise */
        *len = below(256) % (max + 1);
        for (size_t i = 0; i < *len; i++)
            in[i] = (uint8_t)rnd();
        break;
    }
}

/* One to three valid frames of random types and contents, then zero to
 * three corruptions. */
static size_t proto_generate(uint8_t *out, size_t max)
{
    proto_writer w;
    size_t starts[MAX_FRAMES], nstarts = 0, len;
    uint32_t frames = 1 + below(MAX_FRAMES), muts = below(4);

    proto_writer_init(&w, out, max);
    for (uint32_t i = 0; i < frames; i++) {
        starts[nstarts++] = w.len;
        gen_frame(&w, types[below(NTYPES)]);
    }
    len = w.len;
    for (uint32_t i = 0; i < muts; i++)
        mutate(out, &len, max, starts, nstarts);
    return len;
}

/* Where the frames of data[0..size) start, read as a connection reads
 * them (headers only, lengths trusted up to the end). Returns how many. */
static size_t frame_starts(const uint8_t *data, size_t size, size_t *starts, size_t max_starts)
{
    size_t n = 0, at = 0;

    while (n < max_starts && at + PROTO_HEADER_SIZE <= size) {
        starts[n++] = at;
        at += 4 + (size_t)le_get_u32(data + at);
    }
    return n;
}

/* A frame replaced by a new one, a new one inserted, or one corrupted. */
static size_t proto_mutate(uint8_t *data, size_t size, size_t max)
{
    static uint8_t frame[PROTO_MAX_LEN + 4];
    size_t starts[64], n = frame_starts(data, size, starts, 64), len = size;
    size_t k = n ? fz_below((uint32_t)n) : 0, at = n ? starts[k] : size;
    size_t end = k + 1 < n ? starts[k + 1] : size;
    proto_writer w;

    switch (fz_below(3)) {
    case 0: /* replaced */
    case 1: /* inserted */
        proto_writer_init(&w, frame, sizeof frame);
        gen_frame(&w, types[below(NTYPES)]);
        fz_splice(data, &len, max, at, fz_one_in(2) ? end : at, frame, w.len);
        return len;
    default:
        mutate(data, &len, max, starts, n);
        return len;
    }
}

/* Writes one valid frame of each type to DIR/<type name>, a starting
 * corpus for libFuzzer. */
static int write_seeds(const char *dir)
{
    static uint8_t buf[PROTO_MAX_LEN + 4];

    if (mkdir(dir, 0777) != 0 && errno != EEXIST) {
        perror(dir);
        return 1;
    }
    fz_seed(1);
    for (size_t i = 0; i < NTYPES; i++) {
        const uint16_t t = types[i];
        char path[4096];
        proto_writer w;
        proto_frame f;
        proto_msg m;
        FILE *fp;

        /* Draw until the random contents make a frame that decodes. */
        do {
            proto_writer_init(&w, buf, sizeof buf);
            gen_frame(&w, t);
        } while (w.err != PROTO_OK || proto_frame_parse(buf, w.len, PROTO_MAX_LEN, &f) != PROTO_OK ||
                 proto_decode(&f, &m) != PROTO_OK);
        snprintf(path, sizeof path, "%s/%s", dir, proto_type_name(t));
        fp = fopen(path, "wb");
        if (!fp || fwrite(buf, 1, w.len, fp) != w.len || fclose(fp) != 0) {
            perror(path);
            return 1;
        }
    }
    printf("fuzz_proto: wrote %zu seeds to %s\n", NTYPES, dir);
    return 0;
}

static int proto_command(int argc, char **argv)
{
    if (argc == 3 && strcmp(argv[1], "--write-seeds") == 0)
        return write_seeds(argv[2]);
    return -1;
}

/* If the second number drops to near zero, inputs no longer reach the
 * decoder. */
static void proto_report(void)
{
    fprintf(stderr, "fuzz_proto: %lu frames parsed, %lu decoded and round-tripped\n", n_frames,
            n_decoded);
}

const fz_target fz_self = {"fuzz_proto", NULL,          proto_generate, proto_mutate,
                           proto_command, proto_report, NULL};
