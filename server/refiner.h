/*
 * refiner.h: the server's collision-map thread (the paper's "on render:
 * examine the DB for clusters"), and the one way new collision maps reach
 * the tick.
 *
 * It does two things on its own thread and its own database connection, so
 * that the tick never waits on either:
 *
 *   - follows the change feed (db/ecm.h) every REFINER_FEED_MS: each new
 *     ECM version, whoever wrote it (this thread, `cvre-cluster --apply`,
 *     `cvre-admin rollback`), is loaded and queued for the tick, which swaps
 *     it into the scene between ticks and tells the clients;
 *   - every interval (the online loop; 0 turns it off) reads the collisions
 *     logged since the last look, keeps each object's points of its current
 *     version in memory, clusters the objects that got new points (DBSCAN),
 *     and for those with clusters records the run and writes a refined
 *     version (server/pipeline/apply.h), which the feed then publishes.
 *     Collisions against a new version start that object's points afresh:
 *     they feed the next round, until no cluster remains.
 *
 * It signals an eventfd (refiner_fd) that the loop watches; the loop takes
 * updates with refiner_take.
 */
#ifndef CVRE_REFINER_H
#define CVRE_REFINER_H

#include <stdint.h>

#include "dbscan.h"
#include "refine.h"

typedef struct refiner refiner;

typedef struct refiner_config {
    const char *db_path;
    int64_t feed_after;     /* change feed events already reflected in the scene */
    double interval_s;      /* online loop period in seconds; 0: off */
    dbscan_params cluster;  /* eps, min points, min users */
    ecm_params ecm;         /* avatar size in metres */
} refiner_config;

/* A new collision map for an object. */
typedef struct refiner_update {
    uint32_t object_id, version;
    uint32_t count;
    float (*boxes)[6]; /* local; refiner_update_free */
} refiner_update;

/* Starts the thread. NULL with a message in err on failure. */
refiner *refiner_start(const refiner_config *cfg, char *err, size_t errlen);
/* Lets a round in progress finish (it is bounded: one clustering and one
 * refinement per object), then joins the thread. */
void refiner_stop(refiner *r);
int refiner_fd(const refiner *r);
/* Moves the next update into *out; 0, or -EAGAIN when none. */
int refiner_take(refiner *r, refiner_update *out);
void refiner_update_free(refiner_update *u);

/* Counters since refiner_start, for the metrics endpoint. */
typedef struct refiner_stats {
    uint64_t rounds;           /* online rounds: new collisions read and clustered */
    uint64_t versions_written; /* refined collision maps this thread stored */
} refiner_stats;

/* Safe from any thread while the refiner runs. */
void refiner_stats_get(refiner *r, refiner_stats *out);

#endif
