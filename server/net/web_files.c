#define _GNU_SOURCE /* O_PATH: a directory is walked through, never read */
/* web_files.c: a request target to a file of the web root (see web_files.h). */
#include "web_files.h"

#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <unistd.h>

/* Content types by the name's extension, in any case. Text is UTF-8
 * (RFC 9239 for JavaScript; JSON is UTF-8 by definition and takes no
 * charset); the rest is application/octet-stream, which a browser saves
 * rather than runs. */
static const struct {
    const char *ext, *type;
} types[] = {
    {"html", "text/html; charset=utf-8"},
    {"js", "text/javascript; charset=utf-8"},
    {"mjs", "text/javascript; charset=utf-8"},
    {"css", "text/css; charset=utf-8"},
    {"txt", "text/plain; charset=utf-8"},
    {"svg", "image/svg+xml"},
    {"json", "application/json"},
    {"glb", "model/gltf-binary"},
    {"wasm", "application/wasm"},
    {"png", "image/png"},
    {"ico", "image/x-icon"},
};

static const char *type_of(const char *name)
{
    const char *dot = strrchr(name, '.');
    if (dot)
        for (size_t i = 0; i < sizeof types / sizeof types[0]; i++)
            if (strcasecmp(dot + 1, types[i].ext) == 0)
                return types[i].type;
    return "application/octet-stream";
}

static int hex_value(char c)
{
    if (c >= '0' && c <= '9')
        return c - '0';
    c = (char)(c | 0x20);
    return c >= 'a' && c <= 'f' ? c - 'a' + 10 : -1;
}

/* A byte no file name of the web root has, sent or decoded: controls
 * (NUL ends a C string, CR and LF split log lines), DEL, and the backslash,
 * a separator elsewhere. */
static int refused_byte(unsigned char c)
{
    return c < 0x20 || c == 0x7f || c == '\\';
}

/* Percent-decodes the path path[0..len) into out (room for len + 1 bytes)
 * once, NUL-terminated. Returns 0, or -EINVAL for a space (never in a
 * request line), a bad escape, a refused byte or an encoded '/'. */
static int decode(const char *path, size_t len, char *out)
{
    size_t n = 0;
    for (size_t i = 0; i < len; i++) {
        unsigned char c = (unsigned char)path[i];
        if (c == '%') {
            int hi = i + 2 < len ? hex_value(path[i + 1]) : -1;
            int lo = hi >= 0 ? hex_value(path[i + 2]) : -1;
            if (lo < 0)
                return -EINVAL;
            c = (unsigned char)(hi << 4 | lo);
            if (c == '/')
                return -EINVAL;
            i += 2;
        } else if (c == ' ') {
            return -EINVAL;
        }
        if (refused_byte(c))
            return -EINVAL;
        out[n++] = (char)c;
    }
    out[n] = 0;
    return 0;
}

/* Checks each segment of the decoded path (which starts with '/'), and
 * names the index of a path ending in '/'. Returns 0, -EINVAL (an empty or
 * "." segment), -EACCES ("..") or -ENOENT (a hidden name). */
static int check_segments(char *path)
{
    size_t len = strlen(path);
    if (path[len - 1] == '/')
        memcpy(path + len, WEB_FILES_INDEX, sizeof WEB_FILES_INDEX);
    for (const char *seg = path + 1;;) {
        const char *end = strchr(seg, '/');
        size_t n = end ? (size_t)(end - seg) : strlen(seg);
        if (n == 0 || (n == 1 && seg[0] == '.'))
            return -EINVAL;
        if (n == 2 && seg[0] == '.' && seg[1] == '.')
            return -EACCES;
        if (seg[0] == '.')
            return -ENOENT;
        if (!end)
            return 0;
        seg = end + 1;
    }
}

/* What an openat or fstatat failure on a component means here: a symbolic
 * link (ELOOP, or the not-a-directory it looks like through O_DIRECTORY)
 * or a permission refusal is 403; a missing or impossible name 404. */
static int component_error(int dfd, const char *name, int err)
{
    struct stat st;
    if (err == ENOTDIR && fstatat(dfd, name, &st, AT_SYMLINK_NOFOLLOW) == 0 && S_ISLNK(st.st_mode))
        err = ELOOP;
    if (err == ELOOP || err == EACCES)
        return -EACCES;
    if (err == ENOENT || err == ENOTDIR || err == ENAMETOOLONG)
        return -ENOENT;
    return -err;
}

/* Opens the file path (decoded and checked: "/a/b/c") under root_fd, one
 * component at a time, following no symbolic link. Returns 0 with *out
 * filled, or a negative errno (web_files.h). */
static int walk(int root_fd, char *path, web_file *out)
{
    int dfd = root_fd, rc;
    char *name = path + 1;
    for (char *slash; (slash = strchr(name, '/')) != NULL; name = slash + 1) {
        *slash = 0;
        int fd = openat(dfd, name, O_PATH | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC);
        if (fd < 0) {
            rc = component_error(dfd, name, errno);
            goto done;
        }
        if (dfd != root_fd)
            close(dfd);
        dfd = fd;
    }
    /* Looked at before it is opened: opening a FIFO, a socket or a device
     * is not harmless (a FIFO blocks, a device's driver acts). */
    struct stat st;
    if (fstatat(dfd, name, &st, AT_SYMLINK_NOFOLLOW) < 0) {
        rc = component_error(dfd, name, errno);
        goto done;
    }
    if (S_ISLNK(st.st_mode)) {
        rc = -EACCES;
        goto done;
    }
    if (!S_ISREG(st.st_mode)) {
        rc = -ENOENT;
        goto done;
    }
    /* O_NOFOLLOW, O_NONBLOCK and the second look: what is there now may
     * not be what was looked at. */
    int fd = openat(dfd, name, O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_NOCTTY | O_CLOEXEC);
    if (fd < 0) {
        rc = component_error(dfd, name, errno);
        goto done;
    }
    /* GCOVR_EXCL_START: only a file replaced between the look and the open
     * (by whoever may write to the web root) gets here */
    if (fstat(fd, &st) < 0 || !S_ISREG(st.st_mode)) {
        close(fd);
        rc = -ENOENT;
        goto done;
    }
    /* GCOVR_EXCL_STOP */
    out->fd = fd;
    out->size = (uint64_t)st.st_size;
    out->type = type_of(name);
    snprintf(out->etag, sizeof out->etag, "\"%llx-%llx-%llx\"", (unsigned long long)st.st_ino,
             (unsigned long long)st.st_size,
             (unsigned long long)st.st_mtim.tv_sec * 1000000000ull + (unsigned long long)st.st_mtim.tv_nsec);
    rc = 0;
done:
    if (dfd != root_fd)
        close(dfd);
    return rc;
}

int web_files_open(int root_fd, const char *target, size_t len, web_file *out)
{
    /* Room for the longest path decoded (never longer than sent) with the
     * index's name after its final '/'. */
    char path[WEB_FILES_PATH_MAX + sizeof WEB_FILES_INDEX];
    size_t n = 0;
    while (n < len && target[n] != '?' && target[n] != '#')
        n++;
    if (n == 0 || target[0] != '/' || n > WEB_FILES_PATH_MAX)
        return -EINVAL;
    int rc = decode(target, n, path);
    if (rc == 0)
        rc = check_segments(path);
    if (rc == 0)
        rc = walk(root_fd, path, out);
    return rc;
}

int web_files_etag_matches(const char *if_none_match, const char *etag)
{
    if (!if_none_match)
        return 0;
    size_t len = strlen(etag);
    for (const char *p = if_none_match; *p;) {
        p += strspn(p, " \t,");
        if (*p == '*')
            return 1;
        if (strncmp(p, "W/", 2) == 0)
            p += 2;
        size_t n = strcspn(p, " \t,");
        if (n == len && memcmp(p, etag, len) == 0)
            return 1;
        p += n;
    }
    return 0;
}
