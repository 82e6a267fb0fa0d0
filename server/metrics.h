/*
 * metrics.h: the server's metrics in Prometheus's text exposition format
 * (version 0.0.4), and the histogram the tick durations go into.
 *
 * Pure: the caller gathers the figures into a metrics_snapshot (the
 * metrics endpoint, metrics_endpoint.c, reads them from the server, the
 * collision log and the refiner), and metrics_render writes the text:
 * every family with its # HELP and # TYPE, counters as totals since the
 * server started (they never go down, whatever the stats interval does).
 */
#ifndef CVRE_METRICS_H
#define CVRE_METRICS_H

#include <stddef.h>
#include <stdint.h>

#include "proto.h"

/* Upper bounds of the tick duration histogram, in seconds. A tick at 20 Hz
 * has 50 ms, at 30 Hz 33 ms, at 60 Hz 16.7 ms; the buckets are finer
 * below a millisecond (a quiet world), mark each of those budgets, and go
 * past them to tell a late tick from a very late one. */
#define METRICS_TICK_BUCKETS 12
extern const double metrics_tick_bounds[METRICS_TICK_BUCKETS];

/* Protocol status codes counted, 0 .. METRICS_CODES - 1 (proto.h's are
 * all below 64; a code past it is not counted). */
#define METRICS_CODES 64
_Static_assert(PROTO_ERR_RATE_LIMITED < METRICS_CODES, "every protocol error code is counted");

typedef struct metrics_histogram {
    uint64_t counts[METRICS_TICK_BUCKETS + 1]; /* per bucket, not cumulative; the last one is +Inf */
    uint64_t count;
    double sum; /* seconds */
} metrics_histogram;

/* Counts one tick that took seconds. */
void metrics_tick_observe(metrics_histogram *h, double seconds);

/* Every figure the endpoint serves. Counters are totals since start. */
typedef struct metrics_snapshot {
    /* gauges */
    uint64_t clients;            /* connections open, joined or not */
    uint64_t avatars;            /* avatars in the world */
    uint64_t objects;            /* objects in the world */
    uint64_t log_queue;          /* collision rows queued for the log's writer */
    uint64_t log_queue_high;     /* most rows ever queued */
    /* counters */
    uint64_t connections;        /* accepted */
    uint64_t ticks;
    uint64_t frames_in;
    uint64_t moves;              /* received */
    uint64_t moves_dropped;      /* over the rate limit */
    uint64_t bytes_in, bytes_out;
    uint64_t timeouts, slow_readers;
    uint64_t collisions;         /* contacts the tick found */
    uint64_t log_written;        /* collision rows committed */
    uint64_t log_dropped;        /* refused: the queue was full */
    uint64_t log_invalid;        /* refused: a number not finite */
    uint64_t log_lost;           /* in batches the writer gave up on */
    uint64_t log_failures;       /* failed attempts to commit a batch */
    uint64_t imports_ok, imports_failed;
    uint64_t refine_rounds;      /* online clustering rounds */
    uint64_t versions_written;   /* collision maps the online loop stored */
    uint64_t versions_published; /* collision maps put in force, whoever stored them */
    uint64_t errors[METRICS_CODES];   /* error frames sent (the connection then closes), by code */
    uint64_t rejected[METRICS_CODES]; /* object requests refused, by code */
    metrics_histogram tick;
} metrics_snapshot;

/* The text of snap: a malloc'd, NUL-terminated string (its length in
 * *len), or NULL if out of memory. Every protocol error code proto.h
 * names is listed, at 0 until it happens, so that rates work from the
 * first scrape. */
char *metrics_render(const metrics_snapshot *snap, size_t *len);

/* The Content-Type of that text. */
#define METRICS_CONTENT_TYPE "text/plain; version=0.0.4; charset=utf-8"

#endif
