/*
 * import_main.c: cvre-import, the isolated importer. The server starts one
 * per upload (server/import/import_proc.c): it reads one request on stdin
 * (import_pipe.h), parses the model with import_model, writes one answer on
 * stdout and exits. Before it reads a byte of the upload it limits itself
 * (address space, CPU seconds, no files, no core) and installs a seccomp
 * filter that kills it on any system call beyond reading stdin, writing
 * stdout and stderr, managing memory and exiting: whatever a hostile file
 * does to Assimp, it can only crash, spin or run out inside this process.
 */
#include <errno.h>
#include <getopt.h>
#include <limits.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <unistd.h>

#include <seccomp.h>

#include "alloc.h"
#include "err.h"
#include "import.h"
#include "import_pipe.h"

/* Exit codes: the answer was written (whatever the import's result), bad
 * arguments, a malformed request or a failed write, and limits that could
 * not be set. */
enum { EXIT_ANSWERED = 0, EXIT_USAGE = 2, EXIT_REQUEST = 3, EXIT_SETUP = 4 };

/* Coverage builds only (tools/coverage.sh; never a build that ships): gcov
 * writes this process's counts when it ends, which takes opening, locking,
 * seeking, reading and writing a file of counts. There the descriptor
 * limit leaves room for one, the filter lets those calls through, and
 * every exit after the filter writes the counts first: _exit alone skips
 * them. */
#ifdef CVRE_COVERAGE
void __gcov_dump(void);
#define SANDBOX_FILES 8
#define sandbox_exit(status) (__gcov_dump(), _exit(status))
#else
#define SANDBOX_FILES 3
#define sandbox_exit(status) _exit(status)
#endif

static const char usage[] =
    "usage: cvre-import [--memory MB] [--cpu SECONDS] [--help] [--version]\n"
    "\n"
    "Reads one model import request on stdin and writes the answer on stdout\n"
    "(the binary form of server/import/import_pipe.h), then exits. cvre-server\n"
    "starts it once per upload; it is not meant to be run by hand.\n"
    "\n"
    "  --memory MB       address space limit (default 4096)\n"
    "  --cpu SECONDS     CPU time limit; SIGXCPU past it (default 30)\n"
    "  --help            this text\n"
    "  --version         the version\n";

/* Sanitizer builds: AddressSanitizer's and ThreadSanitizer's shadow memory
 * already exceeds any address-space limit. */
#if defined(CVRE_ASAN) || defined(CVRE_TSAN)
#define SANDBOX_LIMIT_DATA
#endif

#ifdef SANDBOX_LIMIT_DATA
/* Bytes of private writable memory mapped now (VmData), or 0. */
static unsigned long long data_now(void)
{
    unsigned long long kb = 0;
    char line[128];
    FILE *f = fopen("/proc/self/status", "r");

    while (f && fgets(line, sizeof line, f))
        if (sscanf(line, "VmData: %llu kB", &kb) == 1)
            break;
    if (f)
        fclose(f);
    return kb << 10;
}
#endif

/* Limits that hold from here on. Under a sanitizer (SANDBOX_LIMIT_DATA)
 * the limit is on data mappings instead, counted from what is mapped now
 * (the server also tells that build's allocator to return NULL rather than
 * abort). 0 or -errno. */
static int set_limits(unsigned long memory_mb, unsigned long cpu_seconds)
{
    struct rlimit cpu = {cpu_seconds, cpu_seconds + 1}, none = {0, 0}, files = {SANDBOX_FILES, SANDBOX_FILES};
#ifndef SANDBOX_LIMIT_DATA
    struct rlimit mem = {memory_mb << 20, memory_mb << 20};
    if (setrlimit(RLIMIT_AS, &mem) != 0)
        return -errno;
#else
    unsigned long long data = data_now() + ((unsigned long long)memory_mb << 20);
    struct rlimit mem = {data, data};
    if (setrlimit(RLIMIT_DATA, &mem) != 0)
        return -errno;
#endif
    /* no file descriptors beyond stdin, stdout and stderr (the seccomp
     * filter forbids opening anything too); no RLIMIT_FSIZE: stderr may be
     * the server's log file, and a sanitizer's report there would die of
     * SIGXFSZ instead of saying what happened */
    if (setrlimit(RLIMIT_CPU, &cpu) != 0 || setrlimit(RLIMIT_NOFILE, &files) != 0 ||
        setrlimit(RLIMIT_CORE, &none) != 0)
        return -errno;
    return 0;
}

/* One argument test (seccomp.h's SCMP_A* macros leave datum_b to the
 * compiler, which -Wmissing-field-initializers refuses). */
static struct scmp_arg_cmp arg(unsigned int n, enum scmp_compare op, scmp_datum_t a, scmp_datum_t b)
{
    return (struct scmp_arg_cmp){.arg = n, .op = op, .datum_a = a, .datum_b = b};
}

/* The seccomp filter: reads from stdin, writes to stdout and stderr, memory
 * that is never executable, futexes (Assimp's locks), signals to itself
 * (abort), the clock, and exit. Anything else kills the process. 0 or
 * -errno (libseccomp's results are). */
static int sandbox(void)
{
    static const int plain[] = {
        SCMP_SYS(brk),          SCMP_SYS(munmap),       SCMP_SYS(mremap),    SCMP_SYS(madvise),
        SCMP_SYS(futex),        SCMP_SYS(exit),         SCMP_SYS(exit_group), SCMP_SYS(rt_sigreturn),
        SCMP_SYS(rt_sigprocmask), SCMP_SYS(gettid),     SCMP_SYS(getpid),    SCMP_SYS(tgkill),
        SCMP_SYS(clock_gettime), SCMP_SYS(sched_yield), SCMP_SYS(close),     SCMP_SYS(fstat),
        SCMP_SYS(newfstatat),   SCMP_SYS(sigaltstack),
#ifdef CVRE_COVERAGE
        SCMP_SYS(openat),       SCMP_SYS(fcntl),        SCMP_SYS(lseek),     SCMP_SYS(read),
        SCMP_SYS(write),
#endif
    };
    scmp_filter_ctx ctx = seccomp_init(SCMP_ACT_KILL_PROCESS);
    int rc = ctx ? 0 : -ENOMEM;

    for (size_t i = 0; rc == 0 && i < sizeof plain / sizeof plain[0]; i++)
        rc = seccomp_rule_add(ctx, SCMP_ACT_ALLOW, plain[i], 0);
    if (rc == 0)
        rc = seccomp_rule_add(ctx, SCMP_ACT_ALLOW, SCMP_SYS(read), 1, arg(0, SCMP_CMP_EQ, 0, 0));
    for (int fd = 1; rc == 0 && fd <= 2; fd++)
        rc = seccomp_rule_add(ctx, SCMP_ACT_ALLOW, SCMP_SYS(write), 1,
                              arg(0, SCMP_CMP_EQ, (scmp_datum_t)fd, 0));
    if (rc == 0)
        rc = seccomp_rule_add(ctx, SCMP_ACT_ALLOW, SCMP_SYS(mmap), 1,
                              arg(2, SCMP_CMP_MASKED_EQ, PROT_EXEC, 0));
    if (rc == 0)
        rc = seccomp_rule_add(ctx, SCMP_ACT_ALLOW, SCMP_SYS(mprotect), 1,
                              arg(2, SCMP_CMP_MASKED_EQ, PROT_EXEC, 0));
    if (rc == 0)
        rc = seccomp_load(ctx); /* sets no_new_privs (SCMP_FLTATR_CTL_NNP is on) */
    if (ctx)
        seccomp_release(ctx);
    return rc;
}

/* Moves exactly n bytes: reads them from stdin into p, or (writing) writes
 * them from p to stdout. 0, -EPIPE at an early end, or -errno. */
static int move_all(uint8_t *p, size_t n, int writing)
{
    while (n) {
        ssize_t k = writing ? write(1, p, n) : read(0, p, n);
        if (k < 0 && errno == EINTR)
            continue;
        if (k < 0)
            return -errno;
        if (k == 0)
            return -EPIPE;
        p += k;
        n -= (size_t)k;
    }
    return 0;
}

#ifdef CVRE_TEST_HOOKS
/*
 * Test builds only (-DCVRE_TEST_HOOKS=ON): an upload that starts with
 * "cvre-import-test:" followed by a word makes the helper misbehave the way
 * a hostile file might make Assimp: crash, spin, allocate without end, or
 * answer too much or garbage. True if the data is such a request; then
 * *status is the status to answer, with m and err as import_model fills
 * them.
 */
static int test_request(const uint8_t *data, size_t len, uint32_t max_triangles, import_mesh *m,
                        char *err, size_t errlen, int *status)
{
    static const char prefix[] = "cvre-import-test:";
    size_t pl = sizeof prefix - 1;
    const char *word = (const char *)data + pl;
    size_t wl = len - pl;

    if (len < pl || memcmp(data, prefix, pl) != 0)
        return 0;
    while (wl && (word[wl - 1] == '\n' || word[wl - 1] == ' '))
        wl--;
#define IS(w) (wl == sizeof(w) - 1 && memcmp(word, w, wl) == 0)
    if (IS("crash")) {
        raise(SIGSEGV);
    } else if (IS("loop")) {
        for (volatile unsigned long spin = 0;; spin++)
            ;
    } else if (IS("alloc")) {
        static void *volatile kept; /* a chain the compiler cannot elide */
        for (;;) {
            void **p = malloc(1u << 20);
            if (!p) {
                *status = cvre_fail(err, errlen, -ENOMEM, "out of memory");
                return 1;
            }
            memset(p, 1, 1u << 20);
            *p = kept;
            kept = p;
        }
    } else if (IS("flood") || IS("nan")) {
        /* more triangles than allowed, or one
         * with a NaN corner */
        uint32_t n = IS("flood") ? 2 * max_triangles + 64 : 1;
        m->tris = calloc((size_t)n, 36u);
        if (!m->tris) {
            *status = -ENOMEM;
            return 1;
        }
        m->ntris = n;
        m->max[0] = m->max[1] = m->max[2] = 0;
        if (IS("nan"))
            m->tris[4] = __builtin_nanf("");
        if (errlen)
            err[0] = 0; /* as import_model leaves it on success */
        *status = 0;
        return 1;
    }
#undef IS
    return 0;
}
#endif

int main(int argc, char **argv)
{
    static const struct option options[] = {{"memory", required_argument, NULL, 'm'},
                                            {"cpu", required_argument, NULL, 'c'},
                                            {"help", no_argument, NULL, 'h'},
                                            {"version", no_argument, NULL, 'V'},
                                            {NULL, 0, NULL, 0}};
    unsigned long memory_mb = 4096, cpu_seconds = 30;
    uint8_t head[IMPORT_PIPE_REQUEST_HEAD], *data, answer[IMPORT_PIPE_ANSWER_HEAD];
    char hint[IMPORT_PIPE_HINT_MAX + 1], err[IMPORT_PIPE_MESSAGE_MAX];
    import_options opt;
    import_mesh mesh = {0};
    uint32_t data_len = 0;
    size_t have = 0;
    long head_len = 0;
    int c, rc, tested = 0;

    while ((c = getopt_long(argc, argv, "", options, NULL)) != -1) {
        char *end;
        unsigned long v;
        switch (c) {
        case 'm':
        case 'c':
            errno = 0;
            v = strtoul(optarg, &end, 10);
            if (errno || *end || v == 0 || v > (c == 'm' ? 1ul << 20 : 86400ul)) {
                fprintf(stderr, "cvre-import: --%s: not a whole number in range: %s\n",
                        c == 'm' ? "memory" : "cpu", optarg);
                return EXIT_USAGE;
            }
            *(c == 'm' ? &memory_mb : &cpu_seconds) = v;
            break;
        case 'h': fputs(usage, stdout); return 0;
        case 'V': printf("cvre-import %s\n", CVRE_VERSION); return 0;
        default: fputs(usage, stderr); return EXIT_USAGE;
        }
    }
    if (optind != argc) {
        fputs(usage, stderr);
        return EXIT_USAGE;
    }
    import_prepare();
    if ((rc = set_limits(memory_mb, cpu_seconds)) != 0 || (rc = sandbox()) != 0) {
        fprintf(stderr, "cvre-import: cannot limit itself: %s\n", strerror(-rc));
        return EXIT_SETUP;
    }

    /* From here on only the filter's system calls, and every exit is
     * _exit: atexit handlers (LeakSanitizer's needs ptrace) would break it.
     * The head's length depends on its hint: read it a byte at a time until
     * it parses. */
    while ((head_len = import_pipe_request_parse(head, have, &opt, hint, &data_len)) == 0) {
        if (have == sizeof head || move_all(head + have, 1, 0) != 0)
            sandbox_exit(EXIT_REQUEST);
        have++;
    }
    if (head_len < 0 || data_len > IMPORT_MAX_BYTES || data_len == 0)
        sandbox_exit(EXIT_REQUEST);
    data = cvre_malloc(data_len);
    if (!data || move_all(data, data_len, 0) != 0)
        sandbox_exit(EXIT_REQUEST);
#ifdef CVRE_TEST_HOOKS
    tested = test_request(data, data_len, opt.max_triangles, &mesh, err, sizeof err, &rc);
#endif
    if (!tested)
        rc = import_model(data, data_len, hint[0] ? hint : NULL, &opt, &mesh, err, sizeof err);
    free(data);
    /* the head, then the triangles straight from the mesh: no copy */
    head_len = (long)import_pipe_answer_head_encode(answer, rc, err, &mesh);
    if (move_all(answer, (size_t)head_len, 1) != 0)
        sandbox_exit(EXIT_REQUEST);
    if (rc == 0) {
        import_pipe_tris_to_le(mesh.tris, (size_t)mesh.ntris * 9u);
        if (move_all((uint8_t *)mesh.tris, (size_t)mesh.ntris * 36u, 1) != 0)
            sandbox_exit(EXIT_REQUEST);
    }
    sandbox_exit(EXIT_ANSWERED);
}
