#include "trimesh.h"

#include <errno.h>
#include <math.h>
#include <string.h>

#include "err.h"
#include "voxel.h"

/* Inline: fminf and fmaxf are library calls on baseline x86-64, and every
 * value here is finite. */
static inline float fmin2(float a, float b) { return a < b ? a : b; }
static inline float fmax2(float a, float b) { return a > b ? a : b; }

/* Triangles checked, then boxed, at a time: the second pass finds them in
 * the cache (one pass over the city block's 14 MB instead of two). */
#define TRIMESH_CHUNK 1024u

int trimesh_init(trimesh *m, const float *tris, uint32_t ntris, char *err, size_t errlen)
{
    memset(m, 0, sizeof *m);
    if (!tris || ntris == 0)
        return cvre_fail(err, errlen, -EINVAL, "the object has no triangles");
    /* In huge pages where the system has them, like the refinement's
     * tables: 9.6 MB for the city block, faulted in page by page otherwise. */
    float(*box)[6] = voxel_table_alloc((size_t)ntris * sizeof *box);
    if (!box)
        return cvre_fail(err, errlen, -ENOMEM, "out of memory");
    float lo[3] = {tris[0], tris[1], tris[2]}, hi[3] = {tris[0], tris[1], tris[2]};
    for (uint32_t t0 = 0; t0 < ntris; t0 += TRIMESH_CHUNK) {
        uint32_t t1 = ntris - t0 > TRIMESH_CHUNK ? t0 + TRIMESH_CHUNK : ntris;
        /* voxel_finite: a pass of bit tests, several times faster than a
         * chain of float operations per vertex. */
        if (!voxel_finite(tris + 9 * (size_t)t0, 9 * (size_t)(t1 - t0))) {
            voxel_table_free(box);
            for (size_t i = 9 * (size_t)t0;; i++) /* which one */
                if (!isfinite(tris[i]))
                    return cvre_fail(err, errlen, -EINVAL, "triangle %zu: a coordinate is not finite", i / 9);
        }
        for (uint32_t t = t0; t < t1; t++) {
            const float *v = tris + 9 * (size_t)t;
            for (int a = 0; a < 3; a++) {
                box[t][a] = fmin2(fmin2(v[a], v[3 + a]), v[6 + a]);
                box[t][3 + a] = fmax2(fmax2(v[a], v[3 + a]), v[6 + a]);
                lo[a] = fmin2(lo[a], box[t][a]);
                hi[a] = fmax2(hi[a], box[t][3 + a]);
            }
        }
    }
    *m = (trimesh){.tris = tris, .ntris = ntris, .box = box};
    memcpy(m->min, lo, sizeof lo);
    memcpy(m->max, hi, sizeof hi);
    return 0;
}

void trimesh_free(trimesh *m)
{
    voxel_table_free(m->box);
    memset(m, 0, sizeof *m);
}

int trimesh_tri_overlaps(const float *t, const float b[6], const double lo[3], const double hi[3])
{
    if (b[0] > hi[0] || b[3] < lo[0] || b[1] > hi[1] || b[4] < lo[1] || b[2] > hi[2] || b[5] < lo[2])
        return 0;
    double v[9];
    for (int k = 0; k < 9; k++)
        v[k] = t[k];
    return voxel_tri_box_overlap(v, lo, hi);
}
