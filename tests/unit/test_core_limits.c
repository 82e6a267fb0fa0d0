/*
 * base/ where it fails: the loop, its epoll backend, the mailbox and
 * the worker when memory, file descriptors or threads run out, when a
 * callback deletes what is already reported ready, when a signal cuts the
 * wait short, and when the queue is full at stop; and a worker's own
 * periodic work, whose results reach the loop like a job's.
 *
 * worker.c is included, not linked, so that the stop test can see the
 * worker's stop flag: the job in progress is released only once the stop
 * is under way, and the jobs still queued must then be dropped, not run.
 */
#define _GNU_SOURCE /* pthread_setattr_default_np */
#include "worker.c"

#include <fcntl.h>
#include <limits.h>
#include <poll.h>
#include <sched.h>
#include <setjmp.h>
#include <signal.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

#include <cmocka.h>

#include "ev.h"
#include "evInt.h"

/* ---- the loop and its backend ------------------------------------------- */

static void test_loop_out_of_memory(void **state)
{
    (void)state;
    /* the loop, its fd table, the backend, the backend's event array */
    for (long n = 0; n < 4; n++) {
        cvre_alloc_fail_after(n);
        assert_null(ev_create(16));
        cvre_alloc_fail_after(-1);
    }
    ev_loop *l = ev_create(16);
    assert_non_null(l);
    assert_true(ev_timer_start(l, 1, 0, NULL, NULL) >= 0);
    cvre_alloc_fail_after(0); /* the second timer needs a bigger table */
    assert_int_equal(ev_timer_start(l, 1, 0, NULL, NULL), -ENOMEM);
    cvre_alloc_fail_after(-1);
    ev_destroy(l);
    ev_destroy(NULL);
}

static void never(ev_loop *l, int fd, unsigned events, void *data)
{
    (void)l, (void)fd, (void)events, (void)data;
    fail_msg("a callback of an fd that epoll refused ran");
}

static void test_watch_refused(void **state)
{
    int fd = open("/dev/null", O_RDONLY), p[2];
    ev_loop *l = ev_create(64);

    (void)state;
    assert_true(fd >= 0);
    assert_int_equal(ev_io_add(l, fd, EV_READ, never, NULL), -EPERM); /* epoll refuses files */
    assert_int_equal(ev_io_del(l, fd), -EINVAL); /* it was never added */
    assert_int_equal(pipe(p), 0);
    assert_int_equal(ev_io_add(l, p[0], EV_READ, never, NULL), 0);
    assert_int_equal(ev_io_mod(l, p[0], EV_READ), 0); /* unchanged: no system call */
    assert_int_equal(ev_io_mod(l, p[0], EV_READ | EV_WRITE), 0);
    assert_int_equal(ev_io_del(l, p[0]), 0);
    close(p[0]);
    close(p[1]);
    close(fd);
    ev_destroy(l);
}

typedef struct two_pipes {
    int a[2], b[2];
    int calls, sleeps, readd;
} two_pipes;

/* Whichever end comes first deletes both, and re-adds the other if asked:
 * the other's report in the same batch is stale either way. */
static void take_both(ev_loop *l, int fd, unsigned events, void *data)
{
    two_pipes *p = data;
    int other = fd == p->a[0] ? p->b[0] : p->a[0];

    (void)events;
    p->calls++;
    assert_int_equal(ev_io_del(l, fd), 0);
    assert_int_equal(ev_io_del(l, other), 0);
    if (p->readd)
        assert_int_equal(ev_io_add(l, other, EV_READ, take_both, p), 0);
}

/* Stops the loop at its second sleep: one whole iteration has run. */
static void stop_second_sleep(ev_loop *l, void *data)
{
    two_pipes *p = data;

    if (++p->sleeps == 2)
        ev_stop(l);
}

static void test_stale_reports_skipped(void **state)
{
    (void)state;
    for (int readd = 0; readd < 2; readd++) {
        two_pipes p = {.readd = readd};
        ev_loop *l = ev_create(64);
        assert_int_equal(pipe(p.a), 0);
        assert_int_equal(pipe(p.b), 0);
        assert_int_equal(ev_io_add(l, p.a[0], EV_READ, take_both, &p), 0);
        assert_int_equal(ev_io_add(l, p.b[0], EV_READ, take_both, &p), 0);
        assert_int_equal(write(p.a[1], "x", 1), 1);
        assert_int_equal(write(p.b[1], "x", 1), 1);
        ev_set_before_sleep(l, stop_second_sleep, &p);
        assert_int_equal(ev_run(l), 0);
        assert_int_equal(p.calls, 1); /* the second report was from before the delete */
        for (int i = 0; i < 2; i++) {
            close(p.a[i]);
            close(p.b[i]);
        }
        ev_destroy(l);
    }
}

/* The fd number of this process's only epoll instance. */
static int find_epoll_fd(void)
{
    char path[64], target[64];
    int found = -1;

    for (int fd = 0; fd < 1024; fd++) {
        ssize_t n;
        snprintf(path, sizeof path, "/proc/self/fd/%d", fd);
        n = readlink(path, target, sizeof target - 1);
        if (n <= 0)
            continue;
        target[n] = 0;
        if (strcmp(target, "anon_inode:[eventpoll]") == 0) {
            assert_int_equal(found, -1);
            found = fd;
        }
    }
    assert_true(found >= 0);
    return found;
}

/* Puts /dev/null where the loop's epoll fd was: its wait fails. */
static void break_epoll(ev_loop *l, void *data)
{
    int null = open("/dev/null", O_RDONLY);

    (void)l;
    assert_true(null >= 0);
    assert_int_equal(dup2(null, *(int *)data), *(int *)data);
    close(null);
}

static void test_wait_fails(void **state)
{
    ev_loop *l = ev_create(64);
    int epfd = find_epoll_fd();

    (void)state;
    ev_set_before_sleep(l, break_epoll, &epfd);
    assert_int_equal(ev_run(l), -EINVAL); /* returned, not spun on */
    ev_destroy(l);                        /* closes the /dev/null in its place */
}

static volatile sig_atomic_t signals;

static void on_signal(int sig)
{
    (void)sig;
    signals++;
}

typedef struct interrupted {
    pthread_t loop_thread;
    int sleeps;
    atomic_int done; /* set by the loop's thread, read by the signalling one */
} interrupted;

static void count_sleeps(ev_loop *l, void *data)
{
    interrupted *in = data;

    if (++in->sleeps == 2) /* the wait came back with nothing ready: EINTR */
        ev_stop(l);
}

/* Signals the loop's thread until the loop has been woken by one. */
static void *keep_signalling(void *data)
{
    interrupted *in = data;
    const struct timespec pause = {0, 1000000};

    while (!in->done) {
        pthread_kill(in->loop_thread, SIGUSR1);
        nanosleep(&pause, NULL);
    }
    return NULL;
}

static void test_wait_interrupted(void **state)
{
    struct sigaction sa, old;
    interrupted in = {.loop_thread = pthread_self()};
    pthread_t t;
    ev_loop *l = ev_create(64);

    (void)state;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal; /* no SA_RESTART (epoll_wait never restarts anyway) */
    assert_int_equal(sigaction(SIGUSR1, &sa, &old), 0);
    ev_set_before_sleep(l, count_sleeps, &in);
    assert_int_equal(pthread_create(&t, NULL, keep_signalling, &in), 0);
    assert_int_equal(ev_run(l), 0); /* no fd, no timer: only a signal ends the wait */
    in.done = 1;
    pthread_join(t, NULL);
    assert_int_equal(in.sleeps, 2);
    assert_true(signals > 0);
    assert_int_equal(sigaction(SIGUSR1, &old, NULL), 0);
    ev_destroy(l);
}

static void test_backend_batch(void **state)
{
    ev__backend *b = ev__backend_create(1);
    ev__ready out[4];
    int p[2], q[2];

    (void)state;
    assert_non_null(b);
    assert_int_equal(pipe(p), 0);
    assert_int_equal(pipe(q), 0);
    assert_int_equal(ev__backend_add(b, p[0], EV_READ), 0);
    assert_int_equal(ev__backend_add(b, q[0], EV_READ), 0);
    assert_int_equal(write(p[1], "x", 1), 1);
    assert_int_equal(write(q[1], "x", 1), 1);
    /* asked for four, the backend holds one at a time */
    assert_int_equal(ev__backend_poll(b, 0, out, 4), 1);
    assert_true(out[0].events & EV_READ);
    ev__backend_destroy(b);
    ev__backend_destroy(NULL);
    for (int i = 0; i < 2; i++) {
        close(p[i]);
        close(q[i]);
    }
}

/* ---- the mailbox --------------------------------------------------------- */

/* Runs with the soft file limit at the lowest free descriptor: nothing new
 * can be opened until restore_fds. */
static struct rlimit fds_saved;

static void no_more_fds(void)
{
    int lowest = dup(0);
    struct rlimit none;

    assert_true(lowest >= 0);
    close(lowest);
    assert_int_equal(getrlimit(RLIMIT_NOFILE, &fds_saved), 0);
    none = fds_saved;
    none.rlim_cur = (rlim_t)lowest;
    assert_int_equal(setrlimit(RLIMIT_NOFILE, &none), 0);
}

static void restore_fds(void) { assert_int_equal(setrlimit(RLIMIT_NOFILE, &fds_saved), 0); }

static int freed;

static void count_free(void *p)
{
    freed++;
    free(p);
}

static void test_mailbox_failures(void **state)
{
    mailbox *m;
    uint64_t almost_full = UINT64_MAX - 1;
    int p[2];

    (void)state;
    no_more_fds();
    m = mailbox_create();
    restore_fds();
    assert_null(m);
    assert_int_equal(errno, EMFILE);

    m = mailbox_create();
    assert_non_null(m);
    /* the eventfd's counter at its maximum: the wake-up fails, the item is
     * still delivered */
    assert_int_equal(write(mailbox_fd(m), &almost_full, sizeof almost_full), (ssize_t)sizeof almost_full);
    mailbox_put(m, strdup("a"));
    mailbox_put(m, strdup("b"));
    char *a = mailbox_take(m);
    assert_string_equal(a, "a");
    free(a);
    /* items still waiting at the end are freed by the callback given */
    freed = 0;
    mailbox_destroy(m, count_free);
    assert_int_equal(freed, 1);
    mailbox_destroy(NULL, count_free);

    /* an eventfd that cannot be read: logged, and nothing is taken */
    m = mailbox_create();
    assert_int_equal(pipe(p), 0);
    assert_int_equal(dup2(p[1], mailbox_fd(m)), mailbox_fd(m));
    assert_null(mailbox_take(m));
    close(p[0]);
    close(p[1]);
    mailbox_destroy(m, NULL);
}

/* ---- the worker ---------------------------------------------------------- */

typedef struct gate {
    pthread_mutex_t lock;
    pthread_cond_t cond;
    int started, open, ran, dropped;
} gate;

static gate g = {PTHREAD_MUTEX_INITIALIZER, PTHREAD_COND_INITIALIZER, 0, 0, 0, 0};

/* Job 1 waits at the gate; every job counts itself and answers its number. */
static void *gated_job(void *ctx, void *job)
{
    int n = *(int *)job;
    int *result = cvre_xmalloc(sizeof *result);

    (void)ctx;
    pthread_mutex_lock(&g.lock);
    g.ran++;
    if (n == 1) {
        g.started = 1;
        pthread_cond_broadcast(&g.cond);
        while (!g.open)
            pthread_cond_wait(&g.cond, &g.lock);
    }
    pthread_mutex_unlock(&g.lock);
    *result = n;
    return result;
}

static void drop(void *job)
{
    assert_true(*(int *)job > 1);
    g.dropped++;
}

static void *stop_worker(void *w)
{
    worker_stop(w);
    return NULL;
}

static void test_worker_full_then_stopped(void **state)
{
    const worker_ops ops = {.job_size = sizeof(int), .queue_max = 2, .run = gated_job, .drop_job = drop};
    char err[128];
    int job;
    pthread_t stopper;
    worker *w = worker_start(&ops, err, sizeof err);
    int stopping = 0;

    (void)state;
    assert_non_null(w);
    job = 1;
    assert_int_equal(worker_submit(w, &job), 0);
    pthread_mutex_lock(&g.lock);
    while (!g.started)
        pthread_cond_wait(&g.cond, &g.lock);
    pthread_mutex_unlock(&g.lock);
    for (job = 2; job <= 3; job++) /* the queue: two slots */
        assert_int_equal(worker_submit(w, &job), 0);
    assert_int_equal(worker_submit(w, &job), -EBUSY); /* full: the job stays the caller's */

    /* stop while job 1 runs; open the gate once the stop flag is up */
    assert_int_equal(pthread_create(&stopper, NULL, stop_worker, w), 0);
    while (!stopping) {
        pthread_mutex_lock(&w->lock);
        stopping = w->stop;
        pthread_mutex_unlock(&w->lock);
        if (!stopping)
            sched_yield();
    }
    pthread_mutex_lock(&g.lock);
    g.open = 1;
    pthread_cond_broadcast(&g.cond);
    pthread_mutex_unlock(&g.lock);
    pthread_join(stopper, NULL);
    assert_int_equal(g.ran, 1);     /* job 1 finished */
    assert_int_equal(g.dropped, 2); /* jobs 2 and 3 never ran */
    worker_stop(NULL);
}

static void test_worker_cannot_start(void **state)
{
    const worker_ops ops = {.job_size = sizeof(int), .queue_max = 2, .run = gated_job};
    pthread_attr_t huge, saved;
    char err[128];

    (void)state;
    no_more_fds();
    assert_null(worker_start(&ops, err, sizeof err));
    restore_fds();
    assert_string_equal(err, "eventfd: Too many open files");

    /* a thread whose stack cannot be mapped */
    assert_int_equal(pthread_getattr_default_np(&saved), 0);
    assert_int_equal(pthread_attr_init(&huge), 0);
    assert_int_equal(pthread_attr_setstacksize(&huge, (size_t)1 << 50), 0);
    assert_int_equal(pthread_setattr_default_np(&huge), 0);
    worker *w = worker_start(&ops, err, sizeof err);
    assert_int_equal(pthread_setattr_default_np(&saved), 0);
    pthread_attr_destroy(&huge);
    pthread_attr_destroy(&saved);
    assert_null(w);
    assert_non_null(strstr(err, "cannot start a worker thread"));
}

/* A worker's own work: every call puts its number as a result, up to 3;
 * the fourth and later put nothing. */
static void count_every(void *ctx, worker *w)
{
    int *calls = ctx; /* the worker's thread only, until it is stopped */
    if (++*calls > 3)
        return;
    int *result = cvre_xmalloc(sizeof *result);
    *result = *calls;
    worker_put(w, result);
}

static void test_worker_every(void **state)
{
    int calls = 0, taken = 0;
    const worker_ops ops = {.ctx = &calls, .every = count_every, .period_ms = 2};
    char err[128];
    worker *w = worker_start(&ops, err, sizeof err);
    int job = 0;

    (void)state;
    assert_non_null(w);
    assert_int_equal(worker_submit(w, &job), -EBUSY); /* no queue: no jobs */
    /* its results arrive in order, through the fd the loop watches */
    while (taken < 3) {
        struct pollfd pf = {.fd = worker_fd(w), .events = POLLIN};
        assert_int_equal(poll(&pf, 1, 60000), 1);
        int *r;
        while ((r = worker_take(w))) {
            assert_int_equal(*r, ++taken);
            free(r);
        }
    }
    worker_stop(w);
    assert_true(calls >= 3);
}

/* Waits (up to a minute: a stuck worker, not a slow one) for the worker's
 * next result, and returns it. */
static int *next_result(worker *w)
{
    int *r;
    while (!(r = worker_take(w))) {
        struct pollfd pf = {.fd = worker_fd(w), .events = POLLIN};
        assert_int_equal(poll(&pf, 1, 60000), 1);
    }
    return r;
}

/* Calls 1 and 2 put their number; call 1 asks for the next one at once
 * (worker_due), so only a wake-up or that request can bring them within
 * the hour-long period. */
static void due_every(void *ctx, worker *w)
{
    int *calls = ctx;
    if (++*calls > 2)
        return;
    if (*calls == 1)
        worker_due(w, 0);
    int *result = cvre_xmalloc(sizeof *result);
    *result = *calls;
    worker_put(w, result);
}

static void test_worker_wake_and_due(void **state)
{
    int calls = 0;
    const worker_ops ops = {.ctx = &calls, .every = due_every, .period_ms = 3600000};
    char err[128];
    worker *w = worker_start(&ops, err, sizeof err);

    (void)state;
    assert_non_null(w);
    worker_wake(w);
    for (int k = 1; k <= 2; k++) {
        int *r = next_result(w);
        assert_int_equal(*r, k);
        free(r);
    }
    worker_stop(w);
    assert_int_equal(calls, 2); /* the third is an hour away */
}

/* Odd jobs hand nothing over (NULL), even ones their number. */
static void *odd_silent(void *ctx, void *job)
{
    (void)ctx;
    int n = *(int *)job;
    if (n % 2)
        return NULL;
    int *result = cvre_xmalloc(sizeof *result);
    *result = n;
    return result;
}

static void test_worker_job_without_result(void **state)
{
    const worker_ops ops = {.job_size = sizeof(int), .queue_max = 4, .run = odd_silent};
    char err[128];
    worker *w = worker_start(&ops, err, sizeof err);

    (void)state;
    assert_non_null(w);
    for (int job = 1; job <= 4; job++)
        assert_int_equal(worker_submit(w, &job), 0);
    for (int k = 2; k <= 4; k += 2) {
        int *r = next_result(w);
        assert_int_equal(*r, k);
        free(r);
    }
    worker_stop(w);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_loop_out_of_memory),
        cmocka_unit_test(test_watch_refused),
        cmocka_unit_test(test_stale_reports_skipped),
        cmocka_unit_test(test_wait_fails),
        cmocka_unit_test(test_wait_interrupted),
        cmocka_unit_test(test_backend_batch),
        cmocka_unit_test(test_mailbox_failures),
        cmocka_unit_test(test_worker_full_then_stopped),
        cmocka_unit_test(test_worker_cannot_start),
        cmocka_unit_test(test_worker_every),
        cmocka_unit_test(test_worker_wake_and_due),
        cmocka_unit_test(test_worker_job_without_result),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
