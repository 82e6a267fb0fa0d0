/* session.c: one client connection (see session.h). */
#include "session.h"

#include <errno.h>
#include <math.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include "alloc.h"
#include "log.h"
#include "le.h"
#include "ws.h"

/* One read buffer shared by every session of the process: a read lands here
 * and is parsed in place, and only the unfinished tail of a frame is copied
 * into the session. 64 KiB drains a socket's worth of snapshots per call while
 * 5,000 bots cost no more input memory than their partial frames. */
#ifndef SESSION_SCRATCH_SIZE
#define SESSION_SCRATCH_SIZE (64u * 1024u)
#endif
_Static_assert(SESSION_SCRATCH_SIZE >= PROTO_HEADER_SIZE, "a read holds at least a header");

/* Reads per readiness callback, so one busy connection cannot starve the
 * others; the loop is level-triggered and calls back for the rest. */
#ifndef SESSION_READS_PER_WAKEUP
#define SESSION_READS_PER_WAKEUP 4
#endif

/* Addresses kept from the resolver; "localhost" gives two (::1, 127.0.0.1)
 * and the first may be the one the server does not listen on. */
#define SESSION_ADDRS_MAX 4

/* The largest frame a server may send us, header included; over a
 * WebSocket, the largest message. */
#define SESSION_IN_MAX (4u + PROTO_MAX_LEN)
/* The unfinished input a session keeps, at most: a frame, or a WebSocket
 * frame with its header, or the upgrade's answer. */
#define SESSION_IN_BUF_MAX (SESSION_IN_MAX + WS_SERVER_HEADER_MAX)
_Static_assert(WS_RESPONSE_MAX <= SESSION_IN_BUF_MAX, "the upgrade's answer fits the input buffer");
/* The largest frame the client sends, which a WebSocket message wraps. */
_Static_assert(PROTO_SIZE_JOIN_MAX <= SESSION_SIZE_CHUNK_MAX, "a join is not the largest frame sent");
/* The path the upgrade asks for: the server takes any. */
#define SESSION_WS_PATH "/"

struct session_ctx {
    ev_loop *loop;
    struct sockaddr_storage addrs[SESSION_ADDRS_MAX];
    socklen_t addr_lens[SESSION_ADDRS_MAX];
    int naddrs;
    int ws; /* sessions speak over a WebSocket */
    char peer[300];
    session *closing; /* ended, waiting for the before-sleep hook */
    uint64_t opened, frames_in, bytes_in;
    uint8_t scratch[SESSION_SCRATCH_SIZE];
};

struct session {
    session_ctx *ctx;
    const session_handler *h;
    void *data;
    session *next_closing;
    int in_closing; /* on ctx->closing */
    int fd;
    int state;
    int addr_i;      /* address being tried */
    unsigned armed;  /* events registered with the loop; 0 when not registered */
    int raw;         /* no handshake */
    int bye_sent;    /* no more frames after the bye */
    int write_dead;  /* a send failed: output is dropped, the read side reports the end */
    int want_writable; /* the owner asked for an on_writable call */
    int ended;
    session_end end;
    char why[256]; /* end.why */
    ws_reader wsr;   /* over a WebSocket: the server's frames */
    int ws_closed;   /* the server's close frame came: what follows is ignored */
    char ws_key[WS_KEY_SIZE]; /* of the upgrade, to check the 101 */
    uint32_t seq;
    int has_pose;    /* session_set_facing was called: moves carry pose */
    proto_pose pose;
    uint64_t last_send;
    uint64_t keepalive_stamp; /* of our own ping whose pong is not in yet; 0 when none */
    uint8_t *in; /* unfinished frame, in_len bytes */
    size_t in_len, in_cap;
    uint8_t *out; /* unsent bytes */
    size_t out_len, out_cap;
    session_view view;
    float box[3];
    char name[PROTO_NAME_MAX + 1];
    session_credential cred;
};

static ev_io_fn on_io;

/* ---- context ----------------------------------------------------------- */

/* Runs before each poll: the one safe point to tell owners about ends,
 * because no callback of any session is on the stack. on_close may free the
 * session and may open or end others, so the list is popped one at a time. */
static void reap(ev_loop *loop, void *data)
{
    session_ctx *ctx = data;
    (void)loop;
    while (ctx->closing) {
        session *c = ctx->closing;
        ctx->closing = c->next_closing;
        c->next_closing = NULL;
        c->in_closing = 0;
        if (c->fd >= 0) {
            close(c->fd);
            c->fd = -1;
        }
        c->h->on_close(c, &c->end, c->data);
    }
}

session_ctx *session_ctx_create(ev_loop *loop, const session_params *net, char *err, size_t errlen)
{
    const char *host = net->host;
    uint16_t port = net->port;
    struct addrinfo hints = {.ai_family = AF_UNSPEC, .ai_socktype = SOCK_STREAM,
                             .ai_flags = AI_NUMERICSERV};
    struct addrinfo *res = NULL;
    char service[8];
    snprintf(service, sizeof service, "%u", (unsigned)port);
    int rc = getaddrinfo(host, service, &hints, &res);
    if (rc != 0) {
        snprintf(err, errlen, "cannot resolve '%s': %s", host,
                 rc == EAI_SYSTEM ? strerror(errno) : gai_strerror(rc));
        return NULL;
    }
    session_ctx *ctx = cvre_xcalloc(1, sizeof *ctx);
    ctx->loop = loop;
    ctx->ws = net->ws;
    for (struct addrinfo *ai = res; ai && ctx->naddrs < SESSION_ADDRS_MAX; ai = ai->ai_next) {
        if (ai->ai_addrlen > sizeof ctx->addrs[0])
            continue;
        memcpy(&ctx->addrs[ctx->naddrs], ai->ai_addr, ai->ai_addrlen);
        ctx->addr_lens[ctx->naddrs++] = ai->ai_addrlen;
    }
    freeaddrinfo(res);
    if (ctx->naddrs == 0) {
        snprintf(err, errlen, "cannot resolve '%s': no usable address", host);
        free(ctx);
        return NULL;
    }
    if (strchr(host, ':'))
        snprintf(ctx->peer, sizeof ctx->peer, "[%s]:%u", host, (unsigned)port);
    else
        snprintf(ctx->peer, sizeof ctx->peer, "%s:%u", host, (unsigned)port);
    ev_set_before_sleep(loop, reap, ctx);
    return ctx;
}

void session_ctx_free(session_ctx *ctx)
{
    if (!ctx)
        return;
    ev_set_before_sleep(ctx->loop, NULL, NULL);
    free(ctx);
}

uint64_t session_ctx_opened(const session_ctx *ctx) { return ctx->opened; }
uint64_t session_ctx_frames_in(const session_ctx *ctx) { return ctx->frames_in; }
uint64_t session_ctx_bytes_in(const session_ctx *ctx) { return ctx->bytes_in; }
const char *session_ctx_peer(const session_ctx *ctx) { return ctx->peer; }

/* ---- ending ------------------------------------------------------------ */

/* Records the first end and takes the socket out of the loop at once, so no
 * further callback arrives; the fd itself stays open until the reap, which
 * keeps its number from being reused by a socket opened meanwhile. */
static void end_conn(session *c, int kind, int code)
{
    if (c->ended)
        return;
    c->ended = 1;
    c->end = (session_end){.kind = kind, .code = code, .after_bye = c->bye_sent,
                        .was_open = c->state != SESSION_CONNECTING, .why = c->why};
    c->state = SESSION_CLOSED;
    if (c->armed) {
        ev_io_del(c->ctx->loop, c->fd);
        c->armed = 0;
    }
    c->next_closing = c->ctx->closing;
    c->ctx->closing = c;
    c->in_closing = 1;
}

void session_close(session *c) { end_conn(c, SESSION_END_LOCAL, 0); }

/* The upgrade refused, or a WebSocket frame that breaks RFC 6455. */
static void end_ws(session *c, const char *why)
{
    snprintf(c->why, sizeof c->why, "%s", why);
    end_conn(c, SESSION_END_WEBSOCKET, 0);
}

/* Registers or re-arms the fd. Returns 0 or -errno, which the caller turns
 * into the end that fits its stage (the loop refuses an fd past its size). */
static int arm(session *c, unsigned events)
{
    int rc = c->armed ? ev_io_mod(c->ctx->loop, c->fd, events)
                      : ev_io_add(c->ctx->loop, c->fd, events, on_io, c);
    if (rc == 0)
        c->armed = events;
    return rc;
}

/* Re-arms an established session; failing to is fatal for it. */
static void rearm(session *c, unsigned events)
{
    int rc = arm(c, events);
    if (rc < 0)
        end_conn(c, SESSION_END_SOCKET, -rc);
}

/* ---- output ------------------------------------------------------------ */

/* Appends to the backlog, which grows on demand so that idle bots hold no
 * output memory; the caller has checked SESSION_OUT_MAX. */
static void out_append(session *c, const uint8_t *p, size_t n)
{
    if (c->out_len + n > c->out_cap) {
        size_t cap = c->out_cap ? c->out_cap * 2 : 512;
        while (cap < c->out_len + n)
            cap *= 2;
        if (cap > SESSION_OUT_MAX)
            cap = SESSION_OUT_MAX;
        c->out = cvre_xrealloc(c->out, cap);
        c->out_cap = cap;
    }
    memcpy(c->out + c->out_len, p, n);
    c->out_len += n;
}

/* A failed send does not end the session: the server may have closed after an
 * error message that is still waiting to be read. Output stops, and the read
 * side, which the kernel now reports as readable, delivers what is left and
 * then the end. */
static void write_failed(session *c)
{
    c->write_dead = 1;
    c->out_len = 0;
    if (c->armed & EV_WRITE)
        rearm(c, EV_READ);
}

/* Once the bye is out, closing our half tells the server we are done even
 * if it does not act on the bye itself. */
static void maybe_shutdown(session *c)
{
    if (c->bye_sent && c->out_len == 0 && !c->write_dead)
        shutdown(c->fd, SHUT_WR);
}

/*
 * Sends bytes that belong together (a frame, a message, the upgrade):
 * directly when nothing is queued, the unsent rest into the backlog
 * (EV_WRITE armed). What would push the backlog past SESSION_OUT_MAX is
 * dropped whole, so the stream never holds half a frame. Returns 0,
 * -ENOBUFS when dropped, -ENOTCONN when the session cannot send any more.
 * Only called on an established connection.
 */
static int send_bytes(session *c, const uint8_t *p, size_t n)
{
    if (c->ended || c->write_dead || c->bye_sent)
        return -ENOTCONN;
    if (c->out_len + n > SESSION_OUT_MAX)
        return -ENOBUFS;
    size_t done = 0;
    if (c->out_len == 0) {
        ssize_t k = send(c->fd, p, n, MSG_NOSIGNAL | MSG_DONTWAIT);
        if (k < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) {
            write_failed(c);
            return -ENOTCONN;
        }
        done = k > 0 ? (size_t)k : 0;
    }
    c->last_send = ev_now(c->ctx->loop);
    if (done < n) {
        out_append(c, p + done, n - done);
        if (!(c->armed & EV_WRITE))
            rearm(c, EV_READ | EV_WRITE);
    }
    return 0;
}

/* A WebSocket message of the client's: opcode and payload in a masked
 * frame, sent as send_bytes does. */
static int send_ws(session *c, unsigned opcode, const uint8_t *p, size_t n)
{
    uint8_t msg[WS_CLIENT_HEADER_MAX + SESSION_SIZE_CHUNK_MAX];
    int len = ws_client_frame(msg, sizeof msg, opcode, p, n);
    if (len < 0) { /* no random bytes for the mask (a frame too large is a bug) */
        end_ws(c, "no random bytes for a frame's mask");
        return -ENOTCONN;
    }
    return send_bytes(c, msg, (size_t)len);
}

/* Sends one whole frame of the protocol: as it is over TCP, in a binary
 * message of its own over a WebSocket. */
static int send_frame(session *c, const uint8_t *p, size_t n)
{
    return c->ctx->ws ? send_ws(c, WS_OP_BINARY, p, n) : send_bytes(c, p, n);
}

/* Writes the backlog when the socket has room again; once it is empty,
 * gives the owner the on_writable call it asked for, and stops watching for
 * writability unless the owner refilled the backlog or asked again. */
static void flush(session *c)
{
    while (c->out_len > 0) {
        ssize_t k = send(c->fd, c->out, c->out_len, MSG_NOSIGNAL | MSG_DONTWAIT);
        if (k < 0) {
            if (errno == EINTR)
                continue;
            if (errno != EAGAIN && errno != EWOULDBLOCK)
                write_failed(c);
            return;
        }
        c->out_len -= (size_t)k;
        memmove(c->out, c->out + k, c->out_len);
    }
    if (c->want_writable) {
        c->want_writable = 0;
        if (!c->bye_sent) { /* after the bye nothing more may be sent */
            c->h->on_writable(c, c->data);
            if (c->ended || c->write_dead)
                return;
        }
    }
    if (c->out_len == 0 && !c->want_writable && (c->armed & EV_WRITE))
        rearm(c, EV_READ);
    maybe_shutdown(c);
}

/* ---- input ------------------------------------------------------------- */

/* Frame types only a server sends; anything else from it is a protocol
 * violation even when it decodes. */
static int from_server(uint16_t type)
{
    switch (type) {
    case PROTO_WELCOME:
    case PROTO_JOIN_OK:
    case PROTO_SNAPSHOT:
    case PROTO_AVATAR_JOINED:
    case PROTO_AVATAR_LEFT:
    case PROTO_ERROR:
    case PROTO_PING:
    case PROTO_PONG:
    case PROTO_BYE:
    case PROTO_AVATAR_POSE:
    case PROTO_OBJECT_INFO:
    case PROTO_OBJECT_REMOVED:
    case PROTO_OBJECT_REJECTED:
    case PROTO_MESH_CHUNK:
    case PROTO_COLLISION:
        return 1;
    default:
        return 0;
    }
}

/* Object messages follow JOIN_OK (the world's objects come right after it)
 * and concern a joined avatar only. */
static int needs_join(uint16_t type)
{
    return type == PROTO_OBJECT_INFO || type == PROTO_OBJECT_REMOVED || type == PROTO_OBJECT_REJECTED ||
           type == PROTO_MESH_CHUNK || type == PROTO_COLLISION;
}

static void send_join(session *c)
{
    uint8_t buf[PROTO_SIZE_JOIN_MAX];
    proto_writer w;
    proto_writer_init(&w, buf, sizeof buf);
    proto_join j = {.name = {c->name, (uint32_t)strlen(c->name)}, .credential = c->cred.kind,
                    .secret = c->cred.secret, .secret_len = c->cred.len};
    memcpy(j.box, c->box, sizeof j.box);
    proto_put_join(&w, &j);
    send_frame(c, buf, w.len);
    memset(buf, 0, sizeof buf);
    memset(&c->cred, 0, sizeof c->cred);
}

void session_set_credential(session *c, const session_credential *cred) { c->cred = *cred; }

static void find_own(session *c, const proto_snapshot *s)
{
    for (uint16_t i = 0; i < s->count; i++) {
        if (le_get_u32(s->entries + (size_t)i * PROTO_SNAPSHOT_ENTRY_SIZE) != c->view.avatar_id)
            continue;
        proto_avatar a;
        proto_snapshot_entry(s, i, &a);
        memcpy(c->view.pos, a.pos, sizeof a.pos);
        c->view.pos_fresh = 1;
        return;
    }
}

/*
 * Decodes one whole frame, advances the handshake and the view, and hands
 * the message to the owner. A frame that does not decode, or is not legal
 * from a server in our state, ends the session with the status.
 */
static void dispatch(session *c, const proto_frame *f)
{
    proto_msg m;
    c->ctx->frames_in++;
    int st = proto_decode(f, &m);
    if (st == PROTO_OK && (!from_server(m.type) || (needs_join(m.type) && c->state != SESSION_JOINED)))
        st = PROTO_ERR_UNEXPECTED;
    c->view.pos_fresh = 0;
    if (st == PROTO_OK) {
        switch (m.type) {
        case PROTO_WELCOME:
            if (c->state != SESSION_HELLO_SENT)
                st = PROTO_ERR_UNEXPECTED;
            else if (m.u.welcome.version != PROTO_VERSION)
                st = PROTO_ERR_VERSION;
            else {
                c->view.welcome = m.u.welcome;
                c->state = SESSION_JOIN_SENT;
                send_join(c);
            }
            break;
        case PROTO_JOIN_OK:
            if (c->state != SESSION_JOIN_SENT) {
                st = PROTO_ERR_UNEXPECTED;
                break;
            }
            c->state = SESSION_JOINED;
            c->view.avatar_id = m.u.join_ok.avatar_id;
            memcpy(c->view.pos, m.u.join_ok.pos, sizeof c->view.pos);
            memcpy(c->view.box, m.u.join_ok.box, sizeof c->view.box);
            c->view.pos_fresh = 1;
            break;
        case PROTO_SNAPSHOT:
            c->view.ack = m.u.snapshot.ack_seq;
            if (c->state == SESSION_JOINED)
                find_own(c, &m.u.snapshot);
            break;
        case PROTO_PONG:
            if (c->keepalive_stamp != 0 && m.u.ping.stamp == c->keepalive_stamp) {
                c->keepalive_stamp = 0;
                return;
            }
            break;
        case PROTO_PING: {
            uint8_t buf[PROTO_SIZE_PING];
            proto_writer w;
            proto_writer_init(&w, buf, sizeof buf);
            proto_put_pong(&w, m.u.ping.stamp);
            send_frame(c, buf, w.len); /* a full backlog loses the pong; the server's idle timer copes */
            break;
        }
        default:
            break;
        }
    }
    if (st != PROTO_OK) {
        end_conn(c, SESSION_END_PROTO, st);
        return;
    }
    c->h->on_msg(c, &m, c->data);
}

/* Bytes the unfinished input in c->in needs in all. A frame: a header
 * until one is there, then what its length field says (checked by
 * proto_frame_parse). A WebSocket frame: what ws_frame_need says (checked
 * by ws_read). The upgrade's answer: as much as its head may take. */
static size_t pending_need(const session *c)
{
    if (c->state == SESSION_UPGRADING)
        return WS_RESPONSE_MAX;
    if (c->ctx->ws)
        return ws_frame_need(c->in, c->in_len);
    if (c->in_len < PROTO_HEADER_SIZE)
        return PROTO_HEADER_SIZE;
    return 4u + (size_t)le_get_u32(c->in);
}

static void in_reserve(session *c, size_t need)
{
    if (need <= c->in_cap)
        return;
    size_t cap = 256;
    while (cap < need)
        cap *= 2;
    if (cap > SESSION_IN_BUF_MAX)
        cap = SESSION_IN_BUF_MAX;
    c->in = cvre_xrealloc(c->in, cap);
    c->in_cap = cap;
}

/* Keeps the unfinished tail of a read in the session. */
static void keep_tail(session *c, const uint8_t *p, size_t n)
{
    in_reserve(c, n);
    memcpy(c->in, p, n);
    c->in_len = n;
}

/* One message of the server's: exactly one frame (PROTOCOL.md,
 * "WebSocket transport"), dispatched as if it had come over TCP. */
static void ws_message(session *c, const uint8_t *p, size_t n)
{
    proto_frame f;
    int st = proto_frame_parse(p, n, PROTO_MAX_LEN, &f);
    if (st == PROTO_INCOMPLETE || (st == PROTO_OK && f.size != n))
        st = PROTO_ERR_TRUNCATED;
    if (st != PROTO_OK) {
        end_conn(c, SESSION_END_PROTO, st);
        return;
    }
    dispatch(c, &f);
}

/* Takes the first WebSocket frame of p[0..n) and acts on what it
 * completed. Returns the bytes taken, 0 if the frame is not all there, or
 * -1 once the session ended. */
static ssize_t take_ws(session *c, uint8_t *p, size_t n)
{
    if (c->ws_closed)
        return (ssize_t)n; /* after the close nothing more is read */
    ws_event ev;
    char err[128];
    ssize_t k = ws_read(&c->wsr, p, n, &ev, err, sizeof err);
    if (k < 0) {
        char why[sizeof c->why];
        snprintf(why, sizeof why, "a bad WebSocket frame from the server: %s", err);
        end_ws(c, why);
        return -1;
    }
    if (k == 0)
        return 0;
    switch (ev.type) {
    case WS_EV_MESSAGE:
        ws_message(c, ev.data, ev.len);
        break;
    case WS_EV_PING:
        send_ws(c, WS_OP_PONG, ev.data, ev.len);
        break;
    case WS_EV_CLOSE: { /* answered with its code (5.5.1) unless our bye went first and shut our half;
                         * the server then closes the TCP connection */
        c->ws_closed = 1;
        uint8_t frame[WS_CLIENT_HEADER_MAX + 2];
        int len = ws_client_close_frame(frame, sizeof frame, ev.code, NULL);
        if (len > 0)
            send_bytes(c, frame, (size_t)len);
        break;
    }
    default: /* a pong, a fragment */
        break;
    }
    return c->ended ? -1 : k;
}

/* Parses the frames of a read that landed in the shared buffer; keeps the
 * unfinished tail in the session. */
static void parse_scratch(session *c, uint8_t *buf, size_t n)
{
    size_t off = 0;
    if (c->ctx->ws) {
        while (off < n && !c->ended) {
            ssize_t k = take_ws(c, buf + off, n - off);
            if (k == 0)
                keep_tail(c, buf + off, n - off);
            if (k <= 0)
                return;
            off += (size_t)k;
        }
        return;
    }
    while (off < n && !c->ended) {
        proto_frame f;
        int st = proto_frame_parse(buf + off, n - off, PROTO_MAX_LEN, &f);
        if (st == PROTO_OK) {
            dispatch(c, &f);
            off += f.size;
        } else if (st == PROTO_INCOMPLETE) {
            keep_tail(c, buf + off, n - off);
            return;
        } else {
            end_conn(c, SESSION_END_PROTO, st);
        }
    }
}

static void start_protocol(session *c);

/* The upgrade's answer, in c->in: once its head is all there and says
 * 101, the protocol starts, and whatever came behind the head is read as
 * frames. */
static void upgrade_answer(session *c)
{
    char err[128], why[sizeof c->why];
    int head = ws_client_response(c->in, c->in_len, c->ws_key, err, sizeof err);
    if (head == 0)
        return;
    if (head < 0) {
        snprintf(why, sizeof why, "the WebSocket upgrade failed: %s", err);
        end_ws(c, why);
        return;
    }
    size_t rest = c->in_len - (size_t)head;
    uint8_t *scratch = c->ctx->scratch; /* free: this read went to c->in */
    memcpy(scratch, c->in + head, rest);
    c->in_len = 0;
    ws_reader_init_client(&c->wsr, SESSION_IN_MAX);
    start_protocol(c);
    if (!c->ended)
        parse_scratch(c, scratch, rest);
}

/* Called after bytes were added to the unfinished input. */
static void parse_pending(session *c)
{
    if (c->state == SESSION_UPGRADING) {
        upgrade_answer(c);
        return;
    }
    if (c->ctx->ws) {
        /* Reads never go past the frame: taken whole, it is all of c->in. */
        if (take_ws(c, c->in, c->in_len) > 0)
            c->in_len = 0;
        return;
    }
    proto_frame f;
    int st = proto_frame_parse(c->in, c->in_len, PROTO_MAX_LEN, &f);
    if (st == PROTO_OK) {
        c->in_len = 0; /* reads never go past the frame, so it is all of c->in */
        dispatch(c, &f);
    } else if (st != PROTO_INCOMPLETE) {
        end_conn(c, SESSION_END_PROTO, st);
    }
}

/*
 * Reads what the socket has, up to SESSION_READS_PER_WAKEUP calls. Without an
 * unfinished frame a read goes to the shared buffer; with one (or the
 * upgrade's answer, always read into the session), the read asks
 * for exactly the rest of that frame, so the session's own buffer never holds
 * more than one frame and a finished frame is parsed where it lies. A short
 * read normally means the socket is drained and saves the call that would
 * say EAGAIN; with drain set (the peer hung up) reading goes on until the
 * end shows. Returns 1 when the socket said EAGAIN, 0 otherwise.
 */
static int read_some(session *c, int drain)
{
    session_ctx *ctx = c->ctx;
    for (int i = 0; i < SESSION_READS_PER_WAKEUP && !c->ended; i++) {
        uint8_t *dst = ctx->scratch;
        size_t want = sizeof ctx->scratch;
        if (c->in_len > 0 || c->state == SESSION_UPGRADING) {
            size_t need = pending_need(c);
            in_reserve(c, need);
            dst = c->in + c->in_len;
            want = need - c->in_len;
        }
        ssize_t n = recv(c->fd, dst, want, 0);
        if (n < 0) {
            if (errno == EINTR)
                continue;
            if (errno == EAGAIN || errno == EWOULDBLOCK)
                return 1;
            end_conn(c, SESSION_END_SOCKET, errno);
            return 0;
        }
        if (n == 0) {
            if (c->state == SESSION_UPGRADING) {
                end_ws(c, "the server closed during the WebSocket upgrade (is this its --web port?)");
            } else if (c->in_len > 0)
                end_conn(c, SESSION_END_PROTO, PROTO_ERR_TRUNCATED);
            else
                end_conn(c, SESSION_END_EOF, 0);
            return 0;
        }
        ctx->bytes_in += (uint64_t)n;
        if (dst == ctx->scratch) {
            parse_scratch(c, dst, (size_t)n);
        } else {
            c->in_len += (size_t)n;
            parse_pending(c);
        }
        if ((size_t)n < want && !drain)
            return 0; /* drained for now */
    }
    return 0;
}

/* ---- connecting -------------------------------------------------------- */

static void send_hello(session *c)
{
    uint8_t buf[PROTO_SIZE_HELLO];
    proto_writer w;
    proto_writer_init(&w, buf, sizeof buf);
    proto_put_hello(&w, &(proto_hello){.magic = PROTO_MAGIC, .version = PROTO_VERSION});
    send_frame(c, buf, w.len);
}

/* The protocol proper: hello, or nothing for a raw session. */
static void start_protocol(session *c)
{
    c->state = c->raw ? SESSION_RAW : SESSION_HELLO_SENT;
    if (!c->raw && !c->ended)
        send_hello(c);
}

static void connected(session *c)
{
    c->ctx->opened++;
    c->last_send = ev_now(c->ctx->loop);
    rearm(c, EV_READ);
    if (!c->ctx->ws) {
        start_protocol(c);
        return;
    }
    char req[512];
    int n = ws_client_request(req, sizeof req, c->ctx->peer, SESSION_WS_PATH, c->ws_key);
    c->state = SESSION_UPGRADING;
    if (n < 0)
        end_ws(c, n == -ENOSPC ? "the host name is too long for the upgrade" : "no random bytes for the upgrade's key");
    else if (!c->ended)
        send_bytes(c, (const uint8_t *)req, (size_t)n);
}

/* Tries the resolved addresses from c->addr_i on; ends the session with the
 * last error when none is left. A refused address moves on to the next one,
 * an exhausted process (EMFILE) does not. */
static void connect_next(session *c)
{
    session_ctx *ctx = c->ctx;
    int err = ECONNREFUSED;
    for (; c->addr_i < ctx->naddrs; c->addr_i++) {
        const struct sockaddr *sa = (const struct sockaddr *)&ctx->addrs[c->addr_i];
        c->fd = socket(sa->sa_family, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
        if (c->fd < 0) {
            err = errno;
            if (err == EMFILE || err == ENFILE || err == ENOBUFS || err == ENOMEM)
                break;
            continue;
        }
        /* Moves are small and latency matters more than packet count. */
        int one = 1;
        setsockopt(c->fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        if (connect(c->fd, sa, ctx->addr_lens[c->addr_i]) == 0) {
            connected(c);
            return;
        }
        if (errno == EINPROGRESS) {
            int rc = arm(c, EV_WRITE);
            if (rc == 0)
                return;
            err = -rc;
            close(c->fd);
            c->fd = -1;
            break;
        }
        err = errno;
        close(c->fd);
        c->fd = -1;
    }
    end_conn(c, SESSION_END_CONNECT, err);
}

static void finish_connect(session *c)
{
    int err = 0;
    socklen_t len = sizeof err;
    if (getsockopt(c->fd, SOL_SOCKET, SO_ERROR, &err, &len) < 0)
        err = errno;
    if (err == 0) {
        connected(c);
        return;
    }
    ev_io_del(c->ctx->loop, c->fd);
    c->armed = 0;
    close(c->fd);
    c->fd = -1;
    c->addr_i++;
    connect_next(c);
}

/* The loop's callback for every session socket. */
static void on_io(ev_loop *loop, int fd, unsigned events, void *data)
{
    session *c = data;
    (void)loop;
    (void)fd;
    if (c->state == SESSION_CONNECTING) {
        finish_connect(c);
        return;
    }
    int drained = 0;
    if (events & (EV_READ | EV_ERROR))
        drained = read_some(c, (events & EV_ERROR) != 0);
    if (!c->ended && (events & EV_ERROR) && drained) {
        /* An error with nothing left to read: level-triggered, it would
         * wake us forever, so it ends the session. */
        int err = 0;
        socklen_t len = sizeof err;
        getsockopt(c->fd, SOL_SOCKET, SO_ERROR, &err, &len);
        end_conn(c, SESSION_END_SOCKET, err ? err : EPIPE);
    }
    if (!c->ended && (events & EV_WRITE))
        flush(c);
}

/* ---- public ------------------------------------------------------------ */

session *session_open(session_ctx *ctx, const char *name, const float box[3], const session_handler *handler,
                void *data)
{
    session *c = cvre_xcalloc(1, sizeof *c);
    c->ctx = ctx;
    c->h = handler;
    c->data = data;
    c->fd = -1;
    c->state = SESSION_CONNECTING;
    c->raw = name == NULL;
    if (name)
        snprintf(c->name, sizeof c->name, "%s", name);
    if (box)
        memcpy(c->box, box, sizeof c->box);
    connect_next(c);
    return c;
}

void session_free(session *c)
{
    if (!c)
        return;
    if (c->in_closing) {
        /* Ended but not reaped yet: unlink it so the hook never sees it. */
        session **p = &c->ctx->closing;
        while (*p && *p != c)
            p = &(*p)->next_closing;
        if (*p)
            *p = c->next_closing;
    }
    if (c->armed)
        ev_io_del(c->ctx->loop, c->fd);
    if (c->fd >= 0)
        close(c->fd);
    ws_reader_free(&c->wsr);
    free(c->in);
    free(c->out);
    free(c);
}

int session_state(const session *c) { return c->state; }

const session_view *session_get_view(const session *c) { return &c->view; }

uint32_t session_send_move(session *c, const float pos[3])
{
    if (c->state != SESSION_JOINED && c->state != SESSION_RAW)
        return 0;
    uint8_t buf[PROTO_SIZE_MOVE_MAX];
    proto_writer w;
    proto_writer_init(&w, buf, sizeof buf);
    proto_move m = {.seq = c->seq + 1, .has_pose = (uint8_t)c->has_pose, .pose = c->pose};
    memcpy(m.pos, pos, sizeof m.pos);
    proto_put_move(&w, &m);
    if (send_frame(c, buf, w.len) < 0)
        return 0;
    return ++c->seq;
}

void session_set_facing(session *c, float yaw, float pitch, int head)
{
    c->has_pose = 1;
    c->pose = (proto_pose){.yaw = yaw, .pitch = pitch};
    if (!head)
        return;
    /* Turned by yaw about y, then by pitch about x: q_yaw x q_pitch. */
    float sy = sinf(yaw * 0.5f), cy = cosf(yaw * 0.5f), sp = sinf(pitch * 0.5f), cp = cosf(pitch * 0.5f);
    const float q[4] = {cy * sp, sy * cp, -sy * sp, cy * cp};
    const float eyes[3] = {0.0f, SESSION_EYE_HEIGHT * c->view.box[1], 0.0f};
    proto_pose_set_part(&c->pose, PROTO_POSE_HEAD, eyes, q);
}

int session_send_ping(session *c, uint64_t stamp)
{
    if (c->state != SESSION_JOINED)
        return -ENOTCONN;
    uint8_t buf[PROTO_SIZE_PING];
    proto_writer w;
    proto_writer_init(&w, buf, sizeof buf);
    proto_put_ping(&w, stamp);
    return send_frame(c, buf, w.len);
}

int session_send_upload_begin(session *c, const proto_upload_begin *m)
{
    if (c->state != SESSION_JOINED)
        return -ENOTCONN;
    uint8_t buf[PROTO_HEADER_SIZE + 8u + 2u + PROTO_OBJECT_NAME_MAX + PROTO_FORMAT_MAX + 5u];
    proto_writer w;
    proto_writer_init(&w, buf, sizeof buf);
    proto_put_upload_begin(&w, m);
    return w.err == PROTO_OK ? send_frame(c, buf, w.len) : -EINVAL;
}

int session_send_upload_chunk(session *c, uint32_t upload_id, uint32_t offset, const uint8_t *data, uint32_t len)
{
    if (c->state != SESSION_JOINED)
        return -ENOTCONN;
    /* Checked before encoding, so a full backlog costs no 16 KiB copy. */
    if (c->out_len + PROTO_HEADER_SIZE + 8u + len > SESSION_OUT_MAX)
        return -ENOBUFS;
    uint8_t buf[SESSION_SIZE_CHUNK_MAX];
    proto_writer w;
    proto_writer_init(&w, buf, sizeof buf);
    proto_put_upload_chunk(&w, &(proto_upload_chunk){.upload_id = upload_id, .offset = offset, .data = data,
                                                     .len = len});
    return w.err == PROTO_OK ? send_frame(c, buf, w.len) : -EINVAL;
}

int session_send_upload_end(session *c, const proto_upload_end *m)
{
    if (c->state != SESSION_JOINED)
        return -ENOTCONN;
    uint8_t buf[PROTO_HEADER_SIZE + 4u + PROTO_SIZE_TRANSFORM];
    proto_writer w;
    proto_writer_init(&w, buf, sizeof buf);
    proto_put_upload_end(&w, m);
    return send_frame(c, buf, w.len);
}

int session_send_object_place(session *c, const proto_object_place *m)
{
    if (c->state != SESSION_JOINED)
        return -ENOTCONN;
    uint8_t buf[PROTO_HEADER_SIZE + 4u + PROTO_SIZE_TRANSFORM];
    proto_writer w;
    proto_writer_init(&w, buf, sizeof buf);
    proto_put_object_place(&w, m);
    return send_frame(c, buf, w.len);
}

int session_send_object_remove(session *c, uint32_t object_id)
{
    if (c->state != SESSION_JOINED)
        return -ENOTCONN;
    uint8_t buf[PROTO_HEADER_SIZE + 4u];
    proto_writer w;
    proto_writer_init(&w, buf, sizeof buf);
    proto_put_object_remove(&w, object_id);
    return send_frame(c, buf, w.len);
}

int session_send_mesh_request(session *c, const proto_mesh_request *m)
{
    if (c->state != SESSION_JOINED)
        return -ENOTCONN;
    uint8_t buf[PROTO_SIZE_MESH_REQUEST];
    proto_writer w;
    proto_writer_init(&w, buf, sizeof buf);
    proto_put_mesh_request(&w, m);
    return send_frame(c, buf, w.len);
}

size_t session_out_pending(const session *c) { return c->out_len; }

int session_want_writable(session *c)
{
    if (c->ended || c->write_dead || c->bye_sent || c->state == SESSION_CONNECTING || !c->h->on_writable)
        return -ENOTCONN;
    c->want_writable = 1;
    if (!(c->armed & EV_WRITE))
        rearm(c, EV_READ | EV_WRITE);
    return c->ended ? -ENOTCONN : 0;
}

void session_keepalive(session *c)
{
    uint64_t now = ev_now(c->ctx->loop);
    uint64_t quiet = (uint64_t)c->view.welcome.idle_timeout_ms * 1000000u / SESSION_KEEPALIVE_FRACTION;
    if (now - c->last_send >= quiet && session_send_ping(c, now / 1000u) == 0)
        c->keepalive_stamp = now / 1000u;
}

int session_bye(session *c, uint8_t reason)
{
    if (c->ended || c->bye_sent)
        return 0;
    if (c->state == SESSION_CONNECTING || c->state == SESSION_UPGRADING) {
        session_close(c);
        return 0;
    }
    uint8_t buf[PROTO_SIZE_BYE];
    proto_writer w;
    proto_writer_init(&w, buf, sizeof buf);
    proto_put_bye(&w, reason);
    if (send_frame(c, buf, w.len) < 0) {
        session_close(c); /* cannot even say bye: nothing more to wait for */
        return 0;
    }
    c->bye_sent = 1;
    maybe_shutdown(c);
    return 1;
}

int session_timer_start(ev_loop *loop, uint64_t delay_ns, uint64_t period_ns, ev_timer_fn *fn, void *data)
{
    int id = ev_timer_start(loop, delay_ns, period_ns, fn, data);
    if (id < 0) {
        log_error("cannot start a timer: %s", strerror(-id));
        abort();
    }
    return id;
}

void session_timer_stop(ev_loop *loop, int *id)
{
    if (*id >= 0)
        ev_timer_stop(loop, *id);
    *id = -1;
}
