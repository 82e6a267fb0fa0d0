/*
 * second.h: a second candidate from the judge's own trials. Pure module: no
 * I/O, no global state; the same input gives the same output (times aside).
 *
 * A job's first candidate (r, judged in j by an open judgement jg) that is
 * better and has the boxes of the cap: the judge's trials on it tell where
 * it still stops users where nothing real is (judge_places), places the
 * clusters never showed (a staircase's first map is made from users
 * stopped at its one box's faces; its trials walk on to the treads
 * behind). Step 8 alone (refine.h, ecm_move_boxes) moves boxes there: each
 * place is an avatar where a user stood, weighing its ticks (the
 * SECOND_PLACES_MAX with the most), each box that held trials back
 * SECOND_HOT_MIN ticks or more a held cluster of their contact points, and
 * where the job's users stood (p->stood) stays out of every join. The
 * second replaces the first in *r, its figures in *j, when the same trials
 * meet at least half fewer phantom blocks on it (SECOND_GAIN_NUM /
 * SECOND_GAIN_DEN, and JUDGE_GAIN_MIN) and it opens no more
 * (server/pipeline/apply.c publishes it as any better map).
 *
 * Whichever is kept carries the times and cells of both refinements, and
 * the judge's time of all walks (walk_ms: those of the first). Returns 0
 * with *out saying what it did (nothing, when the first is not better, not
 * at the cap or met no phantom block), or a negative errno with a one-line
 * reason in err: -ENOMEM, or ecm_move_boxes's and judge_new's errors; *r
 * and *j are then the first's.
 */
#ifndef CVRE_ECM_SECOND_H
#define CVRE_ECM_SECOND_H

#include <stdint.h>

#include "judge.h"
#include "refine.h"

/* What ecm_second_candidate did. */
typedef struct ecm_second {
    int kept;               /* 1: the second replaced the first */
    uint32_t places;        /* the places it went by, when kept */
    uint32_t first_count;   /* the first's boxes, */
    uint64_t first_phantom; /* and its phantom blocks on the trials, when kept */
} ecm_second;

int ecm_second_candidate(const ecm_params *lp, const trimesh *mesh, judge *jg, double walk_ms, ecm_result *r,
                         judge_result *j, ecm_second *out, char *err, size_t errlen);

#endif
