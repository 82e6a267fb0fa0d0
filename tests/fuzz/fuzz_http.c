/*
 * fuzz_http.c: structure-aware fuzz target for the HTTP request head
 * (server/net/http.c over Debian's http_parser), which every HTTP endpoint
 * (--metrics now, the web client's next) feeds with a stranger's bytes.
 *
 * Inputs are request heads. The generator writes a request line (known,
 * unknown and lower-case methods; origin, absolute, authority and asterisk
 * targets, long ones, ones with spaces, %00 and ../; HTTP/1.1, 1.0, 2.0,
 * 0.9 and garbage versions), then headers: Host, Content-Length (0, 5,
 * negative, past 2^64, twice), Transfer-Encoding, Connection, Upgrade and
 * the WebSocket ones, fillers up to past the head's cap, folded lines,
 * lines without a colon, blanks before the colon, one header past the
 * count cap; CRLF, LF or CR line ends; sometimes a body and a second
 * request behind. The mutator changes lines (fz_mutate_text).
 *
 * Each input is fed three ways, whole, a byte at a time, and in chunks
 * whose sizes the input decides, and the results must agree (same_result):
 * one of http.h's, and for a complete request the same method, target,
 * path and Host, a target within HTTP_URL_MAX, a Host without surrounding
 * blanks, and a response head that fits.
 */
#include <stdio.h>
#include <string.h>

#include "fz.h"
#include "http.h"

/* Header lines: the well-formed ones first (GOOD of them), then the
 * hostile ones. */
static const char *const templates[] = {
    "Host: %n",
    "Host: \t %n \t",
    "User-Agent: %n/%f",
    "Accept: */*",
    "Content-Length: 0",
    "Connection: close",
    "Connection: keep-alive, Upgrade",
    "Upgrade: websocket",
    "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==",
    "Sec-WebSocket-Version: 13",
    "%n: %n",
    "%n:%f",
    "X-%n: %%00%%2e%%2e/../%n",
    " folded %n",
    "Host:",
    "Content-Length: %c",
    "Content-Length: -%c",
    "Content-Length: 99999999999999999999999",
    "Transfer-Encoding: chunked",
    "Transfer-Encoding: gzip, chunked",
    "%n : %n",
    "%n",
    "\tfolded",
    ": %n",
    "GET /%n HTTP/1.1",
    "GET http://%n/%n?%n=%f HTTP/1.0",
};
#define NTEMPLATES (sizeof templates / sizeof templates[0])
#define GOOD 14

/* Request line parts: the first GOOD_* of each are well-formed. */
static const char *const methods[] = {"GET", "POST", "HEAD", "PUT", "DELETE", "OPTIONS", "PATCH", "CONNECT",
                                      "get", "BREW", "", "GET GET", "M-SEARCH", "PRI"};
#define GOOD_METHODS 7
static const char *const targets[] = {"/metrics", "/metrics?x=1", "/", "/metrics/", "http://h:9100/metrics",
                                      "https://h", "/../../etc/passwd", "/%2e%2e/%2e%2e", "*", "h:443", "/a b",
                                      "/%00", "", "//", "/\x7f", "/?#frag"};
#define GOOD_TARGETS 8
static const char *const versions[] = {"HTTP/1.1", "HTTP/1.0", "HTTP/2.0", "HTTP/0.9", "HTTP/1.10",
                                       "HTTP/1",   "http/1.1", "HTTP/1.1 ", "",        "HTTP/999.999"};
#define GOOD_VERSIONS 2

/* An entry of list[0..n): one of the first good ones, mostly. */
static const char *pick(const char *const *list, uint32_t n, uint32_t good)
{
    return list[fz_one_in(4) ? fz_below(n) : fz_below(good)];
}

static const char *eol(void)
{
    return fz_one_in(16) ? (fz_one_in(2) ? "\n" : "\r") : "\r\n";
}

static size_t http_generate(uint8_t *out, size_t max)
{
    fz_buf b = {out, 0, max};
    fz_text t = {templates, NTEMPLATES, 8, 0};
    const char *e = eol();
    fz_printf(&b, "%s ", pick(methods, sizeof methods / sizeof methods[0], GOOD_METHODS));
    if (fz_one_in(16)) { /* a target at or past HTTP_URL_MAX */
        uint32_t n = HTTP_URL_MAX - 2 + fz_below(4);
        fz_puts(&b, "/");
        for (uint32_t i = 0; i < n; i++)
            fz_puts(&b, "u");
    } else {
        fz_puts(&b, pick(targets, sizeof targets / sizeof targets[0], GOOD_TARGETS));
    }
    fz_printf(&b, " %s%s", pick(versions, sizeof versions / sizeof versions[0], GOOD_VERSIONS), e);
    if (!fz_one_in(8))
        fz_printf(&b, "Host: 127.0.0.1:9100%s", e);
    uint32_t nheaders = fz_one_in(8) ? HTTP_HEADERS_MAX - 2 + fz_below(4) : fz_below(8);
    for (uint32_t i = 0; i < nheaders && b.len < b.cap; i++) {
        fz_expand(&b, fz_one_in(16) ? templates[fz_below(NTEMPLATES)] : templates[fz_below(GOOD)], &t);
        fz_puts(&b, fz_one_in(32) ? eol() : e);
    }
    if (fz_one_in(8) && b.len + 24 < HTTP_HEAD_MAX) { /* a head within 12 bytes of HTTP_HEAD_MAX */
        size_t fill = HTTP_HEAD_MAX - b.len - 24 + fz_below(24);
        fz_puts(&b, "X-Fill: ");
        for (size_t i = 0; i < fill && b.len < b.cap; i++)
            fz_puts(&b, "f");
        fz_puts(&b, e);
    }
    fz_puts(&b, e);
    if (fz_one_in(8))
        fz_puts(&b, "hello");
    if (fz_one_in(8))
        fz_printf(&b, "GET /second HTTP/1.1%sHost: h%s%s", e, e, e);
    return b.len;
}

static size_t http_mutate(uint8_t *data, size_t size, size_t max)
{
    fz_text t = {templates, NTEMPLATES, 8, 0};
    return fz_mutate_text(data, size, max, &t);
}

/* What the inputs came to, for the report. */
static unsigned long n_inputs, n_complete, n_refused[600];

/* The result of feeding data[0..size) in pieces: whole (step 0), or
 * pieces of 1, 2, ... step bytes in turn; checks a complete request and
 * writes what it kept to kept (method, target, path, Host). */
static int feed(const uint8_t *data, size_t size, size_t step, char kept[HTTP_HEAD_MAX])
{
    http_request *r = http_request_new();
    int rc = HTTP_INCOMPLETE;
    FZ_CHECK(r);
    for (size_t at = 0, k = 1; at < size && rc == HTTP_INCOMPLETE;) {
        size_t n = step ? k : size;
        if (n > size - at)
            n = size - at;
        rc = http_request_feed(r, data + at, n);
        at += n;
        if (step)
            k = k % step + 1;
    }
    FZ_CHECK(rc == HTTP_INCOMPLETE || rc == HTTP_COMPLETE || rc == 400 || rc == 413 || rc == 414 || rc == 431 ||
             rc == 505);
    FZ_CHECK(rc == HTTP_INCOMPLETE || http_request_feed(r, data, size) == rc); /* final */
    kept[0] = 0;
    if (rc == HTTP_COMPLETE) {
        char head[512];
        const char *host = http_request_header(r, "host");
        FZ_CHECK(http_request_method(r)[0]);
        FZ_CHECK(http_request_path(r)[0]);
        FZ_CHECK(strlen(http_request_target(r)) <= HTTP_URL_MAX);
        FZ_CHECK(strlen(http_request_path(r)) <= strlen(http_request_target(r)));
        FZ_CHECK(http_response_head(head, sizeof head, 200, "text/plain", size, NULL) > 0);
        if (host && *host) /* values come without surrounding blanks */
            FZ_CHECK(!strchr(" \t", host[0]) && !strchr(" \t", host[strlen(host) - 1]));
        snprintf(kept, HTTP_HEAD_MAX, "%s %s %s %s", http_request_method(r), http_request_target(r),
                 http_request_path(r), host ? host : "-");
    }
    http_request_free(r);
    return rc;
}

/* A head both malformed and over a limit may be refused for either,
 * depending on where the reads cut it: http_parser hands over a string
 * piece by piece, and stops at a bad byte without handing over what came
 * before it in that read. Any other difference is a bug. */
static int same_result(int a, int b)
{
    int limit_a = a == 414 || a == 431, limit_b = b == 414 || b == 431;
    return a == b || (a == 400 && limit_b) || (b == 400 && limit_a);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static char kept_whole[HTTP_HEAD_MAX], kept[HTTP_HEAD_MAX];
    int whole = feed(data, size, 0, kept_whole);
    size_t steps[2] = {1, size ? 2u + data[size / 2] % 61u : 2u};
    for (int i = 0; i < 2; i++) {
        FZ_CHECK(same_result(feed(data, size, steps[i], kept), whole));
        FZ_CHECK(strcmp(kept, kept_whole) == 0);
    }
    n_inputs++;
    if (whole == HTTP_COMPLETE)
        n_complete++;
    else if (whole != HTTP_INCOMPLETE)
        n_refused[whole]++;
    return 0;
}

/* If "complete" drops to near zero, inputs no longer get past the
 * request line. */
static void http_report(void)
{
    fprintf(stderr, "fuzz_http: %lu heads, %lu complete, refused 400 %lu, 413 %lu, 414 %lu, 431 %lu, 505 %lu\n",
            n_inputs, n_complete, n_refused[400], n_refused[413], n_refused[414], n_refused[431], n_refused[505]);
}

const fz_target fz_self = {"fuzz_http", NULL, http_generate, http_mutate, NULL, http_report, NULL};
