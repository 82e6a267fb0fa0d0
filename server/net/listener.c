/* listener.c: a listening socket on the event loop (see listener.h). */
#include "listener.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "alloc.h"
#include "conn.h"
#include "err.h"
#include "log.h"

#define NS_PER_MS ((uint64_t)1000000)

struct net_listener {
    ev_loop *loop;
    int fd;
    int budget;
    int pause_timer; /* the pending end of a pause, or -1 */
    net_accept_fn *fn;
    void *data;
    char prefix[40]; /* "metrics: ", or empty */
    char address[80];
};

const char *net_listener_address(const net_listener *l) { return l->address; }

static void on_accept(ev_loop *loop, int fd, unsigned events, void *data);

/* The end of a pause: watch the socket again. */
static void resume(ev_loop *loop, void *data)
{
    net_listener *l = data;
    l->pause_timer = -1;
    if (ev_io_add(loop, l->fd, EV_READ, on_accept, l) < 0)
        log_error("%scannot watch the listening socket again; no new connections", l->prefix);
}

static void on_accept(ev_loop *loop, int fd, unsigned events, void *data)
{
    (void)events;
    net_listener *l = data;
    for (int k = 0; k < l->budget; k++) {
        char peer[80];
        int cfd = conn_accept(fd, peer, sizeof peer);
        if (cfd >= 0) {
            l->fn(l->data, cfd, peer);
            continue;
        }
        if (cfd == -EMFILE || cfd == -ENFILE) {
            log_warn("%saccept: %s; raise the file limit (ulimit -n); no new connections for %u ms", l->prefix,
                     strerror(-cfd), NET_ACCEPT_PAUSE_MS);
            l->pause_timer = ev_timer_start(loop, NET_ACCEPT_PAUSE_MS * NS_PER_MS, 0, resume, l);
            if (l->pause_timer >= 0)
                ev_io_del(loop, fd);
        } else if (cfd != -EAGAIN) {
            log_warn("%saccept: %s", l->prefix, strerror(-cfd));
        }
        return;
    }
}

int net_listener_start(ev_loop *loop, const net_listener_config *cfg, net_accept_fn *fn, void *data,
                       net_listener **out, char *err, size_t errlen)
{
    *out = NULL;
    net_listener *l = cvre_calloc(1, sizeof *l);
    if (!l)
        return cvre_fail(err, errlen, -ENOMEM, "out of memory");
    *l = (net_listener){.loop = loop, .fd = -1, .budget = cfg->budget, .pause_timer = -1, .fn = fn, .data = data};
    if (cfg->name)
        snprintf(l->prefix, sizeof l->prefix, "%s: ", cfg->name);
    int rc = conn_listen(cfg->host, cfg->port, cfg->backlog, l->address, sizeof l->address, err, errlen);
    if (rc >= 0) {
        l->fd = rc;
        rc = ev_io_add(loop, l->fd, EV_READ, on_accept, l);
        if (rc < 0)
            cvre_fail(err, errlen, rc, "event loop: %s", strerror(-rc));
    }
    if (rc < 0) {
        net_listener_stop(l);
        return rc;
    }
    *out = l;
    return 0;
}

void net_listener_stop(net_listener *l)
{
    if (!l)
        return;
    if (l->pause_timer >= 0)
        ev_timer_stop(l->loop, l->pause_timer);
    if (l->fd >= 0) {
        ev_io_del(l->loop, l->fd); /* -EINVAL while paused: not watched */
        close(l->fd);
    }
    free(l);
}
