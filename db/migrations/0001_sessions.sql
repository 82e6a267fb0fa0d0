-- 0001: users and their sessions, so who was connected when survives restarts.
-- Times are Unix seconds (REAL, UTC); use datetime(x, 'unixepoch') to read them.

CREATE TABLE users (
    id            INTEGER PRIMARY KEY,
    name          TEXT    NOT NULL UNIQUE,  -- display name given at join
    created_at    REAL    NOT NULL,
    last_seen_at  REAL    NOT NULL
);

CREATE TABLE sessions (
    id          INTEGER PRIMARY KEY,        -- the session id sent in welcome
    token       TEXT    NOT NULL,           -- hex of the 16-byte session token
    peer        TEXT    NOT NULL,           -- remote address:port
    started_at  REAL    NOT NULL,           -- connection accepted
    user_id     INTEGER REFERENCES users(id),
    avatar_id   INTEGER,
    joined_at   REAL,                       -- join accepted (NULL: never joined)
    ended_at    REAL,                       -- NULL while connected
    end_reason  TEXT                        -- quit, timeout, error: ..., shutdown, crashed
);

CREATE INDEX sessions_by_user ON sessions(user_id, started_at);
CREATE INDEX sessions_by_start ON sessions(started_at);
CREATE INDEX sessions_open ON sessions(ended_at) WHERE ended_at IS NULL;
