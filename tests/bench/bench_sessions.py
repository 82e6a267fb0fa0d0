"""Session benchmark: cvre-server against the cvre-client bot swarm, and the
bare frame-counting server (bare_server.c) against the same swarm, side by
side in one run. Bounded: each run lasts ramp + --seconds and stops itself.

Prints, per avatar count: tick duration p50/p99/max, inbound moves/s,
outbound bytes/s, server CPU %, peak RSS, disconnects, and the server's CPU
per inbound move as a ratio to the bare server's CPU per frame. Then, at
--ws-avatars (2,000), the same swarm over raw TCP and over WebSockets (the
server's --web port, cvre-client --ws) in turn, --ws-runs pairs: the
server's CPU per inbound move over WebSocket as a ratio to raw TCP's (the
median pair; exit status 1 when it is over --ws-target, 1.3); and for both
transports the bytes per second per avatar in and out with the bots' VR
poses (--pose: a facing and a head with every move) off and on."""
import argparse
import json
import os
import random
import re
import statistics
import signal
import subprocess
import sys
import tempfile
import time

CLK = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid):
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK  # utime + stime


def rss_mib(pid):
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return 0.0


def start(cmd, **kw):
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, **kw)
    line = p.stdout.readline()
    if not line.startswith("listening on"):
        p.kill()
        sys.exit(f"bench: {cmd[0]} did not start: {line!r}")
    return p, int(line.rsplit(":", 1)[1])


def web_port(log, proc):
    """The --web port, from the server's "web on http://HOST:PORT/" line."""
    for _ in range(100):
        m = re.search(r"web on http://[^ ]*:(\d+)/", open(log).read())
        if m:
            return int(m.group(1))
        if proc.poll() is not None:
            break
        time.sleep(0.1)
    proc.kill()
    sys.exit(f"bench: no 'web on' line in {log}")


def swarm(bindir, port, n, seconds, extra=(), name="bot", ramp=2000):
    """n bots in one client process, starting ramp connections per second
    (crash.py, soak.py and test_disk_faults.py share it)."""
    return subprocess.Popen([os.path.join(bindir, "cvre-client"), "--port", str(port), "--bots", str(n),
                             "--name", name, "--rate", "20", "--pattern", "random-walk", "--duration", str(seconds),
                             "--ramp", str(ramp), *extra], stdout=subprocess.PIPE, text=True)


def swarms(bindir, port, n, seconds, extra=(), processes=1, ramp=2000):
    """n bots in as many client processes (each its own name prefix), so
    that the clients' side keeps up on a small machine, starting ramp
    connections per second in all."""
    per = -(-n // processes)
    return [swarm(bindir, port, min(per, n - k * per), seconds, extra, f"bot{k}", max(1, ramp // processes))
            for k in range(processes) if n - k * per > 0]


def summary(procs, timeout):
    """The swarm's summaries, added up."""
    total = {}
    for proc in procs:
        out, _ = proc.communicate(timeout=timeout)
        for line in reversed(out.splitlines()):
            e = json.loads(line)
            if e.get("event") == "summary":
                for k, v in e.items():
                    if isinstance(v, (int, float)):
                        total[k] = total.get(k, 0) + v
                break
    return total


def ramp_up(stats, n, ramp):
    """Waits out the ramp: ramp seconds, then, on a machine too busy for
    it, until the server's stats line counts n clients (for at most twice
    as long again). Returns the seconds waited."""
    t0 = time.time()
    time.sleep(ramp)
    while time.time() - t0 < 3 * ramp:
        try:
            if json.loads(open(stats).read().splitlines()[-1])["clients"] >= n:
                break
        except (IndexError, ValueError):  # no line yet, or the last one half written
            pass
        time.sleep(0.5)
    return time.time() - t0


def measure_window(pid, seconds):
    """CPU seconds used and peak RSS over the steady window after ramp-up."""
    c0, t0 = cpu_seconds(pid), time.time()
    peak = 0.0
    while time.time() - t0 < seconds:
        time.sleep(0.5)
        peak = max(peak, rss_mib(pid))
    return cpu_seconds(pid) - c0, time.time() - t0, peak


def run_bare(bindir, n, ramp, seconds):
    srv, port = start([os.path.join(bindir, "tests", "bare_server")])
    sw = [swarm(bindir, port, n, ramp + seconds + 1, ["--no-handshake"])]
    time.sleep(ramp)
    c0 = cpu_seconds(srv.pid)
    # Frames are counted by the server only at exit, so estimate the window's
    # frames from the swarm's send rate: n bots x 20 Hz.
    t0 = time.time()
    time.sleep(seconds)
    cpu, wall = cpu_seconds(srv.pid) - c0, time.time() - t0
    summary(sw, 30)
    srv.send_signal(signal.SIGTERM)
    srv.communicate(timeout=10)
    return cpu / (n * 20 * wall)


MODELS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "..", "shared", "models", "openings")
# Each opening model, with what it needs to stand on the floor in metres.
PIECES = [("kenney_archway_cliff_cave_stone.glb", "", 4, 0.2), ("kenney_building-garage.glb", "", 6, 0),
          ("openfoam_room_with_doorway.stl", "up z", 1, 0), ("openfoam_desk.stl", "up z", 1, 0),
          ("homedecor_desk.obj", "", 1, 0.5), ("homedecor_doghouse.obj", "", 1, 0.5),
          ("homedecor_kitchen_chair.obj", "", 1, 0.312), ("homedecor_spiral_staircase.obj", "", 1, 0.594)]


def world_file(path, count, seed=7):
    """A world of count copies of the opening models, scattered over the
    1 km x 1 km world (same seed, same world)."""
    rng = random.Random(seed)
    with open(path, "w") as f:
        for i in range(count):
            name, up, scale, lift = PIECES[i % len(PIECES)]
            x, z = rng.uniform(-490, 490), rng.uniform(-490, 490)
            f.write(f"object {os.path.join(MODELS, name)} name o{i} {up} at {x:.2f} {lift * scale:.3f} {z:.2f} "
                    f"yaw {rng.choice((0, 90, 180, 270))} scale {scale}\n")


def run_cvre(bindir, n, ramp, seconds, objects, bots_extra=(), ws=False, processes=1, conn_rate=2000):
    """One run of the server under n bots, over raw TCP or (ws) over
    WebSockets on the server's --web port; the server is the same either
    way (its --web on, its log at info for the port's line)."""
    tmp = tempfile.mkdtemp(prefix="cvre-bench-")
    stats, log = os.path.join(tmp, "stats.jsonl"), os.path.join(tmp, "server.log")
    extra = []
    if objects:
        world_file(os.path.join(tmp, "bench.world"), objects)
        extra = ["--world", os.path.join(tmp, "bench.world")]
    with open(log, "w") as logf:
        srv, port = start([os.path.join(bindir, "cvre-server"), "--port", "0", "--db", os.path.join(tmp, "b.db"),
                           "--max-clients", str(n + 100), "--world-size", "1000", "--spawn-radius", "500",
                           "--stats-file", stats, "--stats-interval", "1", "--log-level", "info",
                           "--max-per-address", "0", "--joins-per-second", "0",
                           "--web", "127.0.0.1:0", "--web-root", tmp, *extra], stderr=logf)
    if ws:
        port = web_port(log, srv)
        bots_extra = ["--ws", *bots_extra]
    # The bots run long enough for the longest ramp and are told to end
    # (SIGINT: their byes and summary) once the window is over.
    sw = swarms(bindir, port, n, 3 * ramp + seconds + 5, bots_extra, processes, conn_rate)
    t_start = time.time()
    waited = ramp_up(stats, n, ramp)
    cpu, wall, peak = measure_window(srv.pid, seconds)
    t_end = time.time()
    for p in sw:
        p.send_signal(signal.SIGINT)
    sm = summary(sw, 60)
    srv.send_signal(signal.SIGTERM)
    srv.communicate(timeout=30)
    # Stats lines are one per second; keep those inside the steady window.
    lines = [json.loads(l) for l in open(stats)]
    steady = lines[int(waited - 0.5) + 1: int(t_end - t_start)]
    ticks = sorted(t for l in steady for t in l["tick_us"])
    secs = sum(l["seconds"] for l in steady) or 1
    moves = sum(l["moves_in"] for l in steady)
    pct = lambda q: ticks[min(len(ticks) - 1, int(q * len(ticks)))] / 1000 if ticks else float("nan")
    return dict(n=n, p50=pct(0.5), p99=pct(0.99), max=ticks[-1] / 1000 if ticks else float("nan"),
                moves_s=moves / secs, out_s=sum(l["bytes_out"] for l in steady) / secs,
                in_s=sum(l["bytes_in"] for l in steady) / secs,
                cpu_pct=100 * cpu / wall, rss=peak, cpu_per_move=cpu / moves if moves else float("nan"),
                disconnects=sm.get("disconnects", "?"), errors=sm.get("errors", "?"),
                joined=sm.get("joined", "?"), collisions_s=sm.get("collisions", 0) / (t_end - t_start))


WS_RAMP = 250  # connections per second, in all, in the WebSocket comparison


def ws_vs_tcp(a):
    """The WebSocket comparison at a.ws_avatars: a.ws_runs pairs of runs,
    TCP then WebSocket, poses off; then one pair with poses on. Prints the
    table and returns the ratio of the median pair."""
    # The web endpoint answers at most 16 upgrades at a time (503 past
    # them: server/net/http_server.h), so both transports ramp gently.
    n, ramp = a.ws_avatars, a.ws_avatars / WS_RAMP + 3
    run = lambda ws, extra=(): run_cvre(a.bin, n, ramp, a.seconds, a.objects, extra, ws, a.swarms, WS_RAMP)
    pairs = []
    for i in range(a.ws_runs):
        pairs.append((run(False), run(True)))
        print(f"# WebSocket vs TCP, pair {i + 1} of {a.ws_runs} done", file=sys.stderr, flush=True)
    on = (run(False, ["--pose"]), run(True, ["--pose"]))
    ratios = [w["cpu_per_move"] / t["cpu_per_move"] for t, w in pairs]
    print(f"\nWebSocket vs raw TCP, {n} avatars in {a.swarms} client processes, {a.seconds:g} s each, "
          f"poses off")
    print("pair | transport | joined | moves/s | tick p99 ms | CPU % | in B/s per avatar | out B/s per avatar | "
          "CPU/move us | disconnects | WS/TCP")
    for i, ((t, w), r) in enumerate(zip(pairs, ratios)):
        for name, x, shown in (("tcp", t, ""), ("ws", w, f"{r:.2f}")):
            print(f"{i + 1} | {name} | {x['joined']} | {x['moves_s']:.0f} | {x['p99']:.2f} | {x['cpu_pct']:.0f} | "
                  f"{per_avatar(x, 'in_s'):.0f} | {per_avatar(x, 'out_s'):.0f} | {x['cpu_per_move'] * 1e6:.2f} | "
                  f"{x['disconnects']} | {shown}")
    # Poses: every move carries a facing and a head (45-byte frames instead
    # of 22), which viewers get back as AVATAR_POSE when they changed past
    # the server's thresholds; a WebSocket adds a 6-byte header to each
    # move and 2 to 4 to each message out.
    # Bytes per move in show the frames' sizes whatever rate a busy machine
    # let the bots reach.
    print(f"\nposes, {n} avatars | transport | moves/s | in B/s per avatar | in B per move | out B/s per avatar | "
          f"CPU/move us")
    (t_off, w_off) = pairs[len(pairs) // 2]
    for pose, t, w in (("off", t_off, w_off), ("on", on[0], on[1])):
        for name, x in (("tcp", t), ("ws", w)):
            print(f"{pose} | {name} | {x['moves_s']:.0f} | {per_avatar(x, 'in_s'):.0f} | "
                  f"{x['in_s'] / x['moves_s'] if x['moves_s'] else float('nan'):.1f} | "
                  f"{per_avatar(x, 'out_s'):.0f} | {x['cpu_per_move'] * 1e6:.2f}")
    ratio = statistics.median(ratios)
    print(f"\nserver CPU per inbound move, WebSocket / raw TCP: {ratio:.2f} (median of {len(ratios)}; "
          f"target at most {a.ws_target:.2f})")
    return ratio


def per_avatar(r, k):
    return r[k] / r["joined"] if isinstance(r["joined"], int) and r["joined"] else float("nan")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bin", required=True, help="build directory")
    ap.add_argument("--avatars", default="1000,5000,10000",
                    help="comma-separated avatar counts; empty: only the WebSocket comparison")
    ap.add_argument("--seconds", type=float, default=10, help="steady-state window per run")
    ap.add_argument("--objects", type=int, default=0,
                    help="scatter this many real models (collisions on); 0: an empty world")
    ap.add_argument("--ws-avatars", type=int, default=2000,
                    help="avatars of the WebSocket vs TCP comparison; 0 skips it")
    ap.add_argument("--ws-runs", type=int, default=3, help="pairs of runs (TCP, WebSocket) compared")
    ap.add_argument("--ws-target", type=float, default=1.3,
                    help="the most the WebSocket's CPU per move may be, as a ratio to TCP's")
    ap.add_argument("--swarms", type=int, default=2, help="client processes the bots are spread over")
    a = ap.parse_args()
    if a.swarms < 1 or a.ws_runs < 1 or a.ws_avatars < 0:
        ap.error("--swarms and --ws-runs are at least 1, --ws-avatars at least 0")
    rows = []
    for n in [int(x) for x in a.avatars.split(",") if x]:
        ramp = n / 2000 + 3
        bare = run_bare(a.bin, n, ramp, a.seconds)
        r = run_cvre(a.bin, n, ramp, a.seconds, a.objects, processes=a.swarms)
        r["ratio"] = r["cpu_per_move"] / bare
        r["bare_us"] = bare * 1e6
        rows.append(r)
        print(f"# {n} avatars done", file=sys.stderr, flush=True)
    print(f"world: {a.objects} objects")
    if rows:
        table(rows)
    if a.ws_avatars and ws_vs_tcp(a) > a.ws_target:
        sys.exit(1)


def table(rows):
    print("avatars | joined | tick p50 ms | p99 ms | max ms | moves/s | collisions/s | out MB/s | CPU % | "
          "RSS MiB | disconnects | CPU/move us | bare CPU/frame us | ratio")
    for r in rows:
        print(f"{r['n']} | {r['joined']} | {r['p50']:.2f} | {r['p99']:.2f} | {r['max']:.2f} | {r['moves_s']:.0f} | "
              f"{r['collisions_s']:.0f} | "
              f"{r['out_s'] / 1e6:.2f} | {r['cpu_pct']:.0f} | {r['rss']:.0f} | {r['disconnects']} | "
              f"{r['cpu_per_move'] * 1e6:.2f} | {r['bare_us']:.2f} | {r['ratio']:.2f}")


if __name__ == "__main__":
    main()
