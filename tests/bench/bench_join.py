#!/usr/bin/env python3
"""Joins in big worlds: for worlds of 1,000, 20,000 and 100,000 objects
(flat tiles 5 m apart, tests/integration/tiles.py), the server's start-up
time and memory, then for a few clients joining one after another the
time from connecting until the client knows every object within its area
of interest (until its last OBJECT_INFO), and the bytes that took.

Target: joining costs the same in every world (bytes per join in the
largest world within twice those in the smallest), and no client is cut
off. Exits 1 when a target is missed.

  python3 tests/bench/bench_join.py --bin build [--sizes 1000,20000,100000] [--joins 5]
"""
import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "integration"))
from bench_sessions import rss_mib  # noqa: E402
from tiles import Walker, pump_until, write_world  # noqa: E402

RADIUS = 64.0


def measure(bindir, tmp, n, joins):
    world, rects = write_world(tmp, n)
    db = os.path.join(tmp, f"bench{n}.db")
    t0 = time.time()
    proc = subprocess.Popen([os.path.join(bindir, "cvre-server"), "--port", "0", "--db", db, "--world", world,
                             "--world-size", "2000", "--aoi-radius", str(RADIUS), "--joins-per-second", "0",
                             "--max-per-address", "0", "--refine-interval", "0", "--log-level", "warn"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        line = proc.stdout.readline()
        if not line.startswith("listening on"):
            raise SystemExit(f"bench_join: the server did not start with {n} objects")
        start_s = time.time() - t0
        port = int(line.rsplit(":", 1)[1])
        times, sizes, counts, cut = [], [], [], 0
        for i in range(joins):
            t = time.time()
            w = Walker(port, f"joiner{i}")
            # done once nothing came for a while; then checked, untimed
            pump_until([w], lambda: w.last_info is not None and time.time() - w.last_info > 0.5, 60)
            whole = w.pos is not None and w.view(rects, RADIUS)[0] == []
            times.append(w.last_info - t)
            sizes.append(w.bytes)
            counts.append(len(w.known))
            cut += w.closed or not whole
            w.close()
        rss = rss_mib(proc.pid)
    finally:
        proc.terminate()
        proc.wait(30)
    return dict(n=n, start_s=start_s, rss_mb=rss, join_ms=1000 * statistics.median(times),
                join_kb=statistics.median(sizes) / 1024, objects=statistics.median(counts), cut=cut)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", required=True, help="the build directory holding cvre-server")
    ap.add_argument("--sizes", default="1000,20000,100000", help="world sizes, in objects")
    ap.add_argument("--joins", type=int, default=5, help="clients joining each world, one after another")
    a = ap.parse_args()
    tmp = tempfile.mkdtemp(prefix="cvre-bench-join-")
    rows = []
    try:
        print(f"{'objects':>8} {'start s':>8} {'RSS MB':>7} {'join ms':>8} {'KB/join':>8} {'known':>6} {'cut off':>8}")
        for n in (int(x) for x in a.sizes.split(",")):
            r = measure(a.bin, tmp, n, a.joins)
            rows.append(r)
            print(f"{r['n']:>8} {r['start_s']:>8.1f} {r['rss_mb']:>7.0f} {r['join_ms']:>8.1f} {r['join_kb']:>8.1f} "
                  f"{r['objects']:>6.0f} {r['cut']:>8}", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    ratio = rows[-1]["join_kb"] / rows[0]["join_kb"]
    ok = ratio <= 2.0 and not any(r["cut"] for r in rows)
    print(f"bytes per join, {rows[-1]['n']} vs {rows[0]['n']} objects: {ratio:.2f}x (target <= 2x); "
          f"clients cut off: {sum(r['cut'] for r in rows)} (target 0): {'met' if ok else 'NOT met'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
