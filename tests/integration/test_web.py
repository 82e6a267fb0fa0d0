"""The web endpoint (--web) on the real server: the web root's files over
HTTP (a large one streamed whole, paths outside the root refused), a
WebSocket handshake and a join from a raw socket, a WebSocket client and a
TCP client that see each other, pings answered, the game's bye and a kick
as close frames; and each malformed class of the WebSocket side closes that
connection only while a witness TCP client keeps playing. cvre-client --ws,
a swarm and a single user, plays beside a TCP witness."""
import base64
import hashlib
import json
import math
import os
import signal
import socket
import struct
import subprocess
import tempfile
import time

from harness import (MODELS, TEMP_DIRS, T, Client, Raw, Server, admin, args, drain, frame, hello, join, move, ping,
                     run, split_frames, still_moving)

A = args()
GUID = b"258EAFA5-E914-47DA-95CA-C5AB0DC85B11"  # RFC 6455 4.2.2
HEAD_MAX = 8192  # server/net/http.h
REQUEST_TIMEOUT = 5.0  # server/net/http_server.h
ROOT = tempfile.mkdtemp(prefix="cvre-web-")
TEMP_DIRS.append(ROOT)
INDEX = b"<!doctype html><title>cvre</title>\n"
BIG = os.urandom(1_300_000)  # three.js's size: streamed, never buffered whole
with open(os.path.join(ROOT, "index.html"), "wb") as f:
    f.write(INDEX)
with open(os.path.join(ROOT, "big.js"), "wb") as f:
    f.write(BIG)
SRV = Server(A.bin, "--web", "127.0.0.1:0", "--web-root", ROOT)


def web_port():
    for _ in range(50):
        for line in SRV.logtext().splitlines():
            if "web on http://127.0.0.1:" in line:
                return int(line.split("web on http://127.0.0.1:")[1].split("/")[0])
        time.sleep(0.1)
    raise AssertionError("no 'web on' line: " + SRV.logtext()[-2000:])


PORT = web_port()


def http(request, timeout=30):
    """Sends request bytes, returns everything until the server closes."""
    s = socket.create_connection(("127.0.0.1", PORT), timeout=timeout)
    s.sendall(request)
    return drain(s)


def status(response):
    return int(response.split(b" ", 2)[1])


def upgrade_request(key=None, version="13", extra=""):
    key = key if key is not None else base64.b64encode(os.urandom(16)).decode()
    lines = ["GET /game HTTP/1.1", "Host: 127.0.0.1", "Upgrade: websocket", "Connection: keep-alive, Upgrade"]
    if key:
        lines.append("Sec-WebSocket-Key: " + key)
    if version:
        lines.append("Sec-WebSocket-Version: " + version)
    return ("\r\n".join(lines) + "\r\n" + extra + "\r\n").encode()


def ws_frame(b0, payload=b"", masked=True, length=None):
    """A client frame; length overrides the one written (a 64-bit form)."""
    n = len(payload)
    m = 0x80 if masked else 0
    if length is not None:
        head = bytes([b0, m | 127]) + struct.pack(">Q", length)
    elif n < 126:
        head = bytes([b0, m | n])
    elif n <= 0xFFFF:
        head = bytes([b0, m | 126]) + struct.pack(">H", n)
    else:
        head = bytes([b0, m | 127]) + struct.pack(">Q", n)
    if not masked:
        return head + payload
    key = os.urandom(4)
    return head + key + bytes(c ^ key[i % 4] for i, c in enumerate(payload))


class Ws(Raw):
    """A WebSocket game connection from a raw socket: the protocol's frames
    sent one per masked binary message, the server's messages unwrapped
    (each must hold exactly one frame); a close frame is kept in
    close_code."""

    def __init__(self, port=None):
        self.s = socket.create_connection(("127.0.0.1", port or PORT), timeout=5)
        self.wsbuf, self.queue, self.closed = b"", [], False
        self.close_code, self.pongs = None, []
        key = base64.b64encode(os.urandom(16)).decode()
        self.s.sendall(upgrade_request(key))
        head = b""
        while b"\r\n\r\n" not in head:
            d = self.s.recv(4096)
            assert d, f"closed during the handshake: {head!r}"
            head += d
        head, rest = head.split(b"\r\n\r\n", 1)
        lines = head.decode().split("\r\n")
        assert lines[0] == "HTTP/1.1 101 Switching Protocols", lines
        fields = {k.lower(): v.strip() for k, v in (line.split(":", 1) for line in lines[1:])}
        want = base64.b64encode(hashlib.sha1(key.encode() + GUID).digest()).decode()
        assert fields["sec-websocket-accept"] == want, fields
        assert fields["upgrade"].lower() == "websocket" and fields["connection"].lower() == "upgrade", fields
        self.queue += self.frames(rest)

    def send(self, data):
        """Each whole frame of data in a message of its own."""
        out = b""
        while data:
            n = 4 + struct.unpack_from("<I", data)[0]
            out += ws_frame(0x82, data[:n])
            data = data[n:]
        self.s.sendall(out)

    def raw(self, data):
        self.s.sendall(data)

    def frames(self, data):
        """The messages of the whole server frames buffered: binary ones
        each one frame of the protocol; pongs and the close kept aside."""
        self.wsbuf += data
        out = []
        while len(self.wsbuf) >= 2 and self.close_code is None:
            b0, b1 = self.wsbuf[0], self.wsbuf[1]
            assert b0 & 0x70 == 0 and b1 & 0x80 == 0, "a server frame with RSV bits or a mask"
            n, at = b1 & 0x7F, 2
            if n == 126:
                if len(self.wsbuf) < 4:
                    break
                n, at = struct.unpack_from(">H", self.wsbuf, 2)[0], 4
                assert n >= 126, "a 16-bit length not in its shortest form"
            elif n == 127:
                if len(self.wsbuf) < 10:
                    break
                n, at = struct.unpack_from(">Q", self.wsbuf, 2)[0], 10
                assert n > 0xFFFF, "a 64-bit length not in its shortest form"
            if len(self.wsbuf) < at + n:
                break
            payload, self.wsbuf = self.wsbuf[at:at + n], self.wsbuf[at + n:]
            op = b0 & 0xF
            assert b0 & 0x80, "a fragmented server frame"
            if op == 0x2:
                msgs, rest = split_frames(payload)
                assert len(msgs) == 1 and rest == b"", f"a message that is not one frame: {payload!r}"
                out += msgs
            elif op == 0xA:
                self.pongs.append(payload)
            elif op == 0x8:
                self.close_code = struct.unpack(">H", payload[:2])[0] if payload else 0
            else:
                raise AssertionError(f"unexpected server opcode {op}")
        return out

    def wait_close_frame(self, timeout=10):
        """Reads until the server's close frame and the TCP close; returns
        the close code."""
        self.wait_closed(timeout)
        assert self.close_code is not None, "closed without a close frame"
        return self.close_code


def witness():
    w = Raw(SRV.port)
    w.handshake("witness")
    return w


def test_files():
    r = http(b"GET / HTTP/1.1\r\nHost: h\r\n\r\n")
    head, body = r.split(b"\r\n\r\n", 1)
    assert status(r) == 200 and body == INDEX, r
    assert b"Content-Type: text/html" in head and b"Connection: close" in head, head
    r = http(b"GET /big.js HTTP/1.1\r\nHost: h\r\n\r\n")
    head, body = r.split(b"\r\n\r\n", 1)
    assert status(r) == 200 and f"Content-Length: {len(BIG)}".encode() in head, head
    assert body == BIG, f"{len(body)} bytes of {len(BIG)}"
    assert status(http(b"GET /nothing.html HTTP/1.1\r\nHost: h\r\n\r\n")) == 404
    assert status(http(b"GET /../" + os.path.basename(ROOT).encode() + b"/index.html HTTP/1.1\r\nHost: h\r\n\r\n")) \
        == 403
    assert status(http(b"GET /%2e%2e/etc/passwd HTTP/1.1\r\nHost: h\r\n\r\n")) == 403
    assert status(http(b"POST / HTTP/1.1\r\nHost: h\r\n\r\n")) == 405
    # An upgrade to something else than a WebSocket is ignored (RFC 9110 7.8).
    r = http(b"GET / HTTP/1.1\r\nHost: h\r\nConnection: Upgrade, HTTP2-Settings\r\nUpgrade: h2c\r\n\r\n")
    assert status(r) == 200 and r.endswith(INDEX), r


def test_not_modified():
    """Every file carries an ETag and asks to be checked again (no-cache);
    a GET with that tag gets 304 and no body, a stale tag the whole file."""
    r = http(b"GET /big.js HTTP/1.1\r\nHost: h\r\n\r\n")
    head = r.split(b"\r\n\r\n", 1)[0].decode()
    tag = [line.split(":", 1)[1].strip() for line in head.split("\r\n") if line.lower().startswith("etag:")]
    assert len(tag) == 1 and tag[0].startswith('"'), head
    assert "Cache-Control: no-cache" in head, head
    r = http(f"GET /big.js HTTP/1.1\r\nHost: h\r\nIf-None-Match: \"old\", {tag[0]}\r\n\r\n".encode())
    head, body = r.split(b"\r\n\r\n", 1)
    assert status(r) == 304 and body == b"", r[:300]
    assert f"Content-Length: {len(BIG)}".encode() in head and tag[0].encode() in head, head
    r = http(b'GET /big.js HTTP/1.1\r\nHost: h\r\nIf-None-Match: "old"\r\n\r\n')
    assert status(r) == 200 and r.split(b"\r\n\r\n", 1)[1] == BIG


def test_file_not_read_is_cut_off():
    """A peer that stops reading a large file is cut off once nothing has
    moved for the linger (HTTP_LINGER_MS, 5 s): the rest of the file is
    never read into the server's memory for it."""
    s = socket.create_connection(("127.0.0.1", PORT), timeout=30)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 65536)
    s.sendall(b"GET /big.js HTTP/1.1\r\nHost: h\r\n\r\n")
    time.sleep(REQUEST_TIMEOUT + 3)  # the linger is as long as the request's time
    got = drain(s)
    assert 0 < len(got) < len(BIG), f"{len(got)} bytes of {len(BIG)}"


def test_join_over_websocket():
    """A WebSocket client and a TCP client see each other join and move."""
    tcp = Raw(SRV.port)
    tcp.handshake("tcp-anna")
    ws = Ws()
    ws.send(hello() + join("ws-bert"))
    ws.expect("welcome")
    ok = ws.expect("join_ok")
    tcp.expect("joined", where=lambda m: m["name"] == "ws-bert" and m["id"] == ok["id"])
    ws.expect("joined", where=lambda m: m["name"] == "tcp-anna")
    start = ws.expect("snapshot")["avatars"][ok["id"]]
    ws.send(move(1, (start[0] + 0.1, start[1], start[2])))
    ws.expect("snapshot", where=lambda m: m["ack"] == 1)
    tcp.expect("snapshot", where=lambda m: ok["id"] in m["avatars"] and m["avatars"][ok["id"]][0] > start[0])
    # A ping of the WebSocket answered with its payload; the game's own ping too.
    ws.raw(ws_frame(0x89, b"are you there"))
    ws.send(ping(7))
    ws.expect("pong", where=lambda m: m["stamp"] == 7)
    assert ws.pongs == [b"are you there"], ws.pongs
    # The game's bye: a close frame 1000 after it, then the close.
    ws.send(frame(T["BYE"], bytes([0])))
    assert ws.wait_close_frame() == 1000
    tcp.expect("left", where=lambda m: m["id"] == ok["id"])
    still_moving(tcp, 1)
    tcp.close()


def moved(w, ids, dist, timeout=15):
    """Reads w's snapshots (which carry the avatars that moved) until each
    of ids has been seen at two points dist apart or more."""
    seen, end = {i: [] for i in ids}, time.time() + timeout
    while any(not pts or max(math.dist(pts[0], p) for p in pts) < dist for pts in seen.values()):
        m = w.expect("snapshot", timeout=max(0.1, end - time.time()))
        for i in ids:
            if i in m["avatars"]:
                seen[i].append(m["avatars"][i])


def test_client_over_websocket():
    """cvre-client --ws: three bots with poses and a scripted user, over
    WebSockets, and a TCP witness see each other join and move; everyone
    leaves cleanly."""
    w = Raw(SRV.port)
    _, wok = w.handshake("tcp-witness")
    bots = subprocess.Popen([os.path.join(A.bin, "cvre-client"), "--ws", "--port", str(PORT), "--bots", "3",
                             "--name", "wsbot", "--pose", "--rate", "10", "--duration", "60"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    solo = Client(A.bin, PORT, "ws-solo", None, "--ws", "--json")
    try:
        # The witness sees each of them join, the bots walk and turn their heads.
        names = {}
        while len(names) < 4:
            m = w.expect("joined", timeout=15)
            names[m["id"]] = m["name"]
        assert sorted(names.values()) == ["ws-solo", "wsbot-0", "wsbot-1", "wsbot-2"], names
        bot_ids = [i for i, n in names.items() if n.startswith("wsbot")]
        moved(w, bot_ids, 0.2)
        w.expect("pose", timeout=10, where=lambda m: m["id"] in bot_ids)
        # The user over a WebSocket sees the witness move.
        solo.until("the witness", lambda e: e["event"] == "joined" and e["name"] == "tcp-witness")
        x, y, z = wok["pos"]
        for seq in range(1, 11):  # 2 m/s, under the speed limit
            w.send(move(seq, (x + 0.2 * seq, y, z)))
            time.sleep(0.1)
        solo.until("the witness moved", lambda e: e["event"] == "snapshot" and any(
            a["id"] == wok["id"] and a["pos"][0] > x + 0.5 for a in e["avatars"]))
        # And the witness sees the user walk.
        solo.send("walk 1 0 0.5\n")
        moved(w, [i for i, n in names.items() if n == "ws-solo"], 0.5)
        solo.send("quit\n")
        assert solo.wait() == 0, solo.stderr
        bots.send_signal(signal.SIGINT)  # the swarm's end: every bot says bye
        out, err = bots.communicate(timeout=30)
        assert bots.returncode == 0, (out[-2000:], err)
        summary = [json.loads(line) for line in out.splitlines()][-1]
        assert summary["event"] == "summary" and summary["joined"] == 3 and summary["errors"] == 0, summary
        assert summary["disconnects"] == 0 and summary["frames_in"] > 0, summary
        left = set()
        while len(left) < 4:
            left.add(w.expect("left", timeout=10)["id"])
        assert left == set(names), (left, names)
        still_moving(w, 11)
    finally:
        bots.kill()
        solo.proc.kill()
        w.close()


def test_client_objects_over_websocket():
    """Over --ws, an account's import (its chunks in 16 KiB messages) and
    another user's fetch of the mesh (the server's chunks in large
    messages, read across many socket reads)."""
    os.environ["CVRE_PASSWORD"] = SRV.account("wsann")
    try:
        ann = Client(A.bin, PORT, "wsann", f"import {os.path.join(MODELS, 'classic', 'teapot.obj')} at 3 0 3\nquit\n",
                     "--ws", "--json")
    finally:
        del os.environ["CVRE_PASSWORD"]
    assert ann.wait(60) == 0, ann.stderr
    done = [e for e in ann.of("done") if e["command"] == "import"]
    assert done and done[0]["result"] == "ok", ann.events[-5:]
    oid, out = done[0]["object"], os.path.join(ROOT, "teapot-fetched.obj")
    bob = Client(A.bin, PORT, "wsbob", f"ping\nfetch {oid} {out}\nquit\n", "--ws", "--json")
    assert bob.wait(60) == 0, bob.stderr
    info = [e for e in bob.of("object") if e["id"] == oid][0]
    fetched = bob.of("fetched")
    assert fetched and fetched[0]["triangles"] == info["triangles"] > 1000, (fetched, info)
    with open(out) as f:
        assert sum(line.startswith("f ") for line in f) == info["triangles"]


def test_client_websocket_refused():
    """cvre-client --ws on the raw TCP port: the upgrade is never answered
    with a 101, and the client says which port it wanted."""
    c = Client(A.bin, SRV.port, "lost", "quit\n", "--ws", "--json")
    assert c.wait() == 1
    errors = c.of("error")
    assert errors and "--web port" in errors[0]["message"], c.events


def test_client_close_echoed():
    ws = Ws()
    ws.send(hello() + join("closer"))
    ws.expect("join_ok")
    ws.raw(ws_frame(0x88, struct.pack(">H", 4001) + b"bye now"))
    assert ws.wait_close_frame() == 4001


def test_kick_closes_with_1008():
    """cvre-admin kick: the bye (kicked), then close 1008."""
    ws = Ws()
    ws.send(hello() + join("kicked"))
    session = ws.expect("welcome")["session"]
    ws.expect("join_ok")
    for _ in range(100):  # the session's record is written at the next tick
        if admin("kick", session, db=SRV.db, check=None)[0] == 0:
            break
        time.sleep(0.1)
    assert ws.expect("bye", timeout=15)["reason"] == 2  # PROTO_BYE_KICKED
    assert ws.wait_close_frame() == 1008


def test_fragmented_message():
    """A frame of the protocol in three fragments, a ping between them."""
    ws = Ws()
    data = hello() + join("pieces")
    h = hello()
    ws.raw(ws_frame(0x02, h[:3]) + ws_frame(0x89, b"p") + ws_frame(0x00, h[3:5]) + ws_frame(0x80, h[5:]))
    ws.send(data[len(h):])
    ws.expect("join_ok")
    assert ws.pongs == [b"p"]
    ws.close()


# Each malformed class: what it sends, and the close code (None: an HTTP
# status instead, at the handshake).
BAD_FRAMES = {
    "unmasked": (ws_frame(0x82, frame(T["PING"], bytes(8)), masked=False), 1002),
    "reserved bits": (ws_frame(0xC2, frame(T["PING"], bytes(8))), 1002),
    "unknown opcode": (ws_frame(0x83, b"x"), 1002),
    "64-bit length, top bit": (ws_frame(0x82, length=1 << 63), 1002),
    "text message": (ws_frame(0x81, b"hello"), 1003),
    "fragmented control frame": (ws_frame(0x09, b"x"), 1002),
    "control frame over 125": (ws_frame(0x89, b"x" * 126), 1002),
    "message past the cap": (ws_frame(0x82, length=1 << 20), 1009),
    "message past the cap before join": (ws_frame(0x82, bytes(300)), 1009),
    "close code never sent": (ws_frame(0x88, struct.pack(">H", 1005)), 1002),
    "message of two frames": (ws_frame(0x82, hello() + join("two")), 1008),
    # The TCP side's classes, inside a well-formed message: an ERROR, then 1008.
    "frame length below 2": (ws_frame(0x82, struct.pack("<I", 1) + b"\0"), 1008),
    "unknown message type": (ws_frame(0x82, frame(200, bytes(4))), 1008),
    "bad hello": (ws_frame(0x82, frame(T["HELLO"], bytes(6))), 1008),
}


def test_malformed_frames():
    w = witness()
    for k, (name, (data, code)) in enumerate(BAD_FRAMES.items()):
        ws = Ws()
        ws.raw(data)
        msgs = ws.wait_closed(10)
        assert ws.close_code == code, f"{name}: close {ws.close_code}, expected {code}"
        if code == 1008:  # the game's refusal says why first
            assert [m["type"] for m in msgs] == ["error"], f"{name}: {msgs}"
        still_moving(w, k + 1)
    assert SRV.alive()
    w.close()


def test_bad_handshakes():
    w = witness()
    cases = {
        "missing key": (upgrade_request(key=""), 400),
        "key not 16 bytes": (upgrade_request(key=base64.b64encode(b"short").decode()), 400),
        "wrong version": (upgrade_request(version="8"), 426),
        "no version": (upgrade_request(version=""), 426),
        "HTTP/1.0": (upgrade_request().replace(b"HTTP/1.1", b"HTTP/1.0"), 400),
        "oversized headers": (upgrade_request(extra="X-Filler: " + "a" * HEAD_MAX + "\r\n"), 431),
    }
    for k, (name, (request, code)) in enumerate(cases.items()):
        r = http(request)
        assert status(r) == code, f"{name}: {r[:200]!r}"
        if code == 426:
            assert b"Sec-WebSocket-Version: 13" in r, r
        still_moving(w, 100 + k)
    # A request that never finishes: 408 once its time is up, then the close.
    s = socket.create_connection(("127.0.0.1", PORT), timeout=REQUEST_TIMEOUT + 20)
    s.sendall(upgrade_request()[:40])
    still_moving(w, 200)
    r = b""
    while True:
        d = s.recv(4096)
        if not d:
            break
        r += d
    s.close()
    assert status(r) == 408, r
    still_moving(w, 201)
    w.close()


def upgrade_status(port, origin):
    """The status line's code of an upgrade sent with this Origin header."""
    s = socket.create_connection(("127.0.0.1", port), timeout=10)
    s.sendall(upgrade_request(extra=f"Origin: {origin}\r\n"))
    head = b""
    while b"\r\n" not in head:
        d = s.recv(4096)
        assert d, head
        head += d
    s.close()
    return status(head)


def test_origin():
    """A page of another site may not open a WebSocket in a visitor's name
    (403); the server's own pages may (the Origin is the Host), and so may
    clients that send no Origin (the other tests)."""
    assert upgrade_status(PORT, "http://127.0.0.1") == 101  # upgrade_request's Host
    assert upgrade_status(PORT, "HTTPS://127.0.0.1") == 101
    for other in ("https://evil.example", "http://127.0.0.1:1", "null", "http://127.0.0.1.evil.example"):
        assert upgrade_status(PORT, other) == 403, other
    assert "not in --web-origin" in SRV.logtext()


def test_full_server_and_missing_root():
    """A second server, of one client, with no web root and two more
    origins: files are 404, a listed origin's page may open a WebSocket,
    and a WebSocket past --max-clients gets its 101, SERVER_FULL in a
    message and close 1013."""
    srv = Server(A.bin, "--web", "127.0.0.1:0", "--web-root", os.path.join(ROOT, "missing"), "--max-clients", "1",
                 "--web-origin", "https://a.example, https://play.example")
    try:
        port = None
        for _ in range(50):
            if "web on http://127.0.0.1:" in srv.logtext():
                port = int(srv.logtext().split("web on http://127.0.0.1:")[1].split("/")[0])
                break
            time.sleep(0.1)
        assert port and "every file is 404" in srv.logtext(), srv.logtext()[-2000:]
        s = socket.create_connection(("127.0.0.1", port), timeout=10)
        s.sendall(b"GET / HTTP/1.1\r\nHost: h\r\n\r\n")
        assert status(s.recv(4096)) == 404
        s.close()
        tcp = Raw(srv.port)
        tcp.handshake("only")
        ws = Ws(port)
        msgs = ws.wait_closed()
        assert [m["type"] for m in msgs] == ["error"] and msgs[0]["code"] == 30, msgs  # SERVER_FULL
        assert ws.close_code == 1013, ws.close_code
        still_moving(tcp, 1)
        assert upgrade_status(port, "https://evil.example") == 403
        assert upgrade_status(port, "https://PLAY.example") == 101  # listed (then SERVER_FULL)
        tcp.close()
        assert srv.stop() == 0
    finally:
        srv.proc.kill()


def test_shutdown_close():
    """The server's shutdown bye reaches a WebSocket client, then close 1001."""
    ws = Ws()
    ws.send(hello() + join("last"))
    ws.expect("join_ok")
    SRV.proc.send_signal(15)
    ws.expect("bye")
    assert ws.wait_close_frame() == 1001
    assert SRV.proc.wait(30) == 0


run([test_files, test_not_modified, test_file_not_read_is_cut_off, test_join_over_websocket, test_client_over_websocket,
     test_client_objects_over_websocket, test_client_websocket_refused, test_client_close_echoed,
     test_kick_closes_with_1008, test_fragmented_message, test_malformed_frames, test_bad_handshakes,
     test_origin, test_full_server_and_missing_root, test_shutdown_close])
