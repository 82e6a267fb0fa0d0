/* Accounts (db/account.h): name rules, adding and refusing, verifying
 * passwords (and that an unknown name costs what a wrong password costs),
 * new passwords, deletion and what it does to objects and tokens, resume
 * tokens, and the migration of a database at schema version 4.
 *
 * Each Argon2id hash costs ~64 MiB and 0.1-0.3 s, so the tests count them:
 * about twenty in all (the timing test takes the shortest of three runs).
 * Accounts that need a password only to get tokens are given a placeholder
 * hash by SQL instead. */
#include <errno.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "account.h"
#include "db.h"
#include "migrations.h"
#define TESTDB_NAME "account"
#include "../testdb.h"

static int64_t scalar(db *d, const char *sql)
{
    return testdb_scalar(db_sqlite(d), sql);
}

static double seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

/* Adds an account without hashing: a placeholder hash lets it hold tokens
 * (nothing verifies against it). */
static int64_t add_unhashed(db *d, const char *name)
{
    int64_t id;
    assert_int_equal(db_account_add(d, name, NULL, 0, 0, 100.0, &id), 0);
    char sql[128];
    snprintf(sql, sizeof sql, "UPDATE accounts SET password_hash = 'placeholder' WHERE id = %lld", (long long)id);
    assert_int_equal(sqlite3_exec(db_sqlite(d), sql, NULL, NULL, NULL), SQLITE_OK);
    return id;
}

static void valid(const char *name)
{
    char why[128] = "";
    if (db_account_name_check(name, why, sizeof why) != 0)
        fail_msg("\"%s\" refused: %s", name, why);
}

/* Refused, with a reason that holds `because`. */
static void invalid(const char *name, const char *because)
{
    char why[128] = "";
    if (db_account_name_check(name, why, sizeof why) != -EINVAL)
        fail_msg("\"%s\" accepted", name ? name : "(null)");
    if (!strstr(why, because))
        fail_msg("\"%s\": \"%s\" does not say \"%s\"", name ? name : "(null)", why, because);
}

static void test_names(void **state)
{
    (void)state;
    valid("alice");
    valid("a");
    valid("worlds");
    valid("world_2");
    valid("Zoë");
    valid("名前");
    valid("\xf0\x9f\x99\x82"); /* U+1F642, 4 bytes */
    valid("abcdefghijklmnopqrstuvwxyz012345"); /* 32 bytes */
    invalid("", "empty");
    invalid(NULL, "empty");
    invalid("abcdefghijklmnopqrstuvwxyz0123456", "at most 32 bytes");
    invalid("al ice", "a space: U+0020 at byte 2");
    invalid("al\tice", "a control character: U+0009");
    invalid("al\x7f", "a control character: U+007F");
    invalid("a\xc2\x85", "a control character: U+0085"); /* C1 NEL */
    invalid("a\xc2\xa0" "b", "a space: U+00A0");
    invalid("a\xe3\x80\x80", "a space: U+3000");
    invalid("a\xe2\x80\x8b" "b", "invisible formatting character: U+200B"); /* zero-width space */
    invalid("a\xe2\x80\xae" "b", "invisible formatting character: U+202E"); /* right-to-left override */
    invalid("\xef\xbb\xbf" "a", "invisible formatting character: U+FEFF");
    invalid("a\xef\xbf\xbe", "a noncharacter: U+FFFE");
    invalid("a\xff", "UTF-8: byte 1");
    invalid("a\xc0\x80", "UTF-8: byte 1");         /* overlong NUL */
    invalid("\xe0\x80\xaf", "UTF-8: byte 0");       /* overlong '/' */
    invalid("a\xed\xa0\x80", "UTF-8: byte 1");      /* a surrogate */
    invalid("\xf4\x90\x80\x80", "UTF-8: byte 0");   /* beyond U+10FFFF */
    invalid("ab\xe6\x97", "UTF-8: byte 2");         /* truncated */
    invalid("a\x80", "UTF-8: byte 1");              /* stray continuation */
    invalid("world", "reserved");
    invalid("WoRlD", "reserved");
}

/* db_account_list's callback: records ids, and stops with 7 once it has
 * seen 4. */
struct seen {
    int n;
    int64_t ids[4];
};

static int collect(void *ctx, const db_account *a)
{
    struct seen *seen = ctx;
    if (seen->n == 4)
        return 7;
    seen->ids[seen->n++] = a->id;
    return 0;
}

static void test_add_find_list(void **state)
{
    (void)state;
    db *d = testdb_open();
    /* The migration made the reserved account. */
    db_account w;
    assert_int_equal(db_account_get(d, DB_ACCOUNT_WORLD, &w), 0);
    assert_string_equal(w.name, "world");
    assert_false(w.can_log_in);
    assert_false(w.is_admin);
    assert_true(w.created_at > 1.7e9);

    int64_t alice, bob;
    assert_int_equal(db_account_add(d, "alice", "s3cret pass", 11, 1, 100.0, &alice), 0); /* hash 1 */
    assert_int_equal(alice, 2);
    assert_int_equal(db_account_add(d, "bob", NULL, 0, 0, 101.0, &bob), 0);
    /* Duplicates, ignoring ASCII case, are refused before any hash. */
    assert_int_equal(db_account_add(d, "ALICE", "other", 5, 0, 102.0, NULL), -EEXIST);
    assert_non_null(strstr(db_error(d), "\"alice\" is taken"));
    assert_int_equal(db_account_add(d, "World", NULL, 0, 0, 102.0, NULL), -EINVAL);
    assert_non_null(strstr(db_error(d), "reserved"));
    assert_int_equal(db_account_add(d, "bad name", NULL, 0, 0, 102.0, NULL), -EINVAL);
    assert_non_null(strstr(db_error(d), "space"));
    assert_int_equal(db_account_add(d, "carol", "", 0, 0, 102.0, NULL), -EINVAL);
    assert_non_null(strstr(db_error(d), "password must be 1 to"));
    assert_int_equal(db_account_add(d, "carol", "x", DB_ACCOUNT_PASSWORD_MAX + 1, 0, 102.0, NULL), -EINVAL);
    assert_int_equal(scalar(d, "SELECT count(*) FROM accounts"), 3);

    /* Only an Argon2id hash is kept, never the password. */
    assert_int_equal(scalar(d, "SELECT count(*) FROM accounts WHERE name = 'alice' AND "
                               "password_hash LIKE '$argon2id$v=19$m=65536,t=2,p=1$%' AND "
                               "instr(password_hash, 's3cret') = 0 AND password_at = 100"), 1);

    db_account a;
    assert_int_equal(db_account_find(d, "ALIce", &a), 0);
    assert_int_equal(a.id, alice);
    assert_string_equal(a.name, "alice"); /* the stored spelling */
    assert_true(a.is_admin && a.can_log_in);
    assert_true(a.created_at == 100.0 && a.password_at == 100.0);
    assert_int_equal(db_account_get(d, bob, &a), 0);
    assert_true(!a.is_admin && !a.can_log_in && a.password_at == 0.0);
    assert_int_equal(db_account_find(d, "nobody", &a), -ENOENT);
    assert_non_null(strstr(db_error(d), "no account named \"nobody\""));
    assert_int_equal(db_account_get(d, 99, &a), -ENOENT);

    struct seen seen = {0};
    assert_int_equal(db_account_list(d, collect, &seen), 0);
    assert_int_equal(seen.n, 3);
    assert_true(seen.ids[0] == 1 && seen.ids[1] == alice && seen.ids[2] == bob);
    assert_int_equal(db_account_list(d, collect, &seen), 7); /* fn's value stops it */

    /* The writers need a transaction of their own. */
    assert_int_equal(db_begin(d), 0);
    assert_int_equal(db_account_add(d, "dave", NULL, 0, 0, 1.0, NULL), -EINVAL);
    assert_non_null(strstr(db_error(d), "inside a transaction"));
    db_rollback(d);
    db_close(d);
}

/* db_account_verify with the length of password, run `runs` times: its
 * (last) answer, and the shortest time a run took in *secs (the one least
 * disturbed by whatever else the machine was doing). */
static int verify_timed(db *d, const char *name, const char *password, int64_t *id, int runs, double *secs)
{
    int rc = -1;
    *secs = 1e9;
    for (int i = 0; i < runs; i++) {
        double t0 = seconds();
        rc = db_account_verify(d, name, password, strlen(password), id);
        double t = seconds() - t0;
        *secs = t < *secs ? t : *secs;
    }
    return rc;
}

static void test_verify(void **state)
{
    (void)state;
    db *d = testdb_open();
    int64_t alice, id = 0;
    double right, wrong, unknown, world, t;
    assert_int_equal(db_account_add(d, "alice", "correct horse", 13, 0, 100.0, &alice), 0); /* hash 1 */

    assert_int_equal(verify_timed(d, "alice", "correct horse", &id, 1, &right), 0);
    assert_int_equal(id, alice);
    id = 0;
    assert_int_equal(verify_timed(d, "ALICE", "correct horse", &id, 1, &t), 0); /* names ignore ASCII case */
    assert_int_equal(id, alice);

    id = -7;
    assert_int_equal(verify_timed(d, "alice", "correct horsf", &id, 3, &wrong), -EACCES);
    assert_string_equal(db_error(d), "wrong name or password");
    assert_int_equal(verify_timed(d, "mallory", "correct horse", &id, 3, &unknown), -EACCES);
    assert_string_equal(db_error(d), "wrong name or password");
    assert_int_equal(verify_timed(d, "world", "", &id, 3, &world), -EACCES);
    assert_int_equal(verify_timed(d, "alice", "correct hors", &id, 1, &t), -EACCES); /* a prefix */
    assert_int_equal(id, -7); /* untouched on denial */

    /* Every answer costs one Argon2id run (~0.1 s or more), the unknown
     * name and the account without a password included: skipping it would
     * make them ~10^4 times faster. Only that is checked, with a margin no
     * busy machine (ctest -j2 beside sanitizer builds) comes near: a
     * bound from above, or a tighter one, failed under load. */
    print_message("verify (shortest of 3): wrong %.3f s, unknown name %.3f s, no password %.3f s; right %.3f s\n",
                  wrong, unknown, world, right);
    assert_true(wrong > 0.02);
    assert_true(unknown > 0.1 * wrong);
    assert_true(world > 0.1 * wrong);
    db_close(d);
}

static void test_passwd_and_delete(void **state)
{
    (void)state;
    db *d = testdb_open();
    int64_t alice, id = 0;
    assert_int_equal(db_account_add(d, "alice", "first", 5, 0, 100.0, &alice), 0); /* hash 1 */
    uint8_t tok[DB_ACCOUNT_TOKEN_BYTES];
    assert_int_equal(db_account_token_issue(d, alice, 100.0, 1e12, tok), 0);

    assert_int_equal(db_account_set_password(d, "Alice", "second", 6, 200.0), 0); /* hash 2 */
    assert_int_equal(scalar(d, "SELECT password_at FROM accounts WHERE name = 'alice'"), 200);
    assert_int_equal(scalar(d, "SELECT count(*) FROM account_tokens"), 0); /* every device logged out */
    assert_int_equal(db_account_verify(d, "alice", "first", 5, &id), -EACCES); /* hash 3 */
    assert_int_equal(db_account_verify(d, "alice", "second", 6, &id), 0);                /* hash 4 */
    assert_int_equal(id, alice);
    assert_int_equal(db_account_set_password(d, "world", "x", 1, 200.0), -EPERM);
    assert_non_null(strstr(db_error(d), "reserved account \"world\""));
    assert_int_equal(db_account_set_password(d, "nobody", "x", 1, 200.0), -ENOENT);
    assert_int_equal(db_account_set_password(d, "alice", "", 0, 200.0), -EINVAL);
    assert_int_equal(scalar(d, "SELECT count(*) FROM accounts WHERE password_hash IS NULL"), 1); /* world still */

    /* Objects owned under the name: one in the world, one removed, one of
     * somebody else. */
    static const float tri[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    static const float box[1][6] = {{0, 0, 0, 1, 1, 0}};
    int64_t objs[3];
    const char *owners[3] = {"alice", "alice", "bob"};
    for (int i = 0; i < 3; i++) {
        db_object o = {.owner = owners[i], .name = "thing", .format = "obj", .scale = 1, .tri_count = 1,
                       .tris = tri, .max = {1, 1, 0}, .box_count = 1, .boxes = box};
        assert_int_equal(db_object_create(d, &o, 150.0), 0);
        objs[i] = o.id;
    }
    assert_int_equal(db_object_remove(d, objs[1], 160.0), 0);
    assert_int_equal(db_account_token_issue(d, alice, 300.0, 1e12, tok), 0);

    int64_t handed = -1;
    assert_int_equal(db_account_delete(d, "ALICE", &handed), 0);
    assert_int_equal(handed, 1);
    assert_int_equal(db_account_find(d, "alice", &(db_account){0}), -ENOENT);
    assert_int_equal(scalar(d, "SELECT count(*) FROM account_tokens"), 0);
    char sql[160];
    const char *want[3] = {"world", "alice", "bob"};
    for (int i = 0; i < 3; i++) {
        snprintf(sql, sizeof sql,
                 "SELECT count(*) FROM objects o JOIN users u ON u.id = o.owner_id WHERE o.id = %lld AND u.name = '%s'",
                 (long long)objs[i], want[i]);
        assert_int_equal(scalar(d, sql), 1);
    }
    assert_int_equal(scalar(d, "SELECT count(*) FROM users WHERE name = 'alice'"), 1); /* history stays */
    assert_int_equal(db_account_token_redeem(d, tok, 400.0, &id), -EACCES);

    assert_int_equal(db_account_delete(d, "world", &handed), -EPERM);
    assert_int_equal(handed, 0);
    assert_int_equal(db_account_delete(d, "alice", NULL), -ENOENT);
    assert_int_equal(db_account_delete(d, "bob", NULL), -ENOENT); /* a display name, no account */
    /* A new alice is a new account: a new id, nothing of the old one's. */
    assert_int_equal(db_account_add(d, "alice", NULL, 0, 0, 500.0, &id), 0);
    assert_true(id > alice);
    /* Deleting with no objects in the world hands over nothing. */
    assert_int_equal(db_account_delete(d, "alice", &handed), 0);
    assert_int_equal(handed, 0);
    db_close(d);
}

static void test_tokens(void **state)
{
    (void)state;
    db *d = testdb_open();
    int64_t alice = add_unhashed(d, "alice"), bob = add_unhashed(d, "bob"), id = 0;
    uint8_t t1[DB_ACCOUNT_TOKEN_BYTES], t2[DB_ACCOUNT_TOKEN_BYTES], t3[DB_ACCOUNT_TOKEN_BYTES];
    assert_int_equal(db_account_token_issue(d, alice, 1000.0, 2000.0, t1), 0);
    assert_int_equal(db_account_token_issue(d, alice, 1000.0, 1500.0, t2), 0);
    assert_int_equal(db_account_token_issue(d, bob, 1000.0, 2000.0, t3), 0);
    assert_memory_not_equal(t1, t2, sizeof t1);
    /* The store has hashes only: no row holds a token's bytes. */
    sqlite3_stmt *st;
    assert_int_equal(sqlite3_prepare_v2(db_sqlite(d), "SELECT count(*) FROM account_tokens WHERE hash = ?1 OR "
                                                      "hash = ?2 OR hash = ?3", -1, &st, NULL), SQLITE_OK);
    sqlite3_bind_blob(st, 1, t1, sizeof t1, SQLITE_STATIC);
    sqlite3_bind_blob(st, 2, t2, sizeof t2, SQLITE_STATIC);
    sqlite3_bind_blob(st, 3, t3, sizeof t3, SQLITE_STATIC);
    assert_int_equal(sqlite3_step(st), SQLITE_ROW);
    assert_int_equal(sqlite3_column_int(st, 0), 0);
    sqlite3_finalize(st);
    assert_int_equal(scalar(d, "SELECT count(*) FROM account_tokens WHERE length(hash) = 32"), 3);

    /* Right token: its account, once. */
    assert_int_equal(db_account_token_redeem(d, t1, 1999.0, &id), 0);
    assert_int_equal(id, alice);
    id = -7;
    assert_int_equal(db_account_token_redeem(d, t1, 1999.0, &id), -EACCES);
    assert_string_equal(db_error(d), "unknown or expired token");
    assert_int_equal(id, -7);
    /* Wrong tokens: one bit off, and none at all. */
    uint8_t bad[DB_ACCOUNT_TOKEN_BYTES];
    memcpy(bad, t3, sizeof bad);
    bad[31] ^= 1;
    assert_int_equal(db_account_token_redeem(d, bad, 1000.0, &id), -EACCES);
    memset(bad, 0, sizeof bad);
    assert_int_equal(db_account_token_redeem(d, bad, 1000.0, &id), -EACCES);
    /* Expired: refused at expires_at, and deleted when found. */
    assert_int_equal(db_account_token_redeem(d, t2, 1500.0, &id), -EACCES);
    assert_int_equal(scalar(d, "SELECT count(*) FROM account_tokens"), 1);
    assert_int_equal(db_account_token_redeem(d, t3, 1500.0, &id), 0);
    assert_int_equal(id, bob);

    /* Refusals. */
    assert_int_equal(db_account_token_issue(d, DB_ACCOUNT_WORLD, 1000.0, 2000.0, t1), -EPERM);
    int64_t nopw;
    assert_int_equal(db_account_add(d, "carol", NULL, 0, 0, 1.0, &nopw), 0);
    assert_int_equal(db_account_token_issue(d, nopw, 1000.0, 2000.0, t1), -EPERM);
    assert_int_equal(db_account_token_issue(d, 99, 1000.0, 2000.0, t1), -ENOENT);
    assert_int_equal(db_account_token_issue(d, alice, 1000.0, 1000.0, t1), -EINVAL);
    assert_int_equal(scalar(d, "SELECT count(*) FROM account_tokens"), 0);

    /* At most DB_ACCOUNT_TOKENS_MAX per account: the oldest go. */
    uint8_t first[DB_ACCOUNT_TOKEN_BYTES], last[DB_ACCOUNT_TOKEN_BYTES];
    for (int i = 0; i < DB_ACCOUNT_TOKENS_MAX + 4; i++)
        assert_int_equal(db_account_token_issue(d, alice, 3000.0 + i, 9000.0 + i, i == 0 ? first : last), 0);
    assert_int_equal(scalar(d, "SELECT count(*) FROM account_tokens"), DB_ACCOUNT_TOKENS_MAX);
    assert_int_equal(scalar(d, "SELECT min(created_at) FROM account_tokens"), 3004);
    assert_int_equal(db_account_token_redeem(d, first, 3500.0, &id), -EACCES);
    assert_int_equal(db_account_token_redeem(d, last, 3500.0, &id), 0);

    /* Housekeeping: expired ones (expires_at <= now), then one account's. */
    assert_int_equal(db_account_token_issue(d, bob, 3000.0, 3100.0, t1), 0);
    assert_int_equal(db_account_tokens_expire(d, 9005.0), 3); /* alice's until 9004 and 9005, bob's */
    assert_int_equal(db_account_tokens_expire(d, 9005.0), 0);
    assert_int_equal(db_account_tokens_revoke(d, alice), DB_ACCOUNT_TOKENS_MAX - 1 - 2);
    assert_int_equal(scalar(d, "SELECT count(*) FROM account_tokens"), 0);
    db_close(d);
}

/* A database at schema version 4 with a user and an object, as a server of
 * the previous release left it, opened by this build: migrated to 5 with the
 * world account, the old rows untouched. */
static void test_migration_from_schema_4(void **state)
{
    (void)state;
    assert_true(db_schema_version() >= 5); /* accounts came with 5; later ones migrate too */
    sqlite3 *raw;
    assert_int_equal(sqlite3_open(testdb_path, &raw), SQLITE_OK);
    for (int i = 0; i < 4; i++)
        assert_int_equal(sqlite3_exec(raw, db_migrations[i].sql, NULL, NULL, NULL), SQLITE_OK);
    assert_int_equal(sqlite3_exec(raw,
                                  "PRAGMA user_version = 4; PRAGMA journal_mode = WAL;"
                                  "INSERT INTO users(id, name, created_at, last_seen_at) VALUES (1, 'world', 1, 1),"
                                  " (2, 'alice', 1, 2);"
                                  "INSERT INTO objects(id, owner_id, name, format, created_at, pos_x, pos_y, pos_z,"
                                  " yaw, scale, ecm_version, tri_count, min_x, min_y, min_z, max_x, max_y, max_z)"
                                  " VALUES (7, 2, 'arch', 'glb', 5, 0, 0, 0, 0, 1, 1, 0, 0, 0, 0, 1, 1, 1);",
                                  NULL, NULL, NULL),
                     SQLITE_OK);
    sqlite3_close(raw);

    char err[256];
    assert_null(db_open(testdb_path, DB_READONLY, err, sizeof err)); /* read-only never migrates */
    char want[64];
    snprintf(want, sizeof want, "schema version 4, this build expects %d", db_schema_version());
    assert_non_null(strstr(err, want));
    db *d = testdb_open();
    assert_int_equal(scalar(d, "PRAGMA user_version"), db_schema_version());
    assert_int_equal(scalar(d, "SELECT count(*) FROM accounts"), 1);
    assert_int_equal(scalar(d, "SELECT id FROM accounts WHERE name = 'world' AND password_hash IS NULL"),
                     DB_ACCOUNT_WORLD);
    assert_int_equal(scalar(d, "SELECT count(*) FROM users"), 2);
    assert_int_equal(scalar(d, "SELECT owner_id FROM objects WHERE id = 7"), 2);
    /* The new tables work on the old file: alice gets an account, is
     * deleted, and her object passes to the world's users row. */
    assert_int_equal(db_account_add(d, "alice", NULL, 0, 0, 10.0, NULL), 0);
    int64_t handed;
    assert_int_equal(db_account_delete(d, "alice", &handed), 0);
    assert_int_equal(handed, 1);
    assert_int_equal(scalar(d, "SELECT owner_id FROM objects WHERE id = 7"), 1);
    db_close(d);
    d = db_open(testdb_path, DB_READONLY, err, sizeof err);
    assert_non_null(d);
    db_close(d);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_names),
        cmocka_unit_test_setup_teardown(test_add_find_list, testdb_setup, testdb_teardown),
        cmocka_unit_test_setup_teardown(test_verify, testdb_setup, testdb_teardown),
        cmocka_unit_test_setup_teardown(test_passwd_and_delete, testdb_setup, testdb_teardown),
        cmocka_unit_test_setup_teardown(test_tokens, testdb_setup, testdb_teardown),
        cmocka_unit_test_setup_teardown(test_migration_from_schema_4, testdb_setup, testdb_teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
