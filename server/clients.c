/*
 * clients.c: one client's connection to the game protocol (clients.h),
 * on the network layer's conn (net/conn.h) with the game's limits: adding
 * and freeing it, frames written through a proto_writer over the output's
 * room and queued for the flush before the loop sleeps, the close and the
 * kill; and the WebSocket transport under a browser's client (clients.h).
 * It knows the protocol only to send an error frame and to find the frames
 * in a WebSocket's messages; it calls no other file of the server.
 */
#include "clients.h"

#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "le.h"
#include "log.h"
#include "srv_limits.h"
#include "ws.h"

/* The game's limits on each connection: the linger is fixed (a client
 * has SRV_CLOSE_LINGER_MS to take its bye or error, however it reads). */
static const conn_config game_conn = {.out_hard = SRV_OUTBUF_HARD, .out_soft = SRV_OUTBUF_SOFT,
                                      .out_soft_ms = SRV_OUTBUF_SOFT_MS, .linger_ms = SRV_CLOSE_LINGER_MS,
                                      .linger_extends = 0, .sndbuf = SRV_SOCKET_SNDBUF};

static void want_write(server *s, client *c);

/* Appends bytes to c's output as they are (no frame, no message header). */
static int out_raw(server *s, client *c, const uint8_t *p, size_t n)
{
    uint8_t *room;
    size_t len;
    int rc = conn_out_reserve(&c->c, n, &room, &len);
    if (rc < 0)
        return rc;
    memcpy(room, p, n);
    conn_out_commit(&c->c, n);
    want_write(s, c);
    return 0;
}

int clients__add(server *s, int fd, const char *peer, const char *addr, ev_io_fn *io, const uint8_t *ws_first,
                 size_t ws_first_len)
{
    client *c = cvre_xcalloc(1, sizeof *c);
    int rc = conn_open(&c->c, s->loop, fd, &game_conn, io, c);
    if (rc == 0 && ws_first)
        rc = out_raw(s, c, ws_first, ws_first_len);
    if (rc < 0) {
        conn_free(&c->c);
        free(c);
        return rc;
    }
    if (ws_first) {
        c->ws = cvre_xmalloc(sizeof *c->ws);
        ws_reader_init(c->ws, SRV_INBUF_CAP);
    }
    c->srv = s;
    snprintf(c->peer, sizeof c->peer, "%s", peer);
    snprintf(c->addr, sizeof c->addr, "%s", addr);
    c->connected_ns = c->last_frame_ns = server__now(s);
    c->index = s->nclients;
    s->clients[s->nclients++] = c;
    s->st.accepted++;
    log_debug("%s connected%s", c->peer, c->ws ? " (WebSocket)" : "");
    return 0;
}

void clients__free(server *s, client *c)
{
    conn_free(&c->c);
    if (s->cfg.max_per_address)
        addrcount_add(s->per_address, c->addr, -1);
    s->clients[c->index] = s->clients[--s->nclients];
    s->clients[c->index]->index = c->index;
    s->st.closed++;
    if (c->ws) {
        ws_reader_free(c->ws);
        free(c->ws);
        free(c->ws_in);
    }
    free(c->known);
    free(c);
}

client *clients__by_session(server *s, int64_t session)
{
    for (uint32_t i = 0; i < s->nclients; i++)
        if (s->clients[i]->session_id == session && !s->clients[i]->dead)
            return s->clients[i];
    return NULL;
}

static void want_write(server *s, client *c)
{
    if (!c->in_write_list) {
        c->in_write_list = 1;
        s->write_list[s->nwrite++] = c;
    }
}

/* A client whose backlog would pass the hard limit is a slow reader: it is
 * disconnected rather than buffered without end. */
/* Room a WebSocket client's frames need for their message headers, at
 * most: a frame is at least PROTO_HEADER_SIZE bytes, and its header 2
 * bytes under 126, 4 under 64 KiB, 10 past: never over a third of the
 * frames' bytes. */
static size_t ws_slack(const client *c, size_t need) { return c->ws ? need / 3 + WS_SERVER_HEADER_MAX : 0; }
_Static_assert(PROTO_HEADER_SIZE >= 6, "a message header is at most a third of its frame");

int clients__out_begin(server *s, client *c, size_t need, proto_writer *w)
{
    if (c->dead)
        return -ENOTCONN;
    uint8_t *room;
    size_t len, slack = ws_slack(c, need);
    int rc = conn_out_reserve(&c->c, need + slack, &room, &len);
    if (rc < 0) {
        s->st.slow_readers++;
        clients__kill(s, c, "output backlog over the hard limit (%zu bytes pending)", conn_out_pending(&c->c));
        return rc;
    }
    /* A WebSocket's writer holds need bytes exactly, so that out_end
     * knows the slack from its cap. */
    proto_writer_init(w, room + slack, c->ws ? need : len);
    return 0;
}

/* The close code a frame sent to a WebSocket client asks for: a bye says
 * why the server ends it, an error frame that it broke the protocol. */
static uint16_t ws_close_for(const uint8_t *frame, size_t size)
{
    uint16_t type = le_get_u16(frame + 4);
    if (type == PROTO_ERROR)
        return WS_CLOSE_POLICY;
    if (type != PROTO_BYE || size <= PROTO_HEADER_SIZE)
        return 0;
    switch (frame[PROTO_HEADER_SIZE]) {
    case PROTO_BYE_SHUTDOWN: return WS_CLOSE_GOING_AWAY;
    case PROTO_BYE_KICKED: return WS_CLOSE_POLICY;
    default: return WS_CLOSE_NORMAL;
    }
}

/* Wraps each frame the writer holds (after the slack out_begin kept) in a
 * binary message header, moving the frames forward over the slack; returns
 * the bytes of the messages, from room's start. */
static size_t ws_wrap(client *c, uint8_t *room, size_t slack, size_t len)
{
    size_t put = 0;
    for (size_t at = 0; at + PROTO_HEADER_SIZE <= len;) {
        const uint8_t *frame = room + slack + at;
        size_t size = 4 + (size_t)le_get_u32(frame); /* the writer's own frames: whole */
        uint16_t code = ws_close_for(frame, size);
        if (code)
            c->ws_close = code;
        uint8_t head[WS_SERVER_HEADER_MAX];
        size_t h = ws_header(head, WS_OP_BINARY, size);
        memmove(room + put + h, frame, size); /* put + h <= slack + at: never past what is still to move */
        memcpy(room + put, head, h);
        put += h + size;
        at += size;
    }
    return put;
}

void clients__out_end(server *s, client *c, const proto_writer *w)
{
    size_t slack = ws_slack(c, w->cap);
    conn_out_commit(&c->c, c->ws ? ws_wrap(c, w->buf - slack, slack, w->len) : w->len);
    want_write(s, c);
}

void clients__begin_close(server *s, client *c, const char *reason)
{
    if (c->closing)
        return;
    c->closing = 1;
    snprintf(c->end_reason, sizeof c->end_reason, "%s", reason);
    if (c->ws) { /* the close frame, after what is queued */
        uint8_t frame[2 + WS_CONTROL_MAX];
        int n = ws_close_frame(frame, sizeof frame, c->ws_close ? c->ws_close : WS_CLOSE_NORMAL, reason);
        if (n > 0 && out_raw(s, c, frame, (size_t)n) < 0)
            log_debug("%s: no room for the close frame", c->peer);
    }
    conn_begin_close(&c->c);
    want_write(s, c);
}

void clients__kill(server *s, client *c, const char *fmt, ...)
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

void clients__protocol_error(server *s, client *c, int code, const char *fmt, ...)
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
    if (clients__out_begin(s, c, PROTO_SIZE_ERROR_MAX, &w) == 0) {
        proto_put_error(&w, (uint16_t)code, msg);
        clients__out_end(s, c, &w);
    }
    char reason[sizeof c->end_reason];
    snprintf(reason, sizeof reason, "error: %s", msg);
    clients__begin_close(s, c, reason);
}

void clients__input(client *c, uint8_t **in, size_t *len)
{
    *in = c->ws ? c->ws_in : c->c.in;
    *len = c->ws ? c->ws_in_len : c->c.in_len;
}

void clients__consume(client *c, size_t n)
{
    if (!c->ws) {
        conn_consume(&c->c, n);
        return;
    }
    if (n == 0)
        return;
    memmove(c->ws_in, c->ws_in + n, c->ws_in_len - n);
    c->ws_in_len -= n;
}

size_t clients__read_cap(const client *c, size_t cap) { return c->ws ? cap + WS_CLIENT_HEADER_MAX : cap; }

/* Appends a message, which must be exactly one frame of the protocol, to
 * the input handle_input reads. 0, or -EPROTO once c is closing. */
static int ws_message(server *s, client *c, const uint8_t *p, size_t n)
{
    if (n < 4 || (uint64_t)le_get_u32(p) + 4 != n) {
        clients__protocol_error(s, c, PROTO_ERR_TRUNCATED, "a WebSocket message of %zu bytes that is not one frame",
                                n);
        return -EPROTO;
    }
    if (c->ws_in_len + n > c->ws_in_cap) {
        size_t cap = c->ws_in_cap ? c->ws_in_cap : NET_INBUF_INITIAL;
        while (cap < c->ws_in_len + n)
            cap *= 2;
        c->ws_in = cvre_xrealloc(c->ws_in, cap);
        c->ws_in_cap = cap;
    }
    memcpy(c->ws_in + c->ws_in_len, p, n);
    c->ws_in_len += n;
    return 0;
}

void clients__unwrap(server *s, client *c)
{
    if (!c->ws)
        return;
    /* The frame cap in force, as for TCP (handlers.c): a message past it
     * is refused from its header (1009), before the socket's read cap. */
    c->ws->cap = c->state == ST_JOINED ? SRV_INBUF_CAP : SRV_INBUF_CAP_PREJOIN;
    size_t at = 0;
    while (!c->closing) {
        ws_event ev;
        char err[128];
        ssize_t n = ws_read(c->ws, c->c.in + at, c->c.in_len - at, &ev, err, sizeof err);
        if (n == 0)
            break;
        if (n < 0) {
            log_info("%s (session %lld): WebSocket: %s; closing", c->peer, (long long)c->session_id, err);
            s->st.protocol_errors++;
            c->ws_close = c->ws->close_code;
            char reason[sizeof c->end_reason];
            snprintf(reason, sizeof reason, "websocket: %s", err);
            clients__begin_close(s, c, reason);
            break;
        }
        at += (size_t)n;
        if (ev.type == WS_EV_MESSAGE && ws_message(s, c, ev.data, ev.len) < 0)
            break;
        if (ev.type == WS_EV_PING) {
            uint8_t pong[2 + WS_CONTROL_MAX];
            int len = ws_control(pong, sizeof pong, WS_OP_PONG, ev.data, ev.len);
            if (len > 0 && out_raw(s, c, pong, (size_t)len) < 0)
                clients__kill(s, c, "output backlog over the hard limit (a pong)");
        } else if (ev.type == WS_EV_CLOSE) {
            c->ws_close = ev.code;
            clients__begin_close(s, c, "closed by the client (WebSocket close)");
        }
    }
    conn_consume(&c->c, c->closing ? c->c.in_len : at);
}

/* Frames behind a join wait in the socket until the join is settled. */
void clients__watch(server *s, client *c)
{
    (void)s;
    conn_set_reading(&c->c, c->state != ST_AUTH);
}

/* Writes what c has pending (conn_flush: EV_WRITE stays armed only while
 * bytes remain, and a closing client's write side is shut once its output
 * is out, so that it reads the error before the close). */
void clients__flush(server *s, client *c)
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
}
