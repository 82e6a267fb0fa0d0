/*
 * query.h: the questions cvre-admin asks the store. Each function runs its
 * statements in one read transaction (one consistent snapshot, while the
 * server goes on writing in WAL mode) and prints the result through out.h.
 *
 * Every SQL text is assembled from constant fragments only; user values
 * (ids, names, times, regions, limits) are always bound as parameters.
 *
 * Return value: QUERY_OK; QUERY_NOT_FOUND when the object or user asked
 * about does not exist; QUERY_ERROR when the database failed or the output
 * could not be written. Both failures leave a message in err.
 */
#ifndef CVRE_ADMIN_QUERY_H
#define CVRE_ADMIN_QUERY_H

#include <sqlite3.h>
#include <stddef.h>
#include <stdint.h>

enum { QUERY_OK = 0, QUERY_NOT_FOUND = 1, QUERY_ERROR = -1 };

/* Filters; a subcommand uses the ones that make sense for it. */
typedef struct query_filter {
    int has_object;
    int64_t object;
    const char *user; /* display name; NULL: everyone */
    int has_since, has_until;
    double since, until; /* Unix seconds: since <= t < until */
    int has_region;
    double region[6]; /* x0, y0, z0, x1, y1, z1 with x0 <= x1 and so on; closed box */
    int64_t limit;    /* most rows; 0: no limit */
} query_filter;

/* Collisions matching f, newest first. */
int query_collisions(sqlite3 *s, const query_filter *f, int format, char *err, size_t errlen);
/* Objects by collision count within [since, until), most first. */
int query_top_objects(sqlite3 *s, const query_filter *f, int format, char *err, size_t errlen);
/* One object: placement, geometry, collision map and collision summary. */
int query_object(sqlite3 *s, int64_t id, int format, char *err, size_t errlen);
/* The ECM versions of one object, oldest first. */
int query_versions(sqlite3 *s, int64_t id, int format, char *err, size_t errlen);
/* Counts of everything, and the time span the store covers. */
int query_totals(sqlite3 *s, int format, char *err, size_t errlen);
/* The clusters of the latest cvre-cluster run (f: object, limit). */
int query_clusters(sqlite3 *s, const query_filter *f, int format, char *err, size_t errlen);
/* Sessions connected at some moment in [since, until), newest first. */
int query_sessions(sqlite3 *s, const query_filter *f, int format, char *err, size_t errlen);

#endif
