#include "tribins.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"

/* The bins [blo, bhi] of the interval [lo, hi] on axis a; 0 if it misses
 * the region. */
static int bin_range(const tribins *b, int a, double lo, double hi, uint32_t *blo, uint32_t *bhi)
{
    if (hi < b->min[a] || lo > b->max[a])
        return 0;
    double l = (lo - b->min[a]) * b->inv[a], h = (hi - b->min[a]) * b->inv[a];
    uint32_t last = b->per_axis - 1;
    /* Clamped both ways: a face on the region's max side is in the last bin.
     * The cast is floor here (no call: the build does this 6 times a
     * triangle). */
    *blo = l < 0 ? 0 : l > last ? last : (uint32_t)l;
    *bhi = h < 0 ? 0 : h > last ? last : (uint32_t)h;
    return 1;
}

/* The bins of box i grown by grow; their count, 0 if none. */
static uint64_t box_bins(const tribins *b, const float box[6], double grow, uint32_t lo[3], uint32_t hi[3])
{
    uint64_t count = 1;
    for (int a = 0; a < 3; a++) {
        if (!bin_range(b, a, (double)box[a] - grow, (double)box[3 + a] + grow, &lo[a], &hi[a]))
            return 0;
        count *= hi[a] - lo[a] + 1;
    }
    return count;
}

int tribins_build(tribins *b, const double region[6], uint32_t per_axis, const float (*box)[6], uint32_t ntris,
                  double grow, uint64_t spread_max)
{
    memset(b, 0, sizeof *b);
    if (per_axis < 1 || per_axis > TRIBINS_PER_AXIS_MAX)
        return -EINVAL;
    b->per_axis = per_axis;
    b->ntris = ntris;
    for (int a = 0; a < 3; a++) {
        double ext = region[3 + a] - region[a];
        b->min[a] = region[a];
        b->max[a] = region[3 + a];
        b->inv[a] = ext > 0 ? per_axis / ext : 0;
    }
    const uint32_t nb = per_axis * per_axis * per_axis;
    b->start = cvre_calloc(nb + 1, sizeof *b->start);
    b->seen = cvre_calloc(ntris ? ntris : 1, sizeof *b->seen);
    /* Each triangle's bins, found once for both passes (bins fit a byte:
     * per_axis <= 256); lo > hi on x for a triangle in no bin: lo 2 when it
     * goes to the big list, 1 when it misses the region. */
    uint8_t(*rng)[6] = cvre_malloc((ntris ? ntris : 1) * sizeof *rng);
    if (!b->start || !b->seen || !rng) {
        free(rng);
        return -ENOMEM;
    }
    for (uint32_t i = 0; i < ntris; i++) {
        uint32_t lo[3], hi[3];
        uint64_t c = box_bins(b, box[i], grow, lo, hi);
        rng[i][0] = 1;
        rng[i][3] = 0;
        if (spread_max && c > spread_max) {
            rng[i][0] = 2;
            b->nbig++;
            continue;
        }
        for (uint32_t z = lo[2]; c && z <= hi[2]; z++)
            for (uint32_t y = lo[1]; y <= hi[1]; y++)
                for (uint32_t x = lo[0]; x <= hi[0]; x++)
                    b->start[x + per_axis * (y + per_axis * z) + 1]++;
        for (int a = 0; c && a < 3; a++) {
            rng[i][a] = (uint8_t)lo[a];
            rng[i][3 + a] = (uint8_t)hi[a];
        }
    }
    for (uint32_t k = 0; k < nb; k++)
        b->start[k + 1] += b->start[k];
    b->list = cvre_malloc((b->start[nb] ? b->start[nb] : 1) * sizeof *b->list);
    b->big = cvre_malloc((b->nbig ? b->nbig : 1) * sizeof *b->big);
    if (!b->list || !b->big) {
        free(rng);
        return -ENOMEM;
    }
    b->nbig = 0;
    for (uint32_t i = 0; i < ntris; i++) {
        const uint8_t *r = rng[i];
        if (r[0] > r[3]) {
            if (r[0] == 2)
                b->big[b->nbig++] = i;
            continue;
        }
        for (uint32_t z = r[2]; z <= r[5]; z++)
            for (uint32_t y = r[1]; y <= r[4]; y++)
                for (uint32_t x = r[0]; x <= r[3]; x++)
                    b->list[b->start[x + per_axis * (y + per_axis * z)]++] = i;
    }
    free(rng);
    /* The fill moved each offset to its bin's end: shift back. */
    memmove(b->start + 1, b->start, nb * sizeof *b->start);
    b->start[0] = 0;
    return 0;
}

void tribins_free(tribins *b)
{
    free(b->start);
    free(b->list);
    free(b->big);
    free(b->seen);
    memset(b, 0, sizeof *b);
}

void tribins_query(tribins *b, const double lo[3], const double hi[3], tribins_iter *it)
{
    *it = (tribins_iter){.b = b, .src = b->big, .end = b->nbig, .more = 1};
    for (int a = 0; a < 3; a++)
        if (!bin_range(b, a, lo[a], hi[a], &it->lo[a], &it->hi[a])) {
            it->end = 0; /* misses the region: no candidate, big ones included */
            it->more = 0;
            return;
        }
    it->x = it->lo[0];
    it->y = it->lo[1];
    it->z = it->lo[2];
    if (++b->query == 0) { /* wrapped: stamps of old queries could match */
        memset(b->seen, 0, (b->ntris ? b->ntris : 1) * sizeof *b->seen);
        b->query = 1;
    }
}
