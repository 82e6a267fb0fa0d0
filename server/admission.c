/*
 * admission.c: who may connect to the game protocol, and the client each
 * connection becomes (admission.h).
 */
#include "admission.h"

#include <netinet/in.h>
#include <netinet/tcp.h>
#include <stdio.h>
#include <sys/socket.h>
#include <unistd.h>

#include "clients.h"
#include "handlers.h"
#include "log.h"
#include "srv_limits.h"

/* Connections accepted per wakeup of the listening socket. */
#define ACCEPT_BUDGET 256

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

static void on_accepted(void *data, int cfd, const char *peer)
{
    server *s = data;
    char addr[80];
    ratelimit_address(peer, addr, sizeof addr);
    if (s->nclients >= s->cfg.max_clients || cfd >= s->max_fd) {
        log_warn("%s refused: server full (%u clients)", peer, s->nclients);
        refuse(cfd, "server full");
        return;
    }
    if (s->cfg.max_per_address && addrcount_add(s->per_address, addr, +1) > s->cfg.max_per_address) {
        addrcount_add(s->per_address, addr, -1);
        log_warn("%s refused: over %u connections from this address", peer, s->cfg.max_per_address);
        refuse(cfd, "too many connections from your address");
        return;
    }
    int one = 1;
    setsockopt(cfd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    if (clients__add(s, cfd, peer, addr, handlers__on_io) < 0) {
        log_error("%s refused: cannot register the connection", peer);
        if (s->cfg.max_per_address)
            addrcount_add(s->per_address, addr, -1);
    }
}

int admission__start(server *s, char *err, size_t errlen)
{
    net_listener_config lc = {.host = s->cfg.host, .port = s->cfg.port, .backlog = SRV_LISTEN_BACKLOG,
                              .budget = ACCEPT_BUDGET};
    int rc = net_listener_start(s->loop, &lc, on_accepted, s, &s->listener, err, errlen);
    if (rc == 0)
        snprintf(s->address, sizeof s->address, "%s", net_listener_address(s->listener));
    return rc;
}

void admission__stop(server *s)
{
    net_listener_stop(s->listener);
    s->listener = NULL;
}
