-- 0005: accounts (a name and an Argon2id password hash) and their resume
-- tokens, for a server that asks who you are. Written through db/account.c;
-- see db/account.h for the rules (names, tokens, deletion).
--
-- An account's name is the display name it joins under, so the existing
-- tables (users: every display name ever seen; sessions; objects.owner_id)
-- keep working unchanged: this migration only adds.

CREATE TABLE accounts (
    -- AUTOINCREMENT: a deleted account's id is never handed to a new one, so
    -- an id a running server still holds can only name the account it was.
    id            INTEGER PRIMARY KEY AUTOINCREMENT,
    -- 1..32 bytes of printable UTF-8 without spaces (db_account_name_check);
    -- unique ignoring ASCII case, so "Alice" cannot pose as "alice".
    name          TEXT    NOT NULL UNIQUE COLLATE NOCASE
                          CHECK (length(CAST(name AS BLOB)) BETWEEN 1 AND 32),
    -- crypto_pwhash_str (Argon2id, its parameters and salt inside the
    -- string); NULL: the account cannot log in (the reserved world account).
    password_hash TEXT,
    is_admin      INTEGER NOT NULL DEFAULT 0 CHECK (is_admin IN (0, 1)),
    created_at    REAL    NOT NULL,           -- Unix seconds
    password_at   REAL                        -- when the password was last set (NULL: never)
);

-- The reserved account that the world file's objects belong to: always id 1,
-- no password, cannot log in, cannot be deleted (db_account_delete refuses).
INSERT INTO accounts(id, name, password_hash, is_admin, created_at)
    VALUES (1, 'world', NULL, 0, (julianday('now') - 2440587.5) * 86400.0);

-- Resume tokens: a client that reconnects shows its token instead of its
-- password. Only a hash of each token is kept (crypto_generichash, 32 bytes,
-- of 32 random bytes), so a copy of the database lets nobody resume. A token
-- is used once: redeeming it deletes it.
CREATE TABLE account_tokens (
    hash        BLOB    PRIMARY KEY CHECK (length(hash) = 32),
    account_id  INTEGER NOT NULL REFERENCES accounts(id) ON DELETE CASCADE,
    created_at  REAL    NOT NULL,
    expires_at  REAL    NOT NULL              -- refused at or after this time
) WITHOUT ROWID;
CREATE INDEX account_tokens_by_account ON account_tokens(account_id, created_at);
CREATE INDEX account_tokens_by_expiry ON account_tokens(expires_at);
