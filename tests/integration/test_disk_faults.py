"""The database's disk failing under a running, loaded server: full (a tmpfs
of fixed size, filled up), the database file made read-only (chattr +i: not
even root may write it) and the file deleted. Each time the collision log
writer counts what it could not store (log_lost in the stats file), says
why in the log at a bounded rate, the world goes on (bots stay connected, a
new client joins and is answered), and when the disk is back logging
resumes; the server stops cleanly and the database passes integrity_check.
A server started on a read-only database refuses with a message, not a
crash. The full-disk and read-only cases need root (mount, chattr) and are
skipped, saying so, where that is not possible."""
import atexit
import errno
import json
import os
import re
import sqlite3
import subprocess
import sys
import tempfile
import time

from harness import TEMP_DIRS, Raw, Server, args, hello, join, run

A = args()
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "bench"))
from bench_sessions import swarm  # noqa: E402
from load import crowded_world, stats_lines, world_flags  # noqa: E402

BOTS = 30
WAIT_S = 90              # bound on each awaited event (ASan, a loaded 2-core machine)
REPORT_S = 10            # DBLOG_REPORT_MS: the summed-up failure lines come at most this often
DBLOG_ATTEMPTS = 3       # dblog.h: failure lines are logged one by one for one batch's attempts
SQLITE_READONLY_DBMOVED = 1032


class Loaded:
    """cvre-server on db with the crowded world, a stats line a second and
    BOTS bots walking into desks."""

    def __init__(self, tag, db):
        world = os.path.join(TMP, f"{tag}.world")
        crowded_world(world, 5)
        self.stats = os.path.join(TMP, f"{tag}-stats.jsonl")
        self.srv = Server(A.bin, "--world", world, "--stats-file", self.stats, "--stats-interval", "1",
                          "--max-clients", str(BOTS + 64), *world_flags(), db=db)
        self.bots = swarm(A.bin, self.srv.port, BOTS, 3600)
        atexit.register(self.bots.kill)
        self.t0 = time.monotonic()

    def last(self):
        lines = stats_lines(self.stats)
        return lines[-1] if lines else {}

    def wait(self, what, pred):
        """Waits for pred(last stats line) to hold; returns that line."""
        end = time.monotonic() + WAIT_S
        while True:
            s = self.last()
            if s and pred(s):
                return s
            assert self.srv.alive(), f"the server died waiting for {what}: {self.srv.logtext()[-2000:]}"
            assert time.monotonic() < end, f"no {what} within {WAIT_S} s; last stats {s}"
            time.sleep(0.2)

    def wait_log(self, pattern):
        end = time.monotonic() + WAIT_S
        while not re.search(pattern, self.srv.logtext()):
            assert self.srv.alive(), f"the server died waiting for /{pattern}/"
            assert time.monotonic() < end, f"no /{pattern}/ in the log within {WAIT_S} s"
            time.sleep(0.2)

    def world_goes_on(self, seq):
        """The tick goes on moving every bot (stop() checks that none was
        disconnected), and a newcomer is answered: let in, or refused with
        an error saying why (a guest's join is recorded in the database)."""
        s = self.wait("a stats line with every bot moving", lambda s: s["clients"] >= BOTS and s["moves_in"] > 0)
        c = Raw(self.srv.port)
        c.send(hello() + join(f"newcomer{seq}"))
        msgs, end = [], time.monotonic() + WAIT_S
        while not any(m["type"] in ("join_ok", "error") for m in msgs):
            assert time.monotonic() < end and not c.closed, f"newcomer{seq}: no answer to its join; saw {msgs}"
            msgs += c.poll(0.2, first=True)
        assert all(m["message"] for m in msgs if m["type"] == "error"), msgs
        c.close()
        return s

    def failure_lines_bounded(self):
        """Failures are said one by one for the attempts at the first batch
        of each episode (an episode starts with "rows lost; further failures
        ..."), then summed up at most every REPORT_S."""
        text = self.srv.logtext()
        episodes = len(re.findall(r"rows lost; further failures are reported every", text))
        one_by_one = len(re.findall(r"collision log: batch of \d+ rows to .* failed", text))
        summed = len(re.findall(r"rows lost to database errors since the last report", text))
        assert episodes >= 1, text[-3000:]
        assert one_by_one <= DBLOG_ATTEMPTS * episodes, text[-3000:]
        assert summed <= (time.monotonic() - self.t0) / REPORT_S + 1 + episodes, text[-3000:]

    def stop(self):
        """Stops the bots (none may have been disconnected) and the server
        (exit 0); returns the server's log."""
        self.bots.terminate()
        out, _ = self.bots.communicate(timeout=30)
        summary = [e for e in map(json.loads, out.splitlines()) if e["event"] == "summary"]
        assert summary and summary[0]["joined"] == BOTS and summary[0]["disconnects"] == 0, out[-2000:]
        rc = self.srv.stop()
        assert rc == 0, f"exit {rc}: {self.srv.logtext()[-2000:]}"
        return self.srv.logtext()


def integrity(db):
    c = sqlite3.connect(db)
    try:
        return [r[0] for r in c.execute("PRAGMA integrity_check")], \
            c.execute("SELECT count(*), coalesce(max(id), 0) FROM collisions").fetchone()
    finally:
        c.close()


def test_full_disk():
    fs = os.path.join(TMP, "fs")
    db = os.path.join(fs, "cvre.db")
    L = Loaded("full", db)
    filler = os.path.join(fs, "filler")
    try:
        before = L.wait("committed collisions", lambda s: s["log_written"] > 0)
        with open(filler, "wb", buffering=0) as f:  # the disk fills up
            try:
                while True:
                    f.write(b"\0" * 65536)
            except OSError as e:
                assert e.errno == errno.ENOSPC, e
        full = L.wait("rows lost to the full disk", lambda s: s["log_lost"] > 0)
        L.wait_log(r"failed \(attempt 1 of \d+\): (database or disk is full|.*No space left on device)")
        assert full["log_written"] >= before["log_written"]
        L.world_goes_on(1)
        lost = L.wait("more rows lost", lambda s: s["log_lost"] > full["log_lost"])
        os.unlink(filler)  # space returns
        L.wait_log(r"collision log: writing again; \d+ rows were lost while it failed")
        back = L.wait("rows written again", lambda s: s["log_written"] > lost["log_written"])
        L.world_goes_on(2)
        L.failure_lines_bounded()
        text = L.stop()
        m = re.search(r"collision log: (\d+) rows written, (\d+) dropped, (\d+) lost", text)
        assert m and int(m.group(3)) >= back["log_lost"] > 0, text[-2000:]
        check, (rows, max_id) = integrity(db)
        assert check == ["ok"] and rows == max_id == int(m.group(1)), (check, rows, max_id, m.group(0))
    finally:
        L.srv.proc.kill()
        L.bots.kill()
        L.srv.proc.wait()
        subprocess.run(["umount", "-l", fs], capture_output=True)


def immutable(paths, on):
    subprocess.run(["chattr", "+i" if on else "-i", *paths], check=True, capture_output=True)


def test_read_only_file():
    db = os.path.join(TMP, "ro", "cvre.db")
    os.makedirs(os.path.dirname(db))
    L = Loaded("ro", db)
    files = [db, db + "-wal"]
    try:
        L.wait("committed collisions", lambda s: s["log_written"] > 0)
        immutable(files, True)
        ro = L.wait("rows lost to the read-only file", lambda s: s["log_lost"] > 0)
        L.wait_log(r"failed \(attempt 1 of \d+\): disk I/O error \(Operation not permitted\)")
        L.world_goes_on(3)
        immutable(files, False)
        L.wait_log(r"collision log: writing again")
        L.wait("rows written again", lambda s: s["log_written"] > ro["log_written"])
        L.failure_lines_bounded()
        L.stop()
        assert integrity(db)[0] == ["ok"]
        # Started on a database it may not write, the server refuses, saying so.
        immutable([db], True)
        p = subprocess.run([os.path.join(A.bin, "cvre-server"), "--port", "0", "--db", db],
                           capture_output=True, text=True, timeout=60)
        assert p.returncode > 0 and p.stdout == "", (p.returncode, p.stdout)
        assert db in p.stderr and re.search(r"read-?only|not permitted|readonly", p.stderr, re.I), p.stderr
    finally:
        immutable([f for f in files if os.path.exists(f)], False)


def test_deleted_file():
    db = os.path.join(TMP, "gone", "cvre.db")
    os.makedirs(os.path.dirname(db))
    L = Loaded("gone", db)
    before = L.wait("committed collisions", lambda s: s["log_written"] > 0)
    os.unlink(db)
    L.wait_log(r"collision log: database file .*cvre\.db was deleted or replaced while the server runs")
    gone = L.wait("rows lost to the deleted file",
                  lambda s: s["log_lost"] > 0 and s["log_last_error"] == SQLITE_READONLY_DBMOVED)
    L.world_goes_on(4)
    after = L.wait("more rows lost", lambda s: s["log_lost"] > gone["log_lost"])
    assert after["log_written"] == gone["log_written"], (gone, after)  # nothing into the unlinked file
    assert after["log_committed_id"] == gone["log_committed_id"] >= before["log_committed_id"]
    L.stop()


def can(cmd):
    return subprocess.run(cmd, capture_output=True).returncode == 0


TMP = tempfile.mkdtemp(prefix="cvre-disk-")
TEMP_DIRS.append(TMP)
tests, fs = [test_deleted_file], os.path.join(TMP, "fs")
os.makedirs(fs)
# 24 MiB: the world's meshes and a few seconds of collisions, filled in a moment.
if can(["mount", "-t", "tmpfs", "-o", "size=24m,mode=0700", "tmpfs", fs]):
    tests.append(test_full_disk)
else:
    print("skip test_full_disk: cannot mount a tmpfs here (needs root)", flush=True)
probe = os.path.join(TMP, "probe")
open(probe, "w").close()
if can(["chattr", "+i", probe]):
    can(["chattr", "-i", probe])
    tests.append(test_read_only_file)
else:
    print("skip test_read_only_file: chattr +i does not work on this file system or as this user", flush=True)
try:
    run(tests)
finally:
    subprocess.run(["umount", "-l", fs], capture_output=True)
