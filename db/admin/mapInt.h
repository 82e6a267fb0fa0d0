/*
 * mapInt.h: what the files of `cvre-admin map` share (map.h is the command).
 *
 *   map.c          the command: reads one snapshot into a world, computes the
 *                  figures, writes the picture and prints the figures
 *   map_world.c    geometry: world coordinates, box and union volumes, the
 *                  views' world rectangles and their outline rasters
 *   map_svg.c      the picture: page layout, views, labels, legend, caption
 *   map_figures.c  the figures on stdout: a table or JSON
 *
 * Data flows one way: map.c fills a world and two views, the others only
 * read them (map_svg.c places the frames on the page).
 */
#ifndef CVRE_ADMIN_MAPINT_H
#define CVRE_ADMIN_MAPINT_H

#include <stddef.h>
#include <stdint.h>

#include "dbscan.h"
#include "sbuf.h"
#include "voxel.h"

/* Points drawn per picture at most: 20,000 points are 40,000 circles (two
 * views), about 2.5 MB of SVG that a browser draws in well under a second;
 * more would only pile up on the same pixels and slow every viewer down.
 * Beyond it an evenly spaced subsample (in id order) is drawn, and the
 * caption says so. Clusters are always computed over every point. */
#ifndef MAP_POINTS_MAX
#define MAP_POINTS_MAX 20000u
#endif
/* Cells of the outline raster along the longer side of a view: a cell is
 * about 2 px of a MAP_VIEW_PX view, finer than the boxes it frames, and a
 * 256 x 256 mask emits at most a few thousand runs where one element per
 * triangle would be 400,000 on the city block. */
#ifndef MAP_MASK_CELLS
#define MAP_MASK_CELLS 256u
#endif
/* Longest side of one view in px: two views, the gap and the margins fit
 * a 1200 px wide window, and legend and caption fit under them in 700
 * (the page grows with what it holds: map_svg.c). */
#ifndef MAP_VIEW_PX
#define MAP_VIEW_PX 500.0
#endif
/* The digitization behind occupied_volume: 2^7 cells per axis over the
 * object's MBR, the depth the refiner works at by default. */
#ifndef MAP_DEPTH
#define MAP_DEPTH 7u
#endif
/* Clusters named one by one in the legend (their colours repeat after the
 * palette's 12 anyway). */
#ifndef MAP_LEGEND_CLUSTERS
#define MAP_LEGEND_CLUSTERS 12u
#endif
_Static_assert(MAP_POINTS_MAX >= 1u && MAP_POINTS_MAX <= 1000000u, "a picture a browser can still open");
_Static_assert(MAP_MASK_CELLS >= 16u && MAP_MASK_CELLS <= 4096u, "an outline between a sketch and a bitmap");
_Static_assert(MAP_DEPTH >= VOXEL_DEPTH_MIN && MAP_DEPTH <= VOXEL_DEPTH_MAX, "a depth the voxelizer takes");

/* What is drawn of one object. */
typedef struct mobj {
    int64_t id;
    char *name;
    double pos[3], yaw, scale;
    float mbr[6];                /* local */
    uint32_t tri_count;
    uint32_t version, in_force, nversions;
    char *reason;                /* of the version shown */
    uint32_t points_version;     /* the collisions drawn were logged against it */
    int has_run;
    int64_t run_id;
    dbscan_params prm;
    float (*boxes)[6];           /* the version shown, local */
    uint32_t nboxes;
    float (*orig)[6];            /* version 1, local */
    uint32_t norig;
    float *xyz;                  /* points, local, in id order */
    uint32_t *users;
    int32_t *labels;
    size_t npts, cap;
    size_t nclusters, noise;
    double box_volume, union_volume, occupied_volume; /* world m^3 */
    uint64_t voxels;
} mobj;

/* Everything drawn: the objects in id order. */
typedef struct world {
    mobj *o;
    size_t n;
    size_t points, drawn; /* all points; drawn ones */
    int object_mode;
} world;

/* One of the two views: a world rectangle, its frame on the page and the
 * outline raster of the geometry projected into it. */
typedef struct view {
    const char *id;  /* "top", "side" */
    int va;          /* world axis of the page's vertical: 2 (z) or 1 (y) */
    int up;          /* 1: it grows up the page (y); 0: down (z) */
    double u0, u1, v0, v1; /* world rect shown: x, then the va axis */
    double s;        /* px per metre */
    double ox, oy, w, h;   /* the frame, px */
    uint32_t cols, rows;
    double cell;     /* outline cell, metres */
    uint8_t *mask;   /* rows x cols, row 0 at v0 */
} view;

/* ---- map_world.c ---- */

/* world = R_y(yaw) * (scale * local) + pos, as scene_to_world does (in
 * double here: the picture needs no bit-exactness with the server). */
void map__to_world(const mobj *o, const float l[3], double w[3]);
/* The world AABB of a local box turned and scaled with the object (the
 * box itself for a yaw that is a multiple of 90 degrees), as the server's
 * scene_box_to_world makes it. */
void map__box_world(const mobj *o, const float b[6], double mn[3], double mx[3]);
/* The volume of n boxes (local) summed, and of their union (overlaps once). */
double map__box_volume(const float (*b)[6], uint32_t n);
double map__union_volume(const float (*b)[6], uint32_t n);
/* Sets the views' world rectangles (everything drawn, and a margin), their
 * common scale and frame sizes, and allocates their outline masks (the
 * caller frees views[i].mask). Frames are placed on the page by map__svg. */
void map__layout(const world *wd, view *views);
/* Marks the outline cells of v that one world triangle's projection touches. */
void map__view_mark(view *v, const double w[3][3]);
/* Whether point g (0-based over every object's points in turn) is one of
 * the `drawn` evenly spaced in id order. */
int map__drawn_point(size_t g, size_t total, size_t drawn);

/* ---- map_svg.c ---- */

/* Builds the whole SVG of wd in b: places the views' frames, sizes the page
 * to what it holds and places the world map's labels. */
void map__svg(sbuf *b, const world *wd, view *views);

/* ---- map_figures.c ---- */

/* One object's figures as a JSON object (drawn: its points drawn). */
void map__figures_json(sbuf *b, const mobj *o, size_t drawn);
/* Every object's figures as a table. */
void map__figures_table(sbuf *b, const world *wd);

#endif
