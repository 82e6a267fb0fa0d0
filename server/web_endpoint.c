/*
 * web_endpoint.c: `--web HOST:PORT` (web_endpoint.h): a GET is a file of
 * the web root, sent with Connection: close; a GET asking for a WebSocket
 * gets the handshake's answer and becomes a game client.
 */
#include "web_endpoint.h"

#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <unistd.h>

#include "admission.h"
#include "alloc.h"
#include "http_server.h"
#include "log.h"
#include "web_files.h"
#include "ws.h"

/* Connections served at once: a browser loads a page's files over up to
 * six connections, each closed after its file; a few browsers loading at
 * once fit. An upgraded connection leaves this count (it is a client). */
#define WEB_CONNS 64u

/* The upgrade's answer (RFC 6455 4.2.2). */
static char *switching(const char *accept, size_t *len)
{
    char *out = cvre_xmalloc(160);
    int n = snprintf(out, 160,
                     "HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                     "Sec-WebSocket-Accept: %s\r\n\r\n",
                     accept);
    *len = (size_t)n;
    return out;
}

/* Whether a page of this Origin may open a WebSocket: a browser sends
 * Origin, so a page elsewhere that the user happens to visit cannot play
 * in their name on a server their browser reaches (127.0.0.1 included)
 * unless --web-origin lists it. The server's own pages (the origin is
 * http:// or https:// followed by the Host the request was sent to) may,
 * and so may every client that sends no Origin (cvre-client --ws, bots):
 * they are not a browser acting for someone. */
static int origin_allowed(const server *s, const char *origin, const char *host)
{
    if (!origin)
        return 1;
    const char *rest = strncasecmp(origin, "http://", 7) == 0    ? origin + 7
                       : strncasecmp(origin, "https://", 8) == 0 ? origin + 8
                                                                  : NULL;
    if (rest && host && strcasecmp(rest, host) == 0)
        return 1;
    const char *list = s->cfg.web_origins;
    return list && (ws_list_has(list, "*") || ws_list_has(list, origin));
}

static void upgrade(server *s, const http_request *req, http_reply *rep)
{
    const char *origin = http_request_header(req, "origin");
    if (!origin_allowed(s, origin, http_request_header(req, "host"))) {
        log_info("web: a WebSocket from a page of %s refused: not this server's, not in --web-origin", origin);
        rep->status = 403;
        return;
    }
    ws_upgrade u = {.method = http_request_method(req),
                    .http_minor = http_request_minor(req),
                    .upgrade = http_request_header(req, "upgrade"),
                    .connection = http_request_header(req, "connection"),
                    .version = http_request_header(req, "sec-websocket-version"),
                    .key = http_request_header(req, "sec-websocket-key")};
    char accept[WS_ACCEPT_SIZE], err[128];
    int rc = ws_handshake(&u, accept, err, sizeof err);
    if (rc < 0) {
        log_info("web: a WebSocket handshake refused: %s", err);
        rep->status = rc == -EPROTONOSUPPORT ? 426 : rc == -EINVAL ? 400 : 500;
        if (rc == -EPROTONOSUPPORT)
            rep->extra = "Sec-WebSocket-Version: 13\r\n";
        return;
    }
    rep->status = 101;
    rep->body = switching(accept, &rep->body_len);
    rep->takeover = admission__websocket;
    rep->takeover_data = s;
}

static void on_request(void *data, const http_request *req, http_reply *rep)
{
    server *s = data;
    if (ws_asks_upgrade(http_request_header(req, "upgrade"))) { /* h2c and the like are ignored */
        upgrade(s, req, rep);
        return;
    }
    if (strcmp(http_request_method(req), "GET") != 0) {
        rep->status = 405;
        rep->extra = "Allow: GET\r\n";
        return;
    }
    const char *target = http_request_target(req);
    web_file f;
    int rc = s->web_root_fd < 0 ? -ENOENT : web_files_open(s->web_root_fd, target, strlen(target), &f);
    switch (rc) {
    case 0:
        /* Each load asks again (no-cache) and gets 304 while the file is
         * the same: about 2 MB of three.js is not sent twice. */
        snprintf(rep->extra_buf, sizeof rep->extra_buf, "ETag: %s\r\nCache-Control: no-cache\r\n", f.etag);
        rep->extra = rep->extra_buf;
        rep->file_size = f.size;
        if (web_files_etag_matches(http_request_header(req, "if-none-match"), f.etag)) {
            close(f.fd);
            rep->status = 304;
            return;
        }
        rep->file_fd = f.fd;
        rep->content_type = f.type;
        return;
    case -ENOENT: rep->status = 404; return;
    case -EACCES: rep->status = 403; return;
    case -EINVAL: rep->status = 400; return;
    default:
        log_warn("web: %s: %s", target, strerror(-rc));
        rep->status = rc == -EMFILE || rc == -ENFILE ? 503 : 500;
        return;
    }
}

int web__start(server *s, char *err, size_t errlen)
{
    s->web_root_fd = -1;
    if (!s->cfg.web_host)
        return 0;
    s->web_root_fd = open(s->cfg.web_root, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (s->web_root_fd < 0) /* the WebSocket is still of use (a page served elsewhere, a script) */
        log_warn("web: --web-root %s: %s; every file is 404", s->cfg.web_root, strerror(errno));
    http_server_config hc = {.name = "web", .host = s->cfg.web_host, .port = s->cfg.web_port, .max_conns = WEB_CONNS};
    int rc = http_server_start(s->loop, &hc, on_request, s, &s->web, err, errlen);
    if (rc < 0)
        return rc;
    log_info("web on http://%s/ (files from %s)", http_server_address(s->web), s->cfg.web_root);
    return 0;
}

void web__stop(server *s)
{
    http_server_stop(s->web);
    s->web = NULL;
    if (s->web_root_fd >= 0)
        close(s->web_root_fd);
    s->web_root_fd = -1;
}
