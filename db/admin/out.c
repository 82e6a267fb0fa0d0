#include "out.h"

#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "json.h"
#include "sbuf.h"
#include "timefmt.h"

/* Longest formatted cell other than text: an ISO time or a %.17g number. */
#define OUT_CELL_MAX 64
_Static_assert(OUT_CELL_MAX >= TIMEFMT_ISO_MAX, "a time fits a cell");
/* Most columns in a result: the widest, collisions, has 21. */
#define OUT_MAX_COLUMNS 64

struct out {
    int format, ncols, vertical;
    FILE *f;
    const out_column *cols;
    long rows;
    /* Table form: cells of the shown columns, row after row. */
    char **cells;
    size_t ncells, cap;
    sbuf line; /* CSV and JSON form: the row being built */
};

out *out_begin(int format, FILE *f, const out_column *cols, int ncols, int vertical)
{
    if (ncols < 1 || ncols > OUT_MAX_COLUMNS)
        abort(); /* a programming error: the column lists are constants */
    out *o = cvre_xcalloc(1, sizeof *o);
    o->format = format;
    o->f = f;
    o->cols = cols;
    o->ncols = ncols;
    o->vertical = vertical;
    if (format == OUT_CSV)
        for (int i = 0; i < ncols; i++)
            fprintf(f, "%s%s", i ? "," : "", cols[i].name); /* names never need quoting */
    if (format == OUT_CSV)
        fputs("\r\n", f);
    if (format == OUT_JSON && vertical != OUT_RECORD_BARE)
        fputc('[', f);
    return o;
}

static void format_duration(char *buf, double s)
{
    long long t = llround(s);
    if (!isfinite(s) || t < 0)
        snprintf(buf, OUT_CELL_MAX, "%.3f", s);
    else
        snprintf(buf, OUT_CELL_MAX, "%lld:%02lld:%02lld", t / 3600, t / 60 % 60, t % 60);
}

/* The table form of one cell, in a new string. Control characters in text
 * become '?', so that a crafted name cannot drive the terminal. */
static char *table_cell(sqlite3_stmt *st, int i, int kind)
{
    char buf[OUT_CELL_MAX];
    if (sqlite3_column_type(st, i) == SQLITE_NULL)
        return strcpy(cvre_xmalloc(2), "-");
    if (kind == OUT_TIME && sqlite3_column_type(st, i) == SQLITE_TEXT)
        kind = OUT_TEXT; /* a word instead of a time: never */
    switch (kind) {
    case OUT_INT: snprintf(buf, sizeof buf, "%lld", (long long)sqlite3_column_int64(st, i)); break;
    case OUT_REAL:
    case OUT_FLOAT: snprintf(buf, sizeof buf, "%.3f", sqlite3_column_double(st, i)); break;
    case OUT_TIME: timefmt_iso(buf, sqlite3_column_double(st, i), 3); break;
    case OUT_SECONDS: format_duration(buf, sqlite3_column_double(st, i)); break;
    case OUT_BOOL: snprintf(buf, sizeof buf, "%s", sqlite3_column_int64(st, i) ? "yes" : "no"); break;
    default: {
        const unsigned char *t = sqlite3_column_text(st, i);
        size_t n = (size_t)sqlite3_column_bytes(st, i);
        char *s = cvre_xmalloc(n + 1);
        for (size_t k = 0; k < n; k++)
            s[k] = t[k] < 0x20 || t[k] == 0x7f ? '?' : (char)t[k];
        s[n] = 0;
        return s;
    }
    }
    return strcpy(cvre_xmalloc(strlen(buf) + 1), buf);
}

/* Text as a CSV field: quoted when it holds a comma, a quote or a line
 * break, quotes doubled. */
static void csv_text(sbuf *b, const char *t, size_t n)
{
    if (!memchr(t, ',', n) && !memchr(t, '"', n) && !memchr(t, '\n', n) && !memchr(t, '\r', n)) {
        sb_put(b, t, n);
        return;
    }
    sb_put(b, "\"", 1);
    for (size_t k = 0; k < n; k++) {
        if (t[k] == '"')
            sb_put(b, "\"", 1);
        sb_put(b, t + k, 1);
    }
    sb_put(b, "\"", 1);
}

/* Appends one cell in CSV or JSON form to b. */
static void stream_cell(const out *o, sbuf *b, sqlite3_stmt *st, int i)
{
    int json = o->format == OUT_JSON, kind = o->cols[i].kind;
    char buf[OUT_CELL_MAX];
    if (sqlite3_column_type(st, i) == SQLITE_NULL) {
        if (json)
            sb_puts(b, "null");
        return;
    }
    if (kind == OUT_TIME && sqlite3_column_type(st, i) == SQLITE_TEXT)
        kind = OUT_TEXT; /* a word instead of a time: never */
    double v = kind == OUT_INT || kind == OUT_BOOL || kind == OUT_TEXT ? 0 : sqlite3_column_double(st, i);
    switch (kind) {
    case OUT_INT: sb_printf(b, "%lld", (long long)sqlite3_column_int64(st, i)); break;
    case OUT_BOOL: sb_puts(b, sqlite3_column_int64(st, i) ? (json ? "true" : "1") : (json ? "false" : "0")); break;
    case OUT_TIME:
        timefmt_iso(buf, v, 6);
        sb_printf(b, json ? "\"%s\"" : "%s", buf);
        break;
    case OUT_REAL:
    case OUT_FLOAT:
    case OUT_SECONDS:
        if (!json && !isfinite(v))
            sb_printf(b, "%g", v); /* CSV says inf or nan; JSON, which has neither, null */
        else if (kind == OUT_FLOAT)
            sb_real32(b, v);
        else
            sb_real(b, v);
        break;
    default: {
        const char *t = (const char *)sqlite3_column_text(st, i);
        size_t n = (size_t)sqlite3_column_bytes(st, i);
        if (json)
            json_put_string(b, t, n);
        else
            csv_text(b, t, n);
    }
    }
}

void out_row(out *o, sqlite3_stmt *st)
{
    if (o->format == OUT_TABLE) {
        for (int i = 0; i < o->ncols; i++) {
            if (o->cols[i].detail_only)
                continue;
            if (o->ncells == o->cap) {
                o->cap = o->cap ? o->cap * 2 : 256;
                o->cells = cvre_xrealloc(o->cells, o->cap * sizeof *o->cells);
            }
            o->cells[o->ncells++] = table_cell(st, i, o->cols[i].kind);
        }
    } else {
        /* The row is built whole, then written in one go. */
        sbuf *b = &o->line;
        sb_clear(b);
        if (o->format == OUT_CSV) {
            for (int i = 0; i < o->ncols; i++) {
                if (i)
                    sb_put(b, ",", 1);
                stream_cell(o, b, st, i);
            }
            sb_puts(b, "\r\n");
        } else {
            if (o->vertical == OUT_RECORD_BARE && o->rows)
                abort(); /* a programming error: a bare record is one row */
            sb_puts(b, o->vertical == OUT_RECORD_BARE ? "{" : o->rows ? ",\n{" : "\n{");
            for (int i = 0; i < o->ncols; i++) {
                sb_printf(b, "%s\"%s\": ", i ? ", " : "", o->cols[i].name); /* names never need escaping */
                stream_cell(o, b, st, i);
            }
            sb_put(b, "}", 1);
        }
        fwrite(b->p, 1, b->len, o->f); /* a failure shows in ferror at out_end */
    }
    o->rows++;
}

/* Characters a terminal shows for s: UTF-8 continuation bytes take none. */
static size_t width(const char *s)
{
    size_t w = 0;
    for (; *s; s++)
        w += ((unsigned char)*s & 0xc0) != 0x80;
    return w;
}

static void pad(FILE *f, size_t n)
{
    while (n--)
        fputc(' ', f);
}

static void print_table(out *o)
{
    int shown[OUT_MAX_COLUMNS], n = 0;
    for (int i = 0; i < o->ncols; i++)
        if (!o->cols[i].detail_only)
            shown[n++] = i;
    if (n == 0)
        return;
    if (o->vertical) {
        size_t w = 0;
        for (int k = 0; k < n; k++)
            if (width(o->cols[shown[k]].name) > w)
                w = width(o->cols[shown[k]].name);
        for (size_t r = 0; r < o->ncells / (size_t)n; r++) {
            if (r)
                fputc('\n', o->f);
            for (int k = 0; k < n; k++) {
                fputs(o->cols[shown[k]].name, o->f);
                pad(o->f, w - width(o->cols[shown[k]].name) + 2);
                fprintf(o->f, "%s\n", o->cells[r * (size_t)n + (size_t)k]);
            }
        }
        return;
    }
    size_t w[OUT_MAX_COLUMNS];
    for (int k = 0; k < n; k++)
        w[k] = width(o->cols[shown[k]].name);
    for (size_t c = 0; c < o->ncells; c++)
        if (width(o->cells[c]) > w[c % (size_t)n])
            w[c % (size_t)n] = width(o->cells[c]);
    for (size_t r = 0; r <= o->ncells / (size_t)n + 1; r++) {
        for (int k = 0; k < n; k++) {
            int kind = o->cols[shown[k]].kind;
            int right = kind == OUT_INT || kind == OUT_REAL || kind == OUT_FLOAT || kind == OUT_SECONDS;
            const char *s = r == 0 ? o->cols[shown[k]].name : NULL;
            if (r == 1) {
                for (size_t i = 0; i < w[k]; i++)
                    fputc('-', o->f);
            } else {
                if (!s)
                    s = o->cells[(r - 2) * (size_t)n + (size_t)k];
                if (right)
                    pad(o->f, w[k] - width(s));
                fputs(s, o->f);
                if (!right && k + 1 < n)
                    pad(o->f, w[k] - width(s));
            }
            if (k + 1 < n)
                fputs("  ", o->f);
        }
        fputc('\n', o->f);
    }
}

long out_end(out *o)
{
    if (o->format == OUT_TABLE)
        print_table(o);
    else if (o->format == OUT_JSON && o->vertical == OUT_RECORD_BARE)
        fputs(o->rows ? "" : "null", o->f);
    else if (o->format == OUT_JSON)
        fputs(o->rows ? "\n]\n" : "]\n", o->f);
    long rows = o->rows;
    FILE *f = o->f;
    for (size_t i = 0; i < o->ncells; i++)
        free(o->cells[i]);
    free(o->cells);
    sb_free(&o->line);
    free(o);
    if (fflush(f) != 0 || ferror(f))
        return -EIO;
    return rows;
}
