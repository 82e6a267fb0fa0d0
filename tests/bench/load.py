"""A loaded server for the long runs (crash.py, soak.py): a small world
crowded with real desks, so that bots walking at random keep running into
them and every second of load logs collisions, and the few things both
runs read from a server (its stats file, its process figures)."""
import json
import os
import random

from bench_sessions import MODELS

# The crowded world: DESKS desks within HALF m of the spawn point, in a world
# 2 * (HALF + 6) m wide (a desk reaches a few metres from its origin) whose
# walls turn the bots back towards them.
DESKS = 16
HALF = 14


def world_flags(half=HALF):
    """The server flags of a crowded world (and of a bot swarm on one address)."""
    return ["--world-size", str(2 * (half + 6)), "--spawn-radius", str(half),
            "--max-per-address", "0", "--joins-per-second", "0"]


def crowded_world(path, seed, desks=DESKS, half=HALF):
    """Writes the world file: desks copies of the OpenFOAM desk within half m
    of the origin, the same for the same seed. Some spawn points fall inside
    a desk: those avatars log "inside" collisions until they walk out, as in
    a real world."""
    rng = random.Random(seed)
    with open(path, "w") as f:
        for i in range(desks):
            x, z = rng.uniform(-half, half), rng.uniform(-half, half)
            f.write(f"object {os.path.join(MODELS, 'openfoam_desk.stl')} name desk{i} up z "
                    f"at {x:.2f} 0 {z:.2f} yaw {rng.choice((0, 90))}\n")


def stats_lines(path):
    """The complete lines of a server's --stats-file, parsed: a line the
    server was killed in the middle of (no newline yet) is left out."""
    try:
        with open(path) as f:
            text = f.read()
    except FileNotFoundError:
        return []
    return [json.loads(line) for line in text.split("\n")[:-1]]


def open_fds(pid):
    return len(os.listdir(f"/proc/{pid}/fd"))


def slope(samples):
    """Least-squares slope of (t, v) samples, per hour; 0 with fewer than 2."""
    if len(samples) < 2:
        return 0.0
    n = len(samples)
    mt = sum(t for t, _ in samples) / n
    mv = sum(v for _, v in samples) / n
    var = sum((t - mt) ** 2 for t, _ in samples)
    return 3600 * sum((t - mt) * (v - mv) for t, v in samples) / var if var else 0.0
