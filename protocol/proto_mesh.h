/*
 * proto_mesh.h: the encoded mesh that MESH_CHUNK frames carry (PROTOCOL.md,
 * section 5, "Meshes"): positions quantized to u16 within the mesh's own
 * box, and indices. The server encodes an object's stored triangles once
 * per request; a client decodes what it reassembled from the chunks.
 *
 * Unlike proto.c this allocates (the encoder's vertex table and its
 * output), through base/alloc.h, and returns 0 or -ENOMEM. The decoder
 * allocates nothing: the decoded mesh points into the caller's buffer.
 */
#ifndef CVRE_PROTO_MESH_H
#define CVRE_PROTO_MESH_H

#include <stddef.h>
#include <stdint.h>

/* Header: u32 vertex count, u32 triangle count, vec3 min, vec3 max. */
#define PROTO_MESH_HEAD_SIZE 32u
/* Steps of a quantized coordinate: 0..65535 across the box on each axis. */
#define PROTO_MESH_STEPS 65535u
/* Most triangles in one mesh: the importer's cap (4,000,000) with room;
 * the encoded size, at most 32 + 6 x 3T + 12T bytes, then stays far under
 * 2^32 as the chunks' u32 total needs. */
#define PROTO_MESH_TRIS_MAX 16777216u
/* Meshes of up to this many vertices use u16 indices, others u32. */
#define PROTO_MESH_SMALL_VERTS 65536u

_Static_assert(PROTO_MESH_HEAD_SIZE + 30ull * PROTO_MESH_TRIS_MAX < 0xffffffffull, "an encoded mesh's size is a u32");

/* A decoded mesh; positions and indices point into the encoded bytes. */
typedef struct proto_mesh {
    uint32_t vertex_count;
    uint32_t tri_count;
    float min[3], max[3];       /* the box the positions are quantized in */
    const uint8_t *positions;   /* vertex_count x 3 u16 */
    const uint8_t *indices;     /* 3 x tri_count, index_size bytes each */
    uint32_t index_size;        /* 2 when vertex_count <= PROTO_MESH_SMALL_VERTS, else 4 */
} proto_mesh;

/*
 * Encodes ntris triangles (9 floats each, finite) into a new buffer *out of
 * *len bytes, which the caller frees. Vertices that quantize to the same
 * point become one. Returns 0; -EINVAL for no triangles, more than
 * PROTO_MESH_TRIS_MAX or a coordinate that is not finite; -ENOMEM.
 */
int proto_mesh_encode(const float *tris, uint32_t ntris, uint8_t **out, size_t *len);

/*
 * Checks buf[0..len) as an encoded mesh and fills *m. Returns PROTO_OK, or
 * PROTO_ERR_SHORT (ends before its layout), PROTO_ERR_TRAILING (bytes
 * after it), PROTO_ERR_NOT_FINITE (the box), PROTO_ERR_BAD_VALUE (no
 * vertex or triangle, more than PROTO_MESH_TRIS_MAX triangles or 3 per
 * triangle vertices, a box whose max is below its min, an index past the
 * vertices).
 */
int proto_mesh_decode(const uint8_t *buf, size_t len, proto_mesh *m);

/* Vertex i (< vertex_count) of a decoded mesh, in the mesh's coordinates. */
void proto_mesh_vertex(const proto_mesh *m, uint32_t i, float out[3]);
/* Index k (< 3 x tri_count): triangle k / 3, corner k % 3. */
uint32_t proto_mesh_index(const proto_mesh *m, uint32_t k);

#endif
