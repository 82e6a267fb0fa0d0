"""cvre-admin kick, ban, unban and bans against the real server on
loopback, all while it runs: a kicked session gets bye (kicked) and is
closed, its record ends with reason kicked; a banned account and a banned
guest name are disconnected and their joins refused (error 40, "banned"),
the account's resume token too; bans lists them (table, CSV, JSON);
unban lets the name in again. A witness keeps moving throughout and never
notices. Then the refusals and their exit codes, and the help texts."""
import csv
import io
import json
import sqlite3
import time
from contextlib import closing

from harness import E, Raw, Server, admin, args, iso, ping, refused_join, run, still_moving

A = args()
BYE_KICKED = 2  # PROTO_BYE_KICKED
BAN_COLUMNS = ["name", "until", "since"]


def session(db, sid):
    """Session sid as cvre-admin sessions --json shows it, or None."""
    _, out, _ = admin("sessions", "--json", "--limit", "0", db=db)
    return next((r for r in json.loads(out) if r["session"] == sid), None)


def wait_for(what, fn, timeout=20):
    """Polls fn until it returns something true; returns that."""
    end = time.time() + timeout
    while True:
        v = fn()
        if v or time.time() > end:
            assert v, f"no {what} within {timeout}s"
            return v
        time.sleep(0.05)


def kicked_out(c):
    """c gets bye (reason kicked) and the server closes it."""
    msgs = c.wait_closed(timeout=10)
    byes = [m for m in msgs if m["type"] == "bye"]
    assert byes and byes[0]["reason"] == BYE_KICKED, msgs


def ended(db, sid, reason):
    """Waits for session sid's record to end, and checks why it did."""
    def done():
        s = session(db, sid)
        return s if s and s["ended"] else None
    s = wait_for(f"the end of session {sid}", done)
    assert s["reason"] == reason, s


def record(out):
    """A record in table form ("field  value" lines) as a dict."""
    return dict(line.split(None, 1) for line in out.strip().split("\n"))


def bans(db):
    _, out, _ = admin("bans", "--json", db=db)
    return {r["name"]: r for r in json.loads(out)}


def test_kick_ban_unban_while_running():
    srv = Server(A.bin, "--login-burst", "50")
    w = Raw(srv.port)
    w.handshake("witness")
    bystander = Raw(srv.port)
    bystander.handshake("bystander")
    still_moving(w, 1)

    # kick: that session only, bye then close; its record says kicked
    kid = Raw(srv.port)
    welcome, _ = kid.handshake("kid")
    sid = welcome["session"]
    wait_for(f"session {sid} in the store", lambda: session(srv.db, sid))
    _, out, _ = admin("kick", sid, db=srv.db)
    fields = record(out)
    assert fields["session"] == str(sid) and fields["user"] == f"guest{sid}:kid", fields
    kicked_out(kid)
    still_moving(w, 2)
    bystander.send(ping(7))
    bystander.expect("pong", where=lambda m: m["stamp"] == 7)
    ended(srv.db, sid, "kicked")
    _, _, err = admin("kick", sid, db=srv.db, check=1)
    assert f"session {sid} is not open (it ended: kicked)" in err, err
    _, _, err = admin("kick", 999999, db=srv.db, check=1)
    assert "no session 999999" in err, err

    # ban of a connected account: closed, its password and token refused
    pw = srv.account("mallory")
    mal = Raw(srv.port)
    mw, ok = mal.handshake("mallory", pw)
    troll = Raw(srv.port)  # a guest under the name banned next
    tw, _ = troll.handshake("troll")
    wait_for("the sessions in the store", lambda: session(srv.db, mw["session"]) and session(srv.db, tw["session"]))
    still_moving(w, 3)
    _, out, _ = admin("ban", "Mallory", db=srv.db)  # any letter case
    fields = record(out)
    assert list(fields) == BAN_COLUMNS and fields["name"] == "Mallory" and fields["until"] == "never", fields
    kicked_out(mal)
    still_moving(w, 4)
    assert "mallory is banned" in refused_join(srv.port, "mallory", E["AUTH"], password=pw)
    assert "token" in refused_join(srv.port, "mallory", E["AUTH"], token=ok["token"])  # revoked
    ended(srv.db, mw["session"], "banned")

    # a guest name, for a while: the guest is closed, the name refused
    _, out, _ = admin("ban", "troll", "--minutes", "5", "--json", db=srv.db)
    (t,) = json.loads(out)
    with closing(sqlite3.connect(srv.db)) as con:
        (until, since), = con.execute("SELECT until, created_at FROM bans WHERE name = 'troll'").fetchall()
    assert t == {"name": "troll", "until": iso(until), "since": iso(since)} and 299 < until - since < 301, t
    kicked_out(troll)
    ended(srv.db, tw["session"], "banned")
    assert "troll is banned for 5 more minutes" in refused_join(srv.port, "troll", E["AUTH"])
    assert "banned" in refused_join(srv.port, "TROLL", E["AUTH"])
    still_moving(w, 5)

    # bans shows both, in every form
    got = bans(srv.db)
    assert list(got) == ["Mallory", "troll"] and got["Mallory"]["until"] == "never", got
    assert got["troll"] == t, got
    _, out, _ = admin("bans", "--csv", db=srv.db)
    rows = list(csv.reader(io.StringIO(out, newline="")))
    assert rows == [BAN_COLUMNS, ["Mallory", "never", got["Mallory"]["since"]], ["troll", t["until"], t["since"]]], rows
    _, out, _ = admin("bans", db=srv.db)
    lines = out.rstrip("\n").split("\n")
    assert lines[0].split() == BAN_COLUMNS and lines[2].split()[:2] == ["Mallory", "never"], lines
    assert lines[3].split() == ["troll", iso(until, 3), iso(since, 3)], lines

    # unban: they join again; a second unban has nothing to lift
    _, out, _ = admin("unban", "mallory", "--json", db=srv.db)
    assert json.loads(out) == [got["Mallory"]], out
    mal = Raw(srv.port)
    mal.handshake("mallory", pw)
    _, _, err = admin("unban", "mallory", db=srv.db, check=1)
    assert "mallory is not banned" in err, err
    admin("unban", "troll", db=srv.db)
    Raw(srv.port).handshake("troll")
    assert bans(srv.db) == {}
    still_moving(w, 6)
    assert not w.closed and not bystander.closed
    assert srv.stop() == 0


def test_refusals_and_help():
    srv = Server(A.bin)
    assert srv.stop() == 0
    for argv, words in [
        (["kick"], "wants a session number"),
        (["kick", "abc"], 'wants a positive whole number as the session, not "abc"'),
        (["kick", "0"], "not \"0\""),
        (["kick", "1", "2"], 'unexpected argument "2"'),
        (["kick", "1", "--minutes", "5"], "--minutes is not an option of this command"),
        (["ban"], "wants a name"),
        (["ban", "x" * 33], "a name is 1 to 32 bytes, not 33"),
        (["ban", "a\tb"], "a control character at byte 1"),
        (["ban", "eve", "--minutes", "0"], "--minutes wants a whole number from 1 to 52596000"),
        (["ban", "eve", "--minutes", "1.5"], 'not "1.5"'),
        (["ban", "eve", "--minutes", "52596001"], 'not "52596001"'),
        (["ban", "eve", "--minutes"], "--minutes needs a value"),
        (["--minutes", "5", "ban", "eve"], "--minutes must come after the command"),
        (["unban"], "wants a name"),
        (["unban", "a", "b"], 'unexpected argument "b"'),
        (["bans", "eve"], 'unexpected argument "eve"'),
    ]:
        _, _, err = admin(*argv, db=srv.db, check=2)
        assert words in err, (argv, err)
    assert bans(srv.db) == {}  # nothing was written
    _, _, err = admin("unban", "eve", db=srv.db, check=1)
    assert "eve is not banned" in err, err
    _, _, err = admin("kick", 1, db=srv.db, check=1)  # nobody ever connected
    assert "no session 1" in err, err
    _, out, _ = admin("bans", db=srv.db)
    assert out.split() == ["name", "until", "since", "----", "-----", "-----"], out
    # a ban whose time is up is no ban
    admin("ban", "eve", "--minutes", "1", db=srv.db)
    with closing(sqlite3.connect(srv.db)) as con:
        con.execute("UPDATE bans SET until = until - 120, created_at = created_at - 86400")
        con.commit()
    assert bans(srv.db) == {}
    admin("unban", "eve", db=srv.db, check=1)
    _, out, _ = admin("ban", "eve", "--json", db=srv.db)  # a new ban, not the old one's row
    (eve,) = json.loads(out)
    with closing(sqlite3.connect(srv.db)) as con:
        (since,), = con.execute("SELECT created_at FROM bans").fetchall()
    assert eve == {"name": "eve", "until": "never", "since": iso(since)} and since > time.time() - 60, eve

    _, out, _ = admin("--help")
    for line in ("kick SESSION", "ban NAME [--minutes N]", "unban NAME", "bans "):
        assert "\n  " + line in out, out
    assert "the only command that writes" not in out and "kick, ban and unban write" in out, out
    for cmd in ("kick", "ban", "unban", "bans"):
        _, out, _ = admin(cmd, "--help")
        _, out2, _ = admin("help", cmd)
        assert out == out2 and out.startswith("usage: cvre-admin " + cmd), out


run([test_kick_ban_unban_while_running, test_refusals_and_help])
