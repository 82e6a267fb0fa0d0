#define _GNU_SOURCE /* pipe2: both ends close-on-exec from the start */
#include "import_proc.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "alloc.h"
#include "err.h"
#include "import_pipe.h"
#include "importInt.h"
#include "le.h"
#include "task.h"

const char *import_proc_default_helper(void)
{
    static char path[PATH_MAX];
    ssize_t n = readlink("/proc/self/exe", path, sizeof path - 1);
    char *slash;
    static const char name[] = "cvre-import";

    if (n <= 0)
        return name;
    path[n] = 0;
    slash = strrchr(path, '/');
    if (!slash || (size_t)(slash + 1 - path) + sizeof name > sizeof path)
        return name;
    memcpy(slash + 1, name, sizeof name);
    return path;
}

/* The sanitizer of this build whose allocator would abort at the helper's
 * memory limit: its options ask for a NULL from malloc instead, as
 * without it. */
#if defined(CVRE_ASAN)
#define HELPER_NULL_ALLOCATOR "ASAN_OPTIONS"
#elif defined(CVRE_TSAN)
#define HELPER_NULL_ALLOCATOR "TSAN_OPTIONS"
#endif

/* The helper's environment: the sanitizers' options, passed on (with
 * HELPER_NULL_ALLOCATOR's), and glibc's huge-page malloc. envp holds 6
 * pointers, bufs 4 strings. */
static void helper_env(char *envp[6], char bufs[4][512])
{
    static const char *const names[] = {"ASAN_OPTIONS", "UBSAN_OPTIONS", "LSAN_OPTIONS", "TSAN_OPTIONS"};
    /* glibc (2.35 on) backs malloc with transparent huge pages: every page
     * of a new process is touched for the first time, and in 2 MB pages
     * the city block's import took 0.25 s instead of 0.65 s here */
    static char tunables[] = "GLIBC_TUNABLES=glibc.malloc.hugetlb=1";
    int k = 0;

    for (int i = 0; i < 4; i++) {
        const char *v = getenv(names[i]);
        char extra[96] = "";
#ifdef HELPER_NULL_ALLOCATOR
        if (strcmp(names[i], HELPER_NULL_ALLOCATOR) == 0)
            snprintf(extra, sizeof extra, "%sallocator_may_return_null=1", v && *v ? ":" : "");
#endif
        if (!v && !extra[0])
            continue;
        snprintf(bufs[k], 512, "%s=%s%s", names[i], v ? v : "", extra);
        envp[k] = bufs[k];
        k++;
    }
    envp[k++] = tunables;
    envp[k] = NULL;
}

/* What the pipes carried and how the helper ended. The answer's head is
 * read into head; once it parses, its triangles go straight into tris,
 * the array the caller keeps. */
typedef struct exchange {
    uint32_t max_triangles;
    uint8_t head[IMPORT_PIPE_ANSWER_HEAD];
    size_t head_have;
    long head_len;        /* 0 until the head parses */
    import_pipe_head h;
    float *tris;
    size_t tris_have, tris_need;
    int bad;              /* EPROTO or EFBIG: the answer broke the form; the helper was killed */
    char why[256];        /* for bad */
    int timed_out;        /* the wall-clock deadline passed: the helper was killed */
    int status;           /* waitpid's */
} exchange;

/* Takes n bytes of answer from p. 0, or -ENOMEM; a broken answer sets
 * x->bad (the caller kills the helper). */
static int take_answer(exchange *x, const uint8_t *p, size_t n)
{
    if (x->head_len == 0) {
        size_t k = n < sizeof x->head - x->head_have ? n : sizeof x->head - x->head_have;
        memcpy(x->head + x->head_have, p, k);
        x->head_have += k;
        x->head_len = import_pipe_answer_head(x->head, x->head_have, x->max_triangles, &x->h, x->why, sizeof x->why);
        if (x->head_len < 0) {
            x->bad = (int)-x->head_len;
            return 0;
        }
        if (x->head_len == 0) /* a whole head's room always parses or fails */
            return 0;
        x->tris_need = x->h.status == 0 ? (size_t)x->h.ntris * 36u : 0;
        if (x->tris_need && !(x->tris = cvre_malloc(x->tris_need)))
            return -ENOMEM;
        /* what came after the head is the start of the triangles */
        p += k - (x->head_have - (size_t)x->head_len);
        n -= k - (x->head_have - (size_t)x->head_len);
    }
    if (n > x->tris_need - x->tris_have) {
        x->bad = EPROTO;
        snprintf(x->why, sizeof x->why, "the importer answered more than its %u triangles", x->h.ntris);
        return 0;
    }
    if (n) { /* tris is NULL for a refusal, which has no triangles */
        memcpy((uint8_t *)x->tris + x->tris_have, p, n);
        x->tris_have += n;
    }
    return 0;
}

/* Feeds head then data to *fd_in (closed and set to -1 once all is sent)
 * while reading the answer from fd_out into x, until the helper closes its
 * stdout, breaks the answer's form, or the deadline. Returns 0 or -errno
 * (x->bad / x->timed_out set when it killed the helper). */
static int talk(pid_t pid, int *fd_in, int fd_out, const uint8_t *head, size_t head_len,
                const uint8_t *data, size_t len, double deadline, exchange *x)
{
    size_t sent = 0, total = head_len + len;
    uint8_t buf[65536];

    fcntl(*fd_in, F_SETFL, O_NONBLOCK);
    fcntl(fd_out, F_SETFL, O_NONBLOCK);
    for (;;) {
        struct pollfd pf[2] = {{fd_out, POLLIN, 0}, {*fd_in, POLLOUT, 0}};
        double left = deadline - task_wall_ms();
        int n;
        if (left <= 0) {
            x->timed_out = 1;
            kill(pid, SIGKILL);
            return 0;
        }
        n = poll(pf, 2, (int)left + 1);
        if (n < 0 && errno != EINTR)
            return -errno;
        if (n <= 0)
            continue;
        if (pf[1].revents & (POLLOUT | POLLERR | POLLHUP)) {
            const uint8_t *from = sent < head_len ? head + sent : data + (sent - head_len);
            size_t chunk = sent < head_len ? head_len - sent : total - sent;
            ssize_t k = write(*fd_in, from, chunk);
            if (k > 0)
                sent += (size_t)k;
            else if (k < 0 && errno != EAGAIN && errno != EINTR)
                sent = total; /* EPIPE: it stopped reading; its answer or its end says why */
            if (sent == total) {
                close(*fd_in);
                *fd_in = -1;
            }
        }
        if (pf[0].revents & (POLLIN | POLLERR | POLLHUP)) {
            /* the triangles straight into their array; the rest through buf */
            int direct = x->head_len > 0 && x->tris_have < x->tris_need;
            uint8_t *to = direct ? (uint8_t *)x->tris + x->tris_have : buf;
            size_t room = direct ? x->tris_need - x->tris_have : sizeof buf;
            ssize_t k = read(fd_out, to, room);
            if (k == 0)
                return 0;
            if (k < 0 && errno != EAGAIN && errno != EINTR)
                return -errno;
            if (k > 0 && direct)
                x->tris_have += (size_t)k;
            else if (k > 0 && take_answer(x, buf, (size_t)k) < 0) {
                kill(pid, SIGKILL);
                return -ENOMEM;
            }
            if (x->bad) {
                kill(pid, SIGKILL);
                return 0;
            }
        }
    }
}

/* Waits for the helper, killing it at the deadline. */
static void reap(pid_t pid, double deadline, exchange *x)
{
    for (;;) {
        pid_t r = waitpid(pid, &x->status, WNOHANG);
        if (r == pid || (r < 0 && errno != EINTR))
            return;
        if (r == 0 && task_wall_ms() > deadline) {
            x->timed_out = 1;
            kill(pid, SIGKILL);
            waitpid(pid, &x->status, 0);
            return;
        }
        if (r == 0) {
            struct timespec ms = {0, 1000000};
            nanosleep(&ms, NULL);
        }
    }
}

int import_isolated(const import_proc *p, const void *data, size_t len, const char *hint,
                    const import_options *opt, import_mesh *out, char *err, size_t errlen)
{
    static const import_options defaults = IMPORT_OPTIONS_DEFAULT;
    uint8_t head[IMPORT_PIPE_REQUEST_HEAD];
    char mem[16], cpu[16], envbuf[4][512], *envp[6];
    char *argv[] = {(char *)p->helper, "--memory", mem, "--cpu", cpu, NULL};
    int to[2] = {-1, -1}, from[2] = {-1, -1}, rc;
    exchange x = {.max_triangles = opt ? opt->max_triangles : IMPORT_MAX_TRIANGLES};
    posix_spawn_file_actions_t fa;
    pid_t pid;
    double deadline = task_wall_ms() + IMPORT_PROC_WALL_SECONDS(p->cpu_seconds) * 1e3; /* task_wall_ms */
    size_t head_len;

    memset(out, 0, sizeof *out);
    if (!opt)
        opt = &defaults;
    if (!data || len == 0)
        return cvre_fail(err, errlen, -EINVAL, "empty file");
    if (len > IMPORT_MAX_BYTES)
        return cvre_fail(err, errlen, -EFBIG, "file of %zu bytes is over the %u-byte limit", len,
                   (unsigned)IMPORT_MAX_BYTES);
    head_len = import_pipe_request_head(head, hint, opt, (uint32_t)len);
    snprintf(mem, sizeof mem, "%u", (unsigned)p->memory_mb);
    snprintf(cpu, sizeof cpu, "%u", (unsigned)p->cpu_seconds);
    helper_env(envp, envbuf);
    if (pipe2(to, O_CLOEXEC) != 0 || pipe2(from, O_CLOEXEC) != 0) {
        rc = cvre_fail(err, errlen, -errno, "cannot start the importer: pipe: %s", strerror(errno));
        goto cleanup;
    }
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_adddup2(&fa, to[0], 0);
    posix_spawn_file_actions_adddup2(&fa, from[1], 1);
    rc = posix_spawn(&pid, p->helper, &fa, NULL, argv, envp);
    posix_spawn_file_actions_destroy(&fa);
    if (rc != 0) {
        rc = cvre_fail(err, errlen, -rc, "cannot start the importer %s: %s", p->helper, strerror(rc));
        import__printable(err, errlen); /* the path may be any bytes */
        goto cleanup;
    }
    close(to[0]), to[0] = -1;
    close(from[1]), from[1] = -1;
    rc = talk(pid, &to[1], from[0], head, head_len, data, len, deadline, &x);
    reap(pid, deadline, &x);
    if (rc < 0) {
        cvre_fail(err, errlen, rc, "import failed: reading the importer's answer: %s", strerror(-rc));
    } else if (x.timed_out ||
               (WIFSIGNALED(x.status) && WTERMSIG(x.status) == SIGXCPU)) {
        rc = cvre_fail(err, errlen, -ETIMEDOUT, "import failed: timed out (over %u s of CPU)",
                 (unsigned)p->cpu_seconds);
    } else if (x.bad == EFBIG) {
        rc = cvre_fail(err, errlen, -EFBIG, "import failed: too large (%s)", x.why);
    } else if (x.bad) {
        rc = cvre_fail(err, errlen, -EPROTO, "import failed: bad answer from the importer: %s", x.why);
    } else if (WIFSIGNALED(x.status)) {
        rc = cvre_fail(err, errlen, -ECHILD, "import failed: parser crashed (%s)",
                 WTERMSIG(x.status) == SIGSYS ? "a forbidden system call"
                                              : strsignal(WTERMSIG(x.status)));
    } else if (!WIFEXITED(x.status) || WEXITSTATUS(x.status) != 0) {
        rc = cvre_fail(err, errlen, -ECHILD, "import failed: the importer exited with status %d",
                 WIFEXITED(x.status) ? WEXITSTATUS(x.status) : -1);
    } else if (x.head_len <= 0 || x.tris_have != x.tris_need) {
        rc = cvre_fail(err, errlen, -EPROTO, "import failed: bad answer from the importer: it ended %s",
                 x.head_len <= 0 ? "in its header" : "before its last triangle");
    } else if (x.h.status == -ENOMEM) {
        rc = cvre_fail(err, errlen, -EFBIG, "import failed: too large (over the importer's %u MB)",
                 (unsigned)p->memory_mb);
    } else if (x.h.status != 0) {
        rc = cvre_fail(err, errlen, x.h.status, "%s", x.h.message);
    } else if ((rc = import_pipe_answer_tris(x.tris, &x.h, x.why, sizeof x.why)) != 0) {
        cvre_fail(err, errlen, rc, "import failed: bad answer from the importer: %s", x.why);
    } else {
        out->tris = x.tris;
        out->ntris = x.h.ntris;
        memcpy(out->min, x.h.box, sizeof out->min);
        memcpy(out->max, x.h.box + 3, sizeof out->max);
        x.tris = NULL;
        if (errlen)
            err[0] = 0;
    }
cleanup:
    for (int i = 0; i < 2; i++) {
        if (to[i] >= 0)
            close(to[i]);
        if (from[i] >= 0)
            close(from[i]);
    }
    free(x.tris);
    return rc;
}
