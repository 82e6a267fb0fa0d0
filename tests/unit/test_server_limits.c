/*
 * The server's small modules at their limits: a connection's input and
 * output buffers at their caps and when memory runs out, a peer that stops
 * reading or goes away, the soft limit's clock, the close's shut write and
 * linger (fixed or extended), listening and accepting when that fails; the
 * grid and the rate limiter when memory runs out.
 */
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <setjmp.h>
#include <signal.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cmocka.h>

#include "alloc.h"
#include "conn.h"
#include "grid.h"
#include "ratelimit.h"
#include "srv_limits.h"

static ev_loop *loop;

/* The game's output limits, without a soft limit or a linger. */
static const conn_config plain = {.out_hard = SRV_OUTBUF_HARD};

static void on_io(ev_loop *l, int fd, unsigned events, void *data)
{
    (void)l;
    (void)fd;
    (void)events;
    (void)data;
}

/* A connection over one end of a non-blocking socket pair, under cfg;
 * *peer the other. */
static void pair_with(conn *c, int *peer, const conn_config *cfg)
{
    int sv[2];

    assert_int_equal(socketpair(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK, 0, sv), 0);
    assert_int_equal(conn_open(c, loop, sv[0], cfg, on_io, NULL), 0);
    *peer = sv[1];
}

static void pair(conn *c, int *peer) { pair_with(c, peer, &plain); }

/* Lets the loop's clock move on past t. */
static void clock_past(uint64_t t)
{
    while (ev_clock(loop) <= t)
        ;
}

static void test_input_cap_and_memory(void **state)
{
    conn c;
    int peer;
    static uint8_t junk[4 * NET_INBUF_INITIAL];

    (void)state;
    cvre_alloc_fail_after(0);
    assert_int_equal(conn_open(&c, loop, dup(0), &plain, on_io, NULL), -ENOMEM);
    cvre_alloc_fail_after(-1);
    conn_free(&c); /* closes the descriptor even so */

    pair(&c, &peer);
    assert_int_equal(conn_read(&c, 2 * NET_INBUF_INITIAL, 1024), -EAGAIN); /* nothing there */
    assert_int_equal(write(peer, junk, sizeof junk), (ssize_t)sizeof junk);
    assert_int_equal(conn_read(&c, 2 * NET_INBUF_INITIAL, 1024), NET_INBUF_INITIAL);
    cvre_alloc_fail_after(0); /* full: growing it fails */
    assert_int_equal(conn_read(&c, 2 * NET_INBUF_INITIAL, 1024), -ENOMEM);
    cvre_alloc_fail_after(-1);
    assert_int_equal(conn_read(&c, 2 * NET_INBUF_INITIAL, 1024), NET_INBUF_INITIAL);
    /* full at the cap: the frame parser must have refused before this */
    assert_int_equal(conn_read(&c, 2 * NET_INBUF_INITIAL, 1024), -ENOBUFS);
    conn_consume(&c, NET_INBUF_INITIAL);
    assert_int_equal(c.in_len, NET_INBUF_INITIAL);
    close(peer);
    conn_free(&c);
}

/* Appends n bytes of output. Returns conn_out_reserve's status. */
static int put(conn *c, size_t n)
{
    uint8_t *room;
    size_t len;
    int rc = conn_out_reserve(c, n, &room, &len);

    if (rc == 0) {
        assert_true(len >= n);
        memset(room, 'x', n);
        conn_out_commit(c, n);
    }
    return rc;
}

/* Reads what the peer has been sent; returns how much. */
static size_t drain(int peer)
{
    static uint8_t sink[1 << 16];
    size_t total = 0;
    ssize_t n;
    while ((n = read(peer, sink, sizeof sink)) > 0)
        total += (size_t)n;
    return total;
}

static void test_output_limits(void **state)
{
    conn c;
    int peer;

    (void)state;
    pair(&c, &peer);
    assert_int_equal(put(&c, SRV_OUTBUF_HARD + 1), -ENOBUFS); /* never past the hard limit */
    cvre_alloc_fail_after(0);
    assert_int_equal(put(&c, 100), -ENOMEM);
    cvre_alloc_fail_after(-1);
    assert_int_equal(conn_out_pending(&c), 0);

    /* a peer that does not read: what the socket will not take stays */
    assert_int_equal(put(&c, SRV_OUTBUF_HARD - 1000), 0);
    ssize_t left = conn_flush(&c);
    assert_true(left > 0 && (size_t)left < SRV_OUTBUF_HARD - 1000);
    assert_true(c.out_head > 0);
    /* more output slides the pending bytes to the front, then fits the cap */
    assert_int_equal(put(&c, 1000 + (size_t)(SRV_OUTBUF_HARD - 1000 - (size_t)left)), 0);
    assert_int_equal(c.out_head, 0);
    assert_int_equal(c.out_cap, SRV_OUTBUF_HARD);
    assert_int_equal(conn_out_pending(&c), SRV_OUTBUF_HARD);

    /* the peer reads it all: the burst's big buffer is given back */
    while (conn_out_pending(&c)) {
        drain(peer);
        assert_true(conn_flush(&c) >= 0);
    }
    assert_null(c.out);
    assert_int_equal(c.out_cap, 0);

    /* the peer goes away: the error, not a signal */
    assert_int_equal(put(&c, 10), 0);
    close(peer);
    assert_int_equal(conn_flush(&c), -EPIPE);
    conn_free(&c);
}

/* EV_WRITE is armed only while bytes remain; output past the soft limit
 * starts a clock that conn_overdue reads, and going below stops it. */
static void test_write_arming_and_soft_limit(void **state)
{
    const conn_config soft = {.out_hard = SRV_OUTBUF_HARD, .out_soft = 1000, .out_soft_ms = 0};
    conn c;
    int peer;

    (void)state;
    pair_with(&c, &peer, &soft);
    assert_true(c.reading && !c.writing);
    assert_int_equal(put(&c, 2000), 0);
    assert_int_equal(conn_flush(&c), 0); /* the socket takes it at once: nothing armed */
    assert_false(c.writing);
    assert_int_equal(c.soft_since_ns, 0);
    assert_int_equal(drain(peer), 2000);

    assert_int_equal(put(&c, SRV_OUTBUF_HARD), 0); /* more than the socket takes */
    assert_true(conn_flush(&c) > 1000);
    assert_true(c.writing);
    uint64_t since = c.soft_since_ns;
    assert_int_equal(since, ev_now(loop));
    assert_int_equal(conn_overdue(&c), 0); /* not for longer than out_soft_ms yet */
    clock_past(since);
    assert_true(conn_flush(&c) > 1000);
    assert_int_equal(c.soft_since_ns, since); /* the clock runs from the first time */
    assert_int_equal(conn_overdue(&c), -ENOBUFS);
    while (conn_out_pending(&c)) {
        drain(peer);
        assert_true(conn_flush(&c) >= 0);
    }
    assert_false(c.writing);
    assert_int_equal(c.soft_since_ns, 0);
    assert_int_equal(conn_overdue(&c), 0);
    conn_set_reading(&c, 0);
    assert_false(c.reading);
    close(peer);
    conn_free(&c);
}

/* The close: the flush that empties the output shuts the write side, so
 * the peer reads everything and then the end; the linger is over after
 * linger_ms, fixed or given again by each write the peer takes. */
static void test_close_and_linger(void **state)
{
    const conn_config fixed = {.out_hard = SRV_OUTBUF_HARD, .out_soft = 1000, .linger_ms = 60000};
    const conn_config extends = {.out_hard = SRV_OUTBUF_HARD, .linger_ms = 60000, .linger_extends = 1};
    const conn_config none = {.out_hard = SRV_OUTBUF_HARD, .linger_ms = 0};
    conn c;
    int peer;
    uint8_t byte;

    (void)state;
    pair_with(&c, &peer, &none);
    assert_int_equal(put(&c, 10), 0);
    conn_begin_close(&c);
    assert_int_equal(conn_overdue(&c), 0);
    assert_int_equal(conn_flush(&c), 0);
    assert_true(c.shut_wr);
    assert_int_equal(drain(peer), 10);
    assert_int_equal(read(peer, &byte, 1), 0); /* the end, after the output */
    clock_past(c.linger_until_ns);
    assert_int_equal(conn_overdue(&c), -ETIMEDOUT);
    close(peer);
    conn_free(&c);

    for (int ext = 0; ext < 2; ext++) {
        pair_with(&c, &peer, ext ? &extends : &fixed);
        assert_int_equal(put(&c, SRV_OUTBUF_HARD), 0);
        assert_true(conn_flush(&c) > 1000);
        conn_begin_close(&c);
        uint64_t until = c.linger_until_ns;
        assert_int_equal(until, ev_now(loop) + 60000 * (uint64_t)1000000);
        conn_begin_close(&c); /* a second call does nothing */
        assert_int_equal(c.linger_until_ns, until);
        assert_int_equal(conn_overdue(&c), 0); /* closing: the soft limit is the linger's business */
        clock_past(until - 60000 * (uint64_t)1000000);
        assert_true(drain(peer) > 0);
        assert_true(conn_flush(&c) >= 0); /* the peer took some */
        if (ext)
            assert_true(c.linger_until_ns > until);
        else
            assert_int_equal(c.linger_until_ns, until);
        assert_false(c.shut_wr && conn_out_pending(&c));
        close(peer);
        conn_free(&c);
    }
}

static void test_listen_and_accept(void **state)
{
    char address[64], peer[64], err[256];
    int fd, busy, client;

    (void)state;
    assert_true(conn_listen("no.such.host.invalid", 0, 8, address, sizeof address, err, sizeof err) < 0);
    assert_non_null(strstr(err, "cannot resolve no.such.host.invalid"));

    /* no descriptor left for the socket */
    struct rlimit saved, none;
    assert_int_equal(getrlimit(RLIMIT_NOFILE, &saved), 0);
    none = saved;
    none.rlim_cur = 0;
    assert_int_equal(setrlimit(RLIMIT_NOFILE, &none), 0);
    fd = conn_listen("127.0.0.1", 0, 8, address, sizeof address, err, sizeof err);
    assert_int_equal(setrlimit(RLIMIT_NOFILE, &saved), 0);
    assert_int_equal(fd, -EMFILE);
    assert_string_equal(err, "cannot listen on 127.0.0.1:0: Too many open files");

    busy = conn_listen("127.0.0.1", 0, 8, address, sizeof address, err, sizeof err);
    assert_true(busy >= 0);
    assert_int_equal(strncmp(address, "127.0.0.1:", 10), 0);
    /* the same port again, from a socket that does not share it */
    fd = socket(AF_INET, SOCK_STREAM, 0);
    assert_true(fd >= 0);
    struct sockaddr_in sin = {.sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK),
                              .sin_port = htons((uint16_t)atoi(address + 10))};
    assert_int_equal(conn_listen("127.0.0.1", (uint16_t)atoi(address + 10), 8, peer, sizeof peer, err, sizeof err),
                     -EADDRINUSE); /* SO_REUSEADDR does not share a listening port */
    assert_non_null(strstr(err, "Address already in use"));

    assert_int_equal(conn_accept(busy, peer, sizeof peer), -EAGAIN); /* nobody waiting */
    client = fd;
    assert_int_equal(connect(client, (struct sockaddr *)&sin, sizeof sin), 0);
    fd = conn_accept(busy, peer, sizeof peer);
    assert_true(fd >= 0);
    assert_int_equal(strncmp(peer, "127.0.0.1:", 10), 0);
    assert_true(fcntl(fd, F_GETFL) & O_NONBLOCK);
    close(fd);
    close(client);
    assert_int_equal(conn_accept(-1, peer, sizeof peer), -EBADF);
    close(busy);

    fd = conn_listen("::1", 0, 8, address, sizeof address, err, sizeof err);
    if (fd >= 0) { /* where the machine has IPv6 loopback: brackets */
        assert_int_equal(strncmp(address, "[::1]:", 6), 0);
        close(fd);
    }
    struct sockaddr_storage unnamed = {.ss_family = AF_UNSPEC};
    conn_peer_name(&unnamed, sizeof unnamed, peer, sizeof peer);
    assert_string_equal(peer, "?");
}

static void test_grid_and_limits_out_of_memory(void **state)
{
    grid *g;
    uint32_t found[4];

    (void)state;
    for (long n = 0; n < 3; n++) { /* the grid, its cells, its entries */
        cvre_alloc_fail_after(n);
        assert_null(grid_create(0, 0, 100, 100, 10, 16));
        cvre_alloc_fail_after(-1);
    }
    grid_destroy(NULL);
    g = grid_create(0, 0, 100, 100, 10, 16);
    assert_non_null(g);
    cvre_alloc_fail_after(0);
    assert_int_equal(grid_insert(g, 0, 5, 5), -ENOMEM);
    cvre_alloc_fail_after(-1);
    assert_int_equal(grid_insert(g, 0, 5, 5), 0);
    /* a move into a cell that cannot grow keeps the handle, with its new
     * coordinates, in its old cell: a query reaching that cell finds it */
    cvre_alloc_fail_after(0);
    assert_int_equal(grid_move(g, 0, 15, 5), -ENOMEM);
    cvre_alloc_fail_after(-1);
    assert_int_equal(grid_query(g, 15, 5, 6, found, 4), 1);
    assert_int_equal(grid_query(g, 5, 5, 1, found, 4), 0); /* it is no longer there */
    assert_int_equal(grid_move(g, 0, 95, 95), 0);
    assert_int_equal(grid_query(g, 95, 95, 1, found, 4), 1);
    assert_int_equal(found[0], 0);
    grid_destroy(g);

    for (long n = 0; n < 2; n++) { /* the table, its buckets or counts */
        cvre_alloc_fail_after(n);
        assert_null(ratelimit_create(64, 1, 2));
        cvre_alloc_fail_after(n);
        assert_null(addrcount_create(64));
        cvre_alloc_fail_after(-1);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_input_cap_and_memory),
        cmocka_unit_test(test_output_limits),
        cmocka_unit_test(test_write_arming_and_soft_limit),
        cmocka_unit_test(test_close_and_linger),
        cmocka_unit_test(test_listen_and_accept),
        cmocka_unit_test(test_grid_and_limits_out_of_memory),
    };
    signal(SIGPIPE, SIG_IGN); /* as the server does */
    loop = ev_create(1024);
    if (!loop)
        return 1;
    int rc = cmocka_run_group_tests(tests, NULL, NULL);
    ev_destroy(loop);
    return rc;
}
