"""A live multi-user session: real cvre-client processes see each other's
joins, moves and departures; the area of interest is exact; moves are
clamped; sessions survive a restart in SQLite."""
import os
import re
import sqlite3
import time

from harness import Client, Raw, Server, args, close_to, move, ping, run

A = args()


def test_clients_see_each_other():
    """Three real clients, driven step by step: each step waits for the
    events that show the last one done, not for a time."""
    srv = Server(A.bin, "--max-speed", "200", "--spawn-radius", "4")
    names = ["alice", "bob", "carol"]
    clients = {n: Client(A.bin, srv.port, n, None) for n in names}
    ids = {n: c.until(f"{n} joins", lambda e: e["event"] == "join_ok")["id"] for n, c in clients.items()}
    for n, c in clients.items():
        for o in names:
            if o != n:
                c.until(f"{n} sees {o} join", lambda e, o=o: e["event"] == "joined" and e["id"] == ids[o])
    targets = {"alice": (10, 0, 10), "bob": (-10, 0, 5), "carol": (0, 0, -5)}
    moved = lambda who, pos: clients[who].until(f"{who}'s move to {pos} done", lambda e: e["event"] == "done" and
                                               e["command"] == "move" and close_to(e["pos"], pos))
    for n, c in clients.items():
        c.send("move %g %g %g\n" % targets[n])
    for n in names:
        moved(n, targets[n])

    def saw_at(viewer, who, pos):
        clients[viewer].until(f"{viewer} sees {who} at {pos}", lambda e: e["event"] == "snapshot" and any(
            a["id"] == ids[who] and close_to(a["pos"], pos) for a in e["avatars"]))

    saw_at("alice", "bob", targets["bob"])
    saw_at("bob", "alice", targets["alice"])
    saw_at("alice", "alice", targets["alice"])  # its own authoritative position
    # carol walks out of everyone's range, bob leaves
    clients["carol"].send("move 300 0 300\n")
    moved("carol", (300, 0, 300))
    left = lambda who, reason: clients["alice"].until(
        f"alice sees {who} leave ({reason})", lambda e: e["event"] == "left" and e["id"] == ids[who] and
        e["reason"] == reason)
    left("carol", "out_of_range")
    clients["bob"].send("quit\n")
    left("bob", "disconnected")
    for n in ["alice", "carol"]:
        clients[n].send("quit\n")
    for n, c in clients.items():
        assert c.wait(30) == 0, f"{n} exited with {c.proc.returncode}: {c.stderr}"
        assert [e["event"] for e in c.events[:2]] == ["welcome", "join_ok"], c.events[:2]
        joined = {e["name"]: e["id"] for e in c.of("joined")}
        assert {k: v for k, v in ids.items() if k != n} == joined, (n, joined)
    assert srv.stop() == 0

    db = sqlite3.connect(srv.db)
    rows = db.execute("SELECT u.name, s.end_reason, s.joined_at IS NOT NULL, s.ended_at >= s.started_at "
                      "FROM sessions s JOIN users u ON u.id = s.user_id ORDER BY u.name").fetchall()
    # guests: one users row each, "guest<session>:<name>"
    assert all(re.fullmatch(r"guest\d+:\w+", r[0]) for r in rows), rows
    rows = sorted((r[0].split(":", 1)[1],) + r[1:] for r in rows)
    assert rows == [("alice", "quit", 1, 1), ("bob", "quit", 1, 1), ("carol", "quit", 1, 1)], rows
    db.close()

    # A restart keeps the history and continues the session ids.
    srv2 = Server(A.bin, db=srv.db)
    r = Raw(srv2.port)
    welcome, _ = r.handshake("dave")
    assert welcome["session"] == 4, welcome
    r.close()
    assert srv2.stop() == 0
    db = sqlite3.connect(srv.db)
    assert db.execute("SELECT count(*) FROM sessions").fetchone()[0] == 4
    assert db.execute("SELECT end_reason FROM sessions WHERE id = 4").fetchone()[0] == "closed without bye"


def test_area_of_interest_is_exact():
    """25 avatars on a line 10 m apart: each must know exactly those within
    the 64 m radius, through joins and leaves as they walk into place."""
    srv = Server(A.bin, "--max-speed", "1000", "--spawn-radius", "0", "--joins-per-second", "0")
    n = 25
    cs = [Raw(srv.port) for _ in range(n)]
    oks = [c.handshake(f"p{i}")[1] for i, c in enumerate(cs)]
    ids, pos = [ok["id"] for ok in oks], [ok["pos"] for ok in oks]
    # Each move covers at most max speed x the time since the last one:
    # every avatar moves again, after the snapshot that acks its last move
    # (with its position if that changed), until it stands in its place.
    msgs, placed, seq, end = [[] for _ in cs], set(), 0, time.time() + 60
    while len(placed) < n:
        assert time.time() < end, f"only {len(placed)} of {n} avatars in place"
        seq += 1
        todo = [i for i in range(n) if i not in placed]
        for i in todo:
            cs[i].send(move(seq, (10.0 * i, 0, 0)))
        for i in todo:
            msgs[i] += cs[i].collect("snapshot", 10, lambda m: m["ack"] == seq)
            pos[i] = msgs[i][-1]["avatars"].get(ids[i], pos[i])
            if close_to(pos[i], (10.0 * i, 0, 0), 1e-4):
                placed.add(i)
    # Every view was made after the last move (its ack was read); a ping's
    # pong then comes after all it sent.
    for i, c in enumerate(cs):
        c.send(ping(i))
        msgs[i] += c.collect("pong", 10, lambda m, i=i: m["stamp"] == i)
    for i, c in enumerate(cs):
        known = set()
        for m in msgs[i]:
            if m["type"] == "joined":
                known.add(m["id"])
            elif m["type"] == "left":
                known.discard(m["id"])
        want = {ids[j] for j in range(n) if j != i and abs(10 * i - 10 * j) <= 64}
        assert known == want, (i, sorted(known), sorted(want))
    for c in cs:
        c.close()
    assert srv.stop() == 0


def test_moves_are_clamped():
    srv = Server(A.bin, "--max-speed", "10", "--spawn-radius", "0", "--world-size", "20")
    r = Raw(srv.port)
    _, ok = r.handshake("runner")
    me = ok["id"]
    # 10 m/s and at most 0.25 s of credit: one move covers at most 2.5 m.
    r.send(move(1, (40, 0, 0)))
    snap = r.expect("snapshot", where=lambda m: m["ack"] == 1)
    x = snap["avatars"][me][0]
    assert 0 < x <= 2.5 + 1e-4, snap
    # Requests outside the world end at its edge (the box's half-width
    # inside) and on the floor.
    # Each move after the ack of the one before has at least a tick's
    # credit: the avatar walks until the edge stops it, never past it.
    pos, last, seq, end = snap["avatars"][me], None, 1, time.time() + 60
    while pos != last:
        assert time.time() < end, f"still moving at {pos}"
        last, seq = pos, seq + 1
        r.send(move(seq, (80, -5, 0)))
        pos = r.expect("snapshot", where=lambda m: m["ack"] == seq)["avatars"].get(me, pos)
        assert pos[0] <= 10 - 0.3 + 1e-3 and pos[1] >= 0, pos
    assert close_to(pos, (10 - 0.3, 0, 0), 1e-3), pos
    r.close()
    assert srv.stop() == 0


run([test_clients_see_each_other, test_area_of_interest_is_exact, test_moves_are_clamped])
