#!/usr/bin/env python3
"""Prints gcovr's per-file line and branch coverage side by side and checks
the targets (tools/coverage.sh runs it on build-coverage/coverage.json).

Targets: each of base/, protocol/, algo/, server/ and db/ covers at least 90% of its
lines, and every parser the network reaches covers all of its lines (a
line that cannot run is excluded in the source with gcovr's markers, with a
comment saying why). Branch coverage is reported, not checked. Exit status:
0 when every target is met, 1 when one is missed, 2 on bad input."""
import argparse
import json
import sys

TREES = ("base/", "protocol/", "algo/", "server/", "db/")
TREE_MIN = 90.0
# The parsers the network reaches: the wire codec, the importer's format
# pre-checks (which see every uploaded byte before Assimp does), the
# checked form of what cvre-import answers, the HTTP request head of the
# HTTP endpoints, the request target the web endpoint turns into a file, and
# the WebSocket frames and handshake it reads after the upgrade.
PARSERS = ("protocol/proto.c", "server/import/import.c", "server/import/import_text.c",
           "server/import/import_obj.c", "server/import/import_stl.c", "server/import/import_ply.c",
           "server/import/import_glb.c", "server/import/import_json.c", "server/import/import_pipe.c",
           "server/net/http.c", "server/net/web_files.c", "protocol/ws.c")


def pct(covered, total):
    return 100.0 * covered / total if total else 100.0


def cell(covered, total):
    return f"{pct(covered, total):6.1f}% {covered:>5}/{total:<5}" if total else f"{'-':>7} {'':>11}"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("summary", help="gcovr --json-summary output")
    args = ap.parse_args()
    try:
        with open(args.summary) as f:
            files = json.load(f)["files"]
    except (OSError, ValueError, KeyError) as e:
        print(f"coverage: cannot read {args.summary}: {e}", file=sys.stderr)
        return 2
    files.sort(key=lambda r: r["filename"])
    width = max([len(r["filename"]) for r in files] + [len("file")])
    print(f"{'file':<{width}}  {'lines':^19}  {'branches':^19}")
    for r in files:
        print(f"{r['filename']:<{width}}  {cell(r['line_covered'], r['line_total'])}  "
              f"{cell(r['branch_covered'], r['branch_total'])}")

    def total(prefix):
        rows = [r for r in files if r["filename"].startswith(prefix)]
        return [sum(r[k] for r in rows) for k in ("line_covered", "line_total", "branch_covered", "branch_total")]

    print()
    missed = []
    for tree in TREES + ("",):
        lc, lt, bc, bt = total(tree)
        print(f"{tree or 'all':<{width}}  {cell(lc, lt)}  {cell(bc, bt)}")
        if tree and pct(lc, lt) < TREE_MIN:
            missed.append(f"{tree} covers {pct(lc, lt):.1f}% of its lines, under {TREE_MIN:.0f}%")
    for name in PARSERS:
        row = next((r for r in files if r["filename"] == name), None)
        if row is None:
            missed.append(f"{name}: no coverage data")
        elif row["line_covered"] < row["line_total"]:
            missed.append(f"{name} (a parser the network reaches) misses "
                          f"{row['line_total'] - row['line_covered']} of its {row['line_total']} lines")
    for m in missed:
        print(f"coverage: target missed: {m}", file=sys.stderr)
    if not missed:
        print(f"coverage: targets met: {', '.join(TREES)} at {TREE_MIN:.0f}% of lines or more; "
              f"{', '.join(PARSERS)} at 100%")
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
