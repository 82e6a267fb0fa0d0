/*
 * session.h: one client connection to a cvre server, shared by the scripted
 * client and the bot swarm.
 *
 * A session owns a non-blocking TCP socket registered with an ev loop, a bounded
 * input remainder and a bounded output backlog. Over a WebSocket (the
 * server's --web port; protocol/ws.h) it opens with the HTTP upgrade and
 * then carries each frame in a binary message of its own, both ways;
 * everything above the frames is the same. It runs the handshake itself
 * (hello on connect, join on welcome), answers pings, tracks what the server
 * said about the own avatar (session_view) and hands every decoded message to
 * the owner's on_msg callback. A connection ends exactly once: the end is
 * recorded, the socket leaves the loop at once, and on_close runs later from
 * the loop's before-sleep hook, never from inside a callback of the session, so
 * on_close is the one place where the owner may session_free() it.
 *
 * All conns of a process share a session_ctx: the resolved server address, one
 * read buffer and the totals the bot swarm reports.
 */
#ifndef CVRE_CLIENT_SESSION_H
#define CVRE_CLIENT_SESSION_H

#include <stddef.h>
#include <stdint.h>

#include "ev.h"
#include "proto.h"

/* A bot whose unsent output passes this many bytes is overloaded: further
 * moves are dropped instead of growing memory. 64 KiB is a few seconds of
 * moves at 20 Hz, so it is only reached when the server stops reading. */
#ifndef SESSION_OUT_MAX
#define SESSION_OUT_MAX (64u * 1024u)
#endif
_Static_assert(SESSION_OUT_MAX >= PROTO_SIZE_JOIN_MAX + PROTO_SIZE_HELLO, "the handshake fits the backlog");

/* The largest frame the client sends: an upload chunk with a full payload. */
#define SESSION_SIZE_CHUNK_MAX (PROTO_HEADER_SIZE + 8u + PROTO_CHUNK_MAX)
_Static_assert(SESSION_SIZE_CHUNK_MAX <= SESSION_OUT_MAX, "a whole chunk fits the backlog");

/* The server closes a connection that sent no frame for the idle timeout it
 * announces in the welcome; a joined connection with nothing else to send
 * pings after a quarter of it, leaving room for the caller's check interval
 * and a slow link. */
#define SESSION_KEEPALIVE_FRACTION 4u

typedef struct session_ctx session_ctx;
typedef struct session session;

/* Where to connect and who to be; given to both the scripted client and the
 * swarm (which appends "-<i>" to the name). */
typedef struct session_params {
    const char *host;
    uint16_t port;
    int ws; /* over a WebSocket: port is the server's --web port */
    const char *name;
    float box[3];
} session_params;

/* What a join proves: nothing (a guest), an account's password, or a
 * resume token from an earlier join_ok (enum proto_credential). */
typedef struct session_credential {
    uint8_t kind;
    uint8_t secret[PROTO_PASSWORD_MAX];
    uint32_t len;
} session_credential;

enum session_state {
    SESSION_CONNECTING, /* TCP connect in progress */
    SESSION_UPGRADING,  /* WebSocket: the upgrade sent, waiting for the 101 */
    SESSION_HELLO_SENT, /* waiting for welcome */
    SESSION_JOIN_SENT,  /* waiting for join_ok */
    SESSION_JOINED,
    SESSION_RAW,    /* connected without a handshake (benchmarking a bare server) */
    SESSION_CLOSED, /* ended; on_close has run or is pending */
};

/* How a connection ended. */
enum session_end_kind {
    SESSION_END_EOF,     /* the server closed cleanly between frames */
    SESSION_END_LOCAL,   /* session_close() */
    SESSION_END_CONNECT, /* could not connect; code is the errno */
    SESSION_END_SOCKET,  /* send/recv failed; code is the errno */
    SESSION_END_PROTO,   /* the server sent a bad frame; code is the proto status */
    SESSION_END_WEBSOCKET, /* the upgrade was refused or a WebSocket frame broke RFC 6455; why says which */
};

typedef struct session_end {
    int kind;      /* enum session_end_kind */
    int code;      /* errno or proto status, as kind says; 0 otherwise */
    int after_bye; /* we had sent bye: the end was asked for */
    int was_open;  /* the TCP connection had been established */
    const char *why; /* SESSION_END_WEBSOCKET: the reason; valid during on_close */
} session_end;

/* What the server told us about our own avatar. Updated before on_msg sees
 * the message that changed it. */
typedef struct session_view {
    proto_welcome welcome; /* valid once the welcome arrived */
    uint32_t avatar_id;    /* valid once joined */
    float pos[3];          /* authoritative own position: spawn, then own snapshot entries */
    float box[3];
    uint32_t ack;  /* ack_seq of the latest snapshot */
    int pos_fresh; /* the message being delivered carried our own entry */
} session_view;

typedef struct session_handler {
    /* Every decoded message, including welcome, join_ok and pings (already
     * answered). m and the strings in it are valid only during the call. The
     * callback may send, session_bye() or session_close(), but not session_free(). */
    void (*on_msg)(session *c, const proto_msg *m, void *data);
    /* The end, once, from the before-sleep hook. The session is SESSION_CLOSED and
     * may be freed here. */
    void (*on_close)(session *c, const session_end *end, void *data);
    /* Optional (NULL if never asked for): the answer to session_want_writable(),
     * once the backlog is empty and the socket takes more. Called from the
     * session's readiness callback; the same rules as for on_msg apply. */
    void (*on_writable)(session *c, void *data);
} session_handler;

/*
 * Resolves net's host and port (numeric IPv4 or IPv6, or a name such as
 * localhost), notes whether its sessions speak over a WebSocket, and takes
 * over the loop's before-sleep hook, where ended connections are reaped.
 * Returns NULL and a message in err on failure. The loop must outlive the
 * ctx.
 */
session_ctx *session_ctx_create(ev_loop *loop, const session_params *net, char *err, size_t errlen);
/* Frees the ctx; every session must have been freed first. */
void session_ctx_free(session_ctx *ctx);
/* Totals over all conns since the ctx was created. */
uint64_t session_ctx_opened(const session_ctx *ctx); /* TCP connections established */
uint64_t session_ctx_frames_in(const session_ctx *ctx);
uint64_t session_ctx_bytes_in(const session_ctx *ctx);
/* "host:port" as given, for messages. */
const char *session_ctx_peer(const session_ctx *ctx);

/*
 * Starts connecting. With a name, the session says hello once connected and
 * joins with name and box when welcomed; with name NULL it stays raw and
 * sends only what the owner asks. Failures, even immediate ones, are
 * reported through on_close, never here. handler must outlive the session.
 */
session *session_open(session_ctx *ctx, const char *name, const float box[3], const session_handler *handler,
                void *data);
/* Sets what the join will carry (copied; wiped once sent). Call right after
 * session_open: the join goes out when the server's welcome arrives. */
void session_set_credential(session *c, const session_credential *cred);
/* Closes the socket if still open and frees the session; on_close is not called
 * if it had not run yet. Not from inside the session's own on_msg. */
void session_free(session *c);

int session_state(const session *c);
const session_view *session_get_view(const session *c);

/*
 * Sends a move to pos with the next sequence number. Returns that number
 * (from 1 up), or 0 when nothing was sent: the session is not joined or raw,
 * or its backlog is full (overloaded), in which case the move is dropped and
 * the sequence number is not used.
 */
uint32_t session_send_move(session *c, const float pos[3]);
/*
 * From now on every move carries this facing (radians; pitch within
 * +-PROTO_PITCH_MAX, positive looks up) and, when head is set, a head at
 * SESSION_EYE_HEIGHT of the avatar's height, turned the same way: what a
 * client without a headset can say of where its avatar looks. Call it once
 * joined (the box sets the eye height).
 */
#define SESSION_EYE_HEIGHT 0.93f /* eyes of a standing adult: 1.67 m of 1.8 */
void session_set_facing(session *c, float yaw, float pitch, int head);
/* Sends a ping (legal only once joined); 0, or -ENOBUFS (backlog full) or
 * -ENOTCONN. */
int session_send_ping(session *c, uint64_t stamp);

/*
 * The object requests, legal only once joined. Each sends one whole frame
 * and returns 0, -ENOBUFS when the backlog has no room for it (nothing was
 * sent; try again once it drains) or -ENOTCONN (not joined, or the session
 * cannot send any more). Strings longer than their limit are cut by the
 * codec; values are the caller's to check (PROTOCOL.md gives the ranges).
 */
int session_send_upload_begin(session *c, const proto_upload_begin *m);
/* len is 1..PROTO_CHUNK_MAX; data is copied before the call returns. */
int session_send_upload_chunk(session *c, uint32_t upload_id, uint32_t offset, const uint8_t *data, uint32_t len);
int session_send_upload_end(session *c, const proto_upload_end *m);
int session_send_object_place(session *c, const proto_object_place *m);
int session_send_object_remove(session *c, uint32_t object_id);
int session_send_mesh_request(session *c, const proto_mesh_request *m);

/* Bytes queued in the session's backlog, not yet taken by the socket. A bulk
 * sender (an upload) sends only while this is 0, so that whatever else is
 * sent meanwhile (moves, pongs) waits behind at most one of its frames. */
size_t session_out_pending(const session *c);
/*
 * Asks for one on_writable call at the next loop iteration in which the
 * backlog is empty and the socket is writable: the way to send bulk data a
 * slice per wakeup without starving reads and timers. Returns 0, or
 * -ENOTCONN when the session cannot send any more (no call will come) or the
 * handler has no on_writable.
 */
int session_want_writable(session *c);
/* Pings with the current monotonic time in microseconds if the session is
 * joined and nothing was sent for a SESSION_KEEPALIVE_FRACTION of the server's
 * idle timeout; the pong is consumed
 * here, not passed to on_msg, since nobody asked for it. The caller's check
 * interval adds to the silence, so call it often (every 250 ms to 1 s). */
void session_keepalive(session *c);

/*
 * Says bye: queues it, and once the backlog is flushed shuts down our half
 * of the connection, so the server sees the end and closes; the session then
 * ends with after_bye set. The caller bounds the wait with session_close().
 * Returns 1 if this call sent the bye; 0 if it had been sent already, the
 * session had ended, or it could not be sent (still connecting, or the
 * backlog is full), in which case the session is closed instead.
 */
int session_bye(session *c, uint8_t reason);
/* Ends the connection now (SESSION_END_LOCAL); a no-op if it already ended. */
void session_close(session *c);

/* ev_timer_start for the client loop, where failing to get a timer (a small
 * allocation) is not recoverable: it logs and aborts. Returns the id. */
int session_timer_start(ev_loop *loop, uint64_t delay_ns, uint64_t period_ns, ev_timer_fn *fn, void *data);
/* Stops *id if it is running (>= 0) and sets it to -1. */
void session_timer_stop(ev_loop *loop, int *id);

#endif
