/* utf8.c: see utf8.h. */
#include "utf8.h"

size_t utf8_next(const uint8_t *s, size_t n, uint32_t *cp)
{
    uint32_t c = s[0];
    uint32_t min;
    size_t len;

    if (c < 0x80u) {
        *cp = c;
        return 1;
    }
    if ((c & 0xe0u) == 0xc0u) {
        len = 2;
        min = 0x80u;
        c &= 0x1fu;
    } else if ((c & 0xf0u) == 0xe0u) {
        len = 3;
        min = 0x800u;
        c &= 0x0fu;
    } else if ((c & 0xf8u) == 0xf0u) {
        len = 4;
        min = 0x10000u;
        c &= 0x07u;
    } else {
        return 0;
    }
    for (size_t i = 1; i < len; i++) {
        if (i >= n || (s[i] & 0xc0u) != 0x80u)
            return 0;
        c = c << 6 | (s[i] & 0x3fu);
    }
    if (c < min || c > 0x10ffffu || (c >= 0xd800u && c <= 0xdfffu))
        return 0;
    *cp = c;
    return len;
}
