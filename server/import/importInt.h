/*
 * importInt.h: what the importer's files share beyond import.h. Not for
 * callers of the importer. The files, from the entry point down:
 *
 *   import.c        import_model: options, which format the content is,
 *                   Assimp's call through an in-memory file, its scene
 *                   walked into triangles; the limits' checks
 *   import_obj.c    OBJ        \
 *   import_stl.c    STL         | one model format each: its signature and
 *   import_ply.c    PLY         | the pre-check that refuses what Assimp's
 *   import_glb.c    GLB        /  reader of it would mishandle
 *   import_text.c   words and numbers read as Assimp's text readers do
 *                   (OBJ, ASCII STL, PLY)
 *   import_json.c   a GLB's JSON chunk, parsed by jansson within a memory
 *                   budget, and typed access to its values
 *   import_pipe.c, import_proc.c: the isolated importer's request and
 *                   answer, and running it (import_pipe.h, import_proc.h)
 *
 * Results follow CONTRIBUTING.md: 0 or a negative errno, the reason in the
 * caller's err buffer through cvre_fail; "True if" functions are tests.
 */
#ifndef CVRE_IMPORT_INT_H
#define CVRE_IMPORT_INT_H

#include <stddef.h>
#include <stdint.h>

#include <jansson.h>

/* Turns every byte of the message in err[0..errlen) that is not printable
 * ASCII into '?' (nothing if errlen is 0), so that a message quoting the
 * upload, Assimp or a path stays one line whatever the bytes were. */
void import__printable(char *err, size_t errlen);

/* ---- the formats (import_obj.c, import_stl.c, import_ply.c, import_glb.c) */

typedef struct import__format {
    const char *ext;  /* ours and Assimp's name for it */
    const char *name; /* for messages */
    /* True if p[0..n) (n >= 1) bears the format's signature. */
    int (*sniff)(const unsigned char *p, size_t n);
    /* Refuses what Assimp would mishandle in p[0..n): 0, or -EINVAL (or
     * -ENOMEM) with err set. Linear in n, bounded in memory. */
    int (*check)(const unsigned char *p, size_t n, char *err, size_t errlen);
} import__format;

extern const import__format import__obj, import__stl, import__ply, import__glb;

/* ---- text as Assimp reads it (import_text.c) ----------------------------- */

/* True for the bytes isspace() takes in the C locale. */
int import__is_space(unsigned char c);

/* True if p[0..n) starts with the lower-case word w, case-insensitively. */
int import__starts_with(const unsigned char *p, size_t n, const char *w);

/* Offset of the first control character other than tab and line ends in
 * p[0..n), or n. Assimp's text readers end a line or the whole file at
 * NUL, CR or form feed where a plain reading would not, so text formats
 * must not hold them elsewhere. */
size_t import__find_control(const unsigned char *p, size_t n);

/* Reads the next whitespace-separated word of p[0..n) from *at, advancing
 * it past the word: its length (0 at the end) and its start in *w. */
size_t import__next_word(const unsigned char *p, size_t n, size_t *at, const unsigned char **w);

/* True if the word w[0..n) is exactly kw (Assimp's keywords are lower case). */
int import__kw_is(const unsigned char *w, size_t n, const char *kw);

/* True if the word w[0..n) is all digits, at least one. */
int import__all_digits(const unsigned char *w, size_t n);

/* True if the whole word w[0..n) is a number Assimp's fast_atof reads
 * without throwing and without leaving characters for the next read:
 * decimal, with optional sign, fraction and exponent, or nan/inf (refused
 * later as non-finite). */
int import__is_number(const unsigned char *w, size_t n);

/* ---- a GLB's JSON chunk (import_json.c) ---------------------------------- */

/* A walk over a JSON document that keeps its first refusal: why the
 * document is refused (NULL while it is not), and nomem set when the
 * refusal is that memory ran out. */
typedef struct import__json_check {
    const char *why;
    int nomem;
} import__json_check;

/* Refuses the document for why, unless it is refused already. */
void import__json_refuse(import__json_check *c, const char *why);

/*
 * Parses s[0..len) within IMPORT_MAX_JSON_MEMORY into an object no deeper
 * than IMPORT_MAX_JSON_DEPTH. The text ends at its first NUL, as for
 * rapidjson (Assimp's parser), which reads it as a C string; and Assimp
 * takes the first of two members with one key, so duplicates are refused.
 * Returns the document (the caller json_decrefs it), or NULL with a
 * refusal in c. A syntax error's refusal is written into where[0..wherelen)
 * with its place in the file (s lies at offset there).
 */
json_t *import__json_load(import__json_check *c, const unsigned char *s, size_t len, size_t offset,
                          char *where, size_t wherelen);

/* The member key of object v if it is of the wanted kind (or absent: NULL),
 * else NULL and the refusal why. */
json_t *import__json_member(import__json_check *c, const json_t *v, const char *key, json_type kind,
                            const char *why);

/* An index value: an integer in [0, limit); UINT32_MAX and a refusal
 * (range_why when it is an integer out of range) otherwise. */
uint32_t import__json_index(import__json_check *c, const json_t *v, uint32_t limit, const char *range_why);

#endif
