"""The clustering command lines at their edges: cvre-cluster's time windows
in every form (those cvre-admin prints and takes among them), its object filter against a world with objects, the --apply
options, its progress line on a terminal and its limits; dbscan_cli's
flags and every malformed input, in both of its formats, refused with its
exit code and a message."""
import os
import pty
import sqlite3
import struct
import subprocess
import tempfile

from harness import TEMP_DIRS, Server, args, run

A = args()
CLUSTER = os.path.join(A.bin, "cvre-cluster")
CLI = os.path.join(A.bin, "dbscan_cli")
WORLD = os.path.join(os.path.dirname(os.path.abspath(__file__)), "room.world")
TMP = tempfile.mkdtemp(prefix="cvre-cluster-tools-")
TEMP_DIRS.append(TMP)


def world_db():
    """A database holding the room (object 1) and no collisions."""
    srv = Server(A.bin, "--world", WORLD, db=os.path.join(TMP, "room.db"))
    assert srv.stop() == 0
    return srv.db


def cluster(db, *flags, stderr=subprocess.PIPE):
    p = subprocess.run([CLUSTER, "--db", db, *flags], stdout=subprocess.PIPE, stderr=stderr, text=True, timeout=120)
    return p.returncode, p.stdout, p.stderr


def test_cluster_windows_objects_and_apply():
    db = world_db()
    rc, out, err = cluster(db, "--object", "1", "--object", "99", "--since", "2020-01-01T00:00:00",
                           "--until", "4102444800", "--json")
    assert rc == 0, err
    assert "no object 99 in the world; skipped" in err, err
    assert out.startswith('{"run":') and '"objects":1,"points":0,"clusters":[]' in out, out
    rc, out, err = cluster(db, "--object", "99")  # names only an absent object: none clustered
    assert rc == 0 and "0 objects, 0 collisions" in out, (out, err)
    rc, out, err = cluster(db, "--apply", "--depth", "5", "--max-boxes", "16", "--max-empty", "0.5", "--threads", "1",
                           "--json")
    assert rc == 0 and '"refined":[]' in out, (out, err)  # no clusters: nothing refined


def test_cluster_time_forms():
    """Every form cvre-admin prints or takes, and those cvre-cluster took
    before, give the window the run records (since, until)."""
    db = world_db()
    t = 1796146800.0  # 2026-12-01T17:40:00Z
    for since, until, want in (
            ("2026-12-01T17:40:00Z", "2026-12-01T17:40:00.250000Z", (t, t + 0.25)),  # cvre-admin's CSV/JSON
            ("2026-12-01T17:40:00.000Z", "2026-12-01T18:40:00+01:00", (t, t)),  # its table; a zone
            ("2026-12-01T17:40:00", "1796146800.5", (t, t + 0.5)),  # the forms cvre-cluster took before
            ("2026-12-1T17:40:0", "2026-12-01 17:41", (t, t + 60)),
            ("2026-12-01", "2026-12-01T12:40:00-0500", (t - 63600, t))):
        rc, out, err = cluster(db, "--since", since, "--until", until, "--json")
        assert rc == 0 and out.startswith('{"run":'), (since, until, out, err)
        c = sqlite3.connect(db)
        got = c.execute("SELECT since, until FROM cluster_runs ORDER BY id DESC LIMIT 1").fetchone()
        c.close()
        assert got == want, (since, until, got, want)


def test_cluster_progress_on_a_terminal():
    db = world_db()
    master, slave = pty.openpty()
    try:
        rc, out, _ = cluster(db, stderr=slave)
        os.close(slave)
        slave = -1
        seen = b""
        while True:
            try:
                chunk = os.read(master, 4096)
            except OSError:  # the terminal's other side closed: all is read
                break
            if not chunk:
                break
            seen += chunk
    finally:
        if slave >= 0:
            os.close(slave)
        os.close(master)
    assert rc == 0, out
    assert b"cvre-cluster: 1/1 objects, 0 collisions, 0 clusters" in seen, seen


def test_cluster_refusals():
    db = world_db()
    many = []
    for i in range(257):
        many += ["--object", str(i + 1)]
    for flags, words in ((many, "too many --object flags (256 at most)"),
                         (["--since", "yesterday"], "a time is Unix seconds or ISO 8601 (2026-12-01T17:40:00Z"),
                         (["--since", "2026-02-30T00:00:00Z"], "a time is Unix seconds or ISO 8601"),
                         (["--until", "inf"], "a time is Unix seconds"),
                         (["--depth", "9"], "--depth wants a whole number from 2 to 8"),
                         (["--max-boxes", "0"], "--max-boxes wants a whole number from 1 to 1024"),
                         (["--max-empty", "2"], "--max-empty wants a share from 0 to 1"),
                         (["--threads", "17"], "--threads wants a whole number from 0 to 16"),
                         (["--eps", "0"], "--eps wants a distance in metres above 0"),
                         (["--no-such-flag"], "try --help")):
        rc, out, err = cluster(db, *flags)
        assert rc == 2 and words in err and out == "", (flags[:4], rc, err)
    rc, _, err = cluster(os.path.join(TMP, "none.db"))
    assert rc == 3 and "none.db: No such file or directory" in err, err


def points_file(name, data, mode="w"):
    path = os.path.join(TMP, name)
    with open(path, mode) as f:
        f.write(data)
    return path


def cli(*argv):
    p = subprocess.run([CLI, *argv], capture_output=True, text=True, timeout=60)
    return p.returncode, p.stdout, p.stderr


def binary(records, count=None, tail=b""):
    head = b"CVREPTS1" + struct.pack("<Q", len(records) if count is None else count)
    return head + b"".join(struct.pack("<3fI", *r) for r in records) + tail


def test_dbscan_cli_flags():
    good = points_file("good.txt", "# three points of two users\n\n0 0 0 1\n0.1 0 0 2\n\t0 0.1 0 1\n")
    rc, out, err = cli("--eps", "0.5", "--min-points", "2", "--min-users", "2", "--threads", "1", "--summary", good)
    assert rc == 0, err
    assert out.split("\n")[:3] == ["0 1", "0 1", "0 1"], out
    assert "clusters=1" in err and "cluster 0 points=3 users=2" in err, err
    rc, out, err = cli("--min-users", "3", good)  # two users are too few
    assert rc == 0 and out.split("\n")[:3] == ["-1 0", "-1 0", "-1 0"], out
    for argv in (["--eps", "x", good], ["--min-points", "-1", good], ["--min-users", "4294967296", good],
                 ["--threads", "", good], ["--bogus", good], [good, "out", "extra"], [], ["--eps"]):
        rc, _, err = cli(*argv)
        assert rc == 2 and err.startswith("usage: dbscan_cli"), (argv, rc, err)
    rc, _, err = cli("--eps", "-1", good)  # parsed, then refused by dbscan_run
    assert rc == 1 and "dbscan_cli: dbscan_run: Invalid argument" in err, err
    rc, _, err = cli(good, TMP)  # OUT a folder
    assert rc == 1 and "Is a directory" in err, err
    rc, _, err = cli(good, "/dev/full")
    assert rc == 1 and "dbscan_cli: write failed" in err, err


def test_dbscan_cli_bad_inputs():
    rc, _, err = cli(os.path.join(TMP, "missing.txt"))
    assert rc == 1 and "missing.txt: No such file or directory" in err, err
    for name, text, line in (("words.txt", "0 0 0 1\nzero 0 0 1\n", 2),
                             ("short.txt", "0 0 0\n", 1),
                             ("extra.txt", "0 0 0 1 5\n", 1),
                             ("user.txt", "0 0 0 4294967296\n", 1),
                             ("long.txt", "0 0 0 1" + " " * 600 + "\n", 1)):
        rc, _, err = cli(points_file(name, text))
        assert rc == 1 and f"{name}:{line}: bad line" in err, (name, err)
    pts = [(0, 0, 0, 1), (0.1, 0, 0, 2)]
    rc, out, err = cli(points_file("good.bin", binary(pts), "wb"))
    assert rc == 0 and len(out.split("\n")) == 3, (out, err)
    for name, data in (("head.bin", b"CVREPTS1\x02\x00"),                   # the count cut short
                       ("huge.bin", binary([], count=(1 << 30) + 1)),       # over DBSCAN_MAX_POINTS
                       ("cut.bin", binary(pts, count=3)),                   # a record missing
                       ("trail.bin", binary(pts, tail=b"\x00"))):           # a byte after the last
        rc, _, err = cli(points_file(name, data, "wb"))
        assert rc == 1 and f"{name}: Invalid argument" in err, (name, err)


run([test_cluster_windows_objects_and_apply, test_cluster_time_forms, test_cluster_progress_on_a_terminal,
     test_cluster_refusals, test_dbscan_cli_flags, test_dbscan_cli_bad_inputs])
