/*
 * fuzz_web_files.c: structure-aware fuzz target for the web root's files
 * (server/net/web_files.c), which turns a stranger's request target into
 * an open file.
 *
 * Inputs are request targets, resolved against the root of tests/webroot.h
 * (made once per process in /tmp, removed at exit): real files and
 * directories, hidden names, names that need escapes, symbolic links
 * pointing inside and out, a FIFO, files beside the root. The generator
 * joins segments (the root's names, "..", "%2e%2e", "%2E%2e", ".", empty,
 * backslashes, %00, %2f, bad escapes, controls, long names) behind "/" or
 * not, with a final '/', a ?query or #fragment, sometimes padded to within
 * bytes of WEB_FILES_PATH_MAX. The mutator replaces, inserts and deletes
 * segments, %-encodes a byte or decodes an escape, changes an escape's
 * case, adds or drops the query, and pads.
 *
 * The invariant: a 0 result is an open regular file that the root holds
 * under a name none of whose segments is hidden, with its size and a
 * content type; anything else is -ENOENT, -EACCES or -EINVAL, and no
 * descriptor is left open. And three ways of writing a target that mean
 * the same must get the same result: again, with its ?query changed, and
 * with a byte of the path %-encoded or the case of its escapes changed
 * (while the path stays within the limit).
 */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "../webroot.h"
#include "fz.h"
#include "web_files.h"

static char dir[64];
static int root = -1;

/* The files a request may get: regular, in the root, not hidden. */
static struct stat served[WEBROOT_ENTRIES];
static size_t nserved;

static void root_remove(void)
{
    close(root);
    webroot_remove(dir);
}

static void root_make(void)
{
    if (root >= 0)
        return;
    root = webroot_make(dir);
    FZ_CHECK(root >= 0);
    atexit(root_remove);
    int top = open(dir, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    FZ_CHECK(top >= 0);
    for (size_t i = 0; i < WEBROOT_ENTRIES; i++) {
        const webroot_entry *e = &webroot_entries[i];
        if (e->kind == 'f' && strncmp(e->path, "root/", 5) == 0 && !strstr(e->path, "/."))
            FZ_CHECK(fstatat(top, e->path, &served[nserved++], AT_SYMLINK_NOFOLLOW) == 0);
    }
    close(top);
}

/* ---- inputs ------------------------------------------------------------------ */

/* Segments: the root's names first (REAL of them), then hostile ones. */
static const char *const segments[] = {
    "index.html", "app.js", "mod.mjs", "style.css", "model.glb", "lib.wasm", "sub", "deeper", "empty",
    "with%20space.txt", "100%25.txt", "%C3%A9t%C3%A9.txt", "LOUD.HTML", "README", "link-in", "link-dir-in",
    "link-out", "link-dir-out", "link-abs", "link-up", "dangling", "fifo", ".git", "config", ".hidden",
    /* hostile */
    "..", "%2e%2e", "%2E%2e", ".%2E", "%2e.", ".", "%2e", "", "\\", "..\\..", "%5c", "%5C..", "%00",
    "a%00b", "%2f", "%2F", "%", "%4", "%zz", "%%41", "\x7f", "%7f", "%0a", "\r\n", " ", "%20", "...",
    "%2561pp.js", "outside.txt", "outside-dir", "secret.txt", "root", "missing", "%61pp.js",
};
#define NSEGMENTS (sizeof segments / sizeof segments[0])
#define REAL 25

static const char *pick_segment(void)
{
    return segments[fz_one_in(3) ? fz_below(NSEGMENTS) : fz_below(REAL)];
}

static size_t files_generate(uint8_t *out, size_t max)
{
    static const char *const prefixes[] = {"", "http://h", "*", ".", "\\", "%2f"};
    fz_buf b = {out, 0, max};
    if (fz_one_in(16))
        fz_puts(&b, prefixes[fz_below(sizeof prefixes / sizeof prefixes[0])]);
    else
        fz_puts(&b, "/");
    uint32_t n = fz_below(5);
    for (uint32_t i = 0; i < n; i++) {
        if (i)
            fz_puts(&b, "/");
        fz_puts(&b, pick_segment());
        if (fz_one_in(32))
            fz_put(&b, "", 1); /* a NUL, sent as it is */
    }
    if (fz_one_in(16)) { /* a name taking the path to within bytes of the limit */
        size_t want = WEB_FILES_PATH_MAX - 3 + fz_below(6);
        fz_puts(&b, "/");
        while (b.len < want && b.len < b.cap)
            fz_puts(&b, fz_one_in(64) ? "/" : "p");
    }
    if (fz_one_in(8))
        fz_puts(&b, "/");
    if (fz_one_in(4))
        fz_printf(&b, "?name=%s", pick_segment());
    if (fz_one_in(8))
        fz_printf(&b, "#%s", pick_segment());
    return b.len;
}

/* The end of the path: the first '?' or '#', or size. */
static size_t path_end(const uint8_t *data, size_t size)
{
    size_t n = 0;
    while (n < size && data[n] != '?' && data[n] != '#')
        n++;
    return n;
}

static int is_hex(uint8_t c)
{
    return (c >= '0' && c <= '9') || ((c | 0x20) >= 'a' && (c | 0x20) <= 'f');
}

static size_t files_mutate(uint8_t *data, size_t size, size_t max)
{
    size_t end = path_end(data, size);
    /* A segment: from just after the k-th '/' of the path to the next. */
    size_t slashes = 0, seg = 0, seg_end = end;
    for (size_t i = 0; i < end; i++)
        slashes += data[i] == '/';
    if (slashes) {
        size_t k = fz_below((uint32_t)slashes) + 1;
        for (size_t i = 0; i < end && k; i++)
            if (data[i] == '/' && --k == 0)
                seg = i + 1;
        for (seg_end = seg; seg_end < end && data[seg_end] != '/'; seg_end++)
            ;
    }
    size_t at = end ? fz_below((uint32_t)end) : 0;
    char tmp[16];
    switch (fz_below(8)) {
    case 0: { /* a segment replaced */
        const char *s = pick_segment();
        fz_splice(data, &size, max, seg, seg_end, (const uint8_t *)s, strlen(s));
        break;
    }
    case 1: { /* a segment inserted */
        int n = snprintf(tmp, sizeof tmp, "/%.14s", pick_segment());
        fz_splice(data, &size, max, seg_end, seg_end, (const uint8_t *)tmp, (size_t)n);
        break;
    }
    case 2: /* a segment deleted, with its '/' */
        fz_splice(data, &size, max, seg ? seg - 1 : 0, seg_end, NULL, 0);
        break;
    case 3: /* a byte of the path %-encoded */
        if (end) {
            int n = snprintf(tmp, sizeof tmp, fz_one_in(2) ? "%%%02X" : "%%%02x", data[at]);
            fz_splice(data, &size, max, at, at + 1, (const uint8_t *)tmp, (size_t)n);
        }
        break;
    case 4: /* an escape decoded */
        for (size_t i = at; i + 2 < end; i++)
            if (data[i] == '%' && is_hex(data[i + 1]) && is_hex(data[i + 2])) {
                char hex[3] = {(char)data[i + 1], (char)data[i + 2], 0};
                uint8_t c = (uint8_t)strtoul(hex, NULL, 16);
                fz_splice(data, &size, max, i, i + 3, &c, 1);
                break;
            }
        break;
    case 5: /* the case of the path's escapes swapped */
        for (size_t i = 0; i + 2 < end; i++)
            if (data[i] == '%')
                for (size_t j = i + 1; j <= i + 2; j++)
                    if (is_hex(data[j]) && data[j] > '9')
                        data[j] ^= 0x20;
        break;
    case 6: /* a query or fragment added or dropped */
        if (end < size) {
            size = end;
        } else {
            const char *s = fz_one_in(2) ? "?v=1" : "#top";
            fz_splice(data, &size, max, size, size, (const uint8_t *)s, strlen(s));
        }
        break;
    default: { /* padded to within bytes of the limit */
        size_t want = WEB_FILES_PATH_MAX - 3 + fz_below(6);
        while (end < want && size < max) {
            uint8_t p = 'p';
            fz_splice(data, &size, max, end, end, &p, 1);
            end++;
        }
        break;
    }
    }
    return size;
}

/* ---- the invariant --------------------------------------------------------- */

static unsigned long n_inputs, n_open, n_enoent, n_eacces, n_einval, n_encoded;

/* The lowest free descriptor: the same before and after a call means it
 * left none open. */
static int lowest_free_fd(void)
{
    int fd = dup(root);
    FZ_CHECK(fd >= 0);
    close(fd);
    return fd;
}

/* Opens data[0..size) and checks what came back; returns the result. */
static int open_checked(const uint8_t *data, size_t size)
{
    web_file f;
    int rc = web_files_open(root, (const char *)data, size, &f);
    FZ_CHECK(rc == 0 || rc == -ENOENT || rc == -EACCES || rc == -EINVAL);
    if (rc == 0) {
        struct stat st;
        FZ_CHECK(fstat(f.fd, &st) == 0);
        FZ_CHECK(S_ISREG(st.st_mode));
        size_t i = 0;
        while (i < nserved && !(served[i].st_dev == st.st_dev && served[i].st_ino == st.st_ino))
            i++;
        FZ_CHECK(i < nserved); /* a file under the root, not hidden */
        FZ_CHECK(f.size == (uint64_t)st.st_size);
        FZ_CHECK(f.type && strchr(f.type, '/'));
        FZ_CHECK((fcntl(f.fd, F_GETFL) & O_ACCMODE) == O_RDONLY);
        close(f.fd);
    }
    return rc;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static uint8_t other[WEB_FILES_PATH_MAX + 64];
    root_make();
    int before = lowest_free_fd();
    int rc = open_checked(data, size);
    FZ_CHECK(open_checked(data, size) == rc);
    size_t end = path_end(data, size);
    if (end + 8 <= sizeof other) {
        /* The query does not count. */
        memcpy(other, data, end);
        memcpy(other + end, "?x=/../", 7);
        FZ_CHECK(open_checked(other, end + 7) == rc);
        FZ_CHECK(open_checked(other, end) == rc);
        /* Nor how a byte is written: the first letter, digit or '.' of
         * the path outside an escape %-encoded, and every escape's hex
         * digits in the other case. */
        size_t i = 0;
        while (i < end && !(data[i] == '.' || (data[i] >= '0' && data[i] <= '9') ||
                            ((data[i] | 0x20) >= 'a' && (data[i] | 0x20) <= 'z')))
            i += data[i] == '%' ? 3 : 1;
        if (i < end && end + 2 <= WEB_FILES_PATH_MAX) {
            memcpy(other, data, i);
            snprintf((char *)other + i, 4, "%%%02x", data[i]);
            memcpy(other + i + 3, data + i + 1, end - i - 1);
            for (size_t j = 0; j + 2 < end + 2; j++)
                if (other[j] == '%')
                    for (size_t k = j + 1; k <= j + 2; k++)
                        if (is_hex(other[k]) && other[k] > '9')
                            other[k] ^= 0x20;
            FZ_CHECK(open_checked(other, end + 2) == rc);
            n_encoded++;
        }
    }
    FZ_CHECK(lowest_free_fd() == before);
    n_inputs++;
    n_open += rc == 0;
    n_enoent += rc == -ENOENT;
    n_eacces += rc == -EACCES;
    n_einval += rc == -EINVAL;
    return 0;
}

/* If "opened" drops to near zero, the inputs no longer reach the files. */
static void files_report(void)
{
    fprintf(stderr, "fuzz_web_files: %lu targets, opened %lu, 404 %lu, 403 %lu, 400 %lu; %lu re-encoded\n", n_inputs,
            n_open, n_enoent, n_eacces, n_einval, n_encoded);
}

const fz_target fz_self = {"fuzz_web_files", NULL, files_generate, files_mutate, NULL, files_report, NULL};
