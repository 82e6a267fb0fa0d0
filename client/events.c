/* events.c: JSON event lines on stdout (see events.h), or, on a terminal,
 * the short lines of terminal.c. */
#include "events.h"

#include <inttypes.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "json.h"
#include "sbuf.h"
#include "terminal.h"

/* Set by events_to_terminal(): the script's events go to terminal.c. */
static int to_terminal;

/* The line being built; written and flushed whole at its end, so one event
 * never reaches the reader in two pieces. */
static sbuf line;

void events_to_terminal(int on) { to_terminal = on; }

static void begin(const char *event, int bot)
{
    sb_clear(&line);
    sb_printf(&line, "{\"event\":\"%s\"", event);
    if (bot >= 0)
        sb_printf(&line, ",\"bot\":%d", bot);
}

static void finish(void)
{
    sb_puts(&line, "}\n");
    fwrite(line.p, 1, line.len, stdout);
    fflush(stdout);
}

/* Floats with millimetre precision; JSON has no NaN or infinity (the codec
 * refuses them on the wire, so null only guards local values). */
static void put_float(float v)
{
    if (isfinite(v))
        sb_printf(&line, "%.3f", (double)v);
    else
        sb_puts(&line, "null");
}

static void put_floats(const char *key, const float *v, int n)
{
    if (key)
        sb_printf(&line, ",\"%s\":[", key);
    else
        sb_puts(&line, "[");
    for (int i = 0; i < n; i++) {
        if (i)
            sb_puts(&line, ",");
        put_float(v[i]);
    }
    sb_puts(&line, "]");
}

static void put_vec3(const char *key, const float v[3]) { put_floats(key, v, 3); }

/* Angles and scales: three decimals would lose too much of them (a scale
 * of 0.0015, a tenth of a degree), so they get the seven significant digits
 * a float holds. */
static void put_fine(const char *key, float v)
{
    sb_printf(&line, ",\"%s\":", key);
    if (isfinite(v))
        sb_printf(&line, "%.7g", (double)v);
    else
        sb_puts(&line, "null");
}

/* A string field; base/json.c escapes it (the server's strings are clean,
 * local messages such as strerror texts and paths need not be). */
static void put_string(const char *key, const char *s, size_t len)
{
    sb_printf(&line, ",\"%s\":", key);
    json_put_string(&line, s, len);
}

/* Hex digits of a token. */
static void put_hex(const uint8_t *p, unsigned n)
{
    for (unsigned i = 0; i < n; i++)
        sb_printf(&line, "%02x", p[i]);
}

void events_error(int bot, unsigned code, const char *text, size_t len)
{
    if (to_terminal && bot < 0) {
        terminal_error(code, text, len);
        return;
    }
    begin("error", bot);
    sb_printf(&line, ",\"code\":%u", code);
    put_string("message", text, len);
    finish();
}

void events_bye(int bot, unsigned reason)
{
    if (to_terminal && bot < 0) {
        terminal_bye(reason, 0);
        return;
    }
    begin("bye", bot);
    sb_printf(&line, ",\"reason\":\"%s\"", proto_bye_name(reason));
    finish();
}

void events_bye_sent(unsigned reason)
{
    if (to_terminal) {
        terminal_bye(reason, 1);
        return;
    }
    begin("bye", -1);
    sb_printf(&line, ",\"reason\":\"%s\",\"from\":\"client\"", proto_bye_name(reason));
    finish();
}

void events_closed(int bot)
{
    if (to_terminal && bot < 0) {
        terminal_closed();
        return;
    }
    begin("closed", bot);
    finish();
}

static void welcome(const proto_welcome *w)
{
    begin("welcome", -1);
    sb_printf(&line, ",\"session\":%" PRIu64 ",\"token\":\"", w->session_id);
    put_hex(w->token, PROTO_TOKEN_SIZE);
    sb_printf(&line, "\",\"tick_hz\":%u,\"aoi_radius\":", (unsigned)w->tick_hz);
    put_float(w->aoi_radius);
    sb_puts(&line, ",\"max_speed\":");
    put_float(w->max_speed);
    put_vec3("world_min", w->world_min);
    put_vec3("world_max", w->world_max);
    finish();
}

static void snapshot(const proto_snapshot *s)
{
    begin("snapshot", -1);
    sb_printf(&line, ",\"tick\":%" PRIu32 ",\"ack\":%" PRIu32 ",\"avatars\":[", s->tick, s->ack_seq);
    for (uint16_t i = 0; i < s->count; i++) {
        proto_avatar a;
        proto_snapshot_entry(s, i, &a);
        sb_printf(&line, "%s{\"id\":%" PRIu32, i ? "," : "", a.id);
        put_vec3("pos", a.pos);
        sb_puts(&line, "}");
    }
    sb_puts(&line, "]");
    finish();
}

static void object_info(const proto_object_info *o)
{
    begin("object", -1);
    sb_printf(&line, ",\"id\":%" PRIu32 ",\"upload\":%" PRIu32, o->object_id, o->upload_id);
    put_string("owner", o->owner.ptr, o->owner.len);
    put_string("name", o->name.ptr, o->name.len);
    put_vec3("pos", o->at.pos);
    put_fine("yaw", o->at.yaw);
    put_fine("scale", o->at.scale);
    sb_printf(&line, ",\"ecm_version\":%" PRIu32 ",\"triangles\":%" PRIu32 ",\"mesh\":\"", o->ecm_version,
              o->tri_count);
    put_hex(o->mesh_hash, PROTO_MESH_HASH_SIZE);
    sb_puts(&line, "\",\"boxes\":[");
    for (uint16_t i = 0; i < o->box_count; i++) {
        float box[6];
        proto_object_box(o, i, box, box + 3);
        if (i)
            sb_puts(&line, ",");
        put_floats(NULL, box, 6);
    }
    sb_puts(&line, "]");
    finish();
}

/* An avatar's pose: the facing in radians and each part present, its
 * position in metres from the avatar and its quaternion (x, y, z, w). */
static void avatar_pose(const proto_avatar_pose *a)
{
    static const char *const part_names[PROTO_POSE_PARTS] = {"head", "left", "right"};
    begin("pose", -1);
    sb_printf(&line, ",\"id\":%" PRIu32, a->id);
    put_fine("yaw", a->pose.yaw);
    put_fine("pitch", a->pose.pitch);
    for (unsigned k = 0; k < PROTO_POSE_PARTS; k++) {
        if (!PROTO_POSE_HAS(&a->pose, k))
            continue;
        float at[3], q[4];
        for (int i = 0; i < 3; i++)
            at[i] = (float)a->pose.pos[k][i] / 1000.0f;
        for (int i = 0; i < 4; i++)
            q[i] = (float)a->pose.rot[k][i] / (float)PROTO_QUAT_ONE;
        sb_printf(&line, ",\"%s\":{\"pos\":", part_names[k]);
        put_floats(NULL, at, 3);
        sb_puts(&line, ",\"rot\":");
        put_floats(NULL, q, 4);
        sb_puts(&line, "}");
    }
    finish();
}

static void collision(const proto_collision *c)
{
    begin("collision", -1);
    sb_printf(&line, ",\"object\":%" PRIu32 ",\"ecm_version\":%" PRIu32 ",\"box\":%u,\"inside\":%s", c->object_id,
              c->ecm_version, (unsigned)c->box_index, c->inside ? "true" : "false");
    put_vec3("point", c->point);
    put_vec3("normal", c->normal);
    finish();
}

void events_message(const proto_msg *m, uint64_t now_us)
{
    if (to_terminal) {
        terminal_message(m, now_us);
        return;
    }
    switch (m->type) {
    case PROTO_WELCOME:
        welcome(&m->u.welcome);
        break;
    case PROTO_JOIN_OK:
        begin("join_ok", -1);
        sb_printf(&line, ",\"id\":%" PRIu32, m->u.join_ok.avatar_id);
        put_vec3("pos", m->u.join_ok.pos);
        put_vec3("box", m->u.join_ok.box);
        if (m->u.join_ok.has_token) { /* for CVRE_TOKEN on the next join */
            sb_puts(&line, ",\"resume_token\":\"");
            put_hex(m->u.join_ok.token, PROTO_RESUME_TOKEN_SIZE);
            sb_puts(&line, "\"");
        }
        finish();
        break;
    case PROTO_AVATAR_JOINED:
        begin("joined", -1);
        sb_printf(&line, ",\"id\":%" PRIu32, m->u.avatar_joined.id);
        put_string("name", m->u.avatar_joined.name.ptr, m->u.avatar_joined.name.len);
        put_vec3("pos", m->u.avatar_joined.pos);
        put_vec3("box", m->u.avatar_joined.box);
        finish();
        break;
    case PROTO_AVATAR_LEFT:
        begin("left", -1);
        sb_printf(&line, ",\"id\":%" PRIu32 ",\"reason\":\"%s\"", m->u.avatar_left.id,
                  m->u.avatar_left.reason == PROTO_LEFT_OUT_OF_RANGE ? "out_of_range" : "disconnected");
        finish();
        break;
    case PROTO_SNAPSHOT:
        snapshot(&m->u.snapshot);
        break;
    case PROTO_ERROR:
        events_error(-1, m->u.error.code, m->u.error.message.ptr, m->u.error.message.len);
        break;
    case PROTO_PONG: {
        uint64_t stamp = m->u.ping.stamp;
        begin("pong", -1);
        sb_printf(&line, ",\"stamp\":%" PRIu64 ",\"rtt_ms\":%.3f", stamp,
                  now_us >= stamp ? (double)(now_us - stamp) / 1000.0 : 0.0);
        finish();
        break;
    }
    case PROTO_BYE:
        events_bye(-1, m->u.bye.reason);
        break;
    case PROTO_OBJECT_INFO:
        object_info(&m->u.object_info);
        break;
    case PROTO_OBJECT_REMOVED:
        begin("object_removed", -1);
        sb_printf(&line, ",\"id\":%" PRIu32, m->u.object_id);
        finish();
        break;
    case PROTO_OBJECT_REJECTED:
        begin("rejected", -1);
        sb_printf(&line, ",\"request\":%" PRIu32 ",\"code\":%u", m->u.object_rejected.request_id,
                  (unsigned)m->u.object_rejected.code);
        put_string("message", m->u.object_rejected.message.ptr, m->u.object_rejected.message.len);
        finish();
        break;
    case PROTO_COLLISION:
        collision(&m->u.collision);
        break;
    case PROTO_AVATAR_POSE:
        avatar_pose(&m->u.avatar_pose);
        break;
    default:
        break;
    }
}

int events_conn_end(int bot, const session_end *end, const char *peer)
{
    char text[PROTO_MESSAGE_MAX + 100];
    unsigned code = 0;
    if (end->after_bye && end->kind == SESSION_END_SOCKET)
        return 0; /* a reset after our bye is just how some servers close */
    switch (end->kind) {
    case SESSION_END_CONNECT:
        snprintf(text, sizeof text, "client: cannot connect to %s: %s", peer, strerror(end->code));
        break;
    case SESSION_END_SOCKET:
        snprintf(text, sizeof text, "client: connection to %s failed: %s", peer, strerror(end->code));
        break;
    case SESSION_END_PROTO:
        snprintf(text, sizeof text, "client: bad frame from server: %s", proto_strerror(end->code));
        code = (unsigned)end->code;
        break;
    case SESSION_END_WEBSOCKET:
        snprintf(text, sizeof text, "client: %s: %s", peer, end->why);
        break;
    default:
        return 0;
    }
    events_error(bot, code, text, strlen(text));
    return 1;
}

void events_done(const char *command, const float pos[3])
{
    if (to_terminal) {
        terminal_done(command, pos);
        return;
    }
    begin("done", -1);
    sb_printf(&line, ",\"command\":\"%s\"", command);
    put_vec3("pos", pos);
    finish();
}

void events_done_object(const char *command, const char *result, uint32_t object_id, uint32_t upload_id,
                        double seconds, const float box[6])
{
    if (to_terminal) {
        terminal_done_object(command, result, object_id, seconds, box);
        return;
    }
    begin("done", -1);
    sb_printf(&line, ",\"command\":\"%s\",\"result\":\"%s\",\"object\":", command, result);
    if (object_id)
        sb_printf(&line, "%" PRIu32, object_id);
    else
        sb_puts(&line, "null");
    if (upload_id)
        sb_printf(&line, ",\"upload\":%" PRIu32, upload_id);
    sb_printf(&line, ",\"seconds\":%.3f", seconds);
    if (box) {
        put_vec3("box_min", box);
        put_vec3("box_max", box + 3);
    }
    finish();
}

void events_fetched(uint32_t object_id, const char *file, uint32_t vertices, uint32_t triangles, size_t bytes,
                    int cached)
{
    if (to_terminal) {
        terminal_fetched(object_id, file, triangles, cached);
        return;
    }
    begin("fetched", -1);
    sb_printf(&line, ",\"object\":%" PRIu32, object_id);
    put_string("file", file, strlen(file));
    sb_printf(&line, ",\"vertices\":%" PRIu32 ",\"triangles\":%" PRIu32 ",\"bytes\":%zu,\"cached\":%s", vertices,
              triangles, bytes, cached ? "true" : "false");
    finish();
}

static void counts(const char *event, const events_counts *k, const char *time_key, double t)
{
    begin(event, -1);
    sb_printf(&line,
              ",\"%s\":%.3f,\"connected\":%" PRIu64 ",\"joined\":%" PRIu64 ",\"moves_sent\":%" PRIu64
              ",\"moves_dropped\":%" PRIu64 ",\"frames_in\":%" PRIu64 ",\"bytes_in\":%" PRIu64
              ",\"errors\":%" PRIu64 ",\"disconnects\":%" PRIu64 ",\"collisions\":%" PRIu64,
              time_key, t, k->connected, k->joined, k->moves_sent, k->moves_dropped, k->frames_in, k->bytes_in,
              k->errors, k->disconnects, k->collisions);
    finish();
}

void events_stats(const events_counts *k, double t) { counts("stats", k, "t", t); }

void events_summary(const events_counts *k, double duration) { counts("summary", k, "duration", duration); }
