"""Objects end to end: uploads in chunks, import, placement and removal by
the owner only, every bad upload refused with the server and database
intact, the scene restored after a restart, and collisions with the boxes
sent to the client and logged completely, even when SIGTERM comes under
load."""
import math
import os
import re
import sqlite3
import struct
import subprocess
import time

from harness import (E, MODELS, T, Raw, Server, args, close_to, frame, move, ping, refused, run, s8, transform,
                     upload, upload_frames)

A = args()
ROOM = os.path.join(MODELS, "openings", "openfoam_room_with_doorway.stl")
# SOURCES.md: the room's AABB in file axes (Z up, metres).
ROOM_MIN, ROOM_MAX = (-5.64239, -0.416065, 0.0), (0.217568, 4.4352, 2.8)


def read(path):
    with open(path, "rb") as f:
        return f.read()


def room_world_box(pos):
    """The room's MBR once turned Y-up ((x, y, z) -> (x, z, -y)) and placed at pos."""
    lo = (ROOM_MIN[0], ROOM_MIN[2], -ROOM_MAX[1])
    hi = (ROOM_MAX[0], ROOM_MAX[2], -ROOM_MIN[1])
    return tuple(l + p for l, p in zip(lo, pos)) + tuple(h + p for h, p in zip(hi, pos))


def glb(json):
    """A GLB holding only the JSON chunk json (bytes), padded with spaces."""
    json += b" " * (-len(json) % 4)
    return b"glTF" + struct.pack("<III", 2, 20 + len(json), len(json)) + b"JSON" + json


def test_upload_place_remove_and_ownership():
    srv = Server(A.bin)
    # accounts first: a connection waiting on them could outlast the handshake timeout
    ann_pw, bob_pw = srv.account("ann"), srv.account("bob")
    ann = Raw(srv.port)
    ann.handshake("ann", ann_pw)
    bob = Raw(srv.port)
    bob.handshake("bob", bob_pw)
    obj = upload(ann, 7, read(ROOM), "room.stl", fmt="stl", up=1, pos=(10, 0, 0))
    assert obj["owner"] == "ann" and obj["name"] == "room.stl" and obj["triangles"] == 54, obj
    assert obj["ecm_version"] == 1 and len(obj["boxes"]) == 1
    assert close_to(obj["boxes"][0], room_world_box((10, 0, 0)), 1e-3), obj["boxes"]
    seen = bob.expect("object", where=lambda m: m["id"] == obj["id"])
    assert seen["upload"] == 0 and seen["boxes"] == obj["boxes"]

    place = lambda oid, pos, yaw=0.0, scale=1.0: frame(T["OBJECT_PLACE"], struct.pack("<I", oid) +
                                                       transform(pos, yaw, scale))
    bob.send(place(obj["id"], (0, 0, 0)))
    assert "belongs to ann" in refused(bob, obj["id"], E["NOT_OWNER"])["message"]
    bob.send(frame(T["OBJECT_REMOVE"], struct.pack("<I", obj["id"])))
    refused(bob, obj["id"], E["NOT_OWNER"])
    ann.send(frame(T["OBJECT_REMOVE"], struct.pack("<I", 999)))
    refused(ann, 999, E["NO_OBJECT"])

    # Turned by 90 degrees about +y: (x, z) -> (z, -x), then moved.
    ann.send(place(obj["id"], (20, 0, 5), math.pi / 2, 2.0))
    moved = bob.expect("object", where=lambda m: m["id"] == obj["id"] and m["pos"][0] == 20)
    lo, hi = room_world_box((0, 0, 0))[:3], room_world_box((0, 0, 0))[3:]
    want = (2 * lo[2] + 20, 2 * lo[1], -2 * hi[0] + 5, 2 * hi[2] + 20, 2 * hi[1], -2 * lo[0] + 5)
    assert close_to(moved["boxes"][0], want, 1e-3), (moved["boxes"][0], want)
    ann.send(frame(T["OBJECT_REMOVE"], struct.pack("<I", obj["id"])))
    bob.expect("object_removed", where=lambda m: m["id"] == obj["id"])
    ann.expect("object_removed", where=lambda m: m["id"] == obj["id"])
    assert srv.stop() == 0
    db = sqlite3.connect(srv.db)
    row = db.execute("SELECT pos_x, pos_z, scale, removed_at IS NOT NULL FROM objects").fetchone()
    assert row == (20.0, 5.0, 2.0, 1), row


def test_bad_uploads_leave_everything_intact():
    srv = Server(A.bin, "--max-upload", "1000000")
    c = Raw(srv.port)
    c.handshake("mallory", srv.account("mallory"))
    room = read(ROOM)
    c.send(upload_frames(1, b"x" * 10, "big", total=1000001))
    assert "over the upload limit" in refused(c, 1, E["UPLOAD"])["message"]
    c.send(upload_frames(2, b"this is not a model at all\n" * 20, "text.obj", fmt="obj"))
    refused(c, 2, E["IMPORT"])
    c.send(upload_frames(3, os.urandom(5000), "noise"))
    refused(c, 3, E["IMPORT"])
    # A binary STL header that claims 2^31-1 triangles in a 184-byte file.
    stl = b"\0" * 80 + struct.pack("<I", 0x7FFFFFFF) + b"\0" * 100
    c.send(upload_frames(4, stl, "huge.stl", fmt="stl"))
    refused(c, 4, E["IMPORT"])
    # An ASCII PLY that declares four billion vertices.
    ply = b"ply\nformat ascii 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\n" \
          b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n"
    c.send(upload_frames(5, ply, "huge.ply", fmt="ply"))
    refused(c, 5, E["IMPORT"])
    # Truncated: the model is cut short (the import fails) ...
    spider = read(os.path.join(MODELS, "formats", "assimp_Spider_binary.stl"))
    c.send(upload_frames(6, spider[:len(spider) // 2], "half.stl", fmt="stl"))
    refused(c, 6, E["IMPORT"])
    # GLB JSON with an object where glTF has an array: a heap overflow once.
    for uid, accessors in ((13, b'{"a":{"count":5},"b":{"count":6}}'), (14, b'{"q":[1,2]}')):
        c.send(upload_frames(uid, glb(b'{"asset":{"version":"2.0"},"accessors":' + accessors + b"}"),
                             "hostile.glb", fmt="glb"))
        assert "accessors is not an array" in refused(c, uid, E["IMPORT"])["message"]
    # ... or the upload ends before its announced size.
    begin = frame(T["UPLOAD_BEGIN"], struct.pack("<II", 8, len(room)) + s8("short") + s8("stl") +
                  struct.pack("<Bf", 1, 1.0))
    c.send(begin + frame(T["UPLOAD_CHUNK"], struct.pack("<II", 8, 0) + room[:1000]) +
           frame(T["UPLOAD_END"], struct.pack("<I", 8) + transform((0, 0, 0))))
    assert "ended after 1000" in refused(c, 8, E["UPLOAD"])["message"]
    # Chunks out of order, or past the announced size.
    c.send(begin.replace(struct.pack("<I", 8), struct.pack("<I", 9), 1) +
           frame(T["UPLOAD_CHUNK"], struct.pack("<II", 9, 500) + room[:100]))
    refused(c, 9, E["UPLOAD"])
    c.send(upload_frames(10, b"", "empty", total=1)[:-30] +
           frame(T["UPLOAD_CHUNK"], struct.pack("<II", 10, 0) + b"ab"))
    refused(c, 10, E["UPLOAD"])
    c.send(frame(T["UPLOAD_CHUNK"], struct.pack("<II", 11, 0) + b"ab"))
    refused(c, 11, E["UPLOAD"])
    # An abandoned upload: its sender leaves mid-way.
    quitter = Raw(srv.port)
    quitter.handshake("quitter", srv.account("quitter"))
    quitter.send(begin + frame(T["UPLOAD_CHUNK"], struct.pack("<II", 8, 0) + room[:1000]))
    quitter.close()
    # A good upload still works, then invalid transforms are frame errors.
    good = upload(c, 12, room, "room.stl", fmt="stl", up=1)
    assert good["triangles"] == 54
    for bad, code in ((transform((0, 0, 0), math.nan), E["NOT_FINITE"]), (transform((0, 0, 0), 0, 0.0), E["BAD_VALUE"]),
                      (transform((0, 0, 0), 0, 1e6), E["BAD_VALUE"])):
        v = Raw(srv.port)
        v.handshake("mallory", "pw-mallory")
        v.send(frame(T["OBJECT_PLACE"], struct.pack("<I", good["id"]) + bad))
        errors = [m for m in v.wait_closed() if m["type"] == "error"]
        assert errors and errors[0]["code"] == code, errors
    c.send(ping(77))
    c.expect("pong", where=lambda m: m["stamp"] == 77)
    assert srv.stop() == 0
    log = srv.logtext()
    assert "upload 8 abandoned after 1000" in log, log[-2000:]
    db = sqlite3.connect(srv.db)
    assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    assert db.execute("SELECT count(*) FROM objects").fetchone()[0] == 1
    assert db.execute("SELECT count(*) FROM meshes").fetchone()[0] == 1


def test_restart_restores_the_scene():
    srv = Server(A.bin)
    c = Raw(srv.port)
    c.handshake("ann", srv.account("ann"))
    a = upload(c, 1, read(ROOM), "a.stl", fmt="stl", up=1, pos=(5, 0, 5))
    b = upload(c, 2, read(ROOM), "b.stl", fmt="stl", up=1, pos=(-5, 0, -5))
    c.send(frame(T["OBJECT_PLACE"], struct.pack("<I", a["id"]) + transform((7, 1, 7), 0.5, 1.5)))
    placed = c.expect("object", where=lambda m: m["id"] == a["id"] and m["pos"][0] == 7)
    c.send(frame(T["OBJECT_REMOVE"], struct.pack("<I", b["id"])))
    c.expect("object_removed")
    assert srv.stop() == 0
    srv2 = Server(A.bin, db=srv.db)
    d = Raw(srv2.port)
    d.handshake("dora")
    got = d.expect("object")
    assert got["id"] == a["id"] and got["boxes"] == placed["boxes"], (got, placed)
    assert got["pos"] == placed["pos"] and got["yaw"] == placed["yaw"] and got["scale"] == placed["scale"]
    assert not [m for m in d.poll(0.5) if m["type"] == "object"], "a removed object came back"
    assert srv2.stop() == 0


def test_collisions_are_sent_and_logged():
    world = os.path.join(os.path.dirname(os.path.abspath(__file__)), "room.world")
    srv = Server(A.bin, "--world", world, "--spawn-radius", "0")
    c = Raw(srv.port)
    c.handshake("walker")
    obj = c.expect("object")
    for seq in range(1, 60):  # walk east into the room's west wall at x = 4.358
        c.send(move(seq, (20, 0, 0)))
        time.sleep(0.02)
    # A collision goes out in the tick that applies the move, before that
    # tick's snapshot: the one that acks the last move ends them.
    hits = [m for m in c.collect("snapshot", 10, lambda m: m["ack"] == 59) if m["type"] == "collision"]
    assert hits, "no collision reported"
    h = hits[0]
    assert h["object"] == obj["id"] and h["box"] == 0 and h["inside"] == 0 and h["ecm_version"] == 1
    assert close_to(h["normal"], (-1, 0, 0), 1e-6) and abs(h["point"][0] - obj["boxes"][0][0]) < 1e-3, h
    c.close()
    assert srv.stop() == 0
    db = sqlite3.connect(srv.db)
    rows = db.execute("SELECT object_id, ecm_version, box_index, inside, world_x, local_x, local_y, local_z, "
                      "normal_x, user_id IS NOT NULL, vel_x > 0 FROM collisions").fetchall()
    assert len(rows) == len(hits), (len(rows), len(hits))
    r = rows[0]
    assert r[:4] == (obj["id"], 1, 0, 0) and r[8] == -1.0 and r[10] == 1, r
    # Object-local: the world point minus the object's position (no turn, scale 1).
    assert abs(r[5] - (r[4] - obj["pos"][0])) < 1e-4 and abs(r[5] - ROOM_MIN[0]) < 1e-3, r
    assert db.execute("SELECT count(*) FROM collisions c JOIN collision_cells r ON r.g = c.g "
                      "WHERE c.world_x BETWEEN r.min_x AND r.max_x AND c.world_y BETWEEN r.min_y AND r.max_y "
                      "AND c.world_z BETWEEN r.min_z AND r.max_z").fetchone()[0] == len(rows)


def test_log_complete_after_sigterm_under_load():
    """200 bots spawned around a wall collide all the time; SIGTERM in the
    middle must still leave every pushed row in the database."""
    world = os.path.join(os.path.dirname(os.path.abspath(__file__)), "room.world")
    srv = Server(A.bin, "--world", world, "--spawn-radius", "12", "--max-speed", "5", "--max-per-address", "0", "--joins-per-second", "0")
    bots = subprocess.Popen([os.path.join(A.bin, "cvre-client"), "--port", str(srv.port), "--bots", "200",
                             "--rate", "20", "--pattern", "random-walk", "--duration", "30"],
                            stdout=subprocess.DEVNULL)
    # Under load: once the log holds a few hundred rows, with the bots
    # still pushing (they walk for 30 s).
    end, rows = time.time() + 25, 0
    while rows < 300:
        assert time.time() < end and bots.poll() is None, f"{rows} rows logged"
        time.sleep(0.1)
        db = sqlite3.connect(srv.db)
        rows = db.execute("SELECT count(*) FROM collisions").fetchone()[0]
        db.close()
    assert srv.stop() == 0
    bots.kill()
    bots.wait()
    m = re.search(r"collision log: (\d+) rows written, (\d+) dropped, (\d+) lost", srv.logtext())
    assert m, srv.logtext()[-1000:]
    written, dropped, lost = map(int, m.groups())
    assert written > 0 and dropped == 0 and lost == 0, m.group(0)
    db = sqlite3.connect(srv.db)
    assert db.execute("SELECT count(*) FROM collisions").fetchone()[0] == written
    assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"


run([test_upload_place_remove_and_ownership, test_bad_uploads_leave_everything_intact,
     test_restart_restores_the_scene, test_collisions_are_sent_and_logged, test_log_complete_after_sigterm_under_load])
