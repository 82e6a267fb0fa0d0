"""Crash safety in the test suite: tests/bench/crash.py's kill -9 cycles, ten
of them under 30 bots walking into desks (bench-crash runs 100 under 200).
After every SIGKILL the database passes integrity_check, holds every
collision the log reported committed, never fewer collisions than before and
no gap in their ids; the server restarts on it and closes the sessions the
killed run left open. The runner's figures are checked again here, against
the database it leaves, and its checks are shown to catch a committed
collision that goes missing."""
import json
import os
import sqlite3
import subprocess
import sys
import tempfile

from harness import TEMP_DIRS, args, run

A = args()
BENCH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "bench")
sys.path.insert(0, BENCH)
import crash  # noqa: E402  (tests/bench/crash.py: its checks, reused)

OUT = tempfile.mkdtemp(prefix="cvre-crash-")
TEMP_DIRS.append(OUT)
CYCLES = 10


def runner():
    report = os.path.join(OUT, "report.json")
    p = subprocess.run([sys.executable, os.path.join(BENCH, "crash.py"), "--bin", A.bin, "--cycles", str(CYCLES),
                        "--bots", "30", "--out", OUT, "--json", report],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stdout[-4000:] + p.stderr[-4000:]
    with open(report) as f:
        return json.load(f)


REPORT = runner()


def test_every_kill_leaves_a_sound_database():
    cycles = REPORT["cycles"]
    assert len(cycles) == CYCLES and REPORT["summary"]["cycles"] == CYCLES, REPORT["summary"]
    rows = [c["rows"] for c in cycles]
    assert rows == sorted(rows), rows  # never backwards
    assert rows[-1] > 0, rows  # the load did log collisions
    for c in cycles:
        assert c["integrity"] == ["ok"], c
        assert c["max_id"] == c["rows"] == c["segmented"] and c["orphans"] == 0, c
        assert c["reported"] is None or c["reported"] <= c["rows"], c
    # Every kill after start-up came while rows were being committed: the
    # runner waited for that run's first ones before picking its moment.
    late = [c for c in cycles if c["restart_s"] is not None]
    assert late and all(c["reported"] is not None and c["reported"] > 0 for c in late), cycles


def test_sessions_of_killed_runs_are_closed():
    """The bots were only ever stopped after their server was killed, so every
    session in the database was closed by a restart, as crashed."""
    db = sqlite3.connect(f"file:{os.path.join(OUT, 'crash.db')}?mode=ro", uri=True)
    total, crashed = db.execute("SELECT count(*), count(*) FILTER (WHERE ended_at IS NOT NULL AND "
                                "end_reason = 'crashed') FROM sessions").fetchone()
    assert crashed == total == REPORT["summary"]["crashed_sessions"] > 0, (total, crashed, REPORT["summary"])
    assert db.execute("SELECT count(*) FROM collisions").fetchone()[0] == REPORT["summary"]["rows"]
    db.close()


def failed(d, prev, reported):
    """The runner's after-kill checks on figures d: the failure's text, or None."""
    try:
        crash.check_after_kill(d, prev, reported, 99)
    except crash.Failed as e:
        return str(e)
    return None


def test_checks_catch_a_missing_committed_row():
    """The runner's checks hold on the database it left, and fail when a
    collision reported committed is missing, when the count went down, or
    when a row is deleted from a copy of it."""
    db = os.path.join(OUT, "crash.db")
    d = crash.inspect(db)
    assert failed(d, dict(rows=d["rows"]), d["max_id"]) is None
    assert "reported id" in failed(d, dict(rows=0), d["max_id"] + 1)
    assert "went down" in failed(d, dict(rows=d["rows"] + 1), None)
    src = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    copy = os.path.join(OUT, "doctored.db")
    dst = sqlite3.connect(copy)
    src.backup(dst)
    src.close()
    dst.execute("DELETE FROM collisions WHERE id = ?", (d["max_id"] // 2,))
    dst.commit()
    dst.close()
    assert failed(crash.inspect(copy), dict(rows=0), None) is not None


run([test_every_kill_leaves_a_sound_database, test_sessions_of_killed_runs_are_closed,
     test_checks_catch_a_missing_committed_row])
