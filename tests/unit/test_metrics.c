/* The metrics text (server/metrics.c): every line in Prometheus's text
 * format, every figure of the snapshot under its name, the histogram's
 * buckets, counts by protocol code, and out of memory. */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>
#include <ctype.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "metrics.h"

/* cmocka's assert_float_equal is for float; the figures are double. */
#define assert_near(a, b, eps) assert_true(fabs((double)(a) - (double)(b)) <= (eps))

static int is_name(const char *p, size_t n)
{
    if (n == 0 || !(isalpha((unsigned char)p[0]) || p[0] == '_' || p[0] == ':'))
        return 0;
    for (size_t i = 1; i < n; i++)
        if (!(isalnum((unsigned char)p[i]) || p[i] == '_' || p[i] == ':'))
            return 0;
    return 1;
}

static int ends_with(const char *s, size_t n, const char *tail)
{
    size_t k = strlen(tail);
    return n >= k && memcmp(s + n - k, tail, k) == 0;
}

/* Checks a label set {a="x",b="y"} at p; returns the byte after '}'. */
static const char *check_labels(const char *p)
{
    assert_int_equal(*p, '{');
    p++;
    for (;;) {
        const char *eq = strchr(p, '=');
        assert_non_null(eq);
        assert_true(is_name(p, (size_t)(eq - p)));
        assert_int_equal(eq[1], '"');
        p = eq + 2;
        while (*p != '"') {
            assert_true(*p && *p != '\n');
            if (*p == '\\') {
                assert_true(p[1] == '\\' || p[1] == '"' || p[1] == 'n');
                p++;
            }
            p++;
        }
        p++;
        if (*p == '}')
            return p + 1;
        assert_int_equal(*p, ',');
        p++;
    }
}

/* Walks every line of text as the exposition format defines it: HELP
 * then TYPE once per family, names unique, every sample of the family
 * just typed (a histogram's _bucket, _sum and _count), one space, a number
 * that parses whole. Returns the families seen. */
static int check_format(const char *text, size_t len)
{
    char family[128] = "", type[16] = "", seen[64][128];
    int nseen = 0;
    assert_true(len > 0);
    assert_int_equal(text[len - 1], '\n');
    assert_int_equal(strlen(text), len);
    for (const char *line = text; *line;) {
        const char *end = strchr(line, '\n');
        size_t n = (size_t)(end - line);
        char buf[1024];
        assert_true(n < sizeof buf);
        memcpy(buf, line, n);
        buf[n] = 0;
        if (strncmp(buf, "# HELP ", 7) == 0) {
            const char *name = buf + 7, *sp = strchr(name, ' ');
            assert_non_null(sp);
            assert_true(is_name(name, (size_t)(sp - name)));
            assert_true(strlen(sp + 1) > 0 && !strchr(sp + 1, '\\'));
            snprintf(family, sizeof family, "%.*s", (int)(sp - name), name);
            for (int i = 0; i < nseen; i++)
                assert_string_not_equal(seen[i], family);
            assert_true(nseen < 64);
            snprintf(seen[nseen++], sizeof seen[0], "%s", family);
            type[0] = 0;
        } else if (strncmp(buf, "# TYPE ", 7) == 0) {
            char name[128];
            assert_int_equal(sscanf(buf + 7, "%127s %15s", name, type), 2);
            assert_string_equal(name, family);
            assert_true(strcmp(type, "counter") == 0 || strcmp(type, "gauge") == 0 ||
                        strcmp(type, "histogram") == 0);
            if (strcmp(type, "counter") == 0)
                assert_true(ends_with(family, strlen(family), "_total"));
        } else {
            assert_true(type[0]); /* a sample only after its family's TYPE */
            size_t k = strcspn(buf, "{ ");
            assert_true(is_name(buf, k));
            if (strcmp(type, "histogram") == 0) {
                size_t f = strlen(family);
                assert_true(k > f && strncmp(buf, family, f) == 0);
                assert_true(ends_with(buf, k, "_bucket") || ends_with(buf, k, "_sum") || ends_with(buf, k, "_count"));
            } else {
                assert_true(k == strlen(family) && strncmp(buf, family, k) == 0);
            }
            const char *p = buf + k;
            if (*p == '{')
                p = check_labels(p);
            assert_int_equal(*p, ' ');
            char *num_end;
            double v = strtod(p + 1, &num_end);
            assert_true(num_end > p + 1 && *num_end == 0);
            assert_true(isfinite(v) && v >= 0);
        }
        line = end + 1;
    }
    return nseen;
}

/* The value of the sample series (name and labels as written), which
 * must be there exactly once. */
static double value_of(const char *text, const char *series)
{
    size_t k = strlen(series);
    const char *found = NULL;
    for (const char *line = text; *line; line = strchr(line, '\n') + 1)
        if (strncmp(line, series, k) == 0 && line[k] == ' ') {
            assert_null(found);
            found = line + k + 1;
        }
    if (!found)
        fail_msg("no sample %s", series);
    return strtod(found, NULL);
}

static int has_series(const char *text, const char *series)
{
    size_t k = strlen(series);
    for (const char *line = text; *line; line = strchr(line, '\n') + 1)
        if (strncmp(line, series, k) == 0 && line[k] == ' ')
            return 1;
    return 0;
}

static void test_histogram_buckets(void **state)
{
    (void)state;
    metrics_histogram h = {0};
    for (size_t i = 1; i < METRICS_TICK_BUCKETS; i++)
        assert_true(metrics_tick_bounds[i] > metrics_tick_bounds[i - 1]);
    metrics_tick_observe(&h, 0);                             /* first bucket */
    metrics_tick_observe(&h, metrics_tick_bounds[0]);        /* a bound is in its own bucket (le) */
    metrics_tick_observe(&h, metrics_tick_bounds[5] * 1.01); /* the next one up */
    metrics_tick_observe(&h, 1e6);                           /* +Inf */
    assert_int_equal(h.counts[0], 2);
    assert_int_equal(h.counts[6], 1);
    assert_int_equal(h.counts[METRICS_TICK_BUCKETS], 1);
    assert_int_equal(h.count, 4);
    assert_near(h.sum, metrics_tick_bounds[0] + metrics_tick_bounds[5] * 1.01 + 1e6, 1e-9);
    /* The 20, 30 and 60 Hz budgets are bounds of their own. */
    int budgets = 0;
    for (size_t i = 0; i < METRICS_TICK_BUCKETS; i++)
        budgets += fabs(metrics_tick_bounds[i] - 0.05) < 1e-9 || fabs(metrics_tick_bounds[i] - 0.0333) < 1e-4 ||
                   fabs(metrics_tick_bounds[i] - 0.0167) < 1e-4;
    assert_int_equal(budgets, 3);
}

/* A snapshot whose every field differs, so that a figure under the wrong
 * name shows. */
static void fill(metrics_snapshot *m)
{
    memset(m, 0, sizeof *m);
    uint64_t *fields[] = {&m->clients, &m->avatars, &m->objects, &m->log_queue, &m->log_queue_high,
                          &m->connections, &m->ticks, &m->frames_in, &m->moves, &m->moves_dropped,
                          &m->bytes_in, &m->bytes_out, &m->timeouts, &m->slow_readers, &m->collisions,
                          &m->log_written, &m->log_dropped, &m->log_invalid, &m->log_lost, &m->log_failures, &m->imports_ok,
                          &m->imports_failed, &m->refine_rounds, &m->versions_written, &m->versions_published};
    for (size_t i = 0; i < sizeof fields / sizeof fields[0]; i++)
        *fields[i] = 1000 + i;
    m->errors[PROTO_ERR_BAD_VALUE] = 7;
    m->errors[PROTO_ERR_TIMEOUT] = 3;
    m->errors[60] = 2; /* a code proto.h does not name */
    m->rejected[PROTO_ERR_GUEST] = 5;
    for (int i = 0; i < 40; i++)
        metrics_tick_observe(&m->tick, 0.0001 * i + 0.00005); /* off the bounds */
    metrics_tick_observe(&m->tick, 3.0);
}

static void test_render(void **state)
{
    (void)state;
    metrics_snapshot m;
    fill(&m);
    size_t len = 0;
    char *text = metrics_render(&m, &len);
    assert_non_null(text);
    assert_int_equal(check_format(text, len), 24);
    static const struct {
        const char *series;
        size_t offset;
    } scalars[] = {
        {"cvre_clients", offsetof(metrics_snapshot, clients)},
        {"cvre_avatars", offsetof(metrics_snapshot, avatars)},
        {"cvre_objects", offsetof(metrics_snapshot, objects)},
        {"cvre_collision_log_queue_rows", offsetof(metrics_snapshot, log_queue)},
        {"cvre_collision_log_queue_high_water_rows", offsetof(metrics_snapshot, log_queue_high)},
        {"cvre_connections_total", offsetof(metrics_snapshot, connections)},
        {"cvre_ticks_total", offsetof(metrics_snapshot, ticks)},
        {"cvre_frames_received_total", offsetof(metrics_snapshot, frames_in)},
        {"cvre_moves_total", offsetof(metrics_snapshot, moves)},
        {"cvre_moves_dropped_total", offsetof(metrics_snapshot, moves_dropped)},
        {"cvre_received_bytes_total", offsetof(metrics_snapshot, bytes_in)},
        {"cvre_sent_bytes_total", offsetof(metrics_snapshot, bytes_out)},
        {"cvre_timeouts_total", offsetof(metrics_snapshot, timeouts)},
        {"cvre_slow_readers_total", offsetof(metrics_snapshot, slow_readers)},
        {"cvre_collisions_total", offsetof(metrics_snapshot, collisions)},
        {"cvre_collision_log_rows_total{outcome=\"written\"}", offsetof(metrics_snapshot, log_written)},
        {"cvre_collision_log_rows_total{outcome=\"dropped\"}", offsetof(metrics_snapshot, log_dropped)},
        {"cvre_collision_log_rows_total{outcome=\"invalid\"}", offsetof(metrics_snapshot, log_invalid)},
        {"cvre_collision_log_rows_total{outcome=\"lost\"}", offsetof(metrics_snapshot, log_lost)},
        {"cvre_collision_log_write_failures_total", offsetof(metrics_snapshot, log_failures)},
        {"cvre_imports_total{result=\"ok\"}", offsetof(metrics_snapshot, imports_ok)},
        {"cvre_imports_total{result=\"failed\"}", offsetof(metrics_snapshot, imports_failed)},
        {"cvre_refine_rounds_total", offsetof(metrics_snapshot, refine_rounds)},
        {"cvre_collision_maps_written_total", offsetof(metrics_snapshot, versions_written)},
        {"cvre_collision_maps_published_total", offsetof(metrics_snapshot, versions_published)},
    };
    for (size_t i = 0; i < sizeof scalars / sizeof scalars[0]; i++) {
        uint64_t want;
        memcpy(&want, (const char *)&m + scalars[i].offset, sizeof want);
        if (value_of(text, scalars[i].series) != (double)want)
            fail_msg("%s: %g, not %llu", scalars[i].series, value_of(text, scalars[i].series),
                     (unsigned long long)want);
    }
    /* The histogram: cumulative, ending at the count. */
    double last = 0;
    for (size_t i = 0; i < METRICS_TICK_BUCKETS; i++) {
        char series[96];
        snprintf(series, sizeof series, "cvre_tick_duration_seconds_bucket{le=\"%g\"}", metrics_tick_bounds[i]);
        double v = value_of(text, series);
        assert_true(v >= last);
        last = v;
    }
    assert_near(value_of(text, "cvre_tick_duration_seconds_bucket{le=\"0.0005\"}"), 5, 0);
    assert_near(last, 40, 0);
    assert_near(value_of(text, "cvre_tick_duration_seconds_bucket{le=\"+Inf\"}"), 41, 0);
    assert_near(value_of(text, "cvre_tick_duration_seconds_count"), 41, 0);
    assert_near(value_of(text, "cvre_tick_duration_seconds_sum"), m.tick.sum, 1e-6);
    /* By code: every code proto.h names, at 0 until counted; others only
     * once counted. */
    assert_near(value_of(text, "cvre_protocol_errors_total{code=\"23\",reason=\"value out of range\"}"), 7, 0);
    assert_near(value_of(text, "cvre_protocol_errors_total{code=\"29\",reason=\"timeout\"}"), 3, 0);
    assert_near(value_of(text, "cvre_protocol_errors_total{code=\"16\",reason=\"frame length below 2\"}"), 0, 0);
    assert_near(value_of(text, "cvre_protocol_errors_total{code=\"60\",reason=\"unknown status\"}"), 2, 0);
    assert_false(has_series(text, "cvre_protocol_errors_total{code=\"31\",reason=\"unknown status\"}"));
    assert_near(value_of(text, "cvre_requests_rejected_total{code=\"39\",reason=\"not allowed for guests\"}"), 5,
                       0);
    for (int code = PROTO_ERR_FRAME_EMPTY; code <= PROTO_ERR_RATE_LIMITED; code++) {
        char series[160];
        if (strcmp(proto_strerror(code), proto_strerror(-1)) == 0)
            continue;
        snprintf(series, sizeof series, "cvre_requests_rejected_total{code=\"%d\",reason=\"%s\"}", code,
                 proto_strerror(code));
        assert_true(has_series(text, series));
    }
    free(text);
}

/* Every allocation the rendering makes can fail: NULL, nothing leaked
 * (LeakSanitizer in the ASan tree), and the same text once they do not. */
static void test_out_of_memory(void **state)
{
    (void)state;
    metrics_snapshot m;
    fill(&m);
    size_t want_len = 0, len = 0;
    char *want = metrics_render(&m, &want_len);
    assert_non_null(want);
    int failed = 0;
    for (long n = 0;; n++) {
        cvre_alloc_fail_after(n);
        char *text = metrics_render(&m, &len);
        cvre_alloc_fail_after(-1);
        if (text) {
            assert_int_equal(len, want_len);
            assert_memory_equal(text, want, len);
            free(text);
            break;
        }
        failed++;
    }
    assert_true(failed >= 2); /* the first buffer and at least one growth */
    free(want);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_histogram_buckets),
        cmocka_unit_test(test_render),
        cmocka_unit_test(test_out_of_memory),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
