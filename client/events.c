/* events.c: JSON event lines on stdout (see events.h). */
#include "events.h"

#include <inttypes.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "utf8.h"

/* Each line is built with stdio's buffer and flushed whole at its end, so
 * one event never reaches the reader in two pieces. */
static void begin(const char *event, int bot)
{
    printf("{\"event\":\"%s\"", event);
    if (bot >= 0)
        printf(",\"bot\":%d", bot);
}

static void finish(void)
{
    fputs("}\n", stdout);
    fflush(stdout);
}

/* Floats with millimetre precision; JSON has no NaN or infinity (the codec
 * refuses them on the wire, so null only guards local values). */
static void put_float(float v)
{
    if (isfinite(v))
        printf("%.3f", (double)v);
    else
        fputs("null", stdout);
}

static void put_vec3(const char *key, const float v[3])
{
    printf(",\"%s\":[", key);
    for (int i = 0; i < 3; i++) {
        if (i)
            putchar(',');
        put_float(v[i]);
    }
    putchar(']');
}

/* Angles and scales: three decimals would lose too much of them (a scale
 * of 0.0015, a tenth of a degree), so they get the seven significant digits
 * a float holds. */
static void put_fine(const char *key, float v)
{
    printf(",\"%s\":", key);
    if (isfinite(v))
        printf("%.7g", (double)v);
    else
        fputs("null", stdout);
}

/* A JSON string from len bytes: quotes, backslashes and control characters
 * escaped, bytes that are not UTF-8 replaced by U+FFFD. The server's strings
 * are already clean; local messages (strerror, paths) need not be. */
static void put_string(const char *key, const char *s, size_t len)
{
    const unsigned char *p = (const unsigned char *)s;
    printf(",\"%s\":\"", key);
    for (size_t i = 0; i < len;) {
        unsigned char ch = p[i];
        if (ch == '"' || ch == '\\') {
            putchar('\\');
            putchar(ch);
            i++;
        } else if (ch == '\n') {
            fputs("\\n", stdout);
            i++;
        } else if (ch == '\t') {
            fputs("\\t", stdout);
            i++;
        } else if (ch == '\r') {
            fputs("\\r", stdout);
            i++;
        } else if (ch < 0x20u) {
            printf("\\u%04x", ch);
            i++;
        } else {
            uint32_t cp;
            size_t k = utf8_next(p + i, len - i, &cp);
            if (k == 0) {
                fputs("\\ufffd", stdout);
                i++;
            } else {
                fwrite(p + i, 1, k, stdout);
                i += k;
            }
        }
    }
    putchar('"');
}

void events_error(int bot, unsigned code, const char *text, size_t len)
{
    begin("error", bot);
    printf(",\"code\":%u", code);
    put_string("message", text, len);
    finish();
}

static const char *bye_reason(unsigned reason)
{
    return reason == PROTO_BYE_SHUTDOWN ? "shutdown" : reason == PROTO_BYE_KICKED ? "kicked" : "quit";
}

void events_bye(int bot, unsigned reason)
{
    begin("bye", bot);
    printf(",\"reason\":\"%s\"", bye_reason(reason));
    finish();
}

void events_bye_sent(unsigned reason)
{
    begin("bye", -1);
    printf(",\"reason\":\"%s\",\"from\":\"client\"", bye_reason(reason));
    finish();
}

void events_closed(int bot)
{
    begin("closed", bot);
    finish();
}

static void welcome(const proto_welcome *w)
{
    begin("welcome", -1);
    printf(",\"session\":%" PRIu64 ",\"token\":\"", w->session_id);
    for (unsigned i = 0; i < PROTO_TOKEN_SIZE; i++)
        printf("%02x", w->token[i]);
    printf("\",\"tick_hz\":%u,\"aoi_radius\":", (unsigned)w->tick_hz);
    put_float(w->aoi_radius);
    fputs(",\"max_speed\":", stdout);
    put_float(w->max_speed);
    put_vec3("world_min", w->world_min);
    put_vec3("world_max", w->world_max);
    finish();
}

static void snapshot(const proto_snapshot *s)
{
    begin("snapshot", -1);
    printf(",\"tick\":%" PRIu32 ",\"ack\":%" PRIu32 ",\"avatars\":[", s->tick, s->ack_seq);
    for (uint16_t i = 0; i < s->count; i++) {
        proto_avatar a;
        proto_snapshot_entry(s, i, &a);
        printf("%s{\"id\":%" PRIu32, i ? "," : "", a.id);
        put_vec3("pos", a.pos);
        putchar('}');
    }
    putchar(']');
    finish();
}

static void object_info(const proto_object_info *o)
{
    begin("object", -1);
    printf(",\"id\":%" PRIu32 ",\"upload\":%" PRIu32, o->object_id, o->upload_id);
    put_string("owner", o->owner.ptr, o->owner.len);
    put_string("name", o->name.ptr, o->name.len);
    put_vec3("pos", o->at.pos);
    put_fine("yaw", o->at.yaw);
    put_fine("scale", o->at.scale);
    printf(",\"ecm_version\":%" PRIu32 ",\"triangles\":%" PRIu32 ",\"boxes\":[", o->ecm_version, o->tri_count);
    for (uint16_t i = 0; i < o->box_count; i++) {
        float lo[3], hi[3];
        proto_object_box(o, i, lo, hi);
        fputs(i ? ",[" : "[", stdout);
        for (int k = 0; k < 6; k++) {
            if (k)
                putchar(',');
            put_float(k < 3 ? lo[k] : hi[k - 3]);
        }
        putchar(']');
    }
    putchar(']');
    finish();
}

static void collision(const proto_collision *c)
{
    begin("collision", -1);
    printf(",\"object\":%" PRIu32 ",\"ecm_version\":%" PRIu32 ",\"box\":%u,\"inside\":%s", c->object_id,
           c->ecm_version, (unsigned)c->box_index, c->inside ? "true" : "false");
    put_vec3("point", c->point);
    put_vec3("normal", c->normal);
    finish();
}

void events_message(const proto_msg *m, uint64_t now_us)
{
    switch (m->type) {
    case PROTO_WELCOME:
        welcome(&m->u.welcome);
        break;
    case PROTO_JOIN_OK:
        begin("join_ok", -1);
        printf(",\"id\":%" PRIu32, m->u.join_ok.avatar_id);
        put_vec3("pos", m->u.join_ok.pos);
        put_vec3("box", m->u.join_ok.box);
        if (m->u.join_ok.has_token) { /* for CVRE_TOKEN on the next join */
            fputs(",\"resume_token\":\"", stdout);
            for (unsigned i = 0; i < PROTO_RESUME_TOKEN_SIZE; i++)
                printf("%02x", m->u.join_ok.token[i]);
            putchar('"');
        }
        finish();
        break;
    case PROTO_AVATAR_JOINED:
        begin("joined", -1);
        printf(",\"id\":%" PRIu32, m->u.avatar_joined.id);
        put_string("name", m->u.avatar_joined.name.ptr, m->u.avatar_joined.name.len);
        put_vec3("pos", m->u.avatar_joined.pos);
        put_vec3("box", m->u.avatar_joined.box);
        finish();
        break;
    case PROTO_AVATAR_LEFT:
        begin("left", -1);
        printf(",\"id\":%" PRIu32 ",\"reason\":\"%s\"", m->u.avatar_left.id,
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
        printf(",\"stamp\":%" PRIu64 ",\"rtt_ms\":%.3f", stamp,
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
        printf(",\"id\":%" PRIu32, m->u.object_id);
        finish();
        break;
    case PROTO_OBJECT_REJECTED:
        begin("rejected", -1);
        printf(",\"request\":%" PRIu32 ",\"code\":%u", m->u.object_rejected.request_id,
               (unsigned)m->u.object_rejected.code);
        put_string("message", m->u.object_rejected.message.ptr, m->u.object_rejected.message.len);
        finish();
        break;
    case PROTO_COLLISION:
        collision(&m->u.collision);
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
    default:
        return 0;
    }
    events_error(bot, code, text, strlen(text));
    return 1;
}

void events_done(const char *command, const float pos[3])
{
    begin("done", -1);
    printf(",\"command\":\"%s\"", command);
    put_vec3("pos", pos);
    finish();
}

void events_done_object(const char *command, const char *result, uint32_t object_id, uint32_t upload_id,
                        double seconds)
{
    begin("done", -1);
    printf(",\"command\":\"%s\",\"result\":\"%s\",\"object\":", command, result);
    if (object_id)
        printf("%" PRIu32, object_id);
    else
        fputs("null", stdout);
    if (upload_id)
        printf(",\"upload\":%" PRIu32, upload_id);
    printf(",\"seconds\":%.3f", seconds);
    finish();
}

static void counts(const char *event, const events_counts *k, const char *time_key, double t)
{
    begin(event, -1);
    printf(",\"%s\":%.3f,\"connected\":%" PRIu64 ",\"joined\":%" PRIu64 ",\"moves_sent\":%" PRIu64
           ",\"moves_dropped\":%" PRIu64 ",\"frames_in\":%" PRIu64 ",\"bytes_in\":%" PRIu64
           ",\"errors\":%" PRIu64 ",\"disconnects\":%" PRIu64 ",\"collisions\":%" PRIu64,
           time_key, t, k->connected, k->joined, k->moves_sent, k->moves_dropped, k->frames_in,
           k->bytes_in, k->errors, k->disconnects, k->collisions);
    finish();
}

void events_stats(const events_counts *k, double t) { counts("stats", k, "t", t); }

void events_summary(const events_counts *k, double duration) { counts("summary", k, "duration", duration); }
