/*
 * listener.h: the game protocol's listening socket: it accepts within a
 * budget per wake-up, pauses while the process is out of file descriptors,
 * refuses (with an error frame) a connection past --max-clients or past the
 * per-address cap, and makes every other one a client whose socket
 * handlers.h serves. Calls handlers.h and clients.h.
 */
#ifndef CVRE_LISTENER_H
#define CVRE_LISTENER_H

#include <stddef.h>

#include "serverInt.h"

/* Listens on cfg.host:cfg.port (server.address: as bound) and starts
 * accepting. Returns 0, or -1 with a message in err. */
int listener__start(server *s, char *err, size_t errlen);
/* Stops accepting and closes the socket; no-op if not listening. */
void listener__stop(server *s);

#endif
