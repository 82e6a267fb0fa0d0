/*
 * fuzz_ply.c: structure-aware fuzz target for PLY uploads: the importer's
 * PLY pre-check (server/import/import_ply.c, which walks the body the
 * header declares) and Assimp's PLY reader.
 *
 * Inputs are PLY files, ASCII or binary of either byte order. The mutator
 * parses the header into elements and properties and changes it: a count
 * made hostile (4000000000, 4294967296, -1, one more or less than the
 * data), a property's type or a list's count type changed (float counts,
 * signed chars), properties added or dropped, the format switched under
 * the same body, lines Assimp skips or misreads (comments, obj_info, CR).
 * Or it rewrites the body from the header, values as the types say, with
 * NaN, 1e38 and indices out of range now and then, lists of 0 or 255; or
 * changes body bytes or text. The generator writes a header (vertices with
 * positions and maybe normals and colours, faces as lists, now and then
 * another element) and its body. Each input is imported with the hint
 * "ply" and with none (fz_import.c).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fz.h"

#define ELEMS_MAX 8
#define PROPS_MAX 12
#define WORD_MAX 24

/* Instances written per element when the body is made from the header:
 * a count past this (4e9) is written as a header claim only. */
#define BODY_INSTANCES_MAX 300

typedef struct prop {
    char type[WORD_MAX];
    char count_type[WORD_MAX]; /* "" for a scalar */
    char name[WORD_MAX];
} prop;

typedef struct elem {
    char name[WORD_MAX];
    char count[WORD_MAX]; /* as written, which may be no number at all */
    prop props[PROPS_MAX];
    int nprops;
} elem;

typedef struct ply {
    int format; /* 0 ascii, 1 binary_little_endian, 2 binary_big_endian */
    elem elems[ELEMS_MAX];
    int nelems;
    const char *extra; /* a line put before end_header, or NULL */
    const uint8_t *body;
    size_t body_len;
} ply;

static const char *const formats[] = {"ascii", "binary_little_endian", "binary_big_endian"};
static const char *const types[] = {"char",   "uchar", "short",  "ushort",  "int",     "uint",
                                    "float",  "double", "int8",  "uint8",   "int16",   "uint16",
                                    "int32",  "uint32", "float32", "float64", "float128", "list"};
#define NTYPES (sizeof types / sizeof types[0])

static const char *const templates[] = {"%f %f %f", "3 %i %i %i", "4 %i %i %i %i", "%f %f %f %c %c %c",
                                        "255 %i %i", "0", "%c", "-1 %i", "3 %i %i", "%f"};

static void word(char *to, const char *from, size_t n)
{
    if (n >= WORD_MAX)
        n = WORD_MAX - 1;
    memcpy(to, from, n);
    to[n] = 0;
}

/* Size in bytes of a type name, 0 if it is not one. */
static int type_size(const char *t)
{
    static const char *const names[] = {"char",  "uchar", "int8",    "uint8",   "short",  "ushort",
                                        "int16", "uint16", "int",    "uint",    "int32",  "uint32",
                                        "float", "float32", "double", "float64"};
    static const int sizes[] = {1, 1, 1, 1, 2, 2, 2, 2, 4, 4, 4, 4, 4, 4, 8, 8};

    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++)
        if (strcmp(t, names[i]) == 0)
            return sizes[i];
    return 0;
}

static int is_float(const char *t) { return t[0] == 'f' || t[0] == 'd'; }

/* Reads the header of p[0..n) into f, the body after it as is. 0 if p is
 * not a PLY file with an end_header line. */
static int ply_read(const uint8_t *p, size_t n, ply *f)
{
    size_t at = 0;

    memset(f, 0, sizeof *f);
    if (n < 4 || memcmp(p, "ply", 3) != 0)
        return 0;
    while (at < n) {
        const char *w[6];
        size_t wl[6], k = 0, eol = at, i;
        while (eol < n && p[eol] != '\n')
            eol++;
        for (i = at; i < eol && k < 6;) {
            while (i < eol && (p[i] == ' ' || p[i] == '\t' || p[i] == '\r'))
                i++;
            if (i == eol)
                break;
            w[k] = (const char *)p + i;
            while (i < eol && p[i] != ' ' && p[i] != '\t' && p[i] != '\r')
                i++;
            wl[k] = (size_t)((const char *)p + i - w[k]);
            k++;
        }
        at = eol < n ? eol + 1 : n;
        if (k == 0)
            continue;
        if (wl[0] == 10 && memcmp(w[0], "end_header", 10) == 0) {
            f->body = p + at;
            f->body_len = n - at;
            return 1;
        }
        if (k >= 2 && wl[0] == 6 && memcmp(w[0], "format", 6) == 0) {
            f->format = w[1][0] == 'a' ? 0 : wl[1] > 7 && w[1][7] == 'l' ? 1 : 2;
        } else if (k >= 3 && wl[0] == 7 && memcmp(w[0], "element", 7) == 0 && f->nelems < ELEMS_MAX) {
            elem *e = &f->elems[f->nelems++];
            word(e->name, w[1], wl[1]);
            word(e->count, w[2], wl[2]);
        } else if (k >= 3 && wl[0] == 8 && memcmp(w[0], "property", 8) == 0 && f->nelems &&
                   f->elems[f->nelems - 1].nprops < PROPS_MAX) {
            elem *e = &f->elems[f->nelems - 1];
            prop *q = &e->props[e->nprops++];
            if (k >= 5 && wl[1] == 4 && memcmp(w[1], "list", 4) == 0) {
                word(q->count_type, w[2], wl[2]);
                word(q->type, w[3], wl[3]);
                word(q->name, w[4], wl[4]);
            } else {
                word(q->type, w[1], wl[1]);
                word(q->name, w[2], wl[2]);
            }
        }
    }
    return 0;
}

static void put_header(fz_buf *b, const ply *f)
{
    fz_printf(b, "ply\nformat %s 1.0\n", formats[f->format]);
    for (int e = 0; e < f->nelems; e++) {
        fz_printf(b, "element %s %s\n", f->elems[e].name, f->elems[e].count);
        for (int k = 0; k < f->elems[e].nprops; k++) {
            const prop *q = &f->elems[e].props[k];
            if (q->count_type[0])
                fz_printf(b, "property list %s %s %s\n", q->count_type, q->type, q->name);
            else
                fz_printf(b, "property %s %s\n", q->type, q->name);
        }
    }
    if (f->extra)
        fz_printf(b, "%s\n", f->extra);
    fz_puts(b, "end_header\n");
}

/* Writes one value of the type: text for ASCII, else its bytes in the
 * file's order (integers wrap; a float type takes the value as is). */
static void put_value(fz_buf *b, int format, const char *type, double v)
{
    int size = type_size(type);
    uint64_t bits;

    if (format == 0) {
        if (is_float(type))
            fz_printf(b, "%g ", v);
        else
            fz_printf(b, "%lld ", v > -9e18 && v < 9e18 ? (long long)v : 0ll);
        return;
    }
    if (size == 0)
        size = 4;
    if (is_float(type) && size == 4) {
        float f = (float)v;
        uint32_t u;
        memcpy(&u, &f, 4);
        bits = u;
    } else if (is_float(type)) {
        memcpy(&bits, &v, 8);
    } else {
        bits = (uint64_t)(v > -9e18 && v < 9e18 ? (long long)v : 0ll);
    }
    for (int i = 0; i < size; i++) {
        int shift = format == 1 ? i : size - 1 - i;
        uint8_t byte = (uint8_t)(bits >> (8 * shift));
        fz_put(b, &byte, 1);
    }
}

static double coordinate(void)
{
    if (fz_one_in(32)) {
        static const double bad[] = {1e38, -1e38, 1e39, 3.4028235e38, 1e308};
        return fz_one_in(2) ? (double)fz_f32() : bad[fz_below(5)];
    }
    return (double)((int)fz_below(2001) - 1000) / 64.0;
}

/* Writes a body that follows the header: each element's instances (up to
 * BODY_INSTANCES_MAX), lists mostly of three, indices mostly into the
 * first element. */
static void put_body(fz_buf *b, const ply *f)
{
    uint32_t nv = (uint32_t)strtoul(f->elems[0].count, NULL, 10);

    for (int e = 0; e < f->nelems && b->len < b->cap; e++) {
        const elem *el = &f->elems[e];
        unsigned long count = strtoul(el->count, NULL, 10);
        if (count > BODY_INSTANCES_MAX)
            count = fz_below(BODY_INSTANCES_MAX);
        for (unsigned long i = 0; i < count && b->len < b->cap; i++) {
            for (int k = 0; k < el->nprops; k++) {
                const prop *q = &el->props[k];
                if (q->count_type[0]) {
                    static const int lens[] = {0, 1, 2, 5, 100, 255, -1};
                    int len = fz_one_in(8) ? lens[fz_below(sizeof lens / sizeof lens[0])] : 3 + (int)fz_below(2);
                    int bad = fz_one_in(16) ? (int)fz_below((uint32_t)(len > 0 ? len : 1)) : -1;
                    put_value(b, f->format, q->count_type, len);
                    for (int j = 0; j < len; j++)
                        put_value(b, f->format, q->type, (double)(j == bad ? fz_index(nv, 0) : fz_below(nv)));
                } else {
                    put_value(b, f->format, q->type, coordinate());
                }
            }
            if (f->format == 0)
                fz_puts(b, "\n");
        }
    }
}

static ply doc;

static size_t ply_write(const ply *f, int new_body, uint8_t *out, size_t max)
{
    fz_buf b = {out, 0, max};
    uint8_t *body = NULL;

    /* the body may live in out: keep it before writing over it */
    if (!new_body && f->body_len && !(body = malloc(f->body_len)))
        return 0;
    if (body)
        memcpy(body, f->body, f->body_len);
    put_header(&b, f);
    if (new_body)
        put_body(&b, f);
    else
        fz_put(&b, body, f->body_len);
    free(body);
    return b.len;
}

static size_t ply_generate(uint8_t *out, size_t max)
{
    static const char *const xyz[] = {"float", "float", "float", "double", "int", "uchar", "short"};
    static const char *const counts[] = {"uchar", "uchar", "uchar", "char", "int", "uint", "ushort"};
    static const char *const items[] = {"int", "int", "uint", "ushort", "uchar", "char", "float"};
    const char *t = xyz[fz_below(7)];
    elem *v = &doc.elems[0], *fc = &doc.elems[1];

    memset(&doc, 0, sizeof doc);
    doc.format = (int)fz_below(3);
    doc.nelems = 2;
    snprintf(v->name, WORD_MAX, "vertex");
    snprintf(v->count, WORD_MAX, "%u", 3 + fz_below(40));
    for (int k = 0; k < 3; k++) {
        snprintf(v->props[k].type, WORD_MAX, "%s", t);
        snprintf(v->props[k].name, WORD_MAX, "%c", 'x' + k);
    }
    v->nprops = 3;
    if (fz_one_in(3))
        for (int k = 0; k < 3; k++, v->nprops++) {
            snprintf(v->props[v->nprops].type, WORD_MAX, "%s", fz_one_in(2) ? "float" : "uchar");
            snprintf(v->props[v->nprops].name, WORD_MAX, "%s", fz_one_in(2) ? "nx" : "red");
        }
    snprintf(fc->name, WORD_MAX, "face");
    snprintf(fc->count, WORD_MAX, "%u", fz_below(60));
    snprintf(fc->props[0].count_type, WORD_MAX, "%s", counts[fz_below(7)]);
    snprintf(fc->props[0].type, WORD_MAX, "%s", items[fz_below(7)]);
    snprintf(fc->props[0].name, WORD_MAX, "vertex_indices");
    fc->nprops = 1;
    if (fz_one_in(8)) {
        elem *x = &doc.elems[doc.nelems++];
        snprintf(x->name, WORD_MAX, "edge");
        snprintf(x->count, WORD_MAX, "%u", fz_below(5));
        snprintf(x->props[0].type, WORD_MAX, "int");
        snprintf(x->props[0].name, WORD_MAX, "vertex1");
        x->nprops = 1;
    }
    return ply_write(&doc, 1, out, max);
}

/* One change to the header. */
static void change_header(ply *f)
{
    static const char *const counts[] = {"4000000000", "4294967295", "4294967296", "2147483647",
                                         "0",          "-1",         "1e3",        "00000000003",
                                         "",           "3.5"};
    static const char *const extras[] = {"comment made by fuzz_ply", "obj_info fuzz",
                                         "element", "property float x", "bogus line",
                                         "format ascii 1.0", "element empty 1", "end_header\r"};
    elem *e = f->nelems ? &f->elems[fz_below((uint32_t)f->nelems)] : NULL;
    prop *q = e && e->nprops ? &e->props[fz_below((uint32_t)e->nprops)] : NULL;

    switch (fz_below(7)) {
    case 0:
    case 1: /* a count made hostile, or one off */
        if (!e)
            break;
        if (fz_one_in(2))
            snprintf(e->count, WORD_MAX, "%s", counts[fz_below(sizeof counts / sizeof counts[0])]);
        else
            snprintf(e->count, WORD_MAX, "%ld", strtol(e->count, NULL, 10) + (fz_one_in(2) ? 1 : -1));
        break;
    case 2: /* a type changed */
        if (q)
            snprintf(fz_one_in(2) && q->count_type[0] ? q->count_type : q->type, WORD_MAX, "%s",
                     types[fz_below(NTYPES)]);
        break;
    case 3: /* a property added, or made a list */
        if (e && e->nprops < PROPS_MAX) {
            prop *n = &e->props[e->nprops++];
            snprintf(n->type, WORD_MAX, "%s", types[fz_below(NTYPES - 2)]);
            snprintf(n->name, WORD_MAX, "p%d", e->nprops);
            if (fz_one_in(2))
                snprintf(n->count_type, WORD_MAX, "%s", types[fz_below(NTYPES - 2)]);
        }
        break;
    case 4: /* a property or element dropped */
        if (q && fz_one_in(2))
            e->nprops--;
        else if (f->nelems)
            f->nelems--;
        break;
    case 5: /* the format switched under the same body */
        f->format = (int)fz_below(3);
        break;
    default:
        f->extra = extras[fz_below(sizeof extras / sizeof extras[0])];
        break;
    }
}

static size_t ply_mutate(uint8_t *data, size_t size, size_t max)
{
    size_t head, n;

    if (!ply_read(data, size, &doc))
        return 0;
    head = (size_t)(doc.body - data);
    switch (fz_below(8)) {
    case 0:
    case 1:
    case 2: /* the header changed over the same body */
        change_header(&doc);
        return ply_write(&doc, 0, data, max);
    case 3:
    case 4: /* a new body for the header, perhaps changed first */
        if (fz_one_in(2))
            change_header(&doc);
        return ply_write(&doc, 1, data, max);
    default: /* the body's text or bytes changed */
        if (doc.format == 0) {
            fz_text t = {templates, sizeof templates / sizeof templates[0],
                         (uint32_t)strtoul(doc.elems[0].count, NULL, 10), 0};
            n = fz_mutate_text(data + head, size - head, max - head, &t);
        } else {
            n = fz_mutate_bytes(data + head, size - head, max - head);
        }
        return head + n;
    }
}

/* Reads one binary value of the type at p, into *v; 0 if it does not fit
 * in n bytes or the type is not one. */
static int get_value(const uint8_t *p, size_t n, const char *type, int big_endian, double *v)
{
    int size = type_size(type);
    uint64_t u = 0;

    if (size == 0 || (size_t)size > n)
        return 0;
    for (int i = 0; i < size; i++)
        u |= (uint64_t)p[big_endian ? size - 1 - i : i] << (8 * i);
    if (is_float(type) && size == 4) {
        uint32_t w = (uint32_t)u;
        float f;
        memcpy(&f, &w, 4);
        *v = f;
    } else if (is_float(type)) {
        memcpy(v, &u, 8);
    } else if (type[0] != 'u' && (u >> (8 * size - 1)) & 1) {
        *v = (double)(int64_t)(u | ~(uint64_t)0 << (8 * size - 1));
    } else {
        *v = (double)u;
    }
    return 1;
}

/* Reads the next value of instance text t (ASCII, one line) into *v. */
static int next_text_value(const char **t, double *v)
{
    char *end;

    *v = strtod(*t, &end);
    if (end == *t)
        return 0;
    *t = end;
    return 1;
}

/*
 * Refused by the PLY pre-check since fuzzing found them
 * (corpus/fuzz_ply/hostile-*.ply): a list of length 0 (Assimp's
 * triangulation aborted), a first element other than vertex and a list in
 * the vertex element (32 GB allocations), two vertex elements (a heap
 * write past Assimp's positions).
 *
 * Known, reported, unfixed, all let through by the PLY pre-check
 * (corpus/fuzz_ply/known-*.ply):
 * - a polygon of four or more vertices with an index out of range makes
 *   the triangulation read out of bounds (SIGSEGV), before import.c
 *   checks indices;
 * - a binary body whose first byte is a line feed is read by Assimp one
 *   byte later than by the pre-check, so the data it reads was never
 *   checked (shifted face lists: the SIGSEGV above);
 * - in ASCII, a real number ("-1e+38") in an integer column makes
 *   Assimp's reader throw on the rest of the line, leaking its mesh
 *   (found by fuzz-long).
 * Skipped: binary bodies starting with a line feed; a real in an integer
 * column (ASCII); a list of four or more with an index outside the first
 * element, walking the body as the header says until it stops making
 * sense.
 */
static const char *ply_known(const uint8_t *data, size_t size)
{
    static ply f;
    static char line[4096];
    size_t at;
    double nv;

    if (!ply_read(data, size, &f) || f.nelems == 0)
        return NULL;
    nv = strtod(f.elems[0].count, NULL);
    at = (size_t)(f.body - data);
    if (f.format != 0 && at < size && data[at] == '\n')
        return "binary PLY body starting with a line feed";
    for (int e = 0; e < f.nelems; e++) {
        unsigned long count = strtoul(f.elems[e].count, NULL, 10);
        for (unsigned long i = 0; i < count && at < size; i++) {
            const char *t = line;
            size_t start = at;
            if (f.format == 0) { /* one instance a line */
                size_t eol = at, len;
                while (eol < size && data[eol] != '\n')
                    eol++;
                len = eol - at < sizeof line - 1 ? eol - at : sizeof line - 1;
                memcpy(line, data + at, len);
                line[len] = 0;
                at = eol + 1;
            }
            for (int k = 0; k < f.elems[e].nprops; k++) {
                const prop *q = &f.elems[e].props[k];
                double items = 1, v;
                if (q->count_type[0]) {
                    if (f.format == 0 ? !next_text_value(&t, &items)
                                      : !get_value(data + at, size - at, q->count_type, f.format == 2, &items))
                        return NULL;
                    at += f.format ? (size_t)type_size(q->count_type) : 0;
                    if (!(items > 0 && items <= 4096))
                        return NULL;
                }
                for (int j = 0; j < (int)items; j++) {
                    const char *from = t;
                    if (f.format == 0 ? !next_text_value(&t, &v)
                                      : !get_value(data + at, size - at, q->type, f.format == 2, &v))
                        return NULL;
                    if (f.format == 0 && !is_float(q->type) && strpbrk(from, ".eEnN") &&
                        strpbrk(from, ".eEnN") < t)
                        return "PLY real number in an integer column";
                    at += f.format ? (size_t)type_size(q->type) : 0;
                    if (q->count_type[0] && items > 3 && !(v >= 0 && v < nv))
                        return "PLY polygon index out of range";
                }
            }
            if (at == start) /* an instance of nothing: the walk ends */
                return NULL;
        }
    }
    return NULL;
}

const fz_target fz_self = {"fuzz_ply", "ply", ply_generate, ply_mutate, NULL, fz_import_report,
                           ply_known};
