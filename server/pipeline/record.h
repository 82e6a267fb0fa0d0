/*
 * record.h: a clustering run's results in the store (tables cluster_runs and
 * clusters, db/migrations/0003_clusters.sql). Shared by the offline job
 * (cvre-cluster) and the server's online loop (server/refiner.c).
 */
#ifndef CVRE_CLUSTER_RECORD_H
#define CVRE_CLUSTER_RECORD_H

#include <stddef.h>
#include <stdint.h>

#include "db.h"
#include "dbscan.h"

/* Defaults of the offline job and the server's online loop: 0.5 m is about
 * an avatar's width; 10 collisions by 3 distinct users make a place where
 * people keep being stopped, not one person bumping on purpose. */
#define CLUSTER_EPS_DEFAULT 0.5
#define CLUSTER_MIN_POINTS_DEFAULT 10u
#define CLUSTER_MIN_USERS_DEFAULT 3u

/* One cluster found on one object's ECM version. */
typedef struct cluster_found {
    int64_t object_id;
    uint32_t ecm_version;
    uint32_t cluster_id; /* 0.. within the object, in DBSCAN's order */
    uint32_t box;        /* the box it names: find.h's cluster_find (refinement takes
                          * every other box its points lie on too: refine.h) */
    dbscan_cluster c;
} cluster_found;

typedef struct cluster_run {
    double started, finished;
    dbscan_params params;
    int has_since, has_until; /* time window read; open sides are NULL */
    double since, until;
    uint64_t objects, points; /* examined */
} cluster_run;

/* How many distinct (object, version, box) the n clusters name. */
uint64_t cluster_problem_boxes(const cluster_found *found, size_t n);

/* Writes the run and its n clusters in one transaction; sets *run_id.
 * Returns 0, or a negative errno (db/db.h) with the message in err
 * (nothing written). */
int cluster_record(db *d, const cluster_run *run, const cluster_found *found, size_t n, int64_t *run_id, char *err,
                   size_t errlen);

#endif
