-- 0003: results of the clustering job (cvre-cluster): one row per run and one
-- per cluster found, each naming the ECM box it points at (the problem box).

CREATE TABLE cluster_runs (
    id           INTEGER PRIMARY KEY,
    started_at   REAL    NOT NULL,
    finished_at  REAL    NOT NULL,
    eps          REAL    NOT NULL,
    min_points   INTEGER NOT NULL,
    min_users    INTEGER NOT NULL,
    since        REAL,                 -- time window of the collisions read (NULL: open)
    until        REAL,
    objects      INTEGER NOT NULL,     -- objects examined
    points       INTEGER NOT NULL,     -- collisions read
    clusters     INTEGER NOT NULL,
    problem_boxes INTEGER NOT NULL     -- distinct (object, box) with a cluster
);

CREATE TABLE clusters (
    run_id       INTEGER NOT NULL REFERENCES cluster_runs(id),
    object_id    INTEGER NOT NULL,
    ecm_version  INTEGER NOT NULL,
    cluster_id   INTEGER NOT NULL,     -- 0.. within the object, in DBSCAN's order
    points       INTEGER NOT NULL,
    users        INTEGER NOT NULL,
    centroid_x REAL NOT NULL, centroid_y REAL NOT NULL, centroid_z REAL NOT NULL,  -- object-local
    min_x REAL NOT NULL, min_y REAL NOT NULL, min_z REAL NOT NULL,
    max_x REAL NOT NULL, max_y REAL NOT NULL, max_z REAL NOT NULL,
    box_index    INTEGER NOT NULL,     -- the ECM box the cluster presses on: the problem box
    PRIMARY KEY (run_id, object_id, cluster_id)
) WITHOUT ROWID;
CREATE INDEX clusters_by_object ON clusters(object_id, ecm_version, run_id);
