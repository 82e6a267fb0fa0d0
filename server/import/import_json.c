/*
 * import_json.c: the one JSON reader of the importer, for a GLB's JSON
 * chunk. jansson parses it (a hand-written tokenizer here once let an
 * object stand where an array was expected and overflowed the heap),
 * within a memory budget and a nesting depth, because Assimp's own parser
 * (rapidjson) recurses per level and overflowed an 8 MiB stack at 10^6
 * levels. The walk over the document then reads every value through
 * import__json_member and import__json_index, which check its type. What
 * the values mean to glTF is import_glb.c's. The contracts are in
 * importInt.h.
 */
#include "importInt.h"
#include "import.h"

#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"

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

void import__json_refuse(import__json_check *c, const char *why)
{
    if (!c->why)
        c->why = why;
}

json_t *import__json_member(import__json_check *c, const json_t *v, const char *key, json_type kind,
                            const char *why)
{
    json_t *m = json_object_get(v, key);

    if (m && json_typeof(m) != kind) {
        import__json_refuse(c, why);
        return NULL;
    }
    return m;
}

uint32_t import__json_index(import__json_check *c, const json_t *v, uint32_t limit, const char *range_why)
{
    json_int_t i;

    if (!json_is_integer(v) || (i = json_integer_value(v)) < 0 || i > UINT32_MAX) {
        import__json_refuse(c, "index is not a non-negative integer");
        return UINT32_MAX;
    }
    if ((uint64_t)i >= limit) {
        import__json_refuse(c, range_why);
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

json_t *import__json_load(import__json_check *c, const unsigned char *s, size_t len, size_t offset,
                          char *where, size_t wherelen)
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
        import__json_refuse(c, c->nomem ? "out of memory" : "JSON takes too much memory to parse");
        return NULL;
    }
    if (!doc) {
        if (json_error_code(&e) == json_error_stack_overflow) {
            import__json_refuse(c, "JSON nested too deep");
        } else {
            snprintf(where, wherelen, "%s (near byte %zu)", e.text, (size_t)e.position + offset);
            import__json_refuse(c, where);
        }
        return NULL;
    }
    if (!json_is_object(doc))
        import__json_refuse(c, "JSON document is not an object");
    else if (!json_depth_ok(doc, 0))
        import__json_refuse(c, "JSON nested too deep");
    if (c->why) {
        json_decref(doc);
        return NULL;
    }
    return doc;
}
