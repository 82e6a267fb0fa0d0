"""Every malformed-frame class gets an error frame naming the problem and a
close of that connection only, while other clients (a raw one and a real
cvre-client) stay connected and served."""
import math
import struct
import time

from harness import PREJOIN_CAP, E, T, Client, Raw, Server, args, frame, hello, join, move, ping, run, s8

A = args()
srv = Server(A.bin, "--handshake-timeout", "600", "--idle-timeout", "2500", "--max-speed", "100")
witness = Raw(srv.port)
witness.handshake("witness")
seq = [0]
# A real client that only waits: it must still be there, and be told bye, at the end.
bystander = Client(A.bin, srv.port, "bystander", "ping\nwait 60000\n")


def served():
    """The witness still gets pongs and its moves applied."""
    seq[0] += 1
    witness.send(ping(seq[0]) + move(seq[0], (seq[0] * 0.1, 0, 0)))
    witness.expect("pong", where=lambda m: m["stamp"] == seq[0])
    witness.expect("snapshot", where=lambda m: m["ack"] == seq[0])
    assert srv.alive()


def rejected(data, code, joined=False, name="bad", half_close=False, words=None):
    """Sends data on a new connection (after a full handshake if joined) and
    expects error `code` then a close; the witness is checked after."""
    c = Raw(srv.port)
    if joined:
        c.handshake(name)
    c.send(data)
    if half_close:
        c.s.shutdown(1)
    msgs = c.wait_closed()
    errors = [m for m in msgs if m["type"] == "error"]
    assert errors, f"no error frame before close; got {msgs}"
    assert errors[-1]["code"] == code, f"code {errors[-1]} != {code}"
    if words:
        assert words in errors[-1]["message"], errors[-1]["message"]
    c.close()
    served()
    return errors[-1]


def test_length_zero():
    rejected(struct.pack("<I", 0), E["FRAME_EMPTY"], words="below the minimum")
    rejected(struct.pack("<IB", 1, 0), E["FRAME_EMPTY"], joined=True)


def test_length_over_cap():
    rejected(struct.pack("<IH", PREJOIN_CAP + 1, T["JOIN"]) + b"x" * 10, E["FRAME_TOO_LONG"], words="before join")
    rejected(struct.pack("<IH", 65537, T["MOVE"]), E["FRAME_TOO_LONG"], joined=True, words="65537")


def test_length_overflowing_32_bits():
    rejected(struct.pack("<IH", 0xFFFFFFFF, T["HELLO"]), E["FRAME_TOO_LONG"])
    rejected(struct.pack("<IH", 0xFFFFFFFB, T["MOVE"]), E["FRAME_TOO_LONG"], joined=True)


def test_truncated_then_close():
    rejected(move(1, (0, 0, 0))[:-3], E["TRUNCATED"], joined=True, half_close=True)
    rejected(hello()[:5], E["TRUNCATED"], half_close=True)


def test_unknown_and_reserved_types():
    rejected(frame(999, b"abc"), E["UNKNOWN_TYPE"], joined=True, words="999")
    rejected(frame(36, b""), E["UNKNOWN_TYPE"], joined=True)  # reserved: object_move


def test_payload_shorter_than_layout():
    rejected(frame(T["MOVE"], struct.pack("<Iff", 1, 0, 0)), E["SHORT"], joined=True)
    rejected(frame(T["HELLO"], struct.pack("<I", 0x45525643)), E["SHORT"])


def test_trailing_bytes():
    # A move's bytes past its position are a pose (protocol 2): one past a
    # facing-only pose is trailing.
    rejected(frame(T["MOVE"], struct.pack("<I3fffB", 1, 0, 0, 0, 0, 0, 0) + b"\0"), E["TRAILING"], joined=True)
    rejected(frame(T["PING"], struct.pack("<Q", 1) + b"zz"), E["TRAILING"], joined=True)


def test_string_past_end():
    payload = bytes([30]) + b"abc" + struct.pack("<3f", 0.6, 1.8, 0.6)  # says 30, frame ends first
    rejected(hello() + frame(T["JOIN"], payload[:4]), E["BAD_STRING"])


def test_bad_names_and_boxes():
    rejected(hello() + frame(T["JOIN"], s8("") + struct.pack("<3f", 0.6, 1.8, 0.6)), E["BAD_STRING"])
    rejected(hello() + frame(T["JOIN"], bytes([3]) + b"a\x01b" + struct.pack("<3f", 0.6, 1.8, 0.6)),
             E["BAD_STRING"])
    rejected(hello() + join("tiny", (0.01, 1.8, 0.6)), E["BAD_VALUE"])
    rejected(hello() + join("world"), E["BAD_VALUE"], words="reserved")  # owns the world file's objects


def test_not_finite_coordinates():
    for bad in (math.nan, math.inf, -math.inf):
        rejected(move(1, (0, bad, 0)), E["NOT_FINITE"], joined=True)
    rejected(hello() + join("nanbox", (0.6, math.nan, 0.6)), E["NOT_FINITE"])


def test_frames_before_hello_or_join():
    rejected(move(1, (0, 0, 0)), E["UNEXPECTED"], words="before hello")
    rejected(ping(1), E["UNEXPECTED"])
    rejected(join("early"), E["UNEXPECTED"])
    rejected(hello() + move(1, (0, 0, 0)), E["UNEXPECTED"], words="before join")
    rejected(hello() + hello(), E["UNEXPECTED"])


def test_second_join():
    rejected(join("again"), E["ALREADY_JOINED"], joined=True)


def test_handshake_fields():
    rejected(hello(magic=0x12345678), E["BAD_MAGIC"])
    rejected(hello(version=1), E["VERSION"], words="speaks 2")
    rejected(frame(T["WELCOME"], b"\0" * 60), E["UNEXPECTED"], joined=True, words="server-to-client")


def test_move_sequence_must_increase():
    rejected(move(5, (0, 0, 0)) + move(5, (1, 0, 0)), E["BAD_SEQ"], joined=True)


def slowloris(c, data, limit):
    """Sends one byte every 0.1 s, pinging the witness meanwhile, until the
    server closes c; returns the messages c received."""
    msgs, end = [], time.time() + limit
    for i in range(10**6):
        if c.closed or time.time() > end:
            break
        try:
            c.send(data[i % len(data):i % len(data) + 1])
        except (BrokenPipeError, ConnectionResetError):
            break
        msgs += c.poll(0.1)
        if i % 5 == 0:
            seq[0] += 1
            witness.send(ping(seq[0]))
    msgs += c.poll(1.0)
    assert c.closed, "slow client was not closed"
    return msgs


def test_slowloris_handshake():
    c = Raw(srv.port)
    t0 = time.time()
    msgs = slowloris(c, hello() + join("slow"), 5)
    assert [m["code"] for m in msgs if m["type"] == "error"] == [E["TIMEOUT"]], msgs
    assert time.time() - t0 < 3, "handshake timeout (600 ms) took too long"
    served()


def test_slowloris_after_join():
    c = Raw(srv.port)
    c.handshake("slowjoined")
    # One big frame trickled byte by byte never completes: the idle timeout
    # counts whole frames, not bytes.
    msgs = slowloris(c, struct.pack("<IH", 60000, T["MOVE"]) + bytes(59998), 8)
    errors = [m for m in msgs if m["type"] == "error"]
    assert errors and errors[-1]["code"] == E["TIMEOUT"], msgs
    served()


def test_others_unaffected_and_bye_on_shutdown():
    assert bystander.proc.poll() is None, "the real client was disconnected"
    served()
    assert srv.stop() == 0
    bystander.wait(10)
    assert any(e["reason"] == "shutdown" for e in bystander.of("bye")), bystander.events[-3:]
    assert bystander.of("pong"), "bystander's ping was not answered"
    log = srv.logtext()
    assert "protocol version 1 not supported" in log


run([test_length_zero, test_length_over_cap, test_length_overflowing_32_bits, test_truncated_then_close,
     test_unknown_and_reserved_types, test_payload_shorter_than_layout, test_trailing_bytes,
     test_string_past_end, test_bad_names_and_boxes, test_not_finite_coordinates,
     test_frames_before_hello_or_join, test_second_join, test_handshake_fields,
     test_move_sequence_must_increase, test_slowloris_handshake, test_slowloris_after_join,
     test_others_unaffected_and_bye_on_shutdown])
