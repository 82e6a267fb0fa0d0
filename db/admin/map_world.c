/* map_world.c: the geometry of `cvre-admin map` (mapInt.h): world
 * coordinates, volumes, the views' rectangles and outline rasters. */
#include <math.h>
#include <stdlib.h>

#include "alloc.h"
#include "mapInt.h"

/* world = R_y(yaw) * (scale * local) + pos, as scene_to_world does (in
 * double here: the picture needs no bit-exactness with the server). */
void map__to_world(const mobj *o, const float l[3], double w[3])
{
    double c = cos(o->yaw), sn = sin(o->yaw);
    double x = l[0] * o->scale, y = l[1] * o->scale, z = l[2] * o->scale;
    w[0] = c * x + sn * z + o->pos[0];
    w[1] = y + o->pos[1];
    w[2] = -sn * x + c * z + o->pos[2];
}

/* The world AABB of a local box turned and scaled with the object (the
 * box itself for a yaw that is a multiple of 90 degrees), as the server's
 * scene_box_to_world makes it. */
void map__box_world(const mobj *o, const float b[6], double mn[3], double mx[3])
{
    for (int k = 0; k < 3; k++)
        mn[k] = INFINITY, mx[k] = -INFINITY;
    for (int corner = 0; corner < 8; corner++) {
        float l[3] = {b[corner & 1 ? 3 : 0], b[corner & 2 ? 4 : 1], b[corner & 4 ? 5 : 2]};
        double w[3];
        map__to_world(o, l, w);
        for (int k = 0; k < 3; k++) {
            mn[k] = fmin(mn[k], w[k]);
            mx[k] = fmax(mx[k], w[k]);
        }
    }
}

/* A segment tree over the elementary intervals [zs[i], zs[i + 1]) that
 * knows the length of their union covered by at least one interval. */
typedef struct cover {
    const double *zs;
    int32_t *cnt;
    double *len;
} cover;

static void cover_add(cover *c, size_t node, uint32_t lo, uint32_t hi, uint32_t a, uint32_t b, int32_t d)
{
    if (b <= lo || hi <= a)
        return;
    if (a <= lo && hi <= b) {
        c->cnt[node] += d;
    } else {
        uint32_t mid = lo + (hi - lo) / 2;
        cover_add(c, 2 * node + 1, lo, mid, a, b, d);
        cover_add(c, 2 * node + 2, mid, hi, a, b, d);
    }
    if (c->cnt[node] > 0)
        c->len[node] = c->zs[hi] - c->zs[lo];
    else if (hi - lo == 1)
        c->len[node] = 0;
    else
        c->len[node] = c->len[2 * node + 1] + c->len[2 * node + 2];
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

/* Sorts v[0..n) and drops repeats; returns how many are left. */
static uint32_t sort_unique(double *v, uint32_t n)
{
    qsort(v, n, sizeof *v, cmp_double);
    uint32_t m = 0;
    for (uint32_t i = 0; i < n; i++)
        if (m == 0 || v[i] != v[m - 1])
            v[m++] = v[i];
    return m;
}

static uint32_t index_of(const double *v, uint32_t n, double x)
{
    uint32_t lo = 0, hi = n;
    while (lo < hi) {
        uint32_t mid = lo + (hi - lo) / 2;
        if (v[mid] < x)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

typedef struct yevent {
    double y;
    uint32_t box;
    int32_t d; /* +1 at min_y, -1 at max_y */
} yevent;

static int cmp_yevent(const void *a, const void *b)
{
    const yevent *p = a, *q = b;
    if (p->y != q->y)
        return p->y < q->y ? -1 : 1;
    if (p->box != q->box)
        return p->box < q->box ? -1 : 1;
    return p->d < q->d ? -1 : p->d > q->d;
}

/* The volume of the union of n boxes (local; they may overlap), exact up
 * to rounding: a sweep over the slabs between consecutive distinct x
 * bounds; in each, the area of the union of the (y, z) rectangles of the
 * boxes spanning it, by a sweep over y with the covered z length kept in a
 * segment tree over the distinct z bounds. O(n^2 log n): 1024 boxes (the
 * most a version holds) are 2047 slabs of 2048 events, tens of ms. */
double map__union_volume(const float (*b)[6], uint32_t n)
{
    if (n == 0)
        return 0;
    double *xs = cvre_xmalloc(2 * n * sizeof *xs), *zs = cvre_xmalloc(2 * n * sizeof *zs);
    yevent *ev = cvre_xmalloc(2 * n * sizeof *ev);
    uint32_t *za = cvre_xmalloc(n * sizeof *za), *zb = cvre_xmalloc(n * sizeof *zb);
    uint32_t nx = 0, nz = 0, ne = 0;
    for (uint32_t i = 0; i < n; i++) {
        if (!(b[i][3] > b[i][0] && b[i][4] > b[i][1] && b[i][5] > b[i][2]))
            continue; /* flat: no volume */
        xs[nx++] = b[i][0], xs[nx++] = b[i][3];
        zs[nz++] = b[i][2], zs[nz++] = b[i][5];
        ev[ne++] = (yevent){b[i][1], i, 1};
        ev[ne++] = (yevent){b[i][4], i, -1};
    }
    double vol = 0;
    if (ne) {
        nx = sort_unique(xs, nx);
        nz = sort_unique(zs, nz);
        qsort(ev, ne, sizeof *ev, cmp_yevent);
        for (uint32_t i = 0; i < n; i++) {
            za[i] = index_of(zs, nz, b[i][2]);
            zb[i] = index_of(zs, nz, b[i][5]);
        }
        size_t nodes = 4 * (size_t)nz;
        cover c = {zs, cvre_xcalloc(nodes, sizeof *c.cnt), cvre_xcalloc(nodes, sizeof *c.len)};
        for (uint32_t s = 0; s + 1 < nx; s++) {
            double x0 = xs[s], x1 = xs[s + 1], area = 0, ylast = 0;
            int any = 0;
            for (uint32_t e = 0; e < ne; e++) {
                const float *q = b[ev[e].box];
                if (!(q[0] <= x0 && q[3] >= x1))
                    continue;
                if (any)
                    area += c.len[0] * (ev[e].y - ylast);
                any = 1;
                ylast = ev[e].y;
                cover_add(&c, 0, 0, nz - 1, za[ev[e].box], zb[ev[e].box], ev[e].d);
            }
            vol += area * (x1 - x0);
        }
        free(c.cnt);
        free(c.len);
    }
    free(xs);
    free(zs);
    free(ev);
    free(za);
    free(zb);
    return vol;
}

double map__box_volume(const float (*b)[6], uint32_t n)
{
    double v = 0;
    for (uint32_t i = 0; i < n; i++)
        v += ((double)b[i][3] - b[i][0]) * ((double)b[i][4] - b[i][1]) * ((double)b[i][5] - b[i][2]);
    return v;
}

void map__layout(const world *wd, view *views)
{
    double mn[3] = {INFINITY, INFINITY, INFINITY}, mx[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t i = 0; i < wd->n; i++) {
        const mobj *o = &wd->o[i];
        double a[3], c[3];
        map__box_world(o, o->mbr, a, c);
        for (int k = 0; k < 3; k++)
            mn[k] = fmin(mn[k], a[k]), mx[k] = fmax(mx[k], c[k]);
        for (int set = 0; set < 2; set++)
            for (uint32_t j = 0; j < (set ? o->norig : o->nboxes); j++) {
                map__box_world(o, set ? o->orig[j] : o->boxes[j], a, c);
                for (int k = 0; k < 3; k++)
                    mn[k] = fmin(mn[k], a[k]), mx[k] = fmax(mx[k], c[k]);
            }
        for (size_t p = 0; p < o->npts; p++) {
            map__to_world(o, o->xyz + 3 * p, a);
            for (int k = 0; k < 3; k++)
                mn[k] = fmin(mn[k], a[k]), mx[k] = fmax(mx[k], a[k]);
        }
    }
    if (!(mn[0] <= mx[0] && mn[1] <= mx[1] && mn[2] <= mx[2]))
        for (int k = 0; k < 3; k++)
            mn[k] = -1, mx[k] = 1; /* nothing to draw */
    double big = fmax(mx[0] - mn[0], fmax(mx[1] - mn[1], mx[2] - mn[2]));
    double pad = 0.04 * big + 0.25;
    for (int k = 0; k < 3; k++)
        mn[k] -= pad, mx[k] += pad;
    double s = MAP_VIEW_PX / fmax(mx[0] - mn[0], fmax(mx[1] - mn[1], mx[2] - mn[2]));
    views[0] = (view){.id = "top", .va = 2, .up = 0};
    views[1] = (view){.id = "side", .va = 1, .up = 1};
    for (int i = 0; i < 2; i++) {
        view *v = &views[i];
        v->u0 = mn[0], v->u1 = mx[0], v->v0 = mn[v->va], v->v1 = mx[v->va];
        v->s = s;
        v->w = (v->u1 - v->u0) * s, v->h = (v->v1 - v->v0) * s;
        v->cell = fmax(v->u1 - v->u0, v->v1 - v->v0) / MAP_MASK_CELLS;
        v->cols = (uint32_t)fmin(MAP_MASK_CELLS, ceil((v->u1 - v->u0) / v->cell));
        v->rows = (uint32_t)fmin(MAP_MASK_CELLS, ceil((v->v1 - v->v0) / v->cell));
        if (v->cols < 1)
            v->cols = 1;
        if (v->rows < 1)
            v->rows = 1;
        v->mask = cvre_xcalloc((size_t)v->cols * v->rows, 1);
    }
}

/* 1 if the closed 2D triangle p and the closed rectangle with centre
 * (cx, cy) and half sizes (hx, hy) share a point, given that their
 * bounding boxes do: the edge normals are the remaining separating axes
 * (a degenerate triangle, a segment or a point, is handled too). */
static int tri_rect(const double p[3][2], double cx, double cy, double hx, double hy)
{
    for (int i = 0; i < 3; i++) {
        const double *a = p[i], *b = p[(i + 1) % 3], *c = p[(i + 2) % 3];
        double nx = a[1] - b[1], ny = b[0] - a[0];
        double pa = nx * a[0] + ny * a[1], pc = nx * c[0] + ny * c[1];
        double lo = fmin(pa, pc), hi = fmax(pa, pc);
        double pr = nx * cx + ny * cy, r = hx * fabs(nx) + hy * fabs(ny);
        if (pr + r < lo || pr - r > hi)
            return 0;
    }
    return 1;
}

/* Marks the outline cells that one world triangle's projection touches
 * (conservatively: a wall seen edge-on is a segment, and still marks). */
void map__view_mark(view *v, const double w[3][3])
{
    double p[3][2], umin = INFINITY, umax = -INFINITY, vmin = INFINITY, vmax = -INFINITY;
    for (int i = 0; i < 3; i++) {
        p[i][0] = w[i][0];
        p[i][1] = w[i][v->va];
        umin = fmin(umin, p[i][0]), umax = fmax(umax, p[i][0]);
        vmin = fmin(vmin, p[i][1]), vmax = fmax(vmax, p[i][1]);
    }
    if (!(umax >= v->u0 && umin <= v->u1 && vmax >= v->v0 && vmin <= v->v1))
        return;
    double c0 = floor((umin - v->u0) / v->cell), c1 = floor((umax - v->u0) / v->cell);
    double r0 = floor((vmin - v->v0) / v->cell), r1 = floor((vmax - v->v0) / v->cell);
    c0 = fmax(c0, 0), r0 = fmax(r0, 0);
    c1 = fmin(c1, v->cols - 1.0), r1 = fmin(r1, v->rows - 1.0);
    /* Each cell grows by a millionth of its size: rounding can only add
     * cells to the outline, never drop one. */
    double h = v->cell * (0.5 + 1e-6);
    for (uint32_t r = (uint32_t)r0; r <= (uint32_t)r1; r++)
        for (uint32_t c = (uint32_t)c0; c <= (uint32_t)c1; c++) {
            uint8_t *m = &v->mask[(size_t)r * v->cols + c];
            if (!*m && tri_rect(p, v->u0 + (c + 0.5) * v->cell, v->v0 + (r + 0.5) * v->cell, h, h))
                *m = 1;
        }
}


/* Whether point g (0-based over every object's points in turn) is one of
 * the `drawn` evenly spaced in id order. */
int map__drawn_point(size_t g, size_t total, size_t drawn)
{
    if (total <= drawn)
        return 1;
    return (g + 1) * drawn / total > g * drawn / total;
}
