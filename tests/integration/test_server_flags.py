"""cvre-server's and cvre-import's command lines: every flag outside its
range, or malformed, is refused with exit 2 and a message naming it; a
server that cannot start says why and exits 1; every flag at a value in
range is taken, and the server so configured serves a join."""
import json
import os
import subprocess
import tempfile
import time

from harness import TEMP_DIRS, Raw, Server, args, run

A = args()
SERVER = os.path.join(A.bin, "cvre-server")
IMPORT = os.path.join(A.bin, "cvre-import")


def server(*argv, timeout=30):
    return subprocess.run([SERVER, *argv], capture_output=True, text=True, timeout=timeout)


def refused(argv, words, code=2, program=SERVER):
    p = subprocess.run([program, *argv], capture_output=True, text=True, timeout=30)
    assert p.returncode == code, (argv, p.returncode, p.stderr)
    assert words in p.stderr, (argv, p.stderr)
    assert p.stdout == "", (argv, p.stdout)


def test_help_and_version():
    p = server("--help")
    assert p.returncode == 0 and p.stdout.startswith("usage: cvre-server"), p
    for flag in ("--world-size", "--max-upload", "--refine-max-boxes", "--metrics", "Exit status"):
        assert flag in p.stdout, flag
    p = server("--version")
    assert p.returncode == 0 and p.stdout.startswith("cvre-server ") and "(protocol " in p.stdout, p


def test_numbers_out_of_range():
    cases = [("port", "65536"), ("port", "-1"), ("tick-hz", "0"), ("tick-hz", "241"),
             ("max-clients", "0"), ("max-clients", "65536"), ("aoi-radius", "0.5"),
             ("max-speed", "0.01"), ("world-size", "9"), ("world-size", "8193"),
             ("spawn-radius", "-1"), ("handshake-timeout", "9"), ("idle-timeout", "86400001"),
             ("seed", "-1"), ("max-upload", "0"), ("max-upload", "67108865"),
             ("max-triangles", "4000001"), ("login-burst", "0"), ("quota-objects", "100000001"),
             ("quota-mb", "1048577"), ("max-per-address", "1000001"), ("joins-per-second", "-1"),
             ("import-memory", "255"), ("import-cpu", "0"), ("refine-interval", "86401"),
             ("refine-eps", "0"), ("refine-min-points", "0"), ("refine-min-users", "0"),
             ("refine-depth", "1"), ("refine-depth", "9"), ("refine-max-boxes", "1025"),
             ("refine-max-empty", "1.5"), ("refine-threads", "17"), ("stats-interval", "0.01")]
    for flag, value in cases:
        refused([f"--{flag}", value], f"--{flag} wants a number from")
    for value in ("", "abc", "12abc", "nan", "inf", "1e999"):  # not numbers at all
        refused(["--port", value], '--port wants a number from 0 to 65535, not "%s"' % value)


def test_fractions_where_whole_numbers_are_wanted():
    for flag in ("port", "tick-hz", "max-clients", "seed", "max-upload", "refine-depth", "quota-mb"):
        refused([f"--{flag}", "2.5"], f'--{flag} wants a whole number, not "2.5"')


def test_words_and_shapes():
    refused(["--auth", "maybe"], '--auth wants required or guests, not "maybe"')
    refused(["--log-level", "loud"], '--log-level wants debug, info, warn, error or off, not "loud"')
    for bad in ("7878", ":7878", "[::1:7878", "[]:7878", "localhost:", "[::1]:x"):
        words = "--metrics wants" if bad != "[::1]:x" else "--metrics wants a number from 0 to 65535"
        refused(["--metrics", bad], words)
    refused(["--metrics", "127.0.0.1:65536"], "--metrics wants a number from 0 to 65535")
    refused(["--no-such-flag"], "try --help")
    refused(["--port"], "try --help")  # its value missing
    refused(["stray"], 'unexpected argument "stray"; try --help')
    refused(["--world-size", "100", "--spawn-radius", "60"],
            "--spawn-radius 60 reaches past the world's edge: at most half of --world-size 100")


def test_cannot_start():
    tmp = tempfile.mkdtemp(prefix="cvre-flags-")
    TEMP_DIRS.append(tmp)
    db = os.path.join(tmp, "cvre.db")
    refused(["--port", "0", "--db", os.path.join(tmp, "no-such-dir", "cvre.db")], "cannot start: ", code=1)
    refused(["--port", "0", "--db", db, "--host", "no.such.host.invalid"],
            "cannot resolve no.such.host.invalid", code=1)
    refused(["--port", "0", "--db", db, "--metrics", "no.such.host.invalid:0"],
            "cannot resolve no.such.host.invalid", code=1)
    refused(["--port", "0", "--db", db, "--world", os.path.join(tmp, "no-such.world")],
            "no-such.world", code=1)


def test_every_flag_in_range_serves():
    """All flags at once, each at a value other than its default: the
    server starts, serves a join, and stops cleanly."""
    tmp = tempfile.mkdtemp(prefix="cvre-flags-")
    TEMP_DIRS.append(tmp)
    stats = os.path.join(tmp, "stats.jsonl")
    srv = Server(A.bin, "--host", "127.0.0.1", "--auth", "guests", "--login-burst", "3",
                 "--quota-objects", "5", "--quota-mb", "8", "--max-per-address", "0",
                 "--joins-per-second", "0", "--tick-hz", "30", "--max-clients", "100",
                 "--aoi-radius", "32", "--max-speed", "7.5", "--world-size", "500",
                 "--spawn-radius", "4", "--handshake-timeout", "2000", "--idle-timeout", "20000",
                 "--seed", "42", "--max-upload", "1048576", "--max-triangles", "100000",
                 "--import-memory", "1024", "--import-cpu", "10", "--refine-interval", "0",
                 "--refine-eps", "0.25", "--refine-min-points", "5", "--refine-min-users", "2",
                 "--refine-depth", "6", "--refine-max-boxes", "32", "--refine-max-empty", "0.5",
                 "--refine-threads", "1",
                 "--stats-file", stats, "--stats-interval", "0.5", "--log-level", "debug",
                 "--importer", IMPORT)
    c = Raw(srv.port)
    _, ok = c.handshake("flags")
    assert abs(ok["pos"][0]) <= 4.01 and abs(ok["pos"][2]) <= 4.01, ok  # within --spawn-radius
    end = time.time() + 60  # --stats-interval 0.5: a line a half second
    while not (os.path.exists(stats) and open(stats).read().endswith("\n")):
        assert time.time() < end, "no stats line within 60 s"
        time.sleep(0.1)
    line = json.loads(open(stats).readline())
    assert line["clients"] == 1 and "tick_us" in line and "log_committed_id" in line, line
    c.close()
    assert srv.stop() == 0
    assert "DEBUG" in srv.logtext()  # --log-level debug took
    assert "stats: clients=1" in srv.logtext()

    # a stats file that cannot be opened: said in the log, and the server serves on
    srv = Server(A.bin, "--stats-file", os.path.join(tmp, "no-such-dir", "stats.jsonl"), "--stats-interval", "0.2")
    end = time.time() + 60
    while "stats file " not in srv.logtext():
        assert time.time() < end, "no stats file warning within 60 s"
        time.sleep(0.1)
    Raw(srv.port).handshake("still")
    assert srv.stop() == 0


def test_importer_flags():
    p = subprocess.run([IMPORT, "--help"], capture_output=True, text=True, timeout=30)
    assert p.returncode == 0 and p.stdout.startswith("usage: cvre-import"), p
    p = subprocess.run([IMPORT, "--version"], capture_output=True, text=True, timeout=30)
    assert p.returncode == 0 and p.stdout.startswith("cvre-import "), p
    for argv, words in ((["--memory", "0"], "--memory: not a whole number in range: 0"),
                        (["--memory", "1048577"], "--memory: not a whole number in range"),
                        (["--cpu", "86401"], "--cpu: not a whole number in range: 86401"),
                        (["--cpu", "1x"], "--cpu: not a whole number in range: 1x"),
                        (["--no-such-flag"], "usage: cvre-import"),
                        (["stray"], "usage: cvre-import")):
        p = subprocess.run([IMPORT, *argv], capture_output=True, text=True, timeout=30)
        assert p.returncode != 0 and words in p.stderr, (argv, p)


run([test_help_and_version, test_numbers_out_of_range, test_fractions_where_whole_numbers_are_wanted,
     test_words_and_shapes, test_cannot_start, test_every_flag_in_range_serves, test_importer_flags])
