/*
 * models.h: the shared models folder in unit tests (header only; include it
 * after cmocka.h). A test file with a case per model names that case after
 * the model's file ("classic/teapot.obj") and its other cases test_*, so
 * that --only and --skip can pick one model, or none, or a heavy case, and
 * ctest can give each an entry of its own (tests/CMakeLists.txt).
 */
#ifndef CVRE_MODELS_H
#define CVRE_MODELS_H

#include <dirent.h>
#include <fnmatch.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The folders of shared/models that hold models (SOURCES.md lists them). */
static const char *const models_folders[] = {"openings", "classic", "formats", "scenes"};

static inline int models__by_name(const void *a, const void *b)
{
    return strcmp(*(char *const *)a, *(char *const *)b);
}

/* Every file in dir's model folders but dot files, sorted, as "folder/file".
 * Returns the array (the caller frees each name, then the array) with its
 * length in *n, or NULL with a message on stderr if a folder cannot be read.
 * Aborts when out of memory: it runs before any test. */
static inline char **models_list(const char *dir, size_t *n)
{
    char **names = NULL;
    size_t cap = 0;
    *n = 0;
    for (size_t i = 0; i < sizeof models_folders / sizeof models_folders[0]; i++) {
        char path[4096];
        snprintf(path, sizeof path, "%s/%s", dir, models_folders[i]);
        DIR *d = opendir(path);
        if (!d) {
            fprintf(stderr, "cannot open %s\n", path);
            for (size_t k = 0; k < *n; k++)
                free(names[k]);
            free(names);
            *n = 0;
            return NULL;
        }
        struct dirent *e;
        while ((e = readdir(d))) {
            if (e->d_name[0] == '.')
                continue;
            if (*n == cap) {
                cap = cap ? 2 * cap : 32;
                names = realloc(names, cap * sizeof *names);
                if (!names)
                    abort();
            }
            size_t len = strlen(models_folders[i]) + strlen(e->d_name) + 2;
            if (!(names[*n] = malloc(len)))
                abort();
            snprintf(names[(*n)++], len, "%s/%s", models_folders[i], e->d_name);
        }
        closedir(d);
    }
    if (*n)
        qsort(names, *n, sizeof *names, models__by_name);
    return names;
}

/* Which tests a run keeps: those matching some --only pattern (all when
 * there is none) and no --skip pattern. */
#define MODELS_MAX_PATTERNS 16
typedef struct models_select {
    const char *only[MODELS_MAX_PATTERNS], *skip[MODELS_MAX_PATTERNS];
    int nonly, nskip;
} models_select;

/* A test program's command line: MODELS_DIR (optional when *dir is set
 * already), then any number of --only PATTERN and --skip PATTERN into *sel;
 * --help prints the usage with `about` and exits 0, a bad argument prints
 * a message to stderr and exits 2. */
static inline void models_args(int argc, char **argv, const char *about, const char **dir, models_select *sel)
{
    int have_dir = 0;
    memset(sel, 0, sizeof *sel);
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--help")) {
            printf("usage: %s %sMODELS_DIR%s [--only PATTERN]... [--skip PATTERN]...\n%s\n"
                   "Runs the tests whose names match some --only PATTERN (every test when\n"
                   "there is none) and no --skip PATTERN; patterns are shell patterns.\n"
                   "A model's test is named after its file under MODELS_DIR\n"
                   "(\"classic/teapot.obj\"), the others start with \"test_\".\n",
                   argv[0], *dir ? "[" : "", *dir ? "]" : "", about);
            exit(0);
        }
        int only = !strcmp(argv[i], "--only"), skip = !strcmp(argv[i], "--skip");
        if ((only || skip) && i + 1 < argc && (only ? sel->nonly : sel->nskip) < MODELS_MAX_PATTERNS) {
            if (only)
                sel->only[sel->nonly++] = argv[++i];
            else
                sel->skip[sel->nskip++] = argv[++i];
        } else if (argv[i][0] != '-' && !have_dir) {
            *dir = argv[i];
            have_dir = 1;
        } else {
            fprintf(stderr, "%s: bad argument %s (try --help)\n", argv[0], argv[i]);
            exit(2);
        }
    }
    if (!*dir) {
        fprintf(stderr, "%s: no MODELS_DIR (try --help)\n", argv[0]);
        exit(2);
    }
}

static inline int models__matches(const char *const *patterns, int n, const char *name)
{
    for (int i = 0; i < n; i++)
        if (fnmatch(patterns[i], name, 0) == 0) /* '*' crosses '/' */
            return 1;
    return 0;
}

/* Runs the tests of tests[0..n) that sel keeps, as group `group`; they are
 * moved to the front of tests, in order. Keeping none is an error (exit
 * status 2), so that a renamed model cannot pass as an empty run. Returns
 * what cmocka returns: the number of failed tests. */
static inline int models_run(const char *group, struct CMUnitTest *tests, size_t n, const models_select *sel)
{
    size_t kept = 0;
    for (size_t i = 0; i < n; i++)
        if ((!sel->nonly || models__matches(sel->only, sel->nonly, tests[i].name)) &&
            !models__matches(sel->skip, sel->nskip, tests[i].name))
            tests[kept++] = tests[i];
    if (!kept) {
        fprintf(stderr, "%s: no test left to run\n", group);
        return 2;
    }
    return _cmocka_run_group_tests(group, tests, kept, NULL, NULL);
}

#endif
