/*
 * session_log.c: the sessions and object changes the loop queues for the
 * store, and the one transaction a tick that writes them (session_log.h).
 */
#include "session_log.h"

#include <string.h>

#include "alloc.h"
#include "clients.h"
#include "log.h"

store_event *session_log__push(server *s, int kind, int64_t session)
{
    if (s->nevents == s->events_cap) {
        s->events_cap = s->events_cap ? s->events_cap * 2 : 64;
        s->events = cvre_xrealloc(s->events, s->events_cap * sizeof *s->events);
    }
    store_event *e = &s->events[s->nevents++];
    memset(e, 0, sizeof *e);
    e->kind = kind;
    e->session = session;
    e->at = db_now();
    return e;
}

/* Writes the queued session events in one transaction. A database error is
 * logged and the batch dropped: the world goes on without its history rather
 * than stopping. */
void session_log__flush(server *s)
{
    if (!s->nevents)
        return;
    int rc = db_begin(s->db);
    for (uint32_t i = 0; rc == 0 && i < s->nevents; i++) {
        const store_event *e = &s->events[i];
        switch (e->kind) {
        case EVT_OPEN: rc = db_session_open(s->db, e->session, e->token, e->text, e->at); break;
        case EVT_JOIN: {
            int64_t uid = 0;
            rc = db_session_join(s->db, e->session, e->text, e->avatar, e->at, &uid);
            client *c = rc == 0 ? clients__by_session(s, e->session) : NULL;
            if (c)
                c->user_id = uid;
            break;
        }
        case EVT_CLOSE: rc = db_session_close(s->db, e->session, e->text, e->at); break;
        case EVT_PLACE:
            rc = db_object_place(s->db, e->session, e->at_place.pos, e->at_place.yaw, e->at_place.scale);
            break;
        default: rc = db_object_remove(s->db, e->session, e->at); break;
        }
    }
    if (rc == 0)
        rc = db_commit(s->db);
    if (rc != 0) {
        int busy = db_busy(s->db);
        db_rollback(s->db);
        if (busy && !s->stopping) {
            log_debug("database busy: %u records wait for the next tick", s->nevents);
            return;
        }
        log_error("database: %s; %u session and object records lost", db_error(s->db), s->nevents);
    }
    s->nevents = 0;
}
