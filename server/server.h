/*
 * server.h: cvre-server's core: accepts clients, speaks the protocol, runs
 * the fixed-rate tick over the world and sends each client what it can see.
 * Everything runs on one thread inside one ev loop.
 */
#ifndef CVRE_SERVER_H
#define CVRE_SERVER_H

#include <stddef.h>
#include <stdint.h>

#include "import_proc.h"

typedef struct server_config {
    const char *host;
    uint16_t port;   /* 0: any free port */
    const char *db_path;
    int tick_hz;
    uint32_t max_clients;
    float aoi_radius;
    float max_speed;
    float world_size;   /* x and z extent, centred on 0 */
    float spawn_radius;
    uint32_t handshake_timeout_ms;
    uint32_t idle_timeout_ms;
    uint64_t seed;
    const char *stats_file; /* NULL: none */
    uint32_t stats_interval_ms;
    uint32_t max_upload;    /* bytes of one model file */
    uint32_t max_triangles; /* of one model */
    const char *world_file; /* objects to preload; NULL: none */
    const char *metrics_host; /* the Prometheus endpoint (--metrics); NULL: off */
    uint16_t metrics_port;    /* 0: any free port */
    const char *web_host;     /* the web client and WebSocket endpoint (--web); NULL: off */
    uint16_t web_port;        /* 0: any free port */
    const char *web_root;     /* its files (--web-root) */
    const char *web_origins;  /* --web-origin: comma-separated origins whose pages may
                               * open a WebSocket besides the server's own; "*": any */
    import_proc importer;   /* the isolated importer every model goes through */
    int auth_required;      /* 1: accounts only; 0: guests may walk and look */
    double login_burst;     /* logins an address may make at once (then SRV_LOGIN_PER_SECOND) */
    uint32_t quota_objects;    /* objects one account may have in the world */
    uint64_t quota_bytes;      /* bytes of mesh (36 a triangle) one account may have */
    uint32_t max_per_address;  /* connections open from one address; 0: no limit */
    double joins_per_second;   /* joins per address per second (burst: twice); 0: no limit */
    /* The collision map's online loop (refiner.h). */
    double refine_interval_s;  /* 0: off (changes from other processes still arrive) */
    double refine_eps;         /* DBSCAN radius, m */
    uint32_t refine_min_points;
    uint32_t refine_min_users;
    uint32_t refine_depth;     /* grid 2^depth per axis */
    uint32_t refine_max_boxes; /* per object */
    double refine_max_empty;   /* share of a merged box that may be new empty space */
    uint32_t refine_threads;   /* most threads a refinement runs on; 0: one per CPU */
} server_config;

typedef struct server server;

/* Fills cfg with the defaults (srv_limits.h). */
void server_config_defaults(server_config *cfg);

/* Opens the database, binds and listens. On failure returns NULL with a
 * message in err. */
server *server_create(const server_config *cfg, char *err, size_t errlen);
/* "HOST:PORT" as bound (IPv6 in brackets). */
const char *server_address(const server *s);
/* Serves until SIGINT or SIGTERM, then says bye to every client, records
 * the end of their sessions and returns 0; the loop's -errno if it failed. */
int server_run(server *s);
void server_destroy(server *s);

#endif
