#include "find.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"

void object_points_add(object_points *p, const float xyz[3], uint32_t user)
{
    if (p->n == p->cap) {
        p->cap = p->cap ? p->cap * 2 : 1024;
        p->xyz = cvre_xrealloc(p->xyz, (size_t)p->cap * 3 * sizeof *p->xyz);
        p->users = cvre_xrealloc(p->users, p->cap * sizeof *p->users);
    }
    memcpy(p->xyz + 3 * (size_t)p->n, xyz, 3 * sizeof *xyz);
    p->users[p->n++] = user;
}

void object_points_free(object_points *p)
{
    free(p->xyz);
    free(p->users);
    *p = (object_points){0};
}

/* The box among boxes[0..n) that contains p, or else the nearest one. */
static uint32_t problem_box(const float (*boxes)[6], uint32_t n, const float p[3])
{
    uint32_t best = 0;
    double best_d = INFINITY;
    for (uint32_t i = 0; i < n; i++) {
        double d = 0;
        for (int k = 0; k < 3; k++) {
            double lo = boxes[i][k], hi = boxes[i][3 + k];
            double e = p[k] < lo ? lo - p[k] : p[k] > hi ? p[k] - hi : 0;
            d += e * e;
        }
        if (d < best_d) {
            best_d = d;
            best = i;
        }
    }
    return best;
}

int cluster_find(const object_points *p, const dbscan_params *prm, int64_t object_id, uint32_t version,
                 const float (*boxes)[6], uint32_t nboxes, cluster_found **found, size_t *nfound)
{
    int32_t *labels = cvre_xmalloc((p->n ? p->n : 1) * sizeof *labels);
    dbscan_result *res = NULL;
    int rc = dbscan_run(p->xyz, p->users, p->n, prm, labels, &res);
    free(labels);
    if (rc < 0)
        return rc;
    size_t k = dbscan_result_count(res);
    *found = cvre_xrealloc(*found, (*nfound + k + 1) * sizeof **found);
    for (size_t i = 0; i < k; i++) {
        cluster_found *f = &(*found)[(*nfound)++];
        *f = (cluster_found){.object_id = object_id, .ecm_version = version, .cluster_id = (uint32_t)i,
                             .c = *dbscan_result_cluster(res, i)};
        f->box = problem_box(boxes, nboxes, f->c.centroid);
    }
    dbscan_result_free(res);
    return (int)k;
}
