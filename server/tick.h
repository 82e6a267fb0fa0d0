/*
 * tick.h: the fixed-rate step (SRV_TICK_HZ_DEFAULT): the world moves, each
 * contact is told to its client and queued for the collision log, and each
 * joined client is told what changed near it (avatar_view.h, objects.h);
 * then the session log is written. Calls avatar_view.h, objects.h,
 * clients.h, session_log.h and stats.h.
 */
#ifndef CVRE_TICK_H
#define CVRE_TICK_H

#include "serverInt.h"

/* The tick timer's callback; data: the server. */
void tick__run(ev_loop *loop, void *data);

#endif
