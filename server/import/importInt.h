/*
 * importInt.h: what the importer's modules (import.c, import_pipe.c,
 * import_proc.c) share beyond import.h. Not for callers of the importer.
 */
#ifndef CVRE_IMPORT_INT_H
#define CVRE_IMPORT_INT_H

#include <stddef.h>

/* Formats a message into err (errlen bytes; nothing if 0) and returns rc.
 * Bytes that are not printable ASCII (from a hint, or file text quoted by
 * Assimp or the helper) become '?', so the message stays one line whatever
 * the upload held. */
int import__fail(char *err, size_t errlen, int rc, const char *fmt, ...) __attribute__((format(printf, 4, 5)));

#endif
