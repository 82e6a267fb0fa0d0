/*
 * stats.h: the server's figures over time: each tick's duration, and the
 * periodic report (a log line, and a line of the stats file if one was
 * asked for). The totals themselves live in serverInt.h's stats, counted
 * where things happen; the metrics endpoint serves them as they are.
 * Calls no other file of the server.
 */
#ifndef CVRE_STATS_H
#define CVRE_STATS_H

#include <stdint.h>

#include "serverInt.h"

/* Counts a tick that took us microseconds (its histogram, and the
 * interval's list for exact percentiles while there is room). */
void stats__tick(stats *st, uint64_t us);
/* The stats timer's callback (data: the server): reports the interval's
 * figures, the growth of the totals since it began, and starts a new one. */
void stats__report(ev_loop *loop, void *data);

#endif
