/*
 * objects.c: the server's side of objects: uploads in chunks, imports on the
 * importer thread, placement and removal by their owners, the scene restored
 * from the database and preloaded from a world file, new collision maps from
 * the refiner thread, and OBJECT_INFO for every client.
 */
#include <errno.h>
#include <libgen.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "alloc.h"
#include "ecm.h"
#include "log.h"
#include "scene/import_proc.h"
#include "serverInt.h"
#include "srv_limits.h"

/* ---- telling clients -------------------------------------------------- */

/* Appends an OBJECT_INFO for o to c's output; upload_id is non-zero only for
 * the uploader's copy. */
static void send_info(server *s, client *c, const scene_object *o, uint32_t upload_id)
{
    proto_writer w;
    if (server__out_begin(s, c, PROTO_SIZE_OBJECT_INFO(o->box_count), &w) < 0)
        return;
    float(*lo)[3] = xmalloc(o->box_count * sizeof *lo), (*hi)[3] = xmalloc(o->box_count * sizeof *hi);
    for (uint32_t i = 0; i < o->box_count; i++) {
        memcpy(lo[i], o->world[i].min, sizeof lo[i]);
        memcpy(hi[i], o->world[i].max, sizeof hi[i]);
    }
    proto_object_info m = {.object_id = o->id, .upload_id = upload_id,
                           .owner = {o->owner, (uint32_t)strlen(o->owner)},
                           .name = {o->name, (uint32_t)strlen(o->name)}, .at = o->at,
                           .ecm_version = o->ecm_version, .tri_count = o->tri_count,
                           .box_count = (uint16_t)o->box_count};
    proto_put_object_info(&w, &m, (const float(*)[3])lo, (const float(*)[3])hi);
    free(lo);
    free(hi);
    server__out_end(s, c, &w);
}

/* Sends o to every joined client; the uploader's copy names its upload. */
static void broadcast_info(server *s, const scene_object *o, const client *uploader, uint32_t upload_id)
{
    for (uint32_t i = 0; i < s->nclients; i++) {
        client *c = s->clients[i];
        if (c->state == ST_JOINED && !c->closing)
            send_info(s, c, o, c == uploader ? upload_id : 0);
    }
}

void objects__send_all(server *s, client *c)
{
    for (uint32_t i = 0; i < scene_count(s->scene); i++)
        send_info(s, c, scene_at(s->scene, i), 0);
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
    if (server__out_begin(s, c, PROTO_SIZE_OBJECT_REJECTED_MAX, &w) < 0)
        return;
    proto_put_object_rejected(&w, request_id, (uint16_t)code, msg);
    server__out_end(s, c, &w);
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
    u->data = xrealloc(u->data, u->received + m->len);
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
    server__events_flush(s);
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
        client *c = server__client_by_session(s, r.session);
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
                                .tri_count = r.tri_count, .tris = r.tris, .box_count = 1, .boxes = &mbr};
        int rc = scene_add(s->scene, &def);
        importer_result_free(&r);
        if (rc < 0) {
            s->st.imports_failed++;
            log_error("object %u: cannot add it to the scene: %s", r.object_id, strerror(-rc));
            continue;
        }
        s->st.imports_ok++;
        const scene_object *o = scene_get(s->scene, r.object_id);
        log_info("object %u \"%s\" of %s imported: %u triangles", o->id, o->name, o->owner, o->tri_count);
        broadcast_info(s, o, c, r.upload_id);
    }
}

/* Takes the refiner's new collision maps: each replaces its object's boxes
 * between two ticks, and every client hears of it. An avatar that the new
 * boxes enclose is not trapped (move.h's inside policy). */
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
        _Static_assert(sizeof(scene_box) == sizeof *u.boxes, "a box is six floats");
        int rc = scene_set_ecm(s->scene, u.object_id, u.version, (const scene_box *)u.boxes, u.count);
        refiner_update_free(&u);
        if (rc < 0) {
            log_error("object %u: cannot take collision map v%u: %s", u.object_id, u.version, strerror(-rc));
            continue;
        }
        s->st.versions_published++;
        o = scene_get(s->scene, u.object_id);
        log_info("object %u \"%s\": collision map v%u -> v%u in force, %u -> %u boxes", o->id, o->name, old_version,
                 o->ecm_version, before, o->box_count);
        broadcast_info(s, o, NULL, 0);
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
    if (!owned(s, c, m->object_id))
        return;
    server__event_push(s, EVT_PLACE, m->object_id)->at_place = m->at;
    scene_place(s->scene, m->object_id, &m->at);
    broadcast_info(s, scene_get(s->scene, m->object_id), NULL, 0);
}

static void on_remove(server *s, client *c, uint32_t id)
{
    if (!owned(s, c, id))
        return;
    server__event_push(s, EVT_REMOVE, id);
    scene_remove(s->scene, id);
    log_info("object %u removed by %s", id, c->peer);
    for (uint32_t i = 0; i < s->nclients; i++) {
        client *other = s->clients[i];
        proto_writer w;
        if (other->state != ST_JOINED || other->closing ||
            server__out_begin(s, other, PROTO_SIZE_OBJECT_REMOVED, &w) < 0)
            continue;
        proto_put_object_removed(&w, id);
        server__out_end(s, other, &w);
    }
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
        broadcast_info(s, o, NULL, 0);
    }
}

void objects__on_message(server *s, client *c, const proto_msg *m)
{
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

static int restore_one(void *ctx, const db_object *o)
{
    server *s = ctx;
    scene_box *boxes = xcalloc(o->box_count ? o->box_count : 1, sizeof *boxes);
    for (uint32_t i = 0; i < o->box_count; i++) {
        memcpy(boxes[i].min, o->boxes[i], sizeof boxes[i].min);
        memcpy(boxes[i].max, o->boxes[i] + 3, sizeof boxes[i].max);
    }
    scene_object_def def = {.id = (uint32_t)o->id, .owner = o->owner, .name = o->name,
                            .at = {.pos = {o->pos[0], o->pos[1], o->pos[2]}, .yaw = o->yaw, .scale = o->scale},
                            .ecm_version = o->ecm_version, .tri_count = o->tri_count, .tris = o->tris,
                            .box_count = o->box_count, .boxes = boxes};
    int rc = scene_add(s->scene, &def);
    free(boxes);
    if (rc < 0)
        log_error("object %lld not restored: %s", (long long)o->id, strerror(-rc));
    return 0;
}

static int world_has(const server *s, const char *name)
{
    for (uint32_t i = 0; i < scene_count(s->scene); i++) {
        const scene_object *o = scene_at(s->scene, i);
        if (strcmp(o->owner, WORLD_OWNER) == 0 && strcmp(o->name, name) == 0)
            return 1;
    }
    return 0;
}

/* Reads a whole file into a new buffer (at most max bytes). */
static uint8_t *slurp(const char *path, size_t max, size_t *len, char *err, size_t errlen)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        snprintf(err, errlen, "%s: %s", path, strerror(errno));
        return NULL;
    }
    uint8_t *buf = NULL;
    size_t n = 0, cap = 0;
    for (;;) {
        if (n == cap) {
            cap = cap ? cap * 2 : 65536;
            buf = xrealloc(buf, cap);
        }
        size_t k = fread(buf + n, 1, cap - n, f);
        n += k;
        if (k == 0)
            break;
        if (n > max) {
            snprintf(err, errlen, "%s: over the upload limit of %zu bytes", path, max);
            free(buf);
            fclose(f);
            return NULL;
        }
    }
    fclose(f);
    *len = n;
    return buf;
}

/* Imports one model file into the world now (start-up, before serving). */
static int preload(server *s, const char *path, const char *name, const import_options *opt,
                   const proto_transform *at, char *err, size_t errlen)
{
    size_t len;
    uint8_t *data = slurp(path, s->cfg.max_upload, &len, err, errlen);
    if (!data)
        return -1;
    const char *dot = strrchr(path, '.');
    import_mesh mesh = {0};
    int rc = import_isolated(&s->cfg.importer, data, len, dot ? dot + 1 : NULL, opt, &mesh, err, errlen);
    free(data);
    if (rc < 0)
        return -1;
    float box[1][6] = {{mesh.min[0], mesh.min[1], mesh.min[2], mesh.max[0], mesh.max[1], mesh.max[2]}};
    db_object o = {.owner = WORLD_OWNER, .name = name, .format = dot ? dot + 1 : "detected", .yaw = at->yaw,
                   .scale = at->scale, .tri_count = mesh.ntris, .tris = mesh.tris, .box_count = 1,
                   .boxes = (const float(*)[6])box};
    memcpy(o.pos, at->pos, sizeof o.pos);
    memcpy(o.min, mesh.min, sizeof o.min);
    memcpy(o.max, mesh.max, sizeof o.max);
    if (db_object_create(s->db, &o, db_now()) < 0) {
        snprintf(err, errlen, "%s: %s", path, db_error(s->db));
        import_mesh_free(&mesh);
        return -1;
    }
    rc = restore_one(s, &o);
    import_mesh_free(&mesh);
    log_info("world: object %lld \"%s\" loaded from %s (%u triangles)", (long long)o.id, name, path, o.tri_count);
    return rc;
}

/* Parses one world-file line:
 *   object PATH [name NAME] [up y|z] [units S] at X Y Z [yaw DEGREES] [scale S]
 * A relative PATH is relative to the world file's folder. */
static int world_line(server *s, const char *dir, char *line, int lineno, char *err, size_t errlen)
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
    if (world_has(s, name))
        return 0; /* restored from the database already */
    return preload(s, path, name, &opt, &at, err, errlen);
bad:
    snprintf(err, errlen, "line %d: expected: object PATH [name NAME] [up y|z] [units S] at X Y Z [yaw DEG] [scale S]",
             lineno);
    return -1;
}

static int load_world_file(server *s, const char *file, char *err, size_t errlen)
{
    FILE *f = fopen(file, "r");
    if (!f) {
        snprintf(err, errlen, "world file %s: %s", file, strerror(errno));
        return -1;
    }
    char copy[4096], line[8192];
    snprintf(copy, sizeof copy, "%s", file);
    const char *dir = dirname(copy);
    int lineno = 0, rc = 0;
    while (rc == 0 && fgets(line, sizeof line, f)) {
        char msg[8192];
        lineno++;
        rc = world_line(s, dir, line, lineno, msg, sizeof msg);
        if (rc < 0)
            snprintf(err, errlen, "world file %s: %s", file, msg);
    }
    fclose(f);
    return rc;
}

int objects__start(server *s, char *err, size_t errlen)
{
    float half = s->cfg.world_size * 0.5f;
    float lo[3] = {-half, 0, -half}, hi[3] = {half, SRV_WORLD_HEIGHT, half};
    s->scene = scene_create(lo, hi);
    if (!s->scene) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    /* Changes after this point reach the scene through the refiner. */
    int64_t feed_head;
    if (db_ecm_events_head(s->db, &feed_head) < 0 || db_objects_load(s->db, restore_one, s) < 0) {
        snprintf(err, errlen, "database %s: %s", s->cfg.db_path, db_error(s->db));
        return -1;
    }
    if (scene_count(s->scene))
        log_info("restored %u objects from %s", scene_count(s->scene), s->cfg.db_path);
    if (s->cfg.world_file && load_world_file(s, s->cfg.world_file, err, errlen) < 0)
        return -1;
    importer_limits lim = {s->cfg.max_triangles, s->cfg.quota_objects, s->cfg.quota_bytes};
    s->importer = importer_start(s->cfg.db_path, &s->cfg.importer, &lim, err, errlen);
    if (!s->importer)
        return -1;
    if (ev_io_add(s->loop, importer_fd(s->importer), EV_READ, on_import_results, s) < 0) {
        snprintf(err, errlen, "event loop setup failed");
        return -1;
    }
    const server_config *c = &s->cfg;
    refiner_config rcfg = {.db_path = c->db_path, .feed_after = feed_head, .interval_s = c->refine_interval_s,
                         .cluster = {.eps = c->refine_eps, .min_points = c->refine_min_points,
                                     .min_users = c->refine_min_users, .threads = 1}};
    ecm_params_default(&rcfg.ecm);
    rcfg.ecm.depth = c->refine_depth;
    rcfg.ecm.max_boxes = c->refine_max_boxes;
    rcfg.ecm.max_empty = c->refine_max_empty;
    s->refiner = refiner_start(&rcfg, err, errlen);
    if (!s->refiner)
        return -1;
    if (ev_io_add(s->loop, refiner_fd(s->refiner), EV_READ, on_refiner_updates, s) < 0) {
        snprintf(err, errlen, "event loop setup failed");
        return -1;
    }
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
}
