"""The server at the edges of its resources: out of file descriptors it
stops accepting for a while, says so a line a pause rather than spinning,
keeps serving who is connected, and takes the waiting connections once
descriptors come back; past --max-clients a connection is refused with a
reason; a client's stray PONG is ignored."""
import os
import resource
import socket
import struct
import subprocess
import tempfile
import time

from harness import E, TEMP_DIRS, T, Raw, Server, args, frame, run, still_moving

A = args()
PAUSE_S = 0.5  # NET_ACCEPT_PAUSE_MS in server/net/net_limits.h


def test_out_of_descriptors():
    tmp = tempfile.mkdtemp(prefix="cvre-fds-")
    TEMP_DIRS.append(tmp)
    log = open(os.path.join(tmp, "server.log"), "w+")

    def few_files():  # in the child: a hard limit the server cannot raise
        resource.setrlimit(resource.RLIMIT_NOFILE, (48, 48))

    p = subprocess.Popen([os.path.join(A.bin, "cvre-server"), "--port", "0", "--db", os.path.join(tmp, "cvre.db"),
                          "--max-per-address", "0", "--joins-per-second", "0", "--refine-interval", "0"],
                         stdout=subprocess.PIPE, stderr=log, text=True, preexec_fn=few_files)
    flood = []
    try:
        port = int(p.stdout.readline().rsplit(":", 1)[1])
        witness = Raw(port)
        witness.handshake("witness")
        started = time.time()
        for _ in range(60):  # more than the descriptors left
            flood.append(socket.create_connection(("127.0.0.1", port), timeout=5))
        end = time.time() + 60
        while True:  # two pauses, at least, have begun
            log.seek(0)
            text = log.read()
            if text.count("no new connections for 500 ms") >= 2:
                break
            assert time.time() < end, "no pause in the log within 60 s"
            time.sleep(0.05)
        for seq in range(1, 4):  # those connected are served meanwhile
            still_moving(witness, seq)
        log.seek(0)
        pauses = log.read().count("accept: Too many open files")
        # a line a pause, not a line a turn of the loop
        assert pauses <= (time.time() - started) / PAUSE_S + 2, pauses
        for s in flood:
            s.close()
        flood = []
        late = Raw(port)  # descriptors are back: the next pause's end takes it
        late.s.settimeout(30)
        late.handshake("late")
        p.terminate()
        assert p.wait(30) == 0
    finally:
        for s in flood:
            s.close()
        p.kill()
        p.wait()


def test_server_full():
    srv = Server(A.bin, "--max-clients", "2", "--refine-interval", "0")
    a, b = Raw(srv.port), Raw(srv.port)
    a.handshake("a")
    b.handshake("b")
    c = Raw(srv.port)
    msgs = c.wait_closed(timeout=30)
    errors = [m for m in msgs if m["type"] == "error"]
    assert errors and errors[0]["code"] == E["SERVER_FULL"] and "server full" in errors[0]["message"], msgs
    assert "refused: server full (2 clients)" in srv.logtext()
    still_moving(a, 1)
    assert srv.stop() == 0


def test_stray_pong_ignored():
    srv = Server(A.bin, "--refine-interval", "0")
    c = Raw(srv.port)
    c.handshake("ponger")
    c.send(frame(T["PONG"], struct.pack("<Q", 7)))  # answers nothing the server asked
    still_moving(c, 1)
    assert srv.stop() == 0


run([test_out_of_descriptors, test_server_full, test_stray_pong_ignored])
