#include "auth.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include <sodium.h>

#include "account.h"
#include "alloc.h"
#include "db.h"
#include "log.h"
#include "moderation.h"
#include "worker.h"

struct auth {
    worker *worker; /* auth_job in, auth_result * out */
    db *db;
};

/* 0 if name may join; PROTO_ERR_AUTH with the message if it is banned,
 * PROTO_ERR_INTERNAL if that cannot be told. */
static int check_ban(auth *a, const char *name, auth_result *r)
{
    double until;
    int rc = db_banned(a->db, name, db_now(), &until);

    if (rc == 0)
        return 0;
    if (rc < 0) {
        log_error("ban check of %s: %s", name, db_error(a->db));
        snprintf(r->message, sizeof r->message, "the server could not check the login");
        return r->status = PROTO_ERR_INTERNAL;
    }
    if (until > 0)
        snprintf(r->message, sizeof r->message, "%s is banned for %.0f more minutes", name,
                 (until - db_now()) / 60.0 + 0.5);
    else
        snprintf(r->message, sizeof r->message, "%s is banned", name);
    return r->status = PROTO_ERR_AUTH;
}

/* Settles who an account login is: its name as stored, its users row and
 * its next resume token. */
static void admit_account(auth *a, int64_t account_id, auth_result *r)
{
    db_account acc;
    double now = db_now();

    if (db_account_get(a->db, account_id, &acc) != 0 || !acc.can_log_in) {
        r->status = PROTO_ERR_AUTH;
        snprintf(r->message, sizeof r->message, "login failed: the account is gone");
        return;
    }
    if (check_ban(a, acc.name, r) != 0)
        return;
    snprintf(r->name, sizeof r->name, "%s", acc.name);
    snprintf(r->user, sizeof r->user, "%s", acc.name);
    r->account_id = acc.id;
    r->is_admin = acc.is_admin;
    if (db_user_upsert(a->db, r->user, now, &r->user_id) != 0 ||
        db_account_token_issue(a->db, acc.id, now, now + AUTH_TOKEN_LIFETIME_S, r->token) != 0) {
        log_error("login of %s: %s", acc.name, db_error(a->db));
        r->status = PROTO_ERR_INTERNAL;
        snprintf(r->message, sizeof r->message, "the server could not record the login");
        return;
    }
    r->has_token = 1;
}

/* A guest may use any name no account holds; its users row is its own. */
static void admit_guest(auth *a, const auth_job *job, auth_result *r)
{
    db_account acc;
    int rc = db_account_find(a->db, job->name, &acc);

    if (rc == 0) {
        r->status = PROTO_ERR_AUTH;
        snprintf(r->message, sizeof r->message,
                 "the name \"%s\" belongs to an account: log in with its password", acc.name);
        return;
    }
    if (rc == -ENOENT && check_ban(a, job->name, r) != 0)
        return;
    snprintf(r->name, sizeof r->name, "%s", job->name);
    snprintf(r->user, sizeof r->user, "guest%lld:%s", (long long)job->session, job->name);
    if (rc != -ENOENT || db_user_upsert(a->db, r->user, db_now(), &r->user_id) != 0) {
        log_error("guest join of session %lld: %s", (long long)job->session, db_error(a->db));
        r->status = PROTO_ERR_INTERNAL;
        snprintf(r->message, sizeof r->message, "the server could not record the join");
    }
}

static void *run_job(void *ctx, void *arg)
{
    auth *a = ctx;
    auth_job *job = arg;
    auth_result *r = cvre_xcalloc(1, sizeof *r);
    int64_t id = 0;
    int rc = 0;

    r->session = job->session;
    r->credential = job->credential;
    snprintf(r->name, sizeof r->name, "%s", job->name); /* an account's spelling replaces it */
    if (job->credential == PROTO_CRED_NONE) {
        admit_guest(a, job, r);
        return r;
    }
    if (job->credential == PROTO_CRED_PASSWORD)
        rc = db_account_verify(a->db, job->name, (const char *)job->secret, job->secret_len, &id);
    else
        rc = db_account_token_redeem(a->db, job->secret, db_now(), &id);
    sodium_memzero(job->secret, sizeof job->secret);
    if (rc == 0 && job->credential == PROTO_CRED_TOKEN) {
        db_account acc; /* a token is the account's, whatever name came with it */
        if (db_account_get(a->db, id, &acc) != 0 || strcasecmp(acc.name, job->name) != 0)
            rc = -EACCES;
    }
    if (rc == 0) {
        admit_account(a, id, r);
    } else if (rc == -EACCES) {
        r->status = PROTO_ERR_AUTH;
        snprintf(r->message, sizeof r->message, "login failed: %s",
                 job->credential == PROTO_CRED_PASSWORD ? "wrong name or password"
                                                        : "unknown, used or expired token");
    } else {
        log_error("login of %s: %s", job->name, db_error(a->db));
        r->status = PROTO_ERR_INTERNAL;
        snprintf(r->message, sizeof r->message, "the server could not check the login");
    }
    return r;
}

static void drop_job(void *job) { sodium_memzero(job, sizeof(auth_job)); }

auth *auth_start(const char *db_path, char *err, size_t errlen)
{
    auth *a = cvre_xcalloc(1, sizeof *a);
    worker_ops ops = {.job_size = sizeof(auth_job), .queue_max = AUTH_QUEUE_MAX, .run = run_job, .ctx = a,
                      .drop_job = drop_job};

    if (sodium_init() < 0) {
        snprintf(err, errlen, "libsodium could not start");
        free(a);
        return NULL;
    }
    a->db = db_open(db_path, DB_READWRITE, err, errlen);
    if (!a->db) {
        free(a);
        return NULL;
    }
    a->worker = worker_start(&ops, err, errlen);
    if (!a->worker) {
        db_close(a->db);
        free(a);
        return NULL;
    }
    return a;
}

void auth_stop(auth *a)
{
    if (!a)
        return;
    worker_stop(a->worker);
    db_close(a->db);
    free(a);
}

int auth_fd(const auth *a) { return worker_fd(a->worker); }

int auth_submit(auth *a, auth_job *job)
{
    int rc = worker_submit(a->worker, job);

    sodium_memzero(job->secret, sizeof job->secret);
    return rc;
}

int auth_take(auth *a, auth_result *out)
{
    auth_result *r = worker_take(a->worker);

    if (!r)
        return -EAGAIN;
    *out = *r;
    sodium_memzero(r->token, sizeof r->token);
    free(r);
    return 0;
}
