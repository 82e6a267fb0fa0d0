/* test_task.c: base/task.c, one function run beside the calling thread. */
#include <pthread.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <time.h>

#include <cmocka.h>

#include "task.h"

typedef struct job {
    pthread_t ran_on;
    int runs;
    uint64_t sum;
} job;

static void busy(void *arg)
{
    job *j = arg;
    j->ran_on = pthread_self();
    j->runs++;
    volatile uint64_t s = 0;
    for (uint64_t i = 0; i < 20000000; i++)
        s += i ^ (s >> 3);
    j->sum = s;
}

/* On a thread of its own: it ran there, once, and its CPU time is counted;
 * a second wait runs nothing again. */
static void test_on_a_thread(void **state)
{
    (void)state;
    job j = {0}, here = {0};
    task t;
    task_start(&t, busy, &j, 1);
    busy(&here); /* the same work meanwhile, on this thread */
    double ms = task_wait(&t);
    assert_int_equal(j.runs, 1);
    assert_false(pthread_equal(j.ran_on, pthread_self()));
    assert_true(j.sum == here.sum);
    assert_true(ms > 0);
    assert_true(task_wait(&t) == 0);
    assert_int_equal(j.runs, 1);
}

/* Without a thread it runs inside task_wait, on the calling thread, once,
 * and no CPU time is its own. */
static void test_on_this_thread(void **state)
{
    (void)state;
    job j = {0};
    task t;
    task_start(&t, busy, &j, 0);
    assert_int_equal(j.runs, 0);
    assert_true(task_wait(&t) == 0);
    assert_int_equal(j.runs, 1);
    assert_true(pthread_equal(j.ran_on, pthread_self()));
    assert_true(task_wait(&t) == 0);
    assert_int_equal(j.runs, 1);
}

/* A count given stands; 0 is the CPUs this thread may run on, at least
 * one; a second thread is spare from two on. */
static void test_threads_and_spare(void **state)
{
    (void)state;
    assert_int_equal(task_threads(3), 3);
    unsigned cpus = task_threads(0);
    assert_true(cpus >= 1);
    assert_int_equal(task_spare(0), cpus > 1);
    assert_false(task_spare(1));
    assert_true(task_spare(2));
    assert_true(task_spare(16));
}

/* This thread's CPU clock moves with its own work; the wall clock moves
 * while it sleeps too. */
static void test_cpu_clock(void **state)
{
    (void)state;
    job j = {0};
    double t0 = task_cpu_ms();
    busy(&j);
    assert_true(task_cpu_ms() > t0);
    double w0 = task_wall_ms();
    struct timespec nap = {0, 5000000};
    while (nanosleep(&nap, &nap) != 0)
        ;
    assert_true(task_wall_ms() - w0 >= 4.9);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_on_a_thread),
        cmocka_unit_test(test_on_this_thread),
        cmocka_unit_test(test_threads_and_spare),
        cmocka_unit_test(test_cpu_clock),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
