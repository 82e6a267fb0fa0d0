/*
 * terminal.h: what a person at a terminal sees of the interactive client,
 * instead of the JSON lines (events_to_terminal()): one short line each for
 * the welcome, our join, others joining and leaving, objects, errors, pongs,
 * the end of each command, and a collision once per contact, not once per
 * tick of it. Snapshots are not shown. Each line first clears the line the
 * prompt stands on and is followed by the prompt again (terminal_prompt()),
 * so the prompt stays the last thing on the screen.
 */
#ifndef CVRE_CLIENT_TERMINAL_H
#define CVRE_CLIENT_TERMINAL_H

#include <stddef.h>
#include <stdint.h>

#include "proto.h"

/* The prompt to show again after each line (on stderr), or NULL for none. */
void terminal_prompt(const char *prompt);

/* The counterparts of events.h's functions of the same names. */
void terminal_message(const proto_msg *m, uint64_t now_us);
void terminal_error(unsigned code, const char *text, size_t len);
/* from_client: our own bye. */
void terminal_bye(unsigned reason, int from_client);
void terminal_closed(void);
void terminal_done(const char *command, const float pos[3]);
void terminal_fetched(uint32_t object_id, const char *file, uint32_t triangles, int cached);
void terminal_done_object(const char *command, const char *result, uint32_t object_id, double seconds,
                          const float box[6]);

#endif
