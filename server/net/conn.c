#define _GNU_SOURCE /* accept4 */
#include "conn.h"

#include <errno.h>
#include <netdb.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "alloc.h"
#include "err.h"

#define NS_PER_MS ((uint64_t)1000000)

int conn_open(conn *c, ev_loop *loop, int fd, const conn_config *cfg, ev_io_fn *fn, void *data)
{
    memset(c, 0, sizeof *c);
    c->fd = fd; /* even on failure: conn_free closes it */
    c->loop = loop;
    c->cfg = *cfg;
    c->in = cvre_malloc(NET_INBUF_INITIAL);
    if (!c->in)
        return -ENOMEM;
    c->in_cap = NET_INBUF_INITIAL;
    int rc = ev_io_add(loop, fd, EV_READ, fn, data);
    if (rc < 0)
        return rc;
    c->reading = 1;
    if (cfg->sndbuf > 0)
        setsockopt(fd, SOL_SOCKET, SO_SNDBUF, &cfg->sndbuf, sizeof cfg->sndbuf);
    return 0;
}

void conn_free(conn *c)
{
    if (c->fd >= 0) {
        if (c->loop)
            ev_io_del(c->loop, c->fd); /* -EINVAL if conn_open could not watch it */
        close(c->fd);
    }
    free(c->in);
    free(c->out);
    memset(c, 0, sizeof *c);
    c->fd = -1;
}

static void watch(conn *c)
{
    ev_io_mod(c->loop, c->fd, (c->reading ? (unsigned)EV_READ : 0u) | (c->writing ? (unsigned)EV_WRITE : 0u));
}

void conn_set_reading(conn *c, int on)
{
    c->reading = on != 0;
    watch(c);
}

ssize_t conn_read(conn *c, size_t cap, size_t budget)
{
    if (c->in_len == c->in_cap) {
        if (c->in_cap >= cap)
            return -ENOBUFS;
        size_t ncap = c->in_cap * 2 < cap ? c->in_cap * 2 : cap;
        uint8_t *in = cvre_realloc(c->in, ncap);
        if (!in)
            return -ENOMEM;
        c->in = in;
        c->in_cap = ncap;
    }
    size_t room = c->in_cap - c->in_len;
    ssize_t n = read(c->fd, c->in + c->in_len, room < budget ? room : budget);
    if (n < 0)
        return errno == EINTR ? -EAGAIN : -errno;
    c->in_len += (size_t)n;
    return n;
}

void conn_consume(conn *c, size_t n)
{
    memmove(c->in, c->in + n, c->in_len - n);
    c->in_len -= n;
}

size_t conn_out_pending(const conn *c) { return c->out_tail - c->out_head; }

int conn_out_reserve(conn *c, size_t need, uint8_t **room, size_t *len)
{
    size_t pending = conn_out_pending(c);
    if (pending + need > c->cfg.out_hard)
        return -ENOBUFS;
    if (c->out_cap - c->out_tail < need) {
        if (c->out_head) { /* slide pending bytes to the front first */
            memmove(c->out, c->out + c->out_head, pending);
            c->out_head = 0;
            c->out_tail = pending;
        }
        if (c->out_cap - c->out_tail < need) {
            size_t ncap = c->out_cap ? c->out_cap : NET_OUTBUF_INITIAL;
            while (ncap < pending + need)
                ncap *= 2;
            if (ncap > c->cfg.out_hard)
                ncap = c->cfg.out_hard;
            uint8_t *out = cvre_realloc(c->out, ncap);
            if (!out)
                return -ENOMEM;
            c->out = out;
            c->out_cap = ncap;
        }
    }
    *room = c->out + c->out_tail;
    *len = c->out_cap - c->out_tail;
    return 0;
}

void conn_out_commit(conn *c, size_t n) { c->out_tail += n; }

ssize_t conn_flush(conn *c)
{
    size_t before = conn_out_pending(c);
    while (c->out_head < c->out_tail) {
        ssize_t n = write(c->fd, c->out + c->out_head, c->out_tail - c->out_head);
        if (n < 0) {
            if (errno == EINTR)
                continue;
            if (errno == EAGAIN)
                break;
            return -errno;
        }
        c->out_head += (size_t)n;
    }
    size_t left = conn_out_pending(c);
    if (left == 0) {
        c->out_head = c->out_tail = 0;
        if (c->out_cap > NET_OUTBUF_KEEP) { /* a burst is over */
            free(c->out);
            c->out = NULL;
            c->out_cap = 0;
        }
    }
    uint64_t now = ev_now(c->loop);
    if (c->writing != (left > 0)) {
        c->writing = left > 0;
        watch(c);
    }
    if (c->cfg.out_soft && left > c->cfg.out_soft) {
        if (!c->soft_since_ns)
            c->soft_since_ns = now;
    } else {
        c->soft_since_ns = 0;
    }
    if (c->closing) {
        if (c->cfg.linger_extends && left < before) /* it takes its answer, if slowly */
            c->linger_until_ns = now + c->cfg.linger_ms * NS_PER_MS;
        if (left == 0 && !c->shut_wr) { /* the peer reads all of it before the close */
            shutdown(c->fd, SHUT_WR);
            c->shut_wr = 1;
        }
    }
    return (ssize_t)left;
}

void conn_begin_close(conn *c)
{
    if (c->closing)
        return;
    c->closing = 1;
    c->linger_until_ns = ev_now(c->loop) + c->cfg.linger_ms * NS_PER_MS;
}

int conn_overdue(const conn *c)
{
    uint64_t now = ev_now(c->loop);
    if (c->closing)
        return now > c->linger_until_ns ? -ETIMEDOUT : 0;
    if (c->soft_since_ns && now - c->soft_since_ns > c->cfg.out_soft_ms * NS_PER_MS)
        return -ENOBUFS;
    return 0;
}

void conn_peer_name(const struct sockaddr_storage *sa, socklen_t len, char *out, size_t outlen)
{
    char host[64], port[8]; /* numeric: an IPv6 address with scope fits */
    if (getnameinfo((const struct sockaddr *)sa, len, host, sizeof host, port, sizeof port,
                    NI_NUMERICHOST | NI_NUMERICSERV) != 0)
        snprintf(out, outlen, "?");
    else if (sa->ss_family == AF_INET6)
        snprintf(out, outlen, "[%s]:%s", host, port);
    else
        snprintf(out, outlen, "%s:%s", host, port);
}

int conn_accept(int listen_fd, char *peer, size_t peerlen)
{
    struct sockaddr_storage sa;
    socklen_t len = sizeof sa;
    int fd = accept4(listen_fd, (struct sockaddr *)&sa, &len, SOCK_NONBLOCK | SOCK_CLOEXEC);
    if (fd < 0)
        return errno == EINTR || errno == ECONNABORTED ? -EAGAIN : -errno;
    conn_peer_name(&sa, len, peer, peerlen);
    return fd;
}

int conn_listen(const char *host, uint16_t port, int backlog, char *address, size_t addrlen, char *err,
                size_t errlen)
{
    struct addrinfo hints = {.ai_family = AF_UNSPEC, .ai_socktype = SOCK_STREAM,
                             .ai_flags = AI_PASSIVE | AI_NUMERICSERV},
                    *res = NULL;
    char service[8];
    snprintf(service, sizeof service, "%u", port);
    int rc = getaddrinfo(host, service, &hints, &res);
    if (rc != 0)
        return cvre_fail(err, errlen, rc == EAI_SYSTEM ? -errno : rc == EAI_MEMORY ? -ENOMEM : -EADDRNOTAVAIL,
                         "cannot resolve %s: %s", host, gai_strerror(rc));
    int fd = -1, saved = EADDRNOTAVAIL; /* if no address came back */
    for (struct addrinfo *ai = res; ai; ai = ai->ai_next) {
        fd = socket(ai->ai_family, ai->ai_socktype | SOCK_NONBLOCK | SOCK_CLOEXEC, ai->ai_protocol);
        if (fd < 0) {
            saved = errno;
            continue;
        }
        int one = 1;
        setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
        if (bind(fd, ai->ai_addr, ai->ai_addrlen) == 0 && listen(fd, backlog) == 0)
            break;
        saved = errno;
        close(fd);
        fd = -1;
    }
    freeaddrinfo(res);
    if (fd < 0)
        return cvre_fail(err, errlen, -saved, "cannot listen on %s:%u: %s", host, port, strerror(saved));
    struct sockaddr_storage sa;
    socklen_t len = sizeof sa;
    getsockname(fd, (struct sockaddr *)&sa, &len);
    conn_peer_name(&sa, len, address, addrlen);
    return fd;
}
