/* test_task.c: base/task.c, one function run beside the calling thread. */
#include <pthread.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

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

static void test_spare(void **state)
{
    (void)state;
    assert_false(task_spare(1));
    assert_true(task_spare(2));
    assert_true(task_spare(16));
    (void)task_spare(0); /* one per CPU: either, by the machine */
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_on_a_thread),
        cmocka_unit_test(test_on_this_thread),
        cmocka_unit_test(test_spare),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
