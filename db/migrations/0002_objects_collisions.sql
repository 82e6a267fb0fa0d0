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

-- The collision log (db/README.md, "Collision log storage").
--
-- Rows are gathered into groups: one per object, ECM version, 10 s time
-- bucket (floor(at / 10)) and 4 m cell of the world contact point
-- (floor(world / 4) on each axis). The writer appends each batch as one id
-- range sorted by (bucket, object_id, ecm_version, g): a segment per bucket.
-- Queries find candidate groups (region: the R*Tree of their cells; user:
-- collision_users; object: collision_groups by object; time: buckets), then
-- the segments of their buckets, then, by binary search on the sorted ids,
-- the id ranges holding them, and read only those rows with an exact filter.
CREATE TABLE collision_groups (
    g            INTEGER PRIMARY KEY,
    object_id    INTEGER NOT NULL,
    ecm_version  INTEGER NOT NULL,
    bucket       INTEGER NOT NULL,           -- floor(at / 10) of every row in it
    cell_x INTEGER NOT NULL, cell_y INTEGER NOT NULL, cell_z INTEGER NOT NULL  -- floor(world / 4), clamped
);
CREATE INDEX collision_groups_by_object ON collision_groups(object_id, ecm_version, bucket);

-- One row per blocking contact between an avatar and an ECM box.
CREATE TABLE collisions (
    id           INTEGER PRIMARY KEY,        -- sorted within its segment, see above
    g            INTEGER NOT NULL,           -- collision_groups.g
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

-- Id ranges whose rows all lie in one bucket, sorted by
-- (object_id, ecm_version, g).
CREATE TABLE collision_segments (
    first_id  INTEGER PRIMARY KEY,
    last_id   INTEGER NOT NULL,
    bucket    INTEGER NOT NULL
);
CREATE INDEX collision_segments_by_bucket ON collision_segments(bucket);

-- The groups holding at least one collision of a (known) user.
CREATE TABLE collision_users (
    user_id  INTEGER NOT NULL,
    g        INTEGER NOT NULL,
    PRIMARY KEY (user_id, g)
) WITHOUT ROWID;

-- Region queries: each group's cell (a 4 m cube, the outermost cells
-- unbounded) as a box, and its bucket's time span [10 b, 10 b + 10) in Unix
-- seconds as a 4th dimension, so that region and time narrow the search
-- together (32-bit floats, rounded outwards: about 2 minutes coarse today;
-- the exact bucket is in collision_groups).
CREATE VIRTUAL TABLE collision_cells USING rtree(g, min_x, max_x, min_y, max_y, min_z, max_z, min_t, max_t);
