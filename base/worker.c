#include "worker.h"

#include <errno.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "alloc.h"
#include "mailbox.h"

struct worker {
    worker_ops ops;
    pthread_t thread;
    pthread_mutex_t lock;
    pthread_cond_t wake;
    int stop;
    unsigned char *jobs; /* queue_max slots of job_size bytes, a ring */
    unsigned head, count;
    mailbox *results;
};

static uint64_t now_ms(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (uint64_t)t.tv_sec * 1000u + (uint64_t)t.tv_nsec / 1000000u;
}

/* Waits (the lock held) for a job, the stop, or the time due (ms on the
 * monotonic clock; 0: no time). */
static void wait_for_work(worker *w, uint64_t due)
{
    while (!w->stop && w->count == 0 && (!due || now_ms() < due)) {
        if (!due) {
            pthread_cond_wait(&w->wake, &w->lock);
            continue;
        }
        struct timespec ts = {.tv_sec = (time_t)(due / 1000u), .tv_nsec = (long)(due % 1000u) * 1000000L};
        pthread_cond_timedwait(&w->wake, &w->lock, &ts);
    }
}

static void *run(void *arg)
{
    worker *w = arg;
    void *job = cvre_xmalloc(w->ops.job_size ? w->ops.job_size : 1);
    uint64_t due = w->ops.every ? now_ms() + w->ops.period_ms : 0;

    pthread_mutex_lock(&w->lock);
    for (;;) {
        wait_for_work(w, due);
        if (w->stop)
            break;
        if (w->count == 0) { /* the time is due */
            pthread_mutex_unlock(&w->lock);
            w->ops.every(w->ops.ctx, w);
            due = now_ms() + w->ops.period_ms;
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
        mailbox_put(w->results, w->ops.run(w->ops.ctx, job));
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
    if (!w->results) {
        snprintf(err, errlen, "eventfd: %s", strerror(errno));
        free(w->jobs);
        free(w);
        return NULL;
    }
    pthread_mutex_init(&w->lock, NULL);
    pthread_condattr_t ca; /* timed waits on the monotonic clock: a clock step is no wake-up */
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&w->wake, &ca);
    pthread_condattr_destroy(&ca);
    rc = pthread_create(&w->thread, NULL, run, w);
    if (rc != 0) {
        snprintf(err, errlen, "cannot start a worker thread: %s", strerror(rc));
        mailbox_destroy(w->results, NULL);
        pthread_mutex_destroy(&w->lock);
        pthread_cond_destroy(&w->wake);
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
    pthread_cond_signal(&w->wake);
    pthread_mutex_unlock(&w->lock);
    pthread_join(w->thread, NULL);
    for (; w->count; w->count--, w->head = (w->head + 1) % w->ops.queue_max)
        if (w->ops.drop_job)
            w->ops.drop_job(w->jobs + (size_t)w->head * w->ops.job_size);
    mailbox_destroy(w->results, w->ops.free_result ? w->ops.free_result : free);
    pthread_mutex_destroy(&w->lock);
    pthread_cond_destroy(&w->wake);
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
    pthread_cond_signal(&w->wake);
    pthread_mutex_unlock(&w->lock);
    return 0;
}

void *worker_take(worker *w) { return mailbox_take(w->results); }

void worker_put(worker *w, void *result) { mailbox_put(w->results, result); }
