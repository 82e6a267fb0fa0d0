/*
 * maintain.h: cvre-admin's maintenance commands, backup and retention, over
 * db/maint.h. main.c parses and checks the arguments; these functions run
 * the command on the database and print what it did.
 *
 * Return values are query.h's (0, -EPERM, -EIO) with
 * a message in err.
 */
#ifndef CVRE_ADMIN_MAINTAIN_H
#define CVRE_ADMIN_MAINTAIN_H

#include <stddef.h>

#include "db.h"

/* retention --older-than takes 1 to this many days (100 years): beyond it
 * there is nothing left to remove, and DAYS * 86400 stays a plain date. */
#define MAINTAIN_DAYS_MAX 36500LL
_Static_assert(MAINTAIN_DAYS_MAX * 86400LL < 10000000000LL, "the cutoff stays a date out.c prints");

enum maintain_verb { MAINTAIN_BACKUP, MAINTAIN_RETENTION };

typedef struct maintain_request {
    int verb;         /* enum maintain_verb */
    const char *file; /* backup: the copy to make */
    int vacuum;       /* backup --vacuum */
    long long days;   /* retention --older-than; 0: not given */
} maintain_request;

/* The verb a command name names (backup, retention), or -ENOENT. */
int maintain_verb(const char *command);

/* The commands' help texts (cvre-admin COMMAND --help). */
extern const char maintain_backup_help[];
extern const char maintain_retention_help[];

/* Runs r on the database at path, whose read-only handle ro (schema
 * version checked) it takes over and closes. backup copies from ro
 * (-EPERM, nothing written, if the file exists); retention closes
 * ro, opens path read-write and removes what is older than r->days days.
 * Each prints its figures as one record in format (out.h). */
int maintain_run(db *ro, const char *path, const maintain_request *r, int format, char *err, size_t errlen);

#endif
