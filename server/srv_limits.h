/*
 * srv_limits.h: every server limit in one place, each with the reason for its
 * value. All can be overridden at build time (-DSRV_...=N); the asserts keep
 * overrides sane. Runtime flags (main.c) override the ones marked "default".
 */
#ifndef CVRE_SRV_LIMITS_H
#define CVRE_SRV_LIMITS_H

#include "proto.h"
#include "import.h"
#include "move.h"
#include "net_limits.h"

/* Avatar ids are slot | generation << 16 (world.c), so slots fit in 16 bits. */
#ifndef SRV_MAX_CLIENTS_LIMIT
#define SRV_MAX_CLIENTS_LIMIT 65535
#endif
/* Default --max-clients: the benchmark's stretch goal is 10,000 avatars. */
#ifndef SRV_MAX_CLIENTS_DEFAULT
#define SRV_MAX_CLIENTS_DEFAULT 10000
#endif

/* The game's limits on its connections (clients.c passes them to
 * net/conn.h; the network layer's own are in net/net_limits.h). */

/* Input buffer: a client never needs more than one whole frame buffered, so
 * the cap is one maximal frame; before join the frame cap is tiny. It starts
 * at NET_INBUF_INITIAL and doubles on demand. */
#define SRV_INBUF_CAP (PROTO_HEADER_SIZE + PROTO_MAX_LEN)
#define SRV_INBUF_CAP_PREJOIN (PROTO_HEADER_SIZE + PROTO_MAX_LEN_PREJOIN)

/* Output buffer: one tick for one client is at most a few snapshots' worth
 * (<= 64 KiB each). A client that lets more than the soft limit pile up for
 * SRV_OUTBUF_SOFT_MS is not reading and is disconnected; the hard limit
 * disconnects at once, so a stalled reader can never grow memory. */
#ifndef SRV_OUTBUF_SOFT
#define SRV_OUTBUF_SOFT (256u * 1024u)
#endif
#ifndef SRV_OUTBUF_HARD
#define SRV_OUTBUF_HARD (2u * 1024u * 1024u)
#endif
#define SRV_OUTBUF_SOFT_MS 5000u
/* Kernel send buffer per client socket. Left to autotuning, Linux lets each
 * grow to 4 MiB (tcp_wmem), 40 GiB for 10,000 stalled clients, and a stalled
 * reader would hide behind it for a long time before the soft limit sees it.
 * 256 KiB holds many ticks of snapshots. */
#define SRV_SOCKET_SNDBUF (256 * 1024)

/* Per-wakeup budget so that one busy client cannot starve the others: at most
 * this many bytes are read per readable event, and only the frames they
 * complete are handled before the loop moves on. */
#define SRV_READ_BUDGET (64u * 1024u)

/* Default timeouts (flags override, in ms). A join takes one round trip;
 * 5 s forgives slow links but not a slowloris. Clients ping every 10 s. */
#define SRV_HANDSHAKE_TIMEOUT_MS 5000u
#define SRV_IDLE_TIMEOUT_MS 30000u
/* After an error frame or bye, how long a connection may take to flush. */
#define SRV_CLOSE_LINGER_MS 1000u

/* Simulation defaults. 20 Hz is the usual rate for walking avatars. */
#define SRV_TICK_HZ_DEFAULT 20
#define SRV_TICK_HZ_MIN 1
#define SRV_TICK_HZ_MAX 240
/* A move is limited to max speed x elapsed time; elapsed is capped so that a
 * client silent for a minute cannot jump a minute's worth of distance. */
#define SRV_MAX_SPEED_DEFAULT 5.0f /* m/s: a brisk run */
#define SRV_MOVE_MAX_DT_MS 250
#define SRV_MOVE_MAX_DT (SRV_MOVE_MAX_DT_MS / 1000.0f) /* s */
/* Fastest --max-speed, m/s: a move covers at most this x SRV_MOVE_MAX_DT,
 * which must stay within the movement code's range (MOVE_MAX_COORD). */
#define SRV_MAX_SPEED_LIMIT_M 10000
#define SRV_MAX_SPEED_LIMIT ((float)SRV_MAX_SPEED_LIMIT_M)
/* World: 1 km x 1 km, 256 m tall, floor at y = 0. --world-size may go up to
 * twice MOVE_MAX_COORD: the world is centred on 0, and the movement code
 * refuses positions past MOVE_MAX_COORD (an avatar there could never move
 * again). */
/* (Whole metres in the _M twins: clang's static asserts take no floats.) */
#define SRV_WORLD_SIZE_DEFAULT_M 1000
#define SRV_WORLD_SIZE_DEFAULT ((float)SRV_WORLD_SIZE_DEFAULT_M)
#define SRV_WORLD_SIZE_MIN 10.0f
#define SRV_WORLD_SIZE_MAX_M (2 * MOVE_MAX_COORD_M)
#define SRV_WORLD_SIZE_MAX ((float)SRV_WORLD_SIZE_MAX_M)
#define SRV_WORLD_HEIGHT_M 256
#define SRV_WORLD_HEIGHT ((float)SRV_WORLD_HEIGHT_M)
#define SRV_AOI_RADIUS_DEFAULT 64.0f
#define SRV_AOI_RADIUS_MAX 1000.0f
#define SRV_SPAWN_RADIUS_DEFAULT 8.0f
/* Largest area of interest result per client per tick; more than a snapshot
 * frame can carry is cut (nearest first is not guaranteed). */
#define SRV_AOI_MAX PROTO_SNAPSHOT_MAX_ENTRIES

/* Objects. A model file may be 16 MiB (Sponza's OBJ is 5.6 MB, a city block
 * 13.6 MB); all unfinished uploads together may hold SRV_UPLOAD_BUDGET, so
 * that many clients uploading at once cannot exhaust memory. */
#define SRV_MAX_UPLOAD_DEFAULT (16u * 1024u * 1024u)
#define SRV_UPLOAD_BUDGET (64u * 1024u * 1024u)
/* Largest --max-upload: a file over the budget of all uploads could never
 * be accepted. */
#define SRV_MAX_UPLOAD_LIMIT SRV_UPLOAD_BUDGET
/* Triangles in one model: 4 million (144 MB of floats) is far beyond any
 * model here (the city block has 400,020) and still fits in memory. */
#define SRV_MAX_TRIANGLES_DEFAULT 4000000u
/* Largest --max-triangles: what the importer itself accepts. */
#define SRV_MAX_TRIANGLES_LIMIT IMPORT_MAX_TRIANGLES

/* Where an object may stand: x and z within the world, y within
 * +-SRV_WORLD_HEIGHT (sunk below the floor is harmless), and at most
 * SRV_OBJECT_SIZE_MAX long along any axis: the city block model is 230 m
 * across, and a placement 1,000 times a desk's size or one that covers the
 * default world is a mistake or an attack. Checked at upload, placement
 * and restore (scene_check_fit). */
#define SRV_OBJECT_SIZE_MAX_M 512
#define SRV_OBJECT_SIZE_MAX ((float)SRV_OBJECT_SIZE_MAX_M)

/* Objects have an area of interest like avatars (objects.c): a client is
 * told of the objects whose bounds come within aoi_radius + STEP of where
 * its view was last made, which is made again once the avatar has moved
 * STEP metres (or the scene changed), and forgets those past aoi_radius +
 * 2 x STEP of it. So every object within aoi_radius of the avatar is
 * known, none past aoi_radius + 3 x STEP is, and one at the edge does not
 * flicker in and out. */
#define SRV_OBJECT_VIEW_STEP 4.0f
/* A view sends new objects only while the client's output holds less than
 * this: a join in a crowded place is streamed over ticks as the client
 * reads, never queued past the output limits at once. */
#define SRV_OBJECT_VIEW_BUDGET (SRV_OUTBUF_SOFT / 2u)
/* Meshes (objects.c): MESH_CHUNKs are sent under the same budget as the
 * view, after it, so a download never starves the objects' news and never
 * reaches the output limits. A client may have SRV_MESH_QUEUE requests
 * waiting behind the mesh being sent (a page asks for every object it is
 * told of); an address may ask for SRV_MESH_BURST at once and then
 * SRV_MESH_PER_SECOND a second, so a flood costs the server nothing but
 * refusals. A mesh is encoded once and kept for the next client that asks
 * for it (encoding the 400,020-triangle city block takes 150 ms); the kept
 * meshes hold at most SRV_MESH_MEMORY, the least recently asked for making
 * room for others, and a request waits its turn while those being sent
 * fill it. */
#define SRV_MESH_QUEUE 16u
#define SRV_MESH_BURST 32.0
#define SRV_MESH_PER_SECOND 8.0
#define SRV_MESH_MEMORY (256u * 1024u * 1024u)
/* The online loop looks for clusters every 10 s: a crowd stopped at a
 * doorway gets it opened within seconds, and a quiet world costs one
 * indexed read of new rows per interval. */
#define SRV_REFINE_INTERVAL_DEFAULT 10.0

/* At shutdown the last session records may wait this long for the lock. */
#define SRV_DB_BUSY_SHUTDOWN_MS 5000

/* Logins (a password or a token) per client address: a burst of 5, then one
 * every 2 s. A person mistyping a password never notices; a guesser gets
 * 1,800 tries an hour instead of the 36,000 one Argon2id worker could
 * verify. LOGIN_SLOTS buckets: addresses beyond share them. */
#define SRV_LOGIN_BURST 5.0
#define SRV_LOGIN_PER_SECOND 0.5
#define SRV_LOGIN_SLOTS 4096u

/* Defaults of --max-per-address and --joins-per-second: a household or an
 * office behind one address has a few dozen people, each with a
 * connection or two; nobody joins ten times a second. The bot swarm and
 * benchmarks, many connections from one address, lift them (0: no limit).
 * Joins may come in a burst of twice the rate. */
#define SRV_MAX_PER_ADDRESS_DEFAULT 64u
#define SRV_JOINS_PER_SECOND_DEFAULT 10.0

/* Upload quotas per account (--quota-objects, --quota-mb): a person
 * furnishing a place needs tens of objects; the demo world's largest model
 * (Sponza) is 9.5 MB of mesh. Without them one account filled a world with
 * 16,000 objects in 26 s, and six 16 MiB uploads took 454 MB of database. */
#define SRV_QUOTA_OBJECTS_DEFAULT 100u
#define SRV_QUOTA_MB_DEFAULT 128u

/* Moves a connection may send per second: twice the tick rate (a client
 * ahead of the server's clock by a tick still fits). Moves past it are
 * dropped and counted; a connection that has more than
 * SRV_MOVE_FLOOD_DROPS times the tick rate dropped within one second is
 * flooding, not lagging, and is disconnected. */
#define SRV_MOVES_PER_TICK 2u
#define SRV_MOVE_FLOOD_DROPS 8u

/* listen(2) backlog: the bot swarm connects 1,000 per second. */
#define SRV_LISTEN_BACKLOG 4096

_Static_assert(SRV_MAX_CLIENTS_DEFAULT <= SRV_MAX_CLIENTS_LIMIT, "default within limit");
_Static_assert(SRV_MAX_CLIENTS_LIMIT <= 65535, "avatar ids keep the slot in 16 bits");
_Static_assert(SRV_OUTBUF_SOFT < SRV_OUTBUF_HARD, "soft below hard");
_Static_assert(SRV_OUTBUF_HARD >= 4u * PROTO_SIZE_SNAPSHOT(PROTO_SNAPSHOT_MAX_ENTRIES), "a tick must fit");
_Static_assert(NET_INBUF_INITIAL <= SRV_INBUF_CAP_PREJOIN, "initial within prejoin cap");
_Static_assert(SRV_WORLD_SIZE_DEFAULT_M <= SRV_WORLD_SIZE_MAX_M, "the default world fits the movement range");
_Static_assert(SRV_WORLD_HEIGHT_M <= MOVE_MAX_COORD_M, "the world's top fits the movement range");
_Static_assert(SRV_MAX_SPEED_LIMIT_M * SRV_MOVE_MAX_DT_MS <= MOVE_MAX_COORD_M * 1000, "one move fits the movement range");
_Static_assert(SRV_MOVE_MAX_DT_MS <= MOVE_MAX_DT_MS && 1000 / SRV_TICK_HZ_MIN <= MOVE_MAX_DT_MS, "ticks fit the movement code");
_Static_assert(SRV_MAX_UPLOAD_DEFAULT <= SRV_MAX_UPLOAD_LIMIT, "the default upload fits the budget");
_Static_assert(30ull * IMPORT_MAX_TRIANGLES + 32u <= SRV_MESH_MEMORY, "the largest encoded mesh fits the budget");
_Static_assert(SRV_UPLOAD_BUDGET <= IMPORT_MAX_BYTES, "an upload the server takes, the importer reads");
_Static_assert(SRV_MAX_TRIANGLES_DEFAULT <= SRV_MAX_TRIANGLES_LIMIT, "default triangles within the importer's");
_Static_assert(SRV_OBJECT_SIZE_MAX_M <= SRV_WORLD_SIZE_DEFAULT_M, "an object fits the default world");
_Static_assert(SRV_OBJECT_VIEW_BUDGET + PROTO_SIZE_OBJECT_INFO(PROTO_OBJECT_BOXES_MAX) < SRV_OUTBUF_SOFT,
               "streaming objects never reaches the soft output limit");

#endif
