#include "mailbox.h"

#include <errno.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <unistd.h>

#include "alloc.h"
#include "log.h"

typedef struct item {
    void *p;
    struct item *next;
} item;

struct mailbox {
    pthread_mutex_t lock;
    item *head, *tail;
    int efd;
};

mailbox *mailbox_create(void)
{
    mailbox *m = cvre_xcalloc(1, sizeof *m);
    m->efd = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    if (m->efd < 0) {
        free(m);
        return NULL;
    }
    pthread_mutex_init(&m->lock, NULL);
    return m;
}

void mailbox_destroy(mailbox *m, void (*free_item)(void *))
{
    if (!m)
        return;
    void *p;
    while ((p = mailbox_take(m)))
        if (free_item)
            free_item(p);
    pthread_mutex_destroy(&m->lock);
    close(m->efd);
    free(m);
}

int mailbox_fd(const mailbox *m) { return m->efd; }

void mailbox_put(mailbox *m, void *p)
{
    item *it = cvre_xcalloc(1, sizeof *it);
    it->p = p;
    pthread_mutex_lock(&m->lock);
    if (m->tail)
        m->tail->next = it;
    else
        m->head = it;
    m->tail = it;
    pthread_mutex_unlock(&m->lock);
    uint64_t one = 1;
    if (write(m->efd, &one, sizeof one) != (ssize_t)sizeof one)
        log_error("mailbox: cannot wake the loop: %s", strerror(errno));
}

void *mailbox_take(mailbox *m)
{
    uint64_t drained;
    pthread_mutex_lock(&m->lock);
    item *it = m->head;
    if (it) {
        m->head = it->next;
        if (!m->head)
            m->tail = NULL;
    } else if (read(m->efd, &drained, sizeof drained) < 0 && errno != EAGAIN) {
        log_warn("mailbox: eventfd: %s", strerror(errno));
    }
    pthread_mutex_unlock(&m->lock);
    if (!it)
        return NULL;
    void *p = it->p;
    free(it);
    return p;
}
