#!/usr/bin/env python3
"""What quantizing meshes costs and saves, on every model in
../shared/models, through the real path: a world file loads them into the
store, cvre-client fetches each one (MESH_REQUEST, MESH_CHUNKs) and writes
it as OBJ, and each file is compared corner by corner with the triangles
the store holds. Prints PROTOCOL.md's table ("Why quantized"): the box,
half a quantization step of its longest axis, the largest error, the bytes
stored and sent.

Target: no coordinate off by more than half a step of its box (and float32
rounding). Exits 1 when a model misses it.

  python3 tests/bench/bench_mesh.py --bin build
"""
import os
import shutil
import sqlite3
import struct
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "integration"))
from harness import MODELS, TEMP_DIRS, Client, Server, args  # noqa: E402

# The models and their up axes (SOURCES.md: the OpenFOAM files are Z-up).
FILES = [("scenes/dabrovic_sponza.obj", "y"), ("scenes/openfoam_windAroundBuildings.obj", "z"),
         ("openings/kenney_archway_cliff_cave_stone.glb", "y"), ("openings/kenney_building-garage.glb", "y"),
         ("openings/openfoam_room_with_doorway.stl", "z"), ("openings/openfoam_desk.stl", "z"),
         ("openings/homedecor_desk.obj", "y"), ("openings/homedecor_doghouse.obj", "y"),
         ("openings/homedecor_kitchen_chair.obj", "y"), ("openings/homedecor_spiral_staircase.obj", "y"),
         ("classic/stanford-bunny.obj", "y"), ("classic/teapot.obj", "y"), ("classic/spot.obj", "y"),
         ("formats/assimp_Wuson_ascii.ply", "y"), ("formats/assimp_Spider_binary.stl", "y")]
STEPS = 65535  # PROTO_MESH_STEPS


def read_obj(path):
    """The corners of an OBJ's triangles, in order."""
    verts, corners = [], []
    with open(path) as f:
        for line in f:
            p = line.split()
            if p and p[0] == "v":
                verts.append(tuple(map(float, p[1:4])))
            elif p and p[0] == "f":
                corners += [verts[int(x) - 1] for x in p[1:4]]
    return corners


def main():
    bindir = args().bin
    tmp = tempfile.mkdtemp(prefix="cvre-bench-mesh-")
    TEMP_DIRS.append(tmp)
    world = os.path.join(tmp, "all.world")
    with open(world, "w") as f:  # 50 m apart, all within one area of interest
        for i, (m, up) in enumerate(FILES):
            f.write(f"object {os.path.join(MODELS, m)} up {up} at {-400 + 50 * i} 0 200\n")
    srv = Server(bindir, "--world", world, "--aoi-radius", "1000")
    script = "ping\n" + "".join(f"fetch {i + 1} {tmp}/{i + 1}.obj\n" for i in range(len(FILES))) + "quit\n"
    c = Client(bindir, srv.port, "bench", script)
    assert c.wait(600) == 0, c.stderr
    sent = {e["object"]: e["bytes"] for e in c.of("fetched")}
    db = sqlite3.connect(srv.db)
    missed = 0
    print("| model | triangles | box (m) | half a step (mm) | largest error (mm) | stored (bytes) | sent (bytes) |")
    print("|---|---:|---|---:|---:|---:|---:|")
    for oid, (m, up) in enumerate(FILES, 1):
        blob, = db.execute("SELECT triangles FROM meshes WHERE object_id = ?", (oid,)).fetchone()
        want = list(struct.iter_unpack("<3f", blob))
        got = read_obj(os.path.join(tmp, f"{oid}.obj"))
        assert len(got) == len(want), (m, len(got), len(want))
        ext = [max(v[k] for v in want) - min(v[k] for v in want) for k in range(3)]
        half = max(ext) / STEPS / 2
        err = max(abs(a - b) for va, vb in zip(want, got) for a, b in zip(va, vb))
        ok = err <= half * 1.01 + 1e-6
        missed += not ok
        print(f"| {m}{' (z up)' if up == 'z' else ''} | {len(want) // 3} | "
              f"{ext[0]:.3g} × {ext[1]:.3g} × {ext[2]:.3g} | {half * 1000:.3f} | {err * 1000:.3f} | "
              f"{len(blob)} | {sent[oid]} |{'' if ok else ' MISSED'}")
    db.close()
    assert srv.stop() == 0
    print(f"{len(FILES) - missed} of {len(FILES)} models within half a step")
    for d in TEMP_DIRS:  # the server's and ours, kept when a model missed
        if not missed:
            shutil.rmtree(d, ignore_errors=True)
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
