"""cvre-admin's account commands against a database made by the real
migrations (a cvre-server run): user add (also while the server runs), list
in table, CSV and JSON form (never a hash), passwd (revokes tokens), del (the
objects pass to the world account), the terminal prompt (no echo, asked
twice), and every refusal with its exit code: bad names, the reserved world
account, duplicates, empty, long and mistyped passwords, unknown accounts,
a database at the previous schema version. Each add or passwd costs one
Argon2id hash (~0.2 s), so there are few of them."""
import csv
import io
import json
import os
import pty
import select
import shutil
import sqlite3
import subprocess
import tempfile
import time
from contextlib import closing

from harness import TEMP_DIRS, Server, admin, args, copy_with_schema, iso, run

A = args()
LIST_COLUMNS = ["id", "name", "admin", "can_log_in", "created", "password_set", "tokens", "objects"]


def fresh_db():
    """A new database migrated by the real server."""
    srv = Server(A.bin)
    assert srv.stop() == 0
    return srv.db


def user(*argv, db, password=None, check=0):
    """cvre-admin user ARGV with password (str or bytes) as standard input,
    empty if None (a pipe, never the terminal the tests run on)."""
    data = password.encode() if isinstance(password, str) else (password or b"")
    p = subprocess.run([os.path.join(A.bin, "cvre-admin"), "--db", db, "user"] + [str(a) for a in argv],
                       input=data, capture_output=True, timeout=60)
    out, err = p.stdout.decode(), p.stderr.decode()
    if check is not None:
        assert p.returncode == check, f"user {argv}: exit {p.returncode}, stdout {out!r}, stderr {err!r}"
    return p.returncode, out, err


def listed(db):
    _, out, _ = admin("user", "list", "--json", db=db)
    return {r["name"]: r for r in json.loads(out)}


def stored(db, sql, *params):
    with closing(sqlite3.connect(db)) as con:
        return con.execute(sql, params).fetchall()


def file_bytes(db):
    """The database and its WAL, as bytes (a password must be in neither)."""
    data = b""
    for suffix in ("", "-wal"):
        if os.path.exists(db + suffix):
            with open(db + suffix, "rb") as f:
                data += f.read()
    return data


def table(text):
    lines = text.rstrip("\n").split("\n")
    assert set(lines[1].replace(" ", "")) <= {"-"}, lines[:2]
    return lines[0].split(), [line.split() for line in lines[2:]]


def test_add_and_list_every_form():
    db = fresh_db()
    srv = Server(A.bin, db=db)  # a running server does not stop the tool from writing
    t0 = time.time()
    try:
        _, out, _ = user("add", "alice", "--admin", "--password-stdin", db=db, password="hunter2 hunter2\n")
        _, out2, _ = user("add", "Zoë", "--password-stdin", db=db, password="pässwörd ✓\r\n")
    finally:
        assert srv.stop() == 0
    # add prints the new account as a record.
    fields = dict(line.split(None, 1) for line in out.strip().split("\n"))
    assert list(fields) == LIST_COLUMNS and fields["name"] == "alice" and fields["admin"] == "yes", fields
    assert fields["can_log_in"] == "yes" and fields["tokens"] == "0" and fields["objects"] == "0", fields
    assert "Zoë" in out2, out2

    got = listed(db)
    assert list(got) == ["world", "alice", "Zoë"], got
    w, a, z = got["world"], got["alice"], got["Zoë"]
    assert w == {"id": 1, "name": "world", "admin": False, "can_log_in": False, "created": w["created"],
                 "password_set": None, "tokens": 0, "objects": 0}, w
    assert (a["id"], a["admin"], a["can_log_in"], a["tokens"], a["objects"]) == (2, True, True, 0, 0), a
    assert (z["id"], z["admin"], z["can_log_in"]) == (3, False, True), z
    assert a["created"] == a["password_set"] and a["created"] >= time.strftime("%Y-%m-%dT%H:%M:%S",
                                                                              time.gmtime(t0 - 1)), a

    _, out, _ = admin("user", "list", "--csv", db=db)
    rows = list(csv.reader(io.StringIO(out, newline="")))
    assert out.endswith("\r\n") and rows[0] == LIST_COLUMNS, rows
    assert rows[1] == ["1", "world", "0", "0", w["created"], "", "0", "0"], rows[1]
    assert rows[2] == ["2", "alice", "1", "1", a["created"], a["password_set"], "0", "0"], rows[2]
    assert [r[1] for r in rows[1:]] == ["world", "alice", "Zoë"]

    _, out, _ = admin("user", "list", db=db)
    head, rows = table(out)
    assert head == LIST_COLUMNS, head
    (world_at,), = stored(db, "SELECT created_at FROM accounts WHERE id = 1")
    assert iso(world_at) == w["created"], (world_at, w)
    assert rows[0] == ["1", "world", "no", "no", iso(world_at, 3), "-", "0", "0"], rows[0]
    assert rows[1][:4] == ["2", "alice", "yes", "yes"] and rows[2][1] == "Zoë", rows

    # Only Argon2id hashes are stored: no password, in the file or the output.
    hashes = stored(db, "SELECT name, password_hash FROM accounts ORDER BY id")
    assert hashes[0] == ("world", None), hashes
    assert all(h.startswith("$argon2id$v=19$m=65536,t=2,p=1$") for _, h in hashes[1:]), hashes
    data = file_bytes(db)
    for secret in ("hunter2", "pässwörd"):
        assert secret.encode() not in data, secret
    for argv in (["list", "--json"], ["list", "--csv"], ["list"]):
        _, out, _ = admin("user", *argv, db=db)
        assert "argon2" not in out and "hunter2" not in out, out


def test_refusals():
    db = fresh_db()
    user("add", "alice", "--password-stdin", db=db, password="pw\n")
    checks = [
        # (argv, stdin, exit code, words in the message)
        (["add", "ALICE", "--password-stdin"], "x\n", 4, 'an account named "alice" exists already'),
        (["add", "World", "--password-stdin"], "x\n", 2, 'the name "world" is reserved'),
        (["add", "al ice", "--password-stdin"], "x\n", 2, "a space: U+0020 at byte 2"),
        (["add", "a\u200bb", "--password-stdin"], "x\n", 2, "invisible formatting character: U+200B"),
        (["add", "x" * 33, "--password-stdin"], "x\n", 2, "at most 32 bytes"),
        (["add", "bob", "--password-stdin"], "\n", 2, "empty password refused"),
        (["add", "bob", "--password-stdin"], "", 2, "empty password refused"),
        (["add", "bob", "--password-stdin"], "y" * 1025 + "\n", 2, "longer than 1024 bytes"),
        (["add", "bob"], "pw\npw\n", 2, "give --password-stdin"),  # standard input is not a terminal
        (["passwd", "alice"], "pw\npw\n", 2, "give --password-stdin"),
        (["passwd", "nobody", "--password-stdin"], "x\n", 1, 'no account named "nobody"'),
        (["passwd", "WORLD", "--password-stdin"], "x\n", 4, "cannot log in, so it has no password"),
        (["passwd", "alice", "--password-stdin"], "\n", 2, "empty password refused"),
        (["del", "nobody"], "", 1, 'no account named "nobody"'),
        (["del", "world"], "", 4, "cannot be deleted"),
        ([], "", 2, "wants add, del, list or passwd"),
        (["frob"], "", 2, 'no user command "frob"'),
        (["add"], "", 2, "add wants the account's name"),
        (["add", "a", "b", "--password-stdin"], "", 2, 'unexpected argument "b"'),
        (["list", "alice"], "", 2, 'unexpected argument "alice"'),
        (["del", "alice", "--admin"], "", 2, "--admin is an option of user add only"),
        (["list", "--password-stdin"], "", 2, "--password-stdin is an option of user add and user passwd only"),
        (["list", "--object", "1"], "", 2, "--object is not an option of this command"),
    ]
    before = stored(db, "SELECT * FROM accounts ORDER BY id")
    for argv, stdin, code, words in checks:
        _, out, err = user(*argv, db=db, password=stdin, check=code)
        assert out == "" and err.startswith("cvre-admin") and words in err, (argv, out, err)
    assert stored(db, "SELECT * FROM accounts ORDER BY id") == before  # nothing written
    rc, _, err = admin("collisions", "--admin", db=db, check=2)
    assert "--admin is not an option of this command" in err, err


def test_passwd_revokes_tokens():
    db = fresh_db()
    user("add", "bob", "--password-stdin", db=db, password="old password\n")
    (bob_id, old_hash, old_at), = stored(db, "SELECT id, password_hash, password_at FROM accounts WHERE name = 'bob'")
    con = sqlite3.connect(db)
    con.executemany("INSERT INTO account_tokens(hash, account_id, created_at, expires_at) VALUES (?, ?, 0, ?)",
                    [(bytes([1] * 32), bob_id, 4e9), (bytes([2] * 32), bob_id, 1.0)])  # live, expired
    con.commit()
    con.close()
    assert listed(db)["bob"]["tokens"] == 1

    _, out, _ = user("passwd", "BOB", "--password-stdin", "--json", db=db, password="new password\n")
    got = json.loads(out)
    assert len(got) == 1 and got[0]["name"] == "bob" and got[0]["tokens"] == 0, got
    (new_hash, new_at), = stored(db, "SELECT password_hash, password_at FROM accounts WHERE name = 'bob'")
    assert new_hash != old_hash and new_hash.startswith("$argon2id$") and new_at > old_at
    assert stored(db, "SELECT count(*) FROM account_tokens") == [(0,)]
    assert got[0]["password_set"] != got[0]["created"], got
    assert b"new password" not in file_bytes(db)


def test_del_hands_objects_to_world():
    db = fresh_db()
    user("add", "alice", "--password-stdin", db=db, password="pw\n")
    con = sqlite3.connect(db)
    con.executemany("INSERT INTO users(id, name, created_at, last_seen_at) VALUES (?, ?, 0, 0)",
                    [(10, "alice"), (11, "bob")])
    for oid, owner, removed in ((1, 10, None), (2, 10, 5.0), (3, 11, None), (4, 10, None)):
        con.execute("INSERT INTO objects(id, owner_id, name, format, created_at, removed_at, pos_x, pos_y, pos_z, "
                    "yaw, scale, ecm_version, tri_count, min_x, min_y, min_z, max_x, max_y, max_z) "
                    "VALUES (?, ?, 'thing', 'obj', 0, ?, 0, 0, 0, 0, 1, 1, 0, 0, 0, 0, 1, 1, 1)", (oid, owner, removed))
    con.execute("INSERT INTO account_tokens(hash, account_id, created_at, expires_at) VALUES (?, 2, 0, 4e9)",
                (bytes(32),))
    con.commit()
    con.close()
    assert listed(db)["alice"]["objects"] == 2  # in the world: 1 and 4

    _, out, _ = user("del", "Alice", db=db)
    fields = dict(line.split(None, 1) for line in out.strip().split("\n"))
    assert fields == {"id": "2", "name": "alice", "objects_to_world": "2"}, fields
    owners = dict(stored(db, "SELECT o.id, u.name FROM objects o JOIN users u ON u.id = o.owner_id"))
    assert owners == {1: "world", 2: "alice", 3: "bob", 4: "world"}, owners  # removed ones keep their owner
    assert stored(db, "SELECT count(*) FROM account_tokens") == [(0,)]
    assert list(listed(db)) == ["world"]
    assert listed(db)["world"]["objects"] == 2

    # A new alice is a new account, with nothing of the old one's.
    _, out, _ = user("add", "alice", "--password-stdin", "--csv", db=db, password="pw2\n")
    rows = list(csv.DictReader(io.StringIO(out, newline="")))
    assert len(rows) == 1 and rows[0]["id"] == "3" and rows[0]["objects"] == "0", rows
    _, out, _ = user("del", "alice", "--json", db=db)
    assert json.loads(out) == [{"id": 3, "name": "alice", "objects_to_world": 0}], out


def test_terminal_prompt():
    """On a terminal: asked twice, nothing echoed; two different answers
    write nothing."""
    db = fresh_db()

    def on_tty(argv, answers):
        """Runs cvre-admin user ARGV on a new terminal, typing each answer
        after a prompt (a line ending in a colon); at most 30 s in all."""
        pid, fd = pty.fork()
        if pid == 0:
            os.execv(os.path.join(A.bin, "cvre-admin"), ["cvre-admin", "--db", db, "user"] + argv)
        seen, end, todo, done = b"", time.time() + 30, list(answers), False
        try:
            while not done:
                assert time.time() < end, f"cvre-admin user {argv} hangs; it wrote {seen!r}"
                if todo and seen.rstrip().endswith(b":"):
                    seen += b"|"  # where an answer went in
                    os.write(fd, todo.pop(0))
                if select.select([fd], [], [], 0.2)[0]:
                    try:
                        chunk = os.read(fd, 4096)
                    except OSError:  # the child closed the terminal
                        chunk = b""
                    seen += chunk
                    done = not chunk
        finally:
            if not done:
                os.kill(pid, 9)
            _, status = os.waitpid(pid, 0)
            os.close(fd)
        return os.waitstatus_to_exitcode(status), seen.decode()

    rc, text = on_tty(["add", "carol"], [b"typed secret\n", b"typed secret\n"])
    assert rc == 0, text
    assert text.startswith("New password for carol: |\r\nAgain: |\r\nid"), text
    assert "typed secret" not in text, text
    before = stored(db, "SELECT password_hash, password_at FROM accounts WHERE name = 'carol'")
    rc, text = on_tty(["passwd", "carol"], [b"first\n", b"second\n"])
    assert rc == 2 and "the two passwords differ; nothing written" in text, text
    assert "first" not in text and "second" not in text, text
    assert stored(db, "SELECT password_hash, password_at FROM accounts WHERE name = 'carol'") == before


def test_unusable_databases():
    db = fresh_db()
    tmp = tempfile.mkdtemp(prefix="cvre-accounts-")
    TEMP_DIRS.append(tmp)
    old = os.path.join(tmp, "old.db")
    copy_with_schema(db, old, 4)
    _, out, _ = admin("--version")
    schema = int(out.rsplit("schema version ", 1)[1].rstrip(")\n"))  # 5 brought accounts; later ones migrate too
    assert schema >= 5, out
    for argv in (["list"], ["add", "dave", "--password-stdin"], ["del", "world"]):
        _, _, err = user(*argv, db=old, password="pw\n", check=3)
        assert f"schema version 4, this build expects {schema}" in err, err
    assert stored(old, "PRAGMA user_version") == [(4,)]
    _, _, err = user("add", "dave", "--password-stdin", db=os.path.join(tmp, "missing.db"), password="pw\n", check=3)
    assert "No such file" in err, err
    assert not os.path.exists(os.path.join(tmp, "missing.db"))
    # list reads only: the file does not change.
    copy = os.path.join(tmp, "copy.db")
    shutil.copy(db, copy)
    with open(copy, "rb") as f:
        before = f.read()
    admin("user", "list", db=copy)
    with open(copy, "rb") as f:
        assert f.read() == before


def test_help():
    _, out, _ = admin("--help")
    for words in ("user add NAME [--admin]", "user del NAME", "user list", "user passwd NAME", "--password-stdin"):
        assert words in out, words
    _, out, _ = admin("user", "--help")
    assert out.startswith("usage: cvre-admin user add NAME [--admin] [--password-stdin]"), out
    for words in ("user del NAME", "user list", "user passwd NAME", "Exit 1", "reserved"):
        assert words in out, words
    _, out2, _ = admin("help", "user")
    assert out2 == out
    _, out3, _ = admin("user", "add", "--help")
    assert out3 == out


run([test_add_and_list_every_form, test_refusals, test_passwd_revokes_tokens, test_del_hands_objects_to_world,
     test_terminal_prompt, test_unusable_databases, test_help])
