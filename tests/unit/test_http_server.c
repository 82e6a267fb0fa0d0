/* The HTTP endpoint (server/net/http_server.c) on a real event loop, in
 * process, with its deadlines shortened to 300 ms (CMake): a client thread
 * does blocking socket I/O while the test's thread runs the loop. Large
 * responses to slow and half-closed readers, a body past the cap, the
 * request deadline, the linger deadline freeing a slot, a reset peer,
 * running out of memory at each allocation of a connection and of the
 * endpoint, running out of file descriptors, and a loop that cannot
 * watch the socket. */
#define _GNU_SOURCE /* pipe2 */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <time.h>
#include <unistd.h>

#include "alloc.h"
#include "http_server.h"
#include "net_limits.h"

_Static_assert(HTTP_REQUEST_TIMEOUT_MS == 300 && HTTP_LINGER_MS == 300, "the test's deadlines (tests/CMakeLists.txt)");

/* The client thread cannot use cmocka's asserts (they jump to the test's
 * frame on the other thread): a failed check there names itself and
 * aborts. */
#define check(c)                                                                                   \
    do {                                                                                           \
        if (!(c)) {                                                                                \
            fprintf(stderr, "%s:%d: check failed: %s\n", __FILE__, __LINE__, #c);                 \
            abort();                                                                               \
        }                                                                                          \
    } while (0)
#define check_eq(a, b) check((long long)(a) == (long long)(b))

/* What the handler answers: a body of this many 'x'. */
static size_t body_size;
static int handled;

static void handler(void *data, const http_request *req, http_reply *rep)
{
    (void)data;
    (void)req;
    handled++;
    rep->content_type = "text/plain";
    rep->body = malloc(body_size ? body_size : 1);
    assert_non_null(rep->body);
    memset(rep->body, 'x', body_size);
    rep->body_len = body_size;
}

static void sleep_ms(long ms)
{
    struct timespec t = {ms / 1000, (ms % 1000) * 1000000L};
    nanosleep(&t, NULL);
}

/* ---- the client's side (its own thread) ---------------------------------- */

static int port;

/* A connected socket; rcvbuf > 0 makes its receive buffer that small. */
static int connect_to(int rcvbuf)
{
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    check(fd >= 0);
    struct timeval tv = {10, 0};
    setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    if (rcvbuf)
        setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof rcvbuf);
    struct sockaddr_in sa = {.sin_family = AF_INET, .sin_port = htons((uint16_t)port),
                             .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    check_eq(connect(fd, (struct sockaddr *)&sa, sizeof sa), 0);
    return fd;
}

static void send_text(int fd, const char *text)
{
    check_eq(send(fd, text, strlen(text), MSG_NOSIGNAL), (ssize_t)strlen(text));
}

/* Everything until the server closes; its length in *len (NUL-terminated). */
static char *read_all(int fd, size_t *len)
{
    size_t cap = 4096, n = 0;
    char *buf = malloc(cap);
    check(buf);
    for (;;) {
        if (cap - n < 4096) {
            cap *= 2;
            buf = realloc(buf, cap);
            check(buf);
        }
        ssize_t k = recv(fd, buf + n, cap - n - 1, 0);
        if (k <= 0) {
            check(k == 0 || errno == ECONNRESET);
            break;
        }
        n += (size_t)k;
    }
    buf[n] = 0;
    *len = n;
    return buf;
}

/* The status of a whole response, checking that its body is
 * Content-Length long; 0 if the server closed without one. */
static int response(int fd, size_t *body_len)
{
    size_t len;
    char *buf = read_all(fd, &len);
    close(fd);
    int status = 0;
    if (len) {
        const char *end = strstr(buf, "\r\n\r\n"), *cl = strstr(buf, "Content-Length: ");
        check(end);
        check(cl);
        check_eq(sscanf(buf, "HTTP/1.1 %d ", &status), 1);
        check_eq(strtoull(cl + 16, NULL, 10), len - (size_t)(end + 4 - buf));
        check(strstr(buf, "Connection: close\r\n"));
        if (body_len)
            *body_len = len - (size_t)(end + 4 - buf);
    }
    free(buf);
    return status;
}

#define GET "GET /x HTTP/1.1\r\nHost: h\r\n\r\n"

/* One GET on a fresh connection: its status. */
static int get(void)
{
    int fd = connect_to(0);
    send_text(fd, GET);
    return response(fd, NULL);
}

/* ---- the loop's side ----------------------------------------------------- */

static void on_done(ev_loop *loop, int fd, unsigned events, void *data)
{
    (void)fd;
    (void)events;
    (void)data;
    ev_stop(loop);
}

typedef struct client_run {
    void (*fn)(void);
    int done_fd;
} client_run;

static void *client_thread(void *arg)
{
    client_run *c = arg;
    c->fn();
    check_eq(write(c->done_fd, "x", 1), 1);
    return NULL;
}

/* Runs loop while fn runs as the client, until it is done. If
 * fail_after >= 0, the loop's allocations fail from the (fail_after + 1)th
 * one on. */
static void run_client(ev_loop *loop, long fail_after, void (*fn)(void))
{
    int done[2];
    assert_int_equal(pipe2(done, O_CLOEXEC | O_NONBLOCK), 0);
    assert_int_equal(ev_io_add(loop, done[0], EV_READ, on_done, NULL), 0);
    client_run c = {fn, done[1]};
    pthread_t t;
    cvre_alloc_fail_after(fail_after); /* before the thread: it only counts the loop's allocations */
    assert_int_equal(pthread_create(&t, NULL, client_thread, &c), 0);
    assert_int_equal(ev_run(loop), 0);
    pthread_join(t, NULL);
    cvre_alloc_fail_after(-1);
    ev_io_del(loop, done[0]);
    close(done[0]);
    close(done[1]);
}

/* Starts an endpoint of max_conns on loop (its port in port). */
static http_server *start(ev_loop *loop, uint32_t max_conns)
{
    http_server_config cfg = {"test", "127.0.0.1", 0, max_conns};
    char err[256];
    http_server *h;
    assert_int_equal(http_server_start(loop, &cfg, handler, NULL, &h, err, sizeof err), 0);
    assert_non_null(h);
    port = atoi(strrchr(http_server_address(h), ':') + 1);
    return h;
}

/* Starts an endpoint of max_conns, runs the loop while fn runs as the
 * client, then stops the endpoint (with whatever is still open). If
 * fail_after >= 0, the endpoint's allocations fail from the
 * (fail_after + 1)th one made after it started. */
static void serve(uint32_t max_conns, long fail_after, void (*fn)(void))
{
    ev_loop *loop = ev_create(1024);
    assert_non_null(loop);
    http_server *h = start(loop, max_conns);
    run_client(loop, fail_after, fn);
    http_server_stop(h);
    ev_destroy(loop);
}

/* ---- the cases ------------------------------------------------------------- */

/* A body far past the socket buffers, to a reader that waits first: the
 * endpoint waits for the socket to take it, all of it arrives. */
static void slow_reader(void)
{
    int fd = connect_to(4096);
    send_text(fd, GET);
    sleep_ms(200);
    size_t n = 0;
    check_eq(response(fd, &n), 200);
    check_eq(n, HTTP_BODY_MAX);
}

/* The same to a peer that shut its sending side right after asking. */
static void half_closed_reader(void)
{
    int fd = connect_to(4096);
    send_text(fd, GET);
    shutdown(fd, SHUT_WR);
    sleep_ms(200);
    size_t n = 0;
    check_eq(response(fd, &n), 200);
    check_eq(n, HTTP_BODY_MAX);
}

static void test_large_bodies(void **state)
{
    (void)state;
    body_size = HTTP_BODY_MAX;
    serve(4, -1, slow_reader);
    serve(4, -1, half_closed_reader);
}

static void over_the_cap(void) { check_eq(get(), 500); }

static void test_body_past_cap(void **state)
{
    (void)state;
    body_size = HTTP_BODY_MAX + 1;
    serve(4, -1, over_the_cap);
}

/* Silence gets 408 at the request deadline. A peer that takes its answer
 * but neither closes nor sends is closed at the linger deadline: what it
 * sends then meets a closed socket (a reset, and the next send fails),
 * where before the endpoint was reading and dropping it. */
static void deadlines(void)
{
    int fd = connect_to(0);
    check_eq(response(fd, NULL), 408);
    int mute = connect_to(0);
    send_text(mute, GET);
    size_t len;
    char *buf = read_all(mute, &len); /* up to the endpoint's shutdown of its side */
    check(strncmp(buf, "HTTP/1.1 200 OK\r\n", 17) == 0);
    free(buf);
    sleep_ms(HTTP_LINGER_MS + 700);
    send_text(mute, "more");
    sleep_ms(100); /* for the reset to come back */
    check(send(mute, "more", 4, MSG_NOSIGNAL) < 0 && (errno == EPIPE || errno == ECONNRESET));
    close(mute);
}

static void test_deadlines(void **state)
{
    (void)state;
    body_size = 10;
    serve(4, -1, deadlines);
}

/* A peer that resets as soon as it asked for a large body: the endpoint
 * drops it and serves the next one. */
static void resetting_peer(void)
{
    int fd = connect_to(4096);
    struct linger l = {1, 0};
    setsockopt(fd, SOL_SOCKET, SO_LINGER, &l, sizeof l);
    send_text(fd, GET);
    sleep_ms(100);
    close(fd); /* RST: unread data and a zero linger */
    sleep_ms(100);
    check_eq(get(), 200);
}

static void test_reset_peer(void **state)
{
    (void)state;
    body_size = HTTP_BODY_MAX;
    serve(4, -1, resetting_peer);
}

/* Out of memory at each allocation a connection makes (its record, its
 * input buffer, its request, its output buffer, the timer that reaps it):
 * refused with 503, or closed without an answer, or answered and reaped
 * later; nothing leaked (LeakSanitizer in the ASan tree). */
static int refused_status;
static void refused(void) { refused_status = get(); }

static void test_out_of_memory(void **state)
{
    (void)state;
    body_size = 10;
    serve(4, 0, refused);
    assert_int_equal(refused_status, 503);
    serve(4, 1, refused);
    assert_int_equal(refused_status, 0);
    serve(4, 2, refused);
    assert_int_equal(refused_status, 0);
    serve(4, 3, refused); /* its output buffer: no answer either */
    assert_int_equal(refused_status, 0);
    serve(4, 4, refused); /* the answer is out; reaping waits for the sweep */
    assert_int_equal(refused_status, 200);
    /* The endpoint itself. */
    ev_loop *loop = ev_create(1024);
    assert_non_null(loop);
    http_server_config cfg = {"test", "127.0.0.1", 0, 4};
    char err[256];
    for (long k = 0; k < 2; k++) {
        cvre_alloc_fail_after(k);
        http_server *h = NULL;
        assert_int_equal(http_server_start(loop, &cfg, handler, NULL, &h, err, sizeof err), -ENOMEM);
        assert_null(h);
        cvre_alloc_fail_after(-1);
        assert_string_equal(err, "test: out of memory");
    }
    ev_destroy(loop);
}

/* Out of file descriptors (EMFILE) with a connection waiting: the
 * endpoint says so once and leaves its socket alone for
 * NET_ACCEPT_PAUSE_MS instead of spinning on it (a timer well inside the
 * pause stops the loop: one warning by then, where a spinning loop logs
 * one a turn); once descriptors are back and the pause is over, the
 * waiting connection is answered. */
static int waiting;
static void waiting_get(void)
{
    send_text(waiting, GET);
    check_eq(response(waiting, NULL), 200);
}

static void on_stop(ev_loop *loop, void *data)
{
    (void)data;
    ev_stop(loop);
}

static void test_out_of_descriptors(void **state)
{
    (void)state;
    body_size = 10;
    ev_loop *loop = ev_create(1024);
    assert_non_null(loop);
    http_server *h = start(loop, 4);
    char path[] = "/tmp/cvre-test-http-XXXXXX";
    int logfd = mkstemp(path);
    assert_true(logfd >= 0);
    unlink(path);
    int saved_stderr = dup(2);
    assert_true(saved_stderr >= 0);
    waiting = connect_to(0); /* in the listening socket's backlog */
    int lowest = dup(0);     /* the next descriptor: none is left from it on */
    assert_true(lowest >= 0);
    close(lowest);
    struct rlimit saved, none;
    assert_int_equal(getrlimit(RLIMIT_NOFILE, &saved), 0);
    none = saved;
    none.rlim_cur = (rlim_t)lowest;
    fflush(stderr);
    assert_int_equal(dup2(logfd, 2), 2);
    assert_int_equal(setrlimit(RLIMIT_NOFILE, &none), 0);
    assert_true(ev_timer_start(loop, NET_ACCEPT_PAUSE_MS / 10 * 1000000ull, 0, on_stop, NULL) >= 0);
    assert_int_equal(ev_run(loop), 0);
    assert_int_equal(setrlimit(RLIMIT_NOFILE, &saved), 0);
    assert_int_equal(dup2(saved_stderr, 2), 2);
    close(saved_stderr);
    char text[4096];
    ssize_t n = pread(logfd, text, sizeof text - 1, 0);
    close(logfd);
    assert_true(n > 0);
    text[n] = 0;
    int lines = 0;
    for (const char *p = text; (p = strstr(p, "test: accept: Too many open files; raise the file limit")); p++)
        lines++;
    assert_int_equal(lines, 1);
    run_client(loop, -1, waiting_get);
    http_server_stop(h);
    ev_destroy(loop);
}

static void test_start_failures(void **state)
{
    (void)state;
    char err[256];
    http_server_config cfg = {"test", "256.0.0.1", 0, 4};
    ev_loop *loop = ev_create(1024);
    assert_non_null(loop);
    http_server *h = NULL;
    assert_true(http_server_start(loop, &cfg, handler, NULL, &h, err, sizeof err) < 0);
    assert_null(h);
    assert_non_null(strstr(err, "test: cannot resolve 256.0.0.1"));
    ev_destroy(loop);
    /* A loop that cannot watch the listening socket's fd. */
    loop = ev_create(3);
    assert_non_null(loop);
    cfg.host = "127.0.0.1";
    assert_int_equal(http_server_start(loop, &cfg, handler, NULL, &h, err, sizeof err), -EINVAL);
    assert_null(h);
    assert_string_equal(err, "test: event loop: Invalid argument");
    ev_destroy(loop);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_large_bodies),  cmocka_unit_test(test_body_past_cap),
        cmocka_unit_test(test_deadlines),     cmocka_unit_test(test_reset_peer),
        cmocka_unit_test(test_out_of_memory), cmocka_unit_test(test_out_of_descriptors),
        cmocka_unit_test(test_start_failures),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
