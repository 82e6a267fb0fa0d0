/*
 * script_fetch.c: the fetch command: asks the server for a known object's
 * mesh by its id and hash (MESH_REQUEST), puts the MESH_CHUNKs together,
 * decodes them (proto_mesh.h) and writes the mesh as Wavefront OBJ or as
 * binary glTF 2.0, by the file's extension. Meshes are kept by hash for
 * the session: fetching one again, of the same object or another with the
 * same mesh, asks the server for nothing.
 */
#include "scriptInt.h"

#include <errno.h>
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "events.h"
#include "le.h"
#include "log.h"
#include "proto_mesh.h"

/* A fetch is given up when no chunk came for this long. */
#define FETCH_TIMEOUT_NS (30ull * NS_PER_S)

/* glTF 2.0 binary container (the Khronos specification, "GLB File Format"). */
#define GLB_MAGIC 0x46546c67u      /* "glTF" */
#define GLB_VERSION 2u
#define GLB_CHUNK_JSON 0x4e4f534au /* "JSON" */
#define GLB_CHUNK_BIN 0x004e4942u  /* "BIN\0" */
#define GLTF_FLOAT 5126            /* componentType */
#define GLTF_UNSIGNED_INT 5125
#define GLTF_ARRAY_BUFFER 34962    /* bufferView target */
#define GLTF_ELEMENT_ARRAY_BUFFER 34963

struct fetched {
    uint8_t hash[PROTO_MESH_HASH_SIZE];
    uint8_t *data; /* the encoded mesh */
    size_t len;
};

static int write_obj(FILE *f, const proto_mesh *m)
{
    fprintf(f, "# cvre mesh: %" PRIu32 " vertices, %" PRIu32 " triangles, metres, y up\n", m->vertex_count,
            m->tri_count);
    for (uint32_t i = 0; i < m->vertex_count; i++) {
        float v[3];
        proto_mesh_vertex(m, i, v);
        fprintf(f, "v %.9g %.9g %.9g\n", (double)v[0], (double)v[1], (double)v[2]);
    }
    for (uint32_t t = 0; t < m->tri_count; t++)
        fprintf(f, "f %" PRIu32 " %" PRIu32 " %" PRIu32 "\n", proto_mesh_index(m, 3 * t) + 1,
                proto_mesh_index(m, 3 * t + 1) + 1, proto_mesh_index(m, 3 * t + 2) + 1);
    return ferror(f) ? -EIO : 0;
}

/*
 * One mesh, one node, one scene: POSITION as float VEC3 with its exact
 * min and max (the specification requires them), indices as unsigned
 * int, both in the one binary chunk. The JSON is padded with spaces and
 * the binary chunk is a whole number of 4-byte words already.
 */
static int write_glb(FILE *f, const proto_mesh *m)
{
    size_t pos_bytes = 12 * (size_t)m->vertex_count, idx_bytes = 12 * (size_t)m->tri_count;
    size_t bin_len = pos_bytes + idx_bytes;
    uint8_t *bin = cvre_xmalloc(bin_len);
    float lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
    for (uint32_t i = 0; i < m->vertex_count; i++) {
        float v[3];
        proto_mesh_vertex(m, i, v);
        for (int k = 0; k < 3; k++) {
            le_put_f32(bin + 12 * (size_t)i + 4 * (size_t)k, v[k]);
            lo[k] = i == 0 || v[k] < lo[k] ? v[k] : lo[k];
            hi[k] = i == 0 || v[k] > hi[k] ? v[k] : hi[k];
        }
    }
    for (uint32_t k = 0; k < 3 * m->tri_count; k++)
        le_put_u32(bin + pos_bytes + 4 * (size_t)k, proto_mesh_index(m, k));
    char json[2048];
    int n = snprintf(json, sizeof json,
                     "{\"asset\":{\"version\":\"2.0\",\"generator\":\"cvre-client\"},\"scene\":0,"
                     "\"scenes\":[{\"nodes\":[0]}],\"nodes\":[{\"mesh\":0}],"
                     "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0},\"indices\":1}]}],"
                     "\"accessors\":[{\"bufferView\":0,\"componentType\":%d,\"count\":%" PRIu32
                     ",\"type\":\"VEC3\",\"min\":[%.9g,%.9g,%.9g],\"max\":[%.9g,%.9g,%.9g]},"
                     "{\"bufferView\":1,\"componentType\":%d,\"count\":%" PRIu32 ",\"type\":\"SCALAR\"}],"
                     "\"bufferViews\":[{\"buffer\":0,\"byteOffset\":0,\"byteLength\":%zu,\"target\":%d},"
                     "{\"buffer\":0,\"byteOffset\":%zu,\"byteLength\":%zu,\"target\":%d}],"
                     "\"buffers\":[{\"byteLength\":%zu}]}",
                     GLTF_FLOAT, m->vertex_count, (double)lo[0], (double)lo[1], (double)lo[2], (double)hi[0],
                     (double)hi[1], (double)hi[2], GLTF_UNSIGNED_INT, 3 * m->tri_count, pos_bytes,
                     GLTF_ARRAY_BUFFER, pos_bytes, idx_bytes, GLTF_ELEMENT_ARRAY_BUFFER, bin_len);
    size_t json_len = (size_t)n;
    while (json_len % 4)
        json[json_len++] = ' ';
    uint8_t head[20];
    le_put_u32(head, GLB_MAGIC);
    le_put_u32(head + 4, GLB_VERSION);
    le_put_u32(head + 8, (uint32_t)(12 + 8 + json_len + 8 + bin_len));
    le_put_u32(head + 12, (uint32_t)json_len);
    le_put_u32(head + 16, GLB_CHUNK_JSON);
    uint8_t bin_head[8];
    le_put_u32(bin_head, (uint32_t)bin_len);
    le_put_u32(bin_head + 4, GLB_CHUNK_BIN);
    fwrite(head, 1, sizeof head, f);
    fwrite(json, 1, json_len, f);
    fwrite(bin_head, 1, sizeof bin_head, f);
    fwrite(bin, 1, bin_len, f);
    free(bin);
    return ferror(f) ? -EIO : 0;
}

/* Decodes data as a mesh and writes it to the running command's file.
 * Returns 0, or -EINVAL (not a mesh) or -errno of the file, having said
 * why. */
static int write_mesh(script *s, const uint8_t *data, size_t len, int cached)
{
    proto_mesh m;
    int st = proto_mesh_decode(data, len, &m);
    if (st != PROTO_OK) {
        script__obj_error(s, "fetch %" PRIu32 ": the server sent a bad mesh: %s", s->cur.object_id,
                          proto_strerror(st));
        return -EINVAL;
    }
    FILE *f = fopen(s->cur.file, "wb");
    if (!f) {
        int rc = -errno;
        script__obj_error(s, "fetch %" PRIu32 ": %s: %s", s->cur.object_id, s->cur.file, strerror(-rc));
        return rc;
    }
    const char *dot = strrchr(s->cur.file, '.');
    int rc = dot && strcmp(dot, ".glb") == 0 ? write_glb(f, &m) : write_obj(f, &m);
    if (fclose(f) != 0 && rc == 0)
        rc = -errno;
    if (rc < 0) {
        script__obj_error(s, "fetch %" PRIu32 ": writing %s: %s", s->cur.object_id, s->cur.file, strerror(-rc));
        return rc;
    }
    events_fetched(s->cur.object_id, s->cur.file, m.vertex_count, m.tri_count, len, cached);
    return 0;
}

static const struct fetched *cache_find(const script *s, const uint8_t hash[PROTO_MESH_HASH_SIZE])
{
    for (size_t i = 0; i < s->nfetched; i++)
        if (memcmp(s->fetched[i].hash, hash, PROTO_MESH_HASH_SIZE) == 0)
            return &s->fetched[i];
    return NULL;
}

void script__fetch_start(script *s)
{
    const known_object *k = known_get(s->objs, s->cur.object_id);
    if (!k) {
        script__obj_error(s, "fetch %" PRIu32 ": no such object in view", s->cur.object_id);
        script__obj_done(s, "failed", NULL);
        return;
    }
    memcpy(s->fetch_hash, k->mesh_hash, sizeof s->fetch_hash);
    s->fetch_tris = k->tri_count;
    const struct fetched *c = cache_find(s, k->mesh_hash);
    if (c) {
        script__obj_done(s, write_mesh(s, c->data, c->len, 1) == 0 ? "ok" : "failed", NULL);
        return;
    }
    proto_mesh_request r = {.object_id = s->cur.object_id};
    memcpy(r.mesh_hash, k->mesh_hash, sizeof r.mesh_hash);
    int rc = session_send_mesh_request(s->c, &r);
    if (rc < 0) {
        script__obj_error(s, "fetch %" PRIu32 ": not sent: %s", s->cur.object_id, strerror(-rc));
        script__obj_done(s, "failed", NULL);
        return;
    }
    s->t_progress = ev_now(s->loop);
    s->cmd_timer = session_timer_start(s->loop, NS_PER_S, NS_PER_S, script__on_cmd_timer, s);
}

/*
 * A chunk of the mesh being fetched. The server sends them in order; the
 * total is checked against the most an encoded mesh of the object's
 * triangle count can take before anything is allocated, and the buffer
 * grows with what arrives.
 */
void script__fetch_chunk(script *s, const proto_mesh_chunk *ch)
{
    if (ch->object_id != s->cur.object_id)
        return;
    uint64_t most = PROTO_MESH_HEAD_SIZE + 30ull * s->fetch_tris;
    if (ch->offset != s->fetch_len || ch->total > most || (s->fetch_len && ch->total != s->fetch_total)) {
        script__obj_error(s, "fetch %" PRIu32 ": chunk at %" PRIu32 " of %" PRIu32 " does not follow %" PRIu32
                             " bytes",
                          s->cur.object_id, ch->offset, ch->total, s->fetch_len);
        script__obj_finish(s, "failed", NULL);
        return;
    }
    s->fetch_total = ch->total;
    s->fetch_buf = cvre_xrealloc(s->fetch_buf, s->fetch_len + ch->len);
    memcpy(s->fetch_buf + s->fetch_len, ch->data, ch->len);
    s->fetch_len += ch->len;
    s->t_progress = ev_now(s->loop);
    if (s->fetch_len < s->fetch_total)
        return;
    int rc = write_mesh(s, s->fetch_buf, s->fetch_len, 0);
    if (rc == 0) {
        s->fetched = cvre_xrealloc(s->fetched, (s->nfetched + 1) * sizeof *s->fetched);
        struct fetched *f = &s->fetched[s->nfetched++];
        memcpy(f->hash, s->fetch_hash, sizeof f->hash);
        f->data = s->fetch_buf; /* the cache takes the buffer over */
        f->len = s->fetch_len;
        s->fetch_buf = NULL;
    }
    script__obj_finish(s, rc == 0 ? "ok" : "failed", NULL);
}

void script__fetch_check(script *s, uint64_t now)
{
    if (now - s->t_progress >= FETCH_TIMEOUT_NS) {
        log_warn("fetch %" PRIu32 ": no mesh from the server for %llu s; giving up", s->cur.object_id,
                 (unsigned long long)(FETCH_TIMEOUT_NS / NS_PER_S));
        script__obj_finish(s, "timeout", NULL);
    }
}

void script__fetch_release(script *s)
{
    free(s->fetch_buf);
    s->fetch_buf = NULL;
    s->fetch_len = s->fetch_total = 0;
}

void script__fetch_free_cache(script *s)
{
    for (size_t i = 0; i < s->nfetched; i++)
        free(s->fetched[i].data);
    free(s->fetched);
    s->fetched = NULL;
    s->nfetched = 0;
}
