/* tick.c: the fixed-rate step and its collisions (tick.h). */
#include "tick.h"

#include <string.h>

#include "avatar_view.h"
#include "clients.h"
#include "objects.h"
#include "session_log.h"
#include "stats.h"

/* A contact from world_step: the colliding client is told, and the
 * collision is logged with its point in world and object-local coordinates
 * (so its history survives the object being moved). */
static void on_contact(void *ctx, const world_avatar *a, const move_contact *mc, const float vel[3])
{
    server *s = ctx;
    client *c = s->by_slot[world_slot(a->id)];
    const scene_object *o = scene_get(s->scene, mc->object_id);
    if (!c || !o)
        return;
    s->st.collisions++;
    proto_collision m = {.object_id = o->id, .ecm_version = o->ecm_version, .box_index = (uint16_t)mc->box_index,
                         .inside = mc->inside};
    memcpy(m.point, mc->point, sizeof m.point);
    memcpy(m.normal, mc->normal, sizeof m.normal);
    proto_writer w;
    if (!c->closing && clients__out_begin(s, c, PROTO_SIZE_COLLISION, &w) == 0) {
        proto_put_collision(&w, &m);
        clients__out_end(s, c, &w);
    }
    dblog_row row = {.at = db_now(), .session_id = c->session_id, .user_id = c->user_id, .object_id = o->id,
                     .avatar_id = a->id, .ecm_version = o->ecm_version, .box_index = mc->box_index,
                     .inside = mc->inside};
    memcpy(row.avatar, a->pos, sizeof row.avatar);
    memcpy(row.world, mc->point, sizeof row.world);
    scene_to_local(&o->at, mc->point, row.local);
    memcpy(row.normal, mc->normal, sizeof row.normal);
    memcpy(row.vel, vel, sizeof row.vel);
    dblog_push(s->log, &row); /* a full queue is counted in its stats */
}

void tick__run(ev_loop *loop, void *data)
{
    server *s = data;
    uint64_t t0 = ev_clock(loop);
    world_step(s->world, s->scene, on_contact, s);
    uint32_t tick = world_tick(s->world);
    for (uint32_t i = 0; i < s->nclients; i++) {
        client *c = s->clients[i];
        if (c->state == ST_JOINED && !c->closing) {
            avatar_view__update(s, c, tick);
            objects__view(s, c, 0);
        }
    }
    stats__tick(&s->st, (ev_clock(loop) - t0) / 1000u);
    session_log__flush(s);
}
