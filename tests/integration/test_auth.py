"""Accounts on the wire: guests walk and look, accounts change the world;
a wrong password, a used token, another's name or a join without a
password on --auth required each end in an error and a close while a
witness keeps moving; logins are rate-limited per address and never
logged with their password; objects belong to accounts and collisions
carry their users row from the first tick."""
import json
import os
import sqlite3
import struct
import subprocess
import time

from harness import (E, MODELS, T, Raw, Server, args, frame, hello, join, move, refused, refused_join, run,
                     still_moving, upload, upload_frames)

A = args()
ROOM = os.path.join(MODELS, "openings", "openfoam_room_with_doorway.stl")
ROOM_WORLD = os.path.join(os.path.dirname(os.path.abspath(__file__)), "room.world")


def test_guests_accounts_and_tokens():
    srv = Server(A.bin, "--login-burst", "50")
    w = Raw(srv.port)
    w.handshake("witness")
    pw = srv.account("ann", "correct horse")
    # a guest walks and looks, but may not change the world
    g = Raw(srv.port)
    g.handshake("visitor")
    g.send(frame(T["UPLOAD_BEGIN"], struct.pack("<II", 1, 10) + b"\x01a\x00" + struct.pack("<Bf", 0, 1.0)))
    assert "guests" in refused(g, 1, E["GUEST"])["message"]
    still_moving(w, 1)
    # a guest may not take an account's name, in any case
    for name in ("ann", "ANN"):
        assert "belongs to an account" in refused_join(srv.port, name, E["AUTH"])
    # a wrong password, an unknown account: the same answer
    assert "wrong name or password" in refused_join(srv.port, "ann", E["AUTH"], password="wrong")
    assert "wrong name or password" in refused_join(srv.port, "nobody", E["AUTH"], password="x")
    still_moving(w, 2)
    # the right password: join_ok with a resume token, used once
    a = Raw(srv.port)
    _, ok = a.handshake("ann", pw)
    assert ok["token"] is not None and len(ok["token"]) == 32, ok
    a.close()
    b = Raw(srv.port)
    _, ok2 = b.handshake("ann", token=ok["token"])
    assert ok2["token"] is not None and ok2["token"] != ok["token"]
    assert "token" in refused_join(srv.port, "ann", E["AUTH"], token=ok["token"])  # used
    assert "token" in refused_join(srv.port, "bob", E["AUTH"], token=ok2["token"])  # another's name
    b.close()
    still_moving(w, 3)
    assert srv.stop() == 0
    log = srv.logtext()
    assert "correct horse" not in log and "wrong" in log, log[-2000:]
    assert log.count('join as "ann" refused') >= 3, log[-2000:]


def test_objects_belong_to_accounts():
    srv = Server(A.bin)
    w = Raw(srv.port)
    w.handshake("witness")
    ann = Raw(srv.port)
    ann.handshake("ann", srv.account("ann"))
    obj = upload(ann, 1, open(ROOM, "rb").read(), "room.stl", fmt="stl", up=1, pos=(10, 0, 0))
    assert obj["owner"] == "ann"
    remove = frame(T["OBJECT_REMOVE"], struct.pack("<I", obj["id"]))
    # another account may not remove it; a guest may not even try
    bob = Raw(srv.port)
    bob.handshake("bob", srv.account("bob"))
    bob.send(remove)
    refused(bob, obj["id"], E["NOT_OWNER"])
    g = Raw(srv.port)
    g.handshake("eve")
    g.send(remove)
    refused(g, obj["id"], E["GUEST"])
    # a second session of ann (with her password) may; an admin may too
    still_moving(w, 1)
    root = Raw(srv.port)
    root.handshake("root", srv.account("root", admin=True))
    obj2 = upload(ann, 2, open(ROOM, "rb").read(), "room2.stl", fmt="stl", up=1, pos=(-10, 0, 0))
    root.send(frame(T["OBJECT_REMOVE"], struct.pack("<I", obj2["id"])))
    root.expect("object_removed", where=lambda m: m["id"] == obj2["id"])
    ann2 = Raw(srv.port)
    ann2.handshake("ann", "pw-ann")
    ann2.send(remove)
    ann2.expect("object_removed", where=lambda m: m["id"] == obj["id"])
    still_moving(w, 2)
    assert srv.stop() == 0


def test_password_change_and_deletion_reach_a_running_server():
    """A new password ends the account's sessions; a deleted account's
    sessions end and its objects pass to the world, which everyone hears."""
    srv = Server(A.bin)
    w = Raw(srv.port)
    w.handshake("witness")
    ann = Raw(srv.port)
    ann.handshake("ann", srv.account("ann"))
    obj = upload(ann, 1, open(ROOM, "rb").read(), "room.stl", fmt="stl", up=1)
    p = subprocess.run([os.path.join(A.bin, "cvre-admin"), "--db", srv.db, "user", "passwd", "ann",
                        "--password-stdin"], input="new-pw\n", capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p
    assert [m for m in ann.wait_closed(5) if m["type"] == "bye"], "ann was not logged out"
    ann = Raw(srv.port)
    ann.handshake("ann", "new-pw")
    p = subprocess.run([os.path.join(A.bin, "cvre-admin"), "--db", srv.db, "user", "del", "ann"],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p
    assert [m for m in ann.wait_closed(5) if m["type"] == "bye"], "ann's session outlived her account"
    m = w.expect("object", where=lambda m: m["id"] == obj["id"] and m["owner"] == "world")
    still_moving(w, 1)
    assert srv.stop() == 0


def test_upload_quotas():
    """Two objects an account, counted from the store: the third is
    refused until one goes; another account has its own quota."""
    srv = Server(A.bin, "--quota-objects", "2")
    ann = Raw(srv.port)
    ann.handshake("ann", srv.account("ann"))
    room = open(ROOM, "rb").read()
    first = upload(ann, 1, room, "a.stl", fmt="stl", up=1)
    upload(ann, 2, room, "b.stl", fmt="stl", up=1)
    ann.send(upload_frames(3, room, "c.stl", fmt="stl", up=1))
    assert "over your quota: you have 2 objects" in refused(ann, 3, E["UPLOAD"])["message"]
    ann.send(frame(T["OBJECT_REMOVE"], struct.pack("<I", first["id"])))
    ann.expect("object_removed")
    upload(ann, 4, room, "c.stl", fmt="stl", up=1)
    bob = Raw(srv.port)
    bob.handshake("bob", srv.account("bob"))
    upload(bob, 1, room, "d.stl", fmt="stl", up=1)
    assert srv.stop() == 0
    # a restart keeps counting what is stored
    srv = Server(A.bin, "--quota-objects", "2", db=srv.db)
    ann = Raw(srv.port)
    ann.handshake("ann", "pw-ann")
    ann.send(upload_frames(5, room, "e.stl", fmt="stl", up=1))
    refused(ann, 5, E["UPLOAD"])
    assert srv.stop() == 0


def until_taken(port, first, want, codes, timeout=20):
    """A connection that sends `first` and gets a `want` message, tried
    again every 0.2 s while the server refuses it with an error whose code
    is in codes (or closes it unread: a refused connection's reset)."""
    end = time.time() + timeout
    while True:
        c = Raw(port)
        msgs = []
        try:
            c.send(first)
        except (BrokenPipeError, ConnectionResetError):
            c.closed = True
        while not c.closed and not any(m["type"] == want for m in msgs):
            assert time.time() < end, f"no {want} within {timeout}s; saw {msgs}"
            msgs += c.poll(0.2, first=True)
        if not c.closed:
            c.queue = msgs[[m["type"] for m in msgs].index(want) + 1:]
            return c
        assert all(m["type"] == "welcome" or m["type"] == "error" and m["code"] in codes for m in msgs), msgs
        assert time.time() < end, f"still refused after {timeout}s: {msgs}"
        time.sleep(0.2)


def admitted(port):
    """A connection the server answers, once it no longer counts closed ones
    from this address against --max-per-address."""
    return until_taken(port, hello(), "welcome", (E["SERVER_FULL"],))


def retried(port, name, password, *codes):
    """A join that succeeds once a refusal with one of codes is over."""
    return until_taken(port, hello() + join(name, password=password), "join_ok", codes)


def test_required_mode_and_rate_limit():
    # Five password checks queue on one thread, at a tenth of a second each
    # on a quiet machine: the handshake's time limit is not what is tested.
    srv = Server(A.bin, "--auth", "required", "--handshake-timeout", "60000")
    w = Raw(srv.port)
    w.handshake("ann", srv.account("ann"))
    assert "accounts only" in refused_join(srv.port, "visitor", E["AUTH_REQUIRED"])
    # 5 logins at once, then one every 2 s: the witness's took one
    # (sent together: one after the other, the checks' time would refill it)
    cs = [Raw(srv.port) for _ in range(6)]
    for i, c in enumerate(cs):
        c.send(hello() + join("ann", password="guess%d" % i))
    codes = sorted([m for m in c.wait_closed(30) if m["type"] == "error"][0]["code"] for c in cs)
    # six past a burst of five (less what refilled since the witness's)
    assert set(codes) == {E["AUTH"], E["RATE_LIMITED"]} and codes.count(E["AUTH"]) >= 4, codes
    still_moving(w, 1)
    retried(srv.port, "ann", "pw-ann", E["RATE_LIMITED"])  # until a token comes back
    still_moving(w, 2)
    assert srv.stop() == 0
    assert "guess" not in srv.logtext()


def test_abuse_limits():
    """Connections and joins per address, and moves per connection."""
    srv = Server(A.bin, "--max-per-address", "4", "--joins-per-second", "2")
    w = Raw(srv.port)
    w.handshake("witness")
    # joins: a burst of twice the rate, then refused
    codes = []
    for i in range(4):
        c = Raw(srv.port)
        c.send(hello() + join("j%d" % i))
        codes.append(c.expect("join_ok")["type"] if i < 3 else
                     [m for m in c.wait_closed() if m["type"] == "error"][0]["code"])
        c.close()
    assert codes == ["join_ok"] * 3 + [E["RATE_LIMITED"]], codes
    # connections: the witness and three more (taken once the server has
    # seen the joins' connections close), then the fifth is refused
    more = [admitted(srv.port) for _ in range(3)]
    extra = Raw(srv.port)
    msgs = extra.wait_closed()
    assert msgs and msgs[0]["code"] == E["SERVER_FULL"] and "your address" in msgs[0]["message"], msgs
    for c in more:
        c.close()
    # moves: 40 a second are taken, a flood is cut off (once the four are
    # seen closed and a join token is back)
    f = retried(srv.port, "flood", None, E["SERVER_FULL"], E["RATE_LIMITED"])
    f.send(b"".join(move(seq, (1, 0, 1)) for seq in range(1, 2001)))
    errors = [m for m in f.wait_closed() if m["type"] == "error"]
    assert errors and errors[0]["code"] == E["RATE_LIMITED"] and "flooding" in errors[0]["message"], errors
    still_moving(w, 1)
    assert srv.stop() == 0
    assert "over 4 connections from this address" in srv.logtext()


def test_collisions_carry_their_user_from_the_first_tick():
    """Two guests walk into the room's wall at once on joining: every row
    has a user, and they are two users."""
    srv = Server(A.bin, "--world", ROOM_WORLD, "--spawn-radius", "0")
    cs = [Raw(srv.port) for _ in range(2)]
    for i, c in enumerate(cs):
        c.send(hello() + join("walker") + move(1, (20, 0, 0)))  # the move right behind the join
    for c in cs:
        c.expect("join_ok")
    for seq in range(2, 100):  # 2 s: the wall is 4.4 m away at 5 m/s
        for c in cs:
            c.send(move(seq, (20, 0, 0)))
        time.sleep(0.02)
    for c in cs:
        c.expect("collision", timeout=5)
    assert srv.stop() == 0
    db = sqlite3.connect(srv.db)
    rows = db.execute("SELECT count(*), count(user_id), count(DISTINCT user_id) FROM collisions").fetchone()
    assert rows[0] > 0 and rows[1] == rows[0] and rows[2] == 2, rows


def test_client_logs_in_from_the_environment():
    srv = Server(A.bin)
    pw = srv.account("ann")
    env = dict(os.environ, CVRE_PASSWORD=pw)
    p = subprocess.run([os.path.join(A.bin, "cvre-client"), "--port", str(srv.port), "--name", "ann"],
                       input="ping\nquit\n", capture_output=True, text=True, timeout=30, env=env)
    events = [json.loads(line) for line in p.stdout.splitlines()]
    ok = [e for e in events if e["event"] == "join_ok"]
    assert ok and len(ok[0]["resume_token"]) == 64, p.stdout
    env = dict(os.environ, CVRE_TOKEN=ok[0]["resume_token"])
    p = subprocess.run([os.path.join(A.bin, "cvre-client"), "--port", str(srv.port), "--name", "ann"],
                       input="quit\n", capture_output=True, text=True, timeout=30, env=env)
    assert '"join_ok"' in p.stdout, p.stdout + p.stderr
    p = subprocess.run([os.path.join(A.bin, "cvre-client"), "--port", str(srv.port), "--login"],
                       input="quit\n", capture_output=True, text=True, timeout=30,
                       env={k: v for k, v in os.environ.items() if k != "CVRE_PASSWORD"},
                       start_new_session=True)  # no terminal to ask on
    assert p.returncode == 2 and "no terminal" in p.stderr, p
    assert srv.stop() == 0


run([test_guests_accounts_and_tokens, test_objects_belong_to_accounts, test_required_mode_and_rate_limit,
     test_abuse_limits, test_upload_quotas, test_password_change_and_deletion_reach_a_running_server,
     test_collisions_carry_their_user_from_the_first_tick, test_client_logs_in_from_the_environment])
