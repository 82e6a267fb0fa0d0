"""The store failing under a running server, one write or table at a time:
while a trigger makes SQLite refuse a write (as a full or failing disk
would), or a table the server reads has gone, the request that needs it
gets an internal error naming what could not be done, everyone else is
served, the server logs the cause, and once the fault is lifted the same
request succeeds. The faults are made from outside, through a second
connection to the database, as an operator's mistake or a damaged file
would make them."""
import os
import sqlite3
import struct
import time

from harness import (E, T, Raw, Server, args, frame, hello, join, refused, refused_join, run, still_moving,
                     transform, upload, upload_frames)

A = args()
ROOM = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "..", "shared", "models", "openings",
                    "openfoam_room_with_doorway.stl")


def sql(srv, statement):
    """Runs one statement on the server's database from outside."""
    db = sqlite3.connect(srv.db, timeout=30)
    db.execute(statement)
    db.commit()
    db.close()


def refuse_writes(srv, name, table, when="1", op="INSERT"):
    sql(srv, f"CREATE TRIGGER {name} BEFORE {op} ON {table} WHEN {when} "
             f"BEGIN SELECT RAISE(ABORT, 'injected fault'); END")


def lift(srv, name):
    sql(srv, f"DROP TRIGGER {name}")


def wait_log(srv, words, timeout=30):
    end = time.time() + timeout
    while words not in srv.logtext():
        assert time.time() < end, f"no {words!r} in the log within {timeout}s"
        time.sleep(0.05)


def internal_join(srv, name, words, **cred):
    message = refused_join(srv.port, name, E["INTERNAL"], **cred)
    assert words in message, message


def test_joins_when_the_store_fails():
    srv = Server(A.bin, "--refine-interval", "0")
    pw = srv.account("carol")
    witness = Raw(srv.port)
    witness.handshake("witness")

    refuse_writes(srv, "no_guests", "users", "NEW.name LIKE 'guest%'")
    internal_join(srv, "gary", "the server could not record the join")
    wait_log(srv, "guest join of session")
    still_moving(witness, 1)
    lift(srv, "no_guests")
    Raw(srv.port).handshake("gary")

    refuse_writes(srv, "no_tokens", "account_tokens")
    internal_join(srv, "carol", "the server could not record the login", password=pw)
    wait_log(srv, "login of carol: ")
    lift(srv, "no_tokens")

    sql(srv, "ALTER TABLE bans RENAME TO bans_gone")
    internal_join(srv, "gina", "the server could not check the login")
    wait_log(srv, "ban check of gina")
    sql(srv, "ALTER TABLE bans_gone RENAME TO bans")

    sql(srv, "ALTER TABLE accounts RENAME TO accounts_gone")
    internal_join(srv, "carol", "the server could not check the login", password=pw)
    sql(srv, "ALTER TABLE accounts_gone RENAME TO accounts")
    c = Raw(srv.port)
    c.handshake("carol", password=pw)  # all lifted: the login works
    still_moving(witness, 2)
    assert srv.stop() == 0


def test_upload_when_the_store_fails():
    srv = Server(A.bin, "--refine-interval", "0")
    pw = srv.account("ann")
    ann = Raw(srv.port)
    ann.handshake("ann", password=pw)
    room = open(ROOM, "rb").read()

    refuse_writes(srv, "no_meshes", "meshes")
    ann.send(upload_frames(1, room, "room.stl", fmt="stl", up=1, pos=(10, 0, 0)))
    m = refused(ann, 1, E["INTERNAL"])
    assert "the server could not store the object" in m["message"], m
    wait_log(srv, 'storing "room.stl"')
    lift(srv, "no_meshes")
    obj = upload(ann, 2, room, "room.stl", fmt="stl", up=1, pos=(10, 0, 0))

    ann.send(frame(T["OBJECT_PLACE"], struct.pack("<I", obj["id"]) + transform((12, 0, 0))))
    moved = ann.expect("object", timeout=30, where=lambda o: o["id"] == obj["id"] and o["pos"][0] == 12)
    assert moved["triangles"] == 54, moved
    assert srv.stop() == 0


def test_session_records_lost_are_counted():
    """A tick's batch of session records refused: the server says how many
    it lost and goes on; the next batch is kept."""
    srv = Server(A.bin, "--refine-interval", "0")
    witness = Raw(srv.port)
    witness.handshake("witness")
    refuse_writes(srv, "no_sessions", "sessions")
    c = Raw(srv.port)
    c.send(hello())
    c.expect("welcome")
    wait_log(srv, "session and object records lost")
    lift(srv, "no_sessions")
    still_moving(witness, 1)
    c.send(join("late"))
    c.expect("join_ok", timeout=30)
    assert srv.stop() == 0


def test_feeds_when_their_tables_are_gone():
    """The admin feed and the collision-map change feed, read every second
    and every refine interval: a missing table is logged, not fatal."""
    srv = Server(A.bin, "--refine-interval", "0.2")
    witness = Raw(srv.port)
    witness.handshake("witness")
    sql(srv, "ALTER TABLE admin_events RENAME TO admin_events_gone")
    wait_log(srv, "admin feed: ")
    sql(srv, "ALTER TABLE admin_events_gone RENAME TO admin_events")
    sql(srv, "ALTER TABLE ecm_events RENAME TO ecm_events_gone")
    wait_log(srv, "refiner: reading the change feed: ")
    sql(srv, "ALTER TABLE ecm_events_gone RENAME TO ecm_events")
    still_moving(witness, 1)
    assert srv.stop() == 0


run([test_joins_when_the_store_fails, test_upload_when_the_store_fails, test_session_records_lost_are_counted,
     test_feeds_when_their_tables_are_gone])
