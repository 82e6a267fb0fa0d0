"""cvre-admin against a database made by the real migrations (a cvre-server
run) and filled with known rows: every query returns exactly the expected
rows in table, CSV and JSON form; bad arguments and unusable databases get
their exit codes; the tool never modifies the file; and it answers while a
writer keeps committing in WAL mode."""
import calendar
import csv
import hashlib
import io
import json
import math
import os
import random
import shutil
import sqlite3
import struct
import tempfile
import threading
import time

from harness import TEMP_DIRS, Server, admin, args, copy_with_schema, iso, run

A = args()
T0 = calendar.timegm((2026, 11, 22, 10, 0, 0))  # 2026-11-22T10:00:00Z


# ---- the known database ------------------------------------------------------

USERS = {1: "alice", 2: "bob", 3: "carol", 4: 'dave, "the quoted"'}
# id, user, peer, avatar, started, joined, ended, reason
SESSIONS = [
    (1, 1, "127.0.0.1:5001", 65536, T0, T0 + 1, T0 + 1800, "quit"),
    (2, 2, "127.0.0.1:5002", 65537, T0 + 600, T0 + 601, T0 + 3600, "closed without bye"),
    (3, 3, "127.0.0.1:5003", 65538, T0 + 2400, T0 + 2401, None, None),
    (4, 1, "127.0.0.1:5004", 65539, T0 + 7200, T0 + 7201, T0 + 7500, "quit"),
    (5, None, "127.0.0.1:5005", None, T0 - 3600, None, T0 - 3595, "closed without bye"),
    (6, 4, "127.0.0.1:5006", 65540, T0 + 60, T0 + 61, T0 + 120, "quit"),
]
# id, owner, name, format, created, removed, pos, yaw, scale, version, tris, mbr
OBJECTS = [
    (1, 1, "arch.glb", "glb", T0 - 100, None, (10.0, 0.0, 20.0), 0.5, 1.0, 2, 1234,
     (-2.0, 0.0, -0.5, 2.0, 3.0, 0.5)),
    (2, 2, "wall.obj", "obj", T0 - 90, None, (-5.0, 0.0, 7.5), 0.0, 2.0, 1, 12,
     (-4.0, 0.0, -0.25, 4.0, 2.5, 0.25)),
    (3, 3, "gone.stl", "stl", T0 - 80, T0 + 50, (0.0, 0.0, 0.0), 0.0, 1.0, 1, 4, (0.0, 0.0, 0.0, 1.0, 1.0, 1.0)),
]
# object, version, created, reason, boxes
VERSIONS = [(1, 1, T0 - 100, "import", 1), (1, 2, T0 + 150, "refine", 3), (2, 1, T0 - 90, "import", 1),
            (3, 1, T0 - 80, "import", 1)]


def collision_rows():
    """60 collisions with every field known; times exact in binary."""
    rows = []
    users = [1, 2, 3, None, 4]
    objects = [1, 1, 2, 1, 3]
    for i in range(60):
        obj = objects[i % 5]
        rows.append(dict(
            id=i + 1, at=T0 + 10 * i + 0.25 * (i % 4), user=users[i % 5], session=100 + i % 7,
            avatar=65536 + i % 5, object=obj, version=2 if obj == 1 and i >= 20 else 1, box=i % 3,
            inside=1 if i % 11 == 0 else 0,
            world=(1.5 * (i % 10) - 3.0, 0.5 * (i % 3), 2.0 * (i // 10) - 5.0),
            local=(0.25 * (i % 8), 0.5, -0.125 * (i % 5)),
            normal=(1.0, 0.0, 0.0) if i % 2 else (0.0, 0.0, -1.0),
            vel=(-1.5, 0.0, 0.25 * (i % 3))))
    return rows


COLLISIONS = collision_rows()


def make_db():
    """A fresh database migrated by the real server, then filled."""
    srv = Server(A.bin)
    assert srv.stop() == 0
    db = sqlite3.connect(srv.db)
    db.executemany("INSERT INTO users(id, name, created_at, last_seen_at) VALUES (?, ?, ?, ?)",
                   [(k, v, T0 - 1000, T0) for k, v in USERS.items()])
    db.executemany("INSERT INTO sessions(id, user_id, token, peer, avatar_id, started_at, joined_at, ended_at, "
                   "end_reason) VALUES (?, ?, 'ab', ?, ?, ?, ?, ?, ?)",
                   [(s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7]) for s in SESSIONS])
    for o in OBJECTS:
        db.execute("INSERT INTO objects(id, owner_id, name, format, created_at, removed_at, pos_x, pos_y, pos_z, "
                   "yaw, scale, ecm_version, tri_count, min_x, min_y, min_z, max_x, max_y, max_z) "
                   "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                   (o[0], o[1], o[2], o[3], o[4], o[5], *o[6], o[7], o[8], o[9], o[10], *o[11]))
        db.execute("INSERT INTO meshes(object_id, triangles) VALUES (?, x'00')", (o[0],))
    db.executemany("INSERT INTO ecm_versions(object_id, version, created_at, reason, box_count) "
                   "VALUES (?, ?, ?, ?, ?)", VERSIONS)
    for obj, ver, _, _, boxes in VERSIONS:
        db.executemany("INSERT INTO ecm_boxes VALUES (?, ?, ?, 0, 0, 0, 1, 1, 1)",
                       [(obj, ver, b) for b in range(boxes)])
    insert_collisions(db, COLLISIONS)
    db.commit()
    db.close()
    return srv.db


BUCKET_S, CELL_M, BUCKET_MAX, CELL_MAX = 10.0, 4.0, 1 << 40, 1 << 24  # db/dblog.h


def bucket_of(at):
    return max(-BUCKET_MAX, min(BUCKET_MAX, math.floor(at / BUCKET_S)))


def cell_of(v):
    return max(-CELL_MAX, min(CELL_MAX, math.floor(v / CELL_M)))


def insert_collisions(db, rows):
    """Writes rows as one batch, laid out as the log writer (db/dblog.c)
    lays out its batches: each row in the group of its object, version,
    10 s bucket and 4 m cell (made with its rtree cell and time span if
    new), the users of
    each group noted, and the batch sorted by (bucket, object, version,
    group) under new ids, one segment per bucket. Sets each row's "id"."""
    next_id = db.execute("SELECT coalesce(max(id), 0) + 1 FROM collisions").fetchone()[0]
    keyed = []
    for c in rows:
        b, cell = bucket_of(c["at"]), tuple(cell_of(v) for v in c["world"])
        got = db.execute("SELECT g FROM collision_groups WHERE object_id = ? AND ecm_version = ? AND bucket = ? "
                         "AND cell_x = ? AND cell_y = ? AND cell_z = ?", (c["object"], c["version"], b, *cell)).fetchone()
        if got:
            g = got[0]
        else:
            g = db.execute("INSERT INTO collision_groups(object_id, ecm_version, bucket, cell_x, cell_y, cell_z) "
                           "VALUES (?, ?, ?, ?, ?, ?)", (c["object"], c["version"], b, *cell)).lastrowid
            box = []
            for k in cell:
                box += [-3e38 if k == -CELL_MAX else k * CELL_M, 3e38 if k == CELL_MAX else (k + 1) * CELL_M]
            box += [-3e38 if b == -BUCKET_MAX else b * BUCKET_S, 3e38 if b == BUCKET_MAX else (b + 1) * BUCKET_S]
            db.execute("INSERT INTO collision_cells VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)", (g, *box))
        if c["user"] is not None:
            db.execute("INSERT OR IGNORE INTO collision_users(user_id, g) VALUES (?, ?)", (c["user"], g))
        keyed.append(((b, c["object"], c["version"], g), c))
    keyed.sort(key=lambda k: k[0])
    first = next_id
    for i, (key, c) in enumerate(keyed):
        c["id"] = next_id + i
        db.execute("INSERT INTO collisions(id, g, at, session_id, user_id, avatar_id, object_id, ecm_version, "
                   "box_index, inside, avatar_x, avatar_y, avatar_z, world_x, world_y, world_z, local_x, local_y, "
                   "local_z, normal_x, normal_y, normal_z, vel_x, vel_y, vel_z) "
                   "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, 0, 0, 0, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                   (c["id"], key[3], c["at"], c["session"], c["user"], c["avatar"], c["object"], c["version"],
                    c["box"], c["inside"], *c["world"], *c["local"], *c["normal"], *c["vel"]))
        if i + 1 == len(keyed) or keyed[i + 1][0][0] != key[0]:
            db.execute("INSERT INTO collision_segments(first_id, last_id, bucket) VALUES (?, ?, ?)",
                       (first, c["id"], key[0]))
            first = c["id"] + 1


DB = make_db()

# ---- helpers to compare output with expectations -----------------------------


def as_json(c):
    """A collision as cvre-admin's JSON prints it."""
    return {"id": c["id"], "time": iso(c["at"]), "user": USERS.get(c["user"]), "session": c["session"],
            "avatar": c["avatar"], "object": c["object"], "version": c["version"], "box": c["box"],
            "inside": bool(c["inside"]), "world_x": c["world"][0], "world_y": c["world"][1],
            "world_z": c["world"][2], "local_x": c["local"][0], "local_y": c["local"][1], "local_z": c["local"][2],
            "normal_x": c["normal"][0], "normal_y": c["normal"][1], "normal_z": c["normal"][2],
            "velocity_x": c["vel"][0], "velocity_y": c["vel"][1], "velocity_z": c["vel"][2]}


def newest_first(rows):
    return sorted(rows, key=lambda c: (c["at"], c["id"]), reverse=True)


def table(text):
    """A table's header and rows, split on runs of two spaces or more after
    checking the rule line."""
    lines = text.rstrip("\n").split("\n")
    assert set(lines[1].replace(" ", "")) <= {"-"}, lines[:2]
    split = lambda line: [f for f in line.strip().split("  ") if f != ""]
    return [f.strip() for f in split(lines[0])], [[f.strip() for f in split(line)] for line in lines[2:]]


def check_collisions(argv, expected):
    """Runs `collisions argv` in all three forms and compares each with the
    expected rows (already filtered and ordered)."""
    _, out, _ = admin("collisions", *argv, "--json", db=DB)
    got = json.loads(out)
    assert got == [as_json(c) for c in expected], (argv, got[:2], [as_json(c) for c in expected][:2])

    _, out, _ = admin("collisions", *argv, "--csv", db=DB)
    rows = list(csv.reader(io.StringIO(out, newline="")))
    assert out.endswith("\r\n") and rows[0] == list(as_json(COLLISIONS[0]).keys()), rows[0]
    assert len(rows) == 1 + len(expected), (argv, len(rows))
    for r, c in zip(rows[1:], expected):
        j = as_json(c)
        want = [str(v) if isinstance(v, int) and not isinstance(v, bool) else v for v in j.values()]
        for k, (got_v, want_v) in enumerate(zip(r, want)):
            name = rows[0][k]
            if want_v is None:
                assert got_v == "", (name, got_v)
            elif isinstance(want_v, bool):
                assert got_v == ("1" if want_v else "0"), (name, got_v)
            elif isinstance(want_v, float):
                assert float(got_v) == want_v, (name, got_v, want_v)
            else:
                assert got_v == want_v, (name, got_v, want_v)

    _, out, _ = admin("collisions", *argv, db=DB)
    head, rows = table(out)
    assert head == ["id", "time", "user", "object", "version", "box", "inside", "world_x", "world_y", "world_z"], head
    assert len(rows) == len(expected), (argv, len(rows), len(expected))
    for r, c in zip(rows, expected):
        want = [str(c["id"]), iso(c["at"], 3), USERS.get(c["user"], "-"), str(c["object"]), str(c["version"]),
                str(c["box"]), "yes" if c["inside"] else "no"] + [f"{v:.3f}" for v in c["world"]]
        assert r == want, (r, want)


# ---- the tests -----------------------------------------------------------------


def test_collisions_every_form():
    check_collisions([], newest_first(COLLISIONS))
    check_collisions(["--limit", "7"], newest_first(COLLISIONS)[:7])
    check_collisions(["--limit", "0"], newest_first(COLLISIONS))


def test_collisions_filters():
    by = lambda f: newest_first([c for c in COLLISIONS if f(c)])
    check_collisions(["--object", "1"], by(lambda c: c["object"] == 1))
    check_collisions(["--user", "bob"], by(lambda c: c["user"] == 2))
    check_collisions(["--user", USERS[4]], by(lambda c: c["user"] == 4))
    # ISO and Unix seconds; --since inclusive, --until exclusive.
    check_collisions(["--since", "2026-11-22T10:01:40", "--until", T0 + 300],
                     by(lambda c: T0 + 100 <= c["at"] < T0 + 300))
    check_collisions(["--since", "2026-11-22 11:01:40+01:00", "--until", "2026-11-22T10:03:20.25Z"],
                     by(lambda c: T0 + 100 <= c["at"] < T0 + 200.25))
    check_collisions(["--since", "2026-11-22T05:02:30-0500"], by(lambda c: c["at"] >= T0 + 150))
    check_collisions(["--since", "2026-11-22T10:00:30Z", "--until", "2026-11-22T10:02"],
                     by(lambda c: T0 + 30 <= c["at"] < T0 + 120))
    # The region goes through the rtree; edges are inside.
    box = (-1.5, 0.0, -5.0, 3.0, 0.5, 1.0)
    inside = lambda c: all(box[k] <= c["world"][k] <= box[k + 3] for k in range(3))
    assert 0 < len(by(inside)) < 60
    check_collisions(["--region", ",".join(str(v) for v in box)], by(inside))
    check_collisions(["--region", ",".join(str(v) for v in box), "--object", "1", "--user", "alice",
                      "--since", T0 + 5, "--limit", "3"],
                     by(lambda c: inside(c) and c["object"] == 1 and c["user"] == 1 and c["at"] >= T0 + 5)[:3])
    check_collisions(["--object", "2", "--since", T0 + 10000], [])


def test_unknown_object_and_user():
    for argv in (["collisions", "--object", "99"], ["object", "99"], ["versions", "99"]):
        rc, out, err = admin(*argv, db=DB, check=1)
        assert "no object with id 99" in err and out == "", (argv, out, err)
    for argv in (["collisions", "--user", "nobody"], ["sessions", "--user", "nobody"]):
        rc, out, err = admin(*argv, db=DB, check=1)
        assert 'no user named "nobody"' in err and out == "", (argv, err)


def test_top_objects():
    def expect(lo=None, hi=None):
        rows = [c for c in COLLISIONS if (lo is None or c["at"] >= lo) and (hi is None or c["at"] < hi)]
        out = []
        for o in OBJECTS:
            mine = [c for c in rows if c["object"] == o[0]]
            if mine:
                out.append({"object": o[0], "name": o[2], "owner": USERS[o[1]], "collisions": len(mine),
                            "users": len({c["user"] for c in mine if c["user"] is not None}),
                            "first": iso(min(c["at"] for c in mine)), "last": iso(max(c["at"] for c in mine)),
                            "in_world": o[5] is None})
        return sorted(out, key=lambda r: (-r["collisions"], r["object"]))

    _, out, _ = admin("top-objects", "--json", db=DB)
    assert json.loads(out) == expect(), out
    _, out, _ = admin("top-objects", "--json", "--since", T0 + 200, "--until", "2026-11-22T10:07:00", db=DB)
    assert json.loads(out) == expect(T0 + 200, T0 + 420), out
    _, out, _ = admin("--json", "top-objects", "--limit", "1", db=DB)
    assert json.loads(out) == expect()[:1], out
    _, out, _ = admin("top-objects", "--csv", db=DB)
    rows = list(csv.DictReader(io.StringIO(out, newline="")))
    assert [(int(r["object"]), int(r["collisions"]), r["in_world"]) for r in rows] == \
        [(r["object"], r["collisions"], "1" if r["in_world"] else "0") for r in expect()], rows
    _, out, _ = admin("top-objects", db=DB)
    head, rows = table(out)
    assert head == ["object", "name", "owner", "collisions", "users", "first", "last"], head
    assert [r[:5] for r in rows] == [[str(e["object"]), e["name"], e["owner"], str(e["collisions"]), str(e["users"])]
                                     for e in expect()], rows


def test_object_summary():
    o = OBJECTS[0]
    mine = [c for c in COLLISIONS if c["object"] == 1]
    want = {"object": 1, "name": "arch.glb", "format": "glb", "owner": "alice", "created": iso(o[4]), "removed": None,
            "pos_x": 10.0, "pos_y": 0.0, "pos_z": 20.0, "yaw": 0.5, "scale": 1.0, "triangles": 1234,
            "mbr_min_x": -2.0, "mbr_min_y": 0.0, "mbr_min_z": -0.5, "mbr_max_x": 2.0, "mbr_max_y": 3.0,
            "mbr_max_z": 0.5, "ecm_version": 2, "ecm_versions": 2, "boxes": 3, "collisions": len(mine),
            "collisions_current": len([c for c in mine if c["version"] == 2]),
            "users": len({c["user"] for c in mine if c["user"] is not None}),
            "first_collision": iso(min(c["at"] for c in mine)), "last_collision": iso(max(c["at"] for c in mine))}
    _, out, _ = admin("object", "1", "--json", db=DB)
    assert json.loads(out) == [want], out
    _, out, _ = admin("object", "--csv", "1", db=DB)
    rows = list(csv.DictReader(io.StringIO(out, newline="")))
    assert len(rows) == 1 and rows[0]["removed"] == "" and rows[0]["collisions_current"] == str(want["collisions_current"])
    _, out, _ = admin("object", "1", db=DB)
    fields = dict(line.split(None, 1) for line in out.strip().split("\n"))
    assert fields["name"] == "arch.glb" and fields["owner"] == "alice" and fields["removed"] == "-", fields
    assert fields["created"] == iso(o[4], 3) and fields["yaw"] == "0.500" and fields["boxes"] == "3", fields
    assert fields["collisions"] == str(len(mine)) and fields["users"] == str(want["users"]), fields
    assert len(fields) == len(want), sorted(fields)
    # A removed object with no refinement.
    _, out, _ = admin("object", "3", "--json", db=DB)
    got = json.loads(out)[0]
    assert got["removed"] == iso(T0 + 50) and got["boxes"] == 1 and got["ecm_versions"] == 1, got


def test_versions():
    _, out, _ = admin("versions", "1", "--json", db=DB)
    count = lambda v: len([c for c in COLLISIONS if c["object"] == 1 and c["version"] == v])
    none = {"parent": None, "run": None, "clusters": None, "restores": None, "detail": None}  # history: test_versions.py
    assert json.loads(out) == [
        {"version": 1, "created": iso(T0 - 100), "reason": "import", "boxes": 1, "collisions": count(1),
         "current": False, **none},
        {"version": 2, "created": iso(T0 + 150), "reason": "refine", "boxes": 3, "collisions": count(2),
         "current": True, **none}], out
    _, out, _ = admin("versions", "1", db=DB)
    head, rows = table(out)
    assert head == ["version", "created", "reason", "parent", "run", "clusters", "restores", "boxes", "collisions",
                    "current", "detail"], head
    assert rows == [["1", iso(T0 - 100, 3), "import", "-", "-", "-", "-", "1", str(count(1)), "no", "-"],
                    ["2", iso(T0 + 150, 3), "refine", "-", "-", "-", "-", "3", str(count(2)), "yes", "-"]], rows
    _, out, _ = admin("versions", "2", "--csv", db=DB)
    assert out == (f"version,created,reason,parent,run,clusters,restores,boxes,collisions,current,detail\r\n"
                   f"1,{iso(T0 - 90)},import,,,,,1,12,1,\r\n"), out


def test_totals():
    _, out, _ = admin("totals", "--json", db=DB)
    assert json.loads(out) == [{"users": 4, "sessions": 6, "sessions_open": 1, "objects": 3, "objects_in_world": 2,
                                "collisions": 60, "first": iso(T0 - 3600), "last": iso(T0 + 7500)}], out
    _, out, _ = admin("totals", db=DB)
    fields = dict(line.split(None, 1) for line in out.strip().split("\n"))
    assert fields == {"users": "4", "sessions": "6", "sessions_open": "1", "objects": "3", "objects_in_world": "2",
                      "collisions": "60", "first": iso(T0 - 3600, 3), "last": iso(T0 + 7500, 3)}, fields


def test_sessions():
    def expect(user=None, lo=None, hi=None):
        out = []
        for s in sorted(SESSIONS, key=lambda s: (s[4], s[0]), reverse=True):
            if user is not None and s[1] != user:
                continue
            if lo is not None and s[6] is not None and s[6] < lo:
                continue
            if hi is not None and s[4] >= hi:
                continue
            out.append(s[0])
        return out

    _, out, _ = admin("sessions", "--json", db=DB)
    got = json.loads(out)
    assert [r["session"] for r in got] == expect(), got
    first = {r["session"]: r for r in got}
    assert first[1] == {"session": 1, "user": "alice", "peer": "127.0.0.1:5001", "avatar": 65536,
                        "started": iso(T0), "joined": iso(T0 + 1), "ended": iso(T0 + 1800), "reason": "quit",
                        "duration": 1800}, first[1]
    assert first[5]["user"] is None and first[5]["joined"] is None and first[5]["duration"] == 5, first[5]
    # Open: connected until now (or 0 if the clock is before its start).
    assert first[3]["ended"] is None and abs(first[3]["duration"] - max(0, time.time() - (T0 + 2400))) < 60, first[3]
    _, out, _ = admin("sessions", "--json", "--user", "alice", db=DB)
    assert [r["session"] for r in json.loads(out)] == expect(user=1), out
    # Connected at some moment in [10:40, 11:00): bob (until 11:00) and carol (open).
    _, out, _ = admin("sessions", "--json", "--since", "2026-11-22T10:40", "--until", "2026-11-22T11:00", db=DB)
    assert [r["session"] for r in json.loads(out)] == expect(lo=T0 + 2400, hi=T0 + 3600) == [3, 2], out
    _, out, _ = admin("sessions", "--csv", "--limit", "2", db=DB)
    rows = list(csv.DictReader(io.StringIO(out, newline="")))
    assert [int(r["session"]) for r in rows] == expect()[:2] and rows[0]["duration"] == "300", rows
    _, out, _ = admin("sessions", db=DB)
    head, rows = table(out)
    assert head == ["session", "user", "peer", "started", "ended", "reason", "duration"], head
    by_id = {r[0]: r for r in rows}
    assert by_id["1"] == ["1", "alice", "127.0.0.1:5001", iso(T0, 3), iso(T0 + 1800, 3), "quit", "0:30:00"], by_id
    assert by_id["6"][1] == 'dave, "the quoted"', by_id["6"]


def test_help_and_bad_arguments():
    rc, out, _ = admin("--help", check=0)
    assert "Exit status" in out and "collisions" in out and "--json" in out
    for cmd in ("collisions", "top-objects", "object", "versions", "sessions", "totals"):
        _, out, _ = admin(cmd, "--help", check=0)
        assert out.startswith(f"usage: cvre-admin {cmd}"), out
        _, out2, _ = admin("help", cmd, check=0)
        assert out2 == out
    bad = [
        [], ["frobnicate"], ["collisions", "--bogus"], ["collisions", "--object"], ["collisions", "--object", "x"],
        ["collisions", "--object", "0"], ["collisions", "--since", "yesterday"],
        ["collisions", "--until", "2026-13-01"], ["collisions", "--since", "2026-02-30T00:00"],
        ["collisions", "--region", "1,2,3"], ["collisions", "--region", "1,2,3,0,5,6"],
        ["collisions", "--region", "1,2,3,4,5,nan"], ["collisions", "--limit", "-1"], ["collisions", "extra"],
        ["top-objects", "--user", "alice"], ["object"], ["object", "1", "2"], ["object", "abc"],
        ["versions", "-3"], ["totals", "--limit", "3"], ["--object", "1", "collisions"], ["help", "nothing"],
    ]
    for argv in bad:
        rc, out, err = admin(*argv, db=DB, check=2)
        assert err.startswith("cvre-admin") and out == "", (argv, out, err)


def test_unusable_databases():
    tmp = tempfile.mkdtemp(prefix="cvre-admin-")
    TEMP_DIRS.append(tmp)
    rc, _, err = admin("totals", db=os.path.join(tmp, "missing.db"), check=3)
    assert "No such file" in err, err
    junk = os.path.join(tmp, "junk.db")
    with open(junk, "wb") as f:
        f.write(b"this is not a database at all" * 200)
    rc, _, err = admin("totals", db=junk, check=3)
    assert "not a database" in err, err
    other = os.path.join(tmp, "other.db")
    db = sqlite3.connect(other)
    db.execute("CREATE TABLE t(x)")
    db.commit()
    db.close()
    rc, _, err = admin("totals", db=other, check=3)
    assert "schema version 0" in err and "not a cvre database" in err, err
    newer = os.path.join(tmp, "newer.db")
    copy_with_schema(DB, newer, 99)
    rc, _, err = admin("collisions", db=newer, check=3)
    assert "schema version 99" in err, err


def snapshot(path):
    """The database file's time stamp and contents, and the WAL's if there
    is one. A reader of a WAL database may create the -wal and -shm files
    beside it when there are none (SQLite's coordination files, empty of
    data): that is allowed, a change to either file's data is not."""
    out = {}
    for suffix in ("", "-wal"):
        p = path + suffix
        if os.path.exists(p) and (suffix == "" or os.path.getsize(p) > 0):
            st = os.stat(p)
            with open(p, "rb") as f:
                out[suffix] = (st.st_mtime_ns, st.st_size, hashlib.sha256(f.read()).hexdigest())
    return out


def test_read_only():
    before = snapshot(DB)
    for argv in (["collisions"], ["collisions", "--region", "0,0,0,9,9,9"], ["top-objects"], ["object", "1"],
                 ["versions", "1"], ["sessions"], ["totals"], ["collisions", "--csv"], ["object", "99"]):
        admin(*argv, db=DB, check=None)
    assert snapshot(DB) == before, (before, snapshot(DB))
    # A file nobody may write is enough (for a user other than root).
    tmp = tempfile.mkdtemp(prefix="cvre-admin-")
    TEMP_DIRS.append(tmp)
    ro = os.path.join(tmp, "ro.db")
    shutil.copy(DB, ro)
    os.chmod(ro, 0o444)
    before = snapshot(ro)
    _, out, _ = admin("totals", "--json", db=ro)
    assert json.loads(out)[0]["collisions"] == 60
    assert snapshot(ro) == before


def test_while_a_writer_commits():
    """A writer in WAL mode commits batches while cvre-admin queries; every
    query succeeds and sees a growing count."""
    tmp = tempfile.mkdtemp(prefix="cvre-admin-")
    TEMP_DIRS.append(tmp)
    live = os.path.join(tmp, "live.db")
    shutil.copy(DB, live)
    stop = threading.Event()
    written = [60]
    errors = []

    def writer():
        db = sqlite3.connect(live, isolation_level=None)
        db.execute("PRAGMA journal_mode = WAL")
        db.execute("PRAGMA busy_timeout = 5000")
        next_id = 61
        try:
            while not stop.is_set():
                db.execute("BEGIN IMMEDIATE")
                batch = []
                for k in range(200):
                    c = dict(COLLISIONS[k % 60])
                    c["id"] = next_id
                    next_id += 1
                    batch.append(c)
                insert_collisions(db, batch)
                db.execute("COMMIT")
                written[0] = next_id - 1
                time.sleep(0.005)
        except Exception as e:  # reported by the test below
            errors.append(e)
        db.close()

    t = threading.Thread(target=writer)
    t.start()
    try:
        counts = []
        # five rounds at least, until the writer's commits show: counted, not
        # timed, so that a slow machine only takes longer (60 s at most)
        end = time.time() + 60
        while (len(counts) < 5 or counts[-1] == counts[0]) and time.time() < end:
            rc, out, err = admin("totals", "--json", db=live, check=None)
            assert rc == 0, err
            counts.append(json.loads(out)[0]["collisions"])
            rc, out, err = admin("collisions", "--region", "-3,0,-5,1.5,1,3", "--limit", "0", "--csv", db=live,
                                 check=None)
            assert rc == 0, err
            rc, out, err = admin("top-objects", "--json", db=live, check=None)
            assert rc == 0, err
    finally:
        stop.set()
        t.join()
    assert not errors, errors
    assert counts == sorted(counts) and counts[-1] > counts[0] >= 60, counts[:3] + counts[-3:]
    assert len(counts) >= 5, counts


def test_random_log_against_brute_force():
    """A few thousand random collisions written in random batches (the
    writer's layout: groups, segments); every query form, filters combined,
    returns exactly what filtering the rows in Python returns."""
    rnd = random.Random(20261122)
    tmp = tempfile.mkdtemp(prefix="cvre-admin-")
    TEMP_DIRS.append(tmp)
    path = os.path.join(tmp, "random.db")
    shutil.copy(DB, path)
    db = sqlite3.connect(path)
    db.execute("DELETE FROM collisions")
    for t in ("collision_groups", "collision_cells", "collision_users", "collision_segments"):
        db.execute(f"DELETE FROM {t}")
    rows = []
    users = [1, 2, 3, 4, None]
    grid = lambda lo, hi: rnd.randint(int(lo * 8), int(hi * 8)) / 8.0  # exact in binary
    while len(rows) < 3000:
        batch = []
        for _ in range(rnd.randint(1, 400)):
            obj = rnd.choice([1, 1, 2, 3])
            far = rnd.random() < 0.01  # beyond the clamped cells now and then
            batch.append(dict(
                at=T0 + 0.25 * rnd.randint(0, 4000), user=rnd.choice(users), session=rnd.randint(1, 9),
                avatar=65536 + rnd.randint(0, 9), object=obj, version=rnd.choice([1, 2]) if obj == 1 else 1,
                box=rnd.randint(0, 2), inside=rnd.randint(0, 1),
                world=(grid(-30, 30) * (1e8 if far else 1), grid(-2, 6), grid(-30, 30)),
                local=(grid(-2, 2), grid(0, 3), grid(-1, 1)), normal=(1.0, 0.0, 0.0),
                vel=(grid(-2, 2), 0.0, grid(-2, 2))))
        insert_collisions(db, batch)
        rows += batch
    db.commit()
    db.close()

    def query(*argv):
        _, out, _ = admin(*argv, "--json", db=path)
        return json.loads(out)

    checked = 0
    for _ in range(60):
        argv, conds = ["collisions"], []
        if rnd.random() < 0.5:
            x0, y0, z0 = grid(-35, 30), grid(-3, 5), grid(-35, 30)
            box = (x0, y0, z0, x0 + grid(0, 25), y0 + grid(0, 4), z0 + grid(0, 25))
            if rnd.random() < 0.1:
                box = (-1e12, -10.0, -40.0, 1e12, 10.0, 40.0)
            argv += ["--region", ",".join(repr(v) for v in box)]
            conds.append(lambda c, box=box: all(box[k] <= c["world"][k] <= box[k + 3] for k in range(3)))
        if rnd.random() < 0.4:
            u = rnd.choice([1, 2, 3, 4])
            argv += ["--user", USERS[u]]
            conds.append(lambda c, u=u: c["user"] == u)
        if rnd.random() < 0.3:
            o = rnd.choice([1, 2, 3])
            argv += ["--object", str(o)]
            conds.append(lambda c, o=o: c["object"] == o)
        if rnd.random() < 0.5:
            lo = T0 + 0.25 * rnd.randint(-100, 4000)
            argv += ["--since", repr(lo)]
            conds.append(lambda c, lo=lo: c["at"] >= lo)
        if rnd.random() < 0.5:
            hi = T0 + 0.25 * rnd.randint(0, 4100)
            argv += ["--until", repr(hi)]
            conds.append(lambda c, hi=hi: c["at"] < hi)
        limit = rnd.choice([0, 0, 1, 5, 100, 1000])
        argv += ["--limit", str(limit)]
        want = newest_first([c for c in rows if all(f(c) for f in conds)])
        if limit:
            want = want[:limit]
        got = query(*argv)
        assert got == [as_json(c) for c in want], (argv, len(got), len(want))
        checked += len(want)
    assert checked > 1000, checked

    for lo, hi in ((None, None), (T0 + 100, None), (None, T0 + 500.25), (T0 + 333, T0 + 777)):
        argv = (["--since", repr(lo)] if lo else []) + (["--until", repr(hi)] if hi else [])
        sel = [c for c in rows if (lo is None or c["at"] >= lo) and (hi is None or c["at"] < hi)]
        want = sorted(({"object": o, "collisions": len(m), "users": len({c["user"] for c in m if c["user"]}),
                        "first": iso(min(c["at"] for c in m)), "last": iso(max(c["at"] for c in m))}
                       for o in (1, 2, 3) for m in [[c for c in sel if c["object"] == o]] if m),
                      key=lambda r: (-r["collisions"], r["object"]))
        got = [{k: r[k] for k in ("object", "collisions", "users", "first", "last")}
               for r in query("top-objects", "--limit", "0", *argv)]
        assert got == want, (argv, got, want)
    for o in (1, 2, 3):
        mine = [c for c in rows if c["object"] == o]
        current = {1: 2, 2: 1, 3: 1}[o]
        got = query("object", str(o))[0]
        assert (got["collisions"], got["collisions_current"], got["users"], got["first_collision"],
                got["last_collision"]) == (len(mine), len([c for c in mine if c["version"] == current]),
                                           len({c["user"] for c in mine if c["user"]}),
                                           iso(min(c["at"] for c in mine)), iso(max(c["at"] for c in mine))), got
        got = {r["version"]: r["collisions"] for r in query("versions", str(o))}
        assert got == {v: len([c for c in mine if c["version"] == v]) for v in got}, got
    got = query("totals")[0]
    assert got["collisions"] == len(rows), got
    assert got["last"] == iso(max(T0 + 7500, max(c["at"] for c in rows))), got


def test_limit_is_said():
    """A --limit that cuts the answer short says so on stderr, in every
    form; stdout holds the rows alone. An answer that fits says nothing."""
    for form in ([], ["--csv"], ["--json"]):
        rc, out, err = admin("collisions", "--limit", "7", *form, db=DB)
        assert err == "cvre-admin: showing the first 7 rows; more match (--limit N for more, --limit 0 for all)\n", \
            (form, err)
        if form == ["--json"]:
            assert len(json.loads(out)) == 7
        for limit in ("60", "0", "100"):  # 60 rows match: all of them fit
            _, _, err = admin("collisions", "--limit", limit, *form, db=DB)
            assert err == "", (form, limit, err)
    _, out, err = admin("collisions", "--limit", "59", "--json", db=DB)
    assert len(json.loads(out)) == 59 and "showing the first 59 rows; more match" in err, err
    # The default limit, 100, on 180 rows: said.
    d = tempfile.mkdtemp(prefix="cvre-admin-limit-")
    TEMP_DIRS.append(d)
    db = os.path.join(d, "many.db")
    shutil.copy(DB, db)
    more = [dict(c, at=c["at"] + shift) for shift in (100000, 200000) for c in COLLISIONS]
    c = sqlite3.connect(db)
    insert_collisions(c, more)
    c.commit()
    c.close()
    _, out, err = admin("collisions", db=db)
    assert len(table(out)[1]) == 100 and "showing the first 100 rows; more match" in err, err
    _, out, err = admin("collisions", "--limit", "0", "--csv", db=db)
    assert out.count("\r\n") == 181 and err == "", (out.count("\r\n"), err)
    for argv in (["top-objects", "--limit", "1"], ["sessions", "--limit", "2"]):
        _, _, err = admin(*argv, db=DB)
        assert f"showing the first {argv[-1]} rows; more match" in err, (argv, err)


def f32(v):
    return struct.unpack("<f", struct.pack("<f", v))[0]


def test_float32_values_print_short():
    """Coordinates, normals and velocities were floats before they were
    stored: CSV and JSON print the shortest decimal that reads back as the
    same float (0.9, not 0.8999999761581421). A value that is no float
    (computed in double) keeps every digit."""
    d = tempfile.mkdtemp(prefix="cvre-admin-f32-")
    TEMP_DIRS.append(d)
    db = os.path.join(d, "f32.db")
    shutil.copy(DB, db)
    typed = (0.9, -7.3, 1e-3, 123456.7, 0.1, 1.0 / 3, 3.4e38, 65504.0, 2.5, 16777217.0, 1e-40, 0.7)
    row = dict(COLLISIONS[0], at=T0 + 99999, world=typed[0:3], local=typed[3:6], normal=typed[6:9],
               vel=typed[9:12])
    for k in ("world", "local", "normal", "vel"):
        row[k] = tuple(f32(v) for v in row[k])
    c = sqlite3.connect(db)
    insert_collisions(c, [row])
    c.execute("UPDATE objects SET pos_x = ?, yaw = ? WHERE id = 1", (0.123456789012, f32(0.9)))  # a double, a float
    c.commit()
    c.close()
    keys = ["world_x", "world_y", "world_z", "local_x", "local_y", "local_z", "normal_x", "normal_y", "normal_z",
            "velocity_x", "velocity_y", "velocity_z"]
    want = ["0.9", "-7.3", "0.001", "123456.7", "0.1", "0.33333334", "3.4e+38", "65504", "2.5", "16777216",
            "9.99995e-41", "0.7"]
    _, out, _ = admin("collisions", "--limit", "1", "--csv", db=db)
    head, vals = list(csv.reader(io.StringIO(out, newline="")))
    got = [vals[head.index(k)] for k in keys]
    assert got == want, got
    _, out, _ = admin("collisions", "--limit", "1", "--json", db=db)
    raw = out.split("\n")[1]
    for k, w in zip(keys, want):
        assert f'"{k}": {w},' in raw or f'"{k}": {w}}}' in raw, (k, w, raw)
    obj = json.loads(out)[0]
    for k in keys:  # each reads back as the float stored
        key = k.replace("velocity", "vel").split("_")[0]
        assert f32(obj[k]) == row[key]["xyz".index(k[-1])], (k, obj[k])
    _, out, _ = admin("object", "1", "--json", db=db)
    assert '"pos_x": 0.123456789012,' in out and '"yaw": 0.9,' in out, out
    _, out, _ = admin("object", "1", "--csv", db=db)
    assert ",0.123456789012," in out and ",0.9," in out, out


run([test_collisions_every_form, test_limit_is_said, test_float32_values_print_short, test_collisions_filters, test_unknown_object_and_user, test_top_objects,
     test_object_summary, test_versions, test_totals, test_sessions, test_help_and_bad_arguments,
     test_unusable_databases, test_read_only, test_while_a_writer_commits,
     test_random_log_against_brute_force])
