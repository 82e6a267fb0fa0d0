/*
 * apply.h: one refinement round for one object, from the store to the store:
 * load its mesh and the version in force, refine (refine.h), judge the
 * refined map against the one in force (judge.h) from the collisions that
 * asked for it, and write the next version with its history (db/ecm.h),
 * which every running server then publishes, only if the judge found it
 * better; otherwise keep it as a rejected candidate with the judge's
 * figures. Shared by the offline job (cvre-cluster --apply) and the
 * server's online loop.
 */
#ifndef CVRE_ECM_APPLY_H
#define CVRE_ECM_APPLY_H

#include <stddef.h>
#include <stdint.h>

#include "db.h"
#include "judge.h"
#include "record.h"
#include "refine.h"

/* Collisions read as the judge's samples, newest first: the judge takes
 * JUDGE_SAMPLES_DEFAULT of them, evenly; a few times more leaves room for
 * those outside the clusters, and reads in some 10 ms. */
#define APPLY_SAMPLES_READ 16384u

/* What became of one object: written (version), rejected (candidate),
 * rejected before (candidate, judged_before: the same clusters made a
 * candidate that was turned down; nothing refined again), nothing to
 * gain (no_gain: the map in force meets fewer phantom blocks on the
 * judge's trials than any candidate would have to remove, so nothing was
 * refined; judge holds the old map's figures), or unchanged (the rest). */
typedef struct ecm_applied {
    uint32_t version;       /* the version written; 0: none */
    uint32_t candidate;     /* the rejected candidate stored (or found); 0: none */
    int judged_before;      /* 1: candidate was rejected earlier for the same clusters */
    int no_gain;            /* 1: not refined: judge_can_gain said no */
    uint32_t boxes_before, boxes_after;
    ecm_result stats;       /* counts and times; no boxes */
    judge_result judge;     /* the judge's figures; zero when it did not run */
    double store_ms;        /* of which the store's reads and its write, wall clock */
    double total_ms;        /* load, refine, judge, write, wall clock */
} ecm_applied;

/* A hash of the n clusters f (each one's box, extent and centroid), the
 * same whatever their order: equal clusters give equal evidence. */
int64_t ecm_evidence(const cluster_found *f, uint32_t n);

/* One line for people: the judge's figures and verdict ("judge: 120
 * samples, 14400 moves, phantom 900 -> 12, opened 0 -> 0, 35.2 ms"), into
 * buf (room for len bytes). */
void ecm_judge_line(const judge_result *j, char *buf, size_t len);

/* Why an object came out unchanged, for people: its clusters wanted no
 * space opened ("its clusters press on real geometry only"), or what they
 * wanted would take more boxes than the cap leaves (the problem boxes were
 * only tightened, and that changed nothing). Into buf (room for len). */
void ecm_unchanged_line(const ecm_applied *a, char *buf, size_t len);

/* Why an object with nothing to gain (no_gain) was not refined, for
 * people: "the judge's trials meet 2 phantom blocks on it, fewer than the
 * 4 a new map must remove". Into buf (room for len). */
void ecm_no_gain_line(const ecm_applied *a, char *buf, size_t len);

/*
 * Refines the object the n clusters f were found on (all of one object and
 * version, of run run_id; 0: none recorded) from the collisions of run's
 * time window (NULL: all). p's avatar is in metres; it is divided by the
 * object's scale. The judge's samples are the object's collisions with
 * that version in that window (the newest APPLY_SAMPLES_READ) that lie in
 * a cluster's extent, turned into the object's metric frame; the avatars
 * there are where users stood for the refinement too (refine.h, step 6).
 * Returns:
 *   0         done: out->version is the version written; or out->candidate
 *             the candidate the judge rejected (stored; not published), or
 *             the one it rejected earlier for the same clusters (then
 *             out->judged_before: nothing refined); or neither when the
 *             judge's trials on the map in force leave nothing a new map
 *             could gain (out->no_gain: nothing refined, nothing written),
 *             or when the refined boxes are the ones in force (unchanged:
 *             nothing written; a success, since there is nothing to do);
 *   -ESTALE   the object changed version or left meanwhile: nothing written;
 *   -EINVAL   refine.h refused the input (an object without triangles...),
 *             or could not run (out of memory), or the judge had nothing to
 *             judge by (no collisions left in the clusters), with the
 *             message in err;
 *   any other negative errno: the store failed (db/db.h), with the
 *             message in err.
 */
int ecm_apply(db *d, const ecm_params *p, const cluster_run *run, int64_t run_id, const cluster_found *f,
              uint32_t n, ecm_applied *out, char *err, size_t errlen);

/* What became of one object of a round: its n clusters f, ecm_apply's
 * result rc, what it filled in a, and its message in err when rc < 0.
 * Returns 0 to go on, non-zero to end the round there. */
typedef int ecm_round_fn(void *ctx, const cluster_found *f, uint32_t n, int rc, const ecm_applied *a,
                         const char *err);

/*
 * The end of a round, the same for the online loop (server/refiner.c) and
 * the offline job (cvre-cluster): records the run and its n clusters
 * (record.h; sets *run_id) and then, if apply, refines, judges and stores
 * each object they name (ecm_apply above; the clusters of one object are
 * consecutive in found, as cluster_find appends them), calling fn after
 * each. Returns 0; cluster_record's negative errno with the message in err
 * (nothing recorded, nothing refined); or the non-zero fn returned.
 */
int ecm_apply_round(db *d, const ecm_params *p, const cluster_run *run, const cluster_found *found, size_t n,
                    int apply, ecm_round_fn *fn, void *ctx, int64_t *run_id, char *err, size_t errlen);

#endif
