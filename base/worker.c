#include "worker.h"

#include <errno.h>
#include <poll.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <unistd.h>

#include "alloc.h"
#include "mailbox.h"
#include "task.h"

/*
 * The thread sleeps in poll() on an eventfd, not on a condition variable:
 * whoever changes what it waits for (a job, the stop under the lock, the
 * woken flag without it) writes the eventfd afterwards, and the thread
 * drains the fd before it looks, so no wake-up is lost, and worker_wake
 * needs no lock.
 */
struct worker {
    worker_ops ops;
    pthread_t thread;
    pthread_mutex_t lock;
    int stop;
    unsigned char *jobs; /* queue_max slots of job_size bytes, a ring */
    unsigned head, count;
    mailbox *results;
    int wake_fd;
    _Atomic int woken;  /* worker_wake: call ops.every now */
    unsigned next_ms;   /* the worker's thread only: the delay after this call of every */
};

static void wake(worker *w)
{
    uint64_t one = 1;
    ssize_t n = write(w->wake_fd, &one, sizeof one);
    (void)n; /* EAGAIN: the counter is full, so the fd is readable anyway */
}

/* Sleeps (the lock not held) until the fd is written or the time is due
 * (ms on the monotonic clock; 0: no time), then drains the fd. */
static void sleep_until(worker *w, double due)
{
    int timeout = -1;
    if (due > 0) {
        double now = task_wall_ms();
        timeout = due <= now ? 0 : due - now > 60000 ? 60000 : (int)(due - now) + 1; /* never early */
    }
    struct pollfd p = {.fd = w->wake_fd, .events = POLLIN};
    (void)poll(&p, 1, timeout); /* EINTR: the caller looks again */
    uint64_t drained;
    ssize_t n = read(w->wake_fd, &drained, sizeof drained);
    (void)n; /* EAGAIN: nothing was written */
}

static void *run(void *arg)
{
    worker *w = arg;
    void *job = cvre_xmalloc(w->ops.job_size ? w->ops.job_size : 1);
    double due = w->ops.every ? task_wall_ms() + w->ops.period_ms : 0;

    pthread_mutex_lock(&w->lock);
    for (;;) {
        if (w->stop)
            break;
        if (w->count == 0) {
            int woken = atomic_exchange(&w->woken, 0);
            if (due <= 0 || (!woken && task_wall_ms() < due)) {
                pthread_mutex_unlock(&w->lock);
                sleep_until(w, due);
                pthread_mutex_lock(&w->lock);
                continue;
            }
            pthread_mutex_unlock(&w->lock);
            w->next_ms = w->ops.period_ms;
            w->ops.every(w->ops.ctx, w);
            due = task_wall_ms() + w->next_ms;
            pthread_mutex_lock(&w->lock);
            continue;
        }
        /* the slot is wiped once copied: nothing of a job (a password)
         * stays behind in the queue */
        memcpy(job, w->jobs + (size_t)w->head * w->ops.job_size, w->ops.job_size);
        memset(w->jobs + (size_t)w->head * w->ops.job_size, 0, w->ops.job_size);
        w->head = (w->head + 1) % w->ops.queue_max;
        w->count--;
        pthread_mutex_unlock(&w->lock);
        void *result = w->ops.run(w->ops.ctx, job);
        if (result)
            mailbox_put(w->results, result);
        pthread_mutex_lock(&w->lock);
    }
    pthread_mutex_unlock(&w->lock);
    free(job);
    return NULL;
}

worker *worker_start(const worker_ops *ops, char *err, size_t errlen)
{
    worker *w = cvre_xcalloc(1, sizeof *w);
    int rc;

    w->ops = *ops;
    w->jobs = cvre_xcalloc(ops->queue_max, ops->job_size);
    w->results = mailbox_create();
    w->wake_fd = w->results ? eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK) : -1;
    if (w->wake_fd < 0) {
        snprintf(err, errlen, "eventfd: %s", strerror(errno));
        mailbox_destroy(w->results, NULL);
        free(w->jobs);
        free(w);
        return NULL;
    }
    pthread_mutex_init(&w->lock, NULL);
    rc = pthread_create(&w->thread, NULL, run, w);
    if (rc != 0) {
        snprintf(err, errlen, "cannot start a worker thread: %s", strerror(rc));
        mailbox_destroy(w->results, NULL);
        close(w->wake_fd);
        pthread_mutex_destroy(&w->lock);
        free(w->jobs);
        free(w);
        return NULL;
    }
    return w;
}

void worker_stop(worker *w)
{
    if (!w)
        return;
    pthread_mutex_lock(&w->lock);
    w->stop = 1;
    pthread_mutex_unlock(&w->lock);
    wake(w);
    pthread_join(w->thread, NULL);
    for (; w->count; w->count--, w->head = (w->head + 1) % w->ops.queue_max)
        if (w->ops.drop_job)
            w->ops.drop_job(w->jobs + (size_t)w->head * w->ops.job_size);
    mailbox_destroy(w->results, w->ops.free_result ? w->ops.free_result : free);
    close(w->wake_fd);
    pthread_mutex_destroy(&w->lock);
    free(w->jobs);
    free(w);
}

int worker_fd(const worker *w) { return mailbox_fd(w->results); }

int worker_submit(worker *w, const void *job)
{
    pthread_mutex_lock(&w->lock);
    if (w->count == w->ops.queue_max) {
        pthread_mutex_unlock(&w->lock);
        return -EBUSY;
    }
    memcpy(w->jobs + (size_t)((w->head + w->count) % w->ops.queue_max) * w->ops.job_size, job,
           w->ops.job_size);
    w->count++;
    pthread_mutex_unlock(&w->lock);
    wake(w);
    return 0;
}

void *worker_take(worker *w) { return mailbox_take(w->results); }

void worker_put(worker *w, void *result) { mailbox_put(w->results, result); }

void worker_wake(worker *w)
{
    atomic_store(&w->woken, 1);
    wake(w);
}

void worker_due(worker *w, unsigned ms) { w->next_ms = ms; }
