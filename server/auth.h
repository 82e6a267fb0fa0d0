/*
 * auth.h: who a join is, decided on a worker thread, so that the tick never
 * waits for Argon2id (some 0.1-0.3 s and 64 MiB a password) or the store.
 *
 * The loop submits a join (name and credential); the worker checks the
 * password or redeems the resume token (db/account.h), refuses a guest
 * the name of an account, makes the users row the session's collisions
 * are logged under (an account's name; for a guest one row per session,
 * "guest<session>:<name>", so that one person is one user to clustering),
 * and, for an account, issues the next resume token. Results come back
 * through an eventfd (auth_fd) as the importer's do. Jobs wait at most
 * AUTH_QUEUE_MAX at once, of which the caller lets at most AUTH_LOGINS_MAX
 * carry a credential: a flood of logins is refused, not queued.
 */
#ifndef CVRE_AUTH_H
#define CVRE_AUTH_H

#include <stddef.h>
#include <stdint.h>

#include "proto.h"

/* Joins waiting at once. A guest's costs one small write (the bot swarm
 * joins 1,000 a second); a login one Argon2id verification, one after the
 * other: 32 logins are some 5 s of work, past which a client would rather
 * hear "try again" than wait. */
#define AUTH_QUEUE_MAX 4096u
#define AUTH_LOGINS_MAX 32u
/* How long a resume token lasts: a week of coming back without a password. */
#define AUTH_TOKEN_LIFETIME_S (7.0 * 86400.0)

typedef struct auth auth;

typedef struct auth_job {
    int64_t session;
    char name[PROTO_NAME_MAX + 1];
    uint8_t credential;                   /* enum proto_credential */
    uint8_t secret[PROTO_PASSWORD_MAX];   /* wiped once checked */
    uint32_t secret_len;
} auth_job;

typedef struct auth_result {
    int64_t session;
    uint8_t credential;                   /* the job's: a login, or a guest's join */
    int status;                           /* 0, PROTO_ERR_AUTH or PROTO_ERR_INTERNAL */
    char message[PROTO_MESSAGE_MAX + 1];  /* for the client when status is not 0 */
    char name[PROTO_NAME_MAX + 1];        /* the display name: an account's as stored; the
                                           * name asked for when refused */
    char user[PROTO_NAME_MAX + 32];       /* the users row's name */
    int64_t user_id;
    int64_t account_id;                   /* 0: a guest */
    int is_admin;
    int has_token;
    uint8_t token[PROTO_RESUME_TOKEN_SIZE]; /* the next resume token, for join_ok */
} auth_result;

/* Starts the worker with its own connection to db_path. NULL with a message
 * in err on failure. */
auth *auth_start(const char *db_path, char *err, size_t errlen);
/* Finishes the job in progress, drops the waiting ones, joins the thread. */
void auth_stop(auth *a);
/* The fd to watch for readability: results are waiting. */
int auth_fd(const auth *a);
/* Queues a copy of job (its secret is wiped from *job). 0, or -EBUSY when
 * AUTH_QUEUE_MAX jobs wait. */
int auth_submit(auth *a, auth_job *job);
/* Moves the next result into *out; 0, or -EAGAIN when none. */
int auth_take(auth *a, auth_result *out);

#endif
