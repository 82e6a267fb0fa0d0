/* json.c: see json.h. */
#include "json.h"

#include <stdint.h>

#include "utf8.h"

void json_put_string(sbuf *b, const char *s, size_t n)
{
    const uint8_t *p = (const uint8_t *)s;
    sb_put(b, "\"", 1);
    for (size_t i = 0; i < n;) {
        uint8_t c = p[i];
        uint32_t cp;
        size_t k = 1;
        if (c == '"' || c == '\\')
            sb_printf(b, "\\%c", c);
        else if (c == '\n')
            sb_puts(b, "\\n");
        else if (c == '\r')
            sb_puts(b, "\\r");
        else if (c == '\t')
            sb_puts(b, "\\t");
        else if (c < 0x20u || c == 0x7fu)
            sb_printf(b, "\\u%04x", c);
        else if ((k = utf8_next(p + i, n - i, &cp)) == 0) {
            sb_puts(b, "\\ufffd");
            k = 1;
        } else
            sb_put(b, s + i, k);
        i += k;
    }
    sb_put(b, "\"", 1);
}
