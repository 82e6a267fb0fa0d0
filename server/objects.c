/*
 * objects.c: the server's side of objects: uploads in chunks, imports on the
 * importer thread, placement and removal by their owners, the scene restored
 * from the database and preloaded from a world file, new collision maps from
 * the refiner thread, and OBJECT_INFO for every client (objects.h). It
 * tells clients through clients.h and records changes through
 * session_log.h, and calls nothing else of the server's: the handlers and
 * the tick call it, never the other way.
 */
#include "objects.h"

#include <errno.h>
#include <float.h>
#include <libgen.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "alloc.h"
#include "ecm.h"
#include "err.h"
#include "log.h"
#include "import_proc.h"
#include "proto_mesh.h"
#include "clients.h"
#include "session_log.h"
#include "srv_limits.h"

_Static_assert(DB_MESH_HASH_SIZE == PROTO_MESH_HASH_SIZE, "a mesh is named on the wire as in the store");

/* Where objects may stand in this server's world (srv_limits.h). */
static scene_limits world_limits(const server *s)
{
    float half = s->cfg.world_size * 0.5f;
    return (scene_limits){{-half, -SRV_WORLD_HEIGHT, -half}, {half, SRV_WORLD_HEIGHT, half}, SRV_OBJECT_SIZE_MAX};
}

/* ---- telling clients: each one the objects near it ------------------- */

/* Appends an OBJECT_INFO for o to c's output; upload_id is non-zero only for
 * the uploader's copy. Returns 0, or clients__out_begin's -errno when c is
 * being disconnected. */
static int send_info(server *s, client *c, const scene_object *o, uint32_t upload_id)
{
    proto_writer w;
    int rc = clients__out_begin(s, c, PROTO_SIZE_OBJECT_INFO(o->box_count), &w);
    if (rc < 0)
        return rc;
    float(*lo)[3] = cvre_xmalloc(o->box_count * sizeof *lo), (*hi)[3] = cvre_xmalloc(o->box_count * sizeof *hi);
    for (uint32_t i = 0; i < o->box_count; i++) {
        memcpy(lo[i], o->world[i].min, sizeof lo[i]);
        memcpy(hi[i], o->world[i].max, sizeof hi[i]);
    }
    proto_object_info m = {.object_id = o->id, .upload_id = upload_id,
                           .owner = {o->owner, (uint32_t)strlen(o->owner)},
                           .name = {o->name, (uint32_t)strlen(o->name)}, .at = o->at,
                           .ecm_version = o->ecm_version, .tri_count = o->tri_count,
                           .box_count = (uint16_t)o->box_count};
    memcpy(m.mesh_hash, o->mesh_hash, sizeof m.mesh_hash);
    proto_put_object_info(&w, &m, (const float(*)[3])lo, (const float(*)[3])hi);
    free(lo);
    free(hi);
    clients__out_end(s, c, &w);
    return 0;
}

/* Tells c to forget object id: it was removed, or is out of c's view. */
static void send_removed(server *s, client *c, uint32_t id)
{
    proto_writer w;
    if (clients__out_begin(s, c, PROTO_SIZE_OBJECT_REMOVED, &w) < 0)
        return;
    proto_put_object_removed(&w, id);
    clients__out_end(s, c, &w);
}

/* Records that c was told of o, which it did not know. */
static void known_append(client *c, const scene_object *o)
{
    if (c->nobjs == c->objs_cap) {
        c->objs_cap = c->objs_cap ? c->objs_cap * 2 : 64;
        c->objs = cvre_xrealloc(c->objs, c->objs_cap * sizeof *c->objs);
    }
    c->objs[c->nobjs++] = (known_object){o->id, o->slot, o->rev};
}

/* Records that c was told of o as it is now. */
static void known_set(client *c, const scene_object *o)
{
    for (uint32_t k = 0; k < c->nobjs; k++)
        if (c->objs[k].id == o->id) {
            c->objs[k].rev = o->rev;
            return;
        }
    known_append(c, o);
}

/* Records that c was told to forget object id. */
static void known_drop(client *c, uint32_t id)
{
    for (uint32_t k = 0; k < c->nobjs; k++)
        if (c->objs[k].id == id) {
            c->objs[k] = c->objs[--c->nobjs];
            return;
        }
}

/* Squared horizontal distance from p to the nearest point of b. */
static float dist2_xz(const scene_box *b, const float p[3])
{
    float dx = fmaxf(fmaxf(b->min[0] - p[0], p[0] - b->max[0]), 0.0f);
    float dz = fmaxf(fmaxf(b->min[2] - p[2], p[2] - b->max[2]), 0.0f);
    return dx * dx + dz * dz;
}

static int owns(const client *c, const world_avatar *me, const scene_object *o)
{
    return c->account_id != 0 && strcmp(o->owner, me->name) == 0;
}

static int pick_nearer(const void *a, const void *b)
{
    float x = ((const object_pick *)a)->d2, y = ((const object_pick *)b)->d2;
    return (x > y) - (x < y);
}

/* Makes room in the view's scratch for the scene's slots, n found objects
 * and n picks. */
static void view_scratch(server *s, uint32_t n)
{
    uint32_t slots = scene_slots(s->scene);
    if (slots > s->obj_stamps) {
        s->obj_stamp = cvre_xrealloc(s->obj_stamp, slots * sizeof *s->obj_stamp);
        memset(s->obj_stamp + s->obj_stamps, 0, (slots - s->obj_stamps) * sizeof *s->obj_stamp);
        s->obj_stamps = slots;
    }
    if (n > s->obj_found_cap) {
        s->obj_found = cvre_xrealloc(s->obj_found, n * sizeof *s->obj_found);
        s->obj_found_cap = n;
    }
    if (n > s->picks_cap) {
        s->picks = cvre_xrealloc(s->picks, n * sizeof *s->picks);
        s->picks_cap = n;
    }
}

/*
 * The objects' area of interest. What c knows is checked first: objects
 * removed, or now farther than aoi_radius + 2 STEP (unless c owns them),
 * are forgotten (OBJECT_REMOVED); those changed since c was told are sent
 * again. Then the objects within aoi_radius + STEP that c does not know,
 * and after a join every object c owns, are sent nearest first. Sending
 * stops while c's output holds SRV_OBJECT_VIEW_BUDGET bytes; the view is
 * then made again next tick, so a join in a crowded place streams as fast
 * as the client reads. Known objects are stamped per slot, so the work is
 * linear in what c knows plus what is near.
 */
static void view(server *s, client *c, int force)
{
    const world_avatar *me = world_get(s->world, c->avatar_id);
    const float step = SRV_OBJECT_VIEW_STEP;
    float dx = me->pos[0] - c->objs_at[0], dz = me->pos[2] - c->objs_at[1];
    if (!force && !c->objs_more && c->objs_gen == s->scene_gen && dx * dx + dz * dz < step * step)
        return;
    c->objs_more = 1;
    if (conn_out_pending(&c->c) >= SRV_OBJECT_VIEW_BUDGET)
        return;
    float r_in = s->cfg.aoi_radius + step, r_out = s->cfg.aoi_radius + 2.0f * step;
    view_scratch(s, 0);
    if (++s->obj_stamp_now == 0) { /* wrapped: forget every old stamp */
        memset(s->obj_stamp, 0, s->obj_stamps * sizeof *s->obj_stamp);
        s->obj_stamp_now = 1;
    }
    uint32_t S = s->obj_stamp_now, kept = 0;
    int whole = 1;
    for (uint32_t k = 0; k < c->nobjs; k++) {
        known_object ko = c->objs[k];
        const scene_object *o = scene_at_slot(s->scene, ko.slot);
        if (!o || o->id != ko.id || (!owns(c, me, o) && dist2_xz(&o->bounds, me->pos) > r_out * r_out)) {
            send_removed(s, c, ko.id);
            continue;
        }
        if (o->rev != ko.rev) {
            if (conn_out_pending(&c->c) < SRV_OBJECT_VIEW_BUDGET) {
                if (send_info(s, c, o, 0) < 0)
                    return;
                ko.rev = o->rev;
            } else {
                whole = 0;
            }
        }
        s->obj_stamp[o->slot] = S;
        c->objs[kept++] = ko;
    }
    c->nobjs = kept;

    float lo[3] = {me->pos[0] - r_in, -FLT_MAX, me->pos[2] - r_in};
    float hi[3] = {me->pos[0] + r_in, FLT_MAX, me->pos[2] + r_in};
    uint32_t n = scene_query_objects(s->scene, lo, hi, s->obj_found, s->obj_found_cap);
    if (n > s->obj_found_cap) {
        view_scratch(s, n);
        n = scene_query_objects(s->scene, lo, hi, s->obj_found, s->obj_found_cap);
    }
    uint32_t npicks = 0;
    for (uint32_t i = 0; i < n; i++) {
        const scene_object *o = scene_at_slot(s->scene, s->obj_found[i]);
        float d2 = dist2_xz(&o->bounds, me->pos);
        if (s->obj_stamp[o->slot] != S && d2 <= r_in * r_in) {
            s->obj_stamp[o->slot] = S;
            s->picks[npicks++] = (object_pick){o->slot, d2};
        }
    }
    if (c->objs_owned) {
        view_scratch(s, npicks + scene_count(s->scene));
        for (uint32_t i = 0; i < scene_count(s->scene); i++) {
            const scene_object *o = scene_at(s->scene, i);
            if (s->obj_stamp[o->slot] != S && owns(c, me, o)) {
                s->obj_stamp[o->slot] = S;
                s->picks[npicks++] = (object_pick){o->slot, dist2_xz(&o->bounds, me->pos)};
            }
        }
    }
    if (npicks > 1) /* picks may still be NULL */
        qsort(s->picks, npicks, sizeof *s->picks, pick_nearer);
    uint32_t sent = 0;
    while (sent < npicks && conn_out_pending(&c->c) < SRV_OBJECT_VIEW_BUDGET) {
        const scene_object *o = scene_at_slot(s->scene, s->picks[sent++].slot);
        if (send_info(s, c, o, 0) < 0)
            return;
        known_append(c, o);
    }
    if (sent == npicks)
        c->objs_owned = 0;
    c->objs_more = !whole || sent < npicks;
    c->objs_gen = s->scene_gen;
    c->objs_at[0] = me->pos[0];
    c->objs_at[1] = me->pos[2];
}

/* Refuses a request without closing the connection. */
static void reject(server *s, client *c, uint32_t request_id, int code, const char *fmt, ...)
    __attribute__((format(printf, 5, 6)));
static void reject(server *s, client *c, uint32_t request_id, int code, const char *fmt, ...)
{
    char msg[PROTO_MESSAGE_MAX + 1];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    log_info("%s (session %lld): request %u refused: %s", c->peer, (long long)c->session_id, request_id, msg);
    if ((unsigned)code < METRICS_CODES)
        s->st.rejected[code]++;
    proto_writer w;
    if (clients__out_begin(s, c, PROTO_SIZE_OBJECT_REJECTED_MAX, &w) < 0)
        return;
    proto_put_object_rejected(&w, request_id, (uint16_t)code, msg);
    clients__out_end(s, c, &w);
}

/* ---- meshes ----------------------------------------------------------- */

/* Whether c has been told of object id (and not told to forget it). */
static int knows(const client *c, uint32_t id)
{
    for (uint32_t k = 0; k < c->nobjs; k++)
        if (c->objs[k].id == id)
            return 1;
    return 0;
}

/* Lets go of the mesh c is being sent, if any; it stays kept. */
static void mesh_done(client *c)
{
    client_mesh *m = &c->mesh;
    if (m->blob)
        m->blob->refs--;
    m->blob = NULL;
    m->sent = 0;
}

/* Makes room for need more bytes of meshes: forgets kept meshes that no
 * client is being sent and that are not being encoded, least recently
 * asked for first. Returns 1 when there is room. */
static int mesh_room(server *s, size_t need)
{
    uint32_t kept = 0;
    for (uint32_t i = 0; i < s->nmeshes; i++) {
        mesh_blob *b = s->meshes[i];
        if (s->mesh_bytes + need > SRV_MESH_MEMORY && b->refs == 0 && b->data) {
            s->mesh_bytes -= b->len;
            free(b->data);
            free(b);
        } else {
            s->meshes[kept++] = b;
        }
    }
    s->nmeshes = kept;
    return s->mesh_bytes + need <= SRV_MESH_MEMORY;
}

/* The kept mesh of this hash, made the latest used (the array is kept in
 * the order of use, the latest last); NULL if none. */
static mesh_blob *mesh_find(server *s, const uint8_t hash[PROTO_MESH_HASH_SIZE])
{
    for (uint32_t i = 0; i < s->nmeshes; i++) {
        mesh_blob *b = s->meshes[i];
        if (memcmp(b->hash, hash, PROTO_MESH_HASH_SIZE) == 0) {
            memmove(s->meshes + i, s->meshes + i + 1, (s->nmeshes - i - 1) * sizeof *s->meshes);
            s->meshes[s->nmeshes - 1] = b;
            return b;
        }
    }
    return NULL;
}

/* Keeps data (len bytes, encoded, taken over) as the mesh of hash. */
static mesh_blob *mesh_keep(server *s, const uint8_t hash[PROTO_MESH_HASH_SIZE], uint8_t *data, size_t len)
{
    mesh_blob *b = cvre_xcalloc(1, sizeof *b);
    memcpy(b->hash, hash, sizeof b->hash);
    b->data = data;
    b->len = len;
    s->meshes = cvre_xrealloc(s->meshes, (s->nmeshes + 1) * sizeof *s->meshes);
    s->meshes[s->nmeshes++] = b;
    s->mesh_bytes += len;
    return b;
}

/* The encoded mesh of o, kept from an earlier request or import (any
 * object's with the same hash), in *out. Otherwise *out is NULL and the
 * request waits: the mesher encodes it (queued here when there is room for
 * it among the meshes being sent and in the mesher's queue), and a later
 * tick finds it kept. */
static void mesh_get(server *s, const scene_object *o, mesh_blob **out)
{
    size_t most = PROTO_MESH_HEAD_SIZE + 30ull * o->tri_count;
    mesh_blob *b = mesh_find(s, o->mesh_hash);
    *out = b && b->data ? b : NULL;
    if (b || !mesh_room(s, most))
        return;
    int rc = mesher_submit(s->mesher, o->mesh_hash, o->tris, o->tri_count);
    if (rc == 0)
        mesh_keep(s, o->mesh_hash, NULL, most); /* held while it is encoded */
    else if (rc != -EBUSY)
        log_warn("object %u: its mesh cannot be queued for encoding: %s; asked again next tick", o->id,
                 strerror(-rc));
}

/* Starts sending the oldest waiting mesh c can still have: the object may
 * have been removed, or left c's view, since it asked. Returns 1 when one
 * is being sent, 0 when none waits or the oldest is not encoded yet (it
 * waits for a later tick). */
static int mesh_next(server *s, client *c)
{
    client_mesh *m = &c->mesh;
    while (m->nqueue > 0) {
        uint32_t id = m->queue[0];
        const scene_object *o = scene_get(s->scene, id);
        if (o && knows(c, id)) {
            mesh_blob *b;
            mesh_get(s, o, &b);
            if (!b)
                return 0;
            memmove(m->queue, m->queue + 1, --m->nqueue * sizeof *m->queue);
            b->refs++;
            m->blob = b;
            m->object_id = id;
            m->sent = 0;
            return 1;
        }
        memmove(m->queue, m->queue + 1, --m->nqueue * sizeof *m->queue);
        reject(s, c, id, PROTO_ERR_NO_OBJECT, "object %u is gone from your view", id);
    }
    return 0;
}

/* Sends c the next chunks of its meshes while its unread output is under
 * SRV_OBJECT_VIEW_BUDGET; the tick calls it again for the rest. */
static void mesh_pump(server *s, client *c)
{
    client_mesh *m = &c->mesh;
    while (conn_out_pending(&c->c) < SRV_OBJECT_VIEW_BUDGET && (m->blob || mesh_next(s, c))) {
        const mesh_blob *b = m->blob;
        size_t k = b->len - m->sent < PROTO_MESH_CHUNK_MAX ? b->len - m->sent : PROTO_MESH_CHUNK_MAX;
        proto_writer w;
        if (clients__out_begin(s, c, PROTO_SIZE_MESH_CHUNK(k), &w) < 0)
            return;
        proto_mesh_chunk ch = {.object_id = m->object_id, .total = (uint32_t)b->len, .offset = (uint32_t)m->sent,
                               .data = b->data + m->sent, .len = (uint32_t)k};
        proto_put_mesh_chunk(&w, &ch);
        clients__out_end(s, c, &w);
        m->sent += k;
        if (m->sent == b->len)
            mesh_done(c);
    }
}

/* Takes the mesher's encoded meshes: each is kept for the clients waiting
 * for it, who are sent it at once. A mesh that cannot be encoded is
 * refused to every client waiting for it. */
static void on_mesher_results(ev_loop *loop, int fd, unsigned events, void *data)
{
    (void)loop;
    (void)fd;
    (void)events;
    server *s = data;
    mesher_result r;
    while (mesher_take(s->mesher, &r) == 0) {
        mesh_blob *b = mesh_find(s, r.hash);
        if (r.rc == 0) {
            s->mesh_bytes = s->mesh_bytes - b->len + r.len;
            b->data = r.data;
            b->len = r.len;
        } else {
            log_error("a mesh cannot be encoded: %s", strerror(-r.rc));
            s->mesh_bytes -= b->len;
            s->nmeshes--; /* mesh_find made it the last */
            free(b);
        }
        for (uint32_t i = 0; i < s->nclients; i++) {
            client *c = s->clients[i];
            client_mesh *m = &c->mesh;
            if (c->state != ST_JOINED || c->closing)
                continue;
            uint32_t kept = 0;
            for (uint32_t k = 0; k < m->nqueue; k++) {
                const scene_object *o = scene_get(s->scene, m->queue[k]);
                if (r.rc < 0 && o && memcmp(o->mesh_hash, r.hash, PROTO_MESH_HASH_SIZE) == 0)
                    reject(s, c, m->queue[k], PROTO_ERR_INTERNAL, "the mesh of object %u cannot be encoded: %s",
                           m->queue[k], strerror(-r.rc));
                else
                    m->queue[kept++] = m->queue[k];
            }
            m->nqueue = kept;
            if (!m->blob && m->nqueue)
                mesh_pump(s, c);
        }
    }
}

/* A mesh request is answered from what c knows: only an object in its
 * view (or its own), named with the hash its OBJECT_INFO gave. */
static void on_mesh_request(server *s, client *c, const proto_mesh_request *r)
{
    client_mesh *m = &c->mesh;
    const scene_object *o = scene_get(s->scene, r->object_id);
    if (!ratelimit_take(s->mesh_requests, c->addr, server__now(s))) {
        reject(s, c, r->object_id, PROTO_ERR_RATE_LIMITED, "too many mesh requests; at most %g a second",
               SRV_MESH_PER_SECOND);
        return;
    }
    if (!o || !knows(c, r->object_id)) {
        reject(s, c, r->object_id, PROTO_ERR_NO_OBJECT, "no object %u in your view", r->object_id);
        return;
    }
    if (memcmp(r->mesh_hash, o->mesh_hash, PROTO_MESH_HASH_SIZE) != 0) {
        reject(s, c, r->object_id, PROTO_ERR_STALE_MESH, "object %u has another mesh than the one asked for",
               r->object_id);
        return;
    }
    if (m->nqueue == SRV_MESH_QUEUE) {
        reject(s, c, r->object_id, PROTO_ERR_RATE_LIMITED, "%u mesh requests are waiting already", SRV_MESH_QUEUE);
        return;
    }
    m->queue[m->nqueue++] = r->object_id;
    mesh_pump(s, c);
}

void objects__view(server *s, client *c, int force)
{
    view(s, c, force);
    if (c->state == ST_JOINED && !c->closing)
        mesh_pump(s, c);
}

/* ---- uploads ---------------------------------------------------------- */

static void drop_upload(server *s, client *c)
{
    client_upload *u = &c->upload;
    s->upload_bytes -= u->total;
    free(u->data);
    memset(u, 0, sizeof *u);
}

void objects__client_gone(server *s, client *c)
{
    mesh_done(c);
    free(c->objs);
    c->objs = NULL;
    c->nobjs = c->objs_cap = 0;
    if (c->upload.id) {
        log_info("%s (session %lld): upload %u abandoned after %u of %u bytes", c->peer, (long long)c->session_id,
                 c->upload.id, c->upload.received, c->upload.total);
        drop_upload(s, c);
    }
}

static void on_upload_begin(server *s, client *c, const proto_upload_begin *m)
{
    if (c->upload.id) {
        reject(s, c, m->upload_id, PROTO_ERR_UPLOAD, "upload %u is still in progress: one at a time", c->upload.id);
        return;
    }
    if (m->total_size > s->cfg.max_upload) {
        reject(s, c, m->upload_id, PROTO_ERR_UPLOAD, "%u bytes is over the upload limit of %u", m->total_size,
               s->cfg.max_upload);
        return;
    }
    if (s->upload_bytes + m->total_size > SRV_UPLOAD_BUDGET) {
        reject(s, c, m->upload_id, PROTO_ERR_UPLOAD, "the server is busy with other uploads; try again later");
        return;
    }
    client_upload *u = &c->upload;
    /* The buffer grows with the chunks that really arrive, never to the size
     * a peer merely announces. */
    u->id = m->upload_id;
    u->total = m->total_size;
    s->upload_bytes += u->total;
    memcpy(u->name, m->name.ptr, m->name.len);
    u->name[m->name.len] = 0;
    memcpy(u->format, m->format.ptr, m->format.len);
    u->format[m->format.len] = 0;
    u->z_up = m->up_axis == PROTO_UP_Z;
    u->unit_scale = m->unit_scale;
}

static void on_upload_chunk(server *s, client *c, const proto_upload_chunk *m)
{
    client_upload *u = &c->upload;
    if (!u->id || m->upload_id != u->id) {
        reject(s, c, m->upload_id, PROTO_ERR_UPLOAD, "no upload %u in progress", m->upload_id);
        return;
    }
    if (m->offset != u->received || m->len > u->total - u->received) {
        reject(s, c, u->id, PROTO_ERR_UPLOAD, "chunk at %u+%u does not follow %u of %u bytes; upload dropped",
               m->offset, m->len, u->received, u->total);
        drop_upload(s, c);
        return;
    }
    u->data = cvre_xrealloc(u->data, u->received + m->len);
    memcpy(u->data + u->received, m->data, m->len);
    u->received += m->len;
}

static void on_upload_end(server *s, client *c, const proto_upload_end *m)
{
    client_upload *u = &c->upload;
    if (!u->id || m->upload_id != u->id) {
        reject(s, c, m->upload_id, PROTO_ERR_UPLOAD, "no upload %u in progress", m->upload_id);
        return;
    }
    if (u->received != u->total) {
        reject(s, c, u->id, PROTO_ERR_UPLOAD, "upload ended after %u of %u bytes; dropped", u->received, u->total);
        drop_upload(s, c);
        return;
    }
    const world_avatar *me = world_get(s->world, c->avatar_id);
    import_job job = {.session = c->session_id, .upload_id = u->id, .z_up = u->z_up, .unit_scale = u->unit_scale,
                      .at = m->at, .data = u->data, .len = u->received};
    memcpy(job.owner, me->name, sizeof job.owner);
    memcpy(job.name, u->name, sizeof job.name);
    memcpy(job.format, u->format, sizeof job.format);
    u->data = NULL; /* the job owns it now */
    uint32_t id = u->id;
    drop_upload(s, c);
    session_log__flush(s);
    if (importer_submit(s->importer, &job) < 0)
        reject(s, c, id, PROTO_ERR_UPLOAD, "the importer is busy; try again later");
}

/* Takes the importer's finished jobs: a new object for the world, or a
 * rejection for its uploader (who may have left meanwhile). */
static void on_import_results(ev_loop *loop, int fd, unsigned events, void *data)
{
    (void)loop;
    (void)fd;
    (void)events;
    server *s = data;
    import_result r;
    while (importer_take(s->importer, &r) == 0) {
        client *c = clients__by_session(s, r.session);
        if (r.status != 0) {
            s->st.imports_failed++;
            if (c)
                reject(s, c, r.upload_id, r.status, "%s", r.message);
            continue;
        }
        scene_box mbr;
        memcpy(mbr.min, r.min, sizeof mbr.min);
        memcpy(mbr.max, r.max, sizeof mbr.max);
        scene_object_def def = {.id = r.object_id, .owner = r.owner, .name = r.name, .at = r.at, .ecm_version = 1,
                                .tri_count = r.tri_count, .tris = r.tris, .mesh_hash = r.mesh_hash,
                                .box_count = 1, .boxes = &mbr};
        int rc = scene_add(s->scene, &def);
        /* Its mesh, encoded on the importer's thread, is kept for the
         * clients near it, who are about to ask for it. */
        if (rc == 0 && r.mesh && !mesh_find(s, r.mesh_hash) && mesh_room(s, r.mesh_len)) {
            mesh_keep(s, r.mesh_hash, r.mesh, r.mesh_len);
            r.mesh = NULL;
        }
        importer_result_free(&r);
        if (rc < 0) {
            s->st.imports_failed++;
            log_error("object %u: cannot add it to the scene: %s", r.object_id, strerror(-rc));
            continue;
        }
        s->st.imports_ok++;
        const scene_object *o = scene_get(s->scene, r.object_id);
        log_info("object %u \"%s\" of %s imported: %u triangles", o->id, o->name, o->owner, o->tri_count);
        s->scene_gen++; /* the others see it in their next view */
        if (c && c->state == ST_JOINED && !c->closing && send_info(s, c, o, r.upload_id) == 0)
            known_set(c, o);
    }
}

/* Takes the refiner's new collision maps: each replaces its object's boxes
 * between two ticks, and every client hears of it. An avatar that a new box
 * encloses, where no old one did, is pushed out (world_push_out); one that
 * no push frees is not trapped either (move.h's inside policy). */
static void on_refiner_updates(ev_loop *loop, int fd, unsigned events, void *data)
{
    (void)loop;
    (void)fd;
    (void)events;
    server *s = data;
    refiner_update u;
    while (refiner_take(s->refiner, &u) == 0) {
        const scene_object *o = scene_get(s->scene, u.object_id);
        if (!o || u.version <= o->ecm_version) {
            refiner_update_free(&u);
            continue; /* removed, or already in force */
        }
        uint32_t before = o->box_count, old_version = o->ecm_version;
        /* The old world boxes, for the push-out; without them (out of
         * memory) every avatar the new boxes enclose is left inside. */
        scene_box *old = cvre_malloc((size_t)before * sizeof *old);
        if (old)
            memcpy(old, o->world, (size_t)before * sizeof *old);
        else
            log_warn("object %u: out of memory: avatars its new boxes enclose are not pushed out", u.object_id);
        _Static_assert(sizeof(scene_box) == sizeof *u.boxes, "a box is six floats");
        int rc = scene_set_ecm(s->scene, u.object_id, u.version, (const scene_box *)u.boxes, u.count);
        refiner_update_free(&u);
        if (rc < 0) {
            free(old);
            log_error("object %u: cannot take collision map v%u: %s", u.object_id, u.version, strerror(-rc));
            continue;
        }
        s->st.versions_published++;
        uint32_t stuck = 0, pushed = old ? world_push_out(s->world, s->scene, u.object_id, old, before, &stuck) : 0;
        free(old);
        o = scene_get(s->scene, u.object_id);
        log_info("object %u \"%s\": collision map v%u -> v%u in force, %u -> %u boxes; %u avatars pushed out of "
                 "new boxes, %u left inside",
                 o->id, o->name, old_version, o->ecm_version, before, o->box_count, pushed, stuck);
        s->scene_gen++;
    }
}

/* ---- placement and removal -------------------------------------------- */

/* The object named by a request, if c may change it: its owner (an
 * account's objects carry its name, which only that account can join
 * under) or an admin. Otherwise rejects. */
static const scene_object *owned(server *s, client *c, uint32_t id)
{
    const scene_object *o = scene_get(s->scene, id);
    const world_avatar *me = world_get(s->world, c->avatar_id);
    if (!o) {
        reject(s, c, id, PROTO_ERR_NO_OBJECT, "no object %u", id);
        return NULL;
    }
    if (!c->is_admin && strcmp(o->owner, me->name) != 0) {
        reject(s, c, id, PROTO_ERR_NOT_OWNER, "object %u belongs to %s", id, o->owner);
        return NULL;
    }
    return o;
}

static void on_place(server *s, client *c, const proto_object_place *m)
{
    const scene_object *o = owned(s, c, m->object_id);
    if (!o)
        return;
    char why[160];
    scene_limits lim = world_limits(s);
    if (scene_check_fit(o->local, o->box_count, &m->at, &lim, why, sizeof why) < 0) {
        reject(s, c, m->object_id, PROTO_ERR_PLACEMENT, "object %u cannot go there: %s", m->object_id, why);
        return;
    }
    (void)scene_place(s->scene, m->object_id, &m->at); /* it fits: checked above */
    session_log__push(s, EVT_PLACE, m->object_id)->at_place = m->at;
    s->scene_gen++; /* the others see it in their next view; the sender now */
    if (send_info(s, c, o, 0) == 0)
        known_set(c, o);
}

static void on_remove(server *s, client *c, uint32_t id)
{
    if (!owned(s, c, id))
        return;
    session_log__push(s, EVT_REMOVE, id);
    scene_remove(s->scene, id);
    s->scene_gen++;
    send_removed(s, c, id);
    known_drop(c, id);
    log_info("object %u removed by %s", id, c->peer);
}

/* The request id a refusal of m names. */
static uint32_t request_of(const proto_msg *m)
{
    switch (m->type) {
    case PROTO_OBJECT_UPLOAD_BEGIN: return m->u.upload_begin.upload_id;
    case PROTO_OBJECT_UPLOAD_CHUNK: return m->u.upload_chunk.upload_id;
    case PROTO_OBJECT_UPLOAD_END: return m->u.upload_end.upload_id;
    case PROTO_OBJECT_PLACE: return m->u.object_place.object_id;
    default: return m->u.object_id;
    }
}

void objects__owner_gone(server *s, const char *owner)
{
    for (uint32_t i = 0; i < scene_count(s->scene); i++) {
        const scene_object *o = scene_at(s->scene, i);
        if (strcasecmp(o->owner, owner) != 0)
            continue;
        scene_set_owner(s->scene, o->id, WORLD_OWNER);
        log_info("object %u \"%s\": its owner %s was deleted; it is the world's now", o->id, o->name, owner);
        s->scene_gen++;
    }
}

void objects__on_message(server *s, client *c, const proto_msg *m)
{
    if (m->type == PROTO_MESH_REQUEST) { /* guests may look: meshes too */
        on_mesh_request(s, c, &m->u.mesh_request);
        return;
    }
    if (c->account_id == 0) {
        reject(s, c, request_of(m), PROTO_ERR_GUEST, "guests may walk and look: log in to change the world");
        return;
    }
    switch (m->type) {
    case PROTO_OBJECT_UPLOAD_BEGIN: on_upload_begin(s, c, &m->u.upload_begin); break;
    case PROTO_OBJECT_UPLOAD_CHUNK: on_upload_chunk(s, c, &m->u.upload_chunk); break;
    case PROTO_OBJECT_UPLOAD_END: on_upload_end(s, c, &m->u.upload_end); break;
    case PROTO_OBJECT_PLACE: on_place(s, c, &m->u.object_place); break;
    case PROTO_OBJECT_REMOVE: on_remove(s, c, m->u.object_id); break;
    default: break;
    }
}

/* ---- the scene at start-up -------------------------------------------- */

/* Adds a stored object to the scene. Returns 0, -EINVAL when its boxes
 * are not finite under its placement (no world can hold it), or -ENOMEM.
 * One that lies past this world's limits (stored before they were
 * checked, or under a larger --world-size) is added, with a warning. */
static int add_stored(server *s, const db_object *o)
{
    scene_box *boxes = cvre_xcalloc(o->box_count ? o->box_count : 1, sizeof *boxes);
    for (uint32_t i = 0; i < o->box_count; i++) {
        memcpy(boxes[i].min, o->boxes[i], sizeof boxes[i].min);
        memcpy(boxes[i].max, o->boxes[i] + 3, sizeof boxes[i].max);
    }
    scene_object_def def = {.id = (uint32_t)o->id, .owner = o->owner, .name = o->name,
                            .at = {.pos = {o->pos[0], o->pos[1], o->pos[2]}, .yaw = o->yaw, .scale = o->scale},
                            .ecm_version = o->ecm_version, .tri_count = o->tri_count, .tris = o->tris,
                            .mesh_hash = o->mesh_hash, .box_count = o->box_count, .boxes = boxes};
    int rc = scene_add(s->scene, &def);
    char why[160];
    scene_limits lim = world_limits(s);
    if (rc == 0 && scene_check_fit(boxes, o->box_count, &def.at, &lim, why, sizeof why) < 0)
        log_warn("object %lld \"%s\" of %s restored, but %s", (long long)o->id, o->name, o->owner, why);
    free(boxes);
    return rc;
}

/* The objects restore found broken, to be marked removed once the scan of
 * the store is over. */
typedef struct restore {
    server *s;
    int64_t *broken;
    uint32_t nbroken, cap;
} restore;

static int restore_one(void *ctx, const db_object *o)
{
    restore *r = ctx;
    int rc = add_stored(r->s, o);
    if (rc == -EINVAL) {
        log_error("object %lld \"%s\" of %s not restored: its collision boxes are not finite where it stands; "
                  "it is marked removed (its rows stay in the database)",
                  (long long)o->id, o->name, o->owner);
        if (r->nbroken == r->cap) {
            r->cap = r->cap ? r->cap * 2 : 8;
            r->broken = cvre_xrealloc(r->broken, r->cap * sizeof *r->broken);
        }
        r->broken[r->nbroken++] = o->id;
    } else if (rc < 0) {
        log_error("object %lld \"%s\" not restored: %s", (long long)o->id, o->name, strerror(-rc));
    }
    return 0;
}

/* Restores the scene from the store. Returns 0, or the store's negative
 * errno (db_error says why). */
static int restore_all(server *s)
{
    restore r = {.s = s};
    int rc = db_objects_load(s->db, restore_one, &r);
    for (uint32_t i = 0; rc == 0 && i < r.nbroken; i++)
        rc = db_object_remove(s->db, r.broken[i], db_now());
    free(r.broken);
    return rc;
}

/* What loading a world file keeps from line to line: the names of the
 * world's objects (restored or loaded: a name is loaded once), in an
 * open-addressing set, and each model file imported once however many
 * lines place it. A world of 100,000 objects loads in time linear in its
 * lines. */
typedef struct world_model {
    char *path;
    int z_up;
    float unit_scale;
    import_mesh mesh;
} world_model;

typedef struct world_load {
    char **names;
    uint32_t nnames, names_cap; /* a power of two, at most half full */
    world_model *models;
    uint32_t nmodels;
    uint32_t loaded, present;
} world_load;

static uint32_t name_hash(const char *name)
{
    uint32_t h = 2166136261u; /* FNV-1a */
    for (; *name; name++)
        h = (h ^ (uint8_t)*name) * 16777619u;
    return h;
}

/* Adds name to the set; 1 if it was new, 0 if it was there already. */
static int name_add(world_load *wl, const char *name)
{
    if (2 * (wl->nnames + 1) > wl->names_cap) {
        world_load grown = {.names_cap = wl->names_cap ? wl->names_cap * 2 : 64};
        grown.names = cvre_xcalloc(grown.names_cap, sizeof *grown.names);
        for (uint32_t i = 0; i < wl->names_cap; i++)
            for (uint32_t j = wl->names[i] ? name_hash(wl->names[i]) : 0; wl->names[i]; j++)
                if (!grown.names[j & (grown.names_cap - 1)]) {
                    grown.names[j & (grown.names_cap - 1)] = wl->names[i];
                    break;
                }
        free(wl->names);
        wl->names = grown.names;
        wl->names_cap = grown.names_cap;
    }
    for (uint32_t j = name_hash(name);; j++) {
        char **slot = &wl->names[j & (wl->names_cap - 1)];
        if (!*slot) {
            *slot = cvre_xstrdup(name);
            wl->nnames++;
            return 1;
        }
        if (strcmp(*slot, name) == 0)
            return 0;
    }
}

static void world_load_free(world_load *wl)
{
    for (uint32_t i = 0; i < wl->names_cap; i++)
        free(wl->names[i]);
    free(wl->names);
    for (uint32_t i = 0; i < wl->nmodels; i++) {
        free(wl->models[i].path);
        import_mesh_free(&wl->models[i].mesh);
    }
    free(wl->models);
}

/* Reads a whole file into a new buffer *out (at most max bytes; the
 * caller frees it) of *len bytes. Returns 0, or -errno with a message in
 * err (-EFBIG: over max). */
static int slurp(const char *path, size_t max, uint8_t **out, size_t *len, char *err, size_t errlen)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return cvre_fail(err, errlen, -errno, "%s: %s", path, strerror(errno));
    uint8_t *buf = NULL;
    size_t n = 0, cap = 0;
    for (;;) {
        if (n == cap) {
            cap = cap ? cap * 2 : 65536;
            buf = cvre_xrealloc(buf, cap);
        }
        size_t k = fread(buf + n, 1, cap - n, f);
        n += k;
        if (k == 0)
            break;
        if (n > max) {
            free(buf);
            fclose(f);
            return cvre_fail(err, errlen, -EFBIG, "%s: over the upload limit of %zu bytes", path, max);
        }
    }
    fclose(f);
    *out = buf;
    *len = n;
    return 0;
}

/* The mesh of a model file as opt imports it, in *out: from the isolated
 * importer the first time, from wl after (wl owns it). Returns 0, or
 * -errno with a message in err. */
static int world_model_mesh(server *s, world_load *wl, const char *path, const import_options *opt,
                            const import_mesh **out, char *err, size_t errlen)
{
    for (uint32_t i = 0; i < wl->nmodels; i++) {
        world_model *m = &wl->models[i];
        if (strcmp(m->path, path) == 0 && m->z_up == opt->z_up && m->unit_scale == opt->unit_scale) {
            *out = &m->mesh;
            return 0;
        }
    }
    size_t len = 0;
    uint8_t *data = NULL;
    int rc = slurp(path, s->cfg.max_upload, &data, &len, err, errlen);
    if (rc < 0)
        return rc;
    const char *dot = strrchr(path, '.');
    import_mesh mesh = {0};
    rc = import_isolated(&s->cfg.importer, data, len, dot ? dot + 1 : NULL, opt, &mesh, err, errlen);
    free(data);
    if (rc < 0)
        return rc;
    wl->models = cvre_xrealloc(wl->models, (wl->nmodels + 1) * sizeof *wl->models);
    wl->models[wl->nmodels] = (world_model){cvre_xstrdup(path), opt->z_up, opt->unit_scale, mesh};
    *out = &wl->models[wl->nmodels++].mesh;
    return 0;
}

/* Puts one model file into the world now (start-up, before serving).
 * Returns 0, or -errno with a message in err. */
static int preload(server *s, world_load *wl, const char *path, const char *name, const import_options *opt,
                   const proto_transform *at, char *err, size_t errlen)
{
    const import_mesh *mesh;
    int rc = world_model_mesh(s, wl, path, opt, &mesh, err, errlen);
    if (rc < 0)
        return rc;
    scene_box mbr;
    memcpy(mbr.min, mesh->min, sizeof mbr.min);
    memcpy(mbr.max, mesh->max, sizeof mbr.max);
    char why[160];
    scene_limits lim = world_limits(s);
    rc = scene_check_fit(&mbr, 1, at, &lim, why, sizeof why);
    if (rc < 0)
        return cvre_fail(err, errlen, rc, "%s cannot go there: %s", path, why);
    const char *dot = strrchr(path, '.');
    float box[1][6] = {{mbr.min[0], mbr.min[1], mbr.min[2], mbr.max[0], mbr.max[1], mbr.max[2]}};
    db_object o = {.owner = WORLD_OWNER, .name = name, .format = dot ? dot + 1 : "detected", .yaw = at->yaw,
                   .scale = at->scale, .tri_count = mesh->ntris, .tris = mesh->tris, .box_count = 1,
                   .boxes = (const float(*)[6])box};
    memcpy(o.pos, at->pos, sizeof o.pos);
    memcpy(o.min, mbr.min, sizeof o.min);
    memcpy(o.max, mbr.max, sizeof o.max);
    rc = db_object_create(s->db, &o, db_now());
    if (rc < 0)
        return cvre_fail(err, errlen, rc, "%s: %s", path, db_error(s->db));
    rc = add_stored(s, &o);
    if (rc < 0)
        return cvre_fail(err, errlen, rc, "%s: %s", path, strerror(-rc));
    log_debug("world: object %lld \"%s\" loaded from %s (%u triangles)", (long long)o.id, name, path, o.tri_count);
    wl->loaded++;
    return 0;
}

/* Parses one world-file line:
 *   object PATH [name NAME] [up y|z] [units S] at X Y Z [yaw DEGREES] [scale S]
 * A relative PATH is relative to the world file's folder. */
static int world_line(server *s, world_load *wl, const char *dir, char *line, int lineno, char *err, size_t errlen)
{
    char *save = NULL, *tok = strtok_r(line, " \t\r\n", &save);
    if (!tok || tok[0] == '#')
        return 0;
    char path[4096], name[PROTO_OBJECT_NAME_MAX + 1] = "";
    import_options opt = {.unit_scale = 1.0f, .max_triangles = s->cfg.max_triangles};
    proto_transform at = {.scale = 1.0f};
    int have_at = 0, have_path = 0;
    if (strcmp(tok, "object") != 0)
        goto bad;
    for (tok = strtok_r(NULL, " \t\r\n", &save); tok; tok = strtok_r(NULL, " \t\r\n", &save)) {
        char *arg = NULL;
        if (!have_path) {
            if (tok[0] == '/')
                snprintf(path, sizeof path, "%s", tok);
            else
                snprintf(path, sizeof path, "%s/%s", dir, tok);
            have_path = 1;
            continue;
        }
        if (strcmp(tok, "at") == 0) {
            for (int k = 0; k < 3; k++) {
                arg = strtok_r(NULL, " \t\r\n", &save);
                char *end;
                at.pos[k] = arg ? strtof(arg, &end) : NAN;
                if (!arg || *end || !isfinite(at.pos[k]))
                    goto bad;
            }
            have_at = 1;
            continue;
        }
        arg = strtok_r(NULL, " \t\r\n", &save);
        if (!arg)
            goto bad;
        char *end;
        float v = strtof(arg, &end);
        int numeric = *end == 0 && isfinite(v);
        if (strcmp(tok, "name") == 0)
            snprintf(name, sizeof name, "%s", arg);
        else if (strcmp(tok, "up") == 0 && (strcmp(arg, "y") == 0 || strcmp(arg, "z") == 0))
            opt.z_up = arg[0] == 'z';
        else if (strcmp(tok, "units") == 0 && numeric && v >= PROTO_SCALE_MIN && v <= PROTO_SCALE_MAX)
            opt.unit_scale = v;
        else if (strcmp(tok, "yaw") == 0 && numeric)
            at.yaw = v * (float)M_PI / 180.0f;
        else if (strcmp(tok, "scale") == 0 && numeric && v >= PROTO_SCALE_MIN && v <= PROTO_SCALE_MAX)
            at.scale = v;
        else
            goto bad;
    }
    if (!have_path || !have_at)
        goto bad;
    if (!name[0]) {
        char copy[sizeof path];
        snprintf(copy, sizeof copy, "%s", path);
        snprintf(name, sizeof name, "%s", basename(copy));
    }
    if (!name_add(wl, name)) {
        wl->present++; /* restored from the database already */
        return 0;
    }
    char msg[sizeof path + 1024];
    int rc = preload(s, wl, path, name, &opt, &at, msg, sizeof msg);
    if (rc < 0)
        return cvre_fail(err, errlen, rc, "line %d: %s", lineno, msg);
    return 0;
bad:
    return cvre_fail(err, errlen, -EINVAL,
                     "line %d: expected: object PATH [name NAME] [up y|z] [units S] at X Y Z [yaw DEG] [scale S]",
                     lineno);
}

static int load_world_file(server *s, const char *file, char *err, size_t errlen)
{
    FILE *f = fopen(file, "r");
    if (!f)
        return cvre_fail(err, errlen, -errno, "world file %s: %s", file, strerror(errno));
    world_load wl = {0};
    for (uint32_t i = 0; i < scene_count(s->scene); i++) {
        const scene_object *o = scene_at(s->scene, i);
        if (strcmp(o->owner, WORLD_OWNER) == 0)
            name_add(&wl, o->name);
    }
    char copy[4096], line[8192];
    snprintf(copy, sizeof copy, "%s", file);
    const char *dir = dirname(copy);
    int lineno = 0, rc = 0;
    while (rc == 0 && fgets(line, sizeof line, f)) {
        char msg[8192];
        lineno++;
        rc = world_line(s, &wl, dir, line, lineno, msg, sizeof msg);
        if (rc < 0)
            cvre_fail(err, errlen, rc, "world file %s: %s", file, msg);
    }
    fclose(f);
    if (rc == 0)
        log_info("world file %s: %u objects loaded from %u model files, %u already in the database", file, wl.loaded,
                 wl.nmodels, wl.present);
    world_load_free(&wl);
    return rc;
}

int objects__start(server *s, char *err, size_t errlen)
{
    float half = s->cfg.world_size * 0.5f;
    float lo[3] = {-half, 0, -half}, hi[3] = {half, SRV_WORLD_HEIGHT, half};
    s->scene = scene_create(lo, hi);
    s->mesh_requests = ratelimit_create(SRV_LOGIN_SLOTS, SRV_MESH_PER_SECOND, SRV_MESH_BURST);
    if (!s->scene || !s->mesh_requests)
        return cvre_fail(err, errlen, -ENOMEM, "out of memory");
    /* Changes after this point reach the scene through the refiner. */
    int64_t feed_head;
    int rc = db_ecm_events_head(s->db, &feed_head);
    if (rc == 0)
        rc = restore_all(s);
    if (rc < 0)
        return cvre_fail(err, errlen, rc, "database %s: %s", s->cfg.db_path, db_error(s->db));
    if (scene_count(s->scene))
        log_info("restored %u objects from %s", scene_count(s->scene), s->cfg.db_path);
    if (s->cfg.world_file && (rc = load_world_file(s, s->cfg.world_file, err, errlen)) < 0)
        return rc;
    importer_limits lim = {s->cfg.max_triangles, s->cfg.quota_objects, s->cfg.quota_bytes, world_limits(s)};
    s->importer = importer_start(s->cfg.db_path, &s->cfg.importer, &lim, err, errlen);
    if (!s->importer)
        return -EIO; /* importer_start said why in err */
    rc = ev_io_add(s->loop, importer_fd(s->importer), EV_READ, on_import_results, s);
    if (rc < 0)
        return cvre_fail(err, errlen, rc, "event loop: %s", strerror(-rc));
    s->mesher = mesher_start(err, errlen);
    if (!s->mesher)
        return -EIO; /* mesher_start said why in err */
    rc = ev_io_add(s->loop, mesher_fd(s->mesher), EV_READ, on_mesher_results, s);
    if (rc < 0)
        return cvre_fail(err, errlen, rc, "event loop: %s", strerror(-rc));
    const server_config *c = &s->cfg;
    refiner_config rcfg = {.db_path = c->db_path, .feed_after = feed_head, .interval_s = c->refine_interval_s,
                         .cluster = {.eps = c->refine_eps, .min_points = c->refine_min_points,
                                     .min_users = c->refine_min_users, .threads = 1}};
    ecm_params_default(&rcfg.ecm);
    rcfg.ecm.depth = c->refine_depth;
    rcfg.ecm.max_boxes = c->refine_max_boxes;
    rcfg.ecm.max_empty = c->refine_max_empty;
    rcfg.ecm.threads = c->refine_threads;
    s->refiner = refiner_start(&rcfg, err, errlen);
    if (!s->refiner)
        return -EIO; /* refiner_start said why in err */
    rc = ev_io_add(s->loop, refiner_fd(s->refiner), EV_READ, on_refiner_updates, s);
    if (rc < 0)
        return cvre_fail(err, errlen, rc, "event loop: %s", strerror(-rc));
    if (c->refine_interval_s > 0)
        log_info("collision maps: looking for clusters every %g s (eps %g m, %u collisions, %u users; grid 2^%u, "
                 "at most %u boxes)",
                 c->refine_interval_s, c->refine_eps, c->refine_min_points, c->refine_min_users, c->refine_depth,
                 c->refine_max_boxes);
    return 0;
}

void objects__stop(server *s)
{
    if (s->refiner) {
        ev_io_del(s->loop, refiner_fd(s->refiner));
        refiner_stop(s->refiner);
        s->refiner = NULL;
    }
    if (s->importer) {
        ev_io_del(s->loop, importer_fd(s->importer));
        importer_stop(s->importer);
        s->importer = NULL;
    }
    scene_destroy(s->scene);
    s->scene = NULL;
    if (s->mesher) {
        ev_io_del(s->loop, mesher_fd(s->mesher));
        mesher_stop(s->mesher);
        s->mesher = NULL;
    }
    ratelimit_destroy(s->mesh_requests);
    s->mesh_requests = NULL;
    for (uint32_t i = 0; i < s->nmeshes; i++) { /* the clients are gone: nothing is being sent */
        free(s->meshes[i]->data);
        free(s->meshes[i]);
    }
    free(s->meshes);
    s->meshes = NULL;
    free(s->obj_stamp);
    free(s->obj_found);
    free(s->picks);
}
