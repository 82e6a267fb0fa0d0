/*
 * le.h: little-endian loads and stores, byte by byte, so that no packed
 * struct is ever cast onto a buffer from a peer or a file. Everything that
 * reads or writes such bytes (the wire codec, the model pre-checks, the
 * importer's pipe, the tools' point files) uses these.
 */
#ifndef CVRE_LE_H
#define CVRE_LE_H

#include <stdint.h>
#include <string.h>

static inline uint16_t le_get_u16(const uint8_t *p) { return (uint16_t)(p[0] | p[1] << 8); }

static inline uint32_t le_get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static inline uint64_t le_get_u64(const uint8_t *p)
{
    return (uint64_t)le_get_u32(p) | (uint64_t)le_get_u32(p + 4) << 32;
}

static inline float le_get_f32(const uint8_t *p)
{
    uint32_t u = le_get_u32(p);
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

static inline void le_put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
}

static inline void le_put_u32(uint8_t *p, uint32_t v)
{
    for (int i = 0; i < 4; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}

static inline void le_put_u64(uint8_t *p, uint64_t v)
{
    le_put_u32(p, (uint32_t)v);
    le_put_u32(p + 4, (uint32_t)(v >> 32));
}

static inline void le_put_f32(uint8_t *p, float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    le_put_u32(p, u);
}

#endif
