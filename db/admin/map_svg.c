/*
 * map_svg.c: the picture `cvre-admin map` draws (mapInt.h): two views side
 * by side, each with its title, frame, outline, boxes and points, the world
 * map's object labels, then legend and caption.
 *
 * The page is as large as what it holds: text widths are estimated (no
 * font is measured here) from the number of characters, generously, and
 * the page grows to the widest title, caption line or label. The world
 * map's labels are placed so that none overlaps another: each tries a few
 * places around its object's box, then rings further out with a leader
 * line; one that finds no room is listed under the caption instead.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "mapInt.h"
#include "utf8.h"

/* Page layout in px. */
#define PAGE_MARGIN 20.0
#define PAGE_GAP 50.0      /* between the two views */
#define PAGE_MIN_W 760.0   /* the least: legend lines wrap at it */
#define TITLE_H 24.0       /* a view's title above its frame */
#define LINE_H 16.0        /* legend and caption lines */

/* Cluster colours: distinct from the boxes' blue and from the noise grey. */
static const char *const palette[] = {"#d62728", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2",
                                      "#bcbd22", "#17becf", "#7f0000", "#e6ab02", "#1b5e20", "#c51b7d"};
#define PALETTE_N (sizeof palette / sizeof palette[0])

/* Text sizes (the style sheet's) and estimated widths: DejaVu Sans, the
 * font asked for, averages about 0.55 em a character in running text,
 * bold a little more; these err on the wide side so that nothing is cut. */
#define TEXT_PX 12.0
#define TITLE_PX 13.0
#define LABEL_PX 10.0
#define TEXT_EM 0.62
#define TITLE_EM 0.68
/* A label's box: from the baseline up 10 px, down 3 px. */
#define LABEL_ASCENT 10.0
#define LABEL_H 13.0
/* Characters of a name shown in a label (longer ones end in an ellipsis). */
#ifndef MAP_LABEL_NAME_MAX
#define MAP_LABEL_NAME_MAX 32u
#endif
/* Rings of places tried around an object before its label is listed under
 * the caption instead: 8 rings of 16 places reach about 130 px out. */
#ifndef MAP_LABEL_RINGS
#define MAP_LABEL_RINGS 8
#endif
_Static_assert(MAP_LABEL_NAME_MAX >= 8u && MAP_LABEL_NAME_MAX <= 256u, "a label that names its object");
_Static_assert(MAP_LABEL_RINGS >= 0 && MAP_LABEL_RINGS <= 64, "places a label may go");

/* The page's right edge as far as its content is laid out. */
typedef struct page {
    double right;
} page;

/* Characters a UTF-8 text shows (continuation bytes take none). */
static size_t text_chars(const char *s)
{
    size_t n = 0;
    for (; *s; s++)
        n += ((unsigned char)*s & 0xc0) != 0x80;
    return n;
}

/* The estimated width of s in px, per_char px a character. */
static double text_w(const char *s, double per_char)
{
    return per_char * (double)text_chars(s);
}

/* Notes a text drawn from x, per_char px a character. */
static void page_text(page *pg, double x, const char *s, double per_char)
{
    pg->right = fmax(pg->right, x + text_w(s, per_char));
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

/* Text as XML character data or attribute value: the five special
 * characters escaped; control characters (not allowed in XML 1.0) and
 * bytes that are not UTF-8 become '?', so any stored name gives a
 * well-formed file. */
static void sb_xml(sbuf *b, const char *text)
{
    const uint8_t *s = (const uint8_t *)text;
    size_t n = strlen(text);
    for (size_t i = 0; i < n;) {
        uint8_t c = s[i];
        uint32_t cp;
        size_t k = utf8_next(s + i, n - i, &cp);
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
        default: sb_put(b, text + i, k);
        }
        i += k;
    }
}

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

/* ---- the world map's labels ---- */

/* A label: where one object's label goes: its text, its box (top left x, t; w) and,
 * away from the object, a leader line from (lx0, ly0) to (lx1, ly1). */
typedef struct tag {
    char text[16 + 4 * MAP_LABEL_NAME_MAX + 4];
    double x, t, w;
    int placed, leader;
    double lx0, ly0, lx1, ly1;
} tag;

/* "#id name", the name cut at MAP_LABEL_NAME_MAX characters. */
static void label_text(tag *l, const mobj *o)
{
    size_t n = 0, chars = 0;
    int len = snprintf(l->text, sizeof l->text, "#%lld ", (long long)o->id);
    while (o->name[n] && chars < MAP_LABEL_NAME_MAX) {
        n++;
        while (((unsigned char)o->name[n] & 0xc0) == 0x80)
            n++;
        chars++;
    }
    snprintf(l->text + len, sizeof l->text - (size_t)len, "%.*s%s", (int)n, o->name,
             o->name[n] ? "\xe2\x80\xa6" : "");
}

static int boxes_meet(double x0, double t0, double w0, double x1, double t1, double w1)
{
    return x0 < x1 + w1 + 1 && x1 < x0 + w0 + 1 && t0 < t1 + LABEL_H + 1 && t1 < t0 + LABEL_H + 1;
}

/* Whether a label at (x, t), w wide, fits the frame of v and meets none of
 * the n placed before it. */
static int label_fits(const tag *placed, size_t n, const view *v, double x, double t, double w)
{
    if (x < v->ox + 1 || x + w > v->ox + v->w - 1 || t < v->oy + 1 || t + LABEL_H > v->oy + v->h - 1)
        return 0;
    for (size_t i = 0; i < n; i++)
        if (placed[i].placed && boxes_meet(x, t, w, placed[i].x, placed[i].t, placed[i].w))
            return 0;
    return 1;
}

/* Places the label of every object of wd in the TOP view v, in id order,
 * greedily: first beside the object's box (above, below, right, left),
 * then on rings further out, each farther by a label's height, 16 places
 * a ring, with a leader line back to the box. A label with no room stays
 * unplaced (sb_unlabelled lists it). Deterministic: the same world gives
 * the same places. */
static void place_labels(tag *labels, const world *wd, const view *v)
{
    for (size_t i = 0; i < wd->n; i++) {
        const mobj *o = &wd->o[i];
        tag *l = &labels[i];
        double mn[3], mx[3];
        map__box_world(o, o->mbr, mn, mx);
        double ax0 = px_u(v, mn[0]), ax1 = px_u(v, mx[0]), ay0 = px_v(v, mn[2]), ay1 = px_v(v, mx[2]);
        double cx = (ax0 + ax1) / 2, cy = (ay0 + ay1) / 2;
        label_text(l, o);
        double w = text_w(l->text, LABEL_PX * TEXT_EM) + 2, h = LABEL_H;
        const double beside[][2] = {{ax0, ay0 - h - 1}, {ax0, ay1 + 1},     {ax1 - w, ay0 - h - 1}, {ax1 - w, ay1 + 1},
                                    {ax1 + 2, ay0},     {ax0 - w - 2, ay0}, {ax1 + 2, ay1 - h},     {ax0 - w - 2, ay1 - h}};
        for (size_t k = 0; k < sizeof beside / sizeof beside[0] && !l->placed; k++)
            if (label_fits(labels, i, v, beside[k][0], beside[k][1], w))
                l->x = beside[k][0], l->t = beside[k][1], l->placed = 1;
        double reach = hypot(ax1 - ax0, ay1 - ay0) / 2;
        for (int ring = 1; ring <= MAP_LABEL_RINGS && !l->placed; ring++)
            for (int k = 0; k < 16 && !l->placed; k++) {
                double a = k * 0.39269908169872414 /* pi / 8 */, d = reach + ring * (h + 4);
                double x = cx + d * cos(a) - w / 2, t = cy + d * sin(a) - h / 2;
                if (!label_fits(labels, i, v, x, t, w))
                    continue;
                l->x = x, l->t = t, l->placed = 1, l->leader = 1;
                /* From the label's point nearest the box to the box's point
                 * nearest the label's centre. */
                l->lx1 = fmin(fmax(x + w / 2, ax0), ax1), l->ly1 = fmin(fmax(t + h / 2, ay0), ay1);
                l->lx0 = fmin(fmax(l->lx1, x), x + w), l->ly0 = fmin(fmax(l->ly1, t), t + h);
            }
        l->w = w;
    }
}

static void sb_label(page *pg, sbuf *b, const tag *l)
{
    if (l->leader) {
        sb_puts(b, "<path class=\"leader\" d=\"M");
        sb_num(b, l->lx0);
        sb_puts(b, " ");
        sb_num(b, l->ly0);
        sb_puts(b, "L");
        sb_num(b, l->lx1);
        sb_puts(b, " ");
        sb_num(b, l->ly1);
        sb_puts(b, "\"/>\n");
    }
    sb_puts(b, "<text class=\"label\" x=\"");
    sb_num(b, l->x + 1);
    sb_puts(b, "\" y=\"");
    sb_num(b, l->t + LABEL_ASCENT);
    sb_puts(b, "\">");
    sb_xml(b, l->text);
    sb_puts(b, "</text>\n");
    page_text(pg, l->x + 1, l->text, LABEL_PX * TEXT_EM);
}

static const char *view_title(const view *v)
{
    return v->up ? "SIDE (looking along \xe2\x88\x92z): world x \xe2\x86\x92 right, world y \xe2\x86\x91 up"
                 : "TOP (looking down): world x \xe2\x86\x92 right, world z \xe2\x86\x93 down the page";
}

static void sb_view_title(page *pg, sbuf *b, const view *v)
{
    sb_puts(b, "<text class=\"title\" x=\"");
    sb_num(b, v->ox);
    sb_puts(b, "\" y=\"");
    sb_num(b, v->oy - 8);
    sb_printf(b, "\">%s</text>\n", view_title(v));
    page_text(pg, v->ox, view_title(v), TITLE_PX * TITLE_EM);
}

static void sb_scale_bar(page *pg, sbuf *b, const view *v)
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
    char text[32];
    snprintf(text, sizeof text, "%g m", len);
    sb_printf(b, "\">%s</text></g>\n", text);
    page_text(pg, x1 + 6, text, TEXT_PX * TEXT_EM);
}

/* One view; labels (the world map's TOP view only, else NULL) as placed
 * by place_labels. */
static void sb_view(page *pg, sbuf *b, const view *v, const world *wd, const tag *labels)
{
    sb_printf(b, "<g id=\"%s\" class=\"view\">\n", v->id);
    sb_view_title(pg, b, v);
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
            map__box_world(o, o->boxes[k], mn, mx);
            sb_puts(b, "<rect class=\"box\"");
            sb_rect_attrs(b, v, mn[0], mx[0], mn[v->va], mx[v->va]);
            sb_puts(b, "/>\n");
        }
        for (uint32_t k = 0; k < o->norig; k++) {
            map__box_world(o, o->orig[k], mn, mx);
            sb_puts(b, "<rect class=\"box-original\"");
            sb_rect_attrs(b, v, mn[0], mx[0], mn[v->va], mx[v->va]);
            sb_puts(b, "/>\n");
        }
        /* Noise first, clusters over it. */
        sb_puts(b, "<g class=\"points\">\n");
        for (int pass = 0; pass < 2; pass++)
            for (size_t p = 0; p < o->npts; p++) {
                int32_t l = o->labels[p];
                if ((pass == 0) != (l < 0) || !map__drawn_point(g + p, wd->points, wd->drawn))
                    continue;
                double w[3];
                map__to_world(o, o->xyz + 3 * p, w);
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
        if (labels && labels[i].placed)
            sb_label(pg, b, &labels[i]);
        sb_puts(b, "</g>\n");
        g += o->npts;
    }
    sb_scale_bar(pg, b, v);
    sb_puts(b, "</g>\n");
}

/* Where the next legend entry goes: at (*x, *y) unless its width w (its
 * swatch, sw px, and label) would pass `right`, then at the start of the
 * next line. */
static void legend_place(double *x, double *y, double left, double right, double sw, const char *label)
{
    double w = sw + 6 + text_w(label, TEXT_PX * TEXT_EM) + 18;
    if (*x > left && *x + w > right)
        *x = left, *y += LINE_H + 2;
}

/* The label of a legend entry whose swatch (sw px wide) is drawn; moves
 * *x past the entry. */
static void legend_label(page *pg, sbuf *b, double *x, double y, double sw, const char *label)
{
    sb_printf(b, "<text x=\"%.0f\" y=\"%.0f\">", *x + sw + 6, y);
    sb_xml(b, label);
    sb_puts(b, "</text>\n");
    page_text(pg, *x + sw + 6, label, TEXT_PX * TEXT_EM);
    *x += sw + 6 + text_w(label, TEXT_PX * TEXT_EM) + 18;
}

/* A legend entry with a 16 x 10 swatch: a rect of class cls, or a dot
 * (dot != 0). */
static void legend_item(page *pg, sbuf *b, double *x, double *y, double left, double right, const char *cls, int dot,
                        const char *label)
{
    legend_place(x, y, left, right, 16, label);
    if (dot)
        sb_printf(b, "<circle class=\"%s\" cx=\"%.0f\" cy=\"%.0f\" r=\"3\"/>\n", cls, *x + 8, *y - 4);
    else
        sb_printf(b, "<rect class=\"%s\" x=\"%.0f\" y=\"%.0f\" width=\"16\" height=\"10\"/>\n", cls, *x, *y - 9);
    legend_label(pg, b, x, *y, 16, label);
}

static void sb_text_line(page *pg, sbuf *b, double x, double *y, const char *text)
{
    sb_printf(b, "<text x=\"%.0f\" y=\"%.0f\">", x, *y);
    sb_xml(b, text);
    sb_puts(b, "</text>\n");
    page_text(pg, x, text, TEXT_PX * TEXT_EM);
    *y += LINE_H;
}

/* The labels that found no room, as caption lines that wrap at `right`. */
static void sb_unlabelled(page *pg, sbuf *b, const tag *labels, const world *wd, double left, double right, double *y)
{
    sbuf line = {0};
    size_t left_out = 0;
    for (size_t i = 0; i < wd->n; i++)
        left_out += !labels[i].placed;
    if (left_out == 0)
        return;
    sb_printf(&line, "No room in TOP for the label%s of:", left_out == 1 ? "" : "s");
    for (size_t i = 0; i < wd->n; i++) {
        if (labels[i].placed)
            continue;
        if (line.len && left + text_w(line.p, TEXT_PX * TEXT_EM) + text_w(labels[i].text, TEXT_PX * TEXT_EM) + 8 > right) {
            sb_text_line(pg, b, left, y, line.p);
            sb_clear(&line);
        }
        sb_printf(&line, "%s%s", line.len ? " " : "", labels[i].text);
    }
    sb_text_line(pg, b, left, y, line.p);
    sb_free(&line);
}

static const char *plural(size_t n, const char *one, const char *many)
{
    return n == 1 ? one : many;
}

void map__svg(sbuf *b, const world *wd, view *views)
{
    /* The frames: SIDE right of TOP, TOP's title, or TOP, whichever is wider. */
    for (int i = 0; i < 2; i++)
        views[i].oy = PAGE_MARGIN + TITLE_H;
    views[0].ox = PAGE_MARGIN;
    views[1].ox = PAGE_MARGIN + fmax(views[0].w, text_w(view_title(&views[0]), TITLE_PX * TITLE_EM)) + PAGE_GAP;
    page pg = {.right = views[1].ox + views[1].w};
    double width = fmax(pg.right + PAGE_MARGIN, PAGE_MIN_W);
    double y = fmax(views[0].oy + views[0].h, views[1].oy + views[1].h) + 44;

    /* The views, then legend and caption, each into a buffer of its own:
     * the page's size is known once they are laid out. */
    tag *labels = wd->object_mode ? NULL : cvre_xcalloc(wd->n ? wd->n : 1, sizeof *labels);
    if (labels)
        place_labels(labels, wd, &views[0]);
    sbuf body = {0};
    for (int i = 0; i < 2; i++)
        sb_view(&pg, &body, &views[i], wd, i == 0 ? labels : NULL);
    size_t boxes = 0, orig = 0, clusters = 0, noise = 0;
    double bv = 0, uv = 0, ov = 0;
    for (size_t i = 0; i < wd->n; i++) {
        boxes += wd->o[i].nboxes, orig += wd->o[i].norig, clusters += wd->o[i].nclusters;
        noise += wd->o[i].noise;
        bv += wd->o[i].box_volume, uv += wd->o[i].union_volume, ov += wd->o[i].occupied_volume;
    }
    const mobj *one = wd->object_mode ? &wd->o[0] : NULL;
    char line[1024];

    sbuf tail = {0};
    double x = PAGE_MARGIN, left = PAGE_MARGIN, lim = width - PAGE_MARGIN;
    sb_puts(&tail, "<g id=\"legend\">\n");
    legend_item(&pg, &tail, &x, &y, left, lim, "outline", 0, "geometry (triangles, projected)");
    legend_item(&pg, &tail, &x, &y, left, lim, "swatch-original", 0, "original boxes (version 1)");
    if (one)
        snprintf(line, sizeof line, "boxes of version %u", one->version);
    else
        snprintf(line, sizeof line, "boxes in force");
    legend_item(&pg, &tail, &x, &y, left, lim, "swatch-box", 0, line);
    legend_item(&pg, &tail, &x, &y, left, lim, "noise", 1, "noise (no cluster)");
    size_t listed = one ? (one->nclusters < MAP_LEGEND_CLUSTERS ? one->nclusters : MAP_LEGEND_CLUSTERS) : 0;
    for (size_t k = 0; k < listed; k++) {
        size_t pts = 0;
        for (size_t p = 0; p < one->npts; p++)
            pts += one->labels[p] == (int32_t)k;
        snprintf(line, sizeof line, "cluster %zu (%zu %s)", k, pts, plural(pts, "point", "points"));
        char cls[16];
        snprintf(cls, sizeof cls, "p%zu", k % PALETTE_N);
        legend_item(&pg, &tail, &x, &y, left, lim, cls, 1, line);
    }
    if (one && one->nclusters > listed) {
        snprintf(line, sizeof line, "and %zu more clusters (colours repeat)", one->nclusters - listed);
        legend_place(&x, &y, left, lim, 0, line);
        legend_label(&pg, &tail, &x, y, 0, line);
    }
    if (!one) { /* the palette in a row: cluster k of any object */
        const char *label = "clusters 0, 1, 2... of each object";
        double sw = 8.0 * PALETTE_N;
        legend_place(&x, &y, left, lim, sw, label);
        for (size_t k = 0; k < PALETTE_N; k++)
            sb_printf(&tail, "<circle class=\"p%zu\" cx=\"%.0f\" cy=\"%.0f\" r=\"3\"/>\n", k, x + 4 + 8.0 * (double)k,
                      y - 4);
        legend_label(&pg, &tail, &x, y, sw, label);
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
        sb_text_line(&pg, &tail, left, &y, t.p);
        sb_free(&t);
        if (one->points_version != one->version)
            snprintf(line, sizeof line, "Points: the %zu collisions against version %u (its parent: what it answered)%s.",
                     one->npts, one->points_version, sub);
        else
            snprintf(line, sizeof line, "Points: the %zu collisions against version %u%s.", one->npts,
                     one->points_version, sub);
        sb_text_line(&pg, &tail, left, &y, line);
        if (one->has_run)
            snprintf(line, sizeof line,
                     "%zu %s, %zu noise: DBSCAN with the parameters of run %lld (eps %g m, min points %u, min users %u).",
                     one->nclusters, plural(one->nclusters, "cluster", "clusters"), one->noise,
                     (long long)one->run_id, one->prm.eps, one->prm.min_points, one->prm.min_users);
        else
            snprintf(line, sizeof line, "No clustering run over these collisions: every point is grey.");
        sb_text_line(&pg, &tail, left, &y, line);
    } else {
        snprintf(line, sizeof line, "World: %zu %s in the world, each at its version in force: %zu %s (version 1: %zu).",
                 wd->n, plural(wd->n, "object", "objects"), boxes, plural(boxes, "box", "boxes"), orig);
        sb_text_line(&pg, &tail, left, &y, line);
        snprintf(line, sizeof line,
                 "Points: %zu collisions (each object's against its version's parent, or the version)%s.", wd->points,
                 sub);
        sb_text_line(&pg, &tail, left, &y, line);
        snprintf(line, sizeof line,
                 "%zu %s, %zu noise: DBSCAN per object with its run's parameters (colours per object).", clusters,
                 plural(clusters, "cluster", "clusters"), noise);
        sb_text_line(&pg, &tail, left, &y, line);
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
    sb_text_line(&pg, &tail, left, &y, line);
    if (labels)
        sb_unlabelled(&pg, &tail, labels, wd, left, lim, &y);
    sb_puts(&tail, "</g>\n");
    free(labels);
    double height = y - LINE_H + PAGE_MARGIN;
    width = fmax(width, pg.right + PAGE_MARGIN);

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
               ".leader{fill:none;stroke:#777;stroke-width:0.6}\n"
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
    sb_put(b, body.p, body.len);
    sb_put(b, tail.p, tail.len);
    sb_puts(b, "</svg>\n");
    sb_free(&body);
    sb_free(&tail);
}
