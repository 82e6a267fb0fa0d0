/* terminal.c: the interactive client's lines for a person (see terminal.h). */
#include "terminal.h"

#include <inttypes.h>
#include <stdio.h>
#include <string.h>

#include "alloc.h"
#include "known.h"
#include "sbuf.h"
#include "utf8.h"

/* Objects one contact bookkeeping step can hold: an avatar pressed into a
 * corner touches two or three; past this, a contact is shown again. */
#define CONTACTS_MAX 16

/* A contact with an object lasts from the first COLLISION against it until
 * a move of ours is applied (a snapshot acknowledges it, or carries our own
 * entry) without one: the server sends its COLLISIONs of a tick before that
 * tick's SNAPSHOT. */
typedef struct contacts {
    uint32_t id[CONTACTS_MAX];
    unsigned n;
} contacts;

static struct {
    const char *prompt;
    sbuf line;
    uint32_t self; /* our avatar id, once joined */
    uint32_t ack;  /* of the latest snapshot */
    contacts touching, seen; /* shown, and met since the last applied move */
    struct avatar_name {
        uint32_t id;
        char name[PROTO_NAME_MAX + 1];
    } *names; /* avatars that joined near us, for their leaving line */
    size_t n_names, cap_names;
} t;

void terminal_prompt(const char *prompt) { t.prompt = prompt; }

/* Starts a line: the prompt's line is cleared first ("\r", erase to its
 * end), so an event does not land after "> ". */
static void begin(void)
{
    sb_clear(&t.line);
    if (t.prompt)
        sb_puts(&t.line, "\r\033[K");
}

static void finish(void)
{
    sb_puts(&t.line, "\n");
    fwrite(t.line.p, 1, t.line.len, stdout);
    fflush(stdout);
    if (t.prompt) {
        fputs(t.prompt, stderr);
        fflush(stderr);
    }
}

/* Text from the wire or the system, shown as it is but for what could move
 * the cursor or change the terminal: control bytes and broken UTF-8 become
 * '?'. */
static void put_text(const char *s, size_t n)
{
    const uint8_t *p = (const uint8_t *)s;
    for (size_t i = 0; i < n;) {
        uint32_t cp;
        size_t k = utf8_next(p + i, n - i, &cp);
        if (k == 0 || cp < 0x20u || (cp >= 0x7fu && cp < 0xa0u)) {
            sb_puts(&t.line, "?");
            i += k ? k : 1;
        } else {
            sb_put(&t.line, s + i, k);
            i += k;
        }
    }
}

static void put_point(const float v[3])
{
    sb_printf(&t.line, "(%.2f, %.2f, %.2f)", (double)v[0], (double)v[1], (double)v[2]);
}

static void put_box(const float lo[3], const float hi[3])
{
    put_point(lo);
    sb_puts(&t.line, " to ");
    put_point(hi);
}

static struct avatar_name *name_of(uint32_t id)
{
    for (size_t i = 0; i < t.n_names; i++)
        if (t.names[i].id == id)
            return &t.names[i];
    return NULL;
}

static void name_put(uint32_t id, const proto_str *name)
{
    struct avatar_name *e = name_of(id);
    if (!e) {
        if (t.n_names == t.cap_names) {
            t.cap_names = t.cap_names ? t.cap_names * 2 : 16;
            t.names = cvre_xrealloc(t.names, t.cap_names * sizeof *t.names);
        }
        e = &t.names[t.n_names++];
        e->id = id;
    }
    size_t n = name->len < PROTO_NAME_MAX ? name->len : PROTO_NAME_MAX;
    memcpy(e->name, name->ptr, n);
    e->name[n] = '\0';
}

static int contacts_has(const contacts *c, uint32_t id)
{
    for (unsigned i = 0; i < c->n; i++)
        if (c->id[i] == id)
            return 1;
    return 0;
}

static void contacts_add(contacts *c, uint32_t id)
{
    if (c->n < CONTACTS_MAX && !contacts_has(c, id))
        c->id[c->n++] = id;
}

static void collision(const proto_collision *c)
{
    int ongoing = contacts_has(&t.touching, c->object_id);
    contacts_add(&t.seen, c->object_id);
    if (ongoing)
        return;
    contacts_add(&t.touching, c->object_id);
    begin();
    sb_printf(&t.line, "%s object %" PRIu32 " at ", c->inside ? "stuck inside" : "bumped into", c->object_id);
    put_point(c->point);
    finish();
}

/* A snapshot that shows a move of ours applied ends the contacts it met
 * no collision for. */
static void snapshot(const proto_snapshot *s)
{
    int moved = s->ack_seq != t.ack;
    for (uint16_t i = 0; i < s->count && !moved; i++) {
        proto_avatar a;
        proto_snapshot_entry(s, i, &a);
        moved = a.id == t.self;
    }
    t.ack = s->ack_seq;
    if (moved) {
        t.touching = t.seen;
        t.seen.n = 0;
    }
}

static void object_info(const proto_object_info *o)
{
    begin();
    sb_printf(&t.line, "object %" PRIu32 " \"", o->object_id);
    put_text(o->name.ptr, o->name.len);
    sb_puts(&t.line, "\" of ");
    put_text(o->owner.ptr, o->owner.len);
    sb_puts(&t.line, " at ");
    put_point(o->at.pos);
    float lo[3], hi[3];
    if (known_bounds(o, lo, hi) == 0) {
        sb_puts(&t.line, ", box ");
        put_box(lo, hi);
    }
    sb_printf(&t.line, " (%" PRIu32 " triangles, collision map v%" PRIu32 ")", o->tri_count, o->ecm_version);
    finish();
}

void terminal_message(const proto_msg *m, uint64_t now_us)
{
    switch (m->type) {
    case PROTO_WELCOME: {
        const proto_welcome *w = &m->u.welcome;
        begin();
        sb_printf(&t.line, "welcome: session %" PRIu64 ", world ", w->session_id);
        put_box(w->world_min, w->world_max);
        sb_printf(&t.line, ", %u ticks a second, max speed %.1f m/s", (unsigned)w->tick_hz, (double)w->max_speed);
        finish();
        break;
    }
    case PROTO_JOIN_OK:
        t.self = m->u.join_ok.avatar_id;
        begin();
        sb_printf(&t.line, "joined as avatar %" PRIu32 " at ", t.self);
        put_point(m->u.join_ok.pos);
        if (m->u.join_ok.has_token) {
            sb_puts(&t.line, "; resume token (CVRE_TOKEN) ");
            for (unsigned i = 0; i < PROTO_RESUME_TOKEN_SIZE; i++)
                sb_printf(&t.line, "%02x", m->u.join_ok.token[i]);
        }
        finish();
        break;
    case PROTO_AVATAR_JOINED:
        name_put(m->u.avatar_joined.id, &m->u.avatar_joined.name);
        begin();
        sb_puts(&t.line, "+ ");
        put_text(m->u.avatar_joined.name.ptr, m->u.avatar_joined.name.len);
        sb_printf(&t.line, " (avatar %" PRIu32 ") is here, at ", m->u.avatar_joined.id);
        put_point(m->u.avatar_joined.pos);
        finish();
        break;
    case PROTO_AVATAR_LEFT: {
        struct avatar_name *e = name_of(m->u.avatar_left.id);
        begin();
        sb_printf(&t.line, "- %s (avatar %" PRIu32 ") %s", e ? e->name : "?", m->u.avatar_left.id,
                  m->u.avatar_left.reason == PROTO_LEFT_OUT_OF_RANGE ? "went out of range" : "left");
        finish();
        if (e)
            *e = t.names[--t.n_names];
        break;
    }
    case PROTO_SNAPSHOT:
        snapshot(&m->u.snapshot);
        break;
    case PROTO_ERROR:
        terminal_error(m->u.error.code, m->u.error.message.ptr, m->u.error.message.len);
        break;
    case PROTO_PONG:
        begin();
        sb_printf(&t.line, "pong after %.3f ms",
                  now_us >= m->u.ping.stamp ? (double)(now_us - m->u.ping.stamp) / 1000.0 : 0.0);
        finish();
        break;
    case PROTO_BYE:
        terminal_bye(m->u.bye.reason, 0);
        break;
    case PROTO_OBJECT_INFO:
        object_info(&m->u.object_info);
        break;
    case PROTO_OBJECT_REMOVED:
        begin();
        sb_printf(&t.line, "object %" PRIu32 " is gone (removed, or out of range)", m->u.object_id);
        finish();
        break;
    case PROTO_OBJECT_REJECTED: {
        const proto_object_rejected *r = &m->u.object_rejected;
        begin();
        sb_printf(&t.line, "refused: request %" PRIu32 ", code %u (%s): ", r->request_id, (unsigned)r->code,
                  proto_strerror(r->code));
        put_text(r->message.ptr, r->message.len);
        finish();
        break;
    }
    case PROTO_COLLISION:
        collision(&m->u.collision);
        break;
    default:
        break;
    }
}

void terminal_error(unsigned code, const char *text, size_t len)
{
    begin();
    if (code)
        sb_printf(&t.line, "error %u: ", code);
    else
        sb_puts(&t.line, "error: ");
    put_text(text, len);
    finish();
}

void terminal_bye(unsigned reason, int from_client)
{
    begin();
    if (from_client)
        sb_puts(&t.line, "bye");
    else
        sb_printf(&t.line, "the server says bye (%s)", proto_bye_name(reason));
    finish();
}

void terminal_closed(void)
{
    begin();
    sb_puts(&t.line, "connection closed");
    finish();
}

void terminal_done(const char *command, const float pos[3])
{
    begin();
    sb_printf(&t.line, "%s done, at ", command);
    put_point(pos);
    finish();
}

void terminal_fetched(uint32_t object_id, const char *file, uint32_t triangles, int cached)
{
    begin();
    sb_printf(&t.line, "object %" PRIu32 ": %" PRIu32 " triangles written to %s%s", object_id, triangles, file,
              cached ? " (from this session's meshes)" : "");
    finish();
}

void terminal_done_object(const char *command, const char *result, uint32_t object_id, double seconds,
                          const float box[6])
{
    begin();
    sb_printf(&t.line, "%s: %s", command, result);
    if (object_id)
        sb_printf(&t.line, ", object %" PRIu32, object_id);
    if (box) {
        sb_puts(&t.line, ", box ");
        put_box(box, box + 3);
    }
    sb_printf(&t.line, " (%.1f s)", seconds);
    finish();
}
