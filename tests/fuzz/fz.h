/*
 * fz.h: what the fuzz targets share (tests/fuzz/README.md).
 *
 * A target is one file, fuzz_<name>.c, that defines LLVMFuzzerTestOneInput
 * (the model targets take theirs from fz_import.c) and fz_self, its
 * generator and structure-aware mutator. fz.c turns those into a libFuzzer
 * custom mutator when built with -DCVRE_LIBFUZZER, and otherwise into a
 * main() that replays files and directories and runs generated inputs:
 *   fuzz_<name> FILE|DIR...                        replay
 *   fuzz_<name> --runs N [--seed S] [--save DIR] [FILE|DIR...]
 *                                                  N generated inputs, built
 *                                                  from scratch or by mutating
 *                                                  the files given
 * Everything random draws from one splitmix64 stream (fz_seed), so a seed
 * makes the same inputs with any compiler: callers never put two draws
 * where C leaves their order open (two arguments of one call).
 */
#ifndef CVRE_FZ_H
#define CVRE_FZ_H

#include <stddef.h>
#include <stdint.h>

/* Largest input the standalone driver builds or loads; fuzz-long passes
 * the same to libFuzzer as -max_len. Corpus files stay far below it
 * (~32 KB); the rest is room for what the mutators insert. */
#define FZ_INPUT_MAX (256u * 1024u)

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* A failed check names itself and the input (fz_fail), then aborts. */
#define FZ_CHECK(cond)                                                                             \
    do {                                                                                           \
        if (!(cond))                                                                               \
            fz_fail(#cond, __FILE__, __LINE__);                                                    \
    } while (0)

__attribute__((noreturn)) void fz_fail(const char *what, const char *file, int line);

/* ---- one target ---------------------------------------------------------- */

typedef struct fz_target {
    const char *name; /* "fuzz_glb", for messages and crash files */
    const char *hint; /* the import hint of a model target, NULL for others */
    /* Writes a new input of at most max bytes to out; returns its length. */
    size_t (*generate)(uint8_t *out, size_t max);
    /* Changes the structure of data[0..size) in place, keeping at most max
     * bytes; returns the new length, or 0 if data is not of the target's
     * format (the caller then mutates bytes instead). */
    size_t (*mutate)(uint8_t *data, size_t size, size_t max);
    /* Extra command-line commands: returns main's exit code, or -1 if
     * argv is not one of them. May be NULL. */
    int (*command)(int argc, char **argv);
    /* Prints what the inputs reached, on stderr, after generated runs. */
    void (*report)(void);
    /* The name of a reported, still unfixed bug that data[0..size) would
     * trigger, or NULL. Such inputs are skipped and counted (fz_skip_known),
     * so that fuzzing goes on past a known crash to find the next. Remove
     * an entry once its bug is fixed: the corpus files that show it are
     * then imported again. May be NULL. */
    const char *(*known)(const uint8_t *data, size_t size);
} fz_target;

/* Defined by each target. */
extern const fz_target fz_self;

/* True if fz_self.known names a bug for data[0..size): the caller skips
 * the input (libFuzzer: returns -1, so it stays out of the corpus). The
 * driver reports how many were skipped, and which file, when replaying. */
int fz_skip_known(const uint8_t *data, size_t size);

/* One mutation of data[0..size), as libFuzzer's custom mutator and the
 * standalone driver both make it: mostly fz_self.mutate, now and then a
 * new input from fz_self.generate or a byte-level change. Returns the new
 * length (at most max). */
size_t fz_mutate(uint8_t *data, size_t size, size_t max);

/* A byte-level mutation: libFuzzer's own under -DCVRE_LIBFUZZER, else a
 * small set of flips, noise, boundary values, deletions and copies. */
size_t fz_mutate_bytes(uint8_t *data, size_t size, size_t max);

/* ---- random draws --------------------------------------------------------- */

void fz_seed(uint64_t seed);
uint64_t fz_rnd(void);
uint32_t fz_below(uint32_t n); /* in [0, n); 0 if n is 0 */
int fz_one_in(uint32_t n);     /* true once in n draws */
size_t fz_pick_len(size_t n);  /* a length in [0, n], small ones likelier */

/* A count for a header field: mostly near n, often a boundary
 * (0, 2^31-1, 2^32-1, 4e9...). */
uint32_t fz_count(uint32_t n);
/* A binary float: mostly ordinary coordinates, sometimes NaN, infinity,
 * 1e38, FLT_MAX, -0 or a denormal. */
float fz_f32(void);
/* The same as text into out (32 bytes): also numbers past float's range
 * (1e39), past double's (1e309), and malformed ones (".5", "1e", "0x10").
 * Returns out. */
const char *fz_number(char out[32]);
/* An index into n items counted from base (0 or 1): mostly valid, else
 * n + base, -1, 0, 2^31-1, 2^32-1, or back from the end in OBJ style. */
long long fz_index(uint32_t n, int base);

/* ---- building inputs ------------------------------------------------------ */

/* Bytes appended past cap are dropped: a writer never overruns and a
 * generated input is cut at the size libFuzzer allows. */
typedef struct fz_buf {
    uint8_t *p;
    size_t len, cap;
} fz_buf;

void fz_put(fz_buf *b, const void *p, size_t n);
void fz_puts(fz_buf *b, const char *s);
__attribute__((format(printf, 2, 3))) void fz_printf(fz_buf *b, const char *fmt, ...);
void fz_put_le(fz_buf *b, uint64_t v, unsigned bytes); /* little-endian */
void fz_put_f32(fz_buf *b, float v);                   /* little-endian IEEE 754 */
void fz_set_le(uint8_t *p, uint64_t v, unsigned bytes); /* overwrites bytes at p */

/* Replaces data[at..end) of data[0..*size) with ins[0..n) (ins may be NULL
 * if n is 0), keeping at most max bytes: what does not fit is cut from
 * the end. at <= end <= *size <= max. */
void fz_splice(uint8_t *data, size_t *size, size_t max, size_t at, size_t end, const uint8_t *ins,
               size_t n);

/* ---- text formats (OBJ, ASCII STL, PLY) ------------------------------------ */

/*
 * Statement templates of a line-based format. In a template %f is a
 * number (fz_number), %i an index (fz_index(items, base)), %c a count
 * (fz_count(items)), %n a short name, %% a percent sign; the rest is
 * copied.
 */
typedef struct fz_text {
    const char *const *templates;
    size_t ntemplates;
    uint32_t items; /* what %i indexes: OBJ vertices, PLY vertices */
    int base;       /* 1 for OBJ, 0 for PLY */
} fz_text;

/* Appends template tmpl expanded (no line end). */
void fz_expand(fz_buf *b, const char *tmpl, const fz_text *t);

/* Replaces the number at or after a random offset of the text data[0..size)
 * by a hostile one (fz_number) or an index (fz_index(items, base)).
 * Returns the new length (at most max). */
size_t fz_mutate_number(uint8_t *data, size_t size, size_t max, uint32_t items, int base);

/* One line-level change to the text data[0..size): a number made hostile,
 * a statement from t inserted or repeated thousands of times, lines
 * deleted, swapped or duplicated, a cut mid-line, CR or NUL line ends,
 * indentation, two lines joined. Returns the new length (at most max). */
size_t fz_mutate_text(uint8_t *data, size_t size, size_t max, const fz_text *t);

/* ---- model targets (fz_import.c) -------------------------------------------- */

/* The model targets' LLVMFuzzerTestOneInput is fz_import.c's; this is their
 * fz_target.report: imports made and how many succeeded, per hint. */
void fz_import_report(void);

#endif
