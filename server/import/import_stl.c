/*
 * import_stl.c: STL, binary (an 80-byte header, a triangle count, 50 bytes
 * per triangle) or ASCII (solids of facets, each a normal and three
 * vertices). No unit, no up axis.
 *
 * What Assimp 5.2.5's STL reader does with hostile input: without an
 * extension it takes a binary STL for OBJ (import.c always names the
 * format); the ASCII reader leaks its mesh and node (2.4 KB) whenever it
 * throws, which any cut or malformed facet makes it do, and makes a mesh
 * and a node per solid (empty solids took 1 GB from 6 MB). The pre-check
 * accepts only the facets it reads without throwing, and counts the
 * solids. A binary STL whose count disagrees with its size Assimp refuses
 * itself, cleanly.
 */
#include "importInt.h"
#include "import.h"

#include <errno.h>

#include "err.h"
#include "le.h"

/* A binary STL is an 80-byte header, a triangle count and 50 bytes per
 * triangle, nothing more (Assimp's test too, checked before "solid"
 * because binary headers often start with that word). */
static int is_binary_stl(const unsigned char *p, size_t n)
{
    return n >= 84 && (n - 84) % 50 == 0 && (n - 84) / 50 == le_get_u32(p + 80);
}

/* Reads the next word of p[0..n) from *at if it is on the same line. */
static size_t same_line_word(const unsigned char *p, size_t n, size_t *at, const unsigned char **w)
{
    while (*at < n && (p[*at] == ' ' || p[*at] == '\t'))
        (*at)++;
    if (*at < n && (p[*at] == '\n' || p[*at] == '\r'))
        return 0;
    return import__next_word(p, n, at, w);
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
static int stl_check(const unsigned char *p, size_t n, char *err, size_t errlen)
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
    if ((at = import__find_control(p, n)) < n)
        return cvre_fail(err, errlen, -EINVAL, "STL: control character at byte %zu", at);
    at = 0;
    while ((wl = import__next_word(p, n, &at, &w)) != 0) {
        if (!import__kw_is(w, wl, "solid"))
            return cvre_fail(err, errlen, -EINVAL, "STL: 'solid' expected at byte %zu", at - wl);
        while (at < n && p[at] != '\n') /* the solid's name */
            at++;
        for (;;) {
            wl = import__next_word(p, n, &at, &w);
            if (import__kw_is(w, wl, "endsolid"))
                break;
            if (!import__kw_is(w, wl, "facet"))
                return cvre_fail(err, errlen, -EINVAL, "STL: facet or endsolid expected at byte %zu",
                            at - wl);
            for (size_t k = 0; k < sizeof facet / sizeof facet[0]; k++) {
                const char *want = facet[k] + (facet[k][0] == '+');
                wl = facet[k][0] == '+' ? same_line_word(p, n, &at, &w) : import__next_word(p, n, &at, &w);
                if (want[0] == '#' ? !import__is_number(w, wl) : !import__kw_is(w, wl, want))
                    return cvre_fail(err, errlen, -EINVAL, "STL: malformed facet at byte %zu", at);
            }
        }
        while (at < n && p[at] != '\n') /* the name again */
            at++;
        if (++solids > IMPORT_MAX_PARTS)
            return cvre_fail(err, errlen, -EINVAL, "more than %u STL solids",
                        (unsigned)IMPORT_MAX_PARTS);
    }
    return 0;
}

/* A binary STL by its size, or ASCII by its first word. */
static int stl_sniff(const unsigned char *p, size_t n)
{
    size_t i = 0;

    if (is_binary_stl(p, n))
        return 1;
    while (i < n && import__is_space(p[i]))
        i++;
    return import__starts_with(p + i, n - i, "solid") && (n - i == 5 || import__is_space(p[i + 5]));
}

const import__format import__stl = {"stl", "STL", stl_sniff, stl_check};
