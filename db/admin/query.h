/*
 * query.h: the questions cvre-admin asks the store. Each function runs its
 * statements in one read transaction (one consistent snapshot, while the
 * server goes on writing in WAL mode) and prints the result through out.h.
 *
 * Every SQL text is assembled from constant fragments only; user values
 * (ids, names, times, regions, limits) are always bound as parameters.
 *
 * Return value: QUERY_OK; QUERY_NOT_FOUND when the object, version or user
 * asked about does not exist; QUERY_REFUSED when a rollback has nothing to
 * do or may not be done; QUERY_ERROR when the database failed or the output
 * could not be written. Every failure leaves a message in err.
 *
 * Only query_rollback writes, through db_ecm_write (db/ecm.h) on a handle
 * the caller opened read-write for it.
 */
#ifndef CVRE_ADMIN_QUERY_H
#define CVRE_ADMIN_QUERY_H

#include <sqlite3.h>
#include <stddef.h>
#include <stdint.h>

#include "db.h"

enum { QUERY_OK = 0, QUERY_NOT_FOUND = 1, QUERY_REFUSED = 2, QUERY_ERROR = -1 };
/* user.c's answer for input that is not an argument: an empty, too long or
 * mistyped password (cvre-admin's bad-arguments exit status). */
enum { QUERY_USAGE = 3 };

/* Writes the message into err (errlen bytes) and returns code: how query.c
 * and map.c fail. */
int query_fail(char *err, size_t errlen, int code, const char *fmt, ...) __attribute__((format(printf, 4, 5)));

/* Prints the rows of the prepared statement st as cols (out.h; vertical:
 * enum out_shape) in format, then finalizes st. */
struct out_column;
int query_print(sqlite3 *s, sqlite3_stmt *st, const struct out_column *cols, int ncols, int vertical, int format,
                char *err, size_t errlen);

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
/* The ECM versions of one object, oldest first, with their history: parent,
 * cause (run and clusters), the version a rollback restores, detail. */
int query_versions(sqlite3 *s, int64_t id, int format, char *err, size_t errlen);
/* What changed from version a to version b of one object: a summary, then
 * its boxes only in a, only in b, in both (the six coordinates equal; a box
 * that occurs twice must occur twice in the other version to be in both). */
int query_diff(sqlite3 *s, int64_t id, uint32_t a, uint32_t b, int format, char *err, size_t errlen);
/* Whether object id can be rolled back to version k, on a read-only
 * snapshot: QUERY_NOT_FOUND (no such object or version), QUERY_REFUSED (the
 * object was removed, or the version in force is k or has k's boxes), or
 * QUERY_OK with the version in force in *in_force. Prints nothing. */
int query_rollback_check(sqlite3 *s, int64_t id, uint32_t k, uint32_t *in_force, char *err, size_t errlen);
/* Writes version k's boxes as a new version of object id whose parent is
 * in_force (reason "rollback", restores k) and prints that version.
 * QUERY_REFUSED if in_force is no longer in force (another writer came
 * first: nothing written). */
int query_rollback(db *d, int64_t id, uint32_t k, uint32_t in_force, int format, char *err, size_t errlen);
/* Counts of everything, and the time span the store covers. */
int query_totals(sqlite3 *s, int format, char *err, size_t errlen);
/* The clusters of the latest cvre-cluster run (f: object, limit). */
int query_clusters(sqlite3 *s, const query_filter *f, int format, char *err, size_t errlen);
/* Sessions connected at some moment in [since, until), newest first. */
int query_sessions(sqlite3 *s, const query_filter *f, int format, char *err, size_t errlen);

#endif
