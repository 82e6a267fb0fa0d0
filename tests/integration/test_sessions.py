"""A live multi-user session: real cvre-client processes see each other's
joins, moves and departures; the area of interest is exact; moves are
clamped; sessions survive a restart in SQLite."""
import os
import re
import sqlite3
import time

from harness import Client, Raw, Server, args, close_to, move, run

A = args()


def test_clients_see_each_other():
    srv = Server(A.bin, "--max-speed", "200", "--spawn-radius", "4")
    scripts = {
        "alice": "wait 1000\nmove 10 0 10\nwait 3000\nquit\n",
        "bob": "wait 1000\nmove -10 0 5\nwait 600\nquit\n",
        "carol": "wait 1000\nmove 0 0 -5\nwait 800\nmove 300 0 300\nwait 800\nquit\n",
    }
    clients = {n: Client(A.bin, srv.port, n, s) for n, s in scripts.items()}
    for n, c in clients.items():
        assert c.wait(30) == 0, f"{n} exited with {c.proc.returncode}: {c.stderr}"
    ids = {n: c.of("join_ok")[0]["id"] for n, c in clients.items()}
    for n, c in clients.items():
        assert [e["event"] for e in c.events[:2]] == ["welcome", "join_ok"], c.events[:2]
        joined = {e["name"]: e["id"] for e in c.of("joined")}
        assert {k: v for k, v in ids.items() if k != n} == joined, (n, joined)
    targets = {"alice": (10, 0, 10), "bob": (-10, 0, 5)}

    def saw_at(viewer, who, pos):
        return any(a["id"] == ids[who] and close_to(a["pos"], pos)
                   for e in clients[viewer].of("snapshot") for a in e["avatars"])

    assert saw_at("alice", "bob", targets["bob"]), "alice never saw bob arrive"
    assert saw_at("bob", "alice", targets["alice"]), "bob never saw alice arrive"
    assert saw_at("alice", "alice", targets["alice"]), "alice's own authoritative position missing"
    moved = lambda who: [e["pos"] for e in clients[who].of("done") if e["command"] == "move"]
    assert close_to(moved("alice")[0], targets["alice"])
    assert close_to(moved("carol")[-1], (300, 0, 300))
    left = {(e["id"], e["reason"]) for e in clients["alice"].of("left")}
    assert (ids["bob"], "disconnected") in left, left
    assert (ids["carol"], "out_of_range") in left, left
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
    ids = [c.handshake(f"p{i}")[1]["id"] for i, c in enumerate(cs)]
    for seq in range(1, 6):  # each move may cover max speed x elapsed time
        for i, c in enumerate(cs):
            c.send(move(seq, (10.0 * i, 0, 0)))
        time.sleep(0.2)
    time.sleep(0.3)
    for i, c in enumerate(cs):
        known = set()
        for m in c.queue + c.poll(0.05):
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
    pos = snap["avatars"][me]
    for seq in range(2, 60):
        r.send(move(seq, (80, -5, 0)))
        time.sleep(0.05)
    for m in r.queue + r.poll(0.5):
        if m["type"] == "snapshot" and me in m["avatars"]:
            pos = m["avatars"][me]
    assert close_to(pos, (10 - 0.3, 0, 0), 1e-3), pos
    r.close()
    assert srv.stop() == 0


run([test_clients_see_each_other, test_area_of_interest_is_exact, test_moves_are_clamped])
