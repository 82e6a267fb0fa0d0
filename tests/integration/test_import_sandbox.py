"""The isolated importer: a parser that crashes, spins, allocates without
end, answers too much or answers garbage ends in a clear error for its
uploader, while the server, a witness that keeps moving and the database
carry on. Needs a test build (-DCVRE_TEST_HOOKS=ON, as tools/test.sh
configures): only there does cvre-import honour its test-only inputs."""
import os
import sqlite3
import subprocess
import threading
import time

from harness import E, MODELS, Raw, Server, args, move, ping, refused, run, upload, upload_frames

A = args()
ROOM = os.path.join(MODELS, "openings", "openfoam_room_with_doorway.stl")


class Witness(threading.Thread):
    """A client that moves and pings every 50 ms and notes when each pong
    comes back; a gap in its pongs is an interruption others would feel."""

    def __init__(self, port):
        super().__init__(daemon=True)
        self.c = Raw(port)
        self.c.handshake("witness")
        self.stopping = threading.Event()
        self.sent, self.pongs = 0, []
        self.objects = []

    def take(self, msgs):
        for m in msgs:
            if m["type"] == "pong":
                self.pongs.append(time.time())
            elif m["type"] == "object":
                self.objects.append(m)

    def run(self):
        while not self.stopping.is_set():
            self.sent += 1
            self.c.send(move(self.sent, (0.01 * (self.sent % 100), 0, 0)) + ping(self.sent))
            self.take(self.c.poll(0.05))

    def finish(self, object_id):
        """Stops; waits for the last pongs and for object_id's info (it comes
        with a view update, in a later tick); returns the longest gap
        between pongs."""
        self.stopping.set()
        self.join(10)
        assert not self.is_alive(), "the witness is stuck"
        if len(self.pongs) < self.sent:
            self.take(self.c.collect("pong", 10, lambda m: m["stamp"] == self.sent))
        if object_id not in [o["id"] for o in self.objects]:
            self.take(self.c.collect("object", 10, lambda m: m["id"] == object_id))
        gaps = [b - a for a, b in zip(self.pongs, self.pongs[1:])]
        return max(gaps, default=0.0)


def test_misbehaving_parser_hurts_nobody():
    srv = Server(A.bin, "--max-triangles", "1000", "--import-cpu", "4", "--import-memory", "256")
    w = Witness(srv.port)
    w.start()
    c = Raw(srv.port)
    c.handshake("mallory", srv.account("mallory"))
    cases = ((1, b"crash", "parser crashed"), (2, b"loop", "timed out"), (3, b"alloc", "too large"),
             (4, b"flood", "too large"), (5, b"nan", "bad answer from the importer"))
    for uid, word, why in cases:
        c.send(upload_frames(uid, b"cvre-import-test:" + word, "evil.obj", fmt="obj"))
        m = refused(c, uid, E["IMPORT"])
        assert m["message"].startswith("import failed: ") and why in m["message"], (word, m)
        assert "File size" not in m["message"], m  # stderr (the server's log) stays writable
    good = upload(c, 6, open(ROOM, "rb").read(), "room.stl", fmt="stl", up=1)
    assert good["triangles"] == 54, good
    gap = w.finish(good["id"])
    assert w.sent > 20 and len(w.pongs) == w.sent, (w.sent, len(w.pongs))
    # a liveness check, not a speed one: a stalled loop would stop every pong
    assert gap < 3.0, f"the witness waited {gap:.2f} s for a pong"
    assert [o["id"] for o in w.objects] == [good["id"]], w.objects
    assert srv.alive()
    log = srv.logtext()
    assert "parser crashed" in log and "timed out" in log, log
    assert srv.stop() == 0
    db = sqlite3.connect(srv.db)
    assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    assert db.execute("SELECT count(*) FROM objects").fetchone()[0] == 1


def test_world_file_goes_through_the_importer_too():
    """A world file's model is parsed by the helper: with a helper that
    cannot run, the server refuses to start and says why."""
    tmp = Server(A.bin)  # only for its temporary directory
    tmp.stop()
    world = os.path.join(tmp.tmp, "one.world")
    with open(world, "w") as f:
        f.write(f"object {ROOM} up z at 0 0 0\n")
    p = subprocess.run([os.path.join(A.bin, "cvre-server"), "--port", "0", "--db", os.path.join(tmp.tmp, "w.db"),
                        "--world", world, "--importer", "/nonexistent/cvre-import"],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 1 and "cannot start the importer /nonexistent/cvre-import" in p.stderr, p.stderr
    srv = Server(A.bin, "--world", world)
    assert srv.stop() == 0
    assert sqlite3.connect(srv.db).execute("SELECT tri_count FROM objects").fetchone()[0] == 54


def test_helper_refuses_to_run_by_hand():
    """cvre-import answers --help, and a request that is not one fails."""
    helper = os.path.join(A.bin, "cvre-import")
    p = subprocess.run([helper, "--help"], capture_output=True, text=True, timeout=10)
    assert p.returncode == 0 and "usage: cvre-import" in p.stdout
    p = subprocess.run([helper], input=b"GET / HTTP/1.0\r\n\r\n", capture_output=True, timeout=10)
    assert p.returncode == 3 and p.stdout == b"", p
    p = subprocess.run([helper, "--memory", "0"], capture_output=True, text=True, timeout=10)
    assert p.returncode == 2 and "--memory" in p.stderr


run([test_misbehaving_parser_hurts_nobody, test_world_file_goes_through_the_importer_too,
     test_helper_refuses_to_run_by_hand])
