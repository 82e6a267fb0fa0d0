"""Collision map versions end to end through cvre-admin: `versions` shows
each version's history, `diff` what changed between two versions (exact
coordinates, duplicates counted), `rollback` writes a new version with an
old version's boxes as db_ecm_write does (objects, versions, boxes and the
change feed), refuses what it must with the documented exit codes, never
writes when it refuses, never migrates, and a restarted server serves the
rolled-back boxes.

Objects come from a real server run (a world file); the refined versions a
voxel job would write are written here with sqlite3, statement for
statement as db/ecm.c's db_ecm_write writes them."""
import csv
import glob
import hashlib
import io
import json
import os
import sqlite3
import struct
import tempfile

from harness import MODELS, TEMP_DIRS, Raw, Server, admin, args, close_to, copy_with_schema, iso, run

# The newest schema version: one migration a version.
SCHEMA = len(glob.glob(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "db", "migrations", "*.sql")))
A = args()
ROOM = os.path.join(MODELS, "openings", "openfoam_room_with_doorway.stl")
ROOM_POS = (10.0, 0.0, 0.0)
T_REFINE = 1795000000.5  # exact in binary: created times compare exactly

# Version 2 (a refinement, run 1, clusters 0 and 1) and version 3 (run 2,
# cluster 0) of the room: walls W and E, floor F, roof R; every coordinate
# exact in float32. Version 3 lists W twice, in another order.
W = (-5.5, 0.0, -4.25, -5.25, 2.75, 0.25)
E = (0.0, 0.0, -4.25, 0.25, 2.75, 0.25)
F = (-5.5, -0.125, -4.25, 0.25, 0.0, 0.25)
R = (-5.5, 2.75, -4.25, 0.25, 2.875, 0.25)
V2 = [W, E, F]
V3 = [E, W, R, W]


def f32(x):
    return struct.unpack("<f", struct.pack("<f", x))[0]


def volume(b):
    return (b[3] - b[0]) * (b[4] - b[1]) * (b[5] - b[2])


def table(text):
    """A table's header and rows (cells split on runs of 2+ spaces)."""
    lines = text.rstrip("\n").split("\n")
    assert set(lines[1].replace(" ", "")) <= {"-"}, lines[:2]
    split = lambda line: [f.strip() for f in line.strip().split("  ") if f.strip() != ""]
    return split(lines[0]), [split(line) for line in lines[2:]]


def record(text):
    """A vertical record's fields."""
    return dict(line.split(None, 1) if " " in line else (line, "") for line in text.strip().split("\n"))


def write_version(path, obj, parent, boxes, reason="refine", run_id=None, clusters=(), restores=None, detail=None,
                  at=T_REFINE):
    """db_ecm_write, in Python: one IMMEDIATE transaction with the same
    checks and rows. Returns the new version."""
    db = sqlite3.connect(path, isolation_level=None)
    db.execute("PRAGMA foreign_keys = ON")
    db.execute("BEGIN IMMEDIATE")
    try:
        in_force, removed = db.execute("SELECT ecm_version, removed_at FROM objects WHERE id = ?", (obj,)).fetchone()
        assert removed is None and in_force == parent, (in_force, removed)
        v = db.execute("SELECT coalesce(max(version), 0) + 1 FROM ecm_versions WHERE object_id = ?",
                       (obj,)).fetchone()[0]
        db.execute("INSERT INTO ecm_versions(object_id, version, created_at, reason, box_count, parent_version, "
                   "run_id, restores, detail) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                   (obj, v, at, reason, len(boxes), parent, run_id, restores, detail))
        db.executemany("INSERT INTO ecm_boxes(object_id, version, box_index, min_x, min_y, min_z, max_x, max_y, max_z) "
                       "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)", [(obj, v, i, *map(f32, b)) for i, b in enumerate(boxes)])
        db.executemany("INSERT OR IGNORE INTO ecm_version_clusters(object_id, version, run_id, cluster_id) "
                       "VALUES (?, ?, ?, ?)", [(obj, v, run_id, c) for c in clusters])
        db.execute("UPDATE objects SET ecm_version = ? WHERE id = ? AND ecm_version = ?", (v, obj, parent))
        db.execute("INSERT INTO ecm_events(object_id, version, at, reason) VALUES (?, ?, ?, ?)", (obj, v, at, reason))
        db.execute("COMMIT")
    except BaseException:
        db.execute("ROLLBACK")
        raise
    finally:
        db.close()
    return v


def add_run(path, run_id, obj, clusters):
    """A cvre-cluster run that found `clusters` clusters on obj's version 1."""
    db = sqlite3.connect(path)
    db.execute("INSERT INTO cluster_runs(id, started_at, finished_at, eps, min_points, min_users, objects, points, "
               "clusters, problem_boxes) VALUES (?, 1, 2, 0.5, 5, 3, 1, 100, ?, 1)", (run_id, clusters))
    db.executemany("INSERT INTO clusters VALUES (?, ?, 1, ?, 20, 3, 0, 1, 0, 0, 0, 0, 1, 1, 1, 0)",
                   [(run_id, obj, c) for c in range(clusters)])
    db.commit()
    db.close()


def query(path, sql, *params):
    db = sqlite3.connect(path)
    try:
        return db.execute(sql, params).fetchall()
    finally:
        db.close()


def boxes_of(path, obj, v):
    return [tuple(r) for r in query(path, "SELECT min_x, min_y, min_z, max_x, max_y, max_z FROM ecm_boxes "
                                          "WHERE object_id = ? AND version = ? ORDER BY box_index", obj, v)]


def state(path):
    """Everything a rollback writes."""
    return (query(path, "SELECT id, ecm_version FROM objects ORDER BY id"),
            query(path, "SELECT * FROM ecm_versions ORDER BY object_id, version"),
            query(path, "SELECT count(*) FROM ecm_boxes"), query(path, "SELECT * FROM ecm_events ORDER BY id"))


def snapshot(path):
    """The database file and its WAL (contents and time stamps): a reader
    may create an empty -wal, but must not change either."""
    out = {}
    for suffix in ("", "-wal"):
        p = path + suffix
        if os.path.exists(p) and (suffix == "" or os.path.getsize(p) > 0):
            st = os.stat(p)
            with open(p, "rb") as f:
                out[suffix] = (st.st_mtime_ns, st.st_size, hashlib.sha256(f.read()).hexdigest())
    return out


def make_db():
    """Two rooms imported by the real server from a world file; the second
    then removed; versions 2 and 3 of the first written as a refinement
    job would."""
    tmp = tempfile.mkdtemp(prefix="cvre-versions-")
    TEMP_DIRS.append(tmp)
    world = os.path.join(tmp, "two.world")
    with open(world, "w") as f:
        f.write(f"object {ROOM} name room up z at {ROOM_POS[0]} {ROOM_POS[1]} {ROOM_POS[2]}\n"
                f"object {ROOM} name gone up z at -10 0 0\n")
    srv = Server(A.bin, "--world", world)
    assert srv.stop() == 0
    db = sqlite3.connect(srv.db)
    assert db.execute("PRAGMA user_version").fetchone()[0] == SCHEMA
    db.execute("UPDATE objects SET removed_at = 1795000000 WHERE name = 'gone'")
    db.commit()
    db.close()
    assert query(srv.db, "SELECT id, name, ecm_version FROM objects ORDER BY id") == [(1, "room", 1), (2, "gone", 1)]
    add_run(srv.db, 1, 1, 2)
    add_run(srv.db, 2, 1, 1)
    assert write_version(srv.db, 1, 1, V2, run_id=1, clusters=(1, 0), detail="depth 6") == 2
    assert write_version(srv.db, 1, 2, V3, run_id=2, clusters=(0,), at=T_REFINE + 60) == 3
    return srv.db


DB = make_db()
MBR = boxes_of(DB, 1, 1)[0]
IMPORTED = query(DB, "SELECT created_at FROM ecm_versions WHERE object_id = 1 AND version = 1")[0][0]


def test_versions_history():
    _, out, _ = admin("versions", 1, "--json", db=DB)
    common = dict(restores=None, collisions=0)
    assert json.loads(out) == [
        dict(version=1, created=iso(IMPORTED), reason="import", parent=None, run=None, clusters=None, boxes=1,
             current=False, detail=None, **common),
        dict(version=2, created=iso(T_REFINE), reason="refine", parent=1, run=1, clusters="0,1", boxes=3,
             current=False, detail="depth 6", **common),
        dict(version=3, created=iso(T_REFINE + 60), reason="refine", parent=2, run=2, clusters="0", boxes=4,
             current=True, detail=None, **common)], out
    _, out, _ = admin("versions", 1, db=DB)
    head, rows = table(out)
    assert head == ["version", "created", "reason", "parent", "run", "clusters", "restores", "boxes", "collisions",
                    "current", "detail"], head
    assert rows[1] == ["2", iso(T_REFINE, 3), "refine", "1", "1", "0,1", "-", "3", "0", "no", "depth 6"], rows
    assert rows[2] == ["3", iso(T_REFINE + 60, 3), "refine", "2", "2", "0", "-", "4", "0", "yes", "-"], rows
    assert [r[9] for r in rows] == ["no", "no", "yes"], rows
    _, out, _ = admin("versions", 1, "--csv", db=DB)
    got = list(csv.DictReader(io.StringIO(out, newline="")))
    assert [(r["version"], r["clusters"], r["current"], r["detail"]) for r in got] == \
        [("1", "", "0", ""), ("2", "0,1", "0", "depth 6"), ("3", "0", "1", "")], got
    # A removed object's history is still readable.
    _, out, _ = admin("versions", 2, "--json", db=DB)
    assert [(r["version"], r["reason"], r["current"]) for r in json.loads(out)] == [(1, "import", True)], out
    admin("versions", 99, db=DB, check=1)


def expected_diff(a, b):
    """The diff of two box lists, matched as multisets on exact coordinates."""
    left = list(enumerate(b))
    both, only_a = [], []
    for i, box in enumerate(a):
        j = next((k for k, (_, x) in enumerate(left) if x == box), None)
        if j is None:
            only_a.append(("only_a", i, None, box))
        else:
            both.append(("both", i, left[j][0], box))
            del left[j]
    only_b = [("only_b", None, i, box) for i, box in left]
    return only_a + sorted(only_b, key=lambda r: r[2]) + both


def as_json(rows):
    return [dict(change=c, box_a=i, box_b=j, min_x=x[0], min_y=x[1], min_z=x[2], max_x=x[3], max_y=x[4],
                 max_z=x[5], volume=volume(x)) for c, i, j, x in rows]


CORNERS = ("min_x", "min_y", "min_z", "max_x", "max_y", "max_z")


def f32(v):
    """v as the float it prints as: box corners were floats before they were
    stored, and print with the fewest digits that read back as that float."""
    return struct.unpack("<f", struct.pack("<f", float(v)))[0]


def test_diff():
    for a, b, ba, bb in ((1, 2, [MBR], V2), (2, 3, V2, V3), (3, 2, V3, V2), (3, 3, V3, V3)):
        _, out, _ = admin("diff", 1, a, b, "--json", db=DB)
        got = json.loads(out)
        want = expected_diff(ba, bb)
        boxes = [{k: f32(v) if k in CORNERS else v for k, v in r.items()} for r in got["boxes"]]
        assert boxes == as_json(want), (a, b, got["boxes"], want)
        s = got["summary"]
        count = lambda kind: len([r for r in want if r[0] == kind])
        assert {k: v for k, v in s.items() if not k.startswith("volume")} == dict(
            object=1, a=a, b=b, boxes_a=len(ba), boxes_b=len(bb), only_a=count("only_a"), only_b=count("only_b"),
            both=count("both")), s
        assert abs(s["volume_a"] - sum(map(volume, ba))) < 1e-9 and abs(s["volume_b"] - sum(map(volume, bb))) < 1e-9, s
    # 2 -> 3: W and E stay (at other indexes), F goes, R and a second W come.
    _, out, _ = admin("diff", 1, 2, 3, "--json", db=DB)
    assert [(r["change"], r["box_a"], r["box_b"]) for r in json.loads(out)["boxes"]] == [
        ("only_a", 2, None), ("only_b", None, 2), ("only_b", None, 3), ("both", 0, 1), ("both", 1, 0)], out
    # The table: the summary, a blank line, the boxes to 3 decimals.
    _, out, _ = admin("diff", 1, 2, 3, db=DB)
    summary, boxes = out.split("\n\n")
    fields = record(summary)
    assert (fields["only_a"], fields["only_b"], fields["both"], fields["boxes_a"], fields["boxes_b"]) == \
        ("1", "2", "2", "3", "4"), fields
    assert fields["volume_a"] == f"{sum(map(volume, V2)):.3f}", fields
    head, rows = table(boxes)
    assert head == ["change", "box_a", "box_b", "min_x", "min_y", "min_z", "max_x", "max_y", "max_z", "volume"]
    assert rows[0] == ["only_a", "2", "-", "-5.500", "-0.125", "-4.250", "0.250", "0.000", "0.250",
                       f"{volume(F):.3f}"], rows
    assert [r[0] for r in rows] == ["only_a", "only_b", "only_b", "both", "both"], rows
    # CSV: the boxes, every corner the float stored.
    _, out, _ = admin("diff", 1, 1, 2, "--csv", db=DB)
    got = list(csv.DictReader(io.StringIO(out, newline="")))
    assert [(r["change"], r["box_a"], r["box_b"]) for r in got] == [
        ("only_a", "0", ""), ("only_b", "", "0"), ("only_b", "", "1"), ("only_b", "", "2")], got
    assert tuple(f32(got[0][k]) for k in CORNERS) == MBR, got[0]
    # Errors: no object, no version, bad arguments.
    rc, out, err = admin("diff", 99, 1, 2, db=DB, check=1)
    assert "no object with id 99" in err and out == "", err
    rc, out, err = admin("diff", 1, 1, 9, db=DB, check=1)
    assert "object 1 has no version 9 (its versions: 1 to 3)" in err and out == "", err
    for argv in (["diff", 1, 2], ["diff", 1, 2, "x"], ["diff", 1, 0, 2], ["diff", 1, 2, 3, 4], ["diff", 1, -1, 2],
                 ["diff", 1, 2, 4294967296]):
        rc, out, err = admin(*argv, db=DB, check=2)
        assert err.startswith("cvre-admin diff") and out == "", (argv, err)


def test_reads_change_nothing():
    before = snapshot(DB)
    for argv in (["versions", 1], ["diff", 1, 1, 3], ["diff", 1, 2, 3, "--json"], ["diff", 99, 1, 1]):
        admin(*argv, db=DB, check=None)
    assert snapshot(DB) == before


def test_rollback_refusals():
    before, files = state(DB), snapshot(DB)
    for argv, code, message in (
            (["rollback", 1, 3], 4, "version 3 is already in force for object 1: nothing to do"),
            (["rollback", 99, 1], 1, "no object with id 99"),
            (["rollback", 1, 9], 1, "object 1 has no version 9"),
            (["rollback", 2, 1], 4, "object 2 was removed"),
            (["rollback", 1], 2, "wants an object id and a version"),
            (["rollback", 1, 0], 2, "version number"),
            (["rollback", 1, 2, 3], 2, "unexpected argument")):
        rc, out, err = admin(*argv, db=DB, check=code)
        assert message in err and out == "", (argv, err)
    # Refused before the read-write open: the file is not even touched.
    assert state(DB) == before and snapshot(DB) == files
    tmp = tempfile.mkdtemp(prefix="cvre-versions-")
    TEMP_DIRS.append(tmp)
    rc, _, err = admin("rollback", 1, 1, db=os.path.join(tmp, "missing.db"), check=3)
    assert "No such file" in err and not os.path.exists(os.path.join(tmp, "missing.db")), err
    # Another schema version: refused, and never migrated.
    for v in (3, 99):
        other = os.path.join(tmp, f"v{v}.db")
        copy_with_schema(DB, other, v)
        rc, _, err = admin("rollback", 1, 1, db=other, check=3)
        assert f"schema version {v}" in err, err
        assert query(other, "PRAGMA user_version") == [(v,)]
        assert query(other, "SELECT max(version) FROM ecm_versions WHERE object_id = 1") == [(3,)]


def test_rollback_writes_a_new_version():
    events = query(DB, "SELECT id, object_id, version, reason FROM ecm_events ORDER BY id")
    assert [e[1:] for e in events] == [(1, 2, "refine"), (1, 3, "refine")], events
    # While the server runs on the database (it writes sessions meanwhile).
    srv = Server(A.bin, db=DB)  # no world file: it would import the removed room again
    c = Raw(srv.port)
    c.handshake("watcher")
    rc, out, err = admin("rollback", 1, 1, db=DB)
    fields = record(out)
    assert fields["object"] == "1" and fields["version"] == "4" and fields["parent"] == "3" and \
        fields["restores"] == "1" and fields["reason"] == "rollback" and fields["boxes"] == "1", out
    c.close()
    assert srv.stop() == 0
    assert query(DB, "SELECT ecm_version FROM objects WHERE id = 1") == [(4,)]
    row = query(DB, "SELECT reason, box_count, parent_version, run_id, restores, detail, created_at "
                    "FROM ecm_versions WHERE object_id = 1 AND version = 4")[0]
    assert row[:6] == ("rollback", 1, 3, None, 1, "cvre-admin rollback"), row
    assert boxes_of(DB, 1, 4) == [MBR]
    assert query(DB, "SELECT count(*) FROM ecm_version_clusters WHERE version = 4") == [(0,)]
    after = query(DB, "SELECT id, object_id, version, at, reason FROM ecm_events ORDER BY id")
    assert after[:2] == [e[:3] + (T_REFINE + 60 * i, e[3]) for i, e in enumerate(events)], after
    assert after[2] == (events[-1][0] + 1, 1, 4, row[6], "rollback"), after
    assert fields["created"] == iso(row[6], 3), (fields, row)
    # Version 4 has version 1's boxes: a second rollback to 1 has nothing to do.
    rc, out, err = admin("rollback", 1, 1, db=DB, check=4)
    assert "version 4 in force for object 1 already has version 1's boxes: nothing to do" in err, err
    # To 2, in JSON: version 5 with version 2's boxes, exactly.
    _, out, _ = admin("--json", "rollback", 1, 2, db=DB)
    got = json.loads(out)
    assert len(got) == 1 and {k: got[0][k] for k in ("object", "version", "parent", "restores", "reason", "boxes",
                                                     "detail")} == dict(
        object=1, version=5, parent=4, restores=2, reason="rollback", boxes=3, detail="cvre-admin rollback"), got
    assert boxes_of(DB, 1, 5) == [tuple(map(f32, b)) for b in V2]
    assert query(DB, "SELECT ecm_version FROM objects WHERE id = 1") == [(5,)]
    assert [e[1:] for e in query(DB, "SELECT id, version FROM ecm_events ORDER BY id")] == [(2,), (3,), (4,), (5,)]
    # The history shows it, and diff agrees that 5 is 2.
    _, out, _ = admin("versions", 1, "--json", db=DB)
    hist = json.loads(out)
    assert [(r["version"], r["reason"], r["parent"], r["restores"], r["current"]) for r in hist[3:]] == [
        (4, "rollback", 3, 1, False), (5, "rollback", 4, 2, True)], hist
    _, out, _ = admin("diff", 1, 2, 5, "--json", db=DB)
    s = json.loads(out)["summary"]
    assert (s["only_a"], s["only_b"], s["both"]) == (0, 0, 3), s


def test_restarted_server_serves_the_rolled_back_boxes():
    assert query(DB, "SELECT ecm_version FROM objects WHERE id = 1") == [(5,)]
    srv = Server(A.bin, db=DB)  # everything from the database
    c = Raw(srv.port)
    c.handshake("late")
    obj = c.expect("object", where=lambda m: m["id"] == 1)
    assert obj["ecm_version"] == 5 and len(obj["boxes"]) == 3, obj
    # World coordinates: the room is placed at ROOM_POS without rotation.
    for got, box in zip(obj["boxes"], V2):
        assert close_to(got, [v + ROOM_POS[k % 3] for k, v in enumerate(box)], 1e-5), (got, box)
    assert not [m for m in c.poll(0.5) if m["type"] == "object" and m["id"] == 2], "a removed object came back"
    c.close()
    assert srv.stop() == 0
    assert query(DB, "SELECT count(*) FROM objects") == [(2,)]


def test_help():
    for cmd in ("versions", "diff", "rollback"):
        _, out, _ = admin(cmd, "--help", db=DB)
        assert out.startswith(f"usage: cvre-admin {cmd}"), out
        _, out2, _ = admin("help", cmd, db=DB)
        assert out2 == out
    _, out, _ = admin("--help", db=DB)
    assert "diff ID A B" in out and "rollback ID K" in out and "  4  rollback refused" in out, out


run([test_versions_history, test_diff, test_reads_change_nothing, test_rollback_refusals,
     test_rollback_writes_a_new_version, test_restarted_server_serves_the_rolled_back_boxes, test_help])
