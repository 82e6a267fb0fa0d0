/*
 * listener.h: a listening socket on the event loop, under every endpoint
 * (the game protocol's, the HTTP ones). It accepts at most a budget of
 * connections per wake-up, so that a burst is taken between the loop's
 * other events; and when the process is out of file descriptors (EMFILE,
 * ENFILE) it stops watching the socket for NET_ACCEPT_PAUSE_MS instead of
 * spinning on a socket that stays readable. What a connection becomes is
 * the endpoint's: each accepted socket goes to its callback.
 *
 * The rest of the layer is conn.h: one connection's input, output, flush
 * and close; its limits are in net_limits.h.
 */
#ifndef CVRE_NET_LISTENER_H
#define CVRE_NET_LISTENER_H

#include <stddef.h>
#include <stdint.h>

#include "ev.h"
#include "net_limits.h" /* NET_ACCEPT_PAUSE_MS */


/* A new connection: fd is non-blocking and close-on-exec, and the
 * callback's to keep or close; peer names it ("HOST:PORT"). */
typedef void net_accept_fn(void *data, int fd, const char *peer);

typedef struct net_listener_config {
    const char *name; /* prefix of its log lines ("metrics"); NULL: none */
    const char *host;
    uint16_t port;    /* 0: any free port */
    int backlog;      /* listen(2) */
    int budget;       /* connections accepted per wake-up, >= 1 */
} net_listener_config;

typedef struct net_listener net_listener;

/* Listens on cfg->host:cfg->port and watches the socket on loop, calling
 * fn(data, ...) for each connection. Returns 0 with *out set, or -errno
 * with a message in err. */
int net_listener_start(ev_loop *loop, const net_listener_config *cfg, net_accept_fn *fn, void *data,
                       net_listener **out, char *err, size_t errlen);
/* "HOST:PORT" as bound (IPv6 in brackets). */
const char *net_listener_address(const net_listener *l);
/* Stops watching, cancels a pause, closes the socket and frees l;
 * connections already accepted are the endpoint's. NULL is a no-op. */
void net_listener_stop(net_listener *l);

#endif
