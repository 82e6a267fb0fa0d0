/*
 * session_log.h: what the store is told of sessions (opened, joined,
 * closed) and of objects' places, queued as the loop goes and written in one
 * transaction a tick (serverInt.h's store_event says why). Calls only
 * clients.h (a join's users row goes back to its client).
 */
#ifndef CVRE_SESSION_LOG_H
#define CVRE_SESSION_LOG_H

#include <stdint.h>

#include "serverInt.h"

/* Queues a change (kind: EVT_*; session: the object id for EVT_PLACE and
 * EVT_REMOVE) for the next flush, stamped now. The caller fills the rest;
 * the pointer is valid until the next push. */
store_event *session_log__push(server *s, int kind, int64_t session);
/* Writes the queued changes now (each tick does; an import first, so that
 * the quota it checks counts the removals before it). A database error is
 * logged and the batch dropped; a busy database keeps it for the next tick,
 * unless the server is stopping. */
void session_log__flush(server *s);

#endif
