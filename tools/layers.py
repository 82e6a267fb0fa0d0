#!/usr/bin/env python3
"""layers.py: checks that the includes follow the layers (CONTRIBUTING.md).

Reads every #include "..." of the sources under base/, protocol/, algo/,
db/, server/ and client/, finds the header it names, and checks two
things:

  - direction: a file includes only headers of its own layer or of the
    layers below it (the table USES below, the one in CONTRIBUTING.md);
  - no cycles between modules: a module is foo.c with foo.h; module A
    depends on module B when one of A's files includes B's header. A private
    fooInt.h (what several files of one part share) counts as a module of
    its own that may build on foo.h, so that it holds only what is below
    the files that share it. Two modules that
    depend on each other, directly or round a longer loop, are reported.

Prints the module graph's size and each problem; exit status 0 when there
is none, 1 when there is one, 2 on bad input (a header it cannot find, or
two headers of one name).

Usage: python3 tools/layers.py [--root DIR] [--graph]
"""
import argparse
import os
import re
import sys

# Which layers a layer's files may include, besides its own. A layer is the
# longest prefix in this table that a path starts with.
USES = {
    "base/": [],
    "protocol/": ["base/"],
    "algo/": ["protocol/", "base/"],
    "db/": ["base/"],
    "db/admin/": ["db/", "algo/", "base/"],
    "server/net/": ["base/"],
    "server/import/": ["protocol/", "base/"],
    "server/pipeline/": ["db/", "algo/", "protocol/", "base/"],
    "server/": ["server/net/", "server/import/", "server/pipeline/", "db/", "algo/", "protocol/", "base/"],
    "client/": ["protocol/", "base/"],
}
SOURCES = ("base", "protocol", "algo", "db", "server", "client")
INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.M)


def layer_of(path):
    best = ""
    for prefix in USES:
        if path.startswith(prefix) and len(prefix) > len(best):
            best = prefix
    return best


def module_of(path):
    return os.path.splitext(path)[0]


def sccs(graph):
    """Tarjan's strongly connected components, iteratively."""
    index, low, on, stack, out, counter = {}, {}, set(), [], [], [0]
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on.add(root)
        while work:
            node, it = work[-1]
            nxt = next(it, None)
            if nxt is not None:
                if nxt not in index:
                    index[nxt] = low[nxt] = counter[0]
                    counter[0] += 1
                    stack.append(nxt)
                    on.add(nxt)
                    work.append((nxt, iter(sorted(graph.get(nxt, ())))))
                elif nxt in on:
                    low[node] = min(low[node], index[nxt])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                comp = []
                while True:
                    w = stack.pop()
                    on.discard(w)
                    comp.append(w)
                    if w == node:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--root", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."),
                    help="the source tree (default: this script's checkout)")
    ap.add_argument("--graph", action="store_true", help="also print every module's dependencies")
    args = ap.parse_args()
    root = os.path.abspath(args.root)

    files = []
    for top in SOURCES:
        for d, _, names in os.walk(os.path.join(root, top)):
            files += [os.path.relpath(os.path.join(d, n), root) for n in names if n.endswith((".c", ".h"))]
    if not files:
        print(f"layers: no sources under {root}", file=sys.stderr)
        return 2
    headers = {}
    for f in files:
        if f.endswith(".h"):
            name = os.path.basename(f)
            if name in headers:
                print(f"layers: two headers named {name}: {headers[name]} and {f}", file=sys.stderr)
                return 2
            headers[name] = f

    problems, graph = [], {}
    for f in sorted(files):
        with open(os.path.join(root, f), encoding="utf-8") as fh:
            text = fh.read()
        mod = module_of(f)
        graph.setdefault(mod, set())
        for inc in INCLUDE.findall(text):
            target = headers.get(os.path.basename(inc))
            if target is None:
                if os.path.basename(inc) == inc and inc.endswith(".c"):
                    continue  # a generated or included source: not a layer's header
                print(f"layers: {f} includes \"{inc}\", which no layer has", file=sys.stderr)
                return 2
            mine, theirs = layer_of(f), layer_of(target)
            if theirs != mine and theirs not in USES[mine]:
                problems.append(f"{f} includes {target}: {mine} may not use {theirs}")
            dep = module_of(target)
            if dep != mod and mod != dep + "Int":  # fooInt.h may build on foo.h
                graph[mod].add(dep)

    for comp in sccs(graph):
        problems.append("modules that depend on each other: " + " <-> ".join(comp))
    if args.graph:
        for mod in sorted(graph):
            print(f"{mod}: {' '.join(sorted(graph[mod])) or '-'}")
    edges = sum(len(v) for v in graph.values())
    print(f"layers: {len(files)} files, {len(graph)} modules, {edges} dependencies, {len(problems)} problems")
    for p in problems:
        print("  " + p)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
