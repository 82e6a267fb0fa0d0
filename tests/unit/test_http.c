/* The HTTP request head (server/net/http.c): what it keeps, every refusal and
 * its status, every limit at and past its bound, fed whole and in pieces. */
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
#include "http.h"

/* Feeds text whole into a new request; returns the result and the request
 * in *out (to free). */
static int feed_whole(const char *text, size_t len, http_request **out)
{
    http_request *r = http_request_new();
    assert_non_null(r);
    int rc = http_request_feed(r, (const uint8_t *)text, len);
    *out = r;
    return rc;
}

/* The same, one byte at a time: the result comes at the byte that decides
 * it and stays. */
static int feed_bytes(const char *text, size_t len, http_request **out)
{
    http_request *r = http_request_new();
    assert_non_null(r);
    int rc = HTTP_INCOMPLETE;
    for (size_t i = 0; i < len && rc == HTTP_INCOMPLETE; i++)
        rc = http_request_feed(r, (const uint8_t *)text + i, 1);
    *out = r;
    return rc;
}

/* Feeds text whole, byte by byte and split at every point in two: the
 * result must be the same each way. Returns it. */
static int result_of(const char *text)
{
    size_t len = strlen(text);
    http_request *r;
    int whole = feed_whole(text, len, &r);
    http_request_free(r);
    int bytes = feed_bytes(text, len, &r);
    http_request_free(r);
    assert_int_equal(whole, bytes);
    for (size_t cut = 1; cut < len && len < 600; cut++) {
        r = http_request_new();
        assert_non_null(r);
        int rc = http_request_feed(r, (const uint8_t *)text, cut);
        if (rc == HTTP_INCOMPLETE)
            rc = http_request_feed(r, (const uint8_t *)text + cut, len - cut);
        assert_int_equal(rc, whole);
        http_request_free(r);
    }
    return whole;
}

static void test_get_is_kept(void **state)
{
    (void)state;
    const char *text = "GET /metrics?x=1&y=%41 HTTP/1.1\r\n"
                       "Host: 127.0.0.1:9100\r\n"
                       "User-Agent: Prometheus/2.45.0\r\n"
                       "Accept:   text/plain  \t\r\n"
                       "X-Empty:\r\n"
                       "X-Folded: first\r\n  second\r\n"
                       "X-Folded-Empty:\r\n  only\r\n"
                       "x-twice: first\r\n"
                       "X-Twice: second\r\n"
                       "\r\n";
    assert_int_equal(result_of(text), HTTP_COMPLETE);
    for (int way = 0; way < 2; way++) {
        http_request *r;
        int rc = way ? feed_bytes(text, strlen(text), &r) : feed_whole(text, strlen(text), &r);
        assert_int_equal(rc, HTTP_COMPLETE);
        assert_string_equal(http_request_method(r), "GET");
        assert_string_equal(http_request_target(r), "/metrics?x=1&y=%41");
        assert_string_equal(http_request_path(r), "/metrics");
        assert_string_equal(http_request_header(r, "host"), "127.0.0.1:9100");
        assert_string_equal(http_request_header(r, "USER-AGENT"), "Prometheus/2.45.0");
        assert_string_equal(http_request_header(r, "Accept"), "text/plain");
        assert_string_equal(http_request_header(r, "x-empty"), "");
        /* Obsolete line folding (RFC 9112 5.2): the continuation's blanks
         * stay inside a value, and go at its start. */
        assert_string_equal(http_request_header(r, "x-folded"), "first  second");
        assert_string_equal(http_request_header(r, "x-folded-empty"), "only");
        assert_string_equal(http_request_header(r, "X-Twice"), "first");
        assert_null(http_request_header(r, "Cookie"));
        assert_null(http_request_header(r, "Hos"));
        http_request_free(r);
    }
}

static void test_targets(void **state)
{
    (void)state;
    static const struct {
        const char *text, *method, *path;
    } cases[] = {
        {"GET / HTTP/1.0\r\n\r\n", "GET", "/"},
        {"GET http://example.org:9100/metrics?a=b HTTP/1.1\r\nHost: example.org\r\n\r\n", "GET", "/metrics"},
        {"GET http://example.org HTTP/1.1\r\nHost: example.org\r\n\r\n", "GET", "/"},
        {"OPTIONS * HTTP/1.1\r\nHost: h\r\n\r\n", "OPTIONS", "*"},
        {"CONNECT example.org:443 HTTP/1.1\r\nHost: example.org\r\n\r\n", "CONNECT", "example.org:443"},
        {"POST /metrics HTTP/1.1\r\nHost: h\r\nContent-Length: 0\r\n\r\n", "POST", "/metrics"},
        {"DELETE /a/../b%2e%2e HTTP/1.1\r\nHost: h\r\n\r\n", "DELETE", "/a/../b%2e%2e"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        http_request *r;
        assert_int_equal(result_of(cases[i].text), HTTP_COMPLETE);
        assert_int_equal(feed_whole(cases[i].text, strlen(cases[i].text), &r), HTTP_COMPLETE);
        assert_string_equal(http_request_method(r), cases[i].method);
        assert_string_equal(http_request_path(r), cases[i].path);
        http_request_free(r);
    }
}

static void test_refusals(void **state)
{
    (void)state;
    static const struct {
        const char *text;
        int status;
    } cases[] = {
        {"GARBAGE\r\n\r\n", 400},
        {"GET\r\n\r\n", 400},
        {"GET / HTTP/1.1\r\n\r\n", 400},                            /* 1.1 without Host */
        {"GET / HTTP/1.1\r\nHost: h\r\nNo colon here\r\n\r\n", 400},
        {"GET / HTTP/1.1\r\nHo st: h\r\n\r\n", 400},
        {"GET /a b HTTP/1.1\r\nHost: h\r\n\r\n", 400},
        {"GET / HTTP/1.1\r\nHost: h\r\nX: a\001b\r\n\r\n", 400},    /* a control character */
        {"GET / FTP/1.1\r\nHost: h\r\n\r\n", 400},
        {"BREW /pot HTTP/1.1\r\nHost: h\r\n\r\n", 400},
        {"GET / HTTP/2.0\r\nHost: h\r\n\r\n", 505},
        {"GET / HTTP/0.9\r\nHost: h\r\n\r\n", 505},
        {"POST / HTTP/1.1\r\nHost: h\r\nContent-Length: 5\r\n\r\nhello", 413},
        {"POST / HTTP/1.1\r\nHost: h\r\nTransfer-Encoding: chunked\r\n\r\n0\r\n\r\n", 413},
        {"GET / HTTP/1.1\r\nHost: h\r\nContent-Length: 1\r\nContent-Length: 2\r\n\r\n", 400},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        int rc = result_of(cases[i].text);
        if (rc != cases[i].status)
            fail_msg("case %zu (%s): %d, not %d", i, cases[i].text, rc, cases[i].status);
    }
    /* A NUL anywhere in the head. */
    static const char nul[] = "GET / HTTP/1.1\r\nHost: h\0x\r\n\r\n";
    http_request *r;
    assert_int_equal(feed_whole(nul, sizeof nul - 1, &r), 400);
    http_request_free(r);
}

#define FILL_START "GET / HTTP/1.1\r\nHost: h\r\nX-Fill: "

/* A head of exactly len bytes: a request line, Host, and one filler
 * header that makes up the rest. */
static char *head_of(size_t len)
{
    char *p = malloc(len + 1);
    assert_non_null(p);
    size_t n = strlen(FILL_START);
    assert_true(len >= n + 4);
    memcpy(p, FILL_START, n);
    memset(p + n, 'a', len - n - 4);
    memcpy(p + len - 4, "\r\n\r\n", 5);
    return p;
}

static void test_head_limit(void **state)
{
    (void)state;
    char *at = head_of(HTTP_HEAD_MAX), *over = head_of(HTTP_HEAD_MAX + 1);
    http_request *r;
    assert_int_equal(feed_whole(at, HTTP_HEAD_MAX, &r), HTTP_COMPLETE);
    assert_int_equal(strlen(http_request_header(r, "x-fill")), HTTP_HEAD_MAX - strlen(FILL_START) - 4);
    http_request_free(r);
    assert_int_equal(feed_bytes(at, HTTP_HEAD_MAX, &r), HTTP_COMPLETE);
    http_request_free(r);
    assert_int_equal(feed_whole(over, HTTP_HEAD_MAX + 1, &r), 431);
    http_request_free(r);
    assert_int_equal(feed_bytes(over, HTTP_HEAD_MAX + 1, &r), 431);
    http_request_free(r);
    /* A head that never ends is refused as soon as it passes the cap,
     * however it arrives; nothing more is read. */
    r = http_request_new();
    assert_non_null(r);
    int rc = HTTP_INCOMPLETE;
    size_t fed = 0;
    while (rc == HTTP_INCOMPLETE) {
        rc = http_request_feed(r, (const uint8_t *)over, 1000);
        fed += 1000;
    }
    assert_int_equal(rc, 431);
    assert_true(fed <= HTTP_HEAD_MAX + 1000);
    assert_int_equal(http_request_feed(r, (const uint8_t *)at, 10), 431);
    http_request_free(r);
    free(at);
    free(over);
}

static void test_target_limit(void **state)
{
    (void)state;
    char text[HTTP_URL_MAX + 64];
    http_request *r;
    for (size_t len = HTTP_URL_MAX; len <= HTTP_URL_MAX + 1; len++) {
        memcpy(text, "GET /", 5);
        memset(text + 5, 'u', len - 1);
        snprintf(text + 4 + len, sizeof text - 4 - len, " HTTP/1.1\r\nHost: h\r\n\r\n");
        int rc = feed_whole(text, strlen(text), &r);
        assert_int_equal(rc, len == HTTP_URL_MAX ? HTTP_COMPLETE : 414);
        if (rc == HTTP_COMPLETE)
            assert_int_equal(strlen(http_request_target(r)), HTTP_URL_MAX);
        http_request_free(r);
        assert_int_equal(feed_bytes(text, strlen(text), &r), rc);
        http_request_free(r);
    }
}

static void test_header_count_limit(void **state)
{
    (void)state;
    char text[4096];
    http_request *r;
    for (unsigned n = HTTP_HEADERS_MAX; n <= HTTP_HEADERS_MAX + 1; n++) {
        size_t len = (size_t)snprintf(text, sizeof text, "GET / HTTP/1.1\r\nHost: h\r\n");
        for (unsigned i = 1; i < n; i++)
            len += (size_t)snprintf(text + len, sizeof text - len, "X-%u: %u\r\n", i, i);
        len += (size_t)snprintf(text + len, sizeof text - len, "\r\n");
        int rc = feed_whole(text, len, &r);
        assert_int_equal(rc, n == HTTP_HEADERS_MAX ? HTTP_COMPLETE : 431);
        if (rc == HTTP_COMPLETE) {
            char name[16];
            snprintf(name, sizeof name, "x-%u", n - 1);
            assert_string_equal(http_request_header(r, name), name + 2);
        }
        http_request_free(r);
    }
}

/* One request per connection: what follows the head is not parsed, and a
 * result, once there, does not change. */
static void test_result_is_final(void **state)
{
    (void)state;
    const char *text = "GET /a HTTP/1.1\r\nHost: h\r\n\r\nGET /b HTTP/1.1\r\nHost: h\r\n\r\nGARBAGE";
    http_request *r;
    assert_int_equal(feed_whole(text, strlen(text), &r), HTTP_COMPLETE);
    assert_string_equal(http_request_path(r), "/a");
    assert_int_equal(http_request_feed(r, (const uint8_t *)"\0\0\0", 3), HTTP_COMPLETE);
    assert_string_equal(http_request_path(r), "/a");
    http_request_free(r);
    assert_int_equal(feed_whole("GARBAGE\r\n", 9, &r), 400);
    assert_int_equal(http_request_feed(r, (const uint8_t *)"GET / HTTP/1.0\r\n\r\n", 18), 400);
    assert_int_equal(http_request_feed(r, (const uint8_t *)"", 0), 400);
    http_request_free(r);
    r = http_request_new();
    assert_non_null(r);
    assert_int_equal(http_request_feed(r, (const uint8_t *)"", 0), HTTP_INCOMPLETE);
    http_request_free(r);
}

static void test_response_head(void **state)
{
    (void)state;
    char out[256];
    int n = http_response_head(out, sizeof out, 200, "text/plain", 42, NULL);
    const char *want = "HTTP/1.1 200 OK\r\nContent-Type: text/plain\r\nContent-Length: 42\r\nConnection: close\r\n\r\n";
    assert_int_equal(n, (int)strlen(want));
    assert_string_equal(out, want);
    n = http_response_head(out, sizeof out, 405, NULL, 0, "Allow: GET\r\n");
    want = "HTTP/1.1 405 Method Not Allowed\r\nContent-Length: 0\r\nConnection: close\r\nAllow: GET\r\n\r\n";
    assert_int_equal(n, (int)strlen(want));
    assert_string_equal(out, want);
    assert_string_equal(http_reason(431), "Request Header Fields Too Large");
    assert_string_equal(http_reason(408), "Request Timeout");
    /* Exactly the size, and one byte short (the NUL needs its byte too). */
    n = http_response_head(out, sizeof out, 404, NULL, 7, NULL);
    char small[256];
    assert_int_equal(http_response_head(small, (size_t)n + 1, 404, NULL, 7, NULL), n);
    assert_int_equal(http_response_head(small, (size_t)n, 404, NULL, 7, NULL), -ENOSPC);
}

static void test_out_of_memory(void **state)
{
    (void)state;
    cvre_alloc_fail_after(0);
    assert_null(http_request_new());
    cvre_alloc_fail_after(-1);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_get_is_kept),       cmocka_unit_test(test_targets),
        cmocka_unit_test(test_refusals),          cmocka_unit_test(test_head_limit),
        cmocka_unit_test(test_target_limit),      cmocka_unit_test(test_header_count_limit),
        cmocka_unit_test(test_result_is_final),   cmocka_unit_test(test_response_head),
        cmocka_unit_test(test_out_of_memory),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
