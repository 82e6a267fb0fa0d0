/*
 * The server's small modules at their limits: a connection's input and
 * output buffers at their caps and when memory runs out, a peer that stops
 * reading or goes away, listening and accepting when that fails; the grid
 * and the rate limiter when memory runs out.
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

/* A connection over one end of a non-blocking socket pair; *peer the other. */
static void pair(conn *c, int *peer)
{
    int sv[2];

    assert_int_equal(socketpair(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK, 0, sv), 0);
    assert_int_equal(conn_init(c, sv[0]), 0);
    *peer = sv[1];
}

static void test_input_cap_and_memory(void **state)
{
    conn c;
    int peer;
    static uint8_t junk[4 * SRV_INBUF_INITIAL];

    (void)state;
    cvre_alloc_fail_after(0);
    assert_int_equal(conn_init(&c, dup(0)), -ENOMEM);
    cvre_alloc_fail_after(-1);
    conn_free(&c); /* closes the descriptor even so */

    pair(&c, &peer);
    assert_int_equal(conn_read(&c, 2 * SRV_INBUF_INITIAL, 1024), -EAGAIN); /* nothing there */
    assert_int_equal(write(peer, junk, sizeof junk), (ssize_t)sizeof junk);
    assert_int_equal(conn_read(&c, 2 * SRV_INBUF_INITIAL, 1024), SRV_INBUF_INITIAL);
    cvre_alloc_fail_after(0); /* full: growing it fails */
    assert_int_equal(conn_read(&c, 2 * SRV_INBUF_INITIAL, 1024), -ENOMEM);
    cvre_alloc_fail_after(-1);
    assert_int_equal(conn_read(&c, 2 * SRV_INBUF_INITIAL, 1024), SRV_INBUF_INITIAL);
    /* full at the cap: the frame parser must have refused before this */
    assert_int_equal(conn_read(&c, 2 * SRV_INBUF_INITIAL, 1024), -ENOBUFS);
    conn_consume(&c, SRV_INBUF_INITIAL);
    assert_int_equal(c.in_len, SRV_INBUF_INITIAL);
    close(peer);
    conn_free(&c);
}

/* Appends n bytes of frames' worth of output (raw bytes: conn does not
 * look inside). Returns conn_out_begin's status. */
static int put(conn *c, size_t n)
{
    proto_writer w;
    int rc = conn_out_begin(c, n, &w);

    if (rc == 0) {
        memset(w.buf, 'x', n);
        w.len = n;
        conn_out_end(c, &w);
    }
    return rc;
}

static void test_output_limits(void **state)
{
    conn c;
    int peer;
    static uint8_t sink[1 << 16];

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
        while (read(peer, sink, sizeof sink) > 0)
            ;
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
        cmocka_unit_test(test_listen_and_accept),
        cmocka_unit_test(test_grid_and_limits_out_of_memory),
    };
    signal(SIGPIPE, SIG_IGN); /* as the server does */
    return cmocka_run_group_tests(tests, NULL, NULL);
}
