#!/usr/bin/python3
"""scenario.py: the proof that collision maps fix themselves.

Builds a world from real models (../shared/models), drives simulated users
through the real protocol (one TCP connection each, like any client), and
measures, round after round of clustering and refinement:

  - phantom collisions per 1,000 moves: the server blocked an avatar where
    its box touches no triangle of the object (within one refinement cell:
    the map's resolution), its box taken where the move met the box;
  - leaks: an avatar's box, as the server placed it, overlapping a triangle
    (must be 0 in every round);
  - boxes per object and tightness (cvre-admin map --json), against the two
    baselines: the single MBR (round 0, before any refinement) and the
    full-voxel map (every occupied cell its own box);
  - time spent clustering and refining (cvre-cluster --apply --json).

Users follow the true geometry: each walks to and fro along opening paths
found in the object's real triangles (under arches, through doors, between
columns: lines an avatar's box can follow without touching a triangle that
enter the object's MBR), sometimes heads for a random point of the object
instead (accidental contacts), and three users push into the same real wall
on purpose (their cluster must never open it).

Writes into --out: report.md (the table), report.json, and one SVG per
scene and round (cvre-admin map; each scene is a world of its own, its
one object the whole picture). Deterministic
for a given seed: users move in lockstep with the server (one move per
acknowledgement, a fixed step each), so their paths, their choices and the
collisions do not depend on timing. With several seeds (--seeds 1-5), each
runs in a process of its own into --out/seed-N, and summary.md and
summary.json give, per scene, the mean and the worst reduction over the
seeds, the worst rise between rounds, leaks and boxes.

Usage: scenario.py --bin BUILD_DIR --out DIR [--scenes all|room,...]
                   [--rounds 3] [--moves 400] [--users 6] [--seeds 1-5]
                   [--jobs 3]

Exit status: 0 when every target is met at every seed, 1 when one is not.
"""
import argparse
import json
import math
import os
import random
import select
import socket
import sqlite3
import subprocess
import sys
import time

try:
    import numpy as np
except ImportError:  # numpy comes with Debian's python3-numpy: use that python
    if sys.executable != "/usr/bin/python3" and os.path.exists("/usr/bin/python3"):
        os.execv("/usr/bin/python3", ["/usr/bin/python3"] + sys.argv)
    raise

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "integration"))
from harness import MODELS, hello, join, move, split_frames, upload_frames  # noqa: E402

AVATAR = (0.6, 1.8, 0.6)
BAND = (0.01, 1.9)    # heights an avatar's box spans when it stands on the floor
CELL2D = 0.05         # resolution of the top-down map of free space, m
DEPTH = 7             # the refinement grid (server default): 2^7 cells per axis
TICK = 0.05           # the server's tick: 20 Hz
SPEED = 4.0           # m/s users walk at (the server allows 6)
STUCK_MOVES = 30      # moves without progress before a user gives up a target
LEG_MOVES = 600       # most moves towards one target

# Each scene is its own world (one server each, all running at once): the
# object stands on y = 0 a few metres north of the spawn point (the origin),
# except Sponza, whose courtyard the users start in. name, file, Z-up, scale,
# height of the floor users walk on, in file units (the model's lowest point,
# from ../shared/models/SOURCES.md, or Sponza's arcade floor). Files under
# data/ are the project's own (tests/data/models/make_models.py).
SCENES = [
    ("archway", "openings/kenney_archway_cliff_cave_stone.glb", False, 4.0, -0.05),
    ("room", "openings/openfoam_room_with_doorway.stl", True, 1.0, 0.0),
    ("desk", "openings/homedecor_desk.obj", False, 3.0, -0.5),
    ("doghouse", "openings/homedecor_doghouse.obj", False, 11.0, -0.5),  # its door fits a person at 11x
    ("garage", "openings/kenney_building-garage.glb", False, 6.0, 0.0),
    ("staircase", "openings/homedecor_spiral_staircase.obj", False, 1.5, -0.594),
    ("sponza", "scenes/dabrovic_sponza.obj", False, 1.0, 0.093),
    ("gazebo", "data/gazebo.obj", False, 1.0, 0.0),
    ("colonnade", "data/colonnade.obj", False, 1.0, 0.0),
    ("tunnel", "data/tunnel.obj", False, 1.0, 0.0),
    ("pavilion", "data/pavilion.obj", False, 1.0, 0.0),
]
# Models of ../shared/models that neither the proof nor the refinement was
# built on, run only when named (--scenes extra, or by name): a curved body
# with no opening (the teapot, 3.2 m wide), a cow, a desk to walk under, a
# spider whose legs leave gaps, a figure.
EXTRA = [
    ("teapot", "classic/teapot.obj", False, 0.5, 0.0),
    ("spot", "classic/spot.obj", False, 1.5, -0.736784),
    ("bigdesk", "openings/openfoam_desk.stl", True, 2.5, 0.0),
    ("spider", "formats/assimp_Spider_binary.stl", True, 1.0, -1.64933),
    ("wuson", "formats/assimp_Wuson_ascii.ply", False, 1.0, -0.000566),
]
SEVEN = ("archway", "room", "desk", "doghouse", "garage", "staircase", "sponza")  # the proof's own
DATA = os.path.join(HERE, "..", "data", "models")
INSIDE = {"sponza"}   # users start inside the object's MBR
NORTH = 4.0           # other objects: their MBR starts this far north of the spawn point
# Targets, on every scene at every seed (issue 14).
REDUCTION = 0.97      # fewer phantom collisions in the last round than in round 0
RISE = 5.0            # most a round may be worse than the one before, per 1,000 moves
MAX_BOXES = 64
REFINE_MS = 300.0     # refinement of one round of the seven scenes, in all


# ---- geometry ---------------------------------------------------------------

def tri_box(tris, c, h):
    """Which triangles (M,3,3) touch the closed box centre c, half sizes h:
    the separating axis test (box axes, normal, 9 edge x axis products)."""
    v = tris - c
    ok = np.all((v.min(axis=1) <= h) & (v.max(axis=1) >= -h), axis=1)
    e = (v[:, 1] - v[:, 0], v[:, 2] - v[:, 1], v[:, 0] - v[:, 2])
    n = np.cross(e[0], e[1])
    ok &= np.abs(np.einsum("ij,ij->i", n, v[:, 0])) <= np.abs(n) @ h
    for ed in e:
        for a in range(3):
            axis = np.cross(ed, np.eye(3)[a])
            p = np.einsum("mkj,mj->mk", v, axis)
            r = np.abs(axis) @ h
            ok &= ~((p.min(axis=1) > r) | (p.max(axis=1) < -r))
    return ok


class Geometry:
    """An object's triangles in world coordinates, with their boxes, and
    queries against an avatar's box."""

    def __init__(self, tris):
        self.tris = tris
        self.lo = tris.min(axis=1)
        self.hi = tris.max(axis=1)
        self.min = self.lo.min(axis=0)
        self.max = self.hi.max(axis=0)
        self._free = None
        self._tree = None

    def touches(self, lo, hi):
        lo, hi = np.asarray(lo), np.asarray(hi)
        near = np.all((self.hi >= lo) & (self.lo <= hi), axis=1)
        if not near.any():
            return False
        return bool(tri_box(self.tris[near], (lo + hi) / 2, (hi - lo) / 2).any())

    def free_map(self):
        """Top-down map of where an avatar stands without touching a
        triangle: a cell is blocked if a triangle's part within the height
        band overlaps it (its bounding box, conservatively), then the map is
        eroded by the avatar's half width. Computed once."""
        if self._free is not None:
            return self._free
        x0, z0 = self.min[0] - 3, self.min[2] - 3
        nx = int(math.ceil((self.max[0] + 3 - x0) / CELL2D))
        nz = int(math.ceil((self.max[2] + 3 - z0) / CELL2D))
        blocked = np.zeros((nx, nz), bool)
        for t in self.tris[(self.hi[:, 1] >= BAND[0]) & (self.lo[:, 1] <= BAND[1])]:
            poly = clip_y(t, *BAND)
            if not poly:
                continue
            p = np.array(poly)
            i0, i1 = np.floor((p[:, 0].min() - x0) / CELL2D), np.floor((p[:, 0].max() - x0) / CELL2D)
            k0, k1 = np.floor((p[:, 2].min() - z0) / CELL2D), np.floor((p[:, 2].max() - z0) / CELL2D)
            blocked[int(i0):int(i1) + 1, int(k0):int(k1) + 1] = True
        r = int(math.ceil(AVATAR[0] / 2 / CELL2D))
        s = np.pad(np.cumsum(np.cumsum(blocked, 0), 1), ((1, 0), (1, 0)))
        fits = np.zeros_like(blocked)
        for i in range(nx):
            a, b = max(0, i - r), min(nx, i + r + 1)
            row = s[b, :] - s[a, :]
            kz = np.arange(nz)
            lo, hi = np.maximum(0, kz - r), np.minimum(nz, kz + r + 1)
            fits[i] = (row[hi] - row[lo]) == 0
        self._free = fits, x0, z0
        return self._free


    def free_tree(self):
        """The cells of the free map an avatar reaches from the origin, each
        with the next cell on a shortest way back to it (8 neighbours; a
        diagonal step only past two free cells): (parent dict, cells in the
        order found). Computed once."""
        if self._tree is not None:
            return self._tree
        fits, x0, z0 = self.free_map()
        start = (int((0 - x0) / CELL2D), int((0 - z0) / CELL2D))
        parent, order = {}, []
        if fits[start]:
            parent[start] = None
            order.append(start)
            nx, nz = fits.shape
            for c in order:  # grows while it is read: a breadth-first search
                i, k = c
                for di, dk in ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)):
                    n = (i + di, k + dk)
                    if n in parent or not (0 <= n[0] < nx and 0 <= n[1] < nz) or not fits[n]:
                        continue
                    if di and dk and not (fits[i + di, k] and fits[i, k + dk]):
                        continue
                    parent[n] = c
                    order.append(n)
        self._tree = parent, order
        return self._tree

    def side_trip(self, rng, pos):
        """Legs from pos back to the origin, out to a random place an avatar
        reaches from there, and back, along free cells only (so that users
        inside an object's MBR meet only its boxes, never its triangles), or
        [] if pos is not on a free cell reached from the origin."""
        parent, order = self.free_tree()
        fits, x0, z0 = self.free_map()
        here = (int((pos[0] - x0) / CELL2D), int((pos[2] - z0) / CELL2D))
        if here not in parent:
            return []

        def home(c):  # the cells from c to the origin
            way = [c]
            while parent[way[-1]] is not None:
                way.append(parent[way[-1]])
            return way
        out = home(order[rng.randrange(len(order))])
        cells = home(here) + out[::-1][1:] + out[1:]
        legs = []
        for j in range(1, len(cells)):  # a leg ends where the way turns
            last = j == len(cells) - 1
            if last or (cells[j][0] - cells[j - 1][0], cells[j][1] - cells[j - 1][1]) != (
                    cells[j + 1][0] - cells[j][0], cells[j + 1][1] - cells[j][1]):
                legs.append((x0 + (cells[j][0] + 0.5) * CELL2D, 0.0, z0 + (cells[j][1] + 0.5) * CELL2D))
        return legs

def clip_y(t, lo, hi):
    """The part of triangle t between the planes y = lo and y = hi."""
    poly = [tuple(p) for p in t]
    for keep, level in ((lambda p: p[1] >= lo, lo), (lambda p: p[1] <= hi, hi)):
        out = []
        for i, p in enumerate(poly):
            q = poly[(i + 1) % len(poly)]
            if keep(p):
                out.append(p)
            if keep(p) != keep(q):
                s = (level - p[1]) / (q[1] - p[1])
                out.append((p[0] + s * (q[0] - p[0]), level, p[2] + s * (q[2] - p[2])))
        poly = out
        if not poly:
            return []
    return poly


def opening_paths(g):
    """Lines along x or z from outside the MBR that an avatar follows without
    touching a triangle for at least 1 m into the MBR: (start, goal) pairs,
    one per run of such lines (its middle), widest runs first."""
    fits, x0, z0 = g.free_map()
    paths = []
    for axis in (0, 2):
        lo, hi = g.min[axis], g.max[axis]
        o0 = x0 if axis == 0 else z0
        other = 2 - axis
        p0 = x0 if other == 0 else z0
        grid = fits if axis == 0 else fits.T  # [along, across]
        for side in (-1, 1):
            start = lo - 1.5 if side < 0 else hi + 1.5
            entry = lo if side < 0 else hi
            good = []
            for j in range(grid.shape[1]):
                across = p0 + (j + 0.5) * CELL2D
                if not g.min[other] + 0.3 < across < g.max[other] - 0.3:
                    good.append(None)
                    continue
                step = -side  # walking in, away from the start's side
                i = int((start - o0) / CELL2D)
                far = i
                while 0 <= far < grid.shape[0] and grid[far, j]:
                    far += step
                reach = o0 + (far - step + 0.5) * CELL2D  # the last cell the avatar fits in
                depth = (reach - entry) * step
                if not grid[i, j] or depth < 1.0:
                    good.append(None)
                    continue
                through = hi + 1.5 if step > 0 else lo - 1.5
                goal = through if (reach - through) * step >= 0 else reach - step * 0.2
                good.append((across, goal))
            j = 0
            while j < len(good):
                if good[j] is None:
                    j += 1
                    continue
                k = j
                while k < len(good) and good[k] is not None:
                    k += 1
                if k - j >= 3:  # room for the avatar to stray a little either way
                    across, goal = good[(j + k) // 2]
                    s = [0.0, 0.0, 0.0]
                    s[axis], s[other] = start, across
                    e = [0.0, 0.0, 0.0]
                    e[axis], e[other] = goal, across
                    paths.append((k - j, axis, side, tuple(s), tuple(e)))
                j = k
    paths.sort(key=lambda p: (-p[0], p[1], p[2], p[3]))
    return [dict(axis=p[1], side=p[2], start=p[3], goal=p[4]) for p in paths]


def interior_paths(g):
    """For users who start inside the MBR (at the origin): free lines along x
    through points of the free line along z through the origin, and the
    other way round; each from its hub on that line to the end of its free
    run (at least 3 m away)."""
    fits, x0, z0 = g.free_map()
    i0, k0 = int((0 - x0) / CELL2D), int((0 - z0) / CELL2D)
    if not fits[i0, k0]:
        return []

    def run(line, at):
        lo = hi = at
        while lo - 1 >= 0 and line[lo - 1]:
            lo -= 1
        while hi + 1 < len(line) and line[hi + 1]:
            hi += 1
        return lo, hi

    paths = []
    for axis, line, at, o_along, o_hub in ((0, fits[i0, :], k0, x0, z0), (2, fits[:, k0], i0, z0, x0)):
        # hubs on the line through the origin (along the other axis), every 2 m
        lo, hi = run(line, at)
        for h in range(lo, hi + 1, int(2 / CELL2D)):
            row = fits[:, h] if axis == 0 else fits[h, :]
            centre = i0 if axis == 0 else k0
            if not row[centre]:
                continue
            a, b = run(row, centre)
            hub = o_hub + (h + 0.5) * CELL2D
            for end in (a, b):
                far = o_along + (end + 0.5) * CELL2D
                far -= math.copysign(0.2, far)
                if abs(far) >= 3:
                    s3, e3 = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
                    s3[2 - axis], e3[2 - axis] = hub, hub
                    e3[axis] = far
                    paths.append(dict(axis=axis, side=0, start=tuple(s3), goal=tuple(e3)))
    return paths


def wall_target(g):
    """A spot of real wall facing -z or -x, for the deliberate bumpers: the
    first line from outside that hits a triangle within 0.3 m of the MBR's
    face, near the middle."""
    fits, x0, z0 = g.free_map()
    for axis in (2, 0):
        other = 2 - axis
        o0, p0 = (z0, x0) if axis == 2 else (x0, z0)
        grid = fits.T if axis == 2 else fits
        mid = (g.min[other] + g.max[other]) / 2
        for d in sorted(range(grid.shape[1]), key=lambda j: abs(p0 + (j + 0.5) * CELL2D - mid)):
            across = p0 + (d + 0.5) * CELL2D
            i = int((g.min[axis] - 1.5 - o0) / CELL2D)
            while i < grid.shape[0] and grid[i, d]:
                i += 1
            stop = o0 + i * CELL2D
            if abs(stop - g.min[axis]) < 0.3:
                s = [0.0, 0.0, 0.0]
                s[axis], s[other] = g.min[axis] - 1.5, across
                e = [0.0, 0.0, 0.0]
                e[axis], e[other] = g.min[axis] + 1.0, across
                return dict(axis=axis, side=-1, start=tuple(s), goal=tuple(e))
    return None


# ---- the world and the tools -----------------------------------------------

class Server:
    def __init__(self, bindir, out, world, name):
        self.db = os.path.join(out, f"{name}.db")
        for suffix in ("", "-wal", "-shm"):
            if os.path.exists(self.db + suffix):
                os.remove(self.db + suffix)
        self.log = open(os.path.join(out, f"{name}.log"), "w")
        self.proc = subprocess.Popen(
            [os.path.join(bindir, "cvre-server"), "--port", "0", "--db", self.db, "--world", world,
             "--refine-interval", "0", "--max-speed", "6", "--spawn-radius", "0",
             "--max-clients", "1000", "--idle-timeout", "600000"],
            stdout=subprocess.PIPE, stderr=self.log, text=True)
        line = self.proc.stdout.readline()
        if not line.startswith("listening on"):
            raise SystemExit(f"cvre-server did not start; see {self.log.name}")
        self.port = int(line.rsplit(":", 1)[1])

    def stop(self):
        if self.proc.poll() is None:
            self.proc.terminate()
        return self.proc.wait(30)


def tool(bindir, name, *argv):
    t0 = time.time()
    p = subprocess.run([os.path.join(bindir, name), *argv], capture_output=True, text=True, timeout=600)
    if p.returncode != 0:
        raise SystemExit(f"{name} {' '.join(argv)}: exit {p.returncode}: {p.stderr.strip()}")
    return p.stdout, time.time() - t0


def load_objects(db):
    """name -> (id, Geometry in world coordinates)."""
    out = {}
    con = sqlite3.connect(db)
    for oid, name, px, py, pz, yaw, scale, blob in con.execute(
            "SELECT o.id, o.name, o.pos_x, o.pos_y, o.pos_z, o.yaw, o.scale, m.triangles "
            "FROM objects o JOIN meshes m ON m.object_id = o.id WHERE o.removed_at IS NULL"):
        t = np.frombuffer(blob, dtype="<f4").astype(np.float64).reshape(-1, 3, 3) * scale
        c, s = math.cos(yaw), math.sin(yaw)
        w = np.empty_like(t)
        w[..., 0] = c * t[..., 0] + s * t[..., 2] + px
        w[..., 1] = t[..., 1] + py
        w[..., 2] = -s * t[..., 0] + c * t[..., 2] + pz
        out[name] = (oid, Geometry(w))
    con.close()
    return out


# ---- users -------------------------------------------------------------------

class User:
    """One connection and what its avatar is doing: a list of legs (targets)
    walked one after another, refilled by its plan. Lockstep: a user sends
    its next move only once the server has acknowledged the last one, and
    each move asks for one tick's walk at SPEED, so the positions, and every
    choice made from them, do not depend on timing."""

    def __init__(self, port, name, scene, plan):
        self.s = socket.create_connection(("127.0.0.1", port), timeout=10)
        self.s.sendall(hello() + join(name, AVATAR))
        self.buf, self.name, self.scene, self.plan = b"", name, scene, plan
        self.id, self.pos, self.seq, self.acked = None, None, 0, True
        self.bumper, self.arrived = False, False
        self.legs, self.still, self.leg_moves, self.sent_from = [], 0, 0, None
        self.pending = []   # collisions waiting for the position they left the avatar at
        while self.id is None:
            r, _, _ = select.select([self.s], [], [], 5)
            if not r:
                raise SystemExit(f"{name}: no answer to join")
            for m in self.read():
                if m["type"] == "join_ok":
                    self.id, self.pos = m["id"], m["pos"]

    def read(self):
        """The messages that arrived (call when the socket is readable)."""
        d = self.s.recv(1 << 20)
        if not d:
            raise SystemExit(f"{self.name}: the server closed the connection")
        out, self.buf = split_frames(self.buf + d)
        return out

    def snapshot(self, m):
        """Takes a snapshot: the avatar's position (no entry: it did not
        move) and whether the last move was acknowledged."""
        self.pos = m["avatars"].get(self.id, self.pos)
        if m["ack"] >= self.seq and not self.acked:
            self.acked = True
            moved = math.hypot(self.pos[0] - self.sent_from[0], self.pos[2] - self.sent_from[2])
            self.still = self.still + 1 if moved < 0.01 else 0

    def step(self):
        """Sends the next move of the current leg; a leg ends at its target,
        after STUCK_MOVES moves without progress, or after LEG_MOVES."""
        while True:
            if not self.legs:
                self.legs = self.plan(self)
                self.still = self.leg_moves = 0
            target = self.legs[0]
            d = math.hypot(target[0] - self.pos[0], target[2] - self.pos[2])
            if d > 0.02 and self.still < STUCK_MOVES and self.leg_moves < LEG_MOVES:
                break
            self.legs.pop(0)
            self.still = self.leg_moves = 0
        k = min(1.0, SPEED * TICK / d)
        aim = (self.pos[0] + k * (target[0] - self.pos[0]), 0.0, self.pos[2] + k * (target[2] - self.pos[2]))
        self.seq += 1
        self.s.sendall(move(self.seq, aim))
        self.acked, self.sent_from = False, self.pos
        self.leg_moves += 1


def drive(users, moves, handle, wanted=None):
    """Lets each user make `moves` moves (or, with wanted, move until
    wanted(user) holds), one per acknowledgement; handle(user, message)
    sees every message. Bounded in time: a server that stops answering
    ends the run."""
    by_sock = {u.s: u for u in users}
    left = {u.name: moves for u in users}
    deadline = time.time() + max(60.0, moves * TICK * 10)
    while True:
        busy = False
        for u in users:
            if wanted is not None and wanted(u):
                continue
            if u.acked and left[u.name] > 0:
                u.step()
                left[u.name] -= 1
            busy |= left[u.name] > 0 or not u.acked
        if not busy:
            return
        if time.time() > deadline:
            raise SystemExit("the servers stopped acknowledging moves")
        r, _, _ = select.select(list(by_sock), [], [], 0.1)
        for sock in r:
            u = by_sock[sock]
            for m in u.read():
                handle(u, m)


def approach(g, start):
    """Legs from the spawn point (the origin, south of the object) to start
    without crossing the object: along z = 0, then north, around the east
    side if start is on the far side."""
    if g.min[2] <= 0:  # the user starts inside (Sponza): paths begin on free lines through the origin
        return [(start[0], 0.0, 0.0), start] if start[2] != 0 else [start]
    if start[2] < g.min[2] or start[0] > g.max[0] or start[0] < g.min[0]:
        return [(start[0], 0.0, 0.0), start]
    side = g.max[0] + 2.5
    return [(side, 0.0, 0.0), (side, 0.0, start[2]), start]


def one_side(paths):
    """The paths of the side (axis and direction) with the most room, so
    that going from one path's start to the next stays outside the object."""
    best = {}
    for p in paths:
        best.setdefault((p["axis"], p["side"]), []).append(p)
    return max(best.values(), key=len)


# ---- one run -----------------------------------------------------------------

def model_path(rel):
    """Where a scene's file is: ../shared/models, or data/ = tests/data/models."""
    return os.path.join(DATA, rel[5:]) if rel.startswith("data/") else os.path.join(MODELS, rel)


def model_mbr(rel, z_up):
    """The model's bounding box in object-local axes (Y up), from the table
    in ../shared/models/SOURCES.md (file axes; Z-up files turn (x,y,z) into
    (x,z,-y)), or, for the project's own OBJ files, from their vertices."""
    if rel.startswith("data/"):
        v = np.array([[float(t) for t in line.split()[1:4]] for line in open(model_path(rel))
                      if line.startswith("v ")])
        return list(v.min(axis=0)), list(v.max(axis=0))
    for line in open(os.path.join(MODELS, "SOURCES.md")):
        if line.startswith(f"| `{rel}`"):
            cells = [c.strip() for c in line.split("|")]
            lo = [float(v) for v in cells[4].strip("()").split(",")]
            hi = [float(v) for v in cells[5].strip("()").split(",")]
            if z_up:
                lo, hi = [lo[0], lo[2], -hi[1]], [hi[0], hi[2], -lo[1]]
            return lo, hi
    raise SystemExit(f"{rel}: not in SOURCES.md")


class Scene:
    """One world: its server, its object, the paths its users walk. The
    object of a scene users start inside is placed once they are there
    (place()): the server spawns nobody inside a box, so a world that held
    it from the start would put them outside its MBR."""

    def __init__(self, a, spec, index):
        self.name, self.rel, self.z_up, self.scale, floor = spec
        lo, hi = model_mbr(self.rel, self.z_up)
        x = -self.scale * (lo[0] + hi[0]) / 2
        z = -self.scale * (lo[2] + hi[2]) / 2 if self.name in INSIDE else NORTH - self.scale * lo[2]
        self.at = (x, -self.scale * floor, z)
        world = os.path.join(a.out, f"{self.name}.world")
        with open(world, "w") as f:
            if self.name not in INSIDE:
                f.write(f"object {model_path(self.rel)} name {self.name}{' up z' if self.z_up else ''} "
                        f"at {x:.4f} {self.at[1]:.4f} {z:.4f} scale {self.scale}\n")
        self.srv = Server(a.bin, a.out, world, self.name)
        try:
            if self.name not in INSIDE:
                self.setup()
        except BaseException:
            self.srv.stop()
            raise

    def place(self, a):
        """Uploads the object around the users already in the world, as an
        account (guests may not upload), and waits until it stands."""
        name, password = "builder", "scenario-builder"
        p = subprocess.run([os.path.join(a.bin, "cvre-admin"), "--db", self.srv.db, "user", "add", name,
                            "--password-stdin"], input=password + "\n", capture_output=True, text=True, timeout=60)
        if p.returncode != 0:
            raise SystemExit(f"{self.name}: cvre-admin user add: {p.stderr.strip()}")
        s = socket.create_connection(("127.0.0.1", self.srv.port), timeout=60)
        with open(model_path(self.rel), "rb") as f:
            data = f.read()
        s.sendall(hello() + join(name, AVATAR, password=password))
        s.sendall(upload_frames(1, data, os.path.basename(self.rel), up=1 if self.z_up else 0, pos=self.at,
                                scale=self.scale))
        buf, deadline = b"", time.time() + 120
        while time.time() < deadline:
            d = s.recv(1 << 20)
            if not d:
                break
            msgs, buf = split_frames(buf + d)
            for m in msgs:
                if m["type"] == "object" and m.get("upload") == 1:
                    s.close()
                    self.setup(m["id"])
                    return
                if m["type"] in ("rejected", "error"):
                    raise SystemExit(f"{self.name}: placing the object: {m}")
        raise SystemExit(f"{self.name}: the object was not placed within 120 s")

    def setup(self, oid=None):
        objs = load_objects(self.srv.db)
        self.id, self.g = objs[self.name] if oid is None else next(v for v in objs.values() if v[0] == oid)
        ext = self.g.max - self.g.min
        self.cells = ext / (1 << DEPTH)  # the refinement grid over the MBR, per axis
        self.cell = float(max(self.cells))
        if self.name in INSIDE:
            paths = interior_paths(self.g)
        else:
            paths = opening_paths(self.g)
            # An object with no opening (the garage's door is shut): users
            # walk up to it from the south at a few places, expecting to
            # touch it where it really is.
            paths = one_side(paths) if paths else [
                dict(axis=2, side=-1, start=(x, 0.0, self.g.min[2] - 1.5), goal=(x, 0.0, self.g.max[2] + 1.5))
                for x in np.linspace(self.g.min[0] + 0.4, self.g.max[0] - 0.4, 5)]
        if not paths:
            raise SystemExit(f"{self.name}: no path found for its users")
        # A few paths, so that each is walked by several users in a round
        # (a cluster needs 3 distinct users).
        self.paths = paths[:4]
        self.wall = None


def plan_for(scene, a, index, bumper):
    """What a user of scene does next: walk an opening path there and back,
    sometimes head for a random point of the object instead (an accidental
    contact), or, for a bumper, push into the real wall. Users inside the
    MBR, whom the inside policy would let through real geometry, take side
    trips along free space instead: out to a random place and back."""
    state = dict(k=index)
    rng = random.Random(f"{a.seed}/{scene.name}/{index}/{bumper}")  # its own: the order users ask in may vary

    def plan(user):
        g = scene.g  # read when the user first moves: a scene's object may be placed after its users joined
        if user.arrived and scene.name in INSIDE and rng.random() < a.accidents:
            trip = g.side_trip(rng, user.pos)
            if trip:
                return trip
        if bumper:
            first, legs = scene.wall["start"], [scene.wall["goal"], scene.wall["start"]]
        else:
            state["k"] += 1
            path = scene.paths[state["k"] % len(scene.paths)]
            first = path["start"]
            if scene.name not in INSIDE and rng.random() < a.accidents:
                target = (rng.uniform(g.min[0], g.max[0]), 0.0, rng.uniform(g.min[2], g.max[2]))
                legs = [target, first]
            else:
                legs = [path["goal"], first]
        if not user.arrived:
            user.arrived = True
            return approach(g, first) + legs
        return [first] + legs
    return plan


def seed_list(text):
    """"4", "1-5" or "1,3,7-9" -> the seeds, in order."""
    seeds = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        if not lo.strip().isdigit() or (hi and not hi.strip().isdigit()):
            raise argparse.ArgumentTypeError(f"{text!r}: seeds are numbers or ranges, as in 1-5 or 1,3,7")
        seeds += range(int(lo), int(hi or lo) + 1)
    if not seeds:
        raise argparse.ArgumentTypeError(f"{text!r}: no seed")
    return seeds


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bin", required=True, help="build directory with cvre-server, cvre-cluster, cvre-admin")
    ap.add_argument("--out", required=True, help="directory for the reports and the SVGs")
    ap.add_argument("--scenes", default="all", help="comma-separated scene names, all, or extra")
    ap.add_argument("--rounds", type=int, default=3, help="refinement rounds after the baseline round")
    ap.add_argument("--moves", type=int, default=400, help="moves per user and round (20 a second)")
    ap.add_argument("--users", type=int, default=6, help="users per scene (at least 3: min users)")
    ap.add_argument("--accidents", type=float, default=0.15,
                    help="share of legs towards a random point (a side trip for users inside)")
    ap.add_argument("--seeds", type=seed_list, default=[1], help="seeds to run, as in 4, 1-5 or 1,3,7 (default 1)")
    ap.add_argument("--seed", type=int, help="one seed (the same as --seeds N)")
    ap.add_argument("--jobs", type=int, default=3, help="seeds run at once (default 3)")
    a = ap.parse_args()
    if a.seed is not None:
        a.seeds = [a.seed]
    groups = {"all": SCENES, "extra": EXTRA}
    names = [s[0] for s in groups[a.scenes]] if a.scenes in groups else a.scenes.split(",")
    specs = [s for s in SCENES + EXTRA if s[0] in names]
    if len(specs) != len(names) or a.users < 3 or a.rounds < 1 or a.jobs < 1:
        ap.error(f"scenes are {', '.join(s[0] for s in SCENES + EXTRA)} (all: the first {len(SCENES)}, "
                 "extra: the rest); --users >= 3; --rounds >= 1; --jobs >= 1")
    os.makedirs(a.out, exist_ok=True)
    if len(a.seeds) == 1:
        a.seed = a.seeds[0]
        run_seed(a, specs)
        return summary(a, {a.seed: a.out})
    # Each seed in a process of its own, --jobs at a time, into out/seed-N.
    dirs, running, todo = {}, [], list(a.seeds)
    argv = [sys.executable, os.path.abspath(__file__), "--bin", a.bin, "--scenes", ",".join(names),
            "--rounds", str(a.rounds), "--moves", str(a.moves), "--users", str(a.users),
            "--accidents", str(a.accidents)]
    try:
        while todo or running:
            while todo and len(running) < a.jobs:
                seed = todo.pop(0)
                dirs[seed] = os.path.join(a.out, f"seed-{seed}")
                log = open(os.path.join(a.out, f"seed-{seed}.log"), "w")
                running.append((seed, log, subprocess.Popen(argv + ["--seed", str(seed), "--out", dirs[seed]],
                                                             stdout=log, stderr=subprocess.STDOUT)))
                print(f"seed {seed}: running, log in {log.name}", flush=True)
            time.sleep(1)
            for job in [j for j in running if j[2].poll() is not None]:
                running.remove(job)
                job[1].close()
                print(f"seed {job[0]}: done (exit {job[2].returncode})", flush=True)
    finally:  # interrupted: no seed is left running
        for _, log, proc in running:
            proc.terminate()
            proc.wait(60)
    return summary(a, dirs)


def run_seed(a, specs):
    """One seed: its worlds, its rounds, its report in a.out."""
    scenes = []
    try:
        for i, spec in enumerate(specs):
            scenes.append(Scene(a, spec, i))
        run_scenes(a, scenes)
    finally:  # whatever went wrong, no server is left running
        for sc in scenes:
            sc.srv.stop()


def run_scenes(a, scenes):
    """The rounds: users walk, then each scene's map is clustered, refined
    and pictured; then the report."""
    users = []
    for sc in scenes:
        for i in range(a.users):
            users.append(User(sc.srv.port, f"{sc.name}-{i}", sc, plan_for(sc, a, i, False)))
        if sc.name in INSIDE:
            sc.place(a)
        print(f"{sc.name}: object {sc.id}, {len(sc.g.tris)} triangles, {len(sc.paths)} paths, "
              f"refinement cell {sc.cell:.3f} m", flush=True)
    bump = next((sc for sc in scenes if sc.name == "room"), None) or next(
        (sc for sc in scenes if sc.name not in INSIDE), None)
    if bump:
        bump.wall = wall_target(bump.g)
    if bump and bump.wall:
        for i in range(3):
            u = User(bump.srv.port, f"bumper-{i}", bump, plan_for(bump, a, 0, True))
            u.bumper = True
            users.append(u)

    # Everyone walks to their scene first; that is not measured.
    def arrive(u, m):
        if m["type"] == "snapshot":
            u.snapshot(m)
    drive(users, 100000, arrive, wanted=lambda u: u.acked and near(u, u.scene.g))

    rounds = []
    for r in range(a.rounds + 1):
        stats = {sc.name: dict(moves=0, collisions=0, phantom=0, leaks=0) for sc in scenes}
        bumped = dict(collisions=0, leaks=0)

        def handle(u, m):
            # A collision comes before the snapshot of its tick, which a
            # moving user always gets (it acknowledges the move).
            if m["type"] == "snapshot":
                waiting = not u.acked
                u.snapshot(m)
                if waiting and u.acked and not u.bumper and near(u, u.scene.g):
                    stats[u.scene.name]["moves"] += 1  # at its scene, not on the way
                check(u, stats, bumped)
            elif m["type"] == "collision":
                u.pending.append(m)
        drive(users, a.moves, handle)
        time.sleep(0.6)  # the collision log's writer commits every 250 ms
        row = dict(round=r, scenes={}, bumpers=bumped, cluster_s=0.0, refine_ms=0.0)
        for sc in scenes:
            st = stats[sc.name]
            # The map in force during the round: its figures and its picture
            # (with the collisions against the version before it).
            fig = json.loads(tool(a.bin, "cvre-admin", "--db", sc.srv.db, "--json", "map", "--object", str(sc.id),
                                  "--svg", os.path.join(a.out, f"{sc.name}-round{r}.svg"))[0])
            fig = fig[0] if isinstance(fig, list) else fig
            st.update(boxes=fig["boxes"], tightness=fig["tightness"], full_voxel_boxes=fig["full_voxel_boxes"],
                      version=fig["version"],
                      phantom_per_1000=1000.0 * st["phantom"] / st["moves"] if st["moves"] else 0.0)
            if r < a.rounds:  # clustering and refinement, as an operator would run them
                out, wall_s = tool(a.bin, "cvre-cluster", "--db", sc.srv.db, "--apply", "--json")
                job = json.loads(out)
                # Refinement: digitizing, dividing and judging; the rest of
                # total_ms is the store (waiting for its write lock too).
                refine_ms = sum(x["voxel_ms"] + x["divide_ms"] + x.get("judge", {}).get("ms", 0.0)
                                for x in job["refined"])
                total_ms = sum(x["total_ms"] for x in job["refined"])
                st["cluster_s"], st["refine_ms"] = wall_s - total_ms / 1000, refine_ms
                st["clusters"] = len(job["clusters"])
                st["rejected"] = sum(x.get("outcome") == "rejected" for x in job["refined"])
                # What the job did with the scene's one object: written (a new
                # version), rejected (by the judge), unchanged (the refined map
                # is the old one; "unchanged, apart" when the new boxes, taken
                # apart where they reached out of the old map, passed the
                # cap), or no cluster.
                st["outcome"] = (job["refined"][0]["outcome"] if job["refined"]
                                 else "no cluster" if not job["clusters"] else "not refined")
                if st["outcome"] == "unchanged" and job["refined"][0].get("apart_over"):
                    st["outcome"] = "unchanged, apart"
                row["cluster_s"] += st["cluster_s"]
                row["refine_ms"] += refine_ms
            row["scenes"][sc.name] = st
        rounds.append(row)
        print(f"round {r}: " + ", ".join(f"{n} {s['phantom_per_1000']:.1f}/1000 ({s['boxes']} boxes, "
                                           f"{s['leaks']} leaks)" for n, s in row["scenes"].items()), flush=True)
        time.sleep(0.5)  # the servers publish the new maps within 250 ms
    for u in users:
        u.s.close()
    report(a, scenes, rounds, bump)


def near(u, g):
    """Whether u is at its scene: within 3 m of the object's MBR (for users
    inside Sponza: always)."""
    x, z = u.pos[0], u.pos[2]
    return g.min[0] - 3 <= x <= g.max[0] + 3 and g.min[2] - 3 <= z <= g.max[2] + 3


def avatar_box(p):
    """The avatar's box with its feet at p: (lo, hi)."""
    return (np.array([p[0] - AVATAR[0] / 2, p[1], p[2] - AVATAR[2] / 2]),
            np.array([p[0] + AVATAR[0] / 2, p[1] + AVATAR[1], p[2] + AVATAR[2] / 2]))


def check(u, stats, bumped):
    """Judges the collisions u got against where its box met the box
    (phantom: its box there, grown by one refinement cell, touches no
    triangle), and whether the server has put its box into a triangle (a
    leak)."""
    p, sc = u.pos, u.scene
    lo, hi = avatar_box(p)
    # Where the move started: a collision may come at any point of the move
    # (an avatar held back sideways at its first instant may walk on 20 cm
    # along the face in the same tick), so across its normal the box spans
    # the move. Along the normal the move ended at the face it met.
    was_lo, was_hi = avatar_box(u.sent_from if u.sent_from is not None else p)
    st = bumped if u.bumper else stats[sc.name]
    # Grown by one refinement cell sideways and upwards, not downwards: the
    # floor a user stands on is support, not what stopped it.
    grow_lo = np.array([sc.cells[0], -0.01, sc.cells[2]])
    grow_hi = sc.cells
    for m in u.pending:
        if m["object"] != sc.id:
            continue
        st["collisions"] += 1
        along = np.array(m["normal"]) != 0
        mlo, mhi = np.where(along, lo, np.minimum(lo, was_lo)), np.where(along, hi, np.maximum(hi, was_hi))
        if not u.bumper and not sc.g.touches(mlo - grow_lo, mhi + grow_hi):
            st["phantom"] += 1
            if os.environ.get("SCENARIO_DEBUG"):
                print(f"phantom {sc.name} v{m['ecm_version']} box {m['box']} inside {m['inside']} at "
                      f"{tuple(round(v, 2) for v in p)} point {tuple(round(v, 2) for v in m['point'])}")
    u.pending = []
    if sc.g.touches(lo + 0.01, hi - 0.01):
        st["leaks"] += 1
        if os.environ.get("SCENARIO_DEBUG"):
            print(f"leak {sc.name} user {u.name} at {tuple(round(v, 3) for v in p)}")


def report(a, scenes, rounds, bump):
    last = rounds[-1]["scenes"]
    names = [sc.name for sc in scenes]
    wall = bump.wall if bump else None
    lines = ["# Collision maps that fix themselves: scenario report", "",
             f"Seed {a.seed}, {a.users} users per scene and 3 deliberate bumpers, {a.moves} moves per user and "
             f"round, {a.rounds} refinement rounds (`cvre-cluster --apply`, defaults) after the baseline round 0 "
             "(the single-MBR map). Collisions: the COLLISION messages users got (blocked by a box, or moving "
             "inside one). Phantom: a collision where the avatar's box, grown sideways and upwards by one cell "
             "of the refinement grid over the MBR (the map's resolution), touches no triangle of the object "
             "(its box where the move ended along the contact's normal, and across it anywhere from where the "
             "move started to where it ended: the contact may come at any point of the move). "
             "Leak: the avatar's box overlaps a triangle. Refinement ms: digitizing, dividing and judging after the "
             "round (the store's share of the job is not in it). A rejected candidate: a refined map the judge "
             "found no better, not published. After the round: what clustering and refinement did with the "
             "object (written: a new version; rejected; unchanged: the refined map is the old one; "
             "unchanged, apart: so because its new boxes reached out of the old map by more than two cells, "
             "or at all where users stood, and, taken apart, passed the cap; no cluster). Tightness: "
             "volume of occupied cells / volume of the boxes (grid 2^7 over the MBR). Full-voxel baseline: "
             "every occupied cell its own box.", "",
             "| scene | round | version | moves | collisions | phantom | phantom / 1000 moves | leaks | boxes | "
             "tightness | full-voxel boxes | refinement ms | candidates rejected | after the round |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rounds:
        for n, s in r["scenes"].items():
            lines.append(f"| {n} | {r['round']} | {s['version']} | {s['moves']} | {s['collisions']} | {s['phantom']} "
                         f"| {s['phantom_per_1000']:.2f} | {s['leaks']} | {s['boxes']} | {s['tightness']:.3f} "
                         f"| {s['full_voxel_boxes']} | {s.get('refine_ms', 0.0):.1f} | {s.get('rejected', '-')} "
                         f"| {s.get('outcome', '-')} |")
    lines += ["", "| round | clustering s | refinement ms | bumper collisions | bumper leaks |",
              "|---|---|---|---|---|"]
    for r in rounds:
        lines.append(f"| {r['round']} | {r.get('cluster_s', 0):.2f} | {r.get('refine_ms', 0):.1f} | "
                     f"{r['bumpers']['collisions']} | {r['bumpers']['leaks']} |")
    first = rounds[0]["scenes"]
    lines += ["", "## The three maps side by side", "",
              "| scene | single MBR: boxes | tightness | phantom / 1000 | refined (last round): boxes | tightness "
              "| phantom / 1000 | full voxel: boxes | tightness |",
              "|---|---|---|---|---|---|---|---|---|"]
    for n in names:
        f, l = first[n], last[n]
        lines.append(f"| {n} | {f['boxes']} | {f['tightness']:.3f} | {f['phantom_per_1000']:.2f} | {l['boxes']} "
                     f"| {l['tightness']:.3f} | {l['phantom_per_1000']:.2f} | {l['full_voxel_boxes']} | 1.000 |")
    lines += ["", "## Targets", ""]
    judged = {n: judge_scene([r["scenes"][n]["phantom_per_1000"] for r in rounds],
                             [r["scenes"][n] for r in rounds]) for n in names}
    for n in names:
        j = judged[n]
        down = (f"{j['first']:.2f} -> {j['final']:.2f} per 1000 moves ({100.0 * j['reduction']:.1f}% down)"
                if j["first"] > 0 else f"none with the single MBR, {j['final']:.2f} per 1000 moves at the end")
        lines.append(f"- {n}: phantom {down}; worst rise between rounds {j['rise']:.2f}; {j['leaks']} leaks; "
                     f"at most {j['boxes']} boxes: {'met' if j['met'] else 'NOT met'}")
    bumper_leaks = sum(r["bumpers"]["leaks"] for r in rounds)
    wall_ok = not wall or (bumper_leaks == 0 and rounds[-1]["bumpers"]["collisions"] > 0)
    leaks = sum(s["leaks"] for r in rounds for s in r["scenes"].values()) + bumper_leaks
    boxes = max(s["boxes"] for r in rounds for s in r["scenes"].values())
    refine_ms = seven_refine_ms(rounds)
    lines += [f"- leaks in all rounds: {leaks} (target 0)", f"- most boxes of an object: {boxes} (target <= {MAX_BOXES})",
              f"- deliberate bumpers ({bump.name if wall else 'none'}) pushing at "
              f"{tuple(round(v, 2) + 0.0 for v in wall['goal']) if wall else '-'}: "
              f"{bumper_leaks} leaks through the real wall, stopped "
              f"{rounds[-1]['bumpers']['collisions']} times by it in the last round: {'met' if wall_ok else 'NOT met'}",
              "- refinement of the seven scenes, slowest round: " + (
                  f"{refine_ms:.1f} ms (target {REFINE_MS:.0f} ms)" if refine_ms is not None else "not all seven run"),
              "", "Targets for each scene: phantom collisions "
              f"{100 * REDUCTION:.0f}% down by the last round (none at the end where there were none at the start), "
              f"no round worse than the one before by more than {RISE:.0f} per 1000 moves, 0 leaks, at most "
              f"{MAX_BOXES} boxes.", "",
              "Pictures: `<scene>-round<N>.svg`: the map in force during round N (its boxes; the original MBR "
              "dashed; the collisions against the version before it, coloured by cluster, noise grey)."]
    with open(os.path.join(a.out, "report.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    met = all(j["met"] for j in judged.values()) and leaks == 0 and boxes <= MAX_BOXES and wall_ok and (
        refine_ms is None or refine_ms <= REFINE_MS)
    with open(os.path.join(a.out, "report.json"), "w") as f:
        json.dump(dict(seed=a.seed, rounds=rounds, scenes=judged, leaks=leaks, bumper_leaks=bumper_leaks,
                       wall_ok=wall_ok, max_boxes=boxes, refine_ms=refine_ms, targets_met=met),
                  f, indent=1, default=float)


def judge_scene(phantom, stats):
    """One scene of one seed against the targets: phantom collisions per
    1,000 moves in each round, and each round's figures."""
    first, final = phantom[0], phantom[-1]
    reduction = 1 - final / first if first > 0 else (1.0 if final == 0 else 0.0)
    rise = max([0.0] + [b - c for c, b in zip(phantom, phantom[1:])])
    leaks = sum(s["leaks"] for s in stats)
    boxes = max(s["boxes"] for s in stats)
    met = reduction >= REDUCTION and rise <= RISE and leaks == 0 and boxes <= MAX_BOXES
    return dict(first=first, final=final, reduction=reduction, rise=rise, leaks=leaks, boxes=boxes, met=met,
                phantom=phantom)


OUTCOMES = ("written", "rejected", "rejected before", "nothing to gain", "unchanged", "unchanged, apart",
            "no cluster")


def later_outcomes(reports, name):
    """How many jobs after rounds 1 and later ended each way, for one
    scene over all seeds."""
    count = {}
    for rep in reports.values():
        for r in rep["rounds"][1:]:
            o = r["scenes"].get(name, {}).get("outcome")
            if o:
                count[o] = count.get(o, 0) + 1
    return count


def seven_refine_ms(rounds):
    """The slowest round's refinement time over the seven scenes of the
    proof, in ms; None unless all seven were run."""
    if not all(n in rounds[0]["scenes"] for n in SEVEN):
        return None
    return max(sum(r["scenes"][n].get("refine_ms", 0.0) for n in SEVEN) for r in rounds)


def summary(a, dirs):
    """Every seed's report (dirs: seed -> its output directory) in one
    table per scene: mean and worst reduction, worst rise between rounds,
    leaks and boxes, in summary.md and summary.json. Returns the exit
    status: 0 when every target was met at every seed."""
    reports, missing = {}, []
    for seed, d in sorted(dirs.items()):
        try:
            with open(os.path.join(d, "report.json")) as f:
                reports[seed] = json.load(f)
        except (OSError, ValueError):
            missing.append(seed)
    names = []
    for rep in reports.values():
        names += [n for n in rep["scenes"] if n not in names]
    lines = ["# Scenario summary", "", f"Seeds {', '.join(str(x) for x in sorted(dirs))}; each seed's report in "
             + ("this directory" if len(dirs) == 1 else "seed-N/report.md") + ".", "",
             "| scene | seeds | phantom / 1000, round 0 (mean) | last round (mean) | reduction, mean | worst | "
             "worst rise | leaks | most boxes | candidates rejected | met |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    scenes = {}
    for n in names:
        js = [(seed, rep["scenes"][n]) for seed, rep in reports.items() if n in rep["scenes"]]
        worst = min(js, key=lambda x: x[1]["reduction"])
        row = dict(seeds=len(js), first_mean=sum(j["first"] for _, j in js) / len(js),
                   final_mean=sum(j["final"] for _, j in js) / len(js),
                   reduction_mean=sum(j["reduction"] for _, j in js) / len(js),
                   reduction_worst=worst[1]["reduction"], worst_seed=worst[0],
                   rise_worst=max(j["rise"] for _, j in js), leaks=sum(j["leaks"] for _, j in js),
                   boxes=max(j["boxes"] for _, j in js), met=all(j["met"] for _, j in js),
                   rejected=sum(r["scenes"][n].get("rejected", 0) for rep in reports.values() for r in rep["rounds"]
                                if n in r["scenes"]),
                   later=later_outcomes(reports, n))
        scenes[n] = row
        lines.append(f"| {n} | {row['seeds']} | {row['first_mean']:.2f} | {row['final_mean']:.2f} | "
                     f"{100 * row['reduction_mean']:.1f}% | {100 * row['reduction_worst']:.1f}% (seed "
                     f"{row['worst_seed']}) | {row['rise_worst']:.2f} | {row['leaks']} | {row['boxes']} | "
                     f"{row['rejected']} | {'yes' if row['met'] else 'NO'} |")
    cols = list(OUTCOMES) + sorted({o for n in names for o in scenes[n]["later"]} - set(OUTCOMES))
    lines += ["", "After rounds 1 and later (round 0's job makes the first refined map), what each job did, "
              "all seeds: a map that never changes again leaves every trap it has to later users.", "",
              "| scene | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]
    for n in names:
        lines.append(f"| {n} | " + " | ".join(str(scenes[n]["later"].get(o, 0)) for o in cols) + " |")
    refine = [rep["refine_ms"] for rep in reports.values() if rep.get("refine_ms") is not None]
    walls = [seed for seed, rep in reports.items() if not rep.get("wall_ok", True)]
    met = not missing and not walls and all(rep["targets_met"] for rep in reports.values())
    lines += ["", f"- seeds without a report (the run failed; see its log): {missing or 'none'}",
              f"- seeds where the bumpers' wall opened or stopped nobody: {walls or 'none'}",
              f"- leaks in all seeds: {sum(rep['leaks'] for rep in reports.values())}",
              "- refinement of the seven scenes, slowest round of any seed: "
              + (f"{max(refine):.1f} ms (target {REFINE_MS:.0f})" if refine else "not all seven run"),
              f"- targets: {'all met' if met else 'NOT met'}"]
    with open(os.path.join(a.out, "summary.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    with open(os.path.join(a.out, "summary.json"), "w") as f:
        json.dump(dict(seeds=sorted(dirs), missing=missing, scenes=scenes, targets_met=met), f, indent=1)
    print("\n".join(lines))
    if not met:
        print("scenario: targets NOT met (see summary.md and each seed's report.md)", file=sys.stderr)
    return 0 if met else 1


if __name__ == "__main__":
    sys.exit(main())
