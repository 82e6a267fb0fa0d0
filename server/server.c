#include "server.h"

#include <errno.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/random.h>
#include <sys/signalfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include <sodium.h>

#include "alloc.h"
#include "conn.h"
#include "db.h"
#include "ev.h"
#include "moderation.h"
#include "srv_limits.h"
#include "log.h"
#include "proto.h"
#include "record.h"
#include "refine.h"
#include "serverInt.h"
#include "world.h"
#include "le.h"

/* Connections accepted per wakeup of the listening socket. */
#define ACCEPT_BUDGET 256
/* How long the listening socket is left alone once the process is out of
 * file descriptors: the connection accept could not take stays waiting,
 * so the socket stays readable, and watching it would spin the loop (and
 * log a line a turn). Descriptors come back as clients leave; nginx waits
 * half a second too. */
#define ACCEPT_PAUSE_MS 500u
/* How often timeouts and slow readers are checked. */
#define HOUSEKEEPING_MS 100u
/* How long a shutdown waits for clients to take their bye. */
#define SHUTDOWN_GRACE_MS 2000u


void server_config_defaults(server_config *cfg)
{
    *cfg = (server_config){
        .host = "127.0.0.1",
        .port = 7878,
        .db_path = "cvre.db",
        .tick_hz = SRV_TICK_HZ_DEFAULT,
        .max_clients = SRV_MAX_CLIENTS_DEFAULT,
        .aoi_radius = SRV_AOI_RADIUS_DEFAULT,
        .max_speed = SRV_MAX_SPEED_DEFAULT,
        .world_size = SRV_WORLD_SIZE_DEFAULT,
        .spawn_radius = SRV_SPAWN_RADIUS_DEFAULT,
        .handshake_timeout_ms = SRV_HANDSHAKE_TIMEOUT_MS,
        .idle_timeout_ms = SRV_IDLE_TIMEOUT_MS,
        .seed = 1,
        .stats_file = NULL,
        .stats_interval_ms = 10000,
        .max_upload = SRV_MAX_UPLOAD_DEFAULT,
        .max_triangles = SRV_MAX_TRIANGLES_DEFAULT,
        .world_file = NULL,
        .importer = {import_proc_default_helper(), IMPORT_PROC_MEMORY_MB, IMPORT_PROC_CPU_SECONDS},
        .login_burst = SRV_LOGIN_BURST,
        .max_per_address = SRV_MAX_PER_ADDRESS_DEFAULT,
        .quota_objects = SRV_QUOTA_OBJECTS_DEFAULT,
        .quota_bytes = (uint64_t)SRV_QUOTA_MB_DEFAULT << 20,
        .joins_per_second = SRV_JOINS_PER_SECOND_DEFAULT,
        .refine_interval_s = SRV_REFINE_INTERVAL_DEFAULT,
        .refine_eps = CLUSTER_EPS_DEFAULT,
        .refine_min_points = CLUSTER_MIN_POINTS_DEFAULT,
        .refine_min_users = CLUSTER_MIN_USERS_DEFAULT,
        .refine_depth = ECM_DEPTH_DEFAULT,
        .refine_max_boxes = ECM_MAX_BOXES_DEFAULT,
        .refine_max_empty = ECM_MAX_EMPTY_DEFAULT,
    };
}

const char *server_address(const server *s) { return s->address; }

uint64_t server__now(const server *s) { return ev_now(s->loop); }

client *server__client_by_session(server *s, int64_t session)
{
    for (uint32_t i = 0; i < s->nclients; i++)
        if (s->clients[i]->session_id == session && !s->clients[i]->dead)
            return s->clients[i];
    return NULL;
}

/* ---- session log ------------------------------------------------------ */

store_event *server__event_push(server *s, int kind, int64_t session)
{
    if (s->nevents == s->events_cap) {
        s->events_cap = s->events_cap ? s->events_cap * 2 : 64;
        s->events = cvre_xrealloc(s->events, s->events_cap * sizeof *s->events);
    }
    store_event *e = &s->events[s->nevents++];
    memset(e, 0, sizeof *e);
    e->kind = kind;
    e->session = session;
    e->at = db_now();
    return e;
}

/* Writes the queued session events in one transaction. A database error is
 * logged and the batch dropped: the world goes on without its history rather
 * than stopping. */
void server__events_flush(server *s)
{
    if (!s->nevents)
        return;
    int rc = db_begin(s->db);
    for (uint32_t i = 0; rc == 0 && i < s->nevents; i++) {
        const store_event *e = &s->events[i];
        switch (e->kind) {
        case EVT_OPEN: rc = db_session_open(s->db, e->session, e->token, e->text, e->at); break;
        case EVT_JOIN: {
            int64_t uid = 0;
            rc = db_session_join(s->db, e->session, e->text, e->avatar, e->at, &uid);
            client *c = rc == 0 ? server__client_by_session(s, e->session) : NULL;
            if (c)
                c->user_id = uid;
            break;
        }
        case EVT_CLOSE: rc = db_session_close(s->db, e->session, e->text, e->at); break;
        case EVT_PLACE:
            rc = db_object_place(s->db, e->session, e->at_place.pos, e->at_place.yaw, e->at_place.scale);
            break;
        default: rc = db_object_remove(s->db, e->session, e->at); break;
        }
    }
    if (rc == 0)
        rc = db_commit(s->db);
    if (rc != 0) {
        int busy = db_busy(s->db);
        db_rollback(s->db);
        if (busy && !s->stopping) {
            log_debug("database busy: %u records wait for the next tick", s->nevents);
            return;
        }
        log_error("database: %s; %u session and object records lost", db_error(s->db), s->nevents);
    }
    s->nevents = 0;
}

/* ---- output ----------------------------------------------------------- */

static void kill_client(server *s, client *c, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
static void watch(server *s, client *c);
static void handle_input(server *s, client *c);
static db_admin_event_fn on_admin_event;

static void want_write(server *s, client *c)
{
    if (!c->in_write_list) {
        c->in_write_list = 1;
        s->write_list[s->nwrite++] = c;
    }
}

/* Reserves need bytes of output; a client whose backlog would pass the hard
 * limit is disconnected and -1 returned. */
int server__out_begin(server *s, client *c, size_t need, proto_writer *w)
{
    if (c->dead)
        return -1;
    if (conn_out_begin(&c->c, need, w) < 0) {
        s->st.slow_readers++;
        kill_client(s, c, "output backlog over the hard limit (%zu bytes pending)", conn_out_pending(&c->c));
        return -1;
    }
    return 0;
}

void server__out_end(server *s, client *c, const proto_writer *w)
{
    conn_out_end(&c->c, w);
    want_write(s, c);
}

/* Stops reading from c; its output is flushed and the socket closed within
 * SRV_CLOSE_LINGER_MS. reason is kept for the session record. */
static void begin_close(server *s, client *c, const char *reason)
{
    if (c->closing)
        return;
    c->closing = 1;
    snprintf(c->end_reason, sizeof c->end_reason, "%s", reason);
    c->close_deadline_ns = server__now(s) + SRV_CLOSE_LINGER_MS * NS_PER_MS;
    want_write(s, c);
}

static void kill_client(server *s, client *c, const char *fmt, ...)
{
    if (c->dead)
        return;
    va_list ap;
    va_start(ap, fmt);
    char why[96];
    vsnprintf(why, sizeof why, fmt, ap);
    va_end(ap);
    log_warn("%s (session %lld): %s; disconnecting", c->peer, (long long)c->session_id, why);
    if (!c->closing)
        snprintf(c->end_reason, sizeof c->end_reason, "%s", why);
    c->closing = 1;
    c->dead = 1;
    (void)s;
}

/* Sends an error frame naming the problem and closes the connection. */
void server__protocol_error(server *s, client *c, int code, const char *fmt, ...)
{
    char msg[PROTO_MESSAGE_MAX + 1];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    log_info("%s (session %lld): %s; closing", c->peer, (long long)c->session_id, msg);
    if (code == PROTO_ERR_TIMEOUT)
        s->st.timeouts++;
    else
        s->st.protocol_errors++;
    if ((unsigned)code < METRICS_CODES)
        s->st.errors[code]++;
    proto_writer w;
    if (server__out_begin(s, c, PROTO_SIZE_ERROR_MAX, &w) == 0) {
        proto_put_error(&w, (uint16_t)code, msg);
        server__out_end(s, c, &w);
    }
    char reason[sizeof c->end_reason];
    snprintf(reason, sizeof reason, "error: %s", msg);
    begin_close(s, c, reason);
}

/* ---- handshake and messages ------------------------------------------ */

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
        server__protocol_error(s, c, PROTO_ERR_VERSION, "protocol version %u not supported; this server speaks %u",
                       m->version, PROTO_VERSION);
        return;
    }
    if (getrandom(c->token, sizeof c->token, 0) != (ssize_t)sizeof c->token) {
        server__protocol_error(s, c, PROTO_ERR_INTERNAL, "cannot make a session token");
        return;
    }
    c->session_id = ++s->last_session_id;
    store_event *e = server__event_push(s, EVT_OPEN, c->session_id);
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
    if (server__out_begin(s, c, PROTO_SIZE_WELCOME, &w) < 0)
        return;
    proto_put_welcome(&w, &wm);
    server__out_end(s, c, &w);
    c->state = ST_JOIN;
}

/* A join: refused at once when this server admits accounts only and it
 * carries no credential, or when its address is over its login rate;
 * otherwise the auth worker decides (on_auth_results). */
static void on_join(server *s, client *c, const proto_join *m)
{
    auth_job job = {.session = c->session_id, .credential = m->credential, .secret_len = m->secret_len};

    if (m->name.len == sizeof WORLD_OWNER - 1 && strncasecmp(m->name.ptr, WORLD_OWNER, m->name.len) == 0) {
        server__protocol_error(s, c, PROTO_ERR_BAD_VALUE, "the name \"%s\" is reserved", WORLD_OWNER);
        return;
    }
    if (m->credential == PROTO_CRED_NONE && s->cfg.auth_required) {
        server__protocol_error(s, c, PROTO_ERR_AUTH_REQUIRED,
                               "this server admits accounts only: join with your password");
        return;
    }
    if (s->joins && !ratelimit_take(s->joins, c->addr, server__now(s))) {
        server__protocol_error(s, c, PROTO_ERR_RATE_LIMITED, "too many joins from your address: wait a second");
        return;
    }
    if (m->credential != PROTO_CRED_NONE) {
        if (s->logins_pending >= AUTH_LOGINS_MAX) {
            server__protocol_error(s, c, PROTO_ERR_SERVER_FULL, "too many logins at once: try again in a moment");
            return;
        }
        if (!ratelimit_take(s->logins, c->addr, server__now(s))) {
            server__protocol_error(s, c, PROTO_ERR_RATE_LIMITED,
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
        server__protocol_error(s, c, PROTO_ERR_SERVER_FULL, "too many joins at once: try again in a moment");
        return;
    }
    s->logins_pending += m->credential != PROTO_CRED_NONE;
    c->state = ST_AUTH;
    watch(s, c);
}

/* The avatar of a join the auth worker accepted: from its first tick on,
 * its collisions carry its users row (r->user_id). */
static void admit(server *s, client *c, const auth_result *r)
{
    int crowded;
    const world_avatar *a = world_add(s->world, s->scene, r->name, (uint32_t)strlen(r->name), c->join_box, &crowded);
    if (!a) {
        server__protocol_error(s, c, PROTO_ERR_SERVER_FULL, "the world is full (%u avatars)", world_count(s->world));
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
    store_event *e = server__event_push(s, EVT_JOIN, c->session_id);
    e->avatar = a->id;
    snprintf(e->text, sizeof e->text, "%s", r->user);
    log_info("%s (session %lld) joined as \"%s\" (%s), avatar %u", c->peer, (long long)c->session_id, a->name,
             !r->account_id ? "guest" : r->is_admin ? "account, admin" : "account", a->id);

    proto_join_ok ok = {.avatar_id = a->id, .has_token = (uint8_t)r->has_token};
    memcpy(ok.pos, a->pos, sizeof ok.pos);
    memcpy(ok.box, a->box, sizeof ok.box);
    memcpy(ok.token, r->token, sizeof ok.token);
    proto_writer w;
    if (server__out_begin(s, c, PROTO_SIZE_JOIN_OK_MAX, &w) < 0)
        return;
    proto_put_join_ok(&w, &ok);
    server__out_end(s, c, &w);
    sodium_memzero(ok.token, sizeof ok.token);
    c->objs_owned = c->account_id != 0;
    objects__view(s, c, 1);
}

static void on_auth_results(ev_loop *loop, int fd, unsigned events, void *data)
{
    (void)loop;
    (void)fd;
    (void)events;
    server *s = data;
    auth_result r;
    while (auth_take(s->auth, &r) == 0) {
        client *c = server__client_by_session(s, r.session);
        s->logins_pending -= r.credential != PROTO_CRED_NONE;
        if (c && c->state == ST_AUTH && !c->closing) {
            c->state = ST_JOIN;
            if (r.status == PROTO_ERR_AUTH)
                log_warn("%s (session %lld): join as \"%s\" refused: %s", c->peer, (long long)c->session_id, r.name,
                         r.message);
            if (r.status != 0)
                server__protocol_error(s, c, r.status, "%s", r.message);
            else
                admit(s, c, &r);
            watch(s, c);
            handle_input(s, c); /* the frames that came behind the join */
        }
        sodium_memzero(r.token, sizeof r.token);
    }
}

static void on_move(server *s, client *c, const proto_move *m)
{
    if (c->has_seq && m->seq <= c->last_seq) {
        server__protocol_error(s, c, PROTO_ERR_BAD_SEQ, "move seq %u does not follow %u", m->seq, c->last_seq);
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
            server__protocol_error(s, c, PROTO_ERR_RATE_LIMITED, "over %u moves a second: flooding",
                                   (SRV_MOVES_PER_TICK + SRV_MOVE_FLOOD_DROPS) * (uint32_t)s->cfg.tick_hz);
        return;
    }
    world_request_move(s->world, c->avatar_id, m->seq, m->pos);
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
    case PROTO_OBJECT_REMOVE: return 1;
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
    case PROTO_OBJECT_REMOVE: legal = c->state == ST_JOINED; break;
    default: return; /* server-to-client types never get here (handle_input) */
    }
    if (!legal) {
        if (m->type == PROTO_JOIN && c->state == ST_JOINED)
            server__protocol_error(s, c, PROTO_ERR_ALREADY_JOINED, "already joined as avatar %u", c->avatar_id);
        else
            server__protocol_error(s, c, PROTO_ERR_UNEXPECTED, "%s not allowed %s", proto_type_name(m->type),
                           state_names[c->state]);
        return;
    }
    proto_writer w;
    switch (m->type) {
    case PROTO_HELLO: on_hello(s, c, &m->u.hello); break;
    case PROTO_JOIN: on_join(s, c, &m->u.join); break;
    case PROTO_MOVE: on_move(s, c, &m->u.move); break;
    case PROTO_PING:
        if (server__out_begin(s, c, PROTO_SIZE_PING, &w) == 0) {
            proto_put_pong(&w, m->u.ping.stamp);
            server__out_end(s, c, &w);
        }
        break;
    case PROTO_BYE: begin_close(s, c, "quit"); break;
    case PROTO_PONG: break;
    default: objects__on_message(s, c, m); break;
    }
}

/* Handles every whole frame in c's input buffer, then drops them. */
static void handle_input(server *s, client *c)
{
    uint32_t max_len = c->state == ST_JOINED ? PROTO_MAX_LEN : PROTO_MAX_LEN_PREJOIN;
    size_t off = 0;
    while (!c->closing && c->state != ST_AUTH) {
        proto_frame f;
        int rc = proto_frame_parse(c->c.in + off, c->c.in_len - off, max_len, &f);
        if (rc == PROTO_INCOMPLETE)
            break;
        if (rc != PROTO_OK) {
            uint32_t len = le_get_u32(c->c.in + off);
            if (rc == PROTO_ERR_FRAME_TOO_LONG)
                server__protocol_error(s, c, rc, "frame length %u over the limit of %u%s", len, max_len,
                               c->state == ST_JOINED ? "" : " before join");
            else
                server__protocol_error(s, c, rc, "frame length %u is below the minimum of %u", len, PROTO_LEN_MIN);
            break;
        }
        off += f.size;
        c->last_frame_ns = server__now(s);
        s->st.frames_in++;
        proto_msg m;
        rc = proto_decode(&f, &m);
        if (rc != PROTO_ERR_UNKNOWN_TYPE && !from_client(f.type))
            server__protocol_error(s, c, PROTO_ERR_UNEXPECTED, "%s is a server-to-client message", proto_type_name(f.type));
        else if (rc == PROTO_ERR_UNKNOWN_TYPE)
            server__protocol_error(s, c, rc, "unknown message type %u", f.type);
        else if (rc != PROTO_OK)
            server__protocol_error(s, c, rc, "bad %s frame: %s", proto_type_name(f.type), proto_strerror(rc));
        else
            on_message(s, c, &m);
        /* The state may have changed the frame cap (join). */
        max_len = c->state == ST_JOINED ? PROTO_MAX_LEN : PROTO_MAX_LEN_PREJOIN;
    }
    conn_consume(&c->c, c->closing ? c->c.in_len : off);
}

static void on_peer_eof(server *s, client *c)
{
    if (c->closing) {
        c->dead = 1;
        return;
    }
    if (c->c.in_len > 0) {
        server__protocol_error(s, c, PROTO_ERR_TRUNCATED, "connection closed inside a frame (%zu bytes buffered)",
                       c->c.in_len);
        return;
    }
    snprintf(c->end_reason, sizeof c->end_reason, "closed without bye");
    c->dead = 1;
}

/* What the loop watches c for: reads, except while its join is checked
 * (frames behind the join wait in the socket until it is settled), and
 * writes while output is pending. */
static void watch(server *s, client *c)
{
    ev_io_mod(s->loop, c->c.fd, (c->state == ST_AUTH ? 0u : (unsigned)EV_READ) | (c->writing ? (unsigned)EV_WRITE : 0u));
}

static void set_writing(server *s, client *c, int on)
{
    if (c->writing == on)
        return;
    c->writing = on;
    watch(s, c);
}

/* Writes what c has pending. Arms EV_WRITE only when bytes remain; once a
 * closing client's output is out, shuts down the write side so the peer
 * reads the error before the close. */
static void flush_client(server *s, client *c)
{
    if (c->dead)
        return;
    size_t before = conn_out_pending(&c->c);
    ssize_t left = conn_flush(&c->c);
    if (left < 0) {
        snprintf(c->end_reason, sizeof c->end_reason, "%s", c->closing ? c->end_reason : "connection lost");
        c->dead = 1;
        return;
    }
    s->st.bytes_out += before - (size_t)left;
    set_writing(s, c, left > 0);
    if ((size_t)left > SRV_OUTBUF_SOFT) {
        if (!c->soft_since_ns)
            c->soft_since_ns = server__now(s);
    } else {
        c->soft_since_ns = 0;
    }
    if (left == 0 && c->closing && !c->shut_wr) {
        shutdown(c->c.fd, SHUT_WR);
        c->shut_wr = 1;
    }
}

static void on_client_io(ev_loop *loop, int fd, unsigned events, void *data)
{
    (void)loop;
    (void)fd;
    client *c = data;
    server *s = c->srv;
    if (c->dead)
        return;
    if (events & EV_WRITE)
        flush_client(s, c);
    if (c->dead || !(events & (EV_READ | EV_ERROR)))
        return;
    uint32_t cap = c->state == ST_JOINED ? SRV_INBUF_CAP : SRV_INBUF_CAP_PREJOIN;
    ssize_t n = conn_read(&c->c, cap, SRV_READ_BUDGET);
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
    handle_input(s, c);
}

/* ---- the tick: movement and areas of interest ------------------------- */

static int known_reserve(client *c, uint32_t n)
{
    if (n <= c->known_cap)
        return 0;
    uint32_t cap = c->known_cap ? c->known_cap : 16;
    while (cap < n)
        cap *= 2;
    c->known = cvre_xrealloc(c->known, cap * sizeof *c->known);
    c->known_cap = cap;
    return 0;
}

/* Tells c what changed in its area of interest since its last update:
 * avatars that came into view (joined), went out of view or disconnected
 * (left), and the positions that changed (snapshot, with its own entry and
 * the last move applied). The known and visible sets are compared through
 * per-slot stamps, in time linear in their sizes with no sorting: known
 * avatars are stamped S, the visible ones among them restamped S + 1, and
 * known ones left at S are gone. A client whose output is backed up is
 * skipped; it gets the accumulated changes once it reads again. */
static void update_view(server *s, client *c, uint32_t tick)
{
    if (conn_out_pending(&c->c) > SRV_OUTBUF_SOFT)
        return;
    const world_avatar *me = world_get(s->world, c->avatar_id);
    uint32_t n = world_neighbours(s->world, c->avatar_id, s->vis, SRV_AOI_MAX - 1);
    uint32_t nleft = 0, njoined = 0, nsnap = 0;
    if (s->stamp >= UINT32_MAX - 2) { /* wrapped: forget every old stamp */
        memset(s->mark_stamp, 0, s->cfg.max_clients * sizeof *s->mark_stamp);
        s->stamp = 0;
    }
    uint32_t S = s->stamp += 2;
    for (uint32_t k = 0; k < c->nknown; k++) {
        uint32_t slot = world_slot(c->known[k]);
        s->mark_id[slot] = c->known[k];
        s->mark_stamp[slot] = S;
    }
    if (me->changed_tick > c->last_sent_tick)
        s->snap[nsnap++] = me;
    for (uint32_t k = 0; k < n; k++) {
        const world_avatar *v = s->vis[k];
        uint32_t slot = world_slot(v->id);
        if (s->mark_stamp[slot] == S && s->mark_id[slot] == v->id) {
            s->mark_stamp[slot] = S + 1;
            if (v->changed_tick > c->last_sent_tick)
                s->snap[nsnap++] = v;
        } else {
            s->joined[njoined++] = v;
        }
    }
    for (uint32_t k = 0; k < c->nknown; k++)
        if (s->mark_stamp[world_slot(c->known[k])] == S)
            s->left[nleft++] = c->known[k];
    int ack_changed = me->ack_seq != c->sent_ack;
    if (!nleft && !njoined && !nsnap && !ack_changed) {
        c->last_sent_tick = tick;
        return;
    }
    size_t need = nleft * PROTO_SIZE_AVATAR_LEFT + njoined * PROTO_SIZE_AVATAR_JOINED_MAX +
                  PROTO_SIZE_SNAPSHOT(nsnap);
    proto_writer w;
    if (server__out_begin(s, c, need, &w) < 0)
        return;
    for (uint32_t k = 0; k < nleft; k++) {
        proto_avatar_left m = {.id = s->left[k],
                               .reason = world_get(s->world, s->left[k]) ? PROTO_LEFT_OUT_OF_RANGE
                                                                          : PROTO_LEFT_DISCONNECTED};
        proto_put_avatar_left(&w, &m);
    }
    for (uint32_t k = 0; k < njoined; k++) {
        const world_avatar *a = s->joined[k];
        proto_avatar_joined m = {.id = a->id, .name = {a->name, (uint32_t)strlen(a->name)}};
        memcpy(m.pos, a->pos, sizeof m.pos);
        memcpy(m.box, a->box, sizeof m.box);
        proto_put_avatar_joined(&w, &m);
    }
    if (nsnap || ack_changed) {
        size_t at = proto_put_snapshot_begin(&w, tick, me->ack_seq);
        for (uint32_t k = 0; k < nsnap; k++) {
            proto_avatar a = {.id = s->snap[k]->id};
            memcpy(a.pos, s->snap[k]->pos, sizeof a.pos);
            proto_put_snapshot_add(&w, at, &a);
        }
        proto_put_snapshot_end(&w, at);
    }
    server__out_end(s, c, &w);
    known_reserve(c, n);
    for (uint32_t k = 0; k < n; k++)
        c->known[k] = s->vis[k]->id;
    c->nknown = n;
    c->last_sent_tick = tick;
    c->sent_ack = me->ack_seq;
}

/* A contact from world_step: the colliding client is told, and the
 * collision is logged with its point in world and object-local coordinates
 * (so its history survives the object being moved). */
static void on_contact(void *ctx, const world_avatar *a, const move_contact *mc, const float vel[3])
{
    server *s = ctx;
    client *c = s->by_slot[world_slot(a->id)];
    const scene_object *o = scene_get(s->scene, mc->object_id);
    if (!c || !o)
        return;
    s->st.collisions++;
    proto_collision m = {.object_id = o->id, .ecm_version = o->ecm_version, .box_index = (uint16_t)mc->box_index,
                         .inside = mc->inside};
    memcpy(m.point, mc->point, sizeof m.point);
    memcpy(m.normal, mc->normal, sizeof m.normal);
    proto_writer w;
    if (!c->closing && server__out_begin(s, c, PROTO_SIZE_COLLISION, &w) == 0) {
        proto_put_collision(&w, &m);
        server__out_end(s, c, &w);
    }
    dblog_row row = {.at = db_now(), .session_id = c->session_id, .user_id = c->user_id, .object_id = o->id,
                     .avatar_id = a->id, .ecm_version = o->ecm_version, .box_index = mc->box_index,
                     .inside = mc->inside};
    memcpy(row.avatar, a->pos, sizeof row.avatar);
    memcpy(row.world, mc->point, sizeof row.world);
    scene_to_local(&o->at, mc->point, row.local);
    memcpy(row.normal, mc->normal, sizeof row.normal);
    memcpy(row.vel, vel, sizeof row.vel);
    dblog_push(s->log, &row); /* a full queue is counted in its stats */
}

static void on_tick(ev_loop *loop, void *data)
{
    server *s = data;
    uint64_t t0 = ev_clock(loop);
    world_step(s->world, s->scene, on_contact, s);
    uint32_t tick = world_tick(s->world);
    for (uint32_t i = 0; i < s->nclients; i++) {
        client *c = s->clients[i];
        if (c->state == ST_JOINED && !c->closing) {
            update_view(s, c, tick);
            objects__view(s, c, 0);
        }
    }
    uint64_t us = (ev_clock(loop) - t0) / 1000u;
    s->st.ticks++;
    metrics_tick_observe(&s->st.tick_hist, (double)us * 1e-6);
    if (s->st.nticks < s->st.tick_cap)
        s->st.tick_us[s->st.nticks++] = us > UINT32_MAX ? UINT32_MAX : (uint32_t)us;
    server__events_flush(s);
}

/* ---- connections ------------------------------------------------------ */

static void reap(server *s, client *c)
{
    objects__client_gone(s, c);
    if (c->avatar_id) {
        world_remove(s->world, c->avatar_id);
        s->by_slot[world_slot(c->avatar_id)] = NULL;
    }
    if (c->session_id) {
        store_event *e = server__event_push(s, EVT_CLOSE, c->session_id);
        snprintf(e->text, sizeof e->text, "%s", c->end_reason[0] ? c->end_reason : "closed");
        log_info("%s (session %lld) ended: %s", c->peer, (long long)c->session_id, e->text);
    }
    ev_io_del(s->loop, c->c.fd);
    conn_free(&c->c);
    if (s->cfg.max_per_address)
        addrcount_add(s->per_address, c->addr, -1);
    s->clients[c->index] = s->clients[--s->nclients];
    s->clients[c->index]->index = c->index;
    s->st.closed++;
    free(c->known);
    free(c);
}

/* Refuses a connection the server has no room for, with a best-effort error
 * frame (the socket is fresh, so a small write goes through). */
static void refuse(int fd, const char *why)
{
    uint8_t buf[PROTO_SIZE_ERROR_MAX];
    proto_writer w;
    proto_writer_init(&w, buf, sizeof buf);
    proto_put_error(&w, PROTO_ERR_SERVER_FULL, why);
    ssize_t n = write(fd, buf, w.len);
    (void)n;
    close(fd);
}

static void on_accept(ev_loop *loop, int fd, unsigned events, void *data);

/* The end of an ACCEPT_PAUSE_MS pause: watch the listening socket again
 * (unless a shutdown closed it meanwhile). */
static void resume_accept(ev_loop *loop, void *data)
{
    server *s = data;
    if (s->listen_fd >= 0 && ev_io_add(loop, s->listen_fd, EV_READ, on_accept, s) < 0)
        log_error("cannot watch the listening socket again; no new connections");
}

static void on_accept(ev_loop *loop, int fd, unsigned events, void *data)
{
    (void)events;
    server *s = data;
    for (int k = 0; k < ACCEPT_BUDGET; k++) {
        char peer[80], addr[80];
        int cfd = conn_accept(fd, peer, sizeof peer);
        if (cfd < 0) {
            if (cfd == -EMFILE || cfd == -ENFILE) {
                log_warn("accept: %s; raise the file limit (ulimit -n); no new connections for %u ms",
                         strerror(-cfd), ACCEPT_PAUSE_MS);
                if (ev_timer_start(loop, ACCEPT_PAUSE_MS * NS_PER_MS, 0, resume_accept, s) >= 0)
                    ev_io_del(loop, fd);
            } else if (cfd != -EAGAIN)
                log_warn("accept: %s", strerror(-cfd));
            return;
        }
        ratelimit_address(peer, addr, sizeof addr);
        if (s->nclients >= s->cfg.max_clients || cfd >= s->max_fd) {
            log_warn("%s refused: server full (%u clients)", peer, s->nclients);
            refuse(cfd, "server full");
            continue;
        }
        if (s->cfg.max_per_address && addrcount_add(s->per_address, addr, +1) > s->cfg.max_per_address) {
            addrcount_add(s->per_address, addr, -1);
            log_warn("%s refused: over %u connections from this address", peer, s->cfg.max_per_address);
            refuse(cfd, "too many connections from your address");
            continue;
        }
        int one = 1, sndbuf = SRV_SOCKET_SNDBUF;
        setsockopt(cfd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        setsockopt(cfd, SOL_SOCKET, SO_SNDBUF, &sndbuf, sizeof sndbuf);
        client *c = cvre_xcalloc(1, sizeof *c);
        if (conn_init(&c->c, cfd) < 0 || ev_io_add(loop, cfd, EV_READ, on_client_io, c) < 0) {
            log_error("%s refused: cannot register the connection", peer);
            if (s->cfg.max_per_address)
                addrcount_add(s->per_address, addr, -1);
            conn_free(&c->c);
            free(c);
            continue;
        }
        c->srv = s;
        memcpy(c->peer, peer, sizeof c->peer);
        memcpy(c->addr, addr, sizeof c->addr);
        c->connected_ns = c->last_frame_ns = server__now(s);
        c->index = s->nclients;
        s->clients[s->nclients++] = c;
        s->st.accepted++;
        log_debug("%s connected", c->peer);
    }
}

/* Enforces the handshake, idle and linger timeouts and the soft output
 * limit; runs every HOUSEKEEPING_MS. */
static void on_housekeeping(ev_loop *loop, void *data)
{
    (void)loop;
    server *s = data;
    uint64_t now = server__now(s);
    if (db_admin_events(s->db, s->admin_feed_last, on_admin_event, s, &s->admin_feed_last) < 0 && !db_busy(s->db))
        log_warn("admin feed: %s", db_error(s->db));
    for (uint32_t i = 0; i < s->nclients; i++) {
        client *c = s->clients[i];
        if (c->dead)
            continue;
        if (c->closing) {
            if (now > c->close_deadline_ns)
                c->dead = 1;
        } else if (c->state != ST_JOINED && now - c->connected_ns > s->cfg.handshake_timeout_ms * NS_PER_MS) {
            server__protocol_error(s, c, PROTO_ERR_TIMEOUT, "handshake not completed within %u ms",
                           s->cfg.handshake_timeout_ms);
        } else if (now - c->last_frame_ns > s->cfg.idle_timeout_ms * NS_PER_MS) {
            server__protocol_error(s, c, PROTO_ERR_TIMEOUT, "no complete frame for %u ms", s->cfg.idle_timeout_ms);
        } else if (c->soft_since_ns && now - c->soft_since_ns > SRV_OUTBUF_SOFT_MS * NS_PER_MS) {
            s->st.slow_readers++;
            kill_client(s, c, "output backlog over %u bytes for %u ms", SRV_OUTBUF_SOFT, SRV_OUTBUF_SOFT_MS);
        }
    }
}

static int cmp_u32(const void *x, const void *y)
{
    uint32_t a = *(const uint32_t *)x, b = *(const uint32_t *)y;
    return (a > b) - (a < b);
}

/* Logs the interval's figures (the growth of the totals since it began),
 * appends them to the stats file if one was asked for (with every tick
 * duration, for exact percentiles), and starts a new interval. */
static void on_stats(ev_loop *loop, void *data)
{
    server *s = data;
    stats *st = &s->st;
    const stats *b = &s->st_base;
    stats d = {.frames_in = st->frames_in - b->frames_in, .moves_in = st->moves_in - b->moves_in,
               .bytes_in = st->bytes_in - b->bytes_in, .bytes_out = st->bytes_out - b->bytes_out,
               .closed = st->closed - b->closed, .protocol_errors = st->protocol_errors - b->protocol_errors,
               .timeouts = st->timeouts - b->timeouts, .slow_readers = st->slow_readers - b->slow_readers,
               .moves_dropped = st->moves_dropped - b->moves_dropped};
    double secs = (double)(ev_clock(loop) - st->interval_start_ns) * 1e-9;
    uint32_t *sorted = cvre_xmalloc((st->nticks ? st->nticks : 1) * sizeof *sorted);
    memcpy(sorted, st->tick_us, st->nticks * sizeof *sorted);
    qsort(sorted, st->nticks, sizeof *sorted, cmp_u32);
    double p50 = st->nticks ? sorted[st->nticks / 2] / 1000.0 : 0;
    double p99 = st->nticks ? sorted[(st->nticks * 99) / 100] / 1000.0 : 0;
    double mx = st->nticks ? sorted[st->nticks - 1] / 1000.0 : 0;
    free(sorted);
    if (s->nclients || d.frames_in)
        log_info("stats: clients=%u ticks=%u tick_p50=%.2fms p99=%.2fms max=%.2fms moves/s=%.0f in=%.0fB/s "
                 "out=%.0fB/s closed=%llu errors=%llu timeouts=%llu slow=%llu moves_dropped=%llu",
                 s->nclients, st->nticks, p50, p99, mx, (double)d.moves_in / secs, (double)d.bytes_in / secs,
                 (double)d.bytes_out / secs, (unsigned long long)d.closed,
                 (unsigned long long)d.protocol_errors, (unsigned long long)d.timeouts,
                 (unsigned long long)d.slow_readers, (unsigned long long)d.moves_dropped);
    if (s->cfg.stats_file) {
        FILE *f = fopen(s->cfg.stats_file, "a");
        if (!f) {
            log_warn("stats file %s: %s", s->cfg.stats_file, strerror(errno));
        } else {
            fprintf(f,
                    "{\"seconds\":%.3f,\"clients\":%u,\"moves_in\":%llu,\"frames_in\":%llu,\"bytes_in\":%llu,"
                    "\"bytes_out\":%llu,\"closed\":%llu,\"protocol_errors\":%llu,\"timeouts\":%llu,"
                    "\"slow_readers\":%llu,\"moves_dropped\":%llu,\"tick_us\":[",
                    secs, s->nclients, (unsigned long long)d.moves_in, (unsigned long long)d.frames_in,
                    (unsigned long long)d.bytes_in, (unsigned long long)d.bytes_out,
                    (unsigned long long)d.closed, (unsigned long long)d.protocol_errors,
                    (unsigned long long)d.timeouts, (unsigned long long)d.slow_readers,
                    (unsigned long long)d.moves_dropped);
            for (uint32_t i = 0; i < st->nticks; i++)
                fprintf(f, i ? ",%u" : "%u", st->tick_us[i]);
            /* The collision log's totals; rows up to log_committed_id were
             * committed before this line was written (dblog.h). SQLite's
             * heap (its page caches, bounded by their cache_size) apart from
             * the rest tells a long run's cache filling from a leak. */
            dblog_stats ls;
            dblog_stats_get(s->log, &ls);
            fprintf(f, "],\"log_written\":%llu,\"log_dropped\":%llu,\"log_lost\":%llu,\"log_queued\":%llu,"
                       "\"log_committed_id\":%lld,\"log_last_error\":%d,\"sqlite_memory\":%lld}\n",
                    (unsigned long long)ls.written, (unsigned long long)ls.dropped, (unsigned long long)ls.lost,
                    (unsigned long long)ls.queued, (long long)ls.committed_id, ls.last_error,
                    (long long)sqlite3_memory_used());
            fclose(f);
        }
    }
    st->nticks = 0;
    st->interval_start_ns = ev_now(loop);
    s->st_base = *st;
}

/* ---- shutdown --------------------------------------------------------- */

/* Says bye (reason) to c and closes it; why goes to the session record. */
static void say_bye(server *s, client *c, uint8_t reason, const char *why)
{
    proto_writer w;
    if (c->closing || server__out_begin(s, c, PROTO_SIZE_BYE, &w) < 0)
        return;
    proto_put_bye(&w, reason);
    server__out_end(s, c, &w);
    begin_close(s, c, why);
}

static void begin_shutdown(server *s, const char *why)
{
    log_info("%s: shutting down, saying bye to %u clients", why, s->nclients);
    s->stopping = 1;
    s->stop_deadline_ns = server__now(s) + SHUTDOWN_GRACE_MS * NS_PER_MS;
    ev_io_del(s->loop, s->listen_fd);
    close(s->listen_fd);
    s->listen_fd = -1;
    for (uint32_t i = 0; i < s->nclients; i++)
        say_bye(s, s->clients[i], PROTO_BYE_SHUTDOWN, "shutdown");
}

/* One admin action from the store's feed: a kick ends one session; a ban
 * every session joined under the name (the auth worker refuses its joins
 * from now on), a new password or a deleted account that account's
 * sessions (and a deleted account's objects pass to the world). */
static void on_admin_event(void *ctx, const char *kind, int64_t session_id, const char *name)
{
    static const struct {
        const char *kind, *why;
    } ends[] = {{"kick", "kicked"}, {"ban", "banned"}, {"logout", "logged out: the password changed"},
                {"deleted", "the account was deleted"}};
    server *s = ctx;
    size_t k = 0;
    while (k < sizeof ends / sizeof ends[0] && strcmp(kind, ends[k].kind) != 0)
        k++;
    if (k == sizeof ends / sizeof ends[0]) {
        log_info("admin: %s %s", kind, name);
        return;
    }
    for (uint32_t i = 0; i < s->nclients; i++) {
        client *c = s->clients[i];
        const world_avatar *a = c->avatar_id ? world_get(s->world, c->avatar_id) : NULL;
        /* a join being checked may have passed the ban check already */
        const char *who = a ? a->name : c->state == ST_AUTH ? c->join_name : NULL;
        if (k == 0 ? c->session_id != session_id : !(who && strcasecmp(who, name) == 0))
            continue;
        log_info("%s (session %lld): %s", c->peer, (long long)c->session_id, ends[k].why);
        say_bye(s, c, PROTO_BYE_KICKED, ends[k].why);
    }
    if (strcmp(kind, "deleted") == 0)
        objects__owner_gone(s, name);
}

static void on_signal(ev_loop *loop, int fd, unsigned events, void *data)
{
    (void)loop;
    (void)events;
    server *s = data;
    struct signalfd_siginfo si;
    if (read(fd, &si, sizeof si) != (ssize_t)sizeof si || s->stopping)
        return;
    begin_shutdown(s, si.ssi_signo == SIGINT ? "SIGINT" : "SIGTERM");
}

/* Housekeeping before the loop sleeps: write what the tick and the handlers
 * queued (one write per client per wake-up), then free the clients that were
 * closed, outside any of their callbacks. */
static void before_sleep(ev_loop *loop, void *data)
{
    server *s = data;
    for (uint32_t i = 0; i < s->nwrite; i++) {
        s->write_list[i]->in_write_list = 0;
        flush_client(s, s->write_list[i]);
    }
    s->nwrite = 0;
    for (uint32_t i = 0; i < s->nclients;) {
        client *c = s->clients[i];
        if (c->dead)
            reap(s, c); /* moves the last client into slot i */
        else
            i++;
    }
    if (s->stopping && (s->nclients == 0 || server__now(s) > s->stop_deadline_ns))
        ev_stop(loop);
}

/* ---- setup ------------------------------------------------------------ */

static int setup_signals(server *s, char *err, size_t errlen)
{
    sigset_t set;
    sigemptyset(&set);
    sigaddset(&set, SIGINT);
    sigaddset(&set, SIGTERM);
    signal(SIGPIPE, SIG_IGN);
    if (sigprocmask(SIG_BLOCK, &set, NULL) < 0 || (s->signal_fd = signalfd(-1, &set, SFD_NONBLOCK | SFD_CLOEXEC)) < 0) {
        snprintf(err, errlen, "signalfd: %s", strerror(errno));
        return -1;
    }
    return 0;
}

server *server_create(const server_config *cfg, char *err, size_t errlen)
{
    server *s = cvre_xcalloc(1, sizeof *s);
    s->cfg = *cfg;
    s->listen_fd = s->signal_fd = -1;
    /* fds are handed out lowest first, so this bounds every client fd. */
    s->max_fd = (int)cfg->max_clients + 64;
    float half = cfg->world_size * 0.5f;
    world_config wc = {.min = {-half, 0, -half}, .max = {half, SRV_WORLD_HEIGHT, half},
                       .max_speed = cfg->max_speed, .aoi_radius = cfg->aoi_radius,
                       .spawn_radius = cfg->spawn_radius, .tick_dt = 1.0f / (float)cfg->tick_hz,
                       .capacity = cfg->max_clients, .seed = cfg->seed};
    s->world = world_create(&wc);
    if (!s->world) {
        snprintf(err, errlen, "cannot create the world (out of memory?)");
        goto fail;
    }
    s->clients = cvre_xcalloc(cfg->max_clients, sizeof *s->clients);
    s->write_list = cvre_xcalloc(cfg->max_clients, sizeof *s->write_list);
    s->vis = cvre_xcalloc(SRV_AOI_MAX, sizeof *s->vis);
    s->joined = cvre_xcalloc(SRV_AOI_MAX, sizeof *s->joined);
    s->snap = cvre_xcalloc(SRV_AOI_MAX, sizeof *s->snap);
    s->left = cvre_xcalloc(cfg->max_clients, sizeof *s->left);
    s->by_slot = cvre_xcalloc(cfg->max_clients, sizeof *s->by_slot);
    s->mark_id = cvre_xcalloc(cfg->max_clients, sizeof *s->mark_id);
    s->mark_stamp = cvre_xcalloc(cfg->max_clients, sizeof *s->mark_stamp);
    s->st.tick_cap = (uint32_t)cfg->tick_hz * (cfg->stats_interval_ms / 1000u + 1u) * 2u;
    s->st.tick_us = cvre_xcalloc(s->st.tick_cap, sizeof *s->st.tick_us);

    s->db = db_open(cfg->db_path, DB_READWRITE, err, errlen);
    if (!s->db)
        goto fail;
    s->last_session_id = db_session_last_id(s->db);
    int stale = db_sessions_close_stale(s->db, db_now());
    if (s->last_session_id < 0 || stale < 0) {
        snprintf(err, errlen, "database %s: %s", cfg->db_path, db_error(s->db));
        goto fail;
    }
    if (stale)
        log_warn("closed %d sessions left open by a previous run that did not shut down cleanly", stale);

    s->loop = ev_create(s->max_fd);
    if (!s->loop) {
        snprintf(err, errlen, "event loop: %s", strerror(errno));
        goto fail;
    }
    /* Signals are blocked before any thread starts, so that every thread
     * inherits the mask and SIGINT/SIGTERM reach only the signalfd. */
    if (setup_signals(s, err, errlen) < 0)
        goto fail;
    dblog_config lc = {DBLOG_QUEUE_ROWS_DEFAULT, DBLOG_BATCH_ROWS_DEFAULT, DBLOG_BATCH_MS_DEFAULT};
    s->log = dblog_open(cfg->db_path, &lc, err, errlen);
    if (!s->log || objects__start(s, err, errlen) < 0)
        goto fail;
    s->listen_fd = conn_listen(cfg->host, cfg->port, SRV_LISTEN_BACKLOG, s->address, sizeof s->address, err, errlen);
    if (s->listen_fd < 0)
        goto fail;
    s->logins = ratelimit_create(SRV_LOGIN_SLOTS, SRV_LOGIN_PER_SECOND, cfg->login_burst);
    s->per_address = addrcount_create(SRV_LOGIN_SLOTS);
    if (cfg->joins_per_second > 0)
        s->joins = ratelimit_create(SRV_LOGIN_SLOTS, cfg->joins_per_second, 2 * cfg->joins_per_second);
    if (db_admin_events_head(s->db, &s->admin_feed_last) < 0) {
        snprintf(err, errlen, "database %s: %s", cfg->db_path, db_error(s->db));
        goto fail;
    }
    s->auth = auth_start(cfg->db_path, err, errlen);
    if (!s->logins || !s->per_address || (cfg->joins_per_second > 0 && !s->joins) || !s->auth)
        goto fail;
    /* From now on this connection is the tick's: it must never wait. */
    db_set_busy_timeout(s->db, 0);
    uint64_t tick_ns = (uint64_t)1000000000 / (uint64_t)cfg->tick_hz;
    if (ev_io_add(s->loop, s->listen_fd, EV_READ, on_accept, s) < 0 ||
        ev_io_add(s->loop, s->signal_fd, EV_READ, on_signal, s) < 0 ||
        ev_io_add(s->loop, auth_fd(s->auth), EV_READ, on_auth_results, s) < 0 ||
        ev_timer_start(s->loop, tick_ns, tick_ns, on_tick, s) < 0 ||
        ev_timer_start(s->loop, HOUSEKEEPING_MS * NS_PER_MS, HOUSEKEEPING_MS * NS_PER_MS, on_housekeeping, s) < 0 ||
        ev_timer_start(s->loop, cfg->stats_interval_ms * NS_PER_MS, cfg->stats_interval_ms * NS_PER_MS, on_stats,
                       s) < 0) {
        snprintf(err, errlen, "event loop setup failed");
        goto fail;
    }
    if (metrics__start(s, err, errlen) < 0)
        goto fail;
    ev_set_before_sleep(s->loop, before_sleep, s);
    s->st.interval_start_ns = ev_clock(s->loop);
    return s;
fail:
    server_destroy(s);
    return NULL;
}

int server_run(server *s)
{
    log_info("serving on %s: tick %d Hz, world %.0f m, area of interest %.0f m, up to %u clients", s->address,
             s->cfg.tick_hz, (double)s->cfg.world_size, (double)s->cfg.aoi_radius, s->cfg.max_clients);
    int rc = ev_run(s->loop);
    if (rc < 0)
        log_error("event loop: %s", strerror(-rc));
    for (uint32_t i = 0; i < s->nclients; i++)
        if (!s->clients[i]->end_reason[0] || !s->stopping)
            snprintf(s->clients[i]->end_reason, sizeof s->clients[i]->end_reason, "shutdown");
    while (s->nclients)
        reap(s, s->clients[0]);
    db_set_busy_timeout(s->db, SRV_DB_BUSY_SHUTDOWN_MS); /* the last flush may wait */
    server__events_flush(s);
    dblog_stats ls;
    dblog_stop(s->log, &ls);
    s->log = NULL;
    log_info("stopped: %llu connections served; collision log: %llu rows written, %llu dropped, %llu lost",
             (unsigned long long)s->st.accepted, (unsigned long long)ls.written, (unsigned long long)ls.dropped,
             (unsigned long long)ls.lost);
    return rc < 0 ? -1 : 0;
}

void server_destroy(server *s)
{
    if (!s)
        return;
    while (s->nclients)
        reap(s, s->clients[0]);
    objects__stop(s);
    auth_stop(s->auth);
    ratelimit_destroy(s->logins);
    ratelimit_destroy(s->joins);
    addrcount_destroy(s->per_address);
    if (s->log)
        dblog_stop(s->log, NULL);
    metrics__stop(s);
    if (s->loop)
        ev_destroy(s->loop);
    if (s->listen_fd >= 0)
        close(s->listen_fd);
    if (s->signal_fd >= 0)
        close(s->signal_fd);
    db_close(s->db);
    world_destroy(s->world);
    free(s->clients);
    free(s->write_list);
    free(s->vis);
    free(s->joined);
    free(s->snap);
    free(s->left);
    free(s->by_slot);
    free(s->mark_id);
    free(s->mark_stamp);
    free(s->events);
    free(s->st.tick_us);
    free(s);
}
