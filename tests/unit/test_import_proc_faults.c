/*
 * import_isolated against helpers that break the pipe's form in every way
 * the server must survive: one that answers more than it announced, ends
 * in its head or before its last triangle, exits with a status, never
 * reads its input, or answers when the server has no memory for it; and
 * the server's own failures (no descriptors for the pipes, no helper).
 * The helpers are shell scripts that play back an answer made here.
 */
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <setjmp.h>
#include <signal.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cmocka.h>

#include "alloc.h"
#include "import_pipe.h"
#include "import_proc.h"

static char dir[] = "/tmp/cvre-test-proc-XXXXXX";
static char answer_path[PATH_MAX], helper_path[PATH_MAX];

/* One good triangle's answer, and an STL-free model to send (the helpers
 * never parse it). */
static const float tri[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
static const char model[] = "not parsed by these helpers";

/* Writes the answer file: the encoded answer of status/message/one
 * triangle whose box reaches top in y, cut to keep bytes (SIZE_MAX: all),
 * then extra bytes of 'x'. */
static void answer_box(int status, const char *message, size_t keep, size_t extra, float top)
{
    import_mesh m = {(float *)tri, 1, {0, 0, 0}, {1, top, 0}};
    uint8_t *b;
    size_t n;
    FILE *f;

    assert_int_equal(import_pipe_answer_encode(status, message, &m, &b, &n), 0);
    f = fopen(answer_path, "wb");
    assert_non_null(f);
    assert_int_equal(fwrite(b, 1, keep < n ? keep : n, f), keep < n ? keep : n);
    for (size_t i = 0; i < extra; i++)
        fputc('x', f);
    assert_int_equal(fclose(f), 0);
    free(b);
}

static void answer(int status, const char *message, size_t keep, size_t extra)
{
    answer_box(status, message, keep, extra, 1);
}

/* Writes the helper: a shell script (body after the #! line). */
static void helper(const char *body)
{
    FILE *f = fopen(helper_path, "w");

    assert_non_null(f);
    fprintf(f, "#!/bin/sh\n%s\n", body);
    assert_int_equal(fclose(f), 0);
    assert_int_equal(chmod(helper_path, 0700), 0);
}

/* A helper that reads its whole request, plays the answer back and exits
 * with status. */
static void reader(int status)
{
    char body[PATH_MAX + 128];

    snprintf(body, sizeof body, "/bin/cat > /dev/null\n/bin/cat '%s'\nexit %d", answer_path, status);
    helper(body);
}

static int run(const void *data, size_t len, const import_options *opt, char *err, size_t errlen)
{
    import_proc p = {helper_path, 256, 5};
    import_mesh m;
    int rc = import_isolated(&p, data, len, "stl", opt, &m, err, errlen);

    if (rc == 0) {
        assert_int_equal(m.ntris, 1);
        assert_memory_equal(m.tris, tri, sizeof tri);
        import_mesh_free(&m);
    }
    assert_null(m.tris);
    return rc;
}

static int setup(void **state)
{
    (void)state;
    signal(SIGPIPE, SIG_IGN); /* as the server does: a helper that stops reading is an error, not a signal */
    assert_non_null(mkdtemp(dir));
    snprintf(answer_path, sizeof answer_path, "%s/answer", dir);
    snprintf(helper_path, sizeof helper_path, "%s/helper", dir);
    return 0;
}

static int teardown(void **state)
{
    (void)state;
    unlink(answer_path);
    unlink(helper_path);
    rmdir(dir);
    return 0;
}

static void test_good_answer(void **state)
{
    char err[256];

    (void)state;
    answer(0, NULL, SIZE_MAX, 0);
    reader(0);
    assert_int_equal(run(model, sizeof model, NULL, err, sizeof err), 0); /* NULL: default options */
    assert_string_equal(err, "");
}

static void test_broken_answers(void **state)
{
    char err[256];

    (void)state;
    reader(0);
    answer(0, NULL, SIZE_MAX, 5);
    assert_int_equal(run(model, sizeof model, NULL, err, sizeof err), -EPROTO);
    assert_string_equal(err, "import failed: bad answer from the importer: the importer answered more than its 1 triangles");

    answer(0, NULL, 20, 0);
    assert_int_equal(run(model, sizeof model, NULL, err, sizeof err), -EPROTO);
    assert_string_equal(err, "import failed: bad answer from the importer: it ended in its header");

    answer(0, NULL, 14 + 28 + 30, 0);
    assert_int_equal(run(model, sizeof model, NULL, err, sizeof err), -EPROTO);
    assert_string_equal(err, "import failed: bad answer from the importer: it ended before its last triangle");

    answer(0, NULL, SIZE_MAX, 0);
    reader(3); /* a whole answer, then a failure status: the status wins */
    assert_int_equal(run(model, sizeof model, NULL, err, sizeof err), -ECHILD);
    assert_string_equal(err, "import failed: the importer exited with status 3");

    reader(0);
    answer_box(0, NULL, SIZE_MAX, 0, 2); /* a box its triangle does not have */
    assert_int_equal(run(model, sizeof model, NULL, err, sizeof err), -EPROTO);
    assert_string_equal(err, "import failed: bad answer from the importer: the importer's box is not its triangles' box");

    answer(0, NULL, SIZE_MAX, 0);
    import_options one = {0, 1.0f, 0}; /* fewer triangles allowed than it answers */
    assert_int_equal(run(model, sizeof model, &one, err, sizeof err), -EFBIG);
    assert_string_equal(err, "import failed: too large (the importer answered 1 triangles, over the limit of 0)");

    answer(-ENOMEM, "out of memory", SIZE_MAX, 0);
    assert_int_equal(run(model, sizeof model, NULL, err, sizeof err), -EFBIG);
    assert_string_equal(err, "import failed: too large (over the importer's 256 MB)");

    helper("/bin/cat > /dev/null\nprintf 'CVRQ\\001\\000\\000\\000'"); /* the request's magic */
    assert_int_equal(run(model, sizeof model, NULL, err, sizeof err), -EPROTO);
    assert_string_equal(err, "import failed: bad answer from the importer: the importer's answer has no valid header");
}

/* Helpers that die of a signal: a crash, the seccomp filter's SIGSYS, and
 * the CPU limit's SIGXCPU (a time-out, not a crash). */
static void test_helper_killed(void **state)
{
    char err[256];

    (void)state;
    helper("ulimit -c 0; kill -SEGV $$"); /* no core file */
    assert_int_equal(run(model, sizeof model, NULL, err, sizeof err), -ECHILD);
    assert_string_equal(err, "import failed: parser crashed (Segmentation fault)");
    helper("ulimit -c 0; kill -SYS $$");
    assert_int_equal(run(model, sizeof model, NULL, err, sizeof err), -ECHILD);
    assert_string_equal(err, "import failed: parser crashed (a forbidden system call)");
    helper("ulimit -c 0; kill -XCPU $$");
    assert_int_equal(run(model, sizeof model, NULL, err, sizeof err), -ETIMEDOUT);
    assert_string_equal(err, "import failed: timed out (over 5 s of CPU)");
}

/* The head first, the triangles only after the whole request was read: the
 * triangles then go straight into the array the caller keeps. */
static void test_triangles_after_head(void **state)
{
    size_t big = 1u << 20; /* many times a pipe's buffer: the head is read long before */
    char *data = calloc(1, big), body[3 * PATH_MAX], err[256];

    (void)state;
    assert_non_null(data);
    answer(0, NULL, SIZE_MAX, 0);
    snprintf(body, sizeof body,
             "/usr/bin/head -c 42 '%s'\n/bin/cat > /dev/null\n/usr/bin/tail -c +43 '%s'", answer_path,
             answer_path);
    helper(body);
    assert_int_equal(run(data, big, NULL, err, sizeof err), 0);
    free(data);
}

/* The helper's environment carries the sanitizers' options and nothing
 * else of the server's: it says so in its refusal. */
static void test_environment(void **state)
{
    char err[256];

    (void)state;
    helper("/bin/cat > /dev/null\n"
           "m=\"ubsan=$UBSAN_OPTIONS home=$HOME\"\n"
           "printf 'CVRA\\001\\000\\000\\000\\352\\377\\377\\377'\n" /* version 1, -EINVAL */
           "printf \"\\\\$(printf %03o ${#m})\\\\000\"\n"
           "printf '%s' \"$m\"");
    setenv("UBSAN_OPTIONS", "print_stacktrace=1", 0);
    assert_int_equal(run(model, sizeof model, NULL, err, sizeof err), -EINVAL);
    snprintf(err + 128, 128, "ubsan=%s home=", getenv("UBSAN_OPTIONS"));
    assert_string_equal(err, err + 128);
}

/* A helper that closes its input unread, then answers: the server's
 * writes fail (EPIPE) and the answer it did give is taken. */
static void test_helper_stops_reading(void **state)
{
    size_t big = 4u << 20;
    char *data = calloc(1, big), body[PATH_MAX + 64], err[256];

    (void)state;
    assert_non_null(data);
    answer(-EINVAL, "refused unread", SIZE_MAX, 0);
    snprintf(body, sizeof body, "exec 0<&-\nexec /bin/cat '%s'", answer_path);
    helper(body);
    assert_int_equal(run(data, big, NULL, err, sizeof err), -EINVAL);
    assert_string_equal(err, "refused unread");
    free(data);
}

static void test_server_side_failures(void **state)
{
    import_options opt = IMPORT_OPTIONS_DEFAULT;
    struct rlimit saved, none;
    char err[256];

    (void)state;
    assert_int_equal(run(model, 0, &opt, err, sizeof err), -EINVAL);
    assert_string_equal(err, "empty file");
    assert_int_equal(run(model, (size_t)IMPORT_MAX_BYTES + 1, &opt, err, sizeof err), -EFBIG);
    assert_non_null(strstr(err, "over the"));

    /* no memory for the triangles the helper announces */
    answer(0, NULL, SIZE_MAX, 0);
    reader(0);
    cvre_alloc_fail_after(0);
    assert_int_equal(run(model, sizeof model, &opt, err, sizeof err), -ENOMEM);
    cvre_alloc_fail_after(-1);
    assert_string_equal(err, "import failed: reading the importer's answer: Cannot allocate memory");

    /* no descriptors for the pipes */
    assert_int_equal(getrlimit(RLIMIT_NOFILE, &saved), 0);
    none = saved;
    none.rlim_cur = 0;
    assert_int_equal(setrlimit(RLIMIT_NOFILE, &none), 0);
    int rc = run(model, sizeof model, &opt, err, sizeof err);
    assert_int_equal(setrlimit(RLIMIT_NOFILE, &saved), 0);
    assert_int_equal(rc, -EMFILE);
    assert_string_equal(err, "cannot start the importer: pipe: Too many open files");

    /* descriptors for one pipe of the two: the first is closed again */
    int lowest = dup(0);
    assert_true(lowest >= 0);
    close(lowest);
    none.rlim_cur = (rlim_t)lowest + 2;
    assert_int_equal(setrlimit(RLIMIT_NOFILE, &none), 0);
    rc = run(model, sizeof model, &opt, err, sizeof err);
    assert_int_equal(setrlimit(RLIMIT_NOFILE, &saved), 0);
    assert_int_equal(rc, -EMFILE);
    assert_int_equal(dup(0), lowest); /* nothing left open */
    close(lowest);

    /* no helper at that path */
    import_proc missing = {"/nonexistent/cvre-import", 256, 5};
    import_mesh m;
    assert_int_equal(import_isolated(&missing, model, sizeof model, "stl", &opt, &m, err, sizeof err), -ENOENT);
    assert_string_equal(err, "cannot start the importer /nonexistent/cvre-import: No such file or directory");
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_good_answer),
        cmocka_unit_test(test_broken_answers),
        cmocka_unit_test(test_environment),
        cmocka_unit_test(test_helper_stops_reading),
        cmocka_unit_test(test_helper_killed),
        cmocka_unit_test(test_triangles_after_head),
        cmocka_unit_test(test_server_side_failures),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
