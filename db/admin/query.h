/*
 * query.h: the questions cvre-admin asks the store. Each function runs its
 * statements in one read transaction (one consistent snapshot, while the
 * server goes on writing in WAL mode) and prints the result through out.h.
 *
 * Every SQL text is assembled from constant fragments only; user values
 * (ids, names, times, regions, limits) are always bound as parameters.
 *
 * Results, in every file of cvre-admin (query, map, user, moderate,
 * maintain): 0, or a negative errno with a message in err (cvre_fail):
 *   -ENOENT  the object, version, user, account or session asked about does
 *            not exist (or the name to unban is not banned);
 *   -EPERM   refused, nothing written: a rollback with nothing to do or
 *            that may not be done, a name taken, the world account, a
 *            backup file that exists;
 *   -EINVAL  input that is not an argument but is as bad: an empty, too
 *            long or mistyped password;
 *   -EIO     the database failed, or the output or the picture could not be
 *            written (any other negative errno is taken as this).
 * main.c's exit_status is the one place that turns them into exit codes.
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
    int64_t limit;    /* most rows; 0: no limit. When more rows match than
                       * are printed, a line on stderr says so (stdout
                       * holds the rows alone, in every format). */
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
 * snapshot: -ENOENT (no such object or version), -EPERM (the
 * object was removed, or the version in force is k or has k's boxes), or
 * 0 with the version in force in *in_force. Prints nothing. */
int query_rollback_check(sqlite3 *s, int64_t id, uint32_t k, uint32_t *in_force, char *err, size_t errlen);
/* Writes version k's boxes as a new version of object id whose parent is
 * in_force (reason "rollback", restores k) and prints that version.
 * -EPERM if in_force is no longer in force (another writer came
 * first: nothing written). */
int query_rollback(db *d, int64_t id, uint32_t k, uint32_t in_force, int format, char *err, size_t errlen);
/* Counts of everything, and the time span the store covers. */
int query_totals(sqlite3 *s, int format, char *err, size_t errlen);
/* The clusters of the latest cvre-cluster run (f: object, limit). */
int query_clusters(sqlite3 *s, const query_filter *f, int format, char *err, size_t errlen);
/* Sessions connected at some moment in [since, until), newest first. */
int query_sessions(sqlite3 *s, const query_filter *f, int format, char *err, size_t errlen);

#endif
