/*
 * account.h: accounts in the store: a name, an Argon2id password hash, an
 * admin flag, and resume tokens that let a client reconnect without its
 * password (schema: db/migrations/0005_accounts.sql; db/README.md).
 *
 * Names: 1..DB_ACCOUNT_NAME_MAX bytes of printable UTF-8 without spaces
 * (db_account_name_check), unique ignoring ASCII case; a lookup by name
 * ignores ASCII case too, and the stored spelling is the account's name (the
 * display name it joins under). "world" (any case) is reserved: the account
 * DB_ACCOUNT_WORLD owns the world file's objects, has no password, cannot log
 * in and cannot be deleted.
 *
 * Passwords are bytes with a length (1..DB_ACCOUNT_PASSWORD_MAX); they are
 * hashed with crypto_pwhash_str (Argon2id, OPSLIMIT/MEMLIMIT_INTERACTIVE:
 * some 64 MiB and 0.1-0.3 s per hash), never stored, logged or put into
 * an error message. The store copies nothing of them; the caller wipes its
 * own buffers (sodium_memzero).
 *
 * Hashing is slow on purpose: db_account_add, db_account_set_password and
 * db_account_verify each take one hash's time and memory. Call them from a
 * thread that may wait (never an event loop), with a db handle of that
 * thread's own, and bound how many run at once. They hash before taking the
 * write lock, so other writers wait only for the insert or update.
 *
 * Functions return 0, or a negative errno with the message in db_error()
 * (db.h). Besides the database's errors they answer: -EINVAL for an invalid
 * argument (name, password, time, a NULL); -ENOENT: no account of that name
 * or id, nothing written; -EEXIST (db_account_add): the name, ignoring ASCII
 * case, is taken, nothing written; -EPERM: the reserved world account
 * (delete, set a password, issue a token), or an account without a
 * password (issue a token), nothing written; -EACCES (db_account_verify,
 * db_account_token_redeem): wrong name or password, or an unknown, used or
 * expired token, one answer for every reason, so that the caller cannot
 * tell a client more than "no" (the message says as little and may be
 * shown to the client). None leaves a transaction of its own open.
 * add, delete, set_password, token_issue and token_redeem take a BEGIN
 * IMMEDIATE transaction of their own and refuse to run inside one (-EINVAL);
 * tokens_expire and tokens_revoke are one statement each and may run inside
 * the caller's. Statements are prepared per call (nothing here is on a hot
 * path).
 */
#ifndef CVRE_ACCOUNT_H
#define CVRE_ACCOUNT_H

#include <stddef.h>
#include <stdint.h>

#include "db.h"

/* Longest name, in bytes: an account's name is its display name, which the
 * wire carries in at most PROTO_NAME_MAX (32) bytes (protocol/proto.h, which
 * db/ does not include). The schema's CHECK says 32 too (0005_accounts.sql):
 * change them together. */
#ifndef DB_ACCOUNT_NAME_MAX
#define DB_ACCOUNT_NAME_MAX 32u
#endif
/* Longest password, in bytes: far beyond any passphrase, small enough that a
 * line read from a terminal or a pipe is bounded. Argon2 takes any length. */
#ifndef DB_ACCOUNT_PASSWORD_MAX
#define DB_ACCOUNT_PASSWORD_MAX 1024u
#endif
/* A resume token: 32 random bytes (randombytes_buf), 256 bits that nobody
 * guesses; the store keeps their 32-byte crypto_generichash only. */
#define DB_ACCOUNT_TOKEN_BYTES 32u
/* Most live tokens per account: one per device a person uses, with room.
 * Issuing one more deletes the oldest, so a client that logs in in a loop
 * cannot grow the table. */
#ifndef DB_ACCOUNT_TOKENS_MAX
#define DB_ACCOUNT_TOKENS_MAX 16
#endif
_Static_assert(DB_ACCOUNT_NAME_MAX == 32u, "the accounts table's CHECK allows 1..32 bytes");
_Static_assert(DB_ACCOUNT_PASSWORD_MAX >= 64u && DB_ACCOUNT_PASSWORD_MAX <= 65536u, "a password line is bounded");
_Static_assert(DB_ACCOUNT_TOKENS_MAX >= 1, "an account that can log in can hold a token");

/* The reserved account's id and name (inserted by migration 0005). */
#define DB_ACCOUNT_WORLD 1
#define DB_ACCOUNT_WORLD_NAME "world"

typedef struct db_account {
    int64_t id;
    char name[DB_ACCOUNT_NAME_MAX + 1]; /* as stored */
    int is_admin;
    int can_log_in;     /* has a password */
    double created_at;
    double password_at; /* when the password was last set; 0: never */
} db_account;

/* Whether name (a C string) is a valid account name, whatever the store
 * holds: 1..DB_ACCOUNT_NAME_MAX bytes of well-formed UTF-8 (shortest form,
 * no surrogates, at most U+10FFFF) with no control character (C0, DEL, C1),
 * no space of any kind (Unicode White_Space), no invisible formatting
 * character (soft hyphen, zero-width and bidirectional controls, BOM) and no
 * noncharacter, and not "world" in any case. Returns 0, or -EINVAL with the
 * reason in why (whylen bytes; it may quote the name's length, never its
 * bytes). Needs no db: the server may check a name before anything else. */
int db_account_name_check(const char *name, char *why, size_t whylen);

/* Adds an account. password: 1..DB_ACCOUNT_PASSWORD_MAX bytes, or NULL for
 * an account that cannot log in. Sets *id (may be NULL). -EINVAL with
 * nothing written on an invalid name or password (checked first); -EEXIST
 * if the name is taken (checked before hashing, and again by the insert);
 * -ENOMEM if hashing failed. */
int db_account_add(db *d, const char *name, const char *password, size_t password_len, int is_admin, double at,
                   int64_t *id);

/* Deletes an account by name, in one transaction: its tokens go with it, and
 * its objects still in the world (those owned, through users.name, by its
 * name) pass to the world account's users row (made if missing), so that a
 * later account of the same name does not inherit them; removed objects keep
 * their owner as history. Sessions, collisions and the users row stay
 * (history). *objects (may be NULL) gets the number of objects handed over.
 * -ENOENT, -EPERM (world). A running server learns of
 * none of this by itself: it must drop the account's connections and read
 * the objects' owners again. */
int db_account_delete(db *d, const char *name, int64_t *objects);

/* The account with this id, or this name (ignoring ASCII case), into *out.
 * -ENOENT if there is none. */
int db_account_get(db *d, int64_t id, db_account *out);
int db_account_find(db *d, const char *name, db_account *out);

/* Calls fn for every account in id order, in one read snapshot; fn must not
 * use d (a statement is active). Stops early and returns fn's value if it is
 * not 0. */
typedef int db_account_fn(void *ctx, const db_account *a);
int db_account_list(db *d, db_account_fn *fn, void *ctx);

/* Sets the password of the account named name (1..DB_ACCOUNT_PASSWORD_MAX
 * bytes) and deletes its tokens: a new password logs every device out.
 * -ENOENT, -EPERM (world), -EINVAL (an invalid password); nothing written
 * on any failure. */
int db_account_set_password(db *d, const char *name, const char *password, size_t password_len, double at);

/* Checks a name (ignoring ASCII case) and password. 0 and *id when they
 * match; -EACCES when the name is unknown, the account cannot log
 * in, or the password is wrong, empty or too long: each of these costs one
 * Argon2id verification with the same parameters (an unknown name is checked
 * against a dummy hash), so the time taken does not tell whether a name
 * exists. Another negative errno on a database or hashing failure. Reads
 * only. */
int db_account_verify(db *d, const char *name, const char *password, size_t password_len, int64_t *id);

/* Issues a resume token for an account that can log in, valid from at until
 * expires_at (> at; the caller picks the lifetime): 32 random bytes into
 * token, of which only the hash is stored. Keeps at most
 * DB_ACCOUNT_TOKENS_MAX tokens for the account (the oldest go).
 * -ENOENT, -EPERM (world, no password). */
int db_account_token_issue(db *d, int64_t account_id, double at, double expires_at,
                           uint8_t token[DB_ACCOUNT_TOKEN_BYTES]);

/* Redeems a token: hashes it, looks the hash up, compares it in constant
 * time, checks that now < expires_at and that the account can still log in,
 * and deletes the token (tokens are used once: issue a new one for the next
 * reconnection); an expired token found is deleted too. 0 and *account_id;
 * -EACCES for an unknown, used or expired token. */
int db_account_token_redeem(db *d, const uint8_t token[DB_ACCOUNT_TOKEN_BYTES], double now, int64_t *account_id);

/* Deletes every token with expires_at <= now (housekeeping; redeeming never
 * accepts them anyway). Returns how many, or a negative errno. */
int db_account_tokens_expire(db *d, double now);

/* Deletes every token of one account (log out everywhere; a ban). Returns
 * how many, or a negative errno. */
int db_account_tokens_revoke(db *d, int64_t account_id);

#endif
