/* The web root's files (server/net/web_files.c): what is served and with
 * which type, and every way a target is refused, in a temporary root
 * (tests/webroot.h) with symbolic links inside and out and a FIFO. */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include "web_files.h"
#include "../webroot.h"

static char dir[64];
static int root = -1;

static int setup(void **state)
{
    (void)state;
    root = webroot_make(dir);
    return root < 0 ? -1 : 0;
}

static int teardown(void **state)
{
    (void)state;
    close(root);
    webroot_remove(dir);
    return 0;
}

static int open_len(const char *target, size_t len, web_file *f)
{
    return web_files_open(root, target, len, f);
}

/* The result of opening target, which must be rc; a failure leaves the
 * web_file as it was. */
static void expect_len(const char *target, size_t len, int rc)
{
    web_file f = {.fd = -7, .size = 7, .type = "untouched"};
    int got = open_len(target, len, &f);
    if (got != rc)
        print_error("%.*s: %d, expected %d\n", (int)len, target, got, rc);
    assert_int_equal(got, rc);
    if (rc == 0) {
        close(f.fd);
    } else {
        assert_int_equal(f.fd, -7);
        assert_int_equal(f.size, 7);
        assert_string_equal(f.type, "untouched");
    }
}

static void expect(const char *target, int rc)
{
    expect_len(target, strlen(target), rc);
}

/* target opens the root's file entry (a path of webroot.h) with its bytes,
 * read-only and close-on-exec, with that content type. */
static void expect_file(const char *target, const char *entry, const char *type)
{
    const char *data = NULL;
    for (size_t i = 0; i < WEBROOT_ENTRIES; i++)
        if (strcmp(webroot_entries[i].path, entry) == 0)
            data = webroot_entries[i].data;
    assert_non_null(data);
    web_file f;
    int rc = open_len(target, strlen(target), &f);
    if (rc != 0)
        print_error("%s: %d\n", target, rc);
    assert_int_equal(rc, 0);
    struct stat st;
    assert_int_equal(fstat(f.fd, &st), 0);
    assert_true(S_ISREG(st.st_mode));
    assert_int_equal(fcntl(f.fd, F_GETFL) & O_ACCMODE, O_RDONLY);
    assert_true(fcntl(f.fd, F_GETFD) & FD_CLOEXEC);
    assert_int_equal(f.size, strlen(data));
    char got[256];
    ssize_t n = read(f.fd, got, sizeof got);
    assert_int_equal(n, (ssize_t)strlen(data));
    assert_memory_equal(got, data, strlen(data));
    assert_string_equal(f.type, type);
    close(f.fd);
}

#define HTML "text/html; charset=utf-8"
#define JS "text/javascript; charset=utf-8"
#define TEXT "text/plain; charset=utf-8"
#define BYTES "application/octet-stream"

static void test_types(void **state)
{
    (void)state;
    expect_file("/index.html", "root/index.html", HTML);
    expect_file("/app.js", "root/app.js", JS);
    expect_file("/mod.mjs", "root/mod.mjs", JS);
    expect_file("/style.css", "root/style.css", "text/css; charset=utf-8");
    expect_file("/notes.txt", "root/notes.txt", TEXT);
    expect_file("/icon.svg", "root/icon.svg", "image/svg+xml");
    expect_file("/data.json", "root/data.json", "application/json");
    expect_file("/model.glb", "root/model.glb", "model/gltf-binary");
    expect_file("/lib.wasm", "root/lib.wasm", "application/wasm");
    expect_file("/pic.png", "root/pic.png", "image/png");
    expect_file("/favicon.ico", "root/favicon.ico", "image/x-icon");
    expect_file("/LOUD.HTML", "root/LOUD.HTML", HTML); /* any case */
    expect_file("/blob.bin", "root/blob.bin", BYTES);
    expect_file("/README", "root/README", BYTES);
    expect_file("/empty.txt", "root/empty.txt", TEXT);
    expect_file("/sub/deeper/model.glb", "root/sub/deeper/model.glb", "model/gltf-binary");
}

/* A final '/' names the directory's index.html; a directory itself is not
 * served, nor listed. */
static void test_index(void **state)
{
    (void)state;
    expect_file("/", "root/index.html", HTML);
    expect_file("/sub/", "root/sub/index.html", HTML);
    expect("/empty/", -ENOENT);
    expect("/sub", -ENOENT);
    expect("/empty", -ENOENT);
    expect("/sub/deeper/", -ENOENT);
}

/* Writes a file of the root, replacing what it held. */
static void write_file(const char *name, const char *data)
{
    int fd = openat(root, name, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    assert_true(fd >= 0);
    assert_int_equal(write(fd, data, strlen(data)), (ssize_t)strlen(data));
    close(fd);
}

/* A file's entity tag is the same while it is, and changes when it is
 * rewritten; If-None-Match names it among others, weakly or by "*". */
static void test_etags(void **state)
{
    (void)state;
    web_file a, b;
    write_file("etag.txt", "first\n");
    assert_int_equal(open_len("/etag.txt", 9, &a), 0);
    assert_int_equal(open_len("/etag.txt", 9, &b), 0);
    close(a.fd);
    close(b.fd);
    assert_true(a.etag[0] == '"' && a.etag[strlen(a.etag) - 1] == '"');
    assert_string_equal(a.etag, b.etag);
    assert_int_equal(open_len("/app.js", 7, &b), 0);
    close(b.fd);
    assert_string_not_equal(a.etag, b.etag);
    write_file("etag.txt", "second, longer\n");
    assert_int_equal(open_len("/etag.txt", 9, &b), 0);
    close(b.fd);
    assert_string_not_equal(a.etag, b.etag);
    assert_int_equal(unlinkat(root, "etag.txt", 0), 0);

    char list[3 * WEB_FILES_ETAG_MAX];
    assert_true(web_files_etag_matches(b.etag, b.etag));
    snprintf(list, sizeof list, "\"x\", W/%s", b.etag);
    assert_true(web_files_etag_matches(list, b.etag));
    snprintf(list, sizeof list, "%s,\"y\"", b.etag);
    assert_true(web_files_etag_matches(list, b.etag));
    assert_true(web_files_etag_matches("*", b.etag));
    assert_false(web_files_etag_matches(NULL, b.etag));
    assert_false(web_files_etag_matches("", b.etag));
    assert_false(web_files_etag_matches(a.etag, b.etag));
    snprintf(list, sizeof list, "%.*s", (int)strlen(b.etag) - 1, b.etag); /* a prefix is not the tag */
    assert_false(web_files_etag_matches(list, b.etag));
}

static void test_query_and_fragment_ignored(void **state)
{
    (void)state;
    expect_file("/?name=ann", "root/index.html", HTML);
    expect_file("/app.js?v=3", "root/app.js", JS);
    expect_file("/app.js#top", "root/app.js", JS);
    expect_file("/app.js?x=/../../etc/passwd%00", "root/app.js", JS);
    expect_file("/app.js#/..", "root/app.js", JS);
    static const char nul_in_query[] = "/app.js?a\0b";
    web_file f;
    assert_int_equal(open_len(nul_in_query, sizeof nul_in_query - 1, &f), 0);
    close(f.fd);
    expect("/app.js%3Fv=3", -ENOENT); /* an encoded '?' is part of the name */
    expect("/app.js%23top", -ENOENT);
}

/* Decoded once: %2561 is "%61", not "a". */
static void test_percent_decoding(void **state)
{
    (void)state;
    expect_file("/with%20space.txt", "root/with space.txt", TEXT);
    expect_file("/100%25.txt", "root/100%.txt", TEXT);
    expect_file("/%C3%A9t%c3%a9.txt", "root/\xc3\xa9t\xc3\xa9.txt", TEXT);
    expect_file("/\xc3\xa9t\xc3\xa9.txt", "root/\xc3\xa9t\xc3\xa9.txt", TEXT);
    expect_file("/%61pp.%6As", "root/app.js", JS);
    expect_file("/sub/%69ndex.html", "root/sub/index.html", HTML);
    expect("/%2561pp.js", -ENOENT);
    expect("/100%2525.txt", -ENOENT);
}

static void test_bad_escapes(void **state)
{
    (void)state;
    static const char *const bad[] = {"/%", "/%4", "/%zz", "/%4g", "/%g4", "/app.js%", "/app.js%2", "/%%41",
                                      "/% 41", "/%+1", "/%-1"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++)
        expect(bad[i], -EINVAL);
}

/* NUL, controls, DEL, backslashes and encoded slashes, sent or encoded. */
static void test_refused_bytes(void **state)
{
    (void)state;
    static const char raw_nul[] = "/app.js\0.png";
    expect_len(raw_nul, sizeof raw_nul - 1, -EINVAL);
    expect_len("\0/app.js", 8, -EINVAL);
    static const char *const bad[] = {
        "/app.js%00", "/%00", "/app.js%00.png", "/sub%2findex.html", "/sub%2Findex.html", "/%2f",
        "/a\nb", "/a\rb", "/a%0d%0ab", "/a%0Ab", "/a\tb", "/a%09b", "/a\x7f", "/a%7F", "/a\x01", "/a%1b",
        "/with space.txt", "/..\\outside.txt", "/%5c..%5coutside.txt", "/sub\\index.html", "/sub%5Cindex.html",
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++)
        expect(bad[i], -EINVAL);
}

static void test_not_origin_form(void **state)
{
    (void)state;
    static const char *const bad[] = {"", "app.js", "*", "http://h/app.js", "?x", "#f", "%2fapp.js", "./app.js",
                                      "../outside.txt", "\\app.js"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++)
        expect(bad[i], -EINVAL);
    web_file f;
    assert_int_equal(open_len("/app.js", 0, &f), -EINVAL);
    expect_len("/app.js", 1, 0); /* "/": only len bytes are read */
}

/* "..", however spelled, is refused before anything is opened, even where
 * it would stay inside the root; "." and empty segments are malformed. */
static void test_traversal(void **state)
{
    (void)state;
    static const char *const up[] = {"/..", "/../", "/../outside.txt", "/sub/../app.js", "/sub/../../outside.txt",
                                     "/%2e%2e/outside.txt", "/%2E%2E/outside.txt", "/%2E%2e/outside.txt",
                                     "/.%2e/outside.txt", "/%2e./outside.txt", "/sub/%2e%2e/%2e%2e/outside.txt",
                                     "/../outside-dir/secret.txt", "/..?x", "/missing/.."};
    for (size_t i = 0; i < sizeof up / sizeof up[0]; i++)
        expect(up[i], -EACCES);
    static const char *const malformed[] = {"//app.js", "//etc/passwd", "/sub//index.html", "/sub//",
                                            "/./app.js", "/%2e/app.js", "/sub/.", "/sub/./", "/.", "/./"};
    for (size_t i = 0; i < sizeof malformed / sizeof malformed[0]; i++)
        expect(malformed[i], -EINVAL);
    expect("/...", -ENOENT); /* a name like any other, hidden */
}

/* A symbolic link is refused wherever it is on the path and wherever it
 * points. */
static void test_symlinks(void **state)
{
    (void)state;
    static const char *const links[] = {
        "/link-in", "/link-dir-in/index.html", "/link-dir-in/", "/link-out", "/link-dir-out/secret.txt",
        "/link-dir-out/", "/link-abs", "/sub/link-up/outside.txt", "/sub/link-up/app.js", "/dangling",
        "/dangling/x", "/link-%69n", "/link-in?x=1",
    };
    for (size_t i = 0; i < sizeof links / sizeof links[0]; i++)
        expect(links[i], -EACCES);
}

/* Anything not a regular file is 404, and a FIFO is not waited on. */
static void test_not_regular_or_missing(void **state)
{
    (void)state;
    static const char *const none[] = {"/fifo", "/fifo/x", "/missing", "/missing/x", "/app.js/x", "/app.js/",
                                       "/sub/missing.js", "/sub/deeper/missing/x", "/outside.txt", "/root/app.js",
                                       "/index.htm", "/INDEX.HTML"};
    for (size_t i = 0; i < sizeof none / sizeof none[0]; i++)
        expect(none[i], -ENOENT);
    char longname[300] = "/";
    memset(longname + 1, 'n', 290); /* past NAME_MAX */
    expect(longname, -ENOENT);
}

static void test_hidden(void **state)
{
    (void)state;
    static const char *const hidden[] = {"/.hidden", "/.git/config", "/.git/", "/%2ehidden", "/%2Egit/config",
                                         "/sub/.index.html", "/.missing"};
    for (size_t i = 0; i < sizeof hidden / sizeof hidden[0]; i++)
        expect(hidden[i], -ENOENT);
}

/* Writes a file name of len bytes ending in ".txt" at at, NUL-terminated. */
static void long_name(char *at, size_t len)
{
    memset(at, 'f', len - 4);
    memcpy(at + len - 4, ".txt", 5);
}

static void make_file(const char *path)
{
    int fd = openat(root, path, O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
    assert_true(fd >= 0);
    close(fd);
}

/* The limit holds on the path as sent: a real file at exactly
 * WEB_FILES_PATH_MAX bytes is served; longer, the same file through an
 * escape or a longer name that exists too is refused before the file
 * system is asked; the query does not count. */
static void test_path_limit(void **state)
{
    (void)state;
    enum { SEG = 250, DIRS = 4 };
    _Static_assert(DIRS * (SEG + 1) + 1 + 5 < WEB_FILES_PATH_MAX, "the file's name fits after the dirs");
    size_t name_len = WEB_FILES_PATH_MAX - DIRS * (SEG + 1) - 1;
    char path[WEB_FILES_PATH_MAX + 2];
    size_t n = 0;
    for (int d = 0; d < DIRS; d++) {
        path[n++] = '/';
        memset(path + n, 'a' + d, SEG);
        n += SEG;
        path[n] = 0;
        assert_int_equal(mkdirat(root, path + 1, 0755), 0);
    }
    path[n++] = '/';
    long_name(path + n, name_len);
    make_file(path + 1);
    assert_int_equal(strlen(path), WEB_FILES_PATH_MAX);
    expect(path, 0);

    char with_query[WEB_FILES_PATH_MAX + 64];
    snprintf(with_query, sizeof with_query, "%s?%040d", path, 7);
    expect(with_query, 0);

    char escaped[WEB_FILES_PATH_MAX + 4];
    memcpy(escaped, path, n);
    memcpy(escaped + n, "%66", 3);
    strcpy(escaped + n + 3, path + n + 1);
    assert_int_equal(strlen(escaped), WEB_FILES_PATH_MAX + 2);
    expect(escaped, -EINVAL);

    long_name(path + n, name_len + 1);
    make_file(path + 1);
    expect(path, -EINVAL);
    assert_int_equal(unlinkat(root, path + 1, 0), 0);
    long_name(path + n, name_len);
    assert_int_equal(unlinkat(root, path + 1, 0), 0);
    for (int d = DIRS; d > 0; d--) {
        path[d * (SEG + 1)] = 0;
        assert_int_equal(unlinkat(root, path + 1, AT_REMOVEDIR), 0);
    }
}

/* The lowest free descriptor: the same before and after means none was
 * left open. */
static int lowest_free_fd(void)
{
    int fd = dup(root);
    assert_true(fd >= 0);
    close(fd);
    return fd;
}

static void test_no_descriptor_leaks(void **state)
{
    (void)state;
    int before = lowest_free_fd();
    static const char *const targets[] = {"/sub/deeper/missing", "/sub/deeper/", "/sub/link-up/app.js",
                                          "/sub/deeper/model.glb/x", "/fifo", "/sub", "/link-dir-out/secret.txt"};
    for (size_t i = 0; i < sizeof targets / sizeof targets[0]; i++) {
        web_file f;
        if (open_len(targets[i], strlen(targets[i]), &f) == 0)
            close(f.fd);
    }
    assert_int_equal(lowest_free_fd(), before);
    assert_true(fcntl(root, F_GETFD) >= 0); /* the root is never closed */
}

/* What the system refuses comes back as its errno: out of descriptors, a
 * root that is not a descriptor or not a directory. */
static void test_system_errors(void **state)
{
    (void)state;
    struct rlimit saved, low;
    assert_int_equal(getrlimit(RLIMIT_NOFILE, &saved), 0);
    low = saved;
    low.rlim_cur = (rlim_t)lowest_free_fd();
    assert_int_equal(setrlimit(RLIMIT_NOFILE, &low), 0);
    web_file f;
    int rc1 = open_len("/app.js", 7, &f);
    int rc2 = open_len("/sub/index.html", 15, &f);
    assert_int_equal(setrlimit(RLIMIT_NOFILE, &saved), 0);
    assert_int_equal(rc1, -EMFILE);
    assert_int_equal(rc2, -EMFILE);

    assert_int_equal(web_files_open(-1, "/app.js", 7, &f), -EBADF);
    int file = openat(root, "app.js", O_RDONLY | O_CLOEXEC);
    assert_true(file >= 0);
    assert_int_equal(web_files_open(file, "/app.js", 7, &f), -ENOENT);
    close(file);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_types),
        cmocka_unit_test(test_index),
        cmocka_unit_test(test_etags),
        cmocka_unit_test(test_query_and_fragment_ignored),
        cmocka_unit_test(test_percent_decoding),
        cmocka_unit_test(test_bad_escapes),
        cmocka_unit_test(test_refused_bytes),
        cmocka_unit_test(test_not_origin_form),
        cmocka_unit_test(test_traversal),
        cmocka_unit_test(test_symlinks),
        cmocka_unit_test(test_not_regular_or_missing),
        cmocka_unit_test(test_hidden),
        cmocka_unit_test(test_path_limit),
        cmocka_unit_test(test_no_descriptor_leaks),
        cmocka_unit_test(test_system_errors),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
