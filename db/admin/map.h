/*
 * map.h: `cvre-admin map`, pictures of collision maps and their figures.
 *
 * One object (a version of its collision map) or the whole world (every
 * object in it at its version in force) is drawn as one SVG 1.1 file with
 * two views side by side, TOP (world x right, z down the page) and SIDE
 * (world x right, y up), in world coordinates: the geometry's outline, the
 * original boxes (version 1), the boxes of the version shown, and the
 * collision points coloured by DBSCAN cluster. The figures that tell how
 * tight a map is (box and union volumes, the geometry's volume from a 2^7
 * digitization of the object's MBR, points, clusters) print as JSON or as a
 * table. Everything is read in one read transaction; the same database
 * always gives a byte-identical picture.
 */
#ifndef CVRE_ADMIN_MAP_H
#define CVRE_ADMIN_MAP_H

#include <stddef.h>
#include <stdint.h>

#include "db.h"

typedef struct map_request {
    int has_object;   /* 0: the whole world */
    int64_t object;
    uint32_t version; /* with has_object: the version drawn; 0: the one in force */
    const char *svg;  /* the picture's path; NULL: no picture */
    int json;         /* figures as JSON (else a table) on stdout */
} map_request;

/* Reads what r asks for from d (read-only), writes the picture (whole,
 * replacing the file) and prints the figures. Returns 0, -ENOENT (no such
 * object, the object was removed, no such version) or -EIO (a failed
 * query, a stored value that does not add up, the picture or the output
 * could not be written), with a message in err (query.h's results). */
int map_run(db *d, const map_request *r, char *err, size_t errlen);

#endif
