#!/usr/bin/python3
"""Benchmark of algo/refine/voxel.c (through bench_voxel) side by side with
OpenVDB's mesh-to-volume (through bench_openvdb) on the same meshes and
grids, in the same run.

Meshes: the Stanford bunny (69,451 triangles) and the OpenFOAM city block
(400,020), imported as the server does. Grids: n = 64, 128, 256 cells per
axis over each mesh's MBR. Ours marks every cell a triangle touches (exact
separating axis test), on one thread (voxel_mark) and on one per CPU
(voxel_mark_threads); OpenVDB builds an unsigned distance field with a
one-voxel narrow band (the meshes are not watertight) on cubic voxels of the
MBR's largest extent / n, with its default TBB threads (one per CPU) and
capped at one thread. Times are wall-clock medians of --repeat runs; ours
include allocating and freeing the grid, OpenVDB's exclude loading the mesh
into its arrays. Ratios are OpenVDB's time over ours at the same thread
budget: one thread against one thread, all CPUs against all CPUs.

Usage: bench_voxel.py --voxel BENCH_VOXEL [--openvdb BENCH_OPENVDB]
                      [--models DIR] [--depths 6,7,8] [--repeat 7]
Without --openvdb (OpenVDB not found when CMake ran) only ours is timed,
and the script says how to install OpenVDB.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile


def run_json(cmd):
    out = subprocess.run(cmd, check=True, stdout=subprocess.PIPE, text=True).stdout
    return [json.loads(line) for line in out.splitlines() if line.startswith("{")]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--voxel", required=True)
    ap.add_argument("--openvdb")
    ap.add_argument("--models", default=os.path.join(os.path.dirname(__file__), "../../../shared/models"))
    ap.add_argument("--depths", default="6,7,8")
    ap.add_argument("--repeat", type=int, default=7)
    a = ap.parse_args()

    with tempfile.TemporaryDirectory(prefix="bench_voxel.") as tmp:
        ours = run_json([a.voxel, "--models", a.models, "--depths", a.depths, "--repeat", str(a.repeat),
                         "--dump", tmp, "--json"])
        rows = []
        for o in ours:
            row = dict(o)
            if a.openvdb:
                dump = os.path.join(tmp, o["model"] + ".tri")
                for key, threads in (("tbb", 0), ("one", 1)):
                    v = run_json([a.openvdb, dump, "--depth", str(o["depth"]), "--threads", str(threads),
                                  "--repeat", str(max(3, a.repeat // 2))])[0]
                    row[key] = v
            rows.append(row)
            print_row(row, len(rows) == 1, bool(a.openvdb))
            sys.stdout.flush()

    if not a.openvdb:
        print("\nOpenVDB was not found when CMake ran, so only ours was timed. To compare:\n"
              "  bash tools/deps.sh --bench      # installs libopenvdb-dev\n"
              "  cmake -S . -B build && cmake --build build --target bench-voxel")
        return 0
    worst_all = min(r["tbb"]["ms"] / r["ms_threads"] for r in rows)
    worst_one = min(r["one"]["ms"] / r["ms"] for r in rows)
    worst_mixed = min(r["tbb"]["ms"] / r["ms"] for r in rows)
    print(f"\nsmallest ratio: {worst_one:.1f}x with one thread each, {worst_all:.1f}x with all CPUs on both "
          f"sides (target: 20x); OpenVDB on all CPUs against ours on one: {worst_mixed:.1f}x")
    print("cells: ours marks every cell a triangle touches (n^3 bits); OpenVDB's active voxels are\n"
          "those within one voxel of the surface, on cubic voxels of the largest extent / n.")
    return 0


def print_row(r, header, vdb):
    if header:
        h = f"{'':<28} {'':>6} {'ours ms':>8} {'ours ms':>8} {'':>7} {'':>5}"
        if vdb:
            h += f" | {'VDB ms':>7} {'VDB ms':>7} {'':>7} {'':>5} | {'ratio':>6} {'ratio':>6}"
        print(h)
        h = f"{'model':<28} {'grid':>6} {'1 thr':>8} {'all':>8} {'cells':>7} {'MB':>5}"
        if vdb:
            h += f" | {'1 thr':>7} {'TBB':>7} {'voxels':>7} {'MB':>5} | {'1 thr':>6} {'all':>6}"
        print(h)
    s = (f"{r['model'][:28]:<28} {str(r['n']) + '^3':>6} {r['ms']:8.2f} {r['ms_threads']:8.2f}"
         f" {r['cells']:7d} {r['mb']:5.2f}")
    if vdb:
        t, o = r["tbb"], r["one"]
        s += (f" | {o['ms']:7.1f} {t['ms']:7.1f} {t['active']:7d} {t['mb']:5.2f}"
              f" | {o['ms'] / r['ms']:5.1f}x {t['ms'] / r['ms_threads']:5.1f}x")
    print(s)


if __name__ == "__main__":
    sys.exit(main())
