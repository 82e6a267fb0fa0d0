/*
 * ecm.h: collision map (ECM) versions in the store, their history, and the
 * change feed a running server follows.
 *
 * Every change of an object's ECM (a refinement, a rollback) is a new version
 * N+1 written in one transaction together with: its boxes, why it was made
 * (the cluster run and clusters that caused it, or the version a rollback
 * restores), objects.ecm_version = N+1, and one row in the change feed
 * (ecm_events). Any process may write versions (the server's online loop,
 * `cvre-cluster --apply`, `cvre-admin rollback`); the server reads the feed
 * and publishes each change to its clients. Versions only grow: a rollback to
 * version K writes a new version whose boxes are K's.
 *
 * Functions return 0, or a negative errno with the message in db_error()
 * (db.h). A failed call leaves no transaction of its own open, so the connection
 * stays usable. Every function here prepares its statements per call (none
 * is on a hot path: a poll of the feed costs one prepare, tens of us).
 */
#ifndef CVRE_ECM_H
#define CVRE_ECM_H

#include <stdint.h>

#include "db.h"

/* Most boxes in one version: what one OBJECT_INFO can carry
 * (PROTO_OBJECT_BOXES_MAX in protocol/proto.h, which db/ does not include;
 * tests/unit/test_ecm.c asserts that they are equal). A version the wire
 * cannot carry would never reach the clients. */
#ifndef DB_ECM_BOXES_MAX
#define DB_ECM_BOXES_MAX 1024u
#endif
/* Longest reason and detail texts, in bytes: a word, and a line of
 * parameters and counts; anything longer is a caller's mistake. */
#ifndef DB_ECM_REASON_MAX
#define DB_ECM_REASON_MAX 32u
#endif
#ifndef DB_ECM_DETAIL_MAX
#define DB_ECM_DETAIL_MAX 4096u
#endif
_Static_assert(DB_ECM_BOXES_MAX >= 1u && DB_ECM_BOXES_MAX <= 65535u, "box counts travel as u16 on the wire");

typedef struct db_ecm_change {
    int64_t object_id;
    uint32_t parent_version;  /* the version this replaces: must be in force */
    const char *reason;       /* "refine" or "rollback": 1..DB_ECM_REASON_MAX bytes */
    int64_t run_id;           /* cluster_runs.id that caused it; 0: none */
    uint32_t ncluster_ids;    /* clusters of that run it answers (needs run_id) */
    const uint32_t *cluster_ids; /* clusters.cluster_id of this object in run_id */
    uint32_t restores;        /* for a rollback: the version copied; else 0 */
    const char *detail;       /* free text (parameters, counts); may be NULL */
    uint32_t box_count;       /* 1..DB_ECM_BOXES_MAX */
    const float (*boxes)[6];  /* local: min x y z, max x y z; finite, min <= max */
} db_ecm_change;

/* Writes a new version of c->object_id in one BEGIN IMMEDIATE transaction:
 * the version (numbered max(version) + 1 over the object's versions, so
 * numbers never repeat even after a rollback; that is parent_version + 1
 * unless a rollback went before), its boxes in the order given, its ties to
 * (run_id, cluster_id) (duplicates count once), objects.ecm_version, and one
 * ecm_events row, all stamped `at`. Sets *version to the new number.
 *
 * Returns 0, or a negative errno with nothing written: -ESTALE when the
 * object was removed or its version in force is not c->parent_version;
 * -EINVAL on invalid input (checked before anything is read: counts, NaN or
 * infinite coordinates, min > max, empty or long texts, cluster ids without
 * a run) or inside a transaction (it needs one of its own); -ENOENT when
 * the object, the run, one of the clusters or the restored version does
 * not exist; -EOVERFLOW when the object has no version number left; the
 * database's error otherwise (-EBUSY: a lock held beyond the busy
 * timeout). */
int db_ecm_write(db *d, const db_ecm_change *c, double at, uint32_t *version);

/* A refinement the judge found no better than the version in force
 * (algo/refine/judge.h): kept, never published (migration 0008). */
typedef struct db_ecm_candidate {
    int64_t object_id;
    uint32_t version;         /* the version in force it was judged against */
    int64_t run_id;           /* cluster_runs.id whose clusters asked for it; 0: none */
    uint32_t ncluster_ids;    /* those clusters (needs run_id) */
    const uint32_t *cluster_ids;
    int64_t evidence;         /* the caller's hash of the clusters: see db_ecm_rejected */
    const char *detail;       /* free text; may be NULL */
    uint32_t box_count;       /* 1..DB_ECM_BOXES_MAX */
    const float (*boxes)[6];  /* local, finite, min <= max */
    uint64_t samples, moves, phantom_old, phantom_new, opened_old, opened_new; /* the judge's figures */
} db_ecm_candidate;

/* Stores c as the object's next candidate (numbered 1.. within the object)
 * with its boxes and cluster ties in one BEGIN IMMEDIATE transaction,
 * stamped `at`; sets *candidate. Returns 0, or a negative errno with
 * nothing written: -EINVAL on invalid input (as db_ecm_write) or inside a
 * transaction; -ESTALE when the object was removed or c->version is no
 * longer in force (the candidate answers nothing then); -ENOENT when the
 * object does not exist; a run or cluster that does not exist is a
 * foreign key the store refuses (-EINVAL); the database's error otherwise. */
int db_ecm_reject(db *d, const db_ecm_candidate *c, double at, uint32_t *candidate);

/* Whether a candidate of object_id judged against version was made from
 * clusters with this evidence hash: 1 and its number in *candidate, 0 if
 * none (a refinement of the same clusters would be the same candidate
 * again), or the database's negative errno. */
int db_ecm_rejected(db *d, int64_t object_id, uint32_t version, int64_t evidence, uint32_t *candidate);

/* The boxes of one version: *boxes (malloc'd, the caller frees) gets *count
 * boxes in box_index order. -ENOENT if there is no such version, -EIO if
 * the stored boxes do not match the version's box_count, -ENOMEM, or the
 * database's error; then *boxes is NULL and *count 0. */
int db_ecm_boxes(db *d, int64_t object_id, uint32_t version, float (**boxes)[6], uint32_t *count);

/* The change feed: calls fn for each event with id > after, in id order, and
 * sets *last to the id of the last event fn accepted (returned 0 for);
 * *last is unchanged when there was none. If fn returns non-zero, stops and
 * returns that value; that event does not count as accepted, so the next
 * call from *last offers it again. Events are read in batches before fn is
 * called, so fn may use d (load the object, write a version). A negative
 * errno on a database error (events accepted before it stay in *last). */
typedef int db_ecm_event_fn(void *ctx, int64_t event_id, int64_t object_id, uint32_t version);
int db_ecm_events(db *d, int64_t after, db_ecm_event_fn *fn, void *ctx, int64_t *last);
/* The id of the newest event, 0 if none (where a starting server begins). */
int db_ecm_events_head(db *d, int64_t *last);

/* An object's mesh (9 floats a triangle, local) and the version in force
 * with its boxes, read in one snapshot; all malloc'd, the caller frees with
 * db_ecm_object_free. -ENOENT if the object does not exist or was removed,
 * -EIO if the mesh blob's size does not match tri_count or the boxes do not
 * match their version, -ENOMEM, or the database's error; then *out is
 * zeroed (freeing it is harmless). */
typedef struct db_ecm_object {
    int64_t id;
    uint32_t version;
    uint32_t tri_count;
    float *tris;
    uint32_t box_count;
    float (*boxes)[6];
} db_ecm_object;
int db_ecm_object_load(db *d, int64_t object_id, db_ecm_object *out);
/* Frees what db_ecm_object_load allocated and zeroes *o; o may be NULL. */
void db_ecm_object_free(db_ecm_object *o);

#endif
