/*
 * map.c: cvre-admin map (map.h). Reading, then figures, then drawing:
 *
 *   objects, versions, boxes, points (one read snapshot)
 *     -> per object: DBSCAN labels (the run's parameters), union volume
 *        of the boxes, digitization of the mesh (voxel.h); the mesh is
 *        read one object at a time and also rasterized into the outline
 *        masks of the two views
 *     -> the SVG, built in memory and written whole; the figures on stdout.
 *
 * The picture is meant to be compared before and after refinement, so it
 * holds no time and nothing that varies between runs: numbers are printed
 * with fixed precision and everything is drawn in id order.
 */
#include "map.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "dbscan.h"
#include "ecm.h"
#include "query.h"
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
 * a 1200 px wide window, and legend and caption fit under them in 700. */
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

/* Page layout in px. */
#define PAGE_MARGIN 20.0
#define PAGE_GAP 50.0      /* between the two views */
#define PAGE_MIN_W 760.0   /* room for the legend and caption */
#define TITLE_H 24.0       /* a view's title above its frame */
#define LINE_H 16.0        /* legend and caption lines */

/* Cluster colours: distinct from the boxes' blue and from the noise grey. */
static const char *const palette[] = {"#d62728", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2",
                                      "#bcbd22", "#17becf", "#7f0000", "#e6ab02", "#1b5e20", "#c51b7d"};
#define PALETTE_N (sizeof palette / sizeof palette[0])

/* ---- a growing string ---- */

typedef struct sbuf {
    char *p;
    size_t len, cap;
} sbuf;

static void sb_grow(sbuf *b, size_t more)
{
    if (b->len + more + 1 <= b->cap)
        return;
    size_t cap = b->cap ? b->cap : 65536;
    while (cap < b->len + more + 1)
        cap *= 2;
    b->p = cvre_xrealloc(b->p, cap);
    b->cap = cap;
}

static void sb_put(sbuf *b, const char *s, size_t n)
{
    sb_grow(b, n);
    memcpy(b->p + b->len, s, n);
    b->len += n;
    b->p[b->len] = 0;
}

static void sb_puts(sbuf *b, const char *s)
{
    sb_put(b, s, strlen(s));
}

static void sb_printf(sbuf *b, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void sb_printf(sbuf *b, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(NULL, 0, fmt, ap);
    va_end(ap);
    if (n <= 0)
        return;
    sb_grow(b, (size_t)n);
    va_start(ap, fmt);
    vsnprintf(b->p + b->len, (size_t)n + 1, fmt, ap);
    va_end(ap);
    b->len += (size_t)n;
}

/* A px coordinate: 2 decimals, trailing zeros dropped, never "-0". */
static void sb_num(sbuf *b, double v)
{
    char t[48];
    double r = round(v * 100.0) / 100.0;
    if (r == 0 || !isfinite(r))
        r = 0;
    snprintf(t, sizeof t, "%.2f", r);
    char *dot = strchr(t, '.');
    if (dot) {
        char *e = t + strlen(t) - 1;
        while (e > dot && *e == '0')
            *e-- = 0;
        if (e == dot)
            *e = 0;
    }
    sb_puts(b, t);
}

/* Length of the valid UTF-8 sequence at s[0..n), or 0 if it is not one
 * (overlong forms, surrogates and code points beyond U+10FFFF included). */
static size_t utf8_len(const unsigned char *s, size_t n)
{
    unsigned c = s[0];
    size_t k;
    unsigned min, cp;
    if (c < 0x80)
        return 1;
    if ((c & 0xe0) == 0xc0)
        k = 2, min = 0x80, cp = c & 0x1f;
    else if ((c & 0xf0) == 0xe0)
        k = 3, min = 0x800, cp = c & 0x0f;
    else if ((c & 0xf8) == 0xf0)
        k = 4, min = 0x10000, cp = c & 0x07;
    else
        return 0;
    if (k > n)
        return 0;
    for (size_t i = 1; i < k; i++) {
        if ((s[i] & 0xc0) != 0x80)
            return 0;
        cp = cp << 6 | (s[i] & 0x3fu);
    }
    if (cp < min || cp > 0x10ffff || (cp >= 0xd800 && cp <= 0xdfff))
        return 0;
    return k;
}

/* Text as XML character data or attribute value: the five special
 * characters escaped; control characters (not allowed in XML 1.0) and
 * bytes that are not UTF-8 become '?', so any stored name gives a
 * well-formed file. */
static void sb_xml(sbuf *b, const char *text)
{
    const unsigned char *s = (const unsigned char *)text;
    size_t n = strlen(text);
    for (size_t i = 0; i < n;) {
        unsigned char c = s[i];
        size_t k = utf8_len(s + i, n - i);
        if (k == 0 || (c < 0x20 && c != '\t') || c == 0x7f) {
            sb_puts(b, "?");
            i += k ? k : 1;
            continue;
        }
        switch (c) {
        case '<': sb_puts(b, "&lt;"); break;
        case '>': sb_puts(b, "&gt;"); break;
        case '&': sb_puts(b, "&amp;"); break;
        case '"': sb_puts(b, "&quot;"); break;
        case '\'': sb_puts(b, "&apos;"); break;
        default: sb_put(b, (const char *)s + i, k);
        }
        i += k;
    }
}

/* Text as a JSON string (quotes included); bytes that are not UTF-8
 * become U+FFFD. */
static void sb_json(sbuf *b, const char *text)
{
    const unsigned char *s = (const unsigned char *)text;
    size_t n = strlen(text);
    sb_puts(b, "\"");
    for (size_t i = 0; i < n;) {
        unsigned char c = s[i];
        size_t k = utf8_len(s + i, n - i);
        if (k == 0) {
            sb_puts(b, "\\ufffd");
            i++;
        } else if (c == '"' || c == '\\') {
            sb_printf(b, "\\%c", c);
            i++;
        } else if (c < 0x20 || c == 0x7f) {
            sb_printf(b, "\\u%04x", c);
            i++;
        } else {
            sb_put(b, (const char *)s + i, k);
            i += k;
        }
    }
    sb_puts(b, "\"");
}

/* The shortest %g form that reads back as the same double (as out.c). */
static void sb_real(sbuf *b, double v)
{
    char t[64];
    if (!isfinite(v)) {
        sb_puts(b, "null");
        return;
    }
    for (int prec = 15; prec <= 17; prec++) {
        snprintf(t, sizeof t, "%.*g", prec, v);
        if (strtod(t, NULL) == v)
            break;
    }
    sb_puts(b, t);
}

/* ---- what is drawn of one object ---- */

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

static void mobj_free(mobj *o)
{
    free(o->name);
    free(o->reason);
    free(o->boxes);
    free(o->orig);
    free(o->xyz);
    free(o->users);
    free(o->labels);
}

/* world = R_y(yaw) * (scale * local) + pos, as scene_to_world does (in
 * double here: the picture needs no bit-exactness with the server). */
static void to_world(const mobj *o, const float l[3], double w[3])
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
static void box_world(const mobj *o, const float b[6], double mn[3], double mx[3])
{
    for (int k = 0; k < 3; k++)
        mn[k] = INFINITY, mx[k] = -INFINITY;
    for (int corner = 0; corner < 8; corner++) {
        float l[3] = {b[corner & 1 ? 3 : 0], b[corner & 2 ? 4 : 1], b[corner & 4 ? 5 : 2]};
        double w[3];
        to_world(o, l, w);
        for (int k = 0; k < 3; k++) {
            mn[k] = fmin(mn[k], w[k]);
            mx[k] = fmax(mx[k], w[k]);
        }
    }
}

/* ---- figures ---- */

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
static double union_volume(const float (*b)[6], uint32_t n)
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

static double box_volume(const float (*b)[6], uint32_t n)
{
    double v = 0;
    for (uint32_t i = 0; i < n; i++)
        v += ((double)b[i][3] - b[i][0]) * ((double)b[i][4] - b[i][1]) * ((double)b[i][5] - b[i][2]);
    return v;
}

/* ---- the views ---- */

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

static double px_u(const view *v, double u)
{
    return v->ox + (u - v->u0) * v->s;
}

static double px_v(const view *v, double w)
{
    return v->up ? v->oy + (v->v1 - w) * v->s : v->oy + (w - v->v0) * v->s;
}

/* A world rectangle [ua, ub] x [va, vb] as x, y, width, height attributes;
 * at least 0.5 px wide and high, so that a flat box still shows. */
static void sb_rect_attrs(sbuf *b, const view *v, double ua, double ub, double va, double vb)
{
    double x = px_u(v, ua), w = (ub - ua) * v->s;
    double y = v->up ? px_v(v, vb) : px_v(v, va), h = (vb - va) * v->s;
    if (w < 0.5)
        x -= (0.5 - w) / 2, w = 0.5;
    if (h < 0.5)
        y -= (0.5 - h) / 2, h = 0.5;
    sb_puts(b, " x=\"");
    sb_num(b, x);
    sb_puts(b, "\" y=\"");
    sb_num(b, y);
    sb_puts(b, "\" width=\"");
    sb_num(b, w);
    sb_puts(b, "\" height=\"");
    sb_num(b, h);
    sb_puts(b, "\"");
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
static void view_mark(view *v, const double w[3][3])
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

/* The outline: the mask's runs of marked cells, a run that continues one
 * of the same columns in the row before extending it, as <rect>s. */
static void view_outline(sbuf *b, const view *v)
{
    typedef struct run {
        uint32_t c0, c1, r0;
    } run;
    run *open = cvre_xmalloc((v->cols / 2 + 2) * sizeof *open), *next = cvre_xmalloc((v->cols / 2 + 2) * sizeof *next);
    size_t nopen = 0;
    sb_puts(b, "<g class=\"outlines\">\n");
    for (uint32_t r = 0; r <= v->rows; r++) {
        size_t nnext = 0, k = 0;
        for (uint32_t c = 0; r < v->rows && c < v->cols;) {
            if (!v->mask[(size_t)r * v->cols + c]) {
                c++;
                continue;
            }
            uint32_t c0 = c;
            while (c < v->cols && v->mask[(size_t)r * v->cols + c])
                c++;
            /* Open runs left of this one end here. */
            while (k < nopen && open[k].c0 < c0) {
                run *o = &open[k++];
                sb_puts(b, "<rect class=\"outline\"");
                sb_rect_attrs(b, v, v->u0 + o->c0 * v->cell, fmin(v->u1, v->u0 + o->c1 * v->cell),
                              v->v0 + o->r0 * v->cell, fmin(v->v1, v->v0 + r * v->cell));
                sb_puts(b, "/>\n");
            }
            if (k < nopen && open[k].c0 == c0 && open[k].c1 == c)
                next[nnext++] = open[k++];
            else
                next[nnext++] = (run){c0, c, r};
        }
        while (k < nopen) {
            run *o = &open[k++];
            sb_puts(b, "<rect class=\"outline\"");
            sb_rect_attrs(b, v, v->u0 + o->c0 * v->cell, fmin(v->u1, v->u0 + o->c1 * v->cell),
                          v->v0 + o->r0 * v->cell, fmin(v->v1, v->v0 + r * v->cell));
            sb_puts(b, "/>\n");
        }
        run *t = open;
        open = next, next = t;
        nopen = nnext;
    }
    sb_puts(b, "</g>\n");
    free(open);
    free(next);
}

/* A round length (1, 2 or 5 times a power of ten) of at most `most` m. */
static double nice_length(double most)
{
    double p = pow(10, floor(log10(most)));
    return 5 * p <= most ? 5 * p : 2 * p <= most ? 2 * p : p;
}

/* ---- reading ---- */

typedef struct reader {
    db *d;
    sqlite3 *s;
    char *err;
    size_t errlen;
    sqlite3_stmt *version, *nversions, *run, *points;
} reader;

static int db_fail(reader *rd)
{
    return query_fail(rd->err, rd->errlen, QUERY_ERROR, "query failed: %s", sqlite3_errmsg(rd->s));
}

static char *dup_text(sqlite3_stmt *st, int i)
{
    const unsigned char *t = sqlite3_column_text(st, i);
    size_t n = t ? (size_t)sqlite3_column_bytes(st, i) : 0;
    char *s = cvre_xmalloc(n + 1);
    if (n)
        memcpy(s, t, n);
    s[n] = 0;
    return s;
}

/* The version shown, its boxes, version 1's, the run whose parameters
 * label the points, and the points. */
static int read_object(reader *rd, mobj *o)
{
    long long oid = (long long)o->id;
    sqlite3_stmt *st = rd->version;
    sqlite3_bind_int64(st, 1, o->id);
    sqlite3_bind_int64(st, 2, o->version);
    int step = sqlite3_step(st);
    int64_t parent = 0;
    if (step == SQLITE_ROW) {
        o->reason = dup_text(st, 0);
        parent = sqlite3_column_int64(st, 1);
    }
    sqlite3_reset(st);
    sqlite3_bind_int64(rd->nversions, 1, o->id);
    int nstep = sqlite3_step(rd->nversions);
    int64_t last = nstep == SQLITE_ROW ? sqlite3_column_int64(rd->nversions, 1) : 0;
    o->nversions = nstep == SQLITE_ROW ? (uint32_t)sqlite3_column_int64(rd->nversions, 0) : 0;
    sqlite3_reset(rd->nversions);
    if ((step != SQLITE_ROW && step != SQLITE_DONE) || nstep != SQLITE_ROW)
        return db_fail(rd);
    if (step == SQLITE_DONE)
        return query_fail(rd->err, rd->errlen, QUERY_NOT_FOUND, "object %lld has no version %u (its versions: 1 to %lld)",
                    oid, o->version, (long long)last);
    /* The store's reader checks the boxes against the version's count. */
    if (db_ecm_boxes(rd->d, o->id, o->version, &o->boxes, &o->nboxes) < 0 ||
        db_ecm_boxes(rd->d, o->id, 1, &o->orig, &o->norig) < 0)
        return query_fail(rd->err, rd->errlen, QUERY_ERROR, "%s", db_error(rd->d));
    /* The collisions the version answered (its parent's) if it has a
     * parent, else its own. */
    o->points_version = parent > 0 && parent <= UINT32_MAX ? (uint32_t)parent : o->version;

    st = rd->run;
    sqlite3_bind_int64(st, 1, o->id);
    sqlite3_bind_int64(st, 2, o->version);
    sqlite3_bind_int64(st, 3, o->points_version);
    step = sqlite3_step(st);
    if (step == SQLITE_ROW) {
        o->has_run = 1;
        o->run_id = sqlite3_column_int64(st, 0);
        o->prm.eps = sqlite3_column_double(st, 1);
        int64_t mp = sqlite3_column_int64(st, 2), mu = sqlite3_column_int64(st, 3);
        o->prm.min_points = mp < 1 ? 1 : mp > UINT32_MAX ? UINT32_MAX : (uint32_t)mp;
        o->prm.min_users = mu < 0 ? 0 : mu > UINT32_MAX ? UINT32_MAX : (uint32_t)mu;
        o->prm.threads = 0;
    }
    sqlite3_reset(st);
    if (step != SQLITE_ROW && step != SQLITE_DONE)
        return db_fail(rd);

    st = rd->points;
    sqlite3_bind_int64(st, 1, o->id);
    sqlite3_bind_int64(st, 2, o->points_version);
    while ((step = sqlite3_step(st)) == SQLITE_ROW) {
        if (o->npts == o->cap) {
            o->cap = o->cap ? o->cap * 2 : 1024;
            o->xyz = cvre_xrealloc(o->xyz, o->cap * 3 * sizeof *o->xyz);
            o->users = cvre_xrealloc(o->users, o->cap * sizeof *o->users);
        }
        for (int k = 0; k < 3; k++)
            o->xyz[3 * o->npts + (size_t)k] = (float)sqlite3_column_double(st, k);
        /* As cvre-cluster: a user id, or minus the session id for an
         * unknown user, taken modulo 2^32. */
        o->users[o->npts++] = (uint32_t)sqlite3_column_int64(st, 3);
    }
    sqlite3_reset(st);
    return step == SQLITE_DONE ? QUERY_OK : db_fail(rd);
}

/* Labels every point: DBSCAN with the run's parameters, or all noise
 * without a run. */
static int cluster_object(mobj *o, char *err, size_t errlen)
{
    o->labels = cvre_xmalloc((o->npts ? o->npts : 1) * sizeof *o->labels);
    o->nclusters = 0;
    if (!o->has_run || o->npts == 0) {
        for (size_t i = 0; i < o->npts; i++)
            o->labels[i] = -1;
    } else {
        dbscan_result *res = NULL;
        int rc = dbscan_run(o->xyz, o->users, o->npts, &o->prm, o->labels, &res);
        if (rc < 0)
            return query_fail(err, errlen, QUERY_ERROR, "object %lld: clustering with run %lld's parameters failed: %s",
                        (long long)o->id, (long long)o->run_id, strerror(-rc));
        o->nclusters = dbscan_result_count(res);
        dbscan_result_free(res);
    }
    o->noise = 0;
    for (size_t i = 0; i < o->npts; i++)
        o->noise += o->labels[i] < 0;
    return QUERY_OK;
}

/* Reads the mesh of o, digitizes it over the MBR (occupied cells and
 * their volume) and marks its outline in the views. */
static int mesh_object(reader *rd, mobj *o, view *views, int nviews)
{
    long long oid = (long long)o->id;
    db_ecm_object mesh; /* the store's reader checks the mesh against tri_count */
    if (db_ecm_object_load(rd->d, o->id, &mesh) < 0)
        return query_fail(rd->err, rd->errlen, QUERY_ERROR, "%s", db_error(rd->d));
    const float *tris = mesh.tris;

    for (size_t t = 0; t < o->tri_count; t++) {
        double w[3][3];
        for (int k = 0; k < 3; k++)
            to_world(o, tris + 9 * t + 3 * k, w[k]);
        for (int i = 0; i < nviews; i++)
            view_mark(&views[i], (const double(*)[3])w);
    }

    voxel_grid g;
    int rc = voxel_grid_init(&g, MAP_DEPTH, o->mbr, o->mbr + 3);
    if (rc == 0)
        rc = voxel_mark_threads(&g, tris, o->tri_count, 0);
    db_ecm_object_free(&mesh);
    if (rc < 0) {
        voxel_grid_free(&g);
        return query_fail(rd->err, rd->errlen, QUERY_ERROR, "object %lld: cannot digitize its mesh: %s", oid,
                    strerror(-rc));
    }
    double sc3 = o->scale * o->scale * o->scale;
    o->voxels = g.occupied;
    o->occupied_volume = (double)g.occupied * g.cell[0] * g.cell[1] * g.cell[2] * sc3;
    voxel_grid_free(&g);
    return QUERY_OK;
}

/* ---- the picture ---- */

typedef struct world {
    mobj *o;
    size_t n;
    size_t points, drawn; /* all points; drawn ones */
    int object_mode;
} world;

/* Whether point g (0-based over every object's points in turn) is one of
 * the `drawn` evenly spaced in id order. */
static int drawn_point(size_t g, size_t total, size_t drawn)
{
    if (total <= drawn)
        return 1;
    return (g + 1) * drawn / total > g * drawn / total;
}

static void sb_view_title(sbuf *b, const view *v)
{
    sb_puts(b, "<text class=\"title\" x=\"");
    sb_num(b, v->ox);
    sb_puts(b, "\" y=\"");
    sb_num(b, v->oy - 8);
    if (!v->up)
        sb_puts(b, "\">TOP (looking down): world x \xe2\x86\x92 right, world z \xe2\x86\x93 down the page</text>\n");
    else
        sb_puts(b, "\">SIDE (looking along \xe2\x88\x92z): world x \xe2\x86\x92 right, world y \xe2\x86\x91 up</text>\n");
}

static void sb_scale_bar(sbuf *b, const view *v)
{
    double len = nice_length((v->u1 - v->u0) * 0.3);
    double x0 = v->ox, x1 = v->ox + len * v->s, y = v->oy + v->h + 16;
    sb_puts(b, "<g class=\"scale\"><path d=\"M");
    sb_num(b, x0);
    sb_puts(b, " ");
    sb_num(b, y - 4);
    sb_puts(b, "V");
    sb_num(b, y);
    sb_puts(b, "H");
    sb_num(b, x1);
    sb_puts(b, "V");
    sb_num(b, y - 4);
    sb_puts(b, "\"/><text x=\"");
    sb_num(b, x1 + 6);
    sb_puts(b, "\" y=\"");
    sb_num(b, y + 1);
    sb_printf(b, "\">%g m</text></g>\n", len);
}

static void sb_view(sbuf *b, const view *v, const world *wd)
{
    sb_printf(b, "<g id=\"%s\" class=\"view\">\n", v->id);
    sb_view_title(b, v);
    sb_puts(b, "<rect class=\"frame\"");
    sb_rect_attrs(b, v, v->u0, v->u1, v->v0, v->v1);
    sb_puts(b, "/>\n");
    view_outline(b, v);
    size_t g = 0;
    for (size_t i = 0; i < wd->n; i++) {
        const mobj *o = &wd->o[i];
        double mn[3], mx[3];
        sb_printf(b, "<g id=\"%s-o%lld\" class=\"object\">\n", v->id, (long long)o->id);
        for (uint32_t k = 0; k < o->nboxes; k++) {
            box_world(o, o->boxes[k], mn, mx);
            sb_puts(b, "<rect class=\"box\"");
            sb_rect_attrs(b, v, mn[0], mx[0], mn[v->va], mx[v->va]);
            sb_puts(b, "/>\n");
        }
        for (uint32_t k = 0; k < o->norig; k++) {
            box_world(o, o->orig[k], mn, mx);
            sb_puts(b, "<rect class=\"box-original\"");
            sb_rect_attrs(b, v, mn[0], mx[0], mn[v->va], mx[v->va]);
            sb_puts(b, "/>\n");
        }
        /* Noise first, clusters over it. */
        sb_puts(b, "<g class=\"points\">\n");
        for (int pass = 0; pass < 2; pass++)
            for (size_t p = 0; p < o->npts; p++) {
                int32_t l = o->labels[p];
                if ((pass == 0) != (l < 0) || !drawn_point(g + p, wd->points, wd->drawn))
                    continue;
                double w[3];
                to_world(o, o->xyz + 3 * p, w);
                if (l < 0)
                    sb_puts(b, "<circle class=\"point noise\" cx=\"");
                else
                    sb_printf(b, "<circle class=\"point k%d p%zu\" cx=\"", (int)l, (size_t)l % PALETTE_N);
                sb_num(b, px_u(v, w[0]));
                sb_puts(b, "\" cy=\"");
                sb_num(b, px_v(v, w[v->va]));
                sb_puts(b, l < 0 ? "\" r=\"1.8\"/>\n" : "\" r=\"2.2\"/>\n");
            }
        sb_puts(b, "</g>\n");
        if (!wd->object_mode && !v->up) {
            /* Which object is which: its id and name above its MBR. */
            box_world(o, o->mbr, mn, mx);
            sb_puts(b, "<text class=\"label\" x=\"");
            sb_num(b, px_u(v, mn[0]));
            sb_puts(b, "\" y=\"");
            sb_num(b, px_v(v, mn[2]) - 3);
            sb_printf(b, "\">#%lld ", (long long)o->id);
            sb_xml(b, o->name);
            sb_puts(b, "</text>\n");
        }
        sb_puts(b, "</g>\n");
        g += o->npts;
    }
    sb_scale_bar(b, v);
    sb_puts(b, "</g>\n");
}

/* Where the next legend entry goes: at (*x, *y) unless its width w (its
 * swatch, sw px, and label; text estimated at 6.6 px a character of 12 px
 * sans-serif) would pass `right`, then at the start of the next line. */
static void legend_place(double *x, double *y, double left, double right, double sw, const char *label)
{
    double w = sw + 6 + 6.6 * (double)strlen(label) + 18;
    if (*x > left && *x + w > right)
        *x = left, *y += LINE_H + 2;
}

/* The label of a legend entry whose swatch (sw px wide) is drawn; moves
 * *x past the entry. */
static void legend_label(sbuf *b, double *x, double y, double sw, const char *label)
{
    sb_printf(b, "<text x=\"%.0f\" y=\"%.0f\">", *x + sw + 6, y);
    sb_xml(b, label);
    sb_puts(b, "</text>\n");
    *x += sw + 6 + 6.6 * (double)strlen(label) + 18;
}

/* A legend entry with a 16 x 10 swatch: a rect of class cls, or a dot
 * (dot != 0). */
static void legend_item(sbuf *b, double *x, double *y, double left, double right, const char *cls, int dot,
                        const char *label)
{
    legend_place(x, y, left, right, 16, label);
    if (dot)
        sb_printf(b, "<circle class=\"%s\" cx=\"%.0f\" cy=\"%.0f\" r=\"3\"/>\n", cls, *x + 8, *y - 4);
    else
        sb_printf(b, "<rect class=\"%s\" x=\"%.0f\" y=\"%.0f\" width=\"16\" height=\"10\"/>\n", cls, *x, *y - 9);
    legend_label(b, x, *y, 16, label);
}

static void sb_text_line(sbuf *b, double x, double *y, const char *text)
{
    sb_printf(b, "<text x=\"%.0f\" y=\"%.0f\">", x, *y);
    sb_xml(b, text);
    sb_puts(b, "</text>\n");
    *y += LINE_H;
}

static const char *plural(size_t n, const char *one, const char *many)
{
    return n == 1 ? one : many;
}

/* Builds the whole SVG of wd in b. */
static void build_svg(sbuf *b, world *wd, view *views)
{
    double right = views[1].ox + views[1].w;
    double width = fmax(right + PAGE_MARGIN, PAGE_MIN_W);
    double y = fmax(views[0].oy + views[0].h, views[1].oy + views[1].h) + 44;
    size_t boxes = 0, orig = 0, clusters = 0, noise = 0;
    double bv = 0, uv = 0, ov = 0;
    for (size_t i = 0; i < wd->n; i++) {
        boxes += wd->o[i].nboxes, orig += wd->o[i].norig, clusters += wd->o[i].nclusters;
        noise += wd->o[i].noise;
        bv += wd->o[i].box_volume, uv += wd->o[i].union_volume, ov += wd->o[i].occupied_volume;
    }
    const mobj *one = wd->object_mode ? &wd->o[0] : NULL;
    char line[1024];

    /* Legend and caption are laid out first (into their own buffer) to
     * know the page's height. */
    sbuf tail = {0};
    double x = PAGE_MARGIN, left = PAGE_MARGIN, lim = width - PAGE_MARGIN;
    sb_puts(&tail, "<g id=\"legend\">\n");
    legend_item(&tail, &x, &y, left, lim, "outline", 0, "geometry (triangles, projected)");
    legend_item(&tail, &x, &y, left, lim, "swatch-original", 0, "original boxes (version 1)");
    if (one)
        snprintf(line, sizeof line, "boxes of version %u", one->version);
    else
        snprintf(line, sizeof line, "boxes in force");
    legend_item(&tail, &x, &y, left, lim, "swatch-box", 0, line);
    legend_item(&tail, &x, &y, left, lim, "noise", 1, "noise (no cluster)");
    size_t listed = one ? (one->nclusters < MAP_LEGEND_CLUSTERS ? one->nclusters : MAP_LEGEND_CLUSTERS) : 0;
    for (size_t k = 0; k < listed; k++) {
        size_t pts = 0;
        for (size_t p = 0; p < one->npts; p++)
            pts += one->labels[p] == (int32_t)k;
        snprintf(line, sizeof line, "cluster %zu (%zu %s)", k, pts, plural(pts, "point", "points"));
        char cls[16];
        snprintf(cls, sizeof cls, "p%zu", k % PALETTE_N);
        legend_item(&tail, &x, &y, left, lim, cls, 1, line);
    }
    if (one && one->nclusters > listed) {
        snprintf(line, sizeof line, "and %zu more clusters (colours repeat)", one->nclusters - listed);
        legend_place(&x, &y, left, lim, 0, line);
        legend_label(&tail, &x, y, 0, line);
    }
    if (!one) { /* the palette in a row: cluster k of any object */
        const char *label = "clusters 0, 1, 2... of each object";
        double sw = 8.0 * PALETTE_N;
        legend_place(&x, &y, left, lim, sw, label);
        for (size_t k = 0; k < PALETTE_N; k++)
            sb_printf(&tail, "<circle class=\"p%zu\" cx=\"%.0f\" cy=\"%.0f\" r=\"3\"/>\n", k, x + 4 + 8.0 * (double)k,
                      y - 4);
        legend_label(&tail, &x, y, sw, label);
    }
    sb_puts(&tail, "</g>\n<g id=\"caption\">\n");
    y += LINE_H + 10;

    char sub[160] = "";
    if (wd->drawn < wd->points)
        snprintf(sub, sizeof sub, "; subsampled: %zu of %zu drawn, evenly spaced in id order", wd->drawn, wd->points);
    if (one) {
        char *name = one->name;
        sbuf t = {0};
        sb_printf(&t, "%s (object %lld): version %u of %u (%s%s), %u %s; version 1: %u %s", name, (long long)one->id,
                  one->version, one->nversions, one->reason, one->version == one->in_force ? ", in force" : "",
                  one->nboxes, plural(one->nboxes, "box", "boxes"), one->norig, plural(one->norig, "box", "boxes"));
        if (one->version != one->in_force)
            sb_printf(&t, "; version %u is in force", one->in_force);
        sb_text_line(&tail, left, &y, t.p);
        free(t.p);
        if (one->points_version != one->version)
            snprintf(line, sizeof line, "Points: the %zu collisions against version %u (its parent: what it answered)%s.",
                     one->npts, one->points_version, sub);
        else
            snprintf(line, sizeof line, "Points: the %zu collisions against version %u%s.", one->npts,
                     one->points_version, sub);
        sb_text_line(&tail, left, &y, line);
        if (one->has_run)
            snprintf(line, sizeof line,
                     "%zu %s, %zu noise: DBSCAN with the parameters of run %lld (eps %g m, min points %u, min users %u).",
                     one->nclusters, plural(one->nclusters, "cluster", "clusters"), one->noise,
                     (long long)one->run_id, one->prm.eps, one->prm.min_points, one->prm.min_users);
        else
            snprintf(line, sizeof line, "No clustering run over these collisions: every point is grey.");
        sb_text_line(&tail, left, &y, line);
    } else {
        snprintf(line, sizeof line, "World: %zu %s in the world, each at its version in force: %zu %s (version 1: %zu).",
                 wd->n, plural(wd->n, "object", "objects"), boxes, plural(boxes, "box", "boxes"), orig);
        sb_text_line(&tail, left, &y, line);
        snprintf(line, sizeof line,
                 "Points: %zu collisions (each object's against its version's parent, or the version)%s.", wd->points,
                 sub);
        sb_text_line(&tail, left, &y, line);
        snprintf(line, sizeof line,
                 "%zu %s, %zu noise: DBSCAN per object with its run's parameters (colours per object).", clusters,
                 plural(clusters, "cluster", "clusters"), noise);
        sb_text_line(&tail, left, &y, line);
    }
    unsigned long long cells = 0;
    for (size_t i = 0; i < wd->n; i++)
        cells += wd->o[i].voxels;
    char tight[32] = "-";
    if (uv > 0)
        snprintf(tight, sizeof tight, "%.3f", ov / uv);
    snprintf(line, sizeof line,
             "Volumes, world m\xc2\xb3: boxes %.3f (sum), their union %.3f, geometry %.3f (%llu occupied cells of "
             "2^%u per axis of %s MBR); tightness %s.",
             bv, uv, ov, cells, MAP_DEPTH, one ? "the" : "each", tight);
    sb_text_line(&tail, left, &y, line);
    sb_puts(&tail, "</g>\n");
    double height = y - LINE_H + PAGE_MARGIN;

    sb_puts(b, "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
    sb_puts(b, "<svg xmlns=\"http://www.w3.org/2000/svg\" version=\"1.1\" width=\"");
    sb_num(b, width);
    sb_puts(b, "\" height=\"");
    sb_num(b, height);
    sb_puts(b, "\" viewBox=\"0 0 ");
    sb_num(b, width);
    sb_puts(b, " ");
    sb_num(b, height);
    sb_puts(b, "\">\n<title>cvre collision map: ");
    if (one) {
        sb_xml(b, one->name);
        sb_printf(b, " (object %lld), version %u", (long long)one->id, one->version);
    } else {
        sb_puts(b, "the world");
    }
    sb_puts(b, "</title>\n<desc>Drawn by cvre-admin map. TOP and SIDE views in world metres: the geometry's "
               "outline, the original boxes (dashed), the boxes shown (filled) and the collision points, "
               "coloured by cluster.</desc>\n");
    sb_puts(b, "<style type=\"text/css\">\n"
               "text{font-family:'DejaVu Sans',Arial,sans-serif;font-size:12px;fill:#222}\n"
               ".title{font-size:13px;font-weight:bold}\n"
               ".label{font-size:10px;fill:#444}\n"
               ".background{fill:#fff}\n"
               ".frame{fill:#fafafa;stroke:#999;stroke-width:1}\n"
               ".outline{fill:#d0d0d0;shape-rendering:crispEdges}\n"
               ".box,.swatch-box{fill:#1f77b4;fill-opacity:0.22;stroke:#1f4e99;stroke-width:1}\n"
               ".box-original,.swatch-original{fill:none;stroke:#333;stroke-width:1;stroke-dasharray:5 3}\n"
               ".noise{fill:#9a9a9a}\n"
               ".scale path{fill:none;stroke:#222;stroke-width:1.5}\n");
    for (size_t k = 0; k < PALETTE_N; k++)
        sb_printf(b, ".p%zu{fill:%s}\n", k, palette[k]);
    sb_puts(b, "</style>\n<rect class=\"background\" x=\"0\" y=\"0\" width=\"");
    sb_num(b, width);
    sb_puts(b, "\" height=\"");
    sb_num(b, height);
    sb_puts(b, "\"/>\n");
    for (int i = 0; i < 2; i++)
        sb_view(b, &views[i], wd);
    sb_put(b, tail.p, tail.len);
    sb_puts(b, "</svg>\n");
    free(tail.p);
}

/* The views' world rectangles (everything drawn, and a margin), their
 * common scale, frames and outline masks. */
static void layout(world *wd, view *views)
{
    double mn[3] = {INFINITY, INFINITY, INFINITY}, mx[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t i = 0; i < wd->n; i++) {
        const mobj *o = &wd->o[i];
        double a[3], c[3];
        box_world(o, o->mbr, a, c);
        for (int k = 0; k < 3; k++)
            mn[k] = fmin(mn[k], a[k]), mx[k] = fmax(mx[k], c[k]);
        for (int set = 0; set < 2; set++)
            for (uint32_t j = 0; j < (set ? o->norig : o->nboxes); j++) {
                box_world(o, set ? o->orig[j] : o->boxes[j], a, c);
                for (int k = 0; k < 3; k++)
                    mn[k] = fmin(mn[k], a[k]), mx[k] = fmax(mx[k], c[k]);
            }
        for (size_t p = 0; p < o->npts; p++) {
            to_world(o, o->xyz + 3 * p, a);
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
        v->oy = PAGE_MARGIN + TITLE_H;
        v->cell = fmax(v->u1 - v->u0, v->v1 - v->v0) / MAP_MASK_CELLS;
        v->cols = (uint32_t)fmin(MAP_MASK_CELLS, ceil((v->u1 - v->u0) / v->cell));
        v->rows = (uint32_t)fmin(MAP_MASK_CELLS, ceil((v->v1 - v->v0) / v->cell));
        if (v->cols < 1)
            v->cols = 1;
        if (v->rows < 1)
            v->rows = 1;
        v->mask = cvre_xcalloc((size_t)v->cols * v->rows, 1);
    }
    views[0].ox = PAGE_MARGIN;
    /* The titles need about 430 px: the views keep that apart at least. */
    views[1].ox = PAGE_MARGIN + fmax(views[0].w, 430) + PAGE_GAP;
}

/* ---- the figures on stdout ---- */

static void figures_json(sbuf *b, const mobj *o, size_t drawn)
{
    sb_printf(b, "{\"object\": %lld, \"name\": ", (long long)o->id);
    sb_json(b, o->name);
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

static void figures_table(sbuf *b, const world *wd)
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

/* ---- the command ---- */

static int write_file(const char *path, const sbuf *b, char *err, size_t errlen)
{
    FILE *f = fopen(path, "wb");
    if (!f)
        return query_fail(err, errlen, QUERY_ERROR, "cannot write the picture %s: %s", path, strerror(errno));
    size_t n = fwrite(b->p, 1, b->len, f);
    int e = n == b->len ? 0 : errno;
    if (fclose(f) != 0 && !e)
        e = errno;
    if (n != b->len || e)
        return query_fail(err, errlen, QUERY_ERROR, "cannot write the picture %s: %s", path, strerror(e ? e : EIO));
    return QUERY_OK;
}

#define OBJECT_COLUMNS                                                                                     \
    "SELECT id, name, pos_x, pos_y, pos_z, yaw, scale, ecm_version, tri_count, min_x, min_y, min_z, max_x, " \
    "max_y, max_z, removed_at IS NOT NULL FROM objects "

int map_run(db *d, const map_request *r, char *err, size_t errlen)
{
    sqlite3 *s = db_sqlite(d);
    reader rd = {.d = d, .s = s, .err = err, .errlen = errlen};
    world wd = {.object_mode = r->has_object};
    view views[2] = {{0}, {0}};
    sqlite3_stmt *objs = NULL;
    size_t cap = 0;
    int rc = QUERY_OK, step;

    if (sqlite3_exec(s, "BEGIN", NULL, NULL, NULL) != SQLITE_OK)
        return query_fail(err, errlen, QUERY_ERROR, "cannot start a read transaction: %s", sqlite3_errmsg(s));
    int in_tx = 1;
    /* The run whose parameters label the points: the one that made the
     * version shown; else the latest with clusters over the collisions
     * drawn (?3), else over the version shown (?2). */
    if (sqlite3_prepare_v2(s, r->has_object ? OBJECT_COLUMNS "WHERE id = ?1"
                                            : OBJECT_COLUMNS "WHERE removed_at IS NULL ORDER BY id",
                           -1, &objs, NULL) != SQLITE_OK ||
        sqlite3_prepare_v2(s, "SELECT reason, parent_version FROM ecm_versions "
                              "WHERE object_id = ?1 AND version = ?2", -1, &rd.version, NULL) != SQLITE_OK ||
        sqlite3_prepare_v2(s, "SELECT count(*), coalesce(max(version), 0) FROM ecm_versions WHERE object_id = ?1", -1,
                           &rd.nversions, NULL) != SQLITE_OK ||
        sqlite3_prepare_v2(s, "SELECT id, eps, min_points, min_users FROM cluster_runs WHERE id = coalesce("
                              "(SELECT run_id FROM ecm_versions WHERE object_id = ?1 AND version = ?2), "
                              "(SELECT max(run_id) FROM clusters WHERE object_id = ?1 AND ecm_version = ?3), "
                              "(SELECT max(run_id) FROM clusters WHERE object_id = ?1 AND ecm_version = ?2))",
                           -1, &rd.run, NULL) != SQLITE_OK ||
        /* An object's collisions of one version through its groups (the
         * by-object index), the segments of their buckets and the id
         * ranges those cover: no scan of the whole log. In id order, as
         * cvre-cluster reads them, so that cluster ids match its own. */
        sqlite3_prepare_v2(s, "SELECT c.local_x, c.local_y, c.local_z, coalesce(c.user_id, -c.session_id) "
                              "FROM (SELECT DISTINCT bucket FROM collision_groups WHERE object_id = ?1 "
                              "AND ecm_version = ?2) b JOIN collision_segments g ON g.bucket = b.bucket "
                              "JOIN collisions c ON c.id BETWEEN g.first_id AND g.last_id "
                              "WHERE c.object_id = ?1 AND c.ecm_version = ?2 ORDER BY c.id",
                           -1, &rd.points, NULL) != SQLITE_OK) {
        rc = db_fail(&rd);
        goto cleanup;
    }
    if (r->has_object)
        sqlite3_bind_int64(objs, 1, r->object);
    while ((step = sqlite3_step(objs)) == SQLITE_ROW) {
        if (wd.n == cap) {
            cap = cap ? cap * 2 : 16;
            wd.o = cvre_xrealloc(wd.o, cap * sizeof *wd.o);
        }
        mobj *o = &wd.o[wd.n++];
        *o = (mobj){.id = sqlite3_column_int64(objs, 0), .name = dup_text(objs, 1)};
        for (int k = 0; k < 3; k++)
            o->pos[k] = sqlite3_column_double(objs, 2 + k);
        o->yaw = sqlite3_column_double(objs, 5);
        o->scale = sqlite3_column_double(objs, 6);
        int64_t in_force = sqlite3_column_int64(objs, 7), tris = sqlite3_column_int64(objs, 8);
        for (int k = 0; k < 6; k++)
            o->mbr[k] = (float)sqlite3_column_double(objs, 9 + k);
        if (sqlite3_column_int(objs, 15)) {
            rc = query_fail(err, errlen, QUERY_NOT_FOUND, "object %lld was removed from the world", (long long)o->id);
            goto cleanup;
        }
        if (in_force < 1 || in_force > UINT32_MAX || tris < 0 || tris > UINT32_MAX / 9 ||
            !(o->scale > 0) || !isfinite(o->yaw)) {
            rc = query_fail(err, errlen, QUERY_ERROR, "object %lld: stored placement or counts out of range",
                      (long long)o->id);
            goto cleanup;
        }
        o->in_force = (uint32_t)in_force;
        o->tri_count = (uint32_t)tris;
        o->version = r->has_object && r->version ? r->version : o->in_force;
    }
    if (step != SQLITE_DONE) {
        rc = db_fail(&rd);
        goto cleanup;
    }
    if (r->has_object && wd.n == 0) {
        rc = query_fail(err, errlen, QUERY_NOT_FOUND, "no object with id %lld", (long long)r->object);
        goto cleanup;
    }
    for (size_t i = 0; i < wd.n && rc == QUERY_OK; i++) {
        rc = read_object(&rd, &wd.o[i]);
        wd.points += wd.o[i].npts;
    }
    if (rc != QUERY_OK)
        goto cleanup;
    wd.drawn = wd.points < MAP_POINTS_MAX ? wd.points : MAP_POINTS_MAX;
    layout(&wd, views);
    for (size_t i = 0; i < wd.n && rc == QUERY_OK; i++) {
        mobj *o = &wd.o[i];
        double sc3 = o->scale * o->scale * o->scale;
        o->box_volume = box_volume((const float(*)[6])o->boxes, o->nboxes) * sc3;
        o->union_volume = union_volume((const float(*)[6])o->boxes, o->nboxes) * sc3;
        rc = mesh_object(&rd, o, views, 2);
        if (rc == QUERY_OK)
            rc = cluster_object(o, err, errlen);
    }
    if (rc != QUERY_OK)
        goto cleanup;
    sqlite3_exec(s, "COMMIT", NULL, NULL, NULL); /* read-only: nothing to lose */
    in_tx = 0;

    if (r->svg) {
        sbuf svg = {0};
        build_svg(&svg, &wd, views);
        rc = write_file(r->svg, &svg, err, errlen);
        free(svg.p);
        if (rc != QUERY_OK)
            goto cleanup;
    }
    sbuf out = {0};
    if (r->json) {
        size_t g = 0;
        if (!r->has_object)
            sb_puts(&out, "[");
        for (size_t i = 0; i < wd.n; i++) {
            size_t drawn = 0;
            for (size_t p = 0; p < wd.o[i].npts; p++)
                drawn += (size_t)drawn_point(g + p, wd.points, wd.drawn);
            g += wd.o[i].npts;
            sb_puts(&out, i ? ",\n" : r->has_object ? "" : "\n");
            figures_json(&out, &wd.o[i], drawn);
        }
        sb_puts(&out, r->has_object ? "\n" : wd.n ? "\n]\n" : "]\n");
    } else {
        figures_table(&out, &wd);
    }
    if (fwrite(out.p, 1, out.len, stdout) != out.len || fflush(stdout) != 0)
        rc = query_fail(err, errlen, QUERY_ERROR, "cannot write the output");
    free(out.p);

cleanup:
    if (in_tx)
        sqlite3_exec(s, "COMMIT", NULL, NULL, NULL);
    sqlite3_finalize(objs);
    sqlite3_finalize(rd.version);
    sqlite3_finalize(rd.nversions);
    sqlite3_finalize(rd.run);
    sqlite3_finalize(rd.points);
    for (size_t i = 0; i < wd.n; i++)
        mobj_free(&wd.o[i]);
    free(wd.o);
    free(views[0].mask);
    free(views[1].mask);
    return rc;
}
