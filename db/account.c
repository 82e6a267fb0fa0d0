#include "account.h"

#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <sodium.h>
#include <string.h>

#include "dbInt.h"
#include "err.h"

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
    return crypto_state == 0 ? 0 : db__fail(d, -EIO, "account: libsodium could not be initialized");
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
    if (n == 0)
        return cvre_fail(why, whylen, -EINVAL, "a name must not be empty");
    if (n > DB_ACCOUNT_NAME_MAX)
        return cvre_fail(why, whylen, -EINVAL, "a name must be at most %u bytes", DB_ACCOUNT_NAME_MAX);
    const unsigned char *s = (const unsigned char *)name;
    for (size_t at = 0; at < n;) {
        uint32_t c;
        size_t k = utf8_decode(s + at, n - at, &c);
        if (k == 0)
            return cvre_fail(why, whylen, -EINVAL, "a name must be UTF-8: byte %zu is not", at);
        const char *bad = bad_code_point(c);
        if (bad)
            return cvre_fail(why, whylen, -EINVAL, "a name must not hold %s: U+%04X at byte %zu", bad, (unsigned)c,
                             at);
        at += k;
    }
    if (is_world(name))
        return cvre_fail(why, whylen, -EINVAL, "the name \"%s\" is reserved", DB_ACCOUNT_WORLD_NAME);
    return 0;
}

static int password_ok(const char *password, size_t len)
{
    return password && len >= 1 && len <= DB_ACCOUNT_PASSWORD_MAX;
}

/* Hashes a password (one Argon2id run) into out. */
static int hash_password(db *d, const char *password, size_t len, char out[crypto_pwhash_STRBYTES])
{
    int rc = crypto_ready(d);
    if (rc < 0)
        return rc;
    if (crypto_pwhash_str(out, password, len, PWHASH_OPS, PWHASH_MEM) != 0)
        return db__fail(d, -ENOMEM, "account: the password could not be hashed (out of memory)");
    return 0;
}

/* ---- statements ---- */

static int prepare(db *d, const char *sql, sqlite3_stmt **st)
{
    if (sqlite3_prepare_v2(db_sqlite(d), sql, -1, st, NULL) != SQLITE_OK) {
        *st = NULL;
        return db__sql_fail(d, "account");
    }
    return 0;
}

/* Steps st once: 1 with a row, 0 when done, a negative errno on error
 * (with the message). */
static int step(db *d, sqlite3_stmt *st)
{
    int rc = sqlite3_step(st);
    return rc == SQLITE_ROW ? 1 : rc == SQLITE_DONE ? 0 : db__sql_fail(d, "account");
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
 * rows it changed, or a negative errno. */
static int exec_sql(db *d, const char *sql, const params *p)
{
    sqlite3_stmt *st;
    int rc = prepare(d, sql, &st);
    if (rc < 0)
        return rc;
    int i;
    if ((i = sqlite3_bind_parameter_index(st, ":id")))
        sqlite3_bind_int64(st, i, p->id);
    if ((i = sqlite3_bind_parameter_index(st, ":at")))
        sqlite3_bind_double(st, i, p->at);
    if ((i = sqlite3_bind_parameter_index(st, ":hash")))
        sqlite3_bind_blob(st, i, p->hash, DB_ACCOUNT_TOKEN_BYTES, SQLITE_STATIC);
    if ((i = sqlite3_bind_parameter_index(st, ":n")))
        sqlite3_bind_int64(st, i, p->n);
    rc = step(d, st);
    sqlite3_finalize(st);
    return rc < 0 ? rc : sqlite3_changes(db_sqlite(d));
}

/* The write functions run in a BEGIN IMMEDIATE transaction of their own. */
static int begin_write(db *d)
{
    if (!sqlite3_get_autocommit(db_sqlite(d)))
        return db__fail(d, -EINVAL, "account: called inside a transaction (it needs one of its own)");
    return db_begin(d);
}

/* Commits when rc is 0, rolls back otherwise; returns rc, or the commit's
 * error. */
static int end_write(db *d, int rc)
{
    if (rc == 0)
        rc = db_commit(d);
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

/* One account by id (name NULL) or name into *out: 0, -ENOENT or another
 * negative errno. */
static int lookup(db *d, int64_t id, const char *name, db_account *out)
{
    sqlite3_stmt *st;
    int r = prepare(d, name ? "SELECT " ACCOUNT_COLUMNS " FROM accounts WHERE name = ?1"
                            : "SELECT " ACCOUNT_COLUMNS " FROM accounts WHERE id = ?1",
                    &st);
    if (r < 0)
        return r;
    if (name)
        sqlite3_bind_text(st, 1, name, -1, SQLITE_STATIC);
    else
        sqlite3_bind_int64(st, 1, id);
    r = step(d, st);
    if (r == 1)
        read_account(st, out);
    sqlite3_finalize(st);
    if (r == 0)
        return name ? db__fail(d, -ENOENT, "account: no account named \"%s\"", name)
                    : db__fail(d, -ENOENT, "account: no account with id %lld", (long long)id);
    return r < 0 ? r : 0;
}

int db_account_get(db *d, int64_t id, db_account *out) { return lookup(d, id, NULL, out); }

int db_account_find(db *d, const char *name, db_account *out)
{
    if (!name)
        return db__fail(d, -EINVAL, "account: no name given");
    return lookup(d, 0, name, out);
}

int db_account_list(db *d, db_account_fn *fn, void *ctx)
{
    sqlite3_stmt *st;
    int r, rc = prepare(d, "SELECT " ACCOUNT_COLUMNS " FROM accounts ORDER BY id", &st);
    if (rc < 0)
        return rc;
    while ((r = step(d, st)) == 1) {
        db_account a;
        read_account(st, &a);
        rc = fn(ctx, &a);
        if (rc != 0)
            break;
    }
    sqlite3_finalize(st);
    return r < 0 ? r : rc;
}

/* ---- adding, deleting, passwords ---- */

int db_account_add(db *d, const char *name, const char *password, size_t password_len, int is_admin, double at,
                   int64_t *id)
{
    char why[128];
    int rc = db_account_name_check(name, why, sizeof why);
    if (rc < 0)
        return db__fail(d, rc, "account: %s", why);
    if (password && !password_ok(password, password_len))
        return db__fail(d, -EINVAL, "account: a password must be 1 to %u bytes", DB_ACCOUNT_PASSWORD_MAX);
    if (!isfinite(at))
        return db__fail(d, -EINVAL, "account: the time is not finite");
    db_account old;
    rc = lookup(d, 0, name, &old); /* refuse a taken name before paying for a hash */
    if (rc == 0)
        return db__fail(d, -EEXIST, "account: the name \"%s\" is taken", old.name);
    if (rc != -ENOENT)
        return rc;
    char hash[crypto_pwhash_STRBYTES];
    if (password && (rc = hash_password(d, password, password_len, hash)) < 0)
        return rc;
    sqlite3_stmt *st;
    if ((rc = begin_write(d)) < 0)
        return rc;
    rc = prepare(d, "INSERT INTO accounts(name, password_hash, is_admin, created_at, password_at) "
                        "VALUES (?1, ?2, ?3, ?4, ?5)", &st);
    if (rc == 0) {
        sqlite3_bind_text(st, 1, name, -1, SQLITE_STATIC);
        if (password) {
            sqlite3_bind_text(st, 2, hash, -1, SQLITE_STATIC);
            sqlite3_bind_double(st, 5, at);
        }
        sqlite3_bind_int(st, 3, is_admin != 0);
        sqlite3_bind_double(st, 4, at);
        rc = step(d, st);
        if (rc == -EEXIST) /* the unique name: taken by another writer since the check */
            db__fail(d, rc, "account: the name \"%s\" is taken", name);
        sqlite3_finalize(st);
    }
    if (rc == 0 && id)
        *id = sqlite3_last_insert_rowid(db_sqlite(d));
    return end_write(d, rc);
}

/* The account named name, unless it is the world account: 0 and *a,
 * -ENOENT, -EPERM or another negative errno. what names the change for the
 * message. */
static int changeable(db *d, const char *name, db_account *a, const char *what)
{
    int r = lookup(d, 0, name, a);
    if (r != 0)
        return r;
    if (a->id == DB_ACCOUNT_WORLD)
        return db__fail(d, -EPERM, "account: the reserved account \"%s\" cannot %s", a->name, what);
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
    if ((r = exec_sql(d, "INSERT INTO users(name, created_at, last_seen_at) VALUES ('" DB_ACCOUNT_WORLD_NAME
                         "', :at, :at) ON CONFLICT(name) DO NOTHING", &(params){.at = db_now()})) < 0 ||
        (r = prepare(d, "UPDATE objects SET owner_id = (SELECT id FROM users WHERE name = '" DB_ACCOUNT_WORLD_NAME
                        "') WHERE removed_at IS NULL AND owner_id = (SELECT id FROM users WHERE name = ?1)", &st)) < 0)
        return r;
    sqlite3_bind_text(st, 1, a.name, -1, SQLITE_STATIC); /* the stored spelling: owners match exactly */
    r = step(d, st);
    sqlite3_finalize(st);
    if (r < 0)
        return r;
    if (objects)
        *objects = sqlite3_changes(db_sqlite(d));
    /* Tokens explicitly: the cascade needs foreign_keys on, which only this
     * store's own connections promise. */
    if ((r = exec_sql(d, "DELETE FROM account_tokens WHERE account_id = :id", &(params){.id = a.id})) < 0 ||
        (r = exec_sql(d, "DELETE FROM accounts WHERE id = :id", &(params){.id = a.id})) < 0)
        return r;
    return 0;
}

int db_account_delete(db *d, const char *name, int64_t *objects)
{
    if (!name)
        return db__fail(d, -EINVAL, "account: no name given");
    if (objects)
        *objects = 0;
    int rc = begin_write(d);
    if (rc < 0)
        return rc;
    rc = delete_locked(d, name, objects);
    /* running servers end its sessions and hand its objects to the world */
    if (rc == 0)
        rc = db__admin_event(d, "deleted", 0, name, db_now());
    return end_write(d, rc);
}

int db_account_set_password(db *d, const char *name, const char *password, size_t password_len, double at)
{
    if (!name)
        return db__fail(d, -EINVAL, "account: no name given");
    if (!password_ok(password, password_len))
        return db__fail(d, -EINVAL, "account: a password must be 1 to %u bytes", DB_ACCOUNT_PASSWORD_MAX);
    if (!isfinite(at))
        return db__fail(d, -EINVAL, "account: the time is not finite");
    db_account a;
    int rc = changeable(d, name, &a, "have a password"); /* before paying for a hash */
    if (rc != 0)
        return rc;
    char hash[crypto_pwhash_STRBYTES];
    if ((rc = hash_password(d, password, password_len, hash)) < 0 || (rc = begin_write(d)) < 0)
        return rc;
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
    if (rc == 0 && (rc = db_account_tokens_revoke(d, a.id)) > 0)
        rc = 0; /* how many went */
    if (rc == 0) /* a new password logs every device out, running servers too */
        rc = db__admin_event(d, "logout", 0, a.name, at);
    return end_write(d, rc);
}

/* ---- logging in ---- */

int db_account_verify(db *d, const char *name, const char *password, size_t password_len, int64_t *id)
{
    if (!name || !id)
        return db__fail(d, -EINVAL, "account: no name or id given");
    sqlite3_stmt *st;
    int r = crypto_ready(d);
    if (r < 0 || (r = prepare(d, "SELECT id, password_hash FROM accounts WHERE name = ?1 AND password_hash IS NOT NULL",
                              &st)) < 0)
        return r;
    sqlite3_bind_text(st, 1, name, -1, SQLITE_STATIC);
    r = step(d, st);
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
        return r;
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
    return db__fail(d, -EACCES, "wrong name or password");
}

/* ---- resume tokens ---- */

int db_account_token_issue(db *d, int64_t account_id, double at, double expires_at,
                           uint8_t token[DB_ACCOUNT_TOKEN_BYTES])
{
    if (!token)
        return db__fail(d, -EINVAL, "account: no token buffer given");
    if (!isfinite(at) || !isfinite(expires_at) || expires_at <= at)
        return db__fail(d, -EINVAL, "account: a token must expire after it is issued");
    int rc;
    if ((rc = crypto_ready(d)) < 0 || (rc = begin_write(d)) < 0)
        return rc;
    db_account a;
    rc = lookup(d, account_id, NULL, &a);
    if (rc == 0 && (a.id == DB_ACCOUNT_WORLD || !a.can_log_in))
        rc = db__fail(d, -EPERM, "account: \"%s\" cannot log in, so it gets no token", a.name);
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
    if (rc == 0 && (rc = exec_sql(d,
                                  "DELETE FROM account_tokens WHERE account_id = :id AND hash != :hash AND hash NOT IN "
                                  "(SELECT hash FROM account_tokens WHERE account_id = :id AND hash != :hash "
                                  "ORDER BY created_at DESC, hash LIMIT :n)",
                                  &(params){.id = account_id, .hash = hash, .n = DB_ACCOUNT_TOKENS_MAX - 1})) > 0)
        rc = 0; /* how many went */
    rc = end_write(d, rc);
    if (rc != 0)
        sodium_memzero(token, DB_ACCOUNT_TOKEN_BYTES); /* a token that was not stored is no token */
    return rc;
}

/* The part of db_account_token_redeem inside its transaction. */
static int redeem_locked(db *d, const uint8_t hash[DB_ACCOUNT_TOKEN_BYTES], double now, int64_t *account_id)
{
    sqlite3_stmt *st;
    int r = prepare(d, "SELECT t.hash, t.account_id, t.expires_at, a.password_hash IS NOT NULL FROM account_tokens t "
                       "JOIN accounts a ON a.id = t.account_id WHERE t.hash = ?1", &st);
    if (r < 0)
        return r;
    sqlite3_bind_blob(st, 1, hash, DB_ACCOUNT_TOKEN_BYTES, SQLITE_STATIC);
    r = step(d, st);
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
        return r;
    if (match && (r = exec_sql(d, "DELETE FROM account_tokens WHERE hash = :hash", &(params){.hash = hash})) < 0)
        return r;
    if (!match || !live)
        return db__fail(d, -EACCES, "unknown or expired token");
    *account_id = id;
    return 0;
}

int db_account_token_redeem(db *d, const uint8_t token[DB_ACCOUNT_TOKEN_BYTES], double now, int64_t *account_id)
{
    if (!token || !account_id)
        return db__fail(d, -EINVAL, "account: no token given");
    if (!isfinite(now))
        return db__fail(d, -EINVAL, "account: the time is not finite");
    int rc = crypto_ready(d);
    if (rc < 0)
        return rc;
    uint8_t hash[crypto_generichash_BYTES];
    crypto_generichash(hash, sizeof hash, token, DB_ACCOUNT_TOKEN_BYTES, NULL, 0);
    if ((rc = begin_write(d)) < 0)
        return rc;
    rc = redeem_locked(d, hash, now, account_id);
    /* A denial still commits: the expired token it found is gone. */
    int end = end_write(d, rc == -EACCES ? 0 : rc);
    return end == 0 ? rc : end;
}

int db_account_tokens_expire(db *d, double now)
{
    if (!isfinite(now))
        return db__fail(d, -EINVAL, "account: the time is not finite");
    return exec_sql(d, "DELETE FROM account_tokens WHERE expires_at <= :at", &(params){.at = now});
}

int db_account_tokens_revoke(db *d, int64_t account_id)
{
    return exec_sql(d, "DELETE FROM account_tokens WHERE account_id = :id", &(params){.id = account_id});
}
