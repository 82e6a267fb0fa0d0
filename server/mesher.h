/*
 * mesher.h: encodes objects' meshes for clients (proto_mesh.h) on a worker
 * thread, so that the first request for a large mesh never stalls the tick:
 * the city block takes about 150 ms, three ticks. An upload's mesh arrives
 * encoded from the importer; the mesher serves the objects loaded from a
 * world file or restored from the store, whose meshes are encoded the first
 * time a client asks.
 *
 * The loop submits a copy of the triangles (the object may be removed while
 * they are encoded); the worker signals mesher_fd, and the loop takes the
 * results with mesher_take.
 */
#ifndef CVRE_MESHER_H
#define CVRE_MESHER_H

#include <stddef.h>
#include <stdint.h>

#include "proto.h"

typedef struct mesher mesher;

typedef struct mesher_result {
    uint8_t hash[PROTO_MESH_HASH_SIZE]; /* as submitted */
    int rc;                             /* 0, or proto_mesh_encode's -errno */
    uint8_t *data;                      /* the encoded mesh, the taker's to free; NULL on failure */
    size_t len;
} mesher_result;

/* Starts the worker. NULL with a message in err on failure. */
mesher *mesher_start(char *err, size_t errlen);
/* Finishes the mesh being encoded, drops the waiting ones and the results
 * not taken, joins the thread. m may be NULL. */
void mesher_stop(mesher *m);
/* The fd to watch for readability: results are waiting. */
int mesher_fd(const mesher *m);
/* Queues the encoding of the n triangles at tris (9 floats each, copied)
 * under hash. Returns 0, -EBUSY when MESHER_QUEUE_MAX wait, or -ENOMEM. */
int mesher_submit(mesher *m, const uint8_t hash[PROTO_MESH_HASH_SIZE], const float *tris, uint32_t n);
/* The next result, or -EAGAIN when none is waiting. */
int mesher_take(mesher *m, mesher_result *out);

#endif
