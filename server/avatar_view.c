/* avatar_view.c: the avatars each client is told of (avatar_view.h). */
#include "avatar_view.h"

#include <string.h>

#include "alloc.h"
#include "clients.h"
#include "srv_limits.h"

static int known_reserve(client *c, uint32_t n)
{
    if (n <= c->known_cap)
        return 0;
    uint32_t cap = c->known_cap ? c->known_cap : 16;
    while (cap < n)
        cap *= 2;
    c->known = cvre_xrealloc(c->known, cap * sizeof *c->known);
    c->known_cap = cap;
    return 0;
}

/* Tells c what changed in its area of interest since its last update:
 * avatars that came into view (joined), went out of view or disconnected
 * (left), and the positions that changed (snapshot, with its own entry and
 * the last move applied). The known and visible sets are compared through
 * per-slot stamps, in time linear in their sizes with no sorting: known
 * avatars are stamped S, the visible ones among them restamped S + 1, and
 * known ones left at S are gone. A client whose output is backed up is
 * skipped; it gets the accumulated changes once it reads again. */
void avatar_view__update(server *s, client *c, uint32_t tick)
{
    if (conn_out_pending(&c->c) > SRV_OUTBUF_SOFT)
        return;
    const world_avatar *me = world_get(s->world, c->avatar_id);
    uint32_t n = world_neighbours(s->world, c->avatar_id, s->vis, SRV_AOI_MAX - 1);
    uint32_t nleft = 0, njoined = 0, nsnap = 0, npose = 0;
    if (s->stamp >= UINT32_MAX - 2) { /* wrapped: forget every old stamp */
        memset(s->mark_stamp, 0, s->cfg.max_clients * sizeof *s->mark_stamp);
        s->stamp = 0;
    }
    uint32_t S = s->stamp += 2;
    for (uint32_t k = 0; k < c->nknown; k++) {
        uint32_t slot = world_slot(c->known[k]);
        s->mark_id[slot] = c->known[k];
        s->mark_stamp[slot] = S;
    }
    if (me->changed_tick > c->last_sent_tick)
        s->snap[nsnap++] = me;
    for (uint32_t k = 0; k < n; k++) {
        const world_avatar *v = s->vis[k];
        uint32_t slot = world_slot(v->id);
        if (s->mark_stamp[slot] == S && s->mark_id[slot] == v->id) {
            s->mark_stamp[slot] = S + 1;
            if (v->changed_tick > c->last_sent_tick)
                s->snap[nsnap++] = v;
            npose += v->has_pose && v->pose_tick > c->last_sent_tick;
        } else {
            s->joined[njoined++] = v;
            npose += v->has_pose != 0;
        }
    }
    for (uint32_t k = 0; k < c->nknown; k++)
        if (s->mark_stamp[world_slot(c->known[k])] == S)
            s->left[nleft++] = c->known[k];
    int ack_changed = me->ack_seq != c->sent_ack;
    if (!nleft && !njoined && !nsnap && !npose && !ack_changed) {
        c->last_sent_tick = tick;
        return;
    }
    size_t need = nleft * PROTO_SIZE_AVATAR_LEFT + njoined * PROTO_SIZE_AVATAR_JOINED_MAX +
                  npose * PROTO_SIZE_AVATAR_POSE_MAX + PROTO_SIZE_SNAPSHOT(nsnap);
    proto_writer w;
    if (clients__out_begin(s, c, need, &w) < 0)
        return;
    for (uint32_t k = 0; k < nleft; k++) {
        proto_avatar_left m = {.id = s->left[k],
                               .reason = world_get(s->world, s->left[k]) ? PROTO_LEFT_OUT_OF_RANGE
                                                                          : PROTO_LEFT_DISCONNECTED};
        proto_put_avatar_left(&w, &m);
    }
    for (uint32_t k = 0; k < njoined; k++) {
        const world_avatar *a = s->joined[k];
        proto_avatar_joined m = {.id = a->id, .name = {a->name, (uint32_t)strlen(a->name)}};
        memcpy(m.pos, a->pos, sizeof m.pos);
        memcpy(m.box, a->box, sizeof m.box);
        proto_put_avatar_joined(&w, &m);
    }
    /* Poses: of those just come into view, and the changed ones of those
     * still in view (restamped S + 1 above). The own avatar's is not sent
     * back. */
    for (uint32_t k = 0; npose && k < n; k++) {
        const world_avatar *v = s->vis[k];
        uint32_t slot = world_slot(v->id);
        int known = s->mark_stamp[slot] == S + 1 && s->mark_id[slot] == v->id;
        if (v->has_pose && (!known || v->pose_tick > c->last_sent_tick))
            proto_put_avatar_pose(&w, &(proto_avatar_pose){.id = v->id, .pose = v->pose});
    }
    if (nsnap || ack_changed) {
        size_t at = proto_put_snapshot_begin(&w, tick, me->ack_seq);
        for (uint32_t k = 0; k < nsnap; k++) {
            proto_avatar a = {.id = s->snap[k]->id};
            memcpy(a.pos, s->snap[k]->pos, sizeof a.pos);
            proto_put_snapshot_add(&w, at, &a);
        }
        proto_put_snapshot_end(&w, at);
    }
    clients__out_end(s, c, &w);
    known_reserve(c, n);
    for (uint32_t k = 0; k < n; k++)
        c->known[k] = s->vis[k]->id;
    c->nknown = n;
    c->last_sent_tick = tick;
    c->sent_ack = me->ack_seq;
}
