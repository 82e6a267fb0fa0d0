-- 0002: imported objects, their meshes, their collision maps (ECM) with
-- history, and the collision log.
-- Object-local coordinates are the model's own after import (Y up, metres);
-- world = R_y(yaw) * (scale * local) + pos.

CREATE TABLE objects (
    id           INTEGER PRIMARY KEY,
    owner_id     INTEGER NOT NULL REFERENCES users(id),
    name         TEXT    NOT NULL,           -- label given at upload (e.g. file name)
    format       TEXT    NOT NULL,           -- format hint or the detected one
    created_at   REAL    NOT NULL,
    removed_at   REAL,                       -- NULL while in the world
    pos_x REAL NOT NULL, pos_y REAL NOT NULL, pos_z REAL NOT NULL,
    yaw          REAL    NOT NULL,           -- radians about +y
    scale        REAL    NOT NULL,           -- uniform
    ecm_version  INTEGER NOT NULL,           -- the version in force
    tri_count    INTEGER NOT NULL,
    min_x REAL NOT NULL, min_y REAL NOT NULL, min_z REAL NOT NULL,  -- MBR, local
    max_x REAL NOT NULL, max_y REAL NOT NULL, max_z REAL NOT NULL
);

-- Triangles in object-local coordinates: 9 little-endian float32 each.
CREATE TABLE meshes (
    object_id  INTEGER PRIMARY KEY REFERENCES objects(id),
    triangles  BLOB NOT NULL
);

CREATE TABLE ecm_versions (
    object_id   INTEGER NOT NULL REFERENCES objects(id),
    version     INTEGER NOT NULL,            -- 1 = the MBR at import
    created_at  REAL    NOT NULL,
    reason      TEXT    NOT NULL,            -- import, refine, rollback
    box_count   INTEGER NOT NULL,
    PRIMARY KEY (object_id, version)
) WITHOUT ROWID;

-- Each box knows its object, version and index; local coordinates.
CREATE TABLE ecm_boxes (
    object_id  INTEGER NOT NULL,
    version    INTEGER NOT NULL,
    box_index  INTEGER NOT NULL,
    min_x REAL NOT NULL, min_y REAL NOT NULL, min_z REAL NOT NULL,
    max_x REAL NOT NULL, max_y REAL NOT NULL, max_z REAL NOT NULL,
    PRIMARY KEY (object_id, version, box_index),
    FOREIGN KEY (object_id, version) REFERENCES ecm_versions(object_id, version)
) WITHOUT ROWID;

-- One row per blocking contact between an avatar and an ECM box.
CREATE TABLE collisions (
    id           INTEGER PRIMARY KEY,
    at           REAL    NOT NULL,           -- Unix seconds
    session_id   INTEGER NOT NULL,
    user_id      INTEGER,
    avatar_id    INTEGER NOT NULL,
    object_id    INTEGER NOT NULL,
    ecm_version  INTEGER NOT NULL,
    box_index    INTEGER NOT NULL,
    inside       INTEGER NOT NULL,           -- 1: the avatar was already inside the box
    avatar_x REAL NOT NULL, avatar_y REAL NOT NULL, avatar_z REAL NOT NULL,  -- world
    world_x  REAL NOT NULL, world_y  REAL NOT NULL, world_z  REAL NOT NULL,  -- contact, world
    local_x  REAL NOT NULL, local_y  REAL NOT NULL, local_z  REAL NOT NULL,  -- contact, object-local
    normal_x REAL NOT NULL, normal_y REAL NOT NULL, normal_z REAL NOT NULL,  -- world
    vel_x    REAL NOT NULL, vel_y    REAL NOT NULL, vel_z    REAL NOT NULL   -- m/s, world
);
CREATE INDEX collisions_by_object ON collisions(object_id, ecm_version, at);
CREATE INDEX collisions_by_user ON collisions(user_id, at);
CREATE INDEX collisions_by_time ON collisions(at);

-- Region queries: each collision's world contact point as a degenerate box.
CREATE VIRTUAL TABLE collisions_rtree USING rtree(id, min_x, max_x, min_y, max_y, min_z, max_z);
