/*
 * events.h: what the client prints on stdout, one JSON object per line,
 * flushed at once, so that a program reading the pipe sees each event as it
 * happens. Swarm events carry a "bot" field; bot < 0 leaves it out.
 * Diagnostics go to stderr (log.h), never here. A person at a terminal gets
 * short lines instead (events_to_terminal(), terminal.h).
 */
#ifndef CVRE_CLIENT_EVENTS_H
#define CVRE_CLIENT_EVENTS_H

#include <stddef.h>
#include <stdint.h>

#include "session.h"
#include "proto.h"

/* Totals a swarm reports in its stats and summary lines. */
typedef struct events_counts {
    uint64_t connected, joined, moves_sent, moves_dropped, frames_in, bytes_in, errors, disconnects;
    uint64_t collisions; /* COLLISION messages received */
} events_counts;

/* With on set, the one user's events (bot < 0) are shown as terminal.c's
 * lines instead of JSON; the swarm's always stay JSON. */
void events_to_terminal(int on);

/* A message received from the server: welcome, join_ok, joined, left,
 * snapshot, error, pong, bye, object, object_removed, rejected or
 * collision. Pings are answered, not printed. now_us is the monotonic clock
 * in microseconds, for the rtt of a pong. */
void events_message(const proto_msg *m, uint64_t now_us);

void events_error(int bot, unsigned code, const char *text, size_t len);
void events_bye(int bot, unsigned reason);
/* Our own bye, so a reader sees why the session ends: marked "from":"client". */
void events_bye_sent(unsigned reason);
void events_closed(int bot);

/*
 * Prints the error event for an end that was a failure on our side of the
 * wire (could not connect, socket error, bad frame from the server; code 0
 * unless it is a protocol status), with the server's address from peer.
 * A socket error after our bye counts as a clean end. Returns 1 if it
 * printed an error, 0 for a clean end.
 */
int events_conn_end(int bot, const session_end *end, const char *peer);

/* A script command finished; pos is the last authoritative own position. */
void events_done(const char *command, const float pos[3]);
/*
 * An object command (import, place, remove) finished. result is "ok",
 * "rejected", "timeout" or "failed"; object_id 0 prints null (an import
 * that made no object); upload_id 0 leaves the field out (place, remove);
 * seconds is how long the command took; box (min x y z, max x y z), when
 * not NULL, is where the object's box ended up, in world coordinates.
 */
void events_done_object(const char *command, const char *result, uint32_t object_id, uint32_t upload_id,
                        double seconds, const float box[6]);

/* A fetch wrote file: the mesh of object_id, encoded in bytes, from the
 * server or (cached) from the session's earlier fetches. */
void events_fetched(uint32_t object_id, const char *file, uint32_t vertices, uint32_t triangles, size_t bytes,
                    int cached);

void events_stats(const events_counts *k, double t);
void events_summary(const events_counts *k, double duration);

#endif
