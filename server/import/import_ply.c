/*
 * import_ply.c: PLY, a header declaring elements (vertices, faces, ...)
 * and their properties, then a body of their values: ASCII, or binary of
 * either byte order. No unit, no up axis.
 *
 * What Assimp 5.2.5's PLY reader does with hostile input: it loops over
 * every element the header declares even past the end of the data (a
 * 200-byte ASCII file declaring 5*10^8 vertices took 56 s and 5.9 GB, one
 * declaring 5*10^8 faces over 16 GB, a face list of 10^6 indices hung for
 * over 60 s), and leaks its mesh when it throws, as on a value that is
 * not a number. The pre-check walks the body first, so that Assimp works
 * in proportion to the file, not to what its header claims.
 */
#include "importInt.h"
#include "import.h"

#include <errno.h>
#include <string.h>

#include "err.h"
#include "le.h"

typedef struct ply_prop {
    uint8_t size;       /* bytes of the value (binary) */
    uint8_t count_size; /* bytes of a list's length, 0 for a scalar */
    uint8_t count_signed;
} ply_prop;

typedef struct ply_elem {
    uint32_t count;
    uint32_t first, nprops; /* its properties in the table */
    int is_vertex;
} ply_elem;

typedef struct ply_header {
    int ascii, big_endian;
    uint32_t nelems, nprops;
    ply_elem elems[IMPORT_MAX_PLY_PROPERTIES];
    ply_prop props[IMPORT_MAX_PLY_PROPERTIES];
} ply_header;

enum { PLY_FLOAT, PLY_UNSIGNED, PLY_SIGNED };

/* Size in bytes of a PLY type name, 0 if unknown; *kind says which. */
static uint8_t ply_type(const unsigned char *w, size_t n, int *kind)
{
    static const struct {
        const char *name;
        uint8_t size, kind;
    } types[] = {
        {"char", 1, PLY_SIGNED},    {"uchar", 1, PLY_UNSIGNED},  {"int8", 1, PLY_SIGNED},
        {"uint8", 1, PLY_UNSIGNED}, {"short", 2, PLY_SIGNED},    {"ushort", 2, PLY_UNSIGNED},
        {"int16", 2, PLY_SIGNED},   {"uint16", 2, PLY_UNSIGNED}, {"int", 4, PLY_SIGNED},
        {"uint", 4, PLY_UNSIGNED},  {"int32", 4, PLY_SIGNED},    {"uint32", 4, PLY_UNSIGNED},
        {"float", 4, PLY_FLOAT},    {"float32", 4, PLY_FLOAT},   {"double", 8, PLY_FLOAT},
        {"float64", 8, PLY_FLOAT}};

    for (size_t i = 0; i < sizeof types / sizeof types[0]; i++)
        if (strlen(types[i].name) == n && memcmp(w, types[i].name, n) == 0) {
            *kind = types[i].kind;
            return types[i].size;
        }
    return 0;
}

/* Splits the line p[0..n) into at most max words; returns how many. */
static size_t split_words(const unsigned char *p, size_t n, const unsigned char **w, size_t *wl,
                          size_t max)
{
    size_t k = 0, i = 0;

    while (k < max) {
        while (i < n && import__is_space(p[i]))
            i++;
        if (i == n)
            break;
        w[k] = p + i;
        while (i < n && !import__is_space(p[i]))
            i++;
        wl[k] = (size_t)(p + i - w[k]);
        k++;
    }
    return k;
}

/* Parses a whole decimal word into *v: 0, or -EINVAL if it is anything
 * else or over UINT32_MAX. */
static int parse_u32(const unsigned char *w, size_t n, uint32_t *v)
{
    uint64_t x = 0;

    if (n == 0 || n > 10)
        return -EINVAL;
    for (size_t i = 0; i < n; i++) {
        if (w[i] < '0' || w[i] > '9')
            return -EINVAL;
        x = x * 10 + (uint64_t)(w[i] - '0');
    }
    if (x > UINT32_MAX)
        return -EINVAL;
    *v = (uint32_t)x;
    return 0;
}

/*
 * The element layout Assimp's reader survives, found by fuzzing: vertices
 * first (faces before them made it allocate 32 GB), one vertex element (a
 * second made it write past the positions it allocated for the first), and
 * no list among the vertex's properties (a negative length in an unsigned
 * column: 32 GB). 0, or -EINVAL with err set.
 */
static int ply_check_elements(const ply_header *h, char *err, size_t errlen)
{
    if (h->nelems > 0 && !h->elems[0].is_vertex)
        return cvre_fail(err, errlen, -EINVAL, "PLY: the first element must be vertex");
    for (uint32_t e = 1; e < h->nelems; e++)
        if (h->elems[e].is_vertex)
            return cvre_fail(err, errlen, -EINVAL, "PLY: two vertex elements");
    for (uint32_t k = 0; h->nelems > 0 && k < h->elems[0].nprops; k++)
        if (h->props[h->elems[0].first + k].count_size)
            return cvre_fail(err, errlen, -EINVAL, "PLY: a list property in the vertex element");
    return 0;
}

/*
 * Reads the header into h: 0 with the offset of the body in *body, or
 * -EINVAL with err set. Keywords are Assimp's, case and all. Like Assimp
 * we skip lines we do not know (Blender writes one); Assimp also ends an
 * element's properties at the first such line and ignores properties
 * after it, so we refuse those rather than count them differently.
 */
static int ply_parse_header(const unsigned char *p, size_t n, ply_header *h, size_t *body, char *err,
                            size_t errlen)
{
    size_t at = 0;
    int have_format = 0, in_props = 0;

    memset(h, 0, sizeof *h);
    while (at < n && p[at] != '\n') /* the "ply" line */
        at++;
    at++;
    while (at < n) {
        const unsigned char *w[6];
        size_t wl[6], k, eol = at;

        while (eol < n && p[eol] != '\n')
            eol++;
        k = split_words(p + at, eol - at, w, wl, 6);
        at = eol < n ? eol + 1 : n;
        if (k == 0 || import__kw_is(w[0], wl[0], "comment"))
            continue;
        if (import__kw_is(w[0], wl[0], "end_header")) {
            if (!have_format)
                return cvre_fail(err, errlen, -EINVAL, "PLY header has no format line");
            *body = at;
            return ply_check_elements(h, err, errlen);
        }
        if (import__kw_is(w[0], wl[0], "format") && k >= 2) {
            have_format = 1;
            h->ascii = import__kw_is(w[1], wl[1], "ascii");
            h->big_endian = import__kw_is(w[1], wl[1], "binary_big_endian");
            if (!h->ascii && !h->big_endian && !import__kw_is(w[1], wl[1], "binary_little_endian"))
                return cvre_fail(err, errlen, -EINVAL, "PLY format is not ascii or binary");
        } else if (import__kw_is(w[0], wl[0], "element")) {
            ply_elem *e;
            if (h->nelems == IMPORT_MAX_PLY_PROPERTIES)
                return cvre_fail(err, errlen, -EINVAL, "PLY header declares too many elements");
            e = &h->elems[h->nelems++];
            if (k < 3 || parse_u32(w[2], wl[2], &e->count) != 0)
                return cvre_fail(err, errlen, -EINVAL, "PLY element line without a count");
            e->is_vertex = import__kw_is(w[1], wl[1], "vertex");
            e->first = h->nprops;
            in_props = 1;
            continue;
        } else if (import__kw_is(w[0], wl[0], "property")) {
            ply_prop *q;
            int kind, count_kind;
            if (!in_props)
                return cvre_fail(err, errlen, -EINVAL, "PLY property outside an element");
            if (h->nprops == IMPORT_MAX_PLY_PROPERTIES)
                return cvre_fail(err, errlen, -EINVAL, "PLY header declares over %d properties",
                                    IMPORT_MAX_PLY_PROPERTIES);
            q = &h->props[h->nprops++];
            h->elems[h->nelems - 1].nprops++;
            if (k >= 2 && import__kw_is(w[1], wl[1], "list")) {
                if (k < 4 || !(q->count_size = ply_type(w[2], wl[2], &count_kind)) ||
                    count_kind == PLY_FLOAT || !(q->size = ply_type(w[3], wl[3], &kind)))
                    return cvre_fail(err, errlen, -EINVAL, "PLY list property of unknown type");
                q->count_signed = count_kind == PLY_SIGNED;
            } else if (k < 2 || !(q->size = ply_type(w[1], wl[1], &kind))) {
                return cvre_fail(err, errlen, -EINVAL, "PLY property of unknown type");
            }
            continue;
        }
        in_props = 0; /* format, obj_info or a line Assimp skips */
    }
    return cvre_fail(err, errlen, -EINVAL, "PLY header has no end_header line");
}

/* Reads a list length of q->count_size bytes (1, 2 or 4: an integer type)
 * at p; -1 if negative. */
static int64_t ply_get_count(const unsigned char *p, const ply_prop *q, int big_endian)
{
    uint8_t le[4]; /* the bytes in little-endian order */
    uint32_t v;
    unsigned bits = 8u * q->count_size;

    for (unsigned i = 0; i < q->count_size; i++)
        le[i] = p[big_endian ? q->count_size - 1 - i : i];
    v = q->count_size == 1 ? le[0] : q->count_size == 2 ? le_get_u16(le) : le_get_u32(le);
    if (q->count_signed && (v >> (bits - 1)))
        return -1;
    return (int64_t)v;
}

/* True if the line p[at..eol) is one ASCII instance of element el: its
 * values, numbers, a list's length first, and nothing more (Assimp reads
 * one line per instance and throws, leaking, on a missing value). */
static int ply_line_matches(const unsigned char *p, size_t at, size_t eol, const ply_header *h,
                          const ply_elem *el)
{
    for (uint32_t k = el->first; k < el->first + el->nprops; k++) {
        uint64_t want = 1;
        for (uint64_t i = 0; i < want; i++) {
            const unsigned char *w;
            size_t wl = import__next_word(p, eol, &at, &w);
            if (!import__is_number(w, wl))
                return 0;
            if (i == 0 && h->props[k].count_size) {
                uint32_t len;
                /* a list of length 0 (a face without vertices) made
                 * Assimp's triangulation abort the process */
                if (parse_u32(w, wl, &len) != 0 || len == 0)
                    return 0;
                want += len;
            }
        }
    }
    {
        const unsigned char *w;
        return import__next_word(p, eol, &at, &w) == 0;
    }
}

/*
 * Walks the body: every element the header declares must be there, each
 * list no longer than its data. Assimp then allocates and loops in
 * proportion to the file, not to what the header claims. ASCII values
 * must be numbers, one instance a line. Returns 0 or -EINVAL. Linear in
 * the file: each step consumes at least one byte.
 */
static int ply_check(const unsigned char *p, size_t n, char *err, size_t errlen)
{
    ply_header h;
    size_t at = 0, line = 0, bad, text;
    int rc = ply_parse_header(p, n, &h, &at, err, errlen);

    if (rc != 0)
        return rc;
    /* the text: the header, and the body if ASCII; Assimp also ends a
     * PLY line at a CR, so one may only come before a line feed */
    text = h.ascii ? n : at;
    if ((bad = import__find_control(p, text)) < text)
        return cvre_fail(err, errlen, -EINVAL, "PLY: control character at byte %zu", bad);
    for (size_t i = 0; i < text; i++)
        if (p[i] == '\r' && (i + 1 == n || p[i + 1] != '\n'))
            return cvre_fail(err, errlen, -EINVAL, "PLY: carriage return inside a line at byte %zu", i);
    for (uint32_t e = 0; e < h.nelems; e++) {
        const ply_elem *el = &h.elems[e];
        if (el->count > 0 && el->nprops == 0)
            return cvre_fail(err, errlen, -EINVAL, "PLY element %u has no properties", e);
        /* Every value takes at least a byte: refuse impossible counts
         * before walking them. */
        if ((uint64_t)el->count * el->nprops > n - at)
            return cvre_fail(err, errlen, -EINVAL,
                        "PLY header declares %u of element %u, more than the file holds", el->count,
                        e);
        for (uint32_t i = 0; i < el->count; i++) {
            if (h.ascii) {
                size_t eol = at;
                while (eol < n && p[eol] != '\n')
                    eol++;
                line++;
                if (at >= n)
                    return cvre_fail(err, errlen, -EINVAL,
                                "PLY data ends before the elements its header declares");
                if (!ply_line_matches(p, at, eol, &h, el))
                    return cvre_fail(err, errlen, -EINVAL,
                                "PLY data line %zu does not match its element %u", line, e);
                at = eol < n ? eol + 1 : n;
                continue;
            }
            for (uint32_t k = el->first; k < el->first + el->nprops; k++) {
                const ply_prop *q = &h.props[k];
                int64_t items = 1;
                if (q->count_size) {
                    if (n - at < q->count_size)
                        return cvre_fail(err, errlen, -EINVAL,
                                    "PLY data ends before the elements its header declares");
                    items = ply_get_count(p + at, q, h.big_endian);
                    at += q->count_size;
                    if (items == 0) /* Assimp's triangulation aborts */
                        return cvre_fail(err, errlen, -EINVAL, "PLY: a list of length 0 (element %u)", e);
                }
                if (items < 0 || (uint64_t)items > (n - at) / q->size)
                    return cvre_fail(err, errlen, -EINVAL,
                                "PLY data ends before the elements its header declares");
                at += (size_t)items * q->size;
            }
        }
    }
    return 0;
}

/* "ply" alone on the first line. */
static int ply_sniff(const unsigned char *p, size_t n)
{
    return import__starts_with(p, n, "ply") && n > 3 && (p[3] == '\n' || p[3] == '\r');
}

const import__format import__ply = {"ply", "PLY", ply_sniff, ply_check};
