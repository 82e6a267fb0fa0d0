#include "account.h"

#include <math.h>
#include <pthread.h>
#include <sodium.h>
#include <stdio.h>
#include <string.h>

#include "dbInt.h"

/* crypto_pwhash_str hashes with the library's default algorithm; the store
 * promises Argon2id, so a libsodium that changed its default must not build
 * silently. */
_Static_assert(crypto_pwhash_ALG_DEFAULT == crypto_pwhash_ALG_ARGON2ID13, "crypto_pwhash_str must be Argon2id");
_Static_assert(crypto_generichash_BYTES == DB_ACCOUNT_TOKEN_BYTES, "a token's hash fills the 32-byte column");

#define PWHASH_OPS crypto_pwhash_OPSLIMIT_INTERACTIVE
#define PWHASH_MEM crypto_pwhash_MEMLIMIT_INTERACTIVE

/* ---- libsodium, once ---- */

/* An Argon2id hash at the INTERACTIVE costs of a random password nobody
 * kept: a name that is unknown (or an account without a password) is
 * verified against it, so that it costs what a wrong password costs. If
 * this libsodium's INTERACTIVE costs differ from the ones in the string, a
 * dummy is made at start instead (crypto_ready). Sized as libsodium reads
 * it: a full crypto_pwhash_STRBYTES, zero-padded. */
static const char dummy_const[crypto_pwhash_STRBYTES] =
    "$argon2id$v=19$m=65536,t=2,p=1$Psvxr/YfpUDka0IUGKF4eg$KXz0YAYm+b4Gcjt8QhRu4HXhq6IdKUhohBM9L32772M";

static pthread_once_t crypto_once = PTHREAD_ONCE_INIT;
static int crypto_state = -1; /* 0 once sodium_init and the dummy are ready */
static char dummy_made[crypto_pwhash_STRBYTES];
static const char *dummy_hash = dummy_const;

static void crypto_init(void)
{
    if (sodium_init() < 0)
        return;
    if (crypto_pwhash_str_needs_rehash(dummy_const, PWHASH_OPS, PWHASH_MEM) != 0) {
        unsigned char pw[32];
        randombytes_buf(pw, sizeof pw);
        int rc = crypto_pwhash_str(dummy_made, (const char *)pw, sizeof pw, PWHASH_OPS, PWHASH_MEM);
        sodium_memzero(pw, sizeof pw);
        if (rc != 0)
            return;
        dummy_hash = dummy_made;
    }
    crypto_state = 0;
}

/* sodium_init exactly once, whichever thread comes first (pthread_once
 * makes the others wait for it). */
static int crypto_ready(db *d)
{
    pthread_once(&crypto_once, crypto_init);
    return crypto_state == 0 ? 0 : db__fail(d, "account: libsodium could not be initialized");
}

/* ---- names and passwords ---- */

static int ascii_lower(int c) { return c >= 'A' && c <= 'Z' ? c + ('a' - 'A') : c; }

/* "world" in any ASCII case (locale-independent). */
static int is_world(const char *name)
{
    const char *w = DB_ACCOUNT_WORLD_NAME;
    for (; *w; w++, name++)
        if (ascii_lower((unsigned char)*name) != *w)
            return 0;
    return *name == 0;
}

/* Decodes the UTF-8 sequence at s (n bytes left) into *cp and returns its
 * length, or 0 if it is not well-formed: truncated, a stray continuation
 * byte, longer than the shortest form, a surrogate, beyond U+10FFFF. */
static size_t utf8_decode(const unsigned char *s, size_t n, uint32_t *cp)
{
    static const uint32_t least[5] = {0, 0, 0x80, 0x800, 0x10000};
    size_t len = s[0] < 0x80 ? 1 : s[0] >= 0xc2 && s[0] <= 0xdf ? 2 : s[0] >= 0xe0 && s[0] <= 0xef ? 3
               : s[0] >= 0xf0 && s[0] <= 0xf4 ? 4 : 0;
    if (len == 0 || len > n)
        return 0;
    uint32_t c = len == 1 ? s[0] : s[0] & (0x7fu >> len);
    for (size_t i = 1; i < len; i++) {
        if ((s[i] & 0xc0) != 0x80)
            return 0;
        c = c << 6 | (s[i] & 0x3fu);
    }
    if (c < least[len] || (c >= 0xd800 && c <= 0xdfff) || c > 0x10ffff)
        return 0;
    *cp = c;
    return len;
}

/* What is wrong with code point c in a name, or NULL. */
static const char *bad_code_point(uint32_t c)
{
    if (c < 0x20 || c == 0x7f || (c >= 0x80 && c <= 0x9f))
        return "a control character";
    if (c == 0x20 || c == 0xa0 || c == 0x1680 || (c >= 0x2000 && c <= 0x200a) || c == 0x2028 || c == 0x2029 ||
        c == 0x202f || c == 0x205f || c == 0x3000)
        return "a space";
    if (c == 0xad || c == 0x061c || c == 0x180e || (c >= 0x200b && c <= 0x200f) || (c >= 0x202a && c <= 0x202e) ||
        (c >= 0x2060 && c <= 0x2064) || (c >= 0x2066 && c <= 0x206f) || c == 0xfeff ||
        (c >= 0xfff9 && c <= 0xfffb) || (c >= 0xe0000 && c <= 0xe007f))
        return "an invisible formatting character";
    if ((c >= 0xfdd0 && c <= 0xfdef) || (c & 0xfffe) == 0xfffe)
        return "a noncharacter";
    return NULL;
}

int db_account_name_check(const char *name, char *why, size_t whylen)
{
    size_t n = name ? strnlen(name, DB_ACCOUNT_NAME_MAX + 1) : 0;
    if (n == 0) {
        snprintf(why, whylen, "a name must not be empty");
        return -1;
    }
    if (n > DB_ACCOUNT_NAME_MAX) {
        snprintf(why, whylen, "a name must be at most %u bytes", DB_ACCOUNT_NAME_MAX);
        return -1;
    }
    const unsigned char *s = (const unsigned char *)name;
    for (size_t at = 0; at < n;) {
        uint32_t c;
        size_t k = utf8_decode(s + at, n - at, &c);
        if (k == 0) {
            snprintf(why, whylen, "a name must be UTF-8: byte %zu is not", at);
            return -1;
        }
        const char *bad = bad_code_point(c);
        if (bad) {
            snprintf(why, whylen, "a name must not hold %s: U+%04X at byte %zu", bad, (unsigned)c, at);
            return -1;
        }
        at += k;
    }
    if (is_world(name)) {
        snprintf(why, whylen, "the name \"%s\" is reserved", DB_ACCOUNT_WORLD_NAME);
        return -1;
    }
    return 0;
}

static int password_ok(const char *password, size_t len)
{
    return password && len >= 1 && len <= DB_ACCOUNT_PASSWORD_MAX;
}

/* Hashes a password (one Argon2id run) into out. */
static int hash_password(db *d, const char *password, size_t len, char out[crypto_pwhash_STRBYTES])
{
    if (crypto_ready(d) < 0)
        return -1;
    if (crypto_pwhash_str(out, password, len, PWHASH_OPS, PWHASH_MEM) != 0)
        return db__fail(d, "account: the password could not be hashed (out of memory)");
    return 0;
}

/* ---- statements ---- */

static int sql_fail(db *d) { return db__fail(d, "account: %s", sqlite3_errmsg(db_sqlite(d))); }

static int prepare(db *d, const char *sql, sqlite3_stmt **st)
{
    if (sqlite3_prepare_v2(db_sqlite(d), sql, -1, st, NULL) != SQLITE_OK) {
        *st = NULL;
        return sql_fail(d);
    }
    return 0;
}

/* Steps st once: 1 with a row, 0 when done, -1 on error (with the message). */
static int step(db *d, sqlite3_stmt *st)
{
    int rc = sqlite3_step(st);
    return rc == SQLITE_ROW ? 1 : rc == SQLITE_DONE ? 0 : sql_fail(d);
}

/* Values a one-statement write binds by name: each parameter the SQL
 * names (:id, :at, :hash, :n) gets its value, the others are left out. */
typedef struct params {
    int64_t id;
    double at;
    const uint8_t *hash; /* DB_ACCOUNT_TOKEN_BYTES */
    int64_t n;
} params;

/* Prepares sql, binds p, runs it to the end and finalizes it; returns the
 * rows it changed, or -1. */
static int exec_sql(db *d, const char *sql, const params *p)
{
    sqlite3_stmt *st;
    if (prepare(d, sql, &st) < 0)
        return -1;
    int i;
    if ((i = sqlite3_bind_parameter_index(st, ":id")))
        sqlite3_bind_int64(st, i, p->id);
    if ((i = sqlite3_bind_parameter_index(st, ":at")))
        sqlite3_bind_double(st, i, p->at);
    if ((i = sqlite3_bind_parameter_index(st, ":hash")))
        sqlite3_bind_blob(st, i, p->hash, DB_ACCOUNT_TOKEN_BYTES, SQLITE_STATIC);
    if ((i = sqlite3_bind_parameter_index(st, ":n")))
        sqlite3_bind_int64(st, i, p->n);
    int rc = step(d, st);
    sqlite3_finalize(st);
    return rc < 0 ? -1 : sqlite3_changes(db_sqlite(d));
}

/* The write functions run in a BEGIN IMMEDIATE transaction of their own. */
static int begin_write(db *d)
{
    if (!sqlite3_get_autocommit(db_sqlite(d)))
        return db__fail(d, "account: called inside a transaction (it needs one of its own)");
    return db_begin(d);
}

/* Commits when rc is 0, rolls back otherwise; returns rc, or -1 if the
 * commit failed. */
static int end_write(db *d, int rc)
{
    if (rc == 0 && db_commit(d) < 0)
        rc = -1;
    if (rc != 0)
        db_rollback(d);
    return rc;
}

#define ACCOUNT_COLUMNS "id, name, is_admin, password_hash IS NOT NULL, created_at, coalesce(password_at, 0)"

static void read_account(sqlite3_stmt *st, db_account *a)
{
    *a = (db_account){.id = sqlite3_column_int64(st, 0),
                      .is_admin = sqlite3_column_int(st, 2) != 0,
                      .can_log_in = sqlite3_column_int(st, 3) != 0,
                      .created_at = sqlite3_column_double(st, 4),
                      .password_at = sqlite3_column_double(st, 5)};
    const unsigned char *name = sqlite3_column_text(st, 1);
    size_t n = (size_t)sqlite3_column_bytes(st, 1);
    if (name) {
        /* The schema's CHECK bounds it; cut, never overrun, if it did not. */
        n = n < sizeof a->name ? n : sizeof a->name - 1;
        memcpy(a->name, name, n);
        a->name[n] = 0;
    }
}

/* One account by id (name NULL) or name into *out: 0, DB_ACCOUNT_UNKNOWN or
 * -1. */
static int lookup(db *d, int64_t id, const char *name, db_account *out)
{
    sqlite3_stmt *st;
    if (prepare(d, name ? "SELECT " ACCOUNT_COLUMNS " FROM accounts WHERE name = ?1"
                        : "SELECT " ACCOUNT_COLUMNS " FROM accounts WHERE id = ?1",
                &st) < 0)
        return -1;
    if (name)
        sqlite3_bind_text(st, 1, name, -1, SQLITE_STATIC);
    else
        sqlite3_bind_int64(st, 1, id);
    int r = step(d, st);
    if (r == 1)
        read_account(st, out);
    sqlite3_finalize(st);
    if (r == 0) {
        if (name)
            db__fail(d, "account: no account named \"%s\"", name);
        else
            db__fail(d, "account: no account with id %lld", (long long)id);
        return DB_ACCOUNT_UNKNOWN;
    }
    return r < 0 ? -1 : 0;
}

int db_account_get(db *d, int64_t id, db_account *out) { return lookup(d, id, NULL, out); }

int db_account_find(db *d, const char *name, db_account *out)
{
    if (!name)
        return db__fail(d, "account: no name given");
    return lookup(d, 0, name, out);
}

int db_account_list(db *d, db_account_fn *fn, void *ctx)
{
    sqlite3_stmt *st;
    if (prepare(d, "SELECT " ACCOUNT_COLUMNS " FROM accounts ORDER BY id", &st) < 0)
        return -1;
    int r, rc = 0;
    while ((r = step(d, st)) == 1) {
        db_account a;
        read_account(st, &a);
        rc = fn(ctx, &a);
        if (rc != 0)
            break;
    }
    sqlite3_finalize(st);
    return r < 0 ? -1 : rc;
}

/* ---- adding, deleting, passwords ---- */

int db_account_add(db *d, const char *name, const char *password, size_t password_len, int is_admin, double at,
                   int64_t *id)
{
    char why[128];
    if (db_account_name_check(name, why, sizeof why) < 0)
        return db__fail(d, "account: %s", why);
    if (password && !password_ok(password, password_len))
        return db__fail(d, "account: a password must be 1 to %u bytes", DB_ACCOUNT_PASSWORD_MAX);
    if (!isfinite(at))
        return db__fail(d, "account: the time is not finite");
    db_account old;
    int r = lookup(d, 0, name, &old); /* refuse a taken name before paying for a hash */
    if (r == 0) {
        db__fail(d, "account: the name \"%s\" is taken", old.name);
        return DB_ACCOUNT_EXISTS;
    }
    if (r != DB_ACCOUNT_UNKNOWN)
        return -1;
    char hash[crypto_pwhash_STRBYTES];
    if (password && hash_password(d, password, password_len, hash) < 0)
        return -1;
    sqlite3_stmt *st;
    if (begin_write(d) < 0)
        return -1;
    int rc = prepare(d, "INSERT INTO accounts(name, password_hash, is_admin, created_at, password_at) "
                        "VALUES (?1, ?2, ?3, ?4, ?5)", &st);
    if (rc == 0) {
        sqlite3_bind_text(st, 1, name, -1, SQLITE_STATIC);
        if (password) {
            sqlite3_bind_text(st, 2, hash, -1, SQLITE_STATIC);
            sqlite3_bind_double(st, 5, at);
        }
        sqlite3_bind_int(st, 3, is_admin != 0);
        sqlite3_bind_double(st, 4, at);
        rc = sqlite3_step(st) == SQLITE_DONE ? 0 : -1;
        if (rc < 0 && (sqlite3_extended_errcode(db_sqlite(d)) == SQLITE_CONSTRAINT_UNIQUE)) {
            db__fail(d, "account: the name \"%s\" is taken", name); /* by another writer, since the check */
            rc = DB_ACCOUNT_EXISTS;
        } else if (rc < 0) {
            sql_fail(d);
        }
        sqlite3_finalize(st);
    }
    if (rc == 0 && id)
        *id = sqlite3_last_insert_rowid(db_sqlite(d));
    return end_write(d, rc);
}

/* The account named name, unless it is the world account: 0 and *a,
 * DB_ACCOUNT_UNKNOWN, DB_ACCOUNT_REFUSED or -1. what names the change for
 * the message. */
static int changeable(db *d, const char *name, db_account *a, const char *what)
{
    int r = lookup(d, 0, name, a);
    if (r != 0)
        return r;
    if (a->id == DB_ACCOUNT_WORLD) {
        db__fail(d, "account: the reserved account \"%s\" cannot %s", a->name, what);
        return DB_ACCOUNT_REFUSED;
    }
    return 0;
}

/* The part of db_account_delete inside its transaction. */
static int delete_locked(db *d, const char *name, int64_t *objects)
{
    db_account a;
    int r = changeable(d, name, &a, "be deleted");
    if (r != 0)
        return r;
    /* Owners are users rows (display names); the world file's objects
     * belong to the users row "world", which a server without a world file
     * may never have made. */
    sqlite3_stmt *st;
    if (exec_sql(d, "INSERT INTO users(name, created_at, last_seen_at) VALUES ('" DB_ACCOUNT_WORLD_NAME "', :at, :at) "
                    "ON CONFLICT(name) DO NOTHING", &(params){.at = db_now()}) < 0 ||
        prepare(d, "UPDATE objects SET owner_id = (SELECT id FROM users WHERE name = '" DB_ACCOUNT_WORLD_NAME "') "
                   "WHERE removed_at IS NULL AND owner_id = (SELECT id FROM users WHERE name = ?1)", &st) < 0)
        return -1;
    sqlite3_bind_text(st, 1, a.name, -1, SQLITE_STATIC); /* the stored spelling: owners match exactly */
    r = step(d, st);
    sqlite3_finalize(st);
    if (r < 0)
        return -1;
    if (objects)
        *objects = sqlite3_changes(db_sqlite(d));
    /* Tokens explicitly: the cascade needs foreign_keys on, which only this
     * store's own connections promise. */
    if (exec_sql(d, "DELETE FROM account_tokens WHERE account_id = :id", &(params){.id = a.id}) < 0 ||
        exec_sql(d, "DELETE FROM accounts WHERE id = :id", &(params){.id = a.id}) < 0)
        return -1;
    return 0;
}

int db_account_delete(db *d, const char *name, int64_t *objects)
{
    if (!name)
        return db__fail(d, "account: no name given");
    if (objects)
        *objects = 0;
    if (begin_write(d) < 0)
        return -1;
    int rc = delete_locked(d, name, objects);
    /* running servers end its sessions and hand its objects to the world */
    if (rc == 0)
        rc = db__admin_event(d, "deleted", 0, name, db_now());
    return end_write(d, rc);
}

int db_account_set_password(db *d, const char *name, const char *password, size_t password_len, double at)
{
    if (!name)
        return db__fail(d, "account: no name given");
    if (!password_ok(password, password_len))
        return db__fail(d, "account: a password must be 1 to %u bytes", DB_ACCOUNT_PASSWORD_MAX);
    if (!isfinite(at))
        return db__fail(d, "account: the time is not finite");
    db_account a;
    int rc = changeable(d, name, &a, "have a password"); /* before paying for a hash */
    if (rc != 0)
        return rc;
    char hash[crypto_pwhash_STRBYTES];
    if (hash_password(d, password, password_len, hash) < 0)
        return -1;
    if (begin_write(d) < 0)
        return -1;
    rc = changeable(d, name, &a, "have a password"); /* again, under the lock */
    sqlite3_stmt *st = NULL;
    if (rc == 0)
        rc = prepare(d, "UPDATE accounts SET password_hash = ?2, password_at = ?3 WHERE id = ?1", &st);
    if (rc == 0) {
        sqlite3_bind_int64(st, 1, a.id);
        sqlite3_bind_text(st, 2, hash, -1, SQLITE_STATIC);
        sqlite3_bind_double(st, 3, at);
        rc = step(d, st);
        sqlite3_finalize(st);
    }
    if (rc == 0 && db_account_tokens_revoke(d, a.id) < 0)
        rc = -1;
    if (rc == 0) /* a new password logs every device out, running servers too */
        rc = db__admin_event(d, "logout", 0, a.name, at);
    return end_write(d, rc);
}

/* ---- logging in ---- */

int db_account_verify(db *d, const char *name, const char *password, size_t password_len, int64_t *id)
{
    if (!name || !id)
        return db__fail(d, "account: no name or id given");
    if (crypto_ready(d) < 0)
        return -1;
    sqlite3_stmt *st;
    if (prepare(d, "SELECT id, password_hash FROM accounts WHERE name = ?1 AND password_hash IS NOT NULL", &st) < 0)
        return -1;
    sqlite3_bind_text(st, 1, name, -1, SQLITE_STATIC);
    int r = step(d, st);
    int64_t found = 0;
    char hash[crypto_pwhash_STRBYTES] = "";
    if (r == 1) {
        const unsigned char *h = sqlite3_column_text(st, 1);
        size_t n = (size_t)sqlite3_column_bytes(st, 1);
        if (h && n < sizeof hash) { /* a longer one is no hash of ours: it cannot match */
            memcpy(hash, h, n);
            hash[n] = 0;
            found = sqlite3_column_int64(st, 0);
        }
    }
    sqlite3_finalize(st);
    if (r < 0)
        return -1;
    /* Every path below runs one verification at the same costs: a known
     * name against its hash, anything else against the dummy. */
    int ok = password_ok(password, password_len);
    const char *against = found && ok ? hash : dummy_hash;
    const char *pw = ok ? password : "";
    int match = crypto_pwhash_str_verify(against, pw, ok ? password_len : 0) == 0;
    if (found && ok && match) {
        *id = found;
        return 0;
    }
    db__fail(d, "wrong name or password");
    return DB_ACCOUNT_DENIED;
}

/* ---- resume tokens ---- */

int db_account_token_issue(db *d, int64_t account_id, double at, double expires_at,
                           uint8_t token[DB_ACCOUNT_TOKEN_BYTES])
{
    if (!token)
        return db__fail(d, "account: no token buffer given");
    if (!isfinite(at) || !isfinite(expires_at) || expires_at <= at)
        return db__fail(d, "account: a token must expire after it is issued");
    if (crypto_ready(d) < 0 || begin_write(d) < 0)
        return -1;
    db_account a;
    int rc = lookup(d, account_id, NULL, &a);
    if (rc == 0 && (a.id == DB_ACCOUNT_WORLD || !a.can_log_in)) {
        db__fail(d, "account: \"%s\" cannot log in, so it gets no token", a.name);
        rc = DB_ACCOUNT_REFUSED;
    }
    uint8_t hash[crypto_generichash_BYTES];
    sqlite3_stmt *st = NULL;
    if (rc == 0)
        rc = prepare(d, "INSERT INTO account_tokens(hash, account_id, created_at, expires_at) VALUES (?1, ?2, ?3, ?4)",
                     &st);
    if (rc == 0) {
        randombytes_buf(token, DB_ACCOUNT_TOKEN_BYTES);
        crypto_generichash(hash, sizeof hash, token, DB_ACCOUNT_TOKEN_BYTES, NULL, 0);
        sqlite3_bind_blob(st, 1, hash, (int)sizeof hash, SQLITE_STATIC);
        sqlite3_bind_int64(st, 2, account_id);
        sqlite3_bind_double(st, 3, at);
        sqlite3_bind_double(st, 4, expires_at);
        rc = step(d, st);
        sqlite3_finalize(st);
    }
    /* Keep this one and the newest DB_ACCOUNT_TOKENS_MAX - 1 others. */
    if (rc == 0 && exec_sql(d,
                            "DELETE FROM account_tokens WHERE account_id = :id AND hash != :hash AND hash NOT IN "
                            "(SELECT hash FROM account_tokens WHERE account_id = :id AND hash != :hash "
                            "ORDER BY created_at DESC, hash LIMIT :n)",
                            &(params){.id = account_id, .hash = hash, .n = DB_ACCOUNT_TOKENS_MAX - 1}) < 0)
        rc = -1;
    rc = end_write(d, rc);
    if (rc != 0)
        sodium_memzero(token, DB_ACCOUNT_TOKEN_BYTES); /* a token that was not stored is no token */
    return rc;
}

/* The part of db_account_token_redeem inside its transaction. */
static int redeem_locked(db *d, const uint8_t hash[DB_ACCOUNT_TOKEN_BYTES], double now, int64_t *account_id)
{
    sqlite3_stmt *st;
    if (prepare(d, "SELECT t.hash, t.account_id, t.expires_at, a.password_hash IS NOT NULL FROM account_tokens t "
                   "JOIN accounts a ON a.id = t.account_id WHERE t.hash = ?1", &st) < 0)
        return -1;
    sqlite3_bind_blob(st, 1, hash, DB_ACCOUNT_TOKEN_BYTES, SQLITE_STATIC);
    int r = step(d, st);
    int match = 0, live = 0;
    int64_t id = 0;
    if (r == 1) {
        const void *stored = sqlite3_column_blob(st, 0);
        match = stored && sqlite3_column_bytes(st, 0) == DB_ACCOUNT_TOKEN_BYTES &&
                sodium_memcmp(stored, hash, DB_ACCOUNT_TOKEN_BYTES) == 0;
        id = sqlite3_column_int64(st, 1);
        live = now < sqlite3_column_double(st, 2) && sqlite3_column_int(st, 3);
    }
    sqlite3_finalize(st);
    if (r < 0)
        return -1;
    if (match && exec_sql(d, "DELETE FROM account_tokens WHERE hash = :hash", &(params){.hash = hash}) < 0)
        return -1;
    if (!match || !live) {
        db__fail(d, "unknown or expired token");
        return DB_ACCOUNT_DENIED;
    }
    *account_id = id;
    return 0;
}

int db_account_token_redeem(db *d, const uint8_t token[DB_ACCOUNT_TOKEN_BYTES], double now, int64_t *account_id)
{
    if (!token || !account_id)
        return db__fail(d, "account: no token given");
    if (!isfinite(now))
        return db__fail(d, "account: the time is not finite");
    if (crypto_ready(d) < 0)
        return -1;
    uint8_t hash[crypto_generichash_BYTES];
    crypto_generichash(hash, sizeof hash, token, DB_ACCOUNT_TOKEN_BYTES, NULL, 0);
    if (begin_write(d) < 0)
        return -1;
    int rc = redeem_locked(d, hash, now, account_id);
    /* A denial still commits: the expired token it found is gone. */
    return end_write(d, rc == DB_ACCOUNT_DENIED ? 0 : rc) == 0 ? rc : -1;
}

int db_account_tokens_expire(db *d, double now)
{
    if (!isfinite(now))
        return db__fail(d, "account: the time is not finite");
    return exec_sql(d, "DELETE FROM account_tokens WHERE expires_at <= :at", &(params){.at = now});
}

int db_account_tokens_revoke(db *d, int64_t account_id)
{
    return exec_sql(d, "DELETE FROM account_tokens WHERE account_id = :id", &(params){.id = account_id});
}
