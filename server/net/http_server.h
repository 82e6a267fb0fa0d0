/*
 * http_server.h: a small HTTP/1.1 endpoint on the server's event loop, on
 * raw sockets: it accepts, reads one request head per connection within
 * a deadline (http.h parses it), hands a complete request to its handler,
 * writes the response with Connection: close (a file's body streamed from
 * its descriptor), and closes; or hands the socket over to a handler that
 * takes it (an upgrade to a WebSocket). Bad requests get
 * their 4xx from http.h's checks, a request that does not arrive in time
 * 408, a connection past the cap 503; none of it reaches the handler.
 *
 * Everything runs on the loop's thread, from the loop's callbacks; a
 * connection is never freed inside its own callback (a zero-delay timer
 * reaps it).
 */
#ifndef CVRE_HTTP_SERVER_H
#define CVRE_HTTP_SERVER_H

#include <stddef.h>
#include <stdint.h>

#include "ev.h"
#include "http.h"

/* Connections served at once, by default. A scraper holds one; a few
 * more cover overlapping scrapes and a person with curl. Past the cap a
 * connection gets 503 and is closed, so the endpoint's memory (an input
 * buffer and a request head each) stays bounded however many connect. */
#ifndef HTTP_CONNS_DEFAULT
#define HTTP_CONNS_DEFAULT 16u
#endif
/* The whole request head must arrive within this: a slowloris holds a
 * slot for 5 s at most, and gets 408. */
#ifndef HTTP_REQUEST_TIMEOUT_MS
#define HTTP_REQUEST_TIMEOUT_MS 5000u
#endif
/* After the response: time to take the next of it, and at the end to
 * close. A peer that neither reads nor closes for this long is cut off. */
#ifndef HTTP_LINGER_MS
#define HTTP_LINGER_MS 5000u
#endif
/* Largest response body: the metrics text is about 10 KiB. A handler's
 * larger body gets 500 instead. */
#ifndef HTTP_BODY_MAX
#define HTTP_BODY_MAX (1024u * 1024u)
#endif

/* A file body is read into the output this much at a time, topped up as
 * the socket takes it: a 1.2 MB script costs 64 KiB of buffer, not 1.2 MB. */
#ifndef HTTP_FILE_CHUNK
#define HTTP_FILE_CHUNK (64u * 1024u)
#endif

_Static_assert(HTTP_CONNS_DEFAULT >= 1, "at least one connection");
_Static_assert(HTTP_FILE_CHUNK <= HTTP_BODY_MAX, "a file's chunk fits the output");
_Static_assert(HTTP_REQUEST_TIMEOUT_MS >= 100 && HTTP_LINGER_MS >= 100, "deadlines a real client can meet");

/* Takes a connection over (an upgrade): the socket fd (non-blocking,
 * close-on-exec) is the callee's from the call on, to keep or close; first
 * is what it must send before anything else (the reply's body, for
 * instance the 101 response), valid during the call only. Bytes the peer
 * sent after the request head are not passed on: a WebSocket client waits
 * for the 101 before it sends (RFC 6455 4.1). */
typedef void http_takeover_fn(void *data, int fd, const char *peer, const uint8_t *first, size_t first_len);

/* What a handler answers. The server sets status 200, file_fd -1 and the
 * rest empty before the call. A reply without a body or a file gets a
 * one-line text body naming its status, except 304 (Not Modified), which
 * has none: its Content-Length is file_size, the size a 200 would send. */
typedef struct http_reply {
    int status;
    const char *content_type; /* static; NULL: none */
    const char *extra;        /* header lines, each ending in CRLF, that live until the
                               * handler returns (static, or extra_buf); NULL: none */
    char extra_buf[128];      /* room for lines made per request */
    char *body;               /* malloc'd; the server frees it */
    size_t body_len;
    /* A file sent as the body instead, read from the fd as the peer takes
     * it (HTTP_FILE_CHUNK at a time, never the whole of a large file in
     * memory); the server closes the fd. */
    int file_fd;
    uint64_t file_size;
    /* Set: no response; the body's bytes and the socket go to takeover
     * (with takeover_data), and the connection leaves this server. */
    http_takeover_fn *takeover;
    void *takeover_data;
} http_reply;

/* Answers a complete, well-formed request (any method and path). */
typedef void http_handler_fn(void *data, const http_request *req, http_reply *reply);

typedef struct http_server_config {
    const char *name; /* in log lines: "metrics" */
    const char *host;
    uint16_t port;    /* 0: any free port */
    uint32_t max_conns;
} http_server_config;

typedef struct http_server http_server;

/* Listens (through listener.h, which accepts within a budget and pauses
 * while the process is out of file descriptors) and starts serving on
 * loop, with *out set. The loop must be able to watch the connections' fds
 * (ev_create's max_fd; past it a connection is refused like one past the
 * cap). Returns 0, or -errno with a message in err. */
int http_server_start(ev_loop *loop, const http_server_config *cfg, http_handler_fn *fn, void *data,
                      http_server **out, char *err, size_t errlen);
/* "HOST:PORT" as bound. */
const char *http_server_address(const http_server *h);
/* Closes the listener and every connection, stops its timers, frees h.
 * Call it before the loop is destroyed. NULL is a no-op. */
void http_server_stop(http_server *h);

#endif
