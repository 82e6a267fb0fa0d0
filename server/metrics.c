/* metrics.c: Prometheus text exposition of the server's figures (see metrics.h). */
#include "metrics.h"

#include <inttypes.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"

const double metrics_tick_bounds[METRICS_TICK_BUCKETS] = {0.0005, 0.001, 0.002,  0.004, 0.008, 0.0167,
                                                          0.025,  0.0333, 0.05, 0.1,   0.25,  1.0};

void metrics_tick_observe(metrics_histogram *h, double seconds)
{
    size_t i = 0;
    while (i < METRICS_TICK_BUCKETS && seconds > metrics_tick_bounds[i])
        i++;
    h->counts[i]++;
    h->count++;
    h->sum += seconds;
}

/* One sample of a family: its labels as written between the braces
 * (NULL: none) and where its value is in the snapshot. */
typedef struct sample {
    const char *labels;
    size_t offset;
} sample;

#define SAMPLES_MAX 4

/* A family of uint64 samples. Help texts hold no backslash and no line
 * break, so they need no escaping. */
typedef struct family {
    const char *name, *type, *help;
    sample samples[SAMPLES_MAX]; /* the first without labels ends a labelled list */
} family;

#define AT(field) offsetof(metrics_snapshot, field)

static const family families[] = {
    {"cvre_clients", "gauge", "Connections open, joined or not.", {{NULL, AT(clients)}}},
    {"cvre_avatars", "gauge", "Avatars in the world.", {{NULL, AT(avatars)}}},
    {"cvre_objects", "gauge", "Objects in the world.", {{NULL, AT(objects)}}},
    {"cvre_connections_total", "counter", "Connections accepted.", {{NULL, AT(connections)}}},
    {"cvre_ticks_total", "counter", "Simulation ticks run.", {{NULL, AT(ticks)}}},
    {"cvre_frames_received_total", "counter", "Protocol frames received.", {{NULL, AT(frames_in)}}},
    {"cvre_moves_total", "counter", "Moves received.", {{NULL, AT(moves)}}},
    {"cvre_moves_dropped_total", "counter", "Moves dropped for coming faster than twice the tick rate.",
     {{NULL, AT(moves_dropped)}}},
    {"cvre_received_bytes_total", "counter", "Bytes read from game clients.", {{NULL, AT(bytes_in)}}},
    {"cvre_sent_bytes_total", "counter", "Bytes written to game clients.", {{NULL, AT(bytes_out)}}},
    {"cvre_timeouts_total", "counter", "Connections closed for a handshake or idle timeout.", {{NULL, AT(timeouts)}}},
    {"cvre_slow_readers_total", "counter", "Connections cut off for letting their output back up.",
     {{NULL, AT(slow_readers)}}},
    {"cvre_collisions_total", "counter", "Blocking contacts between avatars and object boxes.",
     {{NULL, AT(collisions)}}},
    {"cvre_collision_log_rows_total", "counter",
     "Collision log rows by outcome: written (committed), dropped (the queue was full), invalid (a number not "
     "finite), lost (in a batch the writer gave up on).",
     {{"outcome=\"written\"", AT(log_written)},
      {"outcome=\"dropped\"", AT(log_dropped)},
      {"outcome=\"invalid\"", AT(log_invalid)},
      {"outcome=\"lost\"", AT(log_lost)}}},
    {"cvre_collision_log_write_failures_total", "counter",
     "Failed attempts to commit a batch of collision rows, each logged: a full disk, a lock held too long.",
     {{NULL, AT(log_failures)}}},
    {"cvre_collision_log_queue_rows", "gauge", "Collision rows queued for the log's writer thread.",
     {{NULL, AT(log_queue)}}},
    {"cvre_collision_log_queue_high_water_rows", "gauge", "Most collision rows ever queued at once.",
     {{NULL, AT(log_queue_high)}}},
    {"cvre_imports_total", "counter", "Uploaded models by import result.",
     {{"result=\"ok\"", AT(imports_ok)}, {"result=\"failed\"", AT(imports_failed)}}},
    {"cvre_refine_rounds_total", "counter", "Rounds of the online loop: new collisions read and clustered.",
     {{NULL, AT(refine_rounds)}}},
    {"cvre_collision_maps_written_total", "counter", "Collision map versions the online loop refined and stored.",
     {{NULL, AT(versions_written)}}},
    {"cvre_collision_maps_published_total", "counter",
     "Collision map versions put in force and sent to clients, whoever stored them.",
     {{NULL, AT(versions_published)}}},
};

/* A growing string; oom is sticky, so one check at the end suffices. */
typedef struct text {
    char *p;
    size_t len, cap;
    int oom;
} text;

static void put(text *t, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void put(text *t, const char *fmt, ...)
{
    for (int tries = 0; tries < 2 && !t->oom; tries++) {
        va_list ap;
        va_start(ap, fmt);
        int n = vsnprintf(t->p ? t->p + t->len : NULL, t->p ? t->cap - t->len : 0, fmt, ap);
        va_end(ap);
        if (n < 0) {
            t->oom = 1;
            return;
        }
        if (t->p && (size_t)n < t->cap - t->len) {
            t->len += (size_t)n;
            return;
        }
        size_t cap = t->cap ? t->cap : 4096;
        while (cap - t->len <= (size_t)n)
            cap *= 2;
        char *p = cvre_realloc(t->p, cap);
        if (!p) {
            t->oom = 1;
            return;
        }
        t->p = p;
        t->cap = cap;
    }
}

static void put_head(text *t, const char *name, const char *type, const char *help)
{
    put(t, "# HELP %s %s\n# TYPE %s %s\n", name, help, name, type);
}

/* A label value as the format wants it: backslash, double quote and line
 * feed escaped. */
static void put_label_value(text *t, const char *v)
{
    for (; *v; v++) {
        if (*v == '\\' || *v == '"')
            put(t, "\\%c", *v);
        else if (*v == '\n')
            put(t, "\\n");
        else
            put(t, "%c", *v);
    }
}

static uint64_t value_at(const metrics_snapshot *s, size_t offset)
{
    uint64_t v;
    memcpy(&v, (const char *)s + offset, sizeof v);
    return v;
}

static void put_family(text *t, const metrics_snapshot *s, const family *f)
{
    put_head(t, f->name, f->type, f->help);
    for (size_t k = 0; k < SAMPLES_MAX && (k == 0 || f->samples[k].labels); k++) {
        if (f->samples[k].labels)
            put(t, "%s{%s}", f->name, f->samples[k].labels);
        else
            put(t, "%s", f->name);
        put(t, " %" PRIu64 "\n", value_at(s, f->samples[k].offset));
    }
}

/* Counts by protocol status code, with the code's description as a
 * second label: every error code proto.h names, and any other one that
 * was counted. */
static void put_by_code(text *t, const char *name, const char *help, const uint64_t *by_code)
{
    const char *unknown = proto_strerror(-1);
    put_head(t, name, "counter", help);
    for (int code = PROTO_ERR_FRAME_EMPTY; code < METRICS_CODES; code++) {
        const char *reason = proto_strerror(code);
        if (!by_code[code] && strcmp(reason, unknown) == 0)
            continue;
        put(t, "%s{code=\"%d\",reason=\"", name, code);
        put_label_value(t, reason);
        put(t, "\"} %" PRIu64 "\n", by_code[code]);
    }
}

static void put_histogram(text *t, const char *name, const char *help, const metrics_histogram *h)
{
    uint64_t below = 0;
    put_head(t, name, "histogram", help);
    for (size_t i = 0; i < METRICS_TICK_BUCKETS; i++) {
        below += h->counts[i];
        put(t, "%s_bucket{le=\"%g\"} %" PRIu64 "\n", name, metrics_tick_bounds[i], below);
    }
    put(t, "%s_bucket{le=\"+Inf\"} %" PRIu64 "\n", name, h->count);
    put(t, "%s_sum %.9g\n%s_count %" PRIu64 "\n", name, h->sum, name, h->count);
}

char *metrics_render(const metrics_snapshot *s, size_t *len)
{
    text t = {0};
    for (size_t i = 0; i < sizeof families / sizeof families[0]; i++)
        put_family(&t, s, &families[i]);
    put_histogram(&t, "cvre_tick_duration_seconds",
                  "Time one tick took: movement, collisions and every client's view.", &s->tick);
    put_by_code(&t, "cvre_protocol_errors_total", "Error frames sent before closing a connection, by error code.",
                s->errors);
    put_by_code(&t, "cvre_requests_rejected_total",
                "Object requests refused, the connection kept, by error code.", s->rejected);
    if (t.oom) {
        free(t.p);
        return NULL;
    }
    *len = t.len;
    return t.p;
}
