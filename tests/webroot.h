/*
 * webroot.h: the web root that test_web_files and fuzz_web_files open
 * files in (header only): plain files of every content type, a
 * subdirectory with an index, a directory without, hidden names, names
 * that need %-escapes, symbolic links pointing inside the root and out of
 * it, and a FIFO; beside the root, the files a request must never reach.
 */
#ifndef CVRE_WEBROOT_H
#define CVRE_WEBROOT_H

#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

typedef struct webroot_entry {
    const char *path; /* under the temporary directory; "root/..." is in the root */
    char kind;        /* 'f' file, 'd' directory, 'l' symbolic link, 'p' FIFO */
    const char *data; /* a file's bytes, a link's target */
} webroot_entry;

/* In the order they are made (a directory before what it holds). */
static const webroot_entry webroot_entries[] = {
    {"outside.txt", 'f', "outside the root"},
    {"outside-dir", 'd', NULL},
    {"outside-dir/secret.txt", 'f', "a secret"},
    {"root", 'd', NULL},
    {"root/index.html", 'f', "<!doctype html><title>cvre</title>"},
    {"root/app.js", 'f', "import * as THREE from './three.module.js';"},
    {"root/mod.mjs", 'f', "export const x = 1;"},
    {"root/style.css", 'f', "body { margin: 0 }"},
    {"root/notes.txt", 'f', "notes"},
    {"root/icon.svg", 'f', "<svg xmlns='http://www.w3.org/2000/svg'/>"},
    {"root/data.json", 'f', "{\"a\": 1}"},
    {"root/model.glb", 'f', "glTF"},
    {"root/lib.wasm", 'f', "wasm"},
    {"root/pic.png", 'f', "png"},
    {"root/favicon.ico", 'f', "ico"},
    {"root/LOUD.HTML", 'f', "<p>loud</p>"},
    {"root/blob.bin", 'f', "blob"},
    {"root/README", 'f', "readme"},
    {"root/empty.txt", 'f', ""},
    {"root/with space.txt", 'f', "a space"},
    {"root/100%.txt", 'f', "a percent sign"},
    {"root/\xc3\xa9t\xc3\xa9.txt", 'f', "UTF-8"},
    {"root/.hidden", 'f', "hidden"},
    {"root/.git", 'd', NULL},
    {"root/.git/config", 'f', "[core]"},
    {"root/sub", 'd', NULL},
    {"root/sub/index.html", 'f', "<p>sub</p>"},
    {"root/sub/deeper", 'd', NULL},
    {"root/sub/deeper/model.glb", 'f', "deeper glTF"},
    {"root/empty", 'd', NULL},
    {"root/link-in", 'l', "app.js"},
    {"root/link-dir-in", 'l', "sub"},
    {"root/link-out", 'l', "../outside.txt"},
    {"root/link-dir-out", 'l', "../outside-dir"},
    {"root/link-abs", 'l', "/etc/passwd"},
    {"root/sub/link-up", 'l', ".."},
    {"root/dangling", 'l', "nowhere"},
    {"root/fifo", 'p', NULL},
};
#define WEBROOT_ENTRIES (sizeof webroot_entries / sizeof webroot_entries[0])

/* Makes the tree in a new directory /tmp/cvre-webroot-XXXXXX, whose path
 * it writes to dir. Returns a descriptor of dir/root, or -1 (errno set). */
static inline int webroot_make(char dir[64])
{
    snprintf(dir, 64, "/tmp/cvre-webroot-XXXXXX");
    if (!mkdtemp(dir))
        return -1;
    int top = open(dir, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (top < 0)
        return -1;
    for (size_t i = 0; i < WEBROOT_ENTRIES; i++) {
        const webroot_entry *e = &webroot_entries[i];
        int rc = 0;
        if (e->kind == 'f') {
            int fd = openat(top, e->path, O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
            size_t n = strlen(e->data);
            rc = fd < 0 || write(fd, e->data, n) != (ssize_t)n ? -1 : 0;
            if (fd >= 0)
                close(fd);
        } else if (e->kind == 'd') {
            rc = mkdirat(top, e->path, 0755);
        } else if (e->kind == 'l') {
            rc = symlinkat(e->data, top, e->path);
        } else {
            rc = mkfifoat(top, e->path, 0644);
        }
        if (rc < 0) {
            close(top);
            return -1;
        }
    }
    int root = openat(top, "root", O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    close(top);
    return root;
}

/* Removes what webroot_make made in dir (whatever a test added there it
 * removes first), and dir. */
static inline void webroot_remove(const char *dir)
{
    int top = open(dir, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (top < 0)
        return;
    for (size_t i = WEBROOT_ENTRIES; i-- > 0;)
        unlinkat(top, webroot_entries[i].path, webroot_entries[i].kind == 'd' ? AT_REMOVEDIR : 0);
    close(top);
    rmdir(dir);
}

#endif
