/* stats.c: tick durations and the periodic report of the figures (stats.h). */
#include "stats.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <sqlite3.h>

#include "alloc.h"
#include "log.h"

void stats__tick(stats *st, uint64_t us)
{
    st->ticks++;
    metrics_tick_observe(&st->tick_hist, (double)us * 1e-6);
    if (st->nticks < st->tick_cap)
        st->tick_us[st->nticks++] = us > UINT32_MAX ? UINT32_MAX : (uint32_t)us;
}

static int cmp_u32(const void *x, const void *y)
{
    uint32_t a = *(const uint32_t *)x, b = *(const uint32_t *)y;
    return (a > b) - (a < b);
}

/* Logs the interval's figures (the growth of the totals since it began),
 * appends them to the stats file if one was asked for (with every tick
 * duration, for exact percentiles), and starts a new interval. */
void stats__report(ev_loop *loop, void *data)
{
    server *s = data;
    stats *st = &s->st;
    const stats *b = &s->st_base;
    stats d = {.frames_in = st->frames_in - b->frames_in, .moves_in = st->moves_in - b->moves_in,
               .bytes_in = st->bytes_in - b->bytes_in, .bytes_out = st->bytes_out - b->bytes_out,
               .closed = st->closed - b->closed, .protocol_errors = st->protocol_errors - b->protocol_errors,
               .timeouts = st->timeouts - b->timeouts, .slow_readers = st->slow_readers - b->slow_readers,
               .moves_dropped = st->moves_dropped - b->moves_dropped};
    double secs = (double)(ev_clock(loop) - st->interval_start_ns) * 1e-9;
    uint32_t *sorted = cvre_xmalloc((st->nticks ? st->nticks : 1) * sizeof *sorted);
    memcpy(sorted, st->tick_us, st->nticks * sizeof *sorted);
    qsort(sorted, st->nticks, sizeof *sorted, cmp_u32);
    double p50 = st->nticks ? sorted[st->nticks / 2] / 1000.0 : 0;
    double p99 = st->nticks ? sorted[(st->nticks * 99) / 100] / 1000.0 : 0;
    double mx = st->nticks ? sorted[st->nticks - 1] / 1000.0 : 0;
    free(sorted);
    if (s->nclients || d.frames_in)
        log_info("stats: clients=%u ticks=%u tick_p50=%.2fms p99=%.2fms max=%.2fms moves/s=%.0f in=%.0fB/s "
                 "out=%.0fB/s closed=%llu errors=%llu timeouts=%llu slow=%llu moves_dropped=%llu",
                 s->nclients, st->nticks, p50, p99, mx, (double)d.moves_in / secs, (double)d.bytes_in / secs,
                 (double)d.bytes_out / secs, (unsigned long long)d.closed,
                 (unsigned long long)d.protocol_errors, (unsigned long long)d.timeouts,
                 (unsigned long long)d.slow_readers, (unsigned long long)d.moves_dropped);
    if (s->cfg.stats_file) {
        FILE *f = fopen(s->cfg.stats_file, "a");
        if (!f) {
            log_warn("stats file %s: %s", s->cfg.stats_file, strerror(errno));
        } else {
            fprintf(f,
                    "{\"seconds\":%.3f,\"clients\":%u,\"moves_in\":%llu,\"frames_in\":%llu,\"bytes_in\":%llu,"
                    "\"bytes_out\":%llu,\"closed\":%llu,\"protocol_errors\":%llu,\"timeouts\":%llu,"
                    "\"slow_readers\":%llu,\"moves_dropped\":%llu,\"tick_us\":[",
                    secs, s->nclients, (unsigned long long)d.moves_in, (unsigned long long)d.frames_in,
                    (unsigned long long)d.bytes_in, (unsigned long long)d.bytes_out,
                    (unsigned long long)d.closed, (unsigned long long)d.protocol_errors,
                    (unsigned long long)d.timeouts, (unsigned long long)d.slow_readers,
                    (unsigned long long)d.moves_dropped);
            for (uint32_t i = 0; i < st->nticks; i++)
                fprintf(f, i ? ",%u" : "%u", st->tick_us[i]);
            /* The collision log's totals; rows up to log_committed_id were
             * committed before this line was written (dblog.h). SQLite's
             * heap (its page caches, bounded by their cache_size) apart from
             * the rest tells a long run's cache filling from a leak. */
            dblog_stats ls;
            dblog_stats_get(s->log, &ls);
            fprintf(f, "],\"log_written\":%llu,\"log_dropped\":%llu,\"log_lost\":%llu,\"log_queued\":%llu,"
                       "\"log_committed_id\":%lld,\"log_last_error\":%d,\"sqlite_memory\":%lld}\n",
                    (unsigned long long)ls.written, (unsigned long long)ls.dropped, (unsigned long long)ls.lost,
                    (unsigned long long)ls.queued, (long long)ls.committed_id, ls.last_error,
                    (long long)sqlite3_memory_used());
            fclose(f);
        }
    }
    st->nticks = 0;
    st->interval_start_ns = ev_now(loop);
    s->st_base = *st;
}
