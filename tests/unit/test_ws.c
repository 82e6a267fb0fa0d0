/* The WebSocket codec (protocol/ws.c): the handshake's checks and RFC
 * 6455's own example, every refusal of a client frame with its close code,
 * fragments put together up to the cap, frames read whole and a byte short,
 * and the server's frames; the client's side: its request and the check of
 * the answer, and frames both ways through the one codec (a client's read
 * by the server's reader, a server's by the client's). */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "ws.h"

/* ---- handshake ------------------------------------------------------------- */

static const ws_upgrade good = {
    .method = "GET",
    .http_minor = 1,
    .upgrade = "websocket",
    .connection = "Upgrade",
    .version = "13",
    .key = "dGhlIHNhbXBsZSBub25jZQ==",
};

static void test_rfc_example(void **state)
{
    (void)state;
    char accept[WS_ACCEPT_SIZE], err[128];
    assert_int_equal(ws_handshake(&good, accept, err, sizeof err), 0);
    assert_string_equal(accept, "s3pPLMBiTxaQ9kYGzzhZRbK+xOo="); /* RFC 6455 1.3 */
}

static int handshake(ws_upgrade u)
{
    char accept[WS_ACCEPT_SIZE], err[128] = "";
    int rc = ws_handshake(&u, accept, err, sizeof err);
    if (rc < 0)
        assert_true(err[0]);
    return rc;
}

static void test_handshake_tokens(void **state)
{
    (void)state;
    ws_upgrade u = good;
    u.connection = "keep-alive, Upgrade"; /* Firefox */
    assert_int_equal(handshake(u), 0);
    u.connection = "keep-alive,upgrade ";
    assert_int_equal(handshake(u), 0);
    u.upgrade = "WebSocket";
    assert_int_equal(handshake(u), 0);
    u.http_minor = 2;
    assert_int_equal(handshake(u), 0);
}

static void test_asks_upgrade(void **state)
{
    (void)state;
    assert_true(ws_asks_upgrade("websocket"));
    assert_true(ws_asks_upgrade("h2c, WebSocket"));
    assert_false(ws_asks_upgrade("h2c"));
    assert_false(ws_asks_upgrade(""));
    assert_false(ws_asks_upgrade(NULL));
}

static void test_handshake_refused(void **state)
{
    (void)state;
    ws_upgrade u = good;
    u.method = "POST";
    assert_int_equal(handshake(u), -EINVAL);
    u = good;
    u.http_minor = 0;
    assert_int_equal(handshake(u), -EINVAL);
    u = good;
    u.upgrade = NULL;
    assert_int_equal(handshake(u), -EINVAL);
    u.upgrade = "h2c";
    assert_int_equal(handshake(u), -EINVAL);
    u.upgrade = "websockets";
    assert_int_equal(handshake(u), -EINVAL);
    u = good;
    u.connection = NULL;
    assert_int_equal(handshake(u), -EINVAL);
    u.connection = "keep-alive";
    assert_int_equal(handshake(u), -EINVAL);
    u.connection = "Upgrades";
    assert_int_equal(handshake(u), -EINVAL);
    u = good;
    u.version = NULL;
    assert_int_equal(handshake(u), -EPROTONOSUPPORT);
    u.version = "8";
    assert_int_equal(handshake(u), -EPROTONOSUPPORT);
    u.version = "13 ";
    assert_int_equal(handshake(u), -EPROTONOSUPPORT);
    u = good;
    u.key = NULL;
    assert_int_equal(handshake(u), -EINVAL);
    u.key = "";
    assert_int_equal(handshake(u), -EINVAL);
    u.key = "dGhlIHNhbXBsZSBub25jZQ="; /* 23 characters */
    assert_int_equal(handshake(u), -EINVAL);
    u.key = "dGhlIHNhbXBsZSBub25jZQ=A";
    assert_int_equal(handshake(u), -EINVAL);
    u.key = "dGhlIHNhbXBsZSBub25j*Q==";
    assert_int_equal(handshake(u), -EINVAL);
    u.key = "dGhlIHNhbXBsZSBub25jZR=="; /* R leaves bits past the 16th byte */
    assert_int_equal(handshake(u), -EINVAL);
    u.key = "dGhlIHNhbXBsZSBub25jZQ==x";
    assert_int_equal(handshake(u), -EINVAL);
    u.key = "AAAAAAAAAAAAAAAAAAAAAA=="; /* 16 zero bytes */
    assert_int_equal(handshake(u), 0);
}

/* ---- client frames --------------------------------------------------------- */

/* A client frame: first byte b0 (FIN, RSV, opcode), payload p[0..n) with
 * its length written in `form` bytes (0: the shortest), masked unless
 * unmasked. Returns its length. */
static size_t frame(uint8_t *out, uint8_t b0, const void *p, size_t n, int form, int unmasked)
{
    static const uint8_t mask[4] = {0x37, 0xfa, 0x21, 0x3d};
    size_t at = 0;
    out[at++] = b0;
    uint8_t m = unmasked ? 0 : 0x80;
    if (form == 0)
        form = n < 126 ? 1 : n <= 0xFFFF ? 2 : 8;
    if (form == 1) {
        out[at++] = (uint8_t)(m | n);
    } else if (form == 2) {
        out[at++] = m | 126;
        out[at++] = (uint8_t)(n >> 8);
        out[at++] = (uint8_t)n;
    } else {
        out[at++] = m | 127;
        for (int i = 0; i < 8; i++)
            out[at++] = (uint8_t)((uint64_t)n >> (56 - 8 * i));
    }
    if (!unmasked) {
        memcpy(out + at, mask, 4);
        at += 4;
    }
    for (size_t i = 0; i < n; i++)
        out[at + i] = (uint8_t)(((const uint8_t *)p)[i] ^ (unmasked ? 0 : mask[i & 3]));
    return at + n;
}

enum { FIN = 0x80 };

/* Reads buf[0..len) as one frame after checking that every shorter prefix
 * is "not all there yet" (a copy, since reading unmasks in place). */
static ssize_t read_one(ws_reader *r, uint8_t *buf, size_t len, ws_event *ev)
{
    char err[128];
    uint8_t *copy = malloc(len ? len : 1);
    assert_non_null(copy);
    for (size_t cut = 0; cut < len; cut++) {
        memcpy(copy, buf, cut);
        ssize_t rc = ws_read(r, copy, cut, ev, err, sizeof err);
        if (rc != 0) { /* a refusal may come from the header alone */
            free(copy);
            assert_true(rc < 0);
            return rc;
        }
    }
    free(copy);
    err[0] = 0;
    ssize_t rc = ws_read(r, buf, len, ev, err, sizeof err);
    if (rc < 0)
        assert_true(err[0]);
    return rc;
}

static void test_binary(void **state)
{
    (void)state;
    ws_reader r;
    ws_reader_init(&r, 70000);
    uint8_t buf[70100], payload[70000];
    for (size_t i = 0; i < sizeof payload; i++)
        payload[i] = (uint8_t)(i * 7);
    size_t sizes[] = {0, 1, 125, 126, 65535, 65536, 70000};
    for (size_t k = 0; k < sizeof sizes / sizeof *sizes; k++) {
        ws_event ev;
        size_t n = frame(buf, FIN | WS_OP_BINARY, payload, sizes[k], 0, 0);
        buf[n] = 0xEE; /* a byte of the next frame (read with the large ones) is not taken */
        ssize_t rc = sizes[k] < 200 ? read_one(&r, buf, n, &ev) : ws_read(&r, buf, n + 1, &ev, NULL, 0);
        assert_int_equal(rc, (ssize_t)n);
        assert_int_equal(ev.type, WS_EV_MESSAGE);
        assert_int_equal(ev.len, sizes[k]);
        assert_memory_equal(ev.data, payload, sizes[k]);
    }
    assert_null(r.msg); /* a single frame is never copied */
    ws_reader_free(&r);
}

static void test_too_big(void **state)
{
    (void)state;
    ws_reader r;
    ws_reader_init(&r, 1000);
    uint8_t buf[1100] = {0}, payload[1001] = {0};
    ws_event ev;
    /* Refused from the header alone, before the payload is there. */
    size_t n = frame(buf, FIN | WS_OP_BINARY, payload, 1001, 0, 0);
    assert_int_equal(ws_read(&r, buf, 8, &ev, NULL, 0), -EMSGSIZE);
    assert_int_equal(r.close_code, WS_CLOSE_TOO_BIG);
    ws_reader_init(&r, 1000);
    n = frame(buf, FIN | WS_OP_BINARY, payload, 1000, 0, 0);
    assert_int_equal(ws_read(&r, buf, n, &ev, NULL, 0), (ssize_t)n);
    /* A length of 2^63 - 1: refused, nothing allocated. */
    uint8_t huge[14] = {FIN | WS_OP_BINARY, 0x80 | 127, 0x7F, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF};
    cvre_alloc_fail_after(0);
    assert_int_equal(ws_read(&r, huge, 4, &ev, NULL, 0), 0);
    assert_int_equal(ws_read(&r, huge, 10, &ev, NULL, 0), -EMSGSIZE);
    cvre_alloc_fail_after(-1);
    assert_int_equal(r.close_code, WS_CLOSE_TOO_BIG);
    /* Fragments: the sum is capped, known at the header of the one past it. */
    ws_reader_init(&r, 1000);
    n = frame(buf, WS_OP_BINARY, payload, 600, 0, 0);
    assert_int_equal(ws_read(&r, buf, n, &ev, NULL, 0), (ssize_t)n);
    assert_int_equal(ev.type, WS_EV_NONE);
    n = frame(buf, FIN | WS_OP_CONTINUATION, payload, 401, 0, 0);
    assert_int_equal(ws_read(&r, buf, 4, &ev, NULL, 0), -EMSGSIZE);
    assert_int_equal(r.close_code, WS_CLOSE_TOO_BIG);
    ws_reader_free(&r);
}

static void test_fragments(void **state)
{
    (void)state;
    ws_reader r;
    ws_reader_init(&r, 5000);
    uint8_t buf[5100], payload[5000];
    for (size_t i = 0; i < sizeof payload; i++)
        payload[i] = (uint8_t)(i * 13 + 1);
    ws_event ev;
    /* 3 fragments with a ping and a pong between them, twice (the buffer
     * is kept for the next message). */
    for (int round = 0; round < 2; round++) {
        size_t n = frame(buf, WS_OP_BINARY, payload, 2000, 0, 0);
        assert_int_equal(read_one(&r, buf, n, &ev), (ssize_t)n);
        assert_int_equal(ev.type, WS_EV_NONE);
        n = frame(buf, FIN | WS_OP_PING, "hi", 2, 0, 0);
        assert_int_equal(read_one(&r, buf, n, &ev), (ssize_t)n);
        assert_int_equal(ev.type, WS_EV_PING);
        assert_int_equal(ev.len, 2);
        assert_memory_equal(ev.data, "hi", 2);
        n = frame(buf, WS_OP_CONTINUATION, payload + 2000, 0, 0, 0);
        assert_int_equal(read_one(&r, buf, n, &ev), (ssize_t)n);
        assert_int_equal(ev.type, WS_EV_NONE);
        n = frame(buf, FIN | WS_OP_PONG, NULL, 0, 0, 0);
        assert_int_equal(read_one(&r, buf, n, &ev), (ssize_t)n);
        assert_int_equal(ev.type, WS_EV_PONG);
        n = frame(buf, FIN | WS_OP_CONTINUATION, payload + 2000, 3000, 0, 0);
        assert_int_equal(ws_read(&r, buf, n, &ev, NULL, 0), (ssize_t)n);
        assert_int_equal(ev.type, WS_EV_MESSAGE);
        assert_int_equal(ev.len, 5000);
        assert_memory_equal(ev.data, payload, 5000);
    }
    /* Out of memory for the fragments: 1011. */
    ws_reader_free(&r);
    size_t n = frame(buf, WS_OP_BINARY, payload, 10, 0, 0);
    cvre_alloc_fail_after(0);
    assert_int_equal(ws_read(&r, buf, n, &ev, NULL, 0), -ENOMEM);
    cvre_alloc_fail_after(-1);
    assert_int_equal(r.close_code, WS_CLOSE_INTERNAL);
    ws_reader_free(&r);
}

/* Reads a frame into a fresh reader and returns its result, the close code
 * in *code. */
static ssize_t refusal(uint8_t *buf, size_t n, uint16_t *code)
{
    ws_reader r;
    ws_reader_init(&r, 1000);
    ws_event ev;
    ssize_t rc = read_one(&r, buf, n, &ev);
    *code = r.close_code;
    ws_reader_free(&r);
    return rc;
}

static void test_refused(void **state)
{
    (void)state;
    uint8_t buf[300], payload[200] = {0};
    uint16_t code;
    struct {
        uint8_t b0;
        size_t len;
        int form, unmasked;
        ssize_t rc;
        uint16_t code;
    } cases[] = {
        {FIN | WS_OP_BINARY, 4, 0, 1, -EPROTO, WS_CLOSE_PROTOCOL},       /* unmasked */
        {FIN | 0x40 | WS_OP_BINARY, 4, 0, 0, -EPROTO, WS_CLOSE_PROTOCOL}, /* RSV1 */
        {FIN | 0x20 | WS_OP_BINARY, 4, 0, 0, -EPROTO, WS_CLOSE_PROTOCOL}, /* RSV2 */
        {FIN | 0x10 | WS_OP_BINARY, 4, 0, 0, -EPROTO, WS_CLOSE_PROTOCOL}, /* RSV3 */
        {FIN | 0x3, 4, 0, 0, -EPROTO, WS_CLOSE_PROTOCOL},                  /* reserved data opcode */
        {FIN | 0xB, 4, 0, 0, -EPROTO, WS_CLOSE_PROTOCOL},                  /* reserved control opcode */
        {FIN | 0xF, 0, 0, 0, -EPROTO, WS_CLOSE_PROTOCOL},
        {FIN | WS_OP_TEXT, 4, 0, 0, -EOPNOTSUPP, WS_CLOSE_UNSUPPORTED},
        {WS_OP_TEXT, 4, 0, 0, -EOPNOTSUPP, WS_CLOSE_UNSUPPORTED},
        {WS_OP_PING, 4, 0, 0, -EPROTO, WS_CLOSE_PROTOCOL}, /* fragmented control frames */
        {WS_OP_PONG, 0, 0, 0, -EPROTO, WS_CLOSE_PROTOCOL},
        {WS_OP_CLOSE, 2, 0, 0, -EPROTO, WS_CLOSE_PROTOCOL},
        {FIN | WS_OP_PING, 126, 0, 0, -EPROTO, WS_CLOSE_PROTOCOL}, /* control over 125 */
        {FIN | WS_OP_PING, 4, 2, 0, -EPROTO, WS_CLOSE_PROTOCOL},
        {FIN | WS_OP_CONTINUATION, 4, 0, 0, -EPROTO, WS_CLOSE_PROTOCOL}, /* nothing to continue */
        {FIN | WS_OP_BINARY, 4, 2, 0, -EPROTO, WS_CLOSE_PROTOCOL},       /* lengths not shortest */
        {FIN | WS_OP_BINARY, 130, 8, 0, -EPROTO, WS_CLOSE_PROTOCOL},
        {FIN | WS_OP_BINARY, 125, 1, 0, 125 + 6, 0}, /* the shortest forms are taken */
        {FIN | WS_OP_BINARY, 126, 2, 0, 126 + 8, 0},
    };
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
        size_t n = frame(buf, cases[i].b0, payload, cases[i].len, cases[i].form, cases[i].unmasked);
        code = 0;
        assert_int_equal(refusal(buf, n, &code), cases[i].rc);
        assert_int_equal(code, cases[i].code);
    }
    /* A 64-bit length with its top bit set, whatever follows. */
    uint8_t top[14] = {FIN | WS_OP_BINARY, 0x80 | 127, 0x80, 0, 0, 0, 0, 0, 0, 1};
    assert_int_equal(refusal(top, sizeof top, &code), -EPROTO);
    assert_int_equal(code, WS_CLOSE_PROTOCOL);
    /* A new message inside a fragmented one. */
    ws_reader r;
    ws_reader_init(&r, 1000);
    ws_event ev;
    size_t n = frame(buf, WS_OP_BINARY, payload, 4, 0, 0);
    assert_int_equal(ws_read(&r, buf, n, &ev, NULL, 0), (ssize_t)n);
    n = frame(buf, FIN | WS_OP_BINARY, payload, 4, 0, 0);
    assert_int_equal(ws_read(&r, buf, n, &ev, NULL, 0), -EPROTO);
    assert_int_equal(r.close_code, WS_CLOSE_PROTOCOL);
    ws_reader_free(&r);
}

static void test_close(void **state)
{
    (void)state;
    uint8_t buf[200], p[130];
    ws_reader r;
    ws_reader_init(&r, 1000);
    ws_event ev;
    /* No code at all. */
    size_t n = frame(buf, FIN | WS_OP_CLOSE, NULL, 0, 0, 0);
    assert_int_equal(read_one(&r, buf, n, &ev), (ssize_t)n);
    assert_int_equal(ev.type, WS_EV_CLOSE);
    assert_int_equal(ev.code, 0);
    /* Every code: those a peer may send are taken, with their reason. */
    for (unsigned code = 0; code < 5100; code++) {
        p[0] = (uint8_t)(code >> 8);
        p[1] = (uint8_t)code;
        memcpy(p + 2, "bye \xc3\xa9", 6);
        n = frame(buf, FIN | WS_OP_CLOSE, p, 8, 0, 0);
        ws_reader_init(&r, 1000);
        ssize_t rc = ws_read(&r, buf, n, &ev, NULL, 0);
        int valid = (code >= 1000 && code <= 1003) || (code >= 1007 && code <= 1011) || (code >= 3000 && code <= 4999);
        assert_int_equal(ws_close_code_valid(code), valid);
        if (valid) {
            assert_int_equal(rc, (ssize_t)n);
            assert_int_equal(ev.type, WS_EV_CLOSE);
            assert_int_equal(ev.code, code);
            assert_int_equal(ev.len, 6);
            assert_memory_equal(ev.data, "bye \xc3\xa9", 6);
        } else {
            assert_int_equal(rc, -EPROTO);
            assert_int_equal(r.close_code, WS_CLOSE_PROTOCOL);
        }
    }
    assert_false(ws_close_code_valid(1005) || ws_close_code_valid(1006) || ws_close_code_valid(1015));
    /* A payload of one byte. */
    uint16_t code;
    n = frame(buf, FIN | WS_OP_CLOSE, "\x03", 1, 0, 0);
    assert_int_equal(refusal(buf, n, &code), -EPROTO);
    assert_int_equal(code, WS_CLOSE_PROTOCOL);
    /* A reason that is not UTF-8: 1007. */
    n = frame(buf, FIN | WS_OP_CLOSE, "\x03\xe8\xc3", 3, 0, 0);
    assert_int_equal(refusal(buf, n, &code), -EILSEQ);
    assert_int_equal(code, WS_CLOSE_BAD_DATA);
    n = frame(buf, FIN | WS_OP_CLOSE, "\x03\xe8\xed\xa0\x80", 5, 0, 0); /* a surrogate */
    assert_int_equal(refusal(buf, n, &code), -EILSEQ);
}

/* ---- server frames --------------------------------------------------------- */

static void test_server_frames(void **state)
{
    (void)state;
    uint8_t h[WS_SERVER_HEADER_MAX];
    assert_int_equal(ws_header(h, WS_OP_BINARY, 0), 2);
    assert_memory_equal(h, "\x82\x00", 2);
    assert_int_equal(ws_header(h, WS_OP_BINARY, 125), 2);
    assert_memory_equal(h, "\x82\x7d", 2);
    assert_int_equal(ws_header(h, WS_OP_BINARY, 126), 4);
    assert_memory_equal(h, "\x82\x7e\x00\x7e", 4);
    assert_int_equal(ws_header(h, WS_OP_BINARY, 65535), 4);
    assert_memory_equal(h, "\x82\x7e\xff\xff", 4);
    assert_int_equal(ws_header(h, WS_OP_BINARY, 65536), 10);
    assert_memory_equal(h, "\x82\x7f\x00\x00\x00\x00\x00\x01\x00\x00", 10);

    uint8_t out[200];
    assert_int_equal(ws_control(out, sizeof out, WS_OP_PONG, (const uint8_t *)"abc", 3), 5);
    assert_memory_equal(out, "\x8a\x03" "abc", 5);
    uint8_t big[126] = {0};
    assert_int_equal(ws_control(out, sizeof out, WS_OP_PONG, big, 126), -EINVAL);
    assert_int_equal(ws_control(out, 4, WS_OP_PONG, big, 3), -ENOSPC);

    assert_int_equal(ws_close_frame(out, sizeof out, WS_CLOSE_NORMAL, "bye"), 7);
    assert_memory_equal(out, "\x88\x05\x03\xe8" "bye", 7);
    assert_int_equal(ws_close_frame(out, sizeof out, 0, "ignored"), 2);
    assert_memory_equal(out, "\x88\x00", 2);
    /* A long reason is cut to 123 bytes, at a character's start. */
    char reason[200];
    memset(reason, 'a', 122);
    strcpy(reason + 122, "\xc3\xa9tail");
    int n = ws_close_frame(out, sizeof out, WS_CLOSE_POLICY, reason);
    assert_int_equal(n, 2 + 2 + 122);
    assert_int_equal(out[1], 124);
    assert_int_equal(ws_close_frame(out, 10, WS_CLOSE_POLICY, reason), -ENOSPC);
    /* What the server writes, the reader (cap permitting) reads back when
     * masked: the codec agrees with itself. */
    ws_reader r;
    ws_reader_init(&r, 1000);
    uint8_t buf[300];
    size_t m = frame(buf, out[0], out + 2, out[1], 0, 0);
    ws_event ev;
    assert_int_equal(ws_read(&r, buf, m, &ev, NULL, 0), (ssize_t)m);
    assert_int_equal(ev.code, WS_CLOSE_POLICY);
    assert_int_equal(ev.len, 122);
    ws_reader_free(&r);
}

/* ---- the client's side ------------------------------------------------------ */

/* The server's 101 for a key, as server/web_endpoint.c writes it, and
 * extra header lines. */
static size_t answer(char *out, size_t cap, const char *key, const char *extra)
{
    char accept[WS_ACCEPT_SIZE];
    assert_int_equal(ws_accept_key(key, strlen(key), accept), 0);
    int n = snprintf(out, cap,
                     "HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                     "Sec-WebSocket-Accept: %s\r\n%s\r\n",
                     accept, extra);
    assert_true(n > 0 && (size_t)n < cap);
    return (size_t)n;
}

static int response(const char *head, const char *key)
{
    char err[128] = "";
    int rc = ws_client_response((const uint8_t *)head, strlen(head), key, err, sizeof err);
    if (rc < 0)
        assert_true(err[0]);
    return rc;
}

static void test_client_handshake(void **state)
{
    (void)state;
    char req[512], key[WS_KEY_SIZE], other[WS_KEY_SIZE];
    int n = ws_client_request(req, sizeof req, "127.0.0.1:8080", "/", key);
    assert_true(n > 0);
    assert_int_equal((size_t)n, strlen(req));
    assert_memory_equal(req, "GET / HTTP/1.1\r\n", 16);
    assert_non_null(strstr(req, "\r\nHost: 127.0.0.1:8080\r\n"));
    assert_non_null(strstr(req, "\r\nSec-WebSocket-Version: 13\r\n"));
    assert_string_equal(req + n - 4, "\r\n\r\n");
    /* The key is what the server's check wants, and each request's own. */
    ws_upgrade u = good;
    u.key = key;
    char accept[WS_ACCEPT_SIZE];
    assert_int_equal(ws_handshake(&u, accept, NULL, 0), 0);
    assert_int_equal(ws_client_request(req, sizeof req, "h:1", "/", other), n - 11);
    assert_string_not_equal(key, other);
    assert_int_equal(ws_client_request(req, (size_t)n - 11, "h:1", "/", other), -ENOSPC);

    /* The answer: its head's length, with frames behind it; 0 at every
     * shorter prefix. */
    char head[600];
    size_t h = answer(head, sizeof head, key, "");
    memcpy(head + h, "\x82\x00", 3);
    assert_int_equal(ws_client_response((const uint8_t *)head, h + 2, key, NULL, 0), (int)h);
    for (size_t cut = 0; cut < h; cut++)
        assert_int_equal(ws_client_response((const uint8_t *)head, cut, key, NULL, 0), 0);
    /* RFC 6455's example, names and tokens in any case. */
    const char *rfc = "HTTP/1.1 101 OK\r\nupgrade: WebSocket\r\nCONNECTION: keep-alive, upgrade \r\n"
                      "Sec-Websocket-Accept:s3pPLMBiTxaQ9kYGzzhZRbK+xOo=\t\r\n\r\n";
    assert_int_equal(response(rfc, "dGhlIHNhbXBsZSBub25jZQ=="), (int)strlen(rfc));
}

static void test_client_handshake_refused(void **state)
{
    (void)state;
    const char *key = "dGhlIHNhbXBsZSBub25jZQ==";
    char head[WS_RESPONSE_MAX + 100];
    assert_int_equal(response("HTTP/1.1 426 Upgrade Required\r\nSec-WebSocket-Version: 13\r\n\r\n", key), -EPROTO);
    assert_int_equal(response("HTTP/1.1 1010 x\r\n\r\n", key), -EPROTO);
    assert_int_equal(response("HTTP/1.0 101 x\r\n\r\n", key), -EPROTO);
    assert_int_equal(response("\r\n\r\n", key), -EPROTO);
    assert_int_equal(response("HTTP/1.1 101 x\r\nConnection: Upgrade\r\n"
                              "Sec-WebSocket-Accept: s3pPLMBiTxaQ9kYGzzhZRbK+xOo=\r\n\r\n", key),
                     -EPROTO); /* no Upgrade */
    assert_int_equal(response("HTTP/1.1 101 x\r\nUpgrade: websocket\r\nConnection: close\r\n"
                              "Sec-WebSocket-Accept: s3pPLMBiTxaQ9kYGzzhZRbK+xOo=\r\n\r\n", key),
                     -EPROTO);
    assert_int_equal(response("HTTP/1.1 101 x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\r\n", key),
                     -EPROTO); /* no accept */
    answer(head, sizeof head, "AAAAAAAAAAAAAAAAAAAAAA==", ""); /* another key's accept */
    assert_int_equal(response(head, key), -EPROTO);
    answer(head, sizeof head, key, "Sec-WebSocket-Extensions: permessage-deflate\r\n");
    assert_int_equal(response(head, key), -EPROTO);
    answer(head, sizeof head, key, "Sec-WebSocket-Protocol: chat\r\n");
    assert_int_equal(response(head, key), -EPROTO);
    answer(head, sizeof head, key, "no colon here\r\n");
    assert_int_equal(response(head, key), -EPROTO);
    answer(head, sizeof head, key, "X-Other: fine\r\n");
    assert_int_equal(response(head, key), (int)strlen(head));
    /* A NUL inside the head. */
    size_t h = answer(head, sizeof head, key, "X: a\r\n");
    head[h - 5] = 0;
    assert_int_equal(ws_client_response((const uint8_t *)head, h, key, NULL, 0), -EPROTO);
    /* A head that never ends: waited for up to the bound, refused at it. */
    memset(head, 'a', sizeof head);
    assert_int_equal(ws_client_response((const uint8_t *)head, WS_RESPONSE_MAX - 1, key, NULL, 0), 0);
    assert_int_equal(ws_client_response((const uint8_t *)head, WS_RESPONSE_MAX, key, NULL, 0), -EMSGSIZE);
    assert_int_equal(ws_client_response((const uint8_t *)head, sizeof head, key, NULL, 0), -EMSGSIZE);
}

/* A payload of n bytes, every one different from its neighbours. */
static void fill(uint8_t *p, size_t n, unsigned seed)
{
    for (size_t i = 0; i < n; i++)
        p[i] = (uint8_t)(i * 31 + seed);
}

static void test_client_to_server(void **state)
{
    (void)state;
    static uint8_t payload[70000], buf[70100];
    fill(payload, sizeof payload, 5);
    ws_reader r;
    ws_reader_init(&r, sizeof payload);
    const size_t sizes[] = {0, 1, 7, 8, 9, 22, 45, 125, 126, 1000, 65535, 65536, 70000};
    for (size_t k = 0; k < sizeof sizes / sizeof *sizes; k++) {
        size_t n = sizes[k];
        int len = ws_client_frame(buf, sizeof buf, WS_OP_BINARY, payload, n);
        size_t h = n < 126 ? 2 : n <= 0xFFFF ? 4 : 10;
        assert_int_equal(len, (int)(h + 4 + n));
        assert_int_equal(buf[0], FIN | WS_OP_BINARY);
        assert_true(buf[1] & 0x80);
        if (n >= 8) /* masked: not the payload as it was */
            assert_memory_not_equal(buf + h + 4, payload, n);
        for (size_t cut = 0; cut < h; cut++)
            assert_int_equal(ws_frame_need(buf, cut), cut < 2 ? 2 : h);
        for (size_t cut = h; cut < h + 4; cut++)
            assert_int_equal(ws_frame_need(buf, cut), (size_t)len);
        ws_event ev;
        assert_int_equal(ws_read(&r, buf, (size_t)len - 1, &ev, NULL, 0), 0);
        assert_int_equal(ws_read(&r, buf, (size_t)len, &ev, NULL, 0), len);
        assert_int_equal(ev.type, WS_EV_MESSAGE);
        assert_int_equal(ev.len, n);
        assert_memory_equal(ev.data, payload, n);
    }
    /* Control frames: a pong and a close with its reason. */
    ws_event ev;
    int len = ws_client_frame(buf, sizeof buf, WS_OP_PONG, payload, 125);
    assert_int_equal(ws_read(&r, buf, (size_t)len, &ev, NULL, 0), len);
    assert_int_equal(ev.type, WS_EV_PONG);
    assert_memory_equal(ev.data, payload, 125);
    assert_int_equal(ws_client_frame(buf, sizeof buf, WS_OP_PING, payload, 126), -EINVAL);
    len = ws_client_close_frame(buf, sizeof buf, WS_CLOSE_GOING_AWAY, "quit");
    assert_int_equal(len, 2 + 4 + 2 + 4);
    assert_int_equal(ws_read(&r, buf, (size_t)len, &ev, NULL, 0), len);
    assert_int_equal(ev.type, WS_EV_CLOSE);
    assert_int_equal(ev.code, WS_CLOSE_GOING_AWAY);
    assert_int_equal(ev.len, 4);
    assert_memory_equal(ev.data, "quit", 4);
    ws_reader_free(&r);
    /* Short of room, by one byte. */
    assert_int_equal(ws_client_frame(buf, 2 + 4 + 9, WS_OP_BINARY, payload, 10), -ENOSPC);
    assert_int_equal(ws_client_frame(buf, 2 + 4 + 10, WS_OP_BINARY, payload, 10), 16);
    assert_int_equal(ws_client_close_frame(buf, 5, WS_CLOSE_NORMAL, NULL), -ENOSPC);
    /* Each frame its own key: eight in a row are not all the same. */
    uint8_t first[4];
    int differ = 0;
    for (int i = 0; i < 8; i++) {
        ws_client_frame(buf, sizeof buf, WS_OP_BINARY, payload, 1);
        if (i == 0)
            memcpy(first, buf + 2, 4);
        differ |= memcmp(first, buf + 2, 4) != 0;
    }
    assert_true(differ);
}

static void test_server_to_client(void **state)
{
    (void)state;
    static uint8_t payload[70000], buf[70100];
    fill(payload, sizeof payload, 9);
    ws_reader r;
    ws_reader_init_client(&r, sizeof payload);
    const size_t sizes[] = {0, 1, 22, 125, 126, 65535, 65536, 70000};
    for (size_t k = 0; k < sizeof sizes / sizeof *sizes; k++) {
        size_t n = sizes[k], h = ws_header(buf, WS_OP_BINARY, n);
        memcpy(buf + h, payload, n);
        assert_int_equal(ws_frame_need(buf, 1), 2);
        assert_int_equal(ws_frame_need(buf, h), h + n);
        ws_event ev;
        assert_int_equal(ws_read(&r, buf, h + n - (n > 0), &ev, NULL, 0), n > 0 ? 0 : (ssize_t)h);
        assert_int_equal(ws_read(&r, buf, h + n, &ev, NULL, 0), (ssize_t)(h + n));
        assert_int_equal(ev.type, WS_EV_MESSAGE);
        assert_int_equal(ev.len, n);
        assert_memory_equal(ev.data, payload, n); /* not unmasked: read as it is */
    }
    /* The server's ping, and its close 1013 (full), which only a client
     * may receive. */
    ws_event ev;
    int len = ws_control(buf, sizeof buf, WS_OP_PING, payload, 3);
    assert_int_equal(ws_read(&r, buf, (size_t)len, &ev, NULL, 0), len);
    assert_int_equal(ev.type, WS_EV_PING);
    len = ws_close_frame(buf, sizeof buf, WS_CLOSE_TRY_AGAIN, "full");
    assert_int_equal(ws_read(&r, buf, (size_t)len, &ev, NULL, 0), len);
    assert_int_equal(ev.type, WS_EV_CLOSE);
    assert_int_equal(ev.code, WS_CLOSE_TRY_AGAIN);
    ws_reader_free(&r);
    assert_true(r.of_server); /* freeing keeps which side it reads */
    ws_reader srv;
    ws_reader_init(&srv, 100);
    uint8_t masked[100];
    len = ws_client_close_frame(masked, sizeof masked, WS_CLOSE_TRY_AGAIN, "full");
    assert_int_equal(ws_read(&srv, masked, (size_t)len, &ev, NULL, 0), -EPROTO);
    /* A client refuses a masked frame and a close code never sent. */
    char err[128] = "";
    ws_reader_init_client(&r, 100);
    len = ws_client_frame(masked, sizeof masked, WS_OP_BINARY, payload, 5);
    assert_int_equal(ws_read(&r, masked, (size_t)len, &ev, err, sizeof err), -EPROTO);
    assert_int_equal(r.close_code, WS_CLOSE_PROTOCOL);
    assert_non_null(strstr(err, "masked"));
    ws_reader_init_client(&r, 100);
    len = ws_close_frame(buf, sizeof buf, 1015, NULL);
    assert_int_equal(ws_read(&r, buf, (size_t)len, &ev, NULL, 0), -EPROTO);
    /* Past the cap: refused from the header. */
    ws_reader_init_client(&r, 100);
    size_t h = ws_header(buf, WS_OP_BINARY, 101);
    assert_int_equal(ws_read(&r, buf, h, &ev, NULL, 0), -EMSGSIZE);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_rfc_example), cmocka_unit_test(test_handshake_tokens),
        cmocka_unit_test(test_asks_upgrade), cmocka_unit_test(test_handshake_refused),
        cmocka_unit_test(test_binary),
        cmocka_unit_test(test_too_big), cmocka_unit_test(test_fragments),
        cmocka_unit_test(test_refused), cmocka_unit_test(test_close),
        cmocka_unit_test(test_server_frames), cmocka_unit_test(test_client_handshake),
        cmocka_unit_test(test_client_handshake_refused), cmocka_unit_test(test_client_to_server),
        cmocka_unit_test(test_server_to_client),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
