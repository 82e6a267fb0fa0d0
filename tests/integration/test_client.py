#!/usr/bin/env python3
"""cvre-client as a person and a script see it: the short lines it shows at
a terminal (a pseudo-terminal here) instead of the JSON stream, --json
there, and imports placed by their box's base or dropped onto what is
under them (client/README.md)."""
import atexit
import json
import os
import pty
import re
import select
import sqlite3
import subprocess
import time

from harness import MODELS, Raw, Server, args, run

A = args()
HERE = os.path.dirname(os.path.abspath(__file__))
ROOM = os.path.join(HERE, "room.world")  # its west wall at x = 4.358
DESK = os.path.join(MODELS, "openings", "openfoam_desk.stl")  # its box 1.8 to 4.2 m west of its origin
WAIT = 30  # seconds any one expected line may take on a loaded machine


class Terminal:
    """cvre-client with standard input, output and error on one
    pseudo-terminal, as a person running it in a shell has them."""

    def __init__(self, port, name, *extra):
        master, slave = pty.openpty()
        self.proc = subprocess.Popen([os.path.join(A.bin, "cvre-client"), "--port", str(port), "--name", name,
                                      *extra], stdin=slave, stdout=slave, stderr=slave, close_fds=True)
        atexit.register(self.proc.kill)
        os.close(slave)
        self.fd = master
        self.text = ""

    def type(self, line):
        os.write(self.fd, (line + "\n").encode())

    def read(self, timeout):
        """Takes what the client showed within timeout seconds; False once
        it has closed its side."""
        if not select.select([self.fd], [], [], timeout)[0]:
            return True
        try:
            data = os.read(self.fd, 65536)
        except OSError:  # EIO: no process holds the terminal any more
            data = b""
        self.text += data.decode("utf-8", "replace")
        return bool(data)

    def until(self, pattern):
        """Reads until pattern (a regex) matches what was shown; returns the
        match. Fails after WAIT seconds, or if the client ends first."""
        end = time.time() + WAIT
        while True:
            m = re.search(pattern, self.text)
            if m:
                return m
            left = end - time.time()
            assert left > 0, f"{pattern!r} not shown within {WAIT}s; shown: {self.text[-1500:]!r}"
            assert self.read(left), f"client ended before {pattern!r}; shown: {self.text[-1500:]!r}"

    def finish(self):
        """Reads the rest after quit; returns the exit code."""
        end = time.time() + WAIT
        while time.time() < end and self.proc.poll() is None and self.read(0.2):
            pass
        rc = self.proc.wait(WAIT)
        while self.read(0):
            pass
        os.close(self.fd)
        return rc


def test_terminal_shows_lines_for_a_person():
    srv = Server(A.bin, "--world", ROOM, "--spawn-radius", "0")
    try:
        t = Terminal(srv.port, "tess")
        t.until(r"joined as avatar \d+ at \(0\.00, 0\.00, 0\.00\)")
        t.until(r'object 1 "[^"]+" of world at \(10\.00, 0\.00, 0\.00\), box \(4\.36,')
        bob = Raw(srv.port)
        bob.handshake("bob")
        t.until(r"\+ bob \(avatar \d+\) is here")
        bob.close()
        t.until(r"- bob \(avatar \d+\) left")
        # Into the room's west wall: the server blocks every move for the
        # second it takes the move to give up, with a COLLISION each tick.
        t.type("move 20 0 0")
        t.until(r"move done, at \(4\.0\d, 0\.00, 0\.00\)")
        t.type("bogus")
        t.until(r"stdin:2: unknown command 'bogus'")
        t.type("quit")
        t.until(r"connection closed")
        assert t.finish() == 0, t.text
    finally:
        srv.stop()
    bumps = re.findall(r"bumped into object 1 at \(4\.36, ", t.text)
    assert len(bumps) == 1, t.text
    db = sqlite3.connect(srv.db)
    hits = db.execute("SELECT count(*) FROM collisions").fetchone()[0]
    db.close()
    assert hits >= 5, f"only {hits} collisions: the wall was not pushed long enough to show one line for many"
    assert '"event"' not in t.text and "snapshot" not in t.text, t.text
    assert "> " in t.text, "no prompt"


def test_json_flag_gives_the_stream_at_a_terminal():
    srv = Server(A.bin, "--spawn-radius", "0")
    try:
        t = Terminal(srv.port, "jason", "--json")
        t.until(r'\{"event":"join_ok"')
        t.type("move 1 0 0")
        t.until(r'\{"event":"done","command":"move"')
        t.type("quit")
        t.until(r'\{"event":"closed"\}')
        assert t.finish() == 0, t.text
    finally:
        srv.stop()
    events = [json.loads(line[line.index("{"):]) for line in t.text.splitlines() if '{"event"' in line]
    assert any(e["event"] == "snapshot" for e in events), t.text


def box_of(obj):
    """The box around an object event's boxes: (min, max)."""
    b = obj["boxes"]
    return [min(x[a] for x in b) for a in range(3)], [max(x[a + 3] for x in b) for a in range(3)]


def near(a, b, tol=0.01):
    return all(abs(x - y) <= tol for x, y in zip(a, b))


def test_import_anchored_by_its_base_and_dropped():
    srv = Server(A.bin)
    try:
        pw = srv.account("ann")
        script = "\n".join([
            f'import "{DESK}" --up z at 16 0 -8',                         # 1: by its origin, as ever
            f'import "{DESK}" --up z at 16 0 -8 --anchor base',           # 2: its box's base at 16 0 -8
            f'import "{DESK}" --up z at 16 3 -8 --anchor base --drop',    # 3: falls onto 2
            f'import "{DESK}" --up z at 40 -0.5 0 --drop',                # 4: below the floor: comes up
            f'import "{DESK}" --up z at 20 0 20 --anchor origin --drop',  # 5: already on the floor
            f'import "{DESK}" --up z at 499 0 0 --anchor base',           # 6: its box would leave the world
            "quit", ""])
        c = subprocess.run([os.path.join(A.bin, "cvre-client"), "--port", str(srv.port), "--name", "ann"],
                           input=script, capture_output=True, text=True, timeout=120,
                           env=dict(os.environ, CVRE_PASSWORD=pw))
        assert c.returncode == 0, (c.returncode, c.stderr)
        events = [json.loads(line) for line in c.stdout.splitlines()]
    finally:
        srv.stop()
    done = [e for e in events if e["event"] == "done"]
    assert [d["result"] for d in done] == ["ok"] * 5 + ["rejected"], done
    last = {}  # the latest object event of each object
    for e in events:
        if e["event"] == "object":
            last[e["id"]] = e
    for d in done[:5]:
        lo, hi = box_of(last[d["object"]])
        assert near(d["box_min"], lo, 0.002) and near(d["box_max"], hi, 0.002), (d, last[d["object"]])
    # 1: the origin at 16 0 -8, the box beside it (x 11.8 to 14.2), as before.
    d1 = done[0]
    assert last[d1["object"]]["pos"] == [16, 0, -8] and near([d1["box_min"][0], d1["box_max"][0]], [11.811, 14.160])
    size = [h - l for l, h in zip(d1["box_min"], d1["box_max"])]
    # 2: the bottom centre of the box at 16 0 -8; one object event for the
    # upload, one for the placing.
    d2 = done[1]
    centre = [(d2["box_min"][0] + d2["box_max"][0]) / 2, d2["box_min"][1], (d2["box_min"][2] + d2["box_max"][2]) / 2]
    assert near(centre, [16, 0, -8]), d2
    assert len([e for e in events if e["event"] == "object" and e["id"] == d2["object"]]) == 2
    # 3: the same footprint, dropped from y 3 onto desk 2's top.
    d3 = done[2]
    assert near(d3["box_min"], [d2["box_min"][0], d2["box_max"][1], d2["box_min"][2]]), (d3, d2)
    # 4: its box's bottom was at -0.5, under the floor: raised onto y 0.
    d4 = done[3]
    assert abs(d4["box_min"][1]) <= 0.01 and abs(d4["box_min"][0] - (40 - 4.189)) <= 0.01, d4
    # 5: already resting on the floor: not placed a second time.
    d5 = done[4]
    assert abs(d5["box_min"][1]) <= 0.01 and near([h - l for l, h in zip(d5["box_min"], d5["box_max"])], size)
    assert len([e for e in events if e["event"] == "object" and e["id"] == d5["object"]]) == 1
    # 6: the server refuses the placing past the world's edge (500 m): the
    # object stays where the upload put it, and the done names it.
    d6 = done[5]
    rej = [e for e in events if e["event"] == "rejected"]
    assert d6["object"] is not None and rej and rej[-1]["request"] == d6["object"] and rej[-1]["code"] == 43, (d6, rej)
    assert last[d6["object"]]["pos"] == [499, 0, 0] and "box_min" not in d6, d6


def test_bad_anchor_options():
    """A script is checked whole before connecting: a bad option costs its
    message and exit code 2, and nothing is sent (port 1 is never tried)."""
    path = os.path.join(A.bin, "test_client_bad.script")
    for line, want in [("import x.stl at 0 0 0 --anchor middle", "--anchor: bad anchor 'middle'"),
                       ("import x.stl at 0 0 0 --drop --drop", "'--drop' given twice"),
                       ("place 1 0 0 0 --drop", "place: unexpected '--drop'")]:
        with open(path, "w") as f:
            f.write(line + "\n")
        c = subprocess.run([os.path.join(A.bin, "cvre-client"), "--port", "1", "--script", path],
                           capture_output=True, text=True, timeout=WAIT)
        os.unlink(path)
        assert c.returncode == 2 and "test_client_bad.script:1: " in c.stderr and want in c.stderr, (line, c)
        assert c.stdout == "", c.stdout


run([test_terminal_shows_lines_for_a_person, test_json_flag_gives_the_stream_at_a_terminal,
     test_import_anchored_by_its_base_and_dropped, test_bad_anchor_options])
