/*
 * json.h: the one JSON string escaper, for every program that writes JSON
 * (cvre-client's event lines, cvre-admin's --json output and map figures).
 */
#ifndef CVRE_JSON_H
#define CVRE_JSON_H

#include <stddef.h>

#include "sbuf.h"

/* Appends s[0..n) as a JSON string, quotes included: '"' and '\' escaped,
 * \n \r \t by name, other control characters (and DEL) as \u00XX, and each
 * byte that does not start a well-formed UTF-8 character as U+FFFD, so any
 * bytes give valid JSON. */
void json_put_string(sbuf *b, const char *s, size_t n);

#endif
