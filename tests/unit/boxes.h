/* boxes.h: boxes in the refinement's unit tests (test_refine.c,
 * test_second.c): a solid box's surface as triangles, and whether a map's
 * boxes block a place. */
#ifndef CVRE_TEST_BOXES_H
#define CVRE_TEST_BOXES_H

#include <stddef.h>
#include <stdint.h>

/* The 12 triangles of the surface of the box [lo, hi], into t[108]. */
static inline void box_surface(const float lo[3], const float hi[3], float *t)
{
    size_t k = 0;
    for (int a = 0; a < 3; a++)
        for (int side = 0; side < 2; side++) {
            int u = (a + 1) % 3, w = (a + 2) % 3;
            static const int corner[6][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 0}, {1, 1}, {0, 1}};
            for (int c = 0; c < 6; c++) {
                float *v = t + 3 * k++;
                v[a] = side ? hi[a] : lo[a];
                v[u] = corner[c][0] ? hi[u] : lo[u];
                v[w] = corner[c][1] ? hi[w] : lo[w];
            }
        }
}

/* Whether the box [min, max] overlaps the interior of any of the n boxes. */
static inline int blocked(const float (*boxes)[6], uint32_t n, const float min[3], const float max[3])
{
    for (uint32_t b = 0; b < n; b++) {
        int o = 1;
        for (int a = 0; a < 3; a++)
            o &= min[a] < boxes[b][3 + a] && max[a] > boxes[b][a];
        if (o)
            return 1;
    }
    return 0;
}

#endif
