#include "user.h"

#include <errno.h>
#include <signal.h>
#include <sodium.h>
#include <stdio.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

#include "account.h"
#include "err.h"
#include "out.h"
#include "query.h"

#define LEN(a) ((int)(sizeof(a) / sizeof((a)[0])))

int user_verb(const char *word)
{
    static const char *const verbs[] = {[USER_ADD] = "add", [USER_DEL] = "del", [USER_LIST] = "list",
                                        [USER_PASSWD] = "passwd"};
    for (int i = 0; i < LEN(verbs); i++)
        if (strcmp(word, verbs[i]) == 0)
            return i;
    return -ENOENT;
}

/* ---- output ---- */

/* One row per account (or the one named :name), never a hash: whether it
 * can log in, its live tokens, and the objects in the world owned under its
 * name (what del would hand to the world account). */
static const out_column account_cols[] = {
    {"id", OUT_INT, 0},      {"name", OUT_TEXT, 0},         {"admin", OUT_BOOL, 0},  {"can_log_in", OUT_BOOL, 0},
    {"created", OUT_TIME, 0}, {"password_set", OUT_TIME, 0}, {"tokens", OUT_INT, 0}, {"objects", OUT_INT, 0},
};
static const char account_sql[] =
    "SELECT a.id, a.name, a.is_admin, a.password_hash IS NOT NULL, a.created_at, a.password_at, "
    "(SELECT count(*) FROM account_tokens t WHERE t.account_id = a.id AND t.expires_at > :now), "
    "(SELECT count(*) FROM objects o JOIN users u ON u.id = o.owner_id WHERE u.name = a.name "
    "AND o.removed_at IS NULL) "
    "FROM accounts a WHERE :name IS NULL OR a.name = :name ORDER BY a.id";

/* Every account (name NULL, as rows) or one (as a record), in one read
 * snapshot. */
static int print_accounts(sqlite3 *s, const char *name, int format, char *err, size_t errlen)
{
    sqlite3_stmt *st;
    if (sqlite3_exec(s, "BEGIN", NULL, NULL, NULL) != SQLITE_OK)
        return cvre_fail(err, errlen, -EIO, "cannot start a read transaction: %s", sqlite3_errmsg(s));
    int rc = -EIO;
    if (sqlite3_prepare_v2(s, account_sql, -1, &st, NULL) != SQLITE_OK) {
        cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
    } else {
        sqlite3_bind_double(st, sqlite3_bind_parameter_index(st, ":now"), db_now());
        if (name)
            sqlite3_bind_text(st, sqlite3_bind_parameter_index(st, ":name"), name, -1, SQLITE_STATIC);
        rc = query_print(s, st, account_cols, LEN(account_cols), name ? OUT_RECORD : OUT_ROWS, format, err, errlen);
    }
    sqlite3_exec(s, "COMMIT", NULL, NULL, NULL); /* a read: nothing to lose */
    return rc;
}

/* What del prints: the account that was, and how many of its objects in
 * the world now belong to the world account. */
static int print_deleted(sqlite3 *s, const db_account *a, int64_t objects, int format, char *err, size_t errlen)
{
    static const out_column cols[] = {{"id", OUT_INT, 0}, {"name", OUT_TEXT, 0}, {"objects_to_world", OUT_INT, 0}};
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(s, "SELECT ?1, ?2, ?3", -1, &st, NULL) != SQLITE_OK)
        return cvre_fail(err, errlen, -EIO, "query failed: %s", sqlite3_errmsg(s));
    sqlite3_bind_int64(st, 1, a->id);
    sqlite3_bind_text(st, 2, a->name, -1, SQLITE_STATIC);
    sqlite3_bind_int64(st, 3, objects);
    return query_print(s, st, cols, LEN(cols), OUT_RECORD, format, err, errlen);
}

/* ---- reading a password ---- */

/* The terminal's settings while echo is off, restored by a signal that
 * ends the program while it waits for the password. */
static struct termios saved_tty;
static const int tty_signals[] = {SIGINT, SIGTERM, SIGHUP, SIGQUIT};

static void restore_tty_and_die(int sig)
{
    tcsetattr(STDIN_FILENO, TCSAFLUSH, &saved_tty); /* async-signal-safe */
    signal(sig, SIG_DFL);
    raise(sig);
}

/* Turns the terminal's echo off (on != 0) or back on. */
static int tty_echo_off(int on)
{
    if (on) {
        if (tcgetattr(STDIN_FILENO, &saved_tty) != 0)
            return -errno;
        struct sigaction sa = {.sa_handler = restore_tty_and_die};
        sigemptyset(&sa.sa_mask);
        for (int i = 0; i < LEN(tty_signals); i++)
            sigaction(tty_signals[i], &sa, NULL);
        struct termios quiet = saved_tty;
        quiet.c_lflag &= ~(tcflag_t)(ECHO | ECHOE | ECHOK | ECHONL);
        return tcsetattr(STDIN_FILENO, TCSAFLUSH, &quiet) == 0 ? 0 : -errno;
    }
    int rc = tcsetattr(STDIN_FILENO, TCSAFLUSH, &saved_tty) == 0 ? 0 : -errno;
    for (int i = 0; i < LEN(tty_signals); i++)
        signal(tty_signals[i], SIG_DFL);
    return rc;
}

/* Reads one line from standard input into buf (cap bytes), without its
 * newline and a carriage return before it, byte by byte so that no copy is
 * left in a stdio buffer. Returns its length, -errno on a read error,
 * -E2BIG if it is longer than cap (the rest of the line is read and
 * dropped). */
static long read_line(char *buf, size_t cap)
{
    size_t n = 0;
    int too_long = 0;
    for (;;) {
        char c;
        ssize_t k = read(STDIN_FILENO, &c, 1);
        if (k < 0 && errno == EINTR)
            continue;
        if (k < 0)
            return -errno;
        if (k == 0 || c == '\n')
            break;
        if (n < cap)
            buf[n++] = c;
        else
            too_long = 1;
    }
    if (too_long)
        return -E2BIG;
    if (n && buf[n - 1] == '\r')
        n--;
    return (long)n;
}

/* One password line, prompted for on a terminal with echo off (prompt
 * NULL: from a pipe, no prompt). Returns 0 and *len. */
static int read_password(const char *prompt, char *buf, size_t *len, char *err, size_t errlen)
{
    if (prompt) {
        /* Echo off first: it discards what was typed ahead, so the prompt
         * comes after, when an answer is read. */
        int rc = tty_echo_off(1);
        if (rc < 0)
            return cvre_fail(err, errlen, rc, "cannot turn the terminal's echo off: %s", strerror(-rc));
        fputs(prompt, stderr);
        fflush(stderr);
    }
    long n = read_line(buf, DB_ACCOUNT_PASSWORD_MAX);
    if (prompt) {
        tty_echo_off(0);
        fputc('\n', stderr); /* the Enter that was not echoed */
    }
    if (n == -E2BIG)
        return cvre_fail(err, errlen, -EINVAL, "the password is longer than %u bytes; nothing written",
                          DB_ACCOUNT_PASSWORD_MAX);
    if (n < 0)
        return cvre_fail(err, errlen, (int)n, "cannot read the password: %s", strerror((int)-n));
    if (n == 0)
        return cvre_fail(err, errlen, -EINVAL, "empty password refused; nothing written");
    *len = (size_t)n;
    return 0;
}

/* The new password of the account named name: asked twice on the terminal,
 * or one line of standard input. pw holds DB_ACCOUNT_PASSWORD_MAX bytes; the
 * caller wipes it. */
static int new_password(const user_request *r, const char *name, char *pw, size_t *len, char *err, size_t errlen)
{
    if (r->password_stdin)
        return read_password(NULL, pw, len, err, errlen);
    char prompt[128], again[DB_ACCOUNT_PASSWORD_MAX];
    size_t again_len = 0;
    snprintf(prompt, sizeof prompt, "New password for %s: ", name);
    int rc = read_password(prompt, pw, len, err, errlen);
    if (rc == 0)
        rc = read_password("Again: ", again, &again_len, err, errlen);
    if (rc == 0 && (again_len != *len || sodium_memcmp(again, pw, *len) != 0))
        rc = cvre_fail(err, errlen, -EINVAL, "the two passwords differ; nothing written");
    sodium_memzero(again, sizeof again);
    return rc;
}

/* ---- the commands ---- */

/* The check on the read-only snapshot, before any password is asked for:
 * for add, that the name is free; otherwise that the account exists (into
 * *a) and is not the reserved one. */
static int check(db *ro, const user_request *r, db_account *a, char *err, size_t errlen)
{
    int rc = db_account_find(ro, r->name, a);
    if (rc != 0 && rc != -ENOENT)
        return cvre_fail(err, errlen, -EIO, "%s", db_error(ro));
    if (r->verb == USER_ADD)
        return rc == 0 ? cvre_fail(err, errlen, -EPERM, "an account named \"%s\" exists already; nothing written",
                                    a->name)
                       : 0;
    if (rc == -ENOENT)
        return cvre_fail(err, errlen, -ENOENT, "no account named \"%s\"", r->name);
    if (a->id == DB_ACCOUNT_WORLD)
        return cvre_fail(err, errlen, -EPERM,
                          "\"%s\" is the reserved account of the world's objects: it %s; nothing written", a->name,
                          r->verb == USER_DEL ? "cannot be deleted" : "cannot log in, so it has no password");
    return 0;
}

/* The write, on a handle opened read-write for it, and what it prints. */
static int write_account(db *d, const user_request *r, const db_account *a, const char *pw, size_t len, int format,
                         char *err, size_t errlen)
{
    int64_t objects = 0;
    int rc = r->verb == USER_ADD      ? db_account_add(d, r->name, pw, len, r->admin, db_now(), NULL)
             : r->verb == USER_PASSWD ? db_account_set_password(d, a->name, pw, len, db_now())
                                      : db_account_delete(d, a->name, &objects);
    /* Another writer may have come between the check and this write. */
    if (rc == -EEXIST || rc == -EPERM)
        return cvre_fail(err, errlen, -EPERM, "%s; nothing written", db_error(d));
    if (rc == -ENOENT)
        return cvre_fail(err, errlen, -ENOENT, "no account named \"%s\" (any more); nothing written",
                          r->name);
    if (rc != 0)
        return cvre_fail(err, errlen, -EIO, "nothing written: %s%s", db_error(d),
                          db_busy(d) ? " (another process held the write lock)" : "");
    if (r->verb == USER_DEL)
        return print_deleted(db_sqlite(d), a, objects, format, err, errlen);
    return print_accounts(db_sqlite(d), r->name, format, err, errlen);
}

int user_run(db *ro, const char *path, const user_request *r, int format, char *err, size_t errlen)
{
    if (r->verb == USER_LIST) {
        int rc = print_accounts(db_sqlite(ro), NULL, format, err, errlen);
        db_close(ro);
        return rc;
    }
    db_account a = {0};
    int rc = check(ro, r, &a, err, errlen);
    db_close(ro);
    if (rc != 0)
        return rc;
    char pw[DB_ACCOUNT_PASSWORD_MAX];
    size_t len = 0;
    if (r->verb != USER_DEL)
        rc = new_password(r, r->verb == USER_ADD ? r->name : a.name, pw, &len, err, errlen);
    if (rc == 0) {
        char why[512];
        db *d = db_open(path, DB_READWRITE, why, sizeof why);
        if (!d) {
            rc = cvre_fail(err, errlen, -EIO, "cannot open for writing: %s", why);
        } else {
            rc = write_account(d, r, &a, pw, len, format, err, errlen);
            db_close(d);
        }
    }
    sodium_memzero(pw, sizeof pw);
    return rc;
}
