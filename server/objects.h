/*
 * objects.h: the server's side of objects (objects.c): uploads in chunks,
 * imports on the importer thread, placement and removal by their owners,
 * new collision maps from the refiner, what each client is told of the
 * objects near it, and their meshes, sent in chunks to those who ask. Called by server.c, handlers.c and tick.c; it calls only
 * clients.h (to tell a client) and session_log.h (to record a change).
 */
#ifndef CVRE_OBJECTS_H
#define CVRE_OBJECTS_H

#include <stddef.h>

#include "serverInt.h"

/* Restores the scene from the store, preloads the world file, starts the
 * importer and the refiner on s's loop. Returns 0, or -1 with a message in
 * err; objects__stop undoes what was done either way. */
int objects__start(server *s, char *err, size_t errlen);
void objects__stop(server *s);
/* Handles an object request (or a mesh request) from a joined client. */
void objects__on_message(server *s, client *c, const proto_msg *m);
/* Brings what c knows of the objects up to date with where its avatar
 * is (see SRV_OBJECT_VIEW_STEP): each tick, and at its join with force set;
 * then sends the next chunks of the meshes c asked for, while its output
 * is under SRV_OBJECT_VIEW_BUDGET. Cheap when nothing changed, the avatar
 * did not move far and no mesh is waiting. */
void objects__view(server *s, client *c, int force);
/* The objects of a deleted account pass to the world (the store did the
 * same); every client hears of the new owner. */
void objects__owner_gone(server *s, const char *owner);
/* Frees what c's unfinished upload, its view and its meshes hold. */
void objects__client_gone(server *s, client *c);

#endif
