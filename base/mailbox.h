/*
 * mailbox.h: hands items from worker threads to the event loop. Any thread
 * puts; the loop watches mailbox_fd (an eventfd, readable while items may
 * be waiting) and takes them in the order they were put.
 */
#ifndef CVRE_MAILBOX_H
#define CVRE_MAILBOX_H

typedef struct mailbox mailbox;

/* NULL with errno set if the eventfd cannot be made. */
mailbox *mailbox_create(void);
/* Frees the items still waiting with free_item (if not NULL), then the box. */
void mailbox_destroy(mailbox *m, void (*free_item)(void *));
int mailbox_fd(const mailbox *m);
/* Appends item (never NULL) and wakes the loop. Aborts if out of memory. */
void mailbox_put(mailbox *m, void *item);
/* The oldest item, or NULL when none is waiting (the fd is then drained). */
void *mailbox_take(mailbox *m);

#endif
