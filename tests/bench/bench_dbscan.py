#!/usr/bin/python3
"""Benchmark of algo/cluster/dbscan.c (through dbscan_cli) side by side
with scikit-learn's DBSCAN on the same points, in the same run.

Data: collision-like points in a 100 m cube: 70% in Gaussian hotspots
(one per 5000 points, sigma 0.3 to 1.0 m, the size of a door frame or a
table edge people keep bumping into) and 30% uniform noise. Parameters:
eps = 0.5 m (about an avatar's radius) and min_points = 10, min_users = 1
(scikit-learn has no user criterion).

Timed: our dbscan_run alone (the CLI measures it with CLOCK_MONOTONIC, file
I/O excluded), best of --repeat runs; scikit-learn's DBSCAN.fit, once per
n_jobs setting, in a child process so that its peak memory is its own.
Peak memory of our CLI is measured by /usr/bin/time (maximum resident set).
Labels are compared as in tests/integration/test_dbscan_sklearn.py: core
flags and noise exactly, core partition up to renaming, border points in a
cluster that reaches them.

Usage: bench_dbscan.py --bin BUILD_DIR [--sizes 10000,100000,1000000]
                       [--jobs 1,-1] [--repeat 3] [--threads 0]
Exits 1 if labels differ. Needs Debian's python3-sklearn, so it re-runs
itself under /usr/bin/python3 when started by another python.
"""
import os
import sys

try:
    import numpy as np
    import sklearn  # noqa: F401  (checked here, used in the child)
except ImportError:
    if sys.executable != "/usr/bin/python3" and os.path.exists("/usr/bin/python3"):
        os.execv("/usr/bin/python3", ["/usr/bin/python3"] + sys.argv)
    raise

import argparse
import re
import struct
import subprocess
import tempfile

EPS, MIN_POINTS, CUBE = 0.5, 10, 100.0

SKLEARN_CHILD = r"""
import sys, time, resource, numpy as np
from sklearn.cluster import DBSCAN
x = np.load(sys.argv[1]).astype(np.float64)
t = time.perf_counter()
m = DBSCAN(eps=float(sys.argv[2]), min_samples=int(sys.argv[3]), n_jobs=int(sys.argv[4])).fit(x)
t = time.perf_counter() - t
np.save(sys.argv[5], m.labels_)
core = np.zeros(len(x), bool); core[m.core_sample_indices_] = True
np.save(sys.argv[6], core)
print(t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def generate(n, seed):
    rng = np.random.default_rng(seed)
    nblob = max(1, n // 5000)
    inblobs = int(n * 0.7)
    centers = rng.uniform(5, CUBE - 5, size=(nblob, 3))
    sigma = rng.uniform(0.3, 1.0, size=nblob)
    which = rng.integers(0, nblob, inblobs)
    pts = centers[which] + rng.normal(size=(inblobs, 3)) * sigma[which, None]
    noise = rng.uniform(0, CUBE, size=(n - inblobs, 3))
    x = np.concatenate([pts, noise]).astype(np.float32)
    return x[rng.permutation(n)]


def write_points(path, xyz):
    rec = np.zeros(len(xyz), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("u", "<u4")])
    rec["x"], rec["y"], rec["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    rec["u"] = np.arange(len(xyz), dtype=np.uint32)
    with open(path, "wb") as f:
        f.write(b"CVREPTS1" + struct.pack("<Q", len(xyz)))
        f.write(rec.tobytes())


def find_cli(build_dir):
    for rel in ("dbscan_cli", "tests/bench/dbscan_cli", "tests/dbscan_cli", "bin/dbscan_cli"):
        p = os.path.join(build_dir, rel)
        if os.access(p, os.X_OK):
            return p
    sys.exit(f"dbscan_cli not found under {build_dir}")


def run_ours(cli, inp, out, threads):
    """Returns (dbscan_run ms, peak RSS MB, stderr line, labels, core).

    Peak memory comes from /usr/bin/time (Debian package "time"): the
    ru_maxrss of a child forked straight from this process would include the
    RSS of this python, numpy and all, from before the exec."""
    cmd = [cli, "--eps", str(EPS), "--min-points", str(MIN_POINTS), "--threads", str(threads), inp, out]
    timed = os.access("/usr/bin/time", os.X_OK)
    if timed:
        cmd = ["/usr/bin/time", "-f", "maxrss_kb=%M"] + cmd
    err = tempfile.TemporaryFile()
    p = subprocess.Popen(cmd, stderr=err)
    _, status, ru = os.wait4(p.pid, 0)
    p.returncode = os.waitstatus_to_exitcode(status)
    err.seek(0)
    msg = err.read().decode().strip()
    if p.returncode != 0:
        sys.exit(f"dbscan_cli failed: {msg}")
    ms = float(re.search(r"dbscan_run_ms=([0-9.]+)", msg).group(1))
    kb = int(re.search(r"maxrss_kb=(\d+)", msg).group(1)) if timed else ru.ru_maxrss
    a = np.loadtxt(out, dtype=np.int64, ndmin=2)
    return ms, kb / 1024.0, msg, a[:, 0], a[:, 1].astype(bool)


def run_sklearn(npy, n_jobs, d):
    lab, core = os.path.join(d, "sk_labels.npy"), os.path.join(d, "sk_core.npy")
    p = subprocess.run([sys.executable, "-c", SKLEARN_CHILD, npy, str(EPS), str(MIN_POINTS), str(n_jobs), lab, core],
                       capture_output=True, text=True, check=True)
    t, rss = p.stdout.split()
    return float(t), int(rss) / 1024.0, np.load(lab), np.load(core)


def same_partition(x, labels, core, sk_labels, sk_core):
    """Empty string if equivalent, else what differs."""
    if not np.array_equal(core, sk_core):
        return f"core flags differ at {int((core != sk_core).sum())} points"
    if not np.array_equal(labels < 0, sk_labels < 0):
        return f"noise differs at {int(((labels < 0) != (sk_labels < 0)).sum())} points"
    ours, theirs = labels[core], sk_labels[core]
    pairs = set(zip(ours.tolist(), theirs.tolist()))
    if not len(pairs) == len(set(ours.tolist())) == len(set(theirs.tolist())):
        return "core partitions differ"
    from sklearn.neighbors import NearestNeighbors
    border = np.flatnonzero(~core & (labels >= 0))
    if len(border):
        core_idx = np.flatnonzero(core)
        nn = NearestNeighbors(radius=EPS).fit(x[core].astype(np.float64))
        for i, v in zip(border, nn.radius_neighbors(x[border].astype(np.float64), return_distance=False)):
            if labels[i] not in set(labels[core_idx[v]].tolist()):
                return f"border point {i} in a cluster out of reach"
    return ""


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", required=True)
    ap.add_argument("--sizes", default="10000,100000,1000000")
    ap.add_argument("--jobs", default="1,-1", help="scikit-learn n_jobs values to time")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--threads", type=int, default=0, help="dbscan threads (0: one per CPU)")
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    cli = find_cli(a.bin)
    jobs = [int(j) for j in a.jobs.split(",") if j]
    print(f"eps={EPS} min_points={MIN_POINTS} min_users=1, 100 m cube, 70% hotspots + 30% uniform noise, "
          f"threads={a.threads}, cpus={os.cpu_count()}")
    head = f"{'N':>9} {'ours ms':>9} {'ours MB':>8} {'clusters':>8} {'searches':>9}"
    for j in jobs:
        head += f" {'sk(j=%d) s' % j:>11} {'ratio':>6} {'sk MB':>7}"
    head += "  labels"
    rows, bad = [], 0
    for n in [int(s) for s in a.sizes.split(",")]:
        x = generate(n, a.seed)
        with tempfile.TemporaryDirectory() as d:
            inp, out, npy = os.path.join(d, "pts"), os.path.join(d, "out"), os.path.join(d, "pts.npy")
            write_points(inp, x)
            np.save(npy, x)
            best = None
            for _ in range(a.repeat):
                r = run_ours(cli, inp, out, a.threads)
                if best is None or r[0] < best[0]:
                    best = r
            ms, mb, msg, labels, core = best
            k = re.search(r"clusters=(\d+)", msg).group(1)
            s = re.search(r"searches=(\d+)", msg).group(1)
            row = f"{n:>9} {ms:>9.1f} {mb:>8.1f} {k:>8} {s:>9}"
            verdict = []
            for j in jobs:
                t, skmb, sk_labels, sk_core = run_sklearn(npy, j, d)
                row += f" {t:>11.2f} {t * 1000 / ms:>5.1f}x {skmb:>7.0f}"
                diff = same_partition(x, labels, core, sk_labels, sk_core)
                verdict.append(diff or "same")
                bad += bool(diff)
            row += "  " + ("identical" if all(v == "same" for v in verdict) else "; ".join(verdict))
        rows.append(row)
        print(row if len(rows) > 1 else head + "\n" + row, flush=True)
    if bad:
        print("LABELS DIFFER")
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
