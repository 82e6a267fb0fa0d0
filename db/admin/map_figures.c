/* map_figures.c: the figures `cvre-admin map` prints (mapInt.h), as JSON
 * or as a table. */
#include <stdio.h>
#include <string.h>

#include "json.h"
#include "mapInt.h"

void map__figures_json(sbuf *b, const mobj *o, size_t drawn)
{
    sb_printf(b, "{\"object\": %lld, \"name\": ", (long long)o->id);
    json_put_string(b, o->name, strlen(o->name));
    sb_printf(b, ", \"version\": %u, \"boxes\": %u, \"original_boxes\": %u, \"box_volume\": ", o->version,
              o->nboxes, o->norig);
    sb_real(b, o->box_volume);
    sb_puts(b, ", \"union_volume\": ");
    sb_real(b, o->union_volume);
    sb_puts(b, ", \"occupied_volume\": ");
    sb_real(b, o->occupied_volume);
    sb_puts(b, ", \"tightness\": ");
    if (o->union_volume > 0)
        sb_real(b, o->occupied_volume / o->union_volume);
    else
        sb_puts(b, "null");
    sb_printf(b, ", \"full_voxel_boxes\": %llu, \"depth\": %u, \"points\": %zu, \"clusters\": %zu",
              (unsigned long long)o->voxels, MAP_DEPTH, o->npts, o->nclusters);
    sb_printf(b, ", \"points_drawn\": %zu, \"points_version\": %u, \"run\": ", drawn, o->points_version);
    if (o->has_run)
        sb_printf(b, "%lld}", (long long)o->run_id);
    else
        sb_puts(b, "null}");
}

void map__figures_table(sbuf *b, const world *wd)
{
    sb_printf(b, "%-7s  %-24s  %7s  %5s  %8s  %12s  %12s  %12s  %9s  %7s  %7s  %8s\n", "object", "name", "version",
              "boxes", "original", "box_m3", "union_m3", "geom_m3", "tightness", "voxels", "points", "clusters");
    sb_printf(b, "%-7s  %-24s  %7s  %5s  %8s  %12s  %12s  %12s  %9s  %7s  %7s  %8s\n", "-------",
              "------------------------", "-------", "-----", "--------", "------------", "------------", "------------",
              "---------", "-------", "-------", "--------");
    for (size_t i = 0; i < wd->n; i++) {
        const mobj *o = &wd->o[i];
        char name[25];
        size_t k = 0;
        for (; o->name[k] && k < 24; k++)
            name[k] = (unsigned char)o->name[k] < 0x20 || o->name[k] == 0x7f ? '?' : o->name[k];
        name[k] = 0;
        char tight[32] = "-";
        if (o->union_volume > 0)
            snprintf(tight, sizeof tight, "%.3f", o->occupied_volume / o->union_volume);
        sb_printf(b, "%7lld  %-24s  %7u  %5u  %8u  %12.3f  %12.3f  %12.3f  %9s  %7llu  %7zu  %8zu\n",
                  (long long)o->id, name, o->version, o->nboxes, o->norig, o->box_volume, o->union_volume,
                  o->occupied_volume, tight, (unsigned long long)o->voxels, o->npts, o->nclusters);
    }
}
