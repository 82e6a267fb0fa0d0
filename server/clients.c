/*
 * clients.c: one client's connection to the game protocol (clients.h),
 * on the network layer's conn (net/conn.h) with the game's limits: adding
 * and freeing it, frames written through a proto_writer over the output's
 * room and queued for the flush before the loop sleeps, the close and the
 * kill. It knows the protocol only to send an error frame; it calls no
 * other file of the server.
 */
#include "clients.h"

#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "log.h"
#include "srv_limits.h"

/* The game's limits on each connection: the linger is fixed (a client
 * has SRV_CLOSE_LINGER_MS to take its bye or error, however it reads). */
static const conn_config game_conn = {.out_hard = SRV_OUTBUF_HARD, .out_soft = SRV_OUTBUF_SOFT,
                                      .out_soft_ms = SRV_OUTBUF_SOFT_MS, .linger_ms = SRV_CLOSE_LINGER_MS,
                                      .linger_extends = 0, .sndbuf = SRV_SOCKET_SNDBUF};

int clients__add(server *s, int fd, const char *peer, const char *addr, ev_io_fn *io)
{
    client *c = cvre_xcalloc(1, sizeof *c);
    int rc = conn_open(&c->c, s->loop, fd, &game_conn, io, c);
    if (rc < 0) {
        conn_free(&c->c);
        free(c);
        return rc;
    }
    c->srv = s;
    snprintf(c->peer, sizeof c->peer, "%s", peer);
    snprintf(c->addr, sizeof c->addr, "%s", addr);
    c->connected_ns = c->last_frame_ns = server__now(s);
    c->index = s->nclients;
    s->clients[s->nclients++] = c;
    s->st.accepted++;
    log_debug("%s connected", c->peer);
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
int clients__out_begin(server *s, client *c, size_t need, proto_writer *w)
{
    if (c->dead)
        return -ENOTCONN;
    uint8_t *room;
    size_t len;
    int rc = conn_out_reserve(&c->c, need, &room, &len);
    if (rc < 0) {
        s->st.slow_readers++;
        clients__kill(s, c, "output backlog over the hard limit (%zu bytes pending)", conn_out_pending(&c->c));
        return rc;
    }
    proto_writer_init(w, room, len);
    return 0;
}

void clients__out_end(server *s, client *c, const proto_writer *w)
{
    conn_out_commit(&c->c, w->len);
    want_write(s, c);
}

void clients__begin_close(server *s, client *c, const char *reason)
{
    if (c->closing)
        return;
    c->closing = 1;
    snprintf(c->end_reason, sizeof c->end_reason, "%s", reason);
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
