/*
 * serverInt.h: the state cvre-server's files share: the server, its clients
 * and its figures. Only the server's own .c files include it; each of them
 * declares its functions in its own header:
 *
 *   server.c       lifecycle: create, run, shutdown, housekeeping, reaping
 *   admission.c    who may connect, and the client a connection becomes
 *   handlers.c     a client's frames in, and what each message does
 *   tick.c         the fixed-rate step and its collisions
 *   avatar_view.c  what each client is told of the avatars near it
 *   objects.c      objects: uploads, placement, what each client is told
 *   stats.c        the periodic report of the figures
 *   session_log.c  sessions and object changes queued for the store
 *   clients.c      one client's connection: output, close, linger
 *
 * Calls go down this list, never up: server.c drives everything; admission.c
 * hands a new connection to handlers.c; handlers.c and tick.c call objects.c
 * and avatar_view.c; those call clients.c and session_log.c. objects.c knows
 * nothing of the files above it: it is called, and answers through
 * clients.h (output) and session_log.h (the store).
 */
#ifndef CVRE_SERVER_INT_H
#define CVRE_SERVER_INT_H

#include <stdint.h>

#include "conn.h"
#include "db.h"
#include "dblog.h"
#include "ev.h"
#include "http_server.h"
#include "auth.h"
#include "importer.h"
#include "mesher.h"
#include "listener.h"
#include "metrics.h"
#include "proto.h"
#include "ratelimit.h"
#include "refiner.h"
#include "scene.h"
#include "server.h"
#include "srv_limits.h"
#include "world.h"
#include "ws.h"

#define NS_PER_MS ((uint64_t)1000000)
/* The user that owns the objects of the world file: the reserved account
 * of that name (db/account.h), which cannot log in. */
#define WORLD_OWNER "world"

/* An upload in progress: the file grows chunk by chunk up to its size. */
typedef struct client_upload {
    uint32_t id; /* 0: none */
    uint32_t total, received;
    uint8_t *data;
    char name[PROTO_OBJECT_NAME_MAX + 1];
    char format[PROTO_FORMAT_MAX + 1];
    int z_up;
    float unit_scale;
} client_upload;

/* An encoded mesh (objects.c), kept by hash for every client that asks for
 * it, until the memory for meshes is wanted for others and no client is
 * being sent it. While the mesher encodes it, it has no data yet and len
 * is the most it can take (held for it). */
typedef struct mesh_blob {
    uint8_t hash[PROTO_MESH_HASH_SIZE];
    uint8_t *data; /* NULL: being encoded */
    size_t len;
    uint32_t refs; /* clients being sent it */
} mesh_blob;

/* Meshes a client asked for (objects.c): the one being sent, and the
 * object ids waiting, oldest first. */
typedef struct client_mesh {
    mesh_blob *blob; /* NULL: none being sent */
    size_t sent;
    uint32_t object_id;
    uint32_t queue[SRV_MESH_QUEUE];
    uint32_t nqueue;
} client_mesh;

/* ST_AUTH: the join waits for the auth worker (auth.h). */
typedef enum { ST_HELLO, ST_JOIN, ST_AUTH, ST_JOINED } client_state;

/* An object a client has been told of, at the revision it was told. */
typedef struct known_object {
    uint32_t id, slot, rev;
} known_object;

/* An object a view is about to tell a client of, nearest first. */
typedef struct object_pick {
    uint32_t slot;
    float d2;
} object_pick;

typedef struct client {
    conn c;
    server *srv;
    client_state state;
    int closing;  /* no more input is handled; output is flushed, then closed (conn_begin_close) */
    int dead;     /* reaped at the next safe point */
    int in_write_list;
    /* A WebSocket client (--web; clients.c): its frames' state, and the
     * protocol bytes of the messages unwrapped so far, which handle_input
     * reads instead of the socket's bytes; NULL for a TCP client. */
    ws_reader *ws;
    uint8_t *ws_in;
    size_t ws_in_len, ws_in_cap;
    uint16_t ws_close; /* the close code its close frame will carry; 0: 1000 */
    uint32_t index; /* in server.clients */
    int64_t session_id; /* 0 before hello */
    uint8_t token[PROTO_TOKEN_SIZE];
    char peer[80];
    char addr[80];      /* peer without its port: the key of the per-address limits */
    uint32_t avatar_id; /* 0 before join */
    int64_t user_id;    /* users.id, known before the avatar's first tick; 0 before */
    int64_t account_id; /* accounts.id; 0 for a guest */
    int is_admin;       /* the account may place and remove anyone's objects */
    float join_box[3];  /* the avatar box asked for, kept while the join is checked */
    char join_name[PROTO_NAME_MAX + 1]; /* the name asked for, likewise (a ban may come meanwhile) */
    uint64_t moves_window_ns;  /* start of the second the move counts are for */
    uint32_t moves_in_window, moves_dropped_in_window;
    int has_seq;
    uint32_t last_seq;
    uint32_t sent_ack;
    uint32_t last_sent_tick;
    uint32_t *known; /* ids of the avatars this client has been told of, in no order */
    uint32_t nknown, known_cap;
    uint64_t connected_ns, last_frame_ns;
    char end_reason[PROTO_MESSAGE_MAX + 16];
    client_upload upload;
    /* The objects it knows (objects__view). */
    known_object *objs;
    uint32_t nobjs, objs_cap;
    uint32_t objs_gen;  /* server.scene_gen when the view was last made */
    float objs_at[2];   /* where (x, z) */
    int objs_more;      /* the view is not whole yet: made again next tick */
    int objs_owned;     /* its own objects, wherever they are, still to be sent */
    client_mesh mesh;
} client;

enum { EVT_OPEN, EVT_JOIN, EVT_CLOSE, EVT_PLACE, EVT_REMOVE };

/* A change waiting to be written (a session's, or an object's place); the
 * tick batches them into one transaction (session_log.h) so that a burst of joins costs one
 * commit, and the tick never waits for the database: when the collision
 * log's writer holds the lock, the batch simply waits for the next tick. */
typedef struct store_event {
    int kind;
    int64_t session; /* the object id for EVT_PLACE and EVT_REMOVE */
    proto_transform at_place;
    double at;
    uint32_t avatar;
    char text[PROTO_MESSAGE_MAX + 16]; /* peer (open), name (join), reason (close) */
    char token[2 * PROTO_TOKEN_SIZE + 1];
} store_event;

/* The server's figures. The counters are totals since start, never reset:
 * the metrics endpoint serves them as they are, and each stats interval
 * (stats__report) reports their growth since its start (server.st_base). */
typedef struct stats {
    uint64_t frames_in, moves_in, bytes_in, bytes_out;
    uint64_t accepted, closed, protocol_errors, timeouts, slow_readers, collisions, moves_dropped;
    uint64_t ticks, imports_ok, imports_failed, versions_published;
    uint64_t errors[METRICS_CODES];   /* error frames sent, by code */
    uint64_t rejected[METRICS_CODES]; /* object requests refused, by code */
    metrics_histogram tick_hist;
    uint32_t *tick_us; /* durations of this interval's ticks */
    uint32_t nticks, tick_cap;
    uint64_t interval_start_ns;
} stats;

struct server {
    server_config cfg;
    ev_loop *loop;
    net_listener *listener; /* the protocol's (admission.c); NULL once shut down */
    int signal_fd, max_fd;
    db *db;
    world *world;
    client **clients;
    uint32_t nclients;
    client **write_list;
    uint32_t nwrite;
    /* Per-tick scratch, sized for the largest area of interest. */
    const world_avatar **vis, **joined, **snap;
    uint32_t *left;
    /* Per avatar slot: which id was stamped, and when (avatar_view.c). */
    uint32_t *mark_id, *mark_stamp, stamp;
    store_event *events;
    uint32_t nevents, events_cap;
    int64_t last_session_id;
    int stopping;
    uint64_t stop_deadline_ns;
    stats st;
    stats st_base;            /* st when the stats interval began */
    http_server *metrics;     /* --metrics (metrics_endpoint.c); NULL: off */
    http_server *web;         /* --web (web_endpoint.c); NULL: off */
    int web_root_fd;          /* --web-root, opened once; -1: off */
    char address[80];
    client **by_slot; /* the joined client of each avatar slot */
    dblog *log;       /* the collision log's writer thread */
    /* Objects (objects.c). */
    scene *scene;
    importer *importer;
    auth *auth;          /* joins' credentials, checked off the loop */
    uint32_t logins_pending; /* joins with a credential at the auth worker */
    ratelimit *logins;   /* logins per address */
    ratelimit *joins;    /* joins per address; NULL: no limit */
    addrcount *per_address; /* connections open per address */
    int64_t admin_feed_last;  /* the last admin action applied (db/moderation.h) */
    refiner *refiner;    /* new collision maps from the online loop and the store */
    size_t upload_bytes; /* held by unfinished uploads, all clients */
    mesher *mesher;      /* encodes the meshes no upload brought encoded */
    mesh_blob **meshes;  /* encoded meshes kept (objects.c) */
    uint32_t nmeshes;
    size_t mesh_bytes;   /* what they hold */
    ratelimit *mesh_requests; /* mesh requests per address */
    uint32_t scene_gen;  /* grows with every change to the scene a client may see */
    /* objects__view's scratch: a stamp per object slot, the slots a query
     * found, and the objects to send. */
    uint32_t *obj_stamp, obj_stamps, obj_stamp_now;
    uint32_t *obj_found, obj_found_cap;
    object_pick *picks;
    uint32_t picks_cap;
};

/* The loop's time of this wake-up, in ns. */
static inline uint64_t server__now(const server *s) { return ev_now(s->loop); }

#endif
