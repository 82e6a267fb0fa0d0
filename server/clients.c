/*
 * clients.c: one client's connection to the game protocol (clients.h):
 * adding and freeing it, output reserved under the hard limit and queued
 * for the write before the loop sleeps, the flush that arms EV_WRITE only
 * while bytes remain, the close with its linger and the kill. It knows the
 * protocol only to send an error frame; it calls no other file of the
 * server.
 */
#include "clients.h"

#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>

#include "alloc.h"
#include "log.h"
#include "srv_limits.h"

int clients__add(server *s, int fd, const char *peer, const char *addr, ev_io_fn *io)
{
    client *c = cvre_xcalloc(1, sizeof *c);
    int rc = conn_init(&c->c, fd);
    if (rc == 0)
        rc = ev_io_add(s->loop, fd, EV_READ, io, c);
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
    int rc = conn_out_begin(&c->c, need, w);
    if (rc < 0) {
        s->st.slow_readers++;
        clients__kill(s, c, "output backlog over the hard limit (%zu bytes pending)", conn_out_pending(&c->c));
    }
    return rc;
}

void clients__out_end(server *s, client *c, const proto_writer *w)
{
    conn_out_end(&c->c, w);
    want_write(s, c);
}

void clients__begin_close(server *s, client *c, const char *reason)
{
    if (c->closing)
        return;
    c->closing = 1;
    snprintf(c->end_reason, sizeof c->end_reason, "%s", reason);
    c->close_deadline_ns = server__now(s) + SRV_CLOSE_LINGER_MS * NS_PER_MS;
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
    ev_io_mod(s->loop, c->c.fd, (c->state == ST_AUTH ? 0u : (unsigned)EV_READ) | (c->writing ? (unsigned)EV_WRITE : 0u));
}

static void set_writing(server *s, client *c, int on)
{
    if (c->writing == on)
        return;
    c->writing = on;
    clients__watch(s, c);
}

/* Writes what c has pending. Arms EV_WRITE only when bytes remain; once a
 * closing client's output is out, shuts down the write side so the peer
 * reads the error before the close. */
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
