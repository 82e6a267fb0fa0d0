/*
 * fuzz_ws.c: structure-aware fuzz target for the WebSocket frame reader
 * (protocol/ws.c), which the web endpoint feeds with a browser's, or a
 * stranger's, bytes once the handshake is done; and for the client's side
 * of the same codec (cvre-client --ws), which reads a server's answer to
 * its upgrade and then the server's frames.
 *
 * Inputs are streams of client frames. The generator writes frames of
 * every opcode (the six known and reserved ones), FIN set or not, RSV bits
 * now and then, masked or not, lengths in every form (7-bit, 16-bit,
 * 64-bit, not the shortest, the top bit set) around the control cap (125)
 * and the message cap (FUZZ_WS_CAP), fragmented messages with control
 * frames between the fragments, close frames with every class of code and
 * reasons good and bad UTF-8. The mutator walks the frames and changes one
 * header field (FIN, RSV, opcode, mask bit, length) or repeats, drops or
 * adds a frame.
 *
 * Each input is read twice, from one buffer holding it all and from a
 * buffer filled in chunks whose sizes the input decides, as the endpoint
 * fills conn's input: the two must see the same events (type, length,
 * close code, payload bytes) and end the same way (the same refusal and
 * close code, or the same bytes left over). Every message is within the
 * cap, every control payload within 125 bytes, every close code one a
 * peer may send, and every refusal names a close code the server sends.
 *
 * Every input is also read as a client reads a server: a third of the
 * generated ones are a server's stream (an answer to the upgrade, its
 * header lines shuffled, now and then wrong, then unmasked frames). The
 * answer's check takes no more than the input and agrees with itself on
 * the head alone; what follows the head (or the whole input, when there is
 * no valid head) is read by a client's reader, whole and in pieces, with
 * the same checks.
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fz.h"
#include "ws.h"

/* The message cap under test: small, so that fragments reach it. */
#define FUZZ_WS_CAP 3000u
/* The client's upgrade key and its accept: RFC 6455's example (1.3). */
#define FUZZ_WS_KEY "dGhlIHNhbXBsZSBub25jZQ=="
#define FUZZ_WS_ACCEPT "s3pPLMBiTxaQ9kYGzzhZRbK+xOo="

/* ---- generator --------------------------------------------------------------- */

static const uint16_t close_codes[] = {1000, 1001, 1002, 1003, 1004, 1005, 1006, 1007, 1011, 1012, 1015,
                                       2999, 3000, 4999, 5000, 0, 65535};

static uint64_t pick_length(void)
{
    static const uint64_t near[] = {0, 1, 125, 126, 127, 65535, 65536, FUZZ_WS_CAP - 1, FUZZ_WS_CAP,
                                    FUZZ_WS_CAP + 1};
    if (fz_one_in(3))
        return near[fz_below(sizeof near / sizeof *near)];
    return fz_pick_len(200);
}

/* Appends one frame: b0, a payload of len bytes (its first bytes a close
 * code and reason for a close), the length in form bytes (1, 2 or 8; 0:
 * the shortest), masked unless unmasked. Past the buffer's room the
 * payload is cut (fz_put drops it), which leaves a frame not all there. */
static void put_frame(fz_buf *b, uint8_t b0, uint64_t len, int form, int unmasked)
{
    uint8_t m = unmasked ? 0 : 0x80;
    if (form == 0)
        form = len < 126 ? 1 : len <= 0xFFFF ? 2 : 8;
    fz_put(b, &b0, 1);
    if (form == 1) {
        uint8_t l = (uint8_t)(m | (len > 127 ? 127 : len));
        fz_put(b, &l, 1);
    } else if (form == 2) {
        uint8_t l[3] = {m | 126, (uint8_t)(len >> 8), (uint8_t)len};
        fz_put(b, l, 3);
    } else {
        uint8_t l[9] = {m | 127};
        for (int i = 0; i < 8; i++)
            l[1 + i] = (uint8_t)(len >> (56 - 8 * i));
        if (fz_one_in(16))
            l[1] |= 0x80; /* the top bit */
        fz_put(b, l, 9);
    }
    uint8_t mask[4] = {0};
    if (!unmasked) {
        fz_set_le(mask, fz_rnd(), 4);
        fz_put(b, mask, 4);
    }
    uint8_t payload[256];
    size_t n = len < sizeof payload ? (size_t)len : sizeof payload;
    for (size_t i = 0; i < n; i++)
        payload[i] = (uint8_t)fz_rnd();
    if ((b0 & 0xF) == WS_OP_CLOSE && n >= 2) {
        uint16_t code = close_codes[fz_below(sizeof close_codes / sizeof *close_codes)];
        payload[0] = (uint8_t)(code >> 8);
        payload[1] = (uint8_t)code;
        for (size_t i = 2; i < n; i++) /* mostly ASCII, now and then a bad byte */
            payload[i] = fz_one_in(20) ? (uint8_t)(0x80 | fz_rnd()) : (uint8_t)(' ' + fz_below(90));
    }
    for (uint64_t i = 0; i < len && b->len < b->cap; i++) {
        uint8_t c = (uint8_t)((i < n ? payload[i] : (uint8_t)i) ^ mask[i & 3]);
        fz_put(b, &c, 1);
    }
}

/* Generating a server's stream: frames unmasked, as a server sends them. */
static int server_stream;

static uint8_t pick_b0(void)
{
    static const uint8_t ops[] = {WS_OP_BINARY, WS_OP_BINARY, WS_OP_CONTINUATION, WS_OP_PING, WS_OP_PONG,
                                  WS_OP_CLOSE,  WS_OP_TEXT,   0x3, 0x7, 0xB, 0xF};
    if (!fz_one_in(4)) /* mostly frames that are taken, so that streams go on */
        return (uint8_t)(0x80 | (fz_one_in(3) ? WS_OP_PING + fz_below(2) : WS_OP_BINARY));
    uint8_t b0 = ops[fz_below(sizeof ops / sizeof *ops)];
    if (!fz_one_in(4))
        b0 |= 0x80;
    if (fz_one_in(20))
        b0 |= (uint8_t)(0x10 << fz_below(3));
    return b0;
}

/* Appends a frame of any kind; a data frame now and then starts a
 * fragmented message with controls between its fragments. */
static void put_any(fz_buf *b)
{
    uint8_t b0 = pick_b0();
    uint64_t len = pick_length();
    if ((b0 & 0xF) >= 0x8 && !fz_one_in(10))
        len = fz_below(WS_CONTROL_MAX + 2);
    int form = fz_one_in(12) ? (int)"\1\2\10"[fz_below(3)] : 0;
    put_frame(b, b0, len, form, server_stream ? !fz_one_in(30) : fz_one_in(30));
    if ((b0 & 0xF) == WS_OP_BINARY && !(b0 & 0x80)) {
        for (uint32_t k = fz_below(4); k > 0; k--) {
            if (fz_one_in(2))
                put_frame(b, 0x80 | (uint8_t)(WS_OP_PING + fz_below(2)), fz_below(10), 0, server_stream);
            put_frame(b, WS_OP_CONTINUATION, pick_length(), 0, server_stream);
        }
        put_frame(b, 0x80 | WS_OP_CONTINUATION, pick_length(), 0, server_stream);
    }
}

/* A server's answer to the upgrade: a status line, the three headers it
 * needs in any order, each now and then wrong or left out, now and then a
 * header it must not send or a line without a colon. */
static void put_answer(fz_buf *b)
{
    static const char *const status[] = {"HTTP/1.1 101 Switching Protocols", "HTTP/1.1 101",
                                         "HTTP/1.1 426 Upgrade Required", "HTTP/1.0 101 OK", "HTTP/1.1 1010 x"};
    static const char *const lines[][2] = {
        {"Upgrade: websocket", "Upgrade: h2c"},
        {"Connection: keep-alive, Upgrade", "Connection: close"},
        {"Sec-WebSocket-Accept: " FUZZ_WS_ACCEPT, "Sec-WebSocket-Accept: AAAAAAAAAAAAAAAAAAAAAAAAAAA="},
        {"Sec-WebSocket-Extensions: permessage-deflate", "no colon here"},
        {"Server: cvre", "X-Padding:\t  spaces  \t"},
    };
    const char *st = status[fz_one_in(4) ? fz_below(5) : 0];
    fz_put(b, st, strlen(st));
    fz_put(b, "\r\n", 2);
    int order[5] = {0, 1, 2, 3, 4};
    for (int i = 4; i > 0; i--) {
        int j = (int)fz_below((uint32_t)i + 1), t = order[i];
        order[i] = order[j];
        order[j] = t;
    }
    for (int i = 0; i < 5; i++) {
        int k = order[i];
        if (k >= 3 ? !fz_one_in(8) : fz_one_in(20))
            continue; /* the needed ones mostly there, the others seldom */
        const char *line = lines[k][fz_one_in(10)];
        fz_put(b, line, strlen(line));
        fz_put(b, "\r\n", 2);
    }
    if (!fz_one_in(20))
        fz_put(b, "\r\n", 2);
}

static size_t ws_generate(uint8_t *out, size_t max)
{
    fz_buf b = {out, 0, max < 16384 ? max : 16384};
    server_stream = fz_one_in(3);
    if (server_stream)
        put_answer(&b);
    for (uint32_t k = 1 + fz_below(8); k > 0 && b.len < b.cap; k--)
        put_any(&b);
    return b.len;
}

/* ---- mutator ------------------------------------------------------------------ */

/* Where each frame of data[0..size) starts (at most max_frames), found by
 * reading headers; the last may be cut. Returns how many. */
static size_t frame_starts(const uint8_t *data, size_t size, size_t *at, size_t max_frames)
{
    size_t n = 0, p = 0;
    while (p + 2 <= size && n < max_frames) {
        at[n++] = p;
        uint64_t len = data[p + 1] & 0x7F;
        size_t h = 2;
        if (len == 126 && p + 4 <= size) {
            len = (uint64_t)data[p + 2] << 8 | data[p + 3];
            h = 4;
        } else if (len == 127 && p + 10 <= size) {
            len = 0;
            for (size_t i = 0; i < 8; i++)
                len = len << 8 | data[p + 2 + i];
            h = 10;
        }
        h += (data[p + 1] & 0x80) ? 4 : 0;
        if (len > size - p || h + len > size - p)
            break;
        p += h + (size_t)len;
    }
    return n;
}

static size_t ws_mutate(uint8_t *data, size_t size, size_t max)
{
    size_t at[64];
    size_t n = frame_starts(data, size, at, 64);
    if (n == 0)
        return 0;
    size_t f = at[fz_below((uint32_t)n)];
    switch (fz_below(6)) {
    case 0:
        data[f] ^= 0x80; /* FIN */
        break;
    case 1:
        data[f] ^= (uint8_t)(0x10 << fz_below(3)); /* RSV */
        break;
    case 2:
        data[f] = (uint8_t)((data[f] & 0xF0) | fz_below(16)); /* opcode */
        break;
    case 3:
        data[f + 1] ^= 0x80; /* the mask bit: the rest is now read differently */
        break;
    case 4: { /* a length: the 7-bit one, or the first byte of a longer form */
        size_t i = (data[f + 1] & 0x7F) >= 126 && f + 2 < size && fz_one_in(2) ? f + 2 : f + 1;
        data[i] = (uint8_t)((data[i] & (i == f + 1 ? 0x80 : 0)) | (uint8_t)fz_below(i == f + 1 ? 128 : 256));
        break;
    }
    default: { /* a new frame or two, inserted at a frame's start */
        uint8_t tmp[4096];
        fz_buf b = {tmp, 0, sizeof tmp};
        put_any(&b);
        fz_splice(data, &size, max, f, f, tmp, b.len);
        break;
    }
    }
    return size;
}

/* ---- the target ------------------------------------------------------------- */

/* What a reading saw, event by event, with a hash of the payloads. */
typedef struct seen {
    unsigned long events, bytes;
    uint64_t hash;
    ssize_t end;      /* the refusal, or 0 */
    uint16_t code;    /* its close code */
    size_t left;      /* bytes not taken */
} seen;

static void see(seen *s, const ws_event *ev, size_t cap, int of_server)
{
    FZ_CHECK(ev->type == WS_EV_NONE || ev->type == WS_EV_MESSAGE || ev->type == WS_EV_PING ||
             ev->type == WS_EV_PONG || ev->type == WS_EV_CLOSE);
    if (ev->type == WS_EV_MESSAGE)
        FZ_CHECK(ev->len <= cap);
    if (ev->type == WS_EV_PING || ev->type == WS_EV_PONG)
        FZ_CHECK(ev->len <= WS_CONTROL_MAX);
    if (ev->type == WS_EV_CLOSE) {
        FZ_CHECK(ev->code == 0 ? ev->len == 0
                               : ws_close_code_valid(ev->code) || (of_server && ev->code >= 1012 && ev->code <= 1014));
        FZ_CHECK(ev->len <= WS_CONTROL_MAX - 2);
    }
    if (ev->type == WS_EV_NONE)
        return;
    s->events++;
    s->bytes += ev->len;
    s->hash = s->hash * 1099511628211u + (uint64_t)ev->type * 7919u + ev->code;
    for (size_t i = 0; i < ev->len; i++)
        s->hash = (s->hash ^ ev->data[i]) * 1099511628211u;
}

static void check_refusal(ssize_t rc, uint16_t code)
{
    FZ_CHECK((rc == -EPROTO && code == WS_CLOSE_PROTOCOL) || (rc == -EILSEQ && code == WS_CLOSE_BAD_DATA) ||
             (rc == -EOPNOTSUPP && code == WS_CLOSE_UNSUPPORTED) || (rc == -EMSGSIZE && code == WS_CLOSE_TOO_BIG) ||
             (rc == -ENOMEM && code == WS_CLOSE_INTERNAL));
}

/* Reads data[0..size) as it would arrive in pieces: 0 pieces of step
 * bytes (step 0: all at once), taking frames after each, as the endpoint
 * does with conn's input; as a client reads a server's frames when
 * of_server. */
static void read_stream(const uint8_t *data, size_t size, size_t step, seen *s, int of_server)
{
    static uint8_t buf[FZ_INPUT_MAX];
    ws_reader r;
    if (of_server)
        ws_reader_init_client(&r, FUZZ_WS_CAP);
    else
        ws_reader_init(&r, FUZZ_WS_CAP);
    *s = (seen){.hash = 14695981039346656037u};
    size_t have = 0, fed = 0;
    while (fed < size) {
        size_t n = step ? step : size;
        if (n > size - fed)
            n = size - fed;
        memcpy(buf + have, data + fed, n);
        have += n;
        fed += n;
        for (;;) {
            ws_event ev;
            char err[128] = "";
            ssize_t rc = ws_read(&r, buf, have, &ev, err, sizeof err);
            if (rc < 0) {
                FZ_CHECK(err[0]);
                check_refusal(rc, r.close_code);
                s->end = rc;
                s->code = r.close_code;
                ws_reader_free(&r);
                return;
            }
            if (rc == 0)
                break;
            FZ_CHECK((size_t)rc <= have);
            FZ_CHECK(r.msg_len <= FUZZ_WS_CAP && r.msg_alloc <= FUZZ_WS_CAP);
            see(s, &ev, FUZZ_WS_CAP, of_server);
            memmove(buf, buf + rc, have - (size_t)rc);
            have -= (size_t)rc;
        }
    }
    s->left = have;
    ws_reader_free(&r);
}

static unsigned long n_inputs, n_events, n_refused[5], n_heads, n_client_events;

/* Reads data whole and in pieces of a size the input decides; the two
 * must agree. Returns the whole reading. */
static seen read_both(const uint8_t *data, size_t size, int of_server)
{
    seen whole, pieces;
    read_stream(data, size, 0, &whole, of_server);
    read_stream(data, size, size ? 1u + data[size / 2] % 97u : 1u, &pieces, of_server);
    FZ_CHECK(whole.events == pieces.events && whole.bytes == pieces.bytes && whole.hash == pieces.hash);
    FZ_CHECK(whole.end == pieces.end && whole.code == pieces.code && whole.left == pieces.left);
    return whole;
}

/* The client's side: the answer to the upgrade, then the server's frames. */
static void client_side(const uint8_t *data, size_t size)
{
    char err[128] = "";
    int head = ws_client_response(data, size, FUZZ_WS_KEY, err, sizeof err);
    FZ_CHECK(head <= (int)size && (head >= 0 || err[0]));
    if (head > 0) {
        FZ_CHECK(memcmp(data + head - 4, "\r\n\r\n", 4) == 0);
        FZ_CHECK(ws_client_response(data, (size_t)head, FUZZ_WS_KEY, NULL, 0) == head);
        n_heads++;
    }
    size_t skip = head > 0 ? (size_t)head : 0;
    n_client_events += read_both(data + skip, size - skip, 1).events;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    seen whole = read_both(data, size, 0);
    client_side(data, size);
    n_inputs++;
    n_events += whole.events;
    if (whole.end) {
        static const uint16_t codes[] = {WS_CLOSE_PROTOCOL, WS_CLOSE_BAD_DATA, WS_CLOSE_UNSUPPORTED,
                                         WS_CLOSE_TOO_BIG, WS_CLOSE_INTERNAL};
        for (int i = 0; i < 5; i++)
            if (codes[i] == whole.code)
                n_refused[i]++;
    }
    return 0;
}

/* If events drop to near zero, inputs no longer get past the first header. */
static void ws_report(void)
{
    fprintf(stderr, "fuzz_ws: %lu streams, %lu events, closed 1002 %lu, 1007 %lu, 1003 %lu, 1009 %lu, 1011 %lu; "
            "as a client: %lu answers taken, %lu events\n",
            n_inputs, n_events, n_refused[0], n_refused[1], n_refused[2], n_refused[3], n_refused[4], n_heads,
            n_client_events);
}

const fz_target fz_self = {"fuzz_ws", NULL, ws_generate, ws_mutate, NULL, ws_report, NULL};
