/*
 * conn.h: the network layer under every endpoint (the game protocol's in
 * server/clients.c, HTTP's in http_server.c, and the next ones), the way
 * Redis's connection.c sits under its protocols. It moves bytes and knows
 * no protocol; an endpoint brings its parser and decides what a limit
 * means. What it offers, per connection:
 *
 *  - accept: listener.h listens and accepts within a budget (pausing while
 *    the process is out of file descriptors) and hands each socket, with
 *    its peer's name (conn_peer_name), to the endpoint; conn_open puts the
 *    socket on the loop for reads with the endpoint's callback.
 *  - input: conn_read reads at most a per-wake-up budget into a buffer
 *    that starts small (NET_INBUF_INITIAL) and grows up to a cap the
 *    endpoint passes on each read (it may change with the protocol's
 *    state); the parser looks at in[0..in_len) and conn_consume drops what
 *    it has taken. conn_set_reading stops and resumes watching for input.
 *  - output: conn_out_reserve/conn_out_commit append bytes, never past the
 *    hard limit (-ENOBUFS: the endpoint decides, usually to drop the
 *    peer); conn_flush writes what the socket takes at once and arms
 *    EV_WRITE only while bytes remain; a buffer grown for a burst is given
 *    back once drained. Pending output past the soft limit starts a clock:
 *    conn_overdue says -ENOBUFS once it has run for out_soft_ms.
 *  - close: conn_begin_close starts the linger; the flush that empties the
 *    output then shuts the write side, so the peer reads everything before
 *    the close; conn_overdue says -ETIMEDOUT once the linger is over. The
 *    linger is fixed, or (linger_extends) given again by each write the
 *    peer takes, for a peer that reads a large answer slowly.
 *    conn_free closes the socket; the endpoint calls it at a safe point,
 *    never inside the connection's own callback.
 *
 * Everything runs on the loop's thread; times are the loop's (ev_now).
 * An endpoint keeps a conn inside its own per-connection record.
 */
#ifndef CVRE_CONN_H
#define CVRE_CONN_H

#include <stddef.h>
#include <stdint.h>
#include <sys/socket.h>
#include <sys/types.h>

#include "ev.h"
#include "net_limits.h"

/* An endpoint's choices for its connections, copied into each. */
typedef struct conn_config {
    size_t out_hard;      /* pending output never goes past this */
    size_t out_soft;      /* pending output past this after a flush starts the clock; 0: no soft limit */
    uint32_t out_soft_ms; /* how long output may stay past out_soft */
    uint32_t linger_ms;   /* after conn_begin_close: time to flush and see the peer close */
    int linger_extends;   /* a flush that writes something gives linger_ms again */
    int sndbuf;           /* kernel send buffer (SO_SNDBUF); 0: the kernel's autotuning */
} conn_config;

typedef struct conn {
    int fd;
    ev_loop *loop;
    conn_config cfg;
    uint8_t *in;
    size_t in_len, in_cap;
    uint8_t *out;
    size_t out_head, out_tail, out_cap; /* pending bytes are out[head..tail) */
    uint64_t soft_since_ns;   /* when pending output was first seen past out_soft; 0: below it */
    uint64_t linger_until_ns; /* after conn_begin_close */
    unsigned reading : 1;     /* EV_READ watched */
    unsigned writing : 1;     /* EV_WRITE armed: output is pending */
    unsigned closing : 1;     /* conn_begin_close was called */
    unsigned shut_wr : 1;     /* the output is out and the write side shut */
} conn;

/* Makes c a connection on the socket fd, watched on loop for reads with
 * fn(loop, fd, events, data), under the limits cfg. Takes ownership of fd:
 * conn_free closes it, also after a failure here (call it then too).
 * Returns 0, -ENOMEM, or ev_io_add's error (-EINVAL: fd is past the
 * loop's max_fd). */
int conn_open(conn *c, ev_loop *loop, int fd, const conn_config *cfg, ev_io_fn *fn, void *data);
/* Stops watching c's socket, closes it and frees its buffers. */
void conn_free(conn *c);

/* Reads at most budget bytes, growing the input buffer up to cap bytes in
 * all. Returns bytes read (> 0), 0 at end of stream, -EAGAIN when nothing is
 * there, -ENOBUFS when the buffer is full at cap (the caller's frame parser
 * must already have refused a frame that large), or another -errno. */
ssize_t conn_read(conn *c, size_t cap, size_t budget);
/* Drops the first n bytes of input (n <= in_len). */
void conn_consume(conn *c, size_t n);
/* Watches c for input (on) or stops (off: the bytes wait in the socket). */
void conn_set_reading(conn *c, int on);

/* Makes room for need more bytes of output and points *room at it (*len:
 * how much there is, >= need). Returns 0, -ENOBUFS if that would take the
 * pending output past cfg.out_hard, or -ENOMEM (nothing is changed then).
 * The room is valid until the next call on c's output. */
int conn_out_reserve(conn *c, size_t need, uint8_t **room, size_t *len);
/* Keeps the first n bytes written into the room (n <= its length). */
void conn_out_commit(conn *c, size_t n);
size_t conn_out_pending(const conn *c);

/* Writes as much pending output as the socket takes; arms EV_WRITE while
 * bytes remain, disarms it once none do; keeps the soft limit's clock; on
 * a closing connection, extends the linger if the config says so and
 * shuts the write side once all is out. Returns the bytes still pending
 * (0: all written), or -errno on a broken connection. */
ssize_t conn_flush(conn *c);

/* Starts the close: the linger deadline is cfg.linger_ms from now; the
 * flush that leaves nothing pending shuts the write side. Reading goes on
 * (the endpoint drops what comes). A second call does nothing. */
void conn_begin_close(conn *c);
/* What is overdue now: -ETIMEDOUT once a closing connection's linger is
 * over; -ENOBUFS once an open one's output has stayed past the soft limit
 * for longer than out_soft_ms; else 0. The endpoint decides what follows
 * (and logs it). */
int conn_overdue(const conn *c);

/* Listens on host:port (port 0: any free one) with a non-blocking,
 * close-on-exec socket; writes the bound address to address as
 * conn_peer_name does. Returns the socket, or -errno with a message in
 * err. Endpoints listen through listener.h, which calls this. */
int conn_listen(const char *host, uint16_t port, int backlog, char *address, size_t addrlen, char *err,
                size_t errlen);
/* Accepts a connection waiting on listen_fd, non-blocking and
 * close-on-exec, and names its peer as conn_peer_name does. Returns the
 * socket, or -EAGAIN when none is waiting (also after EINTR or a
 * connection aborted before it was taken), or another -errno (-EMFILE:
 * out of file descriptors). */
int conn_accept(int listen_fd, char *peer, size_t peerlen);
/* "HOST:PORT" of a socket address, numeric, IPv6 in brackets; "?" if it
 * cannot be named. */
void conn_peer_name(const struct sockaddr_storage *sa, socklen_t len, char *out, size_t outlen);

#endif
