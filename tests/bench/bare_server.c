/*
 * bare_server: the benchmark's baseline. A bare epoll server that accepts
 * connections, reads, and counts length-prefixed frames, and nothing else.
 * bench_sessions.py drives it with the same bot swarm as cvre-server and
 * compares CPU per inbound message. It calls epoll directly on purpose: it
 * is the floor that cvre's own loop is measured against.
 *
 * usage: bare_server  (prints "listening on 127.0.0.1:PORT"; on SIGTERM
 * prints {"frames":N,"bytes":N} and exits)
 */
#define _GNU_SOURCE /* accept4 */
#include <errno.h>
#include <netinet/in.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <unistd.h>

#define MAX_FD 70000
#define BUF 4096

typedef struct peer {
    uint8_t buf[BUF];
    size_t len;
} peer;

static volatile sig_atomic_t stop;

static void on_signal(int sig)
{
    (void)sig;
    stop = 1;
}

int main(void)
{
    struct rlimit rl;
    if (getrlimit(RLIMIT_NOFILE, &rl) == 0) {
        rl.rlim_cur = rl.rlim_max;
        setrlimit(RLIMIT_NOFILE, &rl);
    }
    struct sigaction sa = {.sa_handler = on_signal};
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    int lfd = socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK, 0);
    struct sockaddr_in addr = {.sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    socklen_t alen = sizeof addr;
    if (lfd < 0 || bind(lfd, (struct sockaddr *)&addr, sizeof addr) < 0 || listen(lfd, 4096) < 0 ||
        getsockname(lfd, (struct sockaddr *)&addr, &alen) < 0) {
        perror("bare_server");
        return 1;
    }
    printf("listening on 127.0.0.1:%u\n", ntohs(addr.sin_port));
    fflush(stdout);
    int ep = epoll_create1(0);
    struct epoll_event ev = {.events = EPOLLIN, .data.fd = lfd}, ready[1024];
    epoll_ctl(ep, EPOLL_CTL_ADD, lfd, &ev);
    peer **peers = calloc(MAX_FD, sizeof *peers);
    uint64_t frames = 0, bytes = 0;
    while (!stop) {
        int n = epoll_wait(ep, ready, 1024, 100);
        for (int i = 0; i < n; i++) {
            int fd = ready[i].data.fd;
            if (fd == lfd) {
                int c;
                while ((c = accept4(lfd, NULL, NULL, SOCK_NONBLOCK)) >= 0) {
                    if (c >= MAX_FD) {
                        close(c);
                        continue;
                    }
                    peers[c] = calloc(1, sizeof(peer));
                    ev.events = EPOLLIN;
                    ev.data.fd = c;
                    epoll_ctl(ep, EPOLL_CTL_ADD, c, &ev);
                }
                continue;
            }
            peer *p = peers[fd];
            ssize_t r = read(fd, p->buf + p->len, BUF - p->len);
            if (r <= 0) {
                if (r < 0 && errno == EAGAIN)
                    continue;
                close(fd);
                free(p);
                peers[fd] = NULL;
                continue;
            }
            bytes += (uint64_t)r;
            p->len += (size_t)r;
            size_t off = 0;
            while (p->len - off >= 4) {
                uint32_t len = (uint32_t)p->buf[off] | (uint32_t)p->buf[off + 1] << 8 |
                               (uint32_t)p->buf[off + 2] << 16 | (uint32_t)p->buf[off + 3] << 24;
                if (len > BUF - 4) { /* not our traffic: drop the peer */
                    p->len = off = 0;
                    break;
                }
                if (p->len - off < 4 + (size_t)len)
                    break;
                off += 4 + len;
                frames++;
            }
            memmove(p->buf, p->buf + off, p->len - off);
            p->len -= off;
        }
    }
    printf("{\"frames\":%llu,\"bytes\":%llu}\n", (unsigned long long)frames, (unsigned long long)bytes);
    return 0;
}
