/* ev_epoll.c: the epoll backend of ev.c; the only file that calls epoll_*. */
#include <errno.h>
#include <stdlib.h>
#include <sys/epoll.h>
#include <unistd.h>

#include "alloc.h"
#include "evInt.h"

struct ev__backend {
    int epfd;
    int max;
    struct epoll_event *events;
};

ev__backend *ev__backend_create(int max_events)
{
    ev__backend *b = cvre_calloc(1, sizeof *b);
    if (!b)
        return NULL;
    b->max = max_events;
    b->events = cvre_calloc((size_t)max_events, sizeof *b->events);
    b->epfd = epoll_create1(EPOLL_CLOEXEC);
    if (!b->events || b->epfd < 0) {
        int e = b->epfd < 0 ? errno : ENOMEM;
        ev__backend_destroy(b);
        errno = e;
        return NULL;
    }
    return b;
}

void ev__backend_destroy(ev__backend *b)
{
    if (!b)
        return;
    if (b->epfd >= 0)
        close(b->epfd);
    free(b->events);
    free(b);
}

static uint32_t to_epoll(unsigned events)
{
    return ((events & EV_READ) ? (uint32_t)EPOLLIN | (uint32_t)EPOLLRDHUP : 0u) |
           ((events & EV_WRITE) ? (uint32_t)EPOLLOUT : 0u);
}

static int ctl(ev__backend *b, int op, int fd, unsigned events)
{
    struct epoll_event ee = {.events = to_epoll(events), .data.fd = fd};
    return epoll_ctl(b->epfd, op, fd, &ee) < 0 ? -errno : 0;
}

int ev__backend_add(ev__backend *b, int fd, unsigned events) { return ctl(b, EPOLL_CTL_ADD, fd, events); }

int ev__backend_mod(ev__backend *b, int fd, unsigned events) { return ctl(b, EPOLL_CTL_MOD, fd, events); }

int ev__backend_del(ev__backend *b, int fd) { return ctl(b, EPOLL_CTL_DEL, fd, 0); }

int ev__backend_poll(ev__backend *b, int timeout_ms, ev__ready *out, int max)
{
    if (max > b->max)
        max = b->max;
    int n = epoll_wait(b->epfd, b->events, max, timeout_ms);
    if (n < 0)
        return errno == EINTR ? 0 : -errno;
    for (int i = 0; i < n; i++) {
        uint32_t e = b->events[i].events;
        out[i].fd = b->events[i].data.fd;
        out[i].events = ((e & (EPOLLIN | EPOLLRDHUP)) ? (unsigned)EV_READ : 0u) |
                        ((e & EPOLLOUT) ? (unsigned)EV_WRITE : 0u) |
                        ((e & (EPOLLERR | EPOLLHUP)) ? (unsigned)EV_ERROR : 0u);
    }
    return n;
}
