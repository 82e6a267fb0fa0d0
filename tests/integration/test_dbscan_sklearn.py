#!/usr/bin/python3
"""algo/cluster/dbscan.c against scikit-learn's DBSCAN and against an
independent Python computation of the documented rules, through dbscan_cli.

For each data set: core flags and noise must equal scikit-learn's exactly,
core points must be partitioned identically up to renaming of labels, and
every border point must be in a cluster with a core point within eps (any
such cluster is valid DBSCAN). The reference in this file then checks what
dbscan.h adds: the border point goes to its nearest core point (ties: lowest
index), clusters are numbered by their lowest core index, and min_users.

Usage: test_dbscan_sklearn.py --bin BUILD_DIR. Prints one line per test and
"N passed, M failed"; exits 1 if any failed. Needs Debian's python3-sklearn,
so it re-runs itself under /usr/bin/python3 when started by another python.

To check real collision points, call check_points(name, xyz, users, eps,
min_points, min_users) with an (n, 3) float32 array and n user ids.
"""
import os
import sys

try:
    import numpy as np
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components
    from sklearn.cluster import DBSCAN
    from sklearn.neighbors import NearestNeighbors
except ImportError:
    if sys.executable != "/usr/bin/python3" and os.path.exists("/usr/bin/python3"):
        os.execv("/usr/bin/python3", ["/usr/bin/python3"] + sys.argv)
    raise

import argparse
import atexit
import struct
import subprocess
import tempfile

from harness import listening_port

MAGIC = b"CVREPTS1"
RESULTS = []


def find_cli(build_dir):
    for rel in ("dbscan_cli", "tests/bench/dbscan_cli", "tests/dbscan_cli", "bin/dbscan_cli"):
        p = os.path.join(build_dir, rel)
        if os.access(p, os.X_OK):
            return p
    sys.exit(f"dbscan_cli not found under {build_dir}")


def write_points(path, xyz, users):
    """Binary format of dbscan_cli: exact float32 coordinates."""
    rec = np.zeros(len(xyz), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("u", "<u4")])
    rec["x"], rec["y"], rec["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    rec["u"] = users
    with open(path, "wb") as f:
        f.write(MAGIC + struct.pack("<Q", len(xyz)))
        f.write(rec.tobytes())


def run_cli(xyz, users, eps, min_points, min_users=1, threads=0, fmt="bin"):
    """Returns (labels, core flags, cluster summaries) from dbscan_cli."""
    with tempfile.TemporaryDirectory() as d:
        inp, out = os.path.join(d, "in"), os.path.join(d, "out")
        if fmt == "bin":
            write_points(inp, xyz, users)
        else:
            with open(inp, "w") as f:
                f.write("# x y z user\n")
                for (x, y, z), u in zip(xyz.tolist(), users.tolist()):
                    f.write(f"{x!r} {y!r} {z!r} {u}\n")
        cmd = [CLI, "--eps", repr(float(eps)), "--min-points", str(min_points),
               "--min-users", str(min_users), "--threads", str(threads), "--summary", inp, out]
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode != 0:
            raise AssertionError(f"dbscan_cli exit {p.returncode}: {p.stderr.strip()}")
        a = np.loadtxt(out, dtype=np.int64, ndmin=2) if len(xyz) else np.zeros((0, 2), np.int64)
        clusters = []
        for line in p.stderr.splitlines():
            if line.startswith("cluster "):
                f = dict(kv.split("=") for kv in line.split()[2:])
                clusters.append({"points": int(f["points"]), "users": int(f["users"])})
        return a[:, 0], a[:, 1].astype(bool), clusters


def reference(xyz, users, eps, min_points, min_users):
    """The rules of dbscan.h, computed independently (no grid, no FLANN)."""
    n = len(xyz)
    x = xyz.astype(np.float64)
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, bool), []
    nn = NearestNeighbors(radius=eps, algorithm="kd_tree").fit(x)
    nbrs = nn.radius_neighbors(x, return_distance=False)
    core = np.array([len(v) >= min_points for v in nbrs])
    rows, cols = [], []
    for i in np.flatnonzero(core):
        v = nbrs[i][core[nbrs[i]]]
        rows.extend([i] * len(v))
        cols.extend(v.tolist())
    g = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    _, comp = connected_components(g, directed=False)
    comps = sorted(set(comp[core].tolist()))
    members = {c: set() for c in comps}  # core points and every border point reached
    for i in range(n):
        if core[i]:
            members[comp[i]].add(i)
        else:
            for j in nbrs[i]:
                if core[j]:
                    members[comp[j]].add(i)
    ucount = {c: len({int(users[i]) for i in members[c]}) for c in comps}
    alive = [c for c in comps if ucount[c] >= min_users]
    first = {c: int(np.flatnonzero(core & (comp == c)).min()) for c in alive}
    alive.sort(key=lambda c: first[c])
    new_id = {c: k for k, c in enumerate(alive)}
    labels = np.full(n, -1, np.int64)
    for i in np.flatnonzero(core):
        labels[i] = new_id.get(comp[i], -1)
    for i in np.flatnonzero(~core):
        best = None
        for j in nbrs[i]:
            if core[j] and comp[j] in new_id:
                d = x[i] - x[j]
                key = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2], int(j))
                if best is None or key < best:
                    best = key
        if best is not None:
            labels[i] = new_id[comp[best[1]]]
    return labels, core, [ucount[c] for c in alive]


def check_points(name, xyz, users, eps, min_points, min_users=1, threads=0, fmt="bin"):
    """The hook for any point set (real collision logs later): runs every
    check and records one result line."""
    xyz = np.ascontiguousarray(xyz, dtype=np.float32)
    users = np.asarray(users, dtype=np.uint32)
    try:
        labels, core, clusters = run_cli(xyz, users, eps, min_points, min_users, threads, fmt)
        assert len(labels) == len(xyz), f"{len(labels)} labels for {len(xyz)} points"
        if min_users <= 1:
            compare_sklearn(xyz, labels, core, eps, min_points)
        want, want_core, want_users = reference(xyz, users, eps, min_points, min_users)
        assert np.array_equal(core, want_core), "core flags differ from the reference"
        bad = np.flatnonzero(labels != want)
        assert len(bad) == 0, f"{len(bad)} labels differ from the reference, first at {bad[:5].tolist()}: " \
                              f"{labels[bad[:5]].tolist()} != {want[bad[:5]].tolist()}"
        assert [c["users"] for c in clusters] == want_users, f"users {[c['users'] for c in clusters]} != {want_users}"
        sizes = np.bincount(labels[labels >= 0], minlength=len(clusters)) if len(clusters) else []
        assert [c["points"] for c in clusters] == list(sizes), "cluster sizes differ from the labels"
        k = len(clusters)
        RESULTS.append((True, f"ok   {name}: n={len(xyz)} clusters={k} noise={int((labels < 0).sum())} "
                              f"core={int(core.sum())}"))
    except AssertionError as e:
        RESULTS.append((False, f"FAIL {name}: {e}"))


def compare_sklearn(xyz, labels, core, eps, min_points):
    x = xyz.astype(np.float64)
    if len(x) == 0:
        return
    sk = DBSCAN(eps=eps, min_samples=min_points, algorithm="kd_tree").fit(x)
    sk_core = np.zeros(len(x), bool)
    sk_core[sk.core_sample_indices_] = True
    assert np.array_equal(core, sk_core), f"core flags differ at {np.flatnonzero(core != sk_core)[:10].tolist()}"
    noise, sk_noise = labels < 0, sk.labels_ < 0
    assert np.array_equal(noise, sk_noise), f"noise differs at {np.flatnonzero(noise != sk_noise)[:10].tolist()}"
    ours, theirs = labels[core], sk.labels_[core]
    pairs = set(zip(ours.tolist(), theirs.tolist()))
    assert len(pairs) == len(set(ours.tolist())) == len(set(theirs.tolist())), "core partitions differ"
    border = np.flatnonzero(~core & ~noise)
    if len(border):
        nn = NearestNeighbors(radius=eps, algorithm="kd_tree").fit(x[core])
        core_idx = np.flatnonzero(core)
        for i, v in zip(border, nn.radius_neighbors(x[border], return_distance=False)):
            assert labels[i] in set(labels[core_idx[v]].tolist()), f"border point {i} in a cluster out of reach"


def blobs(rng, centers, per, sigma, noise, cube):
    pts = [rng.normal(c, sigma, size=(per, 3)) for c in centers]
    pts.append(rng.uniform(0, cube, size=(noise, 3)))
    return np.concatenate(pts).astype(np.float32)


def real_log(build):
    """Collision points from a real log: the demo world (real models), a
    100-bot swarm walking around the spawn point for 4 s, the server stopped
    with SIGTERM. Returns {object: (object-local xyz, users)} for the objects
    hit at least 50 times in the current ECM version, and what the swarms
    before hit. The swarm walks at random and a busy machine sends fewer
    moves, so a short swarm can leave every object under 50 hits: then a
    fresh server and a longer swarm try again."""
    tried = []
    for seconds in (4, 8, 12):
        found, hits = swarm_log(build, seconds)
        if found:
            return found, tried
        tried.append(f"{seconds} s: {hits or 'nothing'}")
    return {}, tried


def swarm_log(build, seconds):
    import signal
    import sqlite3
    here = os.path.dirname(os.path.abspath(__file__))
    db = os.path.join(tempfile.mkdtemp(prefix="cvre-reallog-"), "log.db")
    srv = subprocess.Popen([os.path.join(build, "cvre-server"), "--port", "0", "--db", db, "--world",
                            os.path.join(here, "..", "..", "server", "worlds", "demo.world"), "--spawn-radius",
                            "25", "--log-level", "warn", "--max-per-address", "0", "--joins-per-second", "0"], stdout=subprocess.PIPE, text=True)
    atexit.register(srv.kill)  # a failed run must not leave it running
    port = str(listening_port(srv))
    subprocess.run([os.path.join(build, "cvre-client"), "--port", port, "--bots", "100", "--rate", "20",
                    "--duration", str(seconds)], stdout=subprocess.DEVNULL, timeout=60)
    srv.send_signal(signal.SIGTERM)
    srv.wait(30)
    con = sqlite3.connect(db)
    rows = con.execute("SELECT c.object_id, c.local_x, c.local_y, c.local_z, coalesce(c.user_id, 1000000 + c.session_id) "
                       "FROM collisions c JOIN objects o ON o.id = c.object_id AND o.ecm_version = c.ecm_version "
                       "ORDER BY c.id").fetchall()
    con.close()
    by = {}
    for oid, x, y, z, u in rows:
        by.setdefault(oid, ([], []))
        by[oid][0].append((x, y, z))
        by[oid][1].append(u)
    hits = {oid: len(p) for oid, (p, _) in by.items()}
    return {oid: (np.array(p, dtype=np.float32), np.array(u)) for oid, (p, u) in by.items() if len(p) >= 50}, hits


def main():
    global CLI
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", required=True, help="build directory holding dbscan_cli")
    build = ap.parse_args().bin
    CLI = find_cli(build)
    rng = np.random.default_rng(20240611)

    # Blobs plus uniform noise, collision-like scale, single and several threads.
    centers = rng.uniform(5, 45, size=(12, 3))
    x = blobs(rng, centers, 400, 0.6, 3000, 50)
    users = rng.integers(0, 50, len(x))
    check_points("blobs+noise eps=0.5 min=10", x, users, 0.5, 10)
    check_points("blobs+noise eps=0.5 min=10 threads=1", x, users, 0.5, 10, threads=1)
    check_points("blobs+noise eps=0.8 min=25", x, users, 0.8, 25)
    check_points("blobs+noise text input", x[:1500], users[:1500], 0.5, 10, fmt="text")
    # Larger and denser: many dense grid cells, several threads.
    x = blobs(rng, rng.uniform(5, 95, size=(40, 3)), 1500, 0.5, 20000, 100)
    check_points("60k dense blobs+noise eps=0.3 min=10", x, rng.integers(0, 100, len(x)), 0.3, 10)
    # One dense cluster.
    x = rng.normal(0, 0.3, size=(3000, 3)).astype(np.float32)
    check_points("single dense cluster", x, np.arange(len(x)), 0.5, 5)
    # All noise.
    x = rng.uniform(0, 100, size=(3000, 3)).astype(np.float32)
    check_points("all noise", x, np.zeros(len(x)), 0.5, 10)
    check_points("no points", np.zeros((0, 3), np.float32), np.zeros(0), 0.5, 10)
    # min_points = 1: every point is core, clusters are connected components.
    x = rng.uniform(0, 10, size=(2000, 3)).astype(np.float32)
    check_points("min_points=1", x, np.arange(len(x)), 0.4, 1)
    # Duplicates: 80 sites with 1..12 copies each, some sites close together.
    sites = rng.uniform(0, 5, size=(80, 3))
    x = np.repeat(sites, rng.integers(1, 13, 80), axis=0).astype(np.float32)
    check_points("duplicate points", x, rng.integers(0, 5, len(x)), 0.3, 6)
    # Integer lattice with holes, eps exactly 1.0: neighbours at distance
    # exactly eps count (sklearn and dbscan.h both use <=).
    g = np.stack(np.meshgrid(*[np.arange(14)] * 3, indexing="ij"), -1).reshape(-1, 3)
    for keep, mp in ((0.55, 4), (0.45, 3), (0.7, 6), (0.3, 2)):
        x = g[rng.random(len(g)) < keep].astype(np.float32)
        check_points(f"lattice eps=1.0 keep={keep} min={mp}", x, np.arange(len(x)), 1.0, mp)
    # Far from the origin, where float spacing is coarse: distances are still
    # exact multiples of eps (1e6 has float spacing 0.0625).
    x = g[rng.random(len(g)) < 0.5].astype(np.float64)
    check_points("lattice at 1e4, eps=1.0", (x + 1e4).astype(np.float32), np.arange(len(x)), 1.0, 4)
    check_points("lattice at 1e6, eps=0.0625", (x * 0.0625 + 1e6).astype(np.float32), np.arange(len(x)),
                 0.0625, 4)
    # Chains at exactly eps and border points between two clusters.
    x = np.array([[i, 0, 0] for i in range(10)] + [[i, 2, 0] for i in range(10)] + [[4, 1, 0], [5, 1, 0]],
                 np.float32)
    check_points("two lattice rows joined by a bridge", x, np.arange(len(x)), 1.0, 3)
    check_points("two lattice rows, border points between", x, np.arange(len(x)), 1.0, 4)
    # Border points equidistant from two clusters (ties go to the lower index).
    x = rng.integers(0, 30, size=(4000, 3)).astype(np.float32) * 0.5
    check_points("half-metre lattice samples (ties)", x, np.arange(len(x)), 1.0, 9)
    # min_users against the reference: blobs by 1, 2, 3 and 8 users, nearby so
    # that border points are shared between surviving and dropped clusters.
    parts, us = [], []
    for k, nu in enumerate((1, 2, 3, 8, 1, 3)):
        c = np.array([k * 3.2, 0, 0])
        parts.append(rng.normal(c, 0.5, size=(300, 3)))
        us.append(rng.integers(0, nu, 300) + 100 * k)
    parts.append(rng.uniform(-2, 18, size=(500, 3)))
    us.append(rng.integers(0, 1000, 500))
    x, users = np.concatenate(parts).astype(np.float32), np.concatenate(us)
    for mu in (2, 3, 4, 10):
        check_points(f"min_users={mu}", x, users, 0.5, 8, min_users=mu)
    check_points("min_users=4, every point its own user", x, np.arange(len(x)), 0.5, 8, min_users=4)

    # Points from a real collision log, one object at a time.
    real, tried = real_log(build)
    if not real:
        RESULTS.append((False, "FAIL real collision log: no object was hit 50 times; hits per object after "
                        + "; ".join(tried)))
    for oid, (x, users) in sorted(real.items()):
        check_points(f"real collision log, object {oid} ({len(x)} points)", x, users, 0.3, 5)
        check_points(f"real collision log, object {oid}, min_users=3", x, users, 0.3, 5, min_users=3)

    for ok, line in RESULTS:
        print(line)
    failed = sum(1 for ok, _ in RESULTS if not ok)
    print(f"{len(RESULTS) - failed} passed, {failed} failed")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
