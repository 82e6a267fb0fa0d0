/*
 * admission.h: who may connect to the game protocol, and what a
 * connection becomes. net/listener.h accepts; this refuses (with an error
 * frame) a connection past --max-clients or past the per-address cap, and
 * makes every other one a client whose socket handlers.h serves; the same
 * for a WebSocket the web endpoint hands over (web_endpoint.c). Calls
 * handlers.h and clients.h.
 */
#ifndef CVRE_ADMISSION_H
#define CVRE_ADMISSION_H

#include <stddef.h>

#include "serverInt.h"

/* Listens on cfg.host:cfg.port (server.address: as bound) and starts
 * admitting. Returns 0, or -errno with a message in err. */
int admission__start(server *s, char *err, size_t errlen);
/* Admits a WebSocket (http_takeover_fn, data: the server): the socket fd
 * after its handshake, first the handshake's answer to send. Refused as a
 * TCP connection is, its error frame in a message, then a close frame. */
void admission__websocket(void *data, int fd, const char *peer, const uint8_t *first, size_t first_len);
/* Stops accepting and closes the listening socket; no-op if not listening.
 * The clients admitted stay. */
void admission__stop(server *s);

#endif
