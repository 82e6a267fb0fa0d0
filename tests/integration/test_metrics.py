"""The Prometheus endpoint (--metrics) on the real server: every line of a
scrape in the text format; the figures move as the game does (joins,
moves and dropped moves, bytes, collisions and the collision log, imports,
refinement rounds and collision maps written and published, errors by
code) and never go back, also across stats intervals; bad requests get
their status, slow and surplus connections are cut off, and the game's
clients notice nothing of it."""
import os
import re
import socket
import sqlite3
import struct
import subprocess
import time

from harness import E, T, Raw, Server, args, drain, frame, hello, join, move, ping, run, still_moving, upload_frames

A = args()
HERE = os.path.dirname(os.path.abspath(__file__))
ROOM_WORLD = os.path.join(HERE, "room.world")
# The doorway room of room.world: its door in the east wall (test_refine.py).
DOOR_X, DOOR_Z = 10.218, -1.965
NAME = r"[a-zA-Z_:][a-zA-Z0-9_:]*"
LABELS = rf'\{{{NAME}="(?:[^"\\\n]|\\[\\"n])*"(?:,{NAME}="(?:[^"\\\n]|\\[\\"n])*")*\}}'
SAMPLE = re.compile(rf"({NAME})({LABELS})? (\S+)$")
HEAD_MAX, URL_MAX, HEADERS_MAX = 8192, 2048, 32  # server/net/http.h
REQUEST_TIMEOUT, CONNS = 5.0, 16                # server/net/http_server.h


class Counting(Raw):
    """A game connection that counts the bytes it sends."""
    sent = 0

    def send(self, data):
        Counting.sent += len(data)
        super().send(data)


def metrics_port(srv):
    m = re.search(r"metrics on http://127\.0\.0\.1:(\d+)/metrics", srv.logtext())
    assert m, srv.logtext()[-2000:]
    return int(m.group(1))


def http(port, data, timeout=30):
    """Sends data on a new connection and reads until the server closes it;
    returns (status, headers, body). Every answer closes its connection."""
    s = socket.create_connection(("127.0.0.1", port), timeout=timeout)
    s.sendall(data)
    buf = drain(s)
    head, sep, body = buf.partition(b"\r\n\r\n")
    assert sep, buf[:200]
    lines = head.decode().split("\r\n")
    assert re.match(r"HTTP/1\.1 \d\d\d [A-Za-z -]+$", lines[0]), lines[0]
    headers = {k.lower(): v.strip() for k, v in (l.split(":", 1) for l in lines[1:])}
    assert headers["connection"] == "close" and int(headers["content-length"]) == len(body), headers
    return int(lines[0].split()[1]), headers, body


def get(port, path="/metrics"):
    return http(port, f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUser-Agent: test\r\n\r\n".encode())


def parse(text):
    """Every line as the text format defines it. Returns {series: value}
    and {family: type}."""
    assert text.endswith("\n")
    values, types, family, helped = {}, {}, None, set()
    for line in text[:-1].split("\n"):
        if line.startswith("# HELP "):
            name, _, help_ = line[7:].partition(" ")
            assert re.fullmatch(NAME, name) and help_ and name not in helped, line
            helped.add(name)
            family = name
        elif line.startswith("# TYPE "):
            name, _, kind = line[7:].partition(" ")
            assert name == family and name not in types and kind in ("counter", "gauge", "histogram"), line
            assert kind != "counter" or name.endswith("_total"), line
            types[name] = kind
        else:
            m = SAMPLE.match(line)
            assert m, line
            name = m.group(1)
            base = re.sub(r"_(bucket|sum|count)$", "", name) if types.get(family) == "histogram" else name
            assert base == family, (line, family)
            series = name + (m.group(2) or "")
            assert series not in values, line
            values[series] = float(m.group(3))
    b = [(float(le), v) for s, v in values.items() for le in re.findall(r'le="([^"]+)"', s)]
    assert b and [v for _, v in sorted(b)] == sorted(v for _, v in b), b  # cumulative
    assert values['cvre_tick_duration_seconds_bucket{le="+Inf"}'] == values["cvre_tick_duration_seconds_count"]
    return values, types


def scrape(port):
    status, headers, body = get(port)
    assert status == 200 and headers["content-type"] == "text/plain; version=0.0.4; charset=utf-8", headers
    return parse(body.decode())


class Scrapes:
    """Scrapes that check every counter against the last scrape: never less."""

    def __init__(self, port):
        self.port, self.last = port, None

    def __call__(self):
        values, types = scrape(self.port)
        if self.last:
            for s, v in self.last.items():
                if types.get(s.split("{")[0]) == "counter":
                    assert values[s] >= v, (s, v, values[s])
        self.last = values
        return values

    def until(self, ok, timeout=30, what="condition"):
        end = time.time() + timeout
        while True:
            v = self()
            if ok(v):
                return v
            assert time.time() < end, f"no {what} within {timeout}s"
            time.sleep(0.1)


def by_code(values, family, code):
    hits = [v for s, v in values.items() if s.startswith(f'{family}{{code="{code}",')]
    assert len(hits) == 1, (family, code)
    return hits[0]


def test_flag_and_help():
    server = os.path.join(A.bin, "cvre-server")
    out = subprocess.run([server, "--help"], capture_output=True, text=True, timeout=30).stdout
    assert "--metrics HOST:PORT" in out
    for bad in ("nope", "127.0.0.1", ":9100", "[::1", "[]:9100", "127.0.0.1:99999", "127.0.0.1:x"):
        p = subprocess.run([server, "--metrics", bad, "--db", "/nonexistent/x.db"], capture_output=True, text=True,
                           timeout=30)
        assert p.returncode == 2 and "--metrics" in p.stderr, (bad, p.returncode, p.stderr)
    # Off by default; a port in use is a clear error at start.
    srv = Server(A.bin)
    assert "metrics on" not in srv.logtext()
    p = subprocess.run([server, "--port", "0", "--db", os.path.join(srv.tmp, "other.db"), "--metrics",
                        f"127.0.0.1:{srv.port}"], capture_output=True, text=True, timeout=60)
    assert p.returncode == 1 and "metrics: cannot listen on 127.0.0.1" in p.stderr, p.stderr
    assert srv.stop() == 0


def test_figures_follow_the_game():
    srv = Server(A.bin, "--metrics", "127.0.0.1:0", "--world", ROOM_WORLD, "--refine-interval", "1",
                 "--refine-min-points", "5", "--spawn-radius", "0", "--max-speed", "20", "--stats-interval", "0.5",
                 "--handshake-timeout", "3000")
    port = metrics_port(srv)
    m = Scrapes(port)
    v0 = m()
    assert v0["cvre_clients"] == 0 and v0["cvre_connections_total"] == 0 and v0["cvre_objects"] == 1, v0
    assert v0["cvre_ticks_total"] == v0["cvre_tick_duration_seconds_count"]
    assert by_code(v0, "cvre_protocol_errors_total", E["UNEXPECTED"]) == 0

    # Four users join and walk into the doorway from the east: the room's
    # single box stops them, so they collide on every tick.
    users = [Counting(srv.port) for _ in range(4)]
    for i, c in enumerate(users):
        c.handshake(f"u{i}")
    seq, moves = 0, 0
    for target, seconds in (((0, 0, 3), 0.5), ((14, 0, 3), 1.0), ((14, 0, DOOR_Z), 0.6), ((5, 0, DOOR_Z), 1.5)):
        end = time.time() + seconds
        while time.time() < end:
            seq += 1
            for c in users:
                c.send(move(seq, target))
                moves += 1
            time.sleep(0.05)
    for c in users:  # everything sent so far is handled once its pong is back
        c.send(ping(seq))
        c.expect("pong", where=lambda msg: msg["stamp"] == seq)
    v1 = m()
    assert v1["cvre_connections_total"] == 4 and v1["cvre_clients"] == 4 and v1["cvre_avatars"] == 4, v1
    assert v1["cvre_moves_total"] == moves and v1["cvre_moves_dropped_total"] == 0, (moves, v1["cvre_moves_total"])
    assert v1["cvre_received_bytes_total"] == Counting.sent, (Counting.sent, v1["cvre_received_bytes_total"])
    assert v1["cvre_frames_received_total"] == 4 * 3 + moves  # hello, join, ping, and the moves
    assert v1["cvre_sent_bytes_total"] > v0["cvre_sent_bytes_total"]
    assert v1["cvre_ticks_total"] > v0["cvre_ticks_total"]
    assert v1["cvre_ticks_total"] == v1["cvre_tick_duration_seconds_count"]
    assert v1["cvre_collisions_total"] > 0, v1
    # Every contact is logged: the writer commits them all within its batch time.
    v2 = m.until(lambda v: v['cvre_collision_log_rows_total{outcome="written"}'] >= v1["cvre_collisions_total"],
                 what="collision rows written")
    for outcome in ("dropped", "invalid", "lost"):
        assert v2[f'cvre_collision_log_rows_total{{outcome="{outcome}"}}'] == 0, v2
    assert v2["cvre_collision_log_write_failures_total"] == 0
    # The online loop clusters them and refines the room (stored and
    # published), and keeps counting its rounds.
    v3 = m.until(lambda v: v["cvre_collision_maps_written_total"] >= 1 and v["cvre_collision_maps_published_total"] >= 1,
                 timeout=60, what="refined collision map")
    assert v3["cvre_refine_rounds_total"] >= 1
    written = v3["cvre_collision_maps_written_total"]
    # A version another process stores is published, not written here.
    room = sqlite3.connect(srv.db).execute("SELECT id FROM objects WHERE name = ?",
                                           ("openfoam_room_with_doorway.stl",)).fetchone()[0]
    p = subprocess.run([os.path.join(A.bin, "cvre-admin"), "--db", srv.db, "rollback", str(room), "1"],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    v4 = m.until(lambda v: v["cvre_collision_maps_published_total"] >= v3["cvre_collision_maps_published_total"] + 1,
                 what="rollback published")
    assert v4["cvre_collision_maps_written_total"] >= written

    # Dropped moves: a fresh client sends 50 moves at once; 40 (twice the
    # tick rate) are taken in its first second, 10 dropped.
    burst = Raw(srv.port)
    burst.handshake("burst")
    burst.send(b"".join(move(k, (0, 0, 0)) for k in range(1, 51)) + ping(1))
    burst.expect("pong")
    v5 = m()
    assert v5["cvre_moves_dropped_total"] == 10 and v5["cvre_moves_total"] == v4["cvre_moves_total"] + 50, v5

    # Errors by code: a ping before hello, a handshake that never comes.
    bad = Raw(srv.port)
    bad.send(ping(1))
    assert [x for x in bad.wait_closed() if x["type"] == "error"][0]["code"] == E["UNEXPECTED"]
    silent = Raw(srv.port)
    assert [x for x in silent.wait_closed(timeout=30) if x["type"] == "error"][0]["code"] == E["TIMEOUT"]
    v6 = m()
    assert by_code(v6, "cvre_protocol_errors_total", E["UNEXPECTED"]) == 1
    assert by_code(v6, "cvre_protocol_errors_total", E["TIMEOUT"]) == 1
    assert v6["cvre_timeouts_total"] == 1 and v6["cvre_connections_total"] == 7

    # Imports: one good, one not a model; a guest may not remove an object.
    pw = srv.account("owner")
    owner = Raw(srv.port)
    owner.handshake("owner", pw)
    tri = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
    owner.send(upload_frames(1, tri, "tri.obj", fmt="obj", pos=(30, 0, 30)))
    owner.expect("object", timeout=60, where=lambda msg: msg["upload"] == 1)
    owner.send(upload_frames(2, b"this is not a model\n" * 10, "junk.obj", fmt="obj"))
    assert owner.expect("rejected", timeout=60, where=lambda msg: msg["request"] == 2)["code"] == E["IMPORT"]
    users[0].send(frame(T["OBJECT_REMOVE"], struct.pack("<I", room)))
    assert users[0].expect("rejected", where=lambda msg: msg["request"] == room)["code"] == E["GUEST"]
    v7 = m()
    assert v7['cvre_imports_total{result="ok"}'] == 1 and v7['cvre_imports_total{result="failed"}'] == 1, v7
    assert by_code(v7, "cvre_requests_rejected_total", E["IMPORT"]) == 1
    assert by_code(v7, "cvre_requests_rejected_total", E["GUEST"]) == 1
    assert v7["cvre_objects"] == 2

    # Leaving: the gauges come down, the counters stay.
    for c in users + [burst, owner]:
        c.close()
    v8 = m.until(lambda v: v["cvre_clients"] == 0, what="clients gone")
    assert v8["cvre_avatars"] == 0 and v8["cvre_connections_total"] == 8
    # Stats intervals (0.5 s) went by all along and reset nothing; the
    # server's last line counts every connection it served.
    assert srv.logtext().count("stats: clients=") >= 2
    assert srv.stop() == 0
    assert "stopped: 8 connections served" in srv.logtext(), srv.logtext()[-500:]


def test_slow_peers_and_bad_requests_leave_the_game_alone():
    srv = Server(A.bin, "--metrics", "127.0.0.1:0")
    port = metrics_port(srv)
    w = Raw(srv.port)
    w.handshake("witness")
    seq = [0]

    def witness():
        seq[0] += 1
        still_moving(w, seq[0])

    # Slow peers, on an endpoint nobody used yet: one sends half a request,
    # one drips a byte at a time, CONNS - 2 more send nothing. They fill
    # every slot (the server takes connections in the order they came), so
    # the next one gets 503 at once; each of them gets 408 at its deadline.
    t0 = time.time()
    half = socket.create_connection(("127.0.0.1", port), timeout=30)
    half.sendall(b"GET /metrics HTTP/1.1\r\nHost: h\r\n")
    drip = socket.create_connection(("127.0.0.1", port), timeout=30)
    idle = [socket.create_connection(("127.0.0.1", port), timeout=30) for _ in range(CONNS - 2)]
    got, _, _ = get(port)
    assert got == 503, got
    witness()
    drip_text = b"GET /metrics HTTP/1.1\r\nHost: h\r\n\r\n"
    for k in range(len(drip_text)):
        if time.time() - t0 > REQUEST_TIMEOUT + 3:
            break
        try:
            drip.sendall(drip_text[k:k + 1])
        except (BrokenPipeError, ConnectionResetError):
            break
        if k % 4 == 0:
            witness()
        time.sleep(0.25)
    for s in [half, drip] + idle:
        buf = drain(s)
        assert buf.startswith(b"HTTP/1.1 408 Request Timeout\r\n"), buf[:80]
    # The slots are free again once the server has seen those closes.
    end = time.time() + 30
    while True:
        got, _, body = get(port)
        if got != 503 or time.time() > end:
            break
        time.sleep(0.05)
    assert got == 200, got

    H = "Host: h\r\n"
    cases = [
        (b"GARBAGE\r\n\r\n", 400),
        (b"GET /metrics HTTP/1.1\r\n\r\n", 400),                       # 1.1 without Host
        (f"GET /metrics HTTP/1.1\r\n{H}No colon\r\n\r\n".encode(), 400),
        (hello() + join("x"), 400),                                   # the game's protocol on the wrong port
        (f"POST /metrics HTTP/1.1\r\n{H}Content-Length: 0\r\n\r\n".encode(), 405),
        (f"DELETE /metrics HTTP/1.1\r\n{H}\r\n".encode(), 405),
        (f"GET /nope HTTP/1.1\r\n{H}\r\n".encode(), 404),
        (f"GET /metrics/x HTTP/1.1\r\n{H}\r\n".encode(), 404),
        (f"POST /metrics HTTP/1.1\r\n{H}Content-Length: 5\r\n\r\nhello".encode(), 413),
        (f"POST /metrics HTTP/1.1\r\n{H}Transfer-Encoding: chunked\r\n\r\n0\r\n\r\n".encode(), 413),
        (f"GET /{'u' * URL_MAX} HTTP/1.1\r\n{H}\r\n".encode(), 414),
        (f"GET /metrics HTTP/1.1\r\n{H}X-Big: {'b' * HEAD_MAX}\r\n\r\n".encode(), 431),
        (f"GET /metrics HTTP/1.1\r\n{H}".encode() + b"".join(b"X-%d: %d\r\n" % (i, i) for i in range(HEADERS_MAX))
         + b"\r\n", 431),
        (f"GET /metrics HTTP/1.1\r\n{H}X-Huge: ".encode() + b"h" * (1 << 20), 431),  # a megabyte, never ended
        (f"GET /metrics HTTP/2.0\r\n{H}\r\n".encode(), 505),
    ]
    for data, status in cases:
        got, headers, body = http(port, data)
        assert got == status, (data[:60], got, body)
        assert body.decode().startswith(f"{status} "), body
        if status == 405:
            assert headers["allow"] == "GET"
        witness()
    # HTTP/1.0, an absolute target and a query string are still /metrics,
    # and none of the above counted as a game connection.
    for data in (b"GET /metrics HTTP/1.0\r\n\r\n", f"GET http://h/metrics?x=1 HTTP/1.1\r\n{H}\r\n".encode()):
        got, _, body = http(port, data)
        assert got == 200
        values, _ = parse(body.decode())
        assert values["cvre_clients"] == 1 and values["cvre_connections_total"] == 1, values
    # The witness was never disturbed.
    witness()
    assert "witness" not in "".join(l for l in srv.logtext().splitlines() if "disconnecting" in l or "ended" in l)
    w.close()
    assert srv.stop() == 0


run([test_flag_and_help, test_figures_follow_the_game, test_slow_peers_and_bad_requests_leave_the_game_alone])
