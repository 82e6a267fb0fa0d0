/*
 * proto_mesh.c: the encoded mesh of MESH_CHUNK (see proto_mesh.h). Bytes
 * go through le.h; the encoder's vertex table is open addressing over the
 * quantized points, so encoding is linear in the triangles.
 */
#include "proto_mesh.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "le.h"
#include "proto.h"

static uint32_t point_hash(const uint16_t q[3])
{
    uint64_t k = (uint64_t)q[0] | (uint64_t)q[1] << 16 | (uint64_t)q[2] << 32;
    k *= 0x9e3779b97f4a7c15ull;
    return (uint32_t)(k >> 32);
}

/* The step of coordinate v within [lo, lo + ext]: the nearest of 0..65535. */
static uint16_t quantize(float v, float lo, float ext)
{
    if (!(ext > 0.0f))
        return 0;
    double t = ((double)v - lo) / ext * PROTO_MESH_STEPS + 0.5;
    return t <= 0.0 ? 0 : t >= PROTO_MESH_STEPS ? (uint16_t)PROTO_MESH_STEPS : (uint16_t)t;
}

/* The encoder's state: the distinct quantized points so far, and a table of
 * their indices + 1 (0: empty), kept at most half full. */
typedef struct verts {
    uint16_t (*q)[3];
    uint32_t n;
    uint32_t *slot;
    uint32_t cap; /* a power of two */
} verts;

static int verts_grow(verts *v)
{
    uint32_t cap = v->cap ? v->cap * 2 : 1024;
    uint32_t *slot = cvre_calloc(cap, sizeof *slot);
    if (!slot)
        return -ENOMEM;
    for (uint32_t i = 0; i < v->n; i++)
        for (uint32_t j = point_hash(v->q[i]);; j++)
            if (!slot[j & (cap - 1)]) {
                slot[j & (cap - 1)] = i + 1;
                break;
            }
    free(v->slot);
    v->slot = slot;
    v->cap = cap;
    return 0;
}

/* The index of point q, added if new (room for it is there). */
static int verts_index(verts *v, const uint16_t q[3], uint32_t *index)
{
    if (2 * (v->n + 1) > v->cap) {
        int rc = verts_grow(v);
        if (rc < 0)
            return rc;
    }
    for (uint32_t j = point_hash(q);; j++) {
        uint32_t *s = &v->slot[j & (v->cap - 1)];
        if (!*s) {
            memcpy(v->q[v->n], q, sizeof v->q[0]);
            *s = ++v->n;
            *index = v->n - 1;
            return 0;
        }
        if (memcmp(v->q[*s - 1], q, sizeof v->q[0]) == 0) {
            *index = *s - 1;
            return 0;
        }
    }
}

int proto_mesh_encode(const float *tris, uint32_t ntris, uint8_t **out, size_t *len)
{
    if (ntris == 0 || ntris > PROTO_MESH_TRIS_MAX)
        return -EINVAL;
    size_t ncorners = (size_t)ntris * 3;
    float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t i = 0; i < ncorners * 3; i++) {
        if (!isfinite(tris[i]))
            return -EINVAL;
        lo[i % 3] = fminf(lo[i % 3], tris[i]);
        hi[i % 3] = fmaxf(hi[i % 3], tris[i]);
    }
    float ext[3] = {hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]};
    verts v = {.q = cvre_malloc(ncorners * sizeof *v.q)};
    uint32_t *index = cvre_malloc(ncorners * sizeof *index);
    int rc = v.q && index ? 0 : -ENOMEM;
    for (size_t c = 0; rc == 0 && c < ncorners; c++) {
        uint16_t q[3];
        for (size_t k = 0; k < 3; k++)
            q[k] = quantize(tris[3 * c + k], lo[k], ext[k]);
        rc = verts_index(&v, q, &index[c]);
    }
    uint8_t *buf = NULL;
    size_t isz = v.n <= PROTO_MESH_SMALL_VERTS ? 2 : 4;
    size_t n = PROTO_MESH_HEAD_SIZE + 6 * (size_t)v.n + isz * ncorners;
    if (rc == 0 && !(buf = cvre_malloc(n)))
        rc = -ENOMEM;
    if (rc == 0) {
        uint8_t *p = buf;
        le_put_u32(p, v.n);
        le_put_u32(p + 4, ntris);
        for (int k = 0; k < 3; k++) {
            le_put_f32(p + 8 + 4 * k, lo[k]);
            le_put_f32(p + 20 + 4 * k, hi[k]);
        }
        p += PROTO_MESH_HEAD_SIZE;
        for (uint32_t i = 0; i < v.n; i++, p += 6)
            for (int k = 0; k < 3; k++)
                le_put_u16(p + 2 * k, v.q[i][k]);
        for (size_t c = 0; c < ncorners; c++, p += isz) {
            if (isz == 2)
                le_put_u16(p, (uint16_t)index[c]);
            else
                le_put_u32(p, index[c]);
        }
        *out = buf;
        *len = n;
    }
    free(v.q);
    free(v.slot);
    free(index);
    return rc;
}

int proto_mesh_decode(const uint8_t *buf, size_t len, proto_mesh *m)
{
    if (len < PROTO_MESH_HEAD_SIZE)
        return PROTO_ERR_SHORT;
    m->vertex_count = le_get_u32(buf);
    m->tri_count = le_get_u32(buf + 4);
    if (m->vertex_count == 0 || m->tri_count == 0 || m->tri_count > PROTO_MESH_TRIS_MAX ||
        m->vertex_count > 3 * m->tri_count)
        return PROTO_ERR_BAD_VALUE;
    for (int k = 0; k < 3; k++) {
        m->min[k] = le_get_f32(buf + 8 + 4 * k);
        m->max[k] = le_get_f32(buf + 20 + 4 * k);
        if (!isfinite(m->min[k]) || !isfinite(m->max[k]))
            return PROTO_ERR_NOT_FINITE;
        if (!(m->max[k] >= m->min[k]))
            return PROTO_ERR_BAD_VALUE;
    }
    m->index_size = m->vertex_count <= PROTO_MESH_SMALL_VERTS ? 2 : 4;
    /* At most 32 + 6 x 3T + 12T: no overflow in a size_t of 64 bits, nor
     * of 32 (PROTO_MESH_TRIS_MAX keeps it under 2^32). */
    size_t want = PROTO_MESH_HEAD_SIZE + 6 * (size_t)m->vertex_count + (size_t)m->index_size * 3 * m->tri_count;
    if (len < want)
        return PROTO_ERR_SHORT;
    if (len > want)
        return PROTO_ERR_TRAILING;
    m->positions = buf + PROTO_MESH_HEAD_SIZE;
    m->indices = m->positions + 6 * (size_t)m->vertex_count;
    for (uint32_t k = 0; k < 3 * m->tri_count; k++)
        if (proto_mesh_index(m, k) >= m->vertex_count)
            return PROTO_ERR_BAD_VALUE;
    return PROTO_OK;
}

void proto_mesh_vertex(const proto_mesh *m, uint32_t i, float out[3])
{
    const uint8_t *p = m->positions + 6 * (size_t)i;
    for (int k = 0; k < 3; k++) {
        float step = (m->max[k] - m->min[k]) / (float)PROTO_MESH_STEPS;
        out[k] = m->min[k] + (float)le_get_u16(p + 2 * k) * step;
    }
}

uint32_t proto_mesh_index(const proto_mesh *m, uint32_t k)
{
    const uint8_t *p = m->indices + (size_t)k * m->index_size;
    return m->index_size == 2 ? le_get_u16(p) : le_get_u32(p);
}
