/*
 * The store when SQLite fails: every data statement of every store call
 * (sessions, objects, collision-map versions, accounts, moderation) is
 * interrupted in turn, the first, then the second, and so on until the
 * call completes untouched. Each interrupted call must report the failure
 * (-1 and SQLite's reason) rather than a result, and a call that writes in
 * one transaction must leave the database exactly as it was. Also: opening
 * a file that is not a database, one a migration cannot apply to, one
 * whose tables do not fit the statements, and the arguments refused
 * before anything is read.
 *
 * The interruption: a statement trace counts the data statements as they
 * start (transaction control is never interrupted: BEGIN, COMMIT and
 * ROLLBACK must still work to clean up), and a progress handler
 * interrupts the chosen one.
 */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <unistd.h>

#include <cmocka.h>
#include <sqlite3.h>

#include "account.h"
#include "alloc.h"
#include "db.h"
#include "ecm.h"
#include "moderation.h"
#define TESTDB_NAME "faults"
#include "../testdb.h"

/* ---- interrupting the nth data statement -------------------------------- */

static int fail_at;    /* the data statement to interrupt, from 1; 0: none */
static int statements; /* data statements started since the count was reset */
static int armed, fired;

static int on_trace(unsigned type, void *ctx, void *p, void *x)
{
    static const char *const control[] = {"BEGIN", "COMMIT", "END", "ROLLBACK", "SAVEPOINT", "RELEASE"};
    const char *sql = x;

    (void)type, (void)ctx, (void)p;
    while (*sql == ' ' || *sql == '\n')
        sql++;
    if (strncmp(sql, "--", 2) == 0) /* a trigger's program: part of the statement running */
        return 0;
    for (size_t i = 0; i < sizeof control / sizeof control[0]; i++)
        if (strncasecmp(sql, control[i], strlen(control[i])) == 0) {
            armed = 0;
            return 0;
        }
    statements++;
    armed = fail_at && statements == fail_at;
    return 0;
}

static int on_progress(void *ctx)
{
    (void)ctx;
    if (!armed)
        return 0;
    armed = 0;
    fired = 1;
    return 1; /* SQLITE_INTERRUPT */
}

/* Every row of every table, hashed (FNV-1a over each value's text). */
static uint64_t digest(db *d)
{
    sqlite3 *s = db_sqlite(d);
    sqlite3_stmt *tables, *rows;
    uint64_t h = 1469598103934665603ull;

    assert_int_equal(sqlite3_prepare_v2(s, "SELECT name FROM sqlite_master WHERE type = 'table' ORDER BY name", -1,
                                        &tables, NULL),
                     SQLITE_OK);
    while (sqlite3_step(tables) == SQLITE_ROW) {
        char sql[160];
        snprintf(sql, sizeof sql, "SELECT * FROM \"%s\"", (const char *)sqlite3_column_text(tables, 0));
        assert_int_equal(sqlite3_prepare_v2(s, sql, -1, &rows, NULL), SQLITE_OK);
        while (sqlite3_step(rows) == SQLITE_ROW)
            for (int c = 0; c < sqlite3_column_count(rows); c++) {
                const unsigned char *v = sqlite3_column_blob(rows, c);
                int n = sqlite3_column_bytes(rows, c);
                for (int i = 0; i < n; i++)
                    h = (h ^ v[i]) * 1099511628211ull;
                h = (h ^ (uint64_t)(unsigned)sqlite3_column_type(rows, c)) * 1099511628211ull;
            }
        sqlite3_finalize(rows);
    }
    sqlite3_finalize(tables);
    return h;
}

typedef int op_fn(db *d, void *ctx);

/* Runs op with its 1st, 2nd, ... data statement interrupted until it runs
 * through untouched; then it must return want. Every interrupted run must
 * return -EINTR (SQLITE_INTERRUPT, passed up as it is) with SQLite's reason; an atomic op must also leave every table
 * as it was. Returns how many statements op ran. */
static int sweep(db *d, const char *what, op_fn *op, void *ctx, int atomic, int want)
{
    for (int j = 1;; j++) {
        uint64_t before = digest(d);
        fail_at = j;
        statements = armed = fired = 0;
        int rc = op(d, ctx);
        fail_at = 0;
        armed = 0;
        if (!fired) {
            if (rc != want)
                fail_msg("%s: returned %d untouched, wanted %d (%s)", what, rc, want, db_error(d));
            return statements;
        }
        if (rc != -EINTR)
            fail_msg("%s: its statement %d was interrupted, yet it returned %d", what, j, rc);
        if (!strstr(db_error(d), "interrupted"))
            fail_msg("%s: statement %d: the message \"%s\" does not say what failed", what, j, db_error(d));
        if (atomic && digest(d) != before)
            fail_msg("%s: statement %d interrupted, yet the database changed", what, j);
    }
}

static db *open_swept(void)
{
    db *d = testdb_open();
    sqlite3_trace_v2(db_sqlite(d), SQLITE_TRACE_STMT, on_trace, NULL);
    sqlite3_progress_handler(db_sqlite(d), 1, on_progress, NULL);
    return d;
}

/* ---- sessions and objects ------------------------------------------------ */

static const float tris[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
static const float boxes[2][6] = {{0, 0, 0, 1, 1, 0.5f}, {0, 0, 0.5f, 1, 1, 1}};
static int64_t object_id, session_id = 1, event_last;

static int op_session_open(db *d, void *c) { return db_session_open(d, *(int64_t *)c, "00ff", "127.0.0.1:1", 10); }
static int op_session_join(db *d, void *c)
{
    int64_t uid;
    (void)c;
    return db_session_join(d, session_id, "ann", 7, 11, &uid);
}
static int op_session_close(db *d, void *c) { return db_session_close(d, *(int64_t *)c, "quit", 12); }
static int op_close_stale(db *d, void *c) { (void)c; return db_sessions_close_stale(d, 13); }
static int op_last_id(db *d, void *c) { (void)c; return (int)db_session_last_id(d); }
static int op_object_create(db *d, void *c)
{
    db_object o = {.owner = "ann", .name = "desk", .format = "stl", .scale = 1, .tri_count = 1, .tris = tris,
                   .min = {0, 0, 0}, .max = {1, 1, 0}, .box_count = 2, .boxes = boxes};
    (void)c;
    int rc = db_object_create(d, &o, 14);
    object_id = o.id;
    return rc;
}
static int op_owner_usage(db *d, void *c)
{
    uint32_t n;
    uint64_t t;
    (void)c;
    int rc = db_owner_usage(d, "ann", &n, &t);
    return rc < 0 ? rc : (int)n;
}
static int op_object_place(db *d, void *c)
{
    const float pos[3] = {2, 0, 2};
    (void)c;
    return db_object_place(d, object_id, pos, 0.5f, 2);
}
static int count_object(void *ctx, const db_object *o)
{
    assert_int_equal(o->box_count, o->ecm_version == 1 ? 2 : 1);
    (*(int *)ctx)++;
    return 0;
}
static int op_objects_load(db *d, void *c)
{
    int n = 0;
    (void)c;
    int rc = db_objects_load(d, count_object, &n);
    return rc < 0 ? rc : n;
}
static int op_object_remove(db *d, void *c) { (void)c; return db_object_remove(d, object_id, 20); }

static void test_sessions_and_objects(void **state)
{
    db *d = open_swept();

    (void)state;
    sweep(d, "db_session_open", op_session_open, &session_id, 1, 0);
    sweep(d, "db_session_join", op_session_join, NULL, 0, 0); /* the user row, then the session: no transaction */
    sweep(d, "db_session_close", op_session_close, &session_id, 1, 0);
    int64_t second = 2;
    sweep(d, "db_session_open", op_session_open, &second, 1, 0);
    sweep(d, "db_sessions_close_stale", op_close_stale, NULL, 1, 1);
    sweep(d, "db_session_last_id", op_last_id, NULL, 1, 2);
    assert_true(sweep(d, "db_object_create", op_object_create, NULL, 1, 0) >= 5);
    sweep(d, "db_owner_usage", op_owner_usage, NULL, 1, 1);
    sweep(d, "db_object_place", op_object_place, NULL, 1, 0);
    sweep(d, "db_objects_load", op_objects_load, NULL, 1, 1);
    sweep(d, "db_object_remove", op_object_remove, NULL, 1, 0);
    sweep(d, "db_objects_load", op_objects_load, NULL, 1, 0);
    db_close(d);
}

/* ---- collision-map versions ------------------------------------------- */

static int op_ecm_write(db *d, void *c)
{
    static const float one[1][6] = {{0, 0, 0, 1, 1, 1}};
    db_ecm_change ch = {.object_id = object_id, .parent_version = 1, .reason = "refine", .detail = "test",
                        .box_count = 1, .boxes = one};
    uint32_t v;
    (void)c;
    int rc = db_ecm_write(d, &ch, 15, &v);
    return rc < 0 ? rc : (int)v;
}
static int op_ecm_boxes(db *d, void *c)
{
    float(*b)[6];
    uint32_t n;
    (void)c;
    int rc = db_ecm_boxes(d, object_id, 1, &b, &n);
    free(b);
    return rc < 0 ? rc : (int)n;
}
static int take_event(void *ctx, int64_t event_id, int64_t object, uint32_t version)
{
    (void)event_id, (void)object, (void)version;
    (*(int *)ctx)++;
    return 0;
}
static int op_ecm_events(db *d, void *c)
{
    int n = 0;
    (void)c;
    int rc = db_ecm_events(d, 0, take_event, &n, &event_last);
    return rc < 0 ? rc : n;
}
static int op_ecm_head(db *d, void *c)
{
    int64_t last;
    (void)c;
    int rc = db_ecm_events_head(d, &last);
    return rc < 0 ? rc : (int)last;
}
static int op_ecm_object(db *d, void *c)
{
    db_ecm_object o;
    (void)c;
    int rc = db_ecm_object_load(d, object_id, &o);
    int n = (int)o.box_count;
    db_ecm_object_free(&o);
    return rc < 0 ? rc : n;
}

static void test_collision_map_versions(void **state)
{
    db *d = open_swept();

    (void)state;
    assert_int_equal(op_object_create(d, NULL), 0);
    sweep(d, "db_ecm_boxes", op_ecm_boxes, NULL, 1, 2);
    sweep(d, "db_ecm_object_load", op_ecm_object, NULL, 1, 2);
    assert_true(sweep(d, "db_ecm_write", op_ecm_write, NULL, 1, 2) >= 4);
    sweep(d, "db_ecm_events", op_ecm_events, NULL, 1, 1);
    sweep(d, "db_ecm_events_head", op_ecm_head, NULL, 1, (int)event_last);
    sweep(d, "db_ecm_object_load", op_ecm_object, NULL, 1, 1);
    db_close(d);
}

/* ---- accounts and moderation -------------------------------------------- */

static uint8_t token[DB_ACCOUNT_TOKEN_BYTES];
static int64_t bob;

static int op_account_add(db *d, void *c) { (void)c; return db_account_add(d, "bob", "pw-bob", 6, 0, 30, &bob); }
static int op_account_find(db *d, void *c)
{
    db_account a;
    (void)c;
    int rc = db_account_find(d, "BOB", &a);
    return rc < 0 ? rc : (int)a.id;
}
static int op_account_get(db *d, void *c)
{
    db_account a;
    (void)c;
    int rc = db_account_get(d, bob, &a);
    return rc < 0 ? rc : a.can_log_in;
}
static int count_account(void *ctx, const db_account *a)
{
    (void)a;
    (*(int *)ctx)++;
    return 0;
}
static int op_account_list(db *d, void *c)
{
    int n = 0;
    (void)c;
    int rc = db_account_list(d, count_account, &n);
    return rc < 0 ? rc : n;
}
static int op_set_password(db *d, void *c) { (void)c; return db_account_set_password(d, "bob", "pw-new", 6, 31); }
static int op_verify(db *d, void *c)
{
    int64_t id;
    (void)c;
    int rc = db_account_verify(d, "bob", "pw-new", 6, &id);
    return rc < 0 ? rc : (int)id;
}
static int op_token_issue(db *d, void *c) { (void)c; return db_account_token_issue(d, bob, 32, 1000, token); }
static int op_token_redeem(db *d, void *c)
{
    int64_t id;
    (void)c;
    int rc = db_account_token_redeem(d, token, 33, &id);
    return rc < 0 ? rc : (int)id;
}
static int op_tokens_expire(db *d, void *c) { (void)c; return db_account_tokens_expire(d, 2000); }
static int op_tokens_revoke(db *d, void *c) { (void)c; return db_account_tokens_revoke(d, bob); }
static int op_account_delete(db *d, void *c)
{
    int64_t moved;
    (void)c;
    int rc = db_account_delete(d, "bob", &moved);
    return rc < 0 ? rc : (int)moved;
}
static int op_kick(db *d, void *c) { (void)c; return db_kick(d, session_id, 40); }
static int op_ban(db *d, void *c) { (void)c; return db_ban(d, "bob", 0, 41); }
static int op_banned(db *d, void *c)
{
    double until;
    (void)c;
    return db_banned(d, "bob", 42, &until);
}
static int op_unban(db *d, void *c) { (void)c; return db_unban(d, "bob", 43); }
static void note_event(void *ctx, const char *kind, int64_t session, const char *name)
{
    (void)kind, (void)session, (void)name;
    (*(int *)ctx)++;
}
static int op_admin_events(db *d, void *c)
{
    int n = 0;
    int64_t last;
    (void)c;
    int rc = db_admin_events(d, 0, note_event, &n, &last);
    return rc < 0 ? rc : n;
}
static int op_admin_head(db *d, void *c)
{
    int64_t last;
    (void)c;
    int rc = db_admin_events_head(d, &last);
    return rc < 0 ? rc : (int)last;
}

static void test_accounts_and_moderation(void **state)
{
    db *d = open_swept();

    (void)state;
    sweep(d, "db_account_add", op_account_add, NULL, 1, 0);
    sweep(d, "db_account_find", op_account_find, NULL, 1, (int)bob);
    sweep(d, "db_account_get", op_account_get, NULL, 1, 1);
    sweep(d, "db_account_list", op_account_list, NULL, 1, 2); /* world and bob */
    sweep(d, "db_account_token_issue", op_token_issue, NULL, 1, 0);
    sweep(d, "db_account_set_password", op_set_password, NULL, 1, 0); /* the token goes with the old password */
    sweep(d, "db_account_verify", op_verify, NULL, 1, (int)bob);
    sweep(d, "db_account_token_issue", op_token_issue, NULL, 1, 0);
    sweep(d, "db_account_token_redeem", op_token_redeem, NULL, 1, (int)bob);
    sweep(d, "db_account_token_issue", op_token_issue, NULL, 1, 0);
    sweep(d, "db_account_tokens_revoke", op_tokens_revoke, NULL, 1, 1);
    sweep(d, "db_account_token_issue", op_token_issue, NULL, 1, 0);
    sweep(d, "db_account_tokens_expire", op_tokens_expire, NULL, 1, 1);

    assert_int_equal(op_session_open(d, &session_id), 0);
    sweep(d, "db_kick", op_kick, NULL, 1, 0);
    sweep(d, "db_ban", op_ban, NULL, 1, 0);
    sweep(d, "db_banned", op_banned, NULL, 1, 1);
    sweep(d, "db_unban", op_unban, NULL, 1, 0);
    sweep(d, "db_admin_events", op_admin_events, NULL, 1, 4); /* kick, ban (and its logout), unban */
    sweep(d, "db_admin_events_head", op_admin_head, NULL, 1, 4);
    sweep(d, "db_account_delete", op_account_delete, NULL, 1, 0);
    db_close(d);
}

static void test_arguments_refused(void **state)
{
    db *d = testdb_open();
    uint8_t t[DB_ACCOUNT_TOKEN_BYTES] = {0};
    int64_t id;

    (void)state;
    assert_int_equal(db_account_add(d, "ann", "pw", 2, 0, NAN, &id), -EINVAL);
    assert_string_equal(db_error(d), "account: the time is not finite");
    assert_int_equal(db_account_delete(d, NULL, NULL), -EINVAL);
    assert_string_equal(db_error(d), "account: no name given");
    assert_int_equal(db_account_set_password(d, NULL, "pw", 2, 1), -EINVAL);
    assert_string_equal(db_error(d), "account: no name given");
    assert_int_equal(db_account_set_password(d, "ann", "pw", 2, INFINITY), -EINVAL);
    assert_string_equal(db_error(d), "account: the time is not finite");
    assert_int_equal(db_account_token_issue(d, 1, 1, 2, NULL), -EINVAL);
    assert_string_equal(db_error(d), "account: no token buffer given");
    assert_int_equal(db_account_token_redeem(d, NULL, 1, &id), -EINVAL);
    assert_string_equal(db_error(d), "account: no token given");
    assert_int_equal(db_account_token_redeem(d, t, NAN, &id), -EINVAL);
    assert_string_equal(db_error(d), "account: the time is not finite");
    assert_int_equal(db_account_tokens_expire(d, NAN), -EINVAL);
    assert_string_equal(db_error(d), "account: the time is not finite");
    db_close(d);
}

/* ---- opening what cannot be used -------------------------------------------- */

static void test_open_refusals(void **state)
{
    char err[512];
    FILE *f;
    db *d;

    (void)state;
    cvre_alloc_fail_after(0);
    assert_null(db_open(testdb_path, DB_READWRITE, err, sizeof err));
    cvre_alloc_fail_after(-1);
    assert_string_equal(err, "out of memory");

    f = fopen(testdb_path, "w"); /* not a database at all */
    assert_non_null(f);
    fputs("this is a text file, not a database, and it is long enough to have a header of one\n", f);
    fclose(f);
    for (int mode = 0; mode < 2; mode++) {
        assert_null(db_open(testdb_path, mode ? DB_READONLY : DB_READWRITE, err, sizeof err));
        assert_non_null(strstr(err, "file is not a database"));
    }
    testdb_remove(testdb_path);

    /* a migration that cannot apply: a table of its name already there */
    sqlite3 *raw;
    assert_int_equal(sqlite3_open(testdb_path, &raw), SQLITE_OK);
    assert_int_equal(sqlite3_exec(raw, "CREATE TABLE sessions(x)", NULL, NULL, NULL), SQLITE_OK);
    sqlite3_close(raw);
    assert_null(db_open(testdb_path, DB_READWRITE, err, sizeof err));
    assert_non_null(strstr(err, "migration 0001_sessions.sql failed: table sessions already exists"));
    testdb_remove(testdb_path);

    /* the right version, the wrong tables: a statement cannot be prepared */
    d = testdb_open();
    db_close(d);
    assert_int_equal(sqlite3_open(testdb_path, &raw), SQLITE_OK);
    assert_int_equal(sqlite3_exec(raw, "PRAGMA foreign_keys = OFF; DROP TABLE meshes", NULL, NULL, NULL), SQLITE_OK);
    sqlite3_close(raw);
    assert_null(db_open(testdb_path, DB_READWRITE, err, sizeof err));
    assert_non_null(strstr(err, "prepare: no such table: meshes"));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_sessions_and_objects, testdb_setup, testdb_teardown),
        cmocka_unit_test_setup_teardown(test_collision_map_versions, testdb_setup, testdb_teardown),
        cmocka_unit_test_setup_teardown(test_accounts_and_moderation, testdb_setup, testdb_teardown),
        cmocka_unit_test_setup_teardown(test_arguments_refused, testdb_setup, testdb_teardown),
        cmocka_unit_test_setup_teardown(test_open_refusals, testdb_setup, testdb_teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
