/*
 * import_text.c: words and numbers read as Assimp's text readers read
 * them, for the pre-checks of the text formats (OBJ, ASCII STL, PLY) and
 * for recognising formats by their first words; and messages that quote
 * such text kept to one printable line. The contracts are in importInt.h.
 */
#include "importInt.h"

#include <string.h>

int import__is_space(unsigned char c)
{
    return c == ' ' || c == '\t' || c == '\r' || c == '\n' || c == '\f' || c == '\v';
}

static unsigned char lower(unsigned char c)
{
    return c >= 'A' && c <= 'Z' ? (unsigned char)(c + 32) : c;
}

int import__starts_with(const unsigned char *p, size_t n, const char *w)
{
    size_t k = strlen(w);

    if (n < k)
        return 0;
    for (size_t i = 0; i < k; i++)
        if (lower(p[i]) != (unsigned char)w[i])
            return 0;
    return 1;
}

/* True if the word w[0..n) is s, case-insensitively. */
static int word_is(const unsigned char *w, size_t n, const char *s)
{
    return strlen(s) == n && import__starts_with(w, n, s);
}

size_t import__find_control(const unsigned char *p, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (p[i] < 0x20 && p[i] != '\t' && p[i] != '\n' && p[i] != '\r')
            return i;
    return n;
}

size_t import__next_word(const unsigned char *p, size_t n, size_t *at, const unsigned char **w)
{
    size_t s;

    while (*at < n && import__is_space(p[*at]))
        (*at)++;
    s = *at;
    while (*at < n && !import__is_space(p[*at]))
        (*at)++;
    *w = p + s;
    return *at - s;
}

int import__kw_is(const unsigned char *w, size_t n, const char *kw)
{
    return strlen(kw) == n && memcmp(w, kw, n) == 0;
}

int import__all_digits(const unsigned char *w, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (w[i] < '0' || w[i] > '9')
            return 0;
    return n > 0;
}

int import__is_number(const unsigned char *w, size_t n)
{
    size_t i = n && (w[0] == '-' || w[0] == '+'), d = 0, dots = 0, e;

    if (word_is(w + i, n - i, "nan") || word_is(w + i, n - i, "inf") ||
        word_is(w + i, n - i, "infinity"))
        return 1;
    for (e = i; e < n && w[e] != 'e' && w[e] != 'E'; e++)
        if (w[e] >= '0' && w[e] <= '9')
            d++;
        else if (w[e] == '.')
            dots++;
        else
            return 0;
    if (d == 0 || dots > 1)
        return 0;
    if (e == n)
        return 1;
    e++;
    if (e < n && (w[e] == '-' || w[e] == '+'))
        e++;
    return import__all_digits(w + e, n - e);
}

void import__printable(char *err, size_t errlen)
{
    if (errlen == 0)
        return;
    for (char *c = err; *c; c++)
        if ((unsigned char)*c < 0x20 || (unsigned char)*c > 0x7e)
            *c = '?';
}
