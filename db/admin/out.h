/*
 * out.h: cvre-admin's result printer. One result set (the rows of one
 * prepared statement) goes out in one of three forms:
 *   - table (default): for people; columns aligned, a header and a rule,
 *     times as ISO-8601 UTC to the millisecond, reals to 3 decimals, NULL as
 *     "-". Columns marked detail_only are left out to keep it readable. A
 *     vertical result (one record) prints as "field  value" lines.
 *   - csv: RFC 4180, a header line, every column; NULL is an empty field.
 *   - json: one JSON array of objects, one object per line, every column;
 *     NULL is null. Times are ISO-8601 strings in UTC to the microsecond.
 * In CSV and JSON, reals are printed with the fewest digits that read back
 * exactly (sb_real), and values stored from 32-bit floats (OUT_FLOAT) with
 * the fewest that read back as the same float (sb_real32: 0.9, not
 * 0.89999997615814209).
 * Table output is held until out_end, to size the columns; the others
 * stream. Out of memory aborts (cvre_xmalloc): this is a command-line tool.
 */
#ifndef CVRE_ADMIN_OUT_H
#define CVRE_ADMIN_OUT_H

#include <sqlite3.h>
#include <stdio.h>

enum out_format { OUT_TABLE, OUT_CSV, OUT_JSON };

enum out_kind {
    OUT_INT,      /* integer */
    OUT_REAL,     /* real number */
    OUT_FLOAT,    /* real number that was a float before it was stored (a
                   * coordinate, a normal, a velocity): %.3f in a table, as
                   * sb_real32 otherwise */
    OUT_TIME,     /* Unix seconds (REAL), printed as ISO-8601 UTC; a TEXT value
                   * (a word such as "never") is printed as text */
    OUT_SECONDS,  /* a duration in seconds: h:mm:ss in a table, a number otherwise */
    OUT_BOOL,     /* 0/1: yes/no in a table, true/false in JSON, 1/0 in CSV */
    OUT_TEXT
};

typedef struct out_column {
    const char *name;
    int kind;        /* enum out_kind */
    int detail_only; /* left out of the table form */
} out_column;

typedef struct out out;

/* out_begin's vertical argument. */
enum out_shape {
    OUT_ROWS = 0,        /* rows: a table, CSV lines, a JSON array */
    OUT_RECORD = 1,      /* a single record: field/value lines in a table */
    OUT_RECORD_BARE = 2  /* as OUT_RECORD, but JSON gets the one object (or null
                          * without a row) instead of an array: a part of a
                          * larger JSON document the caller prints around it */
};

/* Starts a result set with these columns, printed to f. The columns array
 * must outlive the out. vertical: enum out_shape. */
out *out_begin(int format, FILE *f, const out_column *cols, int ncols, int vertical);

/* Adds the current row of st: column i of st is cols[i]. */
void out_row(out *o, sqlite3_stmt *st);

/* Prints what is held, frees o. Returns the number of rows, or -EIO if
 * writing failed (stdout closed, disk full). */
long out_end(out *o);

#endif
