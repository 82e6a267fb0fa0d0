/*
 * tribins.h: triangles by bin, asked "which triangles may touch this box?".
 * A uniform grid of per_axis^3 bins spans a region; each bin lists the
 * triangles whose bounding box (grown by a margin) meets it. Built in two
 * passes over the boxes (each box's bins found once): count per bin, then
 * fill one list (bin k holds list[start[k] .. start[k + 1])). Used by the
 * refinement (tightening boxes to the triangles inside them) and by its
 * judge (the exact contact test).
 * Pure module: no I/O, no global state.
 *
 * Conservative: bins are closed (a box on the face between two bins meets
 * both, one on the region's max face meets the last bin) and the same
 * rounding places triangles and queries, so the candidates of a box hold
 * every triangle whose grown bounding box meets it, plus some that do not:
 * the caller tests each. Triangles whose grown box misses the region are
 * left out, so queries should stay within the region grown by the margin.
 *
 * A triangle spanning more than spread_max bins (0: no limit) is kept once,
 * in a list every query visits: the bins then hold at most spread_max
 * entries a triangle. A query visits each candidate once (a stamp per
 * triangle), so one index serves one thread at a time.
 */
#ifndef CVRE_TRIBINS_H
#define CVRE_TRIBINS_H

#include <stdint.h>

/* Most bins per axis: 256^3 offsets are 64 MiB. */
#define TRIBINS_PER_AXIS_MAX 256u
/* No more candidates. */
#define TRIBINS_END UINT32_MAX

typedef struct tribins {
    uint32_t per_axis;
    double min[3], max[3], inv[3]; /* the region; bins per unit length, 0 if flat */
    uint32_t *start;               /* per_axis^3 + 1 offsets into list */
    uint32_t *list;
    uint32_t *big; /* triangles spanning more than spread_max bins */
    uint32_t nbig;
    uint32_t ntris;
    uint32_t *seen; /* per triangle: the last query that visited it */
    uint32_t query;
} tribins;

/* One query's place: the big list first, then bin by bin. */
typedef struct tribins_iter {
    tribins *b;
    const uint32_t *src; /* the list being read: big or list */
    uint32_t e, end;     /* next entry of src, and its end */
    uint32_t lo[3], hi[3], x, y, z;
    int more; /* bins left: x, y, z is the next one */
} tribins_iter;

/* Builds b over region ([min x y z, max x y z], min <= max) with per_axis
 * (1 to TRIBINS_PER_AXIS_MAX) bins per axis from the ntris boxes (min x y z, max x y z),
 * each grown by grow (>= 0). Returns 0, -EINVAL for a bad per_axis, or
 * -ENOMEM; b is left ready for tribins_free either way. */
int tribins_build(tribins *b, const double region[6], uint32_t per_axis, const float (*box)[6], uint32_t ntris,
                  double grow, uint64_t spread_max);
/* Frees b and zeroes it; a zeroed index may be freed again. */
void tribins_free(tribins *b);

/* Starts a query of the box [lo, hi]; tribins_next then yields its
 * candidates. */
void tribins_query(tribins *b, const double lo[3], const double hi[3], tribins_iter *it);

/* The next candidate of it's query, each triangle once, or TRIBINS_END.
 * Inline: the refinement's tightening calls it once per candidate. */
static inline uint32_t tribins_next(tribins_iter *it)
{
    tribins *b = it->b;
    for (;;) {
        while (it->e < it->end) {
            uint32_t t = it->src[it->e++];
            if (b->seen[t] != b->query) {
                b->seen[t] = b->query;
                return t;
            }
        }
        if (!it->more)
            return TRIBINS_END;
        uint32_t k = it->x + b->per_axis * (it->y + b->per_axis * it->z);
        it->src = b->list;
        it->e = b->start[k];
        it->end = b->start[k + 1];
        if (++it->x > it->hi[0]) {
            it->x = it->lo[0];
            if (++it->y > it->hi[1]) {
                it->y = it->lo[1];
                it->more = ++it->z <= it->hi[2];
            }
        }
    }
}

#endif
