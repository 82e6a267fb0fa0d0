#include "importer.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "db.h"
#include "log.h"
#include "import_proc.h"
#include "proto_mesh.h"
#include "worker.h"

/* Jobs waiting at once. Each holds a whole file (up to --max-upload), so the
 * queue bounds the memory that uploads can pin while they wait. */
#define IMPORTER_QUEUE_MAX 8

struct importer {
    worker *worker; /* import_job in, import_result * out */
    db *db;
    const import_proc *proc;
    importer_limits limits;
};

/* Parses, measures and stores one model; fills r (status and either the
 * object or a message). Runs on the worker thread. */
static void import_one(importer *im, import_job *job, import_result *r)
{
    memset(r, 0, sizeof *r);
    r->session = job->session;
    r->upload_id = job->upload_id;
    import_options opt = {.z_up = job->z_up, .unit_scale = job->unit_scale, .max_triangles = im->limits.max_triangles};
    import_mesh mesh = {0};
    char err[PROTO_MESSAGE_MAX + 1];
    int rc = import_isolated(im->proc, job->data, job->len, job->format[0] ? job->format : NULL, &opt, &mesh, err,
                             sizeof err);
    free(job->data);
    job->data = NULL;
    if (rc < 0) {
        /* the model's fault, or the parser's on its account: the uploader's
         * answer; the server's own trouble (memory, starting the helper) is
         * logged and answered as internal */
        int theirs = rc == -EINVAL || rc == -EFBIG || rc == -ETIMEDOUT || rc == -ECHILD || rc == -EPROTO;
        if (rc == -ECHILD || rc == -EPROTO || rc == -ETIMEDOUT || !theirs)
            log_warn("import of \"%s\" for session %lld: %s", job->name, (long long)job->session, err);
        r->status = theirs ? PROTO_ERR_IMPORT : PROTO_ERR_INTERNAL;
        snprintf(r->message, sizeof r->message, "%s", theirs ? err : "the server could not import the model");
        return;
    }
    scene_box mbr;
    memcpy(mbr.min, mesh.min, sizeof mbr.min);
    memcpy(mbr.max, mesh.max, sizeof mbr.max);
    char why[160];
    if (scene_check_fit(&mbr, 1, &job->at, &im->limits.placement, why, sizeof why) < 0) {
        r->status = PROTO_ERR_PLACEMENT;
        snprintf(r->message, sizeof r->message, "the object cannot go there: %s", why);
        import_mesh_free(&mesh);
        return;
    }
    uint32_t count;
    uint64_t tris;
    if (db_owner_usage(im->db, job->owner, &count, &tris) < 0) {
        log_error("importer: quota of %s: %s", job->owner, db_error(im->db));
        r->status = PROTO_ERR_INTERNAL;
        snprintf(r->message, sizeof r->message, "the server could not check your quota");
        import_mesh_free(&mesh);
        return;
    }
    if (count + 1 > im->limits.quota_objects || (tris + mesh.ntris) * 36u > im->limits.quota_bytes) {
        r->status = PROTO_ERR_UPLOAD;
        snprintf(r->message, sizeof r->message,
                 "over your quota: you have %u objects of %.1f MB of mesh; the limit is %u objects, %.1f MB",
                 count, (double)tris * 36.0 / 1e6, im->limits.quota_objects,
                 (double)im->limits.quota_bytes / 1e6);
        import_mesh_free(&mesh);
        return;
    }
    float box[1][6] = {{mesh.min[0], mesh.min[1], mesh.min[2], mesh.max[0], mesh.max[1], mesh.max[2]}};
    db_object o = {.owner = job->owner, .name = job->name, .format = job->format[0] ? job->format : "detected",
                   .yaw = job->at.yaw, .scale = job->at.scale, .tri_count = mesh.ntris, .tris = mesh.tris,
                   .box_count = 1, .boxes = (const float(*)[6])box};
    memcpy(o.pos, job->at.pos, sizeof o.pos);
    memcpy(o.min, mesh.min, sizeof o.min);
    memcpy(o.max, mesh.max, sizeof o.max);
    if (db_object_create(im->db, &o, db_now()) < 0) {
        log_error("importer: storing \"%s\": %s", job->name, db_error(im->db));
        r->status = PROTO_ERR_INTERNAL;
        snprintf(r->message, sizeof r->message, "the server could not store the object");
        import_mesh_free(&mesh);
        return;
    }
    r->object_id = (uint32_t)o.id;
    memcpy(r->owner, job->owner, sizeof r->owner);
    memcpy(r->name, job->name, sizeof r->name);
    r->at = job->at;
    r->tris = mesh.tris; /* the result takes the triangles over */
    r->tri_count = mesh.ntris;
    memcpy(r->mesh_hash, o.mesh_hash, sizeof r->mesh_hash);
    if (proto_mesh_encode(r->tris, r->tri_count, &r->mesh, &r->mesh_len) < 0)
        r->mesh = NULL; /* the first client to ask has it encoded then */
    memcpy(r->min, mesh.min, sizeof r->min);
    memcpy(r->max, mesh.max, sizeof r->max);
}

static void *run_job(void *ctx, void *arg)
{
    importer *im = ctx;
    import_job *job = arg;
    import_result *r = cvre_xcalloc(1, sizeof *r);

    import_one(im, job, r);
    return r;
}

static void drop_job(void *job) { free(((import_job *)job)->data); }

static void free_result(void *p)
{
    importer_result_free(p);
    free(p);
}

importer *importer_start(const char *db_path, const import_proc *proc, const importer_limits *limits, char *err,
                         size_t errlen)
{
    importer *im = cvre_xcalloc(1, sizeof *im);
    worker_ops ops = {.job_size = sizeof(import_job), .queue_max = IMPORTER_QUEUE_MAX, .run = run_job, .ctx = im,
                      .drop_job = drop_job, .free_result = free_result};

    im->proc = proc;
    im->limits = *limits;
    im->db = db_open(db_path, DB_READWRITE, err, errlen);
    if (!im->db) {
        free(im);
        return NULL;
    }
    im->worker = worker_start(&ops, err, errlen);
    if (!im->worker) {
        db_close(im->db);
        free(im);
        return NULL;
    }
    return im;
}

void importer_stop(importer *im)
{
    if (!im)
        return;
    worker_stop(im->worker);
    db_close(im->db);
    free(im);
}

int importer_fd(const importer *im) { return worker_fd(im->worker); }

int importer_submit(importer *im, import_job *job)
{
    int rc = worker_submit(im->worker, job);

    if (rc != 0)
        free(job->data);
    job->data = NULL;
    return rc;
}

int importer_take(importer *im, import_result *out)
{
    import_result *r = worker_take(im->worker);
    if (!r)
        return -EAGAIN;
    *out = *r;
    free(r);
    return 0;
}

void importer_result_free(import_result *r)
{
    free(r->tris);
    r->tris = NULL;
    free(r->mesh);
    r->mesh = NULL;
}
