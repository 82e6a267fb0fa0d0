/*
 * alloc.h: the one allocation wrapper; every name starts with cvre_.
 *
 * cvre_malloc, cvre_calloc and cvre_realloc return NULL on failure, for
 * library code that reports out-of-memory to its caller (-ENOMEM). The
 * cvre_x* variants are for the server and client loops, where running out
 * of memory is not recoverable: they log and abort. cvre_alloc_fail_after(n)
 * makes the (n+1)th allocation from now on fail (test hook; -1 turns it off).
 */
#ifndef CVRE_ALLOC_H
#define CVRE_ALLOC_H

#include <stddef.h>

void *cvre_malloc(size_t size);
void *cvre_calloc(size_t n, size_t size);
void *cvre_realloc(void *p, size_t size);
void *cvre_xmalloc(size_t size);
void *cvre_xcalloc(size_t n, size_t size);
void *cvre_xrealloc(void *p, size_t size);
/* A copy of the string s, as cvre_xmalloc. */
char *cvre_xstrdup(const char *s);
void cvre_alloc_fail_after(long n);
/* Keeps freed blocks of up to 64 MiB in the process for the next
 * allocation (glibc: no mmap for them, no trim of the heap), so that a
 * refinement's grids, tables and bit arrays (tens of MiB, allocated and
 * freed per cluster and per retry) do not fault their pages in again each
 * time. For programs that refine (cvre-server, cvre-cluster); call it
 * first thing in main. The process keeps its largest refinement's memory. */
void cvre_alloc_keep_freed(void);

#endif
