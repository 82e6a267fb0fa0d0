/*
 * ratelimit.h: token buckets per client address, so that one address cannot
 * spend the server's work (a password check costs 64 MiB and a tenth of a
 * second) faster than a person would. ioquake3 limits challenges the same
 * way, a few per second per address.
 *
 * Addresses hash into a fixed table of buckets (no allocation per address,
 * so a flood of addresses cannot grow it); two addresses that share a
 * bucket share its budget, which errs on the side of refusing.
 */
#ifndef CVRE_RATELIMIT_H
#define CVRE_RATELIMIT_H

#include <stddef.h>
#include <stdint.h>

typedef struct ratelimit ratelimit;

/* A table of `slots` buckets, each holding up to burst tokens and gaining
 * per_second of them a second. NULL when out of memory. */
ratelimit *ratelimit_create(uint32_t slots, double per_second, double burst);
void ratelimit_destroy(ratelimit *r);
/* Takes one token from the bucket of addr (the address without its port);
 * 1 if there was one, 0 if the address is over its rate. now_ns: a
 * monotonic clock. */
int ratelimit_take(ratelimit *r, const char *addr, uint64_t now_ns);
/* Counts per client address (connections open), in a fixed table like the
 * buckets': addresses sharing a slot share a count. */
typedef struct addrcount addrcount;
addrcount *addrcount_create(uint32_t slots);
void addrcount_destroy(addrcount *a);
/* Adds delta (+1 or -1) to addr's count and returns the new count. */
uint32_t addrcount_add(addrcount *a, const char *addr, int delta);

/* The address part of a peer string "1.2.3.4:5678" or "[::1]:5678" into
 * out (outlen bytes). */
void ratelimit_address(const char *peer, char *out, size_t outlen);

#endif
