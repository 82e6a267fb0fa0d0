/*
 * worker.h: one thread that runs jobs from a bounded queue, one at a time,
 * and hands each result to the event loop through a mailbox, so that slow
 * work (parsing a model, hashing a password) never stalls the tick.
 *
 * Jobs are copied in by value (job_size bytes each); the queue holds at most
 * queue_max, so a flood is refused (-EBUSY) rather than held. A worker may
 * also do something of its own every period_ms (between jobs, never during
 * one), sooner when another thread calls worker_wake (which takes no lock:
 * a real-time thread may call it), and hand any number of results over from
 * there with worker_put. The loop watches worker_fd and takes results with
 * worker_take.
 */
#ifndef CVRE_WORKER_H
#define CVRE_WORKER_H

#include <stddef.h>

typedef struct worker worker;

/* Runs one job (a copy the worker owns, freed after the call) and returns
 * its result, allocated, which the loop will take; or NULL when the job has
 * nothing to hand over. */
typedef void *worker_fn(void *ctx, void *job);

typedef struct worker_ops {
    size_t job_size;
    unsigned queue_max; /* 0: no jobs (worker_submit refuses every one) */
    worker_fn *run;     /* NULL when there are no jobs */
    void *ctx;
    void (*drop_job)(void *job);       /* a job never run (at stop); may be NULL */
    void (*free_result)(void *result); /* a result never taken (at stop); may be NULL: free() */
    /* Called with ctx on the worker's thread period_ms after the last
     * call returned (the first period_ms after the start; worker_due
     * changes the delay after one call), or as soon as worker_wake asks,
     * while no job is waiting; NULL: none. */
    void (*every)(void *ctx, worker *w);
    unsigned period_ms;
} worker_ops;

/* Starts the thread. NULL with a message in err on failure. */
worker *worker_start(const worker_ops *ops, char *err, size_t errlen);
/* Finishes the job in progress, drops the waiting ones and the results not
 * taken, joins the thread. w may be NULL. */
void worker_stop(worker *w);
int worker_fd(const worker *w);
/* Queues a copy of job. 0, or -EBUSY when queue_max jobs wait (then the
 * job is the caller's still). */
int worker_submit(worker *w, const void *job);
/* The next result (the caller frees it), or NULL when none is waiting. */
void *worker_take(worker *w);
/* Hands a result (allocated) to the loop, from the worker's own thread:
 * from ops.every (ops.run returns its one result instead). */
void worker_put(worker *w, void *result);
/* Has ops.every called as soon as no job is waiting, from any thread. Takes
 * no lock and never waits: an atomic store and an eventfd write. */
void worker_wake(worker *w);
/* From ops.every: the next call comes ms after this one returns (instead of
 * period_ms), unless worker_wake asks sooner. */
void worker_due(worker *w, unsigned ms);

#endif
