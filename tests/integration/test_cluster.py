"""cvre-cluster on a real collision log: users bumping into the same spot of
a wall make a cluster that names the wall's box; fewer users than min_users
make none; the job runs beside a writing server, is deterministic, and
refuses bad parameters and unusable databases with clear exit codes."""
import json
import os
import sqlite3
import subprocess
import time

from harness import Raw, Server, args, close_to, copy_with_schema, move, run

A = args()
WORLD = os.path.join(os.path.dirname(os.path.abspath(__file__)), "room.world")


def job(db, *flags):
    p = subprocess.run([os.path.join(A.bin, "cvre-cluster"), "--db", db, *flags], capture_output=True, text=True,
                       timeout=60)
    return p.returncode, p.stdout, p.stderr


def bump(srv, names, seconds):
    """Each user walks east into the room's west wall (x = 4.358) from the origin."""
    cs = []
    for n in names:
        c = Raw(srv.port)
        c.handshake(n)
        cs.append(c)
    end, seq = time.time() + seconds, 0
    while time.time() < end:
        seq += 1
        for c in cs:
            c.send(move(seq, (20, 0, 0)))
        time.sleep(0.05)
    return cs


def test_cluster_of_many_users_not_of_few():
    srv = Server(A.bin, "--world", WORLD, "--spawn-radius", "0", "--max-speed", "20")
    cs = bump(srv, ["u1", "u2", "u3", "u4"], 2.0)
    # While the server is still writing, the job runs without "database is locked".
    rc, out, err = job(srv.db, "--json", "--min-users", "3", "--min-points", "5", "--eps", "0.5")
    assert rc == 0, err
    live = json.loads(out)
    for c in cs:
        c.close()
    assert srv.stop() == 0
    assert len(live["clusters"]) == 1, live
    c = live["clusters"][0]
    assert c["users"] == 4 and c["box"] == 0 and c["ecm_version"] == 1, c
    # Object-local: the room sits at x = 10, so the wall's face is at 4.358 - 10.
    assert close_to(c["centroid"], (4.35757 - 10, 0.9, 0.0), 0.05), c
    rc, out, _ = job(srv.db, "--json", "--min-users", "5", "--min-points", "5")
    assert rc == 0 and json.loads(out)["clusters"] == [], out
    # Twice in a row on the same data: the same clusters.
    a = json.loads(job(srv.db, "--json", "--min-users", "3", "--min-points", "5")[1])
    b = json.loads(job(srv.db, "--json", "--min-users", "3", "--min-points", "5")[1])
    assert a["clusters"] == b["clusters"] and b["run"] == a["run"] + 1
    db = sqlite3.connect(srv.db)
    runs = db.execute("SELECT count(*), sum(clusters) FROM cluster_runs").fetchone()
    assert runs[0] == 4 and runs[1] == 3, runs
    row = db.execute("SELECT object_id, box_index, users FROM clusters WHERE run_id = ?", (a["run"],)).fetchone()
    assert row == (c["object"], 0, 4), row
    shown = subprocess.run([os.path.join(A.bin, "cvre-admin"), "--db", srv.db, "--json", "clusters"],
                           capture_output=True, text=True, timeout=30)
    assert shown.returncode == 0, shown.stderr
    rows = json.loads(shown.stdout)
    assert len(rows) == 1 and rows[0]["run"] == b["run"] and rows[0]["box"] == 0 and rows[0]["users"] == 4, rows


def test_bad_parameters_and_databases():
    srv = Server(A.bin)
    assert srv.stop() == 0
    for flags in (("--eps", "0"), ("--eps", "-1"), ("--eps", "nan"), ("--min-points", "0"),
                  ("--min-users", "x"), ("--since", "yesterday"), ("--object", "0"), ("extra",)):
        rc, _, err = job(srv.db, *flags)
        assert rc == 2 and "try --help" in err, (flags, rc, err)
    rc, _, err = job(os.path.join(srv.tmp, "missing.db"))
    assert rc == 3 and "No such file" in err, err
    other = os.path.join(srv.tmp, "other.db")
    copy_with_schema(srv.db, other, 99)
    rc, _, err = job(other)
    assert rc == 3 and "schema version 99" in err, err
    # An object that does not exist, and a world without collisions: done, nothing found.
    rc, out, err = job(srv.db, "--object", "12345")
    assert rc == 0 and "0 clusters" in out and "no object 12345" in err, (out, err)


run([test_cluster_of_many_users_not_of_few, test_bad_parameters_and_databases])
