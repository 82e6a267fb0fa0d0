/*
 * bots.h: a swarm of simulated users on one event loop, for load tests.
 *
 * Bots connect at a fixed ramp (over a WebSocket, with at most
 * BOTS_UPGRADES_MAX upgrades in flight), join as "<prefix>-<i>" and then each sends
 * a move at the rate, spread evenly over the period so the server sees a
 * steady stream rather than bursts. Only totals are printed (a stats line a
 * second and a summary), plus each error, each bye and each unexpected close
 * as its own event with a "bot" field.
 */
#ifndef CVRE_CLIENT_BOTS_H
#define CVRE_CLIENT_BOTS_H

#include "session.h"
#include "ev.h"

enum bots_pattern { BOTS_RANDOM_WALK, BOTS_CIRCLE };

typedef struct bots_opts {
    session_params net;    /* net.name is the name prefix */
    double rate;        /* moves per second per bot */
    unsigned count;     /* bots */
    int pattern;        /* enum bots_pattern */
    double duration;    /* seconds from start until every bot says bye */
    double ramp;        /* connections started per second */
    int no_handshake;   /* raw: no hello or join, moves only */
    int pose;           /* moves carry a facing and a head pose */
} bots_opts;

typedef struct bots bots;

/* Sets up the swarm and its timers; the first bot connects at once. Returns
 * NULL with *exit_code set (1: the host does not resolve). Stops the loop
 * after the summary. */
bots *bots_create(ev_loop *loop, const bots_opts *opts, int *exit_code);
/* SIGINT or SIGTERM: end now as if the duration were over; a second one
 * skips the wait for the byes. */
void bots_interrupt(bots *b);
/* 0 when no bot saw an error or an unexpected disconnect, 1 otherwise. */
int bots_exit_code(const bots *b);
void bots_free(bots *b);

#endif
