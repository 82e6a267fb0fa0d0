/*
 * dbInt.h: what the store's own modules (db.c, ecm.c) share beyond db.h.
 * Not for callers of the store.
 */
#ifndef CVRE_DB_INT_H
#define CVRE_DB_INT_H

#include "db.h"

/* Sets the message db_error() returns; returns -1, so that a module can
 * `return db__fail(d, ...)` in the store's error convention. */
int db__fail(db *d, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

#endif
