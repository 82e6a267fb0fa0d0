/* ev.c: the event loop (see ev.h); polling lives in ev_epoll.c. */
#include <errno.h>
#include <stdlib.h>
#include <time.h>

#include "alloc.h"
#include "evInt.h"

/* Ready events handled per poll. Enough to drain a burst from thousands of
 * clients in a few iterations without a large array. */
#define EV_BATCH 1024

typedef struct io {
    ev_io_fn *fn;
    void *data;
    unsigned events;
    unsigned gen; /* bumped on add/del, so stale ready entries are skipped */
    int active;
} io;

typedef struct timer {
    ev_timer_fn *fn;
    void *data;
    uint64_t due;
    uint64_t period;
    int active;
} timer;

struct ev_loop {
    ev__backend *backend;
    io *ios;
    int max_fd;
    timer *timers;
    int ntimers;
    ev_hook_fn *before_sleep;
    void *before_sleep_data;
    uint64_t now;
    int stop;
    ev__ready ready[EV_BATCH];
};

static uint64_t monotonic_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

ev_loop *ev_create(int max_fd)
{
    ev_loop *l = cvre_calloc(1, sizeof *l);
    if (!l)
        return NULL;
    l->max_fd = max_fd;
    l->ios = cvre_calloc((size_t)max_fd, sizeof *l->ios);
    l->backend = ev__backend_create(EV_BATCH);
    if (!l->ios || !l->backend) {
        int e = errno ? errno : ENOMEM;
        ev_destroy(l);
        errno = e;
        return NULL;
    }
    l->now = monotonic_ns();
    return l;
}

void ev_destroy(ev_loop *l)
{
    if (!l)
        return;
    ev__backend_destroy(l->backend);
    free(l->ios);
    free(l->timers);
    free(l);
}

int ev_io_add(ev_loop *l, int fd, unsigned events, ev_io_fn *fn, void *data)
{
    if (fd < 0 || fd >= l->max_fd || l->ios[fd].active || !fn)
        return -EINVAL;
    int rc = ev__backend_add(l->backend, fd, events);
    if (rc < 0)
        return rc;
    io *e = &l->ios[fd];
    e->fn = fn;
    e->data = data;
    e->events = events;
    e->active = 1;
    e->gen++;
    return 0;
}

int ev_io_mod(ev_loop *l, int fd, unsigned events)
{
    if (fd < 0 || fd >= l->max_fd || !l->ios[fd].active)
        return -EINVAL;
    if (l->ios[fd].events == events)
        return 0;
    int rc = ev__backend_mod(l->backend, fd, events);
    if (rc == 0)
        l->ios[fd].events = events;
    return rc;
}

int ev_io_del(ev_loop *l, int fd)
{
    if (fd < 0 || fd >= l->max_fd || !l->ios[fd].active)
        return -EINVAL;
    l->ios[fd].active = 0;
    l->ios[fd].gen++;
    return ev__backend_del(l->backend, fd);
}

uint64_t ev_now(const ev_loop *l) { return l->now; }

uint64_t ev_clock(ev_loop *l) { return l->now = monotonic_ns(); }

int ev_timer_start(ev_loop *l, uint64_t delay_ns, uint64_t period_ns, ev_timer_fn *fn, void *data)
{
    int id = 0;
    while (id < l->ntimers && l->timers[id].active)
        id++;
    if (id == l->ntimers) {
        timer *t = cvre_realloc(l->timers, (size_t)(l->ntimers + 1) * sizeof *t);
        if (!t)
            return -ENOMEM;
        l->timers = t;
        l->ntimers++;
    }
    l->timers[id] = (timer){.fn = fn, .data = data, .due = monotonic_ns() + delay_ns,
                            .period = period_ns, .active = 1};
    return id;
}

void ev_timer_stop(ev_loop *l, int id)
{
    if (id >= 0 && id < l->ntimers)
        l->timers[id].active = 0;
}

void ev_set_before_sleep(ev_loop *l, ev_hook_fn *fn, void *data)
{
    l->before_sleep = fn;
    l->before_sleep_data = data;
}

void ev_stop(ev_loop *l) { l->stop = 1; }

/* Milliseconds until the nearest timer, rounded up so that a wake-up never
 * comes early; -1 without timers. */
static int poll_timeout(const ev_loop *l)
{
    uint64_t next = UINT64_MAX;
    for (int i = 0; i < l->ntimers; i++)
        if (l->timers[i].active && l->timers[i].due < next)
            next = l->timers[i].due;
    if (next == UINT64_MAX)
        return -1;
    if (next <= l->now)
        return 0;
    uint64_t ms = (next - l->now + 999999u) / 1000000u;
    return ms > 60000 ? 60000 : (int)ms;
}

static void run_timers(ev_loop *l)
{
    /* Timers started by a callback wait for the next iteration. */
    int n = l->ntimers;
    for (int i = 0; i < n; i++) {
        timer *t = &l->timers[i];
        if (!t->active || t->due > l->now)
            continue;
        if (t->period) {
            t->due += t->period;
            if (t->due <= l->now) /* more than a period behind: skip, don't replay */
                t->due = l->now + t->period - (l->now - t->due) % t->period;
        } else {
            t->active = 0;
        }
        t->fn(l, t->data); /* may realloc l->timers: t is not used after this */
    }
}

int ev_run(ev_loop *l)
{
    unsigned gens[EV_BATCH];
    l->stop = 0;
    while (!l->stop) {
        ev_clock(l);
        if (l->before_sleep)
            l->before_sleep(l, l->before_sleep_data);
        if (l->stop)
            break;
        int n = ev__backend_poll(l->backend, poll_timeout(l), l->ready, EV_BATCH);
        if (n < 0)
            return n;
        ev_clock(l);
        for (int i = 0; i < n; i++)
            gens[i] = l->ios[l->ready[i].fd].gen;
        for (int i = 0; i < n && !l->stop; i++) {
            int fd = l->ready[i].fd;
            io *e = &l->ios[fd];
            if (!e->active || e->gen != gens[i])
                continue; /* deleted (and maybe re-added) by an earlier callback */
            e->fn(l, fd, l->ready[i].events, e->data);
        }
        if (!l->stop) {
            ev_clock(l);
            run_timers(l);
        }
    }
    return 0;
}
