/*
 * ev.h: a small single-threaded event loop (file descriptors and timers).
 *
 * One iteration: run the before-sleep hook (housekeeping), poll with the
 * timeout of the nearest timer, dispatch readiness callbacks, then run the
 * timers that are due. Only ev_epoll.c talks to the kernel's epoll API.
 * Callbacks may add, modify and delete any registration, including their own,
 * and may stop the loop; a deleted fd gets no further callback in the same
 * iteration. Every function returns 0 or -errno unless it says otherwise.
 */
#ifndef CVRE_EV_H
#define CVRE_EV_H

#include <stdint.h>

typedef struct ev_loop ev_loop;

enum { EV_READ = 1, EV_WRITE = 2, EV_ERROR = 4 /* error or hang-up; always reported */ };

typedef void ev_io_fn(ev_loop *loop, int fd, unsigned events, void *data);
typedef void ev_timer_fn(ev_loop *loop, void *data);
typedef void ev_hook_fn(ev_loop *loop, void *data);

/* Creates a loop able to watch fds below max_fd. NULL with errno on failure. */
ev_loop *ev_create(int max_fd);
/* Frees the loop; does not close the watched fds. */
void ev_destroy(ev_loop *loop);

/* Watches fd (level-triggered) for events, a mask of EV_READ and EV_WRITE.
 * -EINVAL if fd is out of range or already watched. */
int ev_io_add(ev_loop *loop, int fd, unsigned events, ev_io_fn *fn, void *data);
int ev_io_mod(ev_loop *loop, int fd, unsigned events);
int ev_io_del(ev_loop *loop, int fd);

/* Monotonic time in nanoseconds, read once per iteration (cached). */
uint64_t ev_now(const ev_loop *loop);
/* Reads the clock now, refreshing the cached value. */
uint64_t ev_clock(ev_loop *loop);

/* Starts a timer that first fires after delay_ns and then every period_ns
 * (0: once). Periodic timers keep a fixed schedule (due += period), so they
 * do not drift; if the loop falls more than one period behind, the missed
 * firings are skipped, not replayed. Returns a timer id >= 0 or -errno. */
int ev_timer_start(ev_loop *loop, uint64_t delay_ns, uint64_t period_ns, ev_timer_fn *fn, void *data);
/* Stops a timer; stopping a fired one-shot timer or an unknown id is a no-op. */
void ev_timer_stop(ev_loop *loop, int id);

/* Sets the hook that runs before each poll (NULL to clear). */
void ev_set_before_sleep(ev_loop *loop, ev_hook_fn *fn, void *data);

/* Runs until ev_stop() is called. Returns 0, or -errno if polling failed. */
int ev_run(ev_loop *loop);
/* Makes ev_run() return after the current iteration. */
void ev_stop(ev_loop *loop);

#endif
