#!/usr/bin/env python3
"""tools/layers.py on the tree (no problem), and on small trees made to
break each rule (it must find each one): a layer that includes one above
it, two modules that include each other, a header nobody has."""
import os
import shutil
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
LAYERS = os.path.join(HERE, "..", "..", "tools", "layers.py")


def run(root):
    p = subprocess.run([sys.executable, LAYERS, "--root", root], capture_output=True, text=True, timeout=60)
    return p.returncode, p.stdout + p.stderr


WORK = tempfile.mkdtemp(prefix="cvre-layers-")


def tree(files):
    root = tempfile.mkdtemp(dir=WORK)
    for path, text in files.items():
        os.makedirs(os.path.join(root, os.path.dirname(path)), exist_ok=True)
        with open(os.path.join(root, path), "w") as f:
            f.write(text)
    return root


def expect(cond, what, out):
    if not cond:
        print(f"FAIL: {what}\n{out}")
        sys.exit(1)


def main():
    rc, out = run(os.path.join(HERE, "..", ".."))
    expect(rc == 0 and " 0 problems" in out, "the tree follows its layers", out)

    ok = {"base/a.c": '#include "a.h"\n', "base/a.h": "", "algo/s/s.c": '#include "s.h"\n#include "a.h"\n',
          "algo/s/s.h": ""}
    rc, out = run(tree(ok))
    expect(rc == 0, "a tree that uses only layers below is clean", out)

    rc, out = run(tree(dict(ok, **{"base/b.c": '#include "s.h"\n'})))
    expect(rc == 1 and "base/b.c includes algo/s/s.h: base/ may not use algo/" in out,
           "base/ including algo/ is reported", out)

    cycle = {"client/x.c": '#include "x.h"\n#include "y.h"\n', "client/x.h": "",
             "client/y.c": '#include "y.h"\n#include "x.h"\n', "client/y.h": ""}
    rc, out = run(tree(cycle))
    expect(rc == 1 and "client/x <-> client/y" in out, "two modules that include each other are reported", out)

    rc, out = run(tree({"db/d.c": '#include "nowhere.h"\n'}))
    expect(rc == 2 and "nowhere.h" in out, "a header no layer has is bad input", out)
    print("layers: ok")


if __name__ == "__main__":
    try:
        main()
    finally:
        shutil.rmtree(WORK, ignore_errors=True)
