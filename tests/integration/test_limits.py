#!/usr/bin/env python3
"""Limits that agree: flags within the ranges of the modules they feed,
placements within the world, spawn points outside objects, and a stored
object that cannot stand anywhere kept out of the world, not half in it."""
import os
import sqlite3
import struct
import subprocess
import time

from harness import (E, MODELS, T, Raw, Server, args, frame, move, refused, run, still_moving, transform,
                     upload, upload_frames)

A = args()
ROOM = os.path.join(MODELS, "openings", "openfoam_room_with_doorway.stl")
TEAPOT = os.path.join(MODELS, "classic", "teapot.obj")


def read(path):
    with open(path, "rb") as f:
        return f.read()


def box_obj(lo, hi):
    """An OBJ of one box from lo to hi."""
    vs = [(x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    faces = ["1 3 4 2", "5 6 8 7", "1 2 6 5", "3 7 8 4", "1 5 7 3", "2 4 8 6"]
    return ("".join(f"v {x} {y} {z}\n" for x, y, z in vs) + "".join(f"f {f}\n" for f in faces)).encode()


def overlaps(pos, size, box):
    lo = (pos[0] - size[0] / 2, pos[1], pos[2] - size[2] / 2)
    hi = (pos[0] + size[0] / 2, pos[1] + size[1], pos[2] + size[2] / 2)
    return all(lo[k] < box[3 + k] and box[k] < hi[k] for k in range(3))


def walk(c, avatar, seq, target, moves=40):
    """Asks to go to target, move after move (each goes as far as the speed
    limit lets it), until the avatar stops; returns where it stands and
    the next seq."""
    pos = None
    for _ in range(moves):
        c.send(move(seq, target))
        m = c.expect("snapshot", 5, where=lambda m, s=seq: m["ack"] >= s)
        seq += 1
        if avatar not in m["avatars"]:  # a snapshot leaves out an avatar that did not move
            break
        pos = m["avatars"][avatar]
    return pos, seq


def test_flags_are_checked_against_the_limits_they_feed():
    server = os.path.join(A.bin, "cvre-server")
    for flags, words in [(["--world-size", "100000"], "world-size"), (["--max-upload", "1000000000"], "max-upload"),
                         (["--max-triangles", "100000000"], "max-triangles"),
                         (["--world-size", "1000", "--spawn-radius", "600"], "past the world's edge")]:
        p = subprocess.run([server, "--port", "0", "--db", ":memory:", *flags], capture_output=True, text=True,
                           timeout=30)
        assert p.returncode == 2 and words in p.stderr and p.stdout == "", (flags, p)


def test_an_avatar_at_the_edge_of_the_largest_world_moves_on():
    srv = Server(A.bin, "--world-size", "8192", "--max-speed", "10000")
    c = Raw(srv.port)
    _, ok = c.handshake("far")
    edge, seq = walk(c, ok["id"], 1, (5000, 0, 0))
    assert 4090 < edge[0] <= 4096, edge
    back, _ = walk(c, ok["id"], seq, (4000, 0, 0))
    assert abs(back[0] - 4000) < 1, back  # not frozen at the edge
    assert srv.stop() == 0


def test_placements_past_the_world_or_too_large_are_refused():
    srv = Server(A.bin)
    w = Raw(srv.port)
    w.handshake("witness")
    pw = srv.account("ann")
    ann = Raw(srv.port)
    ann.handshake("ann", pw)
    obj = upload(ann, 1, read(ROOM), "room.stl", fmt="stl", up=1, pos=(10, 0, 0))
    place = lambda pos, scale=1.0: frame(T["OBJECT_PLACE"], struct.pack("<I", obj["id"]) + transform(pos, 0, scale))
    ann.send(place((10, 0, 0), 1000))
    assert "long along" in refused(ann, obj["id"], E["PLACEMENT"])["message"]
    ann.send(place((600, 0, 0)))
    assert "past the world" in refused(ann, obj["id"], E["PLACEMENT"])["message"]
    # A mesh reaching 100 km (within the importer's bound) is refused at upload, at any scale.
    far = box_obj((0, 0, 0), (1e5, 1, 1))
    for uid, scale in [(2, 1.0), (3, 1000.0)]:
        ann.send(upload_frames(uid, far, "far.obj", fmt="obj", scale=scale))
        assert "cannot go there" in refused(ann, uid, E["PLACEMENT"])["message"]
    # Scale 1e30 does not even decode: the sender is closed, nobody else notices.
    mallory = Raw(srv.port)
    mallory.handshake("mallory", srv.account("mallory"))
    mallory.send(frame(T["OBJECT_PLACE"], struct.pack("<I", obj["id"]) + transform((0, 0, 0), 0, 1e30)))
    errors = [m for m in mallory.wait_closed() if m["type"] == "error"]
    assert errors and errors[0]["code"] == E["BAD_VALUE"], errors
    still_moving(w, 1)
    # A placement within the limits still works, and everyone hears of it.
    ann.send(place((-20, 0, 5), 2.0))
    w.expect("object", where=lambda m: m["id"] == obj["id"] and m["pos"][0] == -20)
    assert srv.stop() == 0
    db = sqlite3.connect(srv.db)
    assert db.execute("SELECT count(*) FROM objects WHERE removed_at IS NULL").fetchone()[0] == 1


def test_avatars_spawn_outside_objects():
    srv = Server(A.bin, "--refine-interval", "0")
    pw = srv.account("ann")
    ann = Raw(srv.port)
    ann.handshake("ann", pw)
    teapot = upload(ann, 1, read(TEAPOT), "teapot.obj", fmt="obj", pos=(3, 0, -3), scale=3.0)
    size = (0.6, 1.8, 0.6)
    for i in range(12):
        c = Raw(srv.port)
        _, ok = c.handshake(f"guest{i}")
        assert not overlaps(ok["pos"], size, teapot["boxes"][0]), (ok["pos"], teapot["boxes"][0])
        c.close()
    time.sleep(0.5)  # a tick or two for any inside collision to be logged
    assert srv.stop() == 0
    db = sqlite3.connect(srv.db)
    assert db.execute("SELECT count(*) FROM collisions WHERE inside = 1").fetchone()[0] == 0
    assert "no free spawn point" not in srv.logtext()


def test_no_free_spawn_point_is_said():
    srv = Server(A.bin, "--world-size", "40", "--spawn-radius", "5", "--refine-interval", "0")
    pw = srv.account("ann")
    ann = Raw(srv.port)
    ann.handshake("ann", pw)
    upload(ann, 1, box_obj((-20, 0, -20), (20, 3, 20)), "floor-to-wall.obj", fmt="obj")
    c = Raw(srv.port)
    c.handshake("squeezed")
    still_moving(c, 1)
    assert srv.stop() == 0
    assert "no free spawn point within 64 m" in srv.logtext()


def test_an_object_that_cannot_stand_anywhere_is_not_restored_half():
    srv = Server(A.bin)
    pw = srv.account("ann")
    ann = Raw(srv.port)
    ann.handshake("ann", pw)
    keep = upload(ann, 1, read(ROOM), "room.stl", fmt="stl", up=1, pos=(10, 0, 0))
    bad = upload(ann, 2, read(ROOM), "room2.stl", fmt="stl", up=1, pos=(-10, 0, 0))
    assert srv.stop() == 0
    db = sqlite3.connect(srv.db)
    with db:  # what an older server let through: a scale that overflows every box
        db.execute("UPDATE objects SET scale = 1e38 WHERE id = ?", (bad["id"],))
    db.close()
    srv = Server(A.bin, db=srv.db)
    log = srv.logtext()
    assert f"object {bad['id']} \"room2.stl\" of ann not restored" in log and "marked removed" in log, log
    w = Raw(srv.port)
    w.handshake("witness")
    seen = w.expect("object")
    assert seen["id"] == keep["id"], seen
    still_moving(w, 1)
    assert srv.stop() == 0
    db = sqlite3.connect(srv.db)
    assert db.execute("SELECT removed_at IS NOT NULL FROM objects WHERE id = ?", (bad["id"],)).fetchone() == (1,)


if __name__ == "__main__":
    run([test_flags_are_checked_against_the_limits_they_feed, test_an_avatar_at_the_edge_of_the_largest_world_moves_on,
         test_placements_past_the_world_or_too_large_are_refused, test_avatars_spawn_outside_objects,
         test_no_free_spawn_point_is_said, test_an_object_that_cannot_stand_anywhere_is_not_restored_half])
