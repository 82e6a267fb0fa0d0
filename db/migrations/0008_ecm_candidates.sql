-- 0008: refined collision maps that were not published. A refinement is
-- judged against the version in force (algo/refine/judge.h: the avatar
-- walked through both maps from the collisions that asked for it) and only
-- a better map becomes a version; any other is kept here, with its boxes and
-- the judge's figures, so that an admin sees what was tried and why it was
-- turned down (cvre-admin versions). Written by db_ecm_reject (db/ecm.c) in
-- one transaction; never published, never in force.

CREATE TABLE ecm_candidates (
    object_id    INTEGER NOT NULL REFERENCES objects(id),
    candidate    INTEGER NOT NULL,           -- 1.. within the object
    version      INTEGER NOT NULL,           -- the version in force it was judged against
    created_at   REAL    NOT NULL,
    run_id       INTEGER REFERENCES cluster_runs(id),  -- the run whose clusters asked for it
    evidence     INTEGER NOT NULL,           -- a hash of those clusters (box, extent, centroid):
                                             -- the same clusters are not refined again
    box_count    INTEGER NOT NULL,
    samples      INTEGER NOT NULL,           -- the judge's figures (judge.h)
    moves        INTEGER NOT NULL,
    phantom_old  INTEGER NOT NULL,
    phantom_new  INTEGER NOT NULL,
    opened_old   INTEGER NOT NULL,
    opened_new   INTEGER NOT NULL,
    detail       TEXT,                       -- parameters and figures, as a line of text
    PRIMARY KEY (object_id, candidate),
    FOREIGN KEY (object_id, version) REFERENCES ecm_versions(object_id, version)
) WITHOUT ROWID;
CREATE INDEX ecm_candidates_by_version ON ecm_candidates(object_id, version, evidence);

CREATE TABLE ecm_candidate_boxes (
    object_id  INTEGER NOT NULL,
    candidate  INTEGER NOT NULL,
    box_index  INTEGER NOT NULL,
    min_x REAL NOT NULL, min_y REAL NOT NULL, min_z REAL NOT NULL,
    max_x REAL NOT NULL, max_y REAL NOT NULL, max_z REAL NOT NULL,
    PRIMARY KEY (object_id, candidate, box_index),
    FOREIGN KEY (object_id, candidate) REFERENCES ecm_candidates(object_id, candidate)
) WITHOUT ROWID;

-- The clusters (of ecm_candidates.run_id) a candidate answered.
CREATE TABLE ecm_candidate_clusters (
    object_id   INTEGER NOT NULL,
    candidate   INTEGER NOT NULL,
    run_id      INTEGER NOT NULL,
    cluster_id  INTEGER NOT NULL,
    PRIMARY KEY (object_id, candidate, run_id, cluster_id),
    FOREIGN KEY (object_id, candidate) REFERENCES ecm_candidates(object_id, candidate),
    FOREIGN KEY (run_id, object_id, cluster_id) REFERENCES clusters(run_id, object_id, cluster_id)
) WITHOUT ROWID;
