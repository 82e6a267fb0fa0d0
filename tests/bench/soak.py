#!/usr/bin/python3
"""soak.py: a long run of a loaded cvre-server, watching its memory and its
file descriptors.

For --minutes (default: SOAK_MINUTES from the environment, else 10), --bots
bots (200) walk about a world of desks, so that collisions are logged all
along; the online refiner looks for clusters every 10 s; and --every
seconds (180) after the last time, an account uploads a model (cvre-client's
import, through the sandboxed importer) and then cvre-cluster --apply
refines beside the running server. Every 30 s it samples the server's resident memory (VmRSS,
and SQLite's share of it from the stats file) and its open descriptors, and
from the metrics endpoint the collision rows logged and the collision map
versions published. At the end it stops the bots and the server (SIGTERM),
prints the slopes (least squares, per hour) of the samples after the
warm-up, and reads the server's log.

Exits 1 on: the server dying or exiting non-zero; a sanitizer report in
its log (LeakSanitizer reports at exit in a -DCVRE_SANITIZE=ON build, whose
server runs with a 32 MiB ASan quarantine here, so that its RSS settles
within the warm-up); an upload or a cvre-cluster run that failed; a bot
cut off; or a slope over its limit after the warm-up (--warmup: half the
run, at most 10 minutes; until then the heap grows to its working size
while the first collision maps are refined):

  --max-rss-slope MiB/h (default 64): after the warm-up what the server
  holds grows only with the few uploaded meshes and, in steps, with the
  online refiner's per-object point buffers (they keep their largest size,
  up to 16 MiB an object, while an object's collisions pile up between two
  versions); a step of a few MiB is not a trend over an hour. 64
  MiB/h is 5 bytes per move at 200 bots (4,000 moves/s), 60 bytes per
  collision row (300/s) or 1 KB per tick: a leak per move, row or tick
  above those is over it.
  --max-fd-slope per hour (default 10): descriptors come and go only with
  connections, imports and scrapes, which the samples leave out (those
  taken while an upload or a cluster run is under way do not count); one
  descriptor leaked per upload (20 an hour) is over it.

Usage: soak.py --bin BUILD_DIR [--minutes M] [--bots 200] [--every 180]
               [--warmup S] [--out DIR] [--json FILE]
An hour: SOAK_MINUTES=60 cmake --build BUILD --target soak
"""
import argparse
import atexit
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request

from bench_sessions import MODELS, rss_mib, swarm
from load import crowded_world, open_fds, slope, stats_lines, world_flags

SAMPLE_S = 30
STOP_S = 600             # bound on the stop: it waits for the online refiner's round to end
DESKS, HALF = 60, 60     # a larger world for 200 bots; each desk is refined again and again
ACCOUNT = "soaker"
UPLOADS = [("homedecor_kitchen_chair.obj", ""), ("homedecor_doghouse.obj", ""), ("openfoam_desk.stl", " --up z"),
           ("homedecor_desk.obj", "")]
SANITIZER = re.compile(r"ERROR: (AddressSanitizer|LeakSanitizer)|runtime error:|WARNING: ThreadSanitizer")


def tool(a, name, *argv, stdin=None, env=None, timeout=600):
    p = subprocess.run([os.path.join(a.bin, name), *argv], input=stdin, env=env, capture_output=True, text=True,
                       timeout=timeout)
    return p.returncode, p.stdout, p.stderr


def metrics(url):
    """The endpoint's samples, name{labels} -> value."""
    with urllib.request.urlopen(url, timeout=30) as r:
        text = r.read().decode()
    out = {}
    for line in text.splitlines():
        if line and not line.startswith("#"):
            key, value = line.rsplit(" ", 1)
            out[key] = float(value)
    return out


def upload(a, port, k, rng):
    """One account upload through cvre-client; returns its done event."""
    model, up = UPLOADS[k % len(UPLOADS)]
    x, z = rng.uniform(-HALF, HALF), rng.uniform(-HALF, HALF)
    script = f"import {os.path.join(MODELS, model)}{up} --name up{k} at {x:.2f} 0.5 {z:.2f}\nquit\n"
    env = dict(os.environ, CVRE_PASSWORD="pw-" + ACCOUNT)
    rc, out, err = tool(a, "cvre-client", "--port", str(port), "--name", ACCOUNT, stdin=script, env=env)
    done = [e for e in map(json.loads, out.splitlines()) if e.get("event") == "done"]
    return rc, done[0] if done else {"result": "none", "stderr": err[-500:]}


class Ops(threading.Thread):
    """Every `every` seconds, an upload and then cvre-cluster --apply over the
    collisions since the last run, beside the running server; busy while
    they run (their descriptors are the server's for a moment)."""

    def __init__(self, a, port, db, t0):
        super().__init__(daemon=True)
        self.a, self.port, self.db, self.t0 = a, port, db, t0
        self.busy, self.count, self.problems = False, 0, []
        self.stop = threading.Event()

    def run(self):
        rng, since = random.Random(1), time.time()
        while not self.stop.wait(self.a.every):
            self.busy = True
            t = time.monotonic() - self.t0
            rc, done = upload(self.a, self.port, self.count, rng)
            if rc != 0 or done.get("result") != "ok":
                self.problems.append(f"upload {self.count} at {t:.0f} s: exit {rc}, {done}")
            now = time.time()
            rc, out, err = tool(self.a, "cvre-cluster", "--db", self.db, "--apply", "--since", f"{since:.3f}")
            if rc != 0:
                self.problems.append(f"cvre-cluster --apply at {t:.0f} s: exit {rc}: {err[-500:]}")
            since, self.count, self.busy = now, self.count + 1, False


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\nUsage:")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", required=True, help="build directory with the four programs")
    ap.add_argument("--minutes", type=float, default=float(os.environ.get("SOAK_MINUTES", 10)),
                    help="length of the run (default: SOAK_MINUTES, else 10)")
    ap.add_argument("--bots", type=int, default=200)
    ap.add_argument("--every", type=float, default=180, help="seconds between an upload and cvre-cluster --apply")
    ap.add_argument("--warmup", type=float, help="seconds left out of the slopes (default: half the run, at most "
                                                 "600)")
    ap.add_argument("--max-rss-slope", type=float, default=64, help="MiB per hour (default 64)")
    ap.add_argument("--max-fd-slope", type=float, default=10, help="descriptors per hour (default 10)")
    ap.add_argument("--out", help="directory for the database and the logs (default: a temporary one, removed "
                                  "when the run passed)")
    ap.add_argument("--json", help="write the samples and figures here")
    a = ap.parse_args()
    if not 1 <= a.minutes * 60 / SAMPLE_S or a.bots < 1 or a.every < SAMPLE_S:
        ap.error("--minutes must allow a few samples (at least 0.5), --bots at least 1, --every at least 30")
    missing = [p for p in ("cvre-server", "cvre-client", "cvre-admin", "cvre-cluster") if not os.access(os.path.join(a.bin, p), os.X_OK)]
    if missing:
        ap.error(f"no {', '.join(missing)} in {a.bin} (build it first)")
    seconds = a.minutes * 60
    warmup = a.warmup if a.warmup is not None else min(seconds / 2, 600)
    tmp = a.out or tempfile.mkdtemp(prefix="cvre-soak-")
    os.makedirs(tmp, exist_ok=True)
    db, log = os.path.join(tmp, "soak.db"), os.path.join(tmp, "server.log")
    stats = os.path.join(tmp, "stats.jsonl")
    world = os.path.join(tmp, "soak.world")
    crowded_world(world, 11, DESKS, HALF)
    # A small quarantine, so that an ASan build's RSS settles early (other
    # builds ignore it); leaks are reported at exit.
    asan = [o for o in os.environ.get("ASAN_OPTIONS", "").split(":") if o]
    env = dict(os.environ, ASAN_OPTIONS=":".join(asan + ["quarantine_size_mb=32", "detect_leaks=1"]))
    with open(log, "w") as f:
        srv = subprocess.Popen([os.path.join(a.bin, "cvre-server"), "--port", "0", "--db", db, "--world", world,
                                "--metrics", "127.0.0.1:0", "--stats-file", stats,
                                "--stats-interval", "5", "--max-clients", str(a.bots + 64), *world_flags(HALF)],
                               stdout=subprocess.PIPE, stderr=f, text=True, env=env)
    atexit.register(srv.kill)
    line = srv.stdout.readline()
    if not line.startswith("listening on "):
        sys.exit(f"soak: the server did not start ({line!r}); see {log}")
    port = int(line.rsplit(":", 1)[1])
    rc, _, err = tool(a, "cvre-admin", "--db", db, "user", "add", ACCOUNT, "--password-stdin",
                      stdin="pw-" + ACCOUNT + "\n")
    if rc:
        sys.exit(f"soak: cvre-admin user add: {err}")
    with open(log) as f:
        url = re.search(r"metrics on (http://\S+)", f.read()).group(1)
    bots = swarm(a.bin, port, a.bots, seconds + 60)
    atexit.register(bots.kill)
    bot_lines = []  # a line a second: read all along, or the full pipe would stop the swarm
    drain = threading.Thread(target=lambda: bot_lines.extend(bots.stdout), daemon=True)
    drain.start()
    print(f"soak: {a.minutes:g} min, {a.bots} bots, an upload and cvre-cluster --apply every {a.every:g} s, "
          f"in {tmp}", flush=True)
    print("   t s | RSS MiB | SQLite MiB | fds | rows logged | dropped | lost | versions published | imports | "
          "clients", flush=True)
    problems, samples = [], []
    t0 = time.monotonic()
    ops = Ops(a, port, db, t0)
    ops.start()
    while True:
        t = time.monotonic() - t0
        if srv.poll() is not None:
            problems.append(f"the server exited with {srv.returncode} at {t:.0f} s")
            break
        busy = ops.busy
        rss, fds = rss_mib(srv.pid), open_fds(srv.pid)  # before the scrape's own connection
        m = metrics(url)
        lines = stats_lines(stats)
        s = dict(t=round(t), rss=round(rss, 1), fds=fds, busy=busy or ops.busy,
                 sqlite=round(lines[-1]["sqlite_memory"] / 2**20, 1) if lines else 0.0,
                 rows=int(m['cvre_collision_log_rows_total{outcome="written"}']),
                 dropped=int(m['cvre_collision_log_rows_total{outcome="dropped"}']),
                 lost=int(m['cvre_collision_log_rows_total{outcome="lost"}']),
                 published=int(m["cvre_collision_maps_published_total"]),
                 imports=int(m['cvre_imports_total{result="ok"}']), clients=int(m["cvre_clients"]))
        samples.append(s)
        print(f"{s['t']:6} | {s['rss']:7.1f} | {s['sqlite']:10.1f} | {fds:3}{'*' if s['busy'] else ' '}| "
              f"{s['rows']:11} | {s['dropped']:7} | {s['lost']:4} | {s['published']:18} | {s['imports']:7} | "
              f"{s['clients']}", flush=True)
        if t >= seconds:
            break
        time.sleep(max(0.0, t0 + len(samples) * SAMPLE_S - time.monotonic()))
    ops.stop.set()
    ops.join()
    problems += ops.problems

    bots.send_signal(signal.SIGTERM)
    bots.wait(60)
    drain.join(60)
    summary = [e for e in map(json.loads, bot_lines) if e.get("event") == "summary"]
    if not summary or summary[0]["disconnects"] or summary[0]["errors"]:
        problems.append(f"bots: {summary[0] if summary else 'no summary'}")
    stop_s = None
    if srv.poll() is None:
        srv.send_signal(signal.SIGTERM)
        t_stop = time.monotonic()
        try:
            rc = srv.wait(STOP_S)
        except subprocess.TimeoutExpired:
            srv.kill()
            rc = f"nothing: killed after {STOP_S} s"
        stop_s = round(time.monotonic() - t_stop, 1)
        if rc != 0:
            problems.append(f"the server exited with {rc} on SIGTERM")
    with open(log) as f:
        text = f.read()
    reports = SANITIZER.findall(text)
    if reports:
        problems.append(f"{len(reports)} sanitizer reports in {log}")

    steady = [s for s in samples if s["t"] >= warmup]
    rss_slope = slope([(s["t"], s["rss"]) for s in steady])
    sqlite_slope = slope([(s["t"], s["sqlite"]) for s in steady])
    other_slope = slope([(s["t"], s["rss"] - s["sqlite"]) for s in steady])
    idle = [(s["t"], s["fds"]) for s in steady if not s["busy"]]
    fd_slope = slope(idle)
    first, last = samples[0], samples[-1]
    figures = dict(minutes=a.minutes, bots=a.bots, samples=len(samples), steady_samples=len(steady),
                   idle_samples=len(idle),
                   rss_start=first["rss"], rss_end=last["rss"], rss_max=max(s["rss"] for s in samples),
                   fds_start=first["fds"], fds_end=last["fds"], rss_slope_mib_h=round(rss_slope, 1),
                   sqlite_slope_mib_h=round(sqlite_slope, 1), other_slope_mib_h=round(other_slope, 1),
                   fd_slope_h=round(fd_slope, 1), rows=last["rows"], dropped=last["dropped"], lost=last["lost"],
                   published=last["published"], imports=last["imports"], cluster_runs=ops.count, stop_s=stop_s, sanitizer_reports=len(reports))
    if len(steady) < 2 or len(idle) < 2:
        problems.append(f"{len(steady)} samples after the warm-up, {len(idle)} of them between the uploads and "
                        "cluster runs: too few for a slope (a longer run, or a longer --every)")
    if rss_slope > a.max_rss_slope:
        problems.append(f"RSS grows {rss_slope:.1f} MiB/h after the warm-up (limit {a.max_rss_slope:g})")
    if fd_slope > a.max_fd_slope:
        problems.append(f"descriptors grow {fd_slope:.1f}/h after the warm-up (limit {a.max_fd_slope:g})")
    print("soak: " + ", ".join(f"{n} {v}" for n, v in figures.items()), flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(dict(figures=figures, samples=samples, problems=problems), f, indent=1)
    for p in problems:
        print("FAILED: " + p, flush=True)
    if problems:
        print(f"soak: logs in {tmp}")
        sys.exit(1)
    if not a.out:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
