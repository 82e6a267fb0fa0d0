/*
 * importer.h: imports uploaded models on a worker thread, so that parsing a
 * large model (Sponza: about a second) never stalls the tick.
 *
 * The loop thread submits a job (it gives up the file's bytes); the worker
 * has the model parsed in the isolated importer (import_proc.h), which a
 * hostile file can crash or exhaust without harm here, stores the object, its mesh and ECM version 1 (its MBR)
 * in the database through its own connection, encodes the mesh as clients
 * fetch it (proto_mesh.h: 150 ms for the city block, kept off the tick
 * too), and queues the result. The
 * worker signals an eventfd (importer_fd) that the loop watches; the loop
 * then takes results with importer_take.
 */
#ifndef CVRE_IMPORTER_H
#define CVRE_IMPORTER_H

#include <stddef.h>
#include <stdint.h>

#include "db.h"
#include "proto.h"
#include "import_proc.h"
#include "scene.h"

typedef struct importer importer;

typedef struct import_job {
    int64_t session;      /* who asked, echoed back */
    uint32_t upload_id;   /* echoed back */
    char owner[PROTO_NAME_MAX + 1];
    char name[PROTO_OBJECT_NAME_MAX + 1];
    char format[PROTO_FORMAT_MAX + 1]; /* "" to detect */
    int z_up;
    float unit_scale;
    proto_transform at;
    uint8_t *data; /* the file; the importer frees it */
    size_t len;
} import_job;

typedef struct import_result {
    int64_t session;
    uint32_t upload_id;
    int status;                   /* 0, or a PROTO_ERR_* code for the rejection */
    char message[PROTO_MESSAGE_MAX + 1];
    uint32_t object_id;           /* when status is 0 */
    char owner[PROTO_NAME_MAX + 1];
    char name[PROTO_OBJECT_NAME_MAX + 1];
    proto_transform at;
    float *tris;                  /* owned by the result: importer_result_free */
    uint32_t tri_count;
    uint8_t mesh_hash[DB_MESH_HASH_SIZE]; /* db_mesh_hash of tris */
    uint8_t *mesh;                /* tris encoded (proto_mesh_encode), owned; NULL if that failed */
    size_t mesh_len;
    float min[3], max[3];         /* the MBR: ECM version 1's only box */
} import_result;

/* What one account may put in the world: max_triangles in one model, and
 * at most quota_objects objects of quota_bytes of mesh (36 bytes a
 * triangle) at once, counted from the store when an import is stored; and
 * the model's box, under the upload's transform, must fit placement. */
typedef struct importer_limits {
    uint32_t max_triangles;
    uint32_t quota_objects;
    uint64_t quota_bytes;
    scene_limits placement; /* where the new object may stand */
} importer_limits;

/* Starts the worker with its own connection to db_path; each model is
 * parsed in the isolated importer proc describes (kept by pointer: it must
 * outlive the importer). NULL with a message in err on failure. */
importer *importer_start(const char *db_path, const import_proc *proc, const importer_limits *limits, char *err,
                         size_t errlen);
/* Finishes the job in progress, drops the queued ones (their uploads are
 * lost with the connections that sent them), joins the thread. */
void importer_stop(importer *im);
/* The fd to watch for readability: results are waiting. */
int importer_fd(const importer *im);
/* Queues a job; the importer owns job->data from now on, whatever the
 * result. Returns 0, or -EBUSY when IMPORTER_QUEUE_MAX jobs wait. */
int importer_submit(importer *im, import_job *job);
/* Moves the next finished result into *out; 0, or -EAGAIN when none. */
int importer_take(importer *im, import_result *out);
void importer_result_free(import_result *r);

#endif
