/*
 * ws.h: the WebSocket protocol (RFC 6455) as bytes, with no socket, from
 * both sides: the server's web endpoint (server/web_endpoint.c) and
 * cvre-client --ws (client/session.c). The opening handshake's checks and
 * its Sec-WebSocket-Accept (SHA-1 and base64 from OpenSSL's libcrypto),
 * frames read from a buffer the caller filled, and frames written into
 * one. The caller reads, writes and decides what a message means; this
 * file decides what is a valid frame and which close code a refusal earns.
 *
 * Only what a peer of binary messages needs: a client's frames are masked
 * and a server's are not (5.1, 5.3), RSV1-3 are 0 (no extension is ever
 * agreed), text messages are refused with 1003 (binary only), a data
 * message may come in fragments and is put together up to a cap the
 * caller gives (checked against each frame's header, before its payload
 * is waited for or anything is allocated), control frames carry at most
 * 125 bytes and are never fragmented (5.5), and a close frame's code and
 * reason are checked (7.4, 5.5.1). Frames written are never fragmented; a
 * client's are masked with a fresh key from libcrypto's random source.
 */
#ifndef CVRE_WS_H
#define CVRE_WS_H

#include <stddef.h>
#include <stdint.h>
#include <sys/types.h>

/* Opcodes (5.2). */
enum {
    WS_OP_CONTINUATION = 0x0,
    WS_OP_TEXT = 0x1,
    WS_OP_BINARY = 0x2,
    WS_OP_CLOSE = 0x8,
    WS_OP_PING = 0x9,
    WS_OP_PONG = 0xA,
};

/* Close codes this server sends (7.4.1). */
enum {
    WS_CLOSE_NORMAL = 1000,
    WS_CLOSE_GOING_AWAY = 1001,
    WS_CLOSE_PROTOCOL = 1002,  /* a frame broke RFC 6455 */
    WS_CLOSE_UNSUPPORTED = 1003, /* a text message: binary only here */
    WS_CLOSE_BAD_DATA = 1007,  /* a close reason that is not UTF-8 */
    WS_CLOSE_POLICY = 1008,    /* the game's kick */
    WS_CLOSE_TOO_BIG = 1009,   /* a message past the cap */
    WS_CLOSE_INTERNAL = 1011,  /* out of memory */
    WS_CLOSE_TRY_AGAIN = 1013, /* the server is full (IANA's registry) */
};

/* A control frame's payload, at most (5.5). */
#define WS_CONTROL_MAX 125u
/* The longest client frame header: 2 bytes, a 64-bit length, the mask. */
#define WS_CLIENT_HEADER_MAX 14u
/* The longest server frame header: 2 bytes and a 64-bit length. */
#define WS_SERVER_HEADER_MAX 10u
/* Sec-WebSocket-Accept: base64 of a 20-byte SHA-1, and its NUL. */
#define WS_ACCEPT_SIZE 29u
/* Sec-WebSocket-Key: base64 of 16 bytes, and its NUL. */
#define WS_KEY_SIZE 25u
/* The longest response head a client waits for: the server's 101 is under
 * 200 bytes; a refusal's head (426, 503) is short too. */
#define WS_RESPONSE_MAX 2048u

/* ---- the opening handshake (4.2.1) --------------------------------------- */

/* What a client's upgrade request said: the method, HTTP/1.minor, and the
 * values of its headers (NULL where a header is missing). */
typedef struct ws_upgrade {
    const char *method;
    int http_minor;
    const char *upgrade, *connection, *version, *key;
} ws_upgrade;

/* Checks an upgrade request: GET, HTTP/1.1 or later, an Upgrade header
 * naming websocket and a Connection header naming Upgrade (each a list of
 * tokens, any case), Sec-WebSocket-Version 13, and a Sec-WebSocket-Key
 * that is the base64 of 16 bytes. On success writes Sec-WebSocket-Accept
 * to accept and returns 0. Else returns -EPROTONOSUPPORT for a version
 * other than 13 (the answer is 426 with "Sec-WebSocket-Version: 13"),
 * -EINVAL for anything else (400), or -EIO if libcrypto failed; a reason
 * goes to err. */
int ws_handshake(const ws_upgrade *u, char accept[WS_ACCEPT_SIZE], char *err, size_t errlen);

/* True if the comma-separated list (a header's value: Connection, Upgrade,
 * or a list of the server's own such as --web-origin) holds token, in any
 * case, blanks around the items allowed. */
int ws_list_has(const char *list, const char *token);

/* True if an Upgrade header's value names websocket: the request asks for
 * one (and ws_handshake decides). Another upgrade (h2c) may be ignored
 * and the request served as plain HTTP. NULL: false. */
int ws_asks_upgrade(const char *upgrade);

/* Sec-WebSocket-Accept for a key, as sent (4.2.2): base64(SHA-1(key +
 * the RFC's GUID)). Returns 0, or -EIO if libcrypto failed. */
int ws_accept_key(const char *key, size_t len, char accept[WS_ACCEPT_SIZE]);

/* ---- reading frames -------------------------------------------------------- */

/* What one call of ws_read took in. */
typedef enum {
    WS_EV_NONE,    /* a fragment of a message still under way */
    WS_EV_MESSAGE, /* a whole binary message */
    WS_EV_PING,
    WS_EV_PONG,
    WS_EV_CLOSE, /* the client closes; code 0 when it sent none */
} ws_event_type;

typedef struct ws_event {
    ws_event_type type;
    const uint8_t *data; /* the payload (a message, a ping's, a close's reason) */
    size_t len;
    uint16_t code; /* of a close */
} ws_event;

/* One connection's reading state. */
typedef struct ws_reader {
    size_t cap;      /* a message's largest size */
    int of_server;   /* reads a server's frames (unmasked), on a client */
    int fragmented;  /* a message's first fragment came, its last not yet */
    uint8_t *msg;    /* the fragments so far (cvre_malloc'd, grown to fit) */
    size_t msg_len, msg_alloc;
    uint16_t close_code; /* what the last refusal earns */
} ws_reader;

/* A reader of a client's messages (on the server) of at most cap bytes.
 * Nothing is allocated until a fragmented message comes. */
void ws_reader_init(ws_reader *r, size_t cap);
/* The same for a client reading a server's messages: frames must not be
 * masked, and a close may also carry IANA's 1012-1014 (1013: the server
 * is full). */
void ws_reader_init_client(ws_reader *r, size_t cap);
void ws_reader_free(ws_reader *r);

/* Takes the first frame in data[0..len), unmasking a client's payload in
 * place.
 * Returns the bytes it took (> 0) with *ev saying what they completed, 0
 * if the frame is not all there yet, or a refusal with r->close_code set
 * and a reason in err:
 *   -EPROTO       a frame that breaks RFC 6455: a client's unmasked or a
 *                 server's masked, RSV bits, an
 *                 unknown opcode, a 64-bit length with its top bit set or
 *                 not in its shortest form, a control frame fragmented or
 *                 over 125 bytes, a continuation with no message under
 *                 way or a new message inside one, a close payload of one
 *                 byte or a code that is not sent on the wire (1002);
 *   -EILSEQ       a close reason that is not UTF-8 (1007);
 *   -EOPNOTSUPP   a text message (1003);
 *   -EMSGSIZE     a message past the cap (1009), known from its header;
 *   -ENOMEM       no memory for the fragments (1011).
 * ev->data points into data (a single-frame message, a control frame) or
 * into r (fragments put together); it is valid until the caller's buffer
 * changes or the next call. After a refusal the reader is spent: the
 * caller closes with r->close_code. */
ssize_t ws_read(ws_reader *r, uint8_t *data, size_t len, ws_event *ev, char *err, size_t errlen);

/* True for a close code a peer may send (7.4): 1000-1003, 1007-1011,
 * 3000-4999. */
int ws_close_code_valid(unsigned code);

/* Bytes the frame whose start is in data[0..len) needs before it can be
 * read whole: while its header is not all there, the header's length as
 * far as it is known (2, then 4 or 10); then all of it, header, mask and
 * payload. More than len while the frame is not all there. Call it after
 * ws_read returned 0: what the header says is then known to be valid and
 * within the cap, so that the caller may wait for exactly the rest. */
size_t ws_frame_need(const uint8_t *data, size_t len);

/* ---- the server's frames ----------------------------------------------------- */

/* Writes the header of an unfragmented, unmasked frame of opcode with a
 * payload of len bytes; returns its length (2, 4 or 10). */
size_t ws_header(uint8_t out[WS_SERVER_HEADER_MAX], unsigned opcode, uint64_t len);

/* Writes a whole control frame: a pong echoing payload[0..len), len <=
 * WS_CONTROL_MAX. Returns its length, or -EINVAL if len is too long or
 * -ENOSPC if out[0..cap) is short. */
int ws_control(uint8_t *out, size_t cap, unsigned opcode, const uint8_t *payload, size_t len);

/* Writes a close frame with code and reason (cut to fit the 125 bytes,
 * at a character boundary); code 0 sends none. Returns its length or
 * -ENOSPC. */
int ws_close_frame(uint8_t *out, size_t cap, uint16_t code, const char *reason);

/* ---- the client's side ------------------------------------------------------ */

/* Writes the opening handshake's request for path on host ("host:port",
 * the Host header) with a fresh key from libcrypto's random source, which
 * goes to key for ws_client_response. Returns its length, -ENOSPC if
 * out[0..cap) is short, or -EIO if libcrypto had no random bytes. */
int ws_client_request(char *out, size_t cap, const char *host, const char *path, char key[WS_KEY_SIZE]);

/* Reads the server's answer to the request that sent key, from the start
 * of data[0..len). Returns the length of its head (the blank line
 * included: what follows is frames) once it is all there and says 101
 * with "Upgrade: websocket", "Connection: Upgrade" and the accept of key,
 * and no extension or subprotocol (none was asked for); 0 while the head
 * is not all there; or -EPROTO with a reason (the status line of a
 * refusal, the header that is missing or wrong), -EMSGSIZE for a head of
 * WS_RESPONSE_MAX bytes or more. */
int ws_client_response(const uint8_t *data, size_t len, const char *key, char *err, size_t errlen);

/* Writes a whole client frame of opcode (unfragmented): the header, a
 * fresh mask from libcrypto's random source and payload[0..len) masked.
 * Returns its length, -EINVAL for a control frame over WS_CONTROL_MAX,
 * -ENOSPC if out[0..cap) is short, or -EIO if libcrypto had no random
 * bytes. */
int ws_client_frame(uint8_t *out, size_t cap, unsigned opcode, const uint8_t *payload, size_t len);

/* A client's close frame with code and reason, as ws_close_frame. Returns
 * its length, -ENOSPC or -EIO. */
int ws_client_close_frame(uint8_t *out, size_t cap, uint16_t code, const char *reason);

#endif
