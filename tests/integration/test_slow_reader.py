"""A client that stops reading is disconnected once its output backlog stays
over the soft limit, without growing the server's memory, while everyone
else carries on."""
import json
import os
import socket
import subprocess
import time

from harness import Raw, Server, args, run

A = args()


def rss_kib(pid):
    with open(f"/proc/{pid}/status") as f:
        return next(int(l.split()[1]) for l in f if l.startswith("VmRSS:"))


def test_non_reader_is_cut_off():
    # 100 Hz ticks and 200 busy neighbours make about 320 KB/s of snapshots
    # for the one client that never reads.
    srv = Server(A.bin, "--tick-hz", "100", "--spawn-radius", "3", "--max-speed", "20", "--max-per-address", "0", "--joins-per-second", "0")
    lazy = Raw(srv.port)
    lazy.s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    lazy.handshake("lazy")
    rss0 = rss_kib(srv.proc.pid)
    bots = subprocess.Popen([os.path.join(A.bin, "cvre-client"), "--port", str(srv.port), "--bots", "200",
                             "--rate", "100", "--pattern", "circle", "--duration", "20"],
                            stdout=subprocess.PIPE, text=True)
    deadline, cut = time.time() + 40, False
    while time.time() < deadline and not cut:
        time.sleep(0.5)
        cut = "output backlog" in srv.logtext()
    assert cut, "the non-reading client was never disconnected"
    grew = rss_kib(srv.proc.pid) - rss0
    bots.send_signal(2)  # the swarm says bye and prints its summary
    out, _ = bots.communicate(timeout=15)
    summary = [json.loads(l) for l in out.splitlines() if '"summary"' in l][0]
    assert summary["disconnects"] == 0 and summary["errors"] == 0, summary
    assert summary["joined"] == 200, summary
    # The backlog is bounded by the hard limit (2 MiB); the rest is the bots.
    assert grew < 64 * 1024, f"server RSS grew by {grew} KiB"
    assert srv.stop() == 0


run([test_non_reader_is_cut_off])
