/*
 * handlers.h: the game protocol's side of a client: its socket's events,
 * the frames read from it, and what each message does (hello, join and its
 * check by the auth worker, move, ping, bye; object requests go on to
 * objects.h). Calls objects.h, clients.h and session_log.h.
 */
#ifndef CVRE_HANDLERS_H
#define CVRE_HANDLERS_H

#include "serverInt.h"

/* A client socket's callback (its data: the client): writes what is
 * pending, reads within SRV_READ_BUDGET and handles every whole frame. */
void handlers__on_io(ev_loop *loop, int fd, unsigned events, void *data);
/* The auth worker's fd callback (its data: the server): settles the joins
 * it has checked, then handles the frames that came behind each. */
void handlers__on_auth_results(ev_loop *loop, int fd, unsigned events, void *data);

#endif
