/*
 * metrics_endpoint.c: `--metrics HOST:PORT`, the server's figures for
 * Prometheus. GET /metrics answers with metrics.h's text, gathered on the
 * loop's thread at the moment of the request (the collision log's and the
 * refiner's counters are read through their own stats calls); any other
 * path is 404, any other method on it 405. The endpoint is http_server.h's:
 * bounded, on the same loop, never in the tick's way for longer than one
 * rendering (about 10 KiB of text).
 */
#include <string.h>

#include "http_server.h"
#include "log.h"
#include "metrics.h"
#include "metrics_endpoint.h"

#define METRICS_PATH "/metrics"

static void snapshot(server *s, metrics_snapshot *m)
{
    const stats *st = &s->st;
    dblog_stats ls;
    refiner_stats rs;
    dblog_stats_get(s->log, &ls);
    refiner_stats_get(s->refiner, &rs);
    *m = (metrics_snapshot){
        .clients = s->nclients, .avatars = world_count(s->world), .objects = scene_count(s->scene),
        .log_queue = ls.queued, .log_queue_high = ls.high_water,
        .connections = st->accepted, .ticks = st->ticks, .frames_in = st->frames_in, .moves = st->moves_in,
        .moves_dropped = st->moves_dropped, .bytes_in = st->bytes_in, .bytes_out = st->bytes_out,
        .timeouts = st->timeouts, .slow_readers = st->slow_readers, .collisions = st->collisions,
        .log_written = ls.written, .log_dropped = ls.dropped, .log_invalid = ls.invalid, .log_lost = ls.lost,
        .log_failures = ls.failures,
        .imports_ok = st->imports_ok, .imports_failed = st->imports_failed,
        .refine_rounds = rs.rounds, .versions_written = rs.versions_written,
        .versions_published = st->versions_published, .tick = st->tick_hist};
    memcpy(m->errors, st->errors, sizeof m->errors);
    memcpy(m->rejected, st->rejected, sizeof m->rejected);
}

static void on_request(void *data, const http_request *req, http_reply *rep)
{
    server *s = data;
    if (strcmp(http_request_path(req), METRICS_PATH) != 0) {
        rep->status = 404;
        return;
    }
    if (strcmp(http_request_method(req), "GET") != 0) {
        rep->status = 405;
        rep->extra = "Allow: GET\r\n";
        return;
    }
    metrics_snapshot m;
    snapshot(s, &m);
    rep->body = metrics_render(&m, &rep->body_len);
    if (!rep->body) {
        log_error("metrics: out of memory");
        rep->status = 500;
        return;
    }
    rep->content_type = METRICS_CONTENT_TYPE;
}

int metrics__start(server *s, char *err, size_t errlen)
{
    if (!s->cfg.metrics_host)
        return 0;
    http_server_config hc = {.name = "metrics", .host = s->cfg.metrics_host, .port = s->cfg.metrics_port,
                             .max_conns = HTTP_CONNS_DEFAULT};
    int rc = http_server_start(s->loop, &hc, on_request, s, &s->metrics, err, errlen);
    if (rc < 0)
        return rc;
    log_info("metrics on http://%s" METRICS_PATH, http_server_address(s->metrics));
    return 0;
}

void metrics__stop(server *s)
{
    http_server_stop(s->metrics);
    s->metrics = NULL;
}
