/*
 * avatar_view.h: what each client is told of the avatars in its area of
 * interest: who came into view, who left it, where those it sees have
 * moved (the snapshot, with the last move of its own that was applied) and
 * how they have turned (their poses).
 * Calls clients.h only.
 */
#ifndef CVRE_AVATAR_VIEW_H
#define CVRE_AVATAR_VIEW_H

#include <stdint.h>

#include "serverInt.h"

/* Tells c what changed in its area of interest since its last update, as
 * of tick. A client whose output is backed up past SRV_OUTBUF_SOFT is
 * skipped; it gets the accumulated changes once it reads again. */
void avatar_view__update(server *s, client *c, uint32_t tick);

#endif
