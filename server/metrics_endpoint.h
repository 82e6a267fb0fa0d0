/*
 * metrics_endpoint.h: `--metrics HOST:PORT`, the server's figures for
 * Prometheus (metrics_endpoint.c). Calls no other file of the server; it
 * reads the figures in serverInt.h.
 */
#ifndef CVRE_METRICS_ENDPOINT_H
#define CVRE_METRICS_ENDPOINT_H

#include <stddef.h>

#include "serverInt.h"

/* Starts the endpoint if cfg.metrics_host is set. Returns 0, or -errno with a
 * message in err. */
int metrics__start(server *s, char *err, size_t errlen);
/* Stops it; no-op when it is off. */
void metrics__stop(server *s);

#endif
