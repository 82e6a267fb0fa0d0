/*
 * http.h: one HTTP/1.x request head, parsed by Node's http_parser (Debian's
 * libhttp-parser) from bytes the caller read into its own buffers, within
 * fixed bounds; and the head of a response. No I/O and no policy about
 * paths here: http_server.h reads, writes and closes; each endpoint decides
 * what a path means.
 *
 * One request per connection: parsing stops at the end of the first
 * request, and a request with a body is refused (the endpoints only GET).
 * Every limit below holds while the bytes arrive, before anything grows:
 * the head is copied into a fixed buffer inside the request, and nothing is
 * allocated after http_request_new.
 */
#ifndef CVRE_HTTP_H
#define CVRE_HTTP_H

#include <stddef.h>
#include <stdint.h>

/* Request line and headers together, in bytes. A scraper's or a browser's
 * GET is a few hundred bytes (a browser with cookies a few KiB); 8 KiB is
 * what nginx and Apache allow a header line by default. More is refused
 * with 431 as soon as it arrives. */
#ifndef HTTP_HEAD_MAX
#define HTTP_HEAD_MAX 8192u
#endif
/* The request target: 414 past this. */
#ifndef HTTP_URL_MAX
#define HTTP_URL_MAX 2048u
#endif
/* Header fields: a browser sends about 15; 431 past this. */
#ifndef HTTP_HEADERS_MAX
#define HTTP_HEADERS_MAX 32u
#endif

_Static_assert(HTTP_URL_MAX < HTTP_HEAD_MAX, "the request line is part of the head");
_Static_assert(HTTP_HEAD_MAX <= 65535u, "offsets into the head are 16-bit");
_Static_assert(HTTP_HEADERS_MAX >= 8u, "room for the headers every client sends");

/* What http_request_feed returns: these two, or the status of the error
 * response the request earns (400, 413, 414, 431 or 505). */
enum { HTTP_INCOMPLETE = 0, HTTP_COMPLETE = 1 };

typedef struct http_request http_request;

/* A request ready to be fed. NULL if out of memory. */
http_request *http_request_new(void);
void http_request_free(http_request *r);

/* Feeds the next len bytes of the connection. Returns HTTP_INCOMPLETE
 * while the head is not all there, HTTP_COMPLETE once it is, or an error
 * status:
 *   400  malformed (http_parser refused it, a bad target, HTTP/1.1 without
 *        Host, a NUL);
 *   413  it has a body (Content-Length above 0, or Transfer-Encoding);
 *   414  target over HTTP_URL_MAX;
 *   431  head over HTTP_HEAD_MAX, or over HTTP_HEADERS_MAX fields;
 *   505  not HTTP/1.
 * A head both malformed and over a limit gets 400 or the limit's status,
 * depending on where the reads cut it (http_parser stops at a bad byte
 * without handing over the piece of a string read before it). Once the
 * result is not HTTP_INCOMPLETE it is final: later calls return it again
 * and read nothing. Bytes after the head are not looked at. The
 * caller may reuse its buffer after each call: what the request keeps is
 * copied. */
int http_request_feed(http_request *r, const uint8_t *data, size_t len);

/* Of a complete request (NUL-terminated, valid until http_request_free):
 * the method ("GET"); the target as sent ("/metrics?x=1"); its path, not
 * percent-decoded ("/metrics"; "*" for OPTIONS *; the authority of a
 * CONNECT); the value of the first header of that name (any case),
 * without surrounding blanks, or NULL if there is none. */
const char *http_request_method(const http_request *r);
const char *http_request_target(const http_request *r);
const char *http_request_path(const http_request *r);
const char *http_request_header(const http_request *r, const char *name);
/* Its HTTP minor version: 1 for HTTP/1.1 (a WebSocket needs it). */
int http_request_minor(const http_request *r);

/* The reason phrase of a status ("Not Found"), from http_parser's table. */
const char *http_reason(int status);

/* Writes an HTTP/1.1 response head to out[0..cap): status line,
 * Content-Type (if content_type is not NULL), Content-Length,
 * Connection: close, the lines of extra (each ending in CRLF; may be
 * NULL), and the empty line. Returns its length, or -ENOSPC if it does not
 * fit (out is then unspecified). */
int http_response_head(char *out, size_t cap, int status, const char *content_type, size_t content_length,
                       const char *extra);

#endif
