/*
 * moderate.h: cvre-admin's moderation commands (kick, ban, unban, bans) over
 * db/moderation.h. main.c parses and checks the arguments; these functions
 * do the rest in the order every writing command keeps: check on the
 * read-only handle (whose open checked the schema version), close it, and
 * only then open the file read-write for the one write, never migrating it.
 *
 * The store only records the action; every running server follows the
 * admin_events feed and applies it within a few hundred milliseconds (a
 * kicked or banned session gets bye and is closed), so the commands return
 * before that happens and print what they asked for.
 *
 * Return values are query.h's (0, -ENOENT, -EIO) with
 * a message in err.
 */
#ifndef CVRE_ADMIN_MODERATE_H
#define CVRE_ADMIN_MODERATE_H

#include <stddef.h>
#include <stdint.h>

#include "db.h"

/* Longest ban given with --minutes: 100 years of 365.25 days. A longer one
 * is a ban until unbanned, which says so; the bound keeps now + N minutes
 * a plain calendar date. */
#ifndef MODERATE_MINUTES_MAX
#define MODERATE_MINUTES_MAX 52596000LL
#endif
_Static_assert(MODERATE_MINUTES_MAX >= 1 && MODERATE_MINUTES_MAX <= 100000000LL,
               "a ban's end stays a date out.c prints as ISO-8601");

enum moderate_verb { MODERATE_KICK, MODERATE_BAN, MODERATE_UNBAN, MODERATE_BANS };

typedef struct moderate_request {
    int verb;          /* enum moderate_verb */
    int64_t session;   /* kick */
    const char *name;  /* ban, unban */
    long long minutes; /* ban --minutes; 0: until unbanned */
} moderate_request;

/* The verb a command name names (kick, ban, unban, bans), or -ENOENT. */
int moderate_verb(const char *command);

/* Whether name may be banned: 1 to 32 bytes (the wire's longest name)
 * without control characters. 0, or -EINVAL with the reason in why. Guests may
 * use names that are no account's (spaces, for one), so nothing stricter. */
int moderate_name_check(const char *name, char *why, size_t whylen);

/* Runs r on the database at path, whose read-only handle ro it takes over
 * and closes. bans prints the bans in force. kick checks that the session
 * is open, ban nothing more than main.c did, unban that the name is banned
 * now (-ENOENT otherwise, nothing written); then each writes through
 * db/moderation.h on a read-write handle and prints, in format (out.h), the
 * session it asked servers to close, the ban as it now stands, or the ban
 * it lifted. */
int moderate_run(db *ro, const char *path, const moderate_request *r, int format, char *err, size_t errlen);

#endif
