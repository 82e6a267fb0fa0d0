/* ws.c: RFC 6455's handshake and frames as bytes (see ws.h). */
#include "ws.h"

#include <errno.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include <openssl/evp.h>
#include <openssl/rand.h>
#include <openssl/sha.h>

#include "alloc.h"
#include "err.h"
#include "utf8.h"

/* ---- handshake ------------------------------------------------------------- */

/* 4.2.2: appended to the key before hashing. */
static const char ws_guid[] = "258EAFA5-E914-47DA-95CA-C5AB0DC85B11";

int ws_accept_key(const char *key, size_t len, char accept[WS_ACCEPT_SIZE])
{
    unsigned char digest[SHA_DIGEST_LENGTH];
    EVP_MD_CTX *md = EVP_MD_CTX_new();
    unsigned dlen = 0;
    int ok = md && EVP_DigestInit_ex(md, EVP_sha1(), NULL) && EVP_DigestUpdate(md, key, len) &&
             EVP_DigestUpdate(md, ws_guid, sizeof ws_guid - 1) && EVP_DigestFinal_ex(md, digest, &dlen) &&
             dlen == sizeof digest;
    EVP_MD_CTX_free(md);
    if (!ok)
        return -EIO; /* GCOVR_EXCL_LINE: libcrypto out of memory */
    /* 20 bytes are 28 characters of base64, and EVP_EncodeBlock adds the NUL. */
    _Static_assert(4 * ((SHA_DIGEST_LENGTH + 2) / 3) + 1 == WS_ACCEPT_SIZE, "the accept's size");
    EVP_EncodeBlock((unsigned char *)accept, digest, sizeof digest);
    return 0;
}

/* The value of a base64 digit, or -1. */
static int b64_digit(char c)
{
    static const char digits[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    const char *p = c ? strchr(digits, c) : NULL;
    return p ? (int)(p - digits) : -1;
}

/* 16 bytes in base64: 22 digits, the last of which carries 2 bits of
 * data and 4 zero bits, then "==". */
static int key_valid(const char *key)
{
    if (strlen(key) != 24 || strcmp(key + 22, "==") != 0)
        return 0;
    for (int i = 0; i < 22; i++)
        if (b64_digit(key[i]) < 0)
            return 0;
    return (b64_digit(key[21]) & 0xF) == 0;
}

int ws_list_has(const char *list, const char *token)
{
    size_t tlen = strlen(token);
    for (const char *p = list; *p;) {
        p += strspn(p, " \t,");
        size_t n = strcspn(p, ",");
        size_t m = n;
        while (m > 0 && (p[m - 1] == ' ' || p[m - 1] == '\t'))
            m--;
        if (m == tlen && strncasecmp(p, token, tlen) == 0)
            return 1;
        p += n;
    }
    return 0;
}

int ws_asks_upgrade(const char *upgrade) { return upgrade && ws_list_has(upgrade, "websocket"); }

int ws_handshake(const ws_upgrade *u, char accept[WS_ACCEPT_SIZE], char *err, size_t errlen)
{
    if (!u->method || strcmp(u->method, "GET") != 0)
        return cvre_fail(err, errlen, -EINVAL, "a WebSocket opens with GET, not %s", u->method ? u->method : "?");
    if (u->http_minor < 1)
        return cvre_fail(err, errlen, -EINVAL, "a WebSocket needs HTTP/1.1, not HTTP/1.%d", u->http_minor);
    if (!ws_asks_upgrade(u->upgrade))
        return cvre_fail(err, errlen, -EINVAL, "no \"Upgrade: websocket\"");
    if (!u->connection || !ws_list_has(u->connection, "upgrade"))
        return cvre_fail(err, errlen, -EINVAL, "no \"Connection: Upgrade\"");
    if (!u->version)
        return cvre_fail(err, errlen, -EPROTONOSUPPORT, "no Sec-WebSocket-Version");
    if (strcmp(u->version, "13") != 0)
        return cvre_fail(err, errlen, -EPROTONOSUPPORT, "Sec-WebSocket-Version %.16s, not 13", u->version);
    if (!u->key)
        return cvre_fail(err, errlen, -EINVAL, "no Sec-WebSocket-Key");
    if (!key_valid(u->key))
        return cvre_fail(err, errlen, -EINVAL, "a Sec-WebSocket-Key that is not 16 bytes of base64");
    if (ws_accept_key(u->key, strlen(u->key), accept) < 0)
        return cvre_fail(err, errlen, -EIO, "libcrypto could not hash the key"); /* GCOVR_EXCL_LINE */
    return 0;
}

/* ---- reading frames -------------------------------------------------------- */

void ws_reader_init(ws_reader *r, size_t cap) { *r = (ws_reader){.cap = cap}; }

void ws_reader_init_client(ws_reader *r, size_t cap) { *r = (ws_reader){.cap = cap, .of_server = 1}; }

void ws_reader_free(ws_reader *r)
{
    free(r->msg);
    *r = (ws_reader){.cap = r->cap, .of_server = r->of_server};
}

/* XORs p[0..n) with the 4-byte key (5.3), 8 bytes at a time: a move is
 * 22 to 45 bytes, and this runs on every message both ways. */
static void apply_mask(uint8_t *p, size_t n, const uint8_t key[4])
{
    uint8_t k8[8];
    uint64_t k, v;
    memcpy(k8, key, 4);
    memcpy(k8 + 4, key, 4);
    memcpy(&k, k8, sizeof k);
    size_t i = 0;
    for (; i + 8 <= n; i += 8) {
        memcpy(&v, p + i, sizeof v);
        v ^= k;
        memcpy(p + i, &v, sizeof v);
    }
    for (; i < n; i++) /* i is a multiple of 8 here: the key starts over */
        p[i] ^= key[i & 3];
}

/* The payload length a frame's header writes and where its mask (or its
 * payload) starts; 0 while the length is not all there, 1 once read. */
static int frame_length(const uint8_t *data, size_t len, size_t *at, uint64_t *plen)
{
    if (len < 2)
        return 0;
    *plen = data[1] & 0x7F;
    *at = 2;
    if (*plen == 126) {
        if (len < 4)
            return 0;
        *plen = (uint64_t)data[2] << 8 | data[3];
        *at = 4;
    } else if (*plen == 127) {
        if (len < 10)
            return 0;
        *plen = 0;
        for (int i = 2; i < 10; i++)
            *plen = *plen << 8 | data[i];
        *at = 10;
    }
    return 1;
}

size_t ws_frame_need(const uint8_t *data, size_t len)
{
    size_t at;
    uint64_t plen;
    if (len < 2)
        return 2;
    if (!frame_length(data, len, &at, &plen))
        return (data[1] & 0x7F) == 126 ? 4 : 10;
    return at + (data[1] & 0x80 ? 4u : 0u) + (size_t)plen;
}

static ssize_t refuse(ws_reader *r, uint16_t code, int rc, char *err, size_t errlen, const char *what)
{
    r->close_code = code;
    return cvre_fail(err, errlen, rc, "%s", what);
}

int ws_close_code_valid(unsigned code)
{
    return (code >= 1000 && code <= 1003) || (code >= 1007 && code <= 1011) || (code >= 3000 && code <= 4999);
}

static int utf8_valid(const uint8_t *s, size_t n)
{
    uint32_t cp;
    for (size_t k; n > 0; s += k, n -= k)
        if ((k = utf8_next(s, n, &cp)) == 0)
            return 0;
    return 1;
}

/* A close frame's payload: empty, or a code the wire may carry and a
 * UTF-8 reason (5.5.1, 7.4). */
static ssize_t read_close(ws_reader *r, const uint8_t *p, size_t n, ws_event *ev, char *err, size_t errlen)
{
    *ev = (ws_event){.type = WS_EV_CLOSE};
    if (n == 0)
        return 0;
    if (n == 1)
        return refuse(r, WS_CLOSE_PROTOCOL, -EPROTO, err, errlen, "a close frame of one byte");
    unsigned code = (unsigned)p[0] << 8 | p[1];
    /* A server may also say 1012-1014 (IANA's registry); this one says
     * 1013 when it is full. */
    if (!ws_close_code_valid(code) && !(r->of_server && code >= 1012 && code <= 1014)) {
        r->close_code = WS_CLOSE_PROTOCOL;
        return cvre_fail(err, errlen, -EPROTO, "close code %u is never sent", code);
    }
    if (!utf8_valid(p + 2, n - 2))
        return refuse(r, WS_CLOSE_BAD_DATA, -EILSEQ, err, errlen, "a close reason that is not UTF-8");
    *ev = (ws_event){.type = WS_EV_CLOSE, .code = (uint16_t)code, .data = p + 2, .len = n - 2};
    return 0;
}

/* Appends a fragment to the message under way; the cap was checked. */
static int keep_fragment(ws_reader *r, const uint8_t *p, size_t n)
{
    if (r->msg_len + n > r->msg_alloc) {
        size_t want = r->msg_alloc ? r->msg_alloc : 1024;
        while (want < r->msg_len + n)
            want *= 2;
        if (want > r->cap)
            want = r->cap;
        uint8_t *m = cvre_realloc(r->msg, want);
        if (!m)
            return -ENOMEM;
        r->msg = m;
        r->msg_alloc = want;
    }
    if (n)
        memcpy(r->msg + r->msg_len, p, n);
    r->msg_len += n;
    return 0;
}

ssize_t ws_read(ws_reader *r, uint8_t *data, size_t len, ws_event *ev, char *err, size_t errlen)
{
    *ev = (ws_event){.type = WS_EV_NONE};
    if (len < 2)
        return 0;
    unsigned fin = data[0] >> 7, rsv = (data[0] >> 4) & 7, op = data[0] & 0xF;
    unsigned masked = data[1] >> 7;
    uint64_t plen = data[1] & 0x7F;
    if (rsv)
        return refuse(r, WS_CLOSE_PROTOCOL, -EPROTO, err, errlen, "reserved bits set (no extension was agreed)");
    int control = op >= 0x8;
    if (op != WS_OP_CONTINUATION && op != WS_OP_TEXT && op != WS_OP_BINARY && op != WS_OP_CLOSE &&
        op != WS_OP_PING && op != WS_OP_PONG) {
        r->close_code = WS_CLOSE_PROTOCOL;
        return cvre_fail(err, errlen, -EPROTO, "unknown opcode %#x", op);
    }
    if (masked == (unsigned)r->of_server)
        return refuse(r, WS_CLOSE_PROTOCOL, -EPROTO, err, errlen,
                      masked ? "a server frame that is masked" : "a client frame that is not masked");
    if (control && !fin)
        return refuse(r, WS_CLOSE_PROTOCOL, -EPROTO, err, errlen, "a fragmented control frame");
    if (control && plen > WS_CONTROL_MAX)
        return refuse(r, WS_CLOSE_PROTOCOL, -EPROTO, err, errlen, "a control frame over 125 bytes");
    if (op == WS_OP_TEXT)
        return refuse(r, WS_CLOSE_UNSUPPORTED, -EOPNOTSUPP, err, errlen, "a text message (binary only)");
    if (op == WS_OP_CONTINUATION && !r->fragmented)
        return refuse(r, WS_CLOSE_PROTOCOL, -EPROTO, err, errlen, "a continuation with no message under way");
    if (op == WS_OP_BINARY && r->fragmented)
        return refuse(r, WS_CLOSE_PROTOCOL, -EPROTO, err, errlen, "a new message inside a fragmented one");
    size_t at;
    if (!frame_length(data, len, &at, &plen))
        return 0;
    if (at == 4 && plen < 126)
        return refuse(r, WS_CLOSE_PROTOCOL, -EPROTO, err, errlen, "a 16-bit length under 126");
    if (at == 10 && plen >> 63)
        return refuse(r, WS_CLOSE_PROTOCOL, -EPROTO, err, errlen, "a 64-bit length with its top bit set");
    if (at == 10 && plen <= 0xFFFF)
        return refuse(r, WS_CLOSE_PROTOCOL, -EPROTO, err, errlen, "a 64-bit length under 65536");
    /* The cap, from the header alone: nothing waits for or keeps more. */
    size_t so_far = r->fragmented ? r->msg_len : 0;
    if (!control && plen > r->cap - so_far) {
        r->close_code = WS_CLOSE_TOO_BIG;
        return cvre_fail(err, errlen, -EMSGSIZE, "a message of at least %llu bytes, at most %zu",
                         (unsigned long long)(so_far + plen), r->cap);
    }
    size_t key = masked ? 4 : 0;
    if (len - at < key || len - at - key < plen)
        return 0;
    uint8_t *p = data + at + key;
    if (masked)
        apply_mask(p, (size_t)plen, data + at);
    size_t n = (size_t)plen, took = at + key + n;
    switch (op) {
    case WS_OP_CLOSE: {
        ssize_t rc = read_close(r, p, n, ev, err, errlen);
        return rc < 0 ? rc : (ssize_t)took;
    }
    case WS_OP_PING:
    case WS_OP_PONG:
        *ev = (ws_event){.type = op == WS_OP_PING ? WS_EV_PING : WS_EV_PONG, .data = p, .len = n};
        return (ssize_t)took;
    default: /* binary, or a continuation of binary */
        if (fin && !r->fragmented) {
            *ev = (ws_event){.type = WS_EV_MESSAGE, .data = p, .len = n};
            return (ssize_t)took;
        }
        if (keep_fragment(r, p, n) < 0)
            return refuse(r, WS_CLOSE_INTERNAL, -ENOMEM, err, errlen, "no memory for a fragmented message");
        r->fragmented = !fin;
        if (fin) {
            *ev = (ws_event){.type = WS_EV_MESSAGE, .data = r->msg, .len = r->msg_len};
            r->msg_len = 0;
        }
        return (ssize_t)took;
    }
}

/* ---- the server's frames ----------------------------------------------------- */

/* The header of a frame with a payload of len bytes, without its mask: 2,
 * 4 or 10 bytes; the mask bit is set when masked. */
static size_t put_header(uint8_t out[WS_SERVER_HEADER_MAX], unsigned opcode, uint64_t len, int masked)
{
    uint8_t m = masked ? 0x80 : 0;
    out[0] = (uint8_t)(0x80 | (opcode & 0xF));
    if (len < 126) {
        out[1] = (uint8_t)(m | len);
        return 2;
    }
    if (len <= 0xFFFF) {
        out[1] = m | 126;
        out[2] = (uint8_t)(len >> 8);
        out[3] = (uint8_t)len;
        return 4;
    }
    out[1] = m | 127;
    for (int i = 0; i < 8; i++)
        out[2 + i] = (uint8_t)(len >> (56 - 8 * i));
    return 10;
}

size_t ws_header(uint8_t out[WS_SERVER_HEADER_MAX], unsigned opcode, uint64_t len)
{
    return put_header(out, opcode, len, 0);
}

int ws_control(uint8_t *out, size_t cap, unsigned opcode, const uint8_t *payload, size_t len)
{
    if (len > WS_CONTROL_MAX)
        return -EINVAL;
    if (cap < 2 + len)
        return -ENOSPC;
    size_t h = ws_header(out, opcode, len);
    if (len)
        memcpy(out + h, payload, len);
    return (int)(h + len);
}

/* A close frame's payload: code and reason (cut to fit, at a character
 * boundary), or nothing for code 0. Returns its length. */
static size_t close_body(uint8_t body[WS_CONTROL_MAX], uint16_t code, const char *reason)
{
    size_t n = 0;
    if (code) {
        body[n++] = (uint8_t)(code >> 8);
        body[n++] = (uint8_t)code;
        /* The reason, whole characters only, as long as it fits. */
        const uint8_t *s = (const uint8_t *)(reason ? reason : "");
        size_t left = strlen((const char *)s);
        uint32_t cp;
        for (size_t k; left > 0 && (k = utf8_next(s, left, &cp)) > 0 && n + k <= WS_CONTROL_MAX; s += k, left -= k) {
            memcpy(body + n, s, k);
            n += k;
        }
    }
    return n;
}

int ws_close_frame(uint8_t *out, size_t cap, uint16_t code, const char *reason)
{
    uint8_t body[WS_CONTROL_MAX];
    return ws_control(out, cap, WS_OP_CLOSE, body, close_body(body, code, reason));
}

/* ---- the client's side ------------------------------------------------------ */

int ws_client_request(char *out, size_t cap, const char *host, const char *path, char key[WS_KEY_SIZE])
{
    uint8_t nonce[16];
    if (RAND_bytes(nonce, sizeof nonce) != 1)
        return -EIO; /* GCOVR_EXCL_LINE: libcrypto's random source failed */
    _Static_assert(4 * ((sizeof nonce + 2) / 3) + 1 == WS_KEY_SIZE, "the key's size");
    EVP_EncodeBlock((unsigned char *)key, nonce, sizeof nonce);
    int n = snprintf(out, cap,
                     "GET %s HTTP/1.1\r\nHost: %s\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                     "Sec-WebSocket-Key: %s\r\nSec-WebSocket-Version: 13\r\n\r\n",
                     path, host, key);
    return n >= 0 && (size_t)n < cap ? n : -ENOSPC;
}

/* The end of the head in data[0..len): the bytes up to and including its
 * blank line, or 0 if it has none. */
static size_t head_end(const uint8_t *data, size_t len)
{
    for (size_t i = 3; i < len; i++)
        if (data[i] == '\n' && data[i - 1] == '\r' && data[i - 2] == '\n' && data[i - 3] == '\r')
            return i + 1;
    return 0;
}

int ws_client_response(const uint8_t *data, size_t len, const char *key, char *err, size_t errlen)
{
    size_t head = head_end(data, len < WS_RESPONSE_MAX ? len : WS_RESPONSE_MAX);
    if (head == 0)
        return len >= WS_RESPONSE_MAX
                   ? cvre_fail(err, errlen, -EMSGSIZE, "a response head of %u bytes or more", WS_RESPONSE_MAX)
                   : 0;
    if (memchr(data, 0, head))
        return cvre_fail(err, errlen, -EPROTO, "a NUL in the response head");
    char buf[WS_RESPONSE_MAX];
    memcpy(buf, data, head - 2); /* the lines, each with its CRLF, without the blank one */
    buf[head - 2] = 0;
    char *line = buf, *eol = strstr(line, "\r\n");
    *eol = 0;
    if (strncmp(line, "HTTP/1.1 101", 12) != 0 || (line[12] != ' ' && line[12] != 0))
        return cvre_fail(err, errlen, -EPROTO, "the server answered \"%.80s\", not 101", line);
    const char *upgrade = NULL, *connection = NULL, *accept = NULL;
    for (line = eol + 2; *line; line = eol + 2) {
        eol = strstr(line, "\r\n");
        *eol = 0;
        char *colon = strchr(line, ':');
        if (!colon)
            return cvre_fail(err, errlen, -EPROTO, "a header line without a colon: \"%.80s\"", line);
        *colon = 0;
        char *value = colon + 1 + strspn(colon + 1, " \t");
        for (char *t = value + strlen(value); t > value && (t[-1] == ' ' || t[-1] == '\t');)
            *--t = 0;
        if (strcasecmp(line, "upgrade") == 0)
            upgrade = value;
        else if (strcasecmp(line, "connection") == 0)
            connection = value;
        else if (strcasecmp(line, "sec-websocket-accept") == 0)
            accept = value;
        else if (strcasecmp(line, "sec-websocket-extensions") == 0 || strcasecmp(line, "sec-websocket-protocol") == 0)
            return cvre_fail(err, errlen, -EPROTO, "%s, which the client did not ask for", line);
    }
    if (!ws_asks_upgrade(upgrade))
        return cvre_fail(err, errlen, -EPROTO, "no \"Upgrade: websocket\" in the 101");
    if (!connection || !ws_list_has(connection, "upgrade"))
        return cvre_fail(err, errlen, -EPROTO, "no \"Connection: Upgrade\" in the 101");
    char want[WS_ACCEPT_SIZE];
    if (ws_accept_key(key, strlen(key), want) < 0)
        return cvre_fail(err, errlen, -EIO, "libcrypto could not hash the key"); /* GCOVR_EXCL_LINE */
    if (!accept || strcmp(accept, want) != 0)
        return cvre_fail(err, errlen, -EPROTO, "Sec-WebSocket-Accept %.40s, not %s", accept ? accept : "missing",
                         want);
    return (int)head;
}

int ws_client_frame(uint8_t *out, size_t cap, unsigned opcode, const uint8_t *payload, size_t len)
{
    if (opcode >= WS_OP_CLOSE && len > WS_CONTROL_MAX)
        return -EINVAL;
    size_t h = len < 126 ? 2 : len <= 0xFFFF ? 4 : 10;
    if (cap < h + 4 || cap - h - 4 < len || len > (size_t)INT_MAX - 14)
        return -ENOSPC;
    put_header(out, opcode, len, 1);
    uint8_t *key = out + h;
    if (RAND_bytes(key, 4) != 1)
        return -EIO; /* GCOVR_EXCL_LINE: libcrypto's random source failed */
    if (len)
        memcpy(key + 4, payload, len);
    apply_mask(key + 4, len, key);
    return (int)(h + 4 + len);
}

int ws_client_close_frame(uint8_t *out, size_t cap, uint16_t code, const char *reason)
{
    uint8_t body[WS_CONTROL_MAX];
    return ws_client_frame(out, cap, WS_OP_CLOSE, body, close_body(body, code, reason));
}
