/*
 * apply.h: one refinement round for one object, from the store to the store:
 * load its mesh and the version in force, refine (refine.h) and write the
 * next version with its history (db/ecm.h), which every running server then
 * publishes. Shared by the offline job (cvre-cluster --apply) and the
 * server's online loop.
 */
#ifndef CVRE_ECM_APPLY_H
#define CVRE_ECM_APPLY_H

#include <stddef.h>
#include <stdint.h>

#include "db.h"
#include "record.h"
#include "refine.h"

/* What became of one object. */
typedef struct ecm_applied {
    uint32_t version;       /* the version written; 0: none (unchanged, or a failure) */
    uint32_t boxes_before, boxes_after;
    ecm_result stats;       /* counts and times; no boxes */
    double total_ms;        /* load, refine, write */
} ecm_applied;

/*
 * Refines the object the n clusters f were found on (all of one object and
 * version, of run run_id; 0: none recorded). p's avatar is in metres; it is
 * divided by the object's scale. Returns:
 *   0         done: out->version is the version written, or 0 when the
 *             refined boxes are the ones in force (unchanged: nothing
 *             written; a success, since there is nothing to do);
 *   -ESTALE   the object changed version or left meanwhile: nothing written;
 *   -EINVAL   refine.h refused the input (an object without triangles...),
 *             or could not run (out of memory), with the message in err;
 *   any other negative errno: the store failed (db/db.h), with the
 *             message in err.
 */
int ecm_apply(db *d, const ecm_params *p, int64_t run_id, const cluster_found *f, uint32_t n, ecm_applied *out,
              char *err, size_t errlen);

#endif
