/*
 * listener.c: the game protocol's listening socket and the admission of a
 * new connection (listener.h).
 */
#include "listener.h"

#include <errno.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <stdio.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include "clients.h"
#include "handlers.h"
#include "log.h"
#include "srv_limits.h"

/* Connections accepted per wakeup of the listening socket. */
#define ACCEPT_BUDGET 256
/* How long the listening socket is left alone once the process is out of
 * file descriptors: the connection accept could not take stays waiting,
 * so the socket stays readable, and watching it would spin the loop (and
 * log a line a turn). Descriptors come back as clients leave; nginx waits
 * half a second too. */
#define ACCEPT_PAUSE_MS 500u

/* Refuses a connection the server has no room for, with a best-effort error
 * frame (the socket is fresh, so a small write goes through). */
static void refuse(int fd, const char *why)
{
    uint8_t buf[PROTO_SIZE_ERROR_MAX];
    proto_writer w;
    proto_writer_init(&w, buf, sizeof buf);
    proto_put_error(&w, PROTO_ERR_SERVER_FULL, why);
    ssize_t n = write(fd, buf, w.len);
    (void)n;
    close(fd);
}

static void on_accept(ev_loop *loop, int fd, unsigned events, void *data);

/* The end of an ACCEPT_PAUSE_MS pause: watch the listening socket again
 * (unless a shutdown closed it meanwhile). */
static void resume_accept(ev_loop *loop, void *data)
{
    server *s = data;
    if (s->listen_fd >= 0 && ev_io_add(loop, s->listen_fd, EV_READ, on_accept, s) < 0)
        log_error("cannot watch the listening socket again; no new connections");
}

static void on_accept(ev_loop *loop, int fd, unsigned events, void *data)
{
    (void)events;
    server *s = data;
    for (int k = 0; k < ACCEPT_BUDGET; k++) {
        char peer[80], addr[80];
        int cfd = conn_accept(fd, peer, sizeof peer);
        if (cfd < 0) {
            if (cfd == -EMFILE || cfd == -ENFILE) {
                log_warn("accept: %s; raise the file limit (ulimit -n); no new connections for %u ms",
                         strerror(-cfd), ACCEPT_PAUSE_MS);
                if (ev_timer_start(loop, ACCEPT_PAUSE_MS * NS_PER_MS, 0, resume_accept, s) >= 0)
                    ev_io_del(loop, fd);
            } else if (cfd != -EAGAIN)
                log_warn("accept: %s", strerror(-cfd));
            return;
        }
        ratelimit_address(peer, addr, sizeof addr);
        if (s->nclients >= s->cfg.max_clients || cfd >= s->max_fd) {
            log_warn("%s refused: server full (%u clients)", peer, s->nclients);
            refuse(cfd, "server full");
            continue;
        }
        if (s->cfg.max_per_address && addrcount_add(s->per_address, addr, +1) > s->cfg.max_per_address) {
            addrcount_add(s->per_address, addr, -1);
            log_warn("%s refused: over %u connections from this address", peer, s->cfg.max_per_address);
            refuse(cfd, "too many connections from your address");
            continue;
        }
        int one = 1, sndbuf = SRV_SOCKET_SNDBUF;
        setsockopt(cfd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        setsockopt(cfd, SOL_SOCKET, SO_SNDBUF, &sndbuf, sizeof sndbuf);
        if (clients__add(s, cfd, peer, addr, handlers__on_io) < 0) {
            log_error("%s refused: cannot register the connection", peer);
            if (s->cfg.max_per_address)
                addrcount_add(s->per_address, addr, -1);
        }
    }
}

int listener__start(server *s, char *err, size_t errlen)
{
    s->listen_fd = conn_listen(s->cfg.host, s->cfg.port, SRV_LISTEN_BACKLOG, s->address, sizeof s->address, err,
                               errlen);
    if (s->listen_fd < 0)
        return -1;
    if (ev_io_add(s->loop, s->listen_fd, EV_READ, on_accept, s) < 0) {
        snprintf(err, errlen, "event loop setup failed");
        return -1;
    }
    return 0;
}

void listener__stop(server *s)
{
    if (s->listen_fd < 0)
        return;
    ev_io_del(s->loop, s->listen_fd);
    close(s->listen_fd);
    s->listen_fd = -1;
}
