/* http_server.c: an HTTP/1.1 endpoint on the event loop (see http_server.h). */
#include "http_server.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "alloc.h"
#include "conn.h"
#include "err.h"
#include "listener.h"
#include "log.h"

#define NS_PER_MS ((uint64_t)1000000)
/* Connections accepted per wakeup of the listening socket: a burst past
 * the cap is refused a few at a time, between the game's own events. */
#define ACCEPT_BUDGET 16
/* listen(2) backlog: scrapers come one at a time. */
#define LISTEN_BACKLOG 64
/* How often deadlines are checked: a deadline is met within this. */
#define SWEEP_MS 100u
/* Kernel send buffer per connection: a metrics response (about 10 KiB)
 * goes in one write; a larger one waits in the connection's own buffer,
 * bounded by HTTP_BODY_MAX, rather than in up to 4 MiB of the kernel's
 * per socket (tcp_wmem). */
#define SOCKET_SNDBUF (64 * 1024)
/* Room for a response head: a status line and five short headers. */
#define HEAD_ROOM 512u

/* The endpoint's limits on each connection: its output holds one response
 * at most; the linger starts with the response and starts again with
 * each write the peer takes, so a slow reader of a large body is not cut
 * off while it reads. */
static const conn_config http_conn_config = {.out_hard = HTTP_BODY_MAX + HEAD_ROOM, .linger_ms = HTTP_LINGER_MS,
                                             .linger_extends = 1, .sndbuf = SOCKET_SNDBUF};

/* READING the request head; WRITING the response (the conn is closing:
 * its linger runs); DRAINING: the response is out and the write side
 * shut, reading (and dropping) until the peer closes, so that the close
 * does not reset a response it has not read. */
typedef enum { HC_READING, HC_WRITING, HC_DRAINING } hc_state;

typedef struct http_conn {
    conn c;
    http_server *h;
    http_request *req;
    hc_state state;
    int dead; /* reaped at the next safe point */
    int eof;  /* the peer shut its write side */
    uint64_t request_deadline_ns;
    /* A file body still being read into the output (-1: none): the close
     * begins once the last of it is queued; until then each write the
     * peer takes gives it HTTP_LINGER_MS again (stream_deadline_ns). */
    int file_fd;
    uint64_t file_left;
    uint64_t stream_deadline_ns;
    char peer[80];
} http_conn;

struct http_server {
    ev_loop *loop;
    char name[32];
    uint32_t max_conns;
    http_handler_fn *fn;
    void *data;
    net_listener *listener;
    int sweep_timer;
    int reap_timer; /* a pending zero-delay timer, or -1 */
    http_conn **conns;
    uint32_t nconns;
};

const char *http_server_address(const http_server *h) { return net_listener_address(h->listener); }

static void reap_dead(http_server *h)
{
    for (uint32_t i = 0; i < h->nconns;) {
        http_conn *hc = h->conns[i];
        if (!hc->dead) {
            i++;
            continue;
        }
        conn_free(&hc->c);
        http_request_free(hc->req);
        if (hc->file_fd >= 0)
            close(hc->file_fd);
        free(hc);
        h->conns[i] = h->conns[--h->nconns];
    }
}

static void on_reap(ev_loop *loop, void *data)
{
    (void)loop;
    http_server *h = data;
    h->reap_timer = -1;
    reap_dead(h);
}

/* Marks hc for reaping once the callbacks of this loop iteration are over
 * (the sweep reaps it if no timer could be started). */
static void kill_conn(http_conn *hc)
{
    http_server *h = hc->h;
    hc->dead = 1;
    if (h->reap_timer < 0)
        h->reap_timer = ev_timer_start(h->loop, 0, 0, on_reap, h);
}

/* Tops the output up from the file body to HTTP_FILE_CHUNK pending; once
 * the last byte is queued, closes the file and begins the close. 0, or
 * -errno when the file cannot be read (or came out shorter than it was). */
static int feed_file(http_conn *hc)
{
    while (hc->file_left > 0 && conn_out_pending(&hc->c) < HTTP_FILE_CHUNK) {
        uint8_t *room;
        size_t len;
        int rc = conn_out_reserve(&hc->c, HTTP_FILE_CHUNK, &room, &len);
        if (rc < 0)
            return rc;
        size_t want = hc->file_left < HTTP_FILE_CHUNK ? (size_t)hc->file_left : HTTP_FILE_CHUNK;
        ssize_t n = read(hc->file_fd, room, want);
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0)
            return n < 0 ? -errno : -EIO;
        conn_out_commit(&hc->c, (size_t)n);
        hc->file_left -= (uint64_t)n;
    }
    if (hc->file_left == 0) {
        close(hc->file_fd);
        hc->file_fd = -1;
        conn_begin_close(&hc->c);
    }
    return 0;
}

/* Writes what is pending (conn_flush shuts the write side once all of it
 * is out, after the close began), topping a file body up as the socket
 * takes it; then drains, or closes if the peer has shut its side already. */
static void flush(http_conn *hc)
{
    ssize_t left;
    do {
        if (hc->file_fd >= 0) {
            int rc = feed_file(hc);
            if (rc < 0) {
                log_warn("%s: %s: the file being sent: %s", hc->h->name, hc->peer, strerror(-rc));
                kill_conn(hc);
                return;
            }
        }
        size_t before = conn_out_pending(&hc->c);
        left = conn_flush(&hc->c);
        if (left >= 0 && (size_t)left < before)
            hc->stream_deadline_ns = ev_now(hc->h->loop) + HTTP_LINGER_MS * NS_PER_MS;
    } while (left == 0 && hc->file_fd >= 0);
    if (left < 0 || (left == 0 && hc->eof))
        kill_conn(hc);
    else if (left == 0)
        hc->state = HC_DRAINING;
}

/* Hands hc's socket to the reply's takeover, with the reply's body to send
 * first; hc leaves the server without closing it. */
static void hand_over(http_conn *hc, http_reply *rep)
{
    int fd = hc->c.fd;
    ev_io_del(hc->h->loop, fd);
    hc->c.fd = -1; /* conn_free leaves it open */
    log_debug("%s: %s: %s %s: taken over", hc->h->name, hc->peer, http_request_method(hc->req),
              http_request_target(hc->req));
    rep->takeover(rep->takeover_data, fd, hc->peer, (const uint8_t *)rep->body, rep->body_len);
    free(rep->body);
    kill_conn(hc);
}

/* The one-line body of a reply that has none: "404 Not Found\n". */
static size_t status_body(int status, char *out, size_t cap)
{
    int n = snprintf(out, cap, "%d %s\n", status, http_reason(status));
    return n < 0 ? 0 : (size_t)n < cap ? (size_t)n : cap - 1;
}

/* Queues the response and writes what the socket takes now; frees the
 * reply's body. complete: it answers a whole request (for the log). */
static void respond(http_conn *hc, http_reply *rep, int complete)
{
    char head[HEAD_ROOM], line[64];
    if (rep->body_len > HTTP_BODY_MAX) {
        log_error("%s: a response of %zu bytes is over the limit of %u", hc->h->name, rep->body_len, HTTP_BODY_MAX);
        free(rep->body);
        *rep = (http_reply){.status = 500, .file_fd = -1};
    }
    const char *body = rep->body;
    size_t body_len = rep->body_len;
    int file = rep->file_fd >= 0;
    if (file) {
        body_len = 0;
        hc->file_fd = rep->file_fd;
        hc->file_left = rep->file_size;
    } else if (rep->status == 304) {
        body_len = 0;
    } else if (!body) {
        body_len = status_body(rep->status, line, sizeof line);
        body = line;
        rep->content_type = "text/plain; charset=utf-8";
    }
    int n = http_response_head(head, sizeof head, rep->status, rep->content_type,
                               file || rep->status == 304 ? (size_t)rep->file_size : body_len, rep->extra);
    uint8_t *room;
    size_t room_len;
    if (n < 0 || conn_out_reserve(&hc->c, (size_t)n + body_len, &room, &room_len) < 0) {
        log_error("%s: cannot queue a response of %zu bytes", hc->h->name, body_len);
        free(rep->body);
        kill_conn(hc);
        return;
    }
    memcpy(room, head, (size_t)n);
    if (body_len) /* a file's body follows from flush */
        memcpy(room + n, body, body_len);
    conn_out_commit(&hc->c, (size_t)n + body_len);
    free(rep->body);
    if (complete)
        log_debug("%s: %s: %s %s: %d", hc->h->name, hc->peer, http_request_method(hc->req),
                  http_request_target(hc->req), rep->status);
    else
        log_debug("%s: %s: %d", hc->h->name, hc->peer, rep->status);
    hc->state = HC_WRITING;
    hc->stream_deadline_ns = ev_now(hc->h->loop) + HTTP_LINGER_MS * NS_PER_MS;
    if (!file)
        conn_begin_close(&hc->c);
    flush(hc);
}

static void on_conn_io(ev_loop *loop, int fd, unsigned events, void *data)
{
    (void)loop;
    (void)fd;
    http_conn *hc = data;
    if (!hc->dead && (events & EV_WRITE))
        flush(hc);
    if (hc->dead || !(events & (EV_READ | EV_ERROR)))
        return;
    ssize_t n;
    if (hc->state == HC_READING) {
        n = conn_read(&hc->c, HTTP_HEAD_MAX, HTTP_HEAD_MAX);
    } else { /* answered: what comes now is dropped, a sink's worth at a time */
        char sink[16384];
        n = read(hc->c.fd, sink, sizeof sink);
        if (n < 0)
            n = errno == EAGAIN || errno == EINTR ? -EAGAIN : -errno;
    }
    if (n == -EAGAIN)
        return;
    if (n == 0 && hc->state == HC_WRITING) { /* half-closed: it may still read */
        hc->eof = 1;
        conn_set_reading(&hc->c, 0);
        return;
    }
    if (n <= 0) { /* gone before asking, done after the answer, or broken */
        kill_conn(hc);
        return;
    }
    if (hc->state != HC_READING)
        return;
    int rc = http_request_feed(hc->req, hc->c.in, hc->c.in_len);
    conn_consume(&hc->c, hc->c.in_len); /* the request keeps what it needs */
    if (rc == HTTP_INCOMPLETE)
        return;
    http_reply rep = {.status = rc, .file_fd = -1};
    if (rc == HTTP_COMPLETE) {
        rep.status = 200;
        hc->h->fn(hc->h->data, hc->req, &rep);
    }
    if (rep.takeover)
        hand_over(hc, &rep);
    else
        respond(hc, &rep, rc == HTTP_COMPLETE);
}

/* Deadlines: a request head that has not arrived gets 408; a response
 * not taken (or a peer that does not close) is cut off. Then the dead
 * are reaped. */
static void on_sweep(ev_loop *loop, void *data)
{
    http_server *h = data;
    uint64_t now = ev_now(loop);
    for (uint32_t i = 0; i < h->nconns; i++) {
        http_conn *hc = h->conns[i];
        if (hc->dead)
            continue;
        if (hc->state == HC_READING) {
            if (now > hc->request_deadline_ns) {
                http_reply rep = {.status = 408, .file_fd = -1};
                respond(hc, &rep, 0);
            }
        } else if (conn_overdue(&hc->c) == -ETIMEDOUT || (hc->file_fd >= 0 && now > hc->stream_deadline_ns)) {
            kill_conn(hc);
        }
    }
    reap_dead(h);
}

/* Best effort, on a fresh socket: the status, then the close. */
static void refuse(int fd, int status)
{
    char out[HEAD_ROOM], body[64];
    size_t body_len = status_body(status, body, sizeof body);
    int n = http_response_head(out, sizeof out - body_len, status, "text/plain; charset=utf-8", body_len, NULL);
    if (n > 0) {
        memcpy(out + n, body, body_len);
        ssize_t w = write(fd, out, (size_t)n + body_len);
        (void)w;
    }
    close(fd);
}

/* A connection from the listener: served, or refused past the cap. */
static void on_accepted(void *data, int cfd, const char *peer)
{
    http_server *h = data;
    if (h->nconns >= h->max_conns) {
        log_debug("%s: %s refused: %u connections open", h->name, peer, h->nconns);
        refuse(cfd, 503);
        return;
    }
    http_conn *hc = cvre_calloc(1, sizeof *hc);
    if (!hc) {
        refuse(cfd, 503);
        return;
    }
    if (conn_open(&hc->c, h->loop, cfd, &http_conn_config, on_conn_io, hc) < 0 || !(hc->req = http_request_new())) {
        log_warn("%s: %s refused: cannot register the connection", h->name, peer);
        http_request_free(hc->req);
        conn_free(&hc->c); /* closes cfd */
        free(hc);
        return;
    }
    hc->h = h;
    hc->file_fd = -1;
    snprintf(hc->peer, sizeof hc->peer, "%s", peer);
    hc->request_deadline_ns = ev_now(h->loop) + HTTP_REQUEST_TIMEOUT_MS * NS_PER_MS;
    h->conns[h->nconns++] = hc;
}

int http_server_start(ev_loop *loop, const http_server_config *cfg, http_handler_fn *fn, void *data,
                      http_server **out, char *err, size_t errlen)
{
    *out = NULL;
    http_server *h = cvre_calloc(1, sizeof *h);
    if (!h)
        return cvre_fail(err, errlen, -ENOMEM, "%s: out of memory", cfg->name);
    h->loop = loop;
    snprintf(h->name, sizeof h->name, "%s", cfg->name);
    h->max_conns = cfg->max_conns;
    h->fn = fn;
    h->data = data;
    h->sweep_timer = h->reap_timer = -1;
    int rc = -ENOMEM;
    char msg[256];
    net_listener_config lc = {.name = cfg->name, .host = cfg->host, .port = cfg->port, .backlog = LISTEN_BACKLOG,
                              .budget = ACCEPT_BUDGET};
    h->conns = cvre_calloc(cfg->max_conns, sizeof *h->conns);
    if (!h->conns) {
        cvre_fail(err, errlen, rc, "%s: out of memory", cfg->name);
        goto fail;
    }
    rc = net_listener_start(loop, &lc, on_accepted, h, &h->listener, msg, sizeof msg);
    if (rc < 0) {
        cvre_fail(err, errlen, rc, "%s: %s", cfg->name, msg);
        goto fail;
    }
    h->sweep_timer = rc = ev_timer_start(loop, SWEEP_MS * NS_PER_MS, SWEEP_MS * NS_PER_MS, on_sweep, h);
    if (rc < 0) {
        cvre_fail(err, errlen, rc, "%s: event loop: %s", cfg->name, strerror(-rc));
        goto fail;
    }
    *out = h;
    return 0;
fail:
    http_server_stop(h);
    return rc;
}

void http_server_stop(http_server *h)
{
    if (!h)
        return;
    net_listener_stop(h->listener);
    if (h->sweep_timer >= 0)
        ev_timer_stop(h->loop, h->sweep_timer);
    if (h->reap_timer >= 0)
        ev_timer_stop(h->loop, h->reap_timer);
    for (uint32_t i = 0; i < h->nconns; i++)
        h->conns[i]->dead = 1;
    reap_dead(h);
    free(h->conns);
    free(h);
}
