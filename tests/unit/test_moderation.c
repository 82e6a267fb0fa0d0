/* Kicks and bans in the store (db/moderation.h): the feed a server follows
 * carries each action once, in order; bans end when they say. */
#include <errno.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "account.h"
#include "db.h"
#include "moderation.h"
#define TESTDB_NAME "moderation"
#include "../testdb.h"

/* What the feed gave, as "kind:session:name" lines. */
static char seen[1024];

static void note(void *ctx, const char *kind, int64_t session_id, const char *name)
{
    (void)ctx;
    snprintf(seen + strlen(seen), sizeof seen - strlen(seen), "%s:%lld:%s\n", kind, (long long)session_id, name);
}

static void test_kick_ban_unban_feed(void **state)
{
    db *d = testdb_open();
    int64_t head = -1, last;
    double until;

    (void)state;
    assert_int_equal(db_admin_events_head(d, &head), 0);
    assert_int_equal(head, 0);
    assert_int_equal(db_kick(d, 7, 100.0), -ENOENT); /* no such session */
    assert_int_equal(db_session_open(d, 7, "00", "127.0.0.1:1", 99.0), 0);
    assert_int_equal(db_kick(d, 7, 100.0), 0);
    assert_int_equal(db_ban(d, "Mallory", 200.0, 101.0), 0);
    assert_int_equal(db_banned(d, "mallory", 150.0, &until), 1); /* any letter case */
    assert_true(until == 200.0);
    assert_int_equal(db_banned(d, "mallory", 200.0, &until), 0); /* ended */
    assert_int_equal(db_ban(d, "mallory", 0, 102.0), 0);          /* again: for good */
    assert_int_equal(db_banned(d, "MALLORY", 1e12, &until), 1);
    assert_true(until == 0);
    assert_int_equal(db_unban(d, "mallory", 103.0), 0);
    assert_int_equal(db_banned(d, "mallory", 150.0, &until), 0);
    assert_int_equal(db_unban(d, "mallory", 104.0), -ENOENT);
    assert_int_equal(db_ban(d, "eve", 150.0, 104.0), 0);
    assert_int_equal(db_unban(d, "eve", 160.0), -ENOENT); /* it had ended: no ban to lift */
    assert_int_equal(db_ban(d, "", 0, 105.0), -EINVAL);
    assert_int_equal(db_ban(d, "a-name-longer-than-thirty-two-bytes", 0, 105.0), -EINVAL);

    seen[0] = 0;
    last = 0;
    assert_int_equal(db_admin_events(d, 0, note, NULL, &last), 0);
    assert_string_equal(seen, "kick:7:\nban:0:Mallory\nban:0:mallory\nunban:0:mallory\nban:0:eve\n");
    assert_int_equal(last, 5);
    seen[0] = 0;
    assert_int_equal(db_admin_events(d, last, note, NULL, &last), 0); /* nothing new */
    assert_string_equal(seen, "");
    assert_int_equal(last, 5);
    db_close(d);
}

/* A ban revokes the account's resume tokens: it cannot come back by one. */
static void test_ban_revokes_tokens(void **state)
{
    db *d = testdb_open();
    uint8_t token[DB_ACCOUNT_TOKEN_BYTES];
    int64_t id, got;

    (void)state;
    assert_int_equal(db_account_add(d, "ann", "pw", 2, 0, 1.0, &id), 0);
    assert_int_equal(db_account_token_issue(d, id, 1.0, 1e12, token), 0);
    assert_int_equal(db_ban(d, "ann", 0, 2.0), 0);
    assert_int_equal(db_account_token_redeem(d, token, 3.0, &got), -EACCES);
    db_close(d);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_kick_ban_unban_feed, testdb_setup, testdb_teardown),
        cmocka_unit_test_setup_teardown(test_ban_revokes_tokens, testdb_setup, testdb_teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
