/*
 * fuzz_stl.c: structure-aware fuzz target for STL uploads: the importer's
 * STL recognition and ASCII pre-check (server/import/import_stl.c) and
 * Assimp's STL reader.
 *
 * Inputs are STL files, binary or ASCII. The mutator reads the triangles
 * out of either form and writes them back, now and then in the other
 * form, after changing them: a coordinate made NaN, infinite, 1e38 or
 * FLT_MAX, triangles deleted or repeated, the binary triangle count made
 * to disagree with the size (0, 2^31-1, 2^32-1...), a binary header that
 * starts with "solid". ASCII text also gets line-level changes (keywords
 * misplaced, numbers on the wrong line, 1e39, empty solids past
 * IMPORT_MAX_PARTS). The generator writes a few triangles either way. Each
 * input is imported with the hint "stl" and with none (fz_import.c).
 */
#include <stdio.h>
#include <string.h>

#include "fz.h"
#include "le.h"

/* Triangles the mutator keeps; inputs past it are cut to it. */
#define TRIS_MAX 2048

typedef struct tri {
    float n[3], v[9];
    uint16_t attr;
} tri;

typedef struct stl {
    int binary;
    uint8_t header[80];
    uint32_t count; /* the binary count field as written */
    tri t[TRIS_MAX];
    size_t ntris;
} stl;

static const char *const templates[] = {
    "solid %n", "solid", "endsolid %n", "endsolid", "facet normal %f %f %f", "facet", "outer loop",
    "vertex %f %f %f", "vertex %f %f", "vertex %f %f %f %f", "endloop", "endfacet",
    "normal %f %f %f", "color %f %f %f", "solid\nendsolid",
    ("facet normal %f %f %f\nouter loop\nvertex %f %f %f\nvertex %f %f %f\nvertex %f %f %f\n"
     "endloop\nendfacet"),
    "facet normal 0 0 1 outer loop vertex %f %f %f vertex %f %f %f vertex %f %f %f endloop endfacet",
    "facet normal\n%f %f %f\nouter loop"};
#define NTEMPLATES (sizeof templates / sizeof templates[0])

static int is_binary(const uint8_t *p, size_t n)
{
    return n >= 84 && (n - 84) % 50 == 0 && (n - 84) / 50 == le_get_u32(p + 80);
}

/* Reads p[0..n) as binary STL if it has the binary form's size (or does
 * not start with "solid"), else takes the numbers after each "normal" and
 * "vertex" of the text. 0 if neither yields anything to work on. */
static int stl_read(const uint8_t *p, size_t n, stl *s)
{
    memset(s->header, ' ', sizeof s->header);
    s->ntris = 0;
    if (is_binary(p, n) || (n >= 84 && memcmp(p, "solid", 5) != 0)) {
        s->binary = 1;
        memcpy(s->header, p, 80);
        s->count = le_get_u32(p + 80);
        for (size_t at = 84; at + 50 <= n && s->ntris < TRIS_MAX; at += 50, s->ntris++) {
            tri *t = &s->t[s->ntris];
            for (int k = 0; k < 3; k++)
                t->n[k] = le_get_f32(p + at + 4 * (size_t)k);
            for (int k = 0; k < 9; k++)
                t->v[k] = le_get_f32(p + at + 12 + 4 * (size_t)k);
            t->attr = le_get_u16(p + at + 48);
        }
        return 1;
    }
    s->binary = 0;
    /* each "normal" starts a triangle; "vertex" fills it */
    for (size_t i = 0, nv = 0; i < n && s->ntris <= TRIS_MAX; i++) {
        int normal = n - i > 6 && memcmp(p + i, "normal", 6) == 0;
        int vertex = n - i > 6 && memcmp(p + i, "vertex", 6) == 0;
        float *to;
        if (!normal && !vertex)
            continue;
        if (normal) {
            if (s->ntris == TRIS_MAX)
                break;
            memset(&s->t[s->ntris++], 0, sizeof(tri));
            nv = 0;
        }
        if (s->ntris == 0 || (vertex && nv == 3))
            continue;
        to = normal ? s->t[s->ntris - 1].n : s->t[s->ntris - 1].v + 3 * nv++;
        {
            char text[128];
            size_t len = n - i - 6 < sizeof text - 1 ? n - i - 6 : sizeof text - 1;
            memcpy(text, p + i + 6, len);
            text[len] = 0;
            if (sscanf(text, "%f %f %f", &to[0], &to[1], &to[2]) != 3)
                to[0] = to[1] = to[2] = 0;
        }
    }
    s->count = (uint32_t)s->ntris;
    return s->ntris > 0;
}

static void put_number(fz_buf *b, float f)
{
    fz_printf(b, fz_one_in(4) ? " %e" : " %g", (double)f);
}

static size_t stl_write(const stl *s, uint8_t *out, size_t max)
{
    fz_buf b = {out, 0, max};

    if (s->binary) {
        fz_put(&b, s->header, 80);
        fz_put_le(&b, s->count, 4);
        for (size_t i = 0; i < s->ntris; i++) {
            for (int k = 0; k < 3; k++)
                fz_put_f32(&b, s->t[i].n[k]);
            for (int k = 0; k < 9; k++)
                fz_put_f32(&b, s->t[i].v[k]);
            fz_put_le(&b, s->t[i].attr, 2);
        }
        return b.len;
    }
    fz_puts(&b, "solid fuzz\n");
    for (size_t i = 0; i < s->ntris && b.len < b.cap; i++) {
        fz_puts(&b, " facet normal");
        for (int k = 0; k < 3; k++)
            put_number(&b, s->t[i].n[k]);
        fz_puts(&b, "\n  outer loop\n");
        for (int v = 0; v < 3; v++) {
            fz_puts(&b, "   vertex");
            for (int k = 0; k < 3; k++)
                put_number(&b, s->t[i].v[3 * v + k]);
            fz_puts(&b, "\n");
        }
        fz_puts(&b, "  endloop\n endfacet\n");
    }
    fz_puts(&b, "endsolid fuzz\n");
    return b.len;
}

static float coordinate(void)
{
    return fz_one_in(32) ? fz_f32() : (float)((int)fz_below(2001) - 1000) / 64.0f;
}

/* One change to the triangles or the binary framing. */
static void change(stl *s)
{
    size_t i = fz_below((uint32_t)s->ntris);

    switch (fz_below(7)) {
    case 0:
    case 1: /* a coordinate made hostile */
        if (s->ntris)
            s->t[i].v[fz_below(9)] = fz_f32();
        break;
    case 2: /* the count disagrees with the size */
        s->binary = 1;
        s->count = fz_count((uint32_t)s->ntris);
        break;
    case 3: /* a binary header that reads as ASCII */
        memcpy(s->header, fz_one_in(2) ? "solid " : "solid\n", 6);
        s->binary = 1;
        break;
    case 4: /* the other form */
        s->binary = !s->binary;
        s->count = (uint32_t)s->ntris;
        break;
    case 5: /* triangles deleted */
        if (s->ntris)
            s->ntris = i;
        s->count = (uint32_t)s->ntris;
        break;
    default: { /* a triangle repeated */
        size_t k = fz_one_in(8) ? 1000 : 1 + fz_below(4);
        for (size_t j = 0; j < k && s->ntris && s->ntris < TRIS_MAX; j++)
            s->t[s->ntris++] = s->t[i];
        s->count = (uint32_t)s->ntris;
        break;
    }
    }
}

static stl doc; /* large: one, reused */

static size_t stl_generate(uint8_t *out, size_t max)
{
    doc.binary = (int)fz_below(2);
    memset(doc.header, 0, sizeof doc.header);
    memcpy(doc.header, "fuzz_stl", 8);
    doc.ntris = fz_one_in(16) ? 0 : 1 + fz_below(64);
    for (size_t i = 0; i < doc.ntris; i++) {
        for (int k = 0; k < 3; k++)
            doc.t[i].n[k] = coordinate();
        for (int k = 0; k < 9; k++)
            doc.t[i].v[k] = coordinate();
        doc.t[i].attr = (uint16_t)(fz_one_in(8) ? fz_rnd() : 0);
    }
    doc.count = (uint32_t)doc.ntris;
    if (fz_one_in(4))
        change(&doc);
    return stl_write(&doc, out, max);
}

static size_t stl_mutate(uint8_t *data, size_t size, size_t max)
{
    fz_text t = {templates, NTEMPLATES, 3, 1};

    if (size && !is_binary(data, size) && fz_one_in(2))
        return fz_mutate_text(data, size, max, &t);
    if (!stl_read(data, size, &doc))
        return 0;
    change(&doc);
    return stl_write(&doc, data, max);
}

const fz_target fz_self = {"fuzz_stl", "stl", stl_generate, stl_mutate, NULL, fz_import_report,
                           NULL};
