#define _GNU_SOURCE /* pipe2: both ends close-on-exec from the start */
#include "import_proc.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "alloc.h"
#include "import_pipe.h"
#include "le.h"

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

static double now_s(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + (double)t.tv_nsec * 1e-9;
}

/* The helper's environment: only the sanitizers' options, passed on (and,
 * under AddressSanitizer, whose allocator would abort at the helper's
 * memory limit, a NULL from malloc instead, as without it). envp holds 4
 * pointers, bufs 3 strings. */
static void helper_env(char *envp[4], char bufs[3][512])
{
    static const char *const names[] = {"ASAN_OPTIONS", "UBSAN_OPTIONS", "LSAN_OPTIONS"};
    int k = 0;

    for (int i = 0; i < 3; i++) {
        const char *v = getenv(names[i]);
        char extra[96] = "";
#ifdef CVRE_ASAN
        if (i == 0)
            snprintf(extra, sizeof extra, "%sallocator_may_return_null=1", v && *v ? ":" : "");
#endif
        if (!v && !extra[0])
            continue;
        snprintf(bufs[k], 512, "%s=%s%s", names[i], v ? v : "", extra);
        envp[k] = bufs[k];
        k++;
    }
    envp[k] = NULL;
}

/* Formats err and returns rc. */
__attribute__((format(printf, 4, 5))) static int say(char *err, size_t errlen, int rc,
                                                     const char *fmt, ...)
{
    va_list ap;

    if (errlen) {
        va_start(ap, fmt);
        vsnprintf(err, errlen, fmt, ap);
        va_end(ap);
    }
    return rc;
}

/* What the pipes carried and how the helper ended. */
typedef struct exchange {
    uint8_t *answer;
    size_t have, cap;
    int too_large;  /* the answer passed its largest size: the helper was killed */
    int timed_out;  /* the wall-clock deadline passed: the helper was killed */
    int status;     /* waitpid's */
} exchange;

/* Feeds head then data to *fd_in (closed and set to -1 once all is sent)
 * while reading fd_out into x, until the helper closes its stdout, the
 * answer grows past max, or the deadline. Returns 0 or -errno
 * (x->too_large / x->timed_out set when it killed the helper). */
static int talk(pid_t pid, int *fd_in, int fd_out, const uint8_t *head, size_t head_len,
                const uint8_t *data, size_t len, uint64_t max, double deadline, exchange *x)
{
    size_t sent = 0, total = head_len + len;

    fcntl(*fd_in, F_SETFL, O_NONBLOCK);
    fcntl(fd_out, F_SETFL, O_NONBLOCK);
    for (;;) {
        struct pollfd pf[2] = {{fd_out, POLLIN, 0}, {*fd_in, POLLOUT, 0}};
        double left = deadline - now_s();
        int n;
        if (left <= 0) {
            x->timed_out = 1;
            kill(pid, SIGKILL);
            return 0;
        }
        n = poll(pf, 2, (int)(left * 1000) + 1);
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
            ssize_t k;
            if (x->have == x->cap) {
                size_t cap = x->cap ? x->cap * 2 : 65536;
                uint8_t *b;
                if (cap > max + 1)
                    cap = (size_t)max + 1;
                if (cap <= x->cap || !(b = cvre_realloc(x->answer, cap))) {
                    if (cap <= x->cap) { /* over max by a byte at least */
                        x->too_large = 1;
                        kill(pid, SIGKILL);
                        return 0;
                    }
                    kill(pid, SIGKILL);
                    return -ENOMEM;
                }
                x->answer = b;
                x->cap = cap;
            }
            k = read(fd_out, x->answer + x->have, x->cap - x->have);
            if (k == 0)
                return 0;
            if (k > 0)
                x->have += (size_t)k;
            else if (errno != EAGAIN && errno != EINTR)
                return -errno;
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
        if (r == 0 && now_s() > deadline) {
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
    char mem[16], cpu[16], envbuf[3][512], *envp[4];
    char *argv[] = {(char *)p->helper, "--memory", mem, "--cpu", cpu, NULL};
    int to[2] = {-1, -1}, from[2] = {-1, -1}, rc;
    exchange x = {0};
    posix_spawn_file_actions_t fa;
    pid_t pid;
    double deadline = now_s() + IMPORT_PROC_WALL_SECONDS(p->cpu_seconds);
    size_t head_len;

    memset(out, 0, sizeof *out);
    if (!opt)
        opt = &defaults;
    if (!data || len == 0)
        return say(err, errlen, -EINVAL, "empty file");
    if (len > IMPORT_MAX_BYTES)
        return say(err, errlen, -EFBIG, "file of %zu bytes is over the %u-byte limit", len,
                   (unsigned)IMPORT_MAX_BYTES);
    head_len = import_pipe_request_head(head, hint, opt, (uint32_t)len);
    snprintf(mem, sizeof mem, "%u", (unsigned)p->memory_mb);
    snprintf(cpu, sizeof cpu, "%u", (unsigned)p->cpu_seconds);
    helper_env(envp, envbuf);
    if (pipe2(to, O_CLOEXEC) != 0 || pipe2(from, O_CLOEXEC) != 0) {
        rc = say(err, errlen, -errno, "cannot start the importer: pipe: %s", strerror(errno));
        goto cleanup;
    }
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_adddup2(&fa, to[0], 0);
    posix_spawn_file_actions_adddup2(&fa, from[1], 1);
    rc = posix_spawn(&pid, p->helper, &fa, NULL, argv, envp);
    posix_spawn_file_actions_destroy(&fa);
    if (rc != 0) {
        rc = say(err, errlen, -rc, "cannot start the importer %s: %s", p->helper, strerror(rc));
        goto cleanup;
    }
    close(to[0]), to[0] = -1;
    close(from[1]), from[1] = -1;
    rc = talk(pid, &to[1], from[0], head, head_len, data, len,
              import_pipe_answer_max(opt->max_triangles), deadline, &x);
    reap(pid, deadline, &x);
    if (rc < 0) {
        say(err, errlen, rc, "import failed: reading the importer's answer: %s", strerror(-rc));
    } else if (x.timed_out ||
               (WIFSIGNALED(x.status) && WTERMSIG(x.status) == SIGXCPU)) {
        rc = say(err, errlen, -ETIMEDOUT, "import failed: timed out (over %u s of CPU)",
                 (unsigned)p->cpu_seconds);
    } else if (x.too_large) {
        rc = say(err, errlen, -EFBIG, "import failed: too large (an answer over %u triangles)",
                 (unsigned)opt->max_triangles);
    } else if (WIFSIGNALED(x.status)) {
        rc = say(err, errlen, -ECHILD, "import failed: parser crashed (%s)",
                 WTERMSIG(x.status) == SIGSYS ? "a forbidden system call"
                                              : strsignal(WTERMSIG(x.status)));
    } else if (!WIFEXITED(x.status) || WEXITSTATUS(x.status) != 0) {
        rc = say(err, errlen, -ECHILD, "import failed: the importer exited with status %d",
                 WIFEXITED(x.status) ? WEXITSTATUS(x.status) : -1);
    } else if (x.have >= 14 && (int32_t)le_get_u32(x.answer + 8) == -ENOMEM) {
        rc = say(err, errlen, -EFBIG, "import failed: too large (over the importer's %u MB)",
                 (unsigned)p->memory_mb);
    } else {
        rc = import_pipe_answer(x.answer, x.have, opt->max_triangles, out, err, errlen);
        if (rc == -EPROTO) {
            char why[256];
            snprintf(why, sizeof why, "%s", err);
            say(err, errlen, rc, "import failed: bad answer from the importer: %s", why);
        }
    }
cleanup:
    for (int i = 0; i < 2; i++) {
        if (to[i] >= 0)
            close(to[i]);
        if (from[i] >= 0)
            close(from[i]);
    }
    free(x.answer);
    return rc;
}
