"""VR poses (protocol version 2): a move's facing, head and hands reach the
clients that see the avatar and no others, only when they changed beyond
the server's thresholds; a bad pose ends only its sender's connection and
moves nothing."""
import math
import os
import struct
import subprocess

from harness import E, Client, Raw, Server, T, args, close_to, frame, move, ping, run

A = args()
ONE = 32767  # PROTO_QUAT_ONE


def pose(yaw, pitch=0.0, head=None, hands=(), quat=(0, 0, 0, ONE)):
    """A pose's bytes: the facing, then the head and hands given as
    millimetres from the avatar (each with the quaternion quat)."""
    parts = [] if head is None else [head, *hands]
    bits = (1 if head is not None else 0) | (2 if len(hands) > 0 else 0) | (4 if len(hands) > 1 else 0)
    return struct.pack("<ffB", yaw, pitch, bits) + b"".join(struct.pack("<3h4h", *p, *quat) for p in parts)


def move_posed(seq, pos, tail):
    return frame(T["MOVE"], struct.pack("<I3f", seq, *pos) + tail)


def joined(port, name):
    c = Raw(port)
    _, ok = c.handshake(name)
    return c, ok["id"]


def walk(c, me, seq, to):
    """Moves c's avatar me to `to`, a move per acknowledged move (each
    goes at most max speed x a quarter second); returns the next seq and
    every message seen on the way."""
    seen = []
    for seq in range(seq, seq + 50):
        c.send(move(seq, to))
        seen += c.collect("snapshot", where=lambda m, seq=seq: m["ack"] == seq)
        if close_to(seen[-1]["avatars"].get(me, ()), to):
            return seq + 1, seen
    raise AssertionError(f"avatar {me} did not reach {to}")


def test_pose_reaches_viewers_only():
    srv = Server(A.bin, "--max-speed", "400", "--spawn-radius", "4")
    far, far_id = joined(srv.port, "far")
    far_seq, _ = walk(far, far_id, 1, (300, 0, 300))
    near, near_id = joined(srv.port, "near")
    poser, poser_id = joined(srv.port, "poser")
    near.expect("joined", where=lambda m: m["id"] == poser_id)
    # The first pose: the facing and a head 1.7 m up, turned a quarter about y.
    q = (0, round(ONE * math.sqrt(0.5)), 0, round(ONE * math.sqrt(0.5)))
    first = pose(0.5, 0.1, head=(0, 1700, 0), hands=((-300, 1200, 400), (300, 1200, 400)), quat=q)
    poser.send(move_posed(1, (0, 0, 0), first))
    got = near.expect("pose", where=lambda m: m["id"] == poser_id)
    assert got["pose"] == first, got
    # The tick that sent it to near is over for far too: its pong comes
    # after anything that tick had for it.
    far.send(ping(1))
    seen = far.collect("pong", where=lambda m: m["stamp"] == 1)
    assert not [m for m in seen if m["type"] in ("pose", "joined")], seen
    # Under the threshold (0.005 rad of yaw, 3 mm of head): not forwarded;
    # the move that comes with it is, in the same tick.
    small = pose(0.505, 0.1, head=(3, 1700, 0), hands=((-300, 1200, 400), (300, 1200, 400)), quat=q)
    poser.send(move_posed(2, (1, 0, 0), small))
    seen = near.collect("snapshot", where=lambda m: close_to(m["avatars"].get(poser_id, ()), (1, 0, 0)))
    assert not [m for m in seen if m["type"] == "pose"], seen
    # Over it (0.05 rad): forwarded, as sent.
    big = pose(0.55, 0.1, head=(3, 1700, 0), hands=((-300, 1200, 400), (300, 1200, 400)), quat=q)
    poser.send(move_posed(3, (1, 0, 0), big))
    assert near.expect("pose", where=lambda m: m["id"] == poser_id)["pose"] == big
    # A hand that moved 10 mm is a change too; a pose without hands as well.
    moved = pose(0.55, 0.1, head=(3, 1700, 0), hands=((-310, 1200, 400), (300, 1200, 400)), quat=q)
    poser.send(move_posed(4, (1, 0, 0), moved))
    assert near.expect("pose", where=lambda m: m["id"] == poser_id)["pose"] == moved
    facing = pose(-0.25, -0.2)
    poser.send(move_posed(5, (1, 0, 0), facing))
    assert near.expect("pose", where=lambda m: m["id"] == poser_id)["pose"] == facing
    # A newcomer that sees the avatar gets its pose right after it joins
    # its view; the poser is not sent its own.
    late, _ = joined(srv.port, "late")
    seen = late.collect("pose", where=lambda m: m["id"] == poser_id)
    assert seen[-1]["pose"] == facing
    assert [m["type"] for m in seen if m.get("id") == poser_id] == ["joined", "pose"], seen
    poser.send(ping(9))
    seen = poser.collect("pong", where=lambda m: m["stamp"] == 9)
    assert not [m for m in seen if m["type"] == "pose" and m["id"] == poser_id], seen
    # far walks into view: it is told of the poser and its pose.
    far.send(ping(2))
    far.expect("pong", where=lambda m: m["stamp"] == 2)
    _, seen = walk(far, far_id, far_seq, (2, 0, 2))
    if not [m for m in seen if m["type"] == "pose"]:
        seen += far.collect("pose", where=lambda m: m["id"] == poser_id)
    told = [m for m in seen if m["type"] in ("joined", "pose") and m["id"] == poser_id]
    assert [m["type"] for m in told] == ["joined", "pose"] and told[1]["pose"] == facing, told
    for c in (far, near, poser, late):
        c.close()
    assert srv.stop() == 0


def test_bad_poses():
    """NaN, a quaternion far from unit length, a hand out of reach, hands
    without a head, a pitch past straight up: the protocol's error, the
    close, and the avatar neither moved nor turned for those who see it."""
    srv = Server(A.bin, "--max-speed", "400", "--spawn-radius", "4")
    watcher, _ = joined(srv.port, "watcher")
    nan = struct.pack("<I", 0x7fc00000)
    cases = [
        ("nan yaw", nan + pose(0, 0)[4:], E["NOT_FINITE"]),
        ("nan pitch", struct.pack("<f", 0) + nan + b"\0", E["NOT_FINITE"]),
        ("pitch past up", pose(0, 1.6), E["BAD_VALUE"]),
        ("quaternion not unit", pose(0, 0, head=(0, 1700, 0), quat=(0, 0, 0, ONE // 2)), E["BAD_VALUE"]),
        ("hand out of reach", pose(0, 0, head=(0, 1700, 0), hands=((0, 1700, 1600),)), E["BAD_VALUE"]),
        ("hands without head", struct.pack("<ffB", 0, 0, 2) + struct.pack("<3h4h", 0, 1000, 0, 0, 0, 0, ONE),
         E["BAD_VALUE"]),
        ("cut short", pose(0, 0, head=(0, 1700, 0))[:-2], E["SHORT"]),
    ]
    for name, tail, code in cases:
        bad, bad_id = joined(srv.port, "bad")
        watcher.expect("joined", where=lambda m: m["id"] == bad_id)
        bad.send(move_posed(1, (20, 0, 20), tail))
        msgs = bad.wait_closed(timeout=10)
        errors = [m for m in msgs if m["type"] == "error"]
        assert errors and errors[0]["code"] == code, (name, msgs)
        seen = watcher.collect("left", where=lambda m: m["id"] == bad_id)
        assert not [m for m in seen if m["type"] == "pose"], (name, seen)
        assert not [m for m in seen if m["type"] == "snapshot" and bad_id in m["avatars"]], (name, seen)
        bad.close()
    # The watcher was served all along.
    watcher.send(ping(5))
    watcher.expect("pong", where=lambda m: m["stamp"] == 5)
    watcher.close()
    assert srv.stop() == 0


def test_client_pose_and_bots():
    """cvre-client's pose command turns its avatar and shows the others'
    poses as events; bots with --pose send a facing and a head as they walk."""
    srv = Server(A.bin, "--max-speed", "200", "--spawn-radius", "4", "--joins-per-second", "0",
                 "--max-per-address", "0")
    viewer, poser = Client(A.bin, srv.port, "viewer", None), Client(A.bin, srv.port, "poser", None)
    me = poser.until("poser joins", lambda e: e["event"] == "join_ok")["id"]
    viewer.until("viewer sees poser", lambda e: e["event"] == "joined" and e["id"] == me)
    poser.send("pose 90 10\n")
    poser.until("pose done", lambda e: e["event"] == "done" and e["command"] == "pose")
    e = viewer.until("viewer sees the pose", lambda e: e["event"] == "pose" and e["id"] == me)
    assert abs(e["yaw"] - math.pi / 2) < 1e-6 and abs(e["pitch"] - math.radians(10)) < 1e-6, e
    # The head at eye height, turned 90 degrees about y and 10 about x.
    assert close_to(e["head"]["pos"], (0, 0.93 * 1.8, 0), 0.002), e
    half, tilt = math.radians(45), math.radians(5)
    want = (math.cos(half) * math.sin(tilt), math.sin(half) * math.cos(tilt), -math.sin(half) * math.sin(tilt),
            math.cos(half) * math.cos(tilt))
    assert close_to(e["head"]["rot"], want, 0.002), e
    assert "left" not in e and "right" not in e, e
    # Past straight up: a script error (exit 2), nothing sent.
    poser.send("pose 90 95\n")
    assert poser.wait(30) == 2 and "pose: bad number '95'" in poser.stderr, poser.stderr
    viewer.until("viewer sees poser leave", lambda e: e["event"] == "left" and e["id"] == me)
    assert [e for e in viewer.of("pose") if e["id"] == me] == [e], viewer.of("pose")
    viewer.send("quit\n")
    assert viewer.wait(30) == 0, viewer.stderr

    # Two bots with --pose beside a raw watcher: their poses arrive.
    watcher, _ = joined(srv.port, "watcher")
    bots = subprocess.run([os.path.join(A.bin, "cvre-client"), "--port", str(srv.port), "--bots", "2", "--pose",
                           "--duration", "2", "--pattern", "circle"], capture_output=True, text=True, timeout=60)
    assert bots.returncode == 0, bots
    seen = watcher.collect("left", timeout=30, where=lambda m: m["reason"] == 1)
    poses = [m for m in seen if m["type"] == "pose"]
    assert poses, seen[-5:]
    yaw, pitch, parts = struct.unpack_from("<ffB", poses[-1]["pose"])
    assert parts == 1 and pitch == 0 and len(poses[-1]["pose"]) == 9 + 14, poses[-1]
    watcher.close()
    assert srv.stop() == 0


run([test_pose_reaches_viewers_only, test_bad_poses, test_client_pose_and_bots])
