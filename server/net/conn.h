/*
 * conn.h: one client socket's buffers and I/O, without protocol knowledge.
 *
 * The input buffer grows on demand up to a cap the caller passes on each
 * read (smaller before join); the output buffer grows up to SRV_OUTBUF_HARD.
 * Output is appended through a proto_writer over the buffer's free space:
 * conn_out_begin reserves room, the caller puts frames, conn_out_end keeps
 * what was written.
 */
#ifndef CVRE_CONN_H
#define CVRE_CONN_H

#include <stddef.h>
#include <stdint.h>
#include <sys/socket.h>
#include <sys/types.h>

#include "proto.h"

typedef struct conn {
    int fd;
    uint8_t *in;
    size_t in_len, in_cap;
    uint8_t *out;
    size_t out_head, out_tail, out_cap; /* pending bytes are out[head..tail) */
} conn;

/* Takes ownership of fd (closed by conn_free, also after a failure here).
 * Returns 0 or -ENOMEM. */
int conn_init(conn *c, int fd);
void conn_free(conn *c);

/* Reads at most budget bytes, growing the input buffer up to cap bytes in
 * all. Returns bytes read (> 0), 0 at end of stream, -EAGAIN when nothing is
 * there, -ENOBUFS when the buffer is full at cap (the caller's frame parser
 * must already have refused a frame that large), or another -errno. */
ssize_t conn_read(conn *c, size_t cap, size_t budget);
/* Drops the first n bytes of input (n <= in_len). */
void conn_consume(conn *c, size_t n);

/* Makes room for need more bytes of output and points w at the free space.
 * Returns 0, or -ENOBUFS if that would take the buffer past the hard limit
 * (nothing is changed then). */
int conn_out_begin(conn *c, size_t need, proto_writer *w);
/* Keeps the whole frames w holds. */
void conn_out_end(conn *c, const proto_writer *w);
size_t conn_out_pending(const conn *c);

/* Writes as much pending output as the socket takes. Returns the bytes still
 * pending (0: all written), or -errno on a broken connection. */
ssize_t conn_flush(conn *c);

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
