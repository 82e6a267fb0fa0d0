/*
 * trimesh.h: an object's triangles with each one's bounding box and the
 * object's, worked out once, with the check that every coordinate is
 * finite. The refinement (its tightening) and its judge (its exact contact
 * test) both ask "which triangles may touch this box?" of the same object
 * in one round: on a 400,000-triangle city block, each working out the
 * boxes and checking the coordinates again cost a tenth of the round.
 * Pure module: no I/O, no global state.
 */
#ifndef CVRE_TRIMESH_H
#define CVRE_TRIMESH_H

#include <stddef.h>
#include <stdint.h>

typedef struct trimesh {
    const float *tris; /* ntris triangles, 9 floats each: the caller's, not copied */
    uint32_t ntris;
    float (*box)[6];   /* triangle t's min x y z, max x y z */
    float min[3], max[3];
} trimesh;

/* Fills m over the caller's tris (kept until trimesh_free). Returns 0, or
 * with m zeroed and a one-line reason in err (room for errlen bytes):
 * -EINVAL for no triangles or a coordinate that is not finite (naming the
 * triangle), -ENOMEM. */
int trimesh_init(trimesh *m, const float *tris, uint32_t ntris, char *err, size_t errlen);
/* Frees m's table and zeroes m; a zeroed mesh may be freed again. */
void trimesh_free(trimesh *m);
/* Whether triangle t (9 floats) with bounding box b overlaps the box
 * [lo, hi]: the boxes first, then exactly (voxel.h). */
int trimesh_tri_overlaps(const float *t, const float b[6], const double lo[3], const double hi[3]);

#endif
