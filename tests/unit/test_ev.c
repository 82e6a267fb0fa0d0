/* The event loop: timers keep their schedule, fds are dispatched, and a
 * callback may delete registrations, including ones already reported ready. */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>
#include <unistd.h>

#include "ev.h"

typedef struct counter {
    int fired;
    int stop_at;
    uint64_t first, last;
} counter;

static void count_timer(ev_loop *l, void *data)
{
    counter *c = data;
    if (!c->fired)
        c->first = ev_now(l);
    c->last = ev_now(l);
    if (++c->fired == c->stop_at)
        ev_stop(l);
}

static void test_periodic_timer(void **state)
{
    (void)state;
    ev_loop *l = ev_create(64);
    assert_non_null(l);
    counter c = {.stop_at = 10};
    uint64_t start = ev_now(l); /* the time the schedule counts from */
    assert_true(ev_timer_start(l, 5000000, 5000000, count_timer, &c) >= 0);
    assert_int_equal(ev_run(l), 0);
    assert_int_equal(c.fired, 10);
    /* The tenth firing is due 5 ms + nine periods of 5 ms after the start,
     * and the loop never fires early. (A late firing lets the next one
     * come sooner than a period after it, back on the schedule, so the
     * gap between the first and the tenth proves nothing on a busy
     * machine.) */
    assert_true(c.first >= start + 5000000u);
    assert_true(c.last >= start + 10u * 5000000u);
    ev_destroy(l);
}

static void test_one_shot_and_stop(void **state)
{
    (void)state;
    ev_loop *l = ev_create(64);
    counter once = {.stop_at = -1}, stopper = {.stop_at = 1};
    int id = ev_timer_start(l, 1000000, 0, count_timer, &once);
    int never = ev_timer_start(l, 2000000, 0, count_timer, &once);
    ev_timer_stop(l, never);
    assert_true(ev_timer_start(l, 20000000, 0, count_timer, &stopper) >= 0);
    assert_true(id >= 0);
    assert_int_equal(ev_run(l), 0);
    assert_int_equal(once.fired, 1);
    ev_destroy(l);
}

typedef struct pipes {
    int a[2], b[2];
    int a_calls, b_calls;
} pipes;

/* Whichever end is reported first deletes the other: the other must not be
 * called in the same iteration even though epoll reported it ready. */
static void on_read(ev_loop *l, int fd, unsigned events, void *data)
{
    pipes *p = data;
    assert_true(events & EV_READ);
    if (fd == p->a[0]) {
        p->a_calls++;
        ev_io_del(l, p->b[0]);
    } else {
        p->b_calls++;
        ev_io_del(l, p->a[0]);
    }
    ev_io_del(l, fd);
    ev_stop(l);
}

static void test_delete_inside_callback(void **state)
{
    (void)state;
    ev_loop *l = ev_create(64);
    pipes p = {0};
    assert_int_equal(pipe(p.a), 0);
    assert_int_equal(pipe(p.b), 0);
    assert_int_equal(ev_io_add(l, p.a[0], EV_READ, on_read, &p), 0);
    assert_int_equal(ev_io_add(l, p.b[0], EV_READ, on_read, &p), 0);
    assert_int_equal(ev_io_add(l, p.b[0], EV_READ, on_read, &p), -22); /* twice: EINVAL */
    assert_int_equal(write(p.a[1], "x", 1), 1);
    assert_int_equal(write(p.b[1], "x", 1), 1);
    assert_int_equal(ev_run(l), 0);
    assert_int_equal(p.a_calls + p.b_calls, 1);
    for (int i = 0; i < 2; i++) {
        close(p.a[i]);
        close(p.b[i]);
    }
    ev_destroy(l);
}

static void test_bad_fds(void **state)
{
    (void)state;
    ev_loop *l = ev_create(8);
    assert_int_equal(ev_io_add(l, -1, EV_READ, on_read, NULL), -22);
    assert_int_equal(ev_io_add(l, 8, EV_READ, on_read, NULL), -22);
    assert_int_equal(ev_io_mod(l, 3, EV_READ), -22);
    assert_int_equal(ev_io_del(l, 3), -22);
    ev_destroy(l);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_periodic_timer),
        cmocka_unit_test(test_one_shot_and_stop),
        cmocka_unit_test(test_delete_inside_callback),
        cmocka_unit_test(test_bad_fds),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
