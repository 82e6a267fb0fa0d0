/*
 * admission.c: who may connect to the game protocol, and the client each
 * connection becomes (admission.h).
 */
#include "admission.h"

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
#include "ws.h"

/* Connections accepted per wakeup of the listening socket. */
#define ACCEPT_BUDGET 256

/* A WebSocket's handshake answer, sent before anything else. */
typedef struct ws_first {
    const uint8_t *p;
    size_t len;
} ws_first;

/* The longest handshake answer refuse() sends on: the 101 is about 130
 * bytes. */
#define WS_FIRST_MAX 256u

/* Refuses a connection the server has no room for, with a best-effort error
 * frame (the socket is fresh, so a small write goes through); on a
 * WebSocket after its handshake's answer, in a message, and a close frame. */
static void refuse(int fd, const char *why, const ws_first *ws)
{
    uint8_t frame[PROTO_SIZE_ERROR_MAX];
    proto_writer w;
    proto_writer_init(&w, frame, sizeof frame);
    proto_put_error(&w, PROTO_ERR_SERVER_FULL, why);
    uint8_t buf[WS_FIRST_MAX + WS_SERVER_HEADER_MAX + sizeof frame + 2 + WS_CONTROL_MAX];
    size_t at = 0;
    if (ws && ws->len <= WS_FIRST_MAX) {
        memcpy(buf, ws->p, ws->len);
        at = ws->len + ws_header(buf + ws->len, WS_OP_BINARY, w.len);
    }
    if (!ws || at > 0) {
        memcpy(buf + at, frame, w.len);
        at += w.len;
    }
    if (at > 0 && ws) {
        int n = ws_close_frame(buf + at, sizeof buf - at, WS_CLOSE_TRY_AGAIN, why);
        at += n > 0 ? (size_t)n : 0;
    }
    ssize_t n = write(fd, buf, at);
    (void)n;
    close(fd);
}

/* A connection, TCP or (ws not NULL) a WebSocket: a client, or refused. */
static void admit(server *s, int cfd, const char *peer, const ws_first *ws)
{
    char addr[80];
    ratelimit_address(peer, addr, sizeof addr);
    if (s->nclients >= s->cfg.max_clients || cfd >= s->max_fd) {
        log_warn("%s refused: server full (%u clients)", peer, s->nclients);
        refuse(cfd, "server full", ws);
        return;
    }
    if (s->cfg.max_per_address && addrcount_add(s->per_address, addr, +1) > s->cfg.max_per_address) {
        addrcount_add(s->per_address, addr, -1);
        log_warn("%s refused: over %u connections from this address", peer, s->cfg.max_per_address);
        refuse(cfd, "too many connections from your address", ws);
        return;
    }
    int one = 1;
    setsockopt(cfd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    if (clients__add(s, cfd, peer, addr, handlers__on_io, ws ? ws->p : NULL, ws ? ws->len : 0) < 0) {
        log_error("%s refused: cannot register the connection", peer);
        if (s->cfg.max_per_address)
            addrcount_add(s->per_address, addr, -1);
    }
}

static void on_accepted(void *data, int cfd, const char *peer) { admit(data, cfd, peer, NULL); }

void admission__websocket(void *data, int fd, const char *peer, const uint8_t *first, size_t first_len)
{
    ws_first ws = {first, first_len};
    admit(data, fd, peer, &ws);
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
