/*
 * import.c: model files to triangles, through Assimp's C API.
 *
 * What Assimp 5.2.5 (Debian libassimp5) does with hostile input, found
 * under ASan, valgrind and fuzzing, and what this file does about it:
 *
 * - It is built with assertions on (ASSIMP_BUILD_DEBUG): a zero-length
 *   buffer aborts the process. We refuse empty input first.
 * - Importing "from memory" still opens files on the local disk: an OBJ's
 *   `mtllib /etc/passwd`, a glTF buffer URI. A buffer URI turns the named
 *   file's bytes into vertices, which the server would keep and show; a
 *   FIFO would block. We hand Assimp our own aiFileIO that serves the
 *   upload and nothing else, so missing .mtl files and textures are simply
 *   absent.
 * - Any of its 48 importers can be reached: with no usable extension it
 *   asks each whether it wants the file, and for an extension claimed by
 *   two (glb) it asks everyone when both decline. Some crash or hang on
 *   small files (its own test models: an OpenGEX file segfaults, an OFF
 *   and an SMD file hang), COLLADA expands a 3 KB file of shared
 *   instance_node references into 14 GB, and without an extension a
 *   binary STL is taken for OBJ and a GLB for nothing. So we recognise
 *   the four formats we accept ourselves, always name one, and make sure
 *   its reader takes the file.
 * - Its readers leak their mesh (1.3-2.4 KB) whenever they throw on a
 *   malformed file: a cut ASCII STL facet, an OBJ face naming a missing
 *   vertex, a PLY value that is not a number. A client could leak server
 *   memory at will, so the pre-checks refuse what makes them throw. That
 *   means reading the file as Assimp does: fuzzing found its readers
 *   ending lines at NUL and CR, taking "l1" for a statement, ".5" for no
 *   number and an STL vertex's numbers only from its own line; files a
 *   plain reading would take differently are refused.
 * - PLY: the reader loops over every element the header declares even
 *   past the end of the data: a 200-byte ASCII file declaring 5*10^8
 *   vertices took 56 s and 5.9 GB, one declaring 5*10^8 faces over 16 GB,
 *   a face list of 10^6 indices hung (>60 s). We walk the body first.
 * - GLB: the reader builds one node per path through the node graph (a
 *   1 KB file of nodes listing the next one twice exhausted 24 GB),
 *   recurses per node level (a 20,000-deep chain overflowed the stack) and
 *   per JSON level (10^6 overflowed it), and copies an accessor once per
 *   primitive using it (3.6 MB took 17.6 GB). We parse the JSON first,
 *   with jansson (a hand-written tokenizer here let an object stand where
 *   an array was expected and overflowed the heap), checking the type of
 *   every value we read.
 * - OBJ and ASCII STL: a mesh and a node per named part, names looked up
 *   linearly: 200,000 `usemtl` lines took 54 s and 7 GB. We count them.
 * - Triangulation is quadratic in polygon size: we bound the sum of squares
 *   before triangulating (IMPORT_MAX_POLYGON_WORK).
 * - Binary STL whose triangle count disagrees with its size, GLB accessors
 *   beyond their buffer, node cycles: refused by Assimp itself, cleanly.
 * - Exceptions (std::bad_alloc included) are caught inside the C API and
 *   become a NULL scene. Its logger is a null logger unless one is
 *   attached; we attach none, so nothing reaches stderr.
 * - Each aiImportFile* call makes its own Importer, but the last error is a
 *   global std::string written inside the call: imports are serialised.
 *
 * These guards answer what was found, not everything Assimp might do:
 * running imports in a separate process with memory and time limits would
 * contain the rest.
 */
#include "import.h"
#include "importInt.h"

#include <errno.h>
#include <float.h>
#include <limits.h>
#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <assimp/cfileio.h>
#include <assimp/cimport.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <jansson.h>

#include "alloc.h"
#include "le.h"

_Static_assert(IMPORT_MAX_BYTES > 0 && IMPORT_MAX_BYTES <= UINT_MAX,
               "Assimp takes the length as unsigned int");
_Static_assert(IMPORT_MAX_TRIANGLES >= 1, "a model has at least one triangle");
_Static_assert(IMPORT_MAX_POLYGON_WORK >= 16, "quads must always pass");
_Static_assert(IMPORT_MAX_NODE_DEPTH >= 8 && IMPORT_MAX_NODE_DEPTH <= 4096,
               "deep enough for real files, shallow enough for a thread's stack");
_Static_assert(IMPORT_MAX_JSON_DEPTH >= 16 && IMPORT_MAX_JSON_DEPTH <= 1024,
               "deep enough for glTF, shallow enough for rapidjson's recursion");
_Static_assert(IMPORT_MAX_JSON_MEMORY >= (1u << 20), "room for real documents");
_Static_assert(IMPORT_MAX_GLB_NODES >= 1, "a scene has a node");
_Static_assert(IMPORT_GLB_ELEMENTS_PER_BYTE >= 1 && IMPORT_MAX_GLB_ELEMENTS >= 3,
               "an unshared triangle must pass");
_Static_assert(IMPORT_MAX_PARTS >= 1, "a file has a part");
_Static_assert(IMPORT_MAX_PLY_PROPERTIES >= 16 && IMPORT_MAX_PLY_PROPERTIES <= 4096,
               "a fixed table on the stack");

/* Files Assimp may have open at once through our aiFileIO. The existence
 * check, the size query and the read each open and close the upload, one
 * at a time in every format here; the rest is headroom. */
#define OPEN_MAX 4

static pthread_mutex_t assimp_lock = PTHREAD_MUTEX_INITIALIZER;

/* Formats a message into err and returns rc. Bytes that are not
 * printable ASCII (from the hint, or file text quoted by Assimp) become
 * '?', so the message stays one line whatever the upload held. */
int import__fail(char *err, size_t errlen, int rc, const char *fmt, ...)
{
    va_list ap;

    if (errlen) {
        va_start(ap, fmt);
        vsnprintf(err, errlen, fmt, ap);
        va_end(ap);
        for (char *c = err; *c; c++)
            if ((unsigned char)*c < 0x20 || (unsigned char)*c > 0x7e)
                *c = '?';
    }
    return rc;
}

/* ---- the upload as Assimp's only file ----------------------------------- */

typedef struct memfile {
    struct aiFile f; /* first: Assimp hands this back */
    const char *data;
    size_t len, pos;
    int used;
} memfile;

typedef struct memfs {
    struct aiFileIO io; /* first, likewise */
    const char *name;   /* the one path that opens */
    const char *data;
    size_t len;
    memfile files[OPEN_MAX];
} memfs;

static size_t mem_read(struct aiFile *f, char *buf, size_t size, size_t count)
{
    memfile *m = (memfile *)(void *)f;
    size_t n;

    if (size == 0 || count == 0)
        return 0;
    n = (m->len - m->pos) / size;
    if (n > count)
        n = count;
    memcpy(buf, m->data + m->pos, n * size);
    m->pos += n * size;
    return n;
}

static size_t mem_write(struct aiFile *f, const char *buf, size_t size, size_t count)
{
    (void)f, (void)buf, (void)size, (void)count;
    return 0;
}

static size_t mem_tell(struct aiFile *f) { return ((memfile *)(void *)f)->pos; }

static size_t mem_size(struct aiFile *f) { return ((memfile *)(void *)f)->len; }

static void mem_flush(struct aiFile *f) { (void)f; }

/* Seeks like Assimp's own memory stream: from the end, offset counts back. */
static enum aiReturn mem_seek(struct aiFile *f, size_t off, enum aiOrigin origin)
{
    memfile *m = (memfile *)(void *)f;
    size_t base = origin == aiOrigin_SET ? 0 : origin == aiOrigin_CUR ? m->pos : m->len;

    if (origin == aiOrigin_END) {
        if (off > m->len)
            return aiReturn_FAILURE;
        m->pos = m->len - off;
        return aiReturn_SUCCESS;
    }
    if (off > m->len - base)
        return aiReturn_FAILURE;
    m->pos = base + off;
    return aiReturn_SUCCESS;
}

/* Opens the upload for reading; every other path, and any write, fails as
 * if the file did not exist (how Assimp treats a missing .mtl or texture). */
static struct aiFile *mem_open(struct aiFileIO *io, const char *path, const char *mode)
{
    memfs *fs = (memfs *)(void *)io;

    if (strcmp(path, fs->name) != 0 || strpbrk(mode, "wa+"))
        return NULL;
    for (int i = 0; i < OPEN_MAX; i++) {
        memfile *m = &fs->files[i];
        if (m->used)
            continue;
        memset(m, 0, sizeof *m);
        m->f.ReadProc = mem_read;
        m->f.WriteProc = mem_write;
        m->f.TellProc = mem_tell;
        m->f.FileSizeProc = mem_size;
        m->f.SeekProc = mem_seek;
        m->f.FlushProc = mem_flush;
        m->data = fs->data;
        m->len = fs->len;
        m->used = 1;
        return &m->f;
    }
    return NULL;
}

static void mem_close(struct aiFileIO *io, struct aiFile *f)
{
    (void)io;
    ((memfile *)(void *)f)->used = 0;
}

/* ---- formats and their pre-checks --------------------------------------- */

typedef int (*precheck_fn)(const unsigned char *p, size_t n, char *err, size_t errlen);

typedef struct format {
    const char *ext;   /* ours and Assimp's name for it */
    const char *name;  /* for messages */
    precheck_fn check; /* refuses what Assimp would mishandle */
} format;

static int check_obj(const unsigned char *p, size_t n, char *err, size_t errlen);
static int check_stl(const unsigned char *p, size_t n, char *err, size_t errlen);
static int check_ply(const unsigned char *p, size_t n, char *err, size_t errlen);
static int check_glb(const unsigned char *p, size_t n, char *err, size_t errlen);

enum { FMT_OBJ, FMT_STL, FMT_PLY, FMT_GLB, FMT_COUNT };

static const format formats[FMT_COUNT] = {
    [FMT_OBJ] = {"obj", "OBJ", check_obj},
    [FMT_STL] = {"stl", "STL", check_stl},
    [FMT_PLY] = {"ply", "PLY", check_ply},
    [FMT_GLB] = {"glb", "GLB", check_glb},
};

const char *import_formats(void) { return "obj stl ply glb"; }

static int is_space(unsigned char c)
{
    return c == ' ' || c == '\t' || c == '\r' || c == '\n' || c == '\f' || c == '\v';
}

static unsigned char lower(unsigned char c)
{
    return c >= 'A' && c <= 'Z' ? (unsigned char)(c + 32) : c;
}

/* True if p[0..n) starts with the word w, case-insensitively. */
static int starts_with(const unsigned char *p, size_t n, const char *w)
{
    size_t k = strlen(w);

    if (n < k)
        return 0;
    for (size_t i = 0; i < k; i++)
        if (lower(p[i]) != (unsigned char)w[i])
            return 0;
    return 1;
}

/* True if the word w[0..n) is s, case-insensitively. */
static int word_is(const unsigned char *w, size_t n, const char *s)
{
    return strlen(s) == n && starts_with(w, n, s);
}

/* A binary STL is an 80-byte header, a triangle count and 50 bytes per
 * triangle, nothing more (Assimp's test too, checked before "solid"
 * because binary headers often start with that word). */
static int is_binary_stl(const unsigned char *p, size_t n)
{
    return n >= 84 && (n - 84) % 50 == 0 && (n - 84) / 50 == le_get_u32(p + 80);
}

/* OBJ has no signature: the first line that is neither blank nor a
 * comment must be one of its statements. */
static int looks_like_obj(const unsigned char *p, size_t n)
{
    static const char *const words[] = {"v", "vt", "vn", "vp", "f",      "l",     "p",
                                        "o", "g",  "s",  "mg", "mtllib", "usemtl"};
    size_t i = 0, w;

    for (;;) {
        while (i < n && is_space(p[i]))
            i++;
        if (i == n)
            return 0;
        if (p[i] != '#')
            break;
        while (i < n && p[i] != '\n')
            i++;
    }
    for (w = i; w < n && !is_space(p[w]); w++)
        ;
    if (w == n || (p[w] != ' ' && p[w] != '\t'))
        return 0;
    for (size_t k = 0; k < sizeof words / sizeof words[0]; k++)
        if (strlen(words[k]) == w - i && memcmp(p + i, words[k], w - i) == 0)
            return 1;
    return 0;
}

/* The format the content shows, or -1. */
static int sniff(const unsigned char *p, size_t n)
{
    size_t i = 0;

    if (n >= 4 && memcmp(p, "glTF", 4) == 0)
        return FMT_GLB;
    if (starts_with(p, n, "ply") && n > 3 && (p[3] == '\n' || p[3] == '\r'))
        return FMT_PLY;
    if (is_binary_stl(p, n))
        return FMT_STL;
    while (i < n && is_space(p[i]))
        i++;
    if (starts_with(p + i, n - i, "solid") && (n - i == 5 || is_space(p[i + 5])))
        return FMT_STL;
    if (looks_like_obj(p, n))
        return FMT_OBJ;
    return -1;
}

/* ---- OBJ and ASCII STL pre-check --------------------------------------- */

/* Offset of the first control character other than tab and line ends in
 * p[0..n), or n. Assimp's text readers end a line or the whole file at
 * NUL, CR or form feed where a plain reading would not, so text formats
 * must not hold them elsewhere. */
static size_t find_control(const unsigned char *p, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (p[i] < 0x20 && p[i] != '\t' && p[i] != '\n' && p[i] != '\r')
            return i;
    return n;
}

/* Reads the next whitespace-separated word of p[0..n) from *at. */
static size_t next_word(const unsigned char *p, size_t n, size_t *at, const unsigned char **w)
{
    size_t s;

    while (*at < n && is_space(p[*at]))
        (*at)++;
    s = *at;
    while (*at < n && !is_space(p[*at]))
        (*at)++;
    *w = p + s;
    return *at - s;
}

/* True if the word is exactly kw (Assimp's keywords are lower case). */
static int kw_is(const unsigned char *w, size_t n, const char *kw)
{
    return strlen(kw) == n && memcmp(w, kw, n) == 0;
}

/* True if the word is all digits, at least one. */
static int all_digits(const unsigned char *w, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (w[i] < '0' || w[i] > '9')
            return 0;
    return n > 0;
}

/* True if the whole word is a number Assimp's fast_atof reads without
 * throwing and without leaving characters for the next read: decimal,
 * with optional sign, fraction and exponent, or nan/inf (refused later
 * as non-finite). */
static int is_number(const unsigned char *w, size_t n)
{
    size_t i = n && (w[0] == '-' || w[0] == '+'), d = 0, dots = 0, e;

    if (word_is(w + i, n - i, "nan") || word_is(w + i, n - i, "inf") ||
        word_is(w + i, n - i, "infinity"))
        return 1;
    for (e = i; e < n && w[e] != 'e' && w[e] != 'E'; e++)
        if (w[e] >= '0' && w[e] <= '9')
            d++;
        else if (w[e] == '.')
            dots++;
        else
            return 0;
    if (d == 0 || dots > 1)
        return 0;
    if (e == n)
        return 1;
    e++;
    if (e < n && (w[e] == '-' || w[e] == '+'))
        e++;
    return all_digits(w + e, n - e);
}

/* An OBJ face, line or point vertex: v, v/t, v//n or v/t/n, integers of
 * at most nine digits (Assimp reads them as int). Returns the position
 * index through *v. */
static int obj_vertex_ref(const unsigned char *w, size_t n, long long *v)
{
    size_t part = 0, s = 0;

    for (size_t i = 0; i <= n; i++) {
        size_t a;
        if (i < n && w[i] != '/')
            continue;
        a = s + (s < i && w[s] == '-');
        if ((i > s || part == 0) && (!all_digits(w + a, i - a) || i - a > 9))
            return 0;
        if (part == 0) {
            *v = 0;
            for (size_t k = a; k < i; k++)
                *v = *v * 10 + (w[k] - '0');
            if (a > s)
                *v = -*v;
        }
        if (++part > 3)
            return 0;
        s = i + 1;
    }
    return 1;
}

/*
 * OBJ: Assimp's reader leaks its mesh when a face names a vertex that does
 * not exist, so we count vertices exactly as it does and check every
 * index. It picks a statement by the line's first character ("l1 2" is a
 * line element, " v 1 2 3" nothing) and counts a vertex's numbers by their
 * first character (".5" is not one), so anything those rules could read
 * differently from us is refused: an unknown word starting with f, l, p
 * or v, an indented vertex or element, a number that is not plainly one.
 * Indices count from 1, or back from the last vertex read when negative;
 * 0 is refused. Also bounds the named parts (IMPORT_MAX_PARTS).
 */
static int check_obj(const unsigned char *p, size_t n, char *err, size_t errlen)
{
    unsigned long long vertices = 0, line = 0, parts = 0;
    long long highest = 0; /* the largest positive index used */
    size_t bad = find_control(p, n);

    if (bad < n)
        return import__fail(err, errlen, -EINVAL, "OBJ: control character at byte %zu", bad);
    for (size_t at = 0, eol; at < n; at = eol + 1) {
        size_t cur = at, wl;
        const unsigned char *w, *x;
        size_t xl;
        int vertex, element;
        for (eol = at; eol < n && p[eol] != '\n' && p[eol] != '\r'; eol++) /* CR ends one too */
            ;
        if (eol > at && p[eol - 1] == '\\')
            return import__fail(err, errlen, -EINVAL, "OBJ line %llu: line continuations are not supported",
                        line + 1);
        wl = next_word(p, eol, &cur, &w);
        vertex = kw_is(w, wl, "v") || kw_is(w, wl, "vt") || kw_is(w, wl, "vn");
        element = kw_is(w, wl, "f") || kw_is(w, wl, "l") || kw_is(w, wl, "p");
        if (wl && ((w != p + at && (vertex || element)) ||
                   (w == p + at && strchr("flpv", *w) && !vertex && !element)))
            return import__fail(err, errlen, -EINVAL, "OBJ line %llu: unknown or indented statement",
                        line + 1);
        if (vertex) {
            int k = 0;
            while ((xl = next_word(p, eol, &cur, &x)) != 0) {
                if (!is_number(x, xl) || x[0] == '.')
                    return import__fail(err, errlen, -EINVAL, "OBJ line %llu: malformed number", line + 1);
                k++;
            }
            if (wl == 1 ? k != 3 && k != 4 && k != 6 : w[1] == 'n' ? k != 3 : k < 1 || k > 3)
                return import__fail(err, errlen, -EINVAL, "OBJ line %llu: wrong count of numbers",
                            line + 1);
            vertices += wl == 1;
        } else if (element) {
            while ((xl = next_word(p, eol, &cur, &x)) != 0) {
                long long v = 0;
                if (!obj_vertex_ref(x, xl, &v) || v == 0)
                    return import__fail(err, errlen, -EINVAL, "OBJ line %llu: malformed vertex index",
                                line + 1);
                if (v < 0 && (unsigned long long)-v > vertices)
                    return import__fail(err, errlen, -EINVAL,
                                "OBJ line %llu: vertex index %lld before the first vertex",
                                line + 1, v);
                if (v > highest)
                    highest = v;
            }
        } else if (wl && (*w == 'o' || *w == 'g' || kw_is(w, wl, "usemtl"))) {
            parts++; /* Assimp takes any word starting with o or g */
        }
        line += eol < n && p[eol] == '\n';
    }
    if ((unsigned long long)highest > vertices)
        return import__fail(err, errlen, -EINVAL, "OBJ vertex index %lld, but the file has %llu", highest,
                    vertices);
    if (parts > IMPORT_MAX_PARTS)
        return import__fail(err, errlen, -EINVAL,
                    "%llu OBJ objects, groups and material switches, over the limit of %u", parts,
                    (unsigned)IMPORT_MAX_PARTS);
    return 0;
}

/* Reads the next word of p[0..n) from *at if it is on the same line. */
static size_t same_line_word(const unsigned char *p, size_t n, size_t *at, const unsigned char **w)
{
    while (*at < n && (p[*at] == ' ' || p[*at] == '\t'))
        (*at)++;
    if (*at < n && (p[*at] == '\n' || p[*at] == '\r'))
        return 0;
    return next_word(p, n, at, w);
}

/*
 * ASCII STL: Assimp's reader leaks its mesh and node (2.4 KB) whenever it
 * throws, which any cut or malformed facet makes it do, so a client could
 * leak server memory at will. We accept only what it reads without
 * throwing: solids of whole facets, each a normal and three vertices of
 * three numbers, "normal" and the numbers on the line of the keyword
 * before them as Assimp reads them (fuzzing found that one). Also bounds
 * the solids (IMPORT_MAX_PARTS).
 */
static int check_stl(const unsigned char *p, size_t n, char *err, size_t errlen)
{
    /* after "facet"; '#' is a number; '+' marks a word that must be on
     * the line of the one before it */
    static const char *const facet[] = {
        "+normal", "+#", "+#", "+#", "outer",  "loop", "vertex", "+#", "+#",      "+#",
        "vertex",  "+#", "+#", "+#", "vertex", "+#",   "+#",     "+#", "endloop", "endfacet"};
    size_t at = 0, wl, solids = 0;
    const unsigned char *w;

    if (is_binary_stl(p, n))
        return 0;
    if ((at = find_control(p, n)) < n)
        return import__fail(err, errlen, -EINVAL, "STL: control character at byte %zu", at);
    at = 0;
    while ((wl = next_word(p, n, &at, &w)) != 0) {
        if (!kw_is(w, wl, "solid"))
            return import__fail(err, errlen, -EINVAL, "STL: 'solid' expected at byte %zu", at - wl);
        while (at < n && p[at] != '\n') /* the solid's name */
            at++;
        for (;;) {
            wl = next_word(p, n, &at, &w);
            if (kw_is(w, wl, "endsolid"))
                break;
            if (!kw_is(w, wl, "facet"))
                return import__fail(err, errlen, -EINVAL, "STL: facet or endsolid expected at byte %zu",
                            at - wl);
            for (size_t k = 0; k < sizeof facet / sizeof facet[0]; k++) {
                const char *want = facet[k] + (facet[k][0] == '+');
                wl = facet[k][0] == '+' ? same_line_word(p, n, &at, &w) : next_word(p, n, &at, &w);
                if (want[0] == '#' ? !is_number(w, wl) : !kw_is(w, wl, want))
                    return import__fail(err, errlen, -EINVAL, "STL: malformed facet at byte %zu", at);
            }
        }
        while (at < n && p[at] != '\n') /* the name again */
            at++;
        if (++solids > IMPORT_MAX_PARTS)
            return import__fail(err, errlen, -EINVAL, "more than %u STL solids",
                        (unsigned)IMPORT_MAX_PARTS);
    }
    return 0;
}

/* ---- PLY pre-check ------------------------------------------------------ */

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
        while (i < n && is_space(p[i]))
            i++;
        if (i == n)
            break;
        w[k] = p + i;
        while (i < n && !is_space(p[i]))
            i++;
        wl[k] = (size_t)(p + i - w[k]);
        k++;
    }
    return k;
}

/* Parses a whole decimal word into *v; 0 if it is anything else or over
 * UINT32_MAX. */
static int parse_u32(const unsigned char *w, size_t n, uint32_t *v)
{
    uint64_t x = 0;

    if (n == 0 || n > 10)
        return 0;
    for (size_t i = 0; i < n; i++) {
        if (w[i] < '0' || w[i] > '9')
            return 0;
        x = x * 10 + (uint64_t)(w[i] - '0');
    }
    if (x > UINT32_MAX)
        return 0;
    *v = (uint32_t)x;
    return 1;
}

/*
 * Reads the header into h; returns the offset of the body, or 0 with err
 * set. Keywords are Assimp's, case and all. Like Assimp we skip lines we
 * do not know (Blender writes one); Assimp also ends an element's
 * properties at the first such line and ignores properties after it, so
 * we refuse those rather than count them differently.
 */
/*
 * The element layout Assimp's reader survives, found by fuzzing: vertices
 * first (faces before them made it allocate 32 GB), one vertex element (a
 * second made it write past the positions it allocated for the first), and
 * no list among the vertex's properties (a negative length in an unsigned
 * column: 32 GB). 1, or 0 with err set.
 */
static int ply_check_elements(const ply_header *h, char *err, size_t errlen)
{
    if (h->nelems > 0 && !h->elems[0].is_vertex)
        return import__fail(err, errlen, 0, "PLY: the first element must be vertex");
    for (uint32_t e = 1; e < h->nelems; e++)
        if (h->elems[e].is_vertex)
            return import__fail(err, errlen, 0, "PLY: two vertex elements");
    for (uint32_t k = 0; h->nelems > 0 && k < h->elems[0].nprops; k++)
        if (h->props[h->elems[0].first + k].count_size)
            return import__fail(err, errlen, 0, "PLY: a list property in the vertex element");
    return 1;
}

static size_t ply_parse_header(const unsigned char *p, size_t n, ply_header *h, char *err,
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
        if (k == 0 || kw_is(w[0], wl[0], "comment"))
            continue;
        if (kw_is(w[0], wl[0], "end_header")) {
            if (!have_format)
                return (size_t)import__fail(err, errlen, 0, "PLY header has no format line");
            return ply_check_elements(h, err, errlen) ? at : 0;
        }
        if (kw_is(w[0], wl[0], "format") && k >= 2) {
            have_format = 1;
            h->ascii = kw_is(w[1], wl[1], "ascii");
            h->big_endian = kw_is(w[1], wl[1], "binary_big_endian");
            if (!h->ascii && !h->big_endian && !kw_is(w[1], wl[1], "binary_little_endian"))
                return (size_t)import__fail(err, errlen, 0, "PLY format is not ascii or binary");
        } else if (kw_is(w[0], wl[0], "element")) {
            ply_elem *e;
            if (h->nelems == IMPORT_MAX_PLY_PROPERTIES)
                return (size_t)import__fail(err, errlen, 0, "PLY header declares too many elements");
            e = &h->elems[h->nelems++];
            if (k < 3 || !parse_u32(w[2], wl[2], &e->count))
                return (size_t)import__fail(err, errlen, 0, "PLY element line without a count");
            e->is_vertex = kw_is(w[1], wl[1], "vertex");
            e->first = h->nprops;
            in_props = 1;
            continue;
        } else if (kw_is(w[0], wl[0], "property")) {
            ply_prop *q;
            int kind, count_kind;
            if (!in_props)
                return (size_t)import__fail(err, errlen, 0, "PLY property outside an element");
            if (h->nprops == IMPORT_MAX_PLY_PROPERTIES)
                return (size_t)import__fail(err, errlen, 0, "PLY header declares over %d properties",
                                    IMPORT_MAX_PLY_PROPERTIES);
            q = &h->props[h->nprops++];
            h->elems[h->nelems - 1].nprops++;
            if (k >= 2 && kw_is(w[1], wl[1], "list")) {
                if (k < 4 || !(q->count_size = ply_type(w[2], wl[2], &count_kind)) ||
                    count_kind == PLY_FLOAT || !(q->size = ply_type(w[3], wl[3], &kind)))
                    return (size_t)import__fail(err, errlen, 0, "PLY list property of unknown type");
                q->count_signed = count_kind == PLY_SIGNED;
            } else if (k < 2 || !(q->size = ply_type(w[1], wl[1], &kind))) {
                return (size_t)import__fail(err, errlen, 0, "PLY property of unknown type");
            }
            continue;
        }
        in_props = 0; /* format, obj_info or a line Assimp skips */
    }
    return (size_t)import__fail(err, errlen, 0, "PLY header has no end_header line");
}

/* Reads a list length of q->count_size bytes at p; -1 if negative. */
static int64_t ply_get_count(const unsigned char *p, const ply_prop *q, int big_endian)
{
    uint64_t v = 0;
    unsigned bits = 8u * q->count_size;

    for (unsigned i = 0; i < q->count_size; i++)
        v |= (uint64_t)p[big_endian ? q->count_size - 1 - i : i] << (8 * i);
    if (q->count_signed && (v >> (bits - 1)))
        return -1;
    return (int64_t)v;
}

/* Checks one ASCII element instance, the line p[at..eol): its values,
 * numbers, a list's length first, and nothing more (Assimp reads one line
 * per instance and throws, leaking, on a missing value). */
static int ply_ascii_line(const unsigned char *p, size_t at, size_t eol, const ply_header *h,
                          const ply_elem *el)
{
    for (uint32_t k = el->first; k < el->first + el->nprops; k++) {
        uint64_t want = 1;
        for (uint64_t i = 0; i < want; i++) {
            const unsigned char *w;
            size_t wl = next_word(p, eol, &at, &w);
            if (!is_number(w, wl))
                return 0;
            if (i == 0 && h->props[k].count_size) {
                uint32_t len;
                /* a list of length 0 (a face without vertices) made
                 * Assimp's triangulation abort the process */
                if (!parse_u32(w, wl, &len) || len == 0)
                    return 0;
                want += len;
            }
        }
    }
    {
        const unsigned char *w;
        return next_word(p, eol, &at, &w) == 0;
    }
}

/*
 * Walks the body: every element the header declares must be there, each
 * list no longer than its data. Assimp then allocates and loops in
 * proportion to the file, not to what the header claims. ASCII values
 * must be numbers, one instance a line. Returns 0 or -EINVAL. Linear in
 * the file: each step consumes at least one byte.
 */
static int check_ply(const unsigned char *p, size_t n, char *err, size_t errlen)
{
    ply_header h;
    size_t at = ply_parse_header(p, n, &h, err, errlen), line = 0, bad, text;

    if (at == 0)
        return -EINVAL;
    /* the text: the header, and the body if ASCII; Assimp also ends a
     * PLY line at a CR, so one may only come before a line feed */
    text = h.ascii ? n : at;
    if ((bad = find_control(p, text)) < text)
        return import__fail(err, errlen, -EINVAL, "PLY: control character at byte %zu", bad);
    for (size_t i = 0; i < text; i++)
        if (p[i] == '\r' && (i + 1 == n || p[i + 1] != '\n'))
            return import__fail(err, errlen, -EINVAL, "PLY: carriage return inside a line at byte %zu", i);
    for (uint32_t e = 0; e < h.nelems; e++) {
        const ply_elem *el = &h.elems[e];
        if (el->count > 0 && el->nprops == 0)
            return import__fail(err, errlen, -EINVAL, "PLY element %u has no properties", e);
        /* Every value takes at least a byte: refuse impossible counts
         * before walking them. */
        if ((uint64_t)el->count * el->nprops > n - at)
            return import__fail(err, errlen, -EINVAL,
                        "PLY header declares %u of element %u, more than the file holds", el->count,
                        e);
        for (uint32_t i = 0; i < el->count; i++) {
            if (h.ascii) {
                size_t eol = at;
                while (eol < n && p[eol] != '\n')
                    eol++;
                line++;
                if (at >= n)
                    return import__fail(err, errlen, -EINVAL,
                                "PLY data ends before the elements its header declares");
                if (!ply_ascii_line(p, at, eol, &h, el))
                    return import__fail(err, errlen, -EINVAL,
                                "PLY data line %zu does not match its element %u", line, e);
                at = eol < n ? eol + 1 : n;
                continue;
            }
            for (uint32_t k = el->first; k < el->first + el->nprops; k++) {
                const ply_prop *q = &h.props[k];
                int64_t items = 1;
                if (q->count_size) {
                    if (n - at < q->count_size)
                        return import__fail(err, errlen, -EINVAL,
                                    "PLY data ends before the elements its header declares");
                    items = ply_get_count(p + at, q, h.big_endian);
                    at += q->count_size;
                    if (items == 0) /* Assimp's triangulation aborts */
                        return import__fail(err, errlen, -EINVAL, "PLY: a list of length 0 (element %u)", e);
                }
                if (items < 0 || (uint64_t)items > (n - at) / q->size)
                    return import__fail(err, errlen, -EINVAL,
                                "PLY data ends before the elements its header declares");
                at += (size_t)items * q->size;
            }
        }
    }
    return 0;
}

/* ---- GLB pre-check: the JSON chunk, parsed by jansson ------------------- */

/* What jansson may still allocate on this thread while it parses a GLB's
 * JSON; SIZE_MAX when no parse is under way (jansson's allocator is global,
 * and other code may use the library unbudgeted). Counted per allocation,
 * frees not given back: a bound, not a tally. jansson reports a failed
 * allocation inside its lexer as a syntax error, so the allocator says
 * which of the two ran out. */
static _Thread_local size_t json_budget = SIZE_MAX;
static _Thread_local enum { JSON_FITS, JSON_OVER_BUDGET, JSON_NOMEM } json_short;

static void *json_budget_malloc(size_t size)
{
    void *p;

    if (json_budget != SIZE_MAX) {
        if (size > json_budget) {
            json_short = JSON_OVER_BUDGET;
            return NULL;
        }
        json_budget -= size;
    }
    p = cvre_malloc(size);
    if (!p)
        json_short = JSON_NOMEM;
    return p;
}

static pthread_once_t json_once = PTHREAD_ONCE_INIT;

/* jansson seeds its hash function from /dev/urandom on first use: done
 * here, before a sandbox may forbid opening files. */
static void json_init(void)
{
    json_set_alloc_funcs(json_budget_malloc, free);
    json_object_seed(0);
}

void import_prepare(void) { pthread_once(&json_once, json_init); }

/* Why the GLB is refused, or NULL; *nomem set when memory ran out. */
typedef struct glb_check {
    const char *why;
    int nomem;
} glb_check;

static void glb_refuse(glb_check *c, const char *why)
{
    if (!c->why)
        c->why = why;
}

/* The member key of object v if it is of the wanted kind (or absent: NULL),
 * else NULL and a refusal naming it. */
static json_t *glb_member(glb_check *c, const json_t *v, const char *key, json_type kind,
                          const char *why)
{
    json_t *m = json_object_get(v, key);

    if (m && json_typeof(m) != kind) {
        glb_refuse(c, why);
        return NULL;
    }
    return m;
}

/* An index value: an integer in [0, limit); UINT32_MAX and a refusal
 * otherwise. */
static uint32_t glb_index(glb_check *c, const json_t *v, uint32_t limit, const char *range_why)
{
    json_int_t i;

    if (!json_is_integer(v) || (i = json_integer_value(v)) < 0 || i > UINT32_MAX) {
        glb_refuse(c, "index is not a non-negative integer");
        return UINT32_MAX;
    }
    if ((uint64_t)i >= limit) {
        glb_refuse(c, range_why);
        return UINT32_MAX;
    }
    return (uint32_t)i;
}

/* True if v and everything inside it nest at most IMPORT_MAX_JSON_DEPTH
 * containers deep (v at depth). Recurses at most that deep. */
static int json_depth_ok(const json_t *v, int depth)
{
    const char *key;
    json_t *item;
    size_t i;

    if (!json_is_object(v) && !json_is_array(v))
        return 1;
    if (depth == IMPORT_MAX_JSON_DEPTH)
        return 0;
    if (json_is_array(v)) {
        json_array_foreach(v, i, item) {
            if (!json_depth_ok(item, depth + 1))
                return 0;
        }
    } else {
        json_object_foreach((json_t *)v, key, item) {
            if (!json_depth_ok(item, depth + 1))
                return 0;
        }
    }
    return 1;
}

/*
 * Counts the nodes Assimp will create: one per path from a scene root.
 * Requires trees (each node one parent at most, no cycles, as glTF 2.0
 * does) no deeper than IMPORT_MAX_NODE_DEPTH; a node listed as a root and
 * also as a child, which exporters do, is counted once per path. The
 * arrays have one entry per node. Refuses through c.
 */
static uint64_t glb_node_paths(glb_check *c, const json_t *nodes, const json_t *scenes,
                               uint32_t *parent, uint32_t *roots, uint64_t *paths,
                               uint32_t *stack, uint32_t *level)
{
    uint32_t n = (uint32_t)json_array_size(nodes);
    uint64_t total = 0;
    json_t *node, *scene, *v;
    size_t i, k;

    for (uint32_t x = 0; x < n; x++)
        parent[x] = UINT32_MAX, paths[x] = UINT64_MAX, roots[x] = 0;
    json_array_foreach(nodes, i, node) {
        json_t *ch;
        if (!json_is_object(node)) {
            glb_refuse(c, "node is not an object");
            return 0;
        }
        ch = glb_member(c, node, "children", JSON_ARRAY, "node children is not an array");
        json_array_foreach(ch, k, v) {
            uint32_t x = glb_index(c, v, n, "node child out of range");
            if (c->why)
                return 0;
            if (parent[x] != UINT32_MAX) {
                glb_refuse(c, "node with two parents");
                return 0;
            }
            parent[x] = (uint32_t)i;
        }
        if (c->why)
            return 0;
    }
    json_array_foreach(scenes, i, scene) {
        json_t *rl = glb_member(c, scene, "nodes", JSON_ARRAY, "scene nodes is not an array");
        if (!json_is_object(scene))
            glb_refuse(c, "scene is not an object");
        json_array_foreach(rl, k, v) {
            uint32_t r = glb_index(c, v, n, "scene root out of range");
            if (c->why)
                return 0;
            roots[r]++;
        }
        if (c->why)
            return 0;
    }
    /* paths[x] = roots on x's ancestor chain, x included, and level[x] its
     * length, by walking up to a known ancestor; UINT64_MAX - 1 marks a
     * node on the walk, to find cycles. */
    for (uint32_t x = 0; x < n; x++) {
        uint32_t depth = 0, y = x, lv = 0;
        uint64_t above = 0;
        while (y != UINT32_MAX && paths[y] == UINT64_MAX) {
            paths[y] = UINT64_MAX - 1;
            stack[depth++] = y;
            y = parent[y];
        }
        if (y != UINT32_MAX) {
            if (paths[y] == UINT64_MAX - 1) {
                glb_refuse(c, "node cycle");
                return 0;
            }
            above = paths[y];
            lv = level[y];
        }
        while (depth) {
            y = stack[--depth];
            above += roots[y];
            paths[y] = above;
            level[y] = ++lv;
        }
        if (lv > IMPORT_MAX_NODE_DEPTH) { /* Assimp recurses once per level */
            glb_refuse(c, "node hierarchy too deep");
            return 0;
        }
        total += paths[x];
        if (total > IMPORT_MAX_GLB_NODES)
            return total;
    }
    return total;
}

/* Adds the count of the accessor that index value v names to *total. */
static void glb_add_ref(glb_check *c, const json_t *v, const uint32_t *counts, uint32_t na,
                        uint64_t *total)
{
    uint32_t a = glb_index(c, v, na, "accessor index out of range");

    if (!c->why)
        *total += counts[a];
}

/* Adds the accessors named by the member values of object obj (may be NULL). */
static void glb_add_members(glb_check *c, json_t *obj, const uint32_t *counts, uint32_t na,
                            uint64_t *total)
{
    const char *key;
    json_t *v;

    json_object_foreach(obj, key, v) {
        glb_add_ref(c, v, counts, na, total);
        if (c->why)
            return;
    }
}

/* Sums, over every primitive of every mesh, the counts of the accessors it
 * uses (attributes, indices, morph targets): Assimp copies an accessor once
 * per primitive that uses it. counts[i] is accessor i's count. */
static uint64_t glb_primitive_elements(glb_check *c, const json_t *meshes, const uint32_t *counts,
                                       uint32_t na)
{
    uint64_t total = 0;
    json_t *mesh, *prim, *target;
    size_t i, k, t;

    json_array_foreach(meshes, i, mesh) {
        json_t *prims = glb_member(c, mesh, "primitives", JSON_ARRAY,
                                   "mesh primitives is not an array");
        if (!json_is_object(mesh))
            glb_refuse(c, "mesh is not an object");
        json_array_foreach(prims, k, prim) {
            json_t *ix = json_object_get(prim, "indices"),
                   *attrs = glb_member(c, prim, "attributes", JSON_OBJECT,
                                       "primitive attributes is not an object"),
                   *targets = glb_member(c, prim, "targets", JSON_ARRAY,
                                         "primitive targets is not an array");
            if (!json_is_object(prim))
                glb_refuse(c, "primitive is not an object");
            glb_add_members(c, attrs, counts, na, &total);
            if (ix && !c->why)
                glb_add_ref(c, ix, counts, na, &total);
            json_array_foreach(targets, t, target) {
                if (!json_is_object(target))
                    glb_refuse(c, "morph target is not an object");
                glb_add_members(c, target, counts, na, &total);
                if (c->why)
                    return 0;
            }
            if (c->why)
                return 0;
        }
        if (c->why)
            return 0;
    }
    return total;
}

/* Fills counts[i] with accessor i's count (0 if it has none). */
static void glb_accessor_counts(glb_check *c, const json_t *accessors, uint32_t *counts)
{
    json_t *acc;
    size_t i;

    json_array_foreach(accessors, i, acc) {
        json_t *count = json_object_get(acc, "count");
        if (!json_is_object(acc)) {
            glb_refuse(c, "accessor is not an object");
            return;
        }
        counts[i] = count ? glb_index(c, count, UINT32_MAX, "accessor count too large") : 0;
        if (c->why)
            return;
    }
}

/*
 * The GLB's JSON chunk, parsed within IMPORT_MAX_JSON_MEMORY. rapidjson
 * reads the chunk as a C string, so it ends at the first NUL, and Assimp
 * takes the first of two members with one key: duplicates are refused.
 * Returns the document, or NULL with a refusal.
 */
static json_t *glb_parse(glb_check *c, const unsigned char *s, size_t len, char *where,
                         size_t wherelen)
{
    const unsigned char *nul = memchr(s, 0, len);
    json_error_t e;
    json_t *doc;

    import_prepare();
    json_budget = IMPORT_MAX_JSON_MEMORY;
    json_short = JSON_FITS;
    doc = json_loadb((const char *)s, nul ? (size_t)(nul - s) : len, JSON_REJECT_DUPLICATES, &e);
    json_budget = SIZE_MAX;
    if (json_short != JSON_FITS) {
        json_decref(doc);
        c->nomem = json_short == JSON_NOMEM;
        glb_refuse(c, c->nomem ? "out of memory" : "JSON takes too much memory to parse");
        return NULL;
    }
    if (doc)
        return doc;
    if (json_error_code(&e) == json_error_stack_overflow) {
        glb_refuse(c, "JSON nested too deep");
    } else {
        snprintf(where, wherelen, "%s (near byte %zu)", e.text, (size_t)e.position + 20);
        glb_refuse(c, where);
    }
    return NULL;
}

/*
 * Checks a GLB's header and JSON chunk before Assimp sees them: version 2,
 * lengths that agree with the file, strict JSON no deeper than
 * IMPORT_MAX_JSON_DEPTH (so that Assimp's glTF reader, not a fallback
 * importer, takes it), asset.version 2.x, the members read here of the
 * types glTF gives them, node trees no deeper than IMPORT_MAX_NODE_DEPTH,
 * at most IMPORT_MAX_GLB_NODES nodes once expanded, and at most
 * IMPORT_MAX_GLB_ELEMENTS accessor elements copied into meshes (and
 * IMPORT_GLB_ELEMENTS_PER_BYTE per byte of the file). Every loop walks an
 * array or object jansson sized. Returns 0, -EINVAL or -ENOMEM.
 */
static int check_glb(const unsigned char *p, size_t n, char *err, size_t errlen)
{
    glb_check c = {NULL, 0};
    char where[200];
    json_t *doc, *nodes, *scenes, *meshes, *accessors, *version;
    uint32_t json_len, nn, na;
    uint32_t *u32 = NULL;
    uint64_t *paths = NULL, total = 0, elements_max = (uint64_t)IMPORT_GLB_ELEMENTS_PER_BYTE * n;
    int rc;

    if (elements_max > IMPORT_MAX_GLB_ELEMENTS)
        elements_max = IMPORT_MAX_GLB_ELEMENTS;

    if (n < 20)
        return import__fail(err, errlen, -EINVAL, "GLB shorter than its header");
    if (le_get_u32(p + 4) != 2)
        return import__fail(err, errlen, -EINVAL, "GLB version %u (only glTF 2.0 is supported)",
                    le_get_u32(p + 4));
    if (le_get_u32(p + 8) != n)
        return import__fail(err, errlen, -EINVAL, "GLB length field says %u bytes, the file has %zu",
                    le_get_u32(p + 8), n);
    json_len = le_get_u32(p + 12);
    if (le_get_u32(p + 16) != 0x4E4F534Au || json_len > n - 20)
        return import__fail(err, errlen, -EINVAL, "GLB does not start with a whole JSON chunk");

    doc = glb_parse(&c, p + 20, json_len, where, sizeof where);
    if (doc && !json_is_object(doc))
        glb_refuse(&c, "JSON document is not an object");
    if (doc && !c.why && !json_depth_ok(doc, 0))
        glb_refuse(&c, "JSON nested too deep");
    version = json_object_get(json_object_get(doc, "asset"), "version");
    if (!c.why && (!json_is_string(version) || json_string_value(version)[0] != '2'))
        glb_refuse(&c, "asset.version is not 2.x");
    if (c.why) {
        rc = c.nomem ? import__fail(err, errlen, -ENOMEM, "out of memory")
                     : import__fail(err, errlen, -EINVAL, "GLB JSON: %s", c.why);
        goto cleanup;
    }

    nodes = glb_member(&c, doc, "nodes", JSON_ARRAY, "nodes is not an array");
    scenes = glb_member(&c, doc, "scenes", JSON_ARRAY, "scenes is not an array");
    meshes = glb_member(&c, doc, "meshes", JSON_ARRAY, "meshes is not an array");
    accessors = glb_member(&c, doc, "accessors", JSON_ARRAY, "accessors is not an array");
    if (c.why) {
        rc = import__fail(err, errlen, -EINVAL, "GLB: %s", c.why);
        goto cleanup;
    }
    nn = (uint32_t)json_array_size(nodes); /* under the JSON's length: 32 bits */
    na = (uint32_t)json_array_size(accessors);
    /* parent, roots, stack and level for the nodes, then accessor counts */
    u32 = cvre_calloc((size_t)4 * nn + na + 1, sizeof *u32);
    paths = cvre_malloc(((size_t)nn + 1) * sizeof *paths);
    if (!u32 || !paths) {
        rc = import__fail(err, errlen, -ENOMEM, "out of memory");
        goto cleanup;
    }
    if (nodes)
        total = glb_node_paths(&c, nodes, scenes, u32, u32 + nn, paths, u32 + 2 * nn,
                               u32 + 3 * nn);
    if (!c.why && total > IMPORT_MAX_GLB_NODES) {
        rc = import__fail(err, errlen, -EINVAL, "GLB node hierarchy expands to over %u nodes",
                  (unsigned)IMPORT_MAX_GLB_NODES);
        goto cleanup;
    }
    if (!c.why)
        glb_accessor_counts(&c, accessors, u32 + 4 * nn);
    total = c.why ? 0 : glb_primitive_elements(&c, meshes, u32 + 4 * nn, na);
    if (c.why)
        rc = import__fail(err, errlen, -EINVAL, "GLB: %s", c.why);
    else if (total > elements_max)
        rc = import__fail(err, errlen, -EINVAL,
                  "GLB meshes copy %llu accessor elements, over the limit of %llu for its size",
                  (unsigned long long)total, (unsigned long long)elements_max);
    else
        rc = 0;
cleanup:
    free(u32);
    free(paths);
    json_decref(doc);
    return rc;
}

/* ---- from Assimp's scene to triangles ----------------------------------- */

typedef struct walk {
    const struct aiScene *scene;
    const uint32_t *mesh_tris; /* triangles in each mesh */
    uint32_t max_tris;
    uint64_t ntris; /* counted, then emitted */
    float *out;     /* NULL while counting */
    int z_up;
    double scale;
    float min[3], max[3];
    char *err;
    size_t errlen;
} walk;

/* Counts each mesh's triangles into w->mesh_tris, checking the indices
 * they use. Polygons were triangulated and anything else (points, lines)
 * is skipped. Returns 0 or -EINVAL. */
static int count_meshes(const struct aiScene *sc, uint32_t *mesh_tris, char *err, size_t errlen)
{
    for (unsigned m = 0; m < sc->mNumMeshes; m++) {
        const struct aiMesh *me = sc->mMeshes[m];
        uint32_t t = 0;
        if (!me)
            return import__fail(err, errlen, -EINVAL, "mesh %u missing", m);
        for (unsigned f = 0; f < me->mNumFaces; f++) {
            const struct aiFace *fa = &me->mFaces[f];
            if (fa->mNumIndices != 3)
                continue;
            if (!me->mVertices)
                return import__fail(err, errlen, -EINVAL, "mesh %u has faces but no positions", m);
            for (int k = 0; k < 3; k++)
                if (fa->mIndices[k] >= me->mNumVertices)
                    return import__fail(err, errlen, -EINVAL, "mesh %u: vertex index %u out of range", m,
                                fa->mIndices[k]);
            t++;
        }
        mesh_tris[m] = t;
    }
    return 0;
}

/* Sums, over polygons of more than four vertices (quads are split in
 * constant time), the square of their size: what triangulating costs. */
static int check_polygons(const struct aiScene *sc, char *err, size_t errlen)
{
    uint64_t work = 0;
    unsigned largest = 0;

    for (unsigned m = 0; m < sc->mNumMeshes; m++) {
        const struct aiMesh *me = sc->mMeshes[m];
        if (!me)
            continue;
        for (unsigned f = 0; f < me->mNumFaces; f++) {
            unsigned k = me->mFaces[f].mNumIndices;
            if (k <= 4)
                continue;
            if (k > largest)
                largest = k;
            work += (uint64_t)k * k;
            if (work > IMPORT_MAX_POLYGON_WORK)
                return import__fail(err, errlen, -EINVAL,
                            "polygons too large to triangulate (largest so far %u vertices; "
                            "their squared sizes may total %llu)",
                            largest, (unsigned long long)IMPORT_MAX_POLYGON_WORK);
        }
    }
    return 0;
}

/* r = a * b, 4x4 row-major. */
static void mat_mul(double r[16], const double a[16], const double b[16])
{
    for (int i = 0; i < 4; i++)
        for (int k = 0; k < 4; k++)
            r[4 * i + k] = a[4 * i] * b[k] + a[4 * i + 1] * b[4 + k] + a[4 * i + 2] * b[8 + k] +
                           a[4 * i + 3] * b[12 + k];
}

/* Writes one vertex: node transform m, then the up-axis, then the scale. */
static int emit_vertex(walk *w, const double m[16], const struct aiVector3D *v, float *o)
{
    double x = v->x, y = v->y, z = v->z;
    double p[3] = {m[0] * x + m[1] * y + m[2] * z + m[3], m[4] * x + m[5] * y + m[6] * z + m[7],
                   m[8] * x + m[9] * y + m[10] * z + m[11]};

    if (w->z_up) {
        double t = p[1];
        p[1] = p[2];
        p[2] = -t;
    }
    for (int k = 0; k < 3; k++) {
        double s = p[k] * w->scale;
        /* also false for NaN; checked before the conversion, which
         * would be undefined out of range */
        if (!(fabs(s) <= FLT_MAX))
            return import__fail(w->err, w->errlen, -EINVAL,
                        "coordinate not a finite float in triangle %llu",
                        (unsigned long long)w->ntris + 1);
        if (fabs(s) > IMPORT_MAX_COORD)
            return import__fail(w->err, w->errlen, -EINVAL,
                        "coordinate %.3g m in triangle %llu is beyond %.0f km of the model's origin", s,
                        (unsigned long long)w->ntris + 1, IMPORT_MAX_COORD / 1000.0);
        o[k] = (float)s;
        if (o[k] < w->min[k])
            w->min[k] = o[k];
        if (o[k] > w->max[k])
            w->max[k] = o[k];
    }
    return 0;
}

/*
 * Visits node and its subtree with parent's accumulated transform: counts
 * the triangles of every mesh instance (w->out NULL) or writes them.
 * Counting stops as soon as the total passes w->max_tris. Returns 0,
 * -EINVAL or -EFBIG.
 */
static int visit(walk *w, const struct aiNode *node, const double parent[16], unsigned depth)
{
    const struct aiMatrix4x4 *t = &node->mTransformation;
    const double local[16] = {t->a1, t->a2, t->a3, t->a4, t->b1, t->b2, t->b3, t->b4,
                              t->c1, t->c2, t->c3, t->c4, t->d1, t->d2, t->d3, t->d4};
    double m[16];
    int rc;

    if (depth > IMPORT_MAX_NODE_DEPTH)
        return import__fail(w->err, w->errlen, -EINVAL, "node hierarchy deeper than %d",
                    IMPORT_MAX_NODE_DEPTH);
    mat_mul(m, parent, local);
    for (unsigned i = 0; i < node->mNumMeshes; i++) {
        unsigned mi = node->mMeshes[i];
        const struct aiMesh *me;
        if (mi >= w->scene->mNumMeshes)
            return import__fail(w->err, w->errlen, -EINVAL, "node refers to missing mesh %u", mi);
        if (!w->out) {
            w->ntris += w->mesh_tris[mi];
            if (w->ntris > w->max_tris)
                return import__fail(w->err, w->errlen, -EFBIG, "more than %u triangles", w->max_tris);
            continue;
        }
        me = w->scene->mMeshes[mi];
        for (unsigned f = 0; f < me->mNumFaces; f++) {
            const struct aiFace *fa = &me->mFaces[f];
            float *o = w->out + 9 * w->ntris;
            if (fa->mNumIndices != 3)
                continue;
            for (int k = 0; k < 3; k++)
                if ((rc = emit_vertex(w, m, &me->mVertices[fa->mIndices[k]], o + 3 * k)) != 0)
                    return rc;
            w->ntris++;
        }
    }
    for (unsigned i = 0; i < node->mNumChildren; i++) {
        if (!node->mChildren[i])
            return import__fail(w->err, w->errlen, -EINVAL, "node child missing");
        if ((rc = visit(w, node->mChildren[i], m, depth + 1)) != 0)
            return rc;
    }
    return 0;
}

/* Triangles of every mesh instance into out. Returns 0, -EINVAL, -EFBIG
 * or -ENOMEM. */
static int collect(const struct aiScene *sc, const import_options *opt, import_mesh *out, char *err,
                   size_t errlen)
{
    static const double identity[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    walk w;
    uint32_t *mesh_tris;
    int rc;

    if (!sc->mRootNode)
        return import__fail(err, errlen, -EINVAL, "no scene graph");
    mesh_tris = cvre_calloc(sc->mNumMeshes, sizeof *mesh_tris);
    if (!mesh_tris)
        return import__fail(err, errlen, -ENOMEM, "out of memory");
    memset(&w, 0, sizeof w);
    w.scene = sc;
    w.mesh_tris = mesh_tris;
    w.max_tris = opt->max_triangles;
    w.z_up = opt->z_up;
    w.scale = opt->unit_scale;
    w.err = err;
    w.errlen = errlen;
    if ((rc = count_meshes(sc, mesh_tris, err, errlen)) != 0 ||
        (rc = visit(&w, sc->mRootNode, identity, 0)) != 0)
        goto cleanup;
    if (w.ntris == 0) {
        rc = import__fail(err, errlen, -EINVAL, "the file has no triangles");
        goto cleanup;
    }
    /* GCOVR_EXCL_START: w.ntris is at most max_triangles, a uint32_t, so
     * this holds only where size_t has 32 bits */
    if (w.ntris > SIZE_MAX / (9 * sizeof(float))) {
        rc = import__fail(err, errlen, -ENOMEM, "out of memory");
        goto cleanup;
    }
    /* GCOVR_EXCL_STOP */
    out->tris = cvre_malloc((size_t)w.ntris * 9 * sizeof(float));
    if (!out->tris) {
        rc = import__fail(err, errlen, -ENOMEM, "out of memory for %llu triangles",
                  (unsigned long long)w.ntris);
        goto cleanup;
    }
    w.out = out->tris;
    w.ntris = 0;
    for (int k = 0; k < 3; k++) {
        w.min[k] = FLT_MAX;
        w.max[k] = -FLT_MAX;
    }
    if ((rc = visit(&w, sc->mRootNode, identity, 0)) != 0) {
        import_mesh_free(out);
        goto cleanup;
    }
    out->ntris = (uint32_t)w.ntris;
    memcpy(out->min, w.min, sizeof w.min);
    memcpy(out->max, w.max, sizeof w.max);
cleanup:
    free(mesh_tris);
    return rc;
}

/* ---- the entry points --------------------------------------------------- */

/* The format the hint names, -1 if none, -2 if unsupported. */
static int hint_format(const char *hint)
{
    if (!hint || !*hint)
        return -1;
    if (*hint == '.')
        hint++;
    for (int f = 0; f < FMT_COUNT; f++)
        if (strlen(hint) == strlen(formats[f].ext) &&
            starts_with((const unsigned char *)hint, strlen(hint), formats[f].ext))
            return f;
    return -2;
}

static int check_options(const import_options *o, char *err, size_t errlen)
{
    if (!(o->unit_scale > 0.0f) || !isfinite(o->unit_scale))
        return import__fail(err, errlen, -EINVAL, "unit_scale must be positive and finite");
    if (o->max_triangles == 0)
        return import__fail(err, errlen, -EINVAL, "max_triangles must be at least 1");
    return 0;
}

void import_mesh_free(import_mesh *m)
{
    free(m->tris);
    memset(m, 0, sizeof *m);
}

int import_model(const void *data, size_t len, const char *hint, const import_options *opt,
                 import_mesh *out, char *err, size_t errlen)
{
    static const import_options defaults = IMPORT_OPTIONS_DEFAULT;
    const unsigned char *p = data;
    const struct aiScene *sc;
    memfs fs;
    char name[16];
    int fmt, hinted, rc;

    if (errlen)
        err[0] = 0;
    if (!out)
        return import__fail(err, errlen, -EINVAL, "no output mesh");
    memset(out, 0, sizeof *out);
    if (!opt)
        opt = &defaults;
    if ((rc = check_options(opt, err, errlen)) != 0)
        return rc;
    if (!data || len == 0)
        return import__fail(err, errlen, -EINVAL, "empty file");
    if (len > IMPORT_MAX_BYTES)
        return import__fail(err, errlen, -EFBIG, "file of %zu bytes is over the %u-byte limit", len,
                    (unsigned)IMPORT_MAX_BYTES);
    hinted = hint_format(hint);
    if (hinted == -2)
        return import__fail(err, errlen, -EINVAL, "unsupported format \"%.16s\" (supported: %s)", hint,
                    import_formats());
    fmt = sniff(p, len);
    if (fmt < 0 && hinted == FMT_OBJ)
        fmt = FMT_OBJ;
    if (fmt < 0)
        return hinted >= 0 ? import__fail(err, errlen, -EINVAL, "not a valid %s file", formats[hinted].name)
                           : import__fail(err, errlen, -EINVAL, "unrecognised format (supported: %s)",
                                  import_formats());
    if ((rc = formats[fmt].check(p, len, err, errlen)) != 0)
        return rc;

    snprintf(name, sizeof name, "upload.%s", formats[fmt].ext);
    memset(&fs, 0, sizeof fs);
    fs.io.OpenProc = mem_open;
    fs.io.CloseProc = mem_close;
    fs.name = name;
    fs.data = data;
    fs.len = len;
    pthread_mutex_lock(&assimp_lock);
    sc = aiImportFileEx(name, 0, &fs.io);
    if (!sc) {
        const char *why = aiGetErrorString();
        rc = strstr(why, "bad_alloc") ? -ENOMEM : -EINVAL;
        import__fail(err, errlen, rc, "%s parse error: %s", formats[fmt].name,
             *why ? why : "(no reason given)");
    }
    pthread_mutex_unlock(&assimp_lock);
    if (!sc)
        return rc;
    if ((rc = check_polygons(sc, err, errlen)) != 0) {
        aiReleaseImport(sc);
        return rc;
    }
    /* On failure this releases the scene. */
    sc = aiApplyPostProcessing(sc, aiProcess_Triangulate);
    /* GCOVR_EXCL_START: Assimp's triangulation throws nothing but
     * std::bad_alloc (caught inside, the scene freed), so only running out
     * of memory there, which no test can cause at will, gets here */
    if (!sc)
        return import__fail(err, errlen, -EINVAL, "%s: triangulation failed", formats[fmt].name);
    /* GCOVR_EXCL_STOP */
    rc = collect(sc, opt, out, err, errlen);
    aiReleaseImport(sc);
    return rc;
}
