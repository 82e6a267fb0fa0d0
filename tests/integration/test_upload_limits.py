"""Uploads at their limits: one at a time per connection; all connections'
uploads in progress together within the server's upload budget (an
abandoned one gives its share back); and a full importer queue refuses the
next upload rather than holding it. Each refusal names its reason, and the
uploader stays connected."""
import os
import stat
import struct
import tempfile

from harness import E, T, TEMP_DIRS, Raw, Server, args, frame, refused, run, s8, upload_frames

A = args()
BUDGET = 64 << 20  # SRV_UPLOAD_BUDGET


def begin(upload_id, total, name="m.stl"):
    return frame(T["UPLOAD_BEGIN"], struct.pack("<II", upload_id, total) + s8(name) + s8("stl") +
                 struct.pack("<Bf", 0, 1.0))


def test_one_at_a_time_and_the_budget():
    srv = Server(A.bin, "--max-upload", str(BUDGET), "--refine-interval", "0")
    ann, bob = Raw(srv.port), Raw(srv.port)
    ann.handshake("ann", password=srv.account("ann"))
    bob.handshake("bob", password=srv.account("bob"))
    ann.send(begin(1, 40 << 20))  # announced, nothing sent yet: it holds its share
    ann.send(begin(2, 100))
    m = refused(ann, 2, E["UPLOAD"])
    assert m["message"] == "upload 1 is still in progress: one at a time", m
    bob.send(begin(7, 40 << 20))
    m = refused(bob, 7, E["UPLOAD"])
    assert m["message"] == "the server is busy with other uploads; try again later", m
    ann.close()  # abandons upload 1, and its share of the budget
    bob.send(begin(8, 40 << 20))
    bob.send(frame(T["PING"], struct.pack("<Q", 99)))
    bob.expect("pong", timeout=30, where=lambda p: p["stamp"] == 99)
    assert not [m for m in bob.queue if m["type"] == "rejected"], bob.queue
    assert "upload 1 abandoned after 0 of 41943040 bytes" in srv.logtext()
    assert srv.stop() == 0


def test_importer_queue_full():
    tmp = tempfile.mkdtemp(prefix="cvre-uploads-")
    TEMP_DIRS.append(tmp)
    helper = os.path.join(tmp, "slow-import")
    with open(helper, "w") as f:  # reads the request, takes a second, refuses the model
        f.write("#!/bin/sh\n/bin/cat > /dev/null\n/bin/sleep 1\n"
                "printf 'CVRA\\001\\000\\000\\000\\352\\377\\377\\377\\004\\000slow'\n")
    os.chmod(helper, stat.S_IRWXU)
    srv = Server(A.bin, "--importer", helper, "--refine-interval", "0")
    c = Raw(srv.port)
    c.handshake("ann", password=srv.account("ann"))
    model = b"solid m\nendsolid m\n"
    # eight wait (IMPORTER_QUEUE_MAX), and one more once the importer has
    # taken the first: the ninth or the tenth is turned away
    c.send(b"".join(upload_frames(i, model, f"m{i}.stl", fmt="stl") for i in range(1, 13)))
    busy = c.expect("rejected", timeout=30, where=lambda m: m["message"] == "the importer is busy; try again later")
    assert busy["code"] == E["UPLOAD"] and busy["request"] in (9, 10), busy
    slow = c.expect("rejected", timeout=60, where=lambda m: m["request"] == 1)
    assert slow["message"] == "slow", slow  # the importer's own answer, for the first
    assert srv.stop() == 0


run([test_one_at_a_time_and_the_budget, test_importer_queue_full])
