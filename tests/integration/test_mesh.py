"""Meshes for everyone (PROTOCOL.md section 5, "Meshes"): a model one
client imports is fetched by another with cvre-client's fetch, written as
OBJ and as GLB, and both files, imported again by cvre-import, hold the
stored triangles within the quantization's error; a second fetch of the
same mesh comes from the client's memory. A wrong hash, an unknown object,
an object outside the area of interest, a request before the join, a
server-to-client frame from a client and a flood of requests each get the
protocol's answer, and a witness in the same world notices nothing."""
import os
import sqlite3
import struct
import subprocess
import tempfile
import time

from harness import (E, MODELS, T, TEMP_DIRS, Client, Raw, Server, args, frame, hello, move, ping, refused, run,
                     upload)

A = args()
BUNNY = os.path.join(MODELS, "classic", "stanford-bunny.obj")
TEAPOT = os.path.join(MODELS, "classic", "teapot.obj")
DESK = os.path.join(MODELS, "openings", "homedecor_desk.obj")
STEPS = 65535  # PROTO_MESH_STEPS


def read(path):
    with open(path, "rb") as f:
        return f.read()


def cvre_import(path, hint):
    """The triangles of a model file as cvre-import reads it (Y up, metres),
    spoken to over its pipe form (server/import/import_pipe.h)."""
    data = read(path)
    req = (b"CVRQ" + struct.pack("<IBfIB", 1, 0, 1.0, 4000000, len(hint)) + hint.encode() +
           struct.pack("<I", len(data)) + data)
    p = subprocess.run([os.path.join(A.bin, "cvre-import")], input=req, capture_output=True, timeout=60)
    out = p.stdout
    assert p.returncode == 0 and out[:4] == b"CVRA", (p.returncode, p.stderr[-500:])
    status, mlen = struct.unpack_from("<iH", out, 8)
    assert status == 0, out[14:14 + mlen]
    at = 14 + mlen
    n, = struct.unpack_from("<I", out, at)
    return list(struct.iter_unpack("<9f", out[at + 28:at + 28 + 36 * n]))


def stored(db, oid):
    """The triangles the store holds for object oid."""
    blob, = sqlite3.connect(db).execute("SELECT triangles FROM meshes WHERE object_id = ?", (oid,)).fetchone()
    return list(struct.iter_unpack("<9f", blob))


def max_error(want, got):
    """The largest difference of a coordinate between two lists of
    triangles, corner by corner, and half a quantization step of want's
    box on its longest axis."""
    assert len(got) == len(want), (len(got), len(want))
    lo = [min(t[k + 3 * c] for t in want for c in range(3)) for k in range(3)]
    hi = [max(t[k + 3 * c] for t in want for c in range(3)) for k in range(3)]
    half = max(h - l for l, h in zip(lo, hi)) / STEPS / 2
    return max(abs(a - b) for tw, tg in zip(want, got) for a, b in zip(tw, tg)), half


def test_fetch_obj_and_glb():
    srv = Server(A.bin)
    pw = srv.account("ann")
    ann = Raw(srv.port)
    ann.handshake("ann", pw)
    obj = upload(ann, 1, read(BUNNY), "bunny.obj", fmt="obj", pos=(3, 0, 3))
    out_obj, out_glb = os.path.join(srv.tmp, "bunny.obj"), os.path.join(srv.tmp, "bunny.glb")
    # the ping's pong comes after the join's objects: by then the bunny is known
    bob = Client(A.bin, srv.port, "bob",
                 f"ping\nfetch {obj['id']} {out_obj}\nfetch {obj['id']} {out_glb}\nfetch 4242 x.obj\nquit\n")
    assert bob.wait(60) == 0, bob.stderr
    info = [e for e in bob.of("object") if e["id"] == obj["id"]][0]
    assert len(info["mesh"]) == 64 and info["triangles"] == 69451, info
    fetched = bob.of("fetched")
    assert [f["cached"] for f in fetched] == [False, True], fetched
    assert fetched[0]["triangles"] == 69451 and fetched[0]["bytes"] == fetched[1]["bytes"]
    done = [e for e in bob.of("done") if e.get("command") == "fetch"]
    assert [d["result"] for d in done] == ["ok", "ok", "failed"], done

    want = stored(srv.db, obj["id"])
    assert len(want) == 69451
    for path, hint in ((out_obj, "obj"), (out_glb, "glb")):
        err, half = max_error(want, cvre_import(path, hint))
        assert err <= half * 1.01 + 1e-6, (path, err, half)
        print(f"     {hint}: {len(want)} triangles, largest error {err * 1000:.4f} mm "
              f"(half a step: {half * 1000:.4f} mm)", flush=True)
    ann.close()
    assert srv.stop() == 0


def mesh_request(oid, digest):
    return frame(T["MESH_REQUEST"], struct.pack("<I", oid) + digest)


def test_refusals_and_flood():
    srv = Server(A.bin, "--aoi-radius", "32", "--world", world_file())
    witness = Raw(srv.port)
    witness.handshake("witness")
    prober = Raw(srv.port)
    prober.handshake("prober")  # a guest: guests may look at meshes too
    objs = {}
    while len(objs) < 2:  # the join's objects: the teapot and the bunny, not the far desk
        o = prober.expect("object")
        objs[o["name"]] = o
    teapot, bunny = objs["teapot.obj"], objs["stanford-bunny.obj"]
    desk_id = 2  # the world file's second object, out of view

    wrong = bytes([teapot["mesh"][0] ^ 1]) + teapot["mesh"][1:]
    prober.send(mesh_request(teapot["id"], wrong))
    assert "another mesh" in refused(prober, teapot["id"], E["STALE_MESH"])["message"]
    prober.send(mesh_request(4242, teapot["mesh"]))
    refused(prober, 4242, E["NO_OBJECT"])
    prober.send(mesh_request(desk_id, teapot["mesh"]))
    assert "in your view" in refused(prober, desk_id, E["NO_OBJECT"])["message"]

    # the mesh itself, in chunks in order, decoded here
    prober.send(mesh_request(teapot["id"], teapot["mesh"]))
    data = b""
    while True:
        c = prober.expect("mesh_chunk")
        assert c["id"] == teapot["id"] and c["offset"] == len(data), c
        data += c["data"]
        if len(data) == c["total"]:
            break
    verts, tris = struct.unpack_from("<II", data)
    assert tris == teapot["triangles"] == 6320 and 0 < verts <= 3 * tris
    isz = 2 if verts <= 65536 else 4
    assert len(data) == 32 + 6 * verts + 3 * tris * isz
    idx = struct.unpack_from(f"<{3 * tris}{'H' if isz == 2 else 'I'}", data, 32 + 6 * verts)
    assert max(idx) < verts

    # sixteen bunnies at once (10 MB, more than the socket buffers hold),
    # unread for a while: sent within the output budget as the client reads,
    # so it is never taken for a slow reader
    prober.send(mesh_request(bunny["id"], bunny["mesh"]) * 16)
    time.sleep(1)
    whole = 0
    while whole < 16:
        c = prober.expect("mesh_chunk", timeout=30, where=lambda m: m["id"] == bunny["id"])
        whole += c["offset"] + len(c["data"]) == c["total"]
    assert not prober.closed and "slow" not in srv.logtext()

    # a flood: the first requests are served (or wait their turn), the
    # rest refused, and the connection stays
    prober.send(mesh_request(teapot["id"], teapot["mesh"]) * 200)
    prober.send(ping(77))
    seen = prober.collect("pong", timeout=30, where=lambda m: m["stamp"] == 77)
    limited = [m for m in seen if m["type"] == "rejected" and m["code"] == E["RATE_LIMITED"]]
    assert len(limited) >= 200 - 32 - 1, len(limited)
    assert not prober.closed

    # the witness was not disturbed: it pings, moves and is answered
    witness.send(ping(5) + move(1, (1, 0, 1)))
    witness.expect("pong", where=lambda m: m["stamp"] == 5)
    witness.expect("snapshot", where=lambda m: m["ack"] == 1)
    assert srv.alive()

    # before the join a mesh request is unexpected; a client never sends chunks
    early = Raw(srv.port)
    early.send(hello() + mesh_request(teapot["id"], teapot["mesh"]))
    errs = [m for m in early.wait_closed() if m["type"] == "error"]
    assert errs and errs[0]["code"] == E["UNEXPECTED"], errs
    prober.send(frame(T["MESH_CHUNK"], struct.pack("<III", 1, 1, 0) + b"x"))
    errs = [m for m in prober.wait_closed() if m["type"] == "error"]
    assert errs and errs[-1]["code"] == E["UNEXPECTED"], errs[-3:]
    witness.send(ping(6))
    witness.expect("pong", where=lambda m: m["stamp"] == 6)
    for c in (witness, prober, early):
        c.close()
    assert srv.stop() == 0


def world_file():
    """A teapot and a bunny near the spawn point, and a desk 300 m away."""
    d = tempfile.mkdtemp(prefix="cvre-it-")
    TEMP_DIRS.append(d)
    path = os.path.join(d, "mesh.world")
    with open(path, "w") as f:
        f.write(f"object {TEAPOT} at 0 0 12\nobject {DESK} at 300 0 300\nobject {BUNNY} at 0 0 -12\n")
    return path


run([test_fetch_obj_and_glb, test_refusals_and_flood])
