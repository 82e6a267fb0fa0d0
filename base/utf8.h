/*
 * utf8.h: one UTF-8 decoder for everything that checks or escapes text
 * (the wire codec's strings, JSON and XML output, names typed by users).
 */
#ifndef CVRE_UTF8_H
#define CVRE_UTF8_H

#include <stddef.h>
#include <stdint.h>

/* Decodes the UTF-8 character at s, of which n > 0 bytes are readable.
 * Returns its length in bytes and stores its code point in *cp, or returns
 * 0 when the bytes there are not one well-formed character (a stray
 * continuation byte, a cut sequence, an overlong form, a surrogate, a value
 * past U+10FFFF). */
size_t utf8_next(const uint8_t *s, size_t n, uint32_t *cp);

#endif
