/* http.c: a bounded HTTP/1.x request head over http_parser (see http.h). */
#include "http.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include <http_parser.h>

#include "alloc.h"

/* A header's value offset when the field had no value at all. */
#define NO_VALUE UINT16_MAX

/* Offsets into the request's text: each string there ends in a NUL. */
typedef struct header {
    uint16_t name, value;
} header;

/* Which string the parser's callbacks are adding to. Each arrives in one
 * or more pieces, and pieces of different strings never interleave. */
typedef enum { IN_NONE, IN_URL, IN_FIELD, IN_VALUE } piece;

struct http_request {
    http_parser parser;
    int result;      /* HTTP_INCOMPLETE until final */
    int complete;    /* the parser reached the end of the request */
    size_t fed;      /* bytes of the head given to the parser */
    piece in;
    uint16_t url, path, nheaders;
    header headers[HTTP_HEADERS_MAX];
    char method[24];
    size_t len; /* of text */
    /* The target, each header's name and value, and the path: at most the
     * head's bytes (a line's CRLF and ": " make room for the NULs) plus a
     * copy of the target's path. */
    char text[HTTP_HEAD_MAX + HTTP_URL_MAX + 2];
};

/* Makes status the request's result (the first one set stands) and
 * returns -EPROTO, which a callback returns to stop the parser (any
 * non-zero return is an error for it). */
static int request_reject(http_request *r, int status)
{
    if (r->result == HTTP_INCOMPLETE)
        r->result = status;
    return -EPROTO;
}

/* Adds n bytes to the string being built, keeping a byte for its NUL.
 * The text has room for a whole head and a path (see its size), so the
 * 431 here is a guard against a parser that hands over more than it
 * read, not a limit a request can reach. */
static int append(http_request *r, const char *at, size_t n)
{
    if (memchr(at, 0, n))
        return request_reject(r, 400);
    if (n + 1 > sizeof r->text - r->len)
        return request_reject(r, 431); /* GCOVR_EXCL_LINE: no request reaches it (above) */
    memcpy(r->text + r->len, at, n);
    r->len += n;
    return 0;
}

static int is_blank(char c) { return c == ' ' || c == '\t'; }

/* Ends the string being added to: a header value loses its trailing
 * blanks (http_parser drops the leading ones, also those of a folded
 * line), and every string gets its NUL, in the byte append kept for it. */
static void end_piece(http_request *r)
{
    if (r->in == IN_VALUE) {
        const header *h = &r->headers[r->nheaders - 1];
        while (r->len > h->value && is_blank(r->text[r->len - 1]))
            r->len--;
    }
    if (r->in != IN_NONE)
        r->text[r->len++] = 0;
    r->in = IN_NONE;
}

static int on_url(http_parser *p, const char *at, size_t n)
{
    http_request *r = p->data;
    if (r->in != IN_URL) {
        r->url = (uint16_t)r->len;
        r->in = IN_URL;
    }
    if (r->len - r->url + n > HTTP_URL_MAX)
        return request_reject(r, 414);
    return append(r, at, n);
}

static int on_header_field(http_parser *p, const char *at, size_t n)
{
    http_request *r = p->data;
    if (r->in != IN_FIELD) {
        end_piece(r);
        if (r->nheaders == HTTP_HEADERS_MAX)
            return request_reject(r, 431);
        r->headers[r->nheaders++] = (header){.name = (uint16_t)r->len, .value = NO_VALUE};
        r->in = IN_FIELD;
    }
    return append(r, at, n);
}

static int on_header_value(http_parser *p, const char *at, size_t n)
{
    http_request *r = p->data;
    if (r->in != IN_VALUE) {
        end_piece(r);
        r->headers[r->nheaders - 1].value = (uint16_t)r->len;
        r->in = IN_VALUE;
    }
    return append(r, at, n);
}

/* The path of the target, copied after the head's strings: the path of
 * origin form (/a/b?c) or absolute form (http://h/a/b), "/" for an
 * absolute form without one, "*" for OPTIONS *, the authority for
 * CONNECT. 0, or -EPROTO if the target is not a URL (the result: 400). */
static int copy_path(http_request *r, int is_connect)
{
    const char *url = r->text + r->url;
    size_t url_len = strlen(url);
    struct http_parser_url u;
    http_parser_url_init(&u);
    if (http_parser_parse_url(url, url_len, is_connect, &u) != 0)
        return request_reject(r, 400);
    const char *path = "/";
    size_t len = 1;
    if (is_connect) {
        path = url;
        len = url_len;
    } else if (u.field_set & (1u << UF_PATH)) {
        path = url + u.field_data[UF_PATH].off;
        len = u.field_data[UF_PATH].len;
    }
    r->path = (uint16_t)r->len;
    r->in = IN_URL; /* for end_piece's NUL */
    int rc = append(r, path, len);
    if (rc < 0) /* a part of the target, taken already: no NUL, and room kept */
        return rc; /* GCOVR_EXCL_LINE */
    end_piece(r);
    return 0;
}

/* The head is all there: refuse what these endpoints do not serve. */
static int on_headers_complete(http_parser *p)
{
    http_request *r = p->data;
    end_piece(r);
    if (p->http_major != 1)
        return request_reject(r, 505);
    if (p->http_minor >= 1 && !http_request_header(r, "host"))
        return request_reject(r, 400); /* RFC 9112 3.2: a 1.1 request without Host is refused */
    if ((p->flags & F_CHUNKED) || p->uses_transfer_encoding || ((p->flags & F_CONTENTLENGTH) && p->content_length))
        return request_reject(r, 413);
    snprintf(r->method, sizeof r->method, "%s", http_method_str((enum http_method)p->method));
    return copy_path(r, p->method == HTTP_CONNECT);
}

/* One request per connection: stop here, whatever follows. */
static int on_message_complete(http_parser *p)
{
    http_request *r = p->data;
    r->complete = 1;
    http_parser_pause(p, 1);
    return 0;
}

static const http_parser_settings settings = {
    .on_url = on_url,
    .on_header_field = on_header_field,
    .on_header_value = on_header_value,
    .on_headers_complete = on_headers_complete,
    .on_message_complete = on_message_complete,
};

http_request *http_request_new(void)
{
    http_request *r = cvre_malloc(sizeof *r);
    if (!r)
        return NULL;
    memset(r, 0, offsetof(http_request, text));
    http_parser_init(&r->parser, HTTP_REQUEST);
    r->parser.data = r;
    return r;
}

void http_request_free(http_request *r) { free(r); }

int http_request_feed(http_request *r, const uint8_t *data, size_t len)
{
    if (r->result != HTTP_INCOMPLETE || len == 0)
        return r->result;
    if (r->fed == HTTP_HEAD_MAX)
        return r->result = 431; /* the head goes on past its cap */
    size_t n = len < HTTP_HEAD_MAX - r->fed ? len : HTTP_HEAD_MAX - r->fed;
    r->fed += http_parser_execute(&r->parser, &settings, (const char *)data, n);
    if (r->result != HTTP_INCOMPLETE) /* a callback refused it */
        return r->result;
    if (r->complete)
        return r->result = HTTP_COMPLETE;
    if (HTTP_PARSER_ERRNO(&r->parser) != HPE_OK)
        return r->result = 400;
    if (n < len) /* the cap cut this read, and the head is not over */
        return r->result = 431;
    return HTTP_INCOMPLETE;
}

const char *http_request_method(const http_request *r) { return r->method; }

const char *http_request_target(const http_request *r) { return r->text + r->url; }

const char *http_request_path(const http_request *r) { return r->text + r->path; }

const char *http_request_header(const http_request *r, const char *name)
{
    for (uint16_t i = 0; i < r->nheaders; i++)
        if (strcasecmp(r->text + r->headers[i].name, name) == 0)
            return r->headers[i].value == NO_VALUE ? "" : r->text + r->headers[i].value;
    return NULL;
}

int http_request_minor(const http_request *r) { return r->parser.http_minor; }

const char *http_reason(int status) { return http_status_str((enum http_status)status); }

int http_response_head(char *out, size_t cap, int status, const char *content_type, size_t content_length,
                       const char *extra)
{
    int n = snprintf(out, cap, "HTTP/1.1 %d %s\r\n%s%s%sContent-Length: %zu\r\nConnection: close\r\n%s\r\n", status,
                     http_reason(status), content_type ? "Content-Type: " : "", content_type ? content_type : "",
                     content_type ? "\r\n" : "", content_length, extra ? extra : "");
    if (n < 0 || (size_t)n >= cap)
        return -ENOSPC;
    return n;
}
