"""cvre-admin backup and retention against a running server whose clients
keep walking into a wall, so that the collision log writes all along: the
backup is one intact snapshot holding every row committed before it began,
and a server starts on it; retention removes exactly the old buckets it
reports, in more than one transaction, while the log goes on writing with
no lock error; bad arguments and an existing file are refused."""
import json
import math
import os
import re
import sqlite3
import time
from datetime import datetime

from harness import Client, Server, admin, args, run

A = args()
WORLD = os.path.join(os.path.dirname(os.path.abspath(__file__)), "room.world")
DAY = 86400.0
OLD_BUCKETS = 40       # 10 s buckets logged 40 days ago ...
OLD_PER_BUCKET = 2000  # ... of this many rows each, in two segments (batches)
OLD_USERS = 3          # user entries per old group


def add_old_log(path):
    """Writes a collision log 40 days old into the database at path, laid out
    as the log writer lays it out (db/README.md, "Collision log storage"):
    per bucket, four groups (two objects, two cells) with their R*Tree cells
    and user entries, and the rows as two segments sorted by (object,
    version, group). Returns (rows, groups, user entries, cutoff bucket)."""
    db = sqlite3.connect(path)
    t0 = math.floor((time.time() - 40 * DAY) / 10) * 10
    rows = groups = users = 0
    next_id = 1
    for k in range(OLD_BUCKETS):
        bucket = int(t0 // 10) + k
        gs = []
        for obj in (1001, 1002):
            for cx in (0, 1):
                g = db.execute("INSERT INTO collision_groups(object_id, ecm_version, bucket, cell_x, cell_y, cell_z) "
                               "VALUES (?, 1, ?, ?, 0, 0)", (obj, bucket, cx)).lastrowid
                db.execute("INSERT INTO collision_cells VALUES (?, ?, ?, 0, 4, 0, 4, ?, ?)",
                           (g, cx * 4.0, cx * 4.0 + 4.0, bucket * 10.0, bucket * 10.0 + 10.0))
                for u in range(OLD_USERS):
                    db.execute("INSERT INTO collision_users VALUES (?, ?)", (1000 + u, g))
                gs.append((obj, cx, g))
        groups += len(gs)
        users += len(gs) * OLD_USERS
        half = OLD_PER_BUCKET // 2
        for seg in range(2):
            first = next_id
            for i in range(half):
                obj, cx, g = gs[i * len(gs) // half]  # sorted by object, then group
                x = cx * 4.0 + 1.0
                at = bucket * 10.0 + (seg * half + i) * 10.0 / OLD_PER_BUCKET
                db.execute("INSERT INTO collisions VALUES (?, ?, ?, 1, ?, 1, ?, 1, 0, 0, 0, 0, 0, ?, 1, 1, ?, 1, 1, "
                           "-1, 0, 0, 1, 0, 0)", (next_id, g, at, 1000 + i % OLD_USERS, obj, x, x))
                next_id += 1
            db.execute("INSERT INTO collision_segments VALUES (?, ?, ?)", (first, next_id - 1, bucket))
        rows += OLD_PER_BUCKET
    db.commit()
    db.close()
    return rows, groups, users, int(t0 // 10) + OLD_BUCKETS


def scalar(path, sql, *params):
    db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        return db.execute(sql, params).fetchone()[0]
    finally:
        db.close()


def wait_for(what, cond, timeout=60):
    end = time.time() + timeout
    while not cond():
        assert time.time() < end, f"no {what} within {timeout} s"
        time.sleep(0.2)


def walkers(port, n):
    """n real clients that walk east into the room's west wall and keep
    pushing (about 20 collisions a second each) for up to two minutes."""
    return [Client(A.bin, port, f"walker{i}", "walk 240 0 120\nquit\n", "--rate", "20") for i in range(n)]


def check_intact(path):
    db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        assert db.execute("PRAGMA integrity_check").fetchall() == [("ok",)]
        assert db.execute("SELECT rtreecheck('collision_cells')").fetchone()[0] == "ok"
        assert db.execute("PRAGMA journal_mode").fetchone()[0] == "delete"
    finally:
        db.close()
    assert not os.path.exists(path + "-wal"), "the copy is one file"


def new_rows(path, after_id):
    return scalar(path, "SELECT count(*) FROM collisions WHERE id > ?", after_id)


def test_backup_and_retention_beside_a_colliding_server():
    first = Server(A.bin)  # makes the schema
    assert first.stop() == 0
    old_rows, old_groups, old_users, cut = add_old_log(first.db)
    srv = Server(A.bin, "--world", WORLD, "--spawn-radius", "0", "--max-speed", "20", "--refine-interval", "0",
                 "--max-per-address", "0", "--joins-per-second", "0", db=first.db)
    cs = walkers(srv.port, 4)
    try:
        wait_for("collisions", lambda: new_rows(srv.db, old_rows) >= 200)

        # Backups while the log writes: each holds every row committed before it began.
        for method in ("pages", "vacuum"):
            copy = os.path.join(srv.tmp, f"copy-{method}.db")
            top = scalar(srv.db, "SELECT max(id) FROM collisions")
            committed = scalar(srv.db, "SELECT count(*) FROM collisions")
            sessions = scalar(srv.db, "SELECT count(*) FROM sessions")
            _, out, _ = admin("--db", srv.db, "--json", "backup", copy, *(["--vacuum"] if method == "vacuum" else []))
            rec = json.loads(out)[0]
            assert rec["file"] == copy and rec["method"] == method and rec["integrity"] == "ok", rec
            assert rec["bytes"] == os.path.getsize(copy) and rec["schema"] >= 7, rec
            check_intact(copy)
            assert scalar(copy, "SELECT count(*) FROM collisions WHERE id <= ?", top) == committed
            assert scalar(copy, "SELECT count(*) FROM collisions") >= committed
            assert scalar(copy, "SELECT count(*) FROM sessions") >= sessions
            assert oct(os.stat(copy).st_mode & 0o777) == "0o600"
            # Never over an existing file, whatever it holds.
            rc, _, err = admin("--db", srv.db, "backup", copy, check=4)
            assert "exists" in err and "nothing written" in err, err
        assert not [f for f in os.listdir(srv.tmp) if ".partial-" in f], os.listdir(srv.tmp)

        # Retention while the log writes.
        before = new_rows(srv.db, old_rows)
        _, out, _ = admin("--db", srv.db, "--json", "retention", "--older-than", "30")
        rec = json.loads(out)[0]
        assert rec["collisions"] == old_rows and rec["segments"] == 2 * OLD_BUCKETS, rec
        assert rec["groups"] == old_groups and rec["cells"] == old_groups, rec
        assert rec["user_entries"] == old_users, rec
        assert rec["transactions"] >= 2, rec  # more rows and entries than one transaction may take
        cutoff = datetime.fromisoformat(rec["cutoff"].replace("Z", "+00:00")).timestamp()
        assert cutoff % 10 == 0 and abs(cutoff - (time.time() - 30 * DAY)) < 600, rec
        assert scalar(srv.db, "SELECT count(*) FROM collisions WHERE id <= ?", old_rows) == 0
        assert scalar(srv.db, "SELECT count(*) FROM collision_groups WHERE bucket < ?", cut) == 0
        assert scalar(srv.db, "SELECT count(*) FROM collision_segments WHERE bucket < ?", cut) == 0
        # Nothing of the live log went, and it goes on growing.
        assert new_rows(srv.db, old_rows) >= before
        grown = new_rows(srv.db, old_rows)
        wait_for("more collisions after retention", lambda: new_rows(srv.db, old_rows) > grown)
        # Again: nothing left to do.
        _, out, _ = admin("--db", srv.db, "--json", "retention", "--older-than", "30")
        rec = json.loads(out)[0]
        assert rec["collisions"] == 0 and rec["groups"] == 0, rec
        _, out, _ = admin("--db", srv.db, "--json", "collisions", "--limit", "3")
        assert len(json.loads(out)) == 3
    finally:
        for c in cs:
            c.proc.kill()
            c.proc.wait()
    assert srv.stop() == 0
    log = srv.logtext()
    # No warning or error: the log writer reports each failed batch, loss and drop.
    bad = [line for line in log.splitlines() if " WARN " in line or " ERROR " in line or "locked" in line]
    assert not bad, "\n".join(bad)
    assert " 0 dropped, 0 lost" in log, log
    db = sqlite3.connect(srv.db)
    assert db.execute("PRAGMA integrity_check").fetchall() == [("ok",)]
    assert db.execute("SELECT rtreecheck('collision_cells')").fetchone()[0] == "ok"
    db.close()

    # A server starts on the copy, which is all a restore needs.
    restored = Server(A.bin, db=os.path.join(srv.tmp, "copy-pages.db"))
    assert restored.stop() == 0


def test_refusals():
    srv = Server(A.bin)
    assert srv.stop() == 0
    for argv in (("backup",), ("backup", "a", "b"), ("backup", ""), ("backup", "x", "--older-than", "3"),
                 ("retention",), ("retention", "--older-than", "0"), ("retention", "--older-than", "36501"),
                 ("retention", "--older-than", "1.5"), ("retention", "--older-than", "3", "extra"),
                 ("retention", "--vacuum", "--older-than", "3")):
        rc, _, err = admin("--db", srv.db, *argv, check=2)
        assert "--help" in err, (argv, err)
    rc, _, err = admin("--db", srv.db, "backup", os.path.join(srv.tmp, "missing", "x.db"), check=3)
    assert "cannot write beside" in err, err
    rc, _, err = admin("--db", os.path.join(srv.tmp, "none.db"), "backup", os.path.join(srv.tmp, "y.db"), check=3)
    assert not os.path.exists(os.path.join(srv.tmp, "y.db"))
    # Stopped part way (a trigger refuses the last old row, beyond what one
    # transaction may take): what went stays gone, the message says so, and
    # the next run finishes.
    old_rows = add_old_log(srv.db)[0]
    db = sqlite3.connect(srv.db)
    db.execute(f"CREATE TRIGGER stop BEFORE DELETE ON collisions WHEN old.id = {old_rows} "
               "BEGIN SELECT RAISE(ABORT, 'refused by a test'); END")
    db.commit()
    rc, _, err = admin("--db", srv.db, "retention", "--older-than", "30", check=3)
    m = re.search(r"retention stopped: refused by a test; (\d+) collisions were removed before \(run it again", err)
    assert m and 0 < int(m.group(1)) < old_rows, err
    db.execute("DROP TRIGGER stop")
    db.commit()
    db.close()
    _, out, _ = admin("--db", srv.db, "--json", "retention", "--older-than", "30")
    assert json.loads(out)[0]["collisions"] == old_rows - int(m.group(1)), out
    assert scalar(srv.db, "SELECT count(*) FROM collisions") == 0
    _, out, _ = admin("backup", "--help")
    assert out.startswith("usage: cvre-admin backup FILE") and "WAL" in out
    _, out, _ = admin("help", "retention")
    assert out.startswith("usage: cvre-admin retention --older-than DAYS") and "WAL" in out


run([test_backup_and_retention_beside_a_colliding_server, test_refusals])
