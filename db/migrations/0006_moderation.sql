-- 0006: moderation: names barred from joining, and the feed of admin
-- actions (kick, ban, unban) that a running server follows, as it follows
-- ecm_events for new collision maps. Written through db/moderation.c.

-- A banned name (an account's, or a guest's display name) may not join
-- until `until` (NULL: until unbanned). Letter case does not matter, as for
-- account names.
CREATE TABLE bans (
    name        TEXT    PRIMARY KEY COLLATE NOCASE,
    until       REAL,                         -- Unix seconds; NULL: no end
    created_at  REAL    NOT NULL
);

-- The actions a running server applies within a second: kick a session
-- (session_id); ban (disconnect every session joined under name) or unban
-- a name; logout (an account's password changed: its sessions end) and
-- deleted (an account is gone: its sessions end, its objects are the world
-- account's). AUTOINCREMENT: ids are never reused, so a follower that
-- remembers the last id it saw misses nothing.
CREATE TABLE admin_events (
    id          INTEGER PRIMARY KEY AUTOINCREMENT,
    kind        TEXT    NOT NULL CHECK (kind IN ('kick', 'ban', 'unban', 'logout', 'deleted')),
    session_id  INTEGER,                      -- kick
    name        TEXT,                         -- ban, unban
    at          REAL    NOT NULL
);
