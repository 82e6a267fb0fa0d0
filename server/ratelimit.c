#include "ratelimit.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"

typedef struct bucket {
    double tokens;
    uint64_t at_ns; /* when tokens was last brought up to date; 0: never used */
} bucket;

struct ratelimit {
    bucket *b;
    uint32_t slots;
    double per_ns, burst;
};

ratelimit *ratelimit_create(uint32_t slots, double per_second, double burst)
{
    ratelimit *r = cvre_calloc(1, sizeof *r);

    if (!r)
        return NULL;
    r->b = cvre_calloc(slots, sizeof *r->b);
    if (!r->b) {
        free(r);
        return NULL;
    }
    r->slots = slots;
    r->per_ns = per_second * 1e-9;
    r->burst = burst;
    return r;
}

void ratelimit_destroy(ratelimit *r)
{
    if (!r)
        return;
    free(r->b);
    free(r);
}

/* FNV-1a: cheap, and the table is small enough that no address can pick
 * its neighbours' bucket on purpose to any effect but refusing itself. */
static uint32_t hash(const char *s)
{
    uint32_t h = 2166136261u;

    for (; *s; s++)
        h = (h ^ (uint8_t)*s) * 16777619u;
    return h;
}

int ratelimit_take(ratelimit *r, const char *addr, uint64_t now_ns)
{
    bucket *b = &r->b[hash(addr) % r->slots];

    if (b->at_ns == 0 || now_ns < b->at_ns) {
        b->tokens = r->burst;
    } else {
        b->tokens += (double)(now_ns - b->at_ns) * r->per_ns;
        if (b->tokens > r->burst)
            b->tokens = r->burst;
    }
    b->at_ns = now_ns ? now_ns : 1;
    if (b->tokens < 1.0)
        return 0;
    b->tokens -= 1.0;
    return 1;
}

struct addrcount {
    uint32_t *n;
    uint32_t slots;
};

addrcount *addrcount_create(uint32_t slots)
{
    addrcount *a = cvre_calloc(1, sizeof *a);

    if (!a)
        return NULL;
    a->n = cvre_calloc(slots, sizeof *a->n);
    if (!a->n) {
        free(a);
        return NULL;
    }
    a->slots = slots;
    return a;
}

void addrcount_destroy(addrcount *a)
{
    if (!a)
        return;
    free(a->n);
    free(a);
}

uint32_t addrcount_add(addrcount *a, const char *addr, int delta)
{
    uint32_t *n = &a->n[hash(addr) % a->slots];

    if (delta < 0 && *n > 0)
        (*n)--;
    else if (delta > 0)
        (*n)++;
    return *n;
}

void ratelimit_address(const char *peer, char *out, size_t outlen)
{
    const char *colon = strrchr(peer, ':');
    size_t n = colon ? (size_t)(colon - peer) : strlen(peer);

    snprintf(out, outlen, "%.*s", (int)n, peer);
}
