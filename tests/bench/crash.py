#!/usr/bin/python3
"""crash.py: kill -9 a loaded cvre-server at random moments, again and again,
and check its database after every kill.

Each cycle starts cvre-server on the same database (a world crowded with
desks, load.py; the online refiner every second; a stats line every
second), lets --bots bots walk into the desks, and kills the server with
SIGKILL at a random moment: most cycles 0 to 2 s after this run's first
collisions were committed, one in five 0 to 0.5 s after it was started
(during start-up, often before it listens). After each kill:

  - PRAGMA integrity_check is ok, and every collision has its group, its
    rtree cell and its segment (the log's batches are whole);
  - collision ids have no gap, and their count never went down;
  - every collision the log reported committed is there: log_committed_id
    in the stats file, which the server writes only after COMMIT returned.

After each restart: the server listens again on the same database, the
sessions the killed run left open are closed with end reason "crashed" (and
its log says how many), and the log's committed id starts from the count
stored. A last start ends with SIGTERM: exit 0, no session left open.

Prints one line per cycle and a summary; --json FILE writes the figures.
Exits 0 when every check held, 1 at the first that did not (the server logs
are kept in --out, or in the temporary directory it names).

Usage: crash.py --bin BUILD_DIR [--cycles 100] [--bots 200] [--seed N]
                [--out DIR] [--json FILE]
"""
import argparse
import atexit
import json
import os
import random
import re
import select
import shutil
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time

from bench_sessions import swarm
from load import crowded_world, stats_lines, world_flags

START_S = 120     # bound on a start (the first one imports the world's models; ASan is slow)
ROWS_S = 60       # bound on the first committed collisions of a run
EARLY = 0.2       # share of cycles killed during start-up


class Failed(Exception):
    pass


def check(cond, what):
    if not cond:
        raise Failed(what)


class Run:
    """One cvre-server process on the database, its log and stats file."""

    def __init__(self, a, tmp, k):
        self.log = os.path.join(tmp, f"server-{k}.log")
        self.stats = os.path.join(tmp, f"stats-{k}.jsonl")
        cmd = [os.path.join(a.bin, "cvre-server"), "--port", "0", "--db", os.path.join(tmp, "crash.db"),
               "--world", os.path.join(tmp, "crash.world"), "--stats-file", self.stats, "--stats-interval", "1",
               "--refine-interval", "1", "--max-clients", str(a.bots + 64), *world_flags()]
        with open(self.log, "w") as log:
            self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=log, text=True)
        atexit.register(self.proc.kill)
        self.started = time.monotonic()

    def listening(self):
        """Waits for the ready line; returns the port."""
        r, _, _ = select.select([self.proc.stdout], [], [], START_S)
        line = self.proc.stdout.readline() if r else ""
        check(line.startswith("listening on "),
              f"server did not start within {START_S} s: {line!r}; see {self.log}")
        return int(line.rsplit(":", 1)[1])

    def committed(self):
        """The highest committed id the stats file reported, or None."""
        ids = [s["log_committed_id"] for s in stats_lines(self.stats)]
        return max(ids) if ids else None

    def logtext(self):
        with open(self.log) as f:
            return f.read()


def inspect(db):
    """The database as a restart will find it, read without changing it (a
    read-only connection does not checkpoint the WAL)."""
    c = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=30)
    try:
        one = lambda sql: c.execute(sql).fetchone()[0]
        return dict(
            integrity=[r[0] for r in c.execute("PRAGMA integrity_check")],
            rows=one("SELECT count(*) FROM collisions"),
            max_id=one("SELECT coalesce(max(id), 0) FROM collisions"),
            orphans=one("SELECT count(*) FROM collisions c LEFT JOIN collision_groups g ON g.g = c.g "
                        "LEFT JOIN collision_cells r ON r.g = c.g WHERE g.g IS NULL OR r.g IS NULL"),
            segmented=one("SELECT coalesce(sum(last_id - first_id + 1), 0) FROM collision_segments"),
            open_sessions=one("SELECT count(*) FROM sessions WHERE ended_at IS NULL"),
            crashed=one("SELECT count(*) FROM sessions WHERE end_reason = 'crashed'"),
            versions=one("SELECT count(*) FROM ecm_versions"))
    finally:
        c.close()


def check_after_kill(d, prev, reported, k):
    check(d["integrity"] == ["ok"], f"cycle {k}: integrity_check says {d['integrity'][:5]}")
    check(d["orphans"] == 0, f"cycle {k}: {d['orphans']} collisions without their group or cell")
    check(d["segmented"] == d["rows"], f"cycle {k}: segments cover {d['segmented']} of {d['rows']} rows")
    check(d["rows"] == d["max_id"], f"cycle {k}: {d['rows']} rows but ids up to {d['max_id']}: a gap")
    check(d["rows"] >= prev["rows"], f"cycle {k}: collisions went down from {prev['rows']} to {d['rows']}")
    check(reported is None or d["max_id"] >= reported,
          f"cycle {k}: the log reported id {reported} committed, the table ends at {d['max_id']}")


def check_restart(run, before, db, k):
    """The restarted server closed what the killed one left open."""
    after = inspect(db)
    check(after["open_sessions"] == 0, f"cycle {k}: {after['open_sessions']} sessions still open after restart")
    check(after["crashed"] == before["crashed"] + before["open_sessions"],
          f"cycle {k}: {before['open_sessions']} sessions were open, "
          f"{after['crashed'] - before['crashed']} closed as crashed")
    m = re.search(r"closed (\d+) sessions left open", run.logtext())
    said = int(m.group(1)) if m else 0
    check(said == before["open_sessions"], f"cycle {k}: the log says {said} sessions closed, "
                                           f"{before['open_sessions']} were open")


def stop_bots(bots):
    if bots:
        bots.terminate()
        try:
            bots.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            bots.kill()
            bots.communicate()


def cycle(a, tmp, k, rng, prev):
    """One start, load and SIGKILL; returns this cycle's figures."""
    db = os.path.join(tmp, "crash.db")
    run, bots = Run(a, tmp, k), None
    early = k > 0 and rng.random() < EARLY  # the first start imports the world: let it
    port = restart_s = None
    try:
        if early:
            time.sleep(rng.uniform(0, 0.5))
            at = "start-up"
        else:
            port = run.listening()
            restart_s = time.monotonic() - run.started
            if k > 0:
                check_restart(run, prev, db, k)
            bots = swarm(a.bin, port, a.bots, 3600)
            end = time.monotonic() + ROWS_S
            while (run.committed() or 0) <= prev["rows"]:
                check(run.proc.poll() is None, f"cycle {k}: the server died; see {run.log}")
                check(time.monotonic() < end, f"cycle {k}: no collision committed within {ROWS_S} s")
                time.sleep(0.1)
            delay = rng.uniform(0, 2)
            time.sleep(delay)
            at = f"{delay:.2f} s into the rows"
        check(run.proc.poll() is None, f"cycle {k}: the server exited by itself; see {run.log}")
        run.proc.send_signal(signal.SIGKILL)
        run.proc.wait(30)
    finally:
        run.proc.kill()
        stop_bots(bots)
    lines = stats_lines(run.stats)
    reported = run.committed()
    if lines:
        check(min(s["log_committed_id"] for s in lines) >= prev["rows"],
              f"cycle {k}: the restarted log began below the {prev['rows']} rows stored")
    d = inspect(db)
    check_after_kill(d, prev, reported, k)
    d.update(cycle=k, killed=at, restart_s=restart_s, reported=reported,
             queued=lines[-1]["log_queued"] if lines else None)
    print(f"cycle {k}: killed {at}; committed reported {reported}, stored {d['rows']} "
          f"(+{d['rows'] - prev['rows']}), in the queue at the last report {d['queued']}; "
          f"{d['open_sessions']} sessions left open; "
          f"restart {'-' if restart_s is None else f'{restart_s:.2f} s'}", flush=True)
    return d


def last_start(a, tmp, k, prev):
    """A clean stop after all the kills."""
    run = Run(a, tmp, k)
    try:
        run.listening()
        check_restart(run, prev, os.path.join(tmp, "crash.db"), k)
        run.proc.send_signal(signal.SIGTERM)
        rc = run.proc.wait(60)
    finally:
        run.proc.kill()
    check(rc == 0, f"the last run exited {rc} on SIGTERM; see {run.log}")
    d = inspect(os.path.join(tmp, "crash.db"))
    check(d["integrity"] == ["ok"] and d["open_sessions"] == 0 and d["rows"] == prev["rows"],
          f"after the clean stop: {d}")
    return d


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bin", required=True, help="build directory with cvre-server and cvre-client")
    ap.add_argument("--cycles", type=int, default=100, help="kills (default 100)")
    ap.add_argument("--bots", type=int, default=200, help="bots walking into desks (default 200)")
    ap.add_argument("--seed", type=int, help="seed for the kill moments (default: random, printed)")
    ap.add_argument("--out", help="directory for the database and the server logs (default: a new temporary "
                                  "one, removed when every check held)")
    ap.add_argument("--json", help="write the figures here")
    a = ap.parse_args()
    if a.cycles < 1 or a.bots < 1:
        ap.error("--cycles and --bots must be at least 1")
    missing = [p for p in ("cvre-server", "cvre-client") if not os.access(os.path.join(a.bin, p), os.X_OK)]
    if missing:
        ap.error(f"no {', '.join(missing)} in {a.bin} (build it first)")
    seed = a.seed if a.seed is not None else random.randrange(1 << 30)
    rng = random.Random(seed)
    tmp = a.out or tempfile.mkdtemp(prefix="cvre-crash-")
    os.makedirs(tmp, exist_ok=True)
    crowded_world(os.path.join(tmp, "crash.world"), seed)
    print(f"crash: {a.cycles} kills under {a.bots} bots, seed {seed}, in {tmp}", flush=True)
    prev = dict(rows=0, open_sessions=0, crashed=0)
    cycles, t0 = [], time.monotonic()
    try:
        for k in range(a.cycles):
            prev = cycle(a, tmp, k, rng, prev)
            cycles.append(prev)
        final = last_start(a, tmp, a.cycles, prev)
    except Failed as e:
        print(f"FAILED: {e} (seed {seed}; logs in {tmp})", flush=True)
        sys.exit(1)
    restarts = sorted(c["restart_s"] for c in cycles if c["restart_s"] is not None)
    summary = dict(seed=seed, cycles=len(cycles), bots=a.bots, seconds=round(time.monotonic() - t0, 1),
                   early_kills=sum(c["restart_s"] is None for c in cycles), rows=final["rows"],
                   versions=final["versions"], crashed_sessions=final["crashed"],
                   restart_s_median=round(restarts[len(restarts) // 2], 2), restart_s_max=round(restarts[-1], 2))
    print("crash: " + ", ".join(f"{k} {v}" for k, v in summary.items()) + "; every check held", flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(dict(summary=summary, cycles=cycles), f, indent=1)
    if not a.out:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
