"""A big world of flat tiles, and clients that walk it and keep track of
the objects the server tells them of. Shared by test_big_world.py and
tests/bench/bench_join.py.

A tile is a 1 x 0.2 x 1 m box: low enough to step onto (steps up to
0.35 m), so walkers cross the world without getting stuck."""
import math
import os
import select
import socket
import struct
import time

from harness import T, hello, join, move, split_frames

TILE_SIZE = (1.0, 0.2, 1.0)
VIEW_STEP = 4.0  # SRV_OBJECT_VIEW_STEP: known objects lie within radius + 3 steps


def write_world(dirpath, n, spacing=5.0):
    """Writes tile.obj and a world file of n tiles on a square grid
    centred on 0; returns its path and each tile's (x0, z0, x1, z1) by
    name."""
    sx, sy, sz = TILE_SIZE
    corners = [(x, y, z) for x in (0, sx) for y in (0, sy) for z in (0, sz)]
    faces = ["1 3 4 2", "5 6 8 7", "1 2 6 5", "3 7 8 4", "1 5 7 3", "2 4 8 6"]
    with open(os.path.join(dirpath, "tile.obj"), "w") as f:
        f.write("".join(f"v {x} {y} {z}\n" for x, y, z in corners))
        f.write("".join(f"f {face}\n" for face in faces))
    side = math.ceil(math.sqrt(n))
    origin = -side * spacing / 2
    rects = {}
    path = os.path.join(dirpath, f"tiles{n}.world")
    with open(path, "w") as f:
        for k in range(n):
            x, z = origin + (k // side) * spacing, origin + (k % side) * spacing
            f.write(f"object tile.obj name t{k} at {x:.2f} 0 {z:.2f}\n")
            rects[f"t{k}"] = (x, z, x + sx, z + sz)
    return path, rects


def distance(pos, rect):
    """Horizontal distance from an avatar's position to a tile."""
    x0, z0, x1, z1 = rect
    dx = max(x0 - pos[0], pos[0] - x1, 0.0)
    dz = max(z0 - pos[2], pos[2] - z1, 0.0)
    return math.hypot(dx, dz)


class Walker:
    """One guest connection: what it was told (objects by id, its own
    position) and how many bytes it received."""

    def __init__(self, port, name):
        self.s = socket.create_connection(("127.0.0.1", port), timeout=5)
        self.s.setblocking(False)
        self.s.sendall(hello() + join(name))
        self.buf = b""
        self.known = {}  # object id -> name
        self.avatar = None
        self.pos = None
        self.seq = 0
        self.bytes = 0
        self.closed = False
        self.errors = []
        self.infos = 0
        self.last_info = None  # time.time() of the latest OBJECT_INFO

    def fileno(self):
        return self.s.fileno()

    def take(self):
        try:
            d = self.s.recv(1 << 20)
        except BlockingIOError:
            return
        except ConnectionResetError:
            d = b""
        if not d:
            self.closed = True
            return
        self.bytes += len(d)
        msgs, self.buf = split_frames(self.buf + d)
        for m in msgs:
            kind = m["type"]
            if kind == "join_ok":
                self.avatar, self.pos = m["id"], m["pos"]
            elif kind == "snapshot" and self.avatar in m["avatars"]:
                self.pos = m["avatars"][self.avatar]
            elif kind == "object":
                self.known[m["id"]] = m["name"]
                self.infos += 1
                self.last_info = time.time()
            elif kind == "object_removed":
                self.known.pop(m["id"], None)
            elif kind == "error":
                self.errors.append(m)

    def walk_to(self, target):
        self.seq += 1
        try:
            self.s.sendall(move(self.seq, target))
        except (BlockingIOError, BrokenPipeError, ConnectionResetError):
            pass  # a full socket drops a move; the next one says the same

    def view(self, rects, radius):
        """The tiles it should know but does not, and those it knows that
        lie too far away."""
        names = set(self.known.values())
        missing = sorted(n for n, r in rects.items() if distance(self.pos, r) <= radius and n not in names)
        extra = sorted(n for n in names if distance(self.pos, rects[n]) > radius + 3 * VIEW_STEP + 0.01)
        return missing, extra

    def close(self):
        self.s.close()


def pump(walkers, seconds):
    """Reads whatever the server sends every walker for this long."""
    end = time.time() + seconds
    while True:
        left = end - time.time()
        if left <= 0:
            return
        live = [w for w in walkers if not w.closed]
        if not live:
            return
        ready, _, _ = select.select(live, [], [], min(left, 0.05))
        for w in ready:
            w.take()


def pump_until(walkers, done, timeout):
    """Pumps until done() holds or timeout seconds pass; returns done()."""
    end = time.time() + timeout
    while not done() and time.time() < end:
        pump(walkers, 0.05)
    return done()
