-- 0004: the history of each collision map (ECM) version, what caused it, and
-- the change feed that a running server follows to publish new versions.
-- Versions are written by db_ecm_write (db/ecm.c): the version, its boxes,
-- its cluster ties, objects.ecm_version and one ecm_events row in one
-- transaction. Versions only grow; a rollback writes a new version.

-- Why a version exists. All NULL for the version 1 rows an import writes
-- (and for rows from before this migration).
ALTER TABLE ecm_versions ADD COLUMN parent_version INTEGER;  -- the version in force it replaced
ALTER TABLE ecm_versions ADD COLUMN run_id INTEGER REFERENCES cluster_runs(id);  -- the run that caused it
ALTER TABLE ecm_versions ADD COLUMN restores INTEGER;        -- rollback: the version whose boxes it copies
ALTER TABLE ecm_versions ADD COLUMN detail TEXT;             -- free text: parameters, counts, who

-- The clusters (of ecm_versions.run_id) a version answers.
CREATE TABLE ecm_version_clusters (
    object_id   INTEGER NOT NULL,
    version     INTEGER NOT NULL,
    run_id      INTEGER NOT NULL,
    cluster_id  INTEGER NOT NULL,            -- clusters.cluster_id: numbered within the object
    PRIMARY KEY (object_id, version, run_id, cluster_id),
    FOREIGN KEY (object_id, version) REFERENCES ecm_versions(object_id, version),
    FOREIGN KEY (run_id, object_id, cluster_id) REFERENCES clusters(run_id, object_id, cluster_id)
) WITHOUT ROWID;
-- Which version answered a cluster (so that a job does not answer it twice).
CREATE INDEX ecm_version_clusters_by_cluster ON ecm_version_clusters(run_id, object_id, cluster_id);

-- The change feed: one row per new version, in commit order (writers take
-- the write lock first, so ids are handed out in commit order and a reader
-- never sees an id before the smaller ones). AUTOINCREMENT: ids are never
-- reused, even if the newest rows are deleted, so a follower that remembers
-- the last id it saw misses nothing.
CREATE TABLE ecm_events (
    id          INTEGER PRIMARY KEY AUTOINCREMENT,
    object_id   INTEGER NOT NULL,
    version     INTEGER NOT NULL,
    at          REAL    NOT NULL,            -- Unix seconds, = ecm_versions.created_at
    reason      TEXT    NOT NULL,            -- = ecm_versions.reason
    FOREIGN KEY (object_id, version) REFERENCES ecm_versions(object_id, version)
);
