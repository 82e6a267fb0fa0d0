/*
 * admission.h: who may connect to the game protocol, and what a
 * connection becomes. net/listener.h accepts; this refuses (with an error
 * frame) a connection past --max-clients or past the per-address cap, and
 * makes every other one a client whose socket handlers.h serves. Calls
 * handlers.h and clients.h.
 */
#ifndef CVRE_ADMISSION_H
#define CVRE_ADMISSION_H

#include <stddef.h>

#include "serverInt.h"

/* Listens on cfg.host:cfg.port (server.address: as bound) and starts
 * admitting. Returns 0, or -errno with a message in err. */
int admission__start(server *s, char *err, size_t errlen);
/* Stops accepting and closes the listening socket; no-op if not listening.
 * The clients admitted stay. */
void admission__stop(server *s);

#endif
