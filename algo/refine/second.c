#include "second.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "err.h"

/* Boxes of a capped candidate that held the judge's trials back this many
 * ticks or more become clusters of the second candidate (as refine.h's
 * HOT_MIN collisions make a box hot; a place counts by its ticks). */
#define SECOND_HOT_MIN 3u
/* Most places a second candidate goes by, those with the most ticks: step 8
 * tests joins and new boxes against each (JOIN_TRIES pairs), as against
 * the job's own samples, some hundreds to a few thousand. */
#define SECOND_PLACES_MAX 1024u
/* The share of the first's phantom blocks the second must remove, as a
 * fraction SECOND_GAIN_NUM / SECOND_GAIN_DEN (and JUDGE_GAIN_MIN blocks):
 * it is judged on the very trials that found its places, so a gain the
 * verdict would take from any candidate is no evidence here. The
 * scenario's staircase at seed 4: 16 -> 11 blocks on the trials, and users
 * met 9.58 and 7.08 phantoms per 1,000 moves on it in rounds 2 and 3,
 * against 3.33 and 2.92 on the first. */
#define SECOND_GAIN_NUM 1u
#define SECOND_GAIN_DEN 2u

/* Adds what refinement from did (cells and times) to to. */
static void add_work(ecm_result *to, const ecm_result *from)
{
    to->cells += from->cells;
    to->occupied += from->occupied;
    to->wanted += from->wanted;
    to->voxel_ms += from->voxel_ms;
    to->divide_ms += from->divide_ms;
}

/* Places by ticks, most first; equal ones in the trials' order. */
static int by_ticks(const void *x, const void *y)
{
    const judge_place *a = *(const judge_place *const *)x, *b = *(const judge_place *const *)y;
    if (a->ticks != b->ticks)
        return a->ticks < b->ticks ? 1 : -1;
    return a < b ? -1 : a > b;
}

/* The n places (at) as where users stood, each naming the box that held it
 * and weighing its ticks, then the job's own (p's), naming no box of the
 * candidate: no join may cover them. */
static void places_stood(const ecm_params *p, const judge_place *at, uint32_t n, ecm_stood *stood)
{
    for (uint32_t i = 0; i < n; i++) {
        memcpy(stood[i].box, at[i].box, sizeof stood[i].box);
        stood[i].hit = at[i].hit;
        stood[i].weight = at[i].ticks;
    }
    for (uint32_t i = 0; i < p->nstood; i++) {
        stood[n + i] = p->stood[i];
        stood[n + i].hit = UINT32_MAX;
    }
}

/* A held cluster for each of the nboxes boxes that held the n places'
 * trials back SECOND_HOT_MIN ticks or more: their contact points, weighted
 * by ticks. Returns how many (in cl, room for nboxes). */
static uint32_t places_clusters(const judge_place *at, uint32_t n, uint32_t nboxes, uint64_t *ticks, ecm_cluster *cl)
{
    for (uint32_t i = 0; i < n; i++)
        if (at[i].hit < nboxes)
            ticks[at[i].hit] += at[i].ticks;
    uint32_t ncl = 0;
    for (uint32_t b = 0; b < nboxes; b++) {
        if (ticks[b] < SECOND_HOT_MIN)
            continue;
        ecm_cluster *c = &cl[ncl++];
        *c = (ecm_cluster){.box = b, .weight = ticks[b] > UINT32_MAX ? UINT32_MAX : (uint32_t)ticks[b], .held = true};
        double sum[3] = {0, 0, 0};
        int seen = 0;
        for (uint32_t i = 0; i < n; i++) {
            if (at[i].hit != b)
                continue;
            for (int a = 0; a < 3; a++) {
                float v = at[i].point[a];
                c->min[a] = seen && c->min[a] < v ? c->min[a] : v;
                c->max[a] = seen && c->max[a] > v ? c->max[a] : v;
                sum[a] += (double)v * at[i].ticks;
            }
            seen = 1;
        }
        for (int a = 0; a < 3; a++)
            c->centroid[a] = (float)(sum[a] / (double)ticks[b]);
    }
    return ncl;
}

int ecm_second_candidate(const ecm_params *p, const trimesh *mesh, judge *jg, double walk_ms, ecm_result *r,
                         judge_result *j, ecm_second *out, char *err, size_t errlen)
{
    *out = (ecm_second){0};
    const judge_place *all;
    uint32_t n;
    judge_places(jg, &all, &n);
    if (!j->better || r->count < p->max_boxes || n == 0)
        return 0;
    const judge_place **by = cvre_malloc(n * sizeof *by);
    judge_place *at = cvre_malloc(n * sizeof *at);
    ecm_stood *stood = cvre_malloc(((size_t)n + p->nstood) * sizeof *stood);
    uint64_t *ticks = cvre_calloc(r->count, sizeof *ticks);
    ecm_cluster *cl = cvre_calloc(r->count, sizeof *cl);
    ecm_result r2 = {0};
    int rc = -ENOMEM;
    char why[256] = "out of memory";
    if (!by || !at || !stood || !ticks || !cl)
        goto done;
    for (uint32_t i = 0; i < n; i++)
        by[i] = &all[i];
    if (n > SECOND_PLACES_MAX) {
        qsort(by, n, sizeof *by, by_ticks);
        n = SECOND_PLACES_MAX;
    }
    for (uint32_t i = 0; i < n; i++)
        at[i] = *by[i];
    places_stood(p, at, n, stood);
    uint32_t ncl = places_clusters(at, n, r->count, ticks, cl);
    rc = 0;
    if (!ncl)
        goto done;
    ecm_params sp = *p;
    sp.stood = stood;
    sp.nstood = n + p->nstood;
    judge_result j2;
    rc = ecm_move_boxes(&sp, mesh, (const float(*)[6])r->boxes, r->count, cl, ncl, &r2, why, sizeof why);
    if (rc == 1 && (rc = judge_new(jg, (const float(*)[6])r2.boxes, r2.count, &j2, why, sizeof why)) == 0)
        rc = 1;
    if (rc < 0)
        goto done;
    /* Whichever is kept carries both candidates' cells and times. */
    if (rc == 1 && judge_gain(j->phantom_new, j2.phantom_new, SECOND_GAIN_NUM, SECOND_GAIN_DEN) &&
        j2.opened_new <= j->opened_new) {
        *out = (ecm_second){.kept = 1, .places = n, .first_count = r->count, .first_phantom = j->phantom_new};
        add_work(&r2, r);
        ecm_result_free(r);
        *r = r2;
        r2 = (ecm_result){0};
        *j = j2;
    } else {
        add_work(r, &r2);
    }
    if (rc == 1)
        j->ms = j2.ms + walk_ms; /* the old map's walks and both maps' */
    rc = 0;
done:
    if (rc < 0)
        cvre_fail(err, errlen, rc, "a second candidate: %s", why);
    ecm_result_free(&r2);
    free(by);
    free(at);
    free(stood);
    free(ticks);
    free(cl);
    return rc;
}
