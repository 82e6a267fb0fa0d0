/*
 * task.h: one function run beside the calling thread, for work that splits
 * in two independent halves (a refinement's tables, its triangle index),
 * on a machine with a core to spare; or on the calling thread, when there is
 * none, so that the result is the same either way.
 *
 * A task's function runs once, on its own thread from task_start, or on
 * the calling thread inside task_wait when task_start was told to use none
 * or could not start one. Whoever accounts for CPU time adds the task's
 * (task_wait's return) to the calling thread's: a thread's CPU clock does not
 * count the other's.
 */
#ifndef CVRE_TASK_H
#define CVRE_TASK_H

#include <pthread.h>

typedef struct task {
    void (*fn)(void *arg);
    void *arg;
    pthread_t thread;
    int started;   /* on a thread of its own */
    int waited;    /* task_wait returned */
    double cpu_ms; /* that thread's CPU time */
} task;

/* Starts fn(arg) on a new thread when on_thread is non-zero and one can
 * start; else it waits for task_wait. */
void task_start(task *t, void (*fn)(void *arg), void *arg, int on_thread);
/* Returns once fn(arg) has run (here, if it had not started): the CPU time
 * it took on a thread of its own, ms, or 0 when it ran on this one (or was
 * waited for already). */
double task_wait(task *t);
/* This thread's CPU time, ms (CLOCK_THREAD_CPUTIME_ID, its page faults
 * included): a stage's cost whatever else the machine runs. */
double task_cpu_ms(void);
/* The monotonic clock, ms: a stage's wall time, where task_cpu_ms is its
 * CPU time (the store's reads and writes wait on the disk); the one
 * reading of it for deadlines and periods too (workers, the collision
 * log's writer, the import helper's time limit). */
double task_wall_ms(void);
/* How many threads `threads` stands for: itself, or for 0 the CPUs this
 * thread may run on (its affinity: a container's or taskset's limit), at
 * least 1. */
unsigned task_threads(unsigned threads);
/* 1 when a second thread can run beside this one: task_threads is 2 or more. */
int task_spare(unsigned threads);

#endif
