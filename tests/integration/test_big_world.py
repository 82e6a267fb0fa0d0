#!/usr/bin/env python3
"""Objects have an area of interest, like avatars: in a world of 20,000
objects, 50 clients join and walk across it; none is disconnected, and each
knows exactly the objects near it (all within the radius, none past the
radius plus the view's slack)."""
import math
import os
import tempfile

from harness import TEMP_DIRS, Server, args, run
from tiles import Walker, pump, pump_until, write_world

A = args()
OBJECTS = 20000
CLIENTS = 50
RADIUS = 32.0
SPEED = 25.0


def views_whole(walkers, rects):
    return all(w.pos is not None and w.view(rects, RADIUS) == ([], []) for w in walkers)


def test_clients_know_the_objects_near_them_as_they_walk():
    tmp = tempfile.mkdtemp(prefix="cvre-bigworld-")
    TEMP_DIRS.append(tmp)
    world, rects = write_world(tmp, OBJECTS)
    srv = Server(A.bin, "--world", world, "--aoi-radius", str(RADIUS), "--max-speed", str(SPEED),
                 "--joins-per-second", "0", "--max-per-address", "0", "--refine-interval", "0")
    assert f"{OBJECTS} objects loaded from 1 model files" in srv.logtext()
    walkers = [Walker(srv.port, f"walker{i}") for i in range(CLIENTS)]
    assert pump_until(walkers, lambda: views_whole(walkers, rects), 60), \
        [(w.pos, w.view(rects, RADIUS)) for w in walkers if w.pos is None or w.view(rects, RADIUS) != ([], [])][:3]
    joined_with = [len(w.known) for w in walkers]
    # Each walks 100 m in its own direction (about 4 s at 25 m/s), one
    # move request every 50 ms, as a client would send them.
    targets = []
    for i, w in enumerate(walkers):
        a = 2 * math.pi * i / CLIENTS
        targets.append((w.pos[0] + 100 * math.cos(a), 0.0, w.pos[2] + 100 * math.sin(a)))
    arrived = lambda: all(math.hypot(w.pos[0] - t[0], w.pos[2] - t[2]) < 0.5 for w, t in zip(walkers, targets))
    for _ in range(400):
        for w, t in zip(walkers, targets):
            w.walk_to(t)
        pump(walkers, 0.05)
        if arrived():
            break
    assert arrived(), [(w.pos, t) for w, t in zip(walkers, targets)][:3]
    assert pump_until(walkers, lambda: views_whole(walkers, rects), 10), \
        [w.view(rects, RADIUS) for w in walkers][:3]
    assert not [w for w in walkers if w.closed or w.errors], [w.errors for w in walkers if w.closed or w.errors]
    # They were told of objects as they went, and forgot those behind them.
    assert all(w.infos > n for w, n in zip(walkers, joined_with))
    near = sorted(len(w.known) for w in walkers)
    assert 20 < near[0] and near[-1] < 400, near  # about pi * 36^2 / 25 tiles each, not 20,000
    for w in walkers:
        w.close()
    assert srv.stop() == 0
    log = srv.logtext()
    assert "backlog" not in log and "not reading" not in log, log[-2000:]
    # counted over the whole run, across stats intervals (every 10 s)
    assert f"stopped: {CLIENTS} connections served" in log, log[-2000:]


if __name__ == "__main__":
    run([test_clients_know_the_objects_near_them_as_they_walk])
