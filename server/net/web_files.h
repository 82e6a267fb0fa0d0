/*
 * web_files.h: which file of the web root an HTTP request target names,
 * opened for the web endpoint to send (the browser client's pages,
 * scripts and models). Pure policy over the file system: no sockets, no
 * HTTP parsing (http.h hands over the target), no reading of the file.
 *
 * Only regular files under the root are ever opened. The target's path is
 * percent-decoded once and checked whole before the file system is
 * touched, then opened one component at a time from the root's
 * descriptor, none of them followed if it is a symbolic link: no "..",
 * no symlink, no NUL can take a request out of the root, and a rename
 * under way cannot either.
 */
#ifndef CVRE_WEB_FILES_H
#define CVRE_WEB_FILES_H

#include <stddef.h>
#include <stdint.h>

/* The longest path part of a target (before any ?query or #fragment), in
 * bytes as sent. The deepest file the web client serves
 * (node_modules/three/examples/jsm/...) is about 80 bytes; a path of many
 * times that is a probe, not a page. Below http.h's HTTP_URL_MAX so that
 * a long query string (?name=...) still leaves the path its full room. */
#ifndef WEB_FILES_PATH_MAX
#define WEB_FILES_PATH_MAX 1024u
#endif

/* The file a path ending in '/' names in that directory ("/" is the
 * root's). */
#define WEB_FILES_INDEX "index.html"

/* Room for a file's entity tag: quotes, three 16-digit hex numbers, two
 * dashes and the NUL. */
#define WEB_FILES_ETAG_MAX 56u

typedef struct web_file {
    int fd;           /* read-only, close-on-exec; the caller closes it */
    uint64_t size;    /* bytes, when it was opened */
    const char *type; /* the Content-Type, a static string */
    /* A strong entity tag (RFC 9110 8.8.3), quotes included: the file's
     * inode, size and modification time in ns, so that a file replaced or
     * rewritten (an upgrade of the web client) gets a new one. */
    char etag[WEB_FILES_ETAG_MAX];
} web_file;

/*
 * Resolves an HTTP request target (the raw bytes from the request line,
 * not NUL-terminated) against the web root directory root_fd and opens the
 * file read-only. Returns 0 with *out filled (the caller closes out->fd),
 * or:
 *   -EINVAL  answer 400: not an origin-form path ("/..."), a path over
 *            WEB_FILES_PATH_MAX, a bad %-escape, a NUL, control byte or
 *            backslash (sent or %-encoded), an encoded '/', an empty or "."
 *            segment (a final '/' is not one: it names WEB_FILES_INDEX);
 *   -EACCES  answer 403: a ".." segment (sent or %-encoded, in any case),
 *            a symbolic link anywhere on the path (inside or outside the
 *            root alike: the web root is a tree of plain files), or a file
 *            or directory the server may not read;
 *   -ENOENT  answer 404: no such file, a directory, anything not a regular
 *            file (FIFO, socket, device), a name starting with '.'
 *            (.git, .env, node_modules/.package-lock.json are never
 *            served), a name too long for the file system;
 *   another negative errno the system gave (-EMFILE, -ENFILE, -ENOMEM,
 *            -EIO): answer 500 or 503.
 * The ?query and #fragment are ignored. The root's descriptor is only
 * read from, never closed or moved. *out is untouched on failure.
 */
int web_files_open(int root_fd, const char *target, size_t len, web_file *out);

/* Whether an If-None-Match header's value (NULL: none) names etag: "*",
 * or etag among its comma-separated tags (a weak W/ tag matches its strong
 * twin: the comparison for GET is the weak one, RFC 9110 13.1.2). */
int web_files_etag_matches(const char *if_none_match, const char *etag);

#endif
