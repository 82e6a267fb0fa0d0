/*
 * user.h: cvre-admin's account commands (user add, del, list, passwd) over
 * db/account.h. main.c parses and checks the arguments; these functions do
 * the rest, in the order that never asks for a password in vain and never
 * writes on a refusal: check on the read-only handle, read the password,
 * then open the file read-write for the one write.
 *
 * Return values are query.h's (0, -ENOENT, -EPERM, -EINVAL, -EIO) with a
 * message in err.
 */
#ifndef CVRE_ADMIN_USER_H
#define CVRE_ADMIN_USER_H

#include <stddef.h>

#include "db.h"

enum user_verb { USER_ADD, USER_DEL, USER_LIST, USER_PASSWD };

typedef struct user_request {
    int verb;               /* enum user_verb */
    const char *name;       /* add, del, passwd */
    int admin;              /* add --admin */
    int password_stdin;     /* add, passwd: one line from standard input, not a terminal prompt */
} user_request;

/* The verb a word names (add, del, list, passwd), or -ENOENT. */
int user_verb(const char *word);

/* Runs r on the database at path, whose read-only handle ro (schema version
 * checked) it takes over and closes. list prints every account; add, passwd
 * and del check on ro (the name is free; the account exists and is not the
 * reserved world), close it, read the password if one is needed, open path
 * read-write, write through db/account.h and print the result in format
 * (out.h). */
int user_run(db *ro, const char *path, const user_request *r, int format, char *err, size_t errlen);

#endif
