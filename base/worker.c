#include "worker.h"

#include <errno.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

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

static void *run(void *arg)
{
    worker *w = arg;
    void *job = cvre_xmalloc(w->ops.job_size);

    pthread_mutex_lock(&w->lock);
    for (;;) {
        while (!w->stop && w->count == 0)
            pthread_cond_wait(&w->wake, &w->lock);
        if (w->stop)
            break;
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
    pthread_cond_init(&w->wake, NULL);
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
