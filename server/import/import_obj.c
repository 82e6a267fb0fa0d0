/*
 * import_obj.c: Wavefront OBJ, text. It has no signature, no unit and no
 * up axis; its faces name vertices by index.
 *
 * What Assimp 5.2.5's OBJ reader does with hostile input: it leaks its
 * mesh (1.3 KB) when it throws, as on a face naming a vertex that does not
 * exist, so a client could leak server memory at will; and it makes a mesh
 * and a node per named part and looks the names up linearly (200,000
 * `usemtl` lines took 54 s and 7 GB). The pre-check reads the file as the
 * reader does and refuses what would make it throw, and counts the parts.
 * Its `mtllib` would open a file on the local disk: import.c serves the
 * upload and nothing else.
 */
#include "importInt.h"
#include "import.h"

#include <errno.h>
#include <string.h>

#include "err.h"

/* OBJ has no signature: the first line that is neither blank nor a
 * comment must be one of its statements. */
static int obj_sniff(const unsigned char *p, size_t n)
{
    static const char *const words[] = {"v", "vt", "vn", "vp", "f",      "l",     "p",
                                        "o", "g",  "s",  "mg", "mtllib", "usemtl"};
    size_t i = 0, w;

    for (;;) {
        while (i < n && import__is_space(p[i]))
            i++;
        if (i == n)
            return 0;
        if (p[i] != '#')
            break;
        while (i < n && p[i] != '\n')
            i++;
    }
    for (w = i; w < n && !import__is_space(p[w]); w++)
        ;
    if (w == n || (p[w] != ' ' && p[w] != '\t'))
        return 0;
    for (size_t k = 0; k < sizeof words / sizeof words[0]; k++)
        if (strlen(words[k]) == w - i && memcmp(p + i, words[k], w - i) == 0)
            return 1;
    return 0;
}

/* Reads an OBJ face, line or point vertex: v, v/t, v//n or v/t/n, integers
 * of at most nine digits (Assimp reads them as int). Returns 0 with the
 * position index in *v, or -EINVAL for anything else. */
static int obj_vertex_ref(const unsigned char *w, size_t n, long long *v)
{
    size_t part = 0, s = 0;

    for (size_t i = 0; i <= n; i++) {
        size_t a;
        if (i < n && w[i] != '/')
            continue;
        a = s + (s < i && w[s] == '-');
        if ((i > s || part == 0) && (!import__all_digits(w + a, i - a) || i - a > 9))
            return -EINVAL;
        if (part == 0) {
            *v = 0;
            for (size_t k = a; k < i; k++)
                *v = *v * 10 + (w[k] - '0');
            if (a > s)
                *v = -*v;
        }
        if (++part > 3)
            return -EINVAL;
        s = i + 1;
    }
    return 0;
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
static int obj_check(const unsigned char *p, size_t n, char *err, size_t errlen)
{
    unsigned long long vertices = 0, line = 0, parts = 0;
    long long highest = 0; /* the largest positive index used */
    size_t bad = import__find_control(p, n);

    if (bad < n)
        return cvre_fail(err, errlen, -EINVAL, "OBJ: control character at byte %zu", bad);
    for (size_t at = 0, eol; at < n; at = eol + 1) {
        size_t cur = at, wl;
        const unsigned char *w, *x;
        size_t xl;
        int vertex, element;
        for (eol = at; eol < n && p[eol] != '\n' && p[eol] != '\r'; eol++) /* CR ends one too */
            ;
        if (eol > at && p[eol - 1] == '\\')
            return cvre_fail(err, errlen, -EINVAL, "OBJ line %llu: line continuations are not supported",
                        line + 1);
        wl = import__next_word(p, eol, &cur, &w);
        vertex = import__kw_is(w, wl, "v") || import__kw_is(w, wl, "vt") || import__kw_is(w, wl, "vn");
        element = import__kw_is(w, wl, "f") || import__kw_is(w, wl, "l") || import__kw_is(w, wl, "p");
        if (wl && ((w != p + at && (vertex || element)) ||
                   (w == p + at && strchr("flpv", *w) && !vertex && !element)))
            return cvre_fail(err, errlen, -EINVAL, "OBJ line %llu: unknown or indented statement",
                        line + 1);
        if (vertex) {
            int k = 0;
            while ((xl = import__next_word(p, eol, &cur, &x)) != 0) {
                if (!import__is_number(x, xl) || x[0] == '.')
                    return cvre_fail(err, errlen, -EINVAL, "OBJ line %llu: malformed number", line + 1);
                k++;
            }
            if (wl == 1 ? k != 3 && k != 4 && k != 6 : w[1] == 'n' ? k != 3 : k < 1 || k > 3)
                return cvre_fail(err, errlen, -EINVAL, "OBJ line %llu: wrong count of numbers",
                            line + 1);
            vertices += wl == 1;
        } else if (element) {
            while ((xl = import__next_word(p, eol, &cur, &x)) != 0) {
                long long v = 0;
                if (obj_vertex_ref(x, xl, &v) != 0 || v == 0)
                    return cvre_fail(err, errlen, -EINVAL, "OBJ line %llu: malformed vertex index",
                                line + 1);
                if (v < 0 && (unsigned long long)-v > vertices)
                    return cvre_fail(err, errlen, -EINVAL,
                                "OBJ line %llu: vertex index %lld before the first vertex",
                                line + 1, v);
                if (v > highest)
                    highest = v;
            }
        } else if (wl && (*w == 'o' || *w == 'g' || import__kw_is(w, wl, "usemtl"))) {
            parts++; /* Assimp takes any word starting with o or g */
        }
        line += eol < n && p[eol] == '\n';
    }
    if ((unsigned long long)highest > vertices)
        return cvre_fail(err, errlen, -EINVAL, "OBJ vertex index %lld, but the file has %llu", highest,
                    vertices);
    if (parts > IMPORT_MAX_PARTS)
        return cvre_fail(err, errlen, -EINVAL,
                    "%llu OBJ objects, groups and material switches, over the limit of %u", parts,
                    (unsigned)IMPORT_MAX_PARTS);
    return 0;
}

const import__format import__obj = {"obj", "OBJ", obj_sniff, obj_check};
