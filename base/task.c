/*
 * task.c: see task.h.
 */
#define _GNU_SOURCE /* sched_getaffinity, CPU_COUNT */
#include "task.h"

#include <sched.h>
#include <time.h>
#include <unistd.h>

double task_cpu_ms(void)
{
    struct timespec t;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return (double)t.tv_sec * 1e3 + (double)t.tv_nsec / 1e6;
}

double task_wall_ms(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec * 1e3 + (double)t.tv_nsec / 1e6;
}

static void *task_main(void *arg)
{
    task *t = arg;
    double t0 = task_cpu_ms();
    t->fn(t->arg);
    t->cpu_ms = task_cpu_ms() - t0;
    return NULL;
}

void task_start(task *t, void (*fn)(void *arg), void *arg, int on_thread)
{
    *t = (task){.fn = fn, .arg = arg};
    t->started = on_thread && pthread_create(&t->thread, NULL, task_main, t) == 0;
}

double task_wait(task *t)
{
    if (t->waited)
        return 0;
    t->waited = 1;
    if (!t->started) {
        t->fn(t->arg);
        return 0;
    }
    pthread_join(t->thread, NULL);
    return t->cpu_ms;
}

unsigned task_threads(unsigned threads)
{
    if (threads > 0)
        return threads;
    cpu_set_t set;
    if (sched_getaffinity(0, sizeof set, &set) == 0 && CPU_COUNT(&set) > 0)
        return (unsigned)CPU_COUNT(&set);
    long cpus = sysconf(_SC_NPROCESSORS_ONLN);
    return cpus > 0 ? (unsigned)cpus : 1u;
}

int task_spare(unsigned threads) { return task_threads(threads) > 1; }
