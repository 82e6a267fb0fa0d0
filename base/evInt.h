/*
 * evInt.h: the boundary between ev.c and its polling backend (ev_epoll.c).
 * Only these two files include it.
 */
#ifndef CVRE_EV_INT_H
#define CVRE_EV_INT_H

#include "ev.h"

typedef struct ev__backend ev__backend;

/* One ready fd as the backend reports it; events is a mask of EV_*. */
typedef struct ev__ready {
    int fd;
    unsigned events;
} ev__ready;

ev__backend *ev__backend_create(int max_events);
void ev__backend_destroy(ev__backend *b);
int ev__backend_add(ev__backend *b, int fd, unsigned events);
int ev__backend_mod(ev__backend *b, int fd, unsigned events);
int ev__backend_del(ev__backend *b, int fd);
/* Waits up to timeout_ms (-1: forever) and fills out[0..max). Returns the
 * count, 0 on timeout or EINTR, or -errno. */
int ev__backend_poll(ev__backend *b, int timeout_ms, ev__ready *out, int max);

#endif
