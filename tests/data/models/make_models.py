#!/usr/bin/python3
"""make_models.py: writes the project's own test models with openings
(OBJ, Y up, metres, the lowest point on y = 0) into this folder.

Made for the scenario runner (tests/bench/scenario.py) as shapes the
refinement was not built with: curved walls, round columns, a vault, and a
low plinth that users step onto. Each is a few solids put together
(triangles may meet or cross, as in real models); the output is the same
on every run, so the files in git are what this script writes:

    python3 tests/data/models/make_models.py   # then git diff: nothing

  gazebo      a round well (a ring 0.9 m tall) under a conical roof on six
              posts; users walk in between the posts up to the ring
  colonnade   two rows of five round columns under one slab: an aisle along
              x and gaps between the columns along z
  tunnel      a barrel vault on low walls, 8 m long: users walk through
              under the curved ceiling
  pavilion    a 0.3 m plinth (a step) with a roof on four posts: users step
              onto it and walk across under the roof
"""
import math
import os

HERE = os.path.dirname(os.path.abspath(__file__))


class Mesh:
    def __init__(self):
        self.v, self.f = [], []

    def quad(self, a, b, c, d):
        """Two triangles a b c, a c d (counter-clockwise seen from outside)."""
        n = len(self.v)
        self.v += [a, b, c, d]
        self.f += [(n, n + 1, n + 2), (n, n + 2, n + 3)]

    def tri(self, a, b, c):
        n = len(self.v)
        self.v += [a, b, c]
        self.f.append((n, n + 1, n + 2))

    def box(self, lo, hi):
        (x0, y0, z0), (x1, y1, z1) = lo, hi
        self.quad((x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1))  # bottom
        self.quad((x0, y1, z0), (x0, y1, z1), (x1, y1, z1), (x1, y1, z0))  # top
        self.quad((x0, y0, z0), (x0, y1, z0), (x1, y1, z0), (x1, y0, z0))  # -z
        self.quad((x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1))  # +z
        self.quad((x0, y0, z0), (x0, y0, z1), (x0, y1, z1), (x0, y1, z0))  # -x
        self.quad((x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1))  # +x

    def ring(self, cx, cz, r0, r1, y0, y1, seg):
        """A thick tube (r0 = 0: a solid cylinder) between heights y0 and y1."""
        def p(r, k, y):
            t = 2 * math.pi * k / seg
            return (cx + r * math.cos(t), y, cz + r * math.sin(t))
        for k in range(seg):
            self.quad(p(r1, k, y0), p(r1, k, y1), p(r1, k + 1, y1), p(r1, k + 1, y0))
            if r0 > 0:
                self.quad(p(r0, k, y0), p(r0, k + 1, y0), p(r0, k + 1, y1), p(r0, k, y1))
                self.quad(p(r0, k, y1), p(r0, k + 1, y1), p(r1, k + 1, y1), p(r1, k, y1))
                self.quad(p(r0, k, y0), p(r1, k, y0), p(r1, k + 1, y0), p(r0, k + 1, y0))
            else:
                self.tri((cx, y1, cz), p(r1, k + 1, y1), p(r1, k, y1))
                self.tri((cx, y0, cz), p(r1, k, y0), p(r1, k + 1, y0))

    def cone(self, cx, cz, r, y0, y1, seg):
        """A cone standing on the disc of radius r at y0, its apex at y1."""
        for k in range(seg):
            t0, t1 = 2 * math.pi * k / seg, 2 * math.pi * (k + 1) / seg
            a = (cx + r * math.cos(t0), y0, cz + r * math.sin(t0))
            b = (cx + r * math.cos(t1), y0, cz + r * math.sin(t1))
            self.tri(a, (cx, y1, cz), b)
            self.tri(a, b, (cx, y0, cz))

    def vault(self, r0, r1, y, z0, z1, seg):
        """Half a thick tube along z over x = 0, its axis at height y."""
        def p(r, k, z):
            t = math.pi * k / seg
            return (r * math.cos(t), y + r * math.sin(t), z)
        for k in range(seg):
            self.quad(p(r0, k, z0), p(r0, k, z1), p(r0, k + 1, z1), p(r0, k + 1, z0))
            self.quad(p(r1, k, z0), p(r1, k + 1, z0), p(r1, k + 1, z1), p(r1, k, z1))
            self.quad(p(r0, k, z0), p(r0, k + 1, z0), p(r1, k + 1, z0), p(r1, k, z0))
            self.quad(p(r0, k, z1), p(r1, k, z1), p(r1, k + 1, z1), p(r0, k + 1, z1))

    def write(self, name, about):
        with open(os.path.join(HERE, f"{name}.obj"), "w") as f:
            f.write(f"# {name}: {about}\n# written by make_models.py (CC0 1.0)\n")
            for x, y, z in self.v:
                f.write(f"v {x:.4f} {y:.4f} {z:.4f}\n")
            for a, b, c in self.f:
                f.write(f"f {a + 1} {b + 1} {c + 1}\n")


def gazebo():
    m = Mesh()
    m.ring(0, 0, 0.9, 1.2, 0.0, 0.9, 32)          # the well's curved wall
    for k in range(6):                             # posts on a 2.6 m circle
        t = 2 * math.pi * (k + 0.5) / 6
        m.ring(2.6 * math.cos(t), 2.6 * math.sin(t), 0, 0.12, 0.0, 2.6, 12)
    m.ring(0, 0, 0, 3.1, 2.6, 2.75, 24)            # the roof's eaves
    m.cone(0, 0, 3.1, 2.75, 3.8, 24)
    m.write("gazebo", "a round well under a conical roof on six posts")


def colonnade():
    m = Mesh()
    for row in (-1.6, 1.6):
        for k in range(5):
            x = -5.0 + 2.5 * k
            m.box((x - 0.4, 0.0, row - 0.4), (x + 0.4, 0.2, row + 0.4))  # plinth
            m.ring(x, row, 0, 0.3, 0.2, 3.2, 20)                           # shaft
    m.box((-6.0, 3.2, -2.2), (6.0, 3.6, 2.2))       # the slab both rows carry
    m.write("colonnade", "two rows of round columns under one slab")


def tunnel():
    m = Mesh()
    for x in (-2.3, 2.0):                           # low walls the vault stands on
        m.box((x, 0.0, 0.0), (x + 0.3, 1.2, 8.0))
    m.vault(2.0, 2.3, 1.2, 0.0, 8.0, 24)
    m.write("tunnel", "a barrel vault on low walls, open at both ends")


def pavilion():
    m = Mesh()
    m.box((-2.0, 0.0, -2.0), (2.0, 0.3, 2.0))      # the plinth: a step up
    for x in (-1.8, 1.6):
        for z in (-1.8, 1.6):
            m.box((x, 0.3, z), (x + 0.2, 2.6, z + 0.2))
    m.box((-2.6, 2.6, -2.6), (2.6, 2.8, 2.6))      # the roof overhangs the plinth
    m.write("pavilion", "a plinth one step high with a roof on four posts")


if __name__ == "__main__":
    for make in (gazebo, colonnade, tunnel, pavilion):
        make()
