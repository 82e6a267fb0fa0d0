/*
 * find.h: one object's collisions to its clusters, the first step of the
 * pipeline that the online loop (server/refiner.c) and the offline job
 * (cvre-cluster) share: read the collisions of an object's collision map
 * version -> find its clusters (here) -> record them (record.h) -> refine
 * and store the next version (apply.h).
 */
#ifndef CVRE_CLUSTER_FIND_H
#define CVRE_CLUSTER_FIND_H

#include <stddef.h>
#include <stdint.h>

#include "dbscan.h"
#include "record.h"

/* The collisions of one object and version: object-local points, each
 * with the user it was logged for. */
typedef struct object_points {
    float *xyz; /* 3 a point */
    uint32_t *users;
    uint32_t n, cap;
} object_points;

void object_points_add(object_points *p, const float xyz[3], uint32_t user);
/* Frees the points; p is empty again. */
void object_points_free(object_points *p);

/*
 * Clusters p, the points of object object_id's version, whose boxes are
 * boxes[0..nboxes), with DBSCAN (prm), and appends one cluster_found to
 * *found (grown with cvre_xrealloc, *nfound counting) for each cluster,
 * naming the box that holds its centroid or, if none, the nearest one (ties:
 * the lowest index). Returns the number of clusters appended, or
 * dbscan_run's -errno (nothing appended).
 */
int cluster_find(const object_points *p, const dbscan_params *prm, int64_t object_id, uint32_t version,
                 const float (*boxes)[6], uint32_t nboxes, cluster_found **found, size_t *nfound);

#endif
