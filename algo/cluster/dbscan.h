/*
 * dbscan.h: density clustering of collision points (DBSCAN, Ester et al.
 * 1996) with one extra criterion, a minimum number of distinct users, so that
 * one person bumping into the same spot on purpose never makes a cluster.
 * Pure module: no I/O. Neighbour search goes through FLANN's C API.
 *
 * Definitions, exactly as in the paper, with "within eps" meaning a Euclidean
 * distance <= eps (inclusive, like scikit-learn), computed in double from the
 * float coordinates:
 *   - a core point has at least min_points points, itself included, within eps;
 *   - a cluster is a maximal set of core points connected by chains of core
 *     points within eps of each other, plus every non-core point within eps of
 *     one of them (its border points);
 *   - a cluster whose points (core and border, counting a border point for
 *     every cluster that reaches it) belong to fewer than min_users distinct
 *     users is dropped: its core points become noise, and its border points
 *     are reconsidered for the surviving clusters that also reach them;
 *   - every other point is noise (label -1).
 *
 * A border point reached by several surviving clusters is labelled with the
 * cluster of its nearest core point (ties: the core point with the lowest
 * index). So the labelling does not depend on processing order or threads.
 *
 * Cluster ids are 0..k-1, numbered in increasing order of each cluster's
 * lowest-index core point. The same input always gives the same output.
 */
#ifndef CVRE_DBSCAN_H
#define CVRE_DBSCAN_H

#include <stddef.h>
#include <stdint.h>

/* Most points per run: labels are int32 and FLANN's C API counts rows and
 * neighbours in int. A collision log holds far fewer points per object and
 * ECM version; 2^30 also keeps every internal index in a uint32. */
#ifndef DBSCAN_MAX_POINTS
#define DBSCAN_MAX_POINTS (1u << 30)
#endif

/* Most worker threads for the radius searches; more than the cores of any
 * machine the offline job runs on, and a bound on per-thread buffers. */
#ifndef DBSCAN_MAX_THREADS
#define DBSCAN_MAX_THREADS 64u
#endif

/* Largest |coordinate| accepted, in metres: far beyond any world, and small
 * enough that squared distances stay finite in float inside FLANN. */
#ifndef DBSCAN_MAX_COORD
#define DBSCAN_MAX_COORD 1.0e9
#endif

typedef struct dbscan_params {
    double eps;          /* neighbourhood radius, > 0, inclusive; 1e-15 < eps < 1e15 */
    uint32_t min_points; /* points within eps, itself included, to be core; >= 1 */
    uint32_t min_users;  /* distinct users a cluster needs; 0 and 1 disable the criterion */
    uint32_t threads;    /* worker threads; 0 = one per online CPU */
} dbscan_params;

/* One cluster, over the points labelled with its id. */
typedef struct dbscan_cluster {
    uint32_t points;   /* points labelled with this cluster (core and border) */
    uint32_t users;    /* distinct users among the core points and every border
                        * point the cluster reaches, even one labelled with a
                        * neighbouring cluster: the number compared with
                        * min_users, so always >= min_users */
    float centroid[3]; /* mean of the labelled points */
    float min[3];      /* bounding box of the labelled points */
    float max[3];
} dbscan_cluster;

typedef struct dbscan_result dbscan_result;

/*
 * Clusters n points. xyz holds 3n floats (x, y, z of point i at 3i). users
 * holds n user ids, or is NULL, meaning every point comes from a different
 * user (then min_users <= min_points never drops a cluster). labels_out
 * receives n labels: a cluster id in 0..k-1, or -1 for noise.
 *
 * If out is not NULL, *out receives the per-cluster figures and core flags
 * (the caller frees it with dbscan_result_free); on error *out is NULL.
 *
 * Returns 0, -EINVAL (NULL arrays with n > 0, n > DBSCAN_MAX_POINTS, eps not
 * in range or not finite, min_points < 1, a coordinate NaN, infinite or
 * beyond DBSCAN_MAX_COORD), -ENOMEM, or -EIO if FLANN reports an error.
 * labels_out is unspecified on error. n == 0 is valid and gives no clusters.
 *
 * Runs the radius searches on p->threads threads (the caller's included);
 * several runs may go on at once in different threads.
 *
 * Memory is taken through cvre_malloc and all of it is released on error,
 * except that FLANN allocates its index with C++ new: if that fails, the
 * process aborts (FLANN only catches its own exceptions).
 */
int dbscan_run(const float *xyz, const uint32_t *users, size_t n, const dbscan_params *p,
               int32_t *labels_out, dbscan_result **out);

void dbscan_result_free(dbscan_result *r);

/* Number of clusters k. */
size_t dbscan_result_count(const dbscan_result *r);
/* Cluster i (< k), or NULL if i is out of range. Valid until the result is freed. */
const dbscan_cluster *dbscan_result_cluster(const dbscan_result *r, size_t i);
/* 1 if point i was a core point (whether or not its cluster survived
 * min_users), 0 otherwise or if i is out of range. */
int dbscan_result_is_core(const dbscan_result *r, size_t i);
/* How many FLANN radius searches the run made (the grid settles most core
 * flags without one). For benchmarks. */
size_t dbscan_result_searches(const dbscan_result *r);

#endif
