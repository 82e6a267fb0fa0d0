/*
 * clients.h: one client's connection to the game protocol, below the
 * protocol's meaning, on net/conn.h with the game's limits: frames written
 * under the hard limit and queued for the next write, the close with its
 * linger, the kill, and the client table.
 * Every other file of the server writes to a client through here; this one
 * calls no other file of the server (serverInt.h has the map).
 */
#ifndef CVRE_CLIENTS_H
#define CVRE_CLIENTS_H

#include <stddef.h>
#include <stdint.h>

#include "serverInt.h"

/* Makes c a client of s on the socket fd (which it takes over: closed on
 * failure too), watched for reads through io with c as its data. peer and
 * addr name it (addr: the key of the per-address limits, already counted by
 * the caller; clients__free takes it off). Returns 0, or -errno when the
 * connection cannot be registered. */
int clients__add(server *s, int fd, const char *peer, const char *addr, ev_io_fn *io);
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

/* Sets what the loop watches c's socket for from its state: reads, except
 * while its join is checked, and writes while output is pending. */
void clients__watch(server *s, client *c);
/* Writes what c has pending (see clients.c). */
void clients__flush(server *s, client *c);

#endif
