/*
 * clients.h: one client's connection to the game protocol, below the
 * protocol's meaning, on net/conn.h with the game's limits: frames written
 * under the hard limit and queued for the next write, the close with its
 * linger, the kill, and the client table.
 * Every other file of the server writes to a client through here; this one
 * calls no other file of the server (serverInt.h has the map).
 *
 * The transport is here too: a client is a TCP socket carrying the
 * protocol's frames as they are, or a WebSocket (--web) whose binary
 * messages carry one frame each. For a WebSocket client the frames out are
 * wrapped in a message header each (clients__out_end), the messages in are
 * unwrapped (clients__unwrap) into the bytes handle_input reads
 * (clients__input), pings are answered, and the close is a close frame
 * whose code says why: 1000 for a quit, 1001 for a shutdown, 1008 for a
 * kick or a protocol error, the peer's own code echoed.
 */
#ifndef CVRE_CLIENTS_H
#define CVRE_CLIENTS_H

#include <stddef.h>
#include <stdint.h>

#include "serverInt.h"

/* Makes c a client of s on the socket fd (which it takes over: closed on
 * failure too), watched for reads through io with c as its data. peer and
 * addr name it (addr: the key of the per-address limits, already counted by
 * the caller; clients__free takes it off). ws_first: NULL for a TCP client;
 * for a WebSocket, the handshake's answer, sent first. Returns 0, or -errno
 * when the connection cannot be registered. */
int clients__add(server *s, int fd, const char *peer, const char *addr, ev_io_fn *io, const uint8_t *ws_first,
                 size_t ws_first_len);
/* Closes c's socket, takes it out of the table (the last client moves into
 * its index) and frees it. What c held elsewhere (avatar, upload, session)
 * is the caller's to release first. */
void clients__free(server *s, client *c);
/* The connected client of this session, or NULL (it may have left). */
client *clients__by_session(server *s, int64_t session);

/* Reserves need bytes of c's output and points w at them. Returns 0;
 * -ENOTCONN if c is being dropped already; or the conn_out_reserve error
 * (-ENOBUFS: past SRV_OUTBUF_HARD), after which c is disconnected as a slow
 * reader. Nothing may be put in w then. */
int clients__out_begin(server *s, client *c, size_t need, proto_writer *w);
/* Keeps what w holds and queues c for the write before the loop sleeps. */
void clients__out_end(server *s, client *c, const proto_writer *w);

/* Stops reading from c; its output is flushed and the socket closed within
 * SRV_CLOSE_LINGER_MS. reason is kept for the session record. */
void clients__begin_close(server *s, client *c, const char *reason);
/* Drops c at the next safe point without flushing, logging why. */
void clients__kill(server *s, client *c, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
/* Sends an error frame naming the problem (code: PROTO_ERR_*) and closes
 * the connection; counted in the figures as a timeout or a protocol error. */
void clients__protocol_error(server *s, client *c, int code, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));

/* The protocol bytes read from c and not yet consumed: the socket's own
 * (TCP), or those of the messages unwrapped (WebSocket). */
void clients__input(client *c, uint8_t **in, size_t *len);
/* Drops the first n of them. */
void clients__consume(client *c, size_t n);
/* For a WebSocket client, takes the frames read from the socket: binary
 * messages become input (each must be one whole frame of the protocol),
 * pings are answered, a close is answered and begins the close; a frame
 * that breaks RFC 6455 closes c with the code it earns. No-op for a TCP
 * client. */
void clients__unwrap(server *s, client *c);
/* The read cap of c's socket for a protocol frame cap of cap bytes: the
 * same for TCP, room for a message header more for a WebSocket. */
size_t clients__read_cap(const client *c, size_t cap);

/* Sets what the loop watches c's socket for from its state: reads, except
 * while its join is checked, and writes while output is pending. */
void clients__watch(server *s, client *c);
/* Writes what c has pending (see clients.c). */
void clients__flush(server *s, client *c);

#endif
