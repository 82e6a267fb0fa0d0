"""Test harness: starts the real cvre-server on loopback and speaks the wire
protocol (protocol/PROTOCOL.md) from Python, or drives real cvre-client
processes and reads their JSON event lines."""
import argparse
import atexit
import json
import math
import os
import select
import shutil
import socket
import sqlite3
import struct
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone

MAGIC = 0x45525643
TEMP_DIRS = []  # removed when every test passed; kept (with server logs) otherwise
T = dict(HELLO=1, WELCOME=2, JOIN=3, JOIN_OK=4, MOVE=5, SNAPSHOT=6, AVATAR_JOINED=7,
         AVATAR_LEFT=8, ERROR=9, PING=10, PONG=11, BYE=12, AVATAR_POSE=13, UPLOAD_BEGIN=32, UPLOAD_CHUNK=33,
         UPLOAD_END=34, OBJECT_PLACE=35, OBJECT_REMOVE=37, OBJECT_INFO=38, OBJECT_REMOVED=39,
         OBJECT_REJECTED=40, MESH_REQUEST=41, MESH_CHUNK=42, COLLISION=48)
E = dict(FRAME_EMPTY=16, FRAME_TOO_LONG=17, UNKNOWN_TYPE=18, SHORT=19, TRAILING=20,
         BAD_STRING=21, NOT_FINITE=22, BAD_VALUE=23, BAD_MAGIC=24, VERSION=25, UNEXPECTED=26,
         ALREADY_JOINED=27, TRUNCATED=28, TIMEOUT=29, SERVER_FULL=30, BAD_SEQ=32, INTERNAL=34,
         UPLOAD=35, IMPORT=36, NO_OBJECT=37, NOT_OWNER=38, GUEST=39, AUTH=40, AUTH_REQUIRED=41,
         RATE_LIMITED=42, PLACEMENT=43, STALE_MESH=44)
PREJOIN_CAP = 256  # PROTO_MAX_LEN_PREJOIN
MODELS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "..", "shared", "models")


def args():
    p = argparse.ArgumentParser()
    p.add_argument("--bin", required=True, help="build directory with cvre-server and cvre-client")
    return p.parse_args()


def frame(t, payload=b""):
    return struct.pack("<IH", len(payload) + 2, t) + payload


def s8(text):
    b = text.encode()
    return bytes([len(b)]) + b


def hello(version=2, magic=MAGIC):
    return frame(T["HELLO"], struct.pack("<IH", magic, version))


def join(name, box=(0.6, 1.8, 0.6), password=None, token=None):
    """A join: a guest's, or an account's with its password (str) or a
    resume token (32 bytes from an earlier join_ok)."""
    tail = b""
    if password is not None:
        tail = bytes([1, len(password.encode())]) + password.encode()
    elif token is not None:
        tail = bytes([2, len(token)]) + token
    return frame(T["JOIN"], s8(name) + struct.pack("<3f", *box) + tail)


def move(seq, pos):
    return frame(T["MOVE"], struct.pack("<I3f", seq, *pos))


def ping(stamp):
    return frame(T["PING"], struct.pack("<Q", stamp))


def transform(pos, yaw=0.0, scale=1.0):
    return struct.pack("<3fff", *pos, yaw, scale)


def upload_frames(upload_id, data, name, fmt="", up=0, units=1.0, pos=(0, 0, 0), yaw=0.0, scale=1.0,
                  total=None, chunk=16384):
    """The frames of a whole upload: begin, chunks, end."""
    out = [frame(T["UPLOAD_BEGIN"], struct.pack("<II", upload_id, len(data) if total is None else total)
                 + s8(name) + s8(fmt) + struct.pack("<Bf", up, units))]
    for off in range(0, len(data), chunk):
        out.append(frame(T["UPLOAD_CHUNK"], struct.pack("<II", upload_id, off) + data[off:off + chunk]))
    out.append(frame(T["UPLOAD_END"], struct.pack("<I", upload_id) + transform(pos, yaw, scale)))
    return b"".join(out)


def upload(c, uid, data, name, **kw):
    """Uploads data as upload uid on c and returns the object message."""
    c.send(upload_frames(uid, data, name, **kw))
    return c.expect("object", timeout=30, where=lambda m: m["upload"] == uid)


def refused(c, request, code):
    """Expects request refused with code, and the connection still served."""
    m = c.expect("rejected", timeout=30, where=lambda m: m["request"] == request)
    assert m["code"] == code, m
    c.send(ping(request))  # the connection is still served
    c.expect("pong", where=lambda m: m["stamp"] == request)
    return m


def still_moving(w, seq):
    """A witness moves and gets its pong: nobody's trouble reached it."""
    w.send(move(seq, (0.01 * seq, 0, 0)) + ping(seq))
    w.expect("pong", where=lambda m: m["stamp"] == seq)


def refused_join(port, name, code, **cred):
    """Joins and expects an error with code, then the close; returns the
    error's message."""
    c = Raw(port)
    c.send(hello() + join(name, **cred))
    msgs = c.wait_closed(timeout=30)  # a password join costs an Argon2id hash
    errors = [m for m in msgs if m["type"] == "error"]
    assert errors and errors[0]["code"] == code, msgs
    assert not [m for m in msgs if m["type"] == "join_ok"], msgs
    return errors[0]["message"]


def decode(t, p):
    """One server-to-client message as a dict (enough for the tests)."""
    if t == T["WELCOME"]:
        v, sid = struct.unpack_from("<HQ", p)
        return dict(type="welcome", version=v, session=sid)
    if t == T["JOIN_OK"]:
        i, x, y, z = struct.unpack_from("<I3f", p)
        return dict(type="join_ok", id=i, pos=(x, y, z), token=p[28:60] if len(p) >= 60 else None)
    if t == T["SNAPSHOT"]:
        tick, ack, n = struct.unpack_from("<IIH", p)
        ents = {}
        for k in range(n):
            i, x, y, z = struct.unpack_from("<I3f", p, 10 + 16 * k)
            ents[i] = (x, y, z)
        return dict(type="snapshot", tick=tick, ack=ack, avatars=ents)
    if t == T["AVATAR_JOINED"]:
        i, ln = struct.unpack_from("<IB", p)
        return dict(type="joined", id=i, name=p[5:5 + ln].decode())
    if t == T["AVATAR_LEFT"]:
        i, r = struct.unpack_from("<IB", p)
        return dict(type="left", id=i, reason=r)
    if t == T["ERROR"]:
        code, ln = struct.unpack_from("<HB", p)
        return dict(type="error", code=code, message=p[3:3 + ln].decode())
    if t == T["AVATAR_POSE"]:
        return dict(type="pose", id=struct.unpack_from("<I", p)[0], pose=p[4:])
    if t == T["PONG"]:
        return dict(type="pong", stamp=struct.unpack_from("<Q", p)[0])
    if t == T["BYE"]:
        return dict(type="bye", reason=p[0])
    if t == T["OBJECT_INFO"]:
        oid, up = struct.unpack_from("<II", p)
        at = 8
        owner = p[at + 1:at + 1 + p[at]].decode()
        at += 1 + p[at]
        name = p[at + 1:at + 1 + p[at]].decode()
        at += 1 + p[at]
        x, y, z, yaw, scale, ver, tris = struct.unpack_from("<5fII", p, at)
        mesh = p[at + 28:at + 60]
        nb, = struct.unpack_from("<H", p, at + 60)
        at += 62
        boxes = [struct.unpack_from("<6f", p, at + 24 * i) for i in range(nb)]
        return dict(type="object", id=oid, upload=up, owner=owner, name=name, pos=(x, y, z), yaw=yaw,
                    scale=scale, ecm_version=ver, triangles=tris, mesh=mesh, boxes=boxes)
    if t == T["MESH_CHUNK"]:
        oid, total, offset = struct.unpack_from("<III", p)
        return dict(type="mesh_chunk", id=oid, total=total, offset=offset, data=p[12:])
    if t == T["OBJECT_REMOVED"]:
        return dict(type="object_removed", id=struct.unpack_from("<I", p)[0])
    if t == T["OBJECT_REJECTED"]:
        rid, code, ln = struct.unpack_from("<IHB", p)
        return dict(type="rejected", request=rid, code=code, message=p[7:7 + ln].decode())
    if t == T["COLLISION"]:
        oid, ver, box, inside = struct.unpack_from("<IIHB", p)
        point = struct.unpack_from("<3f", p, 11)
        normal = struct.unpack_from("<3f", p, 23)
        return dict(type="collision", object=oid, ecm_version=ver, box=box, inside=inside, point=point,
                    normal=normal)
    return dict(type="other", t=t)


def split_frames(buf):
    """The whole frames at the start of buf, decoded, and the bytes left."""
    out = []
    while len(buf) >= 6:
        ln, t = struct.unpack_from("<IH", buf)
        if len(buf) < 4 + ln:
            break
        out.append(decode(t, buf[6:4 + ln]))
        buf = buf[4 + ln:]
    return out, buf


def drain(s):
    """Everything the socket s receives until the server closes (or resets)
    it; then closes s."""
    buf = b""
    while True:
        try:
            d = s.recv(65536)
        except ConnectionResetError:
            break
        if not d:
            break
        buf += d
    s.close()
    return buf


def listening_port(proc, timeout=60):
    """The port in the first line of a starting cvre-server's stdout
    ("listening on 127.0.0.1:PORT"), waited for at most timeout seconds (a
    big world loads first). The line is read from the descriptor, not through
    proc.stdout's buffer, which stays empty for later reads."""
    fd, line, end = proc.stdout.fileno(), b"", time.time() + timeout
    while not line.endswith(b"\n"):
        left = end - time.time()
        assert left > 0 and select.select([fd], [], [], left)[0], f"no listening line within {timeout}s"
        c = os.read(fd, 1)
        assert c, f"the server exited before listening (exit {proc.wait(timeout)}), first line {line!r}"
        line += c
    line = line.decode()
    assert line.startswith("listening on 127.0.0.1:"), f"unexpected first line {line!r}"
    return int(line.rsplit(":", 1)[1])


class Server:
    """The real cvre-server on 127.0.0.1 and a free port, with a fresh
    database unless one is given."""

    def __init__(self, bindir, *extra, db=None):
        self.bindir = bindir
        self.tmp = tempfile.mkdtemp(prefix="cvre-it-")
        TEMP_DIRS.append(self.tmp)
        self.db = db or os.path.join(self.tmp, "cvre.db")
        self.log = open(os.path.join(self.tmp, "server.log"), "w+")
        self.proc = subprocess.Popen(
            [os.path.join(bindir, "cvre-server"), "--port", "0", "--db", self.db, *extra],
            stdout=subprocess.PIPE, stderr=self.log, text=True)
        atexit.register(self.proc.kill)  # a failed test must not leave it running
        self.port = listening_port(self.proc)

    def alive(self):
        return self.proc.poll() is None

    def stop(self, sig=15, timeout=10):
        self.proc.send_signal(sig)
        rc = self.proc.wait(timeout)
        rest = self.proc.stdout.read()
        assert rest == "", f"server printed more on stdout: {rest!r}"
        return rc

    def account(self, name, password=None, admin=False):
        """Adds an account with cvre-admin (the server may be running);
        returns its password (by default "pw-" + name)."""
        password = password or "pw-" + name
        p = subprocess.run([os.path.join(self.bindir, "cvre-admin"), "--db", self.db, "user", "add", name,
                            "--password-stdin"] + (["--admin"] if admin else []),
                           input=password + "\n", capture_output=True, text=True, timeout=60)
        assert p.returncode == 0, p
        return password

    def logtext(self):
        self.log.flush()
        self.log.seek(0)
        return self.log.read()


class Raw:
    """A hand-driven connection that sends exact bytes and decodes replies."""

    def __init__(self, port):
        self.s = socket.create_connection(("127.0.0.1", port), timeout=5)
        self.buf = b""
        self.queue = []  # received, not yet consumed by expect()
        self.closed = False

    def send(self, data):
        self.s.sendall(data)

    def handshake(self, name, password=None, token=None):
        self.send(hello() + join(name, password=password, token=token))
        w = self.expect("welcome")
        ok = self.expect("join_ok")
        return w, ok

    def poll(self, timeout, first=False):
        """Messages that arrive within timeout seconds; returns early on
        close, or as soon as any message is in when first is set."""
        out, end = [], time.time() + timeout
        while not self.closed:
            left = end - time.time()
            if left <= 0:
                break
            r, _, _ = select.select([self.s], [], [], left)
            if not r:
                break
            try:
                d = self.s.recv(65536)
            except ConnectionResetError:
                d = b""
            if not d:
                self.closed = True
                break
            out += self.frames(d)
            if first and out:
                break
        return out

    def frames(self, data):
        """The messages whole once data is added to what came before."""
        msgs, self.buf = split_frames(self.buf + data)
        return msgs

    def expect(self, kind, timeout=5, where=None):
        """Consumes messages in order until one of this kind (for which
        where(msg) holds, if given) arrives; earlier ones are dropped."""
        return self.collect(kind, timeout, where)[-1]

    def collect(self, kind, timeout=5, where=None):
        """As expect(), but returns every message consumed, the one
        expected last: a barrier (the pong to a ping, the snapshot that acks
        a move) after which everything sent before it has been read."""
        end = time.time() + timeout
        seen = []
        while True:
            while self.queue:
                m = self.queue.pop(0)
                seen.append(m)
                if m["type"] == kind and (where is None or where(m)):
                    return seen
            if time.time() >= end or self.closed:
                raise AssertionError(f"no {kind} within {timeout}s; saw {seen[-5:]}")
            self.queue += self.poll(min(0.2, end - time.time()), first=True)

    def wait_closed(self, timeout=5):
        end = time.time() + timeout
        msgs, self.queue = self.queue, []
        while not self.closed and time.time() < end:
            msgs += self.poll(0.2)
        assert self.closed, "server did not close the connection"
        return msgs

    def close(self):
        self.s.close()


class Client:
    """A real cvre-client process in script mode; its stdout is JSON lines.
    With script None its standard input stays open: the test gives it
    commands with send() as it goes, and waits for their effects with
    until()."""

    def __init__(self, bindir, port, name, script, *extra):
        self.proc = subprocess.Popen(
            [os.path.join(bindir, "cvre-client"), "--port", str(port), "--name", name, *extra],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        atexit.register(self.proc.kill)
        self.events = []
        self.partial = b""  # stdout read by until(), short of a newline
        if script is not None:
            try:
                self.send(script)
                self.proc.stdin.close()
            except BrokenPipeError:
                pass  # it ended before reading its script: wait() tells how
            self.proc.stdin = None  # so that communicate() does not touch it

    def send(self, text):
        self.proc.stdin.write(text)
        self.proc.stdin.flush()

    def take(self, data):
        lines = (self.partial + data).split(b"\n")
        self.partial = lines.pop()
        self.events += [json.loads(line) for line in lines]  # every line must be JSON

    def until(self, what, pred, timeout=30):
        """The first event (of all so far) for which pred holds, reading more
        as they come for at most timeout seconds; fails naming what."""
        fd, end, at = self.proc.stdout.fileno(), time.time() + timeout, 0
        while True:
            for e in self.events[at:]:
                if pred(e):
                    return e
            at = len(self.events)
            left = end - time.time()
            data = os.read(fd, 65536) if left > 0 and select.select([fd], [], [], left)[0] else b""
            assert data, f"{what}: not within {timeout}s (or the client ended); last events {self.events[-3:]}"
            self.take(data)

    def wait(self, timeout=30):
        if self.proc.stdin:
            self.proc.stdin.close()
            self.proc.stdin = None
        out, err = self.proc.communicate(timeout=timeout)
        self.stderr = err
        self.take(out.encode())
        assert self.partial == b"", f"a last line without its newline: {self.partial!r}"
        return self.proc.returncode

    def of(self, kind):
        return [e for e in self.events if e["event"] == kind]


def iso(t, digits=6):
    """cvre-admin's time form: Unix seconds as ISO-8601 UTC with 3 (table) or
    6 (CSV, JSON) decimals, rounded half away from zero as out.c's llround
    does (Python's round() goes half to even: t * 1e6 of a stored time is a
    multiple of 1/4, so the two differ on about one time in four)."""
    secs, frac = divmod(math.floor(t * 10 ** digits + 0.5), 10 ** digits)
    return datetime.fromtimestamp(secs, timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.") + f"{frac:0{digits}d}Z"


def admin(*argv, db=None, check=0, timeout=120):
    """Runs cvre-admin from --bin; returns (exit code, stdout, stderr), decoded
    from bytes so that CSV's \r\n survives. Asserts the exit code unless
    check is None."""
    cmd = [os.path.join(args().bin, "cvre-admin")] + (["--db", db] if db else []) + [str(a) for a in argv]
    p = subprocess.run(cmd, capture_output=True, timeout=timeout)
    out, err = p.stdout.decode(), p.stderr.decode()
    if check is not None:
        assert p.returncode == check, f"{argv}: exit {p.returncode}, stdout {out[:500]!r}, stderr {err!r}"
    return p.returncode, out, err


def copy_with_schema(src, dst, version):
    """Copies the database src to dst and stamps it with another schema
    version (PRAGMA user_version), for the tools' refusals."""
    shutil.copy(src, dst)
    db = sqlite3.connect(dst)
    db.execute(f"PRAGMA user_version = {version}")
    db.commit()
    db.close()


def close_to(a, b, tol=0.05):
    return all(abs(x - y) <= tol for x, y in zip(a, b))


def run(tests):
    """Runs test functions in order; prints one line each and the total."""
    failed = 0
    for t in tests:
        t0 = time.time()
        try:
            t()
            print(f"ok   {t.__name__} ({time.time() - t0:.1f}s)", flush=True)
        except Exception as e:  # report and go on with the next test
            failed += 1
            print(f"FAIL {t.__name__}: {type(e).__name__}: {e}", flush=True)
    print(f"{len(tests) - failed} passed, {failed} failed")
    if failed:
        print("server logs kept in: " + " ".join(TEMP_DIRS))
    else:
        for d in TEMP_DIRS:
            shutil.rmtree(d, ignore_errors=True)
    sys.exit(1 if failed else 0)
