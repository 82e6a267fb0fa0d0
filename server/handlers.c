/*
 * handlers.c: a client's frames in, and what each message does
 * (handlers.h). The state machine is hello -> join -> (the auth worker's
 * check) -> joined; before each step only its message is legal, and a
 * frame out of turn, malformed or over its size ends the connection with
 * an error frame.
 */
#include "handlers.h"

#include <errno.h>
#include <stdio.h>
#include <string.h>
#include <strings.h>
#include <sys/random.h>

#include <sodium.h>

#include "clients.h"
#include "le.h"
#include "log.h"
#include "objects.h"
#include "session_log.h"
#include "srv_limits.h"

static void handle_input(server *s, client *c);

static void hex(const uint8_t *p, size_t n, char *out)
{
    static const char digits[] = "0123456789abcdef";
    for (size_t i = 0; i < n; i++) {
        out[2 * i] = digits[p[i] >> 4];
        out[2 * i + 1] = digits[p[i] & 15];
    }
    out[2 * n] = 0;
}

static void on_hello(server *s, client *c, const proto_hello *m)
{
    if (m->version != PROTO_VERSION) {
        clients__protocol_error(s, c, PROTO_ERR_VERSION, "protocol version %u not supported; this server speaks %u",
                       m->version, PROTO_VERSION);
        return;
    }
    if (getrandom(c->token, sizeof c->token, 0) != (ssize_t)sizeof c->token) {
        clients__protocol_error(s, c, PROTO_ERR_INTERNAL, "cannot make a session token");
        return;
    }
    c->session_id = ++s->last_session_id;
    store_event *e = session_log__push(s, EVT_OPEN, c->session_id);
    hex(c->token, sizeof c->token, e->token);
    snprintf(e->text, sizeof e->text, "%s", c->peer);

    proto_welcome wm = {.version = PROTO_VERSION, .session_id = (uint64_t)c->session_id,
                        .tick_hz = (uint16_t)s->cfg.tick_hz, .aoi_radius = s->cfg.aoi_radius,
                        .max_speed = s->cfg.max_speed, .idle_timeout_ms = s->cfg.idle_timeout_ms};
    memcpy(wm.token, c->token, sizeof wm.token);
    float half = s->cfg.world_size * 0.5f;
    wm.world_min[0] = wm.world_min[2] = -half;
    wm.world_max[0] = wm.world_max[2] = half;
    wm.world_max[1] = SRV_WORLD_HEIGHT;
    proto_writer w;
    if (clients__out_begin(s, c, PROTO_SIZE_WELCOME, &w) < 0)
        return;
    proto_put_welcome(&w, &wm);
    clients__out_end(s, c, &w);
    c->state = ST_JOIN;
}

/* A join: refused at once when this server admits accounts only and it
 * carries no credential, or when its address is over its login rate;
 * otherwise the auth worker decides (handlers__on_auth_results). */
static void on_join(server *s, client *c, const proto_join *m)
{
    auth_job job = {.session = c->session_id, .credential = m->credential, .secret_len = m->secret_len};

    if (m->name.len == sizeof WORLD_OWNER - 1 && strncasecmp(m->name.ptr, WORLD_OWNER, m->name.len) == 0) {
        clients__protocol_error(s, c, PROTO_ERR_BAD_VALUE, "the name \"%s\" is reserved", WORLD_OWNER);
        return;
    }
    if (m->credential == PROTO_CRED_NONE && s->cfg.auth_required) {
        clients__protocol_error(s, c, PROTO_ERR_AUTH_REQUIRED,
                               "this server admits accounts only: join with your password");
        return;
    }
    if (s->joins && !ratelimit_take(s->joins, c->addr, server__now(s))) {
        clients__protocol_error(s, c, PROTO_ERR_RATE_LIMITED, "too many joins from your address: wait a second");
        return;
    }
    if (m->credential != PROTO_CRED_NONE) {
        if (s->logins_pending >= AUTH_LOGINS_MAX) {
            clients__protocol_error(s, c, PROTO_ERR_SERVER_FULL, "too many logins at once: try again in a moment");
            return;
        }
        if (!ratelimit_take(s->logins, c->addr, server__now(s))) {
            clients__protocol_error(s, c, PROTO_ERR_RATE_LIMITED,
                                   "too many logins from your address: wait a few seconds");
            return;
        }
    }
    memcpy(job.name, m->name.ptr, m->name.len);
    if (m->secret_len)
        memcpy(job.secret, m->secret, m->secret_len);
    memcpy(c->join_box, m->box, sizeof c->join_box);
    memcpy(c->join_name, job.name, sizeof c->join_name);
    if (auth_submit(s->auth, &job) != 0) {
        clients__protocol_error(s, c, PROTO_ERR_SERVER_FULL, "too many joins at once: try again in a moment");
        return;
    }
    s->logins_pending += m->credential != PROTO_CRED_NONE;
    c->state = ST_AUTH;
    clients__watch(s, c);
}

/* The avatar of a join the auth worker accepted: from its first tick on,
 * its collisions carry its users row (r->user_id). */
static void admit(server *s, client *c, const auth_result *r)
{
    int crowded;
    const world_avatar *a = world_add(s->world, s->scene, r->name, (uint32_t)strlen(r->name), c->join_box, &crowded);
    if (!a) {
        clients__protocol_error(s, c, PROTO_ERR_SERVER_FULL, "the world is full (%u avatars)", world_count(s->world));
        return;
    }
    if (crowded)
        log_warn("%s (session %lld): no free spawn point within %.0f m of (%.1f, %.1f); it starts inside an object",
                 c->peer, (long long)c->session_id, (double)WORLD_SPAWN_SEARCH, (double)a->pos[0], (double)a->pos[2]);
    c->avatar_id = a->id;
    c->user_id = r->user_id;
    c->account_id = r->account_id;
    c->is_admin = r->is_admin;
    c->state = ST_JOINED;
    s->by_slot[world_slot(a->id)] = c;
    store_event *e = session_log__push(s, EVT_JOIN, c->session_id);
    e->avatar = a->id;
    snprintf(e->text, sizeof e->text, "%s", r->user);
    log_info("%s (session %lld) joined as \"%s\" (%s), avatar %u", c->peer, (long long)c->session_id, a->name,
             !r->account_id ? "guest" : r->is_admin ? "account, admin" : "account", a->id);

    proto_join_ok ok = {.avatar_id = a->id, .has_token = (uint8_t)r->has_token};
    memcpy(ok.pos, a->pos, sizeof ok.pos);
    memcpy(ok.box, a->box, sizeof ok.box);
    memcpy(ok.token, r->token, sizeof ok.token);
    proto_writer w;
    if (clients__out_begin(s, c, PROTO_SIZE_JOIN_OK_MAX, &w) < 0)
        return;
    proto_put_join_ok(&w, &ok);
    clients__out_end(s, c, &w);
    sodium_memzero(ok.token, sizeof ok.token);
    c->objs_owned = c->account_id != 0;
    objects__view(s, c, 1);
}

void handlers__on_auth_results(ev_loop *loop, int fd, unsigned events, void *data)
{
    (void)loop;
    (void)fd;
    (void)events;
    server *s = data;
    auth_result r;
    while (auth_take(s->auth, &r) == 0) {
        client *c = clients__by_session(s, r.session);
        s->logins_pending -= r.credential != PROTO_CRED_NONE;
        if (c && c->state == ST_AUTH && !c->closing) {
            c->state = ST_JOIN;
            if (r.status == PROTO_ERR_AUTH)
                log_warn("%s (session %lld): join as \"%s\" refused: %s", c->peer, (long long)c->session_id, r.name,
                         r.message);
            if (r.status != 0)
                clients__protocol_error(s, c, r.status, "%s", r.message);
            else
                admit(s, c, &r);
            clients__watch(s, c);
            handle_input(s, c); /* the frames that came behind the join */
        }
        sodium_memzero(r.token, sizeof r.token);
    }
}

static void on_move(server *s, client *c, const proto_move *m)
{
    if (c->has_seq && m->seq <= c->last_seq) {
        clients__protocol_error(s, c, PROTO_ERR_BAD_SEQ, "move seq %u does not follow %u", m->seq, c->last_seq);
        return;
    }
    c->has_seq = 1;
    c->last_seq = m->seq;
    s->st.moves_in++;
    uint64_t now = server__now(s);
    if (now - c->moves_window_ns >= 1000 * NS_PER_MS) {
        c->moves_window_ns = now;
        c->moves_in_window = c->moves_dropped_in_window = 0;
    }
    if (++c->moves_in_window > SRV_MOVES_PER_TICK * (uint32_t)s->cfg.tick_hz) {
        s->st.moves_dropped++;
        if (++c->moves_dropped_in_window > SRV_MOVE_FLOOD_DROPS * (uint32_t)s->cfg.tick_hz)
            clients__protocol_error(s, c, PROTO_ERR_RATE_LIMITED, "over %u moves a second: flooding",
                                   (SRV_MOVES_PER_TICK + SRV_MOVE_FLOOD_DROPS) * (uint32_t)s->cfg.tick_hz);
        return;
    }
    world_request_move(s->world, c->avatar_id, m->seq, m->pos);
    if (m->has_pose) /* already checked by the codec (proto.c) */
        world_set_pose(s->world, c->avatar_id, &m->pose);
}

/* Whether clients may send this type at all. */
static int from_client(uint16_t type)
{
    switch (type) {
    case PROTO_HELLO:
    case PROTO_JOIN:
    case PROTO_MOVE:
    case PROTO_PING:
    case PROTO_PONG:
    case PROTO_BYE:
    case PROTO_OBJECT_UPLOAD_BEGIN:
    case PROTO_OBJECT_UPLOAD_CHUNK:
    case PROTO_OBJECT_UPLOAD_END:
    case PROTO_OBJECT_PLACE:
    case PROTO_OBJECT_REMOVE:
    case PROTO_MESH_REQUEST: return 1;
    default: return 0;
    }
}

/* Which messages each state takes: before hello only hello; before join
 * only join (or bye); after join everything a client may send but those. */
static void on_message(server *s, client *c, const proto_msg *m)
{
    static const char *const state_names[] = {"before hello", "before join", "while the join is checked",
                                              "after join"};
    int legal;
    switch (m->type) {
    case PROTO_HELLO: legal = c->state == ST_HELLO; break;
    case PROTO_JOIN: legal = c->state == ST_JOIN; break;
    case PROTO_BYE: legal = c->state != ST_HELLO; break;
    case PROTO_MOVE:
    case PROTO_PING:
    case PROTO_PONG:
    case PROTO_OBJECT_UPLOAD_BEGIN:
    case PROTO_OBJECT_UPLOAD_CHUNK:
    case PROTO_OBJECT_UPLOAD_END:
    case PROTO_OBJECT_PLACE:
    case PROTO_OBJECT_REMOVE:
    case PROTO_MESH_REQUEST: legal = c->state == ST_JOINED; break;
    default: return; /* server-to-client types never get here (handle_input) */
    }
    if (!legal) {
        if (m->type == PROTO_JOIN && c->state == ST_JOINED)
            clients__protocol_error(s, c, PROTO_ERR_ALREADY_JOINED, "already joined as avatar %u", c->avatar_id);
        else
            clients__protocol_error(s, c, PROTO_ERR_UNEXPECTED, "%s not allowed %s", proto_type_name(m->type),
                           state_names[c->state]);
        return;
    }
    proto_writer w;
    switch (m->type) {
    case PROTO_HELLO: on_hello(s, c, &m->u.hello); break;
    case PROTO_JOIN: on_join(s, c, &m->u.join); break;
    case PROTO_MOVE: on_move(s, c, &m->u.move); break;
    case PROTO_PING:
        if (clients__out_begin(s, c, PROTO_SIZE_PING, &w) == 0) {
            proto_put_pong(&w, m->u.ping.stamp);
            clients__out_end(s, c, &w);
        }
        break;
    case PROTO_BYE: clients__begin_close(s, c, "quit"); break;
    case PROTO_PONG: break;
    default: objects__on_message(s, c, m); break;
    }
}

/* Handles every whole frame in c's input buffer, then drops them. */
static void handle_input(server *s, client *c)
{
    uint32_t max_len = c->state == ST_JOINED ? PROTO_MAX_LEN : PROTO_MAX_LEN_PREJOIN;
    size_t off = 0, in_len;
    uint8_t *in;
    clients__input(c, &in, &in_len);
    while (!c->closing && c->state != ST_AUTH) {
        proto_frame f;
        int rc = proto_frame_parse(in + off, in_len - off, max_len, &f);
        if (rc == PROTO_INCOMPLETE)
            break;
        if (rc != PROTO_OK) {
            uint32_t len = le_get_u32(in + off);
            if (rc == PROTO_ERR_FRAME_TOO_LONG)
                clients__protocol_error(s, c, rc, "frame length %u over the limit of %u%s", len, max_len,
                               c->state == ST_JOINED ? "" : " before join");
            else
                clients__protocol_error(s, c, rc, "frame length %u is below the minimum of %u", len, PROTO_LEN_MIN);
            break;
        }
        off += f.size;
        c->last_frame_ns = server__now(s);
        s->st.frames_in++;
        proto_msg m;
        rc = proto_decode(&f, &m);
        if (rc != PROTO_ERR_UNKNOWN_TYPE && !from_client(f.type))
            clients__protocol_error(s, c, PROTO_ERR_UNEXPECTED, "%s is a server-to-client message", proto_type_name(f.type));
        else if (rc == PROTO_ERR_UNKNOWN_TYPE)
            clients__protocol_error(s, c, rc, "unknown message type %u", f.type);
        else if (rc != PROTO_OK)
            clients__protocol_error(s, c, rc, "bad %s frame: %s", proto_type_name(f.type), proto_strerror(rc));
        else
            on_message(s, c, &m);
        /* The state may have changed the frame cap (join). */
        max_len = c->state == ST_JOINED ? PROTO_MAX_LEN : PROTO_MAX_LEN_PREJOIN;
    }
    clients__consume(c, c->closing ? in_len : off);
}

static void on_peer_eof(server *s, client *c)
{
    if (c->closing) {
        c->dead = 1;
        return;
    }
    if (c->c.in_len > 0) {
        clients__protocol_error(s, c, PROTO_ERR_TRUNCATED, "connection closed inside a frame (%zu bytes buffered)",
                       c->c.in_len);
        return;
    }
    snprintf(c->end_reason, sizeof c->end_reason, "closed without bye");
    c->dead = 1;
}

void handlers__on_io(ev_loop *loop, int fd, unsigned events, void *data)
{
    (void)loop;
    (void)fd;
    client *c = data;
    server *s = c->srv;
    if (c->dead)
        return;
    if (events & EV_WRITE)
        clients__flush(s, c);
    if (c->dead || !(events & (EV_READ | EV_ERROR)))
        return;
    uint32_t cap = c->state == ST_JOINED ? SRV_INBUF_CAP : SRV_INBUF_CAP_PREJOIN;
    ssize_t n = conn_read(&c->c, clients__read_cap(c, cap), SRV_READ_BUDGET);
    if (n == -EAGAIN)
        return;
    if (n == 0) {
        on_peer_eof(s, c);
        return;
    }
    if (n < 0) {
        snprintf(c->end_reason, sizeof c->end_reason, "read failed: %s", strerror((int)-n));
        c->dead = 1;
        return;
    }
    s->st.bytes_in += (uint64_t)n;
    clients__unwrap(s, c);
    handle_input(s, c);
}
