#include "mesher.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "proto_mesh.h"
#include "worker.h"

/* Meshes waiting at once: each holds a copy of its triangles (up to 144 MB
 * for the largest model the importer accepts), so the queue is short; a
 * request past it waits for the next tick. */
#define MESHER_QUEUE_MAX 4

typedef struct mesher_job {
    uint8_t hash[PROTO_MESH_HASH_SIZE];
    float *tris; /* the worker's copy */
    uint32_t n;
} mesher_job;

struct mesher {
    worker *worker; /* mesher_job in, mesher_result * out */
};

static void *run_job(void *ctx, void *arg)
{
    (void)ctx;
    mesher_job *job = arg;
    mesher_result *r = cvre_xcalloc(1, sizeof *r);
    memcpy(r->hash, job->hash, sizeof r->hash);
    r->rc = proto_mesh_encode(job->tris, job->n, &r->data, &r->len);
    if (r->rc < 0)
        r->data = NULL;
    free(job->tris);
    return r;
}

static void drop_job(void *job) { free(((mesher_job *)job)->tris); }

static void free_result(void *p)
{
    free(((mesher_result *)p)->data);
    free(p);
}

mesher *mesher_start(char *err, size_t errlen)
{
    mesher *m = cvre_xcalloc(1, sizeof *m);
    worker_ops ops = {.job_size = sizeof(mesher_job), .queue_max = MESHER_QUEUE_MAX, .run = run_job,
                      .drop_job = drop_job, .free_result = free_result};
    m->worker = worker_start(&ops, err, errlen);
    if (!m->worker) {
        free(m);
        return NULL;
    }
    return m;
}

void mesher_stop(mesher *m)
{
    if (!m)
        return;
    worker_stop(m->worker);
    free(m);
}

int mesher_fd(const mesher *m) { return worker_fd(m->worker); }

int mesher_submit(mesher *m, const uint8_t hash[PROTO_MESH_HASH_SIZE], const float *tris, uint32_t n)
{
    mesher_job job = {.n = n};
    memcpy(job.hash, hash, sizeof job.hash);
    job.tris = cvre_malloc((size_t)n * 9 * sizeof *tris);
    if (!job.tris)
        return -ENOMEM;
    memcpy(job.tris, tris, (size_t)n * 9 * sizeof *tris);
    int rc = worker_submit(m->worker, &job);
    if (rc < 0)
        free(job.tris);
    return rc;
}

int mesher_take(mesher *m, mesher_result *out)
{
    mesher_result *r = worker_take(m->worker);
    if (!r)
        return -EAGAIN;
    *out = *r;
    free(r);
    return 0;
}
