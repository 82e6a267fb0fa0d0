/*
 * web_endpoint.h: `--web HOST:PORT`, the browser's way in (web_endpoint.c):
 * an HTTP endpoint (net/http_server.h) that serves the web client's files
 * from --web-root (net/web_files.h) and upgrades a request for a WebSocket
 * (protocol/ws.h) into a game client, which admission.h then admits like a TCP
 * one. Calls admission.h; reads the server's configuration.
 */
#ifndef CVRE_WEB_ENDPOINT_H
#define CVRE_WEB_ENDPOINT_H

#include <stddef.h>

#include "serverInt.h"

/* Starts the endpoint if cfg.web_host is set and opens the web root (one
 * that cannot be opened is logged, and every file is then 404). Returns 0,
 * or -errno with a message in err. */
int web__start(server *s, char *err, size_t errlen);
/* Stops it and closes the root; no-op when it is off. Clients already
 * upgraded stay. */
void web__stop(server *s);

#endif
