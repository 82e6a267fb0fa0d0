"""World files (--world): every malformed line stops the start with its
line number and the expected form; a model that is missing, too large, not
a model or placed outside the world stops it with a message saying which; comments, blank lines, both path forms and every option load; a
model listed twice is parsed once; and on a restart with the same database
the listed objects are restored, not loaded again."""
import os
import shutil
import subprocess
import tempfile

from harness import MODELS, TEMP_DIRS, Raw, Server, args, run

A = args()
SERVER = os.path.join(A.bin, "cvre-server")
DESK = os.path.join(MODELS, "openings", "openfoam_desk.stl")
FORM = "expected: object PATH [name NAME] [up y|z] [units S] at X Y Z [yaw DEG] [scale S]"


def folder():
    d = tempfile.mkdtemp(prefix="cvre-world-")
    TEMP_DIRS.append(d)
    shutil.copy(DESK, os.path.join(d, "desk.stl"))
    return d


def refused(text, words, *extra):
    """Starts the server on a world file of text; expects exit 1 and words
    in its log."""
    d = folder()
    world = os.path.join(d, "test.world")
    with open(world, "w") as f:
        f.write(text)
    p = subprocess.run([SERVER, "--port", "0", "--db", os.path.join(d, "cvre.db"), "--world", world, *extra],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 1, (text, p.returncode, p.stderr)
    assert words in p.stderr, (text, p.stderr)
    assert p.stdout == "", (text, p.stdout)
    return p.stderr


def test_malformed_lines():
    for line in ("thing desk.stl at 0 0 0",      # not an object line
                 "object",                        # no path
                 "object desk.stl",               # no position
                 "object desk.stl at 0 0",        # a coordinate short
                 "object desk.stl at 0 x 0",      # not a number
                 "object desk.stl at 0 0 inf",    # not finite
                 "object desk.stl at 0 0 0 name",  # an option without its value
                 "object desk.stl up w at 0 0 0",
                 "object desk.stl units 0 at 0 0 0",
                 "object desk.stl at 0 0 0 yaw north",
                 "object desk.stl at 0 0 0 scale 1e9",
                 "object desk.stl at 0 0 0 colour red"):
        refused("# a comment, then a blank line\n\n" + line + "\n", "line 3: " + FORM)


def test_models_that_cannot_load():
    refused("object missing.stl at 0 0 0\n", "line 1: ")
    err = refused("object missing.stl at 0 0 0\n", "missing.stl: No such file or directory")
    assert "world file " in err
    refused("object desk.stl at 0 0 0\n", "desk.stl: over the upload limit of 100 bytes", "--max-upload", "100")
    d = folder()
    with open(os.path.join(d, "junk.stl"), "w") as f:
        f.write("this is no model at all\n")
    refused(f"object {d}/junk.stl at 0 0 0\n", "line 1: not a valid STL file")  # an absolute path
    refused("object desk.stl at 5000 0 0\n", "desk.stl cannot go there: ")  # past the world's edge
    refused("object desk.stl at 0 0 0 scale 1000\n", "desk.stl cannot go there: ")  # larger than any object


def test_every_option_loads_and_restarts():
    d = folder()
    world = os.path.join(d, "all.world")
    with open(world, "w") as f:
        f.write("# every option, and the same model twice with the same import options\n"
                "\n"
                "object desk.stl name desk-a up z units 1 at 20 0 20 yaw 90 scale 1\n"
                f"object {d}/desk.stl name desk-b up z at -20 0 20 scale 0.5\n"
                "object desk.stl up y units 0.5 at 20 0 -20\n")
    db = os.path.join(d, "cvre.db")
    srv = Server(A.bin, "--world", world, db=db)
    c = Raw(srv.port)
    c.handshake("looker")
    names = set()
    for _ in range(3):
        names.add(c.expect("object", timeout=30)["name"])
    assert names == {"desk-a", "desk-b", "desk.stl"}, names
    c.close()
    assert srv.stop() == 0
    log = srv.logtext()
    assert "3 objects loaded from 2 model files, 0 already in the database" in log, log

    again = Server(A.bin, "--world", world, db=db)
    c = Raw(again.port)
    c.handshake("looker")
    ids = {c.expect("object", timeout=30)["id"] for _ in range(3)}
    assert len(ids) == 3
    c.close()
    assert again.stop() == 0
    assert "0 objects loaded from 0 model files, 3 already in the database" in again.logtext()


run([test_malformed_lines, test_models_that_cannot_load, test_every_option_loads_and_restarts])
